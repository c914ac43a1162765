#!/usr/bin/env bash
# The EuRoC AprilGrid recording re-rendered with a known stereo pair, through
# the whole `rigslam-calibrate camera-imu` step (known_stereo_pair.py says
# how). Installs opencv-python-headless from PyPI in ./.venv-opencv
# (gitignored) for the per-instant PnP and the projection.
#
# Usage: bench/calibration/known_stereo_pair.sh [--noise-px 0.5] [--yaw-deg 0] [--seed 1]
#        (from the repository root, after `cargo build --release -p rigslam-calibration`)
set -euo pipefail
cd "$(dirname "$0")/../.."
if [ ! -x .venv-opencv/bin/python ] || ! .venv-opencv/bin/python -c 'import cv2, yaml' 2>/dev/null; then
  python3 -m venv .venv-opencv
  .venv-opencv/bin/pip install --quiet opencv-python-headless numpy pyyaml
fi
.venv-opencv/bin/python bench/calibration/known_stereo_pair.py "$@"
