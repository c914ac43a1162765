//! IMU propagation of the nominal state and of the error-state covariance.
//!
//! One step covers `[t, t + dt]` with constant bias-corrected rates
//! `w = w_m - b_g` and `a = a_m - b_a` (the mean of the two sample values
//! at the ends of the step, so a step between two samples is the
//! trapezoid rule on the inputs):
//!
//! ```text
//! R+ = R Exp(w dt)
//! a_w = R Exp(w dt / 2) a + g        (attitude at the step's midpoint)
//! v+ = v + a_w dt
//! p+ = p + v dt + a_w dt^2 / 2
//! ```
//!
//! [`step_transition`] is the exact Jacobian of this discrete map with
//! respect to the error state (right perturbation of R), so the
//! finite-difference test checks it to rounding. The process noise
//! ([`step_noise`]) turns Kalibr's continuous densities into the
//! discrete covariance of one step: white noise of density `s` enters as
//! variance `s^2 / dt` per sample and is integrated once (`s^2 dt` on the
//! attitude and velocity, `s^2 dt^3 / 4` on the position); the bias
//! random walks add `s_b^2 dt`.

use nalgebra::{Matrix3, Vector3};

use super::state::{Matrix15, NavNominal, BA, BG, POS, THETA, VEL};
use crate::imu::so3::{exp, exp_and_right_jacobian, hat};
use crate::imu::strapdown::gravity_world_m_s2;
use crate::rig::ImuNoise;

/// The nominal state after one step of `dt_s` with the raw (bias-included)
/// measurements `gyro_rad_s` and `accel_m_s2` held over the step.
pub(crate) fn step_nominal(
    x: &NavNominal,
    gyro_rad_s: &Vector3<f64>,
    accel_m_s2: &Vector3<f64>,
    dt_s: f64,
    dt_ns: i64,
) -> NavNominal {
    let w = gyro_rad_s - x.gyro_bias_rad_s;
    let a = accel_m_s2 - x.accel_bias_m_s2;
    let r = x.rotation();
    let half = exp(&(w * (0.5 * dt_s)));
    let a_world = r * (half * a) + gravity_world_m_s2();
    NavNominal {
        t_ns: x.t_ns + dt_ns,
        R_world_body: x.R_world_body * nalgebra::UnitQuaternion::from_scaled_axis(w * dt_s),
        position_world_m: x.position_world_m
            + x.velocity_world_m_s * dt_s
            + a_world * (0.5 * dt_s * dt_s),
        velocity_world_m_s: x.velocity_world_m_s + a_world * dt_s,
        gyro_bias_rad_s: x.gyro_bias_rad_s,
        accel_bias_m_s2: x.accel_bias_m_s2,
    }
}

/// Jacobian of [`step_nominal`] with respect to the 15 error states at
/// the start of the step (the error-state transition matrix Phi).
pub(crate) fn step_transition(
    x: &NavNominal,
    gyro_rad_s: &Vector3<f64>,
    accel_m_s2: &Vector3<f64>,
    dt_s: f64,
) -> Matrix15 {
    let w = gyro_rad_s - x.gyro_bias_rad_s;
    let a = accel_m_s2 - x.accel_bias_m_s2;
    let r = x.rotation();
    let (full, jr_full) = exp_and_right_jacobian(&(w * dt_s));
    let (half, jr_half) = exp_and_right_jacobian(&(w * (0.5 * dt_s)));
    let rh = r * half;
    // Derivatives of the world acceleration a_w.
    let da_dtheta: Matrix3<f64> = -r * hat(&(half * a));
    let da_dbg: Matrix3<f64> = rh * hat(&a) * jr_half * (0.5 * dt_s);
    let da_dba: Matrix3<f64> = -rh;
    let dt2 = 0.5 * dt_s * dt_s;
    let mut phi = Matrix15::identity();
    let mut set = |row: usize, col: usize, m: &Matrix3<f64>| {
        phi.fixed_view_mut::<3, 3>(row, col).copy_from(m);
    };
    set(THETA, THETA, &full.transpose());
    set(THETA, BG, &(-jr_full * dt_s));
    set(POS, THETA, &(da_dtheta * dt2));
    set(POS, VEL, &(Matrix3::identity() * dt_s));
    set(POS, BG, &(da_dbg * dt2));
    set(POS, BA, &(da_dba * dt2));
    set(VEL, THETA, &(da_dtheta * dt_s));
    set(VEL, BG, &(da_dbg * dt_s));
    set(VEL, BA, &(da_dba * dt_s));
    phi
}

/// Discrete process noise of one step of `dt_s` (see the module doc).
pub(crate) fn step_noise(noise: &ImuNoise, dt_s: f64) -> Matrix15 {
    let mut q = Matrix15::zeros();
    let sg2 = noise.gyroscope_noise_density.powi(2);
    let sa2 = noise.accelerometer_noise_density.powi(2);
    let bg2 = noise.gyroscope_random_walk.powi(2);
    let ba2 = noise.accelerometer_random_walk.powi(2);
    for i in 0..3 {
        q[(THETA + i, THETA + i)] = sg2 * dt_s;
        q[(VEL + i, VEL + i)] = sa2 * dt_s;
        q[(POS + i, POS + i)] = sa2 * dt_s.powi(3) / 4.0;
        q[(POS + i, VEL + i)] = sa2 * dt_s * dt_s / 2.0;
        q[(VEL + i, POS + i)] = sa2 * dt_s * dt_s / 2.0;
        q[(BG + i, BG + i)] = bg2 * dt_s;
        q[(BA + i, BA + i)] = ba2 * dt_s;
    }
    q
}
