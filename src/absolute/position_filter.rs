//! The robot position Kalman filter of the absolute stage (paper eq. 60-71).
//!
//! State: the robot position `x` in the world frame, covariance `P`.
//! Prediction (eq. 60-62): `x <- x + Δ`, `P <- P + Q` with the relative
//! stage's incremental translation `Δ` and its covariance `Q`.
//! Correction (eq. 63-71): each visible landmark `i` with map position
//! `L_i` and body-frame position `y_i` gives a position measurement
//! `z_i = L_i - R y_i = x + ε_i - R ν_i`, where `ε_i` is the map's error in
//! `L_i` and `ν_i` the relative stage's error in `y_i`. Stacked over the
//! visible landmarks, `z = H x + w` with `H` stacked identities and
//! `Cov(w) = blockdiag(R Σ_yi R^T) + Σ_L`, the paper's `Q + M Σ_L M^T`,
//! handled jointly (the map errors of co-visible landmarks are correlated).
//!
//! The map error `ε` does not change from frame to frame: a landmark seen
//! again brings the same error again. A filter that ignores this treats
//! every frame's `ε` as new information and becomes overconfident. This
//! filter therefore also keeps (Schmidt's "consider" bookkeeping) the
//! sensitivity `G_k` of its own error to each used landmark's map error,
//! `e_x = a + Σ_k G_k ε_k`, from which the stage computes the
//! cross-covariance `Cov(e_x, ε_V) = Σ_k G_k Σ_L(k, V)` and passes it to
//! [`PositionFilter::correct`]. With the cross-covariance left out the
//! update is the paper's.

use std::collections::HashMap;

use nalgebra::{DMatrix, DVector, Matrix3, Vector3};

/// One visible landmark as a position measurement of the robot.
#[derive(Clone, Copy, Debug)]
pub struct LandmarkFix {
    /// Map id of the landmark (key of the consider bookkeeping).
    pub landmark: u32,
    /// The map's estimate `L_i`, world frame, m.
    pub landmark_world_m: Vector3<f64>,
    /// `R y_i`: the body-frame landmark rotated into the world frame, m.
    pub offset_world_m: Vector3<f64>,
    /// `R Σ_yi R^T`, m^2.
    pub offset_covariance_m2: Matrix3<f64>,
}

/// What one correction did.
#[derive(Clone, Debug)]
pub struct CorrectionReport {
    /// Landmarks used in the correction.
    pub landmarks: usize,
    /// Normalised innovation squared `r^T S^-1 r` (chi-square with
    /// `3 * landmarks` degrees of freedom when the filter is consistent).
    pub nis: f64,
    /// The gain `K` (3 x 3 landmarks, in the order of the fixes): how the
    /// map sensitivities moved (`G_k <- (I - Σ K_v) G_k`, `G_v += K_v`).
    pub gain: DMatrix<f64>,
}

impl Default for CorrectionReport {
    fn default() -> Self {
        Self {
            landmarks: 0,
            nis: 0.0,
            gain: DMatrix::zeros(3, 0),
        }
    }
}

/// Why a correction was not applied.
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
pub enum CorrectionError {
    #[error("innovation covariance is not positive definite")]
    /// The innovation covariance `S` is not positive definite.
    SingularInnovation,
    #[error("a covariance given to the correction is {rows}x{cols}; it needs {expected} columns (3 per landmark)")]
    /// A covariance matrix given has the wrong shape.
    Shape {
        /// Its rows.
        rows: usize,
        /// Its columns.
        cols: usize,
        /// Columns it needs (3 per landmark).
        expected: usize,
    },
}

/// The robot position filter (eq. 60-71).
#[derive(Clone, Debug)]
pub struct PositionFilter {
    position_world_m: Vector3<f64>,
    covariance_m2: Matrix3<f64>,
    /// `G_k`: sensitivity of the position error to landmark k's map error.
    map_sensitivity: HashMap<u32, Matrix3<f64>>,
}

/// Sensitivities below this (Frobenius norm) are dropped: their landmark's
/// map error no longer moves the position error measurably.
const SENSITIVITY_FLOOR: f64 = 1e-9;

impl PositionFilter {
    /// A filter at `position_world_m` (m) with covariance `covariance_m2` (m^2), no map sensitivity
    /// yet.
    pub fn new(position_world_m: Vector3<f64>, covariance_m2: Matrix3<f64>) -> Self {
        Self {
            position_world_m,
            covariance_m2,
            map_sensitivity: HashMap::new(),
        }
    }

    /// Estimated body position in the world (map) frame, m.
    pub fn position_world_m(&self) -> Vector3<f64> {
        self.position_world_m
    }

    /// Covariance of that position, m^2.
    pub fn covariance_m2(&self) -> Matrix3<f64> {
        self.covariance_m2
    }

    /// `G_k` of every landmark whose map error the position error depends on.
    pub fn map_sensitivity(&self) -> &HashMap<u32, Matrix3<f64>> {
        &self.map_sensitivity
    }

    /// Prediction (eq. 60-62): `x <- x + Δ`, `P <- P + Q`. The map
    /// sensitivities do not change (the increment's error is new).
    pub fn predict(&mut self, delta_world_m: &Vector3<f64>, q_m2: &Matrix3<f64>) {
        self.position_world_m += delta_world_m;
        self.covariance_m2 += q_m2;
    }

    /// Each fix's own normalised innovation squared, `r_k^T S_kk^-1 r_k`
    /// with `S_kk` its diagonal block of the correction's `S` (arguments
    /// as for [`Self::correct`]); chi-square with 3 dof for a landmark
    /// the map, the relative stage and the filter agree on. NaN where the
    /// block is not positive definite or the shapes do not fit.
    pub fn landmark_nis(
        &self,
        fixes: &[LandmarkFix],
        map_covariance_m2: &DMatrix<f64>,
        cross_covariance_m2: Option<&DMatrix<f64>>,
    ) -> Vec<f64> {
        let dim = 3 * fixes.len();
        let fits = map_covariance_m2.nrows() == dim
            && map_covariance_m2.ncols() == dim
            && cross_covariance_m2.map_or(true, |c| c.nrows() == 3 && c.ncols() == dim);
        fixes
            .iter()
            .enumerate()
            .map(|(k, fix)| {
                if !fits {
                    return f64::NAN;
                }
                let r = fix.landmark_world_m - fix.offset_world_m - self.position_world_m;
                let mut s: Matrix3<f64> = map_covariance_m2
                    .fixed_view::<3, 3>(3 * k, 3 * k)
                    .into_owned()
                    + fix.offset_covariance_m2
                    + self.covariance_m2;
                if let Some(cross) = cross_covariance_m2 {
                    let c: Matrix3<f64> = cross.fixed_view::<3, 3>(0, 3 * k).into_owned();
                    s -= c + c.transpose();
                }
                let s = 0.5 * (s + s.transpose());
                s.cholesky().map_or(f64::NAN, |ch| r.dot(&ch.solve(&r)))
            })
            .collect()
    }

    /// Correction (eq. 63-71) with the visible landmarks `fixes`, their
    /// joint map covariance `map_covariance_m2` (3m x 3m, `Σ_L` over the
    /// fixes in order) and, optionally, the cross-covariance
    /// `Cov(e_x, ε_V)` (3 x 3m) of the position error with their map
    /// errors. Correlated measurement noise is handled by the textbook
    /// gain `K = (P H^T - C_xw) S^-1`, `S = H P H^T + Cov(w) - H C_xw -
    /// C_xw^T H^T`, `P <- P - K S K^T`.
    pub fn correct(
        &mut self,
        fixes: &[LandmarkFix],
        map_covariance_m2: &DMatrix<f64>,
        cross_covariance_m2: Option<&DMatrix<f64>>,
    ) -> Result<CorrectionReport, CorrectionError> {
        let m = fixes.len();
        if m == 0 {
            return Ok(CorrectionReport::default());
        }
        let dim = 3 * m;
        let shape_error = |m: &DMatrix<f64>, rows: usize| {
            (m.nrows() != rows || m.ncols() != dim).then_some(CorrectionError::Shape {
                rows: m.nrows(),
                cols: m.ncols(),
                expected: dim,
            })
        };
        if let Some(e) = shape_error(map_covariance_m2, dim) {
            return Err(e);
        }
        if let Some(e) = cross_covariance_m2.and_then(|c| shape_error(c, 3)) {
            return Err(e);
        }
        // Innovation r = z - H x and its covariance S.
        let mut residual = DVector::zeros(dim);
        let mut noise = map_covariance_m2.clone();
        for (k, fix) in fixes.iter().enumerate() {
            let z = fix.landmark_world_m - fix.offset_world_m;
            residual
                .fixed_rows_mut::<3>(3 * k)
                .copy_from(&(z - self.position_world_m));
            let mut block = noise.fixed_view_mut::<3, 3>(3 * k, 3 * k);
            block += fix.offset_covariance_m2;
        }
        let p = self.covariance_m2;
        // P H^T - C_xw (3 x 3m).
        let mut gain_numerator = DMatrix::zeros(3, dim);
        for k in 0..m {
            gain_numerator
                .fixed_view_mut::<3, 3>(0, 3 * k)
                .copy_from(&p);
        }
        if let Some(cross) = cross_covariance_m2 {
            gain_numerator -= cross;
        }
        // S = H P H^T + Cov(w) - H C_xw - C_xw^T H^T.
        let mut s = noise;
        for a in 0..m {
            for b in 0..m {
                let mut block = s.fixed_view_mut::<3, 3>(3 * a, 3 * b);
                block += p;
                if let Some(cross) = cross_covariance_m2 {
                    let c_b = cross.fixed_view::<3, 3>(0, 3 * b);
                    let c_a = cross.fixed_view::<3, 3>(0, 3 * a);
                    block -= c_b;
                    block -= c_a.transpose();
                }
            }
        }
        let s = 0.5 * (&s + s.transpose());
        let cholesky = s.cholesky().ok_or(CorrectionError::SingularInnovation)?;
        // K = (P H^T - C_xw) S^-1  <=>  S K^T = (P H^T - C_xw)^T.
        let gain = cholesky.solve(&gain_numerator.transpose()).transpose();
        let nis = residual.dot(&cholesky.solve(&residual));
        let update = &gain * &residual;
        self.position_world_m += Vector3::new(update[0], update[1], update[2]);
        // P <- P - K S K^T = P - K (P H^T - C_xw)^T.
        let reduction = &gain * gain_numerator.transpose();
        let reduction = Matrix3::from_fn(|r, c| reduction[(r, c)]);
        self.covariance_m2 -= reduction;
        self.covariance_m2 = 0.5 * (self.covariance_m2 + self.covariance_m2.transpose());
        // e_x <- (I - K H) e_x + K ε_V - K R ν: the sensitivities.
        let mut k_sum = Matrix3::zeros();
        for k in 0..m {
            k_sum += gain.fixed_view::<3, 3>(0, 3 * k);
        }
        let keep = Matrix3::identity() - k_sum;
        for g in self.map_sensitivity.values_mut() {
            *g = keep * *g;
        }
        for (k, fix) in fixes.iter().enumerate() {
            let block: Matrix3<f64> = gain.fixed_view::<3, 3>(0, 3 * k).into_owned();
            *self
                .map_sensitivity
                .entry(fix.landmark)
                .or_insert_with(Matrix3::zeros) += block;
        }
        self.map_sensitivity
            .retain(|_, g| g.norm() > SENSITIVITY_FLOOR);
        Ok(CorrectionReport {
            landmarks: m,
            nis,
            gain,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;
    use rand_distr::{Distribution, StandardNormal};

    fn iso(v: f64) -> Matrix3<f64> {
        Matrix3::identity() * v
    }

    fn fix(landmark: u32, l: f64, y: f64, r: f64) -> LandmarkFix {
        LandmarkFix {
            landmark,
            landmark_world_m: Vector3::new(l, 0.0, 0.0),
            offset_world_m: Vector3::new(y, 0.0, 0.0),
            offset_covariance_m2: iso(r),
        }
    }

    #[test]
    fn one_dimensional_case_matches_the_hand_computation() {
        // x0 = 0, P0 = 1; move u = 1 with q = 1: x- = 1, P- = 2. Landmark
        // at L = 5 seen 3 m ahead with r = 1, exact map: z = 2,
        // K = 2 / (2 + 1) = 2/3, x+ = 1 + 2/3 (2 - 1) = 5/3, P+ = 2/3.
        let mut f = PositionFilter::new(Vector3::zeros(), iso(1.0));
        f.predict(&Vector3::new(1.0, 0.0, 0.0), &iso(1.0));
        let report = f
            .correct(&[fix(0, 5.0, 3.0, 1.0)], &DMatrix::zeros(3, 3), None)
            .unwrap();
        assert!((f.position_world_m().x - 5.0 / 3.0).abs() < 1e-14);
        assert!(f.position_world_m().y.abs() < 1e-15);
        assert!((f.covariance_m2()[(0, 0)] - 2.0 / 3.0).abs() < 1e-14);
        // NIS = r^2 / S = 1 / 3 on x; y and z innovations are zero.
        assert!((report.nis - 1.0 / 3.0).abs() < 1e-14);
        // A map variance of 1 adds to the noise: K = 2 / 4, P+ = 1.
        let mut g = PositionFilter::new(Vector3::zeros(), iso(1.0));
        g.predict(&Vector3::new(1.0, 0.0, 0.0), &iso(1.0));
        g.correct(&[fix(0, 5.0, 3.0, 1.0)], &DMatrix::identity(3, 3), None)
            .unwrap();
        assert!((g.position_world_m().x - 1.5).abs() < 1e-14);
        assert!((g.covariance_m2()[(0, 0)] - 1.0).abs() < 1e-14);
    }

    #[test]
    fn each_landmark_nis_matches_the_hand_computation_and_the_joint_one() {
        // x = 1, P = 2; landmark 0 at L = 5 seen 3 m ahead (r = 1), map
        // variance 1: innovation 1 on x, S = 2 + 1 + 1 = 4, NIS 1/4.
        // Landmark 1 at L = 10 seen 2 m ahead: innovation 7, NIS 49/4.
        let mut f = PositionFilter::new(Vector3::zeros(), iso(1.0));
        f.predict(&Vector3::new(1.0, 0.0, 0.0), &iso(1.0));
        let fixes = [fix(0, 5.0, 3.0, 1.0), fix(1, 10.0, 2.0, 1.0)];
        let map = DMatrix::identity(6, 6);
        let nis = f.landmark_nis(&fixes, &map, None);
        assert!((nis[0] - 0.25).abs() < 1e-14, "{nis:?}");
        assert!((nis[1] - 49.0 / 4.0).abs() < 1e-13, "{nis:?}");
        // With independent landmarks and an exact filter position (P = 0)
        // the joint NIS of the correction is the sum of the two.
        let exact = PositionFilter::new(Vector3::new(1.0, 0.0, 0.0), iso(0.0));
        let each = exact.landmark_nis(&fixes, &map, None);
        let joint = exact.clone().correct(&fixes, &map, None).unwrap().nis;
        assert!(
            (each[0] + each[1] - joint).abs() < 1e-12,
            "{each:?} {joint}"
        );
        // A cross-covariance C between the position and the map error
        // takes C + C^T off S: 4 - 2 * 0.5 = 3 on landmark 0.
        let mut cross = DMatrix::zeros(3, 6);
        cross[(0, 0)] = 0.5;
        let with_cross = f.landmark_nis(&fixes, &map, Some(&cross));
        assert!((with_cross[0] - 1.0 / 3.0).abs() < 1e-14, "{with_cross:?}");
        assert!((with_cross[1] - nis[1]).abs() < 1e-14);
        // Shapes that do not fit give NaN, not a panic.
        let wrong = f.landmark_nis(&fixes, &DMatrix::identity(3, 3), None);
        assert!(wrong.iter().all(|v| v.is_nan()));
    }

    #[test]
    fn correlated_map_errors_are_fused_jointly() {
        // Two landmarks whose map errors are one shared error of variance
        // s (fully correlated) and independent offsets of variance r: the
        // joint update equals one measurement of the mean z with variance
        // r / 2 + s (hand derivation: the mean is sufficient).
        let (r, s, p) = (0.5, 2.0, 3.0);
        let fixes = [fix(0, 4.0, 1.0, r), fix(1, 7.0, 3.0, r)];
        let mut map_cov = DMatrix::zeros(6, 6);
        for a in 0..2 {
            for b in 0..2 {
                for c in 0..3 {
                    map_cov[(3 * a + c, 3 * b + c)] = s;
                }
            }
        }
        let mut joint = PositionFilter::new(Vector3::zeros(), iso(p));
        joint.correct(&fixes, &map_cov, None).unwrap();
        let z_mean = 0.5 * ((4.0 - 1.0) + (7.0 - 3.0));
        let k = p / (p + r / 2.0 + s);
        assert!((joint.position_world_m().x - k * z_mean).abs() < 1e-13);
        assert!((joint.covariance_m2()[(0, 0)] - (1.0 - k) * p).abs() < 1e-13);
        // Treated as independent, the shared error would be counted twice.
        let mut naive = PositionFilter::new(Vector3::zeros(), iso(p));
        let mut independent = DMatrix::zeros(6, 6);
        independent.fill_diagonal(s);
        naive.correct(&fixes, &independent, None).unwrap();
        assert!(naive.covariance_m2()[(0, 0)] < joint.covariance_m2()[(0, 0)] - 0.1);
    }

    fn random_spd(rng: &mut ChaCha8Rng, scale: f64) -> Matrix3<f64> {
        let m = Matrix3::from_fn(|_, _| rng.gen_range(-1.0..1.0));
        (m * m.transpose() + iso(0.3)) * scale
    }

    /// Kalman filter = batch weighted least squares over the whole
    /// trajectory (for the last state) on a linear-Gaussian toy problem:
    /// prior on x0, increments with noise Q_t, per step a few landmark
    /// fixes with a correlated joint noise.
    #[test]
    fn filter_equals_batch_least_squares_on_a_linear_gaussian_problem() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let steps = 12;
        let x0 = Vector3::new(1.0, -2.0, 0.5);
        let p0 = random_spd(&mut rng, 0.5);
        let mut filter = PositionFilter::new(x0, p0);
        // Batch unknowns: x_0 .. x_steps; information matrix and vector.
        let n = 3 * (steps + 1);
        let mut info = DMatrix::<f64>::zeros(n, n);
        let mut info_vec = DVector::<f64>::zeros(n);
        let p0_inv = p0.try_inverse().unwrap();
        info.fixed_view_mut::<3, 3>(0, 0).copy_from(&p0_inv);
        info_vec.fixed_rows_mut::<3>(0).copy_from(&(p0_inv * x0));
        for t in 1..=steps {
            let delta = Vector3::from_fn(|_, _| rng.gen_range(-1.0..1.0));
            let q = random_spd(&mut rng, 0.2);
            filter.predict(&delta, &q);
            // Process term (x_t - x_{t-1} - Δ)^T Q^-1 (...).
            let q_inv = q.try_inverse().unwrap();
            let (a, b) = (3 * (t - 1), 3 * t);
            for (r, c, sign) in [(a, a, 1.0), (b, b, 1.0), (a, b, -1.0), (b, a, -1.0)] {
                let mut block = info.fixed_view_mut::<3, 3>(r, c);
                block += q_inv * sign;
            }
            let mut seg = info_vec.fixed_rows_mut::<3>(a);
            seg -= q_inv * delta;
            let mut seg = info_vec.fixed_rows_mut::<3>(b);
            seg += q_inv * delta;
            // Measurements z_k = x_t + w, joint covariance C.
            let m = rng.gen_range(1..4);
            let fixes: Vec<LandmarkFix> = (0..m)
                .map(|k| LandmarkFix {
                    landmark: k,
                    landmark_world_m: Vector3::from_fn(|_, _| rng.gen_range(-5.0..5.0)),
                    offset_world_m: Vector3::from_fn(|_, _| rng.gen_range(-5.0..5.0)),
                    offset_covariance_m2: random_spd(&mut rng, 0.1),
                })
                .collect();
            let root = DMatrix::from_fn(3 * m as usize, 3 * m as usize, |_, _| {
                rng.gen_range(-0.3..0.3)
            });
            let map_cov = &root * root.transpose();
            filter.correct(&fixes, &map_cov, None).unwrap();
            let mut c = map_cov.clone();
            for (k, f) in fixes.iter().enumerate() {
                let mut block = c.fixed_view_mut::<3, 3>(3 * k, 3 * k);
                block += f.offset_covariance_m2;
            }
            let c_inv = c.try_inverse().unwrap();
            let z = DVector::from_iterator(
                3 * m as usize,
                fixes.iter().flat_map(|f| {
                    (f.landmark_world_m - f.offset_world_m)
                        .iter()
                        .copied()
                        .collect::<Vec<_>>()
                }),
            );
            // H = stacked identities: H^T C^-1 H and H^T C^-1 z.
            let mut hth = Matrix3::zeros();
            let mut htz = Vector3::zeros();
            for a in 0..m as usize {
                for bb in 0..m as usize {
                    hth += c_inv.fixed_view::<3, 3>(3 * a, 3 * bb);
                }
                htz += c_inv.fixed_rows::<3>(3 * a) * &z;
            }
            let mut block = info.fixed_view_mut::<3, 3>(b, b);
            block += hth;
            let mut seg = info_vec.fixed_rows_mut::<3>(b);
            seg += htz;
        }
        let cov = info.clone().try_inverse().unwrap();
        let solution = &cov * &info_vec;
        let last = 3 * steps;
        let x_batch = Vector3::new(solution[last], solution[last + 1], solution[last + 2]);
        let p_batch: Matrix3<f64> = cov.fixed_view::<3, 3>(last, last).into_owned();
        assert!(
            (filter.position_world_m() - x_batch).norm() < 1e-10,
            "{} vs {}",
            filter.position_world_m(),
            x_batch
        );
        assert!((filter.covariance_m2() - p_batch).norm() < 1e-10 * p_batch.norm());
    }

    /// A robot standing still sees the same three landmarks every frame;
    /// their map errors are drawn once per run. Over many runs the final
    /// position error must match the filter's covariance (NEES) when the
    /// consider cross-covariance is used, and not without it.
    fn static_robot_anees(with_cross: bool) -> f64 {
        let runs = 400;
        let steps = 40;
        let mut rng = ChaCha8Rng::seed_from_u64(21);
        let map_root = DMatrix::from_fn(9, 9, |r, c| {
            if r == c {
                0.3
            } else {
                0.1 * ((r * 7 + c * 3) % 5) as f64 / 5.0
            }
        });
        let map_cov = &map_root * map_root.transpose();
        let offset_cov = iso(0.01);
        let landmarks = [
            Vector3::new(3.0, 0.0, 0.0),
            Vector3::new(0.0, 4.0, 1.0),
            Vector3::new(-2.0, 1.0, 2.0),
        ];
        let mut total = 0.0;
        for _ in 0..runs {
            let draw = |rng: &mut ChaCha8Rng, n: usize| {
                DVector::from_fn(n, |_, _| StandardNormal.sample(rng))
            };
            let map_error = &map_root * draw(&mut rng, 9);
            let truth = Vector3::zeros();
            let mut f = PositionFilter::new(
                truth + Vector3::from_fn(|_, _| StandardNormal.sample(&mut rng)),
                Matrix3::identity(),
            );
            for _ in 0..steps {
                f.predict(&Vector3::zeros(), &iso(1e-6));
                let fixes: Vec<LandmarkFix> = landmarks
                    .iter()
                    .enumerate()
                    .map(|(k, l)| {
                        let nu = Vector3::from_fn(|_, _| {
                            0.1 * {
                                let z: f64 = StandardNormal.sample(&mut rng);
                                z
                            }
                        });
                        LandmarkFix {
                            landmark: k as u32,
                            landmark_world_m: l + Vector3::new(
                                map_error[3 * k],
                                map_error[3 * k + 1],
                                map_error[3 * k + 2],
                            ),
                            offset_world_m: (l - truth) + nu,
                            offset_covariance_m2: offset_cov,
                        }
                    })
                    .collect();
                let cross = with_cross.then(|| {
                    let mut c = DMatrix::zeros(3, 9);
                    for (&k, g) in f.map_sensitivity() {
                        for v in 0..3 {
                            let block = g * map_cov
                                .fixed_view::<3, 3>(3 * k as usize, 3 * v)
                                .into_owned();
                            let mut target = c.fixed_view_mut::<3, 3>(0, 3 * v);
                            target += block;
                        }
                    }
                    c
                });
                f.correct(&fixes, &map_cov, cross.as_ref()).unwrap();
            }
            let e = f.position_world_m() - truth;
            total += e.dot(&(f.covariance_m2().try_inverse().unwrap() * e));
        }
        total / runs as f64
    }

    #[test]
    fn consider_terms_keep_repeated_map_errors_consistent() {
        // ANEES of 400 runs, 3 dof: 95% bounds chi2(1200) / 400 by the
        // Wilson-Hilferty approximation, [2.76, 3.25].
        let (low, high) = crate::absolute::nees::anees_bounds_95(3, 400);
        assert!((low - 2.765).abs() < 0.01 && (high - 3.245).abs() < 0.01);
        let consistent = static_robot_anees(true);
        assert!(
            consistent > low && consistent < high,
            "ANEES {consistent} outside [{low}, {high}]"
        );
        let naive = static_robot_anees(false);
        assert!(naive > 3.0 * high, "paper update ANEES {naive}");
    }
}
