//! The normal equations of one Levenberg-Marquardt step, solved with the
//! Schur complement on the landmarks (eq. 35-40).
//!
//! Unknowns: the free keyframes' states (and gravity) `x`, and the
//! landmarks `l_j`. The Hessian is `[[U, W], [W^T, V]]` with `V`
//! block-diagonal (3x3 per landmark) and `W` non-zero only where a
//! keyframe sees a landmark. Eliminating the landmarks gives the reduced
//! system `S = U - sum_j W_j V_j^-1 W_j^T`, built landmark by landmark from
//! the few keyframes each one touches; `S` is small (15 per free keyframe
//! plus 2) and is solved densely by Cholesky, then each landmark's step is
//! `V_j^-1 (b_j - W_j^T dx)`. The full system is never formed (except by
//! the dense reference in the tests).

use std::ops::Range;

use nalgebra::{DMatrix, DVector, Matrix2x3, Matrix3, SMatrix, SVector, Vector2, Vector3};

use super::camera_imu::{Matrix2xCalib, MatrixCalibx3, CALIB_DIM};
use super::reprojection::Matrix2x6;
use crate::relative::types::LandmarkId;

/// Cross block between a body pose `[dphi, dp]` and a landmark's 3 coordinates.
pub type Matrix6x3 = SMatrix<f64, 6, 3>;

/// Smallest diagonal value damping scales (so that a direction no term
/// constrains is still damped).
const DAMPING_FLOOR: f64 = 1e-6;

/// One observation in the problem, with its linearisation.
#[derive(Debug, Clone, Copy)]
pub(crate) struct ObservationRow {
    /// Window position of the keyframe and index of the observation in it.
    pub kf: usize,
    pub obs_index: usize,
    pub camera: u8,
    /// Index into the problem's landmarks.
    pub landmark: usize,
    /// Column of the keyframe's block in the reduced system (None: fixed).
    pub offset: Option<usize>,
    /// False when the landmark did not project at the linearisation point.
    pub valid: bool,
    /// Squared whitened error.
    pub sq_error: f64,
    /// Robust weight `rho'`.
    pub weight: f64,
    /// Whitened residual and Jacobians.
    pub residual: Vector2<f64>,
    pub d_pose: Matrix2x6,
    pub d_point: Matrix2x3<f64>,
    /// `weight * d_pose^T d_point`: the observation's block of `W`.
    pub w_block: Matrix6x3,
    /// d error / d calibration step (whitened; zero when the camera-IMU
    /// calibration is not estimated).
    pub d_calib: Matrix2xCalib,
}

impl ObservationRow {
    pub fn new(kf: usize, obs_index: usize, camera: u8, landmark: usize) -> Self {
        Self {
            kf,
            obs_index,
            camera,
            landmark,
            offset: None,
            valid: false,
            sq_error: 0.0,
            weight: 0.0,
            residual: Vector2::zeros(),
            d_pose: Matrix2x6::zeros(),
            d_point: Matrix2x3::zeros(),
            w_block: Matrix6x3::zeros(),
            d_calib: Matrix2xCalib::zeros(),
        }
    }
}

/// One landmark in the problem.
#[derive(Debug, Clone)]
pub(crate) struct LandmarkBlock {
    pub id: LandmarkId,
    pub position_world_m: Vector3<f64>,
    /// Its observations (rows sorted by landmark).
    pub rows: Range<usize>,
    /// `V_j` and `b_j = -J_l^T W r` (undamped).
    pub v: Matrix3<f64>,
    pub b: Vector3<f64>,
    /// `(V_j + damping)^-1` of the last solve.
    pub v_inv: Matrix3<f64>,
    pub delta: Vector3<f64>,
    pub usable: bool,
    /// The calibration block's part of `W` for this landmark (all its
    /// observations, fixed keyframes' included).
    pub w_calib: MatrixCalibx3,
}

impl LandmarkBlock {
    pub fn new(id: LandmarkId, position_world_m: Vector3<f64>) -> Self {
        Self {
            id,
            position_world_m,
            rows: 0..0,
            v: Matrix3::zeros(),
            b: Vector3::zeros(),
            v_inv: Matrix3::zeros(),
            delta: Vector3::zeros(),
            usable: true,
            w_calib: MatrixCalibx3::zeros(),
        }
    }
}

/// A block of a factor's Jacobian: columns `col..col + len` of the factor
/// go to the reduced system's columns `offset..offset + len` (None: the
/// variable is held fixed and the block is dropped).
#[derive(Debug, Clone, Copy)]
pub(crate) struct Chunk {
    pub col: usize,
    pub len: usize,
    pub offset: Option<usize>,
}

/// The camera/state part of the normal equations and the reduced system.
#[derive(Debug, Clone, Default)]
pub(crate) struct NormalEquations {
    pub dim: usize,
    /// `U` and `b_c = -J_c^T W r`, undamped.
    pub u: DMatrix<f64>,
    pub bc: DVector<f64>,
    /// The reduced system of the last solve (holds its Cholesky factor
    /// after a solve).
    pub s: DMatrix<f64>,
    pub bs: DVector<f64>,
    pub delta: DVector<f64>,
}

impl NormalEquations {
    /// Zeroes the system for `dim` unknowns (reallocates only when `dim`
    /// grows past what the buffers hold).
    pub fn reset(&mut self, dim: usize) {
        if self.dim != dim || self.u.nrows() != dim {
            self.u = DMatrix::zeros(dim, dim);
            self.s = DMatrix::zeros(dim, dim);
            self.bc = DVector::zeros(dim);
            self.bs = DVector::zeros(dim);
            self.delta = DVector::zeros(dim);
            self.dim = dim;
        } else {
            self.u.fill(0.0);
            self.bc.fill(0.0);
        }
    }

    /// Adds a whitened factor `r`, `J` whose column blocks go where
    /// `chunks` say.
    pub fn add_factor<const R: usize, const C: usize>(
        &mut self,
        r: &SVector<f64, R>,
        j: &SMatrix<f64, R, C>,
        chunks: &[Chunk],
    ) {
        let jtj = j.transpose() * j;
        let jtr = j.transpose() * r;
        for a in chunks {
            let Some(oa) = a.offset else { continue };
            for k in 0..a.len {
                self.bc[oa + k] -= jtr[a.col + k];
            }
            for b in chunks {
                let Some(ob) = b.offset else { continue };
                for ka in 0..a.len {
                    for kb in 0..b.len {
                        self.u[(oa + ka, ob + kb)] += jtj[(a.col + ka, b.col + kb)];
                    }
                }
            }
        }
    }
}

/// Adds the observations' pose terms to `U`, `b_c` and forms each
/// landmark's `V_j`, `b_j` and the `W` blocks (rows already linearised).
/// `calib`: the column of the camera-IMU calibration block, when it is
/// estimated.
pub(crate) fn accumulate_observations(
    eq: &mut NormalEquations,
    rows: &mut [ObservationRow],
    landmarks: &mut [LandmarkBlock],
    calib: Option<usize>,
) {
    for lm in landmarks.iter_mut() {
        lm.v = Matrix3::zeros();
        lm.b = Vector3::zeros();
        lm.w_calib = MatrixCalibx3::zeros();
        for row in &mut rows[lm.rows.clone()] {
            if !row.valid || row.weight == 0.0 {
                row.w_block = Matrix6x3::zeros();
                continue;
            }
            let w = row.weight;
            lm.v += row.d_point.transpose() * row.d_point * w;
            lm.b -= row.d_point.transpose() * row.residual * w;
            if let Some(oc) = calib {
                lm.w_calib += row.d_calib.transpose() * row.d_point * w;
                let ucc = row.d_calib.transpose() * row.d_calib * w;
                let mut block = eq.u.fixed_view_mut::<CALIB_DIM, CALIB_DIM>(oc, oc);
                block += ucc;
                let g = row.d_calib.transpose() * row.residual * w;
                let mut bc = eq.bc.fixed_rows_mut::<CALIB_DIM>(oc);
                bc -= g;
                if let Some(o) = row.offset {
                    let upc = row.d_pose.transpose() * row.d_calib * w;
                    let mut block = eq.u.fixed_view_mut::<6, CALIB_DIM>(o, oc);
                    block += upc;
                    let mut mirror = eq.u.fixed_view_mut::<CALIB_DIM, 6>(oc, o);
                    mirror += upc.transpose();
                }
            }
            if let Some(o) = row.offset {
                row.w_block = row.d_pose.transpose() * row.d_point * w;
                let upp = row.d_pose.transpose() * row.d_pose * w;
                let mut block = eq.u.fixed_view_mut::<6, 6>(o, o);
                block += upp;
                let g = row.d_pose.transpose() * row.residual * w;
                let mut bc = eq.bc.fixed_rows_mut::<6>(o);
                bc -= g;
            } else {
                row.w_block = Matrix6x3::zeros();
            }
        }
    }
}

fn damped3(v: &Matrix3<f64>, lambda: f64) -> Matrix3<f64> {
    let mut d = *v;
    for i in 0..3 {
        d[(i, i)] += lambda * v[(i, i)].max(DAMPING_FLOOR);
    }
    d
}

/// Forms the damped reduced system `S`, `b_S` in `eq.s`, `eq.bs`, and
/// each landmark's damped `V^-1`. A landmark whose block cannot be
/// inverted is marked unusable (step zero).
pub(crate) fn reduce(
    eq: &mut NormalEquations,
    rows: &[ObservationRow],
    landmarks: &mut [LandmarkBlock],
    lambda: f64,
    calib: Option<usize>,
) {
    eq.s.copy_from(&eq.u);
    eq.bs.copy_from(&eq.bc);
    for i in 0..eq.dim {
        eq.s[(i, i)] += lambda * eq.u[(i, i)].max(DAMPING_FLOOR);
    }
    for lm in landmarks.iter_mut() {
        let inv = damped3(&lm.v, lambda)
            .cholesky()
            .map(|c| c.inverse())
            .filter(|m| m.iter().all(|v| v.is_finite()));
        let Some(v_inv) = inv else {
            lm.usable = false;
            continue;
        };
        lm.usable = true;
        lm.v_inv = v_inv;
        let lm_rows = &rows[lm.rows.clone()];
        if let Some(oc) = calib {
            let wcv = lm.w_calib * v_inv;
            let mut bs = eq.bs.fixed_rows_mut::<CALIB_DIM>(oc);
            bs -= wcv * lm.b;
            let mut block = eq.s.fixed_view_mut::<CALIB_DIM, CALIB_DIM>(oc, oc);
            block -= wcv * lm.w_calib.transpose();
            for r in lm_rows {
                let Some(o) = r.offset.filter(|_| r.valid) else {
                    continue;
                };
                let m = wcv * r.w_block.transpose();
                let mut block = eq.s.fixed_view_mut::<CALIB_DIM, 6>(oc, o);
                block -= m;
                let mut mirror = eq.s.fixed_view_mut::<6, CALIB_DIM>(o, oc);
                mirror -= m.transpose();
            }
        }
        for (ia, ra) in lm_rows.iter().enumerate() {
            let Some(oa) = ra.offset.filter(|_| ra.valid) else {
                continue;
            };
            let wv = ra.w_block * v_inv;
            let mut bs = eq.bs.fixed_rows_mut::<6>(oa);
            bs -= wv * lm.b;
            // S is symmetric: each pair once, mirrored.
            for rb in &lm_rows[ia..] {
                let Some(ob) = rb.offset.filter(|_| rb.valid) else {
                    continue;
                };
                let m = wv * rb.w_block.transpose();
                let mut block = eq.s.fixed_view_mut::<6, 6>(oa, ob);
                block -= m;
                if oa != ob || !std::ptr::eq(ra, rb) {
                    let mut mirror = eq.s.fixed_view_mut::<6, 6>(ob, oa);
                    mirror -= m.transpose();
                }
            }
        }
    }
}

/// One damped step: reduce, Cholesky, back-substitute. The step is in
/// `eq.delta` (states) and each landmark's `delta`. False when `S` is
/// not positive definite.
pub(crate) fn solve_step(
    eq: &mut NormalEquations,
    rows: &[ObservationRow],
    landmarks: &mut [LandmarkBlock],
    lambda: f64,
    calib: Option<usize>,
) -> bool {
    reduce(eq, rows, landmarks, lambda, calib);
    let s = std::mem::replace(&mut eq.s, DMatrix::zeros(0, 0));
    let Some(chol) = s.cholesky() else {
        eq.s = DMatrix::zeros(eq.dim, eq.dim);
        return false;
    };
    eq.delta.copy_from(&eq.bs);
    chol.solve_mut(&mut eq.delta);
    eq.s = chol.unpack();
    if !eq.delta.iter().all(|v| v.is_finite()) {
        return false;
    }
    for lm in landmarks.iter_mut() {
        if !lm.usable {
            lm.delta = Vector3::zeros();
            continue;
        }
        let mut rhs = lm.b;
        if let Some(oc) = calib {
            rhs -= lm.w_calib.transpose() * eq.delta.fixed_rows::<CALIB_DIM>(oc);
        }
        for r in &rows[lm.rows.clone()] {
            if let Some(o) = r.offset.filter(|_| r.valid) {
                rhs -= r.w_block.transpose() * eq.delta.fixed_rows::<6>(o);
            }
        }
        lm.delta = lm.v_inv * rhs;
    }
    true
}

/// The inverse of the (nearly undamped) reduced system: the marginal
/// covariance of the free states. None when `S` is singular.
pub(crate) fn reduced_inverse(
    eq: &mut NormalEquations,
    rows: &[ObservationRow],
    landmarks: &mut [LandmarkBlock],
    calib: Option<usize>,
) -> Option<DMatrix<f64>> {
    reduce(eq, rows, landmarks, 1e-9, calib);
    let s = std::mem::replace(&mut eq.s, DMatrix::zeros(0, 0));
    let Some(chol) = s.cholesky() else {
        eq.s = DMatrix::zeros(eq.dim, eq.dim);
        return None;
    };
    let inv = chol.inverse();
    eq.s = chol.unpack();
    inv.iter().all(|v| v.is_finite()).then_some(inv)
}

/// Test reference: the full Hessian `[[U, W], [W^T, V]]` (damped like the
/// Schur path) solved densely; the step of states then landmarks.
#[cfg(test)]
pub(crate) fn dense_step(
    eq: &NormalEquations,
    rows: &[ObservationRow],
    landmarks: &[LandmarkBlock],
    lambda: f64,
    calib: Option<usize>,
) -> Option<DVector<f64>> {
    let n = eq.dim + 3 * landmarks.len();
    let mut h = DMatrix::<f64>::zeros(n, n);
    let mut b = DVector::<f64>::zeros(n);
    h.view_mut((0, 0), (eq.dim, eq.dim)).copy_from(&eq.u);
    b.rows_mut(0, eq.dim).copy_from(&eq.bc);
    for (j, lm) in landmarks.iter().enumerate() {
        let c = eq.dim + 3 * j;
        // V and b of the landmark straight from the rows' Jacobians.
        for r in &rows[lm.rows.clone()] {
            if !r.valid {
                continue;
            }
            let w = r.weight;
            let mut v = h.fixed_view_mut::<3, 3>(c, c);
            v += r.d_point.transpose() * r.d_point * w;
            let mut bl = b.fixed_rows_mut::<3>(c);
            bl -= r.d_point.transpose() * r.residual * w;
            if let Some(o) = r.offset {
                let wb = r.d_pose.transpose() * r.d_point * w;
                let mut top = h.fixed_view_mut::<6, 3>(o, c);
                top += wb;
                let mut left = h.fixed_view_mut::<3, 6>(c, o);
                left += wb.transpose();
            }
            if let Some(oc) = calib {
                let wc = r.d_calib.transpose() * r.d_point * w;
                let mut top = h.fixed_view_mut::<CALIB_DIM, 3>(oc, c);
                top += wc;
                let mut left = h.fixed_view_mut::<3, CALIB_DIM>(c, oc);
                left += wc.transpose();
            }
        }
    }
    let diag: Vec<f64> = (0..n).map(|i| h[(i, i)]).collect();
    for (i, d) in diag.into_iter().enumerate() {
        h[(i, i)] += lambda * d.max(DAMPING_FLOOR);
    }
    let chol = h.cholesky()?;
    Some(chol.solve(&b))
}
