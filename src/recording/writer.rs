//! Writing a recording: one MCAP file, one channel per stream, protobuf
//! messages (Foxglove's schemas where one fits, `rigslam.*` otherwise),
//! chunks compressed with zstd or lz4.
//!
//! Times: every message's log and publish time is the host's receipt time
//! in Unix-epoch nanoseconds, so files line up with other logs; the
//! message's own stamp (`t_ns`, `timestamp`) stays on the sensors' clock.
//! The mapping between the host's `CLOCK_MONOTONIC` (what the daemon
//! stamps receipt with) and the epoch is taken once when the file is
//! created and kept in the file as the `rigslam.clock` metadata record.

use std::collections::BTreeMap;
use std::fs::File;
use std::io::{BufWriter, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};

use foxglove::messages::RawImage;
use foxglove::Encode;
use rigslam_drivers::ImuSample;

use super::schemas::{timestamp, ImuSampleProto, PoseEstimateProto};
use super::{RecordedPose, RecordingError};

/// How a recording's chunks are compressed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Compression {
    /// Stored as they are.
    None,
    /// zstd at its default level: the smallest files.
    #[default]
    Zstd,
    /// lz4: less CPU, larger files.
    Lz4,
}

impl Compression {
    fn mcap(self) -> Option<mcap::Compression> {
        match self {
            Compression::None => None,
            Compression::Zstd => Some(mcap::Compression::Zstd),
            Compression::Lz4 => Some(mcap::Compression::Lz4),
        }
    }
}

/// Which messages a recording holds.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Format {
    /// Protobuf: Foxglove's schemas and rigslam's own, every stream the
    /// daemon has (the MCAP profile is empty).
    #[default]
    Foxglove,
    /// ROS 2's messages in CDR, with the `ros2` profile, for `ros2 bag
    /// play` and the ROS tools ([`super::ros2`]).
    Ros2,
}

impl std::str::FromStr for Format {
    type Err = String;

    fn from_str(name: &str) -> Result<Self, String> {
        match name {
            "foxglove" => Ok(Format::Foxglove),
            "ros2" => Ok(Format::Ros2),
            other => Err(format!(
                "{other:?} is not a recording format: \"foxglove\" (protobuf, every stream) \
                 or \"ros2\" (ROS 2 messages for ros2 bag play)"
            )),
        }
    }
}

impl Format {
    /// The MCAP profile of the file.
    pub fn profile(self) -> &'static str {
        match self {
            Format::Foxglove => "",
            Format::Ros2 => "ros2",
        }
    }
}

/// zstd's level unless set: its fastest. On EuRoC's images it stores
/// 1.26x smaller than raw at 0.6 ms per image; zstd's own default (3)
/// gets 1.32x for three times the CPU (bench/README.md).
pub const DEFAULT_ZSTD_LEVEL: u32 = 1;

/// Name of the metadata record that maps the host's monotonic clock to
/// the epoch.
pub const CLOCK_METADATA: &str = "rigslam.clock";

/// The host's monotonic clock and the epoch, read together.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ClockMapping {
    /// `CLOCK_MONOTONIC`, ns.
    pub monotonic_ns: i64,
    /// `CLOCK_REALTIME` at the same instant, ns since 1970.
    pub unix_ns: i64,
}

impl ClockMapping {
    /// Both clocks now.
    pub fn now() -> Self {
        let unix_ns = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.as_nanos() as i64);
        Self {
            monotonic_ns: crate::sensors::yei::device::host_monotonic_ns(),
            unix_ns,
        }
    }

    /// A host monotonic time on the epoch, ns (0 before 1970).
    pub fn unix_of(&self, monotonic_ns: i64) -> u64 {
        (monotonic_ns - self.monotonic_ns + self.unix_ns).max(0) as u64
    }

    fn metadata(&self) -> BTreeMap<String, String> {
        BTreeMap::from([
            ("monotonic_ns".to_owned(), self.monotonic_ns.to_string()),
            ("unix_ns".to_owned(), self.unix_ns.to_string()),
            (
                "meaning".to_owned(),
                "log and publish times are host receipt times on the Unix epoch: \
                 unix = monotonic - monotonic_ns + unix_ns; message stamps are the \
                 sensors' clock (host CLOCK_MONOTONIC live, the dataset's on a replay)"
                    .to_owned(),
            ),
        ])
    }
}

/// A channel registered in a [`McapRecorder`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ChannelId {
    id: u16,
}

/// A file writer that knows how far the file reaches.
struct Counting<W> {
    inner: W,
    pos: u64,
    end: std::sync::Arc<std::sync::atomic::AtomicU64>,
}

impl<W> Counting<W> {
    fn reach(&mut self) {
        self.end
            .fetch_max(self.pos, std::sync::atomic::Ordering::Relaxed);
    }
}

impl<W: Write> Write for Counting<W> {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        let n = self.inner.write(buf)?;
        self.pos += n as u64;
        self.reach();
        Ok(n)
    }

    fn flush(&mut self) -> std::io::Result<()> {
        self.inner.flush()
    }
}

impl<W: Seek> Seek for Counting<W> {
    fn seek(&mut self, to: SeekFrom) -> std::io::Result<u64> {
        self.pos = self.inner.seek(to)?;
        self.reach();
        Ok(self.pos)
    }
}

/// Writes sensor streams into one MCAP file.
pub struct McapRecorder {
    path: PathBuf,
    writer: mcap::Writer<Counting<BufWriter<File>>>,
    sequences: BTreeMap<u16, u32>,
    buf: Vec<u8>,
    /// How far the file reaches.
    end: std::sync::Arc<std::sync::atomic::AtomicU64>,
    /// `end` when last looked at, and the message bytes given to the
    /// writer since it moved (the chunk being filled, uncompressed).
    seen_end: u64,
    pending: u64,
    clock: ClockMapping,
}

impl McapRecorder {
    /// Creates (or truncates) the MCAP file at `path`, chunks compressed
    /// with `compression` at [`DEFAULT_ZSTD_LEVEL`], ready for channels
    /// and messages.
    pub fn create(
        path: impl AsRef<Path>,
        compression: Compression,
    ) -> Result<McapRecorder, RecordingError> {
        Self::create_with(
            path,
            compression,
            DEFAULT_ZSTD_LEVEL,
            ClockMapping::now(),
            Format::Foxglove,
        )
    }

    /// [`Self::create`] with a compression level (zstd's 1 to 19; lz4's
    /// acceleration otherwise, 0 its default), a given clock mapping
    /// (the host's now, a test's, or one carried over from another file)
    /// and a format: its profile goes in the file's header, and a ROS 2
    /// file gets the `rosbag2` metadata record [`super::ros2`] describes.
    /// The channels are the caller's to add.
    pub fn create_with(
        path: impl AsRef<Path>,
        compression: Compression,
        level: u32,
        clock: ClockMapping,
        format: Format,
    ) -> Result<McapRecorder, RecordingError> {
        let path = path.as_ref().to_path_buf();
        let file = File::create(&path).map_err(|source| RecordingError::Create {
            path: path.clone(),
            source,
        })?;
        let end = std::sync::Arc::new(std::sync::atomic::AtomicU64::new(0));
        let counting = Counting {
            inner: BufWriter::new(file),
            pos: 0,
            end: end.clone(),
        };
        let mcap_err = |source| RecordingError::Mcap {
            path: path.clone(),
            source,
        };
        let mut writer = mcap::WriteOptions::new()
            .compression(compression.mcap())
            .compression_level(level)
            // The recorder has its own thread; the pipeline has the others.
            .compression_threads(0)
            .profile(format.profile())
            .library(concat!("rigslam ", env!("CARGO_PKG_VERSION")))
            .create(counting)
            .map_err(mcap_err)?;
        writer
            .write_metadata(&mcap::records::Metadata {
                name: CLOCK_METADATA.to_owned(),
                metadata: clock.metadata(),
            })
            .map_err(mcap_err)?;
        if format == Format::Ros2 {
            writer
                .write_metadata(&mcap::records::Metadata {
                    name: super::ros2::BAG_METADATA_NAME.to_owned(),
                    metadata: super::ros2::bag_metadata(),
                })
                .map_err(mcap_err)?;
        }
        Ok(McapRecorder {
            path,
            writer,
            sequences: BTreeMap::new(),
            buf: Vec::new(),
            end,
            seen_end: 0,
            pending: 0,
            clock,
        })
    }

    fn mcap_err(&self) -> impl FnOnce(mcap::McapError) -> RecordingError {
        let path = self.path.clone();
        move |source| RecordingError::Mcap { path, source }
    }

    /// The clock mapping this file was created with.
    pub fn clock(&self) -> ClockMapping {
        self.clock
    }

    /// Registers a channel of `T` messages on `topic`.
    pub fn add_channel<T: Encode>(
        &mut self,
        topic: &str,
        metadata: &BTreeMap<String, String>,
    ) -> Result<ChannelId, RecordingError> {
        let schema = T::get_schema().map_or(Ok(0), |s| {
            self.writer
                .add_schema(&s.name, &s.encoding, &s.data)
                .map_err(self.mcap_err())
        })?;
        let id = self
            .writer
            .add_channel(schema, topic, &T::get_message_encoding(), metadata)
            .map_err(self.mcap_err())?;
        Ok(ChannelId { id })
    }

    /// Appends one message received at host time `receipt_t_ns`
    /// (`CLOCK_MONOTONIC`).
    pub fn write<T: Encode>(
        &mut self,
        channel: ChannelId,
        message: &T,
        receipt_t_ns: i64,
    ) -> Result<(), RecordingError> {
        self.buf.clear();
        message
            .encode(&mut self.buf)
            .map_err(|e| RecordingError::Encode {
                path: self.path.clone(),
                reason: e.to_string(),
            })?;
        let sequence = self.sequences.entry(channel.id).or_insert(0);
        *sequence += 1;
        let time = self.clock.unix_of(receipt_t_ns);
        let header = mcap::records::MessageHeader {
            channel_id: channel.id,
            sequence: *sequence,
            log_time: time,
            publish_time: time,
        };
        self.writer
            .write_to_known_channel(&header, &self.buf)
            .map_err(self.mcap_err())?;
        // Message record: opcode, length, header fields, then the data.
        self.add_pending(1 + 8 + 2 + 4 + 8 + 8 + self.buf.len() as u64);
        Ok(())
    }

    /// Registers an IMU stream on `topic` (e.g. `/imu0`), with the sensor's
    /// identity as channel metadata.
    pub fn add_imu_channel(
        &mut self,
        topic: &str,
        metadata: &BTreeMap<String, String>,
    ) -> Result<ChannelId, RecordingError> {
        self.add_channel::<ImuSampleProto>(topic, metadata)
    }

    /// Appends one IMU sample received at `receipt_t_ns`.
    pub fn write_imu(
        &mut self,
        channel: ChannelId,
        sample: &ImuSample,
        receipt_t_ns: i64,
    ) -> Result<(), RecordingError> {
        let message = ImuSampleProto {
            t_ns: sample.t_ns,
            gyro_rad_s: sample.gyro_rad_s.to_vec(),
            accel_m_s2: sample.accel_m_s2.to_vec(),
        };
        self.write(channel, &message, receipt_t_ns)
    }

    /// Registers a pose stream (`rigslam.PoseEstimate`).
    pub fn add_pose_channel(&mut self, topic: &str) -> Result<ChannelId, RecordingError> {
        self.add_channel::<PoseEstimateProto>(topic, &BTreeMap::new())
    }

    /// Appends one pose.
    pub fn write_pose(
        &mut self,
        channel: ChannelId,
        pose: &RecordedPose,
        receipt_t_ns: i64,
    ) -> Result<(), RecordingError> {
        self.write(channel, &PoseEstimateProto::from(pose), receipt_t_ns)
    }

    /// Registers an image stream (`foxglove.RawImage`).
    pub fn add_image_channel(&mut self, topic: &str) -> Result<ChannelId, RecordingError> {
        self.add_channel::<RawImage>(topic, &BTreeMap::new())
    }

    /// Appends one 8-bit grey image (other formats are converted to grey),
    /// stamped `t_ns` on the sensor's clock.
    pub fn write_image(
        &mut self,
        channel: ChannelId,
        t_ns: i64,
        image: &rigslam_drivers::Image,
        frame_id: &str,
        receipt_t_ns: i64,
    ) -> Result<(), RecordingError> {
        let message = RawImage {
            timestamp: Some(timestamp(t_ns)),
            frame_id: frame_id.to_owned(),
            width: image.width(),
            height: image.height(),
            encoding: "mono8".to_owned(),
            step: image.width(),
            data: super::grey_bytes(image).into(),
        };
        self.write(channel, &message, receipt_t_ns)
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
            create_time: self.clock.unix_ns.max(0) as u64,
            name: name.to_string(),
            media_type: media_type.to_string(),
            data: std::borrow::Cow::Borrowed(data),
        };
        self.writer.attach(&attachment).map_err(self.mcap_err())?;
        self.add_pending(0);
        Ok(())
    }

    /// Bytes in the file so far, with the messages of the chunk being
    /// filled counted uncompressed (the summary adds a little at the end).
    pub fn bytes(&self) -> u64 {
        self.seen_end + self.pending
    }

    fn add_pending(&mut self, bytes: u64) {
        let end = self.end.load(std::sync::atomic::Ordering::Relaxed);
        if end != self.seen_end {
            // A chunk went out: what was pending is in the file now.
            self.seen_end = end;
            self.pending = 0;
        }
        self.pending += bytes;
    }

    /// Writes the summary and closes the file.
    pub fn finish(mut self) -> Result<PathBuf, RecordingError> {
        self.writer.finish().map_err(self.mcap_err())?;
        Ok(self.path)
    }
}
