#!/usr/bin/env bash
# OpenCV peer for `rigslam-calibrate camera`: installs
# opencv-python-headless from PyPI in ./.venv-opencv (gitignored) and
# recreates fixtures/opencv/chessboard_9x6_25mm.json, OpenCV's corners and
# calibrateCamera results on the 13 real chessboard images.
# fixtures/opencv/README.md records version, date and command.
#
# Usage: bench/peers/opencv_chessboard.sh   (from the repository root)
set -euo pipefail
cd "$(dirname "$0")/../.."
DATA=$(realpath "${RIGSLAM_SHARED_DATA:-../shared/data}")/calib
if [ ! -x .venv-opencv/bin/python ] || ! .venv-opencv/bin/python -c 'import cv2' 2>/dev/null; then
  python3 -m venv .venv-opencv
  .venv-opencv/bin/pip install --quiet opencv-python-headless numpy
fi
.venv-opencv/bin/python bench/peers/opencv_chessboard.py \
  "$DATA/chessboard_9x6_25mm" fixtures/opencv/chessboard_9x6_25mm.json
