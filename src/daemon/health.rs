//! What the threads tell the supervisor: counters, last-arrival stamps,
//! the SLAM stage's heartbeat, latencies. Atomics (and one short-held
//! lock for the latency window), written by the sensor and SLAM threads,
//! read once per status period into a [`StatusMessage`] and systemd's
//! STATUS= line.

use std::sync::atomic::{AtomicBool, AtomicI64, AtomicU32, AtomicU64, Ordering};
use std::sync::Mutex;

use crate::publish::{
    QueueFill, StatusMessage, HEALTH_CALIBRATION_DRIFT, HEALTH_CAMERA_STALLED,
    HEALTH_CAMERA_STREAMING, HEALTH_IMU_RECONNECTING, HEALTH_IMU_STREAMING, HEALTH_NOISE_AT_BOUND,
    HEALTH_STAGE_STUCK, HEALTH_TIMESTAMP_JUMP,
};
use crate::relative::window::{CameraImuEstimate, NoiseScale};
use crate::run::TimingStats;
use crate::sensors::yei::device::host_monotonic_ns;

/// Shared by every thread of the pipeline.
#[derive(Default)]
pub struct Health {
    /// Frames the sources handed to the frame queue.
    pub frames_in: AtomicU64,
    /// IMU samples the sources handed to the IMU queue.
    pub imu_in: AtomicU64,
    /// Frame poses the sink sent on `rigslam/pose`.
    pub poses_out: AtomicU64,
    /// IMU-rate poses sent on `rigslam/pose_fast`.
    pub pose_fast_out: AtomicU64,
    /// Poses the publisher failed to send.
    pub pose_drops: AtomicU64,
    /// Frames and samples the SLAM stage refused (stamps going back,
    /// non-finite values).
    pub frames_rejected: AtomicU64,
    /// IMU samples the SLAM stage refused (see `frames_rejected`).
    pub imu_rejected: AtomicU64,
    /// Images and samples a source left out as unreadable: a recording's
    /// message that does not decode, a stereo half without its partner, a
    /// listed image whose file is missing, a non-finite row of a dataset.
    pub frames_skipped: AtomicU64,
    /// IMU samples a source left out as unreadable (see `frames_skipped`).
    pub imu_skipped: AtomicU64,
    /// Stamps going back, or forward by more than a second.
    pub timestamp_jumps: AtomicU64,
    /// Host time of the last frame / sample handed to the queue, ns (0: none yet).
    pub last_frame_ns: AtomicI64,
    /// Host `CLOCK_MONOTONIC` of the last IMU sample handed to the queue, ns (0: none yet).
    pub last_imu_ns: AtomicI64,
    /// Host time of the first frame, IMU sample and pose (0: none yet),
    /// ns: a stream that began during a status period is timed from there.
    first_frame_ns: AtomicI64,
    first_imu_ns: AtomicI64,
    first_pose_ns: AtomicI64,
    /// Host time the SLAM stage last went round its loop, ns.
    pub stage_heartbeat_ns: AtomicI64,
    /// The IMU driver lost its port and is reopening it.
    pub imu_reconnecting: AtomicBool,
    /// Times the IMU driver reopened its port.
    pub imu_reconnects: AtomicU64,
    /// The last frame's tracking state (the wire code).
    pub tracking_state: AtomicU32,
    /// Set by a replay source when the recording has been played out.
    pub source_finished: AtomicBool,
    /// Set by a replay source that stopped on an error (the file could
    /// not be read on): the daemon then exits with a failure status.
    pub source_failed: AtomicBool,
    /// A replayed recording was cut short (never closed): it played as
    /// far as its bytes go.
    pub replay_cut: AtomicBool,
    /// Chunks or records of a replayed recording skipped as damaged.
    pub replay_damaged: AtomicU64,
    /// [`MAP_NONE`], [`MAP_BUILDING`] or [`MAP_LOCALISING`] (`[map]`).
    pub map_mode: AtomicU32,
    /// Landmarks of the map last loaded or saved.
    pub map_landmarks: AtomicU64,
    /// Saves of the map so far.
    pub map_saves: AtomicU64,
    /// Unknowns of the absolute stage's last map solve (3 per landmark
    /// or frame node): what its solves cost grows with this.
    pub map_unknowns: AtomicU64,
    /// Localising in a saved map: frames so far, frames placed in the
    /// map, and whether the last frame was.
    pub map_frames: AtomicU64,
    /// See [`Self::map_frames`].
    pub map_frames_placed: AtomicU64,
    /// See [`Self::map_frames`].
    pub map_placed_now: AtomicBool,
    /// The newest frame was placed in the saved map by the odometry alone,
    /// the localisation dropped and not found again yet.
    pub map_carried_now: AtomicBool,
    /// The second stage (map or localiser) is waiting for the relative
    /// stage to settle after a start in motion, or to know its
    /// accelerometer bias (the map-frame pose is the odometry-frame pose
    /// meanwhile).
    pub second_stage_waiting: AtomicBool,
    /// How far the absolute stage has turned the relative stage's
    /// orientation to fit its map, degrees as f64 bits (0 until it has).
    orientation_offset_deg_bits: AtomicU64,
    /// The estimator's noise scales (gyro, accel, pixel) as f64 bits,
    /// valid when `noise_known`; `noise_at_bound` when one hit a bound.
    noise_scale_bits: [AtomicU64; 3],
    noise_known: AtomicBool,
    noise_at_bound: AtomicBool,
    /// The online camera-IMU estimate (rotation deg, translation m, time
    /// offset s from the file) as f64 bits, valid when `camera_imu_known`;
    /// `camera_imu_far` when it wandered beyond the warning distance.
    camera_imu_bits: [AtomicU64; 3],
    camera_imu_known: AtomicBool,
    camera_imu_far: AtomicBool,
    /// Frame arrival to pose published, us, since the last status.
    latency_window_us: Mutex<Vec<f64>>,
    /// Every latency of the run (the exit report), in fixed memory.
    latency_run: Mutex<LatencyHistogram>,
}

/// A latency distribution in fixed memory, so that a daemon running for
/// days does not grow with it: buckets 1 % wide from 1 us to 100 s
/// (about 1 850 of them), the largest value kept exactly. Percentiles come out
/// as the upper edge of their bucket, at most 1 % above the true value.
#[derive(Debug, Clone)]
pub struct LatencyHistogram {
    counts: Vec<u64>,
    total: u64,
    max_us: f64,
}

impl Default for LatencyHistogram {
    fn default() -> Self {
        Self {
            counts: vec![0; Self::BUCKETS],
            total: 0,
            max_us: 0.0,
        }
    }
}

impl LatencyHistogram {
    const GROWTH: f64 = 1.01;
    /// ln(100 s / 1 us) / ln(1.01), rounded up, plus the bucket below 1 us.
    const BUCKETS: usize = 1853 + 1;

    fn bucket(us: f64) -> usize {
        if us.is_nan() || us <= 1.0 {
            return 0;
        }
        let k = (us.ln() / Self::GROWTH.ln()).ceil() as usize;
        k.min(Self::BUCKETS - 1)
    }

    /// The upper edge of bucket `k`, us.
    fn edge_us(k: usize) -> f64 {
        Self::GROWTH.powi(k as i32)
    }

    /// Adds one value (NaN and negative values count as 0).
    pub fn record(&mut self, us: f64) {
        self.counts[Self::bucket(us)] += 1;
        self.total += 1;
        if us > self.max_us {
            self.max_us = us;
        }
    }

    /// Values recorded over the run.
    pub fn count(&self) -> u64 {
        self.total
    }

    /// Largest value recorded, us (0 before any).
    pub fn max_us(&self) -> f64 {
        self.max_us
    }

    /// The nearest-rank `q` quantile (`q` in (0, 1]), never above the
    /// maximum; `None` without values.
    pub fn quantile_us(&self, q: f64) -> Option<f64> {
        if self.total == 0 {
            return None;
        }
        let rank = ((q * self.total as f64).ceil() as u64).clamp(1, self.total);
        let mut seen = 0;
        for (k, &n) in self.counts.iter().enumerate() {
            seen += n;
            if seen >= rank {
                return Some(Self::edge_us(k).min(self.max_us));
            }
        }
        Some(self.max_us)
    }
}

/// Counts events and says when a log line about them is due: at the
/// first, then at most once a second, so that a flood of them does not
/// flood the journal.
#[derive(Debug, Default)]
pub struct LogThrottle {
    last: Option<std::time::Instant>,
    since: u64,
}

impl LogThrottle {
    /// One more event; when a line is due, how many events it covers
    /// (this one included) and whether it is the first line.
    pub fn count(&mut self) -> Option<(u64, bool)> {
        self.since += 1;
        let due = self
            .last
            .map_or(true, |t| t.elapsed() >= std::time::Duration::from_secs(1));
        if !due {
            return None;
        }
        let first = self.last.is_none();
        let since = std::mem::take(&mut self.since);
        self.last = Some(std::time::Instant::now());
        Some((since, first))
    }
}

/// Logs input left out: the first one in full, then at most one line a
/// second saying how many more and the latest.
#[derive(Debug)]
pub struct SkipLog {
    what: &'static str,
    throttle: LogThrottle,
}

impl SkipLog {
    /// `what` names the kind of input ("IMU sample", "image").
    pub fn new(what: &'static str) -> Self {
        Self {
            what,
            throttle: LogThrottle::default(),
        }
    }

    /// One more left out; `detail` says which and why (called only when
    /// a line is written); `total` is the count since start.
    pub fn skipped(&mut self, detail: impl FnOnce() -> String, total: u64) {
        match self.throttle.count() {
            Some((_, true)) => tracing::warn!("{} left out: {}", self.what, detail()),
            Some((since, false)) => tracing::warn!(
                "{since} more {}(s) left out ({total} since start), the latest: {}",
                self.what,
                detail()
            ),
            None => {}
        }
    }
}

/// The counts at the previous status, for rates.
#[derive(Debug, Clone, Copy, Default)]
pub struct RateBase {
    t_ns: i64,
    frames: u64,
    imu: u64,
    poses: u64,
    jumps: u64,
}

/// Arrivals per second over a status period that began at `base_t_ns`
/// (0: the first period) and ends at `now_ns`, with `count` arrivals so
/// far, `base_count` of them before the period, the first ever at
/// `first_ns` (0: none seen). A stream that began during the period is
/// timed from its first arrival, not from the period's start (a camera
/// that took a while to start streaming is not under-counted): that
/// arrival opens the interval and the ones after it are counted. NaN,
/// "not known yet", when nothing has come after it; 0 only when nothing
/// arrived in the period.
pub fn rate_hz(count: u64, base_count: u64, base_t_ns: i64, first_ns: i64, now_ns: i64) -> f64 {
    let n = count.saturating_sub(base_count);
    if n == 0 {
        return 0.0;
    }
    let (arrivals, since_ns) = if first_ns == 0 || first_ns >= base_t_ns {
        (n - 1, first_ns)
    } else {
        (n, base_t_ns)
    };
    if arrivals == 0 || since_ns == 0 || now_ns <= since_ns {
        return f64::NAN;
    }
    arrivals as f64 / ((now_ns - since_ns) as f64 * 1e-9)
}

/// Rules for the health bits.
#[derive(Debug, Clone, Copy)]
pub struct HealthRules {
    /// No frame for this long: camera stalled, ns.
    pub camera_stall_ns: i64,
    /// No IMU sample for this long: IMU gone, ns (ignored when `uses_imu` is false).
    pub imu_stall_ns: i64,
    /// A stage with work and no progress for this long is stuck, ns.
    pub stuck_ns: i64,
    /// Whether the sensor mode uses the IMU, so that an IMU stall matters.
    pub uses_imu: bool,
}

/// [`Health::map_mode`]: no map on disk (`[map] path` unset).
pub const MAP_NONE: u32 = 0;
/// [`Health::map_mode`]: building a map, saved to `[map] path`.
pub const MAP_BUILDING: u32 = 1;
/// [`Health::map_mode`]: localising in the map loaded from `[map] path`.
pub const MAP_LOCALISING: u32 = 2;

impl Health {
    /// The map's state in words (the status line), None without a map.
    pub fn map_words(&self) -> Option<String> {
        let landmarks = self.map_landmarks.load(Ordering::Relaxed);
        let turned = f64::from_bits(self.orientation_offset_deg_bits.load(Ordering::Relaxed));
        match self.map_mode.load(Ordering::Relaxed) {
            MAP_BUILDING => Some(format!(
                "map: building, {} saves ({landmarks} landmarks at the last), {} unknowns in the last solve, orientation turned {turned:.2} deg to fit it",
                self.map_saves.load(Ordering::Relaxed),
                self.map_unknowns.load(Ordering::Relaxed)
            )),
            MAP_LOCALISING => {
                let frames = self.map_frames.load(Ordering::Relaxed);
                let placed = self.map_frames_placed.load(Ordering::Relaxed);
                let now = if self.map_carried_now.load(Ordering::Relaxed) {
                    "placed in it by the odometry alone while relocalising (the map and the track disagreed)"
                } else if self.map_placed_now.load(Ordering::Relaxed) {
                    "placed in it"
                } else if placed == 0 {
                    "not placed in it yet: poses are in the odometry frame until it is (a robot outside the mapped place never will; move the map file away to build a new one)"
                } else {
                    "not placed in it now: poses are in the odometry frame until it is again"
                };
                Some(format!(
                    "map: localising in the saved map ({landmarks} landmarks), {now}; {placed} of {frames} frames placed"
                ))
            }
            _ => None,
        }
    }

    /// The status words while the second stage waits for the relative
    /// stage to settle, None otherwise.
    pub fn waiting_words(&self) -> Option<&'static str> {
        self.second_stage_waiting.load(Ordering::Relaxed).then_some(
            "map: waiting for the odometry to settle (a start in motion, or an accelerometer bias not yet told from tilt: move and turn the rig); poses are in the odometry frame until then",
        )
    }

    /// After each frame while localising in a saved map: whether the
    /// frame was placed in it, and whether by the odometry alone (carried
    /// through a dropped localisation).
    pub fn record_map_placement(&self, placed: bool, carried: bool) {
        self.map_frames.fetch_add(1, Ordering::Relaxed);
        if placed {
            self.map_frames_placed.fetch_add(1, Ordering::Relaxed);
        }
        self.map_placed_now.store(placed, Ordering::Relaxed);
        self.map_carried_now
            .store(placed && carried, Ordering::Relaxed);
    }

    /// The absolute stage's orientation offset after a frame, degrees.
    pub fn record_orientation_offset_deg(&self, degrees: f64) {
        self.orientation_offset_deg_bits
            .store(degrees.to_bits(), Ordering::Relaxed);
    }

    /// All counters zero, the SLAM stage's heartbeat set to now (host `CLOCK_MONOTONIC`), so it
    /// does not count as stuck before it starts.
    pub fn new() -> Self {
        let h = Self::default();
        h.stage_heartbeat_ns
            .store(host_monotonic_ns(), Ordering::Relaxed);
        h
    }

    /// A frame handed to the frame queue at host time `now_ns`.
    pub fn frame_arrived(&self, now_ns: i64) {
        self.last_frame_ns.store(now_ns, Ordering::Relaxed);
        arrived(&self.first_frame_ns, &self.frames_in, now_ns);
    }

    /// An IMU sample handed to the IMU queue at host time `now_ns`.
    pub fn imu_arrived(&self, now_ns: i64) {
        self.last_imu_ns.store(now_ns, Ordering::Relaxed);
        arrived(&self.first_imu_ns, &self.imu_in, now_ns);
    }

    /// A pose sent on `rigslam/pose` at host time `now_ns`.
    pub fn pose_published(&self, now_ns: i64) {
        arrived(&self.first_pose_ns, &self.poses_out, now_ns);
    }

    /// Frames and samples left out as bad input (refused by the stage or
    /// skipped by the source), not counting queue overflows.
    pub fn input_drops(&self) -> (u64, u64) {
        let n =
            |a: &AtomicU64, b: &AtomicU64| a.load(Ordering::Relaxed) + b.load(Ordering::Relaxed);
        (
            n(&self.frames_rejected, &self.frames_skipped),
            n(&self.imu_rejected, &self.imu_skipped),
        )
    }

    /// What the estimator weighs its measurements with now (None: it
    /// estimates nothing), for the status.
    pub fn record_noise_scale(&self, scale: Option<NoiseScale>, at_bound: bool) {
        if let Some(s) = scale {
            for (bits, v) in self.noise_scale_bits.iter().zip([s.gyro, s.accel, s.pixel]) {
                bits.store(v.to_bits(), Ordering::Relaxed);
            }
        }
        self.noise_known.store(scale.is_some(), Ordering::Relaxed);
        self.noise_at_bound.store(at_bound, Ordering::Relaxed);
    }

    /// The camera-IMU calibration as the estimator refines it (None: not
    /// refined), for the status.
    pub fn record_camera_imu(&self, estimate: Option<CameraImuEstimate>) {
        if let Some(e) = estimate {
            for (bits, v) in self.camera_imu_bits.iter().zip([
                e.rotation_from_file_deg,
                e.translation_from_file_m,
                e.time_offset_s,
            ]) {
                bits.store(v.to_bits(), Ordering::Relaxed);
            }
        }
        self.camera_imu_known
            .store(estimate.is_some(), Ordering::Relaxed);
        let far = estimate.filter(|e| e.far_from_file);
        let was_far = self.camera_imu_far.swap(far.is_some(), Ordering::Relaxed);
        if let (Some(e), false) = (far, was_far) {
            tracing::warn!(
                "the camera-IMU calibration estimated online is {:.2} deg, {:.1} mm and {:+.2} ms from the calibration file: the camera may have moved on its mount, or the file is another rig's; recalibrate (rigslam-calibrate camera-imu)",
                e.rotation_from_file_deg,
                e.translation_from_file_m * 1e3,
                e.time_offset_s * 1e3
            );
        }
    }

    /// Records one frame's latency, frame arrival to pose published, us: for the status period's
    /// figures and the whole run's histogram.
    pub fn record_latency_us(&self, us: f64) {
        self.latency_window_us
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .push(us);
        self.latency_run
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .record(us);
    }

    /// The latencies of the whole run so far.
    pub fn run_latencies(&self) -> LatencyHistogram {
        self.latency_run
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .clone()
    }

    /// Whether the SLAM stage has gone `stuck_ns` without a heartbeat.
    pub fn stage_stuck(&self, now_ns: i64, stuck_ns: i64) -> bool {
        now_ns - self.stage_heartbeat_ns.load(Ordering::Relaxed) > stuck_ns
    }

    /// The status now; `base` is updated for the next period's rates.
    pub fn status(
        &self,
        rules: &HealthRules,
        base: &mut RateBase,
        queues: &[QueueFill],
        drops: (u64, u64),
    ) -> StatusMessage {
        self.status_at(host_monotonic_ns(), rules, base, queues, drops)
    }

    /// [`Self::status`] at host time `now` (ns), the period since the
    /// previous one (`base`) or since the start: the rates are over the
    /// time since a stream's first arrival when it began in the period
    /// (NaN until a second one came, see [`rate_hz`]).
    pub fn status_at(
        &self,
        now: i64,
        rules: &HealthRules,
        base: &mut RateBase,
        queues: &[QueueFill],
        drops: (u64, u64),
    ) -> StatusMessage {
        // Acquire: a count seen comes with its stream's first stamp.
        let frames = self.frames_in.load(Ordering::Acquire);
        let imu = self.imu_in.load(Ordering::Acquire);
        let poses = self.poses_out.load(Ordering::Acquire);
        let jumps = self.timestamp_jumps.load(Ordering::Relaxed);
        let rate = |count: u64, base_count: u64, first: &AtomicI64| {
            rate_hz(
                count,
                base_count,
                base.t_ns,
                first.load(Ordering::Relaxed),
                now,
            )
        };
        let mut m = StatusMessage {
            t_ns: now,
            camera_rate_hz: rate(frames, base.frames, &self.first_frame_ns),
            imu_rate_hz: rate(imu, base.imu, &self.first_imu_ns),
            pose_rate_hz: rate(poses, base.poses, &self.first_pose_ns),
            camera_drops: drops.0 + self.input_drops().0,
            imu_drops: drops.1 + self.input_drops().1,
            pose_drops: self.pose_drops.load(Ordering::Relaxed),
            ..StatusMessage::default()
        };
        let window: Vec<f64> = std::mem::take(
            &mut *self
                .latency_window_us
                .lock()
                .unwrap_or_else(|e| e.into_inner()),
        );
        // TimingStats only ranks the numbers; they are us here.
        if let Some(s) = TimingStats::of(&window) {
            m.latency_p50_us = s.p50_ms;
            m.latency_p99_us = s.p99_ms;
        }
        let fresh = |t: i64, within: i64| t > 0 && now - t <= within;
        let last_frame = self.last_frame_ns.load(Ordering::Relaxed);
        if fresh(last_frame, rules.camera_stall_ns) {
            m.sensor_health |= HEALTH_CAMERA_STREAMING;
        } else if last_frame > 0 && !self.source_finished.load(Ordering::Relaxed) {
            m.sensor_health |= HEALTH_CAMERA_STALLED;
        }
        if fresh(self.last_imu_ns.load(Ordering::Relaxed), rules.imu_stall_ns) {
            m.sensor_health |= HEALTH_IMU_STREAMING;
        }
        if self.imu_reconnecting.load(Ordering::Relaxed) {
            m.sensor_health |= HEALTH_IMU_RECONNECTING;
        }
        if jumps > base.jumps {
            m.sensor_health |= HEALTH_TIMESTAMP_JUMP;
        }
        if self.stage_stuck(now, rules.stuck_ns) {
            m.sensor_health |= HEALTH_STAGE_STUCK;
        }
        if self.noise_known.load(Ordering::Relaxed) {
            let [g, a, p] = self
                .noise_scale_bits
                .each_ref()
                .map(|b| f64::from_bits(b.load(Ordering::Relaxed)));
            m.imu_noise_scale_gyro = g;
            m.imu_noise_scale_accel = a;
            m.pixel_noise_scale = p;
        }
        if self.noise_at_bound.load(Ordering::Relaxed) {
            m.sensor_health |= HEALTH_NOISE_AT_BOUND;
        }
        if self.camera_imu_known.load(Ordering::Relaxed) {
            let [r, t, td] = self
                .camera_imu_bits
                .each_ref()
                .map(|b| f64::from_bits(b.load(Ordering::Relaxed)));
            m.camera_imu_rotation_deg = r;
            m.camera_imu_translation_m = t;
            m.camera_imu_time_offset_s = td;
        }
        if self.camera_imu_far.load(Ordering::Relaxed) {
            m.sensor_health |= HEALTH_CALIBRATION_DRIFT;
        }
        m.set_queues(queues);
        *base = RateBase {
            t_ns: now,
            frames,
            imu,
            poses,
            jumps,
        };
        m
    }
}

/// One more arrival at `now_ns` on a stream counted by `count` whose
/// first arrival is kept in `first`.
fn arrived(first: &AtomicI64, count: &AtomicU64, now_ns: i64) {
    // Only the first arrival finds 0 there; later ones leave it.
    let _ = first.compare_exchange(0, now_ns, Ordering::Relaxed, Ordering::Relaxed);
    // Release: whoever sees this count sees the first stamp stored above.
    count.fetch_add(1, Ordering::Release);
}

/// A rate for people: "20.0 Hz", or "measuring" while it is not known
/// yet (NaN, see [`rate_hz`]).
pub fn rate_words(hz: f64, decimals: usize) -> String {
    if hz.is_finite() {
        format!("{hz:.decimals$} Hz")
    } else {
        "measuring".into()
    }
}

/// Whether a status says the daemon is fully working: sensors streaming
/// (the IMU only when the mode uses it), nothing stuck.
pub fn is_healthy(status: &StatusMessage, uses_imu: bool) -> bool {
    let h = status.sensor_health;
    h & HEALTH_CAMERA_STREAMING != 0
        && (!uses_imu || h & HEALTH_IMU_STREAMING != 0)
        && h & (HEALTH_STAGE_STUCK | HEALTH_IMU_RECONNECTING | HEALTH_CAMERA_STALLED) == 0
}

/// The health bits as words, for logs and systemd's STATUS= line.
pub fn health_words(health: u32) -> String {
    let names = [
        (HEALTH_CAMERA_STREAMING, "camera ok"),
        (HEALTH_IMU_STREAMING, "imu ok"),
        (HEALTH_IMU_RECONNECTING, "imu reconnecting"),
        (HEALTH_CAMERA_STALLED, "camera stalled"),
        (HEALTH_TIMESTAMP_JUMP, "timestamp jump"),
        (HEALTH_STAGE_STUCK, "slam stage stuck"),
        (
            HEALTH_NOISE_AT_BOUND,
            "noise estimate at its bound: check the sensor file",
        ),
        (
            HEALTH_CALIBRATION_DRIFT,
            "camera-imu estimate far from the calibration file: recalibrate",
        ),
    ];
    let words: Vec<&str> = names
        .iter()
        .filter(|(bit, _)| health & bit != 0)
        .map(|(_, n)| *n)
        .collect();
    if words.is_empty() {
        "no sensor data".into()
    } else {
        words.join(", ")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rules() -> HealthRules {
        HealthRules {
            camera_stall_ns: 1_000_000_000,
            imu_stall_ns: 1_000_000_000,
            stuck_ns: 10_000_000_000,
            uses_imu: true,
        }
    }

    /// The first status gives each stream's rate over the time since its
    /// first arrival, not since the start (it once said 0 Hz while frames
    /// flowed, then, counted from the start, a fraction of the true rate
    /// when the camera took a while to begin), and says "not known yet"
    /// (NaN) rather than 0 Hz while only one has come; later periods
    /// count from the previous status.
    #[test]
    fn the_first_status_times_each_stream_from_its_first_arrival() {
        const MS: i64 = 1_000_000;
        let health = Health::new();
        let rules = rules();
        let mut base = RateBase::default();
        let start = 1_000_000 * MS;
        // The IMU at 200 Hz from the start, the camera at 20 Hz from
        // 700 ms on, one pose so far at 990 ms.
        for k in 0..200 {
            health.imu_arrived(start + k * 5 * MS);
        }
        for k in 0..6 {
            health.frame_arrived(start + 700 * MS + k * 50 * MS);
        }
        health.pose_published(start + 990 * MS);
        let now = start + 1000 * MS;
        let m = health.status_at(now, &rules, &mut base, &[], (0, 0));
        // 199 samples after the first, over 1 s; 5 frames after the
        // first, over 300 ms.
        assert!((m.imu_rate_hz - 199.0).abs() < 1e-9, "{m:?}");
        assert!((m.camera_rate_hz - 5.0 / 0.3).abs() < 1e-9, "{m:?}");
        assert!(m.pose_rate_hz.is_nan(), "{m:?}");
        assert_eq!(rate_words(m.pose_rate_hz, 1), "measuring");
        assert_eq!(rate_words(m.camera_rate_hz, 1), "16.7 Hz");

        // The next period: from the previous status, every arrival counted.
        for k in 6..26 {
            health.frame_arrived(start + 700 * MS + k * 50 * MS);
        }
        for k in 1..21 {
            health.pose_published(start + 990 * MS + k * 50 * MS);
        }
        let m = health.status_at(now + 1000 * MS, &rules, &mut base, &[], (0, 0));
        assert!((m.camera_rate_hz - 20.0).abs() < 1e-9, "{m:?}");
        assert!((m.pose_rate_hz - 20.0).abs() < 1e-9, "{m:?}");
        // The IMU stopped: 0 Hz is then the truth.
        assert_eq!(m.imu_rate_hz, 0.0, "{m:?}");
    }

    #[test]
    fn the_status_says_when_the_map_waits_for_a_start_in_motion_to_settle() {
        let health = Health::new();
        assert_eq!(health.waiting_words(), None);
        health.second_stage_waiting.store(true, Ordering::Relaxed);
        let words = health.waiting_words().expect("words");
        assert!(
            words.contains("settle") && words.contains("odometry frame"),
            "{words}"
        );
        health.second_stage_waiting.store(false, Ordering::Relaxed);
        assert_eq!(health.waiting_words(), None);
    }

    #[test]
    fn the_map_words_say_how_far_the_orientation_was_turned() {
        let health = Health::new();
        assert_eq!(health.map_words(), None);
        health.map_mode.store(MAP_BUILDING, Ordering::Relaxed);
        health.map_landmarks.store(812, Ordering::Relaxed);
        health.map_saves.store(3, Ordering::Relaxed);
        health.map_unknowns.store(3120, Ordering::Relaxed);
        health.record_orientation_offset_deg(0.4271);
        assert_eq!(
            health.map_words().as_deref(),
            Some("map: building, 3 saves (812 landmarks at the last), 3120 unknowns in the last solve, orientation turned 0.43 deg to fit it")
        );
    }

    /// Localising: the words say whether the robot is placed in the map,
    /// and what a robot that never is should do.
    #[test]
    fn the_map_words_say_whether_the_robot_is_placed_in_the_saved_map() {
        let health = Health::new();
        health.map_mode.store(MAP_LOCALISING, Ordering::Relaxed);
        health.map_landmarks.store(2180, Ordering::Relaxed);
        for _ in 0..3 {
            health.record_map_placement(false, false);
        }
        let words = health.map_words().expect("words");
        assert!(
            words.contains("not placed in it yet")
                && words.contains("move the map file away")
                && words.contains("0 of 3 frames placed"),
            "{words}"
        );
        health.record_map_placement(true, false);
        let words = health.map_words().expect("words");
        assert!(
            words.contains("2180 landmarks), placed in it; 1 of 4 frames placed"),
            "{words}"
        );
        health.record_map_placement(false, false);
        let words = health.map_words().expect("words");
        assert!(
            words.contains("not placed in it now") && words.contains("1 of 5 frames placed"),
            "{words}"
        );
        // A dropped localisation: placed by the odometry until found again.
        health.record_map_placement(true, true);
        let words = health.map_words().expect("words");
        assert!(
            words.contains("by the odometry alone while relocalising")
                && words.contains("2 of 6 frames placed"),
            "{words}"
        );
        health.record_map_placement(true, false);
        let words = health.map_words().expect("words");
        assert!(words.contains("), placed in it; 3 of 7"), "{words}");
    }

    #[test]
    fn rates_over_a_period() {
        // Nothing yet: 0 Hz.
        assert_eq!(rate_hz(0, 0, 0, 0, 1_000), 0.0);
        // A stream that began before the period: every arrival counts.
        assert!((rate_hz(30, 10, 1_000_000_000, 5, 2_000_000_000) - 20.0).abs() < 1e-9);
        // A stream that began in it: timed from its first arrival.
        assert!((rate_hz(11, 0, 1_000_000_000, 1_500_000_000, 2_000_000_000) - 20.0).abs() < 1e-9);
        // One arrival: not known.
        assert!(rate_hz(1, 0, 0, 1_500_000_000, 2_000_000_000).is_nan());
    }

    #[test]
    fn status_says_where_the_camera_imu_estimate_is_and_warns_when_far() {
        let health = Health::new();
        let rules = rules();
        let mut base = RateBase::default();
        let before = health.status(&rules, &mut base, &[], (0, 0));
        assert!(
            before.camera_imu_rotation_deg.is_nan() && before.camera_imu_time_offset_s.is_nan()
        );
        let mut estimate = CameraImuEstimate {
            T_body_cam0: nalgebra::Isometry3::identity(),
            T_cam0_cam1: nalgebra::Isometry3::identity(),
            time_offset_s: -0.005,
            rotation_from_file_deg: 0.8,
            translation_from_file_m: 0.004,
            stereo_rotation_from_file_deg: 0.01,
            rotation_sigma_deg: 0.02,
            translation_sigma_m: 0.001,
            time_offset_sigma_s: 0.0001,
            far_from_file: false,
            solves: 10,
            held_at_file: false,
        };
        health.record_camera_imu(Some(estimate));
        let m = health.status(&rules, &mut base, &[], (0, 0));
        assert_eq!(
            (
                m.camera_imu_rotation_deg,
                m.camera_imu_translation_m,
                m.camera_imu_time_offset_s
            ),
            (0.8, 0.004, -0.005)
        );
        assert_eq!(m.sensor_health & HEALTH_CALIBRATION_DRIFT, 0);
        estimate.far_from_file = true;
        health.record_camera_imu(Some(estimate));
        let m = health.status(&rules, &mut base, &[], (0, 0));
        assert_ne!(m.sensor_health & HEALTH_CALIBRATION_DRIFT, 0);
        assert!(health_words(m.sensor_health).contains("recalibrate"));
        health.record_camera_imu(None);
        let m = health.status(&rules, &mut base, &[], (0, 0));
        assert!(m.camera_imu_rotation_deg.is_nan());
        assert_eq!(m.sensor_health & HEALTH_CALIBRATION_DRIFT, 0);
    }

    #[test]
    fn status_says_what_noise_the_estimator_weighs_with() {
        let health = Health::new();
        let rules = rules();
        let mut base = RateBase::default();
        let before = health.status(&rules, &mut base, &[], (0, 0));
        assert!(before.imu_noise_scale_gyro.is_nan() && before.pixel_noise_scale.is_nan());
        let scale = NoiseScale {
            gyro: 3.5,
            accel: 100.0,
            pixel: 0.25,
            ..NoiseScale::DECLARED
        };
        health.record_noise_scale(Some(scale), true);
        let m = health.status(&rules, &mut base, &[], (0, 0));
        assert_eq!(
            (
                m.imu_noise_scale_gyro,
                m.imu_noise_scale_accel,
                m.pixel_noise_scale
            ),
            (3.5, 100.0, 0.25)
        );
        assert_ne!(m.sensor_health & HEALTH_NOISE_AT_BOUND, 0);
        assert!(health_words(m.sensor_health).contains("check the sensor file"));
        health.record_noise_scale(Some(NoiseScale::DECLARED), false);
        let m = health.status(&rules, &mut base, &[], (0, 0));
        assert_eq!(m.sensor_health & HEALTH_NOISE_AT_BOUND, 0);
        assert_eq!(m.imu_noise_scale_accel, 1.0);
        health.record_noise_scale(None, false);
        assert!(health
            .status(&rules, &mut base, &[], (0, 0))
            .imu_noise_scale_gyro
            .is_nan());
    }

    #[test]
    fn histogram_quantiles_are_within_one_percent_above() {
        let mut h = LatencyHistogram::default();
        assert_eq!(h.quantile_us(0.5), None);
        // 1..=1000 us: p50 = 500, p99 = 990 by nearest rank.
        for us in 1..=1000 {
            h.record(us as f64);
        }
        let p50 = h.quantile_us(0.5).expect("values");
        let p99 = h.quantile_us(0.99).expect("values");
        assert!((500.0..=505.0).contains(&p50), "p50 {p50}");
        assert!((990.0..=999.9).contains(&p99), "p99 {p99}");
        assert_eq!(h.quantile_us(1.0), Some(1000.0));
        assert_eq!(h.count(), 1000);
    }

    #[test]
    fn histogram_takes_any_number() {
        let mut h = LatencyHistogram::default();
        for us in [f64::NAN, -5.0, 0.0, 0.5, 1e12, f64::INFINITY] {
            h.record(us);
        }
        assert_eq!(h.count(), 6);
        assert_eq!(h.quantile_us(0.5), Some(1.0));
        assert_eq!(h.max_us(), f64::INFINITY);
        // The last bucket holds everything past 100 s.
        assert!(h.quantile_us(1.0).expect("values") >= 1e8 * 0.99);
    }

    #[test]
    fn histogram_memory_does_not_grow() {
        let mut h = LatencyHistogram::default();
        let before = h.counts.capacity();
        for i in 0..100_000 {
            h.record(i as f64 * 7.3);
        }
        assert_eq!(h.counts.capacity(), before);
    }
}
