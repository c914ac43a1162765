#!/usr/bin/env python3
"""ATE of the inertial modes against a multiplier on the declared IMU noise.

For each rendering and each multiplier m, runs `rigslam run` with
`imu_noise_scale_gyro = imu_noise_scale_accel = m` (the same as writing m
times the noise into sensor.yaml) twice: with the online noise adaptation
off (the estimator weighs the IMU by exactly what it was told) and on
(it starts from what it was told). Prints a table per mode and writes the
rows as JSON.

By default only the relative stage runs. With `--stages both` the
absolute stage runs too, as the daemon runs it: `ate_m` is then the
published (map-frame) trajectory's and `ate_relative_m` the relative
stage's of the same run, and a table is printed for each.

usage: bench/accuracy/noise_sensitivity.py --out rows.json DATASET...
       [--modes stereo-inertial mono-inertial] [--multipliers 0.5 1 2 5 10 20]
       [--start-s S --max-frames N] [--adaptation both|on|off] [--bin B] [--config C.toml]
       [--stages relative|both]
"""
import argparse, json, os, subprocess, sys, tempfile

def run(binary, dataset, mode, config, start_s, max_frames):
    with tempfile.TemporaryDirectory() as d:
        cfg = os.path.join(d, "config.toml")
        with open(cfg, "w") as f:
            f.write(config)
        report = os.path.join(d, "report.json")
        cmd = [binary, "run", "--dataset", dataset, "--mode", mode, "--config", cfg,
               "--report", report, "--quiet"]
        if start_s:
            cmd += ["--start-s", str(start_s)]
        if max_frames:
            cmd += ["--max-frames", str(max_frames)]
        p = subprocess.run(cmd, capture_output=True, text=True)
        if p.returncode != 0:
            return {"error": p.stderr.strip()[-400:]}
        with open(report) as f:
            r = json.load(f)
        e = r.get("eval") or {}
        return {
            "ate_m": e.get("ate_rmse_m"),
            # With both stages: the relative stage's poses of the same run.
            "ate_relative_m": (r.get("eval_relative") or {}).get("ate_rmse_m"),
            "scale_error": e.get("scale_error"),
            "final_drift_pct": e.get("final_drift_pct"),
            "lost": r.get("lost_count"),
            "resets": (r.get("counters") or {}).get("resets"),
            "ms_per_frame": r.get("mean_ms_per_frame"),
            "noise_scale_end": r.get("imu_noise_scale"),
        }

def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("datasets", nargs="+")
    ap.add_argument("--out", required=True)
    ap.add_argument("--modes", nargs="+", default=["stereo-inertial", "mono-inertial"])
    ap.add_argument("--multipliers", nargs="+", type=float, default=[0.5, 1, 2, 5, 10, 20])
    ap.add_argument("--start-s", type=float, default=0.0)
    ap.add_argument("--max-frames", type=int)
    ap.add_argument("--bin", default=os.environ.get("RIGSLAM", "target/release/rigslam"))
    ap.add_argument("--adaptation", choices=["both", "on", "off"], default="both",
                    help="the runs to make: weighed as declared (off), adapted (on), or both")
    ap.add_argument("--config", help="more [relative] settings (TOML lines after the table header)")
    ap.add_argument("--stages", choices=["relative", "both"], default="relative",
                    help="the relative stage alone, or both stages as the daemon runs them "
                         "(ate_m the published poses', ate_relative_m the relative stage's)")
    a = ap.parse_args()
    adapts = {"both": (False, True), "on": (True,), "off": (False,)}[a.adaptation]
    extra = ""
    if a.config:
        with open(a.config) as f:
            extra = "".join(l for l in f if l.strip() != "[relative]")
    rows = []
    for mode in a.modes:
        for adapt in adapts:
            for m in a.multipliers:
                config = ("[relative]\n" + extra +
                          f"imu_noise_adaptation = {'true' if adapt else 'false'}\n"
                          f"imu_noise_scale_gyro = {m}\nimu_noise_scale_accel = {m}\n")
                if a.stages == "both":
                    config += "[absolute]\nenabled = true\n"
                for ds in a.datasets:
                    r = run(a.bin, ds, mode, config, a.start_s, a.max_frames)
                    row = {"dataset": os.path.basename(ds.rstrip("/")), "mode": mode,
                           "adaptation": adapt, "multiplier": m, "stages": a.stages, **r}
                    rows.append(row)
                    print(json.dumps(row), flush=True)
    with open(a.out, "w") as f:
        json.dump(rows, f, indent=1)
    # Tables: mean ATE over the datasets per (mode, adaptation, multiplier).
    keys = [("ate_m", "published poses (both stages)"), ("ate_relative_m", "relative stage")] \
        if a.stages == "both" else [("ate_m", "relative stage")]
    for key, title in keys:
        print(f"\n{title}\n{'mode':16s} {'adaptation':10s} " + " ".join(f"{m:>7g}x" for m in a.multipliers))
        for mode in a.modes:
            for adapt in adapts:
                cells = []
                for m in a.multipliers:
                    sel = [r for r in rows if r["mode"] == mode and r["adaptation"] == adapt
                           and r["multiplier"] == m]
                    v = [r[key] for r in sel if r.get(key) is not None]
                    cells.append(f"{sum(v)/len(v):8.4f}" if len(v) == len(sel) and v else "  failed")
                print(f"{mode:16s} {'on' if adapt else 'off':10s} " + " ".join(cells))

if __name__ == "__main__":
    main()
