//! The published covariance carried through the solves as a joint
//! covariance of every estimate that a later solve takes as given.
//!
//! A solve estimates the free keyframes (and gravity, the boundary's
//! velocity and biases) with three kinds of input held as if exact: the
//! held keyframes' poses, the mean of the boundary prior (eq. 34) and the
//! mean of the gravity prior. Each input is itself an earlier estimate,
//! wrong by an amount the earlier solves know. Linearised at the result,
//! the estimate moves with each input by the solve's sensitivity
//!
//! ```text
//! S_x = -H^-1 H_ax      (a held pose: its coupling in the reduced system)
//! S_m =  H^-1 J^T J     (a prior's mean: its whitened Jacobian J)
//! ```
//!
//! and with the measurements by the rest, whose covariance is the
//! inverse with each prior's information taken back out:
//! `N = H^-1 - sum S_m H^-1`. So the free estimates' covariance is
//!
//! ```text
//! Sigma_a = S Sigma_in S^T + N,  Cov(a, in) = S Sigma_in
//! ```
//!
//! with `Sigma_in` the inputs' joint covariance from the solves before.
//! The matrix kept here holds, relative to the origin keyframe (zero
//! covariance, the gauge), every held pose, the current prior's mean and
//! the last solve's free estimates, with their cross-covariances: the
//! held keyframes' errors are then carried into the free ones with their
//! correlations, where treating them as exact (or as moving rigidly with
//! the boundary) makes the pose covariance too confident.
//!
//! Used in the inertial modes; without the IMU the window keeps the
//! chain of [`super::pose_covariance`].
//!
//! Consecutive solves share most of their measurements, so an input is
//! not independent of the solve's own noise: the prior's mean is the
//! last solve's estimate, wrong the way this solve's measurements are,
//! and a held pose was estimated from observations still in the window.
//! With `covariance_shared_measurements` the solve's noise `c = H^-1 b`
//! (`b` the measurements' gradient on the free columns) is correlated
//! with the inputs through `D = Cov(b, e)`, carried from solve to solve
//! as if the measurements were the same but for one keyframe's share in
//! `n` (the departing keyframe's); without, they count as independent
//! (too confident by 2-4x on a window with exactly the declared noise,
//! where the gravity prior's sensitivity read from the next prior
//! happens to offset most of it).

use nalgebra::{DMatrix, Matrix6};

use super::camera_imu::CALIB_DIM;
use super::inertial::{inertial_factor, GRAVITY_COL};
use super::schur::Matrix6x3;
use super::state::{inertially_linked, FULL_DIM, VEL};
use super::Window;

/// Which estimate a block of the joint covariance is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Block {
    /// A keyframe's `[dphi, dp]` (window convention).
    Pose(u64),
    /// A keyframe's `[dv, d b_g, d b_a]`.
    Rest(u64),
    /// The mean of the boundary prior on keyframe `seq`'s `[v, b_g, b_a]`.
    BoundaryPrior(u64),
    /// The gravity direction (2 numbers in the tangent basis).
    Gravity,
}

impl Block {
    /// Numbers in the block.
    pub fn size(self) -> usize {
        match self {
            Block::Pose(_) => 6,
            Block::Rest(_) | Block::BoundaryPrior(_) => 9,
            Block::Gravity => 2,
        }
    }
}

/// Joint covariance of a set of blocks.
#[derive(Debug, Clone, Default)]
pub struct JointCovariance {
    blocks: Vec<(Block, usize)>,
    matrix: DMatrix<f64>,
    /// With the shared measurements counted: the last solve's
    /// measurement gradient against every estimate held here.
    noise: Option<NoiseLink>,
}

/// `Cov(b, e)`: `b` the last solve's measurement gradient on its free
/// estimates (rows, block by block), `e` the joint covariance's
/// estimates (its columns).
#[derive(Debug, Clone)]
struct NoiseLink {
    rows: Vec<(Block, usize)>,
    cross: DMatrix<f64>,
}

impl NoiseLink {
    fn row(&self, block: Block) -> Option<usize> {
        self.rows.iter().find(|(b, _)| *b == block).map(|&(_, r)| r)
    }
}

/// What [`JointCovariance::after_solve`] needs to count the measurements
/// a solve shares with the last one.
#[derive(Clone, Copy)]
pub struct SharedMeasurements<'a> {
    /// The free columns' `H^-1`.
    pub inverse: &'a DMatrix<f64>,
    /// `H N`: the measurements' information times `H^-1`.
    pub info_noise: &'a DMatrix<f64>,
    /// The share of the last solve's measurements still in this one.
    pub kept: f64,
}

/// One input of a solve: its block, the solve's sensitivity to it (one
/// column per number of the block, one row per free column), and the
/// covariance to use when no earlier solve estimated it.
pub struct Input {
    /// The input.
    pub block: Block,
    /// `d estimate / d input`, free columns by the block's numbers.
    pub sensitivity: DMatrix<f64>,
    /// Its covariance when the joint covariance does not hold it.
    pub fallback: DMatrix<f64>,
}

impl JointCovariance {
    /// One block with covariance `c`.
    pub fn single(block: Block, c: DMatrix<f64>) -> Self {
        let mut j = Self::default();
        j.push_uncorrelated(block, &c);
        j
    }

    /// Start of `block`'s rows, when held.
    fn start(&self, block: Block) -> Option<usize> {
        self.blocks
            .iter()
            .find(|(b, _)| *b == block)
            .map(|&(_, s)| s)
    }

    /// The covariance of `block`.
    pub fn get(&self, block: Block) -> Option<DMatrix<f64>> {
        let s = self.start(block)?;
        let n = block.size();
        Some(self.matrix.view((s, s), (n, n)).into_owned())
    }

    /// The cross-covariance of `a` (rows) and `b` (columns).
    pub fn cross(&self, a: Block, b: Block) -> Option<DMatrix<f64>> {
        (self.contains(a) && self.contains(b)).then(|| self.gather(&[a], &[b]))
    }

    /// True when `block` is held.
    pub fn contains(&self, block: Block) -> bool {
        self.start(block).is_some()
    }

    /// Names `from` `to` (a prior's mean is the estimate it was centred
    /// on). Does nothing when `from` is not held or `to` already is.
    pub fn rename(&mut self, from: Block, to: Block) {
        if from.size() != to.size() || self.contains(to) {
            return;
        }
        if let Some(entry) = self.blocks.iter_mut().find(|(b, _)| *b == from) {
            entry.0 = to;
        }
    }

    /// Appends `block` with covariance `c`, uncorrelated with the rest.
    fn push_uncorrelated(&mut self, block: Block, c: &DMatrix<f64>) {
        let n = self.matrix.nrows();
        let len = block.size();
        let mut m = DMatrix::zeros(n + len, n + len);
        m.view_mut((0, 0), (n, n)).copy_from(&self.matrix);
        m.view_mut((n, n), (len, len)).copy_from(c);
        self.matrix = m;
        self.blocks.push((block, n));
        if let Some(link) = self.noise.as_mut() {
            let rows = link.cross.nrows();
            let mut cross = DMatrix::zeros(rows, n + len);
            cross.columns_mut(0, n).copy_from(&link.cross);
            link.cross = cross;
        }
    }

    /// The noise link's columns of `columns` (zeros where not held).
    fn noise_columns(&self, link: &NoiseLink, columns: &[Block]) -> DMatrix<f64> {
        let nc: usize = columns.iter().map(|b| b.size()).sum();
        let mut out = DMatrix::zeros(link.cross.nrows(), nc);
        let mut c0 = 0;
        for &cb in columns {
            if let Some(sc) = self.start(cb) {
                out.columns_mut(c0, cb.size())
                    .copy_from(&link.cross.columns(sc, cb.size()));
            }
            c0 += cb.size();
        }
        out
    }

    /// Rows of `blocks`, stacked, against the columns of `columns`.
    fn gather(&self, rows: &[Block], columns: &[Block]) -> DMatrix<f64> {
        let nr: usize = rows.iter().map(|b| b.size()).sum();
        let nc: usize = columns.iter().map(|b| b.size()).sum();
        let mut out = DMatrix::zeros(nr, nc);
        let mut r0 = 0;
        for &rb in rows {
            let (Some(sr), lr) = (self.start(rb), rb.size()) else {
                r0 += rb.size();
                continue;
            };
            let mut c0 = 0;
            for &cb in columns {
                if let Some(sc) = self.start(cb) {
                    out.view_mut((r0, c0), (lr, cb.size()))
                        .copy_from(&self.matrix.view((sr, sc), (lr, cb.size())));
                }
                c0 += cb.size();
            }
            r0 += lr;
        }
        out
    }

    /// The joint covariance after a solve. `inputs` are what the solve
    /// held, `noise` the free columns' covariance from the measurements
    /// alone (`N`), `outputs` the free estimates kept (block and first
    /// free column), `carried` the blocks that stay as they were (the
    /// held poses, the prior's mean). `shared`, to count the measurements
    /// this solve shares with the last.
    pub fn after_solve(
        &self,
        inputs: &[Input],
        noise: &DMatrix<f64>,
        outputs: &[(Block, usize)],
        carried: &[Block],
        shared: Option<SharedMeasurements>,
    ) -> Self {
        let mut previous = self.clone();
        for input in inputs {
            if !previous.contains(input.block) {
                previous.push_uncorrelated(input.block, &input.fallback);
            }
        }
        let free = noise.nrows();
        let n_in: usize = inputs.iter().map(|i| i.block.size()).sum();
        let mut s = DMatrix::zeros(free, n_in);
        let mut c0 = 0;
        for i in inputs {
            s.view_mut((0, c0), (free, i.block.size()))
                .copy_from(&i.sensitivity);
            c0 += i.block.size();
        }
        let in_blocks: Vec<Block> = inputs.iter().map(|i| i.block).collect();
        let carried: Vec<Block> = carried
            .iter()
            .copied()
            .filter(|b| previous.contains(*b))
            .collect();
        let sigma_in = previous.gather(&in_blocks, &in_blocks);
        let sigma_in_carried = previous.gather(&in_blocks, &carried);
        let nc: usize = carried.iter().map(|b| b.size()).sum();
        // The measurements this solve shares with the last one. Its noise
        // is `c = H^-1 b` with `b` the measurements' gradient on the free
        // columns; where an estimate was free in the last solve too, the
        // gradient's covariance with what the last solve's measurements
        // went into (`D`, carried) is taken as the same: the measurements
        // are, but for the newest keyframe's.
        // `D` rows of the free columns, then `C = H^-1 D` (the solve's
        // noise against its inputs and the carried blocks).
        let terms = shared.map(|sh| {
            let mut d_in = DMatrix::zeros(free, n_in);
            let mut d_carried = DMatrix::zeros(free, nc);
            if let Some(link) = previous.noise.as_ref() {
                let g_in = previous.noise_columns(link, &in_blocks);
                let g_carried = previous.noise_columns(link, &carried);
                for &(b, o) in outputs {
                    let Some(r) = link.row(b) else { continue };
                    let len = b.size();
                    d_in.rows_mut(o, len).copy_from(&g_in.rows(r, len));
                    d_carried
                        .rows_mut(o, len)
                        .copy_from(&g_carried.rows(r, len));
                }
                d_in *= sh.kept;
                d_carried *= sh.kept;
            }
            let c_in = sh.inverse * &d_in;
            let c_carried = sh.inverse * &d_carried;
            (d_in, d_carried, c_in, c_carried)
        });
        let mut all = &s * sigma_in * s.transpose() + noise;
        let mut cross = &s * sigma_in_carried;
        if let Some((_, _, c_in, c_carried)) = &terms {
            let sc = &s * c_in.transpose();
            all += &sc + sc.transpose();
            cross += c_carried;
        }
        let no: usize = outputs.iter().map(|(b, _)| b.size()).sum();
        let mut m = DMatrix::zeros(nc + no, nc + no);
        m.view_mut((0, 0), (nc, nc))
            .copy_from(&previous.gather(&carried, &carried));
        let mut blocks: Vec<(Block, usize)> = Vec::with_capacity(carried.len() + outputs.len());
        let mut at = 0;
        for &b in &carried {
            blocks.push((b, at));
            at += b.size();
        }
        for &(ob, oa) in outputs {
            let lo = ob.size();
            let mut at2 = nc;
            for &(pb, pa) in outputs {
                let lp = pb.size();
                m.view_mut((at, at2), (lo, lp))
                    .copy_from(&all.view((oa, pa), (lo, lp)));
                at2 += lp;
            }
            let c = cross.rows(oa, lo);
            m.view_mut((at, 0), (lo, nc)).copy_from(&c);
            m.view_mut((0, at), (nc, lo)).copy_from(&c.transpose());
            blocks.push((ob, at));
            at += lo;
        }
        let m = (&m + m.transpose()) * 0.5;
        // This solve's measurement gradient against the estimates kept:
        // the carried ones as the last solve's, the free ones through
        // `Cov(b, S e + H^-1 b) = D S^T + I H^-1` (`I H^-1 = H N`, the
        // measurements' information).
        let link = shared.zip(terms).map(|(sh, (d_in, d_carried, _, _))| {
            let with_free = &d_in * s.transpose() + sh.info_noise;
            let mut rows = Vec::with_capacity(outputs.len());
            let mut cross_rows = DMatrix::zeros(no, nc + no);
            let mut r = 0;
            for &(ob, oa) in outputs {
                let lo = ob.size();
                cross_rows
                    .view_mut((r, 0), (lo, nc))
                    .copy_from(&d_carried.rows(oa, lo));
                let mut at2 = nc;
                for &(pb, pa) in outputs {
                    let lp = pb.size();
                    cross_rows
                        .view_mut((r, at2), (lo, lp))
                        .copy_from(&with_free.view((oa, pa), (lo, lp)));
                    at2 += lp;
                }
                rows.push((ob, r));
                r += lo;
            }
            NoiseLink {
                rows,
                cross: cross_rows,
            }
        });
        Self {
            blocks,
            matrix: m,
            noise: link,
        }
    }
}

impl JointCovariance {
    /// Drops `block` (an estimate replaced by one not derived from it).
    pub fn remove(&mut self, block: Block) {
        if !self.contains(block) {
            return;
        }
        let keep: Vec<Block> = self
            .blocks
            .iter()
            .map(|&(b, _)| b)
            .filter(|&b| b != block)
            .collect();
        let matrix = self.gather(&keep, &keep);
        if let Some(link) = self.noise.take() {
            let cross = self.noise_columns(&link, &keep);
            self.noise = Some(NoiseLink {
                rows: link.rows,
                cross,
            });
        }
        let mut at = 0;
        self.blocks = keep
            .into_iter()
            .map(|b| {
                let e = (b, at);
                at += b.size();
                e
            })
            .collect();
        self.matrix = matrix;
    }
}

/// `a`'s information inverted (a fallback covariance); zeros when singular.
fn inverse_or_zero(a: &DMatrix<f64>) -> DMatrix<f64> {
    let sym = (a + a.transpose()) * 0.5;
    sym.cholesky()
        .map(|c| c.inverse())
        .filter(|m| m.iter().all(|v| v.is_finite()))
        .unwrap_or_else(|| DMatrix::zeros(a.nrows(), a.ncols()))
}

impl Window {
    /// After a solve whose reduced inverse is `cov` and whose coupling to
    /// the held poses is `coupling` ([`Self::held_pose_coupling`], the
    /// same linearisation): the joint covariance carried to the free
    /// estimates, and each free keyframe's pose covariance from it.
    pub(super) fn propagate_pose_covariances(
        &mut self,
        cov: &DMatrix<f64>,
        coupling: &DMatrix<f64>,
        weighed_gravity_prior: &super::prior::GravityPrior,
    ) {
        let Some(mut previous) = self.joint_covariance.take() else {
            return;
        };
        let p = &self.problem;
        let (nf, sd, a) = (p.n_fixed, p.state_dim, p.eq.dim);
        let n = self.keyframes.len();
        if nf == 0 || nf >= n || cov.nrows() != a || coupling.shape() != (a, 6 * nf) {
            self.joint_covariance = Some(previous);
            return;
        }
        let keyframes = &self.keyframes;
        let mut inputs = Vec::with_capacity(nf + 2);
        for (pos, kf) in keyframes.iter().take(nf).enumerate() {
            let h = coupling.columns(6 * pos, 6);
            if h.iter().all(|v| *v == 0.0) {
                continue;
            }
            let fallback = kf.pose_covariance.map_or_else(
                || DMatrix::zeros(6, 6),
                |c| DMatrix::from_iterator(6, 6, c.iter().copied()),
            );
            inputs.push(Input {
                block: Block::Pose(kf.seq),
                sensitivity: -(cov * h),
                fallback,
            });
        }
        let mut noise = cov.clone();
        let boundary = &keyframes[nf - 1];
        let mut carried: Vec<Block> = keyframes
            .iter()
            .take(nf)
            .map(|k| Block::Pose(k.seq))
            .collect();
        let mut outputs: Vec<(Block, usize)> = Vec::with_capacity(2 * (n - nf) + 2);
        // A keyframe's velocity and biases are an estimate only where an
        // inertial link reaches it: a stereo start in flight keeps the
        // keyframes the window had on the images alone unlinked until
        // they leave, and there the solve's inverse holds only its
        // damping (1e15). Carried, that came back as the boundary prior's
        // mean's covariance and made every pose after a start in flight
        // uncertain by metres; left out, the prior's own covariance (what
        // the alignment declared) stands in for it.
        for (i, kf) in keyframes.iter().enumerate().skip(nf) {
            let slot = i - nf;
            outputs.push((Block::Pose(kf.seq), slot * sd));
            if self.use_imu && inertially_linked(keyframes, i) {
                outputs.push((Block::Rest(kf.seq), slot * sd + VEL));
            }
        }
        if let Some(ob) = p.boundary_offset {
            if let Some(prior) = self.velocity_prior.filter(|pr| pr.seq == boundary.seq) {
                let (_, j) = prior.factor(&boundary.state);
                let w = DMatrix::from_iterator(9, 9, (j.transpose() * j).iter().copied());
                let block = Block::BoundaryPrior(boundary.seq);
                previous.rename(Block::Rest(boundary.seq), block);
                let s = cov.columns(ob, 9) * &w;
                noise -= &s * cov.rows(ob, 9);
                inputs.push(Input {
                    block,
                    sensitivity: s,
                    fallback: inverse_or_zero(&w),
                });
                carried.push(block);
            }
            if keyframes[nf].imu.is_some() {
                outputs.push((Block::Rest(boundary.seq), ob));
            }
        }
        if let Some(og) = p.gravity_offset {
            let prior = if self.config.covariance_shared_measurements {
                weighed_gravity_prior
            } else {
                &self.gravity_prior
            };
            let (_, j) = prior.factor(&self.gravity_dir, &p.gravity_basis);
            let w = DMatrix::from_iterator(2, 2, (j.transpose() * j).iter().copied());
            let s = cov.columns(og, 2) * &w;
            noise -= &s * cov.rows(og, 2);
            inputs.push(Input {
                block: Block::Gravity,
                sensitivity: s,
                fallback: inverse_or_zero(&w),
            });
            outputs.push((Block::Gravity, og));
        }
        noise *= self.vision_only_covariance_factor();
        // `H N` for the shared measurements' bookkeeping; a solve's
        // measurements are its keyframes', one keyframe's leave a window
        // of `n` per solve.
        let info_noise = self
            .config
            .covariance_shared_measurements
            .then(|| cov.clone().cholesky().map(|c| c.solve(&noise)))
            .flatten();
        let shared = info_noise.as_ref().map(|info_noise| SharedMeasurements {
            inverse: cov,
            info_noise,
            kept: (n - 1) as f64 / n as f64,
        });
        let joint = previous.after_solve(&inputs, &noise, &outputs, &carried, shared);
        if !joint.matrix.iter().all(|v| v.is_finite()) {
            // Keep what was carried; the free keyframes keep the chain's
            // covariance ([`Self::update_pose_covariances`]).
            tracing::debug!("propagated pose covariance not finite; kept the chain's");
            self.joint_covariance = Some(previous);
            return;
        }
        for kf in self.keyframes.iter_mut().skip(nf) {
            if let Some(c) = joint.get(Block::Pose(kf.seq)) {
                let m = Matrix6::from_iterator(c.iter().copied());
                // Published only when positive definite (a covariance a
                // consumer can invert); else the chain's value stays.
                if m.cholesky().is_some() {
                    kf.pose_covariance = Some(m);
                } else {
                    tracing::debug!(
                        seq = kf.seq,
                        "propagated pose covariance not positive definite; kept the chain's"
                    );
                }
            }
        }
        self.joint_covariance = Some(joint);
    }

    /// The reduced system's coupling between the free columns and each
    /// held keyframe's pose (6 columns per held keyframe, oldest first):
    /// the landmarks the held and free keyframes share (after the
    /// landmarks are eliminated), the calibration, and the inertial link
    /// from the boundary to the oldest free keyframe.
    pub(super) fn held_pose_coupling(&self) -> DMatrix<f64> {
        let p = &self.problem;
        let (nf, a) = (p.n_fixed, p.eq.dim);
        let mut h = DMatrix::<f64>::zeros(a, 6 * nf);
        for lm in p.landmarks.iter().filter(|l| l.usable) {
            let rows = &p.rows[lm.rows.clone()];
            for held in rows
                .iter()
                .filter(|r| r.kf < nf && r.valid && r.weight > 0.0)
            {
                let wh: Matrix6x3 = held.d_pose.transpose() * held.d_point * held.weight;
                let y = lm.v_inv * wh.transpose();
                let col = 6 * held.kf;
                for free in rows {
                    if let Some(o) = free.offset.filter(|_| free.valid) {
                        let mut block = h.fixed_view_mut::<6, 6>(o, col);
                        block -= free.w_block * y;
                    }
                }
                if let Some(oc) = p.calib_offset {
                    let direct = held.d_calib.transpose() * held.d_pose * held.weight;
                    let mut block = h.fixed_view_mut::<CALIB_DIM, 6>(oc, col);
                    block += direct - lm.w_calib * y;
                }
            }
        }
        if self.use_imu {
            let (ki, kj) = (&self.keyframes[nf - 1], &self.keyframes[nf]);
            if let Some(link) = &kj.imu {
                let (_, j) = inertial_factor(
                    link,
                    &ki.state,
                    &kj.state,
                    &self.gravity_dir,
                    &p.gravity_basis,
                );
                let jx = j.fixed_columns::<6>(0);
                let col = 6 * (nf - 1);
                for (c, len, offset) in [
                    (VEL, 9, p.boundary_offset),
                    (FULL_DIM, FULL_DIM, Some(0)),
                    (GRAVITY_COL, 2, p.gravity_offset),
                ] {
                    if let Some(o) = offset {
                        let mut block = h.view_mut((o, col), (len, 6));
                        block += j.columns(c, len).transpose() * jx;
                    }
                }
                // With the held keyframes following the calibration, the
                // solve's link reaches the calibration through the
                // boundary's body state (`held_cameras`), so the boundary
                // pose couples to it there too. Left out, the solve's
                // answer to a held pose's error lost a term it balances
                // against: after a start in flight the carried covariance
                // grew by 1e3-1e4 a solve, to 1e115 m^2.
                if let Some((calibration, oc)) = self.following_link_calibration(&j, ki) {
                    let mut block = h.fixed_view_mut::<CALIB_DIM, 6>(oc, col);
                    block += calibration.transpose() * jx;
                }
            }
        }
        h
    }
}

#[cfg(test)]
mod tests {
    use nalgebra::{DVector, Matrix2};
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;
    use rand_distr::{Distribution, StandardNormal};

    use super::*;

    #[test]
    fn a_chain_of_linear_solves_matches_its_sampled_errors() {
        // Scalar positions on a line, two per "keyframe" block reused as a
        // 6-vector: x_k = x_(k-1) + d_k + noise, each solve estimating the
        // newest from the held one. After a chain the propagated variance
        // must be the sum of the steps' variances, and the cross-covariance
        // with a carried block the carried block's variance.
        let step = 0.3f64;
        let id6 = DMatrix::<f64>::identity(6, 6);
        let mut joint = JointCovariance::single(Block::Pose(0), DMatrix::zeros(6, 6));
        for k in 1..5u64 {
            let inputs = [Input {
                block: Block::Pose(k - 1),
                sensitivity: id6.clone(),
                fallback: DMatrix::zeros(6, 6),
            }];
            joint = joint.after_solve(
                &inputs,
                &(&id6 * (step * step)),
                &[(Block::Pose(k), 0)],
                &[Block::Pose(k - 1)],
                None,
            );
        }
        let last = joint.get(Block::Pose(4)).expect("held");
        assert!((last[(0, 0)] - 4.0 * step * step).abs() < 1e-12);
        let cross = joint.gather(&[Block::Pose(4)], &[Block::Pose(3)]);
        assert!((cross[(2, 2)] - 3.0 * step * step).abs() < 1e-12);
        assert!(!joint.contains(Block::Pose(2)));
    }

    #[test]
    fn an_averaging_solve_matches_monte_carlo() {
        // Two held inputs with correlated errors; the solve averages them
        // with weights (0.7, 0.3) and adds its own noise. Sampled errors
        // of the estimate against the propagated covariance.
        let l = Matrix2::new(0.2, 0.0, 0.15, 0.1);
        let c_in = l * l.transpose();
        let mut joint = JointCovariance::default();
        let mut m = DMatrix::zeros(12, 12);
        for i in 0..6 {
            m[(i, i)] = c_in[(0, 0)];
            m[(i + 6, i + 6)] = c_in[(1, 1)];
            m[(i, i + 6)] = c_in[(0, 1)];
            m[(i + 6, i)] = c_in[(0, 1)];
        }
        joint.blocks = vec![(Block::Pose(0), 0), (Block::Pose(1), 6)];
        joint.matrix = m;
        let id6 = DMatrix::<f64>::identity(6, 6);
        let noise_sigma = 0.05;
        let inputs = [
            Input {
                block: Block::Pose(0),
                sensitivity: &id6 * 0.7,
                fallback: DMatrix::zeros(6, 6),
            },
            Input {
                block: Block::Pose(1),
                sensitivity: &id6 * 0.3,
                fallback: DMatrix::zeros(6, 6),
            },
        ];
        let after = joint.after_solve(
            &inputs,
            &(&id6 * (noise_sigma * noise_sigma)),
            &[(Block::Pose(2), 0)],
            &[Block::Pose(1)],
            None,
        );
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let n = 50_000;
        let (mut var, mut cov) = (0.0, 0.0);
        for _ in 0..n {
            let z = DVector::from_fn(2, |_, _| StandardNormal.sample(&mut rng));
            let e = l * nalgebra::Vector2::new(z[0], z[1]);
            let own: f64 = StandardNormal.sample(&mut rng);
            let est = 0.7 * e[0] + 0.3 * e[1] + noise_sigma * own;
            var += est * est;
            cov += est * e[1];
        }
        let (var, cov) = (var / n as f64, cov / n as f64);
        let p = after.get(Block::Pose(2)).expect("output");
        let c = after.gather(&[Block::Pose(2)], &[Block::Pose(1)]);
        assert!(
            (p[(3, 3)] - var).abs() < 0.03 * var,
            "{} vs {var}",
            p[(3, 3)]
        );
        assert!(
            (c[(3, 3)] - cov).abs() < 0.03 * cov,
            "{} vs {cov}",
            c[(3, 3)]
        );
        assert!(c[(3, 4)].abs() < 1e-15);
    }

    #[test]
    fn a_prior_centred_on_the_last_solve_shares_its_measurements() {
        // A sliding window over a constant (the gravity block, two
        // numbers): each solve averages the window's `w` unit-variance
        // measurements with a prior centred on the last solve's estimate
        // holding `weight` of its information, as the window's gravity
        // prior does. One measurement leaves and one arrives per solve, so
        // consecutive solves share all but one: the prior's mean is
        // wrong the way the solve's own measurements are. Counted as
        // independent, the propagated variance is far too small; with the
        // shared measurements it must match the sampled one.
        let (w, weight, solves) = (8usize, 0.5, 40usize);
        let kept = (w - 1) as f64 / w as f64;
        let id2 = DMatrix::<f64>::identity(2, 2);
        let propagate = |shared: bool| {
            let mut joint = JointCovariance::default();
            let mut h_prev: Option<f64> = None;
            for _ in 0..solves {
                let wp = h_prev.map_or(0.0, |h| weight * h);
                let h = w as f64 + wp;
                let noise = &id2 * (w as f64 / (h * h));
                let inverse = &id2 / h;
                let info_noise = &id2 * (w as f64 / h);
                let inputs: Vec<Input> = h_prev
                    .map(|_| Input {
                        block: Block::Gravity,
                        sensitivity: &id2 * (wp / h),
                        fallback: DMatrix::zeros(2, 2),
                    })
                    .into_iter()
                    .collect();
                joint = joint.after_solve(
                    &inputs,
                    &noise,
                    &[(Block::Gravity, 0)],
                    &[],
                    shared.then_some(SharedMeasurements {
                        inverse: &inverse,
                        info_noise: &info_noise,
                        kept,
                    }),
                );
                h_prev = Some(h);
            }
            joint.get(Block::Gravity).expect("output")[(0, 0)]
        };
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let trials = 20_000;
        let mut sum = 0.0;
        for _ in 0..trials {
            let n: Vec<f64> = (0..solves + w)
                .map(|_| StandardNormal.sample(&mut rng))
                .collect();
            let (mut e, mut h_prev) = (0.0, None::<f64>);
            for k in 0..solves {
                let z: f64 = n[k..k + w].iter().sum();
                let wp = h_prev.map_or(0.0, |h| weight * h);
                let h = w as f64 + wp;
                e = (z + wp * e) / h;
                h_prev = Some(h);
            }
            sum += e * e;
        }
        let sampled = sum / trials as f64;
        let (independent, with_shared) = (propagate(false), propagate(true));
        println!("sampled {sampled:.4}, independent {independent:.4}, with the shared measurements {with_shared:.4}");
        assert!(
            independent < 0.5 * sampled,
            "independent {independent} against sampled {sampled}"
        );
        assert!(
            (with_shared - sampled).abs() < 0.1 * sampled,
            "with the shared measurements {with_shared} against sampled {sampled}"
        );
    }
}
