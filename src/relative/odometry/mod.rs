//! The relative stage frame by frame (paper Figure 8): the tracker's
//! observations, the IMU between frames and the window's optimisation
//! joined into one [`RelativeEstimator`].
//!
//! Per frame: the gyroscope predicts the rotation since the last frame
//! (for the tracker); the tracker hands over RANSAC-checked observations;
//! the IMU interval from the newest keyframe predicts the state and the
//! window places the frame against its landmarks (the scale of the new
//! translation comes from the known points); a keyframe joins the window,
//! which runs Levenberg-Marquardt over the reprojection and inertial
//! errors.
//!
//! When vision fails (black, blank or frozen frames) the IMU carries the
//! state for at most `imu_only_max_s`; after that the frame is reported
//! lost and the stage re-initialises, from the IMU-carried state when it
//! is recent enough, so the pose does not jump. Leaving a rest, before the
//! images have placed a frame (a monocular window has no landmarks until
//! the motion gives parallax), the IMU carries the rest's state for up to
//! `imu_only_after_rest_max_s`.
//!
//! A keyframe's pose goes out as tracked, before the window's solve; a
//! solve that moves it reaches the published poses at a bounded speed
//! (`published_correction_m_s`, [`super::published_position`]), not as a
//! step on the next frame.
//!
//! How the stage starts (at rest, or moving with a visual-inertial
//! alignment) is in the `start` module.

use std::collections::HashMap;

use nalgebra::{Isometry3, Matrix6, Rotation3, Translation3, Vector2, Vector3};

use crate::imu::{ImuBiases, NavState, Preintegrated, GRAVITY_M_S2};
use crate::sensors::ImuSample;

use super::config::RelativeConfig;
use super::estimator::{FrameInput, FrameTimings, RelativeEstimator, RigModel, SensorMode};
use super::imu_buffer::ImuBuffer;
use super::initializer::StaticStartConfig;
use super::published_position::PublishedPosition;
use super::setup::{front_end, OdometryError};
use super::tracker::Tracker;
use super::types::{
    BodyLandmark, KeyframeState, LandmarkId, PoseCovariance, RelativeOutput, TrackedFrame,
    TrackingState,
};
use super::window::{pose_covariance, NoiseScale, Window, WindowConfig};

mod start;

/// Where the stage is.
#[derive(Debug, Clone, PartialEq)]
enum Phase {
    /// No pose yet. The mono modes keep their first keyframe here while
    /// they wait for parallax.
    Initializing { first: Option<TrackedFrame> },
    /// Inertial modes at rest: the pose is held; `frame` is the newest
    /// frame at rest, the window's first keyframe once the rig moves.
    Resting {
        state: KeyframeState,
        frame: TrackedFrame,
    },
    /// Inertial modes after a moving start: the window runs vision-only
    /// until the IMU is aligned with it.
    Aligning,
    /// The window runs; poses are metric and gravity-aligned (inertial
    /// modes, stereo) or consistently scaled (mono).
    Tracking,
}

/// Counters for the run report.
#[derive(Debug, Clone, Copy, Default)]
struct Counters {
    frames: u64,
    frames_out_of_order: u64,
    tracker_errors: u64,
    keyframes: u64,
    window_errors: u64,
    resets: u64,
    static_frames: u64,
    imu_only_frames: u64,
    alignments_tried: u64,
    /// Keyframes in the window at the last accepted alignment.
    alignment_keyframes: u64,
    /// Inertial links between them the alignment gave the window (one
    /// fewer than the keyframes when every interval was integrated).
    alignment_links: u64,
    bootstraps_tried: u64,
    frames_without_imu: u64,
    /// Vision restarts placed where the trajectory before the loss went.
    resumed: u64,
    /// Left images identical to the previous one, bit for bit (a camera
    /// or driver handing the last buffer again), not used to place the
    /// frame.
    frames_repeated: u64,
    /// Landmarks the window took out with their tracks: their
    /// observations together were inconsistent with one point.
    inconsistent_landmarks: u64,
}

impl Counters {
    fn note_solve(&mut self, report: &super::window::WindowReport) {
        self.inconsistent_landmarks += report.inconsistent_landmarks as u64;
    }
}

/// A keyframe at least this often, ns (0.5 s; the tracker may ask
/// sooner).
const MAX_KEYFRAME_GAP_NS: i64 = 500_000_000;
/// After a loss, the IMU carries the last trusted state to where vision
/// starts again for at most this long; beyond, the trajectory goes on from
/// the last trusted pose itself.
const RESUME_PROPAGATE_MAX_S: f64 = 5.0;

/// The paper's relative stage with the windowed estimator.
pub struct WindowOdometry {
    mode: SensorMode,
    rig: RigModel,
    config: RelativeConfig,
    tracker: Tracker,
    window: Window,
    window_config: WindowConfig,
    imu: Option<ImuBuffer>,
    static_config: StaticStartConfig,
    phase: Phase,
    /// The newest frame's estimate.
    last: Option<KeyframeState>,
    last_output: Option<RelativeOutput>,
    /// Best gyro bias so far (for the tracker's rotation prediction).
    gyro_bias_rad_s: Vector3<f64>,
    /// Left-image positions of the previous frame, for the image motion.
    previous_pixels: HashMap<LandmarkId, Vector2<f64>>,
    /// Left-image positions when the current rest began.
    rest_anchor: HashMap<LandmarkId, Vector2<f64>>,
    /// Median image motion of the newest frame, px.
    last_flow_px: Option<f64>,
    /// Stamp of the last frame the images placed.
    last_vision_ns: Option<i64>,
    /// The window started from a rest and the images have placed no frame
    /// since: a monocular window has no landmarks until the motion gives
    /// parallax, and the IMU carries the rest's well-known state until then
    /// (for at most `imu_only_after_rest_max_s`).
    leaving_rest: bool,
    /// Consecutive frames without a usable pose.
    bad_frames: usize,
    /// The last trusted metric state, carried through a loss by the IMU.
    last_good: Option<KeyframeState>,
    /// The newest frame's pose covariance given the newest keyframe
    /// (window convention), for [`Self::output`].
    frame_marginal: Option<Matrix6<f64>>,
    /// The last tracked pose that had a covariance, with it: where a new
    /// window that continues the trajectory takes its uncertainty from.
    last_covariance: Option<(Isometry3<f64>, PoseCovariance)>,
    /// The last trusted state, kept through a reset (`last_good` is
    /// dropped once too old for the IMU to carry): where a vision
    /// restart continues the trajectory from.
    resume_from: Option<KeyframeState>,
    /// Where the first keyframe of a vision restart is taken to be, with
    /// the covariance the way there adds: stamp, pose, covariance.
    resume: Option<(i64, Isometry3<f64>, Matrix6<f64>)>,
    /// Stamp of the newest keyframe the alignment of a moving start
    /// placed: the estimate settles once the window's oldest keyframe is
    /// newer ([`RelativeEstimator::settling`]).
    aligned_until_ns: Option<i64>,
    /// A digest of the previous left image, and whether the newest frame's
    /// is the same (see [`image_digest`]).
    previous_left_digest: Option<u64>,
    repeated_frame: bool,
    /// A keyframe whose pose went out before the window optimised it:
    /// the optimisation waits for [`RelativeEstimator::finish_frame`].
    deferred: Option<DeferredKeyframe>,
    /// The published position: the estimate, with a solve's correction
    /// of a pose already out spread over the following frames.
    published: PublishedPosition,
    timings: FrameTimings,
    counters: Counters,
}

/// What a keyframe's window optimisation needs once its pose is out.
struct DeferredKeyframe {
    state: KeyframeState,
    frame: TrackedFrame,
    pre: Option<Preintegrated>,
    tracking: TrackingState,
    /// The frame's own marginal, for its answer if the window refuses it.
    frame_marginal: Option<Matrix6<f64>>,
    /// The position its pose went out with.
    published_m: Vector3<f64>,
}

/// A 64-bit digest of an image's bytes, to notice a frame handed over
/// again: a real sensor's noise makes two exposures differ somewhere, so
/// equal digests mean the same buffer (a collision is a 2^-64 chance).
fn image_digest(image: &crate::sensors::Image) -> u64 {
    let data = image.data();
    let mut h: u64 = 0x9e37_79b9_7f4a_7c15 ^ data.len() as u64;
    let mut chunks = data.chunks_exact(8);
    for c in &mut chunks {
        let x = u64::from_le_bytes(c.try_into().expect("8 bytes"));
        h = (h.rotate_left(23) ^ x).wrapping_mul(0x2127_599b_f432_5c37);
    }
    for &b in chunks.remainder() {
        h = (h.rotate_left(23) ^ u64::from(b)).wrapping_mul(0x2127_599b_f432_5c37);
    }
    h ^ (h >> 29)
}

impl WindowOdometry {
    /// The windowed estimator for `mode`, on the cameras (and IMU) of `rig`
    /// the mode uses; it starts initialising. Fails with
    /// [`OdometryError::Rig`] when the rig lacks a camera or the IMU the
    /// mode needs, [`OdometryError::Config`] when a setting is out of
    /// range, and [`OdometryError::Setup`] when the tracker or the window
    /// refuses the rig or the settings.
    pub fn new(
        mode: SensorMode,
        rig: &RigModel,
        config: &RelativeConfig,
    ) -> Result<Self, OdometryError> {
        let (used, tracker) = front_end(mode, rig, config)?;
        let window_config = WindowConfig {
            keyframes_kept: config.window_keyframes,
            keyframes_free: config.window_free,
            pixel_sigma: config.pixel_sigma_px,
            use_imu: false,
            noise_adaptation: config.noise_adaptation(),
            camera_imu: config.camera_imu_refinement(mode),
            covariance_shared_measurements: config.covariance_shared_measurements,
            covariance_pixel_gain: config.covariance_pixel_gain,
            covariance_pixel_floor: config.covariance_pixel_floor,
            ..WindowConfig::default()
        };
        let window = Window::new(window_config.clone(), &used)
            .map_err(|e| OdometryError::Setup(e.to_string()))?;
        let imu = used
            .imu
            .as_ref()
            .map(|imu| ImuBuffer::new(imu.noise, imu.intrinsics));
        Ok(Self {
            mode,
            rig: used,
            config: config.clone(),
            tracker,
            window,
            window_config,
            imu,
            static_config: StaticStartConfig::default(),
            phase: Phase::Initializing { first: None },
            aligned_until_ns: None,
            last: None,
            last_output: None,
            gyro_bias_rad_s: Vector3::zeros(),
            previous_pixels: HashMap::new(),
            rest_anchor: HashMap::new(),
            last_flow_px: None,
            last_vision_ns: None,
            leaving_rest: false,
            bad_frames: 0,
            last_good: None,
            frame_marginal: None,
            last_covariance: None,
            resume_from: None,
            resume: None,
            previous_left_digest: None,
            repeated_frame: false,
            deferred: None,
            published: PublishedPosition::new(config.published_correction_m_s),
            timings: FrameTimings::default(),
            counters: Counters::default(),
        })
    }

    #[allow(non_snake_case)]
    fn T_body_cam0(&self) -> Isometry3<f64> {
        self.rig.cameras[0].T_body_cam
    }

    /// An empty window that keeps what the IMU's noise was found to be.
    fn new_window(&mut self) {
        let noise = self.window.noise_adaptation().clone();
        let previous = std::mem::replace(
            &mut self.window,
            Window::new(self.window_config.clone(), &self.rig)
                .expect("the same config and rig were accepted at start"),
        );
        self.window.keep_noise_adaptation(noise);
        self.window.keep_camera_imu_from(&previous);
        self.window.continue_numbering_from(&previous);
    }

    /// Gyro-predicted rotation of the current left camera in the previous
    /// one, for the tracker.
    #[allow(non_snake_case)]
    fn predicted_camera_rotation(&mut self, t_ns: i64) -> Option<Rotation3<f64>> {
        let last_ns = self.last_output.as_ref()?.t_ns;
        let bias = self.gyro_bias_rad_s;
        let T_bc = self.T_body_cam0();
        self.imu
            .as_mut()?
            .camera_rotation(last_ns, t_ns, &bias, &T_bc)
    }

    /// Median motion of the left features since the previous frame, px.
    fn median_flow_px(&mut self, frame: &TrackedFrame) -> Option<f64> {
        let mut flows: Vec<f64> = frame
            .in_camera(0)
            .filter_map(|o| {
                self.previous_pixels
                    .get(&o.landmark)
                    .map(|p| (o.pixel - p).norm())
            })
            .collect();
        self.previous_pixels.clear();
        self.previous_pixels
            .extend(frame.in_camera(0).map(|o| (o.landmark, o.pixel)));
        if flows.len() < 10 {
            return None;
        }
        let mid = flows.len() / 2;
        flows.select_nth_unstable_by(mid, f64::total_cmp);
        Some(flows[mid])
    }

    fn output(
        &mut self,
        state: &KeyframeState,
        tracking: TrackingState,
        frame: Option<&TrackedFrame>,
    ) -> RelativeOutput {
        let given = self.frame_marginal.take();
        let position_m = self
            .published
            .at(state.t_ns, &state.T_world_body.translation.vector);
        let out = self.answer(state, tracking, frame, given, position_m);
        if let Some(c) = out.pose_covariance {
            self.last_covariance = Some((state.T_world_body, c));
        }
        self.last_output = Some(out.clone());
        out
    }

    /// The answer for `state` (the frame's own marginal `given`), published
    /// at `position_m` ([`PublishedPosition`]), without recording it as the
    /// last one.
    fn answer(
        &self,
        state: &KeyframeState,
        tracking: TrackingState,
        frame: Option<&TrackedFrame>,
        given: Option<Matrix6<f64>>,
        position_m: Vector3<f64>,
    ) -> RelativeOutput {
        let previous = self
            .last_output
            .as_ref()
            .filter(|o| o.state == TrackingState::Tracking)
            .map(|o| o.T_world_body.translation.vector);
        let landmarks = match frame {
            Some(f) if tracking == TrackingState::Tracking => self.body_landmarks(state, f),
            _ => Vec::new(),
        };
        let pose_covariance = match tracking {
            TrackingState::Tracking => self.pose_covariance(state, given),
            _ => None,
        };
        let mut published = *state;
        published.T_world_body.translation.vector = position_m;
        RelativeOutput::from_state(&published, tracking, previous, landmarks, pose_covariance)
    }

    /// The covariance of `state`'s pose: the newest keyframe's, carried
    /// to the frame with the frame's own covariance given the keyframe
    /// (`given`; none at rest, where the pose is held).
    #[allow(non_snake_case)]
    fn pose_covariance(
        &self,
        state: &KeyframeState,
        given: Option<Matrix6<f64>>,
    ) -> Option<PoseCovariance> {
        let (origin_t_ns, T_world_origin) = self.window.covariance_origin()?;
        let (kf, kf_covariance) = self.window.newest_pose_covariance()?;
        let covariance = if kf.t_ns == state.t_ns {
            kf_covariance
        } else {
            pose_covariance::compose(
                &kf.T_world_body,
                &kf_covariance,
                &state.T_world_body,
                &given.unwrap_or_else(Matrix6::zeros),
            )
        };
        Some(PoseCovariance {
            matrix: pose_covariance::to_published(&state.T_world_body, &covariance),
            origin_t_ns,
            T_world_origin,
        })
    }

    /// The covariance of a pose the IMU predicted over `pre` from the
    /// newest keyframe, given that keyframe.
    fn imu_prediction_marginal(&self, pre: &Preintegrated) -> Option<Matrix6<f64>> {
        let kf = self.window.latest()?;
        let scale = self.window.noise_adaptation().scale();
        Some(pose_covariance::imu_prediction(
            pre,
            &kf.T_world_body,
            scale.gyro,
            scale.accel,
        ))
    }

    /// The window's landmarks seen in `frame`, in the frame's body, with
    /// covariances: the newest keyframe's body-frame marginals moved
    /// into this body (the relative pose taken as exact).
    #[allow(non_snake_case)]
    fn body_landmarks(&self, state: &KeyframeState, frame: &TrackedFrame) -> Vec<BodyLandmark> {
        let Some(kf) = self.window.latest() else {
            return Vec::new();
        };
        let seen: std::collections::HashSet<LandmarkId> =
            frame.in_camera(0).map(|o| o.landmark).collect();
        let T_cur_kf = state.T_world_body.inverse() * kf.T_world_body;
        let r = T_cur_kf.rotation.to_rotation_matrix().into_inner();
        self.window
            .landmarks_in_body()
            .iter()
            .filter(|l| seen.contains(&l.id))
            .map(|l| BodyLandmark {
                id: l.id,
                position_body_m: T_cur_kf.transform_point(&l.position_body_m.into()).coords,
                covariance_body_m2: r * l.covariance_body_m2 * r.transpose(),
                descriptor: self.tracker.descriptor(l.id),
                support: l.support,
            })
            .collect()
    }

    fn held_state(&self, t_ns: i64) -> KeyframeState {
        let mut state = self.last.unwrap_or(KeyframeState {
            t_ns,
            T_world_body: Isometry3::identity(),
            velocity_world_m_s: Vector3::zeros(),
            biases: ImuBiases::default(),
        });
        state.t_ns = t_ns;
        state
    }

    fn unplaced_output(&mut self, t_ns: i64, tracking: TrackingState) -> RelativeOutput {
        let state = self.held_state(t_ns);
        self.output(&state, tracking, None)
    }

    /// Starts over: new tracks, an empty window.
    fn reset(&mut self) {
        self.counters.resets += 1;
        self.tracker.reset();
        self.new_window();
        self.phase = Phase::Initializing { first: None };
        self.aligned_until_ns = None;
        self.leaving_rest = false;
        self.bad_frames = 0;
        self.previous_pixels.clear();
        self.published.clear();
    }

    fn trust(&mut self, state: KeyframeState) {
        self.last_good = Some(state);
        self.resume_from = Some(state);
    }

    /// Inertial modes restarting from vision after a loss: where the
    /// keyframe at `t_ns` is, from the last trusted state (carried by the
    /// IMU when it can), so that the alignment's frame is moved there
    /// instead of starting a new trajectory at the origin.
    fn plan_resume(&mut self, t_ns: i64) {
        self.resume = None;
        let Some(good) = self.resume_from.filter(|g| g.t_ns <= t_ns) else {
            return;
        };
        let gap_s = (t_ns - good.t_ns) as f64 * 1e-9;
        let carried = (gap_s <= RESUME_PROPAGATE_MAX_S)
            .then(|| self.propagate(&good, t_ns))
            .flatten();
        let scale = self.window.noise_adaptation().scale();
        self.resume = Some(match carried {
            Some((state, pre)) => (
                t_ns,
                state.T_world_body,
                pose_covariance::imu_prediction(&pre, &good.T_world_body, scale.gyro, scale.accel),
            ),
            None => {
                // Held: the pose is off by about the way travelled since.
                let sigma_m = good.velocity_world_m_s.norm() * gap_s;
                let mut added = Matrix6::zeros();
                for i in 3..6 {
                    added[(i, i)] = sigma_m * sigma_m;
                }
                (t_ns, good.T_world_body, added)
            }
        });
    }

    /// After the alignment: moves the window (yaw and translation, so
    /// that gravity stays) to put its first keyframe where the trajectory
    /// before the loss says it is, and continues its covariance.
    #[allow(non_snake_case)]
    fn apply_resume(&mut self) {
        let Some((t_ns, pose, added)) = self.resume.take() else {
            return;
        };
        let Some(first) = self.window.keyframes().next().copied() else {
            return;
        };
        if first.t_ns != t_ns {
            return;
        }
        let turn = heading_turn(&first.T_world_body.rotation, &pose.rotation);
        let shift = pose.translation.vector - turn * first.T_world_body.translation.vector;
        let T_new_old = Isometry3::from_parts(Translation3::from(shift), turn);
        if self.window.transform(1.0, T_new_old).is_err() {
            return;
        }
        self.counters.resumed += 1;
        if let Some((before_pose, c)) = self.last_covariance {
            let before = pose_covariance::from_published(&before_pose, &c.matrix);
            let moved = T_new_old * first.T_world_body;
            let covariance = pose_covariance::compose(&before_pose, &before, &moved, &added);
            self.window
                .continue_covariance_chain((c.origin_t_ns, c.T_world_origin), covariance);
        }
    }

    /// The state at `t_ns` from `anchor` by the IMU.
    fn propagate(
        &mut self,
        anchor: &KeyframeState,
        t_ns: i64,
    ) -> Option<(KeyframeState, Preintegrated)> {
        let gravity = if self.window.imu_enabled() {
            self.window.gravity_world_m_s2()
        } else {
            Vector3::new(0.0, 0.0, -GRAVITY_M_S2)
        };
        let pre = self
            .imu
            .as_mut()?
            .preintegrate(anchor.t_ns, t_ns, &anchor.biases)?;
        let nav = pre.predict(&nav_of(anchor), &anchor.biases, &gravity);
        let state = KeyframeState {
            t_ns,
            T_world_body: Isometry3::from_parts(
                Translation3::from(nav.position_world_m),
                nav.R_world_body,
            ),
            velocity_world_m_s: nav.velocity_world_m_s,
            biases: anchor.biases,
        };
        Some((state, pre))
    }

    /// The state at `t_ns` predicted from the newest keyframe by the IMU
    /// (inertial terms on) or by constant velocity.
    fn predict(&mut self, t_ns: i64) -> (KeyframeState, Option<Preintegrated>) {
        let anchor = *self
            .window
            .latest()
            .expect("the window has a keyframe when tracking");
        if self.window.imu_enabled() {
            if let Some((state, pre)) = self.propagate(&anchor, t_ns) {
                return (state, Some(pre));
            }
            self.counters.frames_without_imu += 1;
        }
        let last = self
            .last
            .filter(|l| l.t_ns >= anchor.t_ns)
            .unwrap_or(anchor);
        let dt_s = (t_ns - last.t_ns) as f64 * 1e-9;
        let mut state = last;
        state.t_ns = t_ns;
        state.T_world_body.translation.vector += last.velocity_world_m_s * dt_s;
        (state, None)
    }

    /// One frame with the window running.
    fn track(&mut self, frame: TrackedFrame, tracking: TrackingState) -> RelativeOutput {
        let t_ns = frame.t_ns;
        let (guess, pre) = self.predict(t_ns);
        // A repeated image says nothing of where the rig went: where the
        // IMU can carry the state, it does (images that stopped while the
        // rig moves would otherwise hold the pose, then jump).
        let carried_over_repeat = self.repeated_frame && pre.is_some();
        let omega = self
            .angular_rate_at(t_ns, &guess)
            .unwrap_or_else(Vector3::zeros);
        self.window.set_frame_angular_rate(omega);
        let placed = {
            let window = &mut self.window;
            let pre_ref = pre.as_ref();
            let frame_ref = &frame;
            self.timings
                .time("pose", || window.track_frame(guess, frame_ref, pre_ref))
        };
        if !placed.good {
            tracing::debug!(
                "frame at {t_ns} ns not placed by the images: {} of {} matched observations kept (the IMU {})",
                placed.inliers,
                placed.matched,
                if pre.is_some() { "spans the frame" } else { "does not reach it" }
            );
        }
        let mut state = if placed.good && !carried_over_repeat {
            self.last_vision_ns = Some(t_ns);
            self.leaving_rest = false;
            self.bad_frames = 0;
            self.frame_marginal = placed.pose_marginal;
            placed.state
        } else {
            let since_vision_s = self
                .last_vision_ns
                .map_or(f64::INFINITY, |v| (t_ns - v) as f64 * 1e-9);
            // At rest (the images too): hold the pose, as at a static start.
            if self.mode.uses_imu() && self.window.imu_enabled() && !carried_over_repeat {
                let flow = self.last_flow_px;
                if let Some(mut rest) = self.rest_state(&frame, flow) {
                    rest.T_world_body.rotation = guess.T_world_body.rotation;
                    if let Some(last) = self.last {
                        rest.T_world_body.translation = last.T_world_body.translation;
                    }
                    self.counters.static_frames += 1;
                    self.last = Some(rest);
                    self.trust(rest);
                    let out = self.output(&rest, TrackingState::Tracking, None);
                    self.set_rest_anchor(&frame);
                    self.phase = Phase::Resting { state: rest, frame };
                    return out;
                }
            }
            let carry_max_s = if self.leaving_rest {
                self.config.imu_only_after_rest_max_s
            } else {
                self.config.imu_only_max_s
            };
            let carried = pre.is_some() && since_vision_s <= carry_max_s;
            if !carried {
                self.bad_frames += 1;
                if self.bad_frames >= self.config.lost_after_frames {
                    self.reset();
                }
                self.last = Some(guess);
                return self.output(&guess, TrackingState::Lost, None);
            }
            // The IMU carries the state; keyframes stay as the tracker
            // spaces them, so that new landmarks get the parallax to be
            // triangulated and the window keeps older, vision-anchored
            // keyframes (a keyframe every frame filled it with 0.5 s of
            // IMU-only states whose biases wandered off).
            self.counters.imu_only_frames += 1;
            self.frame_marginal = pre.as_ref().and_then(|p| self.imu_prediction_marginal(p));
            guess
        };
        if !self.window.imu_enabled() {
            if let Some(last) = self.last.filter(|l| l.t_ns < t_ns) {
                let dt_s = (t_ns - last.t_ns) as f64 * 1e-9;
                state.velocity_world_m_s = (state.T_world_body.translation.vector
                    - last.T_world_body.translation.vector)
                    / dt_s;
            }
        }
        let kf_gap = self.window.latest().map_or(i64::MAX, |k| t_ns - k.t_ns);
        // A repeated image's observations are the previous frame's: no
        // keyframe from them.
        let keyframe = !carried_over_repeat && (frame.is_keyframe || kf_gap >= MAX_KEYFRAME_GAP_NS);
        if keyframe && tracking == TrackingState::Tracking {
            // The pose goes out as tracked, like any other frame's; the
            // window's optimisation, which takes most of a keyframe's
            // time, follows in `finish_frame` (or first thing on the next
            // frame). The state the next frame starts from, and the
            // answer the second stage gets, are the optimised ones.
            // (While initialising, the alignment needs the keyframe now.)
            let position_m = self
                .published
                .at(t_ns, &state.T_world_body.translation.vector);
            let early = self.answer(
                &state,
                tracking,
                Some(&frame),
                self.frame_marginal,
                position_m,
            );
            self.deferred = Some(DeferredKeyframe {
                state,
                frame,
                pre,
                tracking,
                frame_marginal: self.frame_marginal.take(),
                published_m: position_m,
            });
            return early;
        }
        if keyframe {
            state = self.optimise_keyframe(state, &frame, pre);
        }
        self.settle(state, tracking, &frame)
    }

    /// Adds the keyframe and optimises the window; the keyframe's
    /// optimised state (`state` itself if the window refused it).
    fn optimise_keyframe(
        &mut self,
        mut state: KeyframeState,
        frame: &TrackedFrame,
        pre: Option<Preintegrated>,
    ) -> KeyframeState {
        if self.add_keyframe(state, frame, pre) {
            if let Some(latest) = self.window.latest() {
                let velocity = state.velocity_world_m_s;
                state = *latest;
                if !self.window.imu_enabled() {
                    state.velocity_world_m_s = velocity;
                }
            }
        }
        state
    }

    /// The keyframe optimisation put off by `track`; the keyframe's answer
    /// with the optimised state (None when none was put off).
    fn finish_keyframe(&mut self) -> Option<RelativeOutput> {
        let DeferredKeyframe {
            state,
            frame,
            pre,
            tracking,
            frame_marginal,
            published_m,
        } = self.deferred.take()?;
        self.frame_marginal = frame_marginal;
        let state = self.optimise_keyframe(state, &frame, pre);
        // The pose went out before the solve: go on from where it went.
        self.published
            .hold(&published_m, &state.T_world_body.translation.vector);
        Some(self.settle(state, tracking, &frame))
    }

    /// A tracked frame's state becomes the last one; its answer.
    fn settle(
        &mut self,
        state: KeyframeState,
        tracking: TrackingState,
        frame: &TrackedFrame,
    ) -> RelativeOutput {
        self.gyro_bias_rad_s = state.biases.gyro_rad_s;
        self.last = Some(state);
        if tracking == TrackingState::Tracking
            && (self.mode.uses_imu() == self.window.imu_enabled())
        {
            self.trust(state);
        }
        self.output(&state, tracking, Some(frame))
    }

    /// Pushes and optimises; false (and counted) when the window refused.
    fn add_keyframe(
        &mut self,
        state: KeyframeState,
        frame: &TrackedFrame,
        pre: Option<Preintegrated>,
    ) -> bool {
        let omega = self.angular_rate_at(frame.t_ns, &state);
        let window = &mut self.window;
        let counters = &mut self.counters;
        let pushed = self.timings.time("window", || {
            window.push_keyframe(state, frame, pre)?;
            if let Some(omega) = omega {
                window.set_newest_angular_rate(omega);
            }
            counters.note_solve(&window.optimize());
            Ok::<(), super::window::WindowError>(())
        });
        if let Err(e) = pushed {
            tracing::debug!("keyframe at {} ns refused: {e}", frame.t_ns);
            self.counters.window_errors += 1;
            return false;
        }
        self.counters.keyframes += 1;
        self.tracker.mark_keyframe(frame.t_ns);
        let oldest = self.window.keyframes().next().map(|k| k.t_ns);
        if let (Some(imu), Some(oldest)) = (self.imu.as_mut(), oldest) {
            // Keep a second before the oldest keyframe for the static
            // detector and the alignment.
            imu.discard_before(oldest.min(frame.t_ns - 1_000_000_000));
        }
        true
    }

    /// The body's angular rate at `t_ns`: the gyroscope's mean over the
    /// samples within 5 ms, less the state's bias (None without samples).
    fn angular_rate_at(&self, t_ns: i64, state: &KeyframeState) -> Option<Vector3<f64>> {
        let samples = self
            .imu
            .as_ref()?
            .between(t_ns - 5_000_000, t_ns + 5_000_000);
        if samples.is_empty() {
            return None;
        }
        let sum = samples
            .iter()
            .fold(Vector3::zeros(), |acc, s| acc + Vector3::from(s.gyro_rad_s));
        Some(sum / samples.len() as f64 - state.biases.gyro_rad_s)
    }
}

/// The turn about the world's z axis that best takes attitude `from` to
/// `to` (both gravity-aligned): the heading part of `to from^-1`, read
/// from the whole rotation. Reading each attitude's heading from where
/// one body axis points fails when that axis is near vertical (EuRoC's
/// IMU has x up): a tenth of a degree of tilt moves that reading by
/// degrees (a resume on a rendered loss in flight: 3.4 deg off).
fn heading_turn(
    from: &nalgebra::UnitQuaternion<f64>,
    to: &nalgebra::UnitQuaternion<f64>,
) -> nalgebra::UnitQuaternion<f64> {
    let d = (to * from.inverse()).to_rotation_matrix().into_inner();
    // The z rotation closest to d (least squares over its horizontal
    // block).
    let psi = (d[(1, 0)] - d[(0, 1)]).atan2(d[(0, 0)] + d[(1, 1)]);
    nalgebra::UnitQuaternion::from_axis_angle(&Vector3::z_axis(), psi)
}

fn nav_of(s: &KeyframeState) -> NavState {
    NavState {
        t_ns: s.t_ns,
        R_world_body: s.T_world_body.rotation,
        position_world_m: s.T_world_body.translation.vector,
        velocity_world_m_s: s.velocity_world_m_s,
    }
}

impl RelativeEstimator for WindowOdometry {
    fn push_imu(&mut self, sample: &ImuSample) {
        if let Some(imu) = self.imu.as_mut() {
            imu.push(sample);
        }
    }

    fn push_frame(&mut self, frame: &FrameInput<'_>) -> RelativeOutput {
        self.timings.clear();
        self.finish_keyframe();
        let t_ns = frame.t_ns;
        if let Some(last) = &self.last_output {
            if t_ns <= last.t_ns {
                self.counters.frames_out_of_order += 1;
                return last.clone();
            }
        }
        self.counters.frames += 1;
        let digest = image_digest(frame.left);
        self.repeated_frame = self.previous_left_digest == Some(digest);
        self.previous_left_digest = Some(digest);
        if self.repeated_frame {
            self.counters.frames_repeated += 1;
        }
        let prediction = self.predicted_camera_rotation(t_ns);
        let tracker = &mut self.tracker;
        let tracked = self
            .timings
            .time("track", || tracker.track(frame, prediction.as_ref()));
        let tracked = match tracked {
            Ok(t) => t,
            Err(e) => {
                tracing::warn!("frame at {t_ns} ns not tracked: {e}");
                self.counters.tracker_errors += 1;
                return self.unplaced_output(t_ns, TrackingState::Lost);
            }
        };
        let flow_px = self.median_flow_px(&tracked);
        self.last_flow_px = flow_px;
        match self.phase {
            Phase::Tracking => self.track(tracked, TrackingState::Tracking),
            Phase::Aligning => self.align_step(tracked, flow_px),
            Phase::Initializing { .. } | Phase::Resting { .. } => self.initialize(tracked, flow_px),
        }
    }

    fn finish_frame(&mut self) -> Option<RelativeOutput> {
        self.finish_keyframe()
    }

    fn work_pending(&self) -> bool {
        self.deferred.is_some()
    }

    fn last_timings(&self) -> &FrameTimings {
        &self.timings
    }

    fn imu_noise_scale(&self) -> Option<NoiseScale> {
        self.imu
            .is_some()
            .then(|| self.window.noise_adaptation().scale())
    }

    fn camera_imu(&self) -> Option<crate::relative::window::CameraImuEstimate> {
        self.imu.as_ref()?;
        self.window.camera_imu()
    }

    fn settling(&self) -> bool {
        self.aligned_until_ns.is_some_and(|until| {
            self.window
                .keyframes()
                .next()
                .map_or(true, |oldest| oldest.t_ns <= until)
        })
    }

    fn accel_bias_sigma_m_s2(&self) -> Option<f64> {
        (self.imu.is_some() && self.window.imu_enabled()).then(|| {
            self.window
                .newest_accel_bias_sigma_m_s2()
                .unwrap_or(f64::INFINITY)
        })
    }

    fn gravity_world_m_s2(&self) -> Option<Vector3<f64>> {
        self.window
            .imu_enabled()
            .then(|| self.window.gravity_world_m_s2())
    }

    fn noise_at_bound(&self) -> bool {
        self.window.noise_adaptation().at_bound()
    }

    fn counters(&self) -> Vec<(&'static str, u64)> {
        let c = self.counters;
        vec![
            ("frames", c.frames),
            ("frames_out_of_order", c.frames_out_of_order),
            ("frames_repeated", c.frames_repeated),
            ("tracker_errors", c.tracker_errors),
            ("keyframes", c.keyframes),
            ("window_errors", c.window_errors),
            ("resets", c.resets),
            ("static_frames", c.static_frames),
            ("imu_only_frames", c.imu_only_frames),
            ("alignments_tried", c.alignments_tried),
            ("alignment_keyframes", c.alignment_keyframes),
            ("alignment_links", c.alignment_links),
            ("bootstraps_tried", c.bootstraps_tried),
            ("frames_without_imu", c.frames_without_imu),
            ("resumed", c.resumed),
            ("inconsistent_landmarks", c.inconsistent_landmarks),
            (
                "imu_samples_dropped",
                self.imu.as_ref().map_or(0, ImuBuffer::dropped),
            ),
        ]
    }
}

#[cfg(test)]
mod tests {
    use super::{heading_turn, image_digest};
    use crate::sensors::Image;
    use nalgebra::{Unit, UnitQuaternion, Vector3};

    /// A resume turns the trajectory by the heading between the attitude
    /// before the loss and the new window's, whatever the body's axes:
    /// with the body's x axis near vertical (EuRoC's IMU) as with it
    /// level, and with a small tilt between the two attitudes.
    #[test]
    fn the_heading_turn_is_read_from_the_whole_attitude() {
        let x_up = UnitQuaternion::from_axis_angle(&Vector3::y_axis(), -1.55);
        for base in [UnitQuaternion::identity(), x_up] {
            for heading_deg in [-170.0f64, -51.0, 0.0, 3.0, 90.0] {
                let base = UnitQuaternion::from_euler_angles(0.02, -0.01, 0.4) * base;
                let tilt = UnitQuaternion::from_axis_angle(
                    &Unit::new_normalize(Vector3::new(1.0, 2.0, 0.0)),
                    0.3f64.to_radians(),
                );
                let to = tilt
                    * UnitQuaternion::from_axis_angle(&Vector3::z_axis(), heading_deg.to_radians())
                    * base;
                let turn = heading_turn(&base, &to);
                let axis_z = turn.axis().map_or(1.0, |a| a.z.abs());
                assert!(axis_z > 1.0 - 1e-12, "about z");
                // The turn leaves only the tilt between them.
                let left = (turn * base).angle_to(&to).to_degrees();
                assert!(left < 0.31, "heading {heading_deg}: {left} deg left");
            }
        }
    }

    /// The same bytes give the same digest; one bit anywhere (the tail
    /// past the last whole 8-byte word included) or another size, another.
    #[test]
    fn a_digest_tells_a_repeated_image_from_a_new_one() {
        let (w, h) = (13u32, 7u32);
        let pixels: Vec<u8> = (0..w * h).map(|i| (i * 31 % 251) as u8).collect();
        let image = |p: Vec<u8>| Image::mono8(w, h, p).expect("image");
        let d = image_digest(&image(pixels.clone()));
        assert_eq!(d, image_digest(&image(pixels.clone())));
        for i in [0, 40, pixels.len() - 1] {
            let mut changed = pixels.clone();
            changed[i] ^= 1;
            assert_ne!(d, image_digest(&image(changed)), "byte {i}");
        }
        let black = |w, h| Image::mono8(w, h, vec![0; (w * h) as usize]).expect("image");
        assert_ne!(image_digest(&black(4, 4)), image_digest(&black(4, 5)));
    }
}
