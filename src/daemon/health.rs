//! What the threads tell the supervisor: counters, last-arrival stamps,
//! the SLAM stage's heartbeat, latencies. Atomics (and one short-held
//! lock for the latency window), written by the sensor and SLAM threads,
//! read once per status period into a [`StatusMessage`] and systemd's
//! STATUS= line.

use std::sync::atomic::{AtomicBool, AtomicI64, AtomicU32, AtomicU64, Ordering};
use std::sync::Mutex;

use crate::publish::{
    QueueFill, StatusMessage, HEALTH_CAMERA_STALLED, HEALTH_CAMERA_STREAMING,
    HEALTH_IMU_RECONNECTING, HEALTH_IMU_STREAMING, HEALTH_STAGE_STUCK, HEALTH_TIMESTAMP_JUMP,
};
use crate::run::TimingStats;
use crate::sensors::yei::device::host_monotonic_ns;

/// Shared by every thread of the pipeline.
#[derive(Default)]
pub struct Health {
    pub frames_in: AtomicU64,
    pub imu_in: AtomicU64,
    pub poses_out: AtomicU64,
    pub pose_fast_out: AtomicU64,
    /// Poses the publisher failed to send.
    pub pose_drops: AtomicU64,
    /// Frames and samples the SLAM stage refused (stamps going back).
    pub frames_rejected: AtomicU64,
    pub imu_rejected: AtomicU64,
    /// Stamps going back, or forward by more than a second.
    pub timestamp_jumps: AtomicU64,
    /// Host time of the last frame / sample handed to the queue, ns (0: none yet).
    pub last_frame_ns: AtomicI64,
    pub last_imu_ns: AtomicI64,
    /// Host time the SLAM stage last went round its loop, ns.
    pub stage_heartbeat_ns: AtomicI64,
    /// The IMU driver lost its port and is reopening it.
    pub imu_reconnecting: AtomicBool,
    pub imu_reconnects: AtomicU64,
    /// The last frame's tracking state (the wire code).
    pub tracking_state: AtomicU32,
    /// Set by a replay source when the recording has been played out.
    pub source_finished: AtomicBool,
    /// Frame arrival to pose published, us, since the last status.
    latency_window_us: Mutex<Vec<f64>>,
    /// Every latency of the run, us (the exit report).
    latency_all_us: Mutex<Vec<f64>>,
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

/// Rules for the health bits.
#[derive(Debug, Clone, Copy)]
pub struct HealthRules {
    pub camera_stall_ns: i64,
    pub imu_stall_ns: i64,
    pub stuck_ns: i64,
    pub uses_imu: bool,
}

impl Health {
    pub fn new() -> Self {
        let h = Self::default();
        h.stage_heartbeat_ns
            .store(host_monotonic_ns(), Ordering::Relaxed);
        h
    }

    pub fn record_latency_us(&self, us: f64) {
        for list in [&self.latency_window_us, &self.latency_all_us] {
            list.lock().unwrap_or_else(|e| e.into_inner()).push(us);
        }
    }

    /// Every latency so far, us.
    pub fn all_latencies_us(&self) -> Vec<f64> {
        self.latency_all_us
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
        let now = host_monotonic_ns();
        let frames = self.frames_in.load(Ordering::Relaxed);
        let imu = self.imu_in.load(Ordering::Relaxed);
        let poses = self.poses_out.load(Ordering::Relaxed);
        let jumps = self.timestamp_jumps.load(Ordering::Relaxed);
        let dt_s = if base.t_ns > 0 {
            (now - base.t_ns) as f64 * 1e-9
        } else {
            0.0
        };
        let rate = |n: u64, b: u64| {
            if dt_s > 0.0 {
                n.saturating_sub(b) as f64 / dt_s
            } else {
                0.0
            }
        };
        let mut m = StatusMessage {
            t_ns: now,
            camera_rate_hz: rate(frames, base.frames),
            imu_rate_hz: rate(imu, base.imu),
            pose_rate_hz: rate(poses, base.poses),
            camera_drops: drops.0 + self.frames_rejected.load(Ordering::Relaxed),
            imu_drops: drops.1 + self.imu_rejected.load(Ordering::Relaxed),
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
