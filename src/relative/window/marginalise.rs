//! Carrying the eq. 34 prior forward by marginalisation.
//!
//! When a keyframe becomes the newest fixed one (the boundary), the
//! previous boundary is held entirely and the inertial link between the
//! two leaves the optimisation. What that link and the previous prior
//! knew about the new boundary's `[v, b_g, b_a]` is kept by marginalising
//! them: a small Gaussian system over
//! `[old: dphi dp dv dbg dba | new: the same | gravity 2]` holds
//! - the previous boundary prior on the old `[v, b_g, b_a]`,
//! - the departing preintegrated residual and bias random walk,
//! - the new keyframe's pose with its marginal covariance from the solve
//!   in which it was the oldest free one (it is held from now on, but it
//!   is not exact: conditioning on it would make the prior far too
//!   confident); the old pose is conditioned on, its uncertainty having
//!   entered the previous step,
//! - the current gravity prior;
//!
//! and everything but the new `[v, b_g, b_a]` is eliminated (Schur
//! complement). The result is the next boundary prior. Unlike re-using a
//! share of the last solve's marginal, it counts each measurement once, so
//! the biases' information accumulates (over `boundary_prior_memory_s`)
//! instead of being re-estimated from about two windows' data.

use nalgebra::{DMatrix, DVector, Matrix2, Matrix3x2, SMatrix, Vector3, Vector6};

use super::inertial::{bias_walk_factor, inertial_factor, GRAVITY_COL};
use super::inertial_link::InertialLink;
use super::prior::{GravityPrior, Matrix9, OldestFreePrior, Vector9};
use super::state::{BG, FULL_DIM, VEL};
use crate::relative::types::KeyframeState;

pub(crate) type Matrix15 = SMatrix<f64, 15, 15>;

/// Unknowns of the small system: two keyframes and gravity.
const DIM: usize = 2 * FULL_DIM + 2;
/// Where the kept block (the new keyframe's `[v, b_g, b_a]`) starts.
const KEPT: usize = FULL_DIM + VEL;
const KEPT_DIM: usize = 9;
/// The old keyframe's pose: the first columns, conditioned on.
const OLD_POSE_DIM: usize = 6;

/// The new end of the departing link.
pub(crate) struct LinkEnd<'a> {
    pub state: &'a KeyframeState,
    /// Marginal covariance of `[dphi dp dv dbg dba]` from the last solve
    /// in which this keyframe was free; its pose block is used.
    pub marginal: &'a Matrix15,
}

/// The boundary prior on `new` after marginalising `old`, the link
/// between them (`link`, `bias_walk_sqrt_info`, stored on `new`) and
/// gravity, with the new pose's marginal covariance scaled by
/// `pose_covariance_scale`, and the result's information by
/// `exp(-dt / memory_s)` (see [`super::WindowConfig`]). None if a block
/// is not positive definite.
#[allow(clippy::too_many_arguments)]
pub(crate) fn marginalise_boundary(
    previous: &OldestFreePrior,
    old: &KeyframeState,
    new: LinkEnd<'_>,
    new_seq: u64,
    link: &InertialLink,
    bias_walk_sqrt_info: &Vector6<f64>,
    gravity_dir: &Vector3<f64>,
    gravity_basis: &Matrix3x2<f64>,
    gravity_prior: &GravityPrior,
    pose_covariance_scale: f64,
    memory_s: f64,
) -> Option<OldestFreePrior> {
    let mut h = DMatrix::<f64>::zeros(DIM, DIM);
    let mut g = DVector::<f64>::zeros(DIM);
    let mut add = |r: &[f64], j: &DMatrix<f64>, cols: &[usize]| {
        let jt_j = j.transpose() * j;
        let jt_r = j.transpose() * DVector::from_column_slice(r);
        for (a, &ca) in cols.iter().enumerate() {
            g[ca] += jt_r[a];
            for (b, &cb) in cols.iter().enumerate() {
                h[(ca, cb)] += jt_j[(a, b)];
            }
        }
    };
    let range = |start: usize, len: usize| (start..start + len).collect::<Vec<_>>();

    let (r, j) = inertial_factor(link, old, new.state, gravity_dir, gravity_basis);
    debug_assert_eq!(GRAVITY_COL, 2 * FULL_DIM);
    add(
        r.as_slice(),
        &DMatrix::from_column_slice(9, DIM, j.as_slice()),
        &range(0, DIM),
    );

    let (r, j) = bias_walk_factor(bias_walk_sqrt_info, old, new.state);
    let mut cols = range(BG, 6);
    cols.extend(range(FULL_DIM + BG, 6));
    add(
        r.as_slice(),
        &DMatrix::from_column_slice(6, 12, j.as_slice()),
        &cols,
    );

    let (r, j) = previous.factor(old);
    add(
        r.as_slice(),
        &DMatrix::from_column_slice(9, 9, j.as_slice()),
        &range(VEL, 9),
    );

    let (r, j): (_, Matrix2<f64>) = gravity_prior.factor(gravity_dir, gravity_basis);
    add(
        r.as_slice(),
        &DMatrix::from_column_slice(2, 2, j.as_slice()),
        &range(GRAVITY_COL, 2),
    );

    // The new pose: zero residual at its estimate, the information of
    // its marginal from the solve in which it was the oldest free
    // keyframe, i.e. relative to the old one, which was then fixed. The
    // old pose is therefore conditioned on (its rows left out): its own
    // uncertainty was counted when it was the new end of the link before.
    let cov = new.marginal.fixed_view::<6, 6>(0, 0).into_owned() * pose_covariance_scale;
    let info = ((cov + cov.transpose()) * 0.5).cholesky()?.inverse();
    for a in 0..6 {
        for b in 0..6 {
            h[(FULL_DIM + a, FULL_DIM + b)] += info[(a, b)];
        }
    }

    // Eliminate everything but the kept block and the old pose.
    let eliminated: Vec<usize> = (OLD_POSE_DIM..DIM)
        .filter(|i| !(KEPT..KEPT + KEPT_DIM).contains(i))
        .collect();
    let kept = range(KEPT, KEPT_DIM);
    let pick = |rows: &[usize], cols: &[usize]| {
        DMatrix::from_fn(rows.len(), cols.len(), |a, b| h[(rows[a], cols[b])])
    };
    let h_mm = pick(&eliminated, &eliminated);
    let h_km = pick(&kept, &eliminated);
    let h_kk = pick(&kept, &kept);
    let g_m = DVector::from_iterator(eliminated.len(), eliminated.iter().map(|&i| g[i]));
    let g_k = DVector::from_iterator(KEPT_DIM, kept.iter().map(|&i| g[i]));
    let chol_mm = h_mm.cholesky()?;
    let info = h_kk - &h_km * chol_mm.solve(&h_km.transpose());
    let grad = g_k - &h_km * chol_mm.solve(&g_m);
    let info = Matrix9::from_iterator((&info + info.transpose()).iter().map(|v| 0.5 * v));
    let chol = info.cholesky()?;
    let step = -chol.solve(&Vector9::from_iterator(grad.iter().copied()));
    let info = info * (-link.pre.dt_s / memory_s).exp();
    let mut mean_state = *new.state;
    mean_state.velocity_world_m_s += step.fixed_rows::<3>(0);
    mean_state.biases.gyro_rad_s += step.fixed_rows::<3>(3);
    mean_state.biases.accel_m_s2 += step.fixed_rows::<3>(6);
    OldestFreePrior::from_information(new_seq, &mean_state, &info)
}

#[cfg(test)]
mod tests {
    use nalgebra::{DMatrix, DVector, Vector3};
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    use super::*;
    use crate::relative::window::inertial::{bias_walk_sqrt_info, tangent_basis};
    use crate::relative::window::synthetic::{keyframe_time, Scene};
    use crate::rig::euroc::euroc_imu0;

    struct Case {
        old: KeyframeState,
        new: KeyframeState,
        truth_new: KeyframeState,
        previous: OldestFreePrior,
        marginal: Matrix15,
        link: InertialLink,
        walk: Vector6<f64>,
        gravity: GravityPrior,
    }

    /// Two consecutive keyframes of the synthetic scene with their exact
    /// (noise-free) inertial link; the new one's `[v, b_g, b_a]` moved off
    /// the truth by `offset`.
    fn case(offset: f64) -> Case {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let scene = Scene::new(&mut rng, 10, 4.0);
        let (t0, t1) = (keyframe_time(4), keyframe_time(5));
        let old = scene.truth(t0);
        let truth_new = scene.truth(t1);
        let mut new = truth_new;
        new.velocity_world_m_s += Vector3::new(0.03, -0.02, 0.01) * (offset / 0.03);
        new.biases.gyro_rad_s += Vector3::new(-1.0, 2.0, 0.5) * (offset * 0.03);
        new.biases.accel_m_s2 += Vector3::new(0.5, 0.2, -1.0) * offset;
        let mut marginal = Matrix15::identity() * 1e-4;
        for k in 0..3 {
            marginal[(k, k)] = 1e-6; // attitude, rad^2
            marginal[(3 + k, 3 + k)] = 4e-6; // position, m^2
        }
        marginal[(0, 4)] = 5e-7;
        marginal[(4, 0)] = 5e-7;
        Case {
            previous: OldestFreePrior::isotropic(7, &old, [0.02, 1e-3, 0.02]),
            old,
            new,
            truth_new,
            marginal,
            link: InertialLink::new(scene.preintegrate(t0, t1)),
            walk: bias_walk_sqrt_info(&euroc_imu0().noise, (t1 - t0) as f64 * 1e-9),
            gravity: GravityPrior::isotropic(Vector3::new(0.0, 0.0, -1.0), 0.01),
        }
    }

    fn run(c: &Case) -> OldestFreePrior {
        let down = Vector3::new(0.0, 0.0, -1.0);
        marginalise_boundary(
            &c.previous,
            &c.old,
            LinkEnd {
                state: &c.new,
                marginal: &c.marginal,
            },
            8,
            &c.link,
            &c.walk,
            &down,
            &tangent_basis(&down),
            &c.gravity,
            1.0,
            f64::INFINITY,
        )
        .expect("positive definite")
    }

    #[test]
    fn equals_the_dense_marginal_of_the_stacked_factors() {
        // Reference: every whitened factor stacked into one Jacobian over
        // [new pose | old v b | new v b | gravity] (the old pose is
        // conditioned on), the full covariance inverted densely, and the
        // kept block's covariance and Gauss-Newton step read off it.
        let c = case(0.02);
        let prior = run(&c);
        let down = Vector3::new(0.0, 0.0, -1.0);
        let basis = tangent_basis(&down);
        // Columns of the reference: full index -> reference index.
        let col = |full: usize| -> Option<usize> { full.checked_sub(OLD_POSE_DIM) };
        let n = DIM - OLD_POSE_DIM;
        let mut rows: Vec<(Vec<f64>, f64)> = Vec::new();
        let mut push = |r: &[f64], j: &dyn Fn(usize, usize) -> f64, cols: &[usize]| {
            for (i, ri) in r.iter().enumerate() {
                let mut row = vec![0.0; n];
                for (k, &full) in cols.iter().enumerate() {
                    if let Some(c) = col(full) {
                        row[c] += j(i, k);
                    }
                }
                rows.push((row, *ri));
            }
        };
        let (r, j) = inertial_factor(&c.link, &c.old, &c.new, &down, &basis);
        push(
            r.as_slice(),
            &|i, k| j[(i, k)],
            &(0..DIM).collect::<Vec<_>>(),
        );
        let (r, j) = bias_walk_factor(&c.walk, &c.old, &c.new);
        let cols: Vec<usize> = (BG..BG + 6)
            .chain(FULL_DIM + BG..FULL_DIM + BG + 6)
            .collect();
        push(r.as_slice(), &|i, k| j[(i, k)], &cols);
        let (r, j) = c.previous.factor(&c.old);
        push(
            r.as_slice(),
            &|i, k| j[(i, k)],
            &(VEL..VEL + 9).collect::<Vec<_>>(),
        );
        let (r, j) = c.gravity.factor(&down, &basis);
        push(
            r.as_slice(),
            &|i, k| j[(i, k)],
            &[GRAVITY_COL, GRAVITY_COL + 1],
        );
        // The new pose's prior as rows: U with U^T U = cov^-1.
        let cov6 = c.marginal.fixed_view::<6, 6>(0, 0).into_owned();
        let u = cov6
            .try_inverse()
            .unwrap()
            .cholesky()
            .unwrap()
            .l()
            .transpose();
        let zeros = [0.0; 6];
        push(
            &zeros,
            &|i, k| u[(i, k)],
            &(FULL_DIM..FULL_DIM + 6).collect::<Vec<_>>(),
        );

        let jm = DMatrix::from_fn(rows.len(), n, |i, k| rows[i].0[k]);
        let rv = DVector::from_iterator(rows.len(), rows.iter().map(|r| r.1));
        let cov = (jm.transpose() * &jm).try_inverse().expect("invertible");
        let step = -&cov * (jm.transpose() * rv);
        let kept = KEPT - OLD_POSE_DIM;
        let cov_k = cov.view((kept, kept), (9, 9)).into_owned();
        let info_ref = cov_k.try_inverse().expect("invertible");
        let info = prior.sqrt_info.transpose() * prior.sqrt_info;
        let scale = info_ref.amax();
        let diff = (DMatrix::from_iterator(9, 9, info.iter().copied()) - &info_ref).amax();
        assert!(
            diff < 1e-8 * scale,
            "information differs by {diff} (scale {scale})"
        );
        let mut expected = Vector9::zeros();
        expected
            .fixed_rows_mut::<3>(0)
            .copy_from(&c.new.velocity_world_m_s);
        expected
            .fixed_rows_mut::<3>(3)
            .copy_from(&c.new.biases.gyro_rad_s);
        expected
            .fixed_rows_mut::<3>(6)
            .copy_from(&c.new.biases.accel_m_s2);
        for k in 0..9 {
            expected[k] += step[kept + k];
        }
        assert!(
            (prior.mean - expected).amax() < 1e-9,
            "{} vs {}",
            prior.mean,
            expected
        );
    }

    #[test]
    fn its_mean_returns_to_the_truth_from_a_perturbed_estimate() {
        // The old keyframe and its prior at the truth, a noise-free link:
        // wherever the new estimate sits, the prior's mean is the truth.
        let c = case(0.03);
        let prior = run(&c);
        let t = &c.truth_new;
        let dv = (prior.mean.fixed_rows::<3>(0) - t.velocity_world_m_s).norm();
        let dbg = (prior.mean.fixed_rows::<3>(3) - t.biases.gyro_rad_s).norm();
        let dba = (prior.mean.fixed_rows::<3>(6) - t.biases.accel_m_s2).norm();
        // The estimate was 0.037 m/s, 2.3e-3 rad/s and 0.034 m/s^2 off.
        assert!(dv < 2e-3 && dbg < 1e-4 && dba < 2e-3, "{dv} {dbg} {dba}");
    }
}
