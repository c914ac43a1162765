//! Recordings of live sensor streams as MCAP files: one channel per
//! sensor stream, replayable bit for bit, opened by Foxglove and the MCAP
//! tools.
//!
//! Messages are protobuf: Foxglove's schemas where one fits (images,
//! poses for the 3D panel, transforms, camera calibrations) and the
//! `rigslam.*` ones of [`schemas`] otherwise (IMU samples, pose estimates
//! with covariance and both frames, status). Chunks are compressed (zstd by
//! default). [`writer`] says how times are kept. Older files, whose
//! messages are JSON, are still read. With [`Format::Ros2`] the files
//! hold ROS 2 messages instead ([`ros2`]), for `ros2 bag play`; the
//! replay reads their images and IMU samples too.
//!
//! Reading ([`reader`]) goes record by record and recovers what a file
//! cut short or damaged still holds.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use rigslam_drivers::ImuSample;
use thiserror::Error;

mod json_v1;
mod mcap_bounds;
pub mod reader;
pub mod repair;
pub mod ros2;
pub mod schemas;
mod sensor_replay;
pub mod writer;
pub use reader::{FileEnd, WalkReport};
pub use schemas::{IMU_SCHEMA_NAME, POSE_SCHEMA_NAME};
pub use writer::{ChannelId, ClockMapping, Compression, Format, McapRecorder};
/// Files carried in a recording: (attachment name, bytes).
pub type Attachments = Vec<(String, Vec<u8>)>;
pub use sensor_replay::{
    calibration_attachment_name, calibration_attachments, for_each_sensor_event,
    for_each_sensor_event_in, is_mcap, rig_of_recording, rig_of_recording_in, ReplayEnd,
    ReplayItem, SensorTopics, SkippedMessage, CAMERA_TOPICS,
};

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
    #[error("{path}: message {sequence} on {topic} does not have the channel's layout: {reason}")]
    /// A message does not decode as its channel's schema says.
    BadMessage {
        /// The file.
        path: PathBuf,
        /// The channel's topic.
        topic: String,
        /// The message's sequence number on its channel.
        sequence: u32,
        /// The decoder's error.
        reason: String,
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
    #[error("{path}: a message cannot be encoded: {reason}")]
    /// A message that cannot be written (a string or sequence longer than
    /// its encoding allows).
    Encode {
        /// The file.
        path: PathBuf,
        /// Why.
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

/// A pose as the recording keeps it: everything the published
/// `rigslam/pose` carries but the publisher's own fields (sequence,
/// publish time).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RecordedPose {
    /// Stamp of the frame the pose is for, ns (the clock the frames are stamped in).
    pub t_ns: i64,
    /// The wire code of the tracking state.
    pub tracking_state: u32,
    /// `POSE_FLAG_*` bits.
    pub flags: u32,
    /// Body (IMU) position in the world (map) frame, m.
    pub position_world_m: [f64; 3],
    /// Body-to-world rotation as a unit quaternion, x, y, z, w.
    pub orientation_world_body_xyzw: [f64; 4],
    /// Body velocity in the world frame, m/s.
    pub velocity_world_m_s: [f64; 3],
    /// 6x6 covariance of (position, rotation vector), row-major (NaN
    /// when the pose has none).
    pub covariance: [f64; 36],
    /// Body position in the odometry frame, m.
    pub position_odom_m: [f64; 3],
    /// `R_odom_body` as x, y, z, w.
    pub orientation_odom_body_xyzw: [f64; 4],
    /// Translation of `T_world_odom`, m.
    pub translation_world_odom_m: [f64; 3],
    /// Rotation of `T_world_odom` as x, y, z, w.
    pub rotation_world_odom_xyzw: [f64; 4],
}

impl RecordedPose {
    /// A pose with only the map frame known (odometry frame = map frame,
    /// no covariance), as files before the protobuf layout kept them.
    pub fn map_only(
        t_ns: i64,
        tracking_state: u32,
        position_world_m: [f64; 3],
        orientation_world_body_xyzw: [f64; 4],
        velocity_world_m_s: [f64; 3],
    ) -> Self {
        Self {
            t_ns,
            tracking_state,
            flags: 0,
            position_world_m,
            orientation_world_body_xyzw,
            velocity_world_m_s,
            covariance: [f64::NAN; 36],
            position_odom_m: position_world_m,
            orientation_odom_body_xyzw: orientation_world_body_xyzw,
            translation_world_odom_m: [0.0; 3],
            rotation_world_odom_xyzw: [0.0, 0.0, 0.0, 1.0],
        }
    }
}

impl From<&RecordedPose> for schemas::PoseEstimateProto {
    fn from(p: &RecordedPose) -> Self {
        Self {
            t_ns: p.t_ns,
            tracking_state: p.tracking_state,
            flags: p.flags,
            position_world_m: p.position_world_m.to_vec(),
            orientation_world_body_xyzw: p.orientation_world_body_xyzw.to_vec(),
            velocity_world_m_s: p.velocity_world_m_s.to_vec(),
            covariance: if p.covariance.iter().all(|c| c.is_nan()) {
                Vec::new()
            } else {
                p.covariance.to_vec()
            },
            position_odom_m: p.position_odom_m.to_vec(),
            orientation_odom_body_xyzw: p.orientation_odom_body_xyzw.to_vec(),
            translation_world_odom_m: p.translation_world_odom_m.to_vec(),
            rotation_world_odom_xyzw: p.rotation_world_odom_xyzw.to_vec(),
        }
    }
}

/// `N` numbers from a repeated field that must have exactly that many.
fn fixed<const N: usize>(values: &[f64], field: &str) -> Result<[f64; N], String> {
    values
        .try_into()
        .map_err(|_| format!("{field} has {} numbers, not {N}", values.len()))
}

impl TryFrom<schemas::PoseEstimateProto> for RecordedPose {
    type Error = String;

    fn try_from(m: schemas::PoseEstimateProto) -> Result<Self, String> {
        Ok(Self {
            t_ns: m.t_ns,
            tracking_state: m.tracking_state,
            flags: m.flags,
            position_world_m: fixed(&m.position_world_m, "position_world_m")?,
            orientation_world_body_xyzw: fixed(
                &m.orientation_world_body_xyzw,
                "orientation_world_body_xyzw",
            )?,
            velocity_world_m_s: fixed(&m.velocity_world_m_s, "velocity_world_m_s")?,
            covariance: if m.covariance.is_empty() {
                [f64::NAN; 36]
            } else {
                fixed(&m.covariance, "covariance")?
            },
            position_odom_m: fixed(&m.position_odom_m, "position_odom_m")?,
            orientation_odom_body_xyzw: fixed(
                &m.orientation_odom_body_xyzw,
                "orientation_odom_body_xyzw",
            )?,
            translation_world_odom_m: fixed(
                &m.translation_world_odom_m,
                "translation_world_odom_m",
            )?,
            rotation_world_odom_xyzw: fixed(
                &m.rotation_world_odom_xyzw,
                "rotation_world_odom_xyzw",
            )?,
        })
    }
}

/// An IMU sample from its protobuf message.
fn imu_of(m: schemas::ImuSampleProto) -> Result<ImuSample, String> {
    Ok(ImuSample {
        t_ns: m.t_ns,
        gyro_rad_s: fixed(&m.gyro_rad_s, "gyro_rad_s")?,
        accel_m_s2: fixed(&m.accel_m_s2, "accel_m_s2")?,
    })
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
    read_channel(bytes, path, topic, decode_imu)
}

/// A message's schema must be `name` (a ROS 2 message of another type
/// would decode into nonsense, or fail further in).
pub(crate) fn expect_schema(m: &reader::MessageView<'_>, name: &str) -> Result<(), String> {
    if m.channel.schema_name == name {
        Ok(())
    } else {
        Err(format!("schema {:?}, not {name:?}", m.channel.schema_name))
    }
}

/// An IMU sample from a message of any layout rigslam writes (protobuf,
/// ROS 2's `sensor_msgs/msg/Imu`, or the older JSON).
pub(crate) fn decode_imu(m: &reader::MessageView<'_>) -> Result<ImuSample, String> {
    match m.channel.message_encoding.as_str() {
        "protobuf" => imu_of(prost::Message::decode(m.data).map_err(|e| e.to_string())?),
        ros2::messages::MESSAGE_ENCODING => {
            expect_schema(m, ros2::messages::IMU.name)?;
            let imu = ros2::messages::Imu::decode(m.data)?;
            Ok(ImuSample {
                t_ns: imu.header.stamp.ns(),
                gyro_rad_s: imu.angular_velocity,
                accel_m_s2: imu.linear_acceleration,
            })
        }
        "json" => json_v1::imu(m.data),
        other => Err(format!(
            "message encoding {other:?} is not one rigslam wrote"
        )),
    }
}

/// A pose from a message of either layout.
pub(crate) fn decode_pose(m: &reader::MessageView<'_>) -> Result<RecordedPose, String> {
    match m.channel.message_encoding.as_str() {
        "protobuf" => {
            let message: schemas::PoseEstimateProto =
                prost::Message::decode(m.data).map_err(|e| e.to_string())?;
            RecordedPose::try_from(message)
        }
        "json" => json_v1::pose(m.data),
        ros2::messages::MESSAGE_ENCODING => Err(
            "a ROS 2 message: poses are read back from rigslam.PoseEstimate channels \
             (format = \"foxglove\" recordings) only"
                .to_owned(),
        ),
        other => Err(format!(
            "message encoding {other:?} is not one rigslam wrote"
        )),
    }
}

/// Every message of `topic` decoded with `decode`, in file order. A file
/// cut short gives what it holds; a message that does not decode fails
/// the read, naming it.
fn read_channel<T>(
    bytes: &[u8],
    path: &Path,
    topic: &str,
    decode: impl Fn(&reader::MessageView<'_>) -> Result<T, String>,
) -> Result<Vec<T>, RecordingError> {
    let mut out = Vec::new();
    let mut seen = false;
    let mut error = None;
    let walked = reader::walk(bytes, path, |item| {
        match item {
            reader::Item::Channel(c) if c.topic == topic => seen = true,
            reader::Item::Message(m) if m.channel.topic == topic => match decode(&m) {
                Ok(v) => out.push(v),
                Err(reason) => {
                    error = Some(RecordingError::BadMessage {
                        path: path.to_path_buf(),
                        topic: topic.to_owned(),
                        sequence: m.sequence,
                        reason,
                    });
                    return std::ops::ControlFlow::Break(());
                }
            },
            _ => {}
        }
        std::ops::ControlFlow::Continue(())
    })?;
    if let Some(e) = error {
        return Err(e);
    }
    // A whole channel is asked for: a damaged record may have held some
    // of it (a replay, which plays on, says so instead).
    if let Some(skipped) = walked.skipped.first() {
        return Err(RecordingError::Malformed {
            path: path.to_path_buf(),
            offset: skipped.at,
            reason: skipped.reason.clone(),
        });
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
    read_channel(bytes, path, topic, decode_pose)
}

/// The attachments of a recording, by name: from its summary when it was
/// closed, else read from the start (a file cut short keeps them: the
/// recorder writes them first).
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
    // A file without a readable summary (cut short): every attachment
    // from the start.
    let summary = mcap::Summary::read(bytes).ok().flatten();
    let Some(summary) = summary else {
        let mut out = BTreeMap::new();
        reader::walk(bytes, path, |item| {
            if let reader::Item::Attachment { name, data, .. } = item {
                out.insert(name.to_owned(), data.to_vec());
            }
            std::ops::ControlFlow::Continue(())
        })?;
        return Ok(out);
    };
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

/// The topics of a recording and the messages it holds on each, read
/// from the start: also for a file that was cut short (the report says
/// where it ends) or has a damaged chunk (the report names it).
pub fn message_counts(path: &Path) -> Result<(BTreeMap<String, u64>, WalkReport), RecordingError> {
    let bytes = read_bytes(path)?;
    let mut counts = BTreeMap::new();
    let report = reader::walk(&bytes, path, |item| {
        match item {
            reader::Item::Channel(c) => {
                counts.entry(c.topic.clone()).or_insert(0);
            }
            reader::Item::Message(m) => *counts.entry(m.channel.topic.clone()).or_insert(0) += 1,
            _ => {}
        }
        std::ops::ControlFlow::Continue(())
    })?;
    Ok((counts, report))
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

/// The image as 8-bit grey rows without padding.
pub(crate) fn grey_bytes(image: &rigslam_drivers::Image) -> Vec<u8> {
    let (w, h) = (image.width(), image.height());
    if image.format() == rigslam_drivers::PixelFormat::Mono8 {
        let stride = image.stride_bytes();
        let data = image.data();
        let mut grey = Vec::with_capacity(w as usize * h as usize);
        for row in 0..h as usize {
            grey.extend_from_slice(&data[row * stride..row * stride + w as usize]);
        }
        return grey;
    }
    let mut grey = Vec::with_capacity(w as usize * h as usize);
    for y in 0..h {
        for x in 0..w {
            grey.push(image.grey8_at(x, y).unwrap_or(0));
        }
    }
    grey
}

#[cfg(test)]
mod tests;
