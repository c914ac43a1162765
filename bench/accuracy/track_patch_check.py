#!/usr/bin/env python3
"""Can a track's gathered error be seen without the scene? Each track's
keyframe observations are checked against the patch of its first frame:
the patch is aligned into the keyframe's image by an affine warp started
at the tracked position (OpenCV's ECC, a measuring peer, not used by the
product), and both the tracked position and the aligned one are scored
against where the track's first surface point projects (as in
`track_truth.py`). If the aligned error does not grow with the track's
age, the difference tracked - aligned is the track's drift, measured
online.

Needs numpy and opencv-python-headless (the peers' virtual
environment). Writes nothing; prints a table.

usage: bench/accuracy/track_patch_check.py DATASET TRACKS_CSV [--window 21]
"""
import argparse, os, sys

import numpy as np

try:
    import cv2
except ImportError:
    sys.exit("needs opencv-python-headless (pip install opencv-python-headless)")

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import track_truth as tt  # noqa: E402
from landmark_truth import groundtruth, load_scene  # noqa: E402

MARGIN_PX = 6
AGES = [(1, 8), (8, 16), (16, 32), (32, 64), (64, None)]


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("dataset")
    p.add_argument("tracks")
    p.add_argument("--window", type=int, default=21, help="side of the first frame's patch, px (odd)")
    args = p.parse_args()
    h = args.window // 2
    room, boxes = load_scene(args.dataset)
    t_gt, p_gt, q_gt = groundtruth(args.dataset)
    T, k, d = tt.camera(args.dataset, 0)
    a = np.loadtxt(args.tracks, delimiter=",", skiprows=1, ndmin=2)
    a = a[a[:, 2] == 0]
    if a.size == 0:
        sys.exit(f"{args.tracks}: no left-camera observations")
    frames = np.unique(a[:, 0].astype(np.int64))
    keyframes = set(np.unique(a[a[:, 5] == 1, 0].astype(np.int64)).tolist())
    names = {}
    for line in open(os.path.join(args.dataset, "mav0", "cam0", "data.csv")):
        if line.strip() and not line.startswith("#"):
            stamp, name = line.strip().split(",")[:2]
            names[int(stamp)] = name.strip()
    stamps = np.array(sorted(names))
    images = {}

    def image(t):
        if t not in images:
            if len(images) > 64:
                images.clear()
            near = int(stamps[np.abs(stamps - t).argmin()])  # a camera clock shift of nanoseconds
            path = os.path.join(args.dataset, "mav0", "cam0", "data", names[near])
            im = cv2.imread(path, cv2.IMREAD_GRAYSCALE)
            if im is None:
                sys.exit(f"{path}: cannot read")
            images[t] = im.astype(np.float32)
        return images[t]

    first = {}
    rows = []  # age, tracked error, aligned error, |tracked - aligned|
    for row in a[np.argsort(a[:, 0], kind="stable")]:
        t, track, uv = int(row[0]), int(row[1]), row[3:5]
        pose = tt.camera_in_world(t_gt, p_gt, q_gt, T, t)
        if pose is None:
            continue
        r_wc, o_wc = pose
        if track not in first:
            x = tt.surface_point(room, boxes, k, d, r_wc, o_wc, uv)
            first[track] = None if x is None else (t, uv.copy(), x)
            continue
        if first[track] is None or t not in keyframes:
            continue
        t0, uv0, x = first[track]
        p_cam = r_wc.T @ (x - o_wc)
        if p_cam[2] <= 0.05:
            continue
        truth = tt.project(k, d, p_cam)
        if np.hypot(*(uv - truth)) > tt.STRAY_PX:
            continue  # a jump the window's gate would remove
        patch = cv2.getRectSubPix(image(t0), (2 * h + 1, 2 * h + 1), (float(uv0[0]), float(uv0[1])))
        side = 2 * (h + MARGIN_PX) + 1
        region = cv2.getRectSubPix(image(t), (side, side), (float(uv[0]), float(uv[1])))
        warp = np.array([[1, 0, MARGIN_PX], [0, 1, MARGIN_PX]], np.float32)
        try:
            _, warp = cv2.findTransformECC(patch, region, warp, cv2.MOTION_AFFINE,
                                           (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-6), None, 1)
        except cv2.error:
            continue  # did not converge: counted out
        aligned = uv + (warp @ np.array([h, h, 1.0]) - (h + MARGIN_PX))
        age = int(np.searchsorted(frames, t) - np.searchsorted(frames, t0))
        rows.append((age, np.hypot(*(uv - truth)), np.hypot(*(aligned - truth)), np.hypot(*(uv - aligned))))
    if not rows:
        sys.exit("no keyframe observation to check")
    r = np.array(rows)
    print(f"{len(r)} keyframe observations checked")
    print("age (frames) | n | median tracked error (px) | median aligned error (px) | median |tracked - aligned| (px)")
    for lo, hi in AGES:
        m = (r[:, 0] >= lo) & ((r[:, 0] < hi) if hi else True)
        if m.sum() >= 10:
            print(f"{lo}-{hi - 1 if hi else 'more'} | {m.sum()} | {np.median(r[m, 1]):.3f} | "
                  f"{np.median(r[m, 2]):.3f} | {np.median(r[m, 3]):.3f}")


if __name__ == "__main__":
    main()
