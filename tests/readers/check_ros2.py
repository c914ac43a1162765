"""Reads a rigslam recording made with `[recording] format = "ros2"` with
the Python `mcap` package and `mcap-ros2-support`, and prints what it
found as JSON.

`mcap-ros2-support` knows no ROS message types of its own: it parses the
`ros2msg` definition each schema carries and decodes the CDR of every
message with it, so a definition that does not match its messages (a
field missing, a wrong type, wrong alignment) fails here or gives other
values. Each decoded message is also encoded again by the package's own
CDR writer from the same definition and compared with the bytes in the
file: any difference in padding, lengths or trailing bytes is counted.

Two passes, both with CRC checks: a seeking read through the summary,
and a streaming read from the first byte to the last.

Usage: python check_ros2.py FILE.mcap
"""

import json
import sys
import zlib

from mcap.reader import NonSeekingReader, SeekingReader
from mcap_ros2.decoder import DecoderFactory
from mcap_ros2._dynamic import serialize_dynamic


def stamp(header):
    return [header.stamp.sec, header.stamp.nanosec, header.frame_id]


def xyz(v):
    return [v.x, v.y, v.z]


def xyzw(q):
    return [q.x, q.y, q.z, q.w]


def transforms(m):
    return [
        [
            *stamp(t.header),
            t.child_frame_id,
            *xyz(t.transform.translation),
            *xyzw(t.transform.rotation),
        ]
        for t in m.transforms
    ]


def fields(schema, m):
    """The values of a decoded message, by type, to compare with what was written."""
    if schema == "sensor_msgs/msg/Imu":
        return [
            *stamp(m.header),
            *xyzw(m.orientation),
            list(m.orientation_covariance),
            *xyz(m.angular_velocity),
            list(m.angular_velocity_covariance),
            *xyz(m.linear_acceleration),
            list(m.linear_acceleration_covariance),
        ]
    if schema == "sensor_msgs/msg/Image":
        return [
            *stamp(m.header),
            m.height,
            m.width,
            m.encoding,
            m.is_bigendian,
            m.step,
            len(m.data),
            zlib.crc32(m.data),
        ]
    if schema == "nav_msgs/msg/Odometry":
        return [
            *stamp(m.header),
            m.child_frame_id,
            *xyz(m.pose.pose.position),
            *xyzw(m.pose.pose.orientation),
            list(m.pose.covariance),
            *xyz(m.twist.twist.linear),
            *xyz(m.twist.twist.angular),
            list(m.twist.covariance),
        ]
    if schema == "tf2_msgs/msg/TFMessage":
        return transforms(m)
    if schema == "sensor_msgs/msg/CameraInfo":
        roi = m.roi
        return [
            *stamp(m.header),
            m.height,
            m.width,
            m.distortion_model,
            list(m.d),
            list(m.k),
            list(m.r),
            list(m.p),
            m.binning_x,
            m.binning_y,
            [roi.x_offset, roi.y_offset, roi.height, roi.width, roi.do_rectify],
        ]
    raise SystemExit(f"unexpected schema {schema}")


def main(path):
    out = {
        "messages": {},
        "values": {},
        "log_times": {},
        "reencoded_differ": {},
        "channels": {},
        "schemas": {},
    }
    encoders = {}
    with open(path, "rb") as f:
        reader = SeekingReader(f, validate_crcs=True, decoder_factories=[DecoderFactory()])
        header = reader.get_header()
        out["profile"] = header.profile
        summary = reader.get_summary()
        if summary is None:
            raise SystemExit(f"{path}: no summary")
        out["statistics_messages"] = summary.statistics.message_count
        for schema in summary.schemas.values():
            out["schemas"][schema.name] = schema.encoding
        for channel in summary.channels.values():
            out["channels"][channel.topic] = {
                "message_encoding": channel.message_encoding,
                "schema": summary.schemas[channel.schema_id].name,
                "metadata": dict(channel.metadata),
            }
        out["metadata"] = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
        out["attachments"] = sorted(a.name for a in summary.attachment_indexes)
        for schema, channel, message, decoded in reader.iter_decoded_messages(log_time_order=False):
            topic = channel.topic
            out["messages"][topic] = out["messages"].get(topic, 0) + 1
            out["values"].setdefault(topic, []).append(fields(schema.name, decoded))
            out["log_times"].setdefault(topic, []).append(message.log_time)
            if schema.id not in encoders:
                encoders[schema.id] = serialize_dynamic(schema.name, schema.data.decode())[schema.name]
            again = encoders[schema.id](decoded)
            if again != message.data:
                out["reencoded_differ"][topic] = out["reencoded_differ"].get(topic, 0) + 1
    with open(path, "rb") as f:
        streamed = 0
        reader = NonSeekingReader(f, validate_crcs=True, decoder_factories=[DecoderFactory()])
        for _ in reader.iter_decoded_messages():
            streamed += 1
        out["streamed_messages"] = streamed
    json.dump(out, sys.stdout)


if __name__ == "__main__":
    main(sys.argv[1])
