//! One whole run on a dataset folder: open it, build the SLAM pipeline for
//! the mode, stream it through, score it against the dataset's ground
//! truth, and fill the report. `rigslam run` and `rigslam demo` both call
//! this.

use std::collections::BTreeMap;
use std::path::Path;

use super::recognition_check::{check_recognitions, SightingLog, WRONG_M};
use crate::absolute::map_file::{MapFileError, SavedMap};
use crate::dataset::{
    groundtruth_trajectory, open_dataset, Dataset, DatasetError, SensorStream, StreamOptions,
};
use crate::eval::consistency::{pose_nees, CovariancePose};
use crate::eval::map_consistency::{
    map_position_nees, map_position_nees_from_origin, MapOrigin, MapPosition,
};
use crate::eval::report::Evaluation;
use crate::eval::{evaluate, Alignment, EvalOptions};
use crate::relative::TrackingState;
use crate::relative::{EstimatorKind, OdometryError, RelativeOutput, RigModel, SensorMode};
use crate::slam_config::SlamSettings;
use crate::slam_pipeline::{PipelineError, SecondStage, SlamPipeline};
use crate::trajectory::{StampedPose, Trajectory};

use super::report::{resident_memory_mib, RunReport, TimingStats};
use super::{run_stream, RunOptions, RunOutcome};

/// What to run.
#[derive(Debug, Clone)]
pub struct DatasetRun {
    /// `None`: the richest mode the dataset supports.
    pub mode: Option<SensorMode>,
    /// Relative estimator to run.
    pub estimator: EstimatorKind,
    /// Settings of both stages; `absolute.enabled` runs the absolute
    /// stage (edge map + position filter) on the relative stage's outputs:
    /// the corrected trajectory becomes the run's trajectory and the
    /// relative one is kept beside it.
    pub settings: SlamSettings,
    /// How the run is paced (as recorded, or as fast as possible).
    pub options: RunOptions,
    /// Skip the dataset's first seconds, s (from its first frame).
    pub start_s: f64,
    /// Stop after this many frames (all when `None`).
    pub max_frames: Option<usize>,
    /// Ground truth to score against instead of the dataset's own.
    pub groundtruth: Option<Trajectory>,
    /// `None`: se3 for metric modes, sim3 for `mono`.
    pub align: Option<Alignment>,
    /// With the absolute stage: write the final map (landmarks, covariances,
    /// descriptors) here at the end of the run.
    pub save_map: Option<std::path::PathBuf>,
    /// Localise in this saved map instead of building one: the run's
    /// trajectory is the localised one, in the map's frame, from the
    /// first frame the map was recognised.
    pub load_map: Option<std::sync::Arc<SavedMap>>,
    /// The rig's calibration instead of the dataset's own (a calibration
    /// folder, `rigslam run --calibration`).
    pub rig: Option<RigModel>,
}

impl Default for DatasetRun {
    fn default() -> Self {
        Self {
            mode: None,
            estimator: EstimatorKind::Window,
            settings: SlamSettings::default(),
            options: RunOptions::default(),
            start_s: 0.0,
            max_frames: None,
            groundtruth: None,
            align: None,
            save_map: None,
            load_map: None,
            rig: None,
        }
    }
}

/// Everything a run produced.
pub struct DatasetRunResult {
    /// The numbers of the run.
    pub report: RunReport,
    /// The trajectory, timings and counters.
    pub outcome: RunOutcome,
    /// The trajectory against the ground truth, when there is one.
    pub evaluation: Option<Evaluation>,
    /// The relative stage's own trajectory when the absolute stage ran
    /// (then `outcome.trajectory` is the corrected one).
    pub trajectory_relative: Option<Trajectory>,
    /// The relative stage's trajectory against the ground truth, when the absolute stage ran.
    pub evaluation_relative: Option<Evaluation>,
}

/// Why a run could not happen.
#[derive(Debug, thiserror::Error)]
pub enum RunError {
    #[error(transparent)]
    /// The dataset could not be read.
    Dataset(#[from] DatasetError),
    #[error(transparent)]
    /// The estimator could not be built for the rig and mode.
    Setup(#[from] OdometryError),
    #[error(transparent)]
    /// The pipeline could not be built (the rig, the mode or a setting).
    Pipeline(#[from] PipelineError),
    #[error("--start-s must be a finite number >= 0, got {0}")]
    /// `--start-s` is negative or not finite (the field is the value given).
    BadStart(f64),
    #[error("{0} lists no frames")]
    /// The dataset (named by the field) has no frame to run on.
    NoFrames(String),
    #[error(transparent)]
    /// A setting is missing or out of range.
    Config(#[from] crate::relative::config::ConfigError),
    #[error("saving the map: {0}")]
    /// The map could not be written.
    SaveMap(#[from] MapFileError),
    #[error("--save-map needs the absolute stage (--absolute)")]
    /// `--save-map` was given without `--absolute`.
    SaveMapWithoutAbsolute,
    #[error("the map is saved at the end of the run: no map to save (the absolute stage never had two landmarks in view while tracking)")]
    /// The absolute stage never had a map to save.
    NoMapToSave,
    #[error("the map is saved at the end of the run: no map to save: the absolute stage waited for the relative stage to settle on all {0} frames with landmarks (after a start from rest, until the accelerometer bias is known to [absolute] wait_accel_bias_sigma_m_s2, for at most wait_accel_bias_max_s: move and turn the rig, or set [absolute] wait_accel_bias = \"off\")")]
    /// The absolute stage never started its map: it waited on every frame.
    NoMapWhileWaiting(u64),
    #[error("--load-map and --absolute: pick one (localise in a saved map, or build a new one)")]
    /// `--load-map` and `--absolute` were both given.
    LoadMapAndAbsolute,
}

/// Runs `run` on the dataset at `path`; `on_frame` sees every output and
/// the number of frames the run will take at most.
pub fn run_dataset(
    path: &Path,
    run: &DatasetRun,
    mut on_frame: impl FnMut(&RelativeOutput, usize),
) -> Result<DatasetRunResult, RunError> {
    if !(run.start_s.is_finite() && run.start_s >= 0.0) {
        return Err(RunError::BadStart(run.start_s));
    }
    let build_map = run.settings.absolute.enabled;
    if run.save_map.is_some() && !build_map {
        return Err(RunError::SaveMapWithoutAbsolute);
    }
    if run.load_map.is_some() && build_map {
        return Err(RunError::LoadMapAndAbsolute);
    }
    let dataset = open_dataset(path)?;
    let rig = run.rig.clone().unwrap_or_else(|| rig_of(&dataset));
    let mode = run.mode.unwrap_or_else(|| default_mode(&rig));
    let second = match &run.load_map {
        Some(map) => SecondStage::Localise(map.clone()),
        None => SecondStage::from_settings(&run.settings),
    };
    let mut pipeline = SlamPipeline::new(run.estimator, mode, &rig, &run.settings, second)?;
    let first_ns =
        first_frame_ns(&dataset).ok_or_else(|| RunError::NoFrames(path.display().to_string()))?;
    let mut stream = SensorStream::new(
        &dataset,
        StreamOptions {
            stereo: mode.uses_stereo(),
            imu: mode.uses_imu(),
            start_ns: Some(first_ns + (run.start_s * 1e9).round() as i64),
            max_frames: run.max_frames,
            imu_lead_ns: rig.frame_shift_ns(),
        },
    )?;
    let listed = stream.frames_listed();
    let mut corrected = Vec::new();
    let ground_truth = run
        .groundtruth
        .clone()
        .or_else(|| dataset_groundtruth(&dataset));
    // Only kept when there is a ground truth to check recognitions with.
    let mut sightings = ground_truth
        .as_ref()
        .filter(|_| build_map)
        .map(|_| SightingLog::default());
    if sightings.is_some() {
        if let Some(stage) = pipeline.absolute_mut() {
            stage.keep_alias_log();
        }
    }
    let mut covariance_poses = Vec::new();
    let mut map_positions = Vec::new();
    // The relative stage's origin when the map was anchored (its first
    // published map-frame covariance): what pins the map frame.
    let mut map_origin = None;
    let mut outcome = run_stream(&mut stream, &mut pipeline, run.options, |frame| {
        let o = &frame.relative;
        let mut map_position = None;
        if let Some(pose) = &frame.localised {
            corrected.push(StampedPose::new(
                pose.t_ns,
                pose.T_map_body.translation.vector,
                pose.T_map_body.rotation,
            ));
            map_position = Some((pose.t_ns, pose.T_map_body.translation.vector));
        }
        if let Some(pose) = &frame.corrected {
            if let Some(log) = sightings.as_mut() {
                log.note(o);
            }
            if o.state == TrackingState::Tracking {
                corrected.push(StampedPose::new(
                    pose.t_ns,
                    pose.T_world_body.translation.vector,
                    pose.T_world_body.rotation,
                ));
                map_position = Some((pose.t_ns, pose.T_world_body.translation.vector));
            }
        }
        if let (Some((t_ns, position_m)), Some(covariance_m2), Some(_)) = (
            map_position,
            frame.map_position_covariance_m2(),
            ground_truth.as_ref(),
        ) {
            if frame.corrected.is_some() && map_origin.is_none() {
                map_origin = o.pose_covariance.map(|c| MapOrigin {
                    t_ns: c.origin_t_ns,
                    T_map_origin: c.T_world_origin,
                });
            }
            map_positions.push(MapPosition {
                t_ns,
                position_m,
                covariance_m2,
            });
        }
        if let (Some(c), Some(_), TrackingState::Tracking) =
            (o.pose_covariance, ground_truth.as_ref(), o.state)
        {
            covariance_poses.push(CovariancePose {
                t_ns: o.t_ns,
                T_world_body: o.T_world_body,
                covariance: c,
            });
        }
        on_frame(o, listed)
    })?;
    pipeline.finish();
    let mut trajectory_relative = None;
    let held_back = pipeline.held_back_frames().unwrap_or(0);
    if pipeline.absolute().is_some() {
        if let Some(path) = &run.save_map {
            let map = pipeline.finish_map().ok_or(if held_back > 0 {
                RunError::NoMapWhileWaiting(held_back)
            } else {
                RunError::NoMapToSave
            })?;
            map.write(path)?;
            tracing::info!(
                "saved {} landmarks to {}",
                map.landmarks.len(),
                path.display()
            );
        }
    }
    if pipeline.absolute().is_some() || pipeline.localiser().is_some() {
        trajectory_relative = Some(std::mem::replace(
            &mut outcome.trajectory,
            Trajectory::new(corrected),
        ));
    }

    let align = run.align.unwrap_or(match mode {
        SensorMode::Mono => Alignment::Sim3,
        _ => Alignment::Se3,
    });
    let score = |trajectory: &Trajectory| match &ground_truth {
        Some(gt) if trajectory.len() >= 3 => {
            let options = EvalOptions {
                alignment: align,
                scale_by_path: mode == SensorMode::Mono,
                ..EvalOptions::default()
            };
            match evaluate(trajectory, gt, &options) {
                Ok(e) => Some(e),
                Err(e) => {
                    tracing::warn!("no accuracy: {e}");
                    None
                }
            }
        }
        _ => None,
    };
    let evaluation = score(&outcome.trajectory);
    let recognition_check = pipeline
        .absolute()
        .zip(ground_truth.as_ref())
        .zip(sightings.as_ref())
        .and_then(|((stage, gt), log)| check_recognitions(log, stage.aliases().into_iter(), gt));
    if let Some(check) = &recognition_check {
        tracing::info!(
            "recognitions against the ground truth: {} of {} over {WRONG_M} m ({} over 1 m), median {:.3} m",
            check.wrong,
            check.checked,
            check.over_1_m,
            check.median_m
        );
    }
    let evaluation_relative = trajectory_relative.as_ref().and_then(score);

    let (frame_stats, stages) = outcome.timing_report();
    let (rss_now, rss_peak) = resident_memory_mib();
    let counters: BTreeMap<String, u64> = pipeline
        .relative()
        .counters()
        .into_iter()
        .map(|(k, v)| (k.to_string(), v))
        .collect();
    let sequence_s = outcome.sequence_s();
    let stream_counts = stream.counts();
    let report = RunReport {
        dataset: path.display().to_string(),
        mode: mode.name().to_string(),
        estimator: run.estimator.name().to_string(),
        frames: stream_counts.frames,
        imu_samples: stream_counts.imu_samples,
        wall_s: outcome.wall_s,
        sequence_s,
        realtime_factor: if outcome.wall_s > 0.0 {
            sequence_s / outcome.wall_s
        } else {
            0.0
        },
        mean_ms_per_frame: frame_stats.map_or(0.0, |s| s.mean_ms),
        p50_ms_per_frame: frame_stats.map_or(0.0, |s| s.p50_ms),
        p99_ms_per_frame: frame_stats.map_or(0.0, |s| s.p99_ms),
        max_ms_per_frame: frame_stats.map_or(0.0, |s| s.max_ms),
        pose_latency_ms: TimingStats::of(&outcome.pose_ms),
        stages,
        initialized_at_s: outcome
            .initialized_at_ns
            .zip(outcome.first_frame_ns)
            .map(|(a, b)| (a - b) as f64 * 1e-9),
        lost_count: outcome.lost_count,
        lost_frames: outcome.lost_frames,
        poses_written: outcome.trajectory.len(),
        stream: stream_counts,
        counters,
        imu_noise_scale: pipeline.relative().imu_noise_scale(),
        camera_imu: pipeline.relative().camera_imu().map(Into::into),
        // Monocular vision alone has no metric scale: its covariance is in
        // its own arbitrary unit and a NEES against metric truth means nothing.
        nees: ground_truth
            .as_ref()
            .filter(|_| mode.uses_imu() || mode.uses_stereo())
            .and_then(|gt| pose_nees(&covariance_poses, gt)),
        map_nees: trajectory_relative
            .as_ref()
            .zip(evaluation.as_ref())
            .zip(ground_truth.as_ref())
            .and_then(|((_, e), gt)| map_position_nees(&map_positions, &e.alignment, gt)),
        map_nees_from_origin: map_origin
            .zip(ground_truth.as_ref())
            .and_then(|(origin, gt)| map_position_nees_from_origin(&map_positions, &origin, gt)),
        tilt: ground_truth
            .as_ref()
            .filter(|_| mode.uses_imu())
            .and_then(|gt| {
                crate::eval::tilt::tilt_error(
                    trajectory_relative.as_ref().unwrap_or(&outcome.trajectory),
                    gt,
                )
            }),
        peak_rss_mib: rss_peak,
        rss_at_10pct_mib: outcome.rss_at_10pct_mib,
        rss_at_end_mib: rss_now,
        eval: evaluation.as_ref().map(|e| e.report.clone()),
        eval_relative: evaluation_relative.as_ref().map(|e| e.report.clone()),
        absolute: pipeline.absolute().map(|s| s.stats().clone()),
        second_stage_held_back_frames: pipeline.held_back_frames(),
        second_stage_bias_waits_given_up: pipeline
            .held_back_frames()
            .map(|_| pipeline.bias_waits_given_up()),
        recognition_check,
        localise: pipeline.localiser().map(|l| l.stats().clone()),
    };
    Ok(DatasetRunResult {
        report,
        outcome,
        evaluation,
        trajectory_relative,
        evaluation_relative,
    })
}

/// The rig a dataset describes.
pub fn rig_of(dataset: &Dataset) -> RigModel {
    match dataset {
        Dataset::Euroc(d) => RigModel {
            cameras: d.cameras.iter().map(|c| c.calibration.clone()).collect(),
            imu: d.imu.as_ref().map(|i| i.calibration.clone()),
        },
        Dataset::Kitti(k) => RigModel {
            cameras: vec![k.camera.clone()],
            imu: None,
        },
    }
}

/// The richest mode a rig supports.
pub fn default_mode(rig: &RigModel) -> SensorMode {
    match (rig.cameras.len() >= 2, rig.imu.is_some()) {
        (true, true) => SensorMode::StereoInertial,
        (false, true) => SensorMode::MonoInertial,
        (true, false) => SensorMode::Stereo,
        (false, false) => SensorMode::Mono,
    }
}

fn first_frame_ns(dataset: &Dataset) -> Option<i64> {
    match dataset {
        Dataset::Euroc(d) => d.cameras.first()?.frames.first().map(|f| f.t_ns),
        Dataset::Kitti(k) => k.frames.first().map(|f| f.t_ns),
    }
}

fn dataset_groundtruth(dataset: &Dataset) -> Option<Trajectory> {
    match dataset {
        Dataset::Euroc(d) => d.groundtruth.as_deref().map(groundtruth_trajectory),
        Dataset::Kitti(k) => k.groundtruth.clone(),
    }
}

/// `stereo-inertial (window) 1669 frames in 9.1 s (9.2x real time), 3.10 ms/frame mean, 7.90 ms p99, pose out after 4.20 ms p99; initialised at 0.00 s, lost 0x, 1669 poses; ATE 0.041 m (se3), scale error 0.60 %, final drift 0.31 %`
pub fn summary_line(r: &RunReport) -> String {
    use crate::relative::window::NoiseScale;
    let mut line = format!(
        "{} ({}) {} frames in {:.1} s ({:.1}x real time), {:.2} ms/frame mean, {:.2} ms p99",
        r.mode,
        r.estimator,
        r.frames,
        r.wall_s,
        r.realtime_factor,
        r.mean_ms_per_frame,
        r.p99_ms_per_frame
    );
    if let Some(p) = &r.pose_latency_ms {
        line += &format!(", pose out after {:.2} ms p99", p.p99_ms);
    }
    line += "; ";
    match r.initialized_at_s {
        Some(t) => line += &format!("initialised at {t:.2} s, "),
        None => line += "never initialised, ",
    }
    line += &format!("lost {}x, {} poses", r.lost_count, r.poses_written);
    if let Some(&n) = r.counters.get("frames_without_imu").filter(|&&n| n > 0) {
        line += &format!(
            "; {n} frames without the IMU (it did not reach their instant: a gap in it, or a camera clock behind it)"
        );
    }
    if r.stream.any_skipped() {
        let s = &r.stream;
        line += &format!(
            "; input left out: {} listed images missing, {} right images missing, {} non-finite IMU samples",
            s.frames_missing_image, s.frames_missing_right, s.imu_samples_nonfinite
        );
    }
    if let Some(l) = &r.localise {
        line += &format!(
            "; localised in the map {} of {} frames ({} relocalisations: {} after a drop, {} by a second opinion)",
            l.localised_frames, l.frames, l.relocalisations, l.dropped, l.replaced
        );
    }
    if let Some(e) = &r.eval_relative {
        line += &format!("; relative stage alone ATE {:.3} m", e.ate_rmse_m);
    }
    if let Some(e) = &r.eval {
        line += &format!("; ATE {:.3} m ({})", e.ate_rmse_m, e.align.name());
        // Relative numbers only mean something over a real path, and a
        // mono run's scale is arbitrary by construction.
        if e.path_length_m < 1.0 {
            line += &format!(", true path only {:.3} m", e.path_length_m);
        } else {
            if let (Some(s), false) = (e.scale_error, r.mode == "mono") {
                line += &format!(", scale error {:.2} %", 100.0 * s);
            }
            if let Some(d) = e.final_drift_pct {
                line += &format!(", final drift {d:.2} % of {:.1} m", e.path_length_m);
            }
        }
    }
    if let Some(s) = r.imu_noise_scale.filter(|s| *s != NoiseScale::DECLARED) {
        line += &format!(
            "; noise weighed as {:.1}x the declared gyroscope, {:.1}x the accelerometer, {:.2}x the pixel sigma",
            s.gyro, s.accel, s.pixel
        );
    }
    if let Some(c) = r.camera_imu.as_ref().filter(|c| c.held_at_file) {
        line += &format!(
            "; camera-IMU calibration held at the file (no solve's data disagreed with it beyond chance; stereo rotation {:.3} deg)",
            c.stereo_rotation_from_file_deg
        );
    } else if let Some(c) = &r.camera_imu {
        line += &format!(
            "; camera-IMU refined to {:.3} deg, {:.1} mm and {:+.2} ms from the file (stereo rotation {:.3} deg){}",
            c.rotation_from_file_deg,
            c.translation_from_file_mm,
            c.time_offset_ms,
            c.stereo_rotation_from_file_deg,
            if c.far_from_file {
                " (far from it: check the calibration)"
            } else {
                ""
            }
        );
    }
    if let Some(n) = &r.nees {
        line += &format!(
            "; covariance NEES per dof {:.2} (position {:.2}, rotation {:.2}; each axis alone: position {:.2}, rotation {:.2})",
            n.mean_per_dof,
            n.position_per_dof,
            n.rotation_per_dof,
            n.position_marginal_per_dof,
            n.rotation_marginal_per_dof
        );
    }
    if let Some(n) = &r.map_nees {
        line += &format!(
            "; map-frame position NEES per dof {:.2} (median {:.2}, {:.0} % under the 95 % bound)",
            n.mean_per_dof,
            n.median_per_dof,
            100.0 * n.within_95
        );
        if let Some(o) = &r.map_nees_from_origin {
            line += &format!(
                ", {:.2} from the odometry's origin (median {:.2}, each axis alone {:.2})",
                o.mean_per_dof, o.median_per_dof, o.marginal_per_dof
            );
        }
    }
    if let Some(t) = &r.tilt {
        line += &format!(
            "; roll and pitch {:.2} deg rms from the truth's ({:.2} max)",
            t.rms_deg, t.max_deg
        );
    }
    line
}
