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
//! (a geometric series). For the boundary velocity and biases and for
//! gravity `w = 1/2` (counted at most twice).

use nalgebra::{Matrix2, Matrix3x2, RowVector3, SMatrix, SVector, Vector2, Vector3};

use super::inertial::tangent_basis;
use crate::relative::types::KeyframeState;

pub(crate) type Matrix9 = SMatrix<f64, 9, 9>;
pub(crate) type Vector9 = SVector<f64, 9>;
use crate::imu::so3::hat;

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

/// The upper factor `U` (`U^T U = info`) of a symmetric positive-definite
/// information, symmetrised first; None when it is not one.
fn upper_factor(info: &Matrix9) -> Option<Matrix9> {
    let sym = (info + info.transpose()) * 0.5;
    let sqrt_info = sym.cholesky()?.l().transpose();
    sqrt_info.iter().all(|v| v.is_finite()).then_some(sqrt_info)
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
        upper_factor(info).map(|sqrt_info| Self {
            seq,
            mean: stacked(state),
            sqrt_info,
        })
    }

    /// Forgets what the prior says of the gyroscope bias down to about
    /// `sigma_rad_s`: its covariance's gyroscope block grows by
    /// `sigma_rad_s^2 I` (the rest and the mean stay). Unchanged when the
    /// result is not a valid information.
    pub fn widen_gyro_bias(&mut self, sigma_rad_s: f64) {
        let info = self.sqrt_info.transpose() * self.sqrt_info;
        let Some(mut cov) = info.cholesky().map(|c| c.inverse()) else {
            return;
        };
        for k in 3..6 {
            cov[(k, k)] += sigma_rad_s * sigma_rad_s;
        }
        let sym = (cov + cov.transpose()) * 0.5;
        if let Some(sqrt_info) = sym.cholesky().and_then(|c| upper_factor(&c.inverse())) {
            self.sqrt_info = sqrt_info;
        }
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
    /// A prior centred on `d` with the information `weight * cov^-1`,
    /// where `cov` is the marginal covariance of the direction step in
    /// `basis` (the tangent basis of `d`).
    pub fn from_marginal(
        d: Vector3<f64>,
        basis: Matrix3x2<f64>,
        cov: &Matrix2<f64>,
        weight: f64,
    ) -> Option<Self> {
        let sym = (cov + cov.transpose()) * 0.5;
        Self::from_information(d, basis, &(sym.cholesky()?.inverse() * weight))
    }

    /// A prior centred on `d` with the information `info` on the direction
    /// step in `basis`. The factor measures `B^T (d' - d)`, which is the
    /// step turned by 90 degrees in the tangent plane (`B^T (-[d]x B)`),
    /// so the information is turned with it; otherwise a well-determined
    /// tilt axis would be held as loosely as the poorly determined one
    /// should be, and the other the other way.
    pub fn from_information(
        d: Vector3<f64>,
        basis: Matrix3x2<f64>,
        info: &Matrix2<f64>,
    ) -> Option<Self> {
        let sym = (info + info.transpose()) * 0.5;
        let step_sqrt_info = sym.cholesky()?.l().transpose();
        if !step_sqrt_info.iter().all(|v| v.is_finite()) {
            return None;
        }
        let turn: Matrix2<f64> = basis.transpose() * (-hat(&d) * basis);
        Some(Self {
            mean_dir: d,
            basis,
            sqrt_info: step_sqrt_info * turn.transpose(),
        })
    }

    /// The prior's information on the direction step in `basis` at `d`.
    #[cfg(test)]
    pub fn information(&self, d: &Vector3<f64>, basis: &Matrix3x2<f64>) -> Matrix2<f64> {
        let (_, j) = self.factor(d, basis);
        j.transpose() * j
    }

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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::relative::window::inertial::update_direction;

    /// The widened prior's covariance is the old one plus `sigma^2` on
    /// the gyroscope bias's diagonal and nothing else: checked against
    /// the inverse of its information, with cross terms between the
    /// gyroscope bias and the velocity kept; the mean does not move.
    #[test]
    fn widening_the_gyro_bias_adds_its_variance_and_keeps_the_rest() {
        let mut cov = Matrix9::zeros();
        for k in 0..9 {
            cov[(k, k)] = [1e-3, 2e-3, 3e-3, 1e-7, 2e-7, 4e-7, 1e-4, 1e-4, 2e-4][k];
        }
        // A correlation of 0.5 between vx and bgx, and 0.3 between bgy and bay.
        let c = 0.5 * (cov[(0, 0)] * cov[(3, 3)]).sqrt();
        cov[(0, 3)] = c;
        cov[(3, 0)] = c;
        let c = 0.3 * (cov[(4, 4)] * cov[(7, 7)]).sqrt();
        cov[(4, 7)] = c;
        cov[(7, 4)] = c;
        let state = KeyframeState {
            t_ns: 0,
            T_world_body: nalgebra::Isometry3::identity(),
            velocity_world_m_s: Vector3::new(0.7, -0.2, 0.3),
            biases: crate::imu::ImuBiases::default(),
        };
        let mut prior = OldestFreePrior::from_covariance(3, &state, &cov, 1.0).expect("valid");
        let mean = prior.mean;
        let sigma = 0.01;
        prior.widen_gyro_bias(sigma);
        let info = prior.sqrt_info.transpose() * prior.sqrt_info;
        let got = info.try_inverse().expect("invertible");
        let mut want = cov;
        for k in 3..6 {
            want[(k, k)] += sigma * sigma;
        }
        for r in 0..9 {
            for k in 0..9 {
                let scale = (want[(r, r)] * want[(k, k)]).sqrt();
                assert!(
                    (got[(r, k)] - want[(r, k)]).abs() < 1e-9 * scale,
                    "({r}, {k}): {} against {}",
                    got[(r, k)],
                    want[(r, k)]
                );
            }
        }
        assert_eq!(prior.mean, mean);
        // The gyroscope bias is now held at about sigma, not at 0.3 mrad/s.
        assert!((got[(3, 3)].sqrt() / sigma - 1.0) < 1e-2);
    }

    #[test]
    fn the_gravity_prior_holds_each_tilt_axis_as_its_marginal_says() {
        let d = Vector3::new(0.1, -0.2, -1.0).normalize();
        let basis = tangent_basis(&d);
        // Well determined about the first basis axis, poorly about the second.
        let cov = Matrix2::new(1e-6, 0.0, 0.0, 1e-2);
        let prior = GravityPrior::from_marginal(d, basis, &cov, 1.0).expect("positive definite");
        let info = cov.try_inverse().expect("invertible");
        for delta in [
            Vector2::new(1e-4, 0.0),
            Vector2::new(0.0, 1e-2),
            Vector2::new(3e-4, -5e-3),
        ] {
            let moved = update_direction(&d, &basis, &delta);
            let (r, _) = prior.factor(&moved, &tangent_basis(&moved));
            let expected = (delta.transpose() * info * delta)[0];
            assert!(
                (r.norm_squared() - expected).abs() < 1e-3 * expected,
                "step {delta:?}: cost {} against {expected}",
                r.norm_squared()
            );
        }
        assert!((prior.information(&d, &basis) - info).norm() < 1e-6 * info.norm());
    }
}
