//! How the relative stage starts: the initialisation mode brings it to a
//! metric, gravity-aligned state in one of two ways:
//! - a static start: the IMU (and the images, which must not move either:
//!   the IMU alone cannot tell rest from constant velocity) says the rig is
//!   at rest; gravity and the gyro bias come from the samples, the pose is
//!   held, and the window starts from that state when the rig moves;
//! - a moving start: the window runs vision-only (stereo depth from the
//!   first frame; mono from a five-point bootstrap with a unit first
//!   translation) until the visual-inertial alignment of its keyframes
//!   gives the scale with good certainty, gravity, velocities and the gyro
//!   bias; then the window is mapped into the metric world and the
//!   inertial terms switch on (the paper's hybrid mode).

use std::collections::HashMap;

use nalgebra::{Isometry3, Matrix6, Translation3, Vector2, Vector3};

use super::*;
use crate::relative::initializer::{
    align_with_reintegration, bootstrap_two_view, AlignmentConfig, BootstrapConfig,
    BootstrapRefusal, ScaleMode, VisionKeyframe,
};

/// Median image motion between frames under which the images agree that
/// the rig rests, px (EuRoC's MAV on the ground with its rotors running
/// jitters by about 0.7 px).
const REST_FLOW_PX: f64 = 1.5;
/// Median displacement since the rest began under which it goes on, px.
const REST_DRIFT_PX: f64 = 1.5;

impl WindowOdometry {
    pub(super) fn set_rest_anchor(&mut self, frame: &TrackedFrame) {
        self.rest_anchor.clear();
        self.rest_anchor
            .extend(frame.in_camera(0).map(|o| (o.landmark, o.pixel)));
    }

    /// Inertial modes: the rest state when the IMU and the images agree
    /// that nothing moves.
    pub(super) fn rest_state(
        &mut self,
        frame: &TrackedFrame,
        flow_px: Option<f64>,
    ) -> Option<KeyframeState> {
        if flow_px.is_some_and(|f| f > REST_FLOW_PX) {
            tracing::debug!(
                "not at rest at {} ns: the image moved {:.2} px",
                frame.t_ns,
                flow_px.unwrap_or(0.0)
            );
            return None;
        }
        // Vibration jitters the image by a pixel or so; a slow constant
        // velocity moves it as much per frame but keeps going. So the
        // features must also stay where they were when the rest began.
        if let Some(drift) = median_displacement_px(&self.rest_anchor, frame) {
            if drift > REST_DRIFT_PX {
                tracing::debug!(
                    "not at rest at {} ns: features drifted {drift:.2} px since the rest began",
                    frame.t_ns
                );
                return None;
            }
        }
        let imu = self.imu.as_ref()?;
        let noise = self.rig.imu.as_ref()?.noise;
        let rest = imu.static_start(frame.t_ns, &noise, &self.static_config)?;
        let position = self
            .last
            .map_or(Vector3::zeros(), |s| s.T_world_body.translation.vector);
        // Once resting, the attitude is held: re-levelling every frame
        // would make the pose wander with the accelerometer noise. A rest
        // after a pose (a stop, or a loss that ends at rest) keeps the
        // heading the trajectory had and takes the tilt from the
        // accelerometer: the static start's own heading is arbitrary (on
        // a rendered lap, 52 deg from the pose before a loss).
        let rotation = match (&self.phase, &self.last) {
            (Phase::Resting { state, .. }, _) => state.T_world_body.rotation,
            (_, Some(last)) => {
                heading_turn(&rest.R_world_body, &last.T_world_body.rotation) * rest.R_world_body
            }
            _ => rest.R_world_body,
        };
        Some(KeyframeState {
            t_ns: frame.t_ns,
            T_world_body: Isometry3::from_parts(Translation3::from(position), rotation),
            velocity_world_m_s: Vector3::zeros(),
            biases: ImuBiases {
                gyro_rad_s: rest.gyro_bias_rad_s,
                accel_m_s2: Vector3::zeros(),
            },
        })
    }

    /// Starts the window, inertial terms on, from a known metric state
    /// (the last rest frame, or a state the IMU carried through a loss).
    /// The trajectory goes on from `state`, and so does its covariance:
    /// the last one, carried to `state` with `added` (the IMU's share when
    /// it carried the state).
    fn start_inertial_window(
        &mut self,
        state: KeyframeState,
        frame: &TrackedFrame,
        gravity_sigma_rad: f64,
        added: Matrix6<f64>,
    ) -> bool {
        self.new_window();
        let ok = self.window.enable_imu(true).is_ok()
            && self
                .window
                .set_gravity(Vector3::new(0.0, 0.0, -GRAVITY_M_S2), gravity_sigma_rad)
                .is_ok()
            && self.window.push_keyframe(state, frame, None).is_ok();
        if ok {
            self.counters.keyframes += 1;
            self.tracker.mark_keyframe(frame.t_ns);
            self.last_vision_ns = Some(frame.t_ns);
            if let Some((pose, c)) = self.last_covariance {
                let before = pose_covariance::from_published(&pose, &c.matrix);
                let covariance =
                    pose_covariance::compose(&pose, &before, &state.T_world_body, &added);
                self.window
                    .continue_covariance_chain((c.origin_t_ns, c.T_world_origin), covariance);
            }
        }
        ok
    }

    pub(super) fn initialize(
        &mut self,
        frame: TrackedFrame,
        flow_px: Option<f64>,
    ) -> RelativeOutput {
        let t_ns = frame.t_ns;
        if self.mode.uses_imu() {
            // 1. At rest (or still at rest).
            if let Some(state) = self.rest_state(&frame, flow_px) {
                self.counters.static_frames += 1;
                self.gyro_bias_rad_s = state.biases.gyro_rad_s;
                self.last = Some(state);
                self.trust(state);
                let out = self.output(&state, TrackingState::Tracking, None);
                if !matches!(self.phase, Phase::Resting { .. }) {
                    self.set_rest_anchor(&frame);
                }
                self.phase = Phase::Resting { state, frame };
                return out;
            }
            // 2. The rig started moving: the window starts from the last
            //    rest frame, which becomes its first (fixed) keyframe.
            if let Phase::Resting {
                state,
                frame: rest_frame,
            } = self.phase.clone()
            {
                if self.start_inertial_window(state, &rest_frame, 0.01, Matrix6::zeros()) {
                    self.phase = Phase::Tracking;
                    self.leaving_rest = true;
                    let mut frame = frame;
                    frame.is_keyframe = true;
                    return self.track(frame, TrackingState::Tracking);
                }
            }
            // 3. Carried through a loss by the IMU.
            if let Some(good) = self.last_good {
                let dt_s = (t_ns - good.t_ns) as f64 * 1e-9;
                if dt_s <= self.config.imu_only_max_s {
                    if let Some((state, pre)) = self.propagate(&good, t_ns) {
                        let scale = self.window.noise_adaptation().scale();
                        let added = pose_covariance::imu_prediction(
                            &pre,
                            &good.T_world_body,
                            scale.gyro,
                            scale.accel,
                        );
                        if self.start_inertial_window(state, &frame, 0.02, added) {
                            self.counters.imu_only_frames += 1;
                            self.phase = Phase::Tracking;
                            self.last = Some(state);
                            return self.output(&state, TrackingState::Tracking, Some(&frame));
                        }
                    }
                }
                self.last_good = None;
            }
        }
        // 4. Vision first.
        if self.mode.uses_stereo() {
            self.start_stereo(frame)
        } else {
            self.start_mono(frame)
        }
    }

    /// Stereo: metric from the first frame; the window starts vision-only
    /// at the identity.
    fn start_stereo(&mut self, frame: TrackedFrame) -> RelativeOutput {
        let t_ns = frame.t_ns;
        // After a loss, vision-only modes go on from the last pose, so the
        // trajectory continues instead of jumping back to the origin.
        let pose = if self.mode.uses_imu() {
            Isometry3::identity()
        } else {
            self.last.map_or(Isometry3::identity(), |s| s.T_world_body)
        };
        let state = KeyframeState {
            t_ns,
            T_world_body: pose,
            velocity_world_m_s: Vector3::zeros(),
            biases: ImuBiases {
                gyro_rad_s: self.gyro_bias_rad_s,
                accel_m_s2: Vector3::zeros(),
            },
        };
        self.new_window();
        if frame.in_camera(1).count() < 10
            || self.window.push_keyframe(state, &frame, None).is_err()
        {
            return self.unplaced_output(t_ns, TrackingState::Initializing);
        }
        if self.mode.uses_imu() {
            self.plan_resume(t_ns);
        }
        self.counters.keyframes += 1;
        if !self.mode.uses_imu() {
            if let Some((pose, c)) = self.last_covariance {
                let before = pose_covariance::from_published(&pose, &c.matrix);
                let covariance = pose_covariance::compose(&pose, &before, &pose, &Matrix6::zeros());
                self.window
                    .continue_covariance_chain((c.origin_t_ns, c.T_world_origin), covariance);
            }
        }
        self.vision_started(state, &frame)
    }

    /// The window holds a vision-only start ending at `frame`: tracking
    /// in the vision-only modes, waiting for the IMU alignment otherwise.
    fn vision_started(&mut self, state: KeyframeState, frame: &TrackedFrame) -> RelativeOutput {
        self.tracker.mark_keyframe(frame.t_ns);
        self.last = Some(state);
        self.last_vision_ns = Some(frame.t_ns);
        if self.mode.uses_imu() {
            self.phase = Phase::Aligning;
            self.output(&state, TrackingState::Initializing, None)
        } else {
            self.phase = Phase::Tracking;
            self.output(&state, TrackingState::Tracking, Some(frame))
        }
    }

    /// Mono: wait for parallax against the first keyframe, then the
    /// five-point bootstrap (first translation of unit length).
    fn start_mono(&mut self, frame: TrackedFrame) -> RelativeOutput {
        let t_ns = frame.t_ns;
        let first = match &self.phase {
            Phase::Initializing { first: Some(f) } => f.clone(),
            _ => {
                self.tracker.mark_keyframe(t_ns);
                self.phase = Phase::Initializing { first: Some(frame) };
                if self.mode.uses_imu() {
                    self.plan_resume(t_ns);
                }
                return self.unplaced_output(t_ns, TrackingState::Initializing);
            }
        };
        self.counters.bootstraps_tried += 1;
        let camera = &self.rig.cameras[0].model;
        let config = BootstrapConfig::default();
        let boot = self.timings.time("init", || {
            bootstrap_two_view(&first, &frame, camera, &config)
        });
        let b = match boot {
            Ok(b) => b,
            Err(BootstrapRefusal::TooLittleParallax { .. })
            | Err(BootstrapRefusal::PureRotation { .. }) => {
                return self.unplaced_output(t_ns, TrackingState::Initializing);
            }
            Err(e) => {
                // Start again from this frame when the first has aged.
                tracing::debug!("bootstrap refused: {e}");
                if t_ns - first.t_ns > 2_000_000_000 {
                    self.tracker.mark_keyframe(t_ns);
                    self.phase = Phase::Initializing { first: Some(frame) };
                    if self.mode.uses_imu() {
                        self.plan_resume(t_ns);
                    }
                }
                return self.unplaced_output(t_ns, TrackingState::Initializing);
            }
        };
        #[allow(non_snake_case)]
        let T_cb = self.T_body_cam0().inverse();
        let biases = ImuBiases {
            gyro_rad_s: self.gyro_bias_rad_s,
            accel_m_s2: Vector3::zeros(),
        };
        let s0 = KeyframeState {
            t_ns: first.t_ns,
            T_world_body: T_cb,
            velocity_world_m_s: Vector3::zeros(),
            biases,
        };
        let s1 = KeyframeState {
            t_ns,
            T_world_body: b.T_c0_c1 * T_cb,
            velocity_world_m_s: Vector3::zeros(),
            biases,
        };
        self.new_window();
        let window = &mut self.window;
        let counters = &mut self.counters;
        let started = self.timings.time("window", || {
            window.push_keyframe(s0, &first, None)?;
            window.push_keyframe(s1, &frame, None)?;
            counters.note_solve(&window.optimize());
            Ok::<(), crate::relative::window::WindowError>(())
        });
        if started.is_err() || self.window.landmark_count() < 20 {
            self.new_window();
            return self.unplaced_output(t_ns, TrackingState::Initializing);
        }
        self.counters.keyframes += 2;
        let state = *self.window.latest().expect("two keyframes pushed");
        self.vision_started(state, &frame)
    }

    /// Inertial modes after a moving start: vision-only tracking, and after
    /// each keyframe the visual-inertial alignment; when it is certain the
    /// window becomes metric and gravity-aligned and the IMU joins.
    pub(super) fn align_step(
        &mut self,
        frame: TrackedFrame,
        flow_px: Option<f64>,
    ) -> RelativeOutput {
        // Still at rest (the IMU history may have been too short on the
        // first frame): a static start beats a vision-only one.
        if self.window.keyframe_count() <= 2 && self.rest_state(&frame, flow_px).is_some() {
            self.new_window();
            self.phase = Phase::Initializing { first: None };
            return self.initialize(frame, flow_px);
        }
        let keyframes_before = self.counters.keyframes;
        let out = self.track(frame.clone(), TrackingState::Initializing);
        if out.state == TrackingState::Lost || self.counters.keyframes == keyframes_before {
            return out;
        }
        if !self.try_alignment() {
            return out;
        }
        self.phase = Phase::Tracking;
        let state = *self
            .window
            .latest()
            .expect("an aligned window has keyframes");
        self.aligned_until_ns = Some(state.t_ns);
        self.last = Some(state);
        self.trust(state);
        self.gyro_bias_rad_s = state.biases.gyro_rad_s;
        self.output(&state, TrackingState::Tracking, Some(&frame))
    }

    #[allow(non_snake_case)]
    fn try_alignment(&mut self) -> bool {
        let kfs: Vec<KeyframeState> = self.window.keyframes().copied().collect();
        let full = self.config.window_keyframes;
        let needed = if self.config.init_full_window.enabled_in(self.mode) {
            full
        } else {
            self.config.init_keyframes
        };
        if kfs.len() < needed {
            return false;
        }
        // A full window is all the alignment will ever get: in fast motion
        // keyframes come close together, and a window of them may span
        // less than the configured time; waiting longer would never start.
        let span_s = (kfs[kfs.len() - 1].t_ns - kfs[0].t_ns) as f64 * 1e-9;
        if span_s < self.config.init_min_span_s && kfs.len() < full {
            return false;
        }
        self.counters.alignments_tried += 1;
        let T_bc = self.T_body_cam0();
        let vision: Vec<VisionKeyframe> = kfs
            .iter()
            .map(|k| VisionKeyframe {
                t_ns: k.t_ns,
                T_c0_cam: k.T_world_body * T_bc,
            })
            .collect();
        let scale = if self.mode.uses_stereo() {
            ScaleMode::Known(1.0)
        } else {
            ScaleMode::Estimate
        };
        let config = AlignmentConfig {
            max_scale_rel_std: self.config.init_max_scale_rel_std,
            ..AlignmentConfig::default()
        };
        let Some(imu) = self.imu.as_mut() else {
            return false;
        };
        let (samples, preintegrator) = imu.parts();
        let aligned = self.timings.time("init", || {
            align_with_reintegration(
                &vision,
                samples,
                preintegrator,
                &ImuBiases::default(),
                &T_bc,
                scale,
                &config,
            )
        });
        let a = match aligned {
            Ok(a) => a,
            Err(e) => {
                tracing::debug!("alignment not yet: {e}");
                return false;
            }
        };
        if !(self.mode.uses_stereo() || a.scale_certain) || a.keyframes.len() != kfs.len() {
            return false;
        }
        // x_new = R_world_c0 (s x_old) + t, with t placing the first
        // camera where the alignment put it.
        let cam_old = kfs[0].T_world_body * T_bc;
        let cam_new = a.keyframes[0].T_world_body * T_bc;
        let t = cam_new.translation.vector - a.R_world_c0 * (a.scale * cam_old.translation.vector);
        let T_new_old = Isometry3::from_parts(Translation3::from(t), a.R_world_c0);
        let sigma = a.gravity_std_rad.clamp(0.005, 0.05);
        // The keyframes joined the window while it ran on the images
        // alone, without inertial links. With one camera the alignment's
        // scale is only an estimate: each interval is integrated again at
        // the biases the alignment gives the keyframes, and the first
        // inertial solve (which holds the oldest keyframe alone) weighs
        // the IMU over the whole window, scale included. Left unlinked,
        // the IMU reached the old keyframes only as new ones replaced
        // them, some 2 s later, and the published poses jumped at each of
        // the first solves. A stereo window is metric before the IMU, and
        // there the same links, whose gravity and biases are still the
        // alignment's, made the map built on the first keyframes worse
        // (two stages 9 % worse on starts in flight): stereo keyframes are
        // linked as the window replaces them.
        let links: Vec<Preintegrated> = if self.mode.uses_stereo() {
            Vec::new()
        } else {
            kfs.windows(2)
                .filter_map(|w| {
                    preintegrator
                        .integrate(samples, w[0].t_ns, w[1].t_ns, &a.biases)
                        .map_err(|e| tracing::debug!("alignment: interval not linked: {e}"))
                        .ok()
                })
                .collect()
        };
        let linked = links.len() as u64;
        let mapped = self.window.transform(a.scale, T_new_old).is_ok()
            && self.window.set_states(&a.keyframes).is_ok()
            && links
                .into_iter()
                .all(|pre| self.window.set_preintegrated(pre).is_ok())
            && self
                .window
                .set_gravity(Vector3::new(0.0, 0.0, -GRAVITY_M_S2), sigma)
                .is_ok()
            && self.window.enable_imu(true).is_ok();
        if !mapped {
            self.reset();
            return false;
        }
        self.counters.alignment_keyframes = kfs.len() as u64;
        self.counters.alignment_links = linked;
        if linked > 0 {
            self.window.hold_oldest_only_next_solve();
        }
        // With the camera-IMU calibration refined, the first boundary
        // prior holds the gyroscope bias about as well as the alignment
        // found it, not at the configured 0.01 rad/s: in flight the
        // window's first seconds barely tell a bias from a turn of the
        // camera-IMU rotation (at a steady turn rate both shift the
        // gyroscope against the images alike), and a free bias lets the
        // refinement carry the rotation away from the file.
        if self.window.camera_imu().is_some() {
            self.window.set_start_gyro_bias_sigma(
                ALIGNMENT_GYRO_BIAS_SIGMA_INFLATION * a.gyro_bias_sigma_rad_s.max(),
            );
        }
        self.window.start_in_motion();
        self.apply_resume();
        let window = &mut self.window;
        let counters = &mut self.counters;
        self.timings.time("window", || {
            counters.note_solve(&window.optimize());
        });
        true
    }
}

/// Factor on the alignment's gyroscope bias sigma where it starts the
/// window's boundary prior. The alignment counts the gyroscope's noise
/// only (its vision rotations taken as exact); on starts in flight of the
/// development renderings its bias errors were 1.8 times its sigma (rms
/// over axes and runs).
const ALIGNMENT_GYRO_BIAS_SIGMA_INFLATION: f64 = 2.0;

/// Median distance of `frame`'s left features from where `anchor` saw
/// them, px; `None` with fewer than 10 in common.
fn median_displacement_px(
    anchor: &HashMap<LandmarkId, Vector2<f64>>,
    frame: &TrackedFrame,
) -> Option<f64> {
    let mut d: Vec<f64> = frame
        .in_camera(0)
        .filter_map(|o| anchor.get(&o.landmark).map(|p| (o.pixel - p).norm()))
        .collect();
    if d.len() < 10 {
        return None;
    }
    let mid = d.len() / 2;
    d.select_nth_unstable_by(mid, f64::total_cmp);
    Some(d[mid])
}
