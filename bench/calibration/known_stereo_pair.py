#!/usr/bin/env python3
"""The EuRoC AprilGrid recording again, with a stereo pair known exactly.

`rigslam-calibrate camera-imu` on the real recording puts camera 1 some
0.02 deg from EuRoC's published pair. This writes a copy of the
recording whose corners are rendered from the recording's own geometry:
each instant's target pose in camera 0 (OpenCV's PnP of the real camera-0
corners, EuRoC's intrinsics), the same corners seen in each camera as in
the real detections, projected through EuRoC's intrinsics and a chosen
stereo pair (default: the published one, `--yaw-deg` turns camera 1 about
its y axis on top), with Gaussian pixel noise; the real IMU log and
sequence.yaml are kept. Then it runs the whole `camera-imu` step on the
copy and prints how far its stereo pair lands from the one rendered.

usage: bench/calibration/known_stereo_pair.sh [--noise-px 0.5] [--yaw-deg 0]
       (the .sh installs OpenCV in .venv-opencv and calls this)
"""
import argparse, json, os, shutil, subprocess, sys, tempfile

import cv2
import numpy as np
import yaml


def read_t_bs(path):
    with open(path) as f:
        text = f.read().replace("%YAML:1.0", "")
    return np.array(yaml.safe_load(text)["T_BS"]["data"], dtype=float).reshape(4, 4)


def camera(seq, name):
    c = seq[name]
    fx, fy, cx, cy = c["intrinsics"]
    k = np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1.0]])
    return k, np.array(c["distortion_coeffs"], dtype=float)


def rot_y(deg):
    a = np.radians(deg)
    return np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])


def read_corners(path):
    rows = []
    with open(path) as f:
        header = f.readline()
        for line in f:
            if line.strip():
                rows.append(line.strip().split(","))
    return header, rows


def angle_deg(r):
    return np.degrees(np.arccos(np.clip((np.trace(r) - 1) / 2, -1, 1)))


def yaw_deg(r):
    """Turn about camera 1's y axis (the one that shifts every disparity)."""
    w = cv2.Rodrigues(r)[0].ravel()
    return np.degrees(w[1])


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", default=None, help="shared data folder (default ../shared/data)")
    ap.add_argument("--bin", default="target/release/rigslam-calibrate")
    ap.add_argument("--noise-px", type=float, default=0.5)
    ap.add_argument("--yaw-deg", type=float, default=0.0)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--keep", default=None, help="write the copy here instead of a temporary folder")
    args = ap.parse_args()
    data = os.path.realpath(args.data or os.environ.get("RIGSLAM_SHARED_DATA", "../shared/data"))
    rec = os.path.join(data, "calib/euroc_imu_april/imu_april")
    target = os.path.join(data, "calib/euroc_imu_april/target.yaml")
    with open(os.path.join(rec, "sequence.yaml")) as f:
        seq = yaml.safe_load(f)
    k0, d0 = camera(seq, "cam0")
    k1, d1 = camera(seq, "cam1")
    euroc = os.path.join(data, "euroc/V1_01_micro/mav0")
    t_b_c0 = read_t_bs(os.path.join(euroc, "cam0/sensor.yaml"))
    t_b_c1 = read_t_bs(os.path.join(euroc, "cam1/sensor.yaml"))
    t_c1_c0 = np.linalg.inv(t_b_c1) @ t_b_c0
    # The pair rendered: camera 1 turned by --yaw-deg about its own y axis.
    t_c1_c0[:3, :3] = rot_y(args.yaw_deg).T @ t_c1_c0[:3, :3]
    rng = np.random.default_rng(args.seed)

    out = args.keep or tempfile.mkdtemp(prefix="known-pair-")
    for cam in ("cam0", "cam1"):
        os.makedirs(os.path.join(out, cam), exist_ok=True)
    shutil.copy(os.path.join(rec, "imu0.csv"), out)
    shutil.copy(os.path.join(rec, "sequence.yaml"), out)
    instants = sorted(f for f in os.listdir(os.path.join(rec, "cam0")) if f.endswith(".csv"))
    written = skipped = 0
    pnp_rms = []
    for name in instants:
        h0, r0 = read_corners(os.path.join(rec, "cam0", name))
        p1 = os.path.join(rec, "cam1", name)
        h1, r1 = read_corners(p1) if os.path.exists(p1) else (h0, [])
        if len(r0) < 8:
            skipped += 1
            continue
        obj = np.array([[float(v) for v in r[7:10]] for r in r0])
        img = np.array([[float(v) for v in r[5:7]] for r in r0])
        ok, rvec, tvec = cv2.solvePnP(obj, img, k0, d0, flags=cv2.SOLVEPNP_ITERATIVE)
        if not ok:
            skipped += 1
            continue
        back = cv2.projectPoints(obj, rvec, tvec, k0, d0)[0].reshape(-1, 2)
        pnp_rms.append(np.sqrt(((back - img) ** 2).sum(1).mean()))
        r_c0_t = cv2.Rodrigues(rvec)[0]
        for cam, header, rows, k, d, (r, t) in (
            ("cam0", h0, r0, k0, d0, (r_c0_t, tvec.ravel())),
            ("cam1", h1, r1, k1, d1,
             (t_c1_c0[:3, :3] @ r_c0_t, t_c1_c0[:3, :3] @ tvec.ravel() + t_c1_c0[:3, 3])),
        ):
            if not rows:
                continue
            pts = np.array([[float(v) for v in row[7:10]] for row in rows])
            px = cv2.projectPoints(pts, cv2.Rodrigues(r)[0], t, k, d)[0].reshape(-1, 2)
            px += rng.normal(0.0, args.noise_px, px.shape)
            with open(os.path.join(out, cam, name), "w") as f:
                f.write(header)
                for row, (u, v) in zip(rows, px):
                    row = list(row)
                    row[5], row[6] = f"{u:.10f}", f"{v:.10f}"
                    f.write(",".join(row) + "\n")
        written += 1

    cal = os.path.join(out, "calibration")
    p = subprocess.run([args.bin, "camera-imu", "--detections", out, "--target", target,
                        "--imu", os.path.join(out, "imu0.csv"), "--out", cal, "--json"],
                       capture_output=True, text=True)
    if p.returncode != 0:
        sys.exit(f"camera-imu failed: {p.stderr[-2000:]}")
    with open(os.path.join(cal, "camchain-imucam.yaml")) as f:
        chain = yaml.safe_load(f)
    t_c0_i = np.array(chain["cam0"]["T_cam_imu"], dtype=float)
    t_c1_i = np.array(chain["cam1"]["T_cam_imu"], dtype=float)
    est_c1_c0 = t_c1_i @ np.linalg.inv(t_c0_i)
    err = est_c1_c0[:3, :3] @ t_c1_c0[:3, :3].T
    result = {
        "instants_written": written,
        "instants_skipped": skipped,
        "pnp_rms_px_real_cam0_median": float(np.median(pnp_rms)),
        "noise_px": args.noise_px,
        "rendered_yaw_deg": args.yaw_deg,
        "stereo_rotation_error_deg": float(angle_deg(err)),
        "stereo_yaw_error_deg": float(yaw_deg(err)),
        "baseline_error_mm": float(1e3 * np.linalg.norm(est_c1_c0[:3, 3] - t_c1_c0[:3, 3])),
        "camera_imu_json": json.loads(p.stdout) if p.stdout.strip().startswith("{") else None,
        "folder": out if args.keep else None,
    }
    print(json.dumps(result, indent=1))
    if not args.keep:
        shutil.rmtree(out)


if __name__ == "__main__":
    main()
