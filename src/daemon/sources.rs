//! The threads that read sensors (or a recording) and feed the queues.
//! A live driver read is never blocked: its queue drops the oldest item
//! when full (counted; logged once per second at most). A replay waits
//! for room instead, so that it loses nothing.

use std::ops::ControlFlow;
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use crate::dataset::{open_dataset, SensorEvent, SensorStream, StreamCounts, StreamOptions};
use crate::recording::{for_each_sensor_event, is_mcap, ReplayItem, SensorTopics, SkippedMessage};
use crate::relative::SensorMode;
use crate::sensors::camera::{CameraError, FrameSource};
use crate::sensors::yei::device::{host_monotonic_ns, YeiConfig, YeiDevice};
use crate::sensors::ImuSample;

use super::config::{CameraConfig, CameraSource, ImuConfig, ReplayConfig, ReplayPace};
use super::health::{Health, LogThrottle, SkipLog};
use super::queue::{BoundedQueue, Pushed};
use super::slam_stage::FrameItem;
use super::Doorbell;

/// Says in the log what a replayed recording was missing: a file cut
/// short plays as far as it goes, a damaged chunk is skipped.
fn report_file_end(path: &std::path::Path, end: &crate::recording::ReplayEnd) {
    if let crate::recording::FileEnd::Cut { .. } = end.file.end {
        tracing::warn!(
            "replay: {} is {}; replayed the {} events it holds ({} messages). \
             `rigslamd --repair {}` rewrites it as a closed file",
            path.display(),
            end.file.end,
            end.events,
            end.file.messages,
            path.display()
        );
    }
    for skipped in &end.file.skipped {
        tracing::warn!("replay: {}: {skipped}", path.display());
    }
}

/// What every source thread shares.
#[derive(Clone)]
pub struct SourceLinks {
    /// Frames to the SLAM stage.
    pub frames: Arc<BoundedQueue<FrameItem>>,
    /// IMU samples to the SLAM stage.
    pub imu: Arc<BoundedQueue<ImuSample>>,
    /// Rung after each push, to wake the SLAM stage.
    pub doorbell: Arc<Doorbell>,
    /// Counters and last-seen times the health monitor reads.
    pub health: Arc<Health>,
    /// Set when the daemon stops; the source threads return when they see it.
    pub stop: Arc<AtomicBool>,
    /// Raw samples for the recorder, when recording.
    pub record: Option<super::recorder::RecordSender>,
}

/// Logs drops at most once a second per queue.
#[derive(Default)]
struct DropLog(LogThrottle);

impl DropLog {
    fn new() -> Self {
        Self::default()
    }

    fn dropped(&mut self, queue: &str, total: u64) {
        if let Some((since, _)) = self.0.count() {
            tracing::warn!(
                "{queue} queue full: dropped {since} oldest item(s) ({total} since start); the SLAM stage is behind"
            );
        }
    }
}

impl SourceLinks {
    fn offer_imu(&self, sample: ImuSample, log: &mut DropLog) {
        if let Some(r) = &self.record {
            r.imu(&sample);
        }
        self.health.imu_arrived(host_monotonic_ns());
        if self.imu.push(sample) == Pushed::DroppedOldest {
            log.dropped("imu", self.imu.dropped());
        }
        self.doorbell.ring();
    }

    fn offer_frame(&self, mut frame: FrameItem, log: &mut DropLog) {
        if let Some(r) = &self.record {
            r.frame(&frame);
        }
        frame.arrival_ns = host_monotonic_ns();
        self.health.frame_arrived(frame.arrival_ns);
        if self.frames.push(frame) == Pushed::DroppedOldest {
            log.dropped("frame", self.frames.dropped());
        }
        self.doorbell.ring();
    }

    fn stopping(&self) -> bool {
        self.stop.load(Ordering::Relaxed)
    }

    fn close(&self) {
        self.frames.close();
        self.imu.close();
        self.doorbell.ring();
    }
}

fn spawn(name: &str, f: impl FnOnce() + Send + 'static) -> std::io::Result<JoinHandle<()>> {
    std::thread::Builder::new().name(name.into()).spawn(f)
}

/// Replays a EuRoC folder or an MCAP recording: both sensors from one
/// merged stream, so the order the SLAM stage sees is the recorded one.
/// A EuRoC folder's IMU is handed over up to `imu_lead_ns` past each
/// frame (the rig's camera time shift, as `rigslam run` reads it), so
/// that the last frame too has its samples. Closes the queues at the end
/// (the daemon then exits).
pub fn spawn_replay(
    replay: ReplayConfig,
    mode: SensorMode,
    imu_lead_ns: i64,
    links: SourceLinks,
) -> std::io::Result<JoinHandle<()>> {
    spawn("replay", move || {
        if let Err(e) = replay_loop(&replay, mode, imu_lead_ns, &links) {
            // The errors name the file (and where in it) themselves.
            tracing::error!("replay stopped: {e}");
            links.health.source_failed.store(true, Ordering::Relaxed);
        }
        links.health.source_finished.store(true, Ordering::Relaxed);
        links.close();
    })
}

/// Hands replayed events over at their pace, shifted by a loop's offset.
struct Player<'a> {
    links: &'a SourceLinks,
    pace: ReplayPace,
    start: Instant,
    first_ns: Option<i64>,
    log: DropLog,
    skipped_images: SkipLog,
    skipped_imu: SkipLog,
    /// Offset of the loop being played, ns.
    offset_ns: i64,
    /// Earliest and latest recorded stamp of the loop.
    recorded: (i64, i64),
}

impl Player<'_> {
    /// Hands `event` to the queues; `Break` when the daemon is stopping.
    fn play(&mut self, event: SensorEvent) -> ControlFlow<()> {
        if self.links.stopping() {
            return ControlFlow::Break(());
        }
        let recorded_ns = match &event {
            SensorEvent::Imu(s) => s.t_ns,
            SensorEvent::Frame { t_ns, .. } => *t_ns,
        };
        self.recorded = (
            self.recorded.0.min(recorded_ns),
            self.recorded.1.max(recorded_ns),
        );
        let t_ns = recorded_ns + self.offset_ns;
        let first = *self.first_ns.get_or_insert(t_ns);
        if self.pace == ReplayPace::Recorded {
            let due = Duration::from_nanos((t_ns - first).max(0) as u64);
            if let Some(wait) = due.checked_sub(self.start.elapsed()) {
                std::thread::sleep(wait);
            }
        }
        match event {
            SensorEvent::Imu(mut s) => {
                s.t_ns = t_ns;
                self.links.offer_imu(s, &mut self.log);
            }
            SensorEvent::Frame { left, right, .. } => self.links.offer_frame(
                FrameItem {
                    t_ns,
                    left,
                    right,
                    arrival_ns: 0,
                },
                &mut self.log,
            ),
        }
        ControlFlow::Continue(())
    }

    /// Counts and logs a recording's message the replay leaves out.
    fn skip(&mut self, message: SkippedMessage) {
        let health = &self.links.health;
        let (counter, log) = if message.is_image() {
            (&health.frames_skipped, &mut self.skipped_images)
        } else {
            (&health.imu_skipped, &mut self.skipped_imu)
        };
        let total = counter.fetch_add(1, Ordering::Relaxed) + 1;
        log.skipped(|| message.to_string(), total);
    }

    /// Brings the health's skip counts up to a dataset stream's (what the
    /// stream left out since `seen`; the stream logged it already).
    fn count_stream_skips(&mut self, counts: StreamCounts, seen: &mut StreamCounts) {
        let health = &self.links.health;
        let images = |c: &StreamCounts| c.frames_missing_image + c.frames_missing_right;
        health
            .frames_skipped
            .fetch_add(images(&counts) - images(seen), Ordering::Relaxed);
        health.imu_skipped.fetch_add(
            counts.imu_samples_nonfinite - seen.imu_samples_nonfinite,
            Ordering::Relaxed,
        );
        *seen = counts;
    }
}

fn replay_loop(
    replay: &ReplayConfig,
    mode: SensorMode,
    imu_lead_ns: i64,
    links: &SourceLinks,
) -> anyhow::Result<()> {
    let path = Path::new(&replay.dataset);
    let dataset = if is_mcap(path) {
        None
    } else {
        Some(open_dataset(path)?)
    };
    let mut player = Player {
        links,
        pace: replay.pace,
        start: Instant::now(),
        first_ns: None,
        log: DropLog::new(),
        skipped_images: SkipLog::new("image"),
        skipped_imu: SkipLog::new("IMU sample"),
        offset_ns: 0,
        recorded: (i64::MAX, i64::MIN),
    };
    // Each loop's stamps continue 50 ms after the previous loop's last.
    let mut span_ns: Option<i64> = None;
    for k in 0..i64::from(replay.loops.max(1)) {
        player.offset_ns = span_ns.map_or(0, |s| s * k);
        player.recorded = (i64::MAX, i64::MIN);
        let stopped = match &dataset {
            Some(dataset) => {
                let mut stream = SensorStream::new(
                    dataset,
                    StreamOptions {
                        stereo: mode.uses_stereo(),
                        imu: mode.uses_imu(),
                        start_ns: None,
                        max_frames: replay.max_frames,
                        imu_lead_ns,
                    },
                )?;
                let mut stopped = false;
                let mut seen = StreamCounts::default();
                while let Some(event) = stream.next() {
                    player.count_stream_skips(stream.counts(), &mut seen);
                    if player.play(event?).is_break() {
                        stopped = true;
                        break;
                    }
                }
                player.count_stream_skips(stream.counts(), &mut seen);
                stopped
            }
            None => {
                let mut stopped = false;
                let mut frames = 0;
                let topics = SensorTopics {
                    stereo: mode.uses_stereo(),
                    imu: mode.uses_imu(),
                };
                let end = for_each_sensor_event(path, topics, |item| {
                    let event = match item {
                        ReplayItem::Event(e) => e,
                        ReplayItem::Skipped(m) => {
                            player.skip(m);
                            return ControlFlow::Continue(());
                        }
                    };
                    if let SensorEvent::Frame { .. } = event {
                        if replay.max_frames.is_some_and(|m| frames >= m) {
                            return ControlFlow::Break(());
                        }
                        frames += 1;
                    }
                    let flow = player.play(event);
                    stopped = flow.is_break();
                    flow
                })?;
                // Only the first loop says what the file is missing.
                if k == 0 {
                    report_file_end(path, &end);
                    let h = &player.links.health;
                    if end.file.end != crate::recording::FileEnd::Complete {
                        h.replay_cut.store(true, Ordering::Relaxed);
                    }
                    h.replay_damaged
                        .store(end.file.skipped.len() as u64, Ordering::Relaxed);
                }
                stopped
            }
        };
        if stopped {
            return Ok(());
        }
        let recorded = player.recorded;
        if span_ns.is_none() && recorded.1 >= recorded.0 {
            span_ns = Some(recorded.1 - recorded.0 + 50_000_000);
        }
    }
    Ok(())
}

/// Reads a YEI 3-Space. The driver reopens a vanished port itself (with
/// backoff); this thread opens it the first time, again with backoff
/// while it is missing, and reports the driver's state to the health.
pub fn spawn_yei(imu: ImuConfig, links: SourceLinks) -> std::io::Result<JoinHandle<()>> {
    spawn("imu", move || {
        let port = imu.port.clone().unwrap_or_default();
        let mut config = YeiConfig::new(port.clone());
        config.baud = imu.baud;
        config.interval_us = (1e6 / imu.rate_hz).round() as u32;
        // The daemon's queue is the bound; the driver's own is a short
        // hand-over buffer.
        config.queue_capacity = 1024;
        let mut backoff = Duration::from_millis(100);
        let mut log = DropLog::new();
        while !links.stopping() {
            let device = match YeiDevice::open(config.clone()) {
                Ok(d) => d,
                Err(e) => {
                    links.health.imu_reconnecting.store(true, Ordering::Relaxed);
                    tracing::warn!("IMU: {e}; retrying in {} ms", backoff.as_millis());
                    sleep_unless_stopped(backoff, &links.stop);
                    backoff = (backoff * 2).min(Duration::from_secs(5));
                    continue;
                }
            };
            backoff = Duration::from_millis(100);
            tracing::info!(
                "IMU: YEI 3-Space serial {} firmware {} on {port}",
                device.identity().serial_hex(),
                device.identity().firmware
            );
            let mut seen_disconnects = 0;
            // Samples the driver lost (damaged or missing packets, found
            // from gaps in the sensor's stamps; its own queue overflowing)
            // count in the status; the driver logs them.
            let mut seen_lost = 0;
            while !links.stopping() {
                if let Some(s) = device.recv_timeout(Duration::from_millis(50)) {
                    links.offer_imu(s.imu, &mut log);
                }
                let stats = device.stats();
                let lost = stats.drops + stats.queue_overflows;
                if lost > seen_lost {
                    links
                        .health
                        .imu_skipped
                        .fetch_add(lost - seen_lost, Ordering::Relaxed);
                    seen_lost = lost;
                }
                let reconnecting = stats.disconnects > stats.reconnects;
                links
                    .health
                    .imu_reconnecting
                    .store(reconnecting, Ordering::Relaxed);
                if stats.disconnects > seen_disconnects {
                    seen_disconnects = stats.disconnects;
                    tracing::warn!("IMU: {port} vanished; the driver reconnects with backoff");
                }
                links
                    .health
                    .imu_reconnects
                    .store(stats.reconnects, Ordering::Relaxed);
            }
            device.close();
        }
        links.imu.close();
        links.doorbell.ring();
    })
}

fn sleep_unless_stopped(total: Duration, stop: &AtomicBool) {
    let end = Instant::now() + total;
    while !stop.load(Ordering::Relaxed) {
        let now = Instant::now();
        if now >= end {
            return;
        }
        std::thread::sleep((end - now).min(Duration::from_millis(50)));
    }
}

/// Reads a live camera (left image only; the stereo modes need a
/// replay, see `check`), reopening it with backoff when it fails.
pub fn spawn_camera(camera: CameraConfig, links: SourceLinks) -> std::io::Result<JoinHandle<()>> {
    spawn("camera", move || {
        let mut backoff = Duration::from_millis(100);
        let mut log = DropLog::new();
        while !links.stopping() {
            let mut source = match open_camera(&camera) {
                Ok(s) => s,
                Err(e) => {
                    tracing::warn!("camera: {e}; retrying in {} ms", backoff.as_millis());
                    sleep_unless_stopped(backoff, &links.stop);
                    backoff = (backoff * 2).min(Duration::from_secs(5));
                    continue;
                }
            };
            backoff = Duration::from_millis(100);
            while !links.stopping() {
                match source.next_frame(Duration::from_millis(200)) {
                    Ok(frame) => links.offer_frame(
                        FrameItem {
                            t_ns: frame.t_ns,
                            left: frame,
                            right: None,
                            arrival_ns: 0,
                        },
                        &mut log,
                    ),
                    Err(CameraError::Timeout { .. }) => {}
                    Err(e) => {
                        tracing::warn!("camera: {e}; reopening");
                        break;
                    }
                }
            }
        }
        links.frames.close();
        links.doorbell.ring();
    })
}

fn open_camera(camera: &CameraConfig) -> Result<Box<dyn FrameSource>, CameraError> {
    match camera.source {
        CameraSource::V4l2 => {
            let mut c = crate::sensors::camera::v4l2::V4l2Config::new(
                camera.device.as_deref().unwrap_or("0"),
            );
            c.width = camera.width;
            c.height = camera.height;
            c.rate_hz = camera.rate_hz.map(|r| r.round() as u32);
            Ok(Box::new(crate::sensors::camera::v4l2::open_v4l2(&c)?))
        }
        #[cfg(feature = "aravis")]
        CameraSource::Aravis => {
            let c = crate::sensors::camera::aravis::AravisConfig {
                device: camera.device.clone(),
                width: camera.width,
                height: camera.height,
                rate_hz: camera.rate_hz,
                ..Default::default()
            };
            Ok(Box::new(crate::sensors::camera::aravis::open_aravis(&c)?))
        }
        #[cfg(not(feature = "aravis"))]
        CameraSource::Aravis => Err(CameraError::Driver {
            device: camera.device.clone().unwrap_or_default(),
            message: "this build has no Aravis support (built without the `aravis` feature)".into(),
        }),
        CameraSource::Pattern => Ok(Box::new(crate::sensors::camera::fake::PatternCamera::new(
            camera.width.unwrap_or(752),
            camera.height.unwrap_or(480),
            camera.rate_hz.unwrap_or(20.0),
        ))),
        CameraSource::Replay => Err(CameraError::Driver {
            device: "replay".into(),
            message: "a replay is not a live camera".into(),
        }),
    }
}
