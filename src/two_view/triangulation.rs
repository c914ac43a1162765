//! Two-view triangulation in the paper's two steps: optimal correction of
//! the image points onto the epipolar geometry, then linear (DLT)
//! triangulation of the corrected, now intersecting, rays; with parallax
//! and depth checks.
//!
//! The correction minimises `‖x̂1 − x1‖² + ‖x̂2 − x2‖²` subject to
//! `q̂2ᵀ E q̂1 = 0` (the optimum of Hartley & Sturm, "Triangulation",
//! CVIU 1997) by two Lagrangian steps as in P. Lindstrom, "Triangulation
//! made easy", CVPR 2010 (niter2): each step moves both points along the
//! constraint's gradient at the current estimate by the amount that makes
//! the constraint hold exactly.

use nalgebra::{Matrix2, Matrix3, Matrix4, Vector2, Vector3, Vector4};

use crate::imu::so3::hat as skew;

/// Checks applied to each triangulated point.
#[derive(Debug, Clone, PartialEq)]
pub struct TriangulationConfig {
    /// Smallest angle between the two rays at the point (radians).
    pub min_parallax_rad: f64,
    /// Smallest depth in either camera, in the units of `t`.
    pub min_depth: f64,
    /// Largest depth in either camera, in the units of `t`.
    pub max_depth: f64,
}

impl Default for TriangulationConfig {
    fn default() -> Self {
        Self {
            min_parallax_rad: 1.0_f64.to_radians(),
            min_depth: 1e-6,
            max_depth: f64::INFINITY,
        }
    }
}

/// Why a correspondence gave no point.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum TriangulationFailure {
    #[error("a coordinate or the pose is not finite")]
    /// A coordinate or the pose has a NaN or infinite value.
    NonFinite,
    #[error("rays meet at {parallax_rad} rad, below the minimum parallax")]
    /// The rays are too close to parallel for a reliable depth.
    LowParallax {
        /// Angle between the two rays, rad.
        parallax_rad: f64,
    },
    #[error("point at depths {depth_c1} (view 1) and {depth_c2} (view 2) is behind a camera or too near")]
    /// The point is behind a camera or nearer than the minimum depth.
    BehindCamera {
        /// Depth in the first camera, same unit as the pose's translation.
        depth_c1: f64,
        /// Depth in the second camera.
        depth_c2: f64,
    },
    #[error("point at depths {depth_c1} (view 1) and {depth_c2} (view 2) is too far")]
    /// The point is beyond the maximum depth.
    TooFar {
        /// Depth in the first camera, same unit as the pose's translation.
        depth_c1: f64,
        /// Depth in the second camera.
        depth_c2: f64,
    },
}

/// A point seen in two views, in the first camera's frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TriangulatedPoint {
    /// The point in the first camera's frame (unit of the pose's translation).
    pub point_c1: Vector3<f64>,
    /// Its depth (z) in the first camera.
    pub depth_c1: f64,
    /// Its depth (z) in the second camera.
    pub depth_c2: f64,
    /// Angle between the two viewing rays, rad.
    pub parallax_rad: f64,
    /// The image points after the optimal correction.
    pub corrected_x1: Vector2<f64>,
    /// The second image point after the optimal correction.
    pub corrected_x2: Vector2<f64>,
}

/// The nearest pair `(x̂1, x̂2)` to `(x1, x2)` with `q̂2ᵀ E q̂1 = 0`
/// (normalised coordinates), by two Lindstrom-style steps.
pub fn correct_correspondence(
    e: &Matrix3<f64>,
    x1: &Vector2<f64>,
    x2: &Vector2<f64>,
) -> (Vector2<f64>, Vector2<f64>) {
    let q1 = Vector3::new(x1.x, x1.y, 1.0);
    let q2 = Vector3::new(x2.x, x2.y, 1.0);
    let e2: Matrix2<f64> = e.fixed_view::<2, 2>(0, 0).into();
    let c = q2.dot(&(e * q1));
    // Gradients of the constraint with respect to x1 and x2.
    let n1: Vector2<f64> = e.tr_mul(&q2).xy();
    let n2: Vector2<f64> = (e * q1).xy();
    // Along directions (m1, m2) the constraint is
    // c − μ (n1·m1 + n2·m2) + μ² m2ᵀ Ẽ m1 = 0; take its small root.
    let step = |m1: &Vector2<f64>, m2: &Vector2<f64>| -> f64 {
        let a = m2.dot(&(e2 * m1));
        let b = 0.5 * (n1.dot(m1) + n2.dot(m2));
        let disc = (b * b - a * c).max(0.0);
        let denom = b + b.signum() * disc.sqrt();
        if denom == 0.0 {
            0.0
        } else {
            c / denom
        }
    };
    let lambda = step(&n1, &n2);
    let (d1, d2) = (n1 * lambda, n2 * lambda);
    // Second step: the gradients at the first estimate.
    let m1 = n1 - e2.tr_mul(&d2);
    let m2 = n2 - e2 * d1;
    let mu = step(&m1, &m2);
    (x1 - m1 * mu, x2 - m2 * mu)
}

/// Linear (DLT) triangulation of `x1 ↔ x2` with cameras `[I | 0]` and
/// `[R | t]` (Hartley & Zisserman section 12.2): the right singular vector
/// of the smallest singular value of the 4×4 system. `None` for a point at
/// infinity.
pub fn triangulate_linear(
    rotation_c2_c1: &Matrix3<f64>,
    t_c2_c1: &Vector3<f64>,
    x1: &Vector2<f64>,
    x2: &Vector2<f64>,
) -> Option<Vector3<f64>> {
    let p2_row = |i: usize| -> Vector4<f64> {
        Vector4::new(
            rotation_c2_c1[(i, 0)],
            rotation_c2_c1[(i, 1)],
            rotation_c2_c1[(i, 2)],
            t_c2_c1[i],
        )
    };
    let (p20, p21, p22) = (p2_row(0), p2_row(1), p2_row(2));
    let a = Matrix4::from_rows(&[
        Vector4::new(-1.0, 0.0, x1.x, 0.0).transpose(),
        Vector4::new(0.0, -1.0, x1.y, 0.0).transpose(),
        (p22 * x2.x - p20).transpose(),
        (p22 * x2.y - p21).transpose(),
    ]);
    let svd = a.svd(false, true);
    let v_t = svd.v_t?;
    let (k, _) = svd.singular_values.argmin();
    let h = v_t.row(k);
    if h[3].abs() <= 1e-12 * h.norm() {
        return None;
    }
    Some(Vector3::new(h[0], h[1], h[2]) / h[3])
}

/// Corrects `x1 ↔ x2` optimally for the pose `(R, t)`, triangulates
/// linearly, and applies the parallax and depth checks of `config`.
pub fn triangulate(
    rotation_c2_c1: &Matrix3<f64>,
    t_c2_c1: &Vector3<f64>,
    x1: &Vector2<f64>,
    x2: &Vector2<f64>,
    config: &TriangulationConfig,
) -> Result<TriangulatedPoint, TriangulationFailure> {
    let finite = x1
        .iter()
        .chain(x2.iter())
        .chain(t_c2_c1.iter())
        .all(|v| v.is_finite())
        && rotation_c2_c1.iter().all(|v| v.is_finite());
    if !finite {
        return Err(TriangulationFailure::NonFinite);
    }
    let e = skew(t_c2_c1) * rotation_c2_c1;
    let (c1, c2) = correct_correspondence(&e, x1, x2);
    let ray1 = Vector3::new(c1.x, c1.y, 1.0);
    let ray2_in_c1 = rotation_c2_c1.tr_mul(&Vector3::new(c2.x, c2.y, 1.0));
    let parallax_rad = ray1.angle(&ray2_in_c1);
    // NaN parallax is refused too.
    if parallax_rad.partial_cmp(&config.min_parallax_rad) == Some(std::cmp::Ordering::Less)
        || parallax_rad.is_nan()
    {
        return Err(TriangulationFailure::LowParallax { parallax_rad });
    }
    let point_c1 = triangulate_linear(rotation_c2_c1, t_c2_c1, &c1, &c2)
        .ok_or(TriangulationFailure::LowParallax { parallax_rad })?;
    let depth_c1 = point_c1.z;
    let depth_c2 = (rotation_c2_c1 * point_c1 + t_c2_c1).z;
    if !(depth_c1 > config.min_depth && depth_c2 > config.min_depth) {
        return Err(TriangulationFailure::BehindCamera { depth_c1, depth_c2 });
    }
    if depth_c1 > config.max_depth || depth_c2 > config.max_depth {
        return Err(TriangulationFailure::TooFar { depth_c1, depth_c2 });
    }
    Ok(TriangulatedPoint {
        point_c1,
        depth_c1,
        depth_c2,
        parallax_rad,
        corrected_x1: c1,
        corrected_x2: c2,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::two_view::test_scenes::{random_pose, random_scene};
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    /// The optimal correction by brute force, independent of the
    /// Lagrangian steps: every epipolar plane is a pencil line; search the
    /// pencil angle for the smallest sum of squared point-line distances.
    fn brute_force_cost(e: &Matrix3<f64>, x1: &Vector2<f64>, x2: &Vector2<f64>) -> f64 {
        let svd = e.svd(true, false);
        let u = svd.u.unwrap();
        let (k, _) = svd.singular_values.argmin();
        let epipole2: Vector3<f64> = u.column(k).into();
        let cost = |theta: f64| {
            let p = Vector3::new(theta.cos(), theta.sin(), 0.0);
            let l2 = epipole2.cross(&p);
            let l1 = e.tr_mul(&p);
            let d = |l: &Vector3<f64>, x: &Vector2<f64>| {
                (l.x * x.x + l.y * x.y + l.z).powi(2) / (l.x * l.x + l.y * l.y)
            };
            d(&l1, x1) + d(&l2, x2)
        };
        let steps = 20000;
        let mut best = (f64::INFINITY, 0.0);
        for i in 0..steps {
            let th = std::f64::consts::PI * i as f64 / steps as f64;
            let c = cost(th);
            if c < best.0 {
                best = (c, th);
            }
        }
        // Golden-section refinement around the best sample.
        let h = std::f64::consts::PI / steps as f64;
        let (mut lo, mut hi) = (best.1 - h, best.1 + h);
        let g = 0.5 * (5f64.sqrt() - 1.0);
        for _ in 0..100 {
            let a = hi - g * (hi - lo);
            let b = lo + g * (hi - lo);
            if cost(a) < cost(b) {
                hi = b;
            } else {
                lo = a;
            }
        }
        cost(0.5 * (lo + hi))
    }

    #[test]
    fn correction_reaches_the_brute_force_optimum() {
        let mut rng = ChaCha8Rng::seed_from_u64(9);
        for _ in 0..20 {
            let (r, t) = random_pose(&mut rng, 0.4, 1.0);
            let scene = random_scene(&mut rng, &r, &t, 5, 2.0 / 500.0);
            let e = skew(&t) * r;
            for (x1, x2) in scene.x1().iter().zip(scene.x2().iter()) {
                let (c1, c2) = correct_correspondence(&e, x1, x2);
                let on_constraint =
                    Vector3::new(c2.x, c2.y, 1.0).dot(&(e * Vector3::new(c1.x, c1.y, 1.0)));
                assert!(
                    on_constraint.abs() < 1e-12,
                    "constraint residual {on_constraint:e}"
                );
                let ours = (c1 - x1).norm_squared() + (c2 - x2).norm_squared();
                let optimum = brute_force_cost(&e, x1, x2);
                assert!(
                    ours <= optimum * (1.0 + 1e-6) + 1e-18,
                    "correction cost {ours:e} above the optimum {optimum:e}"
                );
            }
        }
    }

    #[test]
    fn exact_data_triangulates_to_the_true_points() {
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let (r, t) = random_pose(&mut rng, 0.3, 1.0);
        let scene = random_scene(&mut rng, &r, &t, 50, 0.0);
        let config = TriangulationConfig {
            min_parallax_rad: 0.0,
            ..Default::default()
        };
        for (i, (x1, x2)) in scene.x1().iter().zip(scene.x2().iter()).enumerate() {
            let p = triangulate(&r, &t, x1, x2, &config).unwrap();
            let err = (p.point_c1 - scene.points_c1[i]).norm();
            assert!(
                err < 1e-9 * scene.points_c1[i].norm(),
                "point {i}: error {err:e}"
            );
        }
    }

    #[test]
    fn noisy_data_error_is_within_the_expected_depth_uncertainty() {
        let mut rng = ChaCha8Rng::seed_from_u64(12);
        let (r, t) = random_pose(&mut rng, 0.2, 1.0);
        let sigma = 0.5 / 500.0;
        let scene = random_scene(&mut rng, &r, &t, 300, sigma);
        let mut relative_errors = Vec::new();
        for (i, (x1, x2)) in scene.x1().iter().zip(scene.x2().iter()).enumerate() {
            if let Ok(p) = triangulate(&r, &t, x1, x2, &TriangulationConfig::default()) {
                // Depth error of a two-ray point grows as σ·depth/parallax.
                let expected = sigma / p.parallax_rad;
                relative_errors.push(
                    (p.point_c1 - scene.points_c1[i]).norm() / scene.points_c1[i].norm() / expected,
                );
            }
        }
        assert!(relative_errors.len() > 200);
        relative_errors.sort_by(f64::total_cmp);
        let median = relative_errors[relative_errors.len() / 2];
        assert!(
            median < 2.0,
            "median error {median} times the expected uncertainty"
        );
    }

    #[test]
    fn checks_reject_low_parallax_and_points_behind() {
        let r = Matrix3::identity();
        let t = Vector3::new(-1.0, 0.0, 0.0);
        // A point 1000 units ahead: 0.06° of parallax.
        let far = Vector3::new(0.0, 0.0, 1000.0);
        let x1 = far.xy() / far.z;
        let x2 = (far + t).xy() / far.z;
        assert!(matches!(
            triangulate(&r, &t, &x1, &x2, &TriangulationConfig::default()),
            Err(TriangulationFailure::LowParallax { .. })
        ));
        // A point behind both cameras projects the same way as one in front
        // mirrored; the depth check must refuse it.
        let behind = Vector3::new(0.5, 0.2, -4.0);
        let b2 = behind + t;
        let config = TriangulationConfig {
            min_parallax_rad: 0.0,
            ..Default::default()
        };
        assert!(matches!(
            triangulate(
                &r,
                &t,
                &(behind.xy() / behind.z),
                &(b2.xy() / b2.z),
                &config
            ),
            Err(TriangulationFailure::BehindCamera { .. })
        ));
        let nan = Vector2::new(f64::NAN, 0.0);
        assert_eq!(
            triangulate(&r, &t, &nan, &x2, &config),
            Err(TriangulationFailure::NonFinite)
        );
    }
}
