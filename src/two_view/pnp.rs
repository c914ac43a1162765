//! Absolute pose from known points: MSAC over [`p3p`] hypotheses with an
//! adaptive iteration count, then Levenberg-Marquardt on the reprojection
//! errors of the inliers. Used to set the scale of a new frame from
//! landmarks and to relocalise.

use nalgebra::{
    Isometry3, Matrix2x3, Matrix3, Rotation3, SMatrix, SVector, Translation3, UnitQuaternion,
    Vector2, Vector3,
};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use super::p3p::p3p;
use super::ransac::{needed_iterations, sample_distinct, validate_correspondences};
use super::TwoViewError;
use crate::imu::so3::hat as skew;

/// Settings of [`estimate_absolute_pose`].
#[derive(Debug, Clone, PartialEq)]
pub struct AbsolutePoseConfig {
    /// Inlier threshold on the reprojection error, normalised image units.
    pub threshold: f64,
    /// Probability of having drawn one all-inlier sample when RANSAC stops.
    pub confidence: f64,
    /// Largest number of RANSAC iterations.
    pub max_iterations: usize,
    /// Fewest inliers a pose may rest on.
    pub min_inliers: usize,
    /// Seed of the sampler; the same seed and input give the same result.
    pub seed: u64,
    /// Levenberg-Marquardt iterations on the inliers (0 disables).
    pub refine_iterations: usize,
}

impl AbsolutePoseConfig {
    /// Defaults for a camera of focal length `focal_px` and an inlier threshold of `threshold_px`
    /// pixels (confidence 0.999, at most 1000 iterations, 6 inliers, 10 refinement iterations, seed
    /// 0).
    pub fn for_pixels(threshold_px: f64, focal_px: f64) -> Self {
        Self {
            threshold: threshold_px / focal_px,
            confidence: 0.999,
            max_iterations: 1000,
            min_inliers: 6,
            seed: 0,
            refine_iterations: 10,
        }
    }
}

/// The camera's pose against the points' frame.
#[derive(Debug, Clone)]
#[allow(non_snake_case)]
pub struct AbsolutePose {
    /// Maps world coordinates into the camera: `X_cam = T_cam_world X_world`.
    pub T_cam_world: Isometry3<f64>,
    /// Per correspondence: whether it is an inlier of the final pose.
    pub inliers: Vec<bool>,
    /// Number of inliers.
    pub inlier_count: usize,
    /// RANSAC iterations run.
    pub iterations: usize,
}

/// Squared reprojection error, `None` behind the camera.
fn reprojection_sq(
    r: &Matrix3<f64>,
    t: &Vector3<f64>,
    p: &Vector3<f64>,
    x: &Vector2<f64>,
) -> Option<f64> {
    let c = r * p + t;
    (c.z > 0.0).then(|| (c.xy() / c.z - x).norm_squared())
}

fn truncated_cost(
    r: &Matrix3<f64>,
    t: &Vector3<f64>,
    points: &[Vector3<f64>],
    x: &[Vector2<f64>],
    threshold_sq: f64,
    mask: Option<&mut [bool]>,
) -> (f64, usize) {
    let mut cost = 0.0;
    let mut count = 0;
    let mut mask = mask;
    for (i, (p, xi)) in points.iter().zip(x).enumerate() {
        let e = reprojection_sq(r, t, p, xi).unwrap_or(f64::INFINITY);
        let inlier = e < threshold_sq;
        cost += e.min(threshold_sq);
        count += usize::from(inlier);
        if let Some(m) = mask.as_deref_mut() {
            m[i] = inlier;
        }
    }
    (cost, count)
}

/// Reprojection residual of one point and its Jacobian with respect to a
/// left perturbation `(ω, δt)`: `X_cam ← exp([ω]ₓ) X_cam + δt`.
fn residual_and_jacobian(
    r: &Matrix3<f64>,
    t: &Vector3<f64>,
    p: &Vector3<f64>,
    x: &Vector2<f64>,
) -> Option<(Vector2<f64>, SMatrix<f64, 2, 6>)> {
    let c = r * p + t;
    if c.z <= 1e-9 {
        return None;
    }
    let inv_z = 1.0 / c.z;
    let d_proj = Matrix2x3::new(
        inv_z,
        0.0,
        -c.x * inv_z * inv_z,
        0.0,
        inv_z,
        -c.y * inv_z * inv_z,
    );
    let mut j = SMatrix::<f64, 2, 6>::zeros();
    j.fixed_view_mut::<2, 3>(0, 0)
        .copy_from(&(d_proj * -skew(&c)));
    j.fixed_view_mut::<2, 3>(0, 3).copy_from(&d_proj);
    Some((c.xy() * inv_z - x, j))
}

fn apply(
    r: &Matrix3<f64>,
    t: &Vector3<f64>,
    delta: &SVector<f64, 6>,
) -> (Matrix3<f64>, Vector3<f64>) {
    let rot = Rotation3::from_scaled_axis(Vector3::new(delta[0], delta[1], delta[2])).into_inner();
    (
        rot * r,
        rot * t + Vector3::new(delta[3], delta[4], delta[5]),
    )
}

/// Levenberg-Marquardt on the squared reprojection errors of the selected
/// points; never worse than the start.
pub fn refine_absolute_pose(
    r: &Matrix3<f64>,
    t: &Vector3<f64>,
    points: &[Vector3<f64>],
    x: &[Vector2<f64>],
    selected: &[bool],
    max_iterations: usize,
) -> (Matrix3<f64>, Vector3<f64>) {
    let cost_of = |r: &Matrix3<f64>, t: &Vector3<f64>| -> f64 {
        points
            .iter()
            .zip(x)
            .zip(selected)
            .filter(|(_, &s)| s)
            .map(|((p, xi), _)| reprojection_sq(r, t, p, xi).unwrap_or(1e6))
            .sum()
    };
    let (mut r, mut t) = (*r, *t);
    let mut cost = cost_of(&r, &t);
    let mut lambda = 1e-4;
    for _ in 0..max_iterations {
        let mut jtj = SMatrix::<f64, 6, 6>::zeros();
        let mut jtr = SVector::<f64, 6>::zeros();
        for ((p, xi), _) in points.iter().zip(x).zip(selected).filter(|(_, &s)| s) {
            if let Some((res, j)) = residual_and_jacobian(&r, &t, p, xi) {
                jtj += j.transpose() * j;
                jtr += j.transpose() * res;
            }
        }
        let mut improved = false;
        while lambda < 1e8 {
            let mut damped = jtj;
            for i in 0..6 {
                damped[(i, i)] += lambda * jtj[(i, i)].max(1e-12);
            }
            let Some(delta) = damped.cholesky().map(|c| c.solve(&-jtr)) else {
                lambda *= 10.0;
                continue;
            };
            let (r_new, t_new) = apply(&r, &t, &delta);
            let new_cost = cost_of(&r_new, &t_new);
            if new_cost < cost {
                improved = (cost - new_cost) > 1e-10 * cost;
                (r, t, cost) = (r_new, t_new, new_cost);
                lambda = (lambda * 0.1).max(1e-9);
                break;
            }
            lambda *= 10.0;
        }
        if !improved {
            break;
        }
    }
    (r, t)
}

/// Camera pose from known points `points_world[i]` seen at normalised
/// image coordinates `x_cam[i]`: MSAC over P3P samples (truncated squared
/// reprojection errors, adaptive iteration count), then refinement on the
/// inliers.
pub fn estimate_absolute_pose(
    points_world: &[Vector3<f64>],
    x_cam: &[Vector2<f64>],
    config: &AbsolutePoseConfig,
) -> Result<AbsolutePose, TwoViewError> {
    if !(config.threshold > 0.0 && config.threshold.is_finite()) {
        return Err(TwoViewError::InvalidConfig {
            key: "threshold",
            value: config.threshold,
            allowed: "> 0",
        });
    }
    if !(config.confidence > 0.0 && config.confidence < 1.0) {
        return Err(TwoViewError::InvalidConfig {
            key: "confidence",
            value: config.confidence,
            allowed: "(0, 1)",
        });
    }
    validate_correspondences(points_world, x_cam, 4, |p, x| {
        p.iter().chain(x.iter()).all(|v| v.is_finite())
    })?;
    let n = points_world.len();
    let threshold_sq = config.threshold * config.threshold;
    let mut rng = ChaCha8Rng::seed_from_u64(config.seed);
    let mut best: Option<(Matrix3<f64>, Vector3<f64>, f64)> = None;
    let mut needed = config.max_iterations.max(1);
    let mut iterations = 0;
    while iterations < needed {
        iterations += 1;
        let sample = sample_distinct::<3>(&mut rng, n);
        let bearings = sample.map(|i| Vector3::new(x_cam[i].x, x_cam[i].y, 1.0));
        let points = sample.map(|i| points_world[i]);
        for pose in p3p(&bearings, &points).as_slice() {
            let (r, t) = (pose.rotation_cam_world, pose.t_cam_world);
            let (cost, count) = truncated_cost(&r, &t, points_world, x_cam, threshold_sq, None);
            if best.map_or(true, |b| cost < b.2) {
                best = Some((r, t, cost));
                needed = needed_iterations(
                    config.confidence,
                    count as f64 / n as f64,
                    3,
                    config.max_iterations.max(1),
                );
            }
        }
    }
    let Some((mut r, mut t, _)) = best else {
        return Err(TwoViewError::NoConsensus {
            best: 0,
            needed: config.min_inliers,
        });
    };
    let mut mask = vec![false; n];
    let (_, mut inlier_count) =
        truncated_cost(&r, &t, points_world, x_cam, threshold_sq, Some(&mut mask));
    if config.refine_iterations > 0 && inlier_count >= 4 {
        for _ in 0..2 {
            (r, t) =
                refine_absolute_pose(&r, &t, points_world, x_cam, &mask, config.refine_iterations);
            (_, inlier_count) =
                truncated_cost(&r, &t, points_world, x_cam, threshold_sq, Some(&mut mask));
        }
    }
    if inlier_count < config.min_inliers.max(4) {
        return Err(TwoViewError::NoConsensus {
            best: inlier_count,
            needed: config.min_inliers,
        });
    }
    let rotation = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix(&r));
    Ok(AbsolutePose {
        T_cam_world: Isometry3::from_parts(Translation3::from(t), rotation),
        inliers: mask,
        inlier_count,
        iterations,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::two_view::test_scenes::{random_pose, rotation_angle};
    use rand::Rng;

    #[allow(clippy::type_complexity)] // test fixture: truth and observations
    fn scene(
        rng: &mut ChaCha8Rng,
        n: usize,
        sigma: f64,
    ) -> (
        Matrix3<f64>,
        Vector3<f64>,
        Vec<Vector3<f64>>,
        Vec<Vector2<f64>>,
    ) {
        let (r, t) = random_pose(rng, 1.0, 2.0);
        let mut world = Vec::new();
        let mut x = Vec::new();
        for _ in 0..n {
            let c = Vector3::new(rng.gen_range(-1.0..1.0), rng.gen_range(-0.7..0.7), 1.0)
                * rng.gen_range(2.0..20.0);
            world.push(r.transpose() * (c - t));
            x.push(
                c.xy() / c.z
                    + Vector2::new(rng.gen_range(-sigma..sigma), rng.gen_range(-sigma..sigma)),
            );
        }
        (r, t, world, x)
    }

    #[test]
    fn jacobian_matches_central_differences() {
        let mut rng = ChaCha8Rng::seed_from_u64(2);
        let (r, t, world, x) = scene(&mut rng, 5, 0.01);
        for (p, xi) in world.iter().zip(&x) {
            let (_, j) = residual_and_jacobian(&r, &t, p, xi).unwrap();
            for k in 0..6 {
                let mut d = SVector::<f64, 6>::zeros();
                d[k] = 1e-6;
                let (rp, tp) = apply(&r, &t, &d);
                let (rm, tm) = apply(&r, &t, &-d);
                let plus = residual_and_jacobian(&rp, &tp, p, xi).unwrap().0;
                let minus = residual_and_jacobian(&rm, &tm, p, xi).unwrap().0;
                let numeric = (plus - minus) / 2e-6;
                for row in 0..2 {
                    assert!(
                        (j[(row, k)] - numeric[row]).abs() < 1e-6 * numeric[row].abs().max(1e-2),
                        "entry ({row},{k}): {} vs {}",
                        j[(row, k)],
                        numeric[row]
                    );
                }
            }
        }
    }

    #[test]
    fn half_outliers_pose_recovered() {
        let mut rng = ChaCha8Rng::seed_from_u64(30);
        for trial in 0..10 {
            let sigma = 0.5 / 500.0;
            let (r, t, world, mut x) = scene(&mut rng, 100, sigma);
            for xi in x.iter_mut().step_by(2) {
                *xi = Vector2::new(rng.gen_range(-1.0..1.0), rng.gen_range(-0.7..0.7));
            }
            let config = AbsolutePoseConfig {
                seed: trial,
                ..AbsolutePoseConfig::for_pixels(2.0, 500.0)
            };
            let pose = estimate_absolute_pose(&world, &x, &config).unwrap();
            let r_est = pose.T_cam_world.rotation.to_rotation_matrix().into_inner();
            let rot_err_deg = rotation_angle(&r, &r_est).to_degrees();
            let t_err = (pose.T_cam_world.translation.vector - t).norm();
            assert!(
                rot_err_deg < 0.2,
                "trial {trial}: rotation error {rot_err_deg} deg"
            );
            assert!(
                t_err < 0.05 * t.norm().max(1.0),
                "trial {trial}: translation error {t_err}"
            );
            let kept = (1..100).step_by(2).filter(|&i| pose.inliers[i]).count();
            assert!(kept >= 48, "trial {trial}: {kept} of 50 inliers kept");
        }
    }

    #[test]
    fn bad_input_is_an_error() {
        let world = vec![Vector3::new(0.0, 0.0, 5.0); 3];
        let x = vec![Vector2::zeros(); 3];
        let config = AbsolutePoseConfig::for_pixels(1.0, 500.0);
        assert!(matches!(
            estimate_absolute_pose(&world, &x, &config),
            Err(TwoViewError::TooFewCorrespondences { needed: 4, got: 3 })
        ));
        let mut world = vec![Vector3::new(0.0, 0.0, 5.0); 8];
        let x = vec![Vector2::zeros(); 8];
        world[5].x = f64::INFINITY;
        assert!(matches!(
            estimate_absolute_pose(&world, &x, &config),
            Err(TwoViewError::NonFinite { index: 5 })
        ));
        let bad = AbsolutePoseConfig::for_pixels(1.0, f64::NAN);
        world[5].x = 0.0;
        assert!(matches!(
            estimate_absolute_pose(&world, &x, &bad),
            Err(TwoViewError::InvalidConfig { .. })
        ));
        // All points identical: P3P has no solution; an error, no panic.
        assert!(estimate_absolute_pose(&world, &x, &config).is_err());
    }
}
