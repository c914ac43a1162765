#!/usr/bin/env python3
"""Position error lap by lap of a looped replay (`[replay] loops`, the
daemon bench's `--minutes`), in the map frame and the odometry frame.

The replay plays one rendering again and again, each loop's stamps
continuing 50 ms after the previous loop's last; the ground truth of
loop k is the rendering's, shifted by k spans. Both trajectories (the
daemon bench's `--tum-dir`: pose.tum, pose_odom.tum) are aligned to it
with one rigid transform each over the whole run (no scale), then the
RMS error is given per lap.

  python3 bench/soak/lap_ate.py DATASET TUM_DIR [--every N]
"""
import argparse

import numpy as np


def stamps(path, column=0):
    rows = [l.split(",") for l in open(path) if l[:1].isdigit()]
    return np.array([float(r[column]) for r in rows])


def ground_truth(dataset):
    rows = [l.split(",") for l in open(f"{dataset}/mav0/state_groundtruth_estimate0/data.csv") if l[:1].isdigit()]
    return np.array([[float(x) for x in r[:4]] for r in rows])


def rigid_fit(a, b):
    """a moved onto b by the rotation and translation that fit best."""
    ma, mb = a.mean(0), b.mean(0)
    u, _, vt = np.linalg.svd((a - ma).T @ (b - mb))
    d = np.eye(3)
    d[2, 2] = np.sign(np.linalg.det(vt.T @ u.T))
    r = vt.T @ d @ u.T
    return (r @ (a - ma).T).T + mb


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("dataset")
    p.add_argument("tum_dir")
    p.add_argument("--every", type=int, default=1, help="print every N-th lap [1]")
    args = p.parse_args()
    gt = ground_truth(args.dataset)
    imu = stamps(f"{args.dataset}/mav0/imu0/data.csv")
    cam = stamps(f"{args.dataset}/mav0/cam0/data.csv")
    first = min(imu.min(), cam.min())
    span = max(imu.max(), cam.max()) - first + 50e6
    errors = {}
    for name in ("pose", "pose_odom"):
        est = np.loadtxt(f"{args.tum_dir}/{name}.tum", ndmin=2)
        t = est[:, 0] * 1e9
        lap = np.floor((t - first + 1e3) / span)
        t_in_lap = t - lap * span
        truth = np.stack([np.interp(t_in_lap, gt[:, 0], gt[:, i]) for i in (1, 2, 3)], 1)
        err = np.linalg.norm(rigid_fit(est[:, 1:4], truth) - truth, axis=1)
        errors[name] = (lap, err)
        print(f"{name}: ATE over {len(err)} poses, {int(lap.max()) + 1} laps: {np.sqrt((err ** 2).mean()):.4f} m")
    print("| lap | map frame m | odometry frame m |")
    print("|---|---|---|")
    laps = np.unique(errors["pose"][0])
    for lap in laps:
        if int(lap) % args.every and lap != laps[-1]:
            continue
        rms = [np.sqrt((e[k == lap] ** 2).mean()) for k, e in (errors["pose"], errors["pose_odom"])]
        print(f"| {int(lap) + 1} | {rms[0]:.4f} | {rms[1]:.4f} |")


if __name__ == "__main__":
    main()
