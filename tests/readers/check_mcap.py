"""Reads a rigslam recording with the Python `mcap` package, the reader
the MCAP project maintains, and prints what it found as JSON.

Two passes: a seeking read through the summary and its chunk indexes,
and a streaming read from the first byte to the last, both with CRC
checks on (chunks, and the data section in the streaming pass). Every
message is decoded through the schema the file carries (protobuf
descriptors, via `mcap-protobuf-support`), so a descriptor that does not
match its messages fails here.

Usage: python check_mcap.py FILE.mcap
"""

import zlib
import json
import sys

from mcap.reader import NonSeekingReader, SeekingReader
from mcap_protobuf.decoder import DecoderFactory


def fields(topic, m):
    """A few values of each decoded message, to compare with what was written."""
    if topic == "/imu0":
        return [m.t_ns, *m.gyro_rad_s, *m.accel_m_s2]
    if topic in ("/cam0", "/cam1"):
        return [
            m.timestamp.seconds,
            m.timestamp.nanos,
            m.width,
            m.height,
            m.step,
            m.encoding,
            m.frame_id,
            zlib.crc32(m.data),
        ]
    if topic == "/rigslam/pose":
        return [
            m.t_ns,
            m.tracking_state,
            m.flags,
            *m.position_world_m,
            *m.orientation_world_body_xyzw,
            *m.position_odom_m,
            *m.translation_world_odom_m,
            len(m.covariance),
        ]
    if topic in ("/rigslam/pose_map", "/rigslam/pose_odom"):
        p = m.pose.position
        return [m.frame_id, m.timestamp.seconds, m.timestamp.nanos, p.x, p.y, p.z]
    if topic == "/tf":
        return [[t.parent_frame_id, t.child_frame_id] for t in m.transforms]
    if topic.endswith("/calibration"):
        return [m.frame_id, m.width, m.height, m.distortion_model, list(m.K), list(m.D)]
    if topic == "/rigslam/status":
        return [m.t_ns, m.health, m.camera_rate_hz]
    return None


def main(path):
    out = {"messages": {}, "values": {}, "log_times": {}}
    with open(path, "rb") as f:
        reader = SeekingReader(f, validate_crcs=True, decoder_factories=[DecoderFactory()])
        summary = reader.get_summary()
        if summary is None:
            raise SystemExit(f"{path}: no summary")
        out["statistics_messages"] = summary.statistics.message_count
        out["chunk_indexes"] = len(summary.chunk_indexes)
        out["chunk_compression"] = sorted({c.compression for c in summary.chunk_indexes})
        out["attachments"] = sorted(a.name for a in summary.attachment_indexes)
        out["metadata"] = {
            m.name: dict(m.metadata) for m in reader.iter_metadata()
        }
        for schema, channel, message, decoded in reader.iter_decoded_messages(log_time_order=False):
            topic = channel.topic
            out["messages"][topic] = out["messages"].get(topic, 0) + 1
            out["values"].setdefault(topic, []).append(fields(topic, decoded))
            out["log_times"].setdefault(topic, []).append(message.log_time)
    with open(path, "rb") as f:
        streamed = 0
        reader = NonSeekingReader(f, validate_crcs=True, decoder_factories=[DecoderFactory()])
        for _ in reader.iter_decoded_messages():
            streamed += 1
        out["streamed_messages"] = streamed
    json.dump(out, sys.stdout)


if __name__ == "__main__":
    main(sys.argv[1])
