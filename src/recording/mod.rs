//! Recordings of live sensor streams as MCAP files (one channel per
//! sensor stream, replayable bit for bit, opened by Foxglove).
//!
//! Messages are JSON (serde_json with exact float round-tripping) described
//! by a JSON Schema, so viewers can plot them without custom code, and
//! [`read_imu_channel`] gives back exactly the samples written. Each
//! message's log time is the sample's host stamp, its publish time the host
//! receipt time.

use std::collections::BTreeMap;
use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};

use rigslam_drivers::ImuSample;
use thiserror::Error;

mod mcap_bounds;
mod sensor_replay;
/// Files carried in a recording: (attachment name, bytes).
pub type Attachments = Vec<(String, Vec<u8>)>;
pub use sensor_replay::{
    calibration_attachment_name, calibration_attachments, for_each_sensor_event,
    for_each_sensor_event_in, is_mcap, rig_of_recording, rig_of_recording_in, ReplayItem,
    SensorTopics, SkippedMessage,
};

/// Schema name of IMU messages.
pub const IMU_SCHEMA_NAME: &str = "rigslam.ImuSample";

const IMU_JSON_SCHEMA: &str = r#"{"type":"object","properties":{"t_ns":{"type":"integer","description":"host CLOCK_MONOTONIC, ns"},"gyro_rad_s":{"type":"array","items":{"type":"number"},"minItems":3,"maxItems":3},"accel_m_s2":{"type":"array","items":{"type":"number"},"minItems":3,"maxItems":3}},"required":["t_ns","gyro_rad_s","accel_m_s2"]}"#;

#[derive(Debug, Error)]
/// Why a recording could not be written or read. Every variant names the file.
pub enum RecordingError {
    #[error("cannot create recording {path}: {source}")]
    /// The file could not be created.
    Create {
        /// The file.
        path: PathBuf,
        /// The I/O error.
        source: std::io::Error,
    },
    #[error("cannot read recording {path}: {source}")]
    /// The file could not be opened or read.
    Read {
        /// The file.
        path: PathBuf,
        /// The I/O error.
        source: std::io::Error,
    },
    #[error("MCAP error in {path}: {source}")]
    /// The MCAP library refused to write or read the file.
    Mcap {
        /// The file.
        path: PathBuf,
        /// The MCAP library's error.
        source: mcap::McapError,
    },
    #[error("{path} has no summary: the file was not closed (cut off mid-write?)")]
    /// The file ends without its summary section: it was not closed (the writer was cut off).
    NoSummary {
        /// The file.
        path: PathBuf,
    },
    #[error("{path}: message {sequence} on {topic} does not have the channel's layout: {source}")]
    /// A message's JSON does not match its channel's schema.
    BadMessage {
        /// The file.
        path: PathBuf,
        /// The channel's topic.
        topic: String,
        /// The message's sequence number on its channel.
        sequence: u32,
        /// The JSON decoder's error.
        source: serde_json::Error,
    },
    /// A length field that does not fit the file (a string, map, chunk
    /// or attachment longer than what holds it); `offset` is the byte it
    /// is at.
    #[error("{path}: malformed MCAP: {reason}")]
    Malformed {
        /// The file.
        path: PathBuf,
        /// Byte offset of the bad length field.
        offset: u64,
        /// What does not fit.
        reason: String,
    },
    #[error("{path} has no channel {topic}")]
    /// The file has no channel on the topic asked for.
    NoChannel {
        /// The file.
        path: PathBuf,
        /// The missing topic.
        topic: String,
    },
    #[error("{path}: attachment {name}: {reason}")]
    /// An attachment (e.g. the rig calibration) cannot be used.
    BadAttachment {
        /// The file.
        path: PathBuf,
        /// The attachment's name.
        name: String,
        /// Why it cannot be used.
        reason: String,
    },
    #[error("{path}: message {sequence} on {topic}: {reason}")]
    /// An image message does not decode into a frame.
    BadImage {
        /// The file.
        path: PathBuf,
        /// The channel's topic.
        topic: String,
        /// The message's sequence number on its channel.
        sequence: u32,
        /// Why it does not decode (encoding, size, data length).
        reason: String,
    },
}

#[derive(serde::Serialize, serde::Deserialize)]
struct ImuMessage {
    t_ns: i64,
    gyro_rad_s: [f64; 3],
    accel_m_s2: [f64; 3],
}

/// Schema name of pose messages.
pub const POSE_SCHEMA_NAME: &str = "foxglove.PoseInFrame";
/// Schema name of image messages.
pub const IMAGE_SCHEMA_NAME: &str = "foxglove.RawImage";

const TIME_SCHEMA: &str =
    r#"{"type":"object","properties":{"sec":{"type":"integer"},"nsec":{"type":"integer"}}}"#;
const VEC3_SCHEMA: &str = r#"{"type":"object","properties":{"x":{"type":"number"},"y":{"type":"number"},"z":{"type":"number"}}}"#;

/// `foxglove.PoseInFrame` (timestamp, frame_id, pose) with the daemon's
/// fields beside it: the exact stamp, tracking state and velocity.
static POSE_JSON_SCHEMA: std::sync::LazyLock<String> = std::sync::LazyLock::new(|| {
    format!(
        r#"{{"type":"object","properties":{{"timestamp":{TIME_SCHEMA},"frame_id":{{"type":"string"}},"pose":{{"type":"object","properties":{{"position":{VEC3_SCHEMA},"orientation":{{"type":"object","properties":{{"x":{{"type":"number"}},"y":{{"type":"number"}},"z":{{"type":"number"}},"w":{{"type":"number"}}}}}}}}}},"t_ns":{{"type":"integer"}},"tracking_state":{{"type":"integer"}},"velocity_world_m_s":{VEC3_SCHEMA}}}}}"#
    )
});

/// `foxglove.RawImage` with base64 `data`, as Foxglove reads it from JSON.
static IMAGE_JSON_SCHEMA: std::sync::LazyLock<String> = std::sync::LazyLock::new(|| {
    format!(
        r#"{{"type":"object","properties":{{"timestamp":{TIME_SCHEMA},"frame_id":{{"type":"string"}},"width":{{"type":"integer"}},"height":{{"type":"integer"}},"encoding":{{"type":"string"}},"step":{{"type":"integer"}},"data":{{"type":"string","contentEncoding":"base64"}}}}}}"#
    )
});

/// A pose as the recording keeps it (the published `rigslam/pose`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RecordedPose {
    /// Stamp of the frame the pose is for, ns (the clock the frames are stamped in).
    pub t_ns: i64,
    /// The wire code of the tracking state.
    pub tracking_state: u32,
    /// Body (IMU) position in the world frame, m.
    pub position_world_m: [f64; 3],
    /// Body-to-world rotation as a unit quaternion, x, y, z, w.
    pub orientation_world_body_xyzw: [f64; 4],
    /// Body velocity in the world frame, m/s.
    pub velocity_world_m_s: [f64; 3],
}

#[derive(serde::Serialize, serde::Deserialize)]
struct FoxgloveTime {
    sec: i64,
    nsec: i64,
}

impl FoxgloveTime {
    fn of(t_ns: i64) -> Self {
        Self {
            sec: t_ns.div_euclid(1_000_000_000),
            nsec: t_ns.rem_euclid(1_000_000_000),
        }
    }
}

#[derive(serde::Serialize, serde::Deserialize)]
struct Xyz {
    x: f64,
    y: f64,
    z: f64,
}

#[derive(serde::Serialize, serde::Deserialize)]
struct Xyzw {
    x: f64,
    y: f64,
    z: f64,
    w: f64,
}

#[derive(serde::Serialize, serde::Deserialize)]
struct PoseBody {
    position: Xyz,
    orientation: Xyzw,
}

#[derive(serde::Serialize, serde::Deserialize)]
struct PoseJson {
    timestamp: FoxgloveTime,
    frame_id: String,
    pose: PoseBody,
    t_ns: i64,
    tracking_state: u32,
    velocity_world_m_s: Xyz,
}

impl From<&RecordedPose> for PoseJson {
    fn from(p: &RecordedPose) -> Self {
        let [x, y, z] = p.position_world_m;
        let [qx, qy, qz, qw] = p.orientation_world_body_xyzw;
        let [vx, vy, vz] = p.velocity_world_m_s;
        Self {
            timestamp: FoxgloveTime::of(p.t_ns),
            frame_id: "world".into(),
            pose: PoseBody {
                position: Xyz { x, y, z },
                orientation: Xyzw {
                    x: qx,
                    y: qy,
                    z: qz,
                    w: qw,
                },
            },
            t_ns: p.t_ns,
            tracking_state: p.tracking_state,
            velocity_world_m_s: Xyz {
                x: vx,
                y: vy,
                z: vz,
            },
        }
    }
}

#[derive(serde::Serialize, serde::Deserialize)]
struct ImageJson {
    timestamp: FoxgloveTime,
    frame_id: String,
    width: u32,
    height: u32,
    encoding: String,
    step: u32,
    data: String,
}

/// Standard base64 (RFC 4648, with padding), as `foxglove.RawImage`
/// carries bytes in JSON.
fn base64_encode(bytes: &[u8]) -> String {
    const ALPHABET: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut out = String::with_capacity(bytes.len().div_ceil(3) * 4);
    for chunk in bytes.chunks(3) {
        let b = [
            chunk[0],
            *chunk.get(1).unwrap_or(&0),
            *chunk.get(2).unwrap_or(&0),
        ];
        let n = (u32::from(b[0]) << 16) | (u32::from(b[1]) << 8) | u32::from(b[2]);
        for i in 0..4 {
            if i <= chunk.len() {
                out.push(ALPHABET[(n >> (18 - 6 * i) & 63) as usize] as char);
            } else {
                out.push('=');
            }
        }
    }
    out
}

/// A channel registered in a [`McapRecorder`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ChannelId {
    id: u16,
}

/// Writes sensor streams into one MCAP file.
pub struct McapRecorder {
    path: PathBuf,
    writer: mcap::Writer<BufWriter<File>>,
    sequences: BTreeMap<u16, u32>,
    buf: Vec<u8>,
    approx_bytes: u64,
}

impl McapRecorder {
    /// Creates (or truncates) the MCAP file at `path`, without compression, ready for channels and
    /// messages.
    pub fn create(path: impl AsRef<Path>) -> Result<McapRecorder, RecordingError> {
        let path = path.as_ref().to_path_buf();
        let file = File::create(&path).map_err(|source| RecordingError::Create {
            path: path.clone(),
            source,
        })?;
        let writer = mcap::WriteOptions::new()
            .compression(None)
            .profile("")
            .create(BufWriter::new(file))
            .map_err(|source| RecordingError::Mcap {
                path: path.clone(),
                source,
            })?;
        Ok(McapRecorder {
            path,
            writer,
            sequences: BTreeMap::new(),
            buf: Vec::new(),
            approx_bytes: 0,
        })
    }

    fn mcap_err(&self) -> impl FnOnce(mcap::McapError) -> RecordingError {
        let path = self.path.clone();
        move |source| RecordingError::Mcap { path, source }
    }

    /// Registers an IMU stream on `topic` (e.g. `/imu0`), with the sensor's
    /// identity as channel metadata.
    pub fn add_imu_channel(
        &mut self,
        topic: &str,
        metadata: &BTreeMap<String, String>,
    ) -> Result<ChannelId, RecordingError> {
        let schema = self
            .writer
            .add_schema(IMU_SCHEMA_NAME, "jsonschema", IMU_JSON_SCHEMA.as_bytes())
            .map_err(self.mcap_err())?;
        let id = self
            .writer
            .add_channel(schema, topic, "json", metadata)
            .map_err(self.mcap_err())?;
        Ok(ChannelId { id })
    }

    /// Appends one IMU sample received at `receipt_t_ns`.
    pub fn write_imu(
        &mut self,
        channel: ChannelId,
        sample: &ImuSample,
        receipt_t_ns: i64,
    ) -> Result<(), RecordingError> {
        let message = ImuMessage {
            t_ns: sample.t_ns,
            gyro_rad_s: sample.gyro_rad_s,
            accel_m_s2: sample.accel_m_s2,
        };
        self.write_json(channel, sample.t_ns, receipt_t_ns, &message)
    }

    /// Registers a channel of JSON messages described by `json_schema`.
    pub fn add_json_channel(
        &mut self,
        topic: &str,
        schema_name: &str,
        json_schema: &str,
        metadata: &BTreeMap<String, String>,
    ) -> Result<ChannelId, RecordingError> {
        let schema = self
            .writer
            .add_schema(schema_name, "jsonschema", json_schema.as_bytes())
            .map_err(self.mcap_err())?;
        let id = self
            .writer
            .add_channel(schema, topic, "json", metadata)
            .map_err(self.mcap_err())?;
        Ok(ChannelId { id })
    }

    /// Registers a pose stream (Foxglove's `foxglove.PoseInFrame` JSON
    /// layout, plus the daemon's own fields).
    pub fn add_pose_channel(&mut self, topic: &str) -> Result<ChannelId, RecordingError> {
        self.add_json_channel(topic, POSE_SCHEMA_NAME, &POSE_JSON_SCHEMA, &BTreeMap::new())
    }

    /// Registers an image stream (Foxglove's `foxglove.RawImage`).
    pub fn add_image_channel(&mut self, topic: &str) -> Result<ChannelId, RecordingError> {
        self.add_json_channel(
            topic,
            IMAGE_SCHEMA_NAME,
            &IMAGE_JSON_SCHEMA,
            &BTreeMap::new(),
        )
    }

    fn write_json(
        &mut self,
        channel: ChannelId,
        log_time_ns: i64,
        publish_time_ns: i64,
        message: &impl serde::Serialize,
    ) -> Result<(), RecordingError> {
        self.buf.clear();
        serde_json::to_writer(&mut self.buf, message)
            .expect("serialising numbers and strings into a Vec cannot fail");
        let sequence = self.sequences.entry(channel.id).or_insert(0);
        *sequence += 1;
        let header = mcap::records::MessageHeader {
            channel_id: channel.id,
            sequence: *sequence,
            log_time: log_time_ns.max(0) as u64,
            publish_time: publish_time_ns.max(0) as u64,
        };
        self.writer
            .write_to_known_channel(&header, &self.buf)
            .map_err(self.mcap_err())?;
        // Message record: opcode, length, header fields, then the data.
        self.approx_bytes += 1 + 8 + 2 + 4 + 8 + 8 + self.buf.len() as u64;
        Ok(())
    }

    /// Appends one pose.
    pub fn write_pose(
        &mut self,
        channel: ChannelId,
        pose: &RecordedPose,
        receipt_t_ns: i64,
    ) -> Result<(), RecordingError> {
        self.write_json(channel, pose.t_ns, receipt_t_ns, &PoseJson::from(pose))
    }

    /// Appends one 8-bit grey image (other formats are converted to grey).
    pub fn write_image(
        &mut self,
        channel: ChannelId,
        t_ns: i64,
        image: &rigslam_drivers::Image,
        frame_id: &str,
        receipt_t_ns: i64,
    ) -> Result<(), RecordingError> {
        let (w, h) = (image.width(), image.height());
        let mut grey = Vec::with_capacity(w as usize * h as usize);
        for y in 0..h {
            for x in 0..w {
                grey.push(image.grey8_at(x, y).unwrap_or(0));
            }
        }
        let message = ImageJson {
            timestamp: FoxgloveTime::of(t_ns),
            frame_id: frame_id.to_string(),
            width: w,
            height: h,
            encoding: "mono8".into(),
            step: w,
            data: base64_encode(&grey),
        };
        self.write_json(channel, t_ns, receipt_t_ns, &message)
    }

    /// Adds a file (e.g. a calibration) to the recording as an MCAP
    /// attachment named `name`.
    pub fn attach(
        &mut self,
        name: &str,
        media_type: &str,
        data: &[u8],
    ) -> Result<(), RecordingError> {
        let attachment = mcap::Attachment {
            log_time: 0,
            create_time: 0,
            name: name.to_string(),
            media_type: media_type.to_string(),
            data: std::borrow::Cow::Borrowed(data),
        };
        self.writer.attach(&attachment).map_err(self.mcap_err())?;
        self.approx_bytes += data.len() as u64;
        Ok(())
    }

    /// Message bytes written so far (the file adds its index and summary).
    pub fn message_bytes(&self) -> u64 {
        self.approx_bytes
    }

    /// Writes the summary and closes the file.
    pub fn finish(mut self) -> Result<PathBuf, RecordingError> {
        self.writer.finish().map_err(self.mcap_err())?;
        Ok(self.path)
    }
}

/// Refuses a file whose length fields do not fit its bytes, before the
/// `mcap` crate trusts them (see `mcap_bounds.rs`).
fn check_bounds(bytes: &[u8], path: &Path) -> Result<(), RecordingError> {
    mcap_bounds::check(bytes).map_err(|(offset, reason)| RecordingError::Malformed {
        path: path.to_path_buf(),
        offset,
        reason,
    })
}

/// The whole file, naming it in the error.
fn read_bytes(path: &Path) -> Result<Vec<u8>, RecordingError> {
    std::fs::read(path).map_err(|source| RecordingError::Read {
        path: path.to_path_buf(),
        source,
    })
}

/// Reads back every IMU sample of `topic`, in file order.
pub fn read_imu_channel(path: &Path, topic: &str) -> Result<Vec<ImuSample>, RecordingError> {
    read_imu_channel_in(&read_bytes(path)?, path, topic)
}

/// [`read_imu_channel`] of a recording's bytes; `path` names it in errors.
pub fn read_imu_channel_in(
    bytes: &[u8],
    path: &Path,
    topic: &str,
) -> Result<Vec<ImuSample>, RecordingError> {
    read_channel(bytes, path, topic, |m: ImuMessage| ImuSample {
        t_ns: m.t_ns,
        gyro_rad_s: m.gyro_rad_s,
        accel_m_s2: m.accel_m_s2,
    })
}

fn read_channel<M: serde::de::DeserializeOwned, T>(
    bytes: &[u8],
    path: &Path,
    topic: &str,
    convert: impl Fn(M) -> T,
) -> Result<Vec<T>, RecordingError> {
    check_bounds(bytes, path)?;
    let mut out = Vec::new();
    let mut seen = false;
    let stream = mcap::MessageStream::new(bytes).map_err(|source| RecordingError::Mcap {
        path: path.to_path_buf(),
        source,
    })?;
    for message in stream {
        let message = message.map_err(|source| RecordingError::Mcap {
            path: path.to_path_buf(),
            source,
        })?;
        if message.channel.topic != topic {
            continue;
        }
        seen = true;
        let m: M =
            serde_json::from_slice(&message.data).map_err(|source| RecordingError::BadMessage {
                path: path.to_path_buf(),
                topic: topic.to_string(),
                sequence: message.sequence,
                source,
            })?;
        out.push(convert(m));
    }
    if !seen {
        return Err(RecordingError::NoChannel {
            path: path.to_path_buf(),
            topic: topic.to_string(),
        });
    }
    Ok(out)
}

/// Reads back every pose of `topic`, in file order.
pub fn read_pose_channel(path: &Path, topic: &str) -> Result<Vec<RecordedPose>, RecordingError> {
    read_pose_channel_in(&read_bytes(path)?, path, topic)
}

/// [`read_pose_channel`] of a recording's bytes; `path` names it in errors.
pub fn read_pose_channel_in(
    bytes: &[u8],
    path: &Path,
    topic: &str,
) -> Result<Vec<RecordedPose>, RecordingError> {
    read_channel(bytes, path, topic, |m: PoseJson| RecordedPose {
        t_ns: m.t_ns,
        tracking_state: m.tracking_state,
        position_world_m: [m.pose.position.x, m.pose.position.y, m.pose.position.z],
        orientation_world_body_xyzw: [
            m.pose.orientation.x,
            m.pose.orientation.y,
            m.pose.orientation.z,
            m.pose.orientation.w,
        ],
        velocity_world_m_s: [
            m.velocity_world_m_s.x,
            m.velocity_world_m_s.y,
            m.velocity_world_m_s.z,
        ],
    })
}

/// The attachments of a complete recording (from its summary), by name.
pub fn read_attachments(path: &Path) -> Result<BTreeMap<String, Vec<u8>>, RecordingError> {
    read_attachments_in(&read_bytes(path)?, path)
}

/// [`read_attachments`] of a recording's bytes; `path` names it in errors.
pub fn read_attachments_in(
    bytes: &[u8],
    path: &Path,
) -> Result<BTreeMap<String, Vec<u8>>, RecordingError> {
    check_bounds(bytes, path)?;
    let mcap_err = |source| RecordingError::Mcap {
        path: path.to_path_buf(),
        source,
    };
    let summary = mcap::Summary::read(bytes)
        .map_err(mcap_err)?
        .ok_or_else(|| RecordingError::NoSummary {
            path: path.to_path_buf(),
        })?;
    let mut out = BTreeMap::new();
    for index in &summary.attachment_indexes {
        mcap_bounds::check_attachment(bytes, index.offset, index.length).map_err(
            |(offset, reason)| RecordingError::Malformed {
                path: path.to_path_buf(),
                offset,
                reason,
            },
        )?;
        let a = mcap::read::attachment(bytes, index).map_err(mcap_err)?;
        out.insert(a.name, a.data.into_owned());
    }
    Ok(out)
}

/// The topics of a recording and their message counts (from its summary,
/// so only a completely written file answers).
pub fn channel_counts(path: &Path) -> Result<BTreeMap<String, u64>, RecordingError> {
    channel_counts_in(&read_bytes(path)?, path)
}

/// [`channel_counts`] of a recording's bytes; `path` names it in errors.
pub fn channel_counts_in(
    bytes: &[u8],
    path: &Path,
) -> Result<BTreeMap<String, u64>, RecordingError> {
    check_bounds(bytes, path)?;
    let summary = mcap::Summary::read(bytes)
        .map_err(|source| RecordingError::Mcap {
            path: path.to_path_buf(),
            source,
        })?
        .ok_or_else(|| RecordingError::NoSummary {
            path: path.to_path_buf(),
        })?;
    let stats = summary.stats.ok_or_else(|| RecordingError::NoSummary {
        path: path.to_path_buf(),
    })?;
    let mut counts = BTreeMap::new();
    for (id, channel) in &summary.channels {
        let n = stats.channel_message_counts.get(id).copied().unwrap_or(0);
        counts.insert(channel.topic.clone(), n);
    }
    Ok(counts)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    #[test]
    fn imu_samples_replay_bit_for_bit() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("imu.mcap");
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let samples: Vec<ImuSample> = (0..500)
            .map(|k| ImuSample {
                t_ns: 1_000_000_000 + k * 2_500_000,
                // Arbitrary doubles, including ones with 17 significant digits.
                gyro_rad_s: [
                    rng.gen::<f64>() - 0.5,
                    rng.gen_range(-1e-9..1e-9),
                    1.0 / 3.0,
                ],
                accel_m_s2: [
                    rng.gen_range(-50.0..50.0),
                    9.806_65 * 0.1,
                    -rng.gen::<f64>() * 1e3,
                ],
            })
            .collect();
        let mut rec = McapRecorder::create(&path).expect("create");
        let meta = BTreeMap::from([("serial".to_string(), "12345678".to_string())]);
        let imu = rec.add_imu_channel("/imu0", &meta).expect("channel");
        let other = rec
            .add_imu_channel("/imu1", &BTreeMap::new())
            .expect("channel");
        for s in &samples {
            rec.write_imu(imu, s, s.t_ns + 1000).expect("write");
        }
        rec.write_imu(other, &samples[0], 0).expect("write");
        rec.finish().expect("finish");
        let back = read_imu_channel(&path, "/imu0").expect("read");
        assert_eq!(back.len(), samples.len());
        for (a, b) in back.iter().zip(&samples) {
            assert_eq!(a.t_ns, b.t_ns);
            for i in 0..3 {
                assert_eq!(a.gyro_rad_s[i].to_bits(), b.gyro_rad_s[i].to_bits());
                assert_eq!(a.accel_m_s2[i].to_bits(), b.accel_m_s2[i].to_bits());
            }
        }
        assert_eq!(read_imu_channel(&path, "/imu1").expect("read").len(), 1);
        let err = read_imu_channel(&path, "/cam0").unwrap_err();
        assert!(err.to_string().contains("no channel /cam0"), "{err}");
    }
}
