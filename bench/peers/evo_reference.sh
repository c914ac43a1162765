#!/usr/bin/env bash
# Reference numbers for `rigslam eval` from evo (https://github.com/MichaelGrupp/evo).
# Recreates fixtures/evo/*.json; tests/eval_vs_evo.rs holds the same numbers
# as constants and fixtures/evo/README.md records version, date and output.
#
# Usage: bench/peers/evo_reference.sh   (from the repository root)
# Needs: python3 with venv; installs evo into ./.venv (gitignored).
set -euo pipefail
cd "$(dirname "$0")/../.."
# The shared data sits beside the repository; a worktree elsewhere can point
# RIGSLAM_SHARED_DATA at it.
DATA=$(realpath "${RIGSLAM_SHARED_DATA:-../shared/data}")/euroc/ground_truth
GT=$DATA/V1_02_groundtruth.csv
EST=$DATA/V1_02_estimate_sample.tum
OUT=fixtures/evo
WORK=$(mktemp -d)
trap 'rm -rf "$WORK"' EXIT

if [ ! -x .venv/bin/evo_ape ]; then
  python3 -m venv .venv
  .venv/bin/pip install evo
fi
export PATH=$PWD/.venv/bin:$PATH
echo "evo $(.venv/bin/python -c 'import importlib.metadata as m; print(m.version("evo"))')"

# Stats of one result zip as JSON on one line (evo stores full float64).
stats() { unzip -p "$1" stats.json; echo; }

# The ground truth converted by evo itself, kept as a record of what evo reads
# from the EuRoC csv (ns stamps -> float seconds, wxyz -> TUM xyzw).
(cd "$WORK" && evo_traj euroc "$GT" --save_as_tum >/dev/null)
head -c 300 "$WORK/V1_02_groundtruth.tum"; echo "... ($(wc -l < "$WORK/V1_02_groundtruth.tum") poses)"

# APE (translation part) after SE(3) and Sim(3) Umeyama alignment,
# default association (nearest stamp, max_diff 0.01 s, no offset).
evo_ape euroc "$GT" "$EST" -a --save_results "$WORK/ape_se3.zip" >/dev/null
evo_ape euroc "$GT" "$EST" -as --save_results "$WORK/ape_sim3.zip" >/dev/null
# The paper's final drift (eq. 72) anchors the estimate at its first pose:
# evo's --align_origin applies the same T_gt0 * T_est0^-1; the last APE value
# is then the numerator of the drift.
evo_ape euroc "$GT" "$EST" --align_origin --save_results "$WORK/ape_origin.zip" >/dev/null
# RPE between consecutive matched poses: translation (m) and rotation angle (deg).
evo_rpe euroc "$GT" "$EST" --delta 1 --delta_unit f --save_results "$WORK/rpe_frame_trans.zip" >/dev/null
evo_rpe euroc "$GT" "$EST" --delta 1 --delta_unit f -r angle_deg --save_results "$WORK/rpe_frame_rot.zip" >/dev/null
# RPE over ~1 m of ground-truth path: every start pose, the end pose whose
# path distance along the ground truth (--pairs_from_reference; evo's default
# measures it along the estimate) is closest to 1 m, accepted within 10 %.
evo_rpe euroc "$GT" "$EST" --delta 1 --delta_unit m --all_pairs --delta_tol 0.1 --pairs_from_reference \
  --save_results "$WORK/rpe_1m_trans.zip" >/dev/null

for name in ape_origin ape_se3 ape_sim3 rpe_frame_trans rpe_frame_rot rpe_1m_trans; do
  stats "$WORK/$name.zip" > "$OUT/$name.json"
  printf '%-16s pairs=%s %s\n' "$name" \
    "$(.venv/bin/python -c "import numpy,zipfile,io,sys; z=zipfile.ZipFile(sys.argv[1]); print(len(numpy.load(io.BytesIO(z.read('error_array.npy')))))" "$WORK/$name.zip")" \
    "$(cat "$OUT/$name.json")"
done
echo "ape_origin last error (final position error after anchoring, m):" \
  "$(.venv/bin/python -c "import numpy,zipfile,io,sys; z=zipfile.ZipFile(sys.argv[1]); print(repr(float(numpy.load(io.BytesIO(z.read('error_array.npy')))[-1])))" "$WORK/ape_origin.zip")"
# True path length between the first and last matched stamps, over every
# ground-truth pose in between (the denominator of eq. 72), by evo's own
# path_length on the ground truth cut to that interval.
.venv/bin/python - "$GT" "$EST" <<'PY'
import sys
from evo.tools import file_interface
from evo.core import sync
gt = file_interface.read_euroc_csv_trajectory(sys.argv[1])
est = file_interface.read_tum_trajectory_file(sys.argv[2])
gt_matched, _ = sync.associate_trajectories(gt, est)
gt.reduce_to_time_range(gt_matched.timestamps[0], gt_matched.timestamps[-1])
print("true path length between first and last matched stamps, m:", repr(gt.path_length))
PY
