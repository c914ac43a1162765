//! The numbers of one `rigslam run`: per-frame and per-stage timings
//! (mean, p50, p99), counts, and the accuracy when ground truth is known.
//! Written by `--report FILE` and `--json` with the keys listed on [`RunReport`].

use std::collections::BTreeMap;

use crate::absolute::AbsoluteStats;
use crate::dataset::StreamCounts;
use crate::eval::EvalReport;

/// Mean, median and 99th percentile of a set of durations, ms.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct TimingStats {
    /// Mean, ms.
    pub mean_ms: f64,
    /// Median, ms.
    pub p50_ms: f64,
    /// 99th percentile, ms.
    pub p99_ms: f64,
    /// Largest, ms.
    pub max_ms: f64,
    /// How many frames the stage ran on.
    pub count: usize,
}

impl TimingStats {
    /// Stats of `samples_ms`; `None` when empty. Percentiles by the
    /// nearest-rank rule (p99 of 100 samples is the 99th smallest).
    pub fn of(samples_ms: &[f64]) -> Option<Self> {
        if samples_ms.is_empty() {
            return None;
        }
        let mut sorted = samples_ms.to_vec();
        sorted.sort_by(f64::total_cmp);
        let rank = |p: f64| {
            let k = (p * sorted.len() as f64).ceil() as usize;
            sorted[k.clamp(1, sorted.len()) - 1]
        };
        Some(Self {
            mean_ms: sorted.iter().sum::<f64>() / sorted.len() as f64,
            p50_ms: rank(0.5),
            p99_ms: rank(0.99),
            max_ms: sorted[sorted.len() - 1],
            count: sorted.len(),
        })
    }
}

/// `rigslam run --report FILE` (and `--json`).
#[derive(Debug, Clone, serde::Serialize)]
pub struct RunReport {
    /// The dataset's path.
    pub dataset: String,
    /// Sensor mode run (`mono`, `stereo-inertial`, ...).
    pub mode: String,
    /// Relative estimator run (`window` or `ekf`).
    pub estimator: String,
    /// Frames delivered.
    pub frames: u64,
    /// IMU samples delivered.
    pub imu_samples: u64,
    /// Wall time of the run, s.
    pub wall_s: f64,
    /// Sequence time covered by the frames, s.
    pub sequence_s: f64,
    /// Sequence time over wall time.
    pub realtime_factor: f64,
    /// Mean wall time per frame, ms (the frame's calls, its pose and the
    /// work after it, plus the IMU samples before it).
    pub mean_ms_per_frame: f64,
    /// Median wall time per frame, ms.
    pub p50_ms_per_frame: f64,
    /// 99th percentile of the wall time per frame, ms.
    pub p99_ms_per_frame: f64,
    /// Largest wall time of a frame, ms.
    pub max_ms_per_frame: f64,
    /// Wall time from a frame's call to its pose (the IMU samples before
    /// it included): on a keyframe the window's optimisation comes after.
    pub pose_latency_ms: Option<TimingStats>,
    /// Timing of each estimator stage, by name.
    pub stages: BTreeMap<String, TimingStats>,
    /// Sequence time of the first frame with a metric (or, in `mono`,
    /// consistently scaled) pose, s from the first frame; `null` if never.
    pub initialized_at_s: Option<f64>,
    /// Frames on which tracking was lost after having been initialised.
    pub lost_count: u64,
    /// Frames reported lost (including consecutive ones).
    pub lost_frames: u64,
    /// Poses in the written trajectory.
    pub poses_written: usize,
    /// What the dataset stream delivered and left out.
    pub stream: StreamCounts,
    /// The estimator's own counters (drops, resets, keyframes, ...).
    pub counters: BTreeMap<String, u64>,
    /// At the end: the multipliers on the declared gyroscope and
    /// accelerometer noise densities the estimator weighed the IMU with
    /// (estimated online unless `imu_noise_adaptation = false`).
    pub imu_noise_scale: Option<crate::relative::window::NoiseScale>,
    /// At the end: camera 0's pose in the IMU frame and the frames' time
    /// offset as refined online (`camera_imu_refinement`), against the
    /// calibration file.
    pub camera_imu: Option<CameraImuReport>,
    /// Consistency of the published pose covariance against the ground
    /// truth (NEES per degree of freedom; 1 is consistent). None without
    /// ground truth and in `mono`, whose poses have no metric scale.
    pub nees: Option<crate::eval::consistency::NeesReport>,
    /// Consistency of the published map-frame position covariance (the
    /// second stage's) against the ground truth, after the alignment that
    /// scored the trajectory (`crate::eval::map_consistency`). None
    /// without a second stage or ground truth.
    pub map_nees: Option<crate::eval::map_consistency::PositionNeesReport>,
    /// The same positions scored in the covariance's own frame of
    /// reference: from the relative stage's origin the map frame was
    /// pinned by (`map_position_nees_from_origin`), which keeps what the
    /// whole run shares. None without a map built in this run or ground
    /// truth.
    pub map_nees_from_origin: Option<crate::eval::map_consistency::PositionNeesReport>,
    /// Roll and pitch against the ground truth's, whatever the heading
    /// (`crate::eval::tilt`), of the relative stage's poses in the
    /// inertial modes. None without ground truth or an IMU.
    pub tilt: Option<crate::eval::tilt::TiltReport>,
    /// Peak resident memory of the process, MiB (Linux VmHWM).
    pub peak_rss_mib: Option<f64>,
    /// Resident memory at 10 % and at the end of the run, MiB: flat memory
    /// shows as two close numbers.
    pub rss_at_10pct_mib: Option<f64>,
    /// Resident memory at the end of the run, MiB.
    pub rss_at_end_mib: Option<f64>,
    /// Against the dataset's ground truth, when it has one (the corrected
    /// trajectory when the absolute stage ran).
    pub eval: Option<EvalReport>,
    /// The relative stage's own trajectory against the ground truth, when
    /// the absolute stage ran.
    pub eval_relative: Option<EvalReport>,
    /// The absolute stage's counters and times, when it ran.
    pub absolute: Option<AbsoluteStats>,
    /// Frames whose landmarks the absolute stage or the localiser did not
    /// take while the relative stage settled (a start in motion, or its
    /// accelerometer bias not yet known; None without either).
    pub second_stage_held_back_frames: Option<u64>,
    /// Waits for the accelerometer bias that outlasted `[absolute]
    /// wait_accel_bias_max_s`: the second stage then started without it
    /// (None without a second stage).
    pub second_stage_bias_waits_given_up: Option<u64>,
    /// The absolute stage's recognitions checked against the ground truth,
    /// when it ran and recognised landmarks.
    pub recognition_check: Option<super::recognition_check::RecognitionCheck>,
    /// Localisation in a saved map (`--load-map`), when it ran.
    pub localise: Option<crate::absolute::localise::LocaliseStats>,
}

/// The process's resident memory now and at its peak, MiB, from
/// `/proc/self/status` (`None` off Linux).
pub fn resident_memory_mib() -> (Option<f64>, Option<f64>) {
    let Ok(status) = std::fs::read_to_string("/proc/self/status") else {
        return (None, None);
    };
    let field = |name: &str| {
        status
            .lines()
            .find(|l| l.starts_with(name))
            .and_then(|l| l.split_whitespace().nth(1))
            .and_then(|kib| kib.parse::<f64>().ok())
            .map(|kib| kib / 1024.0)
    };
    (field("VmRSS:"), field("VmHWM:"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn percentiles_follow_the_nearest_rank_rule() {
        let samples: Vec<f64> = (1..=100).map(f64::from).collect();
        let s = TimingStats::of(&samples).expect("stats");
        assert_eq!(s.p50_ms, 50.0);
        assert_eq!(s.p99_ms, 99.0);
        assert_eq!(s.max_ms, 100.0);
        assert!((s.mean_ms - 50.5).abs() < 1e-12);
        let one = TimingStats::of(&[3.0]).expect("stats");
        assert_eq!((one.p50_ms, one.p99_ms), (3.0, 3.0));
        assert!(TimingStats::of(&[]).is_none());
    }

    #[test]
    fn memory_is_read_on_linux() {
        let (now, peak) = resident_memory_mib();
        if cfg!(target_os = "linux") {
            let (now, peak) = (now.expect("VmRSS"), peak.expect("VmHWM"));
            assert!(now > 0.0 && peak >= now, "{now} {peak}");
        }
    }
}

/// The online camera-IMU refinement's answer, in a user's units.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct CameraImuReport {
    /// Camera 0 in the body (IMU) frame: translation, m, and rotation as a
    /// quaternion `[w, x, y, z]`.
    pub translation_body_cam0_m: [f64; 3],
    /// Rotation of camera 0 in the body frame, quaternion `[w, x, y, z]`.
    pub rotation_body_cam0_wxyz: [f64; 4],
    /// The frames' lag behind the IMU beyond the file's time shift, ms.
    pub time_offset_ms: f64,
    /// Distance from the file.
    pub rotation_from_file_deg: f64,
    /// Translation distance from the file, mm.
    pub translation_from_file_mm: f64,
    /// Camera 1's rotation in camera 0 against the file's, deg (0 without
    /// a second camera), and that rotation as a quaternion `[w, x, y, z]`.
    pub stereo_rotation_from_file_deg: f64,
    /// Camera 1's rotation in camera 0, quaternion `[w, x, y, z]`.
    pub rotation_cam0_cam1_wxyz: [f64; 4],
    /// One sigma of the last solve.
    pub rotation_sigma_deg: f64,
    /// One sigma of the translation, mm.
    pub translation_sigma_mm: f64,
    /// One sigma of the time offset, ms.
    pub time_offset_sigma_ms: f64,
    /// Farther from the file than the warning distance.
    pub far_from_file: bool,
    /// Still held at the file: no solve's data disagreed with it beyond chance.
    pub held_at_file: bool,
}

impl From<crate::relative::window::CameraImuEstimate> for CameraImuReport {
    fn from(e: crate::relative::window::CameraImuEstimate) -> Self {
        let t = e.T_body_cam0.translation.vector;
        let q = e.T_body_cam0.rotation;
        Self {
            translation_body_cam0_m: [t.x, t.y, t.z],
            rotation_body_cam0_wxyz: [q.w, q.i, q.j, q.k],
            time_offset_ms: e.time_offset_s * 1e3,
            rotation_from_file_deg: e.rotation_from_file_deg,
            stereo_rotation_from_file_deg: e.stereo_rotation_from_file_deg,
            rotation_cam0_cam1_wxyz: {
                let s = e.T_cam0_cam1.rotation;
                [s.w, s.i, s.j, s.k]
            },
            translation_from_file_mm: e.translation_from_file_m * 1e3,
            rotation_sigma_deg: e.rotation_sigma_deg,
            translation_sigma_mm: e.translation_sigma_m * 1e3,
            time_offset_sigma_ms: e.time_offset_sigma_s * 1e3,
            far_from_file: e.far_from_file,
            held_at_file: e.held_at_file,
        }
    }
}
