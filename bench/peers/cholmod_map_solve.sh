#!/usr/bin/env bash
# Peer for `rigslam map solve`: CHOLMOD through scipy +
# scikit-sparse, solving the same edges files.
#
# Usage: bench/peers/cholmod_map_solve.sh EDGES OUT [--json]   (from the repository root)
# Sets up ./.venv-cholmod (gitignored) on first use; needs Debian's
# libsuitesparse-dev and libopenblas0-pthread (installed with apt-get when missing).
set -euo pipefail
cd "$(dirname "$0")/../.."
VENV=.venv-cholmod
if ! dpkg -s libsuitesparse-dev libopenblas0-pthread >/dev/null 2>&1; then
  apt-get update -qq
  DEBIAN_FRONTEND=noninteractive apt-get install -y -qq libsuitesparse-dev libopenblas0-pthread python3-venv python3-dev build-essential >/dev/null
fi
if [ ! -x "$VENV/bin/python" ] || ! "$VENV/bin/python" -c 'import sksparse.cholmod' 2>/dev/null; then
  python3 -m venv "$VENV"
  "$VENV/bin/pip" install -q --upgrade pip
  "$VENV/bin/pip" install -q numpy scipy "cython<3" wheel setuptools
  SUITESPARSE_INCLUDE_DIR=/usr/include/suitesparse "$VENV/bin/pip" install -q --no-build-isolation scikit-sparse==0.4.16
fi
exec "$VENV/bin/python" bench/peers/cholmod_map_solve.py "$@"
