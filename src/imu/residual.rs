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

/// 9-vector `[r_R, r_v, r_p]` (rad, m/s, m), the inertial residual's layout.
pub type Vector9 = SVector<f64, 9>;

/// The residual and its Jacobians.
#[derive(Debug, Clone, PartialEq)]
pub struct ImuResidual {
    /// `[r_R, r_v, r_p]`, unweighted (rad, m/s, m).
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::imu::preintegration::{IntegrationScheme, Preintegrator};
    use crate::rig::ImuNoise;
    use crate::sensors::ImuSample;
    use nalgebra::UnitQuaternion;

    fn preintegrated() -> Preintegrated {
        let samples: Vec<ImuSample> = (-1..=22)
            .map(|k| {
                let t = k as f64 * 0.005;
                ImuSample {
                    t_ns: k * 5_000_000,
                    gyro_rad_s: [0.4 * (4.0 * t).sin(), 0.9, -0.6 + t],
                    accel_m_s2: [1.0 + t, 9.0 * (2.0 * t).cos(), 2.0 * (3.0 * t).sin()],
                }
            })
            .collect();
        let biases = ImuBiases {
            gyro_rad_s: Vector3::new(0.01, 0.02, -0.01),
            accel_m_s2: Vector3::new(0.05, -0.1, 0.02),
        };
        Preintegrator::new(IntegrationScheme::Quadratic, ImuNoise::EUROC_ADIS16448)
            .integrate(&samples, 2_000_000, 101_000_000, &biases)
            .expect("covered")
    }

    fn state(seed: f64) -> NavState {
        NavState {
            t_ns: 0,
            R_world_body: UnitQuaternion::from_scaled_axis(Vector3::new(0.3, -1.1, 2.0) * seed),
            position_world_m: Vector3::new(1.0, -2.0, 0.5) * seed,
            velocity_world_m_s: Vector3::new(0.3, 0.2, -0.4) / seed,
        }
    }

    fn perturb(s: &NavState, k: usize, eps: f64) -> NavState {
        let mut d = Vector3::zeros();
        d[k % 3] = eps;
        let mut out = *s;
        match k / 3 {
            0 => out.R_world_body = s.R_world_body * UnitQuaternion::from_scaled_axis(d),
            1 => out.velocity_world_m_s += d,
            _ => out.position_world_m += d,
        }
        out
    }

    /// Biases away from the integration point, so the bias Jacobians are
    /// tested where the correction is not the identity.
    fn biases_i(pre: &Preintegrated) -> ImuBiases {
        ImuBiases {
            gyro_rad_s: pre.biases.gyro_rad_s + Vector3::new(3e-3, -2e-3, 4e-3),
            accel_m_s2: pre.biases.accel_m_s2 + Vector3::new(0.03, 0.01, -0.02),
        }
    }

    fn check(analytic: &SMatrix<f64, 9, 1>, numeric: &SMatrix<f64, 9, 1>, what: &str) {
        let err = (analytic - numeric).norm();
        assert!(
            err < 1e-7 * (1.0 + analytic.norm()),
            "{what}: analytic {analytic} numeric {numeric}"
        );
    }

    #[test]
    fn jacobians_match_finite_differences() {
        let pre = preintegrated();
        let g = Vector3::new(0.1, -0.2, -9.81);
        let (si, sj) = (state(0.7), state(1.3));
        let b = biases_i(&pre);
        let res = imu_residual(&pre, &si, &sj, &b, &g);
        let eps = 1e-6;
        for k in 0..9 {
            let f = |s: &NavState| imu_residual(&pre, s, &sj, &b, &g).residual;
            let num = (f(&perturb(&si, k, eps)) - f(&perturb(&si, k, -eps))) / (2.0 * eps);
            check(
                &res.d_state_i.column(k).into_owned(),
                &num,
                &format!("state i {k}"),
            );
            let f = |s: &NavState| imu_residual(&pre, &si, s, &b, &g).residual;
            let num = (f(&perturb(&sj, k, eps)) - f(&perturb(&sj, k, -eps))) / (2.0 * eps);
            check(
                &res.d_state_j.column(k).into_owned(),
                &num,
                &format!("state j {k}"),
            );
        }
        for k in 0..6 {
            let f = |sign: f64| {
                let mut bb = b;
                if k < 3 {
                    bb.gyro_rad_s[k] += sign * eps;
                } else {
                    bb.accel_m_s2[k - 3] += sign * eps;
                }
                imu_residual(&pre, &si, &sj, &bb, &g).residual
            };
            let num = (f(1.0) - f(-1.0)) / (2.0 * eps);
            check(
                &res.d_biases.column(k).into_owned(),
                &num,
                &format!("bias {k}"),
            );
        }
        for k in 0..3 {
            let f = |sign: f64| {
                let mut gg = g;
                gg[k] += sign * eps;
                imu_residual(&pre, &si, &sj, &b, &gg).residual
            };
            let num = (f(1.0) - f(-1.0)) / (2.0 * eps);
            check(
                &res.d_gravity.column(k).into_owned(),
                &num,
                &format!("gravity {k}"),
            );
        }
        // The residual is far from zero here, so the tests are not trivial.
        assert!(res.residual.fixed_rows::<3>(0).norm() > 0.5);
    }

    #[test]
    fn predicted_state_has_zero_residual() {
        let pre = preintegrated();
        let g = Vector3::new(0.0, 0.0, -9.81);
        let si = state(0.9);
        let b = biases_i(&pre);
        let sj = pre.predict(&si, &b, &g);
        let res = imu_residual(&pre, &si, &sj, &b, &g);
        assert!(res.residual.norm() < 1e-12, "{}", res.residual);
        // And a shifted end state shows up in the right rows.
        let mut moved = sj;
        moved.position_world_m += Vector3::new(0.0, 0.01, 0.0);
        let res = imu_residual(&pre, &si, &moved, &b, &g);
        assert!(res.residual.fixed_rows::<6>(0).norm() < 1e-12);
        assert!((res.residual.fixed_rows::<3>(6).norm() - 0.01).abs() < 1e-12);
    }
}
