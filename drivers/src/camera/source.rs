//! The [`FrameSource`] trait every camera driver implements, what a source
//! says about itself ([`CameraInfo`]), its counters ([`CaptureStats`]) and
//! the errors a user sees ([`CameraError`]).
//!
//! Two pieces of bookkeeping are shared by the drivers and kept pure here so
//! they are tested without hardware: [`SequenceCounter`] turns a driver's
//! wrapping 32-bit frame counter into a 64-bit sequence and counts the gaps
//! as drops, and [`TimestampSource`] names which clock and which instant of
//! the exposure a frame's `t_ns` comes from.

use std::time::Duration;

use crate::{Frame, FrameError, PixelFormat};

/// Where a frame's `t_ns` comes from. Printed by `rigslam camera` so the
/// user knows what the clock-alignment stage has to correct.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TimestampSource {
    /// Kernel `CLOCK_MONOTONIC` stamp taken at the start of exposure
    /// (V4L2 `TSTAMP_SRC_SOE`); `t_ns` adds half the exposure when known.
    MonotonicStartOfExposure,
    /// Kernel `CLOCK_MONOTONIC` stamp taken when the last byte of the frame
    /// arrived (V4L2 `TSTAMP_SRC_EOF`); `t_ns` subtracts half the exposure
    /// when known, the readout time is left to the camera-IMU time shift.
    MonotonicEndOfFrame,
    /// The camera's own clock (GigE Vision tick counter), mapped onto the
    /// host clock by an offset-and-drift fit under the arrival times
    /// (`clock_sync`).
    CameraClock,
    /// The host's `CLOCK_MONOTONIC` when the driver handed us the buffer:
    /// the fallback when the device's stamps are not monotonic-clock stamps.
    HostReceipt,
}

impl TimestampSource {
    /// snake_case name for reports (`--json`).
    pub fn name(self) -> &'static str {
        match self {
            TimestampSource::MonotonicStartOfExposure => "monotonic_start_of_exposure",
            TimestampSource::MonotonicEndOfFrame => "monotonic_end_of_frame",
            TimestampSource::CameraClock => "camera_clock",
            TimestampSource::HostReceipt => "host_receipt",
        }
    }
}

/// What a source says about itself once opened.
#[derive(Debug, Clone, PartialEq)]
pub struct CameraInfo {
    /// Driver family: "v4l2", "aravis", "fake".
    pub driver: &'static str,
    /// What the user passed to open it (a path, an index, a camera id).
    pub device: String,
    /// The device's own name (V4L2 card, GenICam vendor + model).
    pub name: String,
    /// Bus or serial number, whatever identifies the unit.
    pub bus: String,
    /// Frame width the source hands out, pixels.
    pub width: u32,
    /// Frame height the source hands out, pixels.
    pub height: u32,
    /// Format of the frames the source hands out.
    pub format: PixelFormat,
    /// The device's own name for its wire format (V4L2 FourCC "YUYV",
    /// GenICam "Mono8").
    pub wire_format: String,
    /// Nominal frame rate the device was set to, when it says.
    pub nominal_rate_hz: Option<f64>,
    /// Exposure time the device reports, when it has such a control.
    pub exposure_us: Option<f64>,
    /// Where `t_ns` comes from; may be refined after the first frame (V4L2
    /// says it per buffer).
    pub timestamp_source: TimestampSource,
}

/// Counters of a running source.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct CaptureStats {
    /// Frames handed out.
    pub frames: u64,
    /// Frames the device produced that never reached us (sequence gaps,
    /// buffers the transport lost).
    pub drops: u64,
    /// Buffers that arrived flagged as corrupt or short and were skipped.
    pub corrupt: u64,
}

/// A camera: something that hands out timestamped frames one at a time.
///
/// Frames own their pixels (an `Arc<[u8]>`), never a view into a driver
/// buffer: the driver may reuse its buffer as soon as `next_frame` returns.
pub trait FrameSource {
    /// Identity, format and timestamp source.
    fn info(&self) -> &CameraInfo;
    /// The next frame, waiting at most `timeout`.
    fn next_frame(&mut self, timeout: Duration) -> Result<Frame, CameraError>;
    /// Counters so far.
    fn stats(&self) -> CaptureStats;
    /// The last frame's stamp on the device's own clock, when it has one
    /// (GigE Vision timestamp), for the clock-alignment stage to map onto
    /// the host clock; `None` when `t_ns` already is host time.
    fn last_device_stamp_ns(&self) -> Option<i64> {
        None
    }
}

impl<S: FrameSource + ?Sized> FrameSource for Box<S> {
    fn info(&self) -> &CameraInfo {
        (**self).info()
    }
    fn next_frame(&mut self, timeout: Duration) -> Result<Frame, CameraError> {
        (**self).next_frame(timeout)
    }
    fn stats(&self) -> CaptureStats {
        (**self).stats()
    }
    fn last_device_stamp_ns(&self) -> Option<i64> {
        (**self).last_device_stamp_ns()
    }
}

/// Why a camera could not be opened or read. Every variant names the device
/// and says what was tried; the opening errors also say what to check.
#[derive(Debug, thiserror::Error)]
pub enum CameraError {
    /// The device could not be opened (missing, no permission, busy).
    #[error("cannot open {driver} camera {device}: {source}; check: {hint}")]
    Open {
        /// Driver family: "v4l2", "aravis".
        driver: &'static str,
        /// The device as the user named it.
        device: String,
        /// The OS or library error (Aravis errors are wrapped as `NotFound`).
        source: std::io::Error,
        /// What to check, for the user.
        hint: &'static str,
    },
    /// The device opened but cannot stream video (no capture or streaming
    /// capability, or not a V4L2 node at all).
    #[error("{device} is not a camera we can stream from: {reason}; check: {hint}")]
    NotACamera {
        /// Device path.
        device: String,
        /// What the device lacks.
        reason: String,
        /// What to check, for the user.
        hint: &'static str,
    },
    /// The device applied a different pixel format or size than was asked.
    #[error("{device} refused format {requested}: it set {got} instead; the device offers {offered}; check: pick one of those with --format/--width/--height")]
    FormatRefused {
        /// Device path or camera id.
        device: String,
        /// Format and size asked for, as text ("RGGB 1024x(any)").
        requested: String,
        /// Format and size the device applied, as text.
        got: String,
        /// Formats (V4L2) or size bounds / format names (Aravis) the device
        /// offers, as text.
        offered: String,
    },
    /// The device streams a format this crate cannot turn into a [`Frame`].
    #[error("{device} streams {wire_format}, which rigslam does not read; it offers {offered}; rigslam reads {supported}")]
    UnsupportedFormat {
        /// Device path or camera id.
        device: String,
        /// The device's name for the format it streams (FourCC or GenICam name).
        wire_format: String,
        /// Formats the device offers, comma-separated.
        offered: String,
        /// Formats this driver reads, comma-separated.
        supported: String,
    },
    /// A device call (ioctl, mmap) failed.
    #[error("{device}: {what} failed: {source}")]
    Io {
        /// Device path.
        device: String,
        /// The step that failed, naming the ioctl ("dequeueing a buffer (VIDIOC_DQBUF)").
        what: &'static str,
        /// The OS error.
        source: std::io::Error,
    },
    /// No frame arrived within the timeout given to
    /// [`FrameSource::next_frame`].
    #[error("{device}: no frame within {timeout_ms} ms; check: is the camera triggered or streaming, is the cable/link up")]
    Timeout {
        /// Device path or camera id.
        device: String,
        /// The timeout that expired, milliseconds.
        timeout_ms: u64,
    },
    /// Buffers shorter than one frame kept arriving (V4L2: several in a
    /// row; Aravis: until the timeout).
    #[error("{device}: buffer of {got} B is shorter than a {width}x{height} {wire_format} frame of {needed} B")]
    ShortBuffer {
        /// Device path or camera id.
        device: String,
        /// The device's name for the format (FourCC or GenICam name).
        wire_format: String,
        /// Frame width, pixels.
        width: u32,
        /// Frame height, pixels.
        height: u32,
        /// Bytes the buffer held.
        got: usize,
        /// Bytes one frame needs.
        needed: usize,
    },
    /// The captured bytes did not make a valid [`Image`](crate::Image).
    #[error("{device}: {source}")]
    Frame {
        /// Device path or camera id.
        device: String,
        /// Why the image was rejected.
        #[source]
        source: FrameError,
    },
    /// Any other driver or library failure (corrupt buffers in a row,
    /// incomplete frames, a GenICam feature that could not be set).
    #[error("{device}: {message}")]
    Driver {
        /// Device path or camera id.
        device: String,
        /// What failed, in words.
        message: String,
    },
}

/// Extends a driver's wrapping 32-bit frame counter to 64 bits and counts
/// the frames missing between consecutive buffers.
///
/// A counter that steps back by more than half its range is taken as a
/// wrap; one that steps back by less (a driver restarting its stream) starts
/// a new run without counting drops.
#[derive(Debug, Clone, Default)]
pub struct SequenceCounter {
    last_raw: Option<u32>,
    extended: u64,
    drops: u64,
}

impl SequenceCounter {
    /// A counter that has seen no buffer yet.
    pub fn new() -> Self {
        Self::default()
    }

    /// Records buffer `raw_seq`; returns its 64-bit sequence number and the
    /// number of frames lost just before it.
    pub fn observe(&mut self, raw_seq: u32) -> (u64, u64) {
        let Some(last) = self.last_raw else {
            self.last_raw = Some(raw_seq);
            self.extended = u64::from(raw_seq);
            return (self.extended, 0);
        };
        let step = raw_seq.wrapping_sub(last);
        let lost = if step == 0 || step > u32::MAX / 2 {
            // Repeated or restarted counter: a new run, nothing provably lost.
            self.extended += 1;
            0
        } else {
            self.extended += u64::from(step);
            u64::from(step - 1)
        };
        self.last_raw = Some(raw_seq);
        self.drops += lost;
        (self.extended, lost)
    }

    /// Frames lost so far.
    pub fn drops(&self) -> u64 {
        self.drops
    }
}

/// Host `CLOCK_MONOTONIC` now, in nanoseconds (the clock of every live `t_ns`).
pub fn monotonic_now_ns() -> i64 {
    // std's Instant reads CLOCK_MONOTONIC on Linux but hides its value, and
    // V4L2 stamps are absolute CLOCK_MONOTONIC values: read the clock itself.
    monotonic::now_ns()
}

/// Host `CLOCK_REALTIME` now, in nanoseconds (only to move stamps that
/// libraries take on the wall clock onto the monotonic one).
pub fn realtime_now_ns() -> i64 {
    monotonic::clock_ns(monotonic::CLOCK_REALTIME)
}

mod monotonic {
    #[repr(C)]
    struct Timespec {
        tv_sec: i64,
        tv_nsec: i64,
    }
    extern "C" {
        fn clock_gettime(clock_id: i32, tp: *mut Timespec) -> i32;
    }
    pub const CLOCK_REALTIME: i32 = 0;
    const CLOCK_MONOTONIC: i32 = 1;

    pub fn now_ns() -> i64 {
        clock_ns(CLOCK_MONOTONIC)
    }

    pub fn clock_ns(clock_id: i32) -> i64 {
        let mut ts = Timespec {
            tv_sec: 0,
            tv_nsec: 0,
        };
        // SAFETY: `ts` is a valid, writable timespec (64-bit Linux layout);
        // clock_gettime cannot fail for a valid clock id and pointer.
        let rc = unsafe { clock_gettime(clock_id, &mut ts) };
        assert_eq!(
            rc, 0,
            "clock_gettime cannot fail for a valid clock and pointer"
        );
        ts.tv_sec * crate::NS_PER_S + ts.tv_nsec
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sequence_gaps_are_drops() {
        let mut c = SequenceCounter::new();
        assert_eq!(c.observe(10), (10, 0));
        assert_eq!(c.observe(11), (11, 0));
        assert_eq!(c.observe(14), (14, 2));
        assert_eq!(c.observe(15), (15, 0));
        assert_eq!(c.drops(), 2);
    }

    #[test]
    fn sequence_wraps_at_32_bits() {
        let mut c = SequenceCounter::new();
        c.observe(u32::MAX - 1);
        assert_eq!(c.observe(u32::MAX), (u64::from(u32::MAX), 0));
        assert_eq!(c.observe(1), (u64::from(u32::MAX) + 2, 1));
        assert_eq!(c.drops(), 1);
    }

    #[test]
    fn restarted_counter_is_not_a_drop() {
        let mut c = SequenceCounter::new();
        c.observe(500);
        let (seq, lost) = c.observe(0);
        assert_eq!((seq, lost), (501, 0));
        assert_eq!(c.observe(1), (502, 0));
        assert_eq!(c.drops(), 0);
    }

    #[test]
    fn monotonic_clock_advances() {
        let a = monotonic_now_ns();
        let b = monotonic_now_ns();
        assert!(a > 0 && b >= a);
    }
}
