//! The robot position Kalman filter of the absolute stage (paper eq. 60-71).
//!
//! State: the robot position `x` in the world frame and the map's scale
//! over the relative stage's (below), covariance `P`.
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
//!
//! The body-frame estimates `y_i` repeat too: they are the relative
//! stage's sliding-window estimates, the same between two keyframes and
//! mostly the same from one keyframe to the next. The gain still takes
//! each frame's offset error `u_i = R ν_i` as new (counting each window
//! estimate once in the gain made the corrections too timid: less
//! accurate on the development sequences), but the covariance the filter
//! publishes counts the repetition: beside the gain's `P` it keeps
//! `P_pub`, propagated with the same gain in Joseph form, and the
//! cross-covariance `D_i = Cov(e_x, u_i)` of the position error with each
//! landmark's last offset error. A window that replaced the share `s` of
//! the keyframes an estimate rests on ([`LandmarkFix::offset_new_share`])
//! keeps `1 - s` of its error: `Cov(e_x, u_i') = (1 - s) D_i` (exact for
//! an estimate that is the mean of its keyframes' independent errors; the
//! world-frame error is taken to repeat, as it does while the robot's
//! orientation changes little between keyframes). With every share 1,
//! `P_pub = P`.
//!
//! The relative stage's lengths need not be the map's. A monocular window
//! fixes its scale from the IMU, and it wanders by a percent or so from
//! one stretch to the next while the map holds the average of all the
//! windows that built it; the offsets of one frame then differ from the
//! map by a common factor that no amount of landmarks averages out. The
//! state therefore carries, beside the position, `σ`: the map's lengths
//! over the window's, less one, `L_i = x + (1 + σ) R y_i`, and the
//! increment predicts `x <- x + (1 + σ) Δ`. `σ` starts at 0 with no
//! variance (the map is made of the windows' lengths) and wanders by the
//! variance [`PositionFilter::predict_scale`] lets in; with none it stays
//! at 0 and the filter is the position-only one above.

use std::collections::HashMap;

use nalgebra::{DMatrix, DVector, Matrix3, Matrix3x4, Matrix4, Matrix4x3, Vector3, Vector4};

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
    /// The share of the window keyframes `y_i` rests on that are new
    /// since the landmark's last correction: 1 for an estimate
    /// independent of the last one, 0 for the same estimate again. Only
    /// the published covariance uses it (module docs); values outside
    /// [0, 1] count as 1.
    pub offset_new_share: f64,
}

/// What one correction did.
#[derive(Clone, Debug)]
pub struct CorrectionReport {
    /// Landmarks used in the correction.
    pub landmarks: usize,
    /// Normalised innovation squared `r^T S^-1 r` (chi-square with
    /// `3 * landmarks` degrees of freedom when the filter is consistent).
    pub nis: f64,
    /// The gain `K` (4 x 3 landmarks, in the order of the fixes; rows:
    /// position, then scale).
    pub gain: DMatrix<f64>,
    /// `A = I - K H` (4 x 4): how the map sensitivities moved
    /// (`G_k <- A G_k`, then `G_v += K_v`).
    pub keep: Matrix4<f64>,
}

impl Default for CorrectionReport {
    fn default() -> Self {
        Self {
            landmarks: 0,
            nis: 0.0,
            gain: DMatrix::zeros(STATE, 0),
            keep: Matrix4::identity(),
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

/// Rows of the filter's state: the position, then the scale.
pub const STATE: usize = 4;

/// The robot position filter (eq. 60-71), with the map-over-window scale.
#[derive(Clone, Debug)]
pub struct PositionFilter {
    /// `[x; σ]`: position in the world frame (m) and the scale of the map
    /// over the relative stage's window (module docs).
    state: Vector4<f64>,
    covariance: Matrix4<f64>,
    /// `G_k`: sensitivity of the state error to landmark k's map error.
    map_sensitivity: HashMap<u32, Matrix4x3<f64>>,
    /// The covariance published, the body-frame estimates' repetition
    /// counted (module docs).
    published: Matrix4<f64>,
    /// `D_k = Cov(e, u_k)`: the state error's cross-covariance with
    /// landmark k's last offset error.
    offset_cross: HashMap<u32, Matrix4x3<f64>>,
}

/// Sensitivities below this (Frobenius norm) are dropped: their landmark's
/// map error no longer moves the position error measurably.
const SENSITIVITY_FLOOR: f64 = 1e-9;

fn position_block(m: &Matrix4<f64>) -> Matrix3<f64> {
    m.fixed_view::<3, 3>(0, 0).into_owned()
}

/// `H_k = [I | o_k]`: a fix's measurement Jacobian.
fn jacobian(offset_world_m: &Vector3<f64>) -> Matrix3x4<f64> {
    let mut h = Matrix3x4::zeros();
    h.fixed_view_mut::<3, 3>(0, 0).fill_with_identity();
    h.set_column(3, offset_world_m);
    h
}

impl PositionFilter {
    /// A filter at `position_world_m` (m) with covariance `covariance_m2`
    /// (m^2), no map sensitivity yet, the scale exactly the window's
    /// (`σ = 0` with no variance: it stays so unless
    /// [`Self::predict_scale`] lets it wander).
    pub fn new(position_world_m: Vector3<f64>, covariance_m2: Matrix3<f64>) -> Self {
        let mut covariance = Matrix4::zeros();
        covariance
            .fixed_view_mut::<3, 3>(0, 0)
            .copy_from(&covariance_m2);
        Self {
            state: position_world_m.push(0.0),
            covariance,
            map_sensitivity: HashMap::new(),
            published: covariance,
            offset_cross: HashMap::new(),
        }
    }

    /// Estimated body position in the world (map) frame, m.
    pub fn position_world_m(&self) -> Vector3<f64> {
        self.state.fixed_rows::<3>(0).into_owned()
    }

    /// `σ`: the map's lengths over the relative stage's window's, less one.
    pub fn scale(&self) -> f64 {
        self.state[3]
    }

    /// The variance of [`Self::scale`] the gain works with.
    pub fn scale_variance(&self) -> f64 {
        self.covariance[(3, 3)]
    }

    /// Covariance of that position the gain works with (`P`), m^2.
    pub fn covariance_m2(&self) -> Matrix3<f64> {
        position_block(&self.covariance)
    }

    /// Covariance of that position to publish (`P_pub`, module docs):
    /// `P` with the repetition of the body-frame estimates counted, m^2.
    pub fn published_covariance_m2(&self) -> Matrix3<f64> {
        position_block(&self.published)
    }

    /// `G_k` of every landmark whose map error the state error depends on
    /// (rows: position, then scale).
    pub fn map_sensitivity(&self) -> &HashMap<u32, Matrix4x3<f64>> {
        &self.map_sensitivity
    }

    /// Prediction (eq. 60-62): `x <- x + (1 + σ) Δ`, `P <- F P F^T + Q`
    /// with `F = [I Δ; 0 1]` (and the same for `P_pub`, the map
    /// sensitivities and the offset cross-covariances: the increment's
    /// own error is new). With the scale held (no variance) this is the
    /// paper's `x <- x + Δ`, `P <- P + Q`.
    pub fn predict(&mut self, delta_world_m: &Vector3<f64>, q_m2: &Matrix3<f64>) {
        let scale = 1.0 + self.state[3];
        let mut step = self.state.fixed_rows_mut::<3>(0);
        step += delta_world_m * scale;
        let mut f = Matrix4::identity();
        f.fixed_view_mut::<3, 1>(0, 3).copy_from(delta_world_m);
        let mut q = Matrix4::zeros();
        q.fixed_view_mut::<3, 3>(0, 0).copy_from(q_m2);
        self.covariance = f * self.covariance * f.transpose() + q;
        self.published = f * self.published * f.transpose() + q;
        if delta_world_m.iter().any(|v| *v != 0.0) {
            for g in self.map_sensitivity.values_mut() {
                *g = f * *g;
            }
            for d in self.offset_cross.values_mut() {
                *d = f * *d;
            }
        }
    }

    /// The scale's random walk: `σ`'s variance grows by `variance`.
    pub fn predict_scale(&mut self, variance: f64) {
        if variance.is_finite() && variance > 0.0 {
            self.covariance[(3, 3)] += variance;
            self.published[(3, 3)] += variance;
        }
    }

    /// `r_k = L_k - x - (1 + σ) o_k`.
    fn residual(&self, fix: &LandmarkFix) -> Vector3<f64> {
        fix.landmark_world_m - self.position_world_m() - fix.offset_world_m * (1.0 + self.state[3])
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
            && cross_covariance_m2.map_or(true, |c| cross_rows_fit(c) && c.ncols() == dim);
        fixes
            .iter()
            .enumerate()
            .map(|(k, fix)| {
                if !fits {
                    return f64::NAN;
                }
                let r = self.residual(fix);
                let h = jacobian(&fix.offset_world_m);
                let mut s: Matrix3<f64> = map_covariance_m2
                    .fixed_view::<3, 3>(3 * k, 3 * k)
                    .into_owned()
                    + fix.offset_covariance_m2
                    + h * self.covariance * h.transpose();
                if let Some(cross) = cross_covariance_m2 {
                    let hc = h * cross_block(cross, k);
                    s -= hc + hc.transpose();
                }
                let s = 0.5 * (s + s.transpose());
                s.cholesky().map_or(f64::NAN, |ch| r.dot(&ch.solve(&r)))
            })
            .collect()
    }

    /// Correction (eq. 63-71) with the visible landmarks `fixes`, their
    /// joint map covariance `map_covariance_m2` (3m x 3m, `Σ_L` over the
    /// fixes in order) and, optionally, the cross-covariance
    /// `Cov(e, ε_V)` (4 x 3m, or 3 x 3m for the position alone) of the
    /// state error with their map errors. The measurement `z_k = L_k =
    /// x + (1 + σ) o_k + w_k` is linear in the position and linearised in
    /// the scale, `H_k = [I | o_k]`. Correlated measurement noise is
    /// handled by the textbook gain `K = (P H^T - C_xw) S^-1`, `S = H P
    /// H^T + Cov(w) - H C_xw - C_xw^T H^T`, `P <- P - K S K^T`. The
    /// published covariance follows with the same gain: `P_pub <- A P_pub
    /// A^T + K W K^T + A C K^T + K C^T A^T`, `A = I - K H`, `W = Cov(w)`,
    /// `C = Cov(e, w)`: the given `C_xw` less each repeated offset
    /// error's `(1 - s_i) D_i`.
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
        if map_covariance_m2.nrows() != dim || map_covariance_m2.ncols() != dim {
            return Err(CorrectionError::Shape {
                rows: map_covariance_m2.nrows(),
                cols: map_covariance_m2.ncols(),
                expected: dim,
            });
        }
        let cross = match cross_covariance_m2 {
            Some(c) if !cross_rows_fit(c) || c.ncols() != dim => {
                return Err(CorrectionError::Shape {
                    rows: c.nrows(),
                    cols: c.ncols(),
                    expected: dim,
                })
            }
            Some(c) => state_rows(c),
            None => DMatrix::zeros(STATE, dim),
        };
        let jacobians: Vec<Matrix3x4<f64>> =
            fixes.iter().map(|f| jacobian(&f.offset_world_m)).collect();
        // Innovation r and its covariance S.
        let mut residual = DVector::zeros(dim);
        let mut noise = map_covariance_m2.clone();
        for (k, fix) in fixes.iter().enumerate() {
            residual
                .fixed_rows_mut::<3>(3 * k)
                .copy_from(&self.residual(fix));
            let mut block = noise.fixed_view_mut::<3, 3>(3 * k, 3 * k);
            block += fix.offset_covariance_m2;
        }
        let p = self.covariance;
        // P H^T - C (4 x 3m).
        let mut gain_numerator = -&cross;
        for (k, h) in jacobians.iter().enumerate() {
            let mut block = gain_numerator.fixed_view_mut::<4, 3>(0, 3 * k);
            block += p * h.transpose();
        }
        // S = H P H^T + Cov(w) - H C - C^T H^T.
        let mut s = noise;
        let blocks: Vec<Matrix4x3<f64>> = (0..m).map(|k| cross_block(&cross, k)).collect();
        for (a, ha) in jacobians.iter().enumerate() {
            for (b, hb) in jacobians.iter().enumerate() {
                let mut block = s.fixed_view_mut::<3, 3>(3 * a, 3 * b);
                block += ha * p * hb.transpose();
                // (H C)_ab = H_a C_b; (C^T H^T)_ab = (H_b C_a)^T.
                block -= ha * blocks[b];
                block -= (hb * blocks[a]).transpose();
            }
        }
        let s = 0.5 * (&s + s.transpose());
        let cholesky = s.cholesky().ok_or(CorrectionError::SingularInnovation)?;
        // K = (P H^T - C) S^-1  <=>  S K^T = (P H^T - C)^T.
        let gain = cholesky.solve(&gain_numerator.transpose()).transpose();
        let nis = residual.dot(&cholesky.solve(&residual));
        let mut keep = Matrix4::identity();
        for (k, h) in jacobians.iter().enumerate() {
            keep -= gain.fixed_view::<4, 3>(0, 3 * k) * h;
        }
        self.follow_published(&keep, &gain, fixes, map_covariance_m2, &cross);
        let update = &gain * &residual;
        self.state += Vector4::from_column_slice(update.as_slice());
        // P <- P - K S K^T = P - K (P H^T - C)^T.
        let reduction = &gain * gain_numerator.transpose();
        self.covariance -= Matrix4::from_fn(|r, c| reduction[(r, c)]);
        self.covariance = 0.5 * (self.covariance + self.covariance.transpose());
        // e <- A e + K ε_V - K R ν: the sensitivities.
        for g in self.map_sensitivity.values_mut() {
            *g = keep * *g;
        }
        for (k, fix) in fixes.iter().enumerate() {
            let block: Matrix4x3<f64> = gain.fixed_view::<4, 3>(0, 3 * k).into_owned();
            *self
                .map_sensitivity
                .entry(fix.landmark)
                .or_insert_with(Matrix4x3::zeros) += block;
        }
        self.map_sensitivity
            .retain(|_, g| g.norm() > SENSITIVITY_FLOOR);
        Ok(CorrectionReport {
            landmarks: m,
            nis,
            gain,
            keep,
        })
    }

    /// `P_pub` and the offset cross-covariances `D` after a correction
    /// with gain `gain` (`keep = A = I - K H`; `cross` is `Cov(e, ε_V)`,
    /// 4 x 3m; the rest as for [`Self::correct`]).
    fn follow_published(
        &mut self,
        keep: &Matrix4<f64>,
        gain: &DMatrix<f64>,
        fixes: &[LandmarkFix],
        map_covariance_m2: &DMatrix<f64>,
        cross: &DMatrix<f64>,
    ) {
        let kept_share = |fix: &LandmarkFix| {
            if (0.0..=1.0).contains(&fix.offset_new_share) {
                1.0 - fix.offset_new_share
            } else {
                0.0
            }
        };
        // W = Σ_L + blockdiag(R Σ_y R^T); C = C_xε - (1 - s) D.
        let mut noise = map_covariance_m2.clone();
        let mut cross = cross.clone();
        for (k, fix) in fixes.iter().enumerate() {
            let mut block = noise.fixed_view_mut::<3, 3>(3 * k, 3 * k);
            block += fix.offset_covariance_m2;
            if let Some(d) = self.offset_cross.get(&fix.landmark) {
                let mut block = cross.fixed_view_mut::<4, 3>(0, 3 * k);
                block -= d * kept_share(fix);
            }
        }
        let knk = gain * noise * gain.transpose();
        let ck = &cross * gain.transpose();
        let ack = keep * Matrix4::from_fn(|r, c| ck[(r, c)]);
        let p = keep * self.published * keep.transpose()
            + Matrix4::from_fn(|r, c| knk[(r, c)])
            + ack
            + ack.transpose();
        self.published = 0.5 * (p + p.transpose());
        // Cov(e', u_m) = A D_m for the landmarks not in this correction;
        // A (1 - s_k) D_k - K_k Σ_uk for those in it.
        for fix in fixes {
            if let Some(d) = self.offset_cross.get_mut(&fix.landmark) {
                *d *= kept_share(fix);
            }
        }
        for d in self.offset_cross.values_mut() {
            *d = keep * *d;
        }
        for (k, fix) in fixes.iter().enumerate() {
            let k_block: Matrix4x3<f64> = gain.fixed_view::<4, 3>(0, 3 * k).into_owned();
            *self
                .offset_cross
                .entry(fix.landmark)
                .or_insert_with(Matrix4x3::zeros) -= k_block * fix.offset_covariance_m2;
        }
        self.offset_cross
            .retain(|_, d| d.norm() > SENSITIVITY_FLOOR);
    }
}

/// A cross-covariance has a row per state, or 3 for the position alone.
fn cross_rows_fit(cross: &DMatrix<f64>) -> bool {
    cross.nrows() == STATE || cross.nrows() == 3
}

/// `cross` with a row per state (a missing scale row is zero).
fn state_rows(cross: &DMatrix<f64>) -> DMatrix<f64> {
    if cross.nrows() == STATE {
        cross.clone()
    } else {
        let mut full = DMatrix::zeros(STATE, cross.ncols());
        full.rows_mut(0, cross.nrows()).copy_from(cross);
        full
    }
}

/// Block `k` (the state's rows, a fix's three columns) of a cross-covariance.
fn cross_block(cross: &DMatrix<f64>, k: usize) -> Matrix4x3<f64> {
    let mut block = Matrix4x3::zeros();
    let rows = cross.nrows().min(STATE);
    block
        .rows_mut(0, rows)
        .copy_from(&cross.view((0, 3 * k), (rows, 3)));
    block
}

#[cfg(test)]
mod tests;
