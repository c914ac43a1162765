//! GigE Vision / USB3 Vision cameras through libaravis (feature `aravis`).
//!
//! Acquisition runs on Aravis's own stream thread into a fixed pool of
//! buffers allocated once at start; [`AravisSource::next_frame`] pops a
//! filled buffer, copies the image out into a pooled frame buffer and pushes
//! the Aravis buffer straight back, so the camera never starves while a
//! consumer holds a frame and steady state allocates nothing.
//!
//! Time: a frame carries two stamps. The camera's own (`arv_buffer_get_timestamp`,
//! the GigE Vision tick counter in ns, start of exposure on most cameras) is
//! kept as [`FrameSource::last_device_stamp_ns`]; the host `CLOCK_MONOTONIC`
//! time the frame's first packet arrived (Aravis stamps it on the real-time
//! clock; we move it onto the monotonic one, or take the time we popped it
//! when that stamp is implausible) bounds it from above. When the camera
//! has a clock, `t_ns` is the camera stamp mapped onto the host clock by
//! [`crate::clock_sync::ClockSync`] (offset and drift under the lower
//! envelope of arrival minus camera time, so transport delay does not leak
//! into the stamps); without one, `t_ns` is the arrival time.
//!
//! Drops are gaps in the frame ids (which also cover frames Aravis discarded
//! for want of a free buffer); incomplete frames (missing packets, timeouts)
//! are counted as corrupt and skipped.
//!
//! Tested against Aravis's fake GigE Vision camera on loopback
//! (`GvFakeCamera`, the camera `arv-fake-gv-camera-0.8` serves).

use std::time::Duration;

use aravis::prelude::*;
use aravis::{Buffer, BufferStatus, Camera, Stream};

use super::buffer_pool::BufferPool;
use super::genicam::{frame_id_gap, pixel_format, SUPPORTED_NAMES};
use super::source::{
    monotonic_now_ns, realtime_now_ns, CameraError, CameraInfo, CaptureStats, FrameSource,
    TimestampSource,
};
use crate::clock_sync::{ClockSync, ClockSyncConfig};
use crate::{Frame, Image};

/// What the user asked of the camera; `None` keeps the camera's setting.
#[derive(Debug, Clone, PartialEq)]
pub struct AravisConfig {
    /// Camera id as Aravis names it ("Vendor-Model-Serial"), or an IP
    /// address for GigE; `None` opens the first camera found.
    pub device: Option<String>,
    /// GenICam `PixelFormat` name ("Mono8", "BayerRG8", ...).
    pub pixel_format: Option<String>,
    /// Region of interest width, pixels (the region's offset is kept).
    pub width: Option<u32>,
    /// Region of interest height, pixels (the region's offset is kept).
    pub height: Option<u32>,
    /// `AcquisitionFrameRate`, frames per second.
    pub rate_hz: Option<f64>,
    /// `ExposureTime`, microseconds; an error when the camera lacks the
    /// feature.
    pub exposure_us: Option<f64>,
    /// Aravis buffers in the acquisition pool (at least 2 are used).
    pub buffers: usize,
    /// Which camera of the rig the frames are stamped with.
    pub camera_index: u8,
}

impl Default for AravisConfig {
    fn default() -> Self {
        Self {
            device: None,
            pixel_format: None,
            width: None,
            height: None,
            rate_hz: None,
            exposure_us: None,
            buffers: 8,
            camera_index: 0,
        }
    }
}

/// Frames a consumer may hold before capture allocates new frame buffers.
const POOLED_FRAMES: usize = 8;

/// An Aravis camera streaming into a buffer pool.
pub struct AravisSource {
    camera: Camera,
    stream: Stream,
    info: CameraInfo,
    bytes_per_pixel: usize,
    camera_index: u8,
    pool: BufferPool,
    last_frame_id: Option<u64>,
    last_device_stamp_ns: Option<i64>,
    clock: ClockSync,
    last_t_ns: Option<i64>,
    stats: CaptureStats,
    seq: u64,
}

fn glib_err<'a>(
    device: &'a str,
    what: &'static str,
) -> impl Fn(aravis::glib::Error) -> CameraError + 'a {
    move |e| CameraError::Driver {
        device: device.to_string(),
        message: format!("{what}: {e}"),
    }
}

/// Opens an Aravis camera, applies the configuration, checks what the
/// camera applied, allocates the buffer pool and starts acquisition.
pub fn open_aravis(config: &AravisConfig) -> Result<AravisSource, CameraError> {
    let device = config
        .device
        .clone()
        .unwrap_or_else(|| "(first camera found)".into());
    let camera = Camera::new(config.device.as_deref()).map_err(|e| CameraError::Open {
        driver: "aravis",
        device: device.clone(),
        source: std::io::Error::new(std::io::ErrorKind::NotFound, e.to_string()),
        hint: "is the camera powered; GigE: on the host's subnet or given by its IP address, UDP 3956 not firewalled; USB3: udev permissions; `arv-camera-test-0.8 -n ID` (Debian aravis-tools) tries the same id",
    })?;
    let err = |what| glib_err(&device, what);

    if let Some(name) = &config.pixel_format {
        let offered = camera
            .dup_available_pixel_formats_as_strings()
            .map(|v| {
                v.iter()
                    .map(|s| s.to_string())
                    .collect::<Vec<_>>()
                    .join(", ")
            })
            .unwrap_or_else(|_| "(the camera does not list them)".into());
        let set = camera.set_pixel_format_from_string(name);
        let got = camera
            .pixel_format_as_string()
            .map(|s| s.to_string())
            .unwrap_or_default();
        if set.is_err() || got != *name {
            return Err(CameraError::FormatRefused {
                device,
                requested: name.clone(),
                got: if got.is_empty() {
                    "nothing".into()
                } else {
                    got
                },
                offered,
            });
        }
    }
    if config.width.is_some() || config.height.is_some() {
        let (x, y, w, h) = camera.region().map_err(err("reading the region"))?;
        let want_w = config.width.map_or(w, |v| v as i32);
        let want_h = config.height.map_or(h, |v| v as i32);
        // Aravis does not range-check features by default: check the
        // camera's bounds ourselves, then what it applied.
        let bounds = (camera.width_bounds(), camera.height_bounds());
        let in_bounds = match bounds {
            (Ok((w0, w1)), Ok((h0, h1))) => {
                (w0..=w1).contains(&want_w) && (h0..=h1).contains(&want_h)
            }
            _ => true,
        };
        let set = if in_bounds {
            camera.set_region(x, y, want_w, want_h)
        } else {
            Ok(())
        };
        let (_, _, got_w, got_h) = camera.region().map_err(err("reading the region"))?;
        if !in_bounds || set.is_err() || (got_w, got_h) != (want_w, want_h) {
            let offered = match bounds {
                (Ok((w0, w1)), Ok((h0, h1))) => format!("width {w0}..={w1}, height {h0}..={h1}"),
                _ => "(bounds unknown)".into(),
            };
            return Err(CameraError::FormatRefused {
                device,
                requested: format!("{want_w}x{want_h}"),
                got: format!("{got_w}x{got_h}"),
                offered,
            });
        }
    }
    if let Some(hz) = config.rate_hz {
        camera
            .set_frame_rate(hz)
            .map_err(err("setting AcquisitionFrameRate"))?;
    }
    if let Some(us) = config.exposure_us {
        if camera.is_exposure_time_available().unwrap_or(false) {
            camera
                .set_exposure_time(us)
                .map_err(err("setting ExposureTime"))?;
        } else {
            return Err(CameraError::Driver {
                device,
                message: "the camera has no ExposureTime feature; drop --exposure-us".into(),
            });
        }
    }

    let wire_format = camera
        .pixel_format_as_string()
        .map_err(err("reading PixelFormat"))?
        .to_string();
    let Some(format) = pixel_format(&wire_format) else {
        return Err(CameraError::UnsupportedFormat {
            device,
            offered: camera
                .dup_available_pixel_formats_as_strings()
                .map(|v| {
                    v.iter()
                        .map(|s| s.to_string())
                        .collect::<Vec<_>>()
                        .join(", ")
                })
                .unwrap_or_default(),
            wire_format,
            supported: SUPPORTED_NAMES.join(", "),
        });
    };
    let (_, _, width, height) = camera.region().map_err(err("reading the region"))?;
    let name = format!(
        "{} {}",
        camera
            .vendor_name()
            .map(|s| s.to_string())
            .unwrap_or_default(),
        camera
            .model_name()
            .map(|s| s.to_string())
            .unwrap_or_default()
    );
    let serial = camera
        .device_serial_number()
        .map(|s| s.to_string())
        .unwrap_or_default();
    let nominal_rate_hz = camera.frame_rate().ok();
    let exposure_us = camera.exposure_time().ok();
    let payload = camera.payload().map_err(err("reading PayloadSize"))?;

    let stream = camera
        .create_stream()
        .map_err(err("creating the stream (GVSP socket / USB endpoint)"))?;
    for _ in 0..config.buffers.max(2) {
        stream.push_buffer(Buffer::new_allocate(payload as usize));
    }
    camera
        .start_acquisition()
        .map_err(err("starting acquisition (AcquisitionStart)"))?;

    Ok(AravisSource {
        camera,
        stream,
        info: CameraInfo {
            driver: "aravis",
            device,
            name,
            bus: serial,
            width: width as u32,
            height: height as u32,
            format,
            wire_format,
            nominal_rate_hz,
            exposure_us,
            timestamp_source: TimestampSource::HostReceipt,
        },
        bytes_per_pixel: format.bytes_per_pixel(),
        camera_index: config.camera_index,
        pool: BufferPool::new(POOLED_FRAMES),
        last_frame_id: None,
        last_device_stamp_ns: None,
        clock: ClockSync::new(ClockSyncConfig::default()),
        last_t_ns: None,
        stats: CaptureStats::default(),
        seq: 0,
    })
}

impl AravisSource {
    /// Aravis's own counters: (completed buffers, failures, underruns).
    pub fn stream_statistics(&self) -> (u64, u64, u64) {
        self.stream.statistics()
    }

    /// Copies the image out of a successful buffer.
    fn copy_out(&mut self, buffer: &Buffer) -> Result<Image, CameraError> {
        let width = buffer.image_width().max(0) as usize;
        let height = buffer.image_height().max(0) as usize;
        let (x_padding, _) = buffer.image_padding();
        let row = width * self.bytes_per_pixel;
        let stride = row + x_padding.max(0) as usize;
        let (ptr, len) = buffer.data();
        let needed = if height == 0 {
            0
        } else {
            stride * (height - 1) + row
        };
        if ptr.is_null() || len < needed || width == 0 || height == 0 {
            return Err(CameraError::ShortBuffer {
                device: self.info.device.clone(),
                wire_format: self.info.wire_format.clone(),
                width: width as u32,
                height: height as u32,
                got: if ptr.is_null() { 0 } else { len },
                needed,
            });
        }
        // SAFETY: Aravis owns `len` bytes at `ptr` for as long as we hold
        // `buffer` (it is out of the stream's queue until we push it back),
        // and nothing writes to it meanwhile.
        let data = unsafe { std::slice::from_raw_parts(ptr as *const u8, len) };
        let pixels = self.pool.take(row * height, |out| {
            for (y, dst) in out.chunks_exact_mut(row).enumerate() {
                dst.copy_from_slice(&data[y * stride..y * stride + row]);
            }
        });
        Image::new(width as u32, height as u32, row, self.info.format, pixels).map_err(|source| {
            CameraError::Frame {
                device: self.info.device.clone(),
                source,
            }
        })
    }
}

/// Host monotonic time of a frame from Aravis's real-time arrival stamp,
/// or `popped_ns` when that stamp is missing or implausible (after the pop,
/// or more than a second before it).
fn arrival_ns(system_timestamp_ns: u64, realtime_minus_monotonic_ns: i64, popped_ns: i64) -> i64 {
    if system_timestamp_ns == 0 {
        return popped_ns;
    }
    let arrival = system_timestamp_ns as i64 - realtime_minus_monotonic_ns;
    if arrival <= popped_ns && popped_ns - arrival < crate::NS_PER_S {
        arrival
    } else {
        popped_ns
    }
}

impl AravisSource {
    /// The frame's host time: the camera stamp through the clock fit when
    /// the camera has a clock, never after the arrival and always
    /// increasing; the arrival time otherwise.
    fn host_stamp(&mut self, device_ns: i64, arrival_ns: i64) -> i64 {
        let t_ns = if device_ns > 0 {
            self.clock.observe(device_ns, arrival_ns);
            self.info.timestamp_source = TimestampSource::CameraClock;
            self.clock
                .to_host_ns(device_ns)
                .unwrap_or(arrival_ns)
                .min(arrival_ns)
        } else {
            arrival_ns
        };
        let t_ns = match self.last_t_ns {
            Some(last) => t_ns.max(last + 1),
            None => t_ns,
        };
        self.last_t_ns = Some(t_ns);
        t_ns
    }

    /// The camera clock's fitted offset and drift against the host clock.
    pub fn clock_estimate(&self) -> Option<crate::clock_sync::ClockEstimate> {
        self.clock.estimate()
    }
}

impl FrameSource for AravisSource {
    fn info(&self) -> &CameraInfo {
        &self.info
    }

    fn stats(&self) -> CaptureStats {
        self.stats
    }

    fn last_device_stamp_ns(&self) -> Option<i64> {
        self.last_device_stamp_ns
    }

    fn next_frame(&mut self, timeout: Duration) -> Result<Frame, CameraError> {
        let deadline = std::time::Instant::now() + timeout;
        loop {
            let left = deadline.saturating_duration_since(std::time::Instant::now());
            let Some(buffer) = self
                .stream
                .timeout_pop_buffer(left.as_micros().max(1) as u64)
            else {
                return Err(CameraError::Timeout {
                    device: self.info.device.clone(),
                    timeout_ms: timeout.as_millis() as u64,
                });
            };
            let popped_ns = monotonic_now_ns();
            let offset_ns = realtime_now_ns() - monotonic_now_ns();
            let frame_id = buffer.frame_id();
            if let Some(previous) = self.last_frame_id {
                self.stats.drops += frame_id_gap(previous, frame_id);
            }
            self.last_frame_id = Some(frame_id);
            let result = if buffer.status() == BufferStatus::Success {
                self.copy_out(&buffer).map(|image| {
                    (
                        image,
                        arrival_ns(buffer.system_timestamp(), offset_ns, popped_ns),
                        buffer.timestamp() as i64,
                    )
                })
            } else {
                Err(CameraError::Driver {
                    device: self.info.device.clone(),
                    message: format!("incomplete frame ({:?})", buffer.status()),
                })
            };
            self.stream.push_buffer(buffer);
            match result {
                Ok((image, arrival_t_ns, device_ns)) => {
                    let t_ns = self.host_stamp(device_ns, arrival_t_ns);
                    self.last_device_stamp_ns = Some(device_ns);
                    self.stats.frames += 1;
                    let frame = Frame {
                        t_ns,
                        seq: self.seq,
                        camera_index: self.camera_index,
                        image,
                    };
                    self.seq += 1;
                    return Ok(frame);
                }
                Err(e) => {
                    self.stats.corrupt += 1;
                    if std::time::Instant::now() >= deadline {
                        return Err(e);
                    }
                }
            }
        }
    }
}

impl Drop for AravisSource {
    fn drop(&mut self) {
        // Best effort: a camera that vanished cannot be stopped.
        let _ = self.camera.stop_acquisition();
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::Mutex;

    /// The fake camera listens on the fixed GVCP port 3956: one at a time.
    static FAKE_CAMERA: Mutex<()> = Mutex::new(());

    #[test]
    fn arrival_prefers_the_packet_stamp_when_plausible() {
        let offset = 1_000_000_000_000;
        assert_eq!(arrival_ns(offset as u64 + 5_000, offset, 9_000), 5_000);
        assert_eq!(arrival_ns(0, offset, 9_000), 9_000);
        // After the pop or more than 1 s before it: not believed.
        assert_eq!(arrival_ns(offset as u64 + 10_000, offset, 9_000), 9_000);
        assert_eq!(
            arrival_ns(offset as u64, offset, 2_000_000_000),
            2_000_000_000
        );
    }

    #[test]
    fn streams_from_the_fake_gige_camera_on_loopback() {
        let _one = FAKE_CAMERA.lock().unwrap_or_else(|e| e.into_inner());
        let fake = aravis::GvFakeCamera::new(Some("127.0.0.1"), Some("GV01"));
        assert!(
            fake.is_running(),
            "the fake camera could not bind 127.0.0.1:3956"
        );
        let config = AravisConfig {
            device: Some("127.0.0.1".into()),
            pixel_format: Some("Mono8".into()),
            width: Some(320),
            height: Some(240),
            rate_hz: Some(50.0),
            ..AravisConfig::default()
        };
        let mut source = open_aravis(&config).expect("the fake camera opens");
        let info = source.info().clone();
        assert_eq!(
            (info.width, info.height, info.wire_format.as_str()),
            (320, 240, "Mono8")
        );
        assert!(info.name.contains("Aravis"), "{}", info.name);
        let mut frames = Vec::new();
        for _ in 0..20 {
            frames.push(source.next_frame(Duration::from_secs(3)).expect("a frame"));
        }
        for frame in &frames {
            let img = &frame.image;
            assert_eq!((img.width(), img.height()), (320, 240));
            // The fake camera's diagonal ramp: (x + y + frame id) mod 255
            // (at its default gain and exposure); find the frame's offset
            // from pixel (0, 0) and check every pixel against it.
            let k = u32::from(img.data()[0]);
            for (y, x) in [(0u32, 1u32), (10, 7), (239, 319), (100, 200)] {
                let want = ((x + y + k) % 255) as u8;
                assert_eq!(img.grey8_at(x, y), Some(want), "pixel ({x},{y})");
            }
        }
        for pair in frames.windows(2) {
            assert!(pair[1].t_ns > pair[0].t_ns, "host stamps increase");
            assert_eq!(pair[1].seq, pair[0].seq + 1);
        }
        let device_stamp = source.last_device_stamp_ns().expect("camera stamp");
        assert!(device_stamp > 0);
        // The fake camera has a clock: stamps come from it through the fit.
        assert_eq!(source.info().timestamp_source, TimestampSource::CameraClock);
        assert!(source.clock_estimate().is_some());
        // Stamped by the camera's clock, frames can not come closer than
        // its 50 Hz, however they reach the host (in bursts on a loaded
        // machine). Only this bound is checked: on a shared machine the
        // fake camera itself may run slower (28 Hz seen under load), and
        // speed is not what this test is about.
        let span_s = (frames[19].t_ns - frames[0].t_ns) as f64 * 1e-9;
        let rate = 19.0 / span_s;
        assert!(rate < 55.0, "measured {rate:.1} Hz from a 50 Hz camera");
        assert_eq!(source.stats().frames, 20);
        assert_eq!(source.stats().drops, 0, "nothing lost on loopback");
        drop(source);

        // The same camera refusing a format and a size it does not have.
        let refused = AravisConfig {
            pixel_format: Some("BayerRG12p".into()),
            ..config.clone()
        };
        let err = open_aravis(&refused).err().expect("format refused");
        let text = err.to_string();
        assert!(matches!(err, CameraError::FormatRefused { .. }), "{text}");
        assert!(
            text.contains("BayerRG12p") && text.contains("Mono8"),
            "{text}"
        );
        let too_big = AravisConfig {
            width: Some(100_000),
            ..config.clone()
        };
        let err = open_aravis(&too_big).err().expect("size refused");
        assert!(err.to_string().contains("100000x240"), "{err}");
        drop(fake);
    }

    #[test]
    fn a_camera_that_does_not_exist_says_what_to_check() {
        let _one = FAKE_CAMERA.lock().unwrap_or_else(|e| e.into_inner());
        let config = AravisConfig {
            device: Some("NoSuchVendor-NoSuchModel-0000".into()),
            ..AravisConfig::default()
        };
        let err = open_aravis(&config).err().expect("no such camera");
        let text = err.to_string();
        assert!(matches!(err, CameraError::Open { .. }), "{text}");
        assert!(
            text.contains("NoSuchVendor-NoSuchModel-0000") && text.contains("arv-camera-test"),
            "{text}"
        );
    }
}
