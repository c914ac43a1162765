//! Online refinement of the camera-IMU calibration: the window estimates
//! camera 0's pose in the body (IMU) frame and the time offset between the
//! frames and the IMU, starting from the calibration file.
//!
//! Unknowns (10, after the other states in the reduced system):
//! `[dphi_c, dt_c, d td, dpsi_s]` with `R_bc0 <- R_bc0 Exp(dphi_c)`,
//! `t_bc0 <- t_bc0 + dt_c`, `td <- td + d td`, and camera 1's rotation in
//! camera 0 `R_c0c1 <- R_c0c1 Exp(dpsi_s)`. The other cameras keep their
//! pose in camera 0 (`T_body_cami = T_body_cam0 T_cam0_cami`), and the
//! baseline stays the stereo calibration's (it sets the scale). The stereo
//! rotation is refined because a few hundredths of a degree of it, a
//! fraction of a pixel of disparity, bias every stereo depth; without a
//! second camera `dpsi_s` is held at zero by its prior.
//!
//! Time offset: `td` is what the frames lag behind the IMU clock beyond
//! the file's `timeshift_cam_imu` (already applied to the stamps by
//! [`crate::relative::camera_clock`]): an image stamped `t` was taken at
//! IMU time `t + td`. The body pose then is, to first order in `td`,
//! `R' = R Exp(omega td)`, `p' = p + v td` with `omega` the body's angular
//! rate (gyroscope less bias at the keyframe) and `v` its velocity. The
//! projection goes through that pose:
//! `p_b = R'^T (p_w - p')`, `d p_b / d td = -[omega]x p_b - R'^T v`.
//! The pose Jacobian follows `R' = R Exp(dphi) Exp(omega td)
//! = R Exp(omega td) Exp(Exp(-omega td) dphi)`. The term in the velocity
//! (`-R'^T td`, a few milliseconds times the body Jacobian) is left out:
//! it would tie every observation to its keyframe's velocity columns and
//! moves the step by far less than the noise.
//!
//! Priors: the file's values with the configured sigmas (what a
//! calibration is trusted to), and the estimate of earlier windows: after
//! each solve the marginal information of the block, less the file's
//! (counted once), times `carry_weight` is kept as a prior centred on the
//! estimate. Like gravity, the calibration is a constant of the run, so its
//! information may accumulate, to about `w / (1 - w)` windows' worth.
//!
//! Observability needs motion: rotation about at least two axes for the
//! extrinsic rotation and translation, and angular or linear velocity for
//! the time offset. At rest nothing moves the estimate away from its
//! priors.
//!
//! Held until the data say the file is wrong (`hold_until_tested`, on by
//! default): a correct file refined from the first solve swings by up to
//! 1.6 deg in the first seconds, while the window's attitude, gravity and
//! biases are still settling and trade against it, and the carried prior
//! keeps part of the swing; that cost a correct file 7-12 % of its ATE.
//! So the block starts held at the file by a prior [`HOLD_FACTOR`] times
//! tighter than the configured sigmas, and each solve tests the file
//! against its own data (a score test: [`score_test`]). The data's
//! information on the block is the solve's, less the held prior's; the
//! data's gradient at the file is the solve's information times the small
//! step the held block still took. Their statistic `g^T Lambda^-1 g` is
//! chi-square with as many degrees of freedom as the data see directions
//! when the file is right. Once it exceeds the 99.9 % quantile on
//! [`TEST_SOLVES`] solves in a row, the block is released to the
//! configured sigmas and refined from then on, for good. A wrong file
//! shows in the first solves of motion, before the window's other states
//! have bent towards it; a correct one is held through the first solves,
//! in which it would have swung, and released later if at all (on the
//! consistent-IMU renderings from rest: at solves 8-63, or never). Images
//! rendered along a recorded truth that the real IMU disagrees with fail
//! the test within five solves, as a wrong file would. A correct file's
//! early excess is in the stereo rotation's directions, and weighing the
//! test at the declared pixel sigma or at a stricter level trades it
//! against a small wrong stereo rotation or the real IMU's gain
//! (docs/results/camera-imu-score-variance-2026-12-05.md).
//!
//! After a start in flight the hold is short (a wrong file is released
//! within the first solves), but the visual-inertial alignment has read
//! the gyroscope through the file's rotation: the gyroscope bias took the
//! file's error, and the window's boundary prior holds it about as tight
//! as the alignment found it, which keeps a wrong rotation 0.2-0.3 deg
//! short of the truth. With `release_frees_gyro_bias` (off by default)
//! the window forgets that bias at the release
//! ([`CameraImuState::take_release_in_flight`];
//! docs/results/camera-imu-bias-release-2026-12-07.md).

use nalgebra::{
    Isometry3, Matrix3, SMatrix, SVector, Translation3, UnitQuaternion, Vector2, Vector3,
};

use super::reprojection::{reproject, reprojection_error, Reprojection};
use super::rig_camera::RigCamera;
use crate::imu::so3::{exp, hat, log, right_jacobian_inverse};

/// Unknowns of the calibration block.
pub const CALIB_DIM: usize = 10;
/// Where each part starts in it.
pub const CALIB_ROT: usize = 0;
/// Offset of `dt_c`, camera 0's translation in the body frame (3).
pub const CALIB_POS: usize = 3;
/// Offset of `d td`, the time offset (1).
pub const CALIB_TIME: usize = 6;
/// Offset of `dpsi_s`, camera 1's rotation in camera 0 (3).
pub const CALIB_STEREO: usize = 7;
/// Jacobian of a pixel error with respect to the calibration block.
pub type Matrix2xCalib = SMatrix<f64, 2, CALIB_DIM>;
/// Square matrix over the calibration block (information, covariance).
pub type MatrixCalib = SMatrix<f64, CALIB_DIM, CALIB_DIM>;
/// A vector over the calibration block (step, gradient).
pub type VectorCalib = SVector<f64, CALIB_DIM>;
/// Cross block between the calibration and a landmark's 3 coordinates.
pub type MatrixCalibx3 = SMatrix<f64, CALIB_DIM, 3>;

/// Settings (defaults in brackets).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CameraImuRefinementConfig {
    /// Estimate the calibration in the window's inertial solves [false;
    /// the relative stage's `camera_imu_refinement` decides per mode].
    pub enabled: bool,
    /// How far the file may be off, 1 sigma: rotation deg \[2\],
    /// translation m [0.0005: held, see the relative stage's
    /// `camera_imu_translation_sigma_m`], time offset s [0.01].
    pub rotation_sigma_deg: f64,
    /// How far the file's camera 0 translation may be off, 1 sigma, m.
    pub translation_sigma_m: f64,
    /// How far the frames' time offset beyond the file's time shift may be off, 1 sigma, s.
    pub time_offset_sigma_s: f64,
    /// How far the stereo calibration's rotation between the cameras may
    /// be off, 1 sigma, deg [0.2].
    pub stereo_rotation_sigma_deg: f64,
    /// Share of the last solve's information carried to the next [0.9].
    pub carry_weight: f64,
    /// Hold the block at the file until a score test of the solve's data
    /// shows the file wrong (module doc) [true]; false refines from the
    /// first solve.
    pub hold_until_tested: bool,
    /// When the test releases the block after a start in flight, the
    /// window's boundary prior forgets the gyroscope bias down to its
    /// configured sigma ([`CameraImuState::take_release_in_flight`])
    /// [false].
    pub release_frees_gyro_bias: bool,
    /// When held keyframes keep their cameras and their body states
    /// follow the calibration ([`super::held_cameras`]) [after a start in
    /// flight]; otherwise their body states are held, which ties the
    /// calibration to the value they were held at.
    pub held_keyframes_follow: HeldKeyframesFollow,
    /// The estimate is reported as far from the file (status warning)
    /// beyond: rotation deg [0.5], translation m [0.01], time offset s
    /// [0.003]; a Kalibr calibration of a rigid rig is good to a tenth of
    /// that.
    pub warn_rotation_deg: f64,
    /// Translation from the file beyond which the estimate is reported as far, m.
    pub warn_translation_m: f64,
    /// Time offset beyond which the estimate is reported as far, s.
    pub warn_time_offset_s: f64,
}

impl Default for CameraImuRefinementConfig {
    fn default() -> Self {
        Self {
            enabled: false,
            rotation_sigma_deg: 2.0,
            translation_sigma_m: 0.0005,
            time_offset_sigma_s: 0.01,
            stereo_rotation_sigma_deg: 0.2,
            carry_weight: 0.9,
            hold_until_tested: true,
            release_frees_gyro_bias: false,
            held_keyframes_follow: HeldKeyframesFollow::InFlight,
            warn_rotation_deg: 0.5,
            warn_translation_m: 0.01,
            warn_time_offset_s: 0.003,
        }
    }
}

impl CameraImuRefinementConfig {
    /// Checks that every sigma and warning distance is positive and finite and `carry_weight` is in
    /// [0, 1); the message names the key.
    pub fn validate(&self) -> Result<(), String> {
        for (key, v) in [
            ("camera_imu_rotation_sigma_deg", self.rotation_sigma_deg),
            ("camera_imu_translation_sigma_m", self.translation_sigma_m),
            ("camera_imu_time_offset_sigma_s", self.time_offset_sigma_s),
            (
                "camera_imu_stereo_rotation_sigma_deg",
                self.stereo_rotation_sigma_deg,
            ),
            ("camera_imu_warn_rotation_deg", self.warn_rotation_deg),
            ("camera_imu_warn_translation_m", self.warn_translation_m),
            ("camera_imu_warn_time_offset_s", self.warn_time_offset_s),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Err(format!("{key} must be positive and finite, got {v}"));
            }
        }
        if !(self.carry_weight >= 0.0 && self.carry_weight < 1.0) {
            return Err(format!(
                "camera_imu_carry_weight must be in [0, 1), got {}",
                self.carry_weight
            ));
        }
        Ok(())
    }
}

/// What the window holds the camera-IMU calibration to be now.
#[allow(non_snake_case)]
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CameraImuEstimate {
    /// Camera 0's pose in the body (IMU) frame: maps camera coordinates into the body frame.
    pub T_body_cam0: Isometry3<f64>,
    /// The frames' lag behind the IMU clock beyond the file's time shift,
    /// s (see the module doc).
    pub time_offset_s: f64,
    /// Camera 1's pose in camera 0 (identity without a second camera).
    pub T_cam0_cam1: Isometry3<f64>,
    /// Distance from the file.
    pub rotation_from_file_deg: f64,
    /// Translation distance from the file, m.
    pub translation_from_file_m: f64,
    /// Angle between the stereo rotation refined and the file's, deg.
    pub stereo_rotation_from_file_deg: f64,
    /// One sigma of the last solve (NaN before one).
    pub rotation_sigma_deg: f64,
    /// One sigma of camera 0's translation, m (NaN before a solve).
    pub translation_sigma_m: f64,
    /// One sigma of the time offset, s (NaN before a solve).
    pub time_offset_sigma_s: f64,
    /// Beyond the configured warning distance in any of the three, once
    /// the estimate has settled ([`WARN_AFTER_SOLVES`]), for
    /// [`WARN_PERSIST_SOLVES`] solves in a row.
    pub far_from_file: bool,
    /// Solves the estimate took part in.
    pub solves: u64,
    /// Still held at the file: no solve's data have shown it wrong yet.
    pub held_at_file: bool,
}

/// When the window's held keyframes follow the refined calibration
/// ([`super::held_cameras`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum HeldKeyframesFollow {
    /// After a start in flight (a visual-inertial alignment in motion):
    /// there the held keyframes were fixed with a calibration the data had
    /// not yet tested, and they hold it back. After a start from rest the
    /// block is released within the first solves of motion (the fifth on
    /// a consistent-IMU rendering with a file 1 deg, 10 mm and 5 ms off),
    /// while the held keyframes have hardly turned and tie little, and it
    /// converges without them following.
    InFlight,
    /// Always.
    On,
    /// Never: held keyframes keep their body poses.
    Off,
}

/// How much tighter than the configured sigmas the file's prior holds the
/// block until the test releases it: a thousandth (0.002 deg, 0.01 ms by
/// default), so the held block moves by about a thousandth of what the
/// data ask, which is the gradient the test reads.
pub const HOLD_FACTOR: f64 = 1000.0;

/// Solves in a row whose test must exceed its threshold to release the
/// block. Consecutive solves share most of their data, so this is not
/// three independent tests. On a consistent-IMU rendering (V1_02 seed 10
/// from rest) the correct file exceeded the threshold on at most 8 solves
/// in a row over the whole run, a file 1 deg, 10 mm and 5 ms off on 11
/// from its second; of 3, 5 and 10, three served both best (see
/// docs/results/camera-imu-tested-release-2026-12-05.md).
pub const TEST_SOLVES: u32 = 3;

/// The test's tail probability under a correct file: the one-sided normal
/// quantile of 0.999, for the Wilson-Hilferty chi-square quantile.
const TEST_Z: f64 = 3.090_232;

/// Eigenvalues of the data's information below this share of the largest
/// are directions the solve does not see (the stereo rotation without a
/// second camera, anything at rest); the test leaves them out.
const TEST_FLOOR: f64 = 1e-6;

/// What one solve's score test found.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ScoreTest {
    /// `g^T Lambda^-1 g` over the directions the data see.
    pub statistic: f64,
    /// How many directions that is (the degrees of freedom).
    pub rank: usize,
    /// The chi-square quantile at 99.9 % for `rank` degrees of freedom.
    pub threshold: f64,
}

/// Chi-square quantile for `dof` degrees of freedom at the one-sided
/// normal quantile `z` (Wilson-Hilferty; at 99.9 % it is 1.7 % high at 3
/// dof, 0.9 % at 7 and 0.5 % at 10: a slightly stricter test).
fn chi_square_quantile(dof: f64, z: f64) -> f64 {
    let a = 2.0 / (9.0 * dof);
    dof * (1.0 - a + z * a.sqrt()).powi(3)
}

/// The score test of `H0`: the calibration is the held value. `info` is
/// the solve's information on the block (its marginal covariance
/// inverted), `held_info` the diagonal of the prior that held it, `step`
/// how far the held block moved from its centre. The data's information
/// is `info - held_info`; their gradient at the centre `info step` (the
/// solve's step is `info^-1` times that gradient). None when nothing is
/// seen.
pub fn score_test(
    info: &MatrixCalib,
    held_info: &VectorCalib,
    step: &VectorCalib,
) -> Option<ScoreTest> {
    let g = info * step;
    let eig = data_information(info, held_info);
    let largest = eig.eigenvalues.max();
    if !(largest > 0.0 && largest.is_finite() && g.iter().all(|v| v.is_finite())) {
        return None;
    }
    let (mut statistic, mut rank) = (0.0, 0usize);
    for k in 0..CALIB_DIM {
        let l = eig.eigenvalues[k];
        if l > TEST_FLOOR * largest {
            let v = eig.eigenvectors.column(k).dot(&g);
            statistic += v * v / l;
            rank += 1;
        }
    }
    Some(ScoreTest {
        statistic,
        rank,
        threshold: chi_square_quantile(rank as f64, TEST_Z),
    })
}

/// The data's share of a solve's information on the block: `info` less
/// the diagonal `prior_info` of the file's prior, symmetrised, in its
/// eigenvectors (it may be singular: unobserved directions).
fn data_information(
    info: &MatrixCalib,
    prior_info: &VectorCalib,
) -> nalgebra::SymmetricEigen<f64, nalgebra::Const<CALIB_DIM>> {
    let data = info - MatrixCalib::from_diagonal(prior_info);
    ((data + data.transpose()) * 0.5).symmetric_eigen()
}

/// Solves before the estimate may raise the warning: the first windows'
/// estimates swing (0.6 deg in the first seconds of a correct EuRoC
/// calibration) before they settle within a tenth of that.
pub const WARN_AFTER_SOLVES: u64 = 50;

/// Solves in a row the estimate must stay beyond a warning distance
/// before it is reported as far (about 4-7 s of keyframes). On a correct
/// calibration the time offset wanders: on a rendered lap sequence it
/// went from +1.4 to -3.7 ms over 584 solves (its sigma 0.25 ms), beyond
/// 3 ms on 7 solves, at most 5 in a row; a wrong file stays beyond.
pub const WARN_PERSIST_SOLVES: u64 = 20;

/// The calibration block's state, kept across windows.
#[allow(non_snake_case)]
#[derive(Debug, Clone, PartialEq)]
pub struct CameraImuState {
    config: CameraImuRefinementConfig,
    file_T_body_cam0: Isometry3<f64>,
    file_T_cam0_cam: Vec<Isometry3<f64>>,
    /// Each camera's pose in camera 0 (identity for camera 0); camera 1's
    /// rotation is refined.
    pub(crate) T_cam0_cam: Vec<Isometry3<f64>>,
    pub(crate) T_body_cam0: Isometry3<f64>,
    pub(crate) time_offset_s: f64,
    /// Earlier windows' estimate and the upper factor of its information.
    carried: Option<(Values, MatrixCalib)>,
    last_covariance: Option<MatrixCalib>,
    solves: u64,
    /// Solves in a row, up to the last, that ended beyond a warning
    /// distance.
    beyond_solves: u64,
    /// Held at the file until the test releases it.
    held: bool,
    /// Solves in a row, up to the last, whose test exceeded its threshold.
    over_threshold: u32,
    /// Held keyframes follow the calibration now.
    held_follow: bool,
    /// The window started in flight ([`Self::start_in_motion`]).
    started_in_motion: bool,
    /// The test released the block in the last solve, after a start in
    /// flight (taken by [`Self::take_release_in_flight`]).
    released_in_flight: bool,
}

/// The calibration's values: camera 0 in the body, the time offset,
/// camera 1's rotation in camera 0 (identity without one).
#[allow(non_snake_case)]
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Values {
    T_body_cam0: Isometry3<f64>,
    td: f64,
    R_cam0_cam1: UnitQuaternion<f64>,
}

/// `[Log(R0^T R), t - t0, td - td0, Log(S0^T S)]` and its Jacobian with
/// respect to the calibration step.
fn difference(x: &Values, x0: &Values) -> (VectorCalib, MatrixCalib) {
    let rel = |a: &UnitQuaternion<f64>, b: &UnitQuaternion<f64>| {
        log(&(b.inverse() * a).to_rotation_matrix().into_inner())
    };
    let phi = rel(&x.T_body_cam0.rotation, &x0.T_body_cam0.rotation);
    let psi = rel(&x.R_cam0_cam1, &x0.R_cam0_cam1);
    let mut e = VectorCalib::zeros();
    e.fixed_rows_mut::<3>(CALIB_ROT).copy_from(&phi);
    e.fixed_rows_mut::<3>(CALIB_POS)
        .copy_from(&(x.T_body_cam0.translation.vector - x0.T_body_cam0.translation.vector));
    e[CALIB_TIME] = x.td - x0.td;
    e.fixed_rows_mut::<3>(CALIB_STEREO).copy_from(&psi);
    let mut j = MatrixCalib::identity();
    j.fixed_view_mut::<3, 3>(CALIB_ROT, CALIB_ROT)
        .copy_from(&right_jacobian_inverse(&phi));
    j.fixed_view_mut::<3, 3>(CALIB_STEREO, CALIB_STEREO)
        .copy_from(&right_jacobian_inverse(&psi));
    (e, j)
}

impl CameraImuState {
    /// Starts at the calibration of `cameras` (camera 0 first).
    pub fn new(config: CameraImuRefinementConfig, cameras: &[RigCamera]) -> Self {
        let t_bc0 = cameras
            .first()
            .map_or_else(Isometry3::identity, |c| c.calibration.T_body_cam);
        let t_c0c: Vec<Isometry3<f64>> = cameras
            .iter()
            .map(|c| t_bc0.inverse() * c.calibration.T_body_cam)
            .collect();
        Self {
            config,
            file_T_body_cam0: t_bc0,
            file_T_cam0_cam: t_c0c.clone(),
            T_cam0_cam: t_c0c,
            T_body_cam0: t_bc0,
            time_offset_s: 0.0,
            carried: None,
            last_covariance: None,
            solves: 0,
            beyond_solves: 0,
            held: config.hold_until_tested,
            over_threshold: 0,
            held_follow: config.held_keyframes_follow == HeldKeyframesFollow::On,
            started_in_motion: false,
            released_in_flight: false,
        }
    }

    /// The settings it was built with.
    pub fn config(&self) -> &CameraImuRefinementConfig {
        &self.config
    }

    /// Camera `i`'s pose in the body at the current estimate.
    #[allow(non_snake_case)]
    pub fn T_body_cam(&self, i: usize) -> Isometry3<f64> {
        self.T_body_cam0 * self.T_cam0_cam[i]
    }

    /// Applies a step `[dphi_c, dt_c, d td, dpsi_s]`.
    pub fn apply(&mut self, d: &[f64]) {
        let v3 = |o: usize| Vector3::new(d[o], d[o + 1], d[o + 2]);
        let q = self.T_body_cam0.rotation * UnitQuaternion::from_scaled_axis(v3(CALIB_ROT));
        self.T_body_cam0.rotation = UnitQuaternion::new_normalize(q.into_inner());
        self.T_body_cam0.translation.vector += v3(CALIB_POS);
        self.time_offset_s += d[CALIB_TIME];
        if let Some(t) = self.T_cam0_cam.get_mut(1) {
            let q = t.rotation * UnitQuaternion::from_scaled_axis(v3(CALIB_STEREO));
            t.rotation = UnitQuaternion::new_normalize(q.into_inner());
        }
    }

    /// The estimate, to put back with [`Self::restore`] (a rejected
    /// Levenberg-Marquardt step).
    pub(crate) fn values(&self) -> Values {
        Values {
            T_body_cam0: self.T_body_cam0,
            td: self.time_offset_s,
            R_cam0_cam1: self
                .T_cam0_cam
                .get(1)
                .map_or_else(UnitQuaternion::identity, |t| t.rotation),
        }
    }

    pub(crate) fn restore(&mut self, v: &Values) {
        self.T_body_cam0 = v.T_body_cam0;
        self.time_offset_s = v.td;
        if let Some(t) = self.T_cam0_cam.get_mut(1) {
            t.rotation = v.R_cam0_cam1;
        }
    }

    /// The window started in flight (a visual-inertial alignment in
    /// motion): held keyframes follow the calibration from now on unless
    /// the configuration says never.
    pub fn start_in_motion(&mut self) {
        self.started_in_motion = true;
        if self.config.held_keyframes_follow != HeldKeyframesFollow::Off {
            self.held_follow = true;
        }
    }

    /// Whether held keyframes follow the calibration now
    /// ([`super::held_cameras`]).
    pub fn held_keyframes_follow(&self) -> bool {
        self.held_follow
    }

    /// Gives `cameras` (the rig's, in order) the current estimate.
    pub fn place(&self, cameras: &mut [RigCamera]) {
        for (i, cam) in cameras.iter_mut().enumerate() {
            cam.calibration.T_body_cam = self.T_body_cam(i);
        }
    }

    fn file_values(&self) -> Values {
        Values {
            T_body_cam0: self.file_T_body_cam0,
            td: 0.0,
            R_cam0_cam1: self
                .file_T_cam0_cam
                .get(1)
                .map_or_else(UnitQuaternion::identity, |t| t.rotation),
        }
    }

    fn file_sqrt_info(&self) -> VectorCalib {
        let c = &self.config;
        let r = 1.0 / c.rotation_sigma_deg.to_radians();
        let t = 1.0 / c.translation_sigma_m;
        let s = 1.0 / c.stereo_rotation_sigma_deg.to_radians();
        let held = if self.held { HOLD_FACTOR } else { 1.0 };
        VectorCalib::from_column_slice(&[r, r, r, t, t, t, 1.0 / c.time_offset_sigma_s, s, s, s])
            * held
    }

    /// The file prior's information, a diagonal (squared `file_sqrt_info`).
    fn file_information(&self) -> VectorCalib {
        self.file_sqrt_info().map(|v| v * v)
    }

    /// The whitened prior factors at the current estimate: the file's and
    /// (after a first solve) the carried one.
    pub fn prior_factors(&self) -> Vec<(VectorCalib, MatrixCalib)> {
        let x = self.values();
        let (e, j) = difference(&x, &self.file_values());
        let w = MatrixCalib::from_diagonal(&self.file_sqrt_info());
        let mut out = vec![(w * e, w * j)];
        if let Some((x0, u)) = &self.carried {
            let (e, j) = difference(&x, x0);
            out.push((u * e, u * j));
        }
        out
    }

    /// Takes the solve's marginal covariance of the block: keeps
    /// `carry_weight` times its information, less the file prior's, as
    /// the next solve's carried prior. While held, tests the file instead
    /// (nothing is carried: the held solves' information is centred on
    /// the file, not on what the data say).
    pub fn after_solve(&mut self, covariance: Option<MatrixCalib>) {
        self.solves += 1;
        self.beyond_solves = if self.beyond_warning() {
            self.beyond_solves + 1
        } else {
            0
        };
        let Some(cov) = covariance.filter(|c| c.iter().all(|v| v.is_finite())) else {
            return;
        };
        let sym = (cov + cov.transpose()) * 0.5;
        let Some(info) = sym.cholesky().map(|c| c.inverse()) else {
            return;
        };
        self.last_covariance = Some(sym);
        if self.held {
            self.test_file(&info);
            return;
        }
        // The data's share, kept positive semi-definite.
        let eig = data_information(&info, &self.file_information());
        let clamped = eig
            .eigenvalues
            .map(|l| l.max(0.0) * self.config.carry_weight);
        // Upper factor U with U^T U = info, through the eigenvectors (the
        // information may be singular: unobserved directions).
        let u = MatrixCalib::from_diagonal(&clamped.map(f64::sqrt)) * eig.eigenvectors.transpose();
        if u.iter().all(|v| v.is_finite()) {
            self.carried = Some((self.values(), u));
        }
    }

    /// One held solve's test; releases the block after [`TEST_SOLVES`]
    /// over the threshold in a row.
    fn test_file(&mut self, info: &MatrixCalib) {
        let (step, _) = difference(&self.values(), &self.file_values());
        let test = score_test(info, &self.file_information(), &step);
        let over = test.is_some_and(|t| t.statistic > t.threshold);
        self.over_threshold = if over { self.over_threshold + 1 } else { 0 };
        if self.over_threshold >= TEST_SOLVES {
            let t = test.expect("over the threshold implies a test");
            tracing::info!(
                "camera-IMU calibration: the data disagree with the file beyond chance (score {:.0} over {:.0} in {} directions, {} solves in a row, solve {}): refining it online from now on",
                t.statistic,
                t.threshold,
                t.rank,
                TEST_SOLVES,
                self.solves
            );
            self.held = false;
            self.carried = None;
            self.released_in_flight = self.started_in_motion && self.config.release_frees_gyro_bias;
        }
    }

    /// Whether the test released the block in the last solve after a
    /// start in flight, with `release_frees_gyro_bias` set; true once.
    /// Such a start's visual-inertial alignment found the gyroscope bias
    /// through the file's rotation, so the bias took the file's error (at
    /// a steady turn rate a turn of the camera-IMU rotation and a bias
    /// shift the gyroscope against the images alike), and the window's
    /// boundary prior, held about as tight as the alignment found it,
    /// keeps it there: the window then forgets it ([`super::Window`]).
    /// Off by default: where the images disagree with the IMU (renderings
    /// along a recorded truth with the real IMU) a correct file is
    /// released too, and the freed bias lets the window trust a gyroscope
    /// that does not agree with the images.
    pub fn take_release_in_flight(&mut self) -> bool {
        std::mem::take(&mut self.released_in_flight)
    }

    /// Whether the estimate is beyond a warning distance from the file now.
    fn beyond_warning(&self) -> bool {
        let (e, _) = difference(&self.values(), &self.file_values());
        let c = &self.config;
        e.fixed_rows::<3>(CALIB_ROT).norm().to_degrees() > c.warn_rotation_deg
            || e.fixed_rows::<3>(CALIB_POS).norm() > c.warn_translation_m
            || self.time_offset_s.abs() > c.warn_time_offset_s
    }

    /// The current estimate with its distance from the file and its sigmas.
    pub fn estimate(&self) -> CameraImuEstimate {
        let (e, _) = difference(&self.values(), &self.file_values());
        let rotation_from_file_deg = e.fixed_rows::<3>(CALIB_ROT).norm().to_degrees();
        let translation_from_file_m = e.fixed_rows::<3>(CALIB_POS).norm();
        let sigma = |from: usize| {
            self.last_covariance.map_or(f64::NAN, |c| {
                (c[(from, from)] + c[(from + 1, from + 1)] + c[(from + 2, from + 2)])
                    .max(0.0)
                    .sqrt()
            })
        };
        CameraImuEstimate {
            T_body_cam0: self.T_body_cam0,
            T_cam0_cam1: self
                .T_cam0_cam
                .get(1)
                .copied()
                .unwrap_or_else(Isometry3::identity),
            time_offset_s: self.time_offset_s,
            rotation_from_file_deg,
            translation_from_file_m,
            stereo_rotation_from_file_deg: e.fixed_rows::<3>(CALIB_STEREO).norm().to_degrees(),
            rotation_sigma_deg: sigma(CALIB_ROT).to_degrees(),
            translation_sigma_m: sigma(CALIB_POS),
            time_offset_sigma_s: self
                .last_covariance
                .map_or(f64::NAN, |c| c[(CALIB_TIME, CALIB_TIME)].max(0.0).sqrt()),
            far_from_file: self.solves >= WARN_AFTER_SOLVES
                && self.beyond_solves >= WARN_PERSIST_SOLVES,
            solves: self.solves,
            held_at_file: self.held,
        }
    }
}

/// The body's motion at a keyframe, for the time offset.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct BodyMotion {
    /// Angular rate in the body frame (gyroscope less bias), rad/s.
    pub omega_body_rad_s: Vector3<f64>,
    /// Body velocity in the world frame, m/s.
    pub velocity_world_m_s: Vector3<f64>,
}

/// The body pose when the image was taken, `td` after its stamp.
#[allow(non_snake_case)]
pub fn pose_at_exposure(
    T_world_body: &Isometry3<f64>,
    motion: &BodyMotion,
    td: f64,
) -> Isometry3<f64> {
    let r = T_world_body.rotation * UnitQuaternion::from_scaled_axis(motion.omega_body_rad_s * td);
    Isometry3::from_parts(
        Translation3::from(T_world_body.translation.vector + motion.velocity_world_m_s * td),
        r,
    )
}

/// What every observation of one keyframe shares in
/// [`reproject_refined`]: the pose at exposure, its rotation matrix and
/// the turn back to the stamp (two rotations from an axis-angle each: per
/// observation they were a good part of the window's time).
#[derive(Debug, Clone, Copy)]
pub struct Exposure {
    /// [`pose_at_exposure`].
    pub pose: Isometry3<f64>,
    /// The exposure's rotation as a matrix, `R_world_body`.
    pub rotation: Matrix3<f64>,
    /// `Exp(-omega td)`: from the exposure back to the stamp.
    pub back: Matrix3<f64>,
}

impl Exposure {
    /// The keyframe at `T_world_body` moving by `motion`, imaged `td` after its stamp.
    #[allow(non_snake_case)]
    pub fn new(T_world_body: &Isometry3<f64>, motion: &BodyMotion, td: f64) -> Self {
        let pose = pose_at_exposure(T_world_body, motion, td);
        Self {
            pose,
            rotation: pose.rotation.to_rotation_matrix().into_inner(),
            back: exp(&(-motion.omega_body_rad_s * td)),
        }
    }
}

/// The reprojection through the pose at exposure, with the body and point
/// Jacobians ([`reproject`]'s, chained to the keyframe's own pose) and
/// the Jacobian with respect to the calibration step. `camera` holds the
/// current estimate (`T_body_cam0 T_cam0_cam`).
#[allow(non_snake_case)]
pub fn reproject_refined(
    camera: &RigCamera,
    camera_index: usize,
    T_cam0_cam: &Isometry3<f64>,
    T_world_body: &Isometry3<f64>,
    motion: &BodyMotion,
    td: f64,
    point_world_m: &Vector3<f64>,
    pixel: &Vector2<f64>,
) -> Option<(Reprojection, Matrix2xCalib)> {
    let exposure = Exposure::new(T_world_body, motion, td);
    reproject_exposed(
        camera,
        camera_index,
        T_cam0_cam,
        &exposure,
        motion,
        point_world_m,
        pixel,
    )
}

/// [`reproject_refined`] with the keyframe's [`Exposure`] computed once
/// for all its observations (the same numbers).
#[allow(non_snake_case)]
pub fn reproject_exposed(
    camera: &RigCamera,
    camera_index: usize,
    T_cam0_cam: &Isometry3<f64>,
    exposure: &Exposure,
    motion: &BodyMotion,
    point_world_m: &Vector3<f64>,
    pixel: &Vector2<f64>,
) -> Option<(Reprojection, Matrix2xCalib)> {
    let exposed = &exposure.pose;
    let mut r = reproject(camera, exposed, point_world_m, pixel)?;
    let r_wb = exposure.rotation;
    // d error / d p_body = d_point R' (d_point = d_px R_cb R'^T).
    let d_body = r.d_point * r_wb;
    let back = exposure.back;
    let d_rot = r.d_pose.fixed_view::<2, 3>(0, 0) * back;
    r.d_pose.fixed_view_mut::<2, 3>(0, 0).copy_from(&d_rot);
    let p_body = r_wb.transpose() * (point_world_m - exposed.translation.vector);
    let t_bc = &camera.calibration.T_body_cam;
    let p_cam = t_bc.inverse_transform_point(&p_body.into());
    let p_cam0 = T_cam0_cam.transform_point(&p_cam).coords;
    // d p_cam / d dphi_c = R_c0c^T [p_c0]x; d error / d p_cam = d_body R_bc.
    let r_bc = t_bc.rotation.to_rotation_matrix().into_inner();
    let r_c0c = T_cam0_cam.rotation.to_rotation_matrix().into_inner();
    let d_cam = d_body * r_bc;
    let dpb_dtd =
        -motion.omega_body_rad_s.cross(&p_body) - r_wb.transpose() * motion.velocity_world_m_s;
    let mut d_calib = Matrix2xCalib::zeros();
    d_calib
        .fixed_view_mut::<2, 3>(0, CALIB_ROT)
        .copy_from(&(d_cam * r_c0c.transpose() * hat(&p_cam0)));
    d_calib
        .fixed_view_mut::<2, 3>(0, CALIB_POS)
        .copy_from(&(-d_body));
    d_calib
        .fixed_view_mut::<2, 1>(0, CALIB_TIME)
        .copy_from(&(d_body * dpb_dtd));
    if camera_index == 1 {
        // p_c1 = R_c0c1^T (p_c0 - t_c0c1), R_c0c1 <- R_c0c1 Exp(dpsi):
        // d p_c1 / d dpsi = [p_c1]x.
        d_calib
            .fixed_view_mut::<2, 3>(0, CALIB_STEREO)
            .copy_from(&(d_cam * hat(&p_cam.coords)));
    }
    Some((r, d_calib))
}

/// The error alone through the pose at exposure, with the depth.
#[allow(non_snake_case)]
pub fn reprojection_error_refined(
    camera: &RigCamera,
    T_world_body: &Isometry3<f64>,
    motion: &BodyMotion,
    td: f64,
    point_world_m: &Vector3<f64>,
    pixel: &Vector2<f64>,
) -> Option<(Vector2<f64>, f64)> {
    reprojection_error(
        camera,
        &pose_at_exposure(T_world_body, motion, td),
        point_world_m,
        pixel,
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rig::euroc::{euroc_cam0, euroc_cam1};

    fn refined_at_once() -> CameraImuRefinementConfig {
        CameraImuRefinementConfig {
            hold_until_tested: false,
            ..CameraImuRefinementConfig::default()
        }
    }

    /// A symmetric positive semi-definite information with the given
    /// eigenvalues along a fixed, non-axis-aligned basis.
    fn information(eigenvalues: &[f64; CALIB_DIM]) -> MatrixCalib {
        let mut a = MatrixCalib::zeros();
        for r in 0..CALIB_DIM {
            for c in 0..CALIB_DIM {
                a[(r, c)] = ((r * 7 + c * 3) as f64 * 0.37).sin() + if r == c { 2.0 } else { 0.0 };
            }
        }
        let q = a.qr().q();
        q * MatrixCalib::from_diagonal(&VectorCalib::from_column_slice(eigenvalues)) * q.transpose()
    }

    /// In a linear model the score test equals the Wald test of the
    /// data's own estimate: `g^T Lambda^-1 g = d^T Lambda d` when the data
    /// alone would put the block at `d`, however tightly it is held, and
    /// directions the data do not see drop out of the statistic and of
    /// its degrees of freedom.
    #[test]
    fn the_score_test_is_the_data_estimates_own_chi_square() {
        let held = VectorCalib::from_element(1e12);
        let truth = VectorCalib::from_column_slice(&[
            0.01, -0.004, 0.007, 0.0, 0.0, 0.0, 0.002, 1e-4, -2e-4, 5e-5,
        ]);
        let mut seen = [0.0; CALIB_DIM];
        for (k, l) in seen.iter_mut().enumerate() {
            *l = 10f64.powi(3 + (k % 4) as i32);
        }
        for unseen in [0usize, 3] {
            let mut eig = seen;
            for l in eig.iter_mut().take(unseen) {
                *l = 0.0;
            }
            let data = information(&eig);
            let info = data + MatrixCalib::from_diagonal(&held);
            // The held solve: info step = data truth.
            let step = info.lu().solve(&(data * truth)).expect("invertible");
            let t = score_test(&info, &held, &step).expect("seen");
            let wald = truth.dot(&(data * truth));
            assert_eq!(t.rank, CALIB_DIM - unseen);
            assert!(
                (t.statistic - wald).abs() < 1e-6 * wald,
                "{unseen} unseen: {} against {wald}",
                t.statistic
            );
        }
        // Nothing seen: no test.
        let info = MatrixCalib::from_diagonal(&held);
        assert!(score_test(&info, &held, &VectorCalib::zeros()).is_none());
    }

    #[test]
    fn the_threshold_is_the_chi_square_quantile_at_99_9_percent() {
        // Tabulated chi-square 0.999 quantiles.
        for (dof, table) in [(3.0, 16.266), (7.0, 24.322), (10.0, 29.588)] {
            let q = chi_square_quantile(dof, TEST_Z);
            assert!(
                q >= table && q / table - 1.0 < 0.02,
                "{dof} dof: {q} against {table}"
            );
        }
    }

    /// "in-flight": held keyframes follow the calibration once the
    /// window says it started in motion; "on" from the start; "off" never.
    #[test]
    fn held_keyframes_follow_after_a_start_in_flight_by_default() {
        let cams = [RigCamera::new(euroc_cam0()), RigCamera::new(euroc_cam1())];
        for (setting, before, after) in [
            (HeldKeyframesFollow::InFlight, false, true),
            (HeldKeyframesFollow::On, true, true),
            (HeldKeyframesFollow::Off, false, false),
        ] {
            let config = CameraImuRefinementConfig {
                held_keyframes_follow: setting,
                ..CameraImuRefinementConfig::default()
            };
            let mut state = CameraImuState::new(config, &cams);
            assert_eq!(state.held_keyframes_follow(), before, "{setting:?}");
            state.start_in_motion();
            assert_eq!(state.held_keyframes_follow(), after, "{setting:?}");
        }
        assert_eq!(
            CameraImuRefinementConfig::default().held_keyframes_follow,
            HeldKeyframesFollow::InFlight
        );
    }

    /// Held at the file until TEST_SOLVES solves in a row test it wrong;
    /// a solve under the threshold starts the count again; released, the
    /// prior is the configured one and the information is carried.
    #[test]
    fn the_file_is_held_until_the_data_test_it_wrong() {
        let cams = [RigCamera::new(euroc_cam0()), RigCamera::new(euroc_cam1())];
        let mut state = CameraImuState::new(CameraImuRefinementConfig::default(), &cams);
        assert!(state.estimate().held_at_file);
        let held = state.file_information();
        let released = {
            let mut s = state.clone();
            s.held = false;
            s.file_information()
        };
        assert!((held[0] / released[0] - HOLD_FACTOR * HOLD_FACTOR).abs() < 1e-3);
        let data = information(&[1e8, 1e8, 1e8, 1e4, 1e4, 1e4, 1e9, 1e9, 1e9, 1e9]);
        // One solve on data that put the block at `truth` from the file.
        let solve = |s: &mut CameraImuState, truth: &VectorCalib| {
            let file_values = s.file_values();
            s.restore(&file_values);
            let prior = s.file_information();
            let info = data + MatrixCalib::from_diagonal(&prior);
            let step = info.lu().solve(&(data * truth)).expect("invertible");
            s.apply(step.as_slice());
            s.after_solve(info.try_inverse());
            s.estimate().held_at_file
        };
        let right = VectorCalib::zeros();
        let mut wrong = VectorCalib::zeros();
        wrong[CALIB_ROT] = 1f64.to_radians();
        wrong[CALIB_TIME] = 0.005;
        for _ in 0..20 {
            assert!(solve(&mut state, &right), "a right file stays held");
        }
        for _ in 0..TEST_SOLVES - 1 {
            assert!(solve(&mut state, &wrong));
        }
        assert!(solve(&mut state, &right), "the count starts again");
        assert!(state.carried.is_none(), "nothing carried while held");
        for _ in 0..TEST_SOLVES - 1 {
            assert!(solve(&mut state, &wrong));
        }
        assert!(!solve(&mut state, &wrong), "released");
        assert!(
            state.carried.is_none(),
            "the held solves' information is dropped"
        );
        let now = state.file_information();
        assert!((now - released).norm() < 1e-9 * released.norm());
        assert!(
            !state.take_release_in_flight(),
            "released after a start from rest: the window keeps its gyroscope bias"
        );
        assert!(!solve(&mut state, &wrong) && state.carried.is_some());

        // After a start in flight, by default nothing is said; with
        // `release_frees_gyro_bias` the release is said once, to the
        // solve that released the block.
        let mut state = CameraImuState::new(CameraImuRefinementConfig::default(), &cams);
        state.start_in_motion();
        for _ in 0..TEST_SOLVES {
            solve(&mut state, &wrong);
            assert!(!state.take_release_in_flight(), "off by default");
        }
        assert!(!state.estimate().held_at_file);
        let config = CameraImuRefinementConfig {
            release_frees_gyro_bias: true,
            ..CameraImuRefinementConfig::default()
        };
        let mut state = CameraImuState::new(config, &cams);
        state.start_in_motion();
        for _ in 0..TEST_SOLVES - 1 {
            assert!(solve(&mut state, &wrong));
            assert!(!state.take_release_in_flight(), "still held");
        }
        assert!(!solve(&mut state, &wrong), "released");
        assert!(state.take_release_in_flight());
        assert!(!state.take_release_in_flight(), "said once");
        assert!(!solve(&mut state, &wrong) && !state.take_release_in_flight());
    }

    #[allow(non_snake_case)]
    fn perturbed_camera(
        state: &CameraImuState,
        i: usize,
        base: &RigCamera,
        d: &VectorCalib,
    ) -> (RigCamera, f64) {
        let mut s = state.clone();
        s.apply(d.as_slice());
        let mut cal = base.calibration.clone();
        cal.T_body_cam = s.T_body_cam(i);
        (RigCamera::new(cal), s.time_offset_s)
    }

    /// Every column of every Jacobian against central differences, for
    /// both cameras of a stereo rig, with a time offset and motion.
    #[test]
    fn only_an_estimate_that_stays_far_from_the_file_is_reported() {
        let cams = [RigCamera::new(euroc_cam0()), RigCamera::new(euroc_cam1())];
        let mut state = CameraImuState::new(refined_at_once(), &cams);
        let solve = |s: &mut CameraImuState, td: f64| {
            let step = td - s.time_offset_s;
            let mut d = [0.0; CALIB_DIM];
            d[CALIB_TIME] = step;
            s.apply(&d);
            s.after_solve(None);
            s.estimate().far_from_file
        };
        // Settling: even far, nothing before WARN_AFTER_SOLVES.
        let mut settling = state.clone();
        for _ in 1..WARN_AFTER_SOLVES {
            assert!(!solve(&mut settling, 0.0045));
        }
        for _ in 0..WARN_AFTER_SOLVES {
            assert!(!solve(&mut state, 0.0));
        }
        // Excursions beyond 3 ms shorter than the persistence, as a
        // correct calibration's estimate makes: never reported.
        for _ in 0..5 {
            for _ in 0..WARN_PERSIST_SOLVES - 1 {
                assert!(!solve(&mut state, -0.0036));
            }
            assert!(!solve(&mut state, -0.0012));
        }
        // One that stays: reported from the WARN_PERSIST_SOLVES-th solve,
        // and no longer once it comes back.
        for i in 1..=WARN_PERSIST_SOLVES + 10 {
            assert_eq!(
                solve(&mut state, 0.005),
                i >= WARN_PERSIST_SOLVES,
                "solve {i}"
            );
        }
        assert!(!solve(&mut state, 0.001));
    }

    #[test]
    fn jacobians_match_finite_differences() {
        let cams = [RigCamera::new(euroc_cam0()), RigCamera::new(euroc_cam1())];
        let mut state = CameraImuState::new(CameraImuRefinementConfig::default(), &cams);
        state.apply(&[
            0.01, -0.02, 0.015, 0.004, -0.006, 0.002, 0.004, 0.002, -0.001, 0.003,
        ]);
        let motion = BodyMotion {
            omega_body_rad_s: Vector3::new(0.4, -0.7, 0.9),
            velocity_world_m_s: Vector3::new(0.8, -0.3, 0.5),
        };
        let body = Isometry3::new(Vector3::new(0.3, -0.1, 1.2), Vector3::new(0.2, -0.4, 0.1));
        let h = 1e-6;
        let mut checked = 0;
        for i in 0..2 {
            let (cam, td) = perturbed_camera(&state, i, &cams[i], &VectorCalib::zeros());
            // A point in front of camera i, 2.5 m away.
            let p_cam = Vector3::new(0.3, -0.2, 2.5);
            let point = body
                .transform_point(&cam.calibration.T_body_cam.transform_point(&p_cam.into()))
                .coords;
            let pixel = cam.project(&p_cam).expect("projects") + Vector2::new(1.5, -0.7);
            let (r, d_calib) = reproject_refined(
                &cam,
                i,
                &state.T_cam0_cam[i],
                &body,
                &motion,
                td,
                &point,
                &pixel,
            )
            .expect("projects");
            let err = |cam: &RigCamera, td: f64, body: &Isometry3<f64>, point: &Vector3<f64>| {
                reprojection_error_refined(cam, body, &motion, td, point, &pixel)
                    .expect("projects")
                    .0
            };
            assert!((err(&cam, td, &body, &point) - r.error_px).norm() < 1e-12);
            for k in 0..CALIB_DIM {
                let mut d = VectorCalib::zeros();
                d[k] = h;
                let (cp, tp) = perturbed_camera(&state, i, &cams[i], &d);
                d[k] = -h;
                let (cm, tm) = perturbed_camera(&state, i, &cams[i], &d);
                let fd = (err(&cp, tp, &body, &point) - err(&cm, tm, &body, &point)) / (2.0 * h);
                let analytic = d_calib.column(k);
                assert!(
                    (fd - analytic).norm() < 1e-5 * (1.0 + fd.norm()),
                    "camera {i} calibration column {k}: {fd} vs {analytic}"
                );
                checked += 1;
            }
            for k in 0..6 {
                let mut d = [0.0; 6];
                let step = |s: f64, d: &mut [f64; 6]| {
                    d[k] = s;
                    let mut b = body;
                    let dv = Vector3::new(d[0], d[1], d[2]);
                    b.rotation *= UnitQuaternion::from_scaled_axis(dv);
                    b.translation.vector += Vector3::new(d[3], d[4], d[5]);
                    b
                };
                let bp = step(h, &mut d);
                let bm = step(-h, &mut d);
                let fd = (err(&cam, td, &bp, &point) - err(&cam, td, &bm, &point)) / (2.0 * h);
                let analytic = r.d_pose.column(k);
                assert!(
                    (fd - analytic).norm() < 1e-5 * (1.0 + fd.norm()),
                    "camera {i} pose column {k}: {fd} vs {analytic}"
                );
                checked += 1;
            }
            for k in 0..3 {
                let mut dp = Vector3::zeros();
                dp[k] = h;
                let fd = (err(&cam, td, &body, &(point + dp))
                    - err(&cam, td, &body, &(point - dp)))
                    / (2.0 * h);
                assert!((fd - r.d_point.column(k)).norm() < 1e-5 * (1.0 + fd.norm()));
                checked += 1;
            }
        }
        assert_eq!(checked, 2 * (CALIB_DIM + 6 + 3));
    }

    #[test]
    fn the_prior_factors_vanish_at_their_means_and_their_jacobians_are_exact() {
        let cams = [RigCamera::new(euroc_cam0()), RigCamera::new(euroc_cam1())];
        let mut state = CameraImuState::new(refined_at_once(), &cams);
        let f = state.prior_factors();
        assert_eq!(f.len(), 1);
        assert!(f[0].0.norm() < 1e-12);
        state.apply(&[
            0.02, 0.01, -0.03, 0.01, 0.0, -0.01, 0.003, 0.001, 0.0, -0.002,
        ]);
        let (r, j) = state.prior_factors()[0];
        let h = 1e-6;
        for k in 0..CALIB_DIM {
            let mut d = VectorCalib::zeros();
            d[k] = h;
            let mut p = state.clone();
            p.apply(d.as_slice());
            d[k] = -2.0 * h;
            let mut m = p.clone();
            m.apply(d.as_slice());
            let fd = (p.prior_factors()[0].0 - m.prior_factors()[0].0) / (2.0 * h);
            assert!(
                (fd - j.column(k)).norm() < 1e-4 * (1.0 + fd.norm()),
                "column {k}"
            );
        }
        // 0.02-0.03 rad against a 2 deg sigma: about one sigma each.
        assert!(r.norm() > 1.0);
        let e = state.estimate();
        assert!((e.time_offset_s - 0.003).abs() < 1e-12);
        assert!((e.translation_from_file_m - 0.02f64.sqrt() * 0.1).abs() < 1e-9);
        assert!(e.rotation_sigma_deg.is_nan());
        assert!(!e.far_from_file, "no warning before the estimate settled");
        state.solves = WARN_AFTER_SOLVES;
        state.beyond_solves = WARN_PERSIST_SOLVES;
        assert!(
            state.estimate().far_from_file,
            "2.1 deg from the file is beyond the 0.5 deg warning"
        );
    }

    #[test]
    fn the_carried_prior_keeps_the_data_share_of_the_information() {
        let cams = [RigCamera::new(euroc_cam0())];
        let mut state = CameraImuState::new(refined_at_once(), &cams);
        let file = state.file_sqrt_info();
        // A solve whose information is the file's plus 1e6 on every unknown.
        let info = MatrixCalib::from_diagonal(&file.component_mul(&file)).add_scalar(0.0)
            + MatrixCalib::identity() * 1e6;
        let cov = info.try_inverse().expect("invertible");
        state.after_solve(Some(cov));
        let (_, u) = state.carried.expect("carried");
        let carried = u.transpose() * u;
        assert!((carried - MatrixCalib::identity() * 0.9e6).norm() < 1e-3 * 0.9e6);
        assert_eq!(state.prior_factors().len(), 2);
        assert!(state.estimate().time_offset_sigma_s > 0.0);
    }
}
