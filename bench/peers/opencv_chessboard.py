"""OpenCV peer of `rigslam-calibrate camera`: OpenCV's chessboard
corners and calibrateCamera on the 13 real 9x6 images of
../shared/data/calib/chessboard_9x6_25mm, written as one JSON fixture.

Corners as OpenCV's calibration sample finds them: findChessboardCorners
(ADAPTIVE_THRESH | NORMALIZE_IMAGE | FAST_CHECK), then cornerSubPix with
winSize (11, 11) -- a half width, so a 23x23 px window -- no dead zone,
30 iterations / 1e-4 px. The same start points are also refined with
winSize (5, 5) (an 11x11 window, the size of rigslam's), and the window
sweep records calibrateCamera (flags 0, all views) for winSize 3..11. calibrateCamera with
the five coefficients k1 k2 p1 p2 k3 under:
  - "default":   flags 0 (fx, fy free, k3 free)
  - "fix_aspect": CALIB_FIX_ASPECT_RATIO with fx/fy = 1, the flags recorded in
                  the reference left_intrinsics.yml ("flags: 2", "aspectRatio: 1")
  - "fix_aspect_fix_k3": CALIB_FIX_ASPECT_RATIO | CALIB_FIX_K3 (k3 = 0)
  - "fix_k3":    CALIB_FIX_K3
RMS is OpenCV's return value (sqrt of the mean squared 2-D residual norm),
per-view errors the same per view.

Usage: python opencv_chessboard.py IMAGE_DIR OUT.json
"""

import glob
import json
import os
import platform
import sys

import cv2
import numpy as np

COLS, ROWS, SQUARE = 9, 6, 0.025
CRITERIA = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 30, 1e-4)


def refine(grey, start, half_window):
    return cv2.cornerSubPix(grey, start.copy(), (half_window, half_window), (-1, -1), CRITERIA)


def calibrate(board, points, size, flags):
    return cv2.calibrateCamera([board] * len(points), points, size, np.eye(3), None, flags=flags)


def main():
    image_dir, out = sys.argv[1], sys.argv[2]
    files = sorted(glob.glob(os.path.join(image_dir, "*.jpg")))
    board = np.zeros((ROWS * COLS, 3), np.float32)
    board[:, :2] = np.mgrid[0:COLS, 0:ROWS].T.reshape(-1, 2) * SQUARE
    names, raw_points, images = [], [], []
    size = None
    for f in files:
        grey = cv2.imread(f, cv2.IMREAD_GRAYSCALE)
        size = grey.shape[::-1]
        found, corners = cv2.findChessboardCorners(
            grey,
            (COLS, ROWS),
            cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_FAST_CHECK,
        )
        if not found:
            print(f"board not found in {f}", file=sys.stderr)
            continue
        names.append(os.path.basename(f))
        raw_points.append(corners.reshape(-1, 1, 2).copy())
        images.append(grey)
    image_points = [refine(g, r, 11) for g, r in zip(images, raw_points)]

    runs = {
        "default": 0,
        "fix_aspect": cv2.CALIB_FIX_ASPECT_RATIO,
        "fix_aspect_fix_k3": cv2.CALIB_FIX_ASPECT_RATIO | cv2.CALIB_FIX_K3,
        "fix_k3": cv2.CALIB_FIX_K3,
    }
    results = {}
    for name, flags in runs.items():
        rms, k, dist, rvecs, tvecs = calibrate(board, image_points, size, flags)
        per_view = []
        for pts, rv, tv in zip(image_points, rvecs, tvecs):
            proj, _ = cv2.projectPoints(board, rv, tv, k, dist)
            d = proj.reshape(-1, 2) - pts.reshape(-1, 2)
            per_view.append(float(np.sqrt((d**2).sum(axis=1).mean())))
        results[name] = {
            "flags": int(flags),
            "rms_px": float(rms),
            "fx": float(k[0, 0]),
            "fy": float(k[1, 1]),
            "cx": float(k[0, 2]),
            "cy": float(k[1, 2]),
            "k1_k2_p1_p2_k3": [float(v) for v in dist.ravel()[:5]],
            "per_view_rms_px": per_view,
        }
    sweep = {}
    for half_window in range(3, 12):
        points = [refine(g, r, half_window) for g, r in zip(images, raw_points)]
        rms, k, dist, _, _ = calibrate(board, points, size, 0)
        sweep[str(half_window)] = {
            "rms_px": float(rms),
            "fx": float(k[0, 0]),
            "fy": float(k[1, 1]),
            "cx": float(k[0, 2]),
            "cy": float(k[1, 2]),
        }
    win5 = [refine(g, r, 5) for g, r in zip(images, raw_points)]
    json.dump(
        {
            "provenance": {
                "opencv": cv2.__version__,
                "numpy": np.__version__,
                "python": platform.python_version(),
                "script": "bench/peers/opencv_chessboard.py",
                "images": "../shared/data/calib/chessboard_9x6_25mm/*.jpg",
                "board": f"{COLS}x{ROWS} inner corners, {SQUARE} m squares",
                "corner_refinement": "cornerSubPix winSize (11, 11) = 23x23 px, zeroZone -1, 30 it / 1e-4",
            },
            "image_size": list(size),
            "images": names,
            "corners_px": [p.reshape(-1, 2).tolist() for p in image_points],
            "corners_before_subpix_px": [p.reshape(-1, 2).tolist() for p in raw_points],
            "corners_win5_px": [p.reshape(-1, 2).tolist() for p in win5],
            "calibrations": results,
            "window_sweep_flags0": sweep,
        },
        open(out, "w"),
        indent=1,
    )


if __name__ == "__main__":
    main()
