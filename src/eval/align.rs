//! Aligning an estimated trajectory to its ground truth before scoring:
//! closed-form least squares on matched positions.
//!
//! Umeyama, "Least-squares estimation of transformation parameters between
//! two point patterns", IEEE PAMI 13(4), 1991 (eq. 34-42), for SE(3) and
//! Sim(3); a 2-D version of the same argument for position + yaw.

use nalgebra::{Isometry3, Matrix3, Rotation3, Translation3, UnitQuaternion, Vector3};

use super::error::EvalError;

/// Which transformation is fitted between estimate and ground truth.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
#[serde(rename_all = "lowercase")]
pub enum Alignment {
    /// Compare as is.
    None,
    /// Rotation + translation (stereo, or anything with metric scale).
    Se3,
    /// Rotation + translation + scale (monocular).
    Sim3,
    /// Translation + rotation about the gravity (z) axis only: VIO, where
    /// roll and pitch are observable and must not be corrected.
    Posyaw,
}

impl Alignment {
    /// Lower-case name as `--align` and the JSON report spell it.
    pub fn name(self) -> &'static str {
        match self {
            Self::None => "none",
            Self::Se3 => "se3",
            Self::Sim3 => "sim3",
            Self::Posyaw => "posyaw",
        }
    }
}

/// A similarity `x -> scale * rotation * x + translation`, mapping estimate
/// world coordinates into ground-truth world coordinates.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sim3 {
    /// Rotation from estimate world to ground-truth world.
    pub rotation: Rotation3<f64>,
    /// Translation, in ground-truth world units (m).
    pub translation: Vector3<f64>,
    /// Scale, ground-truth units per estimate unit (1 unless fitted as Sim(3)).
    pub scale: f64,
}

impl Sim3 {
    /// The similarity that changes nothing (scale 1).
    pub fn identity() -> Self {
        Self {
            rotation: Rotation3::identity(),
            translation: Vector3::zeros(),
            scale: 1.0,
        }
    }

    /// Maps a point from estimate world into ground-truth world coordinates.
    pub fn transform_point(&self, p: &Vector3<f64>) -> Vector3<f64> {
        self.scale * (self.rotation * p) + self.translation
    }

    /// Moves a pose of the body in the estimate's world into the ground
    /// truth's world: the position is scaled, the orientation only rotated.
    #[allow(non_snake_case)]
    pub fn transform_pose(&self, T_world_body: &Isometry3<f64>) -> Isometry3<f64> {
        let rotation = UnitQuaternion::from_rotation_matrix(&self.rotation);
        Isometry3::from_parts(
            Translation3::from(self.transform_point(&T_world_body.translation.vector)),
            rotation * T_world_body.rotation,
        )
    }
}

/// Fits `kind` so that `transform(est[i]) ~ gt[i]` in least squares.
pub fn align(
    kind: Alignment,
    est: &[Vector3<f64>],
    gt: &[Vector3<f64>],
) -> Result<Sim3, EvalError> {
    match kind {
        Alignment::None => Ok(Sim3::identity()),
        Alignment::Se3 => umeyama(est, gt, false),
        Alignment::Sim3 => umeyama(est, gt, true),
        Alignment::Posyaw => align_pos_yaw(est, gt),
    }
}

/// Means and the cross-covariance `1/n sum (gt_i - mu_gt)(est_i - mu_est)^T`
/// (Umeyama eq. 38), plus the variance of the estimate (eq. 36).
struct Moments {
    mean_est: Vector3<f64>,
    mean_gt: Vector3<f64>,
    cov_gt_est: Matrix3<f64>,
    var_est: f64,
}

fn moments(est: &[Vector3<f64>], gt: &[Vector3<f64>], needed: usize) -> Result<Moments, EvalError> {
    assert_eq!(est.len(), gt.len(), "matched positions come in pairs");
    if est.len() < needed {
        return Err(EvalError::TooFewPoses {
            what: "alignment",
            needed,
            found: est.len(),
        });
    }
    let n = est.len() as f64;
    let mean_est = est.iter().sum::<Vector3<f64>>() / n;
    let mean_gt = gt.iter().sum::<Vector3<f64>>() / n;
    let mut cov_gt_est = Matrix3::zeros();
    let mut var_est = 0.0;
    for (e, g) in est.iter().zip(gt) {
        let de = e - mean_est;
        cov_gt_est += (g - mean_gt) * de.transpose();
        var_est += de.norm_squared();
    }
    Ok(Moments {
        mean_est,
        mean_gt,
        cov_gt_est: cov_gt_est / n,
        var_est: var_est / n,
    })
}

/// Umeyama's closed form (eq. 39-42): with `cov = U D V^T`, `R = U S V^T`
/// where S flips the axis of the smallest singular value when
/// `det(U) det(V) < 0` (the reflection fix), `c = trace(D S) / var_est`
/// (1 without scale), `t = mu_gt - c R mu_est`.
pub fn umeyama(
    est: &[Vector3<f64>],
    gt: &[Vector3<f64>],
    with_scale: bool,
) -> Result<Sim3, EvalError> {
    let m = moments(est, gt, 3)?;
    if m.var_est <= f64::EPSILON * m.mean_est.norm_squared().max(1.0) {
        return Err(EvalError::Degenerate(
            "all estimated positions are the same point".into(),
        ));
    }
    let svd = m.cov_gt_est.svd(true, true);
    let u = svd.u.expect("svd asked for U");
    let v_t = svd.v_t.expect("svd asked for V^T");
    let d = svd.singular_values;
    let (i_min, d_min) = d.argmin();
    let d_max = d.max();
    // Rank below 2 (points on a line): rotation about that line is free.
    let d_mid = d.sum() - d_max - d_min;
    if d_mid <= 1e-12 * d_max {
        return Err(EvalError::Degenerate(
            "matched positions lie on a line; rotation about it is not fixed".into(),
        ));
    }
    let mut s = Vector3::new(1.0, 1.0, 1.0);
    if u.determinant() * v_t.determinant() < 0.0 {
        s[i_min] = -1.0;
    }
    let r = u * Matrix3::from_diagonal(&s) * v_t;
    let rotation = Rotation3::from_matrix_unchecked(r);
    let scale = if with_scale {
        d.dot(&s) / m.var_est
    } else {
        1.0
    };
    Ok(Sim3 {
        rotation,
        translation: m.mean_gt - scale * (rotation * m.mean_est),
        scale,
    })
}

/// Translation + yaw (rotation about z) in closed form. With centred
/// positions e, g the cost `sum |g - R_z(th) e|^2` is minimal where
/// `th = atan2(sum (e_x g_y - e_y g_x), sum (e_x g_x + e_y g_y))`; z takes
/// no part in the rotation, and `t = mu_gt - R_z mu_est`.
pub fn align_pos_yaw(est: &[Vector3<f64>], gt: &[Vector3<f64>]) -> Result<Sim3, EvalError> {
    let m = moments(est, gt, 2)?;
    // Cross-covariance entries: cov[(r, c)] = mean g_r e_c.
    let c = &m.cov_gt_est;
    let cos_part = c[(0, 0)] + c[(1, 1)];
    let sin_part = c[(1, 0)] - c[(0, 1)];
    if cos_part.hypot(sin_part) <= 1e-15 * m.var_est.max(f64::MIN_POSITIVE) {
        return Err(EvalError::Degenerate(
            "estimated positions do not spread in x-y; yaw is not fixed".into(),
        ));
    }
    let yaw = sin_part.atan2(cos_part);
    let rotation = Rotation3::from_axis_angle(&Vector3::z_axis(), yaw);
    Ok(Sim3 {
        rotation,
        translation: m.mean_gt - rotation * m.mean_est,
        scale: 1.0,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;
    use rand_distr::{Distribution, Normal};

    fn random_points(n: usize, seed: u64) -> Vec<Vector3<f64>> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        (0..n)
            .map(|_| {
                Vector3::new(
                    rng.gen_range(-5.0..5.0),
                    rng.gen_range(-5.0..5.0),
                    rng.gen_range(-1.0..1.0),
                )
            })
            .collect()
    }

    fn known() -> Sim3 {
        Sim3 {
            rotation: Rotation3::from_euler_angles(0.3, -0.5, 2.1),
            translation: Vector3::new(1.5, -2.0, 0.7),
            scale: 1.7,
        }
    }

    /// |R_a - R_b|_F / sqrt(2): the angle between them for small angles,
    /// without the acos that loses digits near zero.
    fn rotation_error_rad(a: &Rotation3<f64>, b: &Rotation3<f64>) -> f64 {
        (a.matrix() - b.matrix()).norm() / 2f64.sqrt()
    }

    #[test]
    fn sim3_recovers_a_known_similarity_exactly() {
        let truth = known();
        let est = random_points(50, 1);
        let gt: Vec<_> = est.iter().map(|p| truth.transform_point(p)).collect();
        let fit = umeyama(&est, &gt, true).expect("well posed");
        assert!((fit.scale - truth.scale).abs() < 1e-9, "{}", fit.scale);
        assert!(rotation_error_rad(&fit.rotation, &truth.rotation) < 1e-9);
        assert!((fit.translation - truth.translation).norm() < 1e-9);
    }

    #[test]
    fn se3_recovers_a_known_rigid_motion_exactly() {
        let truth = Sim3 {
            scale: 1.0,
            ..known()
        };
        let est = random_points(50, 2);
        let gt: Vec<_> = est.iter().map(|p| truth.transform_point(p)).collect();
        let fit = umeyama(&est, &gt, false).expect("well posed");
        assert_eq!(fit.scale, 1.0);
        assert!(rotation_error_rad(&fit.rotation, &truth.rotation) < 1e-9);
        assert!((fit.translation - truth.translation).norm() < 1e-9);
        assert!((fit.rotation.matrix().determinant() - 1.0).abs() < 1e-12);
    }

    #[test]
    fn reflection_is_never_returned() {
        // Ground truth is the estimate mirrored in z. The corners of a
        // 6 x 4 x 2 box have a diagonal covariance, so the best proper
        // rotation is known: the identity, which leaves only the z errors
        // (the axis of least spread). Without the fix U V^T is the mirror.
        let est: Vec<_> = (0..8)
            .map(|k| {
                let sign = |bit: usize| if k & bit == 0 { 1.0 } else { -1.0 };
                Vector3::new(3.0 * sign(1), 2.0 * sign(2), sign(4))
            })
            .collect();
        let gt: Vec<_> = est.iter().map(|p| Vector3::new(p.x, p.y, -p.z)).collect();
        let fit = umeyama(&est, &gt, false).expect("well posed");
        assert!((fit.rotation.matrix().determinant() - 1.0).abs() < 1e-12);
        assert!(rotation_error_rad(&fit.rotation, &Rotation3::identity()) < 1e-9);
    }

    #[test]
    fn pos_yaw_recovers_yaw_and_translation_exactly() {
        let yaw = Rotation3::from_axis_angle(&Vector3::z_axis(), -2.4);
        let t = Vector3::new(-3.0, 0.5, 1.25);
        let est = random_points(30, 4);
        let gt: Vec<_> = est.iter().map(|p| yaw * p + t).collect();
        let fit = align_pos_yaw(&est, &gt).expect("well posed");
        assert!(rotation_error_rad(&fit.rotation, &yaw) < 1e-9);
        assert!((fit.translation - t).norm() < 1e-9);
        assert_eq!(fit.scale, 1.0);
    }

    #[test]
    fn pos_yaw_ignores_tilt_it_cannot_fix() {
        // A roll in the data is not absorbed: yaw stays the true one when the
        // roll is small and symmetric about it (the estimate is rolled about x).
        let yaw = Rotation3::from_axis_angle(&Vector3::z_axis(), 0.8);
        let roll = Rotation3::from_axis_angle(&Vector3::x_axis(), 0.05);
        let est = random_points(200, 5);
        let gt: Vec<_> = est.iter().map(|p| yaw * p).collect();
        let tilted: Vec<_> = est.iter().map(|p| roll * p).collect();
        let fit = align_pos_yaw(&tilted, &gt).expect("well posed");
        let (r, p, _) = fit.rotation.euler_angles();
        assert_eq!((r, p), (0.0, 0.0));
        // Rolling by 0.05 rad scales y by cos(0.05) at most: yaw moves little.
        assert!(rotation_error_rad(&fit.rotation, &yaw) < 0.01);
    }

    /// Noise of sigma per axis on N ground-truth points. First-order error
    /// propagation for the least-squares fit gives standard deviations:
    /// rotation about axis k, sigma / (sqrt(N) s sqrt(var_a + var_b)) with
    /// a, b the other two axes of the estimate's spread (var = per-axis
    /// variance) and s the scale; scale, sigma / (sqrt(N) rms|e|); translation,
    /// sigma / sqrt(N) per axis. Each bound below is 4 of those deviations
    /// (norms over three axes), loose enough not to flake, five orders of
    /// magnitude below what a wrong fit would give.
    #[test]
    fn sim3_with_noise_is_within_its_statistical_error() {
        let truth = known();
        let n = 500;
        let sigma_m = 0.01;
        let est = random_points(n, 6);
        let noise = Normal::new(0.0, sigma_m).expect("valid sigma");
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let gt: Vec<_> = est
            .iter()
            .map(|p| truth.transform_point(p) + Vector3::from_fn(|_, _| noise.sample(&mut rng)))
            .collect();
        let fit = umeyama(&est, &gt, true).expect("well posed");

        let root_n = (n as f64).sqrt();
        let mean = est.iter().sum::<Vector3<f64>>() / n as f64;
        let var = est
            .iter()
            .map(|p| (p - mean).component_mul(&(p - mean)))
            .sum::<Vector3<f64>>()
            / n as f64;
        let rot_var: f64 = (0..3)
            .map(|k| {
                let spread = var.sum() - var[k];
                (sigma_m / (root_n * truth.scale * spread.sqrt())).powi(2)
            })
            .sum();
        let rot_bound_rad = 4.0 * rot_var.sqrt();
        let scale_bound = 4.0 * sigma_m / (root_n * var.sum().sqrt());
        let trans_bound_m = 4.0 * 3f64.sqrt() * sigma_m / root_n;

        let rot_err = rotation_error_rad(&fit.rotation, &truth.rotation);
        let scale_err = (fit.scale - truth.scale).abs();
        let trans_err = (fit.translation - truth.translation).norm();
        assert!(rot_err < rot_bound_rad, "{rot_err} >= {rot_bound_rad}");
        assert!(scale_err < scale_bound, "{scale_err} >= {scale_bound}");
        assert!(trans_err < trans_bound_m, "{trans_err} >= {trans_bound_m}");
        // The noise is visible: the fit is not exact.
        assert!(scale_err > 1e-9 && rot_err > 1e-9);
    }

    #[test]
    fn degenerate_inputs_are_errors() {
        let p = Vector3::new(1.0, 2.0, 3.0);
        let same = vec![p; 5];
        assert!(matches!(
            umeyama(&same, &same, true),
            Err(EvalError::Degenerate(_))
        ));
        let line: Vec<_> = (0..5).map(|i| Vector3::new(i as f64, 0.0, 0.0)).collect();
        assert!(matches!(
            umeyama(&line, &line, false),
            Err(EvalError::Degenerate(_))
        ));
        assert!(matches!(
            umeyama(&line[..2], &line[..2], false),
            Err(EvalError::TooFewPoses { .. })
        ));
    }
}
