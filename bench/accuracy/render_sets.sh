#!/usr/bin/env bash
# Renders the two accuracy sets from the real EuRoC logs in ../shared/data.
#
#   development set: V1_02 along a cubic spline through the ground truth
#     (`--spline through`, the default room, seeds 0-5), the real V1_02 IMU;
#     what the estimator is tuned on.
#   evaluation set (held apart, never tuned on): the ground-truth poses
#     interpolated at each camera stamp with no spline (`--spline none`),
#     other rooms (box count, texture scale) and scene seeds, the real
#     V1_01 and V1_02 IMUs; scored from rest and in flight.
#
# Every sensor.yaml declares the ADIS16448's datasheet noise
# (`--declared-noise datasheet`): what a user on a robot has, not what the
# ground truth reveals.
#
#   consistent-IMU set (`synth`, not in `all`): 45 s of V1_02 (seeds 10-12)
#     and of V1_01 (seeds 20-22) with the IMU synthesised from the rendered
#     motion with the datasheet's noise, so the cameras and the IMU agree
#     exactly and the calibration file is the truth: where the camera-IMU
#     refinement can be scored without the real IMU's own disagreement
#     with the ground truth.
#
# usage: bench/accuracy/render_sets.sh OUT_DIR [dev|eval|all|synth]
set -euo pipefail
cd "$(dirname "$0")/../.."
out=${1:?usage: render_sets.sh OUT_DIR [dev|eval|all|synth]}
which=${2:-all}
data=../shared/data/euroc
bin=${RIGSLAM:-target/release/rigslam}
[ -x "$bin" ] || { echo "build first: cargo build --release (or set RIGSLAM)" >&2; exit 1; }
mkdir -p "$out"

render() { # name, then simulate's options
  local name=$1; shift
  if [ -f "$out/$name/mav0/state_groundtruth_estimate0/data.csv" ]; then
    echo "have $out/$name"; return
  fi
  echo "rendering $out/$name" >&2
  "$bin" simulate --out "$out/$name" --stereo --no-progress --declared-noise datasheet "$@"
}

if [ "$which" = dev ] || [ "$which" = all ]; then
  for seed in 0 1 2 3 4 5; do
    render "dev_v102_s$seed" --trajectory "$data/ground_truth/V1_02_groundtruth.csv" \
      --imu "real:$data/ground_truth/V1_02_imu0.csv" --spline through --seed "$seed"
  done
fi
if [ "$which" = eval ] || [ "$which" = all ]; then
  # V1_01 from rest (65 s), a room with many large-textured boxes. The
  # trajectory is EuRoC's own ground truth of the body (IMU) frame at the
  # camera stamps. Not V1_01_gt_200hz.txt: that file's body is another
  # frame (about 5.5 deg and 4 cm from the IMU's, constant over the run),
  # and cameras rendered along it disagree with the real IMU as a 5 deg
  # error in the camera-IMU calibration would.
  render eval_v101_a --trajectory "$data/V1_01_micro/mav0/state_groundtruth_estimate0/data.csv" \
    --imu "real:$data/V1_01_micro/mav0/imu0/data.csv" --spline none \
    --duration-s 65 --boxes 20 --texel-mm 8 --seed 101
  # V1_02 (83 s), a sparse room with fine texture.
  render eval_v102_b --trajectory "$data/ground_truth/V1_02_groundtruth.csv" \
    --imu "real:$data/ground_truth/V1_02_imu0.csv" --spline none \
    --boxes 6 --texel-mm 4 --seed 102
fi
if [ "$which" = synth ]; then
  for seed_boxes in 10:12 11:19 12:20; do
    seed=${seed_boxes%:*}
    render "synth_v102_s$seed" --trajectory "$data/ground_truth/V1_02_groundtruth.csv" \
      --duration-s 45 --seed "$seed" --boxes "${seed_boxes#*:}"
  done
  for seed in 20 21 22; do
    render "synth_v101_s$seed" --trajectory "$data/V1_01_micro/mav0/state_groundtruth_estimate0/data.csv" \
      --duration-s 45 --seed "$seed"
  done
fi
