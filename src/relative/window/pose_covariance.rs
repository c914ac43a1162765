//! The covariance of the published pose: how uncertain the body pose is
//! relative to the window's origin, the keyframe that fixed its gauge.
//!
//! A solve only knows the free keyframes given the fixed ones (their
//! marginals are conditioned on the held poses). Odometry drifts, so the
//! pose a controller reads is uncertain by everything accumulated since
//! the start. The chain is carried keyframe by keyframe: the origin has
//! zero covariance; after each solve every free keyframe gets
//!
//! ```text
//! Sigma_k = J Sigma_b J^T + Sigma_(k | fixed)
//! ```
//!
//! where `b` is the boundary (the newest fixed keyframe, whose own
//! covariance was set in the last solve where it was free), `J` moves a
//! perturbation of `b` to `k` with their relative pose held, and
//! `Sigma_(k | fixed)` is `k`'s marginal from the solve. When a keyframe
//! becomes fixed it keeps the covariance of its last solve. Treating the
//! older fixed keyframes as if only `b` conditioned `k` is the
//! approximation: it is exact for a chain of relative poses.
//!
//! In the inertial modes the window publishes the covariance carried in
//! [`super::propagated_covariance`], which replaces that approximation by
//! the solve's sensitivity to each held pose; this chain remains for
//! vision-only modes, for a solve whose inverse failed and for held
//! keyframes that never had a covariance (after a restart of the chain).
//!
//! Inside the window the pose perturbation is `[dphi, dp]` with
//! `R <- R Exp(dphi)` (body frame) and `p <- p + dp` (world), as the
//! solve's step ([`super::state`]). What is published follows ROS
//! `PoseWithCovariance`: `[dp, dtheta]` with `R_true = Exp(dtheta) R_est`
//! (world frame), see [`to_published`].

use nalgebra::{Isometry3, Matrix3, Matrix6, SMatrix};

use crate::imu::so3::hat;
use crate::imu::Preintegrated;

/// Covariance of pose `b` (window convention) from `a`'s covariance and
/// `b`'s covariance given `a` (`a` held exact), their relative pose
/// fixed.
#[allow(non_snake_case)]
pub fn compose(
    T_world_a: &Isometry3<f64>,
    covariance_a: &Matrix6<f64>,
    T_world_b: &Isometry3<f64>,
    covariance_b_given_a: &Matrix6<f64>,
) -> Matrix6<f64> {
    let j = transport_jacobian(T_world_a, T_world_b);
    let c = j * covariance_a * j.transpose() + covariance_b_given_a;
    (c + c.transpose()) * 0.5
}

/// `d(perturbation of b) / d(perturbation of a)` when `b = a * T_a_b`
/// with `T_a_b` held: `dphi_b = R_ab^T dphi_a`,
/// `dp_b = dp_a - R_a [t_ab]x dphi_a`.
#[allow(non_snake_case)]
pub fn transport_jacobian(T_world_a: &Isometry3<f64>, T_world_b: &Isometry3<f64>) -> Matrix6<f64> {
    let T_a_b = T_world_a.inverse() * T_world_b;
    let r_ab = T_a_b.rotation.to_rotation_matrix().into_inner();
    let r_a = T_world_a.rotation.to_rotation_matrix().into_inner();
    let mut j = Matrix6::zeros();
    j.fixed_view_mut::<3, 3>(0, 0).copy_from(&r_ab.transpose());
    j.fixed_view_mut::<3, 3>(3, 0)
        .copy_from(&(-r_a * hat(&T_a_b.translation.vector)));
    j.fixed_view_mut::<3, 3>(3, 3)
        .copy_from(&Matrix3::identity());
    j
}

/// From the window's `[dphi_body, dp_world]` to the published
/// `[dp_world, dtheta_world]` (`Exp(R dphi) R = R Exp(dphi)`).
#[allow(non_snake_case)]
pub fn to_published(T_world_body: &Isometry3<f64>, covariance: &Matrix6<f64>) -> Matrix6<f64> {
    let m = published_map(T_world_body);
    let c = m * covariance * m.transpose();
    (c + c.transpose()) * 0.5
}

/// `[dp, dtheta] = M [dphi, dp]`; `M` is orthogonal.
#[allow(non_snake_case)]
fn published_map(T_world_body: &Isometry3<f64>) -> Matrix6<f64> {
    let r = T_world_body.rotation.to_rotation_matrix().into_inner();
    let mut m = Matrix6::zeros();
    m.fixed_view_mut::<3, 3>(0, 3)
        .copy_from(&Matrix3::identity());
    m.fixed_view_mut::<3, 3>(3, 0).copy_from(&r);
    m
}

/// The inverse of [`to_published`].
#[allow(non_snake_case)]
pub fn from_published(T_world_body: &Isometry3<f64>, covariance: &Matrix6<f64>) -> Matrix6<f64> {
    let m = published_map(T_world_body);
    let c = m.transpose() * covariance * m;
    (c + c.transpose()) * 0.5
}

/// Covariance of `[dphi_j, dp]` of the state the IMU predicts at the end
/// of `pre` from a start `T_world_i` held exact, the noise densities
/// scaled by `gyro_scale` and `accel_scale`. The preintegrated
/// covariance is over `[dphi, dv, dp]` in the start's body frame.
#[allow(non_snake_case)]
pub fn imu_prediction(
    pre: &Preintegrated,
    T_world_i: &Isometry3<f64>,
    gyro_scale: f64,
    accel_scale: f64,
) -> Matrix6<f64> {
    let c = pre.scaled_covariance(gyro_scale, accel_scale);
    let r_i = T_world_i.rotation.to_rotation_matrix().into_inner();
    let mut j = SMatrix::<f64, 6, 9>::zeros();
    j.fixed_view_mut::<3, 3>(0, 0)
        .copy_from(&Matrix3::identity());
    j.fixed_view_mut::<3, 3>(3, 6).copy_from(&r_i);
    let p = j * c * j.transpose();
    (p + p.transpose()) * 0.5
}

#[cfg(test)]
mod tests {
    use nalgebra::{Translation3, UnitQuaternion, Vector3, Vector6};
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;
    use rand_distr::{Distribution, StandardNormal};

    use super::*;
    use crate::imu::so3::exp;
    use crate::relative::window::synthetic::pose_difference;

    #[allow(non_snake_case)]
    fn pose(rx: f64, ry: f64, rz: f64, x: f64, y: f64, z: f64) -> Isometry3<f64> {
        Isometry3::from_parts(
            Translation3::new(x, y, z),
            UnitQuaternion::from_scaled_axis(Vector3::new(rx, ry, rz)),
        )
    }

    /// The window's retraction: `R Exp(dphi)`, `p + dp`.
    fn perturb(t: &Isometry3<f64>, d: &Vector6<f64>) -> Isometry3<f64> {
        let r = t.rotation * UnitQuaternion::from_scaled_axis(d.fixed_rows::<3>(0).into_owned());
        Isometry3::from_parts(
            Translation3::from(t.translation.vector + d.fixed_rows::<3>(3)),
            r,
        )
    }

    #[test]
    #[allow(non_snake_case)]
    fn transport_jacobian_matches_finite_differences() {
        let a = pose(0.3, -0.5, 1.1, 1.0, -2.0, 0.5);
        let b = pose(-0.2, 0.4, 2.0, 3.0, 1.5, -0.7);
        let T_a_b = a.inverse() * b;
        let j = transport_jacobian(&a, &b);
        let h = 1e-6;
        for col in 0..6 {
            let mut d = Vector6::zeros();
            d[col] = h;
            let plus = pose_difference(&b, &(perturb(&a, &d) * T_a_b));
            let minus = pose_difference(&b, &(perturb(&a, &-d) * T_a_b));
            let numeric = (plus - minus) / (2.0 * h);
            let analytic = j.column(col);
            assert!(
                (numeric - analytic).amax() < 1e-7,
                "column {col}: numeric {numeric:?} analytic {analytic:?}"
            );
        }
    }

    #[test]
    #[allow(non_snake_case)]
    fn composed_covariance_matches_sampled_chains() {
        // Monte Carlo: perturb a by its covariance, carry the relative
        // pose, perturb b given a; the spread of b is the composition.
        let a = pose(0.1, 0.2, -0.4, 0.5, 0.0, 1.0);
        let b = pose(0.4, -0.1, 0.3, 2.5, -1.0, 1.2);
        let T_a_b = a.inverse() * b;
        let la = Matrix6::from_fn(|i, j| {
            if i == j {
                0.01 + 0.002 * i as f64
            } else if j < i {
                0.001
            } else {
                0.0
            }
        });
        let lb = Matrix6::from_fn(|i, j| if i == j { 0.005 } else { 0.0 });
        let (ca, cb) = (la * la.transpose(), lb * lb.transpose());
        let expected = compose(&a, &ca, &b, &cb);
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let mut draw = || Vector6::from_fn(|_, _| StandardNormal.sample(&mut rng));
        let n = 40_000;
        let mut sum = Matrix6::zeros();
        for _ in 0..n {
            let da = la * draw();
            let db = lb * draw();
            let sample = perturb(&(perturb(&a, &da) * T_a_b), &db);
            let d = pose_difference(&b, &sample);
            sum += d * d.transpose();
        }
        let sampled = sum / n as f64;
        for i in 0..6 {
            for j in 0..6 {
                let scale = (expected[(i, i)] * expected[(j, j)]).sqrt();
                assert!(
                    (sampled[(i, j)] - expected[(i, j)]).abs() < 0.04 * scale,
                    "({i},{j}): sampled {} composed {}",
                    sampled[(i, j)],
                    expected[(i, j)]
                );
            }
        }
    }

    #[test]
    fn published_convention_is_the_world_frame_rotation_error() {
        // A body-frame perturbation dphi equals the world-frame one R dphi;
        // position first, rotation second.
        let t = pose(0.7, -0.3, 1.9, 1.0, 2.0, 3.0);
        let r = t.rotation.to_rotation_matrix().into_inner();
        let dphi = Vector3::new(1e-3, -2e-3, 0.5e-3);
        let left = exp(&(r * dphi)) * r;
        let right = r * exp(&dphi);
        assert!((left - right).amax() < 1e-12);
        let mut c = Matrix6::zeros();
        c[(0, 0)] = 4.0; // rotation x in the body
        c[(4, 4)] = 9.0; // position y
        let p = to_published(&t, &c);
        assert!((p[(1, 1)] - 9.0).abs() < 1e-12);
        let rot = p.fixed_view::<3, 3>(3, 3);
        let expected = r.column(0) * r.column(0).transpose() * 4.0;
        assert!((rot - expected).amax() < 1e-12);
        assert!(p.fixed_view::<3, 3>(0, 3).amax() < 1e-15);
        let back = from_published(&t, &p);
        assert!((back - c).amax() < 1e-12);
    }
}
