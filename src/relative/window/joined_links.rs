//! The IMU's agreement with the images over several keyframe links at
//! once, for the noise adaptation ([`super::noise_adaptation`]).
//!
//! One link at a time, an error that is slow against the link (a real
//! IMU's vibration below the keyframe rate, scale and axis errors) is
//! absorbed by the velocities and biases the window estimates, and how
//! much of it the link's residual still shows depends on how the IMU is
//! weighed: weighed far above its real noise, the states bend towards it
//! and its links look good. Over a few links joined the same error adds
//! up, and the states at the joints cannot take it.
//!
//! The oldest `k` links (from the boundary) are joined
//! ([`crate::imu::chain`]); the joined residual is the transported sum of
//! the links' residuals, `r = sum T_m r_m`, and its Jacobian `sum T_m J_m`
//! over every state the links touch, so that its redundancy `dof - tr(W J
//! Sigma J^T W^T)` is exact for the last solve (`W` whitens with the
//! joined interval's covariance, `Sigma` the solve's covariance). Under
//! the declared noise, `E[chi2] = redundancy` as for one link.

use nalgebra::{DMatrix, SMatrix, SVector};

use super::inertial::{self, INERTIAL_COLS};
use super::inertial_link::whitening;
use super::state::{FULL_DIM, VEL};
use super::Window;
use crate::imu::chain::JoinedIntervals;

/// Squared whitened residual and redundancy of a joined interval's
/// rotation rows (3) and velocity and position rows (6).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct JoinedEvidence {
    pub chi2_rotation: f64,
    pub redundancy_rotation: f64,
    pub chi2_translation: f64,
    pub redundancy_translation: f64,
}

/// The solve's covariance column of column `c` of an inertial factor
/// ([`inertial::inertial_factor`]: `[state i | state j | gravity]`) on
/// link `m` counted from the boundary, which runs from keyframe `nf - 1 +
/// m` to `nf + m`: the boundary's pose is held (None), its `[v, b_g,
/// b_a]` at `ob`; free keyframe `s` starts at `s * state_dim`; gravity at
/// `og`.
pub(super) fn link_column(
    state_dim: usize,
    og: usize,
    ob: usize,
    m: usize,
    c: usize,
) -> Option<usize> {
    if c < FULL_DIM {
        match m {
            0 => (c >= VEL).then(|| ob + c - VEL),
            _ => Some((m - 1) * state_dim + c),
        }
    } else if c < 2 * FULL_DIM {
        Some(m * state_dim + c - FULL_DIM)
    } else {
        Some(og + c - 2 * FULL_DIM)
    }
}

impl Window {
    /// The oldest `k` inertial links of the last solve joined into one:
    /// its evidence on the noise. `cov` is the solve's covariance, `og`
    /// and `ob` the columns of gravity and of the boundary's `[v, b_g,
    /// b_a]`. None when fewer than `k` links follow the boundary. One
    /// link (`k` = 1) gives that link's own evidence.
    pub(super) fn joined_inertial_evidence(
        &self,
        cov: &DMatrix<f64>,
        og: usize,
        ob: usize,
        k: usize,
    ) -> Option<JoinedEvidence> {
        let p = &self.problem;
        let nf = p.n_fixed;
        if k < 1 || nf == 0 || nf + k > self.keyframes.len() {
            return None;
        }
        let boundary = &self.keyframes[nf - 1].state;
        let mut chain =
            JoinedIntervals::new(&self.keyframes[nf].imu.as_ref()?.pre, &boundary.biases);
        for m in 1..k {
            if !chain.push(&self.keyframes[nf + m].imu.as_ref()?.pre) {
                return None;
            }
        }
        let column = |m: usize, c: usize| link_column(p.state_dim, og, ob, m, c);
        let mut columns: Vec<usize> = Vec::new();
        let mut residual = SVector::<f64, 9>::zeros();
        let mut jacobian: Vec<SVector<f64, 9>> = Vec::new();
        for m in 0..k {
            let link = self.keyframes[nf + m].imu.as_ref()?;
            let (rw, jw) = inertial::inertial_factor(
                link,
                &self.keyframes[nf - 1 + m].state,
                &self.keyframes[nf + m].state,
                &self.gravity_dir,
                &p.gravity_basis,
            );
            // Back to the residual's own units: sqrt_info is L^-1.
            let l_inv = &link.sqrt_info;
            let r = l_inv.solve_lower_triangular(&rw)?;
            let j: SMatrix<f64, 9, INERTIAL_COLS> = l_inv.solve_lower_triangular(&jw)?;
            let t = &chain.transport[m];
            residual += t * r;
            for c in 0..INERTIAL_COLS {
                let Some(global) = column(m, c) else {
                    continue;
                };
                let tj = t * j.column(c);
                match columns.iter().position(|&g| g == global) {
                    Some(local) => jacobian[local] += tj,
                    None => {
                        columns.push(global);
                        jacobian.push(tj);
                    }
                }
            }
        }
        let scale = self.noise.scale();
        let w = whitening(&chain.joined.scaled_covariance(scale.gyro, scale.accel));
        let residual = w * residual;
        let jacobian: Vec<SVector<f64, 9>> = jacobian.iter().map(|c| w * c).collect();
        // diag(J Sigma J^T) over the columns the links touch.
        let mut leverage = [0.0; 9];
        for (a, ja) in jacobian.iter().enumerate() {
            for (b, jb) in jacobian.iter().enumerate() {
                let s = cov[(columns[a], columns[b])];
                if s == 0.0 {
                    continue;
                }
                for (row, h) in leverage.iter_mut().enumerate() {
                    *h += ja[row] * s * jb[row];
                }
            }
        }
        Some(JoinedEvidence {
            chi2_rotation: residual.fixed_rows::<3>(0).norm_squared(),
            redundancy_rotation: 3.0 - leverage[..3].iter().sum::<f64>(),
            chi2_translation: residual.fixed_rows::<6>(3).norm_squared(),
            redundancy_translation: 6.0 - leverage[3..].iter().sum::<f64>(),
        })
    }
}
