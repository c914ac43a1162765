#!/usr/bin/env python3
"""Copies of the accuracy sets whose camera calibration is wrong the way a
user's may be: camera 0 (and with it the stereo pair) turned by 1 deg
about the oblique camera axis (0.6, -0.8, 0), moved by (0, 6, 8) mm in the
IMU frame (10 mm), and a time shift of +5 ms (`timeshift_cam_imu: 0.005`,
the frames said to lag the IMU by 5 ms when they do not). The same error
as `tests/camera_imu_refinement.rs`. Images, IMU and ground truth are
linked, not copied; only each camera's `sensor.yaml` and `data.csv` are
written.

Score the online refinement with `run_sets.py OUT --modes stereo-inertial`
against the same run on the sets themselves: the truth is the sets'
calibration, 1 deg, 10 mm and -5 ms from the wrong one.

The options scale the error. With a negligible one (`--angle-deg 0
--move-mm 0 --shift-s 1e-6`: a microsecond, a millionth of a radian at
1 rad/s) the copies are the same rig to any measurement, and how far
their runs land from the originals' is the spread a run has anyway: the
noise floor under which a difference between two builds or settings
means nothing.

usage: bench/accuracy/wrong_calibration.py SETS_DIR OUT_DIR
           [--angle-deg 1] [--move-mm 10] [--shift-s 0.005]
"""
import argparse, math, os, re, shutil, sys

AXIS = (0.6, -0.8, 0.0)
ANGLE_DEG = 1.0
MOVE_M = (0.0, 0.006, 0.008)
SHIFT_S = 0.005


def read_t_bs(text):
    m = re.search(r"T_BS:.*?data:\s*\[(.*?)\]", text, re.S)
    v = [float(x) for x in m.group(1).replace("\n", " ").split(",")]
    return [v[0:4], v[4:8], v[8:12], v[12:16]]


def matmul(a, b):
    return [[sum(a[i][k] * b[k][j] for k in range(4)) for j in range(4)] for i in range(4)]


def inverse(t):
    r = [[t[j][i] for j in range(3)] for i in range(3)]
    p = [-sum(r[i][k] * t[k][3] for k in range(3)) for i in range(3)]
    return [r[0] + [p[0]], r[1] + [p[1]], r[2] + [p[2]], [0.0, 0.0, 0.0, 1.0]]


def turn(axis, angle):
    n = math.sqrt(sum(a * a for a in axis))
    x, y, z = (a / n for a in axis)
    c, s, k = math.cos(angle), math.sin(angle), 1 - math.cos(angle)
    return [
        [c + x * x * k, x * y * k - z * s, x * z * k + y * s, 0.0],
        [y * x * k + z * s, c + y * y * k, y * z * k - x * s, 0.0],
        [z * x * k - y * s, z * y * k + x * s, c + z * z * k, 0.0],
        [0.0, 0.0, 0.0, 1.0],
    ]


def write_yaml(text, t, shift_s):
    data = ", ".join(repr(float(x)) for row in t for x in row)
    text = re.sub(r"(T_BS:.*?data:\s*)\[(.*?)\]", lambda m: m.group(1) + "[" + data + "]", text,
                  flags=re.S)
    if "timeshift_cam_imu" in text:
        sys.exit("the set's calibration already has a time shift")
    return text.rstrip("\n") + f"\ntimeshift_cam_imu: {shift_s!r}\n"


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("src", metavar="SETS_DIR", help="the folder render_sets.sh wrote")
    ap.add_argument("dst", metavar="OUT_DIR", help="where the copies go")
    ap.add_argument("--angle-deg", type=float, default=ANGLE_DEG,
                    help="camera 0 turned about (0.6, -0.8, 0), deg [%(default)s]")
    ap.add_argument("--move-mm", type=float, default=math.hypot(*MOVE_M) * 1e3,
                    help="camera 0 moved along (0, 0.6, 0.8) in the IMU frame, mm [%(default)s]")
    ap.add_argument("--shift-s", type=float, default=SHIFT_S,
                    help="timeshift_cam_imu written to every camera, s [%(default)s]")
    a = ap.parse_args()
    src, dst = a.src, a.dst
    if not os.path.isdir(src):
        sys.exit(f"{src}: not a folder (the folder render_sets.sh wrote)")
    n = math.hypot(*MOVE_M)
    move = MOVE_M if a.move_mm == n * 1e3 else [m / n * a.move_mm * 1e-3 for m in MOVE_M]
    for name in sorted(os.listdir(src)):
        mav = os.path.join(src, name, "mav0")
        if not os.path.isfile(os.path.join(mav, "cam0", "sensor.yaml")):
            continue
        out = os.path.join(dst, name, "mav0")
        os.makedirs(out, exist_ok=True)
        for d in ["imu0", "state_groundtruth_estimate0"]:
            if os.path.exists(os.path.join(mav, d)) and not os.path.lexists(os.path.join(out, d)):
                os.symlink(os.path.abspath(os.path.join(mav, d)), os.path.join(out, d))
        t0 = read_t_bs(open(os.path.join(mav, "cam0", "sensor.yaml")).read())
        wrong = matmul(t0, turn(AXIS, math.radians(a.angle_deg)))
        for i in range(3):
            wrong[i][3] += move[i]
        for cam in sorted(c for c in os.listdir(mav) if re.fullmatch(r"cam\d+", c)):
            cd = os.path.join(out, cam)
            os.makedirs(cd, exist_ok=True)
            if not os.path.lexists(os.path.join(cd, "data")):
                os.symlink(os.path.abspath(os.path.join(mav, cam, "data")), os.path.join(cd, "data"))
            shutil.copy(os.path.join(mav, cam, "data.csv"), os.path.join(cd, "data.csv"))
            text = open(os.path.join(mav, cam, "sensor.yaml")).read()
            # Every camera keeps its pose in camera 0.
            t = matmul(matmul(wrong, inverse(t0)), read_t_bs(text))
            with open(os.path.join(cd, "sensor.yaml"), "w") as f:
                f.write(write_yaml(text, t, a.shift_s))
        print(name)


if __name__ == "__main__":
    main()
