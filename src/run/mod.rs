//! A recorded sequence through the SLAM pipeline, frame by frame, as fast
//! as it goes or paced by its stamps: what `rigslam run` does. The
//! pipeline ([`crate::slam_pipeline`]) sees exactly what it would see live
//! (the merged stream of [`crate::dataset::stream`]); this module only
//! times it, keeps the poses and counts what happened.

pub mod dataset_run;
pub mod recognition_check;
pub mod report;

use std::collections::BTreeMap;
use std::time::{Duration, Instant};

use nalgebra::Isometry3;

use crate::dataset::{DatasetError, SensorEvent, SensorStream};
use crate::relative::{FrameInput, RelativeOutput, TrackingState};
use crate::slam_pipeline::{PipelineFrame, SlamPipeline};
use crate::trajectory::{StampedPose, Trajectory};

pub use report::{resident_memory_mib, RunReport, TimingStats};

/// How to run.
#[derive(Debug, Clone, Copy, Default)]
pub struct RunOptions {
    /// Sleep so that frames are handed over at their recorded pace.
    pub realtime: bool,
}

/// What a run produced, before it is written anywhere.
#[derive(Debug, Clone, Default)]
pub struct RunOutcome {
    /// One pose per frame with a usable estimate from the relative stage
    /// (tracking, or the mono modes' consistently scaled initial poses).
    pub trajectory: Trajectory,
    /// Wall time per frame: the frame's own calls through both stages
    /// (its pose and the work after it) plus the IMU samples delivered
    /// since the previous frame, ms.
    pub frame_ms: Vec<f64>,
    /// Wall time from the frame's call to its pose (the IMU samples since
    /// the previous frame included): the latency a subscriber sees, less
    /// the sensor's, ms.
    pub pose_ms: Vec<f64>,
    /// Wall time of each estimator stage per frame (and `imu_push`, the IMU samples before it), ms,
    /// by stage name.
    pub stage_ms: BTreeMap<&'static str, Vec<f64>>,
    /// Stamp of the first frame, ns (dataset clock).
    pub first_frame_ns: Option<i64>,
    /// Stamp of the last frame, ns.
    pub last_frame_ns: Option<i64>,
    /// Stamp of the first frame with a usable (metric, or in mono consistently scaled) pose, ns.
    pub initialized_at_ns: Option<i64>,
    /// Times tracking was lost after having been initialised (a run of lost frames counts once).
    pub lost_count: u64,
    /// Frames reported lost (including consecutive ones).
    pub lost_frames: u64,
    /// Wall time of the whole run, s.
    pub wall_s: f64,
    /// Resident memory when 10 % of the frames were done, MiB (`None` off Linux).
    pub rss_at_10pct_mib: Option<f64>,
    /// The estimator's last answer (final biases, state).
    pub last_output: Option<RelativeOutput>,
}

/// Feeds `stream` to `pipeline`; `on_frame` sees every frame's answer
/// (progress bars, the second stage's poses). A dataset error (a corrupt
/// image) stops the run with that error; the estimator's own troubles are
/// in its outputs.
pub fn run_stream(
    stream: &mut SensorStream<'_>,
    pipeline: &mut SlamPipeline,
    options: RunOptions,
    mut on_frame: impl FnMut(&PipelineFrame),
) -> Result<RunOutcome, DatasetError> {
    let second_stage = match (pipeline.absolute(), pipeline.localiser()) {
        (Some(_), _) => Some("absolute"),
        (None, Some(_)) => Some("localise"),
        (None, None) => None,
    };
    let mut out = RunOutcome::default();
    let listed = stream.frames_listed().max(1);
    let start = Instant::now();
    let mut imu_ms = 0.0;
    let mut poses = Vec::new();
    let mut was_tracking = false;
    for event in stream.by_ref() {
        match event? {
            SensorEvent::Imu(sample) => {
                pace(options, &out, start, sample.t_ns);
                let t = Instant::now();
                pipeline.push_imu(&sample);
                imu_ms += t.elapsed().as_secs_f64() * 1e3;
            }
            SensorEvent::Frame { t_ns, left, right } => {
                out.first_frame_ns.get_or_insert(t_ns);
                pace(options, &out, start, t_ns);
                let input = FrameInput {
                    t_ns,
                    left: &left.image,
                    right: right.as_ref().map(|r| &r.image),
                };
                let t = Instant::now();
                let frame = pipeline.push_frame(&input);
                let pose_ms = t.elapsed().as_secs_f64() * 1e3 + imu_ms;
                let t = Instant::now();
                let finished = pipeline.finish_frame();
                let after_ms = t.elapsed().as_secs_f64() * 1e3;
                out.pose_ms.push(pose_ms);
                out.frame_ms.push(pose_ms + after_ms);
                out.stage_ms.entry("imu_push").or_default().push(imu_ms);
                imu_ms = 0.0;
                for &(name, ms) in &pipeline.relative().last_timings().stages_ms {
                    out.stage_ms.entry(name).or_default().push(ms);
                }
                if let Some(name) = second_stage {
                    let after = finished.as_ref().map_or(0.0, |f| f.second_stage_ms);
                    out.stage_ms
                        .entry(name)
                        .or_default()
                        .push(frame.second_stage_ms + after);
                }
                let output = &frame.relative;
                out.last_frame_ns = Some(t_ns);
                match output.state {
                    TrackingState::Tracking => {
                        out.initialized_at_ns.get_or_insert(t_ns);
                        was_tracking = true;
                    }
                    TrackingState::Lost => {
                        out.lost_frames += 1;
                        if was_tracking {
                            out.lost_count += 1;
                        }
                        was_tracking = false;
                    }
                    TrackingState::Initializing => was_tracking = false,
                }
                if output.state == TrackingState::Tracking && is_finite(&output.T_world_body) {
                    // Stamped on the IMU clock, like the daemon's poses and
                    // the ground truth: a camera behind the IMU took the
                    // image at its stamp plus the time shift.
                    poses.push(StampedPose::new(
                        output.t_ns,
                        output.T_world_body.translation.vector,
                        output.T_world_body.rotation,
                    ));
                }
                if out.frame_ms.len() == listed.div_ceil(10) {
                    out.rss_at_10pct_mib = resident_memory_mib().0;
                }
                on_frame(&frame);
                out.last_output = Some(frame.relative);
            }
        }
    }
    out.wall_s = start.elapsed().as_secs_f64();
    out.trajectory = Trajectory::new(poses);
    Ok(out)
}

fn is_finite(t: &Isometry3<f64>) -> bool {
    t.translation.vector.iter().all(|v| v.is_finite())
        && t.rotation.coords.iter().all(|v| v.is_finite())
}

/// Sleeps until `t_ns` is due, counting from the first frame's stamp.
fn pace(options: RunOptions, out: &RunOutcome, start: Instant, t_ns: i64) {
    if !options.realtime {
        return;
    }
    let Some(first) = out.first_frame_ns else {
        return;
    };
    let due = Duration::from_nanos(t_ns.saturating_sub(first).max(0) as u64);
    if let Some(wait) = due.checked_sub(start.elapsed()) {
        std::thread::sleep(wait);
    }
}

impl RunOutcome {
    /// The report's timing and count fields (the caller adds dataset,
    /// mode, stream counts and accuracy).
    pub fn timing_report(&self) -> (Option<TimingStats>, BTreeMap<String, TimingStats>) {
        let stages = self
            .stage_ms
            .iter()
            .filter_map(|(name, v)| TimingStats::of(v).map(|s| (name.to_string(), s)))
            .collect();
        (TimingStats::of(&self.frame_ms), stages)
    }

    /// Sequence time from the first to the last frame, s (0 with fewer than two frames).
    pub fn sequence_s(&self) -> f64 {
        match (self.first_frame_ns, self.last_frame_ns) {
            (Some(a), Some(b)) => (b - a) as f64 * 1e-9,
            _ => 0.0,
        }
    }
}
