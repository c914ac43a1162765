//! The inertial terms of the window's cost (eq. 29, 32-33): the
//! preintegrated residual between consecutive keyframes
//! ([`crate::imu::imu_residual`], whitened by the interval's covariance)
//! and the bias random walk between their biases; and the gravity
//! parameterisation.
//!
//! Gravity: the world frame is the one the fixed keyframes live in; its
//! gravity is `9.81 d` with `d` a unit direction estimated as a 2-DoF
//! state, `d <- Exp(B delta) d` with `B` an orthonormal basis of the plane
//! orthogonal to `d`. The initialiser's alignment makes `d = (0, 0, -1)`;
//! the eq. 34 prior keeps it near its previous estimate, and the fixed
//! keyframes hold position and yaw.

use nalgebra::{Matrix3x2, SMatrix, SVector, Vector2, Vector3, Vector6};

use super::inertial_link::InertialLink;
use super::state::{nav_state, BA, BG, FULL_DIM, POS, ROT, VEL};
use crate::imu::so3::{exp, hat};
use crate::imu::{bias_walk_covariance, imu_residual, GRAVITY_M_S2};
use crate::relative::types::KeyframeState;
use crate::rig::ImuNoise;

/// Columns of an inertial factor's Jacobian: keyframe i (15), keyframe j
/// (15), gravity direction (2).
pub const INERTIAL_COLS: usize = 2 * FULL_DIM + 2;
/// First of the two gravity-direction columns (the step `delta` in the
/// tangent plane, see [`tangent_basis`]) in an inertial factor's Jacobian.
pub const GRAVITY_COL: usize = 2 * FULL_DIM;

/// `1 / sigma` of the bias change over `dt_s` under the random walk.
pub(crate) fn bias_walk_sqrt_info(noise: &ImuNoise, dt_s: f64) -> Vector6<f64> {
    bias_walk_covariance(noise, dt_s.max(1e-6))
        .diagonal()
        .map(|v| 1.0 / v.max(1e-18).sqrt())
}

/// An orthonormal basis of the plane orthogonal to the unit vector `d`,
/// by Gram-Schmidt: `b1` is a coordinate axis far from `d` with its
/// component along `d` removed, `b2 = d x b1`. It spans the same plane as
/// `crate::imu::so3::tangent_basis` (a quarter turn apart); the window's
/// gravity steps and every trajectory measured with them use this one,
/// and switching would change their floating-point path.
pub fn tangent_basis(d: &Vector3<f64>) -> Matrix3x2<f64> {
    let a = if d.x.abs() < 0.9 {
        Vector3::x()
    } else {
        Vector3::y()
    };
    let b1 = (a - d * a.dot(d)).normalize();
    let b2 = d.cross(&b1);
    Matrix3x2::from_columns(&[b1, b2])
}

/// `d gravity / d delta` at `delta = 0`: `Exp(B delta) d ~ d - [d]x B delta`.
pub fn gravity_jacobian(d: &Vector3<f64>, basis: &Matrix3x2<f64>) -> Matrix3x2<f64> {
    -hat(d) * basis * GRAVITY_M_S2
}

/// The direction after the step `delta`.
pub fn update_direction(
    d: &Vector3<f64>,
    basis: &Matrix3x2<f64>,
    delta: &Vector2<f64>,
) -> Vector3<f64> {
    (exp(&(basis * delta)) * d).normalize()
}

/// Whitened inertial residual between keyframes i and j and its
/// Jacobian, columns `[i: dphi dp dv dbg dba | j: same | gravity 2]`.
pub(crate) fn inertial_factor(
    link: &InertialLink,
    si: &KeyframeState,
    sj: &KeyframeState,
    gravity_dir: &Vector3<f64>,
    basis: &Matrix3x2<f64>,
) -> (SVector<f64, 9>, SMatrix<f64, 9, INERTIAL_COLS>) {
    let g = gravity_dir * GRAVITY_M_S2;
    let res = imu_residual(&link.pre, &nav_state(si), &nav_state(sj), &si.biases, &g);
    let mut j = SMatrix::<f64, 9, INERTIAL_COLS>::zeros();
    // imu_residual orders each state as [dphi, dv, dp].
    for (base, d_state) in [(0, &res.d_state_i), (FULL_DIM, &res.d_state_j)] {
        j.fixed_view_mut::<9, 3>(0, base + ROT)
            .copy_from(&d_state.fixed_view::<9, 3>(0, 0));
        j.fixed_view_mut::<9, 3>(0, base + VEL)
            .copy_from(&d_state.fixed_view::<9, 3>(0, 3));
        j.fixed_view_mut::<9, 3>(0, base + POS)
            .copy_from(&d_state.fixed_view::<9, 3>(0, 6));
    }
    j.fixed_view_mut::<9, 6>(0, BG).copy_from(&res.d_biases);
    debug_assert_eq!(BA, BG + 3);
    j.fixed_view_mut::<9, 2>(0, GRAVITY_COL)
        .copy_from(&(res.d_gravity * gravity_jacobian(gravity_dir, basis)));
    (link.sqrt_info * res.residual, link.sqrt_info * j)
}

/// Whitened bias random walk `b_j - b_i` and its Jacobian, columns
/// `[i: dbg dba | j: dbg dba]`.
pub(crate) fn bias_walk_factor(
    sqrt_info: &Vector6<f64>,
    si: &KeyframeState,
    sj: &KeyframeState,
) -> (SVector<f64, 6>, SMatrix<f64, 6, 12>) {
    let mut r = SVector::<f64, 6>::zeros();
    r.fixed_rows_mut::<3>(0)
        .copy_from(&(sj.biases.gyro_rad_s - si.biases.gyro_rad_s));
    r.fixed_rows_mut::<3>(3)
        .copy_from(&(sj.biases.accel_m_s2 - si.biases.accel_m_s2));
    let mut j = SMatrix::<f64, 6, 12>::zeros();
    for k in 0..6 {
        j[(k, k)] = -sqrt_info[k];
        j[(k, 6 + k)] = sqrt_info[k];
    }
    (r.component_mul(sqrt_info), j)
}
