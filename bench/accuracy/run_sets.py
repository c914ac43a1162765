#!/usr/bin/env python3
"""Runs the accuracy sets that `render_sets.sh` wrote and prints one table.

Every sequence of the development set (seeds 0-5 from rest, seed 0 in
flight) and of the held-apart evaluation set (V1_01 room A and V1_02
room B, from rest and in flight), or of the consistent-IMU set
(`--sets synth`: six renderings from rest and from 20 s), in each mode
asked for, with the same settings (`--config`, default: the defaults). Columns: ATE RMSE (se3,
m), scale error (%), NEES per dof of the published covariance, and
whether the run lost track or re-initialised; with the absolute stage on
(`[absolute] enabled = true` in `--config`), the two-stage ATE against
the relative stage's poses of the same run, the position filter's
mean NIS per dof and the published map-frame position's NEES per dof
(mean, median in brackets, then the mean taken from the relative
stage's origin that pins the map frame); in the inertial modes the
relative stage's roll and pitch error against gravity (rms, deg). The means per set and mode
are at the end; with `stereo` among the modes, each inertial run is also
compared with the same cameras without the IMU.

usage: bench/accuracy/run_sets.py SETS_DIR [--modes stereo-inertial mono-inertial stereo]
       [--config C.toml] [--sets dev eval synth] [--match TEXT] [--jobs 2] [--out rows.json]
"""
import argparse, json, os, subprocess, sys, tempfile
from concurrent.futures import ThreadPoolExecutor

# name, folder, start (s), frame count (None: to the end)
DEV = [(f"dev s{s}", f"dev_v102_s{s}", 0, None) for s in range(6)] + [
    ("dev s0 in flight", "dev_v102_s0", 25, 600)]
EVAL = [
    ("V1_01 A rest", "eval_v101_a", 0, None),
    ("V1_01 A flight", "eval_v101_a", 30, None),
    ("V1_02 B rest", "eval_v102_b", 0, None),
    ("V1_02 B flight", "eval_v102_b", 25, None),
]
# The consistent-IMU set (`render_sets.sh OUT synth`): an IMU synthesised
# from the rendered motion, so cameras and IMU agree exactly and the
# calibration file is the truth; for the camera-IMU refinement.
SYNTH = [(f"synth {f} {'flight' if t else 'rest'}", f"synth_{f}", t, None)
         for f in ["v102_s10", "v102_s11", "v102_s12", "v101_s20", "v101_s21", "v101_s22"]
         for t in (0, 20)]
SETS = {"dev": DEV, "eval": EVAL, "synth": SYNTH}


def run(binary, root, seq, mode, config):
    name, folder, start, frames = seq
    with tempfile.TemporaryDirectory() as d:
        report = os.path.join(d, "report.json")
        cmd = [binary, "run", "--dataset", os.path.join(root, folder), "--mode", mode,
               "--report", report, "--quiet"]
        if config:
            cmd += ["--config", config]
        if start:
            cmd += ["--start-s", str(start)]
        if frames:
            cmd += ["--max-frames", str(frames)]
        p = subprocess.run(cmd, capture_output=True, text=True)
        if p.returncode != 0:
            return {"sequence": name, "mode": mode, "error": p.stderr.strip()[-400:]}
        with open(report) as f:
            r = json.load(f)
    e = r.get("eval") or {}
    nees = r.get("nees") or {}
    counters = r.get("counters") or {}
    return {
        "sequence": name, "mode": mode,
        "ate_m": e.get("ate_rmse_m"),
        # With the absolute stage on: the relative stage's own poses, same run.
        "ate_relative_m": (r.get("eval_relative") or {}).get("ate_rmse_m"),
        # ... and its position filter's mean NIS per dof (about 1 when the
        # landmark covariances it is given are right).
        "absolute_nis": (r.get("absolute") or {}).get("mean_nis_per_dof"),
        # ... and the NEES of the map-frame position covariance it publishes.
        "map_nees": (r.get("map_nees") or {}).get("mean_per_dof"),
        "map_nees_median": (r.get("map_nees") or {}).get("median_per_dof"),
        # ... the same taken from the relative stage's origin that pins
        # the map frame (what the run shares is kept, not fitted away).
        "map_nees_origin": (r.get("map_nees_from_origin") or {}).get("mean_per_dof"),
        # ... and each of its axes alone against its own variance (what a
        # controller reading the sigmas sees; 1 when they are right).
        "map_nees_origin_axes": (r.get("map_nees_from_origin") or {}).get("marginal_per_dof"),
        # ... and the frames whose landmarks it did not take while the
        # relative stage settled or its accelerometer bias was unknown,
        # and the bias waits that ran out ([absolute] wait_accel_bias_max_s).
        "held_back_frames": r.get("second_stage_held_back_frames"),
        "bias_waits_given_up": r.get("second_stage_bias_waits_given_up"),
        "scale_error_pct": None if e.get("scale_error") is None else 100 * abs(e["scale_error"]),
        "nees": nees.get("mean_per_dof"),
        "nees_position": nees.get("position_per_dof"),
        "nees_rotation": nees.get("rotation_per_dof"),
        # Each axis alone against its own variance: the mean above can be
        # 1 for a covariance too sure in a few directions and far too
        # cautious in the rest; these cannot.
        "nees_position_axes": nees.get("position_marginal_per_dof"),
        "nees_rotation_axes": nees.get("rotation_marginal_per_dof"),
        # Roll and pitch against the ground truth's, rms (inertial modes).
        "tilt_deg": (r.get("tilt") or {}).get("rms_deg"),
        "lost": r.get("lost_count"),
        "resets": counters.get("resets"),
        # Frames the IMU did not reach (a gap, a camera clock behind it):
        # an inertial run with many of them ran on its cameras.
        "frames_without_imu": counters.get("frames_without_imu"),
        "ms_per_frame": r.get("mean_ms_per_frame"),
        "noise_scale_end": r.get("imu_noise_scale"),
        # The online camera-IMU calibration at the end (refined modes).
        "camera_imu_end": r.get("camera_imu"),
    }


def ratio(a, b):
    return f"{a / b:.2f}x" if a and b else "-"


def fmt(v, spec):
    return "-" if v is None else format(v, spec)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("root", help="the folder render_sets.sh wrote")
    ap.add_argument("--modes", nargs="+", default=["stereo-inertial", "mono-inertial", "stereo"])
    ap.add_argument("--sets", nargs="+", default=["dev", "eval"], choices=list(SETS))
    ap.add_argument("--config")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--match", help="only the sequences whose name holds this text (e.g. flight, rest, V1_01)")
    ap.add_argument("--out")
    ap.add_argument("--bin", default=os.environ.get("RIGSLAM", "target/release/rigslam"))
    a = ap.parse_args()
    seqs = [(s, seq) for s in a.sets for seq in SETS[s] if not a.match or a.match in seq[0]]
    if not seqs:
        sys.exit(f"no sequence of {' '.join(a.sets)} is named with {a.match!r}")
    for _, (_, folder, _, _) in seqs:
        if not os.path.isdir(os.path.join(a.root, folder)):
            sys.exit(f"{os.path.join(a.root, folder)} is missing: render it with bench/accuracy/render_sets.sh")
    jobs = [(s, seq, mode) for s, seq in seqs for mode in a.modes]
    with ThreadPoolExecutor(max_workers=a.jobs) as pool:
        rows = list(pool.map(lambda j: dict(run(a.bin, a.root, j[1], j[2], a.config), set=j[0]), jobs))
    if a.out:
        with open(a.out, "w") as f:
            json.dump(rows, f, indent=1)
    by = {(r["sequence"], r["mode"]): r for r in rows}
    print("| set | sequence | mode | ATE m | scale err % | NEES/dof | tilt deg | lost | vs stereo | vs relative stage | map NIS/dof | map NEES/dof (median) / from origin |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        if "error" in r:
            print(f"| {r['set']} | {r['sequence']} | {r['mode']} | failed: {r['error'][-80:]} |")
            continue
        vision = by.get((r["sequence"], "stereo"))
        versus = "-"
        if r["mode"] != "stereo" and vision and vision.get("ate_m") and r.get("ate_m"):
            versus = f"{r['ate_m'] / vision['ate_m']:.2f}x"
        print(f"| {r['set']} | {r['sequence']} | {r['mode']} | {fmt(r['ate_m'], '.4f')} | "
              f"{fmt(r['scale_error_pct'], '.2f')} | {fmt(r['nees'], '.2f')} | {fmt(r.get('tilt_deg'), '.2f')} | "
              f"{r['lost']} | {versus} | "
              f"{ratio(r.get('ate_m'), r.get('ate_relative_m'))} | {fmt(r.get('absolute_nis'), '.2f')} | "
              f"{fmt(r.get('map_nees'), '.2f')} ({fmt(r.get('map_nees_median'), '.2f')}) / "
              f"{fmt(r.get('map_nees_origin'), '.2f')} |")
    short = [r for r in rows if r.get("frames_without_imu")]
    for r in short:
        print(f"warning: {r['sequence']} {r['mode']}: {r['frames_without_imu']} frames without the IMU")
    print()
    print("| set | mode | mean ATE m (from rest) | mean ATE m (all) | max scale err % | mean NEES/dof | "
          "NEES/dof, each axis alone: position / rotation | map frame from origin, whole / axes | mean tilt deg |")
    print("|---|---|---|---|---|---|---|---|---|")
    for s in a.sets:
        for mode in a.modes:
            rs = [r for r in rows if r["set"] == s and r["mode"] == mode and r.get("ate_m") is not None]
            if not rs:
                continue
            rest = [r["ate_m"] for r in rs if "flight" not in r["sequence"]]
            scale = [r["scale_error_pct"] for r in rs if r["scale_error_pct"] is not None]
            mean = lambda v: sum(v) / len(v) if v else None
            # The mean over the runs that have `key`.
            of = lambda key: mean([r[key] for r in rs if r.get(key) is not None])
            print(f"| {s} | {mode} | {fmt(mean(rest), '.4f')} | {fmt(mean([r['ate_m'] for r in rs]), '.4f')} | "
                  f"{fmt(max(scale) if scale else None, '.2f')} | {fmt(of('nees'), '.2f')} | "
                  f"{fmt(of('nees_position_axes'), '.2f')} / {fmt(of('nees_rotation_axes'), '.3f')} | "
                  f"{fmt(of('map_nees_origin'), '.2f')} / {fmt(of('map_nees_origin_axes'), '.2f')} | "
                  f"{fmt(of('tilt_deg'), '.2f')} |")


if __name__ == "__main__":
    main()
