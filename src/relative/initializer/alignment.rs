//! Visual-inertial alignment: the IMU compared with the vision-only motion
//! of a few keyframes to estimate the gyroscope bias, the metric scale,
//! gravity and every keyframe's velocity (the paper's initialisation mode,
//! stage 1 of the method).
//!
//! Inputs: N >= 4 keyframes with camera poses `T_c0_ci` from vision alone
//! (rotation exact, position up to an unknown scale, in an arbitrary frame
//! "c0"), the camera mounting `T_body_cam`, and the N-1 preintegrated IMU
//! intervals between consecutive keyframes. Three steps:
//!
//! 1. Gyroscope bias ([`estimate_gyro_bias`]): Gauss-Newton on the
//!    rotation residuals `Log((dR Exp(J_bg dbg))^T R_c0_bi^T R_c0_bj)`,
//!    each weighted by the inverse of its preintegrated covariance.
//! 2. A linear least-squares problem in the velocities `v_i` (c0 frame),
//!    gravity `g` (c0 frame) and the scale `s` (metric = s x vision), with
//!    the body positions `p_bi = s p_ci - R_c0_bi p_bc` (the camera-IMU
//!    lever arm) and the deltas corrected to the new gyro bias:
//!
//!    ```text
//!    v_j - v_i - g dt                               = R_bi dv
//!    s (p_cj - p_ci) - v_i dt - g dt^2 / 2          = R_bi dp + (R_bj - R_bi) p_bc
//!    ```
//!
//!    whitened by the preintegration covariance of `(dv, dp)` (rotated into
//!    c0). This is the linear alignment of VINS-Mono (Qin et al., T-RO 2018,
//!    sec. V-B) written for positions instead of its relative form.
//! 3. Gravity refined on the sphere of radius 9.81 (two tangent
//!    parameters, re-linearised a few times), with the accelerometer bias
//!    under a Gaussian prior (a few seconds of motion barely separate it
//!    from the tilt of gravity: without it, EuRoC's 0.14 m/s^2 bias costs
//!    0.8 deg of gravity and ~1% of scale that no standard deviation
//!    would show).
//!
//! Certainty: the standard deviation of `s` from the least-squares
//! covariance, inflated by the reduced chi-square when the data fit worse
//! than the preintegration noise says (vision errors, bias drift). Motion
//! without acceleration leaves `s` unobservable: the standard deviation
//! then grows without bound (infinite when the system is singular), and
//! [`Alignment::scale_certain`] is false. This is what the relative stage
//! uses to switch from initialisation to the tightly coupled mode.
//!
//! Allocation: the functions build small dense systems (6(N-1) x (3N+7))
//! per call; they run a few times during initialisation, not per frame.

use nalgebra::{
    DMatrix, DVector, Isometry3, Matrix3, Matrix3x2, Matrix6, SMatrix, UnitQuaternion, Vector3,
};

use super::level_rotation;
use crate::imu::preintegration::Preintegrator;
use crate::imu::so3::{log, right_jacobian, right_jacobian_inverse, tangent_basis};
use crate::imu::{ImuBiases, Preintegrated, PreintegrationError, GRAVITY_M_S2};
use crate::relative::types::KeyframeState;
use crate::sensors::ImuSample;

/// One keyframe's vision-only camera pose.
#[allow(non_snake_case)]
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VisionKeyframe {
    /// Image timestamp, ns, on the IMU's clock: the IMU intervals must
    /// start and end at these stamps.
    pub t_ns: i64,
    /// Maps this camera's coordinates into the first camera's (or any
    /// fixed) frame; the translation is up to scale.
    pub T_c0_cam: Isometry3<f64>,
}

/// Whether the scale is estimated (mono) or known (stereo: 1).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ScaleMode {
    /// Mono: the scale (metric per vision unit) is an unknown of the
    /// alignment.
    Estimate,
    /// The poses' scale is known (stereo: 1, the poses are in metres);
    /// must be positive and finite.
    Known(f64),
}

/// Settings of [`align`].
#[derive(Debug, Clone, PartialEq)]
pub struct AlignmentConfig {
    /// Magnitude of gravity, m/s^2: the refined gravity vector is held to
    /// this norm (default 9.81).
    pub gravity_m_s2: f64,
    /// Keyframes needed; values below 4 count as 4.
    pub min_keyframes: usize,
    /// Gauss-Newton iterations of the gyroscope bias.
    pub gyro_bias_iterations: usize,
    /// Re-linearisations of the gravity direction on its sphere.
    pub gravity_iterations: usize,
    /// Estimate the accelerometer bias in the refinement (else keep the
    /// integration value).
    pub estimate_accel_bias: bool,
    /// Standard deviation of the Gaussian prior on the accelerometer bias,
    /// centred on the integration value. Over a few seconds the bias is
    /// barely separable from the tilt of gravity; the prior keeps its
    /// estimate sane then, and its uncertainty still reaches the scale's
    /// standard deviation instead of biasing the scale unseen.
    pub accel_bias_prior_std_m_s2: f64,
    /// Standard deviation of each vision keyframe position, in metres
    /// (the scale taken as about right); added to the position rows'
    /// covariance so that the IMU is not trusted beyond the vision.
    pub vision_position_sigma_m: f64,
    /// `scale_certain` when `scale_std / scale` is below this.
    pub max_scale_rel_std: f64,
}

impl Default for AlignmentConfig {
    fn default() -> Self {
        Self {
            gravity_m_s2: GRAVITY_M_S2,
            min_keyframes: 4,
            gyro_bias_iterations: 3,
            gravity_iterations: 4,
            estimate_accel_bias: true,
            // Of the order of an ADIS16448's (EuRoC: 0.14 m/s^2).
            accel_bias_prior_std_m_s2: 0.1,
            vision_position_sigma_m: 0.0,
            max_scale_rel_std: 0.01,
        }
    }
}

/// Why the visual-inertial alignment refused its inputs or found no
/// usable solution.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum AlignmentError {
    /// Fewer keyframes than [`AlignmentConfig::min_keyframes`] (at least 4).
    #[error("{got} keyframes, need at least {needed}")]
    TooFewKeyframes {
        /// Keyframes given.
        got: usize,
        /// Keyframes needed.
        needed: usize,
    },
    /// The IMU intervals are not exactly one fewer than the keyframes.
    #[error("{keyframes} keyframes need {} IMU intervals, got {intervals}", keyframes - 1)]
    IntervalCount {
        /// Keyframes given.
        keyframes: usize,
        /// IMU intervals given.
        intervals: usize,
    },
    /// An IMU interval's start or end stamp differs from the stamps of the
    /// two keyframes it should join.
    #[error("IMU interval {index} does not run from keyframe {index} to keyframe {}", index + 1)]
    StampMismatch {
        /// The interval, 0-based (it should join keyframes `index` and
        /// `index + 1`).
        index: usize,
    },
    /// A keyframe pose, the camera mounting or an IMU interval holds NaN
    /// or infinity, or an interval's duration is not positive.
    #[error("keyframe or interval {index} is not finite")]
    NotFinite {
        /// The keyframe or interval, 0-based (also 0 for a non-finite
        /// camera mounting).
        index: usize,
    },
    /// The least-squares problem has no usable solution (fewer equations
    /// than unknowns, a zero system, or gravity solved as zero or not
    /// finite); the text says which.
    #[error("the alignment problem is degenerate: {0}")]
    Degenerate(&'static str),
    /// The estimated scale is zero, negative or NaN: the IMU motion does
    /// not fit the vision poses.
    #[error("the estimated scale {scale} (std {scale_std}) is not positive")]
    ScaleNotPositive {
        /// The estimate, metric per vision unit.
        scale: f64,
        /// Its standard deviation.
        scale_std: f64,
    },
    /// A setting of [`AlignmentConfig`], or the known scale of
    /// [`ScaleMode::Known`], is out of range or not finite.
    #[error("setting `{key}` = {value} is outside the allowed range {allowed}")]
    InvalidConfig {
        /// The setting's name (`scale` for the known scale).
        key: &'static str,
        /// The value given.
        value: f64,
        /// The allowed range, e.g. `> 0`.
        allowed: &'static str,
    },
    /// Preintegrating the raw IMU samples failed
    /// ([`align_with_reintegration`] only).
    #[error(transparent)]
    Preintegration(#[from] PreintegrationError),
}

/// The gyroscope bias from the rotations alone.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GyroBiasEstimate {
    /// The gyroscope bias, IMU frame, rad/s.
    pub gyro_rad_s: Vector3<f64>,
    /// Per-axis standard deviation (inflated by the reduced chi-square
    /// when above 1).
    pub sigma_rad_s: Vector3<f64>,
    /// RMS of the rotation residual norms after the last iteration.
    pub rotation_rms_rad: f64,
}

/// What the alignment found.
#[allow(non_snake_case)]
#[derive(Debug, Clone, PartialEq)]
pub struct Alignment {
    /// Metric = `scale` x vision units.
    pub scale: f64,
    /// Standard deviation of `scale` (0 when known, infinite when
    /// unobservable).
    pub scale_std: f64,
    /// `scale_std / scale`.
    pub scale_rel_std: f64,
    /// `scale_rel_std <= max_scale_rel_std`: safe to switch to the
    /// tightly coupled mode.
    pub scale_certain: bool,
    /// Gravity in the c0 frame, norm `gravity_m_s2`.
    pub gravity_c0_m_s2: Vector3<f64>,
    /// Standard deviation of the gravity direction (both tilt axes), rad.
    pub gravity_std_rad: f64,
    /// Norm of gravity in the first, unconstrained solve: far from 9.81
    /// says that the data do not fit the model.
    pub unconstrained_gravity_m_s2: f64,
    /// Maps c0 into a world frame with gravity `(0, 0, -g)`, yaw 0.
    pub R_world_c0: UnitQuaternion<f64>,
    /// Per keyframe, in the world frame.
    pub velocities_world_m_s: Vec<Vector3<f64>>,
    /// Per keyframe: metric body pose in the world frame, velocity, biases.
    pub keyframes: Vec<KeyframeState>,
    /// The gyroscope bias of step 1 and the accelerometer bias (estimated,
    /// or the integration value), IMU frame; every keyframe state carries
    /// them.
    pub biases: ImuBiases,
    /// Per-axis standard deviation of the gyroscope bias, rad/s (see
    /// [`GyroBiasEstimate::sigma_rad_s`]).
    pub gyro_bias_sigma_rad_s: Vector3<f64>,
    /// Whether `biases.accel_m_s2` was estimated (else the integration
    /// value was kept).
    pub accel_bias_estimated: bool,
    /// Per-axis posterior standard deviation of the accelerometer bias
    /// (infinite when it was not estimated). Close to the prior's: the
    /// data said little about it.
    pub accel_bias_std_m_s2: Vector3<f64>,
    /// RMS of the whitened residuals of the final linear system, in
    /// standard deviations of the preintegration noise (about 1 when the
    /// data fit the noise model).
    pub residual_rms: f64,
}

/// Alignment of a mono rig: scale estimated.
#[allow(non_snake_case)]
pub fn align_mono(
    keyframes: &[VisionKeyframe],
    intervals: &[Preintegrated],
    T_body_cam: &Isometry3<f64>,
    config: &AlignmentConfig,
) -> Result<Alignment, AlignmentError> {
    align(
        keyframes,
        intervals,
        T_body_cam,
        ScaleMode::Estimate,
        config,
    )
}

/// Alignment of a stereo rig: the poses are metric, scale fixed at 1.
#[allow(non_snake_case)]
pub fn align_stereo(
    keyframes: &[VisionKeyframe],
    intervals: &[Preintegrated],
    T_body_cam: &Isometry3<f64>,
    config: &AlignmentConfig,
) -> Result<Alignment, AlignmentError> {
    align(
        keyframes,
        intervals,
        T_body_cam,
        ScaleMode::Known(1.0),
        config,
    )
}

/// Per keyframe: body rotation and camera position in c0.
struct Frame {
    r_c0_b: Matrix3<f64>,
    p_c0_c: Vector3<f64>,
}

#[allow(non_snake_case)]
fn frames(keyframes: &[VisionKeyframe], T_body_cam: &Isometry3<f64>) -> Vec<Frame> {
    let r_bc = T_body_cam.rotation.to_rotation_matrix().into_inner();
    keyframes
        .iter()
        .map(|k| Frame {
            r_c0_b: k.T_c0_cam.rotation.to_rotation_matrix().into_inner() * r_bc.transpose(),
            p_c0_c: k.T_c0_cam.translation.vector,
        })
        .collect()
}

#[allow(non_snake_case)]
fn check_inputs(
    keyframes: &[VisionKeyframe],
    intervals: &[Preintegrated],
    T_body_cam: &Isometry3<f64>,
    config: &AlignmentConfig,
) -> Result<(), AlignmentError> {
    let checks: [(&'static str, f64, bool, &'static str); 4] = [
        (
            "gravity_m_s2",
            config.gravity_m_s2,
            config.gravity_m_s2 > 0.0,
            "> 0",
        ),
        (
            "accel_bias_prior_std_m_s2",
            config.accel_bias_prior_std_m_s2,
            config.accel_bias_prior_std_m_s2 > 0.0,
            "> 0",
        ),
        (
            "vision_position_sigma_m",
            config.vision_position_sigma_m,
            config.vision_position_sigma_m >= 0.0,
            ">= 0",
        ),
        (
            "max_scale_rel_std",
            config.max_scale_rel_std,
            config.max_scale_rel_std > 0.0,
            "> 0",
        ),
    ];
    for (key, value, ok, allowed) in checks {
        if !(ok && value.is_finite()) {
            return Err(AlignmentError::InvalidConfig {
                key,
                value,
                allowed,
            });
        }
    }
    let needed = config.min_keyframes.max(4);
    if keyframes.len() < needed {
        return Err(AlignmentError::TooFewKeyframes {
            got: keyframes.len(),
            needed,
        });
    }
    if intervals.len() + 1 != keyframes.len() {
        return Err(AlignmentError::IntervalCount {
            keyframes: keyframes.len(),
            intervals: intervals.len(),
        });
    }
    let iso_finite = |t: &Isometry3<f64>| {
        t.translation.vector.iter().all(|v| v.is_finite())
            && t.rotation.coords.iter().all(|v| v.is_finite())
    };
    if !iso_finite(T_body_cam) {
        return Err(AlignmentError::NotFinite { index: 0 });
    }
    for (index, k) in keyframes.iter().enumerate() {
        if !iso_finite(&k.T_c0_cam) {
            return Err(AlignmentError::NotFinite { index });
        }
    }
    for (index, p) in intervals.iter().enumerate() {
        if p.t_start_ns != keyframes[index].t_ns || p.t_end_ns != keyframes[index + 1].t_ns {
            return Err(AlignmentError::StampMismatch { index });
        }
        let finite = p.delta_R.iter().all(|v| v.is_finite())
            && p.delta_v_m_s.iter().all(|v| v.is_finite())
            && p.delta_p_m.iter().all(|v| v.is_finite())
            && p.covariance.iter().all(|v| v.is_finite())
            && p.d_R_d_bg.iter().all(|v| v.is_finite())
            && p.dt_s.is_finite()
            && p.dt_s > 0.0;
        if !finite {
            return Err(AlignmentError::NotFinite { index });
        }
    }
    Ok(())
}

/// Step 1 alone: the gyroscope bias that makes the preintegrated rotations
/// agree with the vision rotations, starting from the first interval's
/// integration bias.
#[allow(non_snake_case)]
pub fn estimate_gyro_bias(
    keyframes: &[VisionKeyframe],
    intervals: &[Preintegrated],
    T_body_cam: &Isometry3<f64>,
    config: &AlignmentConfig,
) -> Result<GyroBiasEstimate, AlignmentError> {
    check_inputs(keyframes, intervals, T_body_cam, config)?;
    let frames = frames(keyframes, T_body_cam);
    Ok(gyro_bias(
        &frames,
        intervals,
        config.gyro_bias_iterations.max(1),
    ))
}

/// Rotation residual of one interval and its Jacobian with respect to the
/// gyro bias, at bias `bg`.
fn rotation_residual(
    pre: &Preintegrated,
    r_bi: &Matrix3<f64>,
    r_bj: &Matrix3<f64>,
    bg: &Vector3<f64>,
) -> (Vector3<f64>, Matrix3<f64>) {
    let phi = pre.d_R_d_bg * (bg - pre.biases.gyro_rad_s);
    let d_r = pre.delta_R * crate::imu::so3::exp(&phi);
    let r = log(&(d_r.transpose() * r_bi.transpose() * r_bj));
    // dR(bg + d) = dR(bg) Exp(J_r(phi) J d); Log(Exp(-a) Exp(r)) ~ r - J_l^-1(r) a
    // with J_l^-1(r) = J_r^-1(-r).
    let jac = -right_jacobian_inverse(&(-r)) * right_jacobian(&phi) * pre.d_R_d_bg;
    (r, jac)
}

fn gyro_bias(frames: &[Frame], intervals: &[Preintegrated], iterations: usize) -> GyroBiasEstimate {
    let mut bg = intervals[0].biases.gyro_rad_s;
    let mut info = Matrix3::identity();
    let weight = |pre: &Preintegrated| {
        let c: Matrix3<f64> = pre.covariance.fixed_view::<3, 3>(0, 0).into();
        c.try_inverse()
            .filter(|w| w.iter().all(|v| v.is_finite()))
            .unwrap_or_else(Matrix3::identity)
    };
    for _ in 0..iterations {
        let mut h = Matrix3::zeros();
        let mut g = Vector3::zeros();
        for (k, pre) in intervals.iter().enumerate() {
            let (r, j) = rotation_residual(pre, &frames[k].r_c0_b, &frames[k + 1].r_c0_b, &bg);
            let w = weight(pre);
            h += j.transpose() * w * j;
            g += j.transpose() * w * r;
        }
        let Some(h_inv) = h.try_inverse() else { break };
        bg -= h_inv * g;
        info = h;
    }
    let (mut chi2, mut sum_sq) = (0.0, 0.0);
    for (k, pre) in intervals.iter().enumerate() {
        let (r, _) = rotation_residual(pre, &frames[k].r_c0_b, &frames[k + 1].r_c0_b, &bg);
        chi2 += r.dot(&(weight(pre) * r));
        sum_sq += r.norm_squared();
    }
    let dof = (3 * intervals.len()).saturating_sub(3).max(1) as f64;
    let inflation = (chi2 / dof).max(1.0);
    let cov = info
        .try_inverse()
        .unwrap_or_else(|| Matrix3::from_element(f64::INFINITY));
    GyroBiasEstimate {
        gyro_rad_s: bg,
        sigma_rad_s: cov.diagonal().map(|v| (v * inflation).abs().sqrt()),
        rotation_rms_rad: (sum_sq / intervals.len() as f64).sqrt(),
    }
}

/// Where the unknowns sit in the linear system.
#[derive(Debug, Clone, Copy)]
struct Layout {
    keyframes: usize,
    /// 3 (free gravity) or 2 (tangent update).
    gravity_cols: usize,
    scale: bool,
    accel_bias: bool,
}

impl Layout {
    fn gravity(&self) -> usize {
        3 * self.keyframes
    }
    fn scale(&self) -> usize {
        self.gravity() + self.gravity_cols
    }
    fn accel_bias(&self) -> usize {
        self.scale() + usize::from(self.scale)
    }
    fn cols(&self) -> usize {
        self.accel_bias() + if self.accel_bias { 3 } else { 0 }
    }
}

/// One interval with its deltas corrected to the gyro bias and its
/// whitening matrix.
struct Interval {
    dt: f64,
    dv: Vector3<f64>,
    dp: Vector3<f64>,
    dv_dba: Matrix3<f64>,
    dp_dba: Matrix3<f64>,
    ba0: Vector3<f64>,
    /// `L^-1` with `L L^T` the covariance of `(R_bi dv, R_bi dp)`.
    whiten: Matrix6<f64>,
}

fn prepare_intervals(
    frames: &[Frame],
    intervals: &[Preintegrated],
    bg: &Vector3<f64>,
    vision_position_sigma_m: f64,
) -> Vec<Interval> {
    intervals
        .iter()
        .enumerate()
        .map(|(k, pre)| {
            let biases = ImuBiases {
                gyro_rad_s: *bg,
                accel_m_s2: pre.biases.accel_m_s2,
            };
            let d = pre.corrected(&biases);
            let r = frames[k].r_c0_b;
            let mut rot6 = Matrix6::zeros();
            rot6.fixed_view_mut::<3, 3>(0, 0).copy_from(&r);
            rot6.fixed_view_mut::<3, 3>(3, 3).copy_from(&r);
            let cov: Matrix6<f64> = pre.covariance.fixed_view::<6, 6>(3, 3).into();
            let mut cov = rot6 * cov * rot6.transpose();
            // Two keyframe positions enter each position row.
            for d in 3..6 {
                cov[(d, d)] += 2.0 * vision_position_sigma_m * vision_position_sigma_m;
            }
            let whiten = cov
                .cholesky()
                .and_then(|c| c.l().try_inverse())
                .filter(|w| w.iter().all(|v| v.is_finite()))
                .unwrap_or_else(Matrix6::identity);
            Interval {
                dt: pre.dt_s,
                dv: d.delta_v_m_s,
                dp: d.delta_p_m,
                dv_dba: pre.d_v_d_ba,
                dp_dba: pre.d_p_d_ba,
                ba0: pre.biases.accel_m_s2,
                whiten,
            }
        })
        .collect()
}

/// The gravity unknowns: free (3) or a tangent update of `g0` along the
/// columns of `basis` (2, already multiplied by |g| so the unknowns are
/// angles).
#[derive(Clone, Copy)]
enum GravityParam {
    Free,
    Tangent {
        g0: Vector3<f64>,
        basis: Matrix3x2<f64>,
    },
}

/// The whitened system `A x = b` (module documentation, step 2).
fn build_system(
    frames: &[Frame],
    intervals: &[Interval],
    p_bc: &Vector3<f64>,
    layout: Layout,
    gravity: GravityParam,
    scale: ScaleMode,
    accel_prior: (Vector3<f64>, f64),
) -> (DMatrix<f64>, DVector<f64>) {
    let n = layout.cols();
    let m = 6 * intervals.len() + if layout.accel_bias { 3 } else { 0 };
    let mut a = DMatrix::zeros(m, n);
    let mut b = DVector::zeros(m);
    let mut raw = DMatrix::zeros(6, n);
    for (k, it) in intervals.iter().enumerate() {
        raw.fill(0.0);
        let (fi, fj) = (&frames[k], &frames[k + 1]);
        let r_bi = fi.r_c0_b;
        let dt = it.dt;
        let id = Matrix3::identity();
        // Velocity rows 0..3, position rows 3..6.
        raw.fixed_view_mut::<3, 3>(0, 3 * k).copy_from(&(-id));
        raw.fixed_view_mut::<3, 3>(0, 3 * (k + 1)).copy_from(&id);
        raw.fixed_view_mut::<3, 3>(3, 3 * k).copy_from(&(-id * dt));
        let mut rhs_v = r_bi * (it.dv - it.dv_dba * it.ba0);
        let mut rhs_p = r_bi * (it.dp - it.dp_dba * it.ba0) + (fj.r_c0_b - r_bi) * p_bc;
        let gc = layout.gravity();
        match gravity {
            GravityParam::Free => {
                raw.fixed_view_mut::<3, 3>(0, gc).copy_from(&(-id * dt));
                raw.fixed_view_mut::<3, 3>(3, gc)
                    .copy_from(&(-id * (0.5 * dt * dt)));
            }
            GravityParam::Tangent { g0, basis } => {
                raw.fixed_view_mut::<3, 2>(0, gc).copy_from(&(-basis * dt));
                raw.fixed_view_mut::<3, 2>(3, gc)
                    .copy_from(&(-basis * (0.5 * dt * dt)));
                rhs_v += g0 * dt;
                rhs_p += g0 * (0.5 * dt * dt);
            }
        }
        let dpc = fj.p_c0_c - fi.p_c0_c;
        match scale {
            ScaleMode::Estimate => raw
                .fixed_view_mut::<3, 1>(3, layout.scale())
                .copy_from(&dpc),
            ScaleMode::Known(s) => rhs_p -= dpc * s,
        }
        if layout.accel_bias {
            let c = layout.accel_bias();
            raw.fixed_view_mut::<3, 3>(0, c)
                .copy_from(&(-r_bi * it.dv_dba));
            raw.fixed_view_mut::<3, 3>(3, c)
                .copy_from(&(-r_bi * it.dp_dba));
        }
        let mut rhs = SMatrix::<f64, 6, 1>::zeros();
        rhs.fixed_view_mut::<3, 1>(0, 0).copy_from(&rhs_v);
        rhs.fixed_view_mut::<3, 1>(3, 0).copy_from(&rhs_p);
        let w = DMatrix::from_column_slice(6, 6, it.whiten.as_slice());
        a.rows_mut(6 * k, 6).copy_from(&(&w * &raw));
        b.rows_mut(6 * k, 6).copy_from(&(it.whiten * rhs));
    }
    if layout.accel_bias {
        // The prior, whitened: (b_a - prior) / sigma.
        let (mean, sigma) = accel_prior;
        let (r, c) = (6 * intervals.len(), layout.accel_bias());
        for axis in 0..3 {
            a[(r + axis, c + axis)] = 1.0 / sigma;
            b[r + axis] = mean[axis] / sigma;
        }
    }
    (a, b)
}

/// Least-squares solution with per-unknown variances.
struct Solution {
    x: DVector<f64>,
    /// Variances, already inflated by the reduced chi-square when above
    /// 1; infinite for unknowns the system does not fix.
    var: DVector<f64>,
    rss: f64,
    rows: usize,
}

/// Solves `A x = b` by SVD of the column-equilibrated `A`, dropping
/// singular values below `1e-10` of the largest. `None` when there are
/// fewer rows than unknowns or `A` is zero.
fn solve(a: &DMatrix<f64>, b: &DVector<f64>) -> Option<Solution> {
    let (m, n) = a.shape();
    if m < n || n == 0 {
        return None;
    }
    let norms: Vec<f64> = (0..n)
        .map(|c| {
            let v = a.column(c).norm();
            if v > 0.0 {
                v
            } else {
                1.0
            }
        })
        .collect();
    let mut scaled = a.clone();
    for (c, s) in norms.iter().enumerate() {
        scaled.column_mut(c).scale_mut(1.0 / s);
    }
    let svd = scaled.svd(true, true);
    let (u, v_t) = (svd.u.as_ref()?, svd.v_t.as_ref()?);
    let sv = &svd.singular_values;
    let s_max = sv.max();
    if !(s_max > 0.0 && s_max.is_finite()) {
        return None;
    }
    let tol = s_max * 1e-10;
    let mut x = DVector::zeros(n);
    let mut var = DVector::zeros(n);
    for k in 0..sv.len() {
        let row = v_t.row(k);
        if sv[k] > tol {
            let coef = u.column(k).dot(b) / sv[k];
            for j in 0..n {
                x[j] += coef * row[j];
                var[j] += (row[j] / sv[k]).powi(2);
            }
        } else {
            for j in 0..n {
                if row[j].abs() > 1e-6 {
                    var[j] = f64::INFINITY;
                }
            }
        }
    }
    let rank = sv.iter().filter(|s| **s > tol).count();
    for j in 0..n {
        x[j] /= norms[j];
        var[j] /= norms[j] * norms[j];
    }
    let rss = (a * &x - b).norm_squared();
    let dof = m.saturating_sub(rank);
    if dof > 0 {
        var *= (rss / dof as f64).max(1.0);
    }
    Some(Solution {
        x,
        var,
        rss,
        rows: m,
    })
}

/// Steps 1-3 (module documentation) on preintegrated intervals. The
/// deltas are corrected to the new gyro bias to first order; when that
/// bias is far from the integration bias (more than ~0.01 rad/s over
/// intervals of 0.25 s), [`align_with_reintegration`] is more accurate.
#[allow(non_snake_case)]
pub fn align(
    keyframes: &[VisionKeyframe],
    intervals: &[Preintegrated],
    T_body_cam: &Isometry3<f64>,
    scale: ScaleMode,
    config: &AlignmentConfig,
) -> Result<Alignment, AlignmentError> {
    check_inputs(keyframes, intervals, T_body_cam, config)?;
    if let ScaleMode::Known(s) = scale {
        if !(s > 0.0 && s.is_finite()) {
            return Err(AlignmentError::InvalidConfig {
                key: "scale",
                value: s,
                allowed: "> 0",
            });
        }
    }
    let frames = frames(keyframes, T_body_cam);
    let p_bc = T_body_cam.translation.vector;
    let gyro = gyro_bias(&frames, intervals, config.gyro_bias_iterations.max(1));
    let prepared = prepare_intervals(
        &frames,
        intervals,
        &gyro.gyro_rad_s,
        config.vision_position_sigma_m,
    );
    let estimate_scale = matches!(scale, ScaleMode::Estimate);
    let gravity_g = config.gravity_m_s2;

    // Step 2: free gravity.
    let layout = Layout {
        keyframes: keyframes.len(),
        gravity_cols: 3,
        scale: estimate_scale,
        accel_bias: false,
    };
    let accel_prior = (
        intervals[0].biases.accel_m_s2,
        config.accel_bias_prior_std_m_s2,
    );
    let (a, b) = build_system(
        &frames,
        &prepared,
        &p_bc,
        layout,
        GravityParam::Free,
        scale,
        accel_prior,
    );
    let free = solve(&a, &b).ok_or(AlignmentError::Degenerate(
        "the linear system has no solution",
    ))?;
    let g_free: Vector3<f64> = free.x.fixed_rows::<3>(layout.gravity()).into();
    let unconstrained_gravity_m_s2 = g_free.norm();
    if !(unconstrained_gravity_m_s2 > 1e-3 * gravity_g && unconstrained_gravity_m_s2.is_finite()) {
        return Err(AlignmentError::Degenerate("gravity came out zero"));
    }

    // Step 3: gravity on its sphere, with the accelerometer bias under its
    // prior.
    let mut g = g_free * (gravity_g / unconstrained_gravity_m_s2);
    let mut with_ba = config.estimate_accel_bias;
    let mut accel_bias_std_m_s2 = Vector3::from_element(f64::INFINITY);
    let mut last = None;
    for _ in 0..config.gravity_iterations.max(1) {
        loop {
            let layout = Layout {
                keyframes: keyframes.len(),
                gravity_cols: 2,
                scale: estimate_scale,
                accel_bias: with_ba,
            };
            let basis = tangent_basis(&g.normalize()) * gravity_g;
            let param = GravityParam::Tangent { g0: g, basis };
            let (a, b) = build_system(&frames, &prepared, &p_bc, layout, param, scale, accel_prior);
            let Some(sol) = solve(&a, &b) else {
                if with_ba {
                    with_ba = false;
                    continue;
                }
                return Err(AlignmentError::Degenerate(
                    "the refined system has no solution",
                ));
            };
            if with_ba {
                let c = layout.accel_bias();
                accel_bias_std_m_s2 =
                    Vector3::new(sol.var[c], sol.var[c + 1], sol.var[c + 2]).map(f64::sqrt);
            }
            let w = basis * sol.x.fixed_rows::<2>(layout.gravity());
            g = (g + w).normalize() * gravity_g;
            last = Some((sol, layout));
            break;
        }
    }
    let (sol, layout) = last.expect("at least one refinement iteration ran");

    let (scale_value, scale_std) = match scale {
        ScaleMode::Estimate => (sol.x[layout.scale()], sol.var[layout.scale()].sqrt()),
        ScaleMode::Known(s) => (s, 0.0),
    };
    if !(scale_value > 0.0) {
        return Err(AlignmentError::ScaleNotPositive {
            scale: scale_value,
            scale_std,
        });
    }
    let scale_rel_std = scale_std / scale_value;
    let accel_bias = if layout.accel_bias {
        sol.x.fixed_rows::<3>(layout.accel_bias()).into()
    } else {
        intervals[0].biases.accel_m_s2
    };
    let biases = ImuBiases {
        gyro_rad_s: gyro.gyro_rad_s,
        accel_m_s2: accel_bias,
    };
    let R_world_c0 = level_rotation(&(-g)).ok_or(AlignmentError::Degenerate("gravity"))?;
    let gc = layout.gravity();
    let gravity_std_rad = (sol.var[gc] + sol.var[gc + 1]).sqrt();
    let mut velocities_world_m_s = Vec::with_capacity(keyframes.len());
    let mut states = Vec::with_capacity(keyframes.len());
    for (k, (kf, f)) in keyframes.iter().zip(&frames).enumerate() {
        let v_c0: Vector3<f64> = sol.x.fixed_rows::<3>(3 * k).into();
        let v_world = R_world_c0 * v_c0;
        velocities_world_m_s.push(v_world);
        let r_c0_b = UnitQuaternion::from_matrix(&f.r_c0_b);
        let p_c0_b = f.p_c0_c * scale_value - f.r_c0_b * p_bc;
        states.push(KeyframeState {
            t_ns: kf.t_ns,
            T_world_body: Isometry3::from_parts((R_world_c0 * p_c0_b).into(), R_world_c0 * r_c0_b),
            velocity_world_m_s: v_world,
            biases,
        });
    }
    Ok(Alignment {
        scale: scale_value,
        scale_std,
        scale_rel_std,
        scale_certain: scale_rel_std <= config.max_scale_rel_std,
        gravity_c0_m_s2: g,
        gravity_std_rad,
        unconstrained_gravity_m_s2,
        R_world_c0,
        velocities_world_m_s,
        keyframes: states,
        biases,
        gyro_bias_sigma_rad_s: gyro.sigma_rad_s,
        accel_bias_estimated: layout.accel_bias,
        accel_bias_std_m_s2,
        residual_rms: (sol.rss / sol.rows as f64).sqrt(),
    })
}

/// [`align`] from raw samples: preintegrates the keyframe intervals with
/// `initial_biases`, estimates the gyro bias, preintegrates again with it
/// (so that a large bias is not applied only to first order), and aligns.
#[allow(non_snake_case)]
pub fn align_with_reintegration(
    keyframes: &[VisionKeyframe],
    samples: &[ImuSample],
    preintegrator: &mut Preintegrator,
    initial_biases: &ImuBiases,
    T_body_cam: &Isometry3<f64>,
    scale: ScaleMode,
    config: &AlignmentConfig,
) -> Result<Alignment, AlignmentError> {
    let integrate = |pre: &mut Preintegrator, biases: &ImuBiases| {
        keyframes
            .windows(2)
            .map(|w| pre.integrate(samples, w[0].t_ns, w[1].t_ns, biases))
            .collect::<Result<Vec<_>, _>>()
    };
    if keyframes.len() < 2 {
        return Err(AlignmentError::TooFewKeyframes {
            got: keyframes.len(),
            needed: config.min_keyframes.max(4),
        });
    }
    let first = integrate(preintegrator, initial_biases)?;
    let gyro = estimate_gyro_bias(keyframes, &first, T_body_cam, config)?;
    let biases = ImuBiases {
        gyro_rad_s: gyro.gyro_rad_s,
        accel_m_s2: initial_biases.accel_m_s2,
    };
    let second = integrate(preintegrator, &biases)?;
    align(keyframes, &second, T_body_cam, scale, config)
}

#[cfg(test)]
mod tests;
