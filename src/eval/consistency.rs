//! Is the published covariance honest? The normalised estimation error
//! squared (NEES) of each pose against the ground truth.
//!
//! A relative pose's covariance is relative to an origin (the keyframe
//! that fixed the window, see [`crate::relative::PoseCovariance`]), so the
//! error is too: the true motion from the origin's instant to the pose's
//! is applied to the estimated origin, and compared with the estimate:
//!
//! ```text
//! T_true' = T_world_origin_est (T_world_origin_gt^-1 T_world_gt)
//! e = [p_true' - p_est, Log(R_true' R_est^T)]      NEES = e^T Sigma^-1 e
//! ```
//!
//! For a consistent estimator the NEES of a 6-dof pose averages 6, so the
//! mean per degree of freedom is 1 (a controller that trusts the
//! covariance wants it between about 0.5 and 2: below, the covariance is
//! too pessimistic; above, too confident). Position (3 dof) and rotation
//! (3 dof) are also reported alone, with their own blocks.
//!
//! A mean of 1 says little about the covariance's shape: one too sure in
//! a few thin directions and far too cautious in the others can average
//! 1 (the thin directions dominate the mean). A controller that reads
//! the standard deviations of x, y, z, roll, pitch and yaw sees the
//! marginals, so each axis is also scored alone, `e_i^2 / C_ii`
//! ([`NeesReport::position_marginal_per_dof`],
//! [`NeesReport::rotation_marginal_per_dof`]): 1 when every axis's
//! variance is right whatever the correlations, far below 1 when the
//! published sigmas are far wider than the errors.

use nalgebra::{Isometry3, Matrix3, Translation3, UnitQuaternion, Vector6};
use serde::Serialize;

use crate::imu::so3::log;
use crate::relative::PoseCovariance;
use crate::trajectory::Trajectory;

/// A published pose with its covariance.
#[allow(non_snake_case)]
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CovariancePose {
    /// Stamp, ns.
    pub t_ns: i64,
    /// Body (IMU) pose in the world frame.
    pub T_world_body: Isometry3<f64>,
    /// Covariance of the pose, in the convention of [`PoseCovariance`].
    pub covariance: PoseCovariance,
}

/// NEES over a run.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct NeesReport {
    /// Poses scored (the ground truth covers them and the origin, the
    /// covariance is positive definite).
    pub poses: usize,
    /// Mean of `NEES / 6` over the poses.
    pub mean_per_dof: f64,
    /// The position block alone: mean of `NEES_p / 3`.
    pub position_per_dof: f64,
    /// The rotation block alone: mean of `NEES_r / 3`.
    pub rotation_per_dof: f64,
    /// Median of `NEES / 6` (0.89 when consistent): the mean's tail apart.
    pub median_per_dof: f64,
    /// Each position axis alone, its error against its own variance:
    /// mean of `(e_x^2 / C_xx + e_y^2 / C_yy + e_z^2 / C_zz) / 3`.
    pub position_marginal_per_dof: f64,
    /// The same over the three rotation axes.
    pub rotation_marginal_per_dof: f64,
    /// Distinct origins met (1 + re-initialisations that restarted the
    /// covariance).
    pub origins: usize,
}

/// The pose error `e` (see the module doc) of one pose, None when the
/// ground truth does not cover its instant or its origin's.
#[allow(non_snake_case)]
pub fn relative_pose_error(
    pose: &CovariancePose,
    ground_truth: &Trajectory,
) -> Option<Vector6<f64>> {
    let gt_origin = interpolate(ground_truth, pose.covariance.origin_t_ns)?;
    let gt = interpolate(ground_truth, pose.t_ns)?;
    let truth = pose.covariance.T_world_origin * (gt_origin.inverse() * gt);
    let r_true = truth.rotation.to_rotation_matrix().into_inner();
    let r_est = pose.T_world_body.rotation.to_rotation_matrix().into_inner();
    let mut e = Vector6::zeros();
    e.fixed_rows_mut::<3>(0)
        .copy_from(&(truth.translation.vector - pose.T_world_body.translation.vector));
    e.fixed_rows_mut::<3>(3)
        .copy_from(&log(&(r_true * r_est.transpose())));
    Some(e)
}

/// NEES of every pose the ground truth covers; None when none is.
pub fn pose_nees(poses: &[CovariancePose], ground_truth: &Trajectory) -> Option<NeesReport> {
    let (mut full, mut position, mut rotation) = (0.0, 0.0, 0.0);
    let (mut position_marginal, mut rotation_marginal) = (0.0, 0.0);
    let mut per_pose = Vec::new();
    let mut n = 0usize;
    let mut origins: Vec<i64> = Vec::new();
    for pose in poses {
        let Some(e) = relative_pose_error(pose, ground_truth) else {
            continue;
        };
        let c = &pose.covariance.matrix;
        let quadratic = |block: Vector6<f64>, cov: nalgebra::Matrix6<f64>| {
            cov.cholesky().map(|l| block.dot(&l.solve(&block)))
        };
        let c_p: Matrix3<f64> = c.fixed_view::<3, 3>(0, 0).into_owned();
        let c_r: Matrix3<f64> = c.fixed_view::<3, 3>(3, 3).into_owned();
        let e_p = e.fixed_rows::<3>(0).into_owned();
        let e_r = e.fixed_rows::<3>(3).into_owned();
        let (Some(f), Some(lp), Some(lr)) = (quadratic(e, *c), c_p.cholesky(), c_r.cholesky())
        else {
            continue;
        };
        full += f / 6.0;
        per_pose.push(f / 6.0);
        position += e_p.dot(&lp.solve(&e_p)) / 3.0;
        rotation += e_r.dot(&lr.solve(&e_r)) / 3.0;
        // Positive diagonals: the blocks' Cholesky factors exist.
        position_marginal += marginal_per_dof(&e_p, &c_p);
        rotation_marginal += marginal_per_dof(&e_r, &c_r);
        n += 1;
        if origins.last() != Some(&pose.covariance.origin_t_ns) {
            origins.push(pose.covariance.origin_t_ns);
        }
    }
    origins.sort_unstable();
    origins.dedup();
    (n > 0).then(|| NeesReport {
        poses: n,
        mean_per_dof: full / n as f64,
        position_per_dof: position / n as f64,
        rotation_per_dof: rotation / n as f64,
        median_per_dof: median(&mut per_pose),
        position_marginal_per_dof: position_marginal / n as f64,
        rotation_marginal_per_dof: rotation_marginal / n as f64,
        origins: origins.len(),
    })
}

/// `(e_1^2 / C_11 + e_2^2 / C_22 + e_3^2 / C_33) / 3`: each axis against
/// its own variance, the correlations ignored. `C`'s diagonal must be
/// positive (it is wherever `C` is positive definite).
pub fn marginal_per_dof(e: &nalgebra::Vector3<f64>, c: &Matrix3<f64>) -> f64 {
    (0..3).map(|i| e[i] * e[i] / c[(i, i)]).sum::<f64>() / 3.0
}

/// The median of `values` (sorted in place); NaN when empty.
pub fn median(values: &mut [f64]) -> f64 {
    let n = values.len();
    if n == 0 {
        return f64::NAN;
    }
    values.sort_by(f64::total_cmp);
    if n % 2 == 1 {
        values[n / 2]
    } else {
        0.5 * (values[n / 2 - 1] + values[n / 2])
    }
}

/// How far outside the ground truth's span an instant may be and still
/// take its end pose, ns (10 ms: a fifth of a 20 Hz frame, twice
/// EuRoC's 200 Hz spacing).
pub const END_TOLERANCE_NS: i64 = 10_000_000;

/// The ground-truth pose at `t_ns`, linear in position and spherical in
/// rotation between the two poses around it; None outside.
///
/// Within [`END_TOLERANCE_NS`] outside the first or last sample, the end
/// pose itself: a sequence's first frame may precede its ground truth's
/// first sample by a few milliseconds (EuRoC V1_02: 5 ms), and a
/// covariance whose origin is that frame would otherwise score nothing.
#[allow(non_snake_case)]
pub fn interpolate(trajectory: &Trajectory, t_ns: i64) -> Option<Isometry3<f64>> {
    let poses = &trajectory.poses;
    let (first, last) = (poses.first()?, poses.last()?);
    if t_ns < first.t_ns {
        return (first.t_ns - t_ns <= END_TOLERANCE_NS).then_some(first.T_world_body);
    }
    if t_ns > last.t_ns {
        return (t_ns - last.t_ns <= END_TOLERANCE_NS).then_some(last.T_world_body);
    }
    let after = poses.partition_point(|p| p.t_ns < t_ns);
    let b = poses.get(after)?;
    if b.t_ns == t_ns {
        return Some(b.T_world_body);
    }
    let a = poses.get(after.checked_sub(1)?)?;
    let span = (b.t_ns - a.t_ns) as f64;
    if span <= 0.0 {
        return None;
    }
    let s = (t_ns - a.t_ns) as f64 / span;
    let p = a.position().lerp(&b.position(), s);
    let q: UnitQuaternion<f64> = a.orientation().try_slerp(&b.orientation(), s, 1e-12)?;
    Some(Isometry3::from_parts(Translation3::from(p), q))
}

#[cfg(test)]
mod tests {
    use nalgebra::{Matrix6, Vector3};
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;
    use rand_distr::{Distribution, StandardNormal};

    use super::*;
    use crate::imu::so3::exp;
    use crate::trajectory::StampedPose;

    fn truth() -> Trajectory {
        // A turning, climbing path sampled at 100 Hz for 10 s.
        Trajectory::new(
            (0..1000)
                .map(|k| {
                    let t = k as f64 * 0.01;
                    StampedPose::new(
                        k * 10_000_000,
                        Vector3::new(t.cos() * 3.0, t.sin() * 3.0, 0.1 * t),
                        UnitQuaternion::from_scaled_axis(Vector3::new(0.1 * t.sin(), 0.0, t)),
                    )
                })
                .collect(),
        )
    }

    #[test]
    fn interpolation_is_exact_on_samples_and_between_them_on_a_line() {
        let gt = truth();
        let p = interpolate(&gt, 250_000_000).unwrap();
        assert!((p.translation.vector - gt.poses[25].position()).norm() < 1e-12);
        let line = Trajectory::new(vec![
            StampedPose::new(0, Vector3::zeros(), UnitQuaternion::identity()),
            StampedPose::new(
                10,
                Vector3::new(1.0, 2.0, 3.0),
                UnitQuaternion::from_scaled_axis(Vector3::new(0.0, 0.0, 1.0)),
            ),
        ]);
        let mid = interpolate(&line, 5).unwrap();
        assert!((mid.translation.vector - Vector3::new(0.5, 1.0, 1.5)).norm() < 1e-12);
        assert!((mid.rotation.angle() - 0.5).abs() < 1e-12);
        // Just outside the span: the end pose; further: nothing.
        let end = interpolate(&line, 10 + END_TOLERANCE_NS).unwrap();
        assert!((end.translation.vector - Vector3::new(1.0, 2.0, 3.0)).norm() < 1e-12);
        let start = interpolate(&line, -END_TOLERANCE_NS).unwrap();
        assert!(start.translation.vector.norm() < 1e-12);
        assert!(interpolate(&line, 11 + END_TOLERANCE_NS).is_none());
        assert!(interpolate(&line, -1 - END_TOLERANCE_NS).is_none());
        assert!(interpolate(&Trajectory::new(Vec::new()), 0).is_none());
    }

    /// The estimate whose error against `truth` is `e = [p_true - p_est,
    /// Log(R_true R_est^T)]` (the module's convention).
    fn with_error(truth: &Isometry3<f64>, e: &Vector6<f64>) -> Isometry3<f64> {
        let r_est = exp(&(-e.fixed_rows::<3>(3).into_owned()))
            * truth.rotation.to_rotation_matrix().into_inner();
        Isometry3::from_parts(
            Translation3::from(truth.translation.vector - e.fixed_rows::<3>(0)),
            UnitQuaternion::from_matrix(&r_est),
        )
    }

    /// Poses drawn from their covariance around the truth score a NEES
    /// per dof near 1; the same errors with the covariance 4x too small
    /// score near 4.
    #[allow(non_snake_case)]
    #[test]
    fn errors_drawn_from_the_covariance_score_one_per_dof() {
        let gt = truth();
        let origin_gt = gt.poses[100].T_world_body;
        // The estimate's world is another frame: the origin's estimated
        // pose differs from the true one.
        let T_est_gt = Isometry3::from_parts(
            Translation3::new(5.0, -1.0, 2.0),
            UnitQuaternion::from_scaled_axis(Vector3::new(0.0, 0.0, 0.7)),
        );
        let T_world_origin = T_est_gt * origin_gt;
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let l = Matrix6::from_fn(|i, j| match (i, j) {
            _ if i == j => 0.02 + 0.01 * i as f64,
            (3.., 0..=2) => 0.005,
            _ => 0.0,
        });
        let covariance = l * l.transpose();
        let mut poses = Vec::new();
        for k in (120..1000).step_by(3) {
            let z = Vector6::from_fn(|_, _| StandardNormal.sample(&mut rng));
            let e = l * z;
            poses.push(CovariancePose {
                t_ns: gt.poses[k].t_ns,
                T_world_body: with_error(&(T_est_gt * gt.poses[k].T_world_body), &e),
                covariance: PoseCovariance {
                    matrix: covariance,
                    origin_t_ns: gt.poses[100].t_ns,
                    T_world_origin,
                },
            });
        }
        let r = pose_nees(&poses, &gt).unwrap();
        assert_eq!(r.poses, poses.len());
        assert_eq!(r.origins, 1);
        for v in [
            r.mean_per_dof,
            r.position_per_dof,
            r.rotation_per_dof,
            r.position_marginal_per_dof,
            r.rotation_marginal_per_dof,
        ] {
            assert!((v - 1.0).abs() < 0.15, "{r:?}");
        }
        // The median of chi-square with 6 dof, over 6.
        assert!((r.median_per_dof - 0.891).abs() < 0.1, "{r:?}");
        for p in poses.iter_mut() {
            p.covariance.matrix = covariance / 4.0;
        }
        let over = pose_nees(&poses, &gt).unwrap();
        assert!((over.mean_per_dof - 4.0).abs() < 0.6, "{over:?}");
    }

    /// A covariance of the wrong shape can average 1 per dof: too sure in
    /// position (half the variance), far too cautious in rotation (10 000
    /// times, sigmas 100x the errors). The mean reads 1; the axes alone
    /// read 2 and 1e-4.
    #[allow(non_snake_case)]
    #[test]
    fn the_axes_alone_see_a_shape_the_mean_hides() {
        let gt = truth();
        let T_world_origin = gt.poses[0].T_world_body;
        let sigma = 0.01;
        let published = Matrix6::from_diagonal(&Vector6::from_fn(|i, _| {
            sigma * sigma * if i < 3 { 0.5 } else { 1e4 }
        }));
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let poses: Vec<CovariancePose> = (1..1000)
            .step_by(2)
            .map(|k| {
                let e = Vector6::from_fn(|_, _| {
                    let z: f64 = StandardNormal.sample(&mut rng);
                    sigma * z
                });
                CovariancePose {
                    t_ns: gt.poses[k].t_ns,
                    T_world_body: with_error(&gt.poses[k].T_world_body, &e),
                    covariance: PoseCovariance {
                        matrix: published,
                        origin_t_ns: gt.poses[0].t_ns,
                        T_world_origin,
                    },
                }
            })
            .collect();
        let r = pose_nees(&poses, &gt).unwrap();
        assert!((r.mean_per_dof - 1.0).abs() < 0.15, "{r:?}");
        assert!((r.position_marginal_per_dof - 2.0).abs() < 0.3, "{r:?}");
        assert!(r.rotation_marginal_per_dof < 1e-3, "{r:?}");
        // With no correlation the axes alone and the blocks agree.
        assert!((r.position_marginal_per_dof - r.position_per_dof).abs() < 1e-9);
    }

    /// Strong correlations with the right variances: the axes alone read
    /// 1, the whole matrix does not.
    #[test]
    fn the_axes_alone_ignore_the_correlations() {
        let e = nalgebra::Vector3::new(0.3, -0.2, 0.1);
        let c = Matrix3::new(1.0, 0.99, 0.0, 0.99, 1.0, 0.0, 0.0, 0.0, 1.0);
        let by_axes = marginal_per_dof(&e, &c);
        assert!((by_axes - (0.09 + 0.04 + 0.01) / 3.0).abs() < 1e-12);
        let whole = e.dot(&c.cholesky().unwrap().solve(&e)) / 3.0;
        assert!(whole > 10.0 * by_axes, "{whole} {by_axes}");
        let mut v = [3.0, 1.0, 2.0, 10.0];
        assert_eq!(median(&mut v), 2.5);
        assert!(median(&mut []).is_nan());
    }
}
