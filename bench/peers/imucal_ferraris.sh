#!/usr/bin/env bash
# imucal peer for `rigslam-calibrate imu`: installs imucal from PyPI
# in ./.venv-peers (gitignored) and recreates fixtures/imucal/ferraris_session.json,
# imucal's Ferraris calibration of the real session with its section list.
# fixtures/imucal/README.md records version, date and command.
#
# Usage: bench/peers/imucal_ferraris.sh   (from the repository root)
set -euo pipefail
cd "$(dirname "$0")/../.."
DATA=$(realpath "${RIGSLAM_SHARED_DATA:-../shared/data}")/imu
if [ ! -x .venv-peers/bin/python ] || ! .venv-peers/bin/python -c 'import imucal, allantools' 2>/dev/null; then
  python3 -m venv .venv-peers
  .venv-peers/bin/pip install imucal allantools
fi
.venv-peers/bin/python bench/peers/imucal_ferraris.py \
  "$DATA/imucal_ferraris_session_102p4hz.csv" "$DATA/imucal_ferraris_session_list.json" \
  fixtures/imucal/ferraris_session.json
