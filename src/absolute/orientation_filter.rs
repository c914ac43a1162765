//! The orientation half of the absolute stage's correction.
//!
//! The paper's filter corrects the robot's position only and takes the
//! orientation from the relative stage as exact. It is not: the relative
//! stage's yaw drifts without bound and its tilt wanders, and every edge
//! the map is built from is a body-frame offset turned into the world by
//! that orientation. Handed the true orientation, the two stages halve the
//! relative stage's error on the development renderings; with the drifting
//! one they barely match it (docs/results/).
//!
//! State: the offset `R_o` that turns the relative stage's world frame
//! into the map's (`R_map_body = R_o R_rel`), with covariance `P` (3 x 3,
//! rad², on the left tangent). Prediction: a random walk per second,
//! `P <- P + σ² Δt I`. Correction: each visible map landmark `i` with map
//! position `L_i` and world-turned body offset `v_i = R_o R_rel y_i`
//! (current offset) gives `L_i - x = Exp(θ) v_i + n_i`, linearised at
//! `θ = 0` as `r_i = L_i - x - v_i = δx + J_i θ + n_i` with
//! `J_i = -[v_i]×` and `Cov(n) = N` (the offsets' covariances and the
//! map's joint covariance of the landmarks). The position error `δx` is
//! left free and marginalised out (Schur complement), so the orientation
//! is measured by the landmarks' directions from one another, whatever
//! the position filter did with them; a shift common to all the map's
//! landmarks changes nothing. `θ̂ = (P⁻¹ + H)⁻¹ g`, `R_o <- Exp(θ̂) R_o`.
//!
//! What it leaves out, like the paper's filter: the correlation of the
//! offset's error with the map's (a landmark seen again brings the same
//! map error again), so `P` is optimistic; the random walk keeps it from
//! closing.

use nalgebra::{DMatrix, Matrix3, UnitQuaternion, Vector3};

use super::position_filter::LandmarkFix;

/// Fewer landmarks than this do not correct the orientation: a few
/// directions pin a rotation poorly, and one wrong recognition among them
/// would turn the robot.
pub const MIN_ORIENTATION_LANDMARKS: usize = 10;

/// A correction larger than this (rad, about 3 degrees) in one frame is
/// not applied: the relative stage does not drift that fast, so it is a
/// wrong association or a broken map.
pub const MAX_ORIENTATION_STEP_RAD: f64 = 0.05;

/// One visible landmark as seen for the orientation correction.
#[derive(Clone, Copy, Debug)]
pub struct DirectionFix {
    /// `L_i - x`: the map's landmark less the robot position (any
    /// reference position will do: it is marginalised out), m.
    pub landmark_from_robot_m: Vector3<f64>,
    /// `v_i = R_o R_rel y_i`, m.
    pub offset_world_m: Vector3<f64>,
}

/// What one correction did.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum OrientationUpdate {
    /// Applied: the rotation (rad, left tangent) the offset turned by.
    Applied(Vector3<f64>),
    /// Too few landmarks ([`MIN_ORIENTATION_LANDMARKS`]).
    TooFewLandmarks,
    /// The landmarks' directions do not pin the rotation (collinear), or
    /// the noise covariance is not positive definite.
    Singular,
    /// The step would exceed [`MAX_ORIENTATION_STEP_RAD`].
    TooLarge(f64),
}

/// The orientation offset filter.
#[derive(Clone, Debug)]
pub struct OrientationFilter {
    offset: UnitQuaternion<f64>,
    covariance_rad2: Matrix3<f64>,
    sigma_rad_per_sqrt_s: f64,
    last_t_ns: Option<i64>,
}

/// Variance the offset starts with, rad² (it is exact at the anchor; not
/// zero, to keep the information form finite).
const START_VARIANCE_RAD2: f64 = 1e-12;

impl OrientationFilter {
    /// An offset of identity (the map's frame is the relative stage's at
    /// the anchor) that wanders by `sigma_rad_per_sqrt_s` rad per √s.
    pub fn new(sigma_rad_per_sqrt_s: f64) -> Self {
        Self {
            offset: UnitQuaternion::identity(),
            covariance_rad2: Matrix3::identity() * START_VARIANCE_RAD2,
            sigma_rad_per_sqrt_s,
            last_t_ns: None,
        }
    }

    /// An offset of identity known to `covariance_rad2` (a fit's
    /// uncertainty) that wanders by `sigma_rad_per_sqrt_s` rad per √s.
    pub fn starting_at(sigma_rad_per_sqrt_s: f64, covariance_rad2: Matrix3<f64>) -> Self {
        Self {
            covariance_rad2,
            ..Self::new(sigma_rad_per_sqrt_s)
        }
    }

    /// `R_o`: turns the relative stage's world frame into the map's.
    pub fn offset(&self) -> UnitQuaternion<f64> {
        self.offset
    }

    /// Covariance of the offset, rad².
    pub fn covariance_rad2(&self) -> Matrix3<f64> {
        self.covariance_rad2
    }

    /// The random walk up to the frame at `t_ns` (stamps going back add
    /// nothing).
    pub fn predict(&mut self, t_ns: i64) {
        if let Some(last) = self.last_t_ns {
            let dt_s = (t_ns - last).max(0) as f64 * 1e-9;
            self.covariance_rad2 += Matrix3::identity() * self.sigma_rad_per_sqrt_s.powi(2) * dt_s;
        }
        self.last_t_ns = Some(self.last_t_ns.map_or(t_ns, |l| l.max(t_ns)));
    }

    /// The correction with `fixes` and the joint covariance `noise_m2` of
    /// their residuals (3m x 3m: each offset's covariance on its diagonal
    /// block plus the map's joint covariance of the landmarks). Returns
    /// what it did; the offset and its covariance change only when
    /// [`OrientationUpdate::Applied`].
    pub fn correct(
        &mut self,
        fixes: &[DirectionFix],
        noise_m2: &DMatrix<f64>,
    ) -> OrientationUpdate {
        let m = fixes.len();
        if m < MIN_ORIENTATION_LANDMARKS {
            return OrientationUpdate::TooFewLandmarks;
        }
        let Some(information) = marginal_information(fixes, noise_m2) else {
            return OrientationUpdate::Singular;
        };
        let (h, g) = information;
        let Some(prior_information) = self.covariance_rad2.try_inverse() else {
            return OrientationUpdate::Singular;
        };
        let Some(posterior) = (prior_information + h).try_inverse() else {
            return OrientationUpdate::Singular;
        };
        let posterior = 0.5 * (posterior + posterior.transpose());
        let step = posterior * g;
        if !step.iter().all(|v| v.is_finite()) {
            return OrientationUpdate::Singular;
        }
        if step.norm() > MAX_ORIENTATION_STEP_RAD {
            return OrientationUpdate::TooLarge(step.norm());
        }
        self.offset = UnitQuaternion::from_scaled_axis(step) * self.offset;
        self.covariance_rad2 = posterior;
        OrientationUpdate::Applied(step)
    }
}

impl OrientationFilter {
    /// The correction with the landmarks of a position correction
    /// (`fixes`, the robot at `position_m`): their residual covariance is
    /// each offset's covariance plus `map_covariance_m2`, the map's joint
    /// covariance of the landmarks (3m x 3m). When applied, the fixes'
    /// offsets and their covariances are turned with the offset, ready for
    /// the position's correction.
    pub fn correct_with(
        &mut self,
        fixes: &mut [LandmarkFix],
        map_covariance_m2: &DMatrix<f64>,
        position_m: &Vector3<f64>,
    ) -> OrientationUpdate {
        let directions: Vec<DirectionFix> = fixes
            .iter()
            .map(|f| DirectionFix {
                landmark_from_robot_m: f.landmark_world_m - position_m,
                offset_world_m: f.offset_world_m,
            })
            .collect();
        let mut noise = map_covariance_m2.clone();
        for (k, fix) in fixes.iter().enumerate() {
            let mut block = noise.fixed_view_mut::<3, 3>(3 * k, 3 * k);
            block += fix.offset_covariance_m2;
        }
        let update = self.correct(&directions, &noise);
        if let OrientationUpdate::Applied(step) = update {
            let turn = *UnitQuaternion::from_scaled_axis(step)
                .to_rotation_matrix()
                .matrix();
            for fix in fixes.iter_mut() {
                fix.offset_world_m = turn * fix.offset_world_m;
                fix.offset_covariance_m2 = turn * fix.offset_covariance_m2 * turn.transpose();
            }
        }
        update
    }
}

/// `J = -[v]×`: turning by a small `θ` moves `v` by `θ × v = -[v]× θ`,
/// so the residual `r = z - v` that a turn `θ` explains is `J θ`.
fn direction_jacobian(v: &Vector3<f64>) -> Matrix3<f64> {
    -v.cross_matrix()
}

/// The information `H` (3 x 3) and vector `g` that the fixes carry about
/// the rotation `θ` with the position error marginalised out, from the
/// linearised `r = [I; …] δx + J θ + n`, `Cov(n) = N`. None when `N` is not
/// positive definite or the landmarks do not pin a position.
fn marginal_information(
    fixes: &[DirectionFix],
    noise_m2: &DMatrix<f64>,
) -> Option<(Matrix3<f64>, Vector3<f64>)> {
    let m = fixes.len();
    if noise_m2.nrows() != 3 * m || noise_m2.ncols() != 3 * m {
        return None;
    }
    // Jacobian [I  J_i] per landmark, and the residual.
    let mut jacobian = DMatrix::zeros(3 * m, 6);
    let mut residual = nalgebra::DVector::zeros(3 * m);
    for (k, fix) in fixes.iter().enumerate() {
        jacobian
            .fixed_view_mut::<3, 3>(3 * k, 0)
            .copy_from(&Matrix3::identity());
        jacobian
            .fixed_view_mut::<3, 3>(3 * k, 3)
            .copy_from(&direction_jacobian(&fix.offset_world_m));
        residual
            .fixed_rows_mut::<3>(3 * k)
            .copy_from(&(fix.landmark_from_robot_m - fix.offset_world_m));
    }
    let noise = 0.5 * (noise_m2 + noise_m2.transpose());
    let cholesky = noise.cholesky()?;
    let weighted_jacobian = cholesky.solve(&jacobian);
    let weighted_residual = cholesky.solve(&residual);
    let full = jacobian.transpose() * &weighted_jacobian;
    let vector = jacobian.transpose() * &weighted_residual;
    let a: Matrix3<f64> = full.fixed_view::<3, 3>(0, 0).into_owned();
    let b: Matrix3<f64> = full.fixed_view::<3, 3>(0, 3).into_owned();
    let c: Matrix3<f64> = full.fixed_view::<3, 3>(3, 3).into_owned();
    let a_inv = a.try_inverse()?;
    let va = Vector3::new(vector[0], vector[1], vector[2]);
    let vc = Vector3::new(vector[3], vector[4], vector[5]);
    let h = c - b.transpose() * a_inv * b;
    let h = 0.5 * (h + h.transpose());
    let g = vc - b.transpose() * a_inv * va;
    Some((h, g))
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;
    use rand_distr::{Distribution, StandardNormal};

    /// Landmarks around a robot at `robot`, seen turned by `turn`: the
    /// offsets are what a relative stage whose world is turned by
    /// `turn⁻¹` would give.
    fn fixes_seen_turned(
        landmarks: &[Vector3<f64>],
        robot: Vector3<f64>,
        turn: UnitQuaternion<f64>,
    ) -> Vec<DirectionFix> {
        landmarks
            .iter()
            .map(|l| DirectionFix {
                landmark_from_robot_m: l - robot,
                offset_world_m: turn.inverse() * (l - robot),
            })
            .collect()
    }

    fn normal(rng: &mut ChaCha8Rng) -> f64 {
        StandardNormal.sample(rng)
    }

    fn scattered(n: usize, seed: u64) -> Vec<Vector3<f64>> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        (0..n)
            .map(|_| {
                Vector3::new(
                    4.0 + 2.0 * normal(&mut rng),
                    3.0 * normal(&mut rng),
                    1.0 + normal(&mut rng),
                )
            })
            .collect()
    }

    #[test]
    fn the_jacobian_matches_finite_differences() {
        // After turning by θ the residual is r(θ) = z - Exp(θ) v, and
        // r(0) = J θ is its linearisation: dr/dθ = -J.
        let v = Vector3::new(1.3, -0.4, 2.2);
        let z = Vector3::new(0.2, 0.7, -0.1);
        let residual = |t: Vector3<f64>| z - UnitQuaternion::from_scaled_axis(t) * v;
        let h = 1e-6;
        for k in 0..3 {
            let mut d = Vector3::zeros();
            d[k] = h;
            let numeric = (residual(d) - residual(-d)) / (2.0 * h);
            let analytic = -direction_jacobian(&v).column(k).into_owned();
            assert!(
                (numeric - analytic).norm() < 1e-8,
                "column {k}: {numeric} vs {analytic}"
            );
        }
    }

    #[test]
    fn an_exact_turn_is_recovered_in_a_few_corrections() {
        let landmarks = scattered(20, 1);
        let robot = Vector3::new(0.5, -0.2, 1.0);
        let turn = UnitQuaternion::from_euler_angles(0.004, -0.006, 0.01);
        let mut filter = OrientationFilter::new(1.0);
        filter.predict(0);
        filter.predict(1_000_000_000);
        let noise = DMatrix::identity(60, 60) * 1e-6;
        // A second between frames: each prior is loose again, so each
        // correction is a Gauss-Newton step on the exact data.
        for frame in 2..5 {
            let seen = fixes_seen_turned(&landmarks, robot, turn);
            let fixes: Vec<DirectionFix> = seen
                .iter()
                .map(|f| DirectionFix {
                    offset_world_m: filter.offset() * f.offset_world_m,
                    ..*f
                })
                .collect();
            assert!(matches!(
                filter.correct(&fixes, &noise),
                OrientationUpdate::Applied(_)
            ));
            filter.predict(frame * 1_000_000_000);
        }
        let error = (filter.offset() * turn.inverse()).scaled_axis().norm();
        assert!(error < 1e-6, "left {error} rad");
    }

    #[test]
    fn a_shift_of_the_whole_map_or_the_robot_does_not_turn_it() {
        let landmarks = scattered(15, 2);
        let robot = Vector3::new(0.0, 0.0, 1.0);
        let mut filter = OrientationFilter::new(1.0);
        filter.predict(0);
        filter.predict(1_000_000_000);
        let shift = Vector3::new(0.3, -0.2, 0.1);
        let fixes: Vec<DirectionFix> =
            fixes_seen_turned(&landmarks, robot, UnitQuaternion::identity())
                .into_iter()
                .map(|f| DirectionFix {
                    landmark_from_robot_m: f.landmark_from_robot_m + shift,
                    ..f
                })
                .collect();
        match filter.correct(&fixes, &(DMatrix::identity(45, 45) * 1e-4)) {
            OrientationUpdate::Applied(step) => assert!(step.norm() < 1e-12, "{step}"),
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn the_estimate_is_as_uncertain_as_it_says() {
        // Many noisy corrections of a fixed turn, each from a fresh filter:
        // the error's NEES over 3 dof averages 3.
        let landmarks = scattered(25, 3);
        let robot = Vector3::new(0.2, 0.1, 0.9);
        let turn = UnitQuaternion::from_euler_angles(0.002, 0.001, -0.003);
        let sigma = 0.02;
        let mut rng = ChaCha8Rng::seed_from_u64(4);
        let runs = 400;
        let mut nees = 0.0;
        for _ in 0..runs {
            let mut filter = OrientationFilter::new(0.01);
            filter.predict(0);
            filter.predict(1_000_000_000);
            let fixes: Vec<DirectionFix> = fixes_seen_turned(&landmarks, robot, turn)
                .into_iter()
                .map(|f| DirectionFix {
                    offset_world_m: f.offset_world_m
                        + Vector3::from_fn(|_, _| sigma * normal(&mut rng)),
                    ..f
                })
                .collect();
            let noise = DMatrix::identity(75, 75) * sigma * sigma;
            assert!(matches!(
                filter.correct(&fixes, &noise),
                OrientationUpdate::Applied(_)
            ));
            // The estimate's error against the true turn.
            let error = (filter.offset() * turn.inverse()).scaled_axis();
            nees += error.dot(&(filter.covariance_rad2().try_inverse().unwrap() * error));
        }
        let mean = nees / runs as f64;
        // The prior (σ 0.01 rad around no turn) is consistent with a turn
        // of a few mrad; the mean NEES of 3 dof is 3 within sampling.
        assert!((2.4..3.6).contains(&mean), "mean NEES {mean}");
    }

    #[test]
    fn too_few_or_degenerate_landmarks_leave_it_alone() {
        let mut filter = OrientationFilter::new(1.0);
        filter.predict(0);
        filter.predict(1_000_000_000);
        let few = fixes_seen_turned(
            &scattered(5, 5),
            Vector3::zeros(),
            UnitQuaternion::identity(),
        );
        assert_eq!(
            filter.correct(&few, &DMatrix::identity(15, 15)),
            OrientationUpdate::TooFewLandmarks
        );
        // A noise covariance that is not positive definite.
        let fixes = fixes_seen_turned(
            &scattered(12, 7),
            Vector3::zeros(),
            UnitQuaternion::identity(),
        );
        let mut noisy = DMatrix::identity(36, 36) * 1e-4;
        noisy[(0, 0)] = -1.0;
        assert_eq!(filter.correct(&fixes, &noisy), OrientationUpdate::Singular);
        let offset = filter.offset();
        assert_eq!(offset, UnitQuaternion::identity());
        // A big turn is refused and nothing changes.
        let turned = fixes_seen_turned(
            &scattered(20, 6),
            Vector3::zeros(),
            UnitQuaternion::from_euler_angles(0.0, 0.0, 0.3),
        );
        let before = filter.covariance_rad2();
        assert!(matches!(
            filter.correct(&turned, &(DMatrix::identity(60, 60) * 1e-6)),
            OrientationUpdate::TooLarge(_)
        ));
        assert_eq!(filter.covariance_rad2(), before);
        assert_eq!(filter.offset(), UnitQuaternion::identity());
    }

    #[test]
    fn the_random_walk_grows_with_time_not_with_frames() {
        let mut a = OrientationFilter::new(0.01);
        for k in 0..=20 {
            a.predict(k * 50_000_000);
        }
        let mut b = OrientationFilter::new(0.01);
        b.predict(0);
        b.predict(1_000_000_000);
        // Going back in time adds nothing.
        b.predict(500_000_000);
        let expected = 1e-4 + START_VARIANCE_RAD2;
        assert!((a.covariance_rad2()[(0, 0)] - expected).abs() < 1e-15);
        assert!((b.covariance_rad2()[(2, 2)] - expected).abs() < 1e-15);
    }
}
