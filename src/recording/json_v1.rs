//! The message layout of the first recordings, read so that they still
//! replay: JSON described by a JSON Schema (serde_json with exact float
//! round-tripping), images as `foxglove.RawImage` with base64 data, poses
//! as `foxglove.PoseInFrame` with the daemon's fields beside it.

use rigslam_drivers::ImuSample;

use super::RecordedPose;

#[derive(serde::Deserialize)]
struct ImuMessage {
    t_ns: i64,
    gyro_rad_s: [f64; 3],
    accel_m_s2: [f64; 3],
}

#[derive(serde::Deserialize)]
struct FoxgloveTime {
    sec: i64,
    nsec: i64,
}

#[derive(serde::Deserialize)]
struct Xyz {
    x: f64,
    y: f64,
    z: f64,
}

#[derive(serde::Deserialize)]
struct Xyzw {
    x: f64,
    y: f64,
    z: f64,
    w: f64,
}

#[derive(serde::Deserialize)]
struct PoseBody {
    position: Xyz,
    orientation: Xyzw,
}

#[derive(serde::Deserialize)]
struct PoseJson {
    pose: PoseBody,
    t_ns: i64,
    tracking_state: u32,
    velocity_world_m_s: Xyz,
}

#[derive(serde::Deserialize)]
struct ImageJson {
    timestamp: FoxgloveTime,
    width: u32,
    height: u32,
    encoding: String,
    step: u32,
    data: String,
}

/// An image message before it becomes a frame (either layout).
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) struct RawFrame {
    /// Stamp, ns.
    pub t_ns: i64,
    /// Width, px.
    pub width: u32,
    /// Height, px.
    pub height: u32,
    /// Bytes per row.
    pub step: u32,
    /// Pixel encoding (`mono8` is what rigslam writes).
    pub encoding: String,
    /// The pixels.
    pub data: Vec<u8>,
}

fn json<'a, T: serde::Deserialize<'a>>(data: &'a [u8]) -> Result<T, String> {
    serde_json::from_slice(data).map_err(|e| e.to_string())
}

/// An IMU sample.
pub(crate) fn imu(data: &[u8]) -> Result<ImuSample, String> {
    let m: ImuMessage = json(data)?;
    Ok(ImuSample {
        t_ns: m.t_ns,
        gyro_rad_s: m.gyro_rad_s,
        accel_m_s2: m.accel_m_s2,
    })
}

/// A pose (these files kept only the map frame).
pub(crate) fn pose(data: &[u8]) -> Result<RecordedPose, String> {
    let m: PoseJson = json(data)?;
    let p = &m.pose;
    Ok(RecordedPose::map_only(
        m.t_ns,
        m.tracking_state,
        [p.position.x, p.position.y, p.position.z],
        [
            p.orientation.x,
            p.orientation.y,
            p.orientation.z,
            p.orientation.w,
        ],
        [
            m.velocity_world_m_s.x,
            m.velocity_world_m_s.y,
            m.velocity_world_m_s.z,
        ],
    ))
}

/// An image.
pub(crate) fn image(data: &[u8]) -> Result<RawFrame, String> {
    let m: ImageJson = json(data)?;
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
    Ok(RawFrame {
        t_ns,
        width: m.width,
        height: m.height,
        step: m.step,
        encoding: m.encoding,
        data: base64_decode(&m.data)?,
    })
}

/// Standard base64 with padding (RFC 4648), as `foxglove.RawImage`
/// carries bytes in JSON.
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
    fn base64_decodes_known_texts() {
        // RFC 4648, section 10.
        for (text, bytes) in [
            ("", ""),
            ("Zg==", "f"),
            ("Zm8=", "fo"),
            ("Zm9v", "foo"),
            ("Zm9vYg==", "foob"),
            ("Zm9vYmE=", "fooba"),
            ("Zm9vYmFy", "foobar"),
        ] {
            assert_eq!(base64_decode(text), Ok(bytes.as_bytes().to_vec()), "{text}");
        }
    }

    #[test]
    fn base64_refuses_garbage() {
        assert!(base64_decode("abc").is_err());
        assert!(base64_decode("ab!d").is_err());
        assert!(base64_decode("a===").is_err());
        assert!(base64_decode("ab==abcd").is_err());
    }
}
