//! The window estimator of the relative stage (paper eq. 29-40): L
//! keyframes kept, the newest M optimised by Levenberg-Marquardt, the
//! oldest L-M held fixed.
//!
//! Cost (eq. 29): reprojection error of every observation in the window
//! (sigma `pixel_sigma`, robust kernel, [`reprojection`]) + the inertial
//! residual and the bias random walk between consecutive keyframes from
//! the newest fixed one on ([`inertial`]) + the eq. 34 prior ([`prior`])
//! on gravity and on the velocity (and biases) at the boundary of the free
//! part. The boundary is the newest fixed keyframe: its pose is held, but
//! its velocity and biases are estimated under that prior, so the inertial
//! term that links it to the oldest free keyframe (which carries the scale
//! at a monocular start) does not treat an old velocity estimate as exact.
//! Older fixed keyframes enter through their observations only. The normal equations are solved with the Schur
//! complement on the landmarks ([`schur`]); the LM loop is in
//! [`levenberg_marquardt`]. Frames between keyframes get their pose from
//! the window's landmarks ([`frame_pose`]); new landmarks come from stereo
//! pairs or from two keyframes with parallax ([`new_landmarks`]).
//!
//! Gauge: the fixed keyframes (at least the first one) fix the world
//! frame. In monocular vision-only mode with a single fixed keyframe the
//! distance between the first two keyframes is held (the private `ScaleAnchor` prior),
//! which fixes the scale the initialiser chose (unit first translation);
//! from two fixed keyframes on they fix it. With the IMU the world is
//! gravity-aligned; gravity is a 2-DoF direction state (see [`inertial`])
//! with the eq. 34 prior.

pub mod camera_imu;
mod config;
pub mod frame_pose;
mod held_cameras;
pub mod inertial;
pub mod inertial_link;
mod joined_links;
pub mod landmark_consistency;
pub mod levenberg_marquardt;
mod marginalise;
pub mod new_landmarks;
pub mod noise_adaptation;
pub mod pose_covariance;
pub mod prior;
pub mod propagated_covariance;
pub mod reprojection;
pub mod rig_camera;
pub mod schur;
pub mod state;

#[cfg(test)]
mod synthetic;
#[cfg(test)]
mod tests;

use std::collections::{HashMap, HashSet, VecDeque};

use nalgebra::{DMatrix, Isometry3, Matrix3x2, Matrix6, Vector3};

pub use camera_imu::{CameraImuEstimate, CameraImuRefinementConfig, HeldKeyframesFollow};
pub use config::{WindowConfig, WindowError};
pub use frame_pose::FramePose;
pub use landmark_consistency::LandmarkTest;
pub use levenberg_marquardt::WindowReport;
pub use noise_adaptation::{NoiseAdaptation, NoiseAdaptationConfig, NoiseScale};
pub use reprojection::RobustKernel;

use camera_imu::CameraImuState;
use inertial::{bias_walk_sqrt_info, tangent_basis};
use inertial_link::InertialLink;
use prior::{GravityPrior, OldestFreePrior, ScaleAnchor};
use schur::{LandmarkBlock, NormalEquations, ObservationRow};
use state::{state_is_finite, Keyframe, KeyframeObservation};

use crate::imu::{ImuBiases, Preintegrated, GRAVITY_M_S2};
use crate::relative::types::{BodyLandmark, KeyframeState, LandmarkId, TrackedFrame};
use crate::rig::ImuNoise;
use crate::rig::RigModel;
use rig_camera::RigCamera;

/// The diagonal of `J Sigma J^T` for the `N` rows of a Jacobian read
/// through `j(row, col)`, over `cols`: pairs of a Jacobian column and its
/// row and column in the covariance `cov`.
fn hat_diagonal<const N: usize>(
    j: impl Fn(usize, usize) -> f64,
    cols: &[(usize, usize)],
    cov: &DMatrix<f64>,
) -> [f64; N] {
    let mut diag = [0.0; N];
    for (row, h) in diag.iter_mut().enumerate() {
        for &(a, ka) in cols {
            let ja = j(row, a);
            if ja == 0.0 {
                continue;
            }
            for &(b, kb) in cols {
                *h += ja * cov[(ka, kb)] * j(row, b);
            }
        }
    }
    diag
}

/// A landmark of the window.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Landmark {
    pub position_world_m: Vector3<f64>,
}

/// The first view of a track not yet triangulated.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct PendingTrack {
    pub seq: u64,
    pub obs_index: usize,
}

/// The reusable buffers of one optimisation.
#[derive(Debug, Clone, Default)]
pub(crate) struct Problem {
    pub rows: Vec<ObservationRow>,
    pub landmarks: Vec<LandmarkBlock>,
    pub index: HashMap<LandmarkId, usize>,
    pub counts: Vec<(usize, bool)>,
    pub remap: Vec<usize>,
    pub eq: NormalEquations,
    /// Keyframes `n_fixed..` are free; each has `state_dim` columns.
    pub n_fixed: usize,
    pub state_dim: usize,
    /// Column of the gravity direction (IMU on).
    pub gravity_offset: Option<usize>,
    /// Columns of the newest fixed keyframe's `[v, b_g, b_a]` (IMU on).
    pub boundary_offset: Option<usize>,
    /// Columns of the camera-IMU calibration (IMU on, refinement on).
    pub calib_offset: Option<usize>,
    pub gravity_basis: Matrix3x2<f64>,
    pub stereo_rows: usize,
    pub backup_states: Vec<KeyframeState>,
    pub backup_landmarks: Vec<Vector3<f64>>,
    pub backup_gravity: Vector3<f64>,
    pub backup_calibration: Option<camera_imu::Values>,
    pub backup_velocity_prior: Option<OldestFreePrior>,
    /// `S^-1 Y` of one landmark (body-frame covariances).
    pub z_buffer: DMatrix<f64>,
    /// Linearise with the pixel sigma the published covariance takes
    /// ([`Window::covariance_pixel_scale`]) instead of the estimate's.
    pub covariance_pixels: bool,
}

/// The sliding-window estimator.
#[derive(Debug, Clone)]
pub struct Window {
    config: WindowConfig,
    cameras: Vec<RigCamera>,
    imu_noise: Option<ImuNoise>,
    /// The scale on `imu_noise` the inertial terms are weighted with.
    noise: NoiseAdaptation,
    /// The camera-IMU calibration as refined so far (None: refinement
    /// off); `cameras` hold its current value.
    camera_imu: Option<CameraImuState>,
    /// The angular rate at the frame [`Self::track_frame`] places next.
    frame_omega_body_rad_s: Vector3<f64>,
    /// Sequence number of the keyframe ending the last link measured.
    last_measured_link: Option<u64>,
    /// Sequence number of the newest keyframe of the last solve whose
    /// reprojection errors were measured.
    last_measured_images: Option<u64>,
    use_imu: bool,
    keyframes: VecDeque<Keyframe>,
    next_seq: u64,
    landmarks: HashMap<LandmarkId, Landmark>,
    pending: HashMap<LandmarkId, PendingTrack>,
    /// Tracks whose landmark failed the landmark test, while a keyframe
    /// in the window still sees them: never triangulated again.
    rejected: HashSet<LandmarkId>,
    gravity_dir: Vector3<f64>,
    velocity_prior: Option<OldestFreePrior>,
    /// The next solve's boundary prior forgets the gyroscope bias
    /// ([`CameraImuState::take_release_in_flight`]).
    widen_gyro_bias_next_solve: bool,
    /// Gyroscope bias sigma of the first boundary prior when the states
    /// came with one (the alignment's), rad/s; else the configured sigma.
    start_gyro_bias_sigma_rad_s: Option<f64>,
    /// The next solve holds the oldest keyframe alone
    /// ([`Self::hold_oldest_only_next_solve`]).
    hold_oldest_only_once: bool,
    gravity_prior: GravityPrior,
    scale_anchor: Option<ScaleAnchor>,
    problem: Problem,
    /// Marginal covariance of the free states after the last optimise.
    state_covariance: Option<DMatrix<f64>>,
    /// Stamp and pose of the keyframe the pose covariances are relative
    /// to ([`pose_covariance`]).
    covariance_origin: Option<(i64, Isometry3<f64>)>,
    /// What the pose covariances are carried in ([`propagated_covariance`]).
    joint_covariance: Option<propagated_covariance::JointCovariance>,
    body_landmarks: Vec<BodyLandmark>,
    /// Scratch for the stereo pairing of a new keyframe.
    scratch_pairs: Vec<(LandmarkId, usize)>,
    /// Scratch for the landmarks still seen after a slide.
    scratch_seen: HashSet<LandmarkId>,
    track: frame_pose::TrackBuffers,
}

impl Window {
    /// An empty window; fails when a setting is out of range, the rig has no camera, or `use_imu`
    /// is set and the rig has no IMU.
    pub fn new(config: WindowConfig, rig: &RigModel) -> Result<Self, WindowError> {
        config.validate()?;
        if rig.cameras.is_empty() {
            return Err(WindowError::NoCamera);
        }
        let imu_noise = rig.imu.as_ref().map(|i| i.noise);
        if config.use_imu && imu_noise.is_none() {
            return Err(WindowError::NoImu);
        }
        let down = Vector3::new(0.0, 0.0, -1.0);
        let cameras: Vec<RigCamera> = rig.cameras.iter().cloned().map(RigCamera::new).collect();
        let camera_imu = (config.camera_imu.enabled && imu_noise.is_some())
            .then(|| CameraImuState::new(config.camera_imu, &cameras));
        Ok(Self {
            camera_imu,
            frame_omega_body_rad_s: Vector3::zeros(),
            noise: NoiseAdaptation::new(config.noise_adaptation),
            use_imu: config.use_imu,
            gravity_prior: GravityPrior::isotropic(down, config.gravity_prior_sigma_rad),
            config,
            cameras,
            imu_noise,
            last_measured_link: None,
            last_measured_images: None,
            keyframes: VecDeque::new(),
            next_seq: 0,
            landmarks: HashMap::new(),
            pending: HashMap::new(),
            rejected: HashSet::new(),
            gravity_dir: down,
            velocity_prior: None,
            widen_gyro_bias_next_solve: false,
            start_gyro_bias_sigma_rad_s: None,
            hold_oldest_only_once: false,
            scale_anchor: None,
            problem: Problem {
                gravity_basis: tangent_basis(&down),
                ..Problem::default()
            },
            state_covariance: None,
            covariance_origin: None,
            joint_covariance: None,
            body_landmarks: Vec::new(),
            scratch_pairs: Vec::new(),
            scratch_seen: HashSet::new(),
            track: frame_pose::TrackBuffers::default(),
        })
    }

    /// The settings it was built with.
    pub fn config(&self) -> &WindowConfig {
        &self.config
    }

    /// Adds a keyframe: its initial guess, its observations (distorted
    /// pixels, left and, in stereo, right camera) and the preintegrated
    /// IMU from the previous keyframe (None for the first one or without
    /// IMU). Slides the window (the oldest beyond L leaves with its
    /// observations; landmarks no keyframe sees any more are removed) and
    /// initialises new landmarks. Observations with non-finite pixels or
    /// an unknown camera are skipped.
    pub fn push_keyframe(
        &mut self,
        guess: KeyframeState,
        frame: &TrackedFrame,
        imu: Option<Preintegrated>,
    ) -> Result<(), WindowError> {
        if !state_is_finite(&guess) {
            return Err(WindowError::NonFiniteState { t_ns: guess.t_ns });
        }
        let previous = self.keyframes.back().map(|k| k.state.t_ns);
        if let Some(latest_ns) = previous {
            if guess.t_ns <= latest_ns {
                return Err(WindowError::NotIncreasing {
                    t_ns: guess.t_ns,
                    latest_ns,
                });
            }
        }
        let link = match (imu, previous) {
            (Some(pre), Some(start)) => {
                if pre.t_start_ns != start
                    || pre.t_end_ns != guess.t_ns
                    || !(pre.dt_s.is_finite() && pre.dt_s > 0.0)
                {
                    return Err(WindowError::ImuIntervalMismatch {
                        start_ns: pre.t_start_ns,
                        end_ns: pre.t_end_ns,
                        expected_start_ns: start,
                        expected_end_ns: guess.t_ns,
                    });
                }
                Some(InertialLink::scaled(pre, self.noise.scale()))
            }
            _ => None,
        };
        let bias_walk = match (self.imu_noise, previous) {
            (Some(noise), Some(start)) => Some(bias_walk_sqrt_info(
                &noise,
                (guess.t_ns - start) as f64 * 1e-9,
            )),
            _ => None,
        };
        let n_cameras = self.cameras.len();
        let observations = frame
            .observations
            .iter()
            .filter(|o| {
                (o.camera_index as usize) < n_cameras && o.pixel.iter().all(|v| v.is_finite())
            })
            .map(|o| KeyframeObservation {
                landmark: o.landmark,
                camera: o.camera_index,
                pixel: o.pixel,
                outlier: false,
            })
            .collect();
        let seq = self.next_seq;
        self.next_seq += 1;
        self.keyframes.push_back(Keyframe {
            seq,
            state: guess,
            observations,
            imu: link,
            bias_walk_sqrt_info: bias_walk,
            state_marginal: None,
            pose_marginal: None,
            pose_covariance: None,
            omega_body_rad_s: Vector3::zeros(),
        });
        if self.keyframes.len() == 1 {
            self.restart_covariance_chain();
        }
        if self.keyframes.len() > self.config.keyframes_kept {
            self.keyframes.pop_front();
            self.forget_unobserved();
        }
        if self.keyframes.len() == 2 && self.scale_anchor.is_none() {
            let p0 = self.keyframes[0].state.T_world_body.translation.vector;
            let p1 = self.keyframes[1].state.T_world_body.translation.vector;
            let distance = (p1 - p0).norm();
            if distance.is_finite() && distance > 0.0 {
                self.scale_anchor = Some(ScaleAnchor {
                    seq_first: self.keyframes[0].seq,
                    seq_second: self.keyframes[1].seq,
                    distance,
                });
            }
        }
        self.initialise_landmarks();
        self.state_covariance = None;
        self.body_landmarks.clear();
        Ok(())
    }

    /// Drops the landmarks, refused tracks and pending tracks no keyframe
    /// in the window sees.
    fn forget_unobserved(&mut self) {
        let oldest = self.keyframes.front().map_or(u64::MAX, |k| k.seq);
        self.pending.retain(|_, p| p.seq >= oldest);
        self.scratch_seen.clear();
        for kf in &self.keyframes {
            for o in &kf.observations {
                let id = o.landmark;
                if self.landmarks.contains_key(&id) || self.rejected.contains(&id) {
                    self.scratch_seen.insert(id);
                }
            }
        }
        let seen = &self.scratch_seen;
        self.landmarks.retain(|id, _| seen.contains(id));
        self.rejected.retain(|id| seen.contains(id));
    }

    /// Number of keyframes held fixed now: the oldest L-M, and at least
    /// the first one.
    pub fn fixed_count(&self) -> usize {
        let n = self.keyframes.len();
        n.saturating_sub(self.config.keyframes_free).max(1).min(n)
    }

    /// The newest keyframe's state, if any.
    pub fn latest(&self) -> Option<&KeyframeState> {
        self.keyframes.back().map(|k| &k.state)
    }

    /// The keyframes' states, oldest first.
    pub fn keyframes(&self) -> impl ExactSizeIterator<Item = &KeyframeState> + '_ {
        self.keyframes.iter().map(|k| &k.state)
    }

    /// The newest keyframe and the covariance of its `[dphi, dp]`
    /// relative to [`Self::covariance_origin`] (see [`pose_covariance`]);
    /// None before a solve placed it.
    pub fn newest_pose_covariance(&self) -> Option<(&KeyframeState, Matrix6<f64>)> {
        let kf = self.keyframes.back()?;
        Some((&kf.state, kf.pose_covariance?))
    }

    /// Stamp and pose of the keyframe the pose covariances are relative
    /// to: the oldest one when the window started or was last moved as a
    /// whole (handover, new states).
    pub fn covariance_origin(&self) -> Option<(i64, Isometry3<f64>)> {
        self.covariance_origin
    }

    /// Continues a trajectory: the oldest keyframe's pose covariance is
    /// `covariance` (window convention) relative to `origin` (stamp and
    /// pose), instead of being the origin itself. For a window started
    /// from a state the previous one handed on (after a rest, or carried
    /// by the IMU through a loss).
    pub fn continue_covariance_chain(
        &mut self,
        origin: (i64, Isometry3<f64>),
        covariance: Matrix6<f64>,
    ) {
        if let Some(kf) = self.keyframes.front_mut() {
            kf.pose_covariance = Some(covariance);
            self.covariance_origin = Some(origin);
        }
    }

    /// Makes the oldest keyframe the origin of the pose covariances.
    fn restart_covariance_chain(&mut self) {
        for kf in self.keyframes.iter_mut() {
            kf.pose_marginal = None;
            kf.pose_covariance = None;
        }
        self.covariance_origin = self.keyframes.front_mut().map(|kf| {
            kf.pose_covariance = Some(Matrix6::zeros());
            (kf.state.t_ns, kf.state.T_world_body)
        });
        self.joint_covariance = self.keyframes.front().map(|kf| {
            propagated_covariance::JointCovariance::single(
                propagated_covariance::Block::Pose(kf.seq),
                DMatrix::zeros(6, 6),
            )
        });
    }

    /// Carries the pose covariances to the keyframes after a solve: fixed
    /// ones that have none from the one before them, every free one from
    /// the boundary and its marginal ([`pose_covariance`]); the free ones
    /// are then replaced by the propagated covariance when the solve's
    /// inverse exists ([`propagated_covariance`]).
    fn update_pose_covariances(&mut self, n_fixed: usize) {
        // A marginal given the held keyframes is too confident (they are
        // not exact): the same scale as for the boundary prior.
        let scale =
            self.config.boundary_pose_covariance_scale * self.vision_only_covariance_factor();
        let kfs = &mut self.keyframes;
        for i in 1..n_fixed.min(kfs.len()) {
            if kfs[i].pose_covariance.is_none() {
                let given = kfs[i].pose_marginal.unwrap_or_else(Matrix6::zeros) * scale;
                kfs[i].pose_covariance = kfs[i - 1].pose_covariance.map(|c| {
                    pose_covariance::compose(
                        &kfs[i - 1].state.T_world_body,
                        &c,
                        &kfs[i].state.T_world_body,
                        &given,
                    )
                });
            }
        }
        let Some(b) = n_fixed.checked_sub(1).filter(|&b| b < kfs.len()) else {
            return;
        };
        let (boundary, covariance) = (kfs[b].state.T_world_body, kfs[b].pose_covariance);
        for kf in kfs.iter_mut().skip(n_fixed) {
            kf.pose_covariance = covariance.zip(kf.pose_marginal).map(|(c, m)| {
                pose_covariance::compose(&boundary, &c, &kf.state.T_world_body, &(m * scale))
            });
        }
    }

    /// Keyframes in the window.
    pub fn keyframe_count(&self) -> usize {
        self.keyframes.len()
    }

    /// Gravity in the world frame as the window estimates it, m/s^2 (9.81 m/s^2 along the estimated
    /// direction).
    pub fn gravity_world_m_s2(&self) -> Vector3<f64> {
        self.gravity_dir * GRAVITY_M_S2
    }

    /// Sets gravity (its direction; the magnitude is 9.81) with a prior of
    /// `sigma_rad` around it.
    pub fn set_gravity(
        &mut self,
        gravity_world_m_s2: Vector3<f64>,
        sigma_rad: f64,
    ) -> Result<(), WindowError> {
        let n = gravity_world_m_s2.norm();
        if !(n.is_finite() && n > 0.0 && sigma_rad.is_finite() && sigma_rad > 0.0) {
            return Err(WindowError::InvalidValue {
                what: "gravity or its sigma",
            });
        }
        self.gravity_dir = gravity_world_m_s2 / n;
        self.gravity_prior = GravityPrior::isotropic(self.gravity_dir, sigma_rad);
        if let Some(j) = self.joint_covariance.as_mut() {
            j.remove(propagated_covariance::Block::Gravity);
        }
        self.state_covariance = None;
        Ok(())
    }

    /// The next solve holds the oldest keyframe alone (the gauge) instead
    /// of the usual count, once: after states that came from elsewhere
    /// (the visual-inertial alignment of a vision-only start), whose
    /// attitudes carry the images' drift; held keyframes would keep their
    /// errors and push them into the biases the solve estimates.
    pub fn hold_oldest_only_next_solve(&mut self) {
        self.hold_oldest_only_once = true;
    }

    /// Replaces the keyframes' states (same count and order as
    /// [`Self::keyframes`]).
    pub fn set_states(&mut self, states: &[KeyframeState]) -> Result<(), WindowError> {
        if states.len() != self.keyframes.len() {
            return Err(WindowError::LengthMismatch {
                what: "states",
                got: states.len(),
                expected: self.keyframes.len(),
            });
        }
        if !states.iter().all(state_is_finite) {
            return Err(WindowError::InvalidValue { what: "states" });
        }
        for (kf, s) in self.keyframes.iter_mut().zip(states) {
            kf.state = *s;
            kf.state_marginal = None;
        }
        self.restart_covariance_chain();
        self.velocity_prior = None;
        self.widen_gyro_bias_next_solve = false;
        self.start_gyro_bias_sigma_rad_s = None;
        Ok(())
    }

    /// The window starts in flight (a visual-inertial alignment in
    /// motion): see [`HeldKeyframesFollow::InFlight`].
    pub fn start_in_motion(&mut self) {
        if let Some(c) = self.camera_imu.as_mut() {
            c.start_in_motion();
        }
    }

    /// The gyroscope bias sigma of the boundary prior until a solve gives
    /// its marginal (after [`Self::set_states`]; the configured
    /// `gyro_bias_prior_sigma_rad_s` otherwise), rad/s: what the states'
    /// source knows of the bias (the visual-inertial alignment's sigma).
    /// Kept within [1e-4, the configured sigma]; not finite: ignored.
    pub fn set_start_gyro_bias_sigma(&mut self, sigma_rad_s: f64) {
        self.start_gyro_bias_sigma_rad_s = sigma_rad_s
            .is_finite()
            .then(|| sigma_rad_s.clamp(1e-4, self.config.gyro_bias_prior_sigma_rad_s.max(1e-4)));
    }

    /// Sets every keyframe's velocity and biases (the visual-inertial
    /// alignment's answer), oldest first; the velocity prior restarts at
    /// `velocity_prior_sigma_m_s`.
    pub fn set_velocities_and_biases(
        &mut self,
        velocities_world_m_s: &[Vector3<f64>],
        biases: &[ImuBiases],
    ) -> Result<(), WindowError> {
        let n = self.keyframes.len();
        for (what, got) in [
            ("velocities", velocities_world_m_s.len()),
            ("biases", biases.len()),
        ] {
            if got != n {
                return Err(WindowError::LengthMismatch {
                    what,
                    got,
                    expected: n,
                });
            }
        }
        let finite = velocities_world_m_s
            .iter()
            .all(|v| v.iter().all(|x| x.is_finite()))
            && biases.iter().all(|b| {
                b.gyro_rad_s
                    .iter()
                    .chain(b.accel_m_s2.iter())
                    .all(|x| x.is_finite())
            });
        if !finite {
            return Err(WindowError::InvalidValue {
                what: "velocities or biases",
            });
        }
        for ((kf, v), b) in self
            .keyframes
            .iter_mut()
            .zip(velocities_world_m_s)
            .zip(biases)
        {
            kf.state.velocity_world_m_s = *v;
            kf.state.biases = *b;
            kf.state_marginal = None;
        }
        self.velocity_prior = None;
        self.widen_gyro_bias_next_solve = false;
        Ok(())
    }

    /// Maps everything (keyframes, landmarks, gravity, priors) by
    /// `x_new = T_new_old (scale x_old)`: how the initialiser hands over
    /// a metric, gravity-aligned frame. Velocities scale and rotate.
    ///
    /// What scales is what the images determine: landmarks and the centres
    /// of camera 0. Each body is then placed at its camera's centre minus
    /// the (metric) body-camera offset, so a vision-only solution at an
    /// arbitrary scale stays consistent with its images after the
    /// handover; scaling body positions instead would misplace every
    /// camera by `(1 - scale) |t_body_cam|`.
    #[allow(non_snake_case)]
    pub fn transform(&mut self, scale: f64, T_new_old: Isometry3<f64>) -> Result<(), WindowError> {
        let finite = T_new_old.translation.vector.iter().all(|v| v.is_finite())
            && T_new_old.rotation.coords.iter().all(|v| v.is_finite());
        if !(scale.is_finite() && scale > 0.0 && finite) {
            return Err(WindowError::InvalidValue {
                what: "scale or transform",
            });
        }
        let rot = T_new_old.rotation;
        let map_point = |p: &Vector3<f64>| T_new_old.transform_point(&(p * scale).into()).coords;
        let t_bc = self.cameras[0].calibration.T_body_cam.translation.vector;
        for kf in self.keyframes.iter_mut() {
            let s = &mut kf.state;
            let centre = s.T_world_body.translation.vector + s.T_world_body.rotation * t_bc;
            s.T_world_body.rotation = rot * s.T_world_body.rotation;
            s.T_world_body.translation.vector = map_point(&centre) - s.T_world_body.rotation * t_bc;
            s.velocity_world_m_s = rot * (s.velocity_world_m_s * scale);
            kf.state_marginal = None;
        }
        for lm in self.landmarks.values_mut() {
            lm.position_world_m = map_point(&lm.position_world_m);
        }
        self.gravity_dir = rot * self.gravity_dir;
        let g = self.gravity_prior;
        self.gravity_prior = GravityPrior {
            mean_dir: rot * g.mean_dir,
            basis: rot.to_rotation_matrix().into_inner() * g.basis,
            sqrt_info: g.sqrt_info,
        };
        self.velocity_prior = None;
        self.widen_gyro_bias_next_solve = false;
        if let Some(a) = self.scale_anchor.as_mut() {
            a.distance *= scale;
        }
        self.restart_covariance_chain();
        self.state_covariance = None;
        self.body_landmarks.clear();
        Ok(())
    }

    /// Replaces the preintegrated IMU that ends at keyframe `t_end_ns`
    /// (e.g. integrated again with the biases the initialiser found); it
    /// must start at the previous keyframe.
    pub fn set_preintegrated(&mut self, pre: Preintegrated) -> Result<(), WindowError> {
        let pos = self
            .keyframes
            .iter()
            .position(|k| k.state.t_ns == pre.t_end_ns)
            .filter(|&p| p > 0);
        let Some(pos) = pos else {
            return Err(WindowError::ImuIntervalMismatch {
                start_ns: pre.t_start_ns,
                end_ns: pre.t_end_ns,
                expected_start_ns: self.keyframes.front().map_or(0, |k| k.state.t_ns),
                expected_end_ns: self.keyframes.back().map_or(0, |k| k.state.t_ns),
            });
        };
        let start = self.keyframes[pos - 1].state.t_ns;
        if pre.t_start_ns != start || !(pre.dt_s.is_finite() && pre.dt_s > 0.0) {
            return Err(WindowError::ImuIntervalMismatch {
                start_ns: pre.t_start_ns,
                end_ns: pre.t_end_ns,
                expected_start_ns: start,
                expected_end_ns: pre.t_end_ns,
            });
        }
        self.keyframes[pos].imu = Some(InertialLink::scaled(pre, self.noise.scale()));
        Ok(())
    }

    /// Switches the inertial terms on or off (needs an IMU in the rig).
    /// Preintegrated intervals given to [`Self::push_keyframe`] are kept
    /// while it is off, so switching on after a vision-only start uses them.
    pub fn enable_imu(&mut self, on: bool) -> Result<(), WindowError> {
        if on && self.imu_noise.is_none() {
            return Err(WindowError::NoImu);
        }
        self.use_imu = on;
        self.velocity_prior = None;
        self.widen_gyro_bias_next_solve = false;
        self.state_covariance = None;
        Ok(())
    }

    /// The scale on the declared IMU noise the inertial terms are
    /// weighted with now, and the adaptation behind it.
    pub fn noise_adaptation(&self) -> &NoiseAdaptation {
        &self.noise
    }

    /// The newest keyframe's angular rate in the body frame (gyroscope
    /// less bias), for the time offset's Jacobian ([`camera_imu`]); zero
    /// until set.
    pub fn set_newest_angular_rate(&mut self, omega_body_rad_s: Vector3<f64>) {
        if let Some(kf) = self.keyframes.back_mut() {
            if omega_body_rad_s.iter().all(|v| v.is_finite()) {
                kf.omega_body_rad_s = omega_body_rad_s;
            }
        }
    }

    /// The angular rate at the frame [`Self::track_frame`] places next,
    /// as [`Self::set_newest_angular_rate`] for keyframes.
    pub fn set_frame_angular_rate(&mut self, omega_body_rad_s: Vector3<f64>) {
        self.frame_omega_body_rad_s = if omega_body_rad_s.iter().all(|v| v.is_finite()) {
            omega_body_rad_s
        } else {
            Vector3::zeros()
        };
    }

    /// The largest one-sigma of the accelerometer bias of the newest
    /// keyframe an inertial solve has estimated, m/s^2 (None before one).
    pub fn newest_accel_bias_sigma_m_s2(&self) -> Option<f64> {
        let m = self.keyframes.iter().rev().find_map(|k| k.state_marginal)?;
        Some(
            (12..15)
                .map(|i| m[(i, i)].max(0.0).sqrt())
                .fold(0.0, f64::max),
        )
    }

    /// The camera-IMU calibration as the window holds it now (None when
    /// its refinement is off).
    pub fn camera_imu(&self) -> Option<CameraImuEstimate> {
        self.camera_imu.as_ref().map(|c| c.estimate())
    }

    /// Continues from an earlier window's camera-IMU estimate (a new
    /// window after a loss of tracking).
    pub fn keep_camera_imu_from(&mut self, other: &Window) {
        if let (Some(mine), Some(theirs)) = (self.camera_imu.as_mut(), other.camera_imu.as_ref()) {
            if mine.T_cam0_cam.len() == theirs.T_cam0_cam.len() {
                *mine = theirs.clone();
                mine.place(&mut self.cameras);
            }
        }
    }

    /// Numbers keyframes on from an earlier window's (a new window after a
    /// loss of tracking), so that keyframe numbers keep increasing across
    /// windows ([`crate::relative::types::WindowSupport`]).
    pub fn continue_numbering_from(&mut self, other: &Window) {
        self.next_seq = self.next_seq.max(other.next_seq);
    }

    /// Continues from an earlier window's estimate of the IMU's noise (a
    /// new window after a loss of tracking).
    pub fn keep_noise_adaptation(&mut self, noise: NoiseAdaptation) {
        self.noise = noise;
        let scale = self.noise.scale();
        for kf in self.keyframes.iter_mut() {
            if let Some(link) = kf.imu.as_mut() {
                link.rescale(scale);
            }
        }
    }

    /// Feeds the noise adaptation ([`noise_adaptation`]) with the last
    /// solve's reprojection errors and its oldest inertial link, and
    /// re-weights every link with the answer.
    pub(super) fn measure_noise(&mut self) {
        if !self.noise.config().enabled {
            return;
        }
        self.measure_image_noise();
        if self.use_imu {
            self.measure_inertial_noise();
        }
    }

    /// The pixel sigma (on the declared one) the published covariance
    /// of an inertial mode is computed with: `max(gain * estimate,
    /// floor)` (`covariance_pixel_gain`, `covariance_pixel_floor`). The
    /// estimate comes from the residuals' redundancy, which shows only
    /// the white part of a feature's error: what is slow along a track
    /// moves its landmark and not its residuals, and reaches the poses
    /// all the same. The floor stands for that part: the estimate may
    /// raise the sigma (images noisier than declared) but not take it
    /// below the floor. Keyframes no inertial link reaches (a stereo
    /// start in flight's first ones) take `gain * estimate` without the
    /// floor (`linearize`).
    pub(super) fn covariance_pixel_scale(&self) -> f64 {
        (self.config.covariance_pixel_gain * self.noise.scale().pixel)
            .max(self.config.covariance_pixel_floor)
    }

    /// What a marginal of the last solve is multiplied by to be in the
    /// pixel noise the features show. With the IMU the solve is already
    /// whitened with it (1); without, the solve keeps the declared pixel
    /// sigma (with only images and the gauge in the cost, a common scale
    /// on every term moves no estimate, and leaving it out keeps the
    /// vision-only trajectories exactly as they were) and only the
    /// published covariance takes the estimate: `(pixel scale)^2`.
    pub(super) fn vision_only_covariance_factor(&self) -> f64 {
        if self.use_imu {
            1.0
        } else {
            let s = self.noise.scale().pixel;
            s * s
        }
    }

    /// The reprojection errors of the last solve's inliers against their
    /// redundancy (two per observation less three per landmark and six
    /// per free keyframe), once per newest keyframe.
    fn measure_image_noise(&mut self) {
        let p = &self.problem;
        let Some(newest) = self.keyframes.back() else {
            return;
        };
        if self.last_measured_images == Some(newest.seq) {
            return;
        }
        let gate = self.config.outlier_chi2;
        let (mut chi2, mut rows, mut landmarks) = (0.0, 0usize, 0usize);
        for lm in &p.landmarks {
            let (seen, sum) = p.rows[lm.rows.clone()]
                .iter()
                .filter(|r| r.valid && r.sq_error <= gate)
                .fold((0usize, 0.0), |(n, sum), r| {
                    (n + 1, sum + r.residual.norm_squared())
                });
            // A single observation of a landmark says nothing.
            if seen >= 2 {
                chi2 += sum;
                rows += seen;
                landmarks += 1;
            }
        }
        let free = self.keyframes.len().saturating_sub(p.n_fixed);
        let redundancy = 2.0 * rows as f64 - 3.0 * landmarks as f64 - 6.0 * free as f64;
        let dt_s = match self.keyframes.len() {
            n if n >= 2 => (newest.state.t_ns - self.keyframes[n - 2].state.t_ns) as f64 * 1e-9,
            _ => return,
        };
        self.last_measured_images = Some(newest.seq);
        // `add_images` takes errors whitened with the current estimate;
        // without the IMU the solve whitened them with the declared sigma.
        let chi2 = if self.use_imu {
            chi2
        } else {
            chi2 / self.noise.scale().pixel.powi(2)
        };
        self.noise.add_images(chi2, redundancy, dt_s);
    }

    /// Measures the inertial link the last solve saw longest (from the
    /// boundary to the oldest free keyframe) once.
    fn measure_inertial_noise(&mut self) {
        let p = &self.problem;
        let (Some(cov), Some(og), Some(ob)) = (
            self.state_covariance.as_ref(),
            p.gravity_offset,
            p.boundary_offset,
        ) else {
            return;
        };
        let nf = p.n_fixed;
        if !self.use_imu || nf == 0 || nf >= self.keyframes.len() {
            return;
        }
        let (ki, kj) = (&self.keyframes[nf - 1], &self.keyframes[nf]);
        if self.last_measured_link == Some(kj.seq) {
            return;
        }
        let Some(link) = kj.imu.as_ref() else {
            return;
        };
        let (r, j) = inertial::inertial_factor(
            link,
            &ki.state,
            &kj.state,
            &self.gravity_dir,
            &p.gravity_basis,
        );
        // The link's columns in the solve's covariance (the first link
        // from the boundary).
        let column = |c: usize| joined_links::link_column(p.state_dim, og, ob, 0, c);
        let mut cols: Vec<(usize, usize)> = (0..inertial::INERTIAL_COLS)
            .filter_map(|c| column(c).map(|k| (c, k)))
            .collect();
        // With the held keyframes following the calibration, the link
        // reaches it through the boundary's body state (`held_cameras`):
        // the solve's covariance of the two together is what the link's
        // redundancy needs.
        let calibration = match self.following_link_calibration(&j, ki) {
            Some((columns, oc)) => {
                cols.extend(
                    (0..camera_imu::CALIB_DIM).map(|k| (inertial::INERTIAL_COLS + k, oc + k)),
                );
                columns
            }
            None => nalgebra::SMatrix::zeros(),
        };
        let entry = |r: usize, c: usize| {
            if c < inertial::INERTIAL_COLS {
                j[(r, c)]
            } else {
                calibration[(r, c - inertial::INERTIAL_COLS)]
            }
        };
        // tr(J Sigma J^T) of the rotation rows and of the rest.
        let hat_diag: [f64; 9] = hat_diagonal(entry, &cols, cov);
        // The bias walk between the same keyframes: columns [i: b_g b_a |
        // j: b_g b_a], whitened with the current walk scale.
        let (walk_chi2, walk_redundancy) = match kj.bias_walk_sqrt_info.as_ref() {
            Some(declared) => {
                let sqrt_info = self.noise.scale().walk(declared);
                let (rw, jw) = inertial::bias_walk_factor(&sqrt_info, &ki.state, &kj.state);
                let walk_cols: Vec<(usize, usize)> = (0..12)
                    .filter_map(|c| {
                        let full = if c < 6 {
                            state::BG + c
                        } else {
                            state::FULL_DIM + state::BG + c - 6
                        };
                        column(full).map(|k| (c, k))
                    })
                    .collect();
                let hat: [f64; 6] = hat_diagonal(|r, c| jw[(r, c)], &walk_cols, cov);
                (
                    [
                        rw.fixed_rows::<3>(0).norm_squared(),
                        rw.fixed_rows::<3>(3).norm_squared(),
                    ],
                    [
                        3.0 - hat[..3].iter().sum::<f64>(),
                        3.0 - hat[3..].iter().sum::<f64>(),
                    ],
                )
            }
            None => ([0.0; 2], [0.0; 2]),
        };
        let mut evidence = noise_adaptation::LinkEvidence {
            chi2_rotation: r.fixed_rows::<3>(0).norm_squared(),
            redundancy_rotation: 3.0 - hat_diag[..3].iter().sum::<f64>(),
            chi2_translation: r.fixed_rows::<6>(3).norm_squared(),
            redundancy_translation: 6.0 - hat_diag[3..].iter().sum::<f64>(),
            chi2_gyro_walk: walk_chi2[0],
            redundancy_gyro_walk: walk_redundancy[0],
            chi2_accel_walk: walk_chi2[1],
            redundancy_accel_walk: walk_redundancy[1],
            dt_s: link.pre.dt_s,
        };
        // With more than one link joined, the rotation and translation
        // rows are the joined interval's, counted once per link they
        // span (consecutive measurements overlap by all but one link).
        let wanted = self.noise.config().joined_links;
        if let Some((k, joined)) = (2..=wanted).rev().find_map(|k| {
            self.joined_inertial_evidence(cov, og, ob, k)
                .map(|j| (k, j))
        }) {
            let k = k as f64;
            evidence.chi2_rotation = joined.chi2_rotation / k;
            evidence.redundancy_rotation = joined.redundancy_rotation / k;
            evidence.chi2_translation = joined.chi2_translation / k;
            evidence.redundancy_translation = joined.redundancy_translation / k;
        }
        self.last_measured_link = Some(kj.seq);
        let before = self.noise.scale();
        let after = self.noise.add(&evidence);
        tracing::trace!(
            t_s = kj.state.t_ns as f64 * 1e-9,
            gyro = after.gyro,
            accel = after.accel,
            chi2_rotation = evidence.chi2_rotation,
            redundancy_rotation = evidence.redundancy_rotation,
            chi2_translation = evidence.chi2_translation,
            redundancy_translation = evidence.redundancy_translation,
            "IMU noise scale"
        );
        if after != before {
            for kf in self.keyframes.iter_mut() {
                if let Some(link) = kf.imu.as_mut() {
                    link.rescale(after);
                }
            }
        }
    }

    /// Whether the inertial terms are on.
    pub fn imu_enabled(&self) -> bool {
        self.use_imu
    }

    /// Position of a landmark in the world frame (window units, m when metric), if the window holds
    /// it.
    pub fn landmark_world(&self, id: LandmarkId) -> Option<Vector3<f64>> {
        self.landmarks.get(&id).map(|l| l.position_world_m)
    }

    /// Landmarks in the window.
    pub fn landmark_count(&self) -> usize {
        self.landmarks.len()
    }

    /// Tracks seen once and waiting for a second view to triangulate.
    pub fn pending_count(&self) -> usize {
        self.pending.len()
    }

    /// Landmarks seen (as inliers) in the newest keyframe, in its body
    /// frame, with the 3x3 covariance of that body-frame position, as of
    /// the last [`Self::optimize`] (empty before one, and after a push).
    ///
    /// The covariance is the exact linearised marginal: the landmark's
    /// marginal `V^-1 + V^-1 W^T S^-1 W V^-1` (S the reduced system), its
    /// cross-covariance with the newest keyframe's pose, and that pose's
    /// marginal, propagated through `p_body = R^T (p_world - p)`;
    /// relative to the fixed keyframes. If the reduced system could not
    /// be inverted it falls back to `V^-1` (the landmark given the poses).
    pub fn landmarks_in_body(&self) -> &[BodyLandmark] {
        &self.body_landmarks
    }

    /// [`Self::landmarks_in_body`] moved into the body frame of a frame
    /// at `T_world_frame` (e.g. from [`Self::track_frame`]): positions
    /// mapped through the newest keyframe's pose, covariances rotated. The
    /// uncertainty of the frame relative to that keyframe is not added.
    #[allow(non_snake_case)]
    pub fn landmarks_in_frame_into(
        &self,
        T_world_frame: &Isometry3<f64>,
        out: &mut Vec<BodyLandmark>,
    ) {
        out.clear();
        let Some(newest) = self.keyframes.back() else {
            return;
        };
        let T_frame_key = T_world_frame.inverse() * newest.state.T_world_body;
        let r = T_frame_key.rotation.to_rotation_matrix().into_inner();
        out.extend(self.body_landmarks.iter().map(|l| {
            BodyLandmark {
                id: l.id,
                position_body_m: T_frame_key
                    .transform_point(&l.position_body_m.into())
                    .coords,
                covariance_body_m2: r * l.covariance_body_m2 * r.transpose(),
                descriptor: l.descriptor,
                support: l.support,
            }
        }));
    }

    /// Marginal covariance of the free states (15 per free keyframe,
    /// oldest free first, then gravity's 2) after the last optimisation.
    pub fn state_covariance(&self) -> Option<&DMatrix<f64>> {
        self.state_covariance.as_ref()
    }
}
