#!/usr/bin/env bash
# GTSAM peer for IMU preintegration: installs gtsam from PyPI in
# ./.venv (gitignored), recreates fixtures/gtsam/v1_01_preintegration.txt
# (GTSAM's deltas and covariances for 200 V1_01 intervals spread over the flight) and times
# GTSAM per sample. fixtures/gtsam/README.md records version, date, command.
#
# Usage: bench/peers/gtsam_preintegration.sh [--time-only]   (from the repository root)
set -euo pipefail
cd "$(dirname "$0")/../.."
DATA=$(realpath "${RIGSLAM_SHARED_DATA:-../shared/data}")/euroc
IMU=$DATA/V1_01_micro/mav0/imu0/data.csv
GT=$DATA/ground_truth/V1_01_gt_camrate.csv
INTERVALS=200
if [ ! -x .venv/bin/python ] || ! .venv/bin/python -c 'import gtsam' 2>/dev/null; then
  python3 -m venv .venv
  .venv/bin/pip install gtsam numpy
fi
if [ "${1:-}" = "--time-only" ]; then
  .venv/bin/python bench/peers/gtsam_preintegration.py --time-only "$IMU" "$GT" "$INTERVALS"
else
  .venv/bin/python bench/peers/gtsam_preintegration.py "$IMU" "$GT" fixtures/gtsam/v1_01_preintegration.txt "$INTERVALS"
fi
