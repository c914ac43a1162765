//! Robust relative pose: MSAC over five-point hypotheses with an adaptive
//! iteration count, cheirality, refinement, and a rotation-only fallback
//! when the views have no parallax.
//!
//! Scoring is the truncated quadratic of MSAC (Torr & Zisserman, "MLESAC",
//! CVIU 2000): each correspondence costs its squared Sampson error, clamped
//! at the squared threshold, so outliers cost a constant and inliers their
//! fit. The number of iterations follows the best inlier ratio `w` found so
//! far: `N = log(1 − p) / log(1 − w⁵)` (Fischler & Bolles 1981).

use nalgebra::{Matrix3, Rotation3, Unit, Vector2, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::essential::{pose_from_essential, refine_pose, sampson_error};
use super::five_point::five_point;
use super::TwoViewError;
use crate::imu::so3::hat as skew;

/// Levenberg-Marquardt iterations of each local optimisation.
const LOCAL_REFINE_ITERATIONS: usize = 5;

/// Settings of [`estimate_relative_pose`].
#[derive(Debug, Clone, PartialEq)]
pub struct RelativePoseConfig {
    /// Inlier threshold on the Sampson error, in normalised image units
    /// (pixels divided by the focal length).
    pub threshold: f64,
    /// Probability of having drawn one all-inlier sample when stopping.
    pub confidence: f64,
    /// Largest number of MSAC iterations.
    pub max_iterations: usize,
    /// Fewest inliers a pose may rest on.
    pub min_inliers: usize,
    /// Seed of the sampler; the same seed and input give the same result.
    pub seed: u64,
    /// Levenberg-Marquardt iterations on the inliers (0 disables).
    pub refine_iterations: usize,
    /// Below this median rotation-compensated angle between the rays of
    /// the inliers (radians) the translation is deemed unobservable and
    /// only a rotation is estimated.
    pub min_parallax_rad: f64,
}

impl RelativePoseConfig {
    /// Defaults for a camera of focal length `focal_px` and an inlier
    /// threshold of `threshold_px` pixels.
    pub fn for_pixels(threshold_px: f64, focal_px: f64) -> Self {
        let threshold = threshold_px / focal_px;
        Self {
            threshold,
            confidence: 0.999,
            max_iterations: 1000,
            min_inliers: 8,
            seed: 0,
            refine_iterations: 50,
            min_parallax_rad: 2.0 * threshold,
        }
    }

    fn validate(&self) -> Result<(), TwoViewError> {
        let checks: [(&'static str, f64, bool, &'static str); 4] = [
            ("threshold", self.threshold, self.threshold > 0.0, "> 0"),
            (
                "confidence",
                self.confidence,
                self.confidence > 0.0 && self.confidence < 1.0,
                "(0, 1)",
            ),
            (
                "max_iterations",
                self.max_iterations as f64,
                self.max_iterations > 0,
                ">= 1",
            ),
            (
                "min_parallax_rad",
                self.min_parallax_rad,
                self.min_parallax_rad >= 0.0,
                ">= 0",
            ),
        ];
        for (key, value, ok, allowed) in checks {
            if !ok || !value.is_finite() {
                return Err(TwoViewError::InvalidConfig {
                    key,
                    value,
                    allowed,
                });
            }
        }
        Ok(())
    }
}

/// A relative pose `x_2 = R x_1 + t` up to the scale of `t`.
#[derive(Debug, Clone)]
pub struct RelativePose {
    /// `R` of `x_2 = R x_1 + t`: rotation from the first camera's frame to the second's.
    pub rotation_c2_c1: Rotation3<f64>,
    /// Direction of `t`; `None` when the views have too little parallax to
    /// observe it (pure rotation), in which case `rotation_c2_c1` comes from
    /// the rotation-only fit.
    pub translation_dir_c2_c1: Option<Unit<Vector3<f64>>>,
    /// `[t]ₓ R` of unit norm; zero when the translation is unobservable.
    pub essential: Matrix3<f64>,
    /// Per correspondence: whether it is an inlier of the final pose.
    pub inliers: Vec<bool>,
    /// Number of inliers.
    pub inlier_count: usize,
    /// Inliers in front of both cameras.
    pub in_front_count: usize,
    /// MSAC iterations run.
    pub iterations: usize,
    /// Median angle between `R q1` and `q2` over the inliers.
    pub median_parallax_rad: f64,
}

/// Checks shared by the robust estimators: equal lengths, enough
/// correspondences, finite coordinates.
pub(crate) fn validate_correspondences<A, B>(
    a: &[A],
    b: &[B],
    needed: usize,
    finite: impl Fn(&A, &B) -> bool,
) -> Result<(), TwoViewError> {
    if a.len() != b.len() {
        return Err(TwoViewError::LengthMismatch {
            first: a.len(),
            second: b.len(),
        });
    }
    if a.len() < needed {
        return Err(TwoViewError::TooFewCorrespondences {
            needed,
            got: a.len(),
        });
    }
    if let Some(index) = a.iter().zip(b).position(|(p, q)| !finite(p, q)) {
        return Err(TwoViewError::NonFinite { index });
    }
    Ok(())
}

/// `k` distinct indices below `n` (`k` small, so by rejection).
pub(crate) fn sample_distinct<const K: usize>(rng: &mut ChaCha8Rng, n: usize) -> [usize; K] {
    let mut out = [0; K];
    let mut filled = 0;
    while filled < K {
        let i = rng.gen_range(0..n);
        if !out[..filled].contains(&i) {
            out[filled] = i;
            filled += 1;
        }
    }
    out
}

/// Iterations needed to draw one all-inlier sample of size `k` with
/// probability `confidence` when a fraction `w` are inliers.
pub(crate) fn needed_iterations(confidence: f64, w: f64, k: i32, cap: usize) -> usize {
    let p_good = w.powi(k);
    if p_good >= 1.0 {
        return 1;
    }
    if p_good <= 0.0 {
        return cap;
    }
    let n = (1.0 - confidence).ln() / (1.0 - p_good).ln();
    if n.is_finite() {
        (n.ceil() as usize).clamp(1, cap)
    } else {
        cap
    }
}

/// MSAC cost of `e` (truncated squared Sampson errors) and its inlier
/// count; stops early, returning `None`, once the cost exceeds `bound`.
fn msac_cost(
    e: &Matrix3<f64>,
    x1: &[Vector2<f64>],
    x2: &[Vector2<f64>],
    threshold_sq: f64,
    bound: f64,
) -> Option<(f64, usize)> {
    let mut cost = 0.0;
    let mut inliers = 0;
    for (a, b) in x1.iter().zip(x2) {
        let r2 = sampson_error(e, a, b).powi(2);
        if r2 < threshold_sq {
            cost += r2;
            inliers += 1;
        } else {
            cost += threshold_sq;
        }
        if cost > bound {
            return None;
        }
    }
    Some((cost, inliers))
}

/// MSAC cost with inliers behind either camera (for the best of the four
/// decompositions) counted as outliers: on a planar scene the second
/// essential matrix that fits the points (Nistér 2004, section 4) is
/// refused here, not by the epipolar error.
fn cheirality_cost(
    e: &Matrix3<f64>,
    x1: &[Vector2<f64>],
    x2: &[Vector2<f64>],
    threshold_sq: f64,
    mask: &mut [bool],
) -> (f64, usize) {
    let (cost, inliers) = msac_cost(e, x1, x2, threshold_sq, f64::INFINITY)
        .expect("an infinite bound never stops early");
    mark_inliers(e, x1, x2, threshold_sq, mask);
    let (_, _, in_front) = pose_from_essential(e, x1, x2, mask);
    let behind = inliers - in_front.min(inliers);
    // A point behind costs the threshold instead of its (smaller) error;
    // adding the full threshold is a bound that keeps the order.
    (cost + threshold_sq * behind as f64, inliers)
}

fn mark_inliers(
    e: &Matrix3<f64>,
    x1: &[Vector2<f64>],
    x2: &[Vector2<f64>],
    threshold_sq: f64,
    mask: &mut [bool],
) -> usize {
    let mut count = 0;
    for ((a, b), m) in x1.iter().zip(x2).zip(mask.iter_mut()) {
        *m = sampson_error(e, a, b).powi(2) < threshold_sq;
        count += usize::from(*m);
    }
    count
}

fn bearing(x: &Vector2<f64>) -> Vector3<f64> {
    Vector3::new(x.x, x.y, 1.0).normalize()
}

/// Median over the selected pairs of the angle between `R q1` and `q2`.
fn median_parallax(
    r: &Matrix3<f64>,
    x1: &[Vector2<f64>],
    x2: &[Vector2<f64>],
    mask: &[bool],
) -> f64 {
    let mut angles: Vec<f64> = x1
        .iter()
        .zip(x2)
        .zip(mask)
        .filter(|(_, &m)| m)
        .map(|((a, b), _)| (r * bearing(a)).angle(&bearing(b)))
        .collect();
    if angles.is_empty() {
        return 0.0;
    }
    let mid = angles.len() / 2;
    *angles.select_nth_unstable_by(mid, |a, b| a.total_cmp(b)).1
}

/// Relative pose from normalised image coordinates `x1[i] ↔ x2[i]`
/// (`K⁻¹` applied, distortion removed; see
/// [`crate::camera::CameraModel::unproject`]).
///
/// MSAC over five-point samples, cheirality on the inliers of the winner,
/// then Levenberg-Marquardt on their Sampson errors, re-selecting the
/// inliers once. When the inliers' median parallax is below
/// `min_parallax_rad` (or no essential matrix is found at all), a
/// rotation-only model is fitted instead and the translation reported as
/// unobservable.
pub fn estimate_relative_pose(
    x1: &[Vector2<f64>],
    x2: &[Vector2<f64>],
    config: &RelativePoseConfig,
) -> Result<RelativePose, TwoViewError> {
    config.validate()?;
    validate_correspondences(x1, x2, 5, |a, b| {
        a.iter().chain(b.iter()).all(|v| v.is_finite())
    })?;
    let n = x1.len();
    let threshold_sq = config.threshold * config.threshold;
    let mut rng = ChaCha8Rng::seed_from_u64(config.seed);

    let mut best: Option<(Matrix3<f64>, f64, usize)> = None;
    let mut mask = vec![false; n];
    let mut needed = config.max_iterations;
    let mut iterations = 0;
    while iterations < needed {
        iterations += 1;
        let sample = sample_distinct::<5>(&mut rng, n);
        let q1 = sample.map(|i| Vector3::new(x1[i].x, x1[i].y, 1.0));
        let q2 = sample.map(|i| Vector3::new(x2[i].x, x2[i].y, 1.0));
        let mut improved = false;
        for e in five_point(&q1, &q2).as_slice() {
            let bound = best.map_or(f64::INFINITY, |b| b.1);
            if msac_cost(e, x1, x2, threshold_sq, bound).is_some_and(|(c, _)| c < bound) {
                let (cost, inliers) = cheirality_cost(e, x1, x2, threshold_sq, &mut mask);
                if cost < bound {
                    best = Some((*e, cost, inliers));
                    improved = true;
                }
            }
        }
        if !improved {
            continue;
        }
        // Local optimisation (Chum, Matas & Kittler, "Locally optimized
        // RANSAC", DAGM 2003): refine each new best on its inliers and keep
        // the refined model when it scores better.
        if config.refine_iterations > 0 {
            let (e, cost, _) = best.expect("a model was just accepted");
            mark_inliers(&e, x1, x2, threshold_sq, &mut mask);
            let (r, t, _) = pose_from_essential(&e, x1, x2, &mask);
            let (r, t) = refine_pose(&r, &t, x1, x2, &mask, LOCAL_REFINE_ITERATIONS);
            let refined = skew(&t) * r;
            let (c, inliers) = cheirality_cost(&refined, x1, x2, threshold_sq, &mut mask);
            if c < cost {
                best = Some((refined, c, inliers));
            }
        }
        let w = best.expect("a model was just accepted").2 as f64 / n as f64;
        needed = needed_iterations(config.confidence, w, 5, config.max_iterations);
    }

    let Some((e_best, _, _)) = best else {
        return rotation_only(x1, x2, config, iterations);
    };
    let mut inlier_count = mark_inliers(&e_best, x1, x2, threshold_sq, &mut mask);
    if inlier_count < config.min_inliers.max(5) {
        return rotation_only(x1, x2, config, iterations);
    }
    let (mut r, mut t, _) = pose_from_essential(&e_best, x1, x2, &mask);
    if config.refine_iterations > 0 {
        for _ in 0..3 {
            (r, t) = refine_pose(&r, &t, x1, x2, &mask, config.refine_iterations);
            inlier_count = mark_inliers(&(skew(&t) * r), x1, x2, threshold_sq, &mut mask);
        }
    }
    let parallax = median_parallax(&r, x1, x2, &mask);
    if parallax < config.min_parallax_rad {
        return rotation_only(x1, x2, config, iterations);
    }
    let e = skew(&t) * r;
    let (_, _, in_front_count) = pose_from_essential(&e, x1, x2, &mask);
    Ok(RelativePose {
        rotation_c2_c1: Rotation3::from_matrix_unchecked(r),
        translation_dir_c2_c1: Some(Unit::new_normalize(t)),
        essential: e / e.norm(),
        inliers: mask,
        inlier_count,
        in_front_count,
        iterations,
        median_parallax_rad: parallax,
    })
}

/// Least-squares rotation with `b ≈ R a` over the selected bearing pairs
/// (Kabsch / Wahba by SVD); `None` when the pairs do not fix it.
pub fn fit_rotation(a: &[Vector3<f64>], b: &[Vector3<f64>]) -> Option<Matrix3<f64>> {
    let mut h = Matrix3::zeros();
    for (p, q) in a.iter().zip(b) {
        h += q * p.transpose();
    }
    let svd = h.svd(true, true);
    let (u, v_t) = (svd.u?, svd.v_t?);
    let mut sorted = svd.singular_values;
    sorted.as_mut_slice().sort_by(|x, y| y.total_cmp(x));
    if sorted[1] <= 1e-12 * sorted[0].max(1e-300) {
        return None;
    }
    let d = (u * v_t).determinant().signum();
    Some(u * Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, d)) * v_t)
}

/// The pure-rotation model: RANSAC over two-point samples of the bearing
/// pairs, inliers by the angle between `R q1` and `q2` below the threshold,
/// then a Kabsch fit on all inliers.
fn rotation_only(
    x1: &[Vector2<f64>],
    x2: &[Vector2<f64>],
    config: &RelativePoseConfig,
    iterations_so_far: usize,
) -> Result<RelativePose, TwoViewError> {
    let n = x1.len();
    let f1: Vec<Vector3<f64>> = x1.iter().map(bearing).collect();
    let f2: Vec<Vector3<f64>> = x2.iter().map(bearing).collect();
    let threshold_sq = config.threshold * config.threshold;
    // Squared chord between unit vectors ≈ squared angle for small angles.
    let cost_of = |r: &Matrix3<f64>, mask: Option<&mut [bool]>| -> (f64, usize) {
        let mut cost = 0.0;
        let mut count = 0;
        let mut mask = mask;
        for i in 0..n {
            let d2 = (r * f1[i] - f2[i]).norm_squared();
            let inlier = d2 < threshold_sq;
            cost += d2.min(threshold_sq);
            count += usize::from(inlier);
            if let Some(m) = mask.as_deref_mut() {
                m[i] = inlier;
            }
        }
        (cost, count)
    };
    let mut rng = ChaCha8Rng::seed_from_u64(config.seed ^ 0x5eed);
    let mut best: Option<(Matrix3<f64>, f64)> = None;
    let mut needed = config.max_iterations;
    let mut iterations = 0;
    while iterations < needed {
        iterations += 1;
        let [i, j] = sample_distinct::<2>(&mut rng, n);
        let Some(r) = fit_rotation(&[f1[i], f1[j]], &[f2[i], f2[j]]) else {
            continue;
        };
        let (cost, count) = cost_of(&r, None);
        if best.map_or(true, |b| cost < b.1) {
            best = Some((r, cost));
            needed = needed_iterations(
                config.confidence,
                count as f64 / n as f64,
                2,
                config.max_iterations,
            );
        }
    }
    let mut mask = vec![false; n];
    let Some((r0, _)) = best else {
        return Err(TwoViewError::NoConsensus {
            best: 0,
            needed: config.min_inliers,
        });
    };
    let (_, count) = cost_of(&r0, Some(&mut mask));
    let (a, b): (Vec<_>, Vec<_>) = (0..n).filter(|&i| mask[i]).map(|i| (f1[i], f2[i])).unzip();
    let r = fit_rotation(&a, &b).unwrap_or(r0);
    let (_, inlier_count) = cost_of(&r, Some(&mut mask));
    if inlier_count < config.min_inliers.max(2) {
        return Err(TwoViewError::NoConsensus {
            best: count.max(inlier_count),
            needed: config.min_inliers,
        });
    }
    let parallax = median_parallax(&r, x1, x2, &mask);
    Ok(RelativePose {
        rotation_c2_c1: Rotation3::from_matrix_unchecked(r),
        translation_dir_c2_c1: None,
        essential: Matrix3::zeros(),
        inliers: mask,
        inlier_count,
        in_front_count: 0,
        iterations: iterations_so_far + iterations,
        median_parallax_rad: parallax,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::two_view::test_scenes::{random_pose, random_scene, rotation_angle};

    const FOCAL_PX: f64 = 500.0;

    fn config() -> RelativePoseConfig {
        RelativePoseConfig::for_pixels(1.0, FOCAL_PX)
    }

    #[test]
    fn half_outliers_are_rejected_and_the_pose_recovered() {
        let mut rng = ChaCha8Rng::seed_from_u64(21);
        for trial in 0..10 {
            let (r, t) = random_pose(&mut rng, 0.3, 1.0);
            let scene = random_scene(&mut rng, &r, &t, 200, 0.3 / FOCAL_PX);
            let (mut x1, mut x2) = (scene.x1(), scene.x2());
            // Every other correspondence becomes an outlier: view-2 point
            // replaced by a random one.
            for i in (0..200).step_by(2) {
                x2[i] = Vector2::new(rng.gen_range(-1.0..1.0), rng.gen_range(-1.0..1.0));
            }
            let mut config = config();
            config.seed = trial;
            let pose = estimate_relative_pose(&x1, &x2, &config).unwrap();
            let rot_err_deg = rotation_angle(&r, pose.rotation_c2_c1.matrix()).to_degrees();
            let t_est = pose.translation_dir_c2_c1.expect("translation observable");
            let t_err_deg = t_est.angle(&t).to_degrees();
            assert!(
                rot_err_deg < 0.1,
                "trial {trial}: rotation error {rot_err_deg} deg"
            );
            assert!(
                t_err_deg < 2.0,
                "trial {trial}: translation error {t_err_deg} deg"
            );
            // Outliers that happen to lie near their epipolar line are
            // accepted; true inliers must all be found.
            let true_found = (1..200).step_by(2).filter(|&i| pose.inliers[i]).count();
            assert!(
                true_found >= 95,
                "trial {trial}: {true_found} of 100 inliers kept"
            );
            assert!(
                pose.inlier_count < 130,
                "trial {trial}: {} inliers",
                pose.inlier_count
            );
            x1.truncate(0);
        }
    }

    #[test]
    fn same_seed_same_result() {
        let mut rng = ChaCha8Rng::seed_from_u64(2);
        let (r, t) = random_pose(&mut rng, 0.3, 1.0);
        let scene = random_scene(&mut rng, &r, &t, 60, 0.5 / FOCAL_PX);
        let a = estimate_relative_pose(&scene.x1(), &scene.x2(), &config()).unwrap();
        let b = estimate_relative_pose(&scene.x1(), &scene.x2(), &config()).unwrap();
        assert_eq!(a.rotation_c2_c1, b.rotation_c2_c1);
        assert_eq!(a.inliers, b.inliers);
    }

    #[test]
    fn planar_scene_gives_the_true_pose() {
        // A fronto-parallel plane at depth 5 and a sideways motion: the
        // homography's second decomposition puts points on both sides of
        // the camera, so cheirality must pick the true one.
        let mut rng = ChaCha8Rng::seed_from_u64(4);
        let r = Rotation3::from_scaled_axis(Vector3::new(0.02, -0.05, 0.01)).into_inner();
        let t = Vector3::new(0.5, 0.05, 0.1);
        let (mut x1, mut x2) = (Vec::new(), Vec::new());
        for _ in 0..150 {
            let p = Vector3::new(rng.gen_range(-3.0..3.0), rng.gen_range(-2.0..2.0), 5.0);
            let p2 = r * p + t;
            let mut n = || rng.gen_range(-0.3..0.3) / FOCAL_PX;
            x1.push(Vector2::new(p.x / p.z, p.y / p.z));
            x2.push(Vector2::new(p2.x / p2.z, p2.y / p2.z));
            let (n1, n2, n3, n4) = (n(), n(), n(), n());
            let last = x1.len() - 1;
            x1[last] += Vector2::new(n1, n2);
            x2[last] += Vector2::new(n3, n4);
        }
        let pose = estimate_relative_pose(&x1, &x2, &config()).unwrap();
        let rot_err_deg = rotation_angle(&r, pose.rotation_c2_c1.matrix()).to_degrees();
        assert!(rot_err_deg < 0.2, "rotation error {rot_err_deg} deg");
        let t_err_deg = pose.translation_dir_c2_c1.unwrap().angle(&t).to_degrees();
        assert!(t_err_deg < 5.0, "translation error {t_err_deg} deg");
    }

    #[test]
    fn pure_rotation_gives_the_rotation_and_no_translation() {
        let mut rng = ChaCha8Rng::seed_from_u64(6);
        let r = Rotation3::from_scaled_axis(Vector3::new(0.05, 0.1, -0.03)).into_inner();
        let scene = random_scene(&mut rng, &r, &Vector3::zeros(), 150, 0.5 / FOCAL_PX);
        let pose = estimate_relative_pose(&scene.x1(), &scene.x2(), &config()).unwrap();
        assert!(
            pose.translation_dir_c2_c1.is_none(),
            "translation reported for a pure rotation"
        );
        let rot_err_deg = rotation_angle(&r, pose.rotation_c2_c1.matrix()).to_degrees();
        assert!(rot_err_deg < 0.05, "rotation error {rot_err_deg} deg");
        assert!(pose.inlier_count > 120);
    }

    #[test]
    fn bad_input_is_an_error_not_a_panic() {
        let p = vec![Vector2::new(0.1, 0.2); 4];
        assert!(matches!(
            estimate_relative_pose(&p, &p, &config()),
            Err(TwoViewError::TooFewCorrespondences { needed: 5, got: 4 })
        ));
        let mut q = vec![Vector2::new(0.1, 0.2); 10];
        assert!(matches!(
            estimate_relative_pose(&q, &p, &config()),
            Err(TwoViewError::LengthMismatch { .. })
        ));
        q[3].y = f64::NAN;
        assert!(matches!(
            estimate_relative_pose(&q, &q, &config()),
            Err(TwoViewError::NonFinite { index: 3 })
        ));
        let nan_focal = RelativePoseConfig::for_pixels(1.0, f64::NAN);
        let ok = vec![Vector2::new(0.1, 0.2); 10];
        assert!(matches!(
            estimate_relative_pose(&ok, &ok, &nan_focal),
            Err(TwoViewError::InvalidConfig {
                key: "threshold",
                ..
            })
        ));
        // Ten copies of one correspondence: degenerate, no consensus, no panic.
        assert!(estimate_relative_pose(&ok, &ok, &config()).is_err());
    }
}
