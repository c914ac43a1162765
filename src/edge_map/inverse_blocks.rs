//! Entries of `A^-1` from the map's Cholesky factor with forward solves
//! only (eq. 59): the landmark covariances the position filter needs.
//!
//! faer factors `P A P^T = L L^T`, so for scalar unknowns `r`, `c`
//! `(A^-1)_rc = z_r^T z_c` with `z_u = L^-1 e_{p(u)}`, `p(u)` the position
//! of `u` in the ordering. A forward solve from a unit vector at `p` only
//! touches columns of `L` from `p` on; the landmarks in view were mostly
//! added last and sit late in the ordering, so the solve starts near the
//! end of the factor. Against full solves (forward and backward over the
//! whole factor) that is the backward half saved, plus the skipped head.

use faer::linalg::matmul::matmul;
use faer::linalg::triangular_solve::solve_lower_triangular_in_place;
use faer::prelude::{Reborrow, ReborrowMut};
use faer::sparse::linalg::cholesky::supernodal;
use faer::sparse::linalg::cholesky::SymbolicCholeskyRaw;
use faer::sparse::SparseColMatRef;
use faer::{Accum, Mat, MatMut, Par};
use nalgebra::DMatrix;

use super::solve::CholeskyFactor;

impl CholeskyFactor {
    /// `A^-1` restricted to the rows and columns `unknowns` (scalar
    /// indices into the unknowns of A), as a dense matrix.
    pub fn inverse_entries(&self, unknowns: &[usize]) -> DMatrix<f64> {
        let symbolic = self.symbolic();
        let n = symbolic.nrows();
        let k = unknowns.len();
        if n == 0 || k == 0 {
            return DMatrix::zeros(k, k);
        }
        let position = |u: usize| match symbolic.perm() {
            Some(perm) => perm.arrays().1[u] as usize,
            None => u,
        };
        let first = unknowns.iter().map(|&u| position(u)).min().unwrap_or(0);
        // Rows before `first` stay zero: keep only the tail.
        let rows = n - first;
        let mut z = Mat::<f64>::zeros(rows, k);
        for (c, &u) in unknowns.iter().enumerate() {
            z[(position(u) - first, c)] = 1.0;
        }
        match symbolic.raw() {
            SymbolicCholeskyRaw::Supernodal(raw) => {
                let llt = supernodal::SupernodalLltRef::new(raw, self.values());
                forward_supernodal(&llt, first, z.as_mut(), self.par());
            }
            SymbolicCholeskyRaw::Simplicial(raw) => {
                let l = SparseColMatRef::<'_, u32, f64>::new(raw.factor(), self.values());
                forward_simplicial(l, first, z.as_mut());
            }
        }
        let mut product = Mat::<f64>::zeros(k, k);
        matmul(
            product.as_mut(),
            Accum::Replace,
            z.transpose(),
            z.as_ref(),
            1.0,
            self.par(),
        );
        DMatrix::from_fn(k, k, |r, c| 0.5 * (product[(r, c)] + product[(c, r)]))
    }
}

/// `L z = b` in place for the rows `first..` of a supernodal factor (`z`
/// holds those rows; the ones above are zero).
fn forward_supernodal(
    llt: &supernodal::SupernodalLltRef<'_, u32, f64>,
    first: usize,
    mut z: MatMut<'_, f64>,
    par: Par,
) {
    let k = z.ncols();
    let mut update = Mat::<f64>::zeros(0, k);
    for s in 0..llt.symbolic().n_supernodes() {
        let node = llt.supernode(s);
        let values = node.val();
        let size = values.ncols();
        if node.start() + size <= first {
            continue;
        }
        // A supernode straddling `first` has zero rows above it: they
        // contribute nothing, so solve from `first` within it.
        let skip = first.saturating_sub(node.start());
        let (top, bottom) = values.split_at_row(size);
        let top = top.submatrix(skip, skip, size - skip, size - skip);
        let bottom = bottom.subcols(skip, size - skip);
        let mut z_top = z
            .rb_mut()
            .subrows_mut(node.start() + skip - first, size - skip);
        solve_lower_triangular_in_place(top, z_top.rb_mut(), par);
        let pattern = node.pattern();
        if pattern.is_empty() {
            continue;
        }
        update.resize_with(pattern.len(), k, |_, _| 0.0);
        matmul(
            update.as_mut(),
            Accum::Replace,
            bottom,
            z_top.rb(),
            1.0,
            par,
        );
        for c in 0..k {
            for (idx, &row) in pattern.iter().enumerate() {
                z[(row as usize - first, c)] -= update[(idx, c)];
            }
        }
    }
}

/// `L z = b` in place for the rows `first..` of a simplicial factor.
fn forward_simplicial(l: SparseColMatRef<'_, u32, f64>, first: usize, mut z: MatMut<'_, f64>) {
    let k = z.ncols();
    for j in first..l.ncols() {
        let rows = l.row_idx_of_col_raw(j);
        let values = l.val_of_col(j);
        // The diagonal entry comes first in each column of L.
        let diagonal = values[0];
        debug_assert_eq!(rows[0] as usize, j);
        for c in 0..k {
            let v = z[(j - first, c)] / diagonal;
            z[(j - first, c)] = v;
            if v != 0.0 {
                for (&row, &lv) in rows[1..].iter().zip(&values[1..]) {
                    z[(row as usize - first, c)] -= lv * v;
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::edge_map::laplacian::BlockLaplacian;
    use crate::edge_map::simulate::{simulate_city, CityOptions};
    use crate::edge_map::solve::{EdgeMapSolver, SolveReport, SolverChoice};

    /// Entries of `A^-1` by full solves with unit columns: the reference.
    fn by_full_solves(factor: &CholeskyFactor, dim: usize, unknowns: &[usize]) -> DMatrix<f64> {
        let mut rhs = vec![0.0; dim * unknowns.len()];
        for (c, &u) in unknowns.iter().enumerate() {
            rhs[c * dim + u] = 1.0;
        }
        factor.solve_in_place(&mut rhs, unknowns.len());
        DMatrix::from_fn(unknowns.len(), unknowns.len(), |r, c| {
            rhs[c * dim + unknowns[r]]
        })
    }

    #[test]
    fn forward_solves_give_the_entries_of_full_solves() {
        // A small map factors simplicially, a large one supernodally:
        // both paths must agree with full solves, for unknowns early, late
        // and in between in the ordering.
        let mut kinds = Vec::new();
        for (landmarks, max_visible) in [(40, 10), (2000, 200)] {
            let city = simulate_city(&CityOptions {
                landmarks,
                max_visible,
                range_m: 40.0,
                policy: crate::edge_map::EdgePolicy::AllPairs,
                ..CityOptions::default()
            });
            let laplacian = BlockLaplacian::assemble(&city.problem);
            let mut solver = EdgeMapSolver::new(SolverChoice::Cholesky, 1);
            let factor = solver
                .factorize(&laplacian, &mut SolveReport::default())
                .expect("positive definite");
            let dim = laplacian.dim();
            kinds.push(matches!(
                factor.symbolic().raw(),
                SymbolicCholeskyRaw::Supernodal(_)
            ));
            let unknowns: Vec<usize> = vec![0, 1, 2, dim / 3, dim / 2 + 1, dim - 4, dim - 1];
            let got = factor.inverse_entries(&unknowns);
            let expected = by_full_solves(&factor, dim, &unknowns);
            for r in 0..unknowns.len() {
                for c in 0..unknowns.len() {
                    let (g, e) = (got[(r, c)], expected[(r, c)]);
                    assert!(
                        (g - e).abs() <= 1e-9 * (1.0 + e.abs()),
                        "{landmarks} landmarks ({r},{c}): {g} vs {e}"
                    );
                }
            }
            // Late unknowns only: the solve starts near the factor's end.
            let tail = [dim - 1, dim - 2];
            let got = factor.inverse_entries(&tail);
            let expected = by_full_solves(&factor, dim, &tail);
            assert!((&got - &expected).norm() <= 1e-9 * (1.0 + expected.norm()));
        }
        assert_eq!(
            kinds,
            vec![false, true],
            "which factor kinds were tested (true: supernodal)"
        );
    }
}
