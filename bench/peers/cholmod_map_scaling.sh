#!/usr/bin/env bash
# Scaling table for `rigslam map solve` against CHOLMOD:
# generates map problems of 1e3..1e6 landmarks (simulated drive, knn:4
# edges), solves each with both, alternating, REPEATS times (1 for 1e6),
# and prints the markdown rows of bench/README.md with the best time of
# each side, their ratio, peak RSS and the largest position difference.
#
# Usage: bench/peers/cholmod_map_scaling.sh [WORKDIR] [SIZES...]   (from the repository root)
# Needs a release build of rigslam (cargo build --release) and sets up the
# CHOLMOD venv through cholmod_map_solve.sh.
set -euo pipefail
cd "$(dirname "$0")/../.."
WORK=${1:-/tmp/rigslam-map-bench}
shift || true
SIZES=${*:-1000 10000 100000 1000000}
mkdir -p "$WORK"
BIN=${RIGSLAM_BIN:-${CARGO_TARGET_DIR:-target}/release/rigslam}
bench/peers/cholmod_map_solve.sh /dev/null /dev/null >/dev/null 2>&1 || true   # venv setup only
export OPENBLAS_NUM_THREADS=${OPENBLAS_NUM_THREADS:-1}
exec .venv-cholmod/bin/python bench/peers/cholmod_map_scaling.py "$BIN" "$WORK" $SIZES
