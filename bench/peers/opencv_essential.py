"""OpenCV peer of `rigslam bench essential`: findEssentialMat (RANSAC) +
recoverPose on the same matches, single-threaded, with the same rotation
error against the same ground truth. Prints one JSON object with the keys
of `rigslam bench essential --json`.

Usage: python opencv_essential.py --matches FILE [--gt FILE] [--threshold-px 1.0] [--repeats 5]
"""

import argparse
import json
import math
import time

import cv2
import numpy as np


def read_matches(path):
    k = None
    pairs = []
    with open(path) as f:
        for line in f:
            line = line.strip()
            if not line:
                continue
            if line.startswith("#"):
                if line[1:].strip().startswith("K fx fy cx cy:"):
                    k = [float(v) for v in line.split(":", 1)[1].split()]
                continue
            v = line.split()
            n = int(v[1])
            q = np.array(v[2:], dtype=np.float64).reshape(n, 4)
            pairs.append((int(v[0]), q[:, :2].copy(), q[:, 2:].copy()))
    return k, pairs


def read_gt(path):
    gt = {}
    with open(path) as f:
        for line in f:
            if line.startswith("#") or not line.strip():
                continue
            v = line.split()
            gt[int(v[0])] = np.array(v[1:10], dtype=np.float64).reshape(3, 3)
    return gt


def rotation_error_deg(a, b):
    d = a.T @ b
    s = 0.5 * np.linalg.norm([d[2, 1] - d[1, 2], d[0, 2] - d[2, 0], d[1, 0] - d[0, 1]])
    c = 0.5 * (np.trace(d) - 1.0)
    return math.degrees(math.atan2(s, c))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--matches", required=True)
    ap.add_argument("--gt")
    ap.add_argument("--threshold-px", type=float, default=1.0)
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()
    cv2.setNumThreads(1)
    (fx, fy, cx, cy), pairs = read_matches(args.matches)
    K = np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1]], dtype=np.float64)
    gt = read_gt(args.gt) if args.gt else None
    errors = []
    elapsed = 0.0
    inliers = 0
    for k, p1, p2 in pairs:
        t0 = time.perf_counter()
        for _ in range(args.repeats):
            E, mask = cv2.findEssentialMat(p1, p2, K, method=cv2.RANSAC, prob=0.999, threshold=args.threshold_px)
            # findEssentialMat may stack several solutions; recoverPose takes the first 3x3.
            n_in, R, t, mask_pose = cv2.recoverPose(E[:3], p1, p2, K, mask=mask.copy())
        elapsed += time.perf_counter() - t0
        inliers += int(mask.sum())
        if gt is not None and k in gt:
            errors.append(rotation_error_deg(gt[k], R))
    out = {
        "pairs": len(pairs),
        "ms_per_pair": 1e3 * elapsed / (len(pairs) * args.repeats),
        "inliers_mean": inliers / len(pairs),
        "threshold_px": args.threshold_px,
        "opencv": cv2.__version__,
    }
    if errors:
        out["rot_err_median_deg"] = float(np.quantile(errors, 0.5))
        out["rot_err_p90_deg"] = float(np.quantile(errors, 0.9))
    print(json.dumps(out))


if __name__ == "__main__":
    main()
