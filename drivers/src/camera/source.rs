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
    pub width: u32,
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
    #[error("cannot open {driver} camera {device}: {source}; check: {hint}")]
    Open {
        driver: &'static str,
        device: String,
        source: std::io::Error,
        hint: &'static str,
    },
    #[error("{device} is not a camera we can stream from: {reason}; check: {hint}")]
    NotACamera {
        device: String,
        reason: String,
        hint: &'static str,
    },
    #[error("{device} refused format {requested}: it set {got} instead; the device offers {offered}; check: pick one of those with --format/--width/--height")]
    FormatRefused {
        device: String,
        requested: String,
        got: String,
        offered: String,
    },
    #[error("{device} streams {wire_format}, which rigslam does not read; it offers {offered}; rigslam reads {supported}")]
    UnsupportedFormat {
        device: String,
        wire_format: String,
        offered: String,
        supported: String,
    },
    #[error("{device}: {what} failed: {source}")]
    Io {
        device: String,
        what: &'static str,
        source: std::io::Error,
    },
    #[error("{device}: no frame within {timeout_ms} ms; check: is the camera triggered or streaming, is the cable/link up")]
    Timeout { device: String, timeout_ms: u64 },
    #[error("{device}: buffer of {got} B is shorter than a {width}x{height} {wire_format} frame of {needed} B")]
    ShortBuffer {
        device: String,
        wire_format: String,
        width: u32,
        height: u32,
        got: usize,
        needed: usize,
    },
    #[error("{device}: {source}")]
    Frame {
        device: String,
        #[source]
        source: FrameError,
    },
    #[error("{device}: {message}")]
    Driver { device: String, message: String },
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
