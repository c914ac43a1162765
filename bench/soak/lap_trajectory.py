#!/usr/bin/env python3
"""A closed lap through the simulated room, as a TUM trajectory, for
replaying one rendering many times in a row (`[replay] loops`).

The rig rests for `--rest-s` at the start, drives one lap whose speed
eases in and out (smootherstep in time, so velocity and acceleration are
zero at both ends), and rests again at the pose it started from. Looping
the rendering is then a continuous motion: a robot that pauses at its
dock once a lap. Positions are the IMU (body) frame in the world, z up;
the cameras look along body z, which the lap turns about world z.

  python3 bench/soak/lap_trajectory.py --out lap.tum
  rigslam simulate --trajectory lap.tum --stereo --out lap
"""
import argparse
import math


def smootherstep(x):
    x = min(max(x, 0.0), 1.0)
    return x * x * x * (x * (6.0 * x - 15.0) + 10.0)


def matmul(a, b):
    return [[sum(a[i][k] * b[k][j] for k in range(3)) for j in range(3)] for i in range(3)]


def rot_z(a):
    c, s = math.cos(a), math.sin(a)
    return [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]


def rot_y(a):
    c, s = math.cos(a), math.sin(a)
    return [[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]]


def rot_x(a):
    c, s = math.cos(a), math.sin(a)
    return [[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]]


# Body axes in the forward frame (x forward, z up): body z looks forward,
# body x is up, body y is to the right.
FORWARD_FROM_BODY = [[0.0, 0.0, 1.0], [0.0, -1.0, 0.0], [1.0, 0.0, 0.0]]


def quaternion(r):
    """(x, y, z, w) of a rotation matrix."""
    t = r[0][0] + r[1][1] + r[2][2]
    if t > 0.0:
        s = math.sqrt(t + 1.0) * 2.0
        return ((r[2][1] - r[1][2]) / s, (r[0][2] - r[2][0]) / s, (r[1][0] - r[0][1]) / s, 0.25 * s)
    i = max(range(3), key=lambda k: r[k][k])
    j, k = (i + 1) % 3, (i + 2) % 3
    s = math.sqrt(1.0 + r[i][i] - r[j][j] - r[k][k]) * 2.0
    q = [0.0, 0.0, 0.0, 0.0]
    q[i] = 0.25 * s
    q[j] = (r[j][i] + r[i][j]) / s
    q[k] = (r[k][i] + r[i][k]) / s
    q[3] = (r[k][j] - r[j][k]) / s
    return tuple(q)


def pose(u, args):
    """Position and rotation at lap fraction u (0 and 1: the dock)."""
    a = 2.0 * math.pi * u
    x = -args.radius_x_m * math.cos(a)
    y = args.radius_y_m * math.sin(a)
    z = 1.3 + 0.15 * math.sin(2.0 * a)
    yaw = args.yaw_swing_rad * math.sin(a)
    pitch = 0.12 * math.sin(2.0 * a)
    roll = 0.06 * math.sin(3.0 * a)
    r = matmul(matmul(matmul(rot_z(yaw), rot_y(-pitch)), rot_x(roll)), FORWARD_FROM_BODY)
    return (x, y, z), r


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", required=True, help="TUM file to write")
    p.add_argument("--lap-s", type=float, default=18.0, help="driving time of the lap [18]")
    p.add_argument("--rest-s", type=float, default=1.0, help="rest at each end [1]")
    p.add_argument("--radius-x-m", type=float, default=1.2, help="half the lap's length along x [1.2]")
    p.add_argument("--radius-y-m", type=float, default=1.0, help="half its width along y [1.0]")
    p.add_argument("--yaw-swing-rad", type=float, default=0.9, help="how far the cameras turn each way [0.9]")
    p.add_argument("--rate-hz", type=float, default=200.0, help="samples per second [200]")
    p.add_argument("--laps", type=int, default=1, help="laps one after the other in the file [1]")
    p.add_argument(
        "--reverse",
        action="store_true",
        help="drive the lap the other way round, the cameras swinging the other way: "
        "another trajectory through the same room (the same extent, so the same rendered room)",
    )
    args = p.parse_args()
    lap_total = args.lap_s + 2.0 * args.rest_s
    n = int(round(lap_total * args.laps * args.rate_hz))
    with open(args.out, "w") as f:
        f.write("# timestamp tx ty tz qx qy qz qw (body in world; closed laps)\n")
        for i in range(n + 1):
            t = i / args.rate_hz
            in_lap = t - lap_total * min(int(t // lap_total), args.laps - 1)
            u = smootherstep((in_lap - args.rest_s) / args.lap_s)
            if args.reverse:
                u = 1.0 - u
            (x, y, z), r = pose(u, args)
            q = quaternion(r)
            f.write(f"{t:.6f} {x:.9f} {y:.9f} {z:.9f} {q[0]:.12f} {q[1]:.12f} {q[2]:.12f} {q[3]:.12f}\n")


if __name__ == "__main__":
    main()
