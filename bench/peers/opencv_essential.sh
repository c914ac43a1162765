#!/usr/bin/env bash
# OpenCV's findEssentialMat (RANSAC) + recoverPose against
# `rigslam bench essential` on the same KITTI matches, both single-threaded,
# in the same run so the ratio is fair on a shared machine.
#
# Usage: bench/peers/opencv_essential.sh   (from the repository root)
# Needs: python3 with venv; installs opencv-python-headless into
# ./.venv-opencv (gitignored) and builds rigslam in release.
set -euo pipefail
cd "$(dirname "$0")/../.."
DATA=$(realpath "${RIGSLAM_SHARED_DATA:-../shared/data}")/kitti
MATCHES=$DATA/seq_a_matches.txt
GT=$DATA/seq_a_gt_rel.txt

if [ ! -x .venv-opencv/bin/python ] || ! .venv-opencv/bin/python -c 'import cv2' 2>/dev/null; then
  python3 -m venv .venv-opencv
  .venv-opencv/bin/pip install --quiet opencv-python-headless numpy
fi
cargo build --release -p rigslam --bin rigslam --quiet
RIGSLAM=${CARGO_TARGET_DIR:-target}/release/rigslam

for run in 1 2 3; do
  echo "run $run"
  echo -n "opencv  "; OMP_NUM_THREADS=1 taskset -c 0 .venv-opencv/bin/python bench/peers/opencv_essential.py --matches "$MATCHES" --gt "$GT"
  echo -n "rigslam "; taskset -c 0 "$RIGSLAM" bench essential --matches "$MATCHES" --gt "$GT" --json
done
