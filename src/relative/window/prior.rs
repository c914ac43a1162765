//! The prior of eq. 34 on the oldest free keyframe's velocity (and
//! biases) and on gravity, and (vision-only monocular start) the anchor that holds the
//! distance between the first two keyframes.
//!
//! Update rule: after each optimisation the marginal covariance of the
//! gravity direction and of every free keyframe's `[v, b_g, b_a]` is read
//! from the inverse of the reduced (Schur) system. The next solve puts a
//! prior on the then oldest free keyframe's `[v, b_g, b_a]` and on gravity with `prior_weight` times
//! that marginal information, centred on the estimate. The marginal
//! (The prior sits on the newest fixed keyframe, the one just before the
//! oldest free; see the window's module doc.) The marginal
//! counts measurements that are still in the window: with weight `w` the
//! prior's information converges to `w / (1 - w)` times the window's own
//! (a geometric series). For the boundary velocity and biases `w = 1/2`
//! (counted at most twice); for gravity, a constant of the whole run whose
//! information truly accumulates, `w = 0.9`.

use nalgebra::{Matrix2, Matrix3x2, RowVector3, SMatrix, SVector, Vector2, Vector3};

use super::inertial::tangent_basis;
use crate::relative::types::KeyframeState;

pub(crate) type Matrix9 = SMatrix<f64, 9, 9>;
pub(crate) type Vector9 = SVector<f64, 9>;
use crate::imu::so3::hat;

/// Upper factor `U` with `U^T U = weight * cov^-1`.
pub(crate) fn sqrt_information2(cov: &Matrix2<f64>, weight: f64) -> Option<Matrix2<f64>> {
    let sym = (cov + cov.transpose()) * 0.5;
    let info = sym.cholesky()?.inverse() * weight;
    let u = info.cholesky()?.l().transpose();
    u.iter().all(|v| v.is_finite()).then_some(u)
}

/// The eq. 34 prior at the boundary of the free part: on the velocity
/// (the paper's) and, here, the biases of the newest fixed keyframe,
/// whose pose is held and whose `[v, b_g, b_a]` is estimated. It carries
/// the information of the keyframes before it; its source is that
/// keyframe's marginal from the solve in which it was still free.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct OldestFreePrior {
    pub seq: u64,
    /// `[v, b_g, b_a]`
    pub mean: Vector9,
    pub sqrt_info: Matrix9,
}

fn stacked(s: &KeyframeState) -> Vector9 {
    let mut x = Vector9::zeros();
    x.fixed_rows_mut::<3>(0).copy_from(&s.velocity_world_m_s);
    x.fixed_rows_mut::<3>(3).copy_from(&s.biases.gyro_rad_s);
    x.fixed_rows_mut::<3>(6).copy_from(&s.biases.accel_m_s2);
    x
}

impl OldestFreePrior {
    /// Independent standard deviations of velocity, gyro and accel bias.
    pub fn isotropic(seq: u64, state: &KeyframeState, sigmas: [f64; 3]) -> Self {
        let mut d = Vector9::zeros();
        for k in 0..9 {
            d[k] = 1.0 / sigmas[k / 3];
        }
        Self {
            seq,
            mean: stacked(state),
            sqrt_info: Matrix9::from_diagonal(&d),
        }
    }

    /// Centred on `state` with `weight` times the information of `cov`.
    pub fn from_covariance(
        seq: u64,
        state: &KeyframeState,
        cov: &Matrix9,
        weight: f64,
    ) -> Option<Self> {
        let sym = (cov + cov.transpose()) * 0.5;
        let info = sym.cholesky()?.inverse() * weight;
        let sqrt_info = info.cholesky()?.l().transpose();
        sqrt_info.iter().all(|v| v.is_finite()).then_some(Self {
            seq,
            mean: stacked(state),
            sqrt_info,
        })
    }

    /// Centred on `state` with the information matrix `info`.
    pub fn from_information(seq: u64, state: &KeyframeState, info: &Matrix9) -> Option<Self> {
        let sym = (info + info.transpose()) * 0.5;
        let sqrt_info = sym.cholesky()?.l().transpose();
        sqrt_info.iter().all(|v| v.is_finite()).then_some(Self {
            seq,
            mean: stacked(state),
            sqrt_info,
        })
    }

    /// Whitened residual and its Jacobian with respect to `[dv, dbg, dba]`.
    pub fn factor(&self, state: &KeyframeState) -> (Vector9, Matrix9) {
        (
            self.sqrt_info * (stacked(state) - self.mean),
            self.sqrt_info,
        )
    }
}

/// Prior on the gravity direction, in the tangent plane of its mean.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct GravityPrior {
    pub mean_dir: Vector3<f64>,
    pub basis: Matrix3x2<f64>,
    pub sqrt_info: Matrix2<f64>,
}

impl GravityPrior {
    pub fn isotropic(mean_dir: Vector3<f64>, sigma_rad: f64) -> Self {
        Self {
            mean_dir,
            basis: tangent_basis(&mean_dir),
            sqrt_info: Matrix2::identity() / sigma_rad,
        }
    }

    /// Whitened `B0^T (d - d0)` and its Jacobian with respect to the
    /// direction step in the basis `basis` of the current `d`.
    pub fn factor(&self, d: &Vector3<f64>, basis: &Matrix3x2<f64>) -> (Vector2<f64>, Matrix2<f64>) {
        let r = self.sqrt_info * (self.basis.transpose() * (d - self.mean_dir));
        let j = self.sqrt_info * (self.basis.transpose() * (-hat(d) * basis));
        (r, j)
    }
}

/// Holds `|p_1 - p_0|` (monocular vision-only start, one fixed keyframe).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct ScaleAnchor {
    pub seq_first: u64,
    pub seq_second: u64,
    pub distance: f64,
}

impl ScaleAnchor {
    /// Relative standard deviation of the held distance: small enough to
    /// fix the scale, large enough to keep the reduced system well
    /// conditioned.
    pub const RELATIVE_SIGMA: f64 = 1e-6;

    /// Whitened residual and its Jacobian with respect to `dp_1`.
    pub fn factor(&self, p0: &Vector3<f64>, p1: &Vector3<f64>) -> (f64, RowVector3<f64>) {
        let sigma = Self::RELATIVE_SIGMA * self.distance;
        let d = p1 - p0;
        let n = d.norm().max(1e-300);
        ((n - self.distance) / sigma, (d / n).transpose() / sigma)
    }
}
