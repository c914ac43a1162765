#!/usr/bin/env python3
"""Landmarks against the surfaces they lie on, on a rendering.

`rigslam simulate` writes `scene.json` beside `mav0/`: the room and the
boxes, in the ground truth's frame. Every landmark the front end tracks
is a texture corner on one of those surfaces, so the scene is each
landmark's truth:

  window DATASET LANDMARKS_CSV
      The relative stage's landmarks (`rigslam run --landmarks`, each in
      its frame's body frame, with covariance): placed with the frame's
      true pose, the ray from the true camera 0 centre through the
      landmark is cast into the scene; the signed depth error is the
      estimate's distance along that ray minus the surface's. Reported
      per class of the landmark's largest sigma and per 20 s: the median
      signed error (m and % of depth), and the error over the covariance's
      sigma along the ray (1 when the covariance is honest).

  map DATASET MAP TRAJECTORY
      A saved map's landmarks (`rigslam run --absolute --save-map`):
      brought into the ground truth's frame by the transform that aligns
      the same session's map-frame trajectory (`--trajectory`, TUM) with
      the ground truth (se3, and with --sim3 also the scale), each one's
      distance to the nearest surface, per class of its largest sigma.
      A distance is a lower bound on the landmark's error (the part along
      the surface is not seen).

Needs numpy. Writes nothing; prints a table.

usage: bench/accuracy/landmark_truth.py window DATASET LANDMARKS_CSV [--every 10]
       bench/accuracy/landmark_truth.py map DATASET MAP TRAJECTORY [--sim3]
"""
import argparse, json, os, re, sys

import numpy as np

SIGMA_CLASSES_M = [(0.0, 0.005), (0.005, 0.01), (0.01, 0.03), (0.03, 0.1), (0.1, np.inf)]


def load_scene(dataset):
    path = os.path.join(dataset, "scene.json")
    if not os.path.exists(path):
        sys.exit(f"{path}: missing (render the dataset again with this version of `rigslam simulate`)")
    with open(path) as f:
        s = json.load(f)
    box = lambda b: (np.array(b["min_m"], float), np.array(b["max_m"], float))
    return box(s["room"]), [box(b) for b in s["boxes"]]


def cam0_T_body_cam(dataset):
    path = os.path.join(dataset, "mav0", "cam0", "sensor.yaml")
    text = open(path).read()
    m = re.search(r"T_BS:.*?data:\s*\[([^\]]*)\]", text, re.S)
    if not m:
        sys.exit(f"{path}: no T_BS data")
    return np.array([float(v) for v in m.group(1).split(",")]).reshape(4, 4)


def groundtruth(dataset):
    path = os.path.join(dataset, "mav0", "state_groundtruth_estimate0", "data.csv")
    a = np.loadtxt(path, delimiter=",", comments="#")
    return a[:, 0].astype(np.int64), a[:, 1:4], a[:, 4:8]  # t_ns, p, q (w x y z)


def rotation_wxyz(q):
    w, x, y, z = q / np.linalg.norm(q)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def cast(room, boxes, origin, direction):
    """Distance along the unit `direction` from `origin` (inside the room)
    to the first surface."""
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / direction
        t1, t2 = (room[0] - origin) * inv, (room[1] - origin) * inv
        best = np.nanmin(np.maximum(t1, t2))
        for lo, hi in boxes:
            t1, t2 = (lo - origin) * inv, (hi - origin) * inv
            near, far = np.nanmax(np.minimum(t1, t2)), np.nanmin(np.maximum(t1, t2))
            if 0 < near <= far and near < best:
                best = near
    return best


def distance_to_surface(room, boxes, p):
    d = abs(min((p - room[0]).min(), (room[1] - p).min()))
    for lo, hi in boxes:
        outside = np.linalg.norm(np.maximum(np.maximum(lo - p, p - hi), 0.0))
        d = min(d, outside if outside > 0 else min((p - lo).min(), (hi - p).min()))
    return d


def covariance(c):
    return np.array([[c[0], c[1], c[2]], [c[1], c[3], c[4]], [c[2], c[4], c[5]]])


def largest_sigma(c):
    return float(np.sqrt(max(np.linalg.eigvalsh(c).max(), 0.0)))


def window(args):
    room, boxes = load_scene(args.dataset)
    T_bc = cam0_T_body_cam(args.dataset)
    t_gt, p_gt, q_gt = groundtruth(args.dataset)
    rows = np.loadtxt(args.landmarks, delimiter=",", skiprows=1, ndmin=2)
    if rows.size == 0:
        sys.exit(f"{args.landmarks}: no landmarks")
    stamps = rows[:, 0].astype(np.int64)
    frames = np.unique(stamps)[:: args.every]
    out = []  # t_s, depth, surface depth, sigma along the ray, largest sigma
    for t in frames:
        k = np.searchsorted(t_gt, t)
        if k >= len(t_gt) or t_gt[k] != t:
            continue  # no ground-truth pose at this stamp
        r_wb = rotation_wxyz(q_gt[k])
        centre_b = T_bc[:3, 3]
        centre_w = p_gt[k] + r_wb @ centre_b
        for r in rows[stamps == t]:
            ray_b = r[2:5] - centre_b
            depth = np.linalg.norm(ray_b)
            if not np.isfinite(depth) or depth <= 0:
                continue
            u = ray_b / depth
            c = covariance(r[5:11])
            surface = cast(room, boxes, centre_w, r_wb @ u)
            out.append((t * 1e-9, depth, surface, np.sqrt(max(u @ c @ u, 0.0)), largest_sigma(c)))
    if not out:
        sys.exit("no landmark at a ground-truth stamp")
    a = np.array(out)
    err = a[:, 1] - a[:, 2]
    rel = err / a[:, 2]
    print(f"{len(a)} landmark estimates in {len(frames)} frames")
    print("largest sigma (m) | n | median depth error (mm) | median |error| (mm) | median depth error (%) | median sigma along the ray (mm) | median |error| / sigma")
    for lo, hi in SIGMA_CLASSES_M:
        m = (a[:, 4] >= lo) & (a[:, 4] < hi)
        if m.any():
            print(f"{lo:g}-{hi:g} | {m.sum()} | {np.median(err[m]) * 1e3:.1f} | {np.median(abs(err[m])) * 1e3:.1f} | "
                  f"{np.median(rel[m]) * 100:.2f} | {np.median(a[m, 3]) * 1e3:.1f} | {np.median(abs(err[m]) / a[m, 3]):.2f}")
    print("from (s) | n (largest sigma under 3 cm) | median depth error (%) | median |error| / sigma")
    t0 = a[0, 0]
    for b in np.arange(0.0, a[-1, 0] - t0 + 1e-9, 20.0):
        m = (a[:, 0] - t0 >= b) & (a[:, 0] - t0 < b + 20.0) & (a[:, 4] < 0.03)
        if m.any():
            print(f"{b:.0f} | {m.sum()} | {np.median(rel[m]) * 100:.2f} | {np.median(abs(err[m]) / a[m, 3]):.2f}")


def umeyama(x, y, with_scale):
    mx, my = x.mean(0), y.mean(0)
    xc, yc = x - mx, y - my
    u, d, vt = np.linalg.svd(yc.T @ xc / len(x))
    e = np.eye(3)
    if np.linalg.det(u) * np.linalg.det(vt) < 0:
        e[2, 2] = -1
    r = u @ e @ vt
    s = (d * np.diag(e)).sum() / ((xc ** 2).sum() / len(x)) if with_scale else 1.0
    return r, my - s * r @ mx, s


def map_check(args):
    room, boxes = load_scene(args.dataset)
    t_gt, p_gt, _ = groundtruth(args.dataset)
    est = np.loadtxt(args.trajectory, ndmin=2)
    t_est = np.round(est[:, 0] * 1e9).astype(np.int64)
    k = np.searchsorted(t_gt, t_est).clip(1, len(t_gt) - 1)
    k = np.where(abs(t_gt[k - 1] - t_est) < abs(t_gt[k] - t_est), k - 1, k)
    ok = abs(t_gt[k] - t_est) < 10_000_000
    if ok.sum() < 3:
        sys.exit(f"{args.trajectory}: fewer than three poses match the ground truth's stamps")
    r, t, s = umeyama(est[ok, 1:4], p_gt[k[ok]], args.sim3)
    landmarks = []
    for line in open(args.map):
        if line.startswith("#") or not line.strip():
            continue
        f = line.split()
        x = np.array([float(v) for v in f[1:4]])
        c = covariance([float(v) for v in f[4:10]])
        if np.all(np.isfinite(x)) and np.all(np.isfinite(c)):
            landmarks.append((s * r @ x + t, largest_sigma(c)))
    if not landmarks:
        sys.exit(f"{args.map}: no landmark")
    d = np.array([distance_to_surface(room, boxes, p) for p, _ in landmarks])
    sig = np.array([g for _, g in landmarks])
    print(f"{len(landmarks)} map landmarks; aligned {'sim3' if args.sim3 else 'se3'} on {ok.sum()} poses, truth per map length {s:.4f}")
    print("largest sigma (m) | n | median distance to a surface (mm) | p90 (mm) | median largest sigma (mm) | share farther than 3 sigma")
    for lo, hi in SIGMA_CLASSES_M:
        m = (sig >= lo) & (sig < hi)
        if m.any():
            print(f"{lo:g}-{hi:g} | {m.sum()} | {np.median(d[m]) * 1e3:.1f} | {np.percentile(d[m], 90) * 1e3:.1f} | "
                  f"{np.median(sig[m]) * 1e3:.1f} | {(d[m] > 3 * sig[m]).mean():.2f}")


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="command", required=True)
    w = sub.add_parser("window", help="the relative stage's landmark depths against the scene")
    w.add_argument("dataset")
    w.add_argument("landmarks")
    w.add_argument("--every", type=int, default=10, help="every Nth frame (default 10)")
    m = sub.add_parser("map", help="a saved map's landmarks against the scene")
    m.add_argument("dataset")
    m.add_argument("map")
    m.add_argument("trajectory")
    m.add_argument("--sim3", action="store_true", help="align with a scale as well")
    args = p.parse_args()
    if args.command == "window":
        if args.every < 1:
            sys.exit("--every must be at least 1")
        window(args)
    else:
        map_check(args)


if __name__ == "__main__":
    main()
