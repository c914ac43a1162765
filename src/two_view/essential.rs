//! The essential matrix: Sampson error, decomposition into a pose with the
//! cheirality check, and Levenberg-Marquardt refinement on the 5-DoF
//! essential manifold.
//!
//! Convention: `x_2 = R x_1 + t`, `E = [t]ₓ R`, `q2ᵀ E q1 = 0` for
//! homogeneous normalised image coordinates `q = (x, y, 1)`.

use nalgebra::{Matrix3, Matrix3x2, Rotation3, SMatrix, SVector, Unit, Vector2, Vector3};

use crate::imu::so3::{hat as skew, tangent_basis};

/// `E = [t]ₓ R`.
pub fn essential_from_pose(rotation_c2_c1: &Matrix3<f64>, t_c2_c1: &Vector3<f64>) -> Matrix3<f64> {
    skew(t_c2_c1) * rotation_c2_c1
}

fn homogeneous(x: &Vector2<f64>) -> Vector3<f64> {
    Vector3::new(x.x, x.y, 1.0)
}

/// Signed Sampson error of one correspondence, the first-order distance
/// to the epipolar variety (Hartley & Zisserman eq. 11.9), in normalised
/// image units: `q2ᵀEq1 / ‖(Eq1)₁₂, (Eᵀq2)₁₂‖`.
pub fn sampson_error(e: &Matrix3<f64>, x1: &Vector2<f64>, x2: &Vector2<f64>) -> f64 {
    let (q1, q2) = (homogeneous(x1), homogeneous(x2));
    let e_q1 = e * q1;
    let et_q2 = e.tr_mul(&q2);
    let algebraic = q2.dot(&e_q1);
    let denominator = e_q1.x * e_q1.x + e_q1.y * e_q1.y + et_q2.x * et_q2.x + et_q2.y * et_q2.y;
    if denominator <= 0.0 {
        return if algebraic == 0.0 { 0.0 } else { f64::INFINITY };
    }
    algebraic / denominator.sqrt()
}

/// The four poses `(R, t̂)` an essential matrix factors into
/// (Hartley & Zisserman result 9.19): `R ∈ {U W Vᵀ, U Wᵀ Vᵀ}`, `t̂ = ±u₃`.
pub fn decompose(e: &Matrix3<f64>) -> [(Matrix3<f64>, Vector3<f64>); 4] {
    let svd = e.svd(true, true);
    let mut u = svd.u.expect("U was requested");
    let mut v_t = svd.v_t.expect("Vᵀ was requested");
    // nalgebra does not sort singular values: put the smallest last.
    let (k, _) = svd.singular_values.argmin();
    if k != 2 {
        u.swap_columns(k, 2);
        v_t.swap_rows(k, 2);
    }
    if u.determinant() < 0.0 {
        u.column_mut(2).neg_mut();
    }
    if v_t.determinant() < 0.0 {
        v_t.row_mut(2).neg_mut();
    }
    let w = Matrix3::new(0.0, -1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0);
    let r1 = u * w * v_t;
    let r2 = u * w.transpose() * v_t;
    let t: Vector3<f64> = u.column(2).into();
    [(r1, t), (r1, -t), (r2, t), (r2, -t)]
}

/// Depths `(d1, d2)` along the rays `q1`, `q2` of the point nearest both
/// rays, `d1 R q1 + t ≈ d2 q2` (least squares, the midpoint method);
/// `None` for parallel rays.
pub fn ray_depths(
    rotation_c2_c1: &Matrix3<f64>,
    t_c2_c1: &Vector3<f64>,
    q1: &Vector3<f64>,
    q2: &Vector3<f64>,
) -> Option<(f64, f64)> {
    let a = rotation_c2_c1 * q1;
    let (aa, ab, bb) = (a.dot(&a), a.dot(q2), q2.dot(q2));
    let det = aa * bb - ab * ab;
    if det <= 1e-12 * aa * bb {
        return None;
    }
    let (ra, rb) = (-a.dot(t_c2_c1), q2.dot(t_c2_c1));
    Some(((bb * ra + ab * rb) / det, (ab * ra + aa * rb) / det))
}

/// Of the four decompositions of `e`, the one that puts the most of the
/// `selected` correspondences in front of both cameras (the cheirality
/// check, Hartley & Zisserman section 9.6.3), with that count.
pub fn pose_from_essential(
    e: &Matrix3<f64>,
    x1: &[Vector2<f64>],
    x2: &[Vector2<f64>],
    selected: &[bool],
) -> (Matrix3<f64>, Vector3<f64>, usize) {
    let candidates = decompose(e);
    let mut best = (candidates[0].0, candidates[0].1, 0);
    for (r, t) in candidates {
        let in_front = x1
            .iter()
            .zip(x2)
            .zip(selected)
            .filter(|(_, &s)| s)
            .filter(|((a, b), _)| {
                ray_depths(&r, &t, &homogeneous(a), &homogeneous(b))
                    .is_some_and(|(d1, d2)| d1 > 0.0 && d2 > 0.0)
            })
            .count();
        if in_front > best.2 {
            best = (r, t, in_front);
        }
    }
    best
}

/// The pose moved by `delta = (ω, v)`: `R ← R exp([ω]ₓ)`,
/// `t ← normalise(t + v₁ b₁ + v₂ b₂)`.
fn retract(
    r: &Matrix3<f64>,
    t: &Vector3<f64>,
    delta: &SVector<f64, 5>,
) -> (Matrix3<f64>, Vector3<f64>) {
    let omega = Vector3::new(delta[0], delta[1], delta[2]);
    let basis = tangent_basis(t);
    let (b1, b2) = (basis.column(0), basis.column(1));
    let r_new = r * Rotation3::from_scaled_axis(omega).into_inner();
    let t_new = (t + b1 * delta[3] + b2 * delta[4]).normalize();
    (r_new, t_new)
}

/// Sampson residual of one correspondence and its gradient with respect
/// to the five manifold coordinates of [`retract`] at zero.
fn residual_and_gradient(
    r: &Matrix3<f64>,
    t: &Vector3<f64>,
    basis: &Matrix3x2<f64>,
    x1: &Vector2<f64>,
    x2: &Vector2<f64>,
) -> Option<(f64, SVector<f64, 5>)> {
    let e = skew(t) * r;
    let (q1, q2) = (homogeneous(x1), homogeneous(x2));
    let e_q1 = e * q1;
    let et_q2 = e.tr_mul(&q2);
    let a = q2.dot(&e_q1);
    let s = e_q1.x * e_q1.x + e_q1.y * e_q1.y + et_q2.x * et_q2.x + et_q2.y * et_q2.y;
    if s <= 1e-300 {
        return None;
    }
    let d = s.sqrt();
    // dr/dE_ij = q2_i q1_j / d − a/d³ ((Eq1)_i q1_j [i<2] + (Eᵀq2)_j q2_i [j<2]).
    let mut g = q2 * q1.transpose() / d;
    let k = a / (s * d);
    for i in 0..2 {
        for j in 0..3 {
            g[(i, j)] -= k * e_q1[i] * q1[j];
        }
    }
    for i in 0..3 {
        for j in 0..2 {
            g[(i, j)] -= k * et_q2[j] * q2[i];
        }
    }
    let skew_t_r = skew(t) * r;
    let mut grad = SVector::<f64, 5>::zeros();
    for (c, axis) in [Vector3::x(), Vector3::y(), Vector3::z()]
        .iter()
        .enumerate()
    {
        grad[c] = g.dot(&(skew_t_r * skew(axis)));
    }
    grad[3] = g.dot(&(skew(&basis.column(0).into_owned()) * r));
    grad[4] = g.dot(&(skew(&basis.column(1).into_owned()) * r));
    Some((a / d, grad))
}

fn sampson_cost(
    r: &Matrix3<f64>,
    t: &Vector3<f64>,
    x1: &[Vector2<f64>],
    x2: &[Vector2<f64>],
    selected: &[bool],
) -> f64 {
    let e = skew(t) * r;
    x1.iter()
        .zip(x2)
        .zip(selected)
        .filter(|(_, &s)| s)
        .map(|((a, b), _)| sampson_error(&e, a, b).powi(2))
        .sum()
}

/// Levenberg-Marquardt on the sum of squared Sampson errors of the
/// `selected` correspondences, over rotations and unit translations (the
/// 5-DoF essential manifold). Returns the refined `(R, t̂)`; never worse
/// than the start.
pub fn refine_pose(
    rotation_c2_c1: &Matrix3<f64>,
    t_c2_c1: &Vector3<f64>,
    x1: &[Vector2<f64>],
    x2: &[Vector2<f64>],
    selected: &[bool],
    max_iterations: usize,
) -> (Matrix3<f64>, Vector3<f64>) {
    let mut r = *rotation_c2_c1;
    let mut t = t_c2_c1.normalize();
    let mut cost = sampson_cost(&r, &t, x1, x2, selected);
    let mut lambda = 1e-4;
    for _ in 0..max_iterations {
        let basis = tangent_basis(&t);
        let mut jtj = SMatrix::<f64, 5, 5>::zeros();
        let mut jtr = SVector::<f64, 5>::zeros();
        for ((a, b), _) in x1.iter().zip(x2).zip(selected).filter(|(_, &s)| s) {
            if let Some((res, grad)) = residual_and_gradient(&r, &t, &basis, a, b) {
                jtj += grad * grad.transpose();
                jtr += grad * res;
            }
        }
        let mut improved = false;
        while lambda < 1e8 {
            let mut damped = jtj;
            for i in 0..5 {
                damped[(i, i)] += lambda * jtj[(i, i)].max(1e-12);
            }
            let Some(delta) = damped.cholesky().map(|c| c.solve(&-jtr)) else {
                lambda *= 10.0;
                continue;
            };
            let (r_new, t_new) = retract(&r, &t, &delta);
            let new_cost = sampson_cost(&r_new, &t_new, x1, x2, selected);
            if new_cost < cost {
                let relative_gain = (cost - new_cost) / cost.max(1e-300);
                (r, t, cost) = (r_new, t_new, new_cost);
                lambda = (lambda * 0.1).max(1e-9);
                improved = relative_gain > 1e-10;
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

/// A unit translation direction.
pub fn unit(t: Vector3<f64>) -> Unit<Vector3<f64>> {
    Unit::new_normalize(t)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::two_view::test_scenes::{random_pose, random_scene, rotation_angle};
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    #[test]
    fn gradient_matches_central_differences() {
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let (r, t) = random_pose(&mut rng, 0.3, 1.0);
        let scene = random_scene(&mut rng, &r, &t, 10, 0.01);
        // Evaluate away from the truth so residuals are not zero.
        let (r0, t0) = retract(&r, &t, &SVector::from([0.01, -0.02, 0.015, 0.03, -0.02]));
        let basis = tangent_basis(&t0);
        let (x1, x2) = (scene.x1(), scene.x2());
        for i in 0..x1.len() {
            let (_, grad) = residual_and_gradient(&r0, &t0, &basis, &x1[i], &x2[i]).unwrap();
            for k in 0..5 {
                let h = 1e-6;
                let mut d = SVector::<f64, 5>::zeros();
                d[k] = h;
                let (rp, tp) = retract(&r0, &t0, &d);
                let (rm, tm) = retract(&r0, &t0, &-d);
                let numeric = (sampson_error(&(skew(&tp) * rp), &x1[i], &x2[i])
                    - sampson_error(&(skew(&tm) * rm), &x1[i], &x2[i]))
                    / (2.0 * h);
                assert!(
                    (grad[k] - numeric).abs() < 1e-6 * numeric.abs().max(1e-3),
                    "point {i} coordinate {k}: analytic {} numeric {numeric}",
                    grad[k]
                );
            }
        }
    }

    #[test]
    fn decomposition_and_cheirality_recover_the_pose() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        for _ in 0..50 {
            let (r, t) = random_pose(&mut rng, 0.6, 1.0);
            let scene = random_scene(&mut rng, &r, &t, 30, 0.0);
            let e = essential_from_pose(&r, &t);
            let all = vec![true; 30];
            let (r_est, t_est, in_front) = pose_from_essential(&e, &scene.x1(), &scene.x2(), &all);
            assert_eq!(in_front, 30);
            assert!(rotation_angle(&r, &r_est) < 1e-9);
            assert!((t_est - t.normalize()).norm() < 1e-9);
        }
    }

    #[test]
    fn refinement_lowers_the_rotation_error_of_a_perturbed_start() {
        let mut rng = ChaCha8Rng::seed_from_u64(8);
        let (r, t) = random_pose(&mut rng, 0.3, 1.0);
        let scene = random_scene(&mut rng, &r, &t, 200, 1e-3);
        let (r0, t0) = retract(
            &r,
            &t.normalize(),
            &SVector::from([0.02, 0.0, -0.01, 0.05, 0.02]),
        );
        let all = vec![true; 200];
        let (r1, t1) = refine_pose(&r0, &t0, &scene.x1(), &scene.x2(), &all, 30);
        let before = rotation_angle(&r, &r0);
        let after = rotation_angle(&r, &r1);
        assert!(
            after < 2e-3,
            "rotation error after refinement {after} rad (before {before})"
        );
        assert!((t1 - t.normalize()).norm() < 0.02);
    }
}
