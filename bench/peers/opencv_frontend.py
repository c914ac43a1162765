"""OpenCV peer for `rigslam bench frontend` (run it through opencv_frontend.sh).

Same frames, same protocol as the Rust side, one thread:
  KLT: for every consecutive pair (k-1, k), goodFeaturesToTrack on frame k-1
       (200 corners, quality 0.01, min distance 10 px), calcOpticalFlowPyrLK
       forward k-1 -> k and backward k -> k-1 (21x21 window, maxLevel=2, i.e.
       3 pyramid levels); a track survives when both directions report status 1
       and the backward point lands within 1.0 px of where it started.
  ORB: ORB_create(1000).detectAndCompute on every frame.
Image decoding is outside the timed regions. Prints the same keys as
`rigslam bench frontend --json` (plus the OpenCV version).
"""

import argparse
import json
import pathlib
import sys
import time

import cv2
import numpy as np

FB_THRESHOLD_PX = 1.0


def frame_paths(folder: pathlib.Path):
    """A folder of PNGs, or a EuRoC camN folder holding data/."""
    if (folder / "data").is_dir():
        folder = folder / "data"
    paths = sorted(p for p in folder.iterdir() if p.suffix.lower() == ".png")
    if len(paths) < 2:
        sys.exit(f"{folder}: need at least 2 PNG frames, found {len(paths)}")
    return paths


def main():
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--images", required=True, type=pathlib.Path)
    parser.add_argument("--json", action="store_true")
    parser.add_argument("--repeat", type=int, default=1, help="passes over the frames; the fastest counts")
    # Wall and thread CPU time are both reported; on a busy shared machine
    # the CPU time is the steadier one.
    args = parser.parse_args()

    cv2.setNumThreads(1)
    frames = [cv2.imread(str(p), cv2.IMREAD_GRAYSCALE) for p in frame_paths(args.images)]
    lk = dict(winSize=(21, 21), maxLevel=2,
              criteria=(cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 30, 0.01))

    best_klt_s, best_klt_cpu_s, tracks = float("inf"), float("inf"), []
    for _ in range(args.repeat):
        tracks = []
        t0, c0 = time.perf_counter(), time.thread_time()
        for prev, cur in zip(frames[:-1], frames[1:]):
            p0 = cv2.goodFeaturesToTrack(prev, 200, 0.01, 10)
            if p0 is None:
                tracks.append(0)
                continue
            p1, st1, _ = cv2.calcOpticalFlowPyrLK(prev, cur, p0, None, **lk)
            p0b, st2, _ = cv2.calcOpticalFlowPyrLK(cur, prev, p1, None, **lk)
            fb = np.linalg.norm((p0b - p0).reshape(-1, 2), axis=1)
            ok = (st1.ravel() == 1) & (st2.ravel() == 1) & (fb < FB_THRESHOLD_PX)
            tracks.append(int(ok.sum()))
        best_klt_s = min(best_klt_s, time.perf_counter() - t0)
        best_klt_cpu_s = min(best_klt_cpu_s, time.thread_time() - c0)

    orb = cv2.ORB_create(1000)
    best_orb_s, best_orb_cpu_s, features = float("inf"), float("inf"), []
    for _ in range(args.repeat):
        features = []
        t0, c0 = time.perf_counter(), time.thread_time()
        for img in frames:
            kps, _ = orb.detectAndCompute(img, None)
            features.append(len(kps))
        best_orb_s = min(best_orb_s, time.perf_counter() - t0)
        best_orb_cpu_s = min(best_orb_cpu_s, time.thread_time() - c0)

    report = {
        "frames": len(frames),
        "klt_ms_per_frame": 1e3 * best_klt_s / (len(frames) - 1),
        "klt_tracks_mean": float(np.mean(tracks)),
        "orb_ms_per_frame": 1e3 * best_orb_s / len(frames),
        "orb_features_mean": float(np.mean(features)),
        "klt_cpu_ms_per_frame": 1e3 * best_klt_cpu_s / (len(frames) - 1),
        "orb_cpu_ms_per_frame": 1e3 * best_orb_cpu_s / len(frames),
        "opencv_version": cv2.__version__,
    }
    if args.json:
        print(json.dumps(report))
    else:
        print(f"OpenCV {cv2.__version__}, {report['frames']} frames")
        print(f"KLT detect+track: {report['klt_ms_per_frame']:.2f} ms/frame "
              f"({report['klt_cpu_ms_per_frame']:.2f} ms CPU), "
              f"{report['klt_tracks_mean']:.1f} tracks survive")
        print(f"ORB(1000):        {report['orb_ms_per_frame']:.2f} ms/frame "
              f"({report['orb_cpu_ms_per_frame']:.2f} ms CPU), "
              f"{report['orb_features_mean']:.1f} features")


if __name__ == "__main__":
    main()
