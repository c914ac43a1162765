//! Recordings of live sensor streams as MCAP files (DESIGN.md: one channel
//! per sensor stream, replayable bit for bit, opened by Foxglove).
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

/// Schema name of IMU messages.
pub const IMU_SCHEMA_NAME: &str = "rigslam.ImuSample";

const IMU_JSON_SCHEMA: &str = r#"{"type":"object","properties":{"t_ns":{"type":"integer","description":"host CLOCK_MONOTONIC, ns"},"gyro_rad_s":{"type":"array","items":{"type":"number"},"minItems":3,"maxItems":3},"accel_m_s2":{"type":"array","items":{"type":"number"},"minItems":3,"maxItems":3}},"required":["t_ns","gyro_rad_s","accel_m_s2"]}"#;

#[derive(Debug, Error)]
pub enum RecordingError {
    #[error("cannot create recording {path}: {source}")]
    Create {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("cannot read recording {path}: {source}")]
    Read {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("MCAP error in {path}: {source}")]
    Mcap {
        path: PathBuf,
        source: mcap::McapError,
    },
    #[error("{path}: message {sequence} on {topic} is not an IMU sample: {source}")]
    BadMessage {
        path: PathBuf,
        topic: String,
        sequence: u32,
        source: serde_json::Error,
    },
    #[error("{path} has no channel {topic}")]
    NoChannel { path: PathBuf, topic: String },
}

#[derive(serde::Serialize, serde::Deserialize)]
struct ImuMessage {
    t_ns: i64,
    gyro_rad_s: [f64; 3],
    accel_m_s2: [f64; 3],
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
}

impl McapRecorder {
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
        self.buf.clear();
        serde_json::to_writer(
            &mut self.buf,
            &ImuMessage {
                t_ns: sample.t_ns,
                gyro_rad_s: sample.gyro_rad_s,
                accel_m_s2: sample.accel_m_s2,
            },
        )
        .expect("serialising plain numbers into a Vec cannot fail");
        let sequence = self.sequences.entry(channel.id).or_insert(0);
        *sequence += 1;
        let header = mcap::records::MessageHeader {
            channel_id: channel.id,
            sequence: *sequence,
            log_time: sample.t_ns.max(0) as u64,
            publish_time: receipt_t_ns.max(0) as u64,
        };
        self.writer
            .write_to_known_channel(&header, &self.buf)
            .map_err(self.mcap_err())
    }

    /// Writes the summary and closes the file.
    pub fn finish(mut self) -> Result<PathBuf, RecordingError> {
        self.writer.finish().map_err(self.mcap_err())?;
        Ok(self.path)
    }
}

/// Reads back every IMU sample of `topic`, in file order.
pub fn read_imu_channel(path: &Path, topic: &str) -> Result<Vec<ImuSample>, RecordingError> {
    let bytes = std::fs::read(path).map_err(|source| RecordingError::Read {
        path: path.to_path_buf(),
        source,
    })?;
    let mut samples = Vec::new();
    let mut seen = false;
    let stream = mcap::MessageStream::new(&bytes).map_err(|source| RecordingError::Mcap {
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
        let m: ImuMessage =
            serde_json::from_slice(&message.data).map_err(|source| RecordingError::BadMessage {
                path: path.to_path_buf(),
                topic: topic.to_string(),
                sequence: message.sequence,
                source,
            })?;
        samples.push(ImuSample {
            t_ns: m.t_ns,
            gyro_rad_s: m.gyro_rad_s,
            accel_m_s2: m.accel_m_s2,
        });
    }
    if !seen {
        return Err(RecordingError::NoChannel {
            path: path.to_path_buf(),
            topic: topic.to_string(),
        });
    }
    Ok(samples)
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
