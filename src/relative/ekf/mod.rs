//! The paper's EKF variant of the relative stage
//! (`--estimator ekf`): a baseline to compare the window against.
//!
//! An EKF-SLAM visual-inertial filter on tracked observations (no image
//! processing here; the tracker feeds [`TrackedFrame`]s):
//!
//! - State (private `state` module): body orientation (error-state on SO(3), right
//!   perturbation), position, velocity, gyro and accel biases (15 error
//!   states) plus up to [`EkfConfig::max_landmarks`] landmarks as world
//!   xyz (3 each; why not inverse depth: see the `state` source module).
//! - Propagation (`propagation`) with every IMU sample, continuous
//!   Kalibr densities made discrete per step. The landmark rows of the
//!   covariance do not change during propagation, only the cross terms
//!   with the body do: the filter accumulates the 15x15 transition
//!   between frames and applies it to the cross block once per frame
//!   (exactly equivalent, 15x15 work per IMU sample instead of 15 x 3N).
//! - Update (`update`) with the reprojections of the state's landmarks
//!   in every camera of the frame (distorted pixels, `sigma_px`), each
//!   observation gated by its Mahalanobis distance against
//!   [`EkfConfig::gate_chi2`] (chi-square, 2 dof), then one batch update
//!   in Joseph form.
//! - Landmarks (`init`): a landmark not in the state enters from a
//!   stereo observation (camera 1 in the frame) triangulated with the
//!   calibrated pair, or, with one camera, delayed until a second view
//!   with `min_parallax_mono_rad` of parallax; tracks are preferred by
//!   stereo availability, then by length. A landmark absent from a frame
//!   (it left the view or its track was lost; ids are never reused) is
//!   marginalised by dropping its rows and columns, as is one whose
//!   observations the gate rejected `max_consecutive_rejections` frames
//!   in a row.
//!
//! The paper presents this EKF before its window estimator and gives no
//! equation numbers of its own for it; the models here are the standard
//! error-state formulation (Sola, "Quaternion kinematics for the
//! error-state Kalman filter", 2017, sections 5-7).
//!
//! Known simplifications: the error reset after an update (the
//! `I - [dtheta/2]x` Jacobian on the attitude block) is taken as the
//! identity; the linearisation is the standard EKF's (no first-estimate
//! Jacobians), so the unobservable yaw and position directions most likely gain
//! spurious information over long runs (mean position NEES ~8.3 over 20
//! simulated stereo runs of 10 s, against 3 for a consistent filter;
//! the body-frame landmarks handed to the absolute stage are near
//! consistent, NEES ~4.7).

mod init;
mod propagation;
mod state;
mod update;

#[cfg(test)]
mod tests;

use std::collections::HashMap;

use nalgebra::{DMatrix, Matrix3, SMatrix, Vector2, Vector3};

use crate::imu::ImuBiases;
use crate::relative::estimator::RigModel;
use crate::relative::types::{BodyLandmark, KeyframeState, LandmarkId, TrackedFrame};
use crate::rig::ImuNoise;
use crate::sensors::ImuSample;
use crate::two_view::TriangulationConfig;

use init::{
    landmark_from_camera_point, mono_point_covariance, triangulate_with_covariance, NewLandmark,
    RelativeView,
};
use propagation::{step_noise, step_nominal, step_transition};
use state::{landmark_column, Matrix15, NavNominal, StateLandmark, NAV_DIM, POS};
use update::{
    batch_update, mahalanobis_squared, project_landmark, ObservationRow, RigCamera, UpdateScratch,
};

/// Tuning of the filter. Defaults suit a EuRoC-like 20 Hz stereo rig.
#[derive(Debug, Clone, PartialEq)]
pub struct EkfConfig {
    /// Landmarks kept in the state (each adds 3 error states).
    pub max_landmarks: usize,
    /// Standard deviation of a tracked pixel, px.
    pub pixel_sigma: f64,
    /// Gate on the squared Mahalanobis distance of one 2-D observation
    /// (chi-square with 2 dof: 5.99 at 95%, 9.21 at 99%).
    pub gate_chi2: f64,
    /// Smallest ray angle to initialise from the stereo pair, rad.
    pub min_parallax_stereo_rad: f64,
    /// Smallest ray angle to initialise from two views of one camera, rad.
    pub min_parallax_mono_rad: f64,
    /// Smallest angle between a mono-initialised point's ray and the
    /// baseline of its two views, rad. Near the epipole (moving towards
    /// the point) depth is unobservable and noise can put the point at
    /// the near limit with a deceptively small covariance.
    pub min_ray_baseline_angle_rad: f64,
    /// Largest depth standard deviation, as a fraction of the depth, of a
    /// stereo triangulation that may enter the state. World xyz is a poor
    /// parameterisation for a point elongated along its ray: in the
    /// simulation, edge-of-image stereo points (baseline nearly along the
    /// ray, depth sigma ~25%) were pulled by the updates to the camera
    /// with a collapsed covariance. Such points wait for motion parallax
    /// instead (the mono path).
    pub max_stereo_depth_sigma_fraction: f64,
    /// Landmark depth limits at initialisation, m.
    pub min_depth_m: f64,
    /// Largest landmark depth at initialisation, m.
    pub max_depth_m: f64,
    /// Factor on the two-view triangulation's depth variance in mono
    /// (covers the past pose's error, which is not in the state).
    pub mono_init_inflation: f64,
    /// Smallest depth standard deviation of a mono landmark at
    /// initialisation, as a fraction of its depth: the depth prior along
    /// the ray takes the larger of this and the inflated two-view depth
    /// sigma, and the following frames' updates refine it.
    pub mono_depth_sigma_fraction: f64,
    /// A landmark whose observations were rejected in this many frames in
    /// a row is dropped.
    pub max_consecutive_rejections: u32,
    /// Longest propagation step, s (longer IMU gaps are subdivided).
    pub max_step_s: f64,
}

impl Default for EkfConfig {
    fn default() -> Self {
        Self {
            max_landmarks: 40,
            pixel_sigma: 1.0,
            gate_chi2: 9.21,
            min_parallax_stereo_rad: 0.3_f64.to_radians(),
            min_parallax_mono_rad: 3.0_f64.to_radians(),
            min_ray_baseline_angle_rad: 10.0_f64.to_radians(),
            max_stereo_depth_sigma_fraction: 0.1,
            min_depth_m: 0.2,
            max_depth_m: 40.0,
            mono_init_inflation: 2.0,
            mono_depth_sigma_fraction: 0.25,
            max_consecutive_rejections: 2,
            max_step_s: 0.01,
        }
    }
}

/// Standard deviations of the initial state (per axis), for
/// [`EkfFilter::initialize`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct InitialSigmas {
    /// Tilt (rotation about horizontal world axes), rad.
    pub roll_pitch_rad: f64,
    /// Heading (rotation about world z), rad. The world frame of a VIO is
    /// defined by its first pose, so yaw (like position) starts nearly
    /// certain; a large yaw sigma would only feed the standard EKF's
    /// spurious heading information (see the module doc).
    pub yaw_rad: f64,
    /// Position, per world axis, m.
    pub position_m: f64,
    /// Velocity, per world axis, m/s.
    pub velocity_m_s: f64,
    /// Gyroscope bias, per axis, rad/s.
    pub gyro_bias_rad_s: f64,
    /// Accelerometer bias, per axis, m/s^2.
    pub accel_bias_m_s2: f64,
}

impl Default for InitialSigmas {
    /// What a static start gives: attitude from gravity, gyro bias from
    /// the mean rate at rest, position fixed by convention.
    fn default() -> Self {
        Self {
            roll_pitch_rad: 0.01,
            yaw_rad: 1e-4,
            position_m: 0.001,
            velocity_m_s: 0.02,
            gyro_bias_rad_s: 0.005,
            accel_bias_m_s2: 0.1,
        }
    }
}

/// Why a filter cannot be built.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum EkfError {
    #[error("the rig has no camera; the EKF needs camera 0")]
    /// The rig has no camera.
    NoCamera,
    #[error("the rig has no IMU; the EKF propagates with the IMU (inertial modes only)")]
    /// The rig has no IMU (the EKF is for the inertial modes only).
    NoImu,
    #[error("the IMU sits {lever_arm_m} m from the body origin; the EKF assumes the body is the IMU frame (translation of T_body_imu must be zero)")]
    /// The IMU is not at the body origin: the EKF assumes the body is the IMU frame.
    ImuLeverArm {
        /// Length of the translation of `T_body_imu`, m.
        lever_arm_m: f64,
    },
    #[error("EKF config `{key}` = {value} is outside {allowed}")]
    /// A setting is out of range.
    InvalidConfig {
        /// The setting's key.
        key: &'static str,
        /// Its value.
        value: f64,
        /// The allowed range.
        allowed: &'static str,
    },
}

/// What one [`EkfFilter::update`] did.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EkfUpdate {
    /// The state after the update.
    pub state: KeyframeState,
    /// Observations of state landmarks used in the update.
    pub accepted: usize,
    /// Observations of state landmarks refused by the chi-square gate.
    pub rejected: usize,
    /// Observations dropped as unusable (non-finite pixel, unknown
    /// camera, landmark behind the camera).
    pub ignored: usize,
    /// Landmarks that entered the state on this frame.
    pub landmarks_added: usize,
    /// Landmarks dropped from the state on this frame (left the view, lost, or rejected too often).
    pub landmarks_removed: usize,
    /// Landmarks in the state after the frame.
    pub landmark_count: usize,
    /// False when the frame was not processed (filter not initialised,
    /// or the frame is older than the state).
    pub processed: bool,
}

/// The first sighting of a track not (yet) in the state.
#[derive(Debug, Clone, Copy)]
struct Candidate {
    /// Left-camera pose at the first sighting (the filter's estimate).
    r_world_cam: Matrix3<f64>,
    p_world_cam_m: Vector3<f64>,
    first_pixel: Vector2<f64>,
    frames_seen: u32,
    last_seen_frame: u64,
}

/// The IMU sample the propagation holds, rotated into the body frame.
#[derive(Debug, Clone, Copy)]
struct HeldSample {
    t_ns: i64,
    gyro_rad_s: Vector3<f64>,
    accel_m_s2: Vector3<f64>,
}

/// The EKF baseline of the relative stage (see the module doc).
#[derive(Debug)]
pub struct EkfFilter {
    config: EkfConfig,
    cameras: Vec<RigCamera>,
    noise: ImuNoise,
    r_body_imu: Matrix3<f64>,
    nav: Option<NavNominal>,
    landmarks: Vec<StateLandmark>,
    /// Error-state covariance, `15 + 3 * landmarks.len()` square.
    covariance: DMatrix<f64>,
    /// Transition accumulated since the cross block was last brought up
    /// to date.
    pending_transition: Matrix15,
    last_sample: Option<HeldSample>,
    candidates: HashMap<LandmarkId, Candidate>,
    frame_counter: u64,
    ignored_samples: u64,
    // Per-frame buffers.
    right_pixels: HashMap<LandmarkId, Vector2<f64>>,
    rows: Vec<ObservationRow>,
    row_slots: Vec<usize>,
    scratch: UpdateScratch,
    ready: Vec<(LandmarkId, bool, u32)>,
    last_rejected: Vec<(LandmarkId, u8)>,
}

fn check(key: &'static str, value: f64, ok: bool, allowed: &'static str) -> Result<(), EkfError> {
    if ok && value.is_finite() {
        Ok(())
    } else {
        Err(EkfError::InvalidConfig {
            key,
            value,
            allowed,
        })
    }
}

impl EkfConfig {
    /// Checks every value once, naming the key that is out of range.
    pub fn validate(&self) -> Result<(), EkfError> {
        let c = self;
        check(
            "max_landmarks",
            c.max_landmarks as f64,
            (1..=500).contains(&c.max_landmarks),
            "1..=500",
        )?;
        check("pixel_sigma", c.pixel_sigma, c.pixel_sigma > 0.0, "> 0")?;
        check("gate_chi2", c.gate_chi2, c.gate_chi2 > 0.0, "> 0")?;
        check(
            "min_parallax_stereo_rad",
            c.min_parallax_stereo_rad,
            c.min_parallax_stereo_rad >= 0.0,
            ">= 0",
        )?;
        check(
            "min_parallax_mono_rad",
            c.min_parallax_mono_rad,
            c.min_parallax_mono_rad > 0.0,
            "> 0",
        )?;
        check(
            "min_ray_baseline_angle_rad",
            c.min_ray_baseline_angle_rad,
            (0.0..std::f64::consts::FRAC_PI_2).contains(&c.min_ray_baseline_angle_rad),
            "[0, pi/2)",
        )?;
        check(
            "max_stereo_depth_sigma_fraction",
            c.max_stereo_depth_sigma_fraction,
            c.max_stereo_depth_sigma_fraction > 0.0,
            "> 0",
        )?;
        check("min_depth_m", c.min_depth_m, c.min_depth_m > 0.0, "> 0")?;
        check(
            "max_depth_m",
            c.max_depth_m,
            c.max_depth_m > c.min_depth_m,
            "> min_depth_m",
        )?;
        check(
            "mono_init_inflation",
            c.mono_init_inflation,
            c.mono_init_inflation >= 1.0,
            ">= 1",
        )?;
        check(
            "mono_depth_sigma_fraction",
            c.mono_depth_sigma_fraction,
            c.mono_depth_sigma_fraction > 0.0,
            "> 0",
        )?;
        check(
            "max_consecutive_rejections",
            c.max_consecutive_rejections as f64,
            c.max_consecutive_rejections >= 1,
            ">= 1",
        )?;
        check(
            "max_step_s",
            c.max_step_s,
            c.max_step_s > 0.0 && c.max_step_s <= 0.1,
            "(0, 0.1]",
        )
    }
}

impl EkfFilter {
    /// A filter for `rig` (camera 0, optionally camera 1 for stereo, and
    /// the IMU), not yet initialised.
    pub fn new(config: EkfConfig, rig: &RigModel) -> Result<Self, EkfError> {
        config.validate()?;
        if rig.cameras.is_empty() {
            return Err(EkfError::NoCamera);
        }
        let imu = rig.imu.as_ref().ok_or(EkfError::NoImu)?;
        let lever_arm_m = imu.T_body_imu.translation.vector.norm();
        if !(lever_arm_m <= 1e-9) {
            return Err(EkfError::ImuLeverArm { lever_arm_m });
        }
        let cameras = rig
            .cameras
            .iter()
            .take(2)
            .map(|c| RigCamera {
                model: c.model.clone(),
                r_body_cam: *c.T_body_cam.rotation.to_rotation_matrix().matrix(),
                t_body_cam_m: c.T_body_cam.translation.vector,
            })
            .collect();
        let n_max = NAV_DIM + 3 * config.max_landmarks;
        Ok(Self {
            cameras,
            noise: imu.noise,
            r_body_imu: *imu.T_body_imu.rotation.to_rotation_matrix().matrix(),
            nav: None,
            landmarks: Vec::with_capacity(config.max_landmarks),
            covariance: DMatrix::zeros(NAV_DIM, NAV_DIM),
            pending_transition: Matrix15::identity(),
            last_sample: None,
            candidates: HashMap::new(),
            frame_counter: 0,
            ignored_samples: 0,
            right_pixels: HashMap::new(),
            rows: Vec::with_capacity(2 * n_max),
            row_slots: Vec::with_capacity(2 * n_max),
            scratch: UpdateScratch::default(),
            ready: Vec::new(),
            last_rejected: Vec::new(),
            config,
        })
    }

    /// Starts the filter from a known state (static start or another
    /// initialiser) with a diagonal covariance from `sigmas`. Landmarks
    /// and track candidates are cleared; the held IMU sample is kept.
    pub fn initialize(&mut self, state: KeyframeState, sigmas: &InitialSigmas) {
        let nav = NavNominal::from_keyframe(&state);
        self.landmarks.clear();
        self.candidates.clear();
        self.pending_transition = Matrix15::identity();
        self.covariance = DMatrix::zeros(NAV_DIM, NAV_DIM);
        if !nav.is_finite() {
            self.nav = None;
            return;
        }
        // Orientation: the sigmas are about world axes; the error state
        // is in the body frame, dtheta_body = R^T dtheta_world.
        let finite_var = |sigma: f64| {
            if sigma.is_finite() {
                sigma * sigma
            } else {
                1.0
            }
        };
        let world = Matrix3::from_diagonal(&Vector3::new(
            finite_var(sigmas.roll_pitch_rad),
            finite_var(sigmas.roll_pitch_rad),
            finite_var(sigmas.yaw_rad),
        ));
        let r = nav.rotation();
        let body = r.transpose() * world * r;
        self.covariance
            .fixed_view_mut::<3, 3>(0, 0)
            .copy_from(&((body + body.transpose()) * 0.5));
        let diag = [
            sigmas.position_m,
            sigmas.velocity_m_s,
            sigmas.gyro_bias_rad_s,
            sigmas.accel_bias_m_s2,
        ];
        for (block, sigma) in diag.iter().enumerate() {
            for i in 0..3 {
                self.covariance[(POS + 3 * block + i, POS + 3 * block + i)] = finite_var(*sigma);
            }
        }
        self.nav = Some(nav);
    }

    /// Whether the filter has a state yet ([`EkfFilter::initialize`] was called).
    pub fn is_initialized(&self) -> bool {
        self.nav.is_some()
    }

    /// IMU samples in time order (propagates up to each sample).
    /// Non-finite samples and samples not after the previous one are
    /// ignored (counted in [`EkfFilter::ignored_samples`]).
    pub fn propagate(&mut self, sample: &ImuSample) {
        let sane = sample.is_finite()
            && self
                .last_sample
                .map_or(true, |last| sample.t_ns > last.t_ns);
        if !sane {
            self.ignored_samples += 1;
            return;
        }
        let next = HeldSample {
            t_ns: sample.t_ns,
            gyro_rad_s: self.r_body_imu * Vector3::from(sample.gyro_rad_s),
            accel_m_s2: self.r_body_imu * Vector3::from(sample.accel_m_s2),
        };
        self.propagate_to(sample.t_ns, Some(&next));
        self.last_sample = Some(next);
    }

    /// Samples the filter refused since it was built.
    pub fn ignored_samples(&self) -> u64 {
        self.ignored_samples
    }

    /// Gyro and accel at `t_ns`: interpolated between the held sample and
    /// `next`, or held constant past the last sample.
    fn input_at(
        &self,
        t_ns: i64,
        next: Option<&HeldSample>,
    ) -> Option<(Vector3<f64>, Vector3<f64>)> {
        match (self.last_sample.as_ref(), next) {
            (Some(a), Some(b)) => {
                let span = (b.t_ns - a.t_ns) as f64;
                let u = (((t_ns - a.t_ns) as f64) / span).clamp(0.0, 1.0);
                Some((
                    a.gyro_rad_s.lerp(&b.gyro_rad_s, u),
                    a.accel_m_s2.lerp(&b.accel_m_s2, u),
                ))
            }
            (Some(a), None) => Some((a.gyro_rad_s, a.accel_m_s2)),
            (None, Some(b)) => Some((b.gyro_rad_s, b.accel_m_s2)),
            (None, None) => None,
        }
    }

    /// Propagates the state and the body block of the covariance to
    /// `t_ns` in steps of at most `max_step_s`.
    fn propagate_to(&mut self, t_ns: i64, next: Option<&HeldSample>) {
        let Some(mut nav) = self.nav else { return };
        if t_ns <= nav.t_ns {
            return;
        }
        let Some(_) = self.input_at(t_ns, next) else {
            // No IMU sample yet: nothing to propagate with.
            return;
        };
        let max_step_ns = (self.config.max_step_s * 1e9) as i64;
        let mut prr: Matrix15 = self.covariance.fixed_view::<15, 15>(0, 0).into();
        while nav.t_ns < t_ns {
            let dt_ns = (t_ns - nav.t_ns).min(max_step_ns.max(1));
            let (g0, a0) = self.input_at(nav.t_ns, next).expect("checked above");
            let (g1, a1) = self
                .input_at(nav.t_ns + dt_ns, next)
                .expect("checked above");
            let gyro = (g0 + g1) * 0.5;
            let accel = (a0 + a1) * 0.5;
            let dt_s = dt_ns as f64 * 1e-9;
            let phi = step_transition(&nav, &gyro, &accel, dt_s);
            nav = step_nominal(&nav, &gyro, &accel, dt_s, dt_ns);
            prr = phi * prr * phi.transpose() + step_noise(&self.noise, dt_s);
            self.pending_transition = phi * self.pending_transition;
        }
        prr = (prr + prr.transpose()) * 0.5;
        self.covariance
            .fixed_view_mut::<15, 15>(0, 0)
            .copy_from(&prr);
        self.nav = Some(nav);
    }

    /// Applies the accumulated transition to the body-landmark cross
    /// covariance.
    fn flush_cross_covariance(&mut self) {
        let n = self.covariance.nrows();
        if n > NAV_DIM && self.pending_transition != Matrix15::identity() {
            let cross = self.pending_transition
                * self.covariance.view((0, NAV_DIM), (NAV_DIM, n - NAV_DIM));
            self.covariance
                .view_mut((0, NAV_DIM), (NAV_DIM, n - NAV_DIM))
                .copy_from(&cross);
            self.covariance
                .view_mut((NAV_DIM, 0), (n - NAV_DIM, NAV_DIM))
                .copy_from(&cross.transpose());
        }
        self.pending_transition = Matrix15::identity();
    }

    fn slot_of(&self, id: LandmarkId) -> Option<usize> {
        self.landmarks.iter().position(|l| l.id == id)
    }

    /// Propagates to the frame stamp, then updates with the frame's
    /// observations; then drops landmarks that left the view and adds new
    /// ones.
    pub fn update(&mut self, frame: &TrackedFrame) -> EkfUpdate {
        let mut out = EkfUpdate {
            state: self.state(),
            accepted: 0,
            rejected: 0,
            ignored: 0,
            landmarks_added: 0,
            landmarks_removed: 0,
            landmark_count: self.landmarks.len(),
            processed: false,
        };
        let Some(nav) = self.nav else { return out };
        if frame.t_ns < nav.t_ns {
            return out;
        }
        self.propagate_to(frame.t_ns, None);
        self.flush_cross_covariance();
        self.frame_counter += 1;
        let frame_id = self.frame_counter;
        let nav = self.nav.expect("initialised above");

        // Observations of state landmarks: predict, gate, collect.
        self.rows.clear();
        self.row_slots.clear();
        self.last_rejected.clear();
        let mut rejected_slots: Vec<usize> = Vec::new();
        let sigma = self.config.pixel_sigma;
        for obs in &frame.observations {
            let camera_index = obs.camera_index as usize;
            let usable =
                camera_index < self.cameras.len() && obs.pixel.iter().all(|v| v.is_finite());
            let Some(slot) = self.slot_of(obs.landmark) else {
                if !usable {
                    out.ignored += 1;
                }
                continue;
            };
            if !usable {
                out.ignored += 1;
                continue;
            }
            self.landmarks[slot].last_seen_frame = frame_id;
            let Some(proj) = project_landmark(
                &nav,
                &self.cameras[camera_index],
                &self.landmarks[slot].position_world_m,
                1e-3,
            ) else {
                out.ignored += 1;
                continue;
            };
            let row = ObservationRow {
                landmark_column: landmark_column(slot),
                d_pose: proj.d_pose,
                d_landmark: proj.d_landmark,
                residual_px: obs.pixel - proj.pixel,
            };
            match mahalanobis_squared(&self.covariance, &row, sigma) {
                Some(d2) if d2 <= self.config.gate_chi2 => {
                    self.rows.push(row);
                    self.row_slots.push(slot);
                }
                _ => {
                    out.rejected += 1;
                    rejected_slots.push(slot);
                    self.last_rejected.push((obs.landmark, obs.camera_index));
                }
            }
        }
        // A frame with an accepted observation clears the count; a frame
        // with only rejected ones adds to it.
        for &slot in &self.row_slots {
            self.landmarks[slot].consecutive_rejections = 0;
        }
        rejected_slots.sort_unstable();
        rejected_slots.dedup();
        for &slot in &rejected_slots {
            if !self.row_slots.contains(&slot) {
                self.landmarks[slot].consecutive_rejections += 1;
            }
        }
        out.accepted = self.rows.len();
        if let Some(dx) = batch_update(&mut self.covariance, &self.rows, sigma, &mut self.scratch) {
            let mut nav = nav;
            nav.inject(dx.as_slice());
            for (k, l) in self.landmarks.iter_mut().enumerate() {
                let c = landmark_column(k);
                l.position_world_m += Vector3::new(dx[c], dx[c + 1], dx[c + 2]);
            }
            if nav.is_finite() {
                self.nav = Some(nav);
            }
        }

        out.landmarks_removed = self.remove_landmarks(frame_id);
        out.landmarks_added = self.add_landmarks(frame, frame_id);
        out.landmark_count = self.landmarks.len();
        out.state = self.state();
        out.processed = true;
        out
    }

    /// Marginalises landmarks not seen in frame `frame_id` or rejected
    /// too often: their rows and columns are dropped, compacting the
    /// covariance in place.
    fn remove_landmarks(&mut self, frame_id: u64) -> usize {
        let limit = self.config.max_consecutive_rejections;
        let keep: Vec<bool> = self
            .landmarks
            .iter()
            .map(|l| l.last_seen_frame == frame_id && l.consecutive_rejections < limit)
            .collect();
        let removed = keep.iter().filter(|k| !**k).count();
        if removed == 0 {
            return 0;
        }
        // Kept error-state indices, increasing; entry (i, j) of the new
        // matrix comes from (kept[i], kept[j]) with kept[i] >= i, so a
        // column-major in-place copy never overwrites a pending source.
        let mut kept: Vec<usize> = (0..NAV_DIM).collect();
        for (k, &keep_it) in keep.iter().enumerate() {
            if keep_it {
                let c = landmark_column(k);
                kept.extend([c, c + 1, c + 2]);
            }
        }
        let m = kept.len();
        for (j, &kj) in kept.iter().enumerate() {
            for (i, &ki) in kept.iter().enumerate() {
                self.covariance[(i, j)] = self.covariance[(ki, kj)];
            }
        }
        self.covariance.resize_mut(m, m, 0.0);
        let mut k = 0;
        self.landmarks.retain(|_| {
            let r = keep[k];
            k += 1;
            r
        });
        removed
    }

    /// Records the frame's tracks not in the state as candidates and
    /// initialises the best of them while there is room.
    fn add_landmarks(&mut self, frame: &TrackedFrame, frame_id: u64) -> usize {
        let Some(nav) = self.nav else { return 0 };
        let r_wb = nav.rotation();
        let cam0 = &self.cameras[0];
        let r_world_cam = r_wb * cam0.r_body_cam;
        let p_world_cam_m = nav.position_world_m + r_wb * cam0.t_body_cam_m;
        self.right_pixels.clear();
        if self.cameras.len() > 1 {
            for obs in frame.in_camera(1) {
                if obs.pixel.iter().all(|v| v.is_finite()) {
                    self.right_pixels.insert(obs.landmark, obs.pixel);
                }
            }
        }
        for obs in frame.in_camera(0) {
            if !obs.pixel.iter().all(|v| v.is_finite()) || self.slot_of(obs.landmark).is_some() {
                continue;
            }
            let entry = self.candidates.entry(obs.landmark).or_insert(Candidate {
                r_world_cam,
                p_world_cam_m,
                first_pixel: obs.pixel,
                frames_seen: 0,
                last_seen_frame: frame_id,
            });
            entry.frames_seen += 1;
            entry.last_seen_frame = frame_id;
        }
        self.candidates.retain(|_, c| c.last_seen_frame == frame_id);
        let room = self
            .config
            .max_landmarks
            .saturating_sub(self.landmarks.len());
        if room == 0 {
            return 0;
        }
        // Order: stereo first, then longest track.
        self.ready.clear();
        for (&id, c) in &self.candidates {
            self.ready
                .push((id, self.right_pixels.contains_key(&id), c.frames_seen));
        }
        self.ready
            .sort_unstable_by(|a, b| b.1.cmp(&a.1).then(b.2.cmp(&a.2)).then(a.0.cmp(&b.0)));
        let mut added = 0;
        let ready = std::mem::take(&mut self.ready);
        for &(id, _, _) in &ready {
            if added == room {
                break;
            }
            let Some(pixel) = frame
                .in_camera(0)
                .find(|o| o.landmark == id)
                .map(|o| o.pixel)
            else {
                continue;
            };
            if let Some(new) = self.initialise_landmark(id, &pixel, &nav) {
                self.augment(id, &new, frame_id);
                self.candidates.remove(&id);
                added += 1;
            }
        }
        self.ready = ready;
        added
    }

    /// Triangulates candidate `id` seen at `pixel` in camera 0 now: from
    /// the stereo pair if camera 1 saw it, else from its first sighting.
    fn initialise_landmark(
        &self,
        id: LandmarkId,
        pixel: &Vector2<f64>,
        nav: &NavNominal,
    ) -> Option<NewLandmark> {
        let cam0 = &self.cameras[0];
        let sigma = self.config.pixel_sigma;
        let gate_px = self.config.gate_chi2.sqrt() * sigma;
        let r_wb = nav.rotation();
        let stereo = self.right_pixels.get(&id).and_then(|right| {
            let cam1 = self.cameras.get(1)?;
            // x_c1 = R_c1_c0 x_c0 + t_c1_c0.
            let r_10 = cam1.r_body_cam.transpose() * cam0.r_body_cam;
            let t_10 = cam1
                .r_body_cam
                .tr_mul(&(cam0.t_body_cam_m - cam1.t_body_cam_m));
            let config = TriangulationConfig {
                min_parallax_rad: self.config.min_parallax_stereo_rad,
                min_depth: self.config.min_depth_m,
                max_depth: self.config.max_depth_m,
            };
            triangulate_with_covariance(
                cam0,
                pixel,
                &RelativeView {
                    camera: cam1,
                    r_21: r_10,
                    t_21_m: t_10,
                },
                right,
                &config,
                sigma,
                gate_px,
            )
            .filter(|(q, cov)| {
                let depth = q.norm();
                let u = q / depth;
                u.dot(&(cov * u)).sqrt() <= self.config.max_stereo_depth_sigma_fraction * depth
            })
        });
        let (point_cam, cov_cam) = match stereo {
            Some(found) => found,
            None => {
                let c = self.candidates.get(&id)?;
                let r_world_cam = r_wb * cam0.r_body_cam;
                let p_world_cam = nav.position_world_m + r_wb * cam0.t_body_cam_m;
                // Old view relative to the current one.
                let r_21 = c.r_world_cam.transpose() * r_world_cam;
                let t_21 = c.r_world_cam.tr_mul(&(p_world_cam - c.p_world_cam_m));
                let config = TriangulationConfig {
                    min_parallax_rad: self.config.min_parallax_mono_rad,
                    min_depth: self.config.min_depth_m,
                    max_depth: self.config.max_depth_m,
                };
                // The old camera's centre in the current camera frame.
                let baseline = -r_21.tr_mul(&t_21);
                let ray = cam0.model.unproject(pixel)?;
                let angle = ray.angle(&baseline);
                let min_angle = self.config.min_ray_baseline_angle_rad;
                if !(angle >= min_angle && angle <= std::f64::consts::PI - min_angle) {
                    return None;
                }
                let (q, cov) = triangulate_with_covariance(
                    cam0,
                    pixel,
                    &RelativeView {
                        camera: cam0,
                        r_21,
                        t_21_m: t_21,
                    },
                    &c.first_pixel,
                    &config,
                    sigma,
                    gate_px,
                )?;
                let cov = mono_point_covariance(
                    cam0,
                    &q,
                    &cov,
                    sigma,
                    self.config.mono_init_inflation,
                    self.config.mono_depth_sigma_fraction,
                )?;
                (q, cov)
            }
        };
        let (position_world_m, d_pose) =
            landmark_from_camera_point(&r_wb, &nav.position_world_m, cam0, &point_cam);
        let r_world_cam = r_wb * cam0.r_body_cam;
        Some(NewLandmark {
            position_world_m,
            d_pose,
            measurement_covariance_world: r_world_cam * cov_cam * r_world_cam.transpose(),
        })
    }

    /// Appends a landmark to the state with the augmentation covariance
    /// (see [`init`]).
    fn augment(&mut self, id: LandmarkId, new: &NewLandmark, frame_id: u64) {
        let n = self.covariance.nrows();
        // J P_pose,. (3 x n), pose = the first 6 error states.
        let cross = new.d_pose * self.covariance.fixed_rows::<6>(0);
        let pose_block: SMatrix<f64, 6, 6> = self.covariance.fixed_view::<6, 6>(0, 0).into();
        let p_ll =
            new.d_pose * pose_block * new.d_pose.transpose() + new.measurement_covariance_world;
        self.covariance.resize_mut(n + 3, n + 3, 0.0);
        self.covariance.view_mut((n, 0), (3, n)).copy_from(&cross);
        self.covariance
            .view_mut((0, n), (n, 3))
            .copy_from(&cross.transpose());
        let p_ll = (p_ll + p_ll.transpose()) * 0.5;
        self.covariance
            .fixed_view_mut::<3, 3>(n, n)
            .copy_from(&p_ll);
        self.landmarks.push(StateLandmark {
            id,
            position_world_m: new.position_world_m,
            last_seen_frame: frame_id,
            consecutive_rejections: 0,
        });
    }

    /// The current state (zeros at t = 0 before [`EkfFilter::initialize`]).
    pub fn state(&self) -> KeyframeState {
        match self.nav {
            Some(nav) => nav.to_keyframe(),
            None => KeyframeState {
                t_ns: 0,
                T_world_body: nalgebra::Isometry3::identity(),
                velocity_world_m_s: Vector3::zeros(),
                biases: ImuBiases::default(),
            },
        }
    }

    /// Covariance of the body position in the world, m^2.
    pub fn position_covariance(&self) -> Matrix3<f64> {
        self.covariance.fixed_view::<3, 3>(POS, POS).into()
    }

    /// Covariance of the body's 15 navigation error states, rows and
    /// columns in the order `[dtheta, dp, dv, db_g, db_a]` (3 each):
    /// orientation as a right (body-frame) perturbation
    /// `R = R_hat Exp(dtheta)` in rad, then world position (m), world
    /// velocity (m/s), gyro bias (rad/s) and accel bias (m/s^2).
    pub fn navigation_covariance(&self) -> SMatrix<f64, 15, 15> {
        self.covariance.fixed_view::<15, 15>(0, 0).into()
    }

    /// Landmarks in the state, in the current body frame with 3x3
    /// covariances (for the absolute stage, eq. 41-42). The covariance is
    /// that of `p_b = R^T (l - p)`, so it includes the body pose's
    /// uncertainty and its correlation with the landmark.
    pub fn landmarks_in_body(&self) -> Vec<BodyLandmark> {
        let Some(nav) = self.nav else {
            return Vec::new();
        };
        let r = nav.rotation();
        let prr: SMatrix<f64, 6, 6> = self.covariance.fixed_view::<6, 6>(0, 0).into();
        self.landmarks
            .iter()
            .enumerate()
            .map(|(k, l)| {
                let c = landmark_column(k);
                let p_body = r.tr_mul(&(l.position_world_m - nav.position_world_m));
                let mut j_pose = SMatrix::<f64, 3, 6>::zeros();
                j_pose
                    .fixed_view_mut::<3, 3>(0, 0)
                    .copy_from(&crate::imu::so3::hat(&p_body));
                j_pose
                    .fixed_view_mut::<3, 3>(0, 3)
                    .copy_from(&(-r.transpose()));
                let j_l = r.transpose();
                // Cross block brought up to date with the pending transition.
                let cross15: SMatrix<f64, 15, 3> =
                    self.pending_transition * self.covariance.fixed_view::<15, 3>(0, c);
                let cross: SMatrix<f64, 6, 3> = cross15.fixed_rows::<6>(0).into();
                let pll: Matrix3<f64> = self.covariance.fixed_view::<3, 3>(c, c).into();
                let jc = j_pose * cross * j_l.transpose();
                let cov = j_pose * prr * j_pose.transpose()
                    + jc
                    + jc.transpose()
                    + j_l * pll * j_l.transpose();
                BodyLandmark {
                    id: l.id,
                    position_body_m: p_body,
                    covariance_body_m2: (cov + cov.transpose()) * 0.5,
                    descriptor: None,
                    support: None,
                }
            })
            .collect()
    }

    /// The observations (landmark, camera) the gate refused in the last
    /// [`EkfFilter::update`]: outlier tracks the tracker may drop.
    pub fn last_rejected(&self) -> &[(LandmarkId, u8)] {
        &self.last_rejected
    }

    /// Number of landmarks in the state.
    pub fn landmark_count(&self) -> usize {
        self.landmarks.len()
    }

    /// Back to the state after [`EkfFilter::new`]: not initialised, no
    /// landmarks, no held sample.
    pub fn reset(&mut self) {
        self.nav = None;
        self.landmarks.clear();
        self.candidates.clear();
        self.covariance = DMatrix::zeros(NAV_DIM, NAV_DIM);
        self.pending_transition = Matrix15::identity();
        self.last_sample = None;
    }
}
