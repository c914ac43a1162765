#!/usr/bin/env python3
"""Publishes rigslamd's poses to ROS 2: nav_msgs/Odometry and /tf.

Reads `rigslam/pose` over iceoryx2 (shared memory, the layout of
include/rigslam/pose_message.h, as examples/python/echo_pose.py does) and
publishes, for every tracked pose:

- `/rigslam/odom` (nav_msgs/msg/Odometry): the body's pose in `odom` with
  its covariance turned into odom's axes, the velocity in `body`;
- `/tf`: `map -> odom` and `odom -> body`.

These are the messages a recording with `[recording] format = "ros2"`
holds (src/recording/ros2/convert.rs), so a live robot and `ros2 bag
play` of its recording look the same to ROS nodes. Poses that are not
tracked (initialising, lost) are not published unless --all is given:
ROS messages have no field for the tracking state.

Stamps: the daemon stamps live poses on the host's CLOCK_MONOTONIC; by
default they are moved onto the node's clock (ROS time) by the offset
between the two clocks when the pose arrives. --stamps sensor keeps them
as they are (a replay of a dataset stamps with the dataset's clock).

Needs a sourced ROS 2 (rclpy, nav_msgs, tf2_ros) and iceoryx2's Python
binding of the daemon's iceoryx2 version, in the same Python:

    source /opt/ros/jazzy/setup.bash
    python3 -m venv --system-site-packages ~/rigslam-ros && ~/rigslam-ros/bin/pip install iceoryx2==0.10.0
    ~/rigslam-ros/bin/python examples/ros2/pose_bridge.py --root-path /run/rigslam/iceoryx2

--print publishes nothing and needs no ROS: it prints what it would
publish, one JSON object per pose, stamped as the daemon stamps (what
tests/ros2_pose_bridge.rs checks against the recording's conversion).
"""

import argparse
import json
import math
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "python"))
from echo_pose import POSE_LAYOUT_VERSION, PoseMessage  # noqa: E402

import iceoryx2 as iox2  # noqa: E402

TRACKING = 1
POSE_FLAG_COVARIANCE_VALID = 1 << 0
POSE_FLAG_VELOCITY_VALID = 1 << 1
MAP, ODOM, BODY = "map", "odom", "body"


def rotation_matrix(q):
    """Row-major 3x3 rotation of a unit quaternion x, y, z, w."""
    x, y, z, w = q
    return [
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ]


def transpose(m):
    return [list(row) for row in zip(*m)]


def odom_covariance(m):
    """The pose covariance about odom's axes, row-major 6x6; zeros when unknown.

    The published one is of the map-frame pose about map's axes (position,
    then rotation about fixed axes); with map -> odom taken as exact it
    turns by R_odom_map on both blocks.
    """
    if not m.flags & POSE_FLAG_COVARIANCE_VALID:
        return [0.0] * 36
    c = list(m.covariance)
    if list(m.rotation_world_odom_xyzw) == [0.0, 0.0, 0.0, 1.0]:
        return c
    r = transpose(rotation_matrix(m.rotation_world_odom_xyzw))
    turn = [[0.0] * 6 for _ in range(6)]
    for i in range(3):
        for j in range(3):
            turn[i][j] = turn[i + 3][j + 3] = r[i][j]
    world = [c[6 * i: 6 * i + 6] for i in range(6)]
    tw = [[sum(turn[i][k] * world[k][j] for k in range(6)) for j in range(6)] for i in range(6)]
    out = [[sum(tw[i][k] * turn[j][k] for k in range(6)) for j in range(6)] for i in range(6)]
    return [v for row in out for v in row]


def body_velocity(m):
    """The velocity in the body frame (ROS puts the twist in the child frame)."""
    if not m.flags & POSE_FLAG_VELOCITY_VALID:
        return [0.0, 0.0, 0.0]
    r = rotation_matrix(m.orientation_world_body_xyzw)
    v = m.velocity_world_m_s
    return [sum(r[k][i] * v[k] for k in range(3)) for i in range(3)]


def published(m, stamp_ns):
    """What one pose becomes: the odometry and the two transforms, as plain values."""
    return {
        "stamp_ns": stamp_ns,
        "odometry": {
            "frame_id": ODOM,
            "child_frame_id": BODY,
            "position": list(m.position_odom_m),
            "orientation_xyzw": list(m.orientation_odom_body_xyzw),
            "pose_covariance": odom_covariance(m),
            "linear_velocity": body_velocity(m),
        },
        "transforms": [
            [MAP, ODOM, list(m.translation_world_odom_m), list(m.rotation_world_odom_xyzw)],
            [ODOM, BODY, list(m.position_odom_m), list(m.orientation_odom_body_xyzw)],
        ],
    }


class RosOutput:
    """The ROS 2 side: a node with the odometry publisher and a tf broadcaster."""

    def __init__(self, topic):
        import rclpy
        from nav_msgs.msg import Odometry
        from geometry_msgs.msg import TransformStamped
        from tf2_ros import TransformBroadcaster

        rclpy.init()
        self.rclpy = rclpy
        self.Odometry, self.TransformStamped = Odometry, TransformStamped
        self.node = rclpy.create_node("rigslam_pose_bridge")
        self.odometry = self.node.create_publisher(Odometry, topic, 10)
        self.tf = TransformBroadcaster(self.node)

    def now_ns(self):
        return self.node.get_clock().now().nanoseconds

    def stamp(self, header, stamp_ns):
        header.stamp.sec, header.stamp.nanosec = divmod(stamp_ns, 1_000_000_000)

    def publish(self, p):
        o = self.Odometry()
        self.stamp(o.header, p["stamp_ns"])
        odometry = p["odometry"]
        o.header.frame_id = odometry["frame_id"]
        o.child_frame_id = odometry["child_frame_id"]
        pose = o.pose.pose
        pose.position.x, pose.position.y, pose.position.z = odometry["position"]
        q = pose.orientation
        q.x, q.y, q.z, q.w = odometry["orientation_xyzw"]
        o.pose.covariance = odometry["pose_covariance"]
        t = o.twist.twist.linear
        t.x, t.y, t.z = odometry["linear_velocity"]
        self.odometry.publish(o)
        transforms = []
        for parent, child, translation, rotation in p["transforms"]:
            t = self.TransformStamped()
            self.stamp(t.header, p["stamp_ns"])
            t.header.frame_id, t.child_frame_id = parent, child
            v = t.transform.translation
            v.x, v.y, v.z = translation
            r = t.transform.rotation
            r.x, r.y, r.z, r.w = rotation
            transforms.append(t)
        self.tf.sendTransform(transforms)
        self.rclpy.spin_once(self.node, timeout_sec=0)

    def close(self):
        self.node.destroy_node()
        self.rclpy.shutdown()


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--root-path", help="iceoryx2 root directory of the daemon")
    parser.add_argument("--service", default="rigslam/pose", help="iceoryx2 service")
    parser.add_argument("--topic", default="/rigslam/odom", help="ROS 2 odometry topic")
    parser.add_argument("--stamps", choices=["ros", "sensor"], default="ros",
                        help="ros: moved onto the node's clock; sensor: as the daemon stamps")
    parser.add_argument("--all", action="store_true", help="publish untracked poses too")
    parser.add_argument("--print", action="store_true",
                        help="print what would be published (JSON lines), no ROS needed")
    parser.add_argument("--count", type=int, default=0, help="stop after this many poses")
    parser.add_argument("--timeout-s", type=float, default=0.0,
                        help="give up when no pose comes for this long (0: never)")
    args = parser.parse_args()

    config = iox2.config.default()
    if args.root_path:
        config.global_cfg.root_path = iox2.Path.new(args.root_path.rstrip("/") + "/")
    node = iox2.NodeBuilder.new().config(config).create(iox2.ServiceType.Ipc)
    started = time.monotonic()
    while True:
        try:
            service = (
                node.service_builder(iox2.ServiceName.new(args.service))
                .publish_subscribe(PoseMessage)
                .open()
            )
            break
        except iox2.PublishSubscribeOpenError as error:
            if args.timeout_s and time.monotonic() - started > args.timeout_s:
                sys.exit(f"pose_bridge: cannot open {args.service}: {error}")
            time.sleep(0.1)
    subscriber = service.subscriber_builder().create()
    ros = None if args.print else RosOutput(args.topic)
    sent = 0
    last = time.monotonic()
    try:
        while args.count == 0 or sent < args.count:
            sample = subscriber.receive()
            if sample is None:
                if args.timeout_s and time.monotonic() - last > args.timeout_s:
                    sys.exit(f"pose_bridge: no pose for {args.timeout_s} s")
                time.sleep(0.001)
                continue
            m = sample.payload().contents
            last = time.monotonic()
            if m.layout_version != POSE_LAYOUT_VERSION:
                sys.exit(f"pose_bridge: layout version {m.layout_version}, "
                         f"this bridge knows {POSE_LAYOUT_VERSION}")
            if m.tracking_state == TRACKING or args.all:
                stamp_ns = m.t_ns
                if args.stamps == "ros" and ros is not None:
                    stamp_ns += ros.now_ns() - time.clock_gettime_ns(time.CLOCK_MONOTONIC)
                p = published(m, stamp_ns)
                if ros is None:
                    print(json.dumps(p), flush=True)
                else:
                    ros.publish(p)
                sent += 1
            sample.delete()
    finally:
        if ros is not None:
            ros.close()


if __name__ == "__main__":
    main()
