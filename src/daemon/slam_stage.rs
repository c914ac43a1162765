//! The SLAM stage's thread: takes frames and IMU samples off their queues,
//! hands them to the SLAM pipeline ([`crate::slam_pipeline`]: the relative
//! stage, then the absolute stage when `[slam.absolute] enabled`) in time
//! order, and publishes one pose per frame (`rigslam/pose`) and one per
//! IMU sample (`rigslam/pose_fast`).
//!
//! Order rule (what makes a replay give the same poses bit for bit): the
//! IMU samples received are held in `pending`; before a frame, the stage
//! pushes the pending samples up to the frame's instant on the IMU clock
//! (its stamp plus the camera's time shift when the camera runs behind)
//! and the first one after it, never more, however far ahead the IMU
//! queue is: what `rigslam run`'s reader delivers. In the inertial modes
//! it waits (bounded) for that one sample past the frame, unless the IMU
//! has gone quiet.

use std::collections::VecDeque;
use std::sync::atomic::Ordering;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use nalgebra::{Isometry3, Matrix6};

use crate::publish::{tracking_state_code, PoseMessage};
use crate::relative::{
    EstimatorKind, FrameInput, RelativeOutput, RigModel, SensorMode, TrackingState,
};
use crate::sensors::yei::device::host_monotonic_ns;
use crate::sensors::{Frame, ImuSample};
use crate::slam_config::SlamSettings;
use crate::slam_pipeline::{PipelineError, PipelineFrame, SecondStage, SlamPipeline};

use super::fast_pose::FastPropagator;
use super::health::{Health, SkipLog, MAP_LOCALISING};
use super::map_keeper::MapKeeper;
use super::queue::BoundedQueue;

/// One exposure on its way to the SLAM stage.
#[derive(Debug, Clone)]
pub struct FrameItem {
    /// Exposure stamp, ns: host `CLOCK_MONOTONIC` for live drivers, the recording's time on replay.
    pub t_ns: i64,
    /// The left (cam0) image, or the only one in mono.
    pub left: Frame,
    /// The right (cam1) image of a stereo pair.
    pub right: Option<Frame>,
    /// Host `CLOCK_MONOTONIC` when the source handed it over, ns.
    pub arrival_ns: i64,
}

/// Where the stage's poses go: the iceoryx2 publishers in the daemon, a
/// list in tests. Returns false when the pose could not be sent.
pub trait PoseSink: Send {
    /// Sends a frame's pose; `output` is the estimator's full answer for that frame. Returns false
    /// when it could not be sent.
    fn pose(&mut self, message: &PoseMessage, output: &RelativeOutput) -> bool;
    /// Sends an IMU-rate pose from the fast propagator. Returns false when it could not be sent.
    fn pose_fast(&mut self, message: &PoseMessage) -> bool;
}

/// Forward stamp steps larger than this count as a jump, ns.
const JUMP_FORWARD_NS: i64 = 1_000_000_000;

/// The stage's fixed settings.
#[derive(Debug, Clone)]
pub struct StageSettings {
    /// Sensor mode the estimator runs in.
    pub mode: SensorMode,
    /// Which relative estimator runs (window or EKF).
    pub estimator: EstimatorKind,
    /// Settings of both stages.
    pub slam: SlamSettings,
    /// The map on disk (`[map]`): with a path, the absolute stage runs and
    /// its map outlives the process.
    pub map: super::config::MapConfig,
    /// How long to wait for the IMU sample past a frame, at most.
    pub imu_wait: Duration,
    /// With no IMU sample for this long the stage stops waiting for one, ns.
    pub imu_stall_ns: i64,
    /// Most IMU samples held for frames that have not come (camera
    /// stalled); beyond it the oldest go to the estimator unpaired.
    pub max_pending_imu: usize,
    /// Frames come in real time (a camera, or a replay at its recorded
    /// pace): a frame never waits for the map solve
    /// ([`crate::absolute::AbsoluteStage::never_wait_for_solves`]).
    /// False for a replay as fast as possible, which stays repeatable.
    pub live: bool,
}

/// Inputs of the stage, shared with the sources and the supervisor.
pub struct StageInputs {
    /// Frames from the camera source.
    pub frames: Arc<BoundedQueue<FrameItem>>,
    /// IMU samples from the IMU source.
    pub imu: Arc<BoundedQueue<ImuSample>>,
    /// Rung by the sources when they push, so the stage sleeps on one condition variable.
    pub doorbell: Arc<super::Doorbell>,
    /// Counters and heartbeat the health monitor reads.
    pub health: Arc<Health>,
    /// A new rig to rebuild the estimator with (SIGHUP).
    pub reload: Arc<Mutex<Option<RigModel>>>,
}

/// Runs the stage until both queues are closed and drained.
pub fn run_stage(
    settings: StageSettings,
    rig: RigModel,
    inputs: StageInputs,
    mut sink: Box<dyn PoseSink>,
) -> Result<(), PipelineError> {
    let mut stage = Stage::new(settings, &rig, inputs)?;
    stage.run(sink.as_mut())
}

/// What the stage applies to raw input from the rig's calibration.
struct RigClocks {
    /// Corrects raw IMU samples (`imu_intrinsics.yaml`).
    intrinsics: crate::imu::ImuIntrinsics,
    /// Camera 0's `timeshift_cam_imu`, ns: a frame stamped `t` on the
    /// camera clock was taken at `t + shift` on the IMU clock.
    frame_shift_ns: i64,
}

impl RigClocks {
    fn of(rig: &RigModel) -> Self {
        Self {
            intrinsics: rig
                .imu
                .as_ref()
                .map_or_else(Default::default, |i| i.intrinsics),
            frame_shift_ns: rig.frame_shift_ns(),
        }
    }
}

struct Stage {
    settings: StageSettings,
    pipeline: SlamPipeline,
    /// The map file, with `[map] path`.
    map: Option<MapKeeper>,
    clocks: RigClocks,
    inputs: StageInputs,
    pending: VecDeque<ImuSample>,
    fast: FastPropagator,
    last_imu_t_ns: Option<i64>,
    last_frame_t_ns: Option<i64>,
    refused_imu: SkipLog,
    refused_frames: SkipLog,
    /// A sample / frame whose stamp jumped more than [`JUMP_FORWARD_NS`]
    /// ahead, held until the next one tells a clock that moved (the
    /// stream carries on from it) from a damaged stamp (it does not).
    held_imu: Option<ImuSample>,
    held_frame: Option<FrameItem>,
}

impl Stage {
    fn new(
        settings: StageSettings,
        rig: &RigModel,
        inputs: StageInputs,
    ) -> Result<Self, PipelineError> {
        let (map, second) = match MapKeeper::open(&settings.map, Arc::clone(&inputs.health)) {
            Some((keeper, second)) => (Some(keeper), second),
            None => (None, SecondStage::from_settings(&settings.slam)),
        };
        let pipeline = build_pipeline(&settings, rig, second)?;
        let fast = FastPropagator::new(settings.slam.relative.imu_only_max_s);
        Ok(Self {
            settings,
            pipeline,
            map,
            clocks: RigClocks::of(rig),
            inputs,
            pending: VecDeque::new(),
            fast,
            last_imu_t_ns: None,
            last_frame_t_ns: None,
            refused_imu: SkipLog::new("IMU sample"),
            refused_frames: SkipLog::new("frame"),
            held_imu: None,
            held_frame: None,
        })
    }

    fn heartbeat(&self) {
        self.inputs
            .health
            .stage_heartbeat_ns
            .store(host_monotonic_ns(), Ordering::Relaxed);
    }

    fn run(&mut self, sink: &mut dyn PoseSink) -> Result<(), PipelineError> {
        loop {
            self.heartbeat();
            self.apply_reload()?;
            let seen = self.inputs.doorbell.rung();
            let took_imu = self.drain_imu(sink);
            if let Some(frame) = self.inputs.frames.try_pop() {
                self.wait_for_imu_past(frame.t_ns.saturating_add(self.clocks.frame_shift_ns), sink);
                self.process_frame(frame, sink);
                continue;
            }
            if took_imu {
                continue;
            }
            if self.inputs.frames.is_closed() && self.inputs.imu.is_closed() {
                // Closed and drained (a frame or sample pushed before the
                // close was taken above).
                if self.inputs.frames.is_empty() && self.inputs.imu.is_empty() {
                    self.refuse_held_frame("the stream ended before another frame followed it");
                    // Stopping (SIGTERM, or the replay ended): the map
                    // being built is saved in full.
                    if let Some(keeper) = self.map.as_mut() {
                        keeper.save_now(&mut self.pipeline);
                    }
                    return Ok(());
                }
                continue;
            }
            self.inputs.doorbell.wait(seen, Duration::from_millis(50));
        }
    }

    fn apply_reload(&mut self) -> Result<(), PipelineError> {
        let rig = self
            .inputs
            .reload
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .take();
        if let Some(rig) = rig {
            // The relative stage starts again in a new world frame, so the
            // absolute stage's map (in the old one) starts again too: with
            // a map file it is saved first and localised in afterwards.
            let second = match self.map.as_mut() {
                Some(keeper) => {
                    keeper.save_now(&mut self.pipeline);
                    keeper.restart()
                }
                None => SecondStage::from_settings(&self.settings.slam),
            };
            match build_pipeline(&self.settings, &rig, second) {
                Ok(pipeline) => {
                    self.pipeline = pipeline;
                    self.clocks = RigClocks::of(&rig);
                    tracing::info!("calibration reloaded; the SLAM pipeline starts again");
                }
                Err(e) => tracing::error!("reloaded calibration refused, keeping the old one: {e}"),
            }
        }
        Ok(())
    }

    /// Moves every queued IMU sample into `pending`, publishing its
    /// `pose_fast`; true when there was one.
    fn drain_imu(&mut self, sink: &mut dyn PoseSink) -> bool {
        let mut any = false;
        while let Some(sample) = self.inputs.imu.try_pop() {
            any = true;
            self.accept_imu(sample, sink);
        }
        any
    }

    fn accept_imu(&mut self, sample: ImuSample, sink: &mut dyn PoseSink) {
        let health = Arc::clone(&self.inputs.health);
        if !sample.is_plausible() {
            let total = health.imu_rejected.fetch_add(1, Ordering::Relaxed) + 1;
            self.refused_imu.skipped(
                || {
                    format!(
                        "the sample at {} ns has NaN, infinite or impossible values \
                         (|gyro| > {} rad/s or |accel| > {} m/s^2): gyro {:?}, accel {:?}",
                        sample.t_ns,
                        ImuSample::MAX_GYRO_RAD_S,
                        ImuSample::MAX_ACCEL_M_S2,
                        sample.gyro_rad_s,
                        sample.accel_m_s2
                    )
                },
                total,
            );
            return;
        }
        if let Some(held) = self.held_imu.take() {
            if sample.t_ns > held.t_ns {
                health.timestamp_jumps.fetch_add(1, Ordering::Relaxed);
                tracing::warn!(
                    "IMU stamps jumped forward {} ms",
                    (held.t_ns - self.last_imu_t_ns.unwrap_or(held.t_ns)) / 1_000_000
                );
                self.take_imu(held, sink);
            } else {
                let total = health.imu_rejected.fetch_add(1, Ordering::Relaxed) + 1;
                let last = self.last_imu_t_ns.unwrap_or(held.t_ns);
                self.refused_imu.skipped(
                    || {
                        format!(
                            "the sample at {} ns jumped {} ms ahead and the stream did not follow it (a damaged stamp)",
                            held.t_ns,
                            (held.t_ns - last) / 1_000_000
                        )
                    },
                    total,
                );
            }
        }
        if let Some(last) = self.last_imu_t_ns {
            if sample.t_ns <= last {
                let total = health.imu_rejected.fetch_add(1, Ordering::Relaxed) + 1;
                health.timestamp_jumps.fetch_add(1, Ordering::Relaxed);
                self.refused_imu.skipped(
                    || {
                        format!(
                            "the sample at {} ns does not come after {last} ns",
                            sample.t_ns
                        )
                    },
                    total,
                );
                return;
            }
            if sample.t_ns - last > JUMP_FORWARD_NS {
                self.held_imu = Some(sample);
                return;
            }
        }
        self.take_imu(sample, sink);
    }

    /// An accepted sample: published as `pose_fast` and queued for the
    /// estimator.
    fn take_imu(&mut self, sample: ImuSample, sink: &mut dyn PoseSink) {
        let health = &self.inputs.health;
        self.last_imu_t_ns = Some(sample.t_ns);
        if self.settings.mode.uses_imu() {
            // The estimator corrects the raw sample itself; the fast pose
            // integrates the same corrected values.
            let message = self.fast.on_imu(&self.clocks.intrinsics.correct(&sample));
            if sink.pose_fast(&message) {
                health.pose_fast_out.fetch_add(1, Ordering::Relaxed);
            }
            self.pending.push_back(sample);
            while self.pending.len() > self.settings.max_pending_imu {
                if let Some(old) = self.pending.pop_front() {
                    self.pipeline.push_imu(&old);
                }
            }
        }
    }

    /// Waits until a sample past `t_ns` is pending, the IMU is quiet, or
    /// the wait bound passes.
    fn wait_for_imu_past(&mut self, t_ns: i64, sink: &mut dyn PoseSink) {
        if !self.settings.mode.uses_imu() {
            return;
        }
        let deadline = std::time::Instant::now() + self.settings.imu_wait;
        loop {
            self.drain_imu(sink);
            if self.pending.back().is_some_and(|s| s.t_ns > t_ns) {
                return;
            }
            let last_imu = self.inputs.health.last_imu_ns.load(Ordering::Relaxed);
            let quiet = host_monotonic_ns() - last_imu > self.settings.imu_stall_ns;
            if quiet || self.inputs.imu.is_closed() || std::time::Instant::now() >= deadline {
                return;
            }
            let seen = self.inputs.doorbell.rung();
            if self.inputs.imu.is_empty() {
                self.inputs.doorbell.wait(seen, Duration::from_millis(2));
            }
        }
    }

    fn process_frame(&mut self, frame: FrameItem, sink: &mut dyn PoseSink) {
        let health = Arc::clone(&self.inputs.health);
        if let Some(held) = self.held_frame.take() {
            if frame.t_ns > held.t_ns {
                health.timestamp_jumps.fetch_add(1, Ordering::Relaxed);
                tracing::warn!(
                    "frame stamps jumped forward {} ms",
                    (held.t_ns - self.last_frame_t_ns.unwrap_or(held.t_ns)) / 1_000_000
                );
                self.track_frame(held, sink);
            } else {
                self.held_frame = Some(held);
                self.refuse_held_frame("the next frame did not follow it (a damaged stamp)");
            }
        }
        if let Some(last) = self.last_frame_t_ns {
            if frame.t_ns <= last {
                let total = health.frames_rejected.fetch_add(1, Ordering::Relaxed) + 1;
                health.timestamp_jumps.fetch_add(1, Ordering::Relaxed);
                self.refused_frames.skipped(
                    || {
                        format!(
                            "the frame at {} ns does not come after {last} ns",
                            frame.t_ns
                        )
                    },
                    total,
                );
                return;
            }
            if frame.t_ns - last > JUMP_FORWARD_NS {
                self.held_frame = Some(frame);
                return;
            }
        }
        self.track_frame(frame, sink);
    }

    /// Drops the frame held for its jump forward, counted, saying `why`.
    fn refuse_held_frame(&mut self, why: &str) {
        let Some(held) = self.held_frame.take() else {
            return;
        };
        let health = &self.inputs.health;
        let total = health.frames_rejected.fetch_add(1, Ordering::Relaxed) + 1;
        let last = self.last_frame_t_ns.unwrap_or(held.t_ns);
        self.refused_frames.skipped(
            || {
                format!(
                    "the frame at {} ns jumped {} ms ahead and {why}",
                    held.t_ns,
                    (held.t_ns - last) / 1_000_000
                )
            },
            total,
        );
    }

    /// An accepted frame through the estimator; its pose published.
    fn track_frame(&mut self, frame: FrameItem, sink: &mut dyn PoseSink) {
        let health = Arc::clone(&self.inputs.health);
        self.last_frame_t_ns = Some(frame.t_ns);
        // The samples up to the frame's instant on the IMU clock and the
        // first one past it.
        let instant_ns = frame.t_ns.saturating_add(self.clocks.frame_shift_ns.max(0));
        while let Some(s) = self.pending.front() {
            let past = s.t_ns > instant_ns;
            let s = *s;
            self.pending.pop_front();
            self.pipeline.push_imu(&s);
            if past {
                break;
            }
        }
        let input = FrameInput {
            t_ns: frame.t_ns,
            left: &frame.left.image,
            right: frame.right.as_ref().map(|r| &r.image),
        };
        let frame_out = self.pipeline.push_frame(&input);
        let relative = self.pipeline.relative();
        health.record_noise_scale(relative.imu_noise_scale(), relative.noise_at_bound());
        health.record_camera_imu(relative.camera_imu());
        if let Some(absolute) = self.pipeline.absolute() {
            let stats = absolute.stats();
            health.record_orientation_offset_deg(stats.orientation_offset_deg);
            health
                .map_unknowns
                .store(stats.last_unknowns as u64, Ordering::Relaxed);
        }
        if health.map_mode.load(Ordering::Relaxed) == MAP_LOCALISING {
            health.record_map_placement(
                frame_out.localised.is_some(),
                frame_out.localised.as_ref().is_some_and(|l| l.carried),
            );
        }
        health
            .second_stage_waiting
            .store(self.pipeline.second_stage_waiting(), Ordering::Relaxed);
        let output = &frame_out.relative;
        self.fast.on_frame_in_map(output, map_pose(&frame_out));
        health
            .tracking_state
            .store(tracking_state_code(output.state), Ordering::Relaxed);
        let message = frame_message(&frame_out);
        if sink.pose(&message, output) {
            let now_ns = host_monotonic_ns();
            health.pose_published(now_ns);
            let latency_us = (now_ns - frame.arrival_ns) as f64 * 1e-3;
            health.record_latency_us(latency_us);
        } else {
            health.pose_drops.fetch_add(1, Ordering::Relaxed);
        }
        // The pose is out: now the work it did not wait for (a keyframe's
        // window optimisation, the second stage on the optimised frame),
        // then the map's periodic save.
        self.pipeline.finish_frame();
        if let Some(keeper) = self.map.as_mut() {
            keeper.after_frame(frame.t_ns, &self.pipeline);
        }
    }
}

/// The pipeline the settings ask for on `rig`, with `second` after the
/// relative stage.
fn build_pipeline(
    settings: &StageSettings,
    rig: &RigModel,
    second: SecondStage,
) -> Result<SlamPipeline, PipelineError> {
    let mut pipeline = SlamPipeline::new(
        settings.estimator,
        settings.mode,
        rig,
        &settings.slam,
        second,
    )?;
    if settings.live {
        if let Some(stage) = pipeline.absolute_mut() {
            stage.never_wait_for_solves();
        }
    }
    Ok(pipeline)
}

/// The absolute stage's pose of a tracked frame and `T_world_odom`, the
/// transform from the relative stage's (odometry) frame to its map frame.
#[allow(non_snake_case)]
fn map_pose(frame: &PipelineFrame) -> Option<(Isometry3<f64>, Isometry3<f64>)> {
    if frame.relative.state != TrackingState::Tracking {
        return None;
    }
    let T_world_body = match (&frame.corrected, &frame.localised) {
        (Some(corrected), _) => corrected.T_world_body,
        (None, Some(localised)) => localised.T_map_body,
        (None, None) => return None,
    };
    let T_world_odom = T_world_body * frame.relative.T_world_body.inverse();
    Some((T_world_body, T_world_odom))
}

/// The `rigslam/pose` message of one frame. With the absolute stage, the
/// position is the position filter's and its covariance block the
/// filter's; the orientation, velocity and rotation block are the
/// relative stage's, and the position-rotation cross terms are zero (the
/// filter does not carry them); the odometry fields carry the relative
/// stage's pose as it is and `T_world_odom`. Without it, the relative
/// stage's pose and covariance.
#[allow(non_snake_case)]
fn frame_message(frame: &PipelineFrame) -> PoseMessage {
    let output = &frame.relative;
    if output.state != TrackingState::Tracking {
        // No usable pose yet: say so, with the estimator's numbers as
        // they are (flags tell the reader not to use them).
        let mut m = PoseMessage::from_relative(output, None);
        m.flags = 0;
        return m;
    }
    let relative_covariance = output.pose_covariance.as_ref().map(|c| c.matrix);
    let Some((T_world_body, world_odom)) = map_pose(frame) else {
        return PoseMessage::from_relative(output, relative_covariance.as_ref());
    };
    let position_covariance = frame.map_position_covariance_m2();
    let covariance = match (relative_covariance, position_covariance) {
        (Some(relative), Some(position)) => {
            let mut c = Matrix6::zeros();
            c.fixed_view_mut::<3, 3>(0, 0).copy_from(&position);
            c.fixed_view_mut::<3, 3>(3, 3)
                .copy_from(&relative.fixed_view::<3, 3>(3, 3));
            Some(c)
        }
        // Before the filter starts the position is the relative stage's.
        (relative, None) => relative,
        (None, Some(_)) => None,
    };
    let message = PoseMessage::new(output.t_ns, output.state, &T_world_body)
        .with_velocity(&(world_odom.rotation * output.velocity_world_m_s))
        .with_odometry(&output.T_world_body, &world_odom);
    match covariance {
        Some(c) => message.with_covariance(&c),
        None => message,
    }
}

#[cfg(test)]
mod tests {
    use nalgebra::{Isometry3, Matrix3, Translation3, UnitQuaternion, Vector3};

    use super::*;
    use crate::absolute::CorrectedPose;
    use crate::relative::types::PoseCovariance;

    fn frame(corrected: Option<CorrectedPose>) -> PipelineFrame {
        let mut relative = RelativeOutput::tracking_at_origin(7, Vec::new());
        relative.T_world_body = Isometry3::from_parts(
            Translation3::new(1.0, 2.0, 3.0),
            UnitQuaternion::from_euler_angles(0.1, 0.2, 0.3),
        );
        relative.velocity_world_m_s = Vector3::new(0.5, 0.0, -0.5);
        relative.pose_covariance = Some(PoseCovariance {
            matrix: Matrix6::from_fn(|r, c| {
                1.0 + (r * 6 + c) as f64 + (r == c) as u8 as f64 * 100.0
            }),
            origin_t_ns: 0,
            T_world_origin: Isometry3::identity(),
        });
        PipelineFrame {
            relative,
            corrected,
            localised: None,
            second_stage_ms: 0.0,
        }
    }

    #[test]
    fn the_published_pose_takes_position_and_its_covariance_from_the_filter() {
        let relative_only = frame(None);
        let m = frame_message(&relative_only);
        assert_eq!(m.position_world_m, [1.0, 2.0, 3.0]);
        assert_eq!(
            m.covariance_matrix(),
            Some(
                relative_only
                    .relative
                    .pose_covariance
                    .as_ref()
                    .unwrap()
                    .matrix
            )
        );

        let filter_covariance = Matrix3::from_diagonal(&Vector3::new(0.01, 0.02, 0.03));
        let corrected = CorrectedPose {
            t_ns: 7,
            T_world_body: Isometry3::from_parts(
                Translation3::new(1.1, 1.9, 3.0),
                relative_only.relative.T_world_body.rotation,
            ),
            position_covariance_m2: Some(filter_covariance),
            landmarks_used: 5,
            map_version: 2,
            nis: 1.0,
        };
        let both = frame(Some(corrected));
        let m = frame_message(&both);
        assert_eq!(m.position_world_m, [1.1, 1.9, 3.0]);
        assert_eq!(
            m.orientation_world_body_xyzw,
            frame_message(&relative_only).orientation_world_body_xyzw
        );
        assert_eq!(m.velocity_world_m_s, [0.5, 0.0, -0.5]);
        let c = m.covariance_matrix().expect("a covariance");
        let relative = both.relative.pose_covariance.as_ref().unwrap().matrix;
        assert_eq!(c.fixed_view::<3, 3>(0, 0), filter_covariance);
        assert_eq!(
            c.fixed_view::<3, 3>(3, 3),
            relative.fixed_view::<3, 3>(3, 3)
        );
        assert_eq!(c.fixed_view::<3, 3>(0, 3), Matrix3::zeros());
        assert_eq!(c.fixed_view::<3, 3>(3, 0), Matrix3::zeros());
        // REP-105: the odometry pose is the relative stage's as it is, and
        // T_world_odom takes it to the world (map) pose.
        assert_ne!(m.flags & crate::publish::POSE_FLAG_MAP_CORRECTED, 0);
        assert_eq!(m.position_odom_m, [1.0, 2.0, 3.0]);
        let composed = m.T_world_odom() * m.T_odom_body();
        assert!((composed.translation.vector - Vector3::new(1.1, 1.9, 3.0)).norm() < 1e-12);
        assert!(composed.rotation.angle_to(&m.T_world_body().rotation) < 1e-12);
        assert_eq!(
            frame_message(&relative_only).flags & crate::publish::POSE_FLAG_MAP_CORRECTED,
            0
        );
        assert_eq!(
            frame_message(&relative_only).position_odom_m,
            frame_message(&relative_only).position_world_m
        );

        // The IMU-rate stream starts from the map-frame pose and carries
        // the same odometry transform.
        let mut fast = FastPropagator::new(1.0);
        fast.on_frame_in_map(&both.relative, map_pose(&both));
        let sample = ImuSample {
            t_ns: 8,
            gyro_rad_s: [0.0; 3],
            accel_m_s2: [0.0, 0.0, 9.81],
        };
        let f = fast.on_imu(&sample);
        assert!((f.T_world_body().translation.vector - Vector3::new(1.1, 1.9, 3.0)).norm() < 1e-6);
        assert!((f.T_odom_body().translation.vector - Vector3::new(1.0, 2.0, 3.0)).norm() < 1e-6);
        assert_ne!(f.flags & crate::publish::POSE_FLAG_MAP_CORRECTED, 0);

        // Before the filter starts: the relative stage's covariance.
        let mut early = frame(Some(CorrectedPose {
            position_covariance_m2: None,
            ..both.corrected.clone().unwrap()
        }));
        assert_eq!(frame_message(&early).covariance_matrix(), Some(relative));
        // Not tracking: nothing a reader may use.
        early.relative.state = TrackingState::Lost;
        assert_eq!(frame_message(&early).flags, 0);
    }
}
