#!/usr/bin/env bash
# OpenCV peer for `rigslam bench frontend`: times goodFeaturesToTrack (200
# corners) + calcOpticalFlowPyrLK (21x21, 3 levels, forward-backward) and
# ORB_create(1000).detectAndCompute on the same frames, single-threaded.
#
# Usage: bench/peers/opencv_frontend.sh --images DIR [--json]   (from the repo root)
# Needs: python3 with venv; installs opencv-python-headless into ./.venv-opencv
# (gitignored).
set -euo pipefail
cd "$(dirname "$0")/../.."
VENV=.venv-opencv
if [ ! -x "$VENV/bin/python" ] || ! "$VENV/bin/python" -c 'import cv2' 2>/dev/null; then
  python3 -m venv "$VENV"
  "$VENV/bin/pip" install --quiet opencv-python-headless numpy
fi
# One thread on the BLAS/OpenMP side as well as in OpenCV itself.
export OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1
exec "$VENV/bin/python" bench/peers/opencv_frontend.py "$@"
