//! Cameras without hardware: a scripted V4L2 stream for the driver tests and
//! a pattern camera that `rigslam camera --driver fake` and the pipeline
//! tests read like a real one.

use std::collections::VecDeque;
use std::io;
use std::time::Duration;

use super::source::{
    monotonic_now_ns, CameraError, CameraInfo, CaptureStats, FrameSource, TimestampSource,
};
use super::v4l2::{BufferMeta, RawBuffer, V4l2Stream};
use crate::{Frame, Image, PixelFormat};

/// A [`V4l2Stream`] that plays back buffers pushed in advance, reusing one
/// mapped buffer like a real driver, so a reader that kept a slice instead
/// of copying would see it change. Empty: `TimedOut`.
#[derive(Debug, Default)]
pub struct ScriptedV4l2Stream {
    queued: VecDeque<(Vec<u8>, BufferMeta)>,
    mapped: Vec<u8>,
}

impl ScriptedV4l2Stream {
    /// An empty script.
    pub fn new() -> Self {
        Self::default()
    }

    /// Queues a buffer's bytes and what the driver says about it.
    pub fn push(&mut self, bytes: Vec<u8>, meta: BufferMeta) {
        self.queued.push_back((bytes, meta));
    }
}

impl V4l2Stream for ScriptedV4l2Stream {
    fn dequeue(&mut self, _timeout: Duration) -> io::Result<RawBuffer<'_>> {
        let Some((bytes, meta)) = self.queued.pop_front() else {
            return Err(io::Error::new(io::ErrorKind::TimedOut, "script exhausted"));
        };
        self.mapped.clear();
        self.mapped.extend_from_slice(&bytes);
        Ok(RawBuffer {
            bytes: &self.mapped,
            meta,
        })
    }
}

/// A camera that renders a moving diagonal ramp at a fixed rate on the host
/// clock: frame `k` has pixel `(x, y)` = `(x + y + k) mod 256`.
pub struct PatternCamera {
    info: CameraInfo,
    period_ns: i64,
    next_t_ns: i64,
    seq: u64,
}

impl PatternCamera {
    /// A Mono8 camera of `width` x `height` pixels at `rate_hz` frames per
    /// second. Frame 0 is stamped with the host `CLOCK_MONOTONIC` time of
    /// this call, each later frame one period after the previous one;
    /// [`FrameSource::next_frame`] sleeps until a frame's stamp.
    pub fn new(width: u32, height: u32, rate_hz: f64) -> Self {
        Self {
            info: CameraInfo {
                driver: "fake",
                device: "pattern".into(),
                name: "rigslam pattern camera".into(),
                bus: "none".into(),
                width,
                height,
                format: PixelFormat::Mono8,
                wire_format: "Mono8".into(),
                nominal_rate_hz: Some(rate_hz),
                exposure_us: None,
                timestamp_source: TimestampSource::HostReceipt,
            },
            period_ns: (1e9 / rate_hz).round() as i64,
            next_t_ns: monotonic_now_ns(),
            seq: 0,
        }
    }

    /// The pixels of frame `seq`.
    pub fn pattern(width: u32, height: u32, seq: u64) -> Vec<u8> {
        let mut px = Vec::with_capacity(width as usize * height as usize);
        for y in 0..height as u64 {
            for x in 0..width as u64 {
                px.push(((x + y + seq) % 256) as u8);
            }
        }
        px
    }
}

impl FrameSource for PatternCamera {
    fn info(&self) -> &CameraInfo {
        &self.info
    }

    fn next_frame(&mut self, timeout: Duration) -> Result<Frame, CameraError> {
        let wait_ns = self.next_t_ns - monotonic_now_ns();
        if wait_ns > timeout.as_nanos() as i64 {
            std::thread::sleep(timeout);
            return Err(CameraError::Timeout {
                device: self.info.device.clone(),
                timeout_ms: timeout.as_millis() as u64,
            });
        }
        if wait_ns > 0 {
            std::thread::sleep(Duration::from_nanos(wait_ns as u64));
        }
        let image = Image::mono8(
            self.info.width,
            self.info.height,
            Self::pattern(self.info.width, self.info.height, self.seq),
        )
        .map_err(|source| CameraError::Frame {
            device: self.info.device.clone(),
            source,
        })?;
        let frame = Frame {
            t_ns: self.next_t_ns,
            seq: self.seq,
            camera_index: 0,
            image,
        };
        self.seq += 1;
        self.next_t_ns += self.period_ns;
        Ok(frame)
    }

    fn stats(&self) -> CaptureStats {
        CaptureStats {
            frames: self.seq,
            drops: 0,
            corrupt: 0,
        }
    }
}
