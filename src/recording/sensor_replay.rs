//! The sensor streams of a recording read back as the daemon's replay
//! wants them: IMU samples and (stereo) frames in file order, which is the
//! order the recorder received them in, so a replayed recording goes
//! through the pipeline as the live run did.

use std::ops::ControlFlow;
use std::path::Path;

use rigslam_drivers::{Frame, Image, ImuSample};

use super::{ImageJson, ImuMessage, RecordingError};
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

/// Calls `f` with every IMU sample and frame of the recording at `path`,
/// in file order, until the file ends or `f` breaks. A message that does
/// not decode, and a stereo half without its partner, reach `f` as
/// [`ReplayItem::Skipped`] and the replay goes on; an error is returned
/// only when the file itself cannot be read on. Returns the number of
/// events handed over.
///
/// The file is read into memory whole (the recorder rotates its files at
/// `rotate_mib`, 256 MiB by default).
pub fn for_each_sensor_event(
    path: &Path,
    topics: SensorTopics,
    f: impl FnMut(ReplayItem) -> ControlFlow<()>,
) -> Result<u64, RecordingError> {
    for_each_sensor_event_in(&super::read_bytes(path)?, path, topics, f)
}

/// [`for_each_sensor_event`] over a recording's bytes; `path` names it in
/// errors.
pub fn for_each_sensor_event_in(
    bytes: &[u8],
    path: &Path,
    topics: SensorTopics,
    mut f: impl FnMut(ReplayItem) -> ControlFlow<()>,
) -> Result<u64, RecordingError> {
    let mcap_err = |source| RecordingError::Mcap {
        path: path.to_path_buf(),
        source,
    };
    super::check_bounds(bytes, path)?;
    let stream = mcap::MessageStream::new(bytes).map_err(mcap_err)?;
    // The left image waiting for its right one: (frame, sequence).
    let mut left: Option<(Frame, u32)> = None;
    let mut count = 0u64;
    let unpaired = |topic: &str, (frame, sequence): (Frame, u32)| {
        ReplayItem::Skipped(SkippedMessage::Unpaired {
            topic: topic.to_string(),
            sequence,
            t_ns: frame.t_ns,
        })
    };
    for message in stream {
        let message = message.map_err(mcap_err)?;
        let topic = message.channel.topic.as_str();
        let bad = |source| RecordingError::BadMessage {
            path: path.to_path_buf(),
            topic: topic.to_string(),
            sequence: message.sequence,
            source,
        };
        let unreadable = |image, error| {
            Some(ReplayItem::Skipped(SkippedMessage::Unreadable {
                image,
                error,
            }))
        };
        let mut items: [Option<ReplayItem>; 2] = [None, None];
        match topic {
            "/imu0" if topics.imu => {
                items[0] = match serde_json::from_slice::<ImuMessage>(&message.data) {
                    Ok(m) => Some(ReplayItem::Event(SensorEvent::Imu(ImuSample {
                        t_ns: m.t_ns,
                        gyro_rad_s: m.gyro_rad_s,
                        accel_m_s2: m.accel_m_s2,
                    }))),
                    Err(e) => unreadable(false, bad(e)),
                };
            }
            "/cam0" | "/cam1" if topic == "/cam0" || topics.stereo => {
                let index = u8::from(topic == "/cam1");
                let frame = serde_json::from_slice::<ImageJson>(&message.data)
                    .map_err(bad)
                    .and_then(|m| {
                        decode_frame(&m, index).map_err(|reason| RecordingError::BadImage {
                            path: path.to_path_buf(),
                            topic: topic.to_string(),
                            sequence: message.sequence,
                            reason,
                        })
                    });
                let frame = match frame {
                    Ok(frame) => frame,
                    Err(error) => {
                        items[0] = unreadable(true, error);
                        // A right image that does not decode leaves its
                        // left one waiting (counted when the next left
                        // one replaces it).
                        if emit(&mut f, items, &mut count).is_break() {
                            return Ok(count);
                        }
                        continue;
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
                        items[0] = left.take().map(|l| unpaired("/cam0", l));
                        left = Some((frame, message.sequence));
                    }
                    (_, true) => {
                        items[0] = match left.take() {
                            Some((l, _)) if l.t_ns == frame.t_ns => {
                                Some(ReplayItem::Event(SensorEvent::Frame {
                                    t_ns: l.t_ns,
                                    left: l,
                                    right: Some(frame),
                                }))
                            }
                            Some(l) => {
                                items[1] = Some(unpaired("/cam1", (frame, message.sequence)));
                                Some(unpaired("/cam0", l))
                            }
                            None => Some(unpaired("/cam1", (frame, message.sequence))),
                        }
                    }
                    _ => {}
                }
            }
            _ => {}
        }
        if emit(&mut f, items, &mut count).is_break() {
            return Ok(count);
        }
    }
    if let Some(l) = left.take() {
        let _ = emit(&mut f, [Some(unpaired("/cam0", l)), None], &mut count);
    }
    Ok(count)
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

/// A `foxglove.RawImage` as the recorder writes it (mono8, base64).
fn decode_frame(m: &ImageJson, camera_index: u8) -> Result<Frame, String> {
    if m.encoding != "mono8" {
        return Err(format!("encoding {:?}: only mono8 is replayed", m.encoding));
    }
    let data = base64_decode(&m.data)?;
    let (w, h, step) = (m.width as usize, m.height as usize, m.step as usize);
    if step < w || data.len() < step * h {
        return Err(format!(
            "{} bytes for {}x{} with step {}",
            data.len(),
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
        data.into(),
    )
    .map_err(|e| e.to_string())?;
    let t_ns = m
        .timestamp
        .sec
        .checked_mul(1_000_000_000)
        .and_then(|s| s.checked_add(m.timestamp.nsec))
        .ok_or_else(|| {
            format!(
                "timestamp {}.{} s is out of range",
                m.timestamp.sec, m.timestamp.nsec
            )
        })?;
    Ok(Frame {
        t_ns,
        seq: 0,
        camera_index,
        image,
    })
}

/// Standard base64 with padding (what [`super::base64_encode`] writes).
fn base64_decode(text: &str) -> Result<Vec<u8>, String> {
    let value = |c: u8| -> Result<u32, String> {
        Ok(match c {
            b'A'..=b'Z' => c - b'A',
            b'a'..=b'z' => c - b'a' + 26,
            b'0'..=b'9' => c - b'0' + 52,
            b'+' => 62,
            b'/' => 63,
            _ => return Err(format!("byte {c:#04x} is not base64")),
        } as u32)
    };
    let bytes = text.as_bytes();
    if bytes.len() % 4 != 0 {
        return Err(format!(
            "base64 length {} is not a multiple of 4",
            bytes.len()
        ));
    }
    let mut out = Vec::with_capacity(bytes.len() / 4 * 3);
    for (i, chunk) in bytes.chunks(4).enumerate() {
        let last = i + 1 == bytes.len() / 4;
        let pad = chunk.iter().rev().take_while(|&&c| c == b'=').count();
        if pad > 2 || (pad > 0 && !last) {
            return Err("misplaced base64 padding".into());
        }
        let mut n = 0u32;
        for &c in &chunk[..4 - pad] {
            n = (n << 6) | value(c)?;
        }
        n <<= 6 * pad as u32;
        let got = [(n >> 16) as u8, (n >> 8) as u8, n as u8];
        out.extend_from_slice(&got[..3 - pad]);
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn base64_round_trips_every_length() {
        for len in 0..20 {
            let bytes: Vec<u8> = (0..len).map(|i| (i * 37 + 11) as u8).collect();
            let text = super::super::base64_encode(&bytes);
            assert_eq!(base64_decode(&text), Ok(bytes), "length {len}");
        }
    }

    #[test]
    fn base64_refuses_garbage() {
        assert!(base64_decode("abc").is_err());
        assert!(base64_decode("ab!d").is_err());
        assert!(base64_decode("a===").is_err());
        assert!(base64_decode("ab==abcd").is_err());
    }

    #[test]
    fn mcap_by_extension() {
        assert!(is_mcap(Path::new("/x/rigslam-000001.mcap")));
        assert!(is_mcap(Path::new("a.MCAP")));
        assert!(!is_mcap(Path::new("/data/euroc/V1_01")));
    }
}
