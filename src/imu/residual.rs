//! The inertial residual between two states (the IMU term of the relative
//! stage's cost, eq. 29-40), with analytic Jacobians.
//!
//! With the deltas corrected to the biases at the start (first order):
//!
//! - `r_R = Log(dR(b)^T R_i^T R_j)`
//! - `r_v = R_i^T (v_j - v_i - g dt) - dv(b)`
//! - `r_p = R_i^T (p_j - p_i - v_i dt - g dt^2 / 2) - dp(b)`
//!
//! (Forster et al., TRO 2017, eq. 45). Residual order `[r_R, r_v, r_p]`.
//! State perturbations: `R <- R Exp(dphi)`, `v <- v + dv`, `p <- p + dp`
//! (world frame), in the order `[dphi, dv, dp]`; biases `[d b_g, d b_a]`.

use nalgebra::{Matrix3, SMatrix, SVector, Vector3};

use super::preintegration::Preintegrated;
use super::so3::{exp, hat, log, right_jacobian, right_jacobian_inverse};
use super::strapdown::{ImuBiases, NavState};

pub type Vector9 = SVector<f64, 9>;

/// The residual and its Jacobians.
#[derive(Debug, Clone, PartialEq)]
pub struct ImuResidual {
    pub residual: Vector9,
    /// d residual / d [dphi_i, dv_i, dp_i]
    pub d_state_i: SMatrix<f64, 9, 9>,
    /// d residual / d [dphi_j, dv_j, dp_j]
    pub d_state_j: SMatrix<f64, 9, 9>,
    /// d residual / d [d b_g, d b_a] (biases at the start)
    pub d_biases: SMatrix<f64, 9, 6>,
    /// d residual / d gravity (world frame)
    pub d_gravity: SMatrix<f64, 9, 3>,
}

/// The residual of `pre` between `state_i` and `state_j` for the biases
/// `biases_i`, with gravity `gravity_world_m_s2`.
pub fn imu_residual(
    pre: &Preintegrated,
    state_i: &NavState,
    state_j: &NavState,
    biases_i: &ImuBiases,
    gravity_world_m_s2: &Vector3<f64>,
) -> ImuResidual {
    let t = pre.dt_s;
    let r_i = state_i.R_world_body.to_rotation_matrix().into_inner();
    let r_j = state_j.R_world_body.to_rotation_matrix().into_inner();
    let r_it = r_i.transpose();
    let d = pre.corrected(biases_i);
    let g = gravity_world_m_s2;

    let error_r = d.delta_R.transpose() * r_it * r_j;
    let res_r = log(&error_r);
    let u = state_j.velocity_world_m_s - state_i.velocity_world_m_s - g * t;
    let w = state_j.position_world_m
        - state_i.position_world_m
        - state_i.velocity_world_m_s * t
        - g * (0.5 * t * t);
    let res_v = r_it * u - d.delta_v_m_s;
    let res_p = r_it * w - d.delta_p_m;

    let jr_inv = right_jacobian_inverse(&res_r);
    let mut d_state_i = SMatrix::<f64, 9, 9>::zeros();
    let mut d_state_j = SMatrix::<f64, 9, 9>::zeros();
    let mut d_biases = SMatrix::<f64, 9, 6>::zeros();
    let mut d_gravity = SMatrix::<f64, 9, 3>::zeros();
    let set = |m: &mut SMatrix<f64, 9, 9>, r: usize, c: usize, b: Matrix3<f64>| {
        m.fixed_view_mut::<3, 3>(3 * r, 3 * c).copy_from(&b);
    };
    // Rotation row.
    set(&mut d_state_i, 0, 0, -jr_inv * r_j.transpose() * r_i);
    set(&mut d_state_j, 0, 0, jr_inv);
    // Velocity row.
    set(&mut d_state_i, 1, 0, hat(&(r_it * u)));
    set(&mut d_state_i, 1, 1, -r_it);
    set(&mut d_state_j, 1, 1, r_it);
    // Position row.
    set(&mut d_state_i, 2, 0, hat(&(r_it * w)));
    set(&mut d_state_i, 2, 1, -r_it * t);
    set(&mut d_state_i, 2, 2, -r_it);
    set(&mut d_state_j, 2, 2, r_it);

    let c = pre.d_R_d_bg * (biases_i.gyro_rad_s - pre.biases.gyro_rad_s);
    let d_r_bg = -jr_inv * exp(&res_r).transpose() * right_jacobian(&c) * pre.d_R_d_bg;
    d_biases.fixed_view_mut::<3, 3>(0, 0).copy_from(&d_r_bg);
    d_biases
        .fixed_view_mut::<3, 3>(3, 0)
        .copy_from(&-pre.d_v_d_bg);
    d_biases
        .fixed_view_mut::<3, 3>(3, 3)
        .copy_from(&-pre.d_v_d_ba);
    d_biases
        .fixed_view_mut::<3, 3>(6, 0)
        .copy_from(&-pre.d_p_d_bg);
    d_biases
        .fixed_view_mut::<3, 3>(6, 3)
        .copy_from(&-pre.d_p_d_ba);
    d_gravity
        .fixed_view_mut::<3, 3>(3, 0)
        .copy_from(&(-r_it * t));
    d_gravity
        .fixed_view_mut::<3, 3>(6, 0)
        .copy_from(&(-r_it * (0.5 * t * t)));

    let mut residual = Vector9::zeros();
    residual.fixed_rows_mut::<3>(0).copy_from(&res_r);
    residual.fixed_rows_mut::<3>(3).copy_from(&res_v);
    residual.fixed_rows_mut::<3>(6).copy_from(&res_p);
    ImuResidual {
        residual,
        d_state_i,
        d_state_j,
        d_biases,
        d_gravity,
    }
}
