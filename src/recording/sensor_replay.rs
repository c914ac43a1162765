//! The sensor streams of a recording read back as the daemon's replay
//! wants them: IMU samples and (stereo) frames in file order, which is the
//! order the recorder received them in, so a replayed recording goes
//! through the pipeline as the live run did.

use std::ops::ControlFlow;
use std::path::Path;

use rigslam_drivers::{Frame, Image};

use super::json_v1::RawFrame;
use super::reader::{self, Item, MessageView, WalkReport};
use super::RecordingError;
use crate::dataset::euroc::sensor_yaml::{camera_yaml, imu_yaml};
use crate::dataset::SensorEvent;
use crate::relative::{RigModel, SensorMode};
use crate::rig::folder::CalibrationFile;

/// Which streams to read.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SensorTopics {
    /// `/cam1` paired with `/cam0` by stamp (else `/cam1` is skipped).
    pub stereo: bool,
    /// `/imu0` (else skipped).
    pub imu: bool,
}

/// Whether `path` names an MCAP recording (by its extension) rather than
/// a dataset folder.
pub fn is_mcap(path: &Path) -> bool {
    path.extension()
        .is_some_and(|x| x.eq_ignore_ascii_case("mcap"))
}

/// The name under which a recording carries a sensor's calibration file
/// (`cam0.yaml` -> `calibration/cam0.yaml`). The recorder attaches the
/// rig's files to every file it writes, one EuRoC-layout `sensor.yaml` per
/// camera the mode uses and the IMU's when the mode uses it, so that a
/// recording replays without the files it was made with. The daemon
/// attaches the original files' bytes (the replay then reads the same
/// numbers); [`calibration_attachments`] is the fallback.
pub fn calibration_attachment_name(file: &str) -> String {
    format!("{CALIBRATION_PREFIX}{file}")
}

/// The rig's calibration written out again, for a rig whose files are
/// not at hand (a KITTI replay). Not bit-exact: orientations go through a
/// quaternion and back, so a replay of such a recording is close to the
/// original run but not equal to the bit.
pub fn calibration_attachments(rig: &RigModel, mode: SensorMode) -> super::Attachments {
    let cameras = if mode.uses_stereo() { 2 } else { 1 };
    let mut out: super::Attachments = rig
        .cameras
        .iter()
        .take(cameras)
        .enumerate()
        .map(|(i, c)| {
            let name = format!("cam{i}");
            (
                format!("{CALIBRATION_PREFIX}{name}.yaml"),
                camera_yaml(&name, c).into_bytes(),
            )
        })
        .collect();
    if let (Some(imu), true) = (&rig.imu, mode.uses_imu()) {
        out.push((
            format!("{CALIBRATION_PREFIX}imu0.yaml"),
            imu_yaml(imu).into_bytes(),
        ));
        if !imu.intrinsics.is_identity() {
            out.push((
                format!("{CALIBRATION_PREFIX}{}", crate::rig::folder::IMU_INTRINSICS),
                crate::rig::imu_intrinsics_file::intrinsics_yaml(&imu.intrinsics).into_bytes(),
            ));
        }
    }
    out
}

const CALIBRATION_PREFIX: &str = "calibration/";

/// The rig a recording was made with, from its calibration attachments;
/// `None` when it has none (a recording made without them).
pub fn rig_of_recording(path: &Path) -> Result<Option<RigModel>, RecordingError> {
    rig_of_recording_in(&super::read_bytes(path)?, path)
}

/// [`rig_of_recording`] of a recording's bytes; `path` names it in errors.
pub fn rig_of_recording_in(bytes: &[u8], path: &Path) -> Result<Option<RigModel>, RecordingError> {
    let attachments = super::read_attachments_in(bytes, path)?;
    // Errors name an attachment as if it were a file in the recording.
    let files: Vec<CalibrationFile> = attachments
        .iter()
        .filter_map(|(key, bytes)| {
            let name = key.strip_prefix(CALIBRATION_PREFIX)?;
            Some(CalibrationFile {
                name: name.to_owned(),
                origin: path.join(key),
                bytes: bytes.clone(),
            })
        })
        .collect();
    if files.is_empty() {
        return Ok(None);
    }
    let rig = crate::rig::folder::rig_from_files(&files, &path.join(CALIBRATION_PREFIX), false)
        .map_err(|e| RecordingError::BadAttachment {
            path: path.to_path_buf(),
            name: CALIBRATION_PREFIX.trim_end_matches('/').to_owned(),
            reason: e.to_string(),
        })?;
    Ok(Some(rig))
}

/// What a replay reads from a recording, in file order.
#[derive(Debug)]
pub enum ReplayItem {
    /// A decoded IMU sample or frame.
    Event(SensorEvent),
    /// A sensor message the replay leaves out (the robot's data may be
    /// damaged; the rest of the file still plays).
    Skipped(SkippedMessage),
}

/// A sensor message left out of a replay, and why.
#[derive(Debug)]
pub enum SkippedMessage {
    /// Its bytes do not decode (the error names the file, topic and
    /// sequence number).
    Unreadable {
        /// Whether the message was an image (else an IMU sample).
        image: bool,
        /// What failed to decode.
        error: RecordingError,
    },
    /// A stereo half whose partner is missing or has another stamp.
    Unpaired {
        /// Topic of the half that has no partner.
        topic: String,
        /// Its sequence number on that channel.
        sequence: u32,
        /// Its stamp, ns.
        t_ns: i64,
    },
}

impl SkippedMessage {
    /// An image (else an IMU sample).
    pub fn is_image(&self) -> bool {
        match self {
            SkippedMessage::Unreadable { image, .. } => *image,
            SkippedMessage::Unpaired { .. } => true,
        }
    }
}

impl std::fmt::Display for SkippedMessage {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            SkippedMessage::Unreadable { error, .. } => write!(f, "{error}"),
            SkippedMessage::Unpaired {
                topic,
                sequence,
                t_ns,
            } => write!(
                f,
                "message {sequence} on {topic} (t = {t_ns} ns) has no stereo partner with its stamp"
            ),
        }
    }
}

/// How a replay of a recording ended.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ReplayEnd {
    /// IMU samples and frames handed over.
    pub events: u64,
    /// How far the file could be read, and what was skipped.
    pub file: WalkReport,
}

/// Calls `f` with every IMU sample and frame of the recording at `path`,
/// in file order, until the file ends or `f` breaks. A message that does
/// not decode, and a stereo half without its partner, reach `f` as
/// [`ReplayItem::Skipped`] and the replay goes on. A file cut short plays
/// as far as its bytes go and a damaged chunk is skipped: the returned
/// [`ReplayEnd`] says so. An error is returned only when the file is not
/// an MCAP file at all or cannot be read.
///
/// The file is read into memory whole (the recorder rotates its files at
/// `rotate_mib`, 256 MiB by default).
pub fn for_each_sensor_event(
    path: &Path,
    topics: SensorTopics,
    f: impl FnMut(ReplayItem) -> ControlFlow<()>,
) -> Result<ReplayEnd, RecordingError> {
    for_each_sensor_event_in(&super::read_bytes(path)?, path, topics, f)
}

/// [`for_each_sensor_event`] over a recording's bytes; `path` names it in
/// errors.
pub fn for_each_sensor_event_in(
    bytes: &[u8],
    path: &Path,
    topics: SensorTopics,
    mut f: impl FnMut(ReplayItem) -> ControlFlow<()>,
) -> Result<ReplayEnd, RecordingError> {
    // The left image waiting for its right one: (frame, sequence, topic).
    let mut left: Option<(Frame, u32, String)> = None;
    let mut count = 0u64;
    let unpaired = |topic: &str, frame: Frame, sequence: u32| {
        ReplayItem::Skipped(SkippedMessage::Unpaired {
            topic: topic.to_string(),
            sequence,
            t_ns: frame.t_ns,
        })
    };
    let file = reader::walk(bytes, path, |item| {
        let Item::Message(message) = item else {
            return ControlFlow::Continue(());
        };
        let topic = message.channel.topic.as_str();
        let unreadable = |image, reason| {
            Some(ReplayItem::Skipped(SkippedMessage::Unreadable {
                image,
                error: RecordingError::BadMessage {
                    path: path.to_path_buf(),
                    topic: topic.to_string(),
                    sequence: message.sequence,
                    reason,
                },
            }))
        };
        let mut items: [Option<ReplayItem>; 2] = [None, None];
        match (topic, camera_of_topic(topic)) {
            ("/imu0", _) if topics.imu => {
                items[0] = match super::decode_imu(&message) {
                    Ok(s) => Some(ReplayItem::Event(SensorEvent::Imu(s))),
                    Err(e) => unreadable(false, e),
                };
            }
            (_, Some(index)) if index == 0 || topics.stereo => {
                let frame = match decode_image(&message).and_then(|m| decode_frame(m, index)) {
                    Ok(frame) => frame,
                    Err(reason) => {
                        items[0] = unreadable(true, reason);
                        // A right image that does not decode leaves its
                        // left one waiting (counted when the next left
                        // one replaces it).
                        return emit(&mut f, items, &mut count);
                    }
                };
                match (index, topics.stereo) {
                    (0, false) => {
                        items[0] = Some(ReplayItem::Event(SensorEvent::Frame {
                            t_ns: frame.t_ns,
                            left: frame,
                            right: None,
                        }))
                    }
                    (0, true) => {
                        items[0] = left.take().map(|(l, seq, t)| unpaired(&t, l, seq));
                        left = Some((frame, message.sequence, topic.to_owned()));
                    }
                    (_, true) => {
                        items[0] = match left.take() {
                            Some((l, _, _)) if l.t_ns == frame.t_ns => {
                                Some(ReplayItem::Event(SensorEvent::Frame {
                                    t_ns: l.t_ns,
                                    left: l,
                                    right: Some(frame),
                                }))
                            }
                            Some((l, seq, t)) => {
                                items[1] = Some(unpaired(topic, frame, message.sequence));
                                Some(unpaired(&t, l, seq))
                            }
                            None => Some(unpaired(topic, frame, message.sequence)),
                        }
                    }
                    _ => {}
                }
            }
            _ => {}
        }
        emit(&mut f, items, &mut count)
    })?;
    if let Some((l, seq, t)) = left.take() {
        let _ = emit(&mut f, [Some(unpaired(&t, l, seq)), None], &mut count);
    }
    Ok(ReplayEnd {
        events: count,
        file,
    })
}

/// The topics a camera's images are on: `/camN` in rigslam's own
/// recordings, `/camN/image_raw` in ROS 2 ones.
pub const CAMERA_TOPICS: [[&str; 2]; 2] =
    [["/cam0", "/cam0/image_raw"], ["/cam1", "/cam1/image_raw"]];

/// The camera whose images `topic` carries.
fn camera_of_topic(topic: &str) -> Option<u8> {
    CAMERA_TOPICS
        .iter()
        .position(|names| names.contains(&topic))
        .map(|i| i as u8)
}

/// An image message of any layout rigslam writes (`foxglove.RawImage` in
/// protobuf, ROS 2's `sensor_msgs/msg/Image`, or the older JSON).
fn decode_image(m: &MessageView<'_>) -> Result<RawFrame, String> {
    match m.channel.message_encoding.as_str() {
        super::ros2::messages::MESSAGE_ENCODING => {
            super::expect_schema(m, super::ros2::messages::IMAGE.name)?;
            let image = super::ros2::messages::Image::decode(m.data)?;
            Ok(RawFrame {
                t_ns: image.header.stamp.ns(),
                width: image.width,
                height: image.height,
                step: image.step,
                encoding: image.encoding,
                data: image.data,
            })
        }
        "protobuf" => {
            let image: foxglove::messages::RawImage =
                prost::Message::decode(m.data).map_err(|e| e.to_string())?;
            Ok(RawFrame {
                t_ns: image
                    .timestamp
                    .as_ref()
                    .map(super::schemas::timestamp_ns)
                    .ok_or("the image has no timestamp")?,
                width: image.width,
                height: image.height,
                step: image.step,
                encoding: image.encoding,
                data: image.data.to_vec(),
            })
        }
        "json" => super::json_v1::image(m.data),
        other => Err(format!(
            "message encoding {other:?} is not one rigslam wrote"
        )),
    }
}

/// Hands `items` to `f` in order, counting events; stops when `f` breaks.
fn emit(
    f: &mut impl FnMut(ReplayItem) -> ControlFlow<()>,
    items: [Option<ReplayItem>; 2],
    count: &mut u64,
) -> ControlFlow<()> {
    for item in items.into_iter().flatten() {
        if matches!(item, ReplayItem::Event(_)) {
            *count += 1;
        }
        f(item)?;
    }
    ControlFlow::Continue(())
}

/// A frame from an 8-bit grey image (what the recorder writes).
fn decode_frame(m: RawFrame, camera_index: u8) -> Result<Frame, String> {
    if m.encoding != "mono8" {
        return Err(format!("encoding {:?}: only mono8 is replayed", m.encoding));
    }
    let (w, h, step) = (m.width as usize, m.height as usize, m.step as usize);
    if step < w || m.data.len() < step * h {
        return Err(format!(
            "{} bytes for {}x{} with step {}",
            m.data.len(),
            m.width,
            m.height,
            m.step
        ));
    }
    let image = Image::new(
        m.width,
        m.height,
        step,
        rigslam_drivers::PixelFormat::Mono8,
        m.data.into(),
    )
    .map_err(|e| e.to_string())?;
    Ok(Frame {
        t_ns: m.t_ns,
        seq: 0,
        camera_index,
        image,
    })
}
