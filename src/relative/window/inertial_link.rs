//! A preintegrated IMU interval between two keyframes with its whitening
//! (the square root information of `[r_R, r_v, r_p]`), weighed by the
//! noise the window currently believes ([`super::noise_adaptation`]).
//! Keyframes own their link ([`super::state`]); the inertial factor
//! ([`super::inertial`]) reads it.

use nalgebra::SMatrix;

use super::noise_adaptation::NoiseScale;
use crate::imu::Preintegrated;

/// 9x9 matrix over the inertial residual `[r_R, r_v, r_p]`.
pub type Matrix9 = SMatrix<f64, 9, 9>;

/// A preintegrated interval with its whitening.
#[derive(Debug, Clone)]
pub(crate) struct InertialLink {
    pub pre: Preintegrated,
    /// `L^-1` with `L L^T` the covariance of `[r_R, r_v, r_p]`.
    pub sqrt_info: Matrix9,
}

impl InertialLink {
    /// Weighted by the noise it was integrated with.
    #[cfg(test)]
    pub fn new(pre: Preintegrated) -> Self {
        Self::scaled(pre, NoiseScale::DECLARED)
    }

    /// Weighted by that noise times `scale`.
    pub fn scaled(pre: Preintegrated, scale: NoiseScale) -> Self {
        let sqrt_info = whitening(&pre.scaled_covariance(scale.gyro, scale.accel));
        Self { pre, sqrt_info }
    }

    pub fn rescale(&mut self, scale: NoiseScale) {
        self.sqrt_info = whitening(&self.pre.scaled_covariance(scale.gyro, scale.accel));
    }
}

/// `L^-1` for `L L^T = cov` (symmetrised, with a small floor on the
/// diagonal so that a noise-free interval still has a finite weight).
pub(crate) fn whitening(cov: &Matrix9) -> Matrix9 {
    let mut c = (cov + cov.transpose()) * 0.5;
    let largest = c.diagonal().max().max(0.0);
    let floor = 1e-24 + 1e-12 * largest;
    for i in 0..9 {
        c[(i, i)] += floor;
    }
    match c.cholesky().and_then(|ch| ch.l().try_inverse()) {
        Some(l_inv) if l_inv.iter().all(|v| v.is_finite()) => l_inv,
        _ => Matrix9::from_diagonal(&c.diagonal().map(|v| 1.0 / v.abs().max(1e-24).sqrt())),
    }
}
