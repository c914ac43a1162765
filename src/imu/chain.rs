//! Two consecutive preintegrated intervals joined into one: the deltas,
//! their bias Jacobians and the white-noise covariance of the whole
//! span, without the samples. Used to test how the IMU agrees with the
//! images over several keyframe links at once (an error that is slow
//! against one link is plain over a few).
//!
//! With `A` from `i` to `j` and `B` from `j` to `k`, both at the same
//! biases: `dR = dR_A dR_B`, `dv = dv_A + dR_A dv_B`, `dp = dp_A + dv_A
//! dt_B + dR_A dp_B`. Their errors `[phi, v, p]` (the convention of
//! [`super::preintegration`]: the rotation's error on the right) combine
//! as `phi = dR_B^T phi_A + phi_B`, `v = v_A - dR_A [dv_B]x phi_A + dR_A
//! v_B`, `p = p_A + dt_B v_A - dR_A [dp_B]x phi_A + dR_A p_B`; `A`'s and
//! `B`'s noise are independent.

use nalgebra::Matrix3;

use super::preintegration::{Matrix9, Preintegrated};
use super::so3::hat;
use super::strapdown::ImuBiases;

/// `first` followed by `second` (which must start where `first` ends),
/// both corrected to `biases` first (to first order, by their bias
/// Jacobians); the result is linearised at `biases`. None when the two
/// do not meet.
pub fn join(
    first: &Preintegrated,
    second: &Preintegrated,
    biases: &ImuBiases,
) -> Option<Preintegrated> {
    join_with_transport(first, second, biases).map(|(joined, _, _)| joined)
}

/// [`join`], and how the two parts' errors `[phi, v, p]` reach the
/// joined one: `e = F e_first + G e_second`. The residuals of
/// [`super::imu_residual`] are errors of the same kind, so the joined
/// residual is `F r_first + G r_second` to first order, whatever the
/// state at the joint.
pub fn join_with_transport(
    first: &Preintegrated,
    second: &Preintegrated,
    biases: &ImuBiases,
) -> Option<(Preintegrated, Matrix9, Matrix9)> {
    if first.t_end_ns != second.t_start_ns {
        return None;
    }
    let a = first.corrected(biases);
    let b = second.corrected(biases);
    let (ra, rb) = (a.delta_R, b.delta_R);
    let dt_b = second.dt_s;
    let mut f = Matrix9::identity();
    f.fixed_view_mut::<3, 3>(0, 0).copy_from(&rb.transpose());
    f.fixed_view_mut::<3, 3>(3, 0)
        .copy_from(&-(ra * hat(&b.delta_v_m_s)));
    f.fixed_view_mut::<3, 3>(6, 0)
        .copy_from(&-(ra * hat(&b.delta_p_m)));
    f.fixed_view_mut::<3, 3>(6, 3)
        .copy_from(&(Matrix3::identity() * dt_b));
    let mut g = Matrix9::identity();
    g.fixed_view_mut::<3, 3>(3, 3).copy_from(&ra);
    g.fixed_view_mut::<3, 3>(6, 6).copy_from(&ra);
    let spread = |ca: &Matrix9, cb: &Matrix9| {
        let c = f * ca * f.transpose() + g * cb * g.transpose();
        (c + c.transpose()) * 0.5
    };
    // Bias Jacobians of the joined deltas at `biases`.
    let (ja, jb) = (&first.d_R_d_bg, &second.d_R_d_bg);
    let joined = Preintegrated {
        t_start_ns: first.t_start_ns,
        t_end_ns: second.t_end_ns,
        dt_s: first.dt_s + dt_b,
        scheme: first.scheme,
        biases: *biases,
        delta_R: ra * rb,
        delta_v_m_s: a.delta_v_m_s + ra * b.delta_v_m_s,
        delta_p_m: a.delta_p_m + a.delta_v_m_s * dt_b + ra * b.delta_p_m,
        covariance: spread(&first.covariance, &second.covariance),
        covariance_gyro: spread(&first.covariance_gyro, &second.covariance_gyro),
        d_R_d_bg: rb.transpose() * ja + jb,
        d_v_d_bg: first.d_v_d_bg + ra * second.d_v_d_bg - ra * hat(&b.delta_v_m_s) * ja,
        d_v_d_ba: first.d_v_d_ba + ra * second.d_v_d_ba,
        d_p_d_bg: first.d_p_d_bg + first.d_v_d_bg * dt_b + ra * second.d_p_d_bg
            - ra * hat(&b.delta_p_m) * ja,
        d_p_d_ba: first.d_p_d_ba + first.d_v_d_ba * dt_b + ra * second.d_p_d_ba,
        steps: first.steps + second.steps,
        reliable: first.reliable && second.reliable,
    };
    Some((joined, f, g))
}

/// Consecutive intervals joined one by one, with the transport of each
/// part's error into the joined one.
#[derive(Debug, Clone)]
pub struct JoinedIntervals {
    /// The intervals so far as one, linearised at `biases`.
    pub joined: Preintegrated,
    /// Per part, `T_m`: the joined error is `sum T_m e_m`.
    pub transport: Vec<Matrix9>,
    biases: ImuBiases,
}

impl JoinedIntervals {
    /// One interval, joined with the next ones at `biases`.
    pub fn new(first: &Preintegrated, biases: &ImuBiases) -> Self {
        Self {
            joined: first.clone(),
            transport: vec![Matrix9::identity()],
            biases: *biases,
        }
    }

    /// Appends `next`; false (and nothing changed) when it does not
    /// start where the joined intervals end.
    pub fn push(&mut self, next: &Preintegrated) -> bool {
        match join_with_transport(&self.joined, next, &self.biases) {
            Some((joined, f, g)) => {
                self.joined = joined;
                for t in self.transport.iter_mut() {
                    *t = f * *t;
                }
                self.transport.push(g);
                true
            }
            None => false,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::imu::preintegration::{IntegrationScheme, Preintegrator};
    use crate::imu::so3::log;
    use crate::rig::ImuNoise;
    use crate::sensors::ImuSample;
    use nalgebra::Vector3;

    /// A turning, accelerating motion sampled at 200 Hz over [0, 0.6] s.
    fn samples() -> Vec<ImuSample> {
        (0..=120)
            .map(|k| {
                let t = k as f64 * 0.005;
                ImuSample {
                    t_ns: k * 5_000_000,
                    gyro_rad_s: [0.9 * (3.0 * t).sin(), -0.4 + 0.7 * t, 1.1 * (2.0 * t).cos()],
                    accel_m_s2: [0.3 + (5.0 * t).sin(), 9.81 * t.cos(), -2.0 * t * t + 0.4],
                }
            })
            .collect()
    }

    fn integrator() -> Preintegrator {
        Preintegrator::new(IntegrationScheme::Euler, ImuNoise::EUROC_ADIS16448)
    }

    fn at(g: f64, a: f64) -> ImuBiases {
        ImuBiases {
            gyro_rad_s: Vector3::new(0.01, -0.02, 0.015) * g,
            accel_m_s2: Vector3::new(0.1, -0.05, 0.2) * a,
        }
    }

    /// Joining [0, 0.25] and [0.25, 0.6] gives what integrating [0, 0.6]
    /// gives: deltas, covariance (both parts) and bias Jacobians. The
    /// split falls on a sample, so Euler's steps are the same.
    #[test]
    fn joined_halves_match_the_whole_interval() {
        let s = samples();
        let b = at(1.0, 1.0);
        let whole = integrator().integrate(&s, 0, 600_000_000, &b).unwrap();
        let first = integrator().integrate(&s, 0, 250_000_000, &b).unwrap();
        let second = integrator()
            .integrate(&s, 250_000_000, 600_000_000, &b)
            .unwrap();
        let j = join(&first, &second, &b).expect("they meet");
        let close = |x: f64, y: f64, what: &str| {
            assert!(
                (x - y).abs() <= 1e-9 * (1.0 + y.abs()),
                "{what}: {x} vs {y}"
            );
        };
        assert_eq!(j.t_start_ns, 0);
        assert_eq!(j.t_end_ns, 600_000_000);
        close(j.dt_s, whole.dt_s, "dt");
        assert!(log(&(j.delta_R.transpose() * whole.delta_R)).norm() < 1e-12);
        for k in 0..3 {
            close(j.delta_v_m_s[k], whole.delta_v_m_s[k], "dv");
            close(j.delta_p_m[k], whole.delta_p_m[k], "dp");
        }
        let rel = |x: &Matrix9, y: &Matrix9| (x - y).norm() / y.norm();
        assert!(rel(&j.covariance, &whole.covariance) < 1e-9);
        assert!(rel(&j.covariance_gyro, &whole.covariance_gyro) < 1e-9);
        for (x, y, what) in [
            (&j.d_R_d_bg, &whole.d_R_d_bg, "dR/dbg"),
            (&j.d_v_d_bg, &whole.d_v_d_bg, "dv/dbg"),
            (&j.d_v_d_ba, &whole.d_v_d_ba, "dv/dba"),
            (&j.d_p_d_bg, &whole.d_p_d_bg, "dp/dbg"),
            (&j.d_p_d_ba, &whole.d_p_d_ba, "dp/dba"),
        ] {
            assert!(
                (x - y).norm() <= 1e-9 * (1.0 + y.norm()),
                "{what}: {x} vs {y}"
            );
        }
    }

    /// Halves integrated at other biases are corrected to the join's
    /// biases first: what is left against the whole interval integrated
    /// at those biases is the first-order correction's error, which falls
    /// with the square of the bias difference.
    #[test]
    fn halves_at_other_biases_are_corrected_first() {
        let s = samples();
        let target = at(1.0, 1.0);
        let whole = integrator().integrate(&s, 0, 600_000_000, &target).unwrap();
        let error = |off: f64| {
            let first = integrator()
                .integrate(&s, 0, 250_000_000, &at(1.0 - off, 1.0 - off))
                .unwrap();
            let second = integrator()
                .integrate(
                    &s,
                    250_000_000,
                    600_000_000,
                    &at(1.0 + off, 1.0 + 0.5 * off),
                )
                .unwrap();
            let j = join(&first, &second, &target).expect("they meet");
            assert_eq!(j.biases, target);
            [
                log(&(j.delta_R.transpose() * whole.delta_R)).norm(),
                (j.delta_v_m_s - whole.delta_v_m_s).norm(),
                (j.delta_p_m - whole.delta_p_m).norm(),
            ]
        };
        let (far, near) = (error(1.0), error(0.5));
        for k in 0..3 {
            let ratio = far[k] / near[k];
            assert!(
                (3.0..5.0).contains(&ratio),
                "delta {k}: {far:?} vs {near:?}"
            );
        }
        // Without the correction the velocity is off by far more.
        let first = integrator()
            .integrate(&s, 0, 250_000_000, &at(0.0, 0.0))
            .unwrap();
        let second = integrator()
            .integrate(&s, 250_000_000, 600_000_000, &target)
            .unwrap();
        let uncorrected = join(&first, &second, &first.biases).unwrap();
        assert!((uncorrected.delta_v_m_s - whole.delta_v_m_s).norm() > 100.0 * far[1]);
    }

    /// The residual of the joined intervals between the first and the
    /// last state is the transported sum of the parts' residuals, whatever
    /// the states at the joints: the mismatch falls with the square of
    /// how far the states are from agreeing with the IMU.
    #[test]
    fn joined_residual_is_the_transported_sum_of_the_parts() {
        use crate::imu::residual::imu_residual;
        use crate::imu::strapdown::NavState;
        use nalgebra::UnitQuaternion;
        let s = samples();
        let b = at(1.0, 1.0);
        let cuts = [0, 150_000_000, 350_000_000, 600_000_000];
        let parts: Vec<Preintegrated> = cuts
            .windows(2)
            .enumerate()
            .map(|(m, c)| {
                integrator()
                    .integrate(&s, c[0], c[1], &at(1.0 + 0.1 * m as f64, 1.0))
                    .unwrap()
            })
            .collect();
        let mut chain = JoinedIntervals::new(&parts[0], &b);
        for part in &parts[1..] {
            assert!(chain.push(part));
        }
        let g = Vector3::new(0.0, 0.0, -9.81);
        let start = NavState {
            t_ns: 0,
            R_world_body: UnitQuaternion::from_euler_angles(0.1, -0.2, 0.7),
            velocity_world_m_s: Vector3::new(0.5, -0.3, 0.1),
            position_world_m: Vector3::new(1.0, 2.0, 0.5),
        };
        // States that agree with the IMU, then moved by `size`.
        let mismatch = |size: f64| {
            let mut states = vec![start.clone()];
            for part in &parts {
                let next = part.predict(states.last().unwrap(), &b, &g);
                states.push(next);
            }
            for (m, st) in states.iter_mut().enumerate().skip(1) {
                let k = m as f64;
                let turn = Vector3::new(0.3 * k, -0.5, 0.2 * k - 0.4) * size;
                st.R_world_body = st.R_world_body * UnitQuaternion::from_scaled_axis(turn);
                st.velocity_world_m_s += Vector3::new(-0.2, 0.4 * k, 0.1) * size;
                st.position_world_m += Vector3::new(0.3, -0.1, 0.2 * k) * size;
            }
            let mut sum = nalgebra::SVector::<f64, 9>::zeros();
            for (m, part) in parts.iter().enumerate() {
                let r = imu_residual(part, &states[m], &states[m + 1], &b, &g).residual;
                sum += chain.transport[m] * r;
            }
            let whole = imu_residual(&chain.joined, &states[0], &states[3], &b, &g).residual;
            ((whole - sum).norm(), whole.norm())
        };
        let (far, far_size) = mismatch(1e-2);
        let (near, near_size) = mismatch(5e-3);
        assert!(
            far_size > 1e-3 && near_size > 5e-4,
            "{far_size} {near_size}"
        );
        assert!(far < 0.05 * far_size, "{far} against {far_size}");
        let ratio = far / near;
        assert!((3.0..5.0).contains(&ratio), "mismatch {far} -> {near}");
    }

    #[test]
    fn intervals_that_do_not_meet_are_refused() {
        let s = samples();
        let b = at(1.0, 1.0);
        let first = integrator().integrate(&s, 0, 250_000_000, &b).unwrap();
        let second = integrator()
            .integrate(&s, 300_000_000, 600_000_000, &b)
            .unwrap();
        assert!(join(&first, &second, &b).is_none());
    }
}
