#!/usr/bin/env python3
"""Feature tracks against the scene of a rendering: how much error a
track gathers as it is followed, and how alike that error is from one
keyframe to the next.

`rigslam simulate` writes `scene.json` beside `mav0/`; the front end's
observations come from `cargo bench -p rigslam --bench tracks -- DATASET
OUT.csv`. Each track's first left observation is cast into the scene
from the true camera pose (the surface point the tracker started on);
every later observation, left or right, is compared with where that
point projects through the true pose (interpolated to the frame's stamp)
and the calibration's camera model
(pinhole, radial-tangential). The difference is what the track has
gathered since its first frame (the first detection's own error is not
seen).

Printed: per camera and age (frames since the track's first), the RMS
and median error and its mean (a bias common to the tracks); then, over
the tracks' keyframe observations (a track that ever strays by more
than 1 px left out, as the window's outlier gate would), the lag-1
autocorrelation of the error less its mean, over whole tracks and over
runs of L keyframes as a window of L sees them, with the factor
`(1 + rho) / (1 - rho)` by which correlated errors give less
information than as many independent ones (AR(1)).

Needs numpy. Writes nothing.

usage: bench/accuracy/track_truth.py DATASET TRACKS_CSV [--runs 4 6 10]
"""
import argparse, os, re, sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from landmark_truth import cast, groundtruth, load_scene, rotation_wxyz  # noqa: E402

AGES = [(0, 1), (1, 2), (2, 4), (4, 8), (8, 16), (16, 32), (32, 64), (64, None)]
STRAY_PX = 1.0


def camera(dataset, i):
    path = os.path.join(dataset, "mav0", f"cam{i}", "sensor.yaml")
    if not os.path.exists(path):
        sys.exit(f"{path}: missing")
    text = open(path).read()

    def numbers(key):
        m = re.search(key + r":\s*\[([^\]]*)\]", text, re.S)
        if not m:
            sys.exit(f"{path}: no {key}")
        return [float(v) for v in m.group(1).split(",")]

    model = re.search(r"distortion_model:\s*(\S+)", text)
    if model and model.group(1) not in ("radial-tangential", "radtan"):
        sys.exit(f"{path}: distortion model {model.group(1)}; only radial-tangential is handled")
    t_bs = re.search(r"T_BS:.*?data:\s*\[([^\]]*)\]", text, re.S)
    if not t_bs:
        sys.exit(f"{path}: no T_BS data")
    T = np.array([float(v) for v in t_bs.group(1).split(",")]).reshape(4, 4)
    return T, numbers("intrinsics"), (numbers("distortion_coefficients") + [0.0] * 4)[:4]


def distort(xn, d):
    k1, k2, p1, p2 = d
    x, y = xn[0], xn[1]
    r2 = x * x + y * y
    radial = 1 + k1 * r2 + k2 * r2 * r2
    return np.array([x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x),
                     y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y])


def project(k, d, p_cam):
    xd = distort(p_cam[:2] / p_cam[2], d)
    return np.array([k[0] * xd[0] + k[2], k[1] * xd[1] + k[3]])


def unproject(k, d, uv):
    xd = np.array([(uv[0] - k[2]) / k[0], (uv[1] - k[3]) / k[1]])
    x = xd.copy()
    for _ in range(50):  # fixed point: the distortion is mild inside the image
        x = x - (distort(x, d) - xd)
    v = np.array([x[0], x[1], 1.0])
    return v / np.linalg.norm(v)


def true_pose(t_gt, p_gt, q_gt, t):
    """The ground truth at `t`, interpolated between its two neighbours
    (position linearly, rotation by normalised quaternion blend: the
    samples are milliseconds apart); None outside it or across a gap of
    more than 50 ms."""
    k = int(np.searchsorted(t_gt, t))
    if k < len(t_gt) and t_gt[k] == t:
        return rotation_wxyz(q_gt[k]), p_gt[k]
    if k == 0 or k == len(t_gt) or t_gt[k] - t_gt[k - 1] > 50_000_000:
        return None
    w = (t - t_gt[k - 1]) / (t_gt[k] - t_gt[k - 1])
    q0, q1 = q_gt[k - 1], q_gt[k]
    q1 = q1 if q0 @ q1 >= 0 else -q1
    return rotation_wxyz((1 - w) * q0 + w * q1), (1 - w) * p_gt[k - 1] + w * p_gt[k]


def camera_in_world(t_gt, p_gt, q_gt, t_bs, t):
    """Camera rotation and centre in the world at `t` (`t_bs` the
    camera's pose in the body); None outside the ground truth."""
    pose = true_pose(t_gt, p_gt, q_gt, t)
    if pose is None:
        return None
    r_wb, p_wb = pose
    return r_wb @ t_bs[:3, :3], p_wb + r_wb @ t_bs[:3, 3]


def surface_point(room, boxes, k, d, r_wc, o_wc, uv):
    """The scene point pixel `uv` sees; None when its ray meets nothing."""
    ray = r_wc @ unproject(k, d, uv)
    depth = cast(room, boxes, o_wc, ray)
    return o_wc + depth * ray if np.isfinite(depth) else None


def errors(dataset, csv):
    room, boxes = load_scene(dataset)
    t_gt, p_gt, q_gt = groundtruth(dataset)
    cams = [camera(dataset, 0), camera(dataset, 1)]
    a = np.loadtxt(csv, delimiter=",", skiprows=1, ndmin=2)
    if a.size == 0:
        sys.exit(f"{csv}: no observations")
    frames = np.unique(a[:, 0].astype(np.int64))
    keyframes = set(np.searchsorted(frames, np.unique(a[a[:, 5] == 1, 0].astype(np.int64))).tolist())
    start = {}
    out = []  # track, age, camera, error u, error v, keyframe
    for row in a[np.argsort(a[:, 0], kind="stable")]:
        t, track, c = int(row[0]), int(row[1]), int(row[2])
        T, k, d = cams[c]
        pose = camera_in_world(t_gt, p_gt, q_gt, T, t)
        if pose is None:
            continue  # outside the ground truth
        r_wc, o_wc = pose
        f = int(np.searchsorted(frames, t))
        if track not in start:
            if c != 0:
                continue
            x = surface_point(room, boxes, k, d, r_wc, o_wc, row[3:5])
            start[track] = None if x is None else (x, f)
            continue
        if start[track] is None:
            continue
        x, f0 = start[track]
        p_cam = r_wc.T @ (x - o_wc)
        if p_cam[2] <= 0.05:
            continue
        e = row[3:5] - project(k, d, p_cam)
        out.append((track, f - f0, c, e[0], e[1], f in keyframes))
    if not out:
        sys.exit("no observation after a track's first at a ground-truth stamp")
    return len(start), np.array(out, dtype=float)


def lag_one(series, run):
    num = den = 0.0
    for e in series:
        for s in range(0, len(e), run):
            d = e[s:s + run]
            if len(d) < 3:
                continue
            d = d - d.mean(0)
            num += (d[1:] * d[:-1]).sum()
            den += (d * d).sum()
    return num / den if den > 0 else float("nan")


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("dataset")
    p.add_argument("tracks")
    p.add_argument("--runs", type=int, nargs="*", default=[4, 6, 10],
                   help="keyframes per run for the windowed autocorrelation")
    args = p.parse_args()
    n_tracks, r = errors(args.dataset, args.tracks)
    print(f"{n_tracks} tracks, {len(r)} later observations")
    print("camera | age (frames) | n | rms error (px) | median |error| (px) | mean error u, v (px)")
    for c in (0, 1):
        for lo, hi in AGES:
            m = (r[:, 2] == c) & (r[:, 1] >= lo) & ((r[:, 1] < hi) if hi else True)
            if m.sum() < 10:
                continue
            e = np.hypot(r[m, 3], r[m, 4])
            print(f"{c} | {lo}-{hi - 1 if hi else 'more'} | {m.sum()} | {np.sqrt((e ** 2).mean()):.3f} | "
                  f"{np.median(e):.3f} | {r[m, 3].mean():+.3f}, {r[m, 4].mean():+.3f}")
    series = []
    for track in np.unique(r[:, 0]):
        m = (r[:, 0] == track) & (r[:, 2] == 0) & (r[:, 5] == 1)
        e = r[m][np.argsort(r[m, 1])][:, 3:5]
        if len(e) >= 3 and np.abs(e).max() <= STRAY_PX:
            series.append(e)
    if not series:
        sys.exit("no track seen on three keyframes")
    print(f"{len(series)} tracks on at least three keyframes (mean {np.mean([len(e) for e in series]):.1f})")
    print("keyframes per run | lag-1 autocorrelation | (1 + rho) / (1 - rho)")
    for run in sorted(args.runs) + [10 ** 9]:
        rho = lag_one(series, run)
        print(f"{run if run < 10 ** 9 else 'whole track'} | {rho:.2f} | {(1 + rho) / (1 - rho):.2f}")


if __name__ == "__main__":
    main()
