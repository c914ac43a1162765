#!/usr/bin/env python3
"""Prints the poses rigslamd publishes on `rigslam/pose`, one line each.

A Python process reads them with iceoryx2's own Python binding, of the same
iceoryx2 version as the daemon (0.10), and the message layout of
include/rigslam/pose_message.h written as a ctypes structure below:

    python3 -m venv ~/rigslam-py && ~/rigslam-py/bin/pip install iceoryx2==0.10.0
    ~/rigslam-py/bin/python examples/python/echo_pose.py --root-path /run/rigslam/iceoryx2

The reader must be the daemon's user or in its group (`rigslam`); without
--root-path it looks where iceoryx2 looks by default (/tmp/iceoryx2), which
is where `rigslamd --replay` publishes when run by hand.
"""

import argparse
import ctypes
import json
import sys
import time

import iceoryx2 as iox2

POSE_LAYOUT_VERSION = 2
TRACKING_STATES = {0: "initializing", 1: "tracking", 2: "lost"}
POSE_FLAG_COVARIANCE_VALID = 1 << 0
POSE_FLAG_MAP_CORRECTED = 1 << 3  # odom fields differ from the world pose


class PoseMessage(ctypes.Structure):
    """rigslam_pose_message_t: 520 bytes, 8-aligned, native byte order."""

    _fields_ = [
        ("layout_version", ctypes.c_uint32),
        ("tracking_state", ctypes.c_uint32),
        ("flags", ctypes.c_uint32),
        ("reserved", ctypes.c_uint32),
        ("t_ns", ctypes.c_int64),  # time the pose refers to
        ("published_t_ns", ctypes.c_int64),  # CLOCK_MONOTONIC at publishing
        ("sequence", ctypes.c_uint64),  # +1 per sample: a gap is a miss
        ("position_world_m", ctypes.c_double * 3),
        ("orientation_world_body_xyzw", ctypes.c_double * 4),
        ("velocity_world_m_s", ctypes.c_double * 3),
        ("covariance", ctypes.c_double * 36),  # 6x6 row-major, position then rotation
        ("position_odom_m", ctypes.c_double * 3),  # the relative stage's pose (odom)
        ("orientation_odom_body_xyzw", ctypes.c_double * 4),
        ("translation_world_odom_m", ctypes.c_double * 3),  # T_world_odom (map <- odom)
        ("rotation_world_odom_xyzw", ctypes.c_double * 4),
    ]

    @staticmethod
    def type_name():
        """The name the daemon gives the payload type (RIGSLAM_POSE_TYPE_NAME)."""
        return "rigslam_pose_message_v2"


def line(m):
    """One pose as text: stamp, state, position, quaternion, position sigmas."""
    p, q = m.position_world_m, m.orientation_world_body_xyzw
    text = (
        f"{m.sequence} t={m.t_ns * 1e-9:.6f} {TRACKING_STATES.get(m.tracking_state, '?')} "
        f"p=({p[0]:.4f}, {p[1]:.4f}, {p[2]:.4f}) "
        f"q=({q[0]:.4f}, {q[1]:.4f}, {q[2]:.4f}, {q[3]:.4f})"
    )
    if m.flags & POSE_FLAG_COVARIANCE_VALID:
        sigmas = [m.covariance[7 * i] ** 0.5 for i in range(3)]
        text += " sigma_m=({:.4f}, {:.4f}, {:.4f})".format(*sigmas)
    return text


def as_dict(m):
    """Every field at full precision (covariance None when not valid)."""
    covariance = list(m.covariance) if m.flags & POSE_FLAG_COVARIANCE_VALID else None
    return {
        "sequence": m.sequence,
        "t_ns": m.t_ns,
        "published_t_ns": m.published_t_ns,
        "tracking_state": TRACKING_STATES.get(m.tracking_state, "unknown"),
        "flags": m.flags,
        "position_world_m": list(m.position_world_m),
        "orientation_world_body_xyzw": list(m.orientation_world_body_xyzw),
        "velocity_world_m_s": list(m.velocity_world_m_s),
        "covariance": covariance,
        "position_odom_m": list(m.position_odom_m),
        "orientation_odom_body_xyzw": list(m.orientation_odom_body_xyzw),
        "translation_world_odom_m": list(m.translation_world_odom_m),
        "rotation_world_odom_xyzw": list(m.rotation_world_odom_xyzw),
    }


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--root-path", help="iceoryx2 root directory of the daemon")
    parser.add_argument("--service", default="rigslam/pose", help="service name")
    parser.add_argument("--count", type=int, default=0, help="stop after this many poses")
    parser.add_argument("--json", action="store_true", help="one JSON object per pose")
    parser.add_argument("--timeout-s", type=float, default=30.0,
                        help="give up when no pose comes for this long")
    args = parser.parse_args()

    assert ctypes.sizeof(PoseMessage) == 520 and ctypes.alignment(PoseMessage) == 8
    config = iox2.config.default()
    if args.root_path:
        config.global_cfg.root_path = iox2.Path.new(args.root_path.rstrip("/") + "/")
    node = iox2.NodeBuilder.new().config(config).create(iox2.ServiceType.Ipc)
    deadline = time.monotonic() + args.timeout_s
    while True:
        try:
            service = (
                node.service_builder(iox2.ServiceName.new(args.service))
                .publish_subscribe(PoseMessage)
                .open()
            )
            break
        except iox2.PublishSubscribeOpenError as error:
            if time.monotonic() > deadline:
                sys.exit(f"echo_pose: cannot open {args.service}: {error}")
            time.sleep(0.1)
    subscriber = service.subscriber_builder().create()
    received = 0
    deadline = time.monotonic() + args.timeout_s
    while args.count == 0 or received < args.count:
        sample = subscriber.receive()
        if sample is None:
            if time.monotonic() > deadline:
                sys.exit(f"echo_pose: no pose for {args.timeout_s} s")
            time.sleep(0.002)
            continue
        message = sample.payload().contents
        if message.layout_version != POSE_LAYOUT_VERSION:
            sys.exit(f"echo_pose: layout version {message.layout_version}, "
                     f"this reader knows {POSE_LAYOUT_VERSION}")
        print(json.dumps(as_dict(message)) if args.json else line(message), flush=True)
        sample.delete()
        received += 1
        deadline = time.monotonic() + args.timeout_s


if __name__ == "__main__":
    main()
