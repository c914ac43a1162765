//! The position filter's cross-covariance with the map's errors, kept
//! from one correction to the next while the map stays the same.
//!
//! The filter's state error (position and scale) depends on the map
//! errors of the landmarks it was corrected with, `e = a + Σ_k G_k ε_k`
//! ([`PositionFilter::map_sensitivity`]), so a correction with the
//! landmarks `V` needs `Cov(e, ε_V) = Σ_k G_k Σ_L(k, V)`. `Σ_L(k, V)`
//! for every `k` ever used is a four-column solve with the map's factor.
//! Between two solves, though, every correction uses landmarks of the
//! solve's covariance blocks `S` only (the others are skipped), so the
//! rows of `S` are all that is ever read: `W = Σ_k G_k Σ_L(k, S)` is
//! solved once per map, and each correction then moves it the way it
//! moves the sensitivities. A correction with gains `K_v` sets
//! `G_k <- A G_k` for every `k` (`A = I - Σ_v K_v H_v`) and adds `K_v` to
//! `G_v`, so `W <- A W + Σ_v K_v Σ_L(v, S)`, where `Σ_L(v, S)` are rows
//! of the blocks themselves: no solve.
//!
//! The filter drops sensitivities that have decayed below its floor
//! ([`PositionFilter::correct`]); `W` keeps their share, which is below
//! that floor times the map's variances, until the next map recomputes it.

use nalgebra::{DMatrix, Matrix4};

use super::map_worker::{CovarianceBlocks, SolvedMap};
use super::position_filter::{PositionFilter, STATE};

/// `Cov(e, ε_S)` for the landmarks `S` of one solved map's covariance
/// blocks, 4 x 3|S| (rows: the filter's state), columns in the blocks'
/// slot order.
#[derive(Clone, Debug)]
pub struct MapCrossCovariance {
    /// The [`SolvedMap::version`] it belongs to.
    version: u64,
    /// m^2.
    matrix: DMatrix<f64>,
}

impl MapCrossCovariance {
    /// Solved with `map`'s factor for the landmarks of `blocks` (the
    /// map's own covariance blocks) and the sensitivities of `filter`.
    pub fn solve(map: &SolvedMap, blocks: &CovarianceBlocks, filter: &PositionFilter) -> Self {
        let mut by_slot = vec![u32::MAX; blocks.slot.len()];
        for (&id, &slot) in &blocks.slot {
            by_slot[slot] = id;
        }
        Self {
            version: map.version,
            matrix: cross_covariance(map, &by_slot, filter),
        }
    }

    /// Whether it was computed for `map`.
    pub fn is_for(&self, map: &SolvedMap) -> bool {
        self.version == map.version
    }

    /// `Cov(e, ε_ids)`, 4 x 3|ids|; None if one of `ids` has no slot.
    pub fn select(&self, blocks: &CovarianceBlocks, ids: &[u32]) -> Option<DMatrix<f64>> {
        let mut out = DMatrix::zeros(STATE, 3 * ids.len());
        for (k, id) in ids.iter().enumerate() {
            let slot = *blocks.slot.get(id)?;
            out.fixed_view_mut::<STATE, 3>(0, 3 * k)
                .copy_from(&self.matrix.fixed_view::<STATE, 3>(0, 3 * slot));
        }
        Some(out)
    }

    /// Follows a correction that used `ids` with the gain `gain`
    /// (4 x 3|ids|, [`super::position_filter::CorrectionReport::gain`])
    /// and `keep` (`A = I - K H`, [`super::position_filter::CorrectionReport::keep`]):
    /// `W <- A W + Σ_v K_v Σ_L(v, S)`. Ids without a slot leave it
    /// unchanged (None): the caller solves it again.
    pub fn follow(
        &mut self,
        blocks: &CovarianceBlocks,
        ids: &[u32],
        keep: &Matrix4<f64>,
        gain: &DMatrix<f64>,
    ) -> Option<()> {
        if gain.nrows() != STATE || gain.ncols() != 3 * ids.len() {
            return None;
        }
        let slots: Vec<usize> = ids
            .iter()
            .map(|id| blocks.slot.get(id).copied())
            .collect::<Option<_>>()?;
        let keep = DMatrix::from_fn(STATE, STATE, |r, c| keep[(r, c)]);
        let mut next = keep * &self.matrix;
        // K_v Σ_L(v, S), straight from the blocks' rows.
        for (k, &slot) in slots.iter().enumerate() {
            next.gemm(
                1.0,
                &gain.fixed_view::<STATE, 3>(0, 3 * k),
                &blocks.matrix.rows(3 * slot, 3),
                1.0,
            );
        }
        self.matrix = next;
        Some(())
    }

    /// The whole matrix, 3 x 3|S| in slot order, m^2.
    pub fn matrix(&self) -> &DMatrix<f64> {
        &self.matrix
    }
}

/// `Σ_k G_k Σ_L(k, V)` (4 x 3m) for the map ids `ids`: the rows of `ids`
/// in a four-column solve with the factor (`A^-1 G^T`). The solve runs
/// over the factor's tail only
/// ([`crate::edge_map::solve::CholeskyFactor::solve_rows`]): the landmarks
/// recently used and those in view sit late in the ordering. The
/// reference has no unknowns: its columns stay zero, as do those of an id
/// outside the solved map.
fn cross_covariance(map: &SolvedMap, ids: &[u32], filter: &PositionFilter) -> DMatrix<f64> {
    let factor = map.factor.as_ref().expect("called with a factor");
    let dim = map.laplacian.dim();
    let mut rhs = vec![0.0; dim * STATE];
    for (&id, g) in filter.map_sensitivity() {
        if let Some(u) = map.unknown_of(id) {
            for c in 0..STATE {
                for r in 0..3 {
                    rhs[c * dim + 3 * u + r] = g[(c, r)];
                }
            }
        }
    }
    let unknowns: Vec<Option<usize>> = ids.iter().map(|&id| map.unknown_of(id)).collect();
    let rows: Vec<usize> = unknowns
        .iter()
        .flatten()
        .flat_map(|&u| (0..3).map(move |r| 3 * u + r))
        .collect();
    let solved = if dim > 0 {
        factor.solve_rows(&rhs, STATE, &rows)
    } else {
        DMatrix::zeros(rows.len(), STATE)
    };
    let mut cross = DMatrix::zeros(STATE, 3 * ids.len());
    let mut next = 0;
    for (k, u) in unknowns.iter().enumerate() {
        if u.is_some() {
            for r in 0..STATE {
                for c in 0..3 {
                    cross[(r, 3 * k + c)] = solved[(next + c, r)];
                }
            }
            next += 3;
        }
    }
    cross
}
