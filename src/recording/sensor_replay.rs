//! The sensor streams of a recording read back as the daemon's replay
//! wants them: IMU samples and (stereo) frames in file order, which is the
//! order the recorder received them in, so a replayed recording goes
//! through the pipeline as the live run did.

use std::ops::ControlFlow;
use std::path::Path;

use rigslam_drivers::{Frame, Image, ImuSample};

use super::{ImageJson, ImuMessage, RecordingError};
use crate::dataset::euroc::sensor_yaml::{camera_yaml, imu_yaml};
use crate::dataset::{parse_camera_yaml, parse_imu_yaml, SensorEvent};
use crate::relative::{RigModel, SensorMode};

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
    let text = |name: &str| -> Result<Option<(String, std::path::PathBuf)>, RecordingError> {
        let key = format!("{CALIBRATION_PREFIX}{name}");
        attachments
            .get(&key)
            .map(|bytes| {
                let text = String::from_utf8(bytes.clone()).map_err(|_| {
                    RecordingError::BadAttachment {
                        path: path.to_path_buf(),
                        name: key.clone(),
                        reason: "not UTF-8 text".into(),
                    }
                })?;
                // Errors name the attachment as if it were a file in the recording.
                Ok((text, path.join(&key)))
            })
            .transpose()
    };
    let bad = |name: &str, e: crate::dataset::DatasetError| RecordingError::BadAttachment {
        path: path.to_path_buf(),
        name: format!("{CALIBRATION_PREFIX}{name}"),
        reason: e.to_string(),
    };
    let mut cameras = Vec::new();
    for i in 0.. {
        let name = format!("cam{i}.yaml");
        match text(&name)? {
            Some((t, origin)) => {
                cameras.push(parse_camera_yaml(&t, &origin).map_err(|e| bad(&name, e))?)
            }
            None => break,
        }
    }
    if cameras.is_empty() {
        return Ok(None);
    }
    let imu = match text("imu0.yaml")? {
        Some((t, origin)) => Some(parse_imu_yaml(&t, &origin).map_err(|e| bad("imu0.yaml", e))?),
        None => None,
    };
    Ok(Some(RigModel { cameras, imu }))
}

/// Calls `f` with every IMU sample and frame of the recording at `path`,
/// in file order, until the file ends or `f` breaks. A `/cam0` image
/// without its `/cam1` partner (stereo) is skipped. Returns the number of
/// events handed over.
///
/// The file is read into memory whole (the recorder rotates its files at
/// `rotate_mib`, 256 MiB by default).
pub fn for_each_sensor_event(
    path: &Path,
    topics: SensorTopics,
    f: impl FnMut(SensorEvent) -> ControlFlow<()>,
) -> Result<u64, RecordingError> {
    for_each_sensor_event_in(&super::read_bytes(path)?, path, topics, f)
}

/// [`for_each_sensor_event`] over a recording's bytes; `path` names it in
/// errors.
pub fn for_each_sensor_event_in(
    bytes: &[u8],
    path: &Path,
    topics: SensorTopics,
    mut f: impl FnMut(SensorEvent) -> ControlFlow<()>,
) -> Result<u64, RecordingError> {
    let mcap_err = |source| RecordingError::Mcap {
        path: path.to_path_buf(),
        source,
    };
    super::check_bounds(bytes, path)?;
    let stream = mcap::MessageStream::new(bytes).map_err(mcap_err)?;
    let mut left: Option<Frame> = None;
    let mut count = 0u64;
    for message in stream {
        let message = message.map_err(mcap_err)?;
        let topic = message.channel.topic.as_str();
        let bad = |source| RecordingError::BadMessage {
            path: path.to_path_buf(),
            topic: topic.to_string(),
            sequence: message.sequence,
            source,
        };
        let event = match topic {
            "/imu0" if topics.imu => {
                let m: ImuMessage = serde_json::from_slice(&message.data).map_err(bad)?;
                Some(SensorEvent::Imu(ImuSample {
                    t_ns: m.t_ns,
                    gyro_rad_s: m.gyro_rad_s,
                    accel_m_s2: m.accel_m_s2,
                }))
            }
            "/cam0" | "/cam1" => {
                let m: ImageJson = serde_json::from_slice(&message.data).map_err(bad)?;
                let index = u8::from(topic == "/cam1");
                let frame = decode_frame(&m, index).map_err(|reason| RecordingError::BadImage {
                    path: path.to_path_buf(),
                    topic: topic.to_string(),
                    sequence: message.sequence,
                    reason,
                })?;
                match (index, topics.stereo) {
                    (0, false) => Some(SensorEvent::Frame {
                        t_ns: frame.t_ns,
                        left: frame,
                        right: None,
                    }),
                    (0, true) => {
                        left = Some(frame);
                        None
                    }
                    (_, true) => match left.take() {
                        Some(l) if l.t_ns == frame.t_ns => Some(SensorEvent::Frame {
                            t_ns: l.t_ns,
                            left: l,
                            right: Some(frame),
                        }),
                        _ => None,
                    },
                    _ => None,
                }
            }
            _ => None,
        };
        if let Some(event) = event {
            count += 1;
            if f(event).is_break() {
                break;
            }
        }
    }
    Ok(count)
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
