//! V4L2 capture: a [`V4l2Source`] turns dequeued driver buffers into owned,
//! timestamped [`Frame`]s, over any [`V4l2Stream`] (the ioctl layer).
//!
//! Everything above the ioctl layer (timestamp flags, sequence gaps, corrupt
//! buffers, format negotiation, copying out) is pure and tested with a
//! scripted stream ([`super::fake::ScriptedV4l2Stream`]). The real stream,
//! [`V4l2Device`], is a thin wrapper over the v4l crate's mmap stream.
//!
//! The v4l crate re-queues the buffer it last returned on the next call to
//! `next()`, so a slice it hands out is only valid until then: we copy every
//! frame out (`FrameLayout::to_image`) before asking for the next one.
//!
//! Checking on a real camera (no camera in CI):
//! 1. `v4l2-ctl --list-devices` and `v4l2-ctl -d /dev/video0 --list-formats-ext`
//!    (Debian package v4l-utils) show the device and what it offers.
//! 2. `rigslam camera --driver v4l2 --device /dev/video0 --seconds 5` prints
//!    identity, format, measured rate, drops and the timestamp source; the
//!    rate should match `--list-formats-ext`, drops should be 0 on an idle
//!    machine, and the timestamp source should be `monotonic_*` for any UVC
//!    camera (UVC stamps start of exposure, most others end of frame).
//! 3. Load the machine (`stress -c 2`) or cover the lens in auto exposure:
//!    drops and rate should change as the camera's sequence numbers say.

use std::io;
use std::time::Duration;

use super::buffer_pool::BufferPool;
use super::source::{
    monotonic_now_ns, CameraError, CameraInfo, CaptureStats, FrameSource, SequenceCounter,
    TimestampSource,
};
use super::v4l2_format::{fourcc_name, FrameLayout, LayoutError, WireFormat, SUPPORTED};
use crate::Frame;

/// V4L2 buffer flags we read (`V4L2_BUF_FLAG_*`, videodev2.h).
pub mod buf_flag {
    /// The driver says the data is corrupt.
    pub const ERROR: u32 = 0x0000_0040;
    /// Which clock the timestamp is on.
    pub const TIMESTAMP_MASK: u32 = 0x0000_e000;
    /// Clock not stated: not comparable with host time.
    pub const TIMESTAMP_UNKNOWN: u32 = 0x0000_0000;
    /// Host `CLOCK_MONOTONIC`, the clock of every live `t_ns`.
    pub const TIMESTAMP_MONOTONIC: u32 = 0x0000_2000;
    /// Copied from an output buffer: not a capture time at all.
    pub const TIMESTAMP_COPY: u32 = 0x0000_4000;
    /// Which instant of the frame the timestamp marks.
    pub const TSTAMP_SRC_MASK: u32 = 0x0007_0000;
    /// End of frame: the last pixel arrived.
    pub const TSTAMP_SRC_EOF: u32 = 0x0000_0000;
    /// Start of exposure.
    pub const TSTAMP_SRC_SOE: u32 = 0x0001_0000;
}

/// What the driver says about a dequeued buffer (`struct v4l2_buffer`).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct BufferMeta {
    /// Bytes of the buffer the frame fills.
    pub bytes_used: u32,
    /// `V4L2_BUF_FLAG_*`.
    pub flags: u32,
    /// Timestamp, `struct timeval`: whole seconds, on the clock `flags` name.
    pub timestamp_s: i64,
    /// Timestamp, `struct timeval`: microseconds added to `timestamp_s`.
    pub timestamp_us: i64,
    /// The driver's frame counter; gaps are frames it dropped.
    pub sequence: u32,
}

/// A dequeued buffer, valid until the next `dequeue`.
pub struct RawBuffer<'a> {
    /// The whole mapped buffer; the frame is its first `meta.bytes_used` bytes.
    pub bytes: &'a [u8],
    /// What the driver says about the buffer.
    pub meta: BufferMeta,
}

/// The ioctl layer: hands out one filled buffer at a time and takes the
/// previous one back.
pub trait V4l2Stream {
    /// Waits at most `timeout` for the next filled buffer; an
    /// `io::ErrorKind::TimedOut` error when none came.
    fn dequeue(&mut self, timeout: Duration) -> io::Result<RawBuffer<'_>>;
}

/// A frame's `t_ns` from its buffer's timestamp and flags, with the source
/// it came from.
///
/// Monotonic stamps are used as the device gives them, moved to
/// mid-exposure when the exposure time is known (start of exposure: plus
/// half; end of frame: minus half; the readout time in the latter is a
/// constant the camera-IMU time shift absorbs). Stamps on another clock
/// (`TIMESTAMP_UNKNOWN`, `TIMESTAMP_COPY`) are not comparable with the IMU,
/// so the host's receipt time replaces them.
pub fn frame_stamp(
    meta: &BufferMeta,
    exposure_ns: Option<i64>,
    receipt_ns: i64,
) -> (i64, TimestampSource) {
    if meta.flags & buf_flag::TIMESTAMP_MASK != buf_flag::TIMESTAMP_MONOTONIC {
        return (receipt_ns, TimestampSource::HostReceipt);
    }
    let stamp_ns = meta.timestamp_s * crate::NS_PER_S + meta.timestamp_us * 1_000;
    let half_exposure_ns = exposure_ns.unwrap_or(0) / 2;
    if meta.flags & buf_flag::TSTAMP_SRC_MASK == buf_flag::TSTAMP_SRC_SOE {
        (
            stamp_ns + half_exposure_ns,
            TimestampSource::MonotonicStartOfExposure,
        )
    } else {
        (
            stamp_ns - half_exposure_ns,
            TimestampSource::MonotonicEndOfFrame,
        )
    }
}

/// This many bad buffers in a row end capture with an error instead of
/// being skipped: the format or the link is wrong, not one frame.
const MAX_CONSECUTIVE_BAD: u32 = 8;

/// Frames a consumer may hold before capture allocates new buffers.
const POOLED_FRAMES: usize = 8;

/// A V4L2 camera as a [`FrameSource`], over any [`V4l2Stream`].
pub struct V4l2Source<S> {
    stream: S,
    info: CameraInfo,
    layout: FrameLayout,
    exposure_ns: Option<i64>,
    camera_index: u8,
    sequence: SequenceCounter,
    frames: u64,
    corrupt: u64,
    pool: BufferPool,
}

impl<S: V4l2Stream> V4l2Source<S> {
    /// A source reading `layout`-shaped frames from `stream`.
    pub fn new(stream: S, info: CameraInfo, layout: FrameLayout, camera_index: u8) -> Self {
        let exposure_ns = info.exposure_us.map(|us| (us * 1_000.0).round() as i64);
        Self {
            stream,
            info,
            layout,
            exposure_ns,
            camera_index,
            sequence: SequenceCounter::new(),
            frames: 0,
            corrupt: 0,
            pool: BufferPool::new(POOLED_FRAMES),
        }
    }

    /// How frames sit in the driver's buffers.
    pub fn layout(&self) -> &FrameLayout {
        &self.layout
    }
}

impl<S: V4l2Stream> FrameSource for V4l2Source<S> {
    fn info(&self) -> &CameraInfo {
        &self.info
    }

    fn stats(&self) -> CaptureStats {
        CaptureStats {
            frames: self.frames,
            drops: self.sequence.drops(),
            corrupt: self.corrupt,
        }
    }

    fn next_frame(&mut self, timeout: Duration) -> Result<Frame, CameraError> {
        let mut bad_in_a_row = 0;
        loop {
            let device = &self.info.device;
            let buffer = self.stream.dequeue(timeout).map_err(|e| {
                if e.kind() == io::ErrorKind::TimedOut {
                    CameraError::Timeout {
                        device: device.clone(),
                        timeout_ms: timeout.as_millis() as u64,
                    }
                } else {
                    CameraError::Io {
                        device: device.clone(),
                        what: "dequeueing a buffer (VIDIOC_DQBUF)",
                        source: e,
                    }
                }
            })?;
            let receipt_ns = monotonic_now_ns();
            let meta = buffer.meta;
            let (seq, _lost) = self.sequence.observe(meta.sequence);
            let used = if meta.bytes_used == 0 {
                buffer.bytes.len()
            } else {
                (meta.bytes_used as usize).min(buffer.bytes.len())
            };
            let image = if meta.flags & buf_flag::ERROR != 0 {
                Err(None)
            } else {
                self.layout
                    .to_image_in(&buffer.bytes[..used], &mut self.pool)
                    .map_err(Some)
            };
            match image {
                Ok(image) => {
                    let (t_ns, source) = frame_stamp(&meta, self.exposure_ns, receipt_ns);
                    self.info.timestamp_source = source;
                    self.frames += 1;
                    return Ok(Frame {
                        t_ns,
                        seq,
                        camera_index: self.camera_index,
                        image,
                    });
                }
                Err(why) => {
                    self.corrupt += 1;
                    bad_in_a_row += 1;
                    if bad_in_a_row < MAX_CONSECUTIVE_BAD {
                        continue;
                    }
                    return Err(match why {
                        Some(LayoutError::Short { got, needed }) => CameraError::ShortBuffer {
                            device: device.clone(),
                            wire_format: fourcc_name(self.layout.format.fourcc()),
                            width: self.layout.width,
                            height: self.layout.height,
                            got,
                            needed,
                        },
                        Some(LayoutError::Frame(source)) => CameraError::Frame {
                            device: device.clone(),
                            source,
                        },
                        None => CameraError::Driver {
                            device: device.clone(),
                            message: format!(
                                "{MAX_CONSECUTIVE_BAD} buffers in a row flagged corrupt by the driver (V4L2_BUF_FLAG_ERROR); check the cable and the USB bandwidth"
                            ),
                        },
                    });
                }
            }
        }
    }
}

/// What the user asked of the device; `None` keeps the device's setting.
#[derive(Debug, Clone, PartialEq)]
pub struct V4l2Config {
    /// `/dev/videoN`, or `N` for short.
    pub device: String,
    /// Wire format to set. `None` keeps the device's, unless it is one we
    /// do not read (often MJPG): then the first offered format in
    /// [`SUPPORTED`] order.
    pub format: Option<WireFormat>,
    /// Frame width to set, pixels.
    pub width: Option<u32>,
    /// Frame height to set, pixels.
    pub height: Option<u32>,
    /// Frame rate to set (`VIDIOC_S_PARM`), frames per second.
    pub rate_hz: Option<u32>,
    /// Manual exposure time, microseconds, where the device has the
    /// control (set in its 100 us steps, rounded up).
    pub exposure_us: Option<u32>,
    /// Number of mmap buffers.
    pub buffers: u32,
    /// Which camera of the rig the frames are stamped with.
    pub camera_index: u8,
}

impl V4l2Config {
    /// Opens `device` (a path or an index) with every device setting kept,
    /// 4 mmap buffers and camera index 0.
    pub fn new(device: &str) -> Self {
        Self {
            device: device.to_string(),
            format: None,
            width: None,
            height: None,
            rate_hz: None,
            exposure_us: None,
            buffers: 4,
            camera_index: 0,
        }
    }

    /// The device node: `N` means `/dev/videoN`.
    pub fn device_path(&self) -> String {
        if !self.device.is_empty() && self.device.bytes().all(|b| b.is_ascii_digit()) {
            format!("/dev/video{}", self.device)
        } else {
            self.device.clone()
        }
    }
}

/// The format the device applied, as `VIDIOC_S_FMT`/`G_FMT` report it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct AppliedFormat {
    /// FourCC of the applied pixel format.
    pub fourcc: [u8; 4],
    /// Applied frame width, pixels.
    pub width: u32,
    /// Applied frame height, pixels.
    pub height: u32,
    /// Row stride of the buffers, bytes (`bytesperline`; 0 when the driver
    /// leaves it unset).
    pub bytes_per_line: u32,
}

/// Checks what the device applied against what was asked. V4L2 drivers do
/// not fail `S_FMT` on a format they lack, they silently pick another, so
/// this is where "the camera refused the format" is detected.
pub fn negotiate(
    config: &V4l2Config,
    applied: AppliedFormat,
    offered: &[[u8; 4]],
) -> Result<FrameLayout, CameraError> {
    let device = config.device_path();
    let offered_text = || {
        if offered.is_empty() {
            "nothing (VIDIOC_ENUM_FMT lists no format)".to_string()
        } else {
            offered
                .iter()
                .map(|c| fourcc_name(*c))
                .collect::<Vec<_>>()
                .join(", ")
        }
    };
    let wanted_fourcc = config.format.map(|f| f.fourcc());
    let fourcc_ok = wanted_fourcc.map_or(true, |c| c == applied.fourcc);
    let width_ok = config.width.map_or(true, |w| w == applied.width);
    let height_ok = config.height.map_or(true, |h| h == applied.height);
    if !(fourcc_ok && width_ok && height_ok) {
        let show = |c: Option<[u8; 4]>, w: Option<u32>, h: Option<u32>| {
            format!(
                "{} {}x{}",
                c.map(fourcc_name).unwrap_or_else(|| "(any)".into()),
                w.map(|v| v.to_string()).unwrap_or_else(|| "(any)".into()),
                h.map(|v| v.to_string()).unwrap_or_else(|| "(any)".into()),
            )
        };
        return Err(CameraError::FormatRefused {
            device,
            requested: show(wanted_fourcc, config.width, config.height),
            got: show(
                Some(applied.fourcc),
                Some(applied.width),
                Some(applied.height),
            ),
            offered: offered_text(),
        });
    }
    let Some(format) = WireFormat::from_fourcc(applied.fourcc) else {
        return Err(CameraError::UnsupportedFormat {
            device,
            wire_format: fourcc_name(applied.fourcc),
            offered: offered_text(),
            supported: supported_text(),
        });
    };
    Ok(FrameLayout::new(
        format,
        applied.width,
        applied.height,
        applied.bytes_per_line,
    ))
}

/// The FourCCs rigslam reads, for error messages.
pub fn supported_text() -> String {
    SUPPORTED
        .iter()
        .map(|f| fourcc_name(f.fourcc()))
        .collect::<Vec<_>>()
        .join(", ")
}

/// The first format we read among those a device offers, for a device left
/// in a format we do not read (many webcams default to MJPG).
pub fn preferred_format(offered: &[[u8; 4]]) -> Option<WireFormat> {
    SUPPORTED
        .iter()
        .copied()
        .find(|f| offered.contains(&f.fourcc()))
}

pub use device::{open_v4l2, V4l2Device};

mod device {
    //! The ioctl layer over the v4l crate. Not exercised in CI (no camera);
    //! see the module documentation above for the manual check.

    use std::io;
    use std::time::Duration;

    use v4l::buffer::Type;
    use v4l::io::mmap::Stream;
    use v4l::io::traits::CaptureStream;
    use v4l::video::Capture;
    use v4l::{Device, FourCC};

    use super::{
        negotiate, preferred_format, AppliedFormat, BufferMeta, RawBuffer, V4l2Config, V4l2Source,
        V4l2Stream,
    };
    use crate::camera::source::{CameraError, CameraInfo, TimestampSource};
    use crate::camera::v4l2_format::fourcc_name;

    /// `V4L2_CID_EXPOSURE_AUTO` and its manual setting, and
    /// `V4L2_CID_EXPOSURE_ABSOLUTE` (units of 100 us), videodev2/v4l2-controls.h.
    const CID_EXPOSURE_AUTO: u32 = 0x009a_0901;
    const EXPOSURE_MANUAL: i64 = 1;
    const CID_EXPOSURE_ABSOLUTE: u32 = 0x009a_0902;

    /// The v4l crate's mmap stream.
    pub struct V4l2Device {
        stream: Stream<'static>,
    }

    impl V4l2Stream for V4l2Device {
        fn dequeue(&mut self, timeout: Duration) -> io::Result<RawBuffer<'_>> {
            self.stream
                .set_timeout(timeout.max(Duration::from_millis(1)));
            let (bytes, meta) = self.stream.next()?;
            Ok(RawBuffer {
                bytes,
                meta: BufferMeta {
                    bytes_used: meta.bytesused,
                    flags: meta.flags.bits(),
                    timestamp_s: meta.timestamp.sec,
                    timestamp_us: meta.timestamp.usec,
                    sequence: meta.sequence,
                },
            })
        }
    }

    /// Opens a V4L2 capture device, applies the configured format, rate and
    /// exposure, checks what the device applied, and maps its buffers.
    pub fn open_v4l2(config: &V4l2Config) -> Result<V4l2Source<V4l2Device>, CameraError> {
        let path = config.device_path();
        let io_err = |what: &'static str| {
            let device = path.clone();
            move |source: io::Error| CameraError::Io {
                device: device.clone(),
                what,
                source,
            }
        };
        let dev = Device::with_path(&path).map_err(|source| CameraError::Open {
            driver: "v4l2",
            device: path.clone(),
            hint: match source.kind() {
                io::ErrorKind::NotFound => "`v4l2-ctl --list-devices` lists the cameras; is it plugged in, is the index right",
                io::ErrorKind::PermissionDenied => "the user must be in the `video` group (or install systemd/99-rigslam.rules)",
                _ => "is another program streaming from it (`fuser /dev/video*`)",
            },
            source,
        })?;
        let caps = dev.query_caps().map_err(|source| CameraError::NotACamera {
            device: path.clone(),
            reason: format!("VIDIOC_QUERYCAP failed ({source})"),
            hint: "is this a V4L2 device node (/dev/videoN), not a serial port or a file",
        })?;
        use v4l::capability::Flags;
        if !caps.capabilities.contains(Flags::VIDEO_CAPTURE) {
            return Err(CameraError::NotACamera {
                device: path,
                reason: format!(
                    "{} ({}) has no single-planar video capture (capabilities {:?})",
                    caps.card, caps.driver, caps.capabilities
                ),
                hint: "UVC cameras expose a second /dev/videoN for metadata: try the other node",
            });
        }
        if !caps.capabilities.contains(Flags::STREAMING) {
            return Err(CameraError::NotACamera {
                device: path,
                reason: format!("{} does not support streaming I/O", caps.card),
                hint: "rigslam needs mmap streaming (V4L2_CAP_STREAMING)",
            });
        }
        let offered: Vec<[u8; 4]> = dev
            .enum_formats()
            .map_err(io_err("listing formats (VIDIOC_ENUM_FMT)"))?
            .iter()
            .map(|d| d.fourcc.repr)
            .collect();
        let current = dev
            .format()
            .map_err(io_err("reading the format (VIDIOC_G_FMT)"))?;
        let mut wanted = current;
        match config.format {
            Some(f) => wanted.fourcc = FourCC::new(&f.fourcc()),
            None => {
                if crate::camera::v4l2_format::WireFormat::from_fourcc(current.fourcc.repr)
                    .is_none()
                {
                    if let Some(f) = preferred_format(&offered) {
                        wanted.fourcc = FourCC::new(&f.fourcc());
                    }
                }
            }
        }
        if let Some(w) = config.width {
            wanted.width = w;
        }
        if let Some(h) = config.height {
            wanted.height = h;
        }
        let applied = if wanted.fourcc != current.fourcc
            || wanted.width != current.width
            || wanted.height != current.height
        {
            dev.set_format(&wanted)
                .map_err(io_err("setting the format (VIDIOC_S_FMT)"))?
        } else {
            current
        };
        let layout = negotiate(
            config,
            AppliedFormat {
                fourcc: applied.fourcc.repr,
                width: applied.width,
                height: applied.height,
                bytes_per_line: applied.stride,
            },
            &offered,
        )?;
        let nominal_rate_hz = match config.rate_hz {
            Some(hz) => {
                let params = dev
                    .set_params(&v4l::video::capture::Parameters::with_fps(hz))
                    .map_err(io_err("setting the frame rate (VIDIOC_S_PARM)"))?;
                rate_of(params.interval)
            }
            None => dev.params().ok().and_then(|p| rate_of(p.interval)),
        };
        if let Some(us) = config.exposure_us {
            // Manual mode first; devices without the auto control just lack it.
            let _ = dev.set_control(v4l::Control {
                id: CID_EXPOSURE_AUTO,
                value: v4l::control::Value::Integer(EXPOSURE_MANUAL),
            });
            dev.set_control(v4l::Control {
                id: CID_EXPOSURE_ABSOLUTE,
                value: v4l::control::Value::Integer(i64::from(us.div_ceil(100))),
            })
            .map_err(io_err(
                "setting the exposure (V4L2_CID_EXPOSURE_ABSOLUTE); `v4l2-ctl -l` lists the controls",
            ))?;
        }
        let exposure_us = match dev.control(CID_EXPOSURE_ABSOLUTE) {
            Ok(v4l::Control {
                value: v4l::control::Value::Integer(v),
                ..
            }) => Some(v as f64 * 100.0),
            _ => None,
        };
        let stream = Stream::with_buffers(&dev, Type::VideoCapture, config.buffers.max(2))
            .map_err(io_err("mapping the buffers (VIDIOC_REQBUFS/QUERYBUF/mmap)"))?;
        let info = CameraInfo {
            driver: "v4l2",
            device: path,
            name: format!("{} ({})", caps.card, caps.driver),
            bus: caps.bus,
            width: layout.width,
            height: layout.height,
            format: layout.format.output_format(),
            wire_format: fourcc_name(layout.format.fourcc()),
            nominal_rate_hz,
            exposure_us,
            // Refined from the first buffer's flags.
            timestamp_source: TimestampSource::HostReceipt,
        };
        Ok(V4l2Source::new(
            V4l2Device { stream },
            info,
            layout,
            config.camera_index,
        ))
    }

    fn rate_of(interval: v4l::Fraction) -> Option<f64> {
        (interval.numerator > 0)
            .then(|| f64::from(interval.denominator) / f64::from(interval.numerator))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::fake::ScriptedV4l2Stream;
    use crate::{BayerPattern, PixelFormat};

    fn info() -> CameraInfo {
        CameraInfo {
            driver: "v4l2",
            device: "/dev/video9".into(),
            name: "scripted".into(),
            bus: "test".into(),
            width: 4,
            height: 2,
            format: PixelFormat::Mono8,
            wire_format: "GREY".into(),
            nominal_rate_hz: Some(30.0),
            exposure_us: None,
            timestamp_source: TimestampSource::HostReceipt,
        }
    }

    fn meta(sequence: u32, flags: u32, t_s: i64, t_us: i64) -> BufferMeta {
        BufferMeta {
            bytes_used: 8,
            flags,
            timestamp_s: t_s,
            timestamp_us: t_us,
            sequence,
        }
    }

    const MONO_EOF: u32 = buf_flag::TIMESTAMP_MONOTONIC | buf_flag::TSTAMP_SRC_EOF;
    const MONO_SOE: u32 = buf_flag::TIMESTAMP_MONOTONIC | buf_flag::TSTAMP_SRC_SOE;

    #[test]
    fn stamps_follow_the_buffer_flags() {
        let m = meta(0, MONO_SOE, 12, 345_678);
        assert_eq!(
            frame_stamp(&m, Some(2_000_000), 99),
            (
                12_345_678_000 + 1_000_000,
                TimestampSource::MonotonicStartOfExposure
            )
        );
        let m = meta(0, MONO_EOF, 12, 345_678);
        assert_eq!(
            frame_stamp(&m, Some(2_000_000), 99),
            (
                12_345_678_000 - 1_000_000,
                TimestampSource::MonotonicEndOfFrame
            )
        );
        assert_eq!(
            frame_stamp(&m, None, 99),
            (12_345_678_000, TimestampSource::MonotonicEndOfFrame)
        );
        // Not on the monotonic clock: the device stamp is ignored.
        for clock in [buf_flag::TIMESTAMP_UNKNOWN, buf_flag::TIMESTAMP_COPY] {
            let m = meta(0, clock | buf_flag::TSTAMP_SRC_SOE, 12, 345_678);
            assert_eq!(
                frame_stamp(&m, Some(2_000_000), 99),
                (99, TimestampSource::HostReceipt)
            );
        }
    }

    #[test]
    fn frames_are_copied_out_and_gaps_counted() {
        let layout = FrameLayout::new(WireFormat::Grey, 4, 2, 0);
        let mut stream = ScriptedV4l2Stream::new();
        for (i, seq) in [5u32, 6, 9, 10].into_iter().enumerate() {
            stream.push(vec![i as u8; 8], meta(seq, MONO_EOF, 1, i as i64 * 33_000));
        }
        let mut source = V4l2Source::new(stream, info(), layout, 1);
        let t = Duration::from_millis(10);
        let f0 = source.next_frame(t).expect("scripted frame");
        let f1 = source.next_frame(t).expect("scripted frame");
        // The stream reuses one buffer; earlier frames must keep their pixels.
        assert_eq!(f0.image.data(), &[0; 8]);
        assert_eq!(f1.image.data(), &[1; 8]);
        assert_eq!((f0.seq, f1.seq, f1.camera_index), (5, 6, 1));
        assert_eq!(f1.t_ns - f0.t_ns, 33_000_000);
        let f2 = source.next_frame(t).expect("scripted frame");
        assert_eq!(f2.seq, 9);
        source.next_frame(t).expect("scripted frame");
        assert_eq!(
            source.stats(),
            CaptureStats {
                frames: 4,
                drops: 2,
                corrupt: 0
            }
        );
        assert_eq!(
            source.info().timestamp_source,
            TimestampSource::MonotonicEndOfFrame
        );
        assert!(matches!(
            source.next_frame(t),
            Err(CameraError::Timeout { timeout_ms: 10, .. })
        ));
    }

    #[test]
    fn corrupt_and_short_buffers_are_skipped_then_reported() {
        let layout = FrameLayout::new(WireFormat::Grey, 4, 2, 0);
        let mut stream = ScriptedV4l2Stream::new();
        stream.push(vec![1; 8], meta(0, MONO_EOF | buf_flag::ERROR, 0, 0));
        let mut short = meta(1, MONO_EOF, 0, 0);
        short.bytes_used = 5;
        stream.push(vec![2; 8], short);
        stream.push(vec![3; 8], meta(2, MONO_EOF, 0, 0));
        let mut source = V4l2Source::new(stream, info(), layout, 0);
        let f = source
            .next_frame(Duration::from_millis(1))
            .expect("third buffer is good");
        assert_eq!((f.seq, f.image.data()[0]), (2, 3));
        assert_eq!(source.stats().corrupt, 2);
        assert_eq!(source.stats().drops, 0);

        // A format mismatch makes every buffer short: an error, not a hang.
        let mut stream = ScriptedV4l2Stream::new();
        for seq in 0..MAX_CONSECUTIVE_BAD {
            let mut m = meta(seq, MONO_EOF, 0, 0);
            m.bytes_used = 4;
            stream.push(vec![0; 4], m);
        }
        let mut source = V4l2Source::new(stream, info(), layout, 0);
        let err = source
            .next_frame(Duration::from_millis(1))
            .expect_err("all buffers short");
        let text = err.to_string();
        assert!(matches!(
            err,
            CameraError::ShortBuffer {
                got: 4,
                needed: 8,
                ..
            }
        ));
        assert!(
            text.contains("/dev/video9") && text.contains("GREY"),
            "{text}"
        );
    }

    #[test]
    fn a_refused_format_names_what_was_asked_and_offered() {
        let mut config = V4l2Config::new("3");
        assert_eq!(config.device_path(), "/dev/video3");
        config.format = Some(WireFormat::Bayer8(BayerPattern::Rggb));
        config.width = Some(1024);
        let applied = AppliedFormat {
            fourcc: *b"YUYV",
            width: 640,
            height: 480,
            bytes_per_line: 1280,
        };
        let err = negotiate(&config, applied, &[*b"YUYV", *b"MJPG"]).expect_err("refused");
        let text = err.to_string();
        assert!(text.contains("/dev/video3"), "{text}");
        assert!(text.contains("RGGB 1024x(any)"), "{text}");
        assert!(text.contains("YUYV 640x480"), "{text}");
        assert!(text.contains("YUYV, MJPG"), "{text}");

        // Accepted as asked.
        config.format = Some(WireFormat::Yuyv);
        config.width = Some(640);
        let layout = negotiate(&config, applied, &[*b"YUYV"]).expect("accepted");
        assert_eq!(layout, FrameLayout::new(WireFormat::Yuyv, 640, 480, 1280));

        // Left in a format we cannot read.
        let mjpg = AppliedFormat {
            fourcc: *b"MJPG",
            ..applied
        };
        let err = negotiate(&V4l2Config::new("/dev/video0"), mjpg, &[*b"MJPG"])
            .expect_err("MJPG is not read");
        assert!(matches!(err, CameraError::UnsupportedFormat { .. }));
        assert!(err.to_string().contains("GREY"), "{err}");
        assert_eq!(
            preferred_format(&[*b"MJPG", *b"YUYV", *b"GREY"]),
            Some(WireFormat::Grey)
        );
    }

    #[test]
    fn a_missing_device_says_what_to_check() {
        let err = match open_v4l2(&V4l2Config::new("/dev/video-does-not-exist")) {
            Err(e) => e,
            Ok(_) => panic!("a device that does not exist opened"),
        };
        let text = err.to_string();
        assert!(matches!(err, CameraError::Open { .. }), "{text}");
        assert!(text.contains("/dev/video-does-not-exist"), "{text}");
        assert!(text.contains("v4l2-ctl --list-devices"), "{text}");
    }

    #[test]
    fn a_file_that_is_not_a_camera_is_rejected() {
        let err = match open_v4l2(&V4l2Config::new("/dev/null")) {
            Err(e) => e,
            Ok(_) => panic!("/dev/null opened as a camera"),
        };
        assert!(matches!(err, CameraError::NotACamera { .. }), "{err}");
    }
}
