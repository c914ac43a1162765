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
//! In a supernodal factor each `z_u` is also zero off the elimination
//! tree's path from `p(u)` to the root, so each supernode works on the
//! columns whose path crosses it only, and adds its rows' share of
//! `z_r^T z_c` as soon as they are solved.

use faer::linalg::matmul::matmul;
use faer::linalg::triangular_solve::{
    solve_lower_triangular_in_place, solve_upper_triangular_in_place,
};
use faer::reborrow::{Reborrow, ReborrowMut};
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
        let position = |u: usize| self.position(u);
        let starts: Vec<usize> = unknowns.iter().map(|&u| position(u)).collect();
        let first = starts.iter().copied().min().unwrap_or(0);
        // Rows before `first` stay zero: keep only the tail.
        let rows = n - first;
        let mut z = Mat::<f64>::zeros(rows, k);
        for (c, &p) in starts.iter().enumerate() {
            z[(p - first, c)] = 1.0;
        }
        let product = match symbolic.raw() {
            SymbolicCholeskyRaw::Supernodal(raw) => {
                let llt = supernodal::SupernodalLltRef::new(raw, self.values());
                forward_supernodal_products(&llt, first, &starts, z.as_mut(), self.par())
            }
            SymbolicCholeskyRaw::Simplicial(raw) => {
                let l = SparseColMatRef::<'_, u32, f64>::new(raw.factor(), self.values());
                forward_simplicial(l, first, z.as_mut());
                let mut product = Mat::<f64>::zeros(k, k);
                matmul(
                    product.as_mut(),
                    Accum::Replace,
                    z.transpose(),
                    z.as_ref(),
                    1.0,
                    self.par(),
                );
                product
            }
        };
        DMatrix::from_fn(k, k, |r, c| 0.5 * (product[(r, c)] + product[(c, r)]))
    }
}

impl CholeskyFactor {
    /// Where scalar unknown `u` sits in the factor's elimination order.
    fn position(&self, u: usize) -> usize {
        match self.symbolic().perm() {
            Some(perm) => perm.arrays().1[u] as usize,
            None => u,
        }
    }

    /// Rows `rows` (scalar unknowns) of `A^-1 B`, `B` given column-major
    /// (`dim` rows, `columns` columns), as a `rows.len() x columns`
    /// matrix. With `P A P^T = L L^T`, the forward solve `L y = P b` is
    /// zero above the first position a nonzero row of `B` has, and the
    /// backward solve `L^T x = y` gives a row from the rows after it
    /// only: both run over the factor's tail from the first position any
    /// nonzero of `B` or any asked row has, not over the whole factor.
    /// The position filter's cross-covariance with the map needs the rows
    /// of the landmarks in view, for sensitivities to landmarks recently
    /// used; both were mostly added last and sit late in the ordering.
    pub fn solve_rows(&self, b: &[f64], columns: usize, rows: &[usize]) -> DMatrix<f64> {
        let symbolic = self.symbolic();
        let n = symbolic.nrows();
        if n == 0 || columns == 0 || rows.is_empty() {
            return DMatrix::zeros(rows.len(), columns);
        }
        assert_eq!(b.len(), n * columns, "B has dim rows per column");
        let position = |u: usize| self.position(u);
        let nonzero = (0..n).filter(|&u| (0..columns).any(|c| b[c * n + u] != 0.0));
        let first = nonzero
            .chain(rows.iter().copied())
            .map(position)
            .min()
            .unwrap_or(0);
        let mut y = Mat::<f64>::zeros(n - first, columns);
        for u in 0..n {
            let p = position(u);
            if p >= first {
                for c in 0..columns {
                    y[(p - first, c)] = b[c * n + u];
                }
            }
        }
        match symbolic.raw() {
            SymbolicCholeskyRaw::Supernodal(raw) => {
                let llt = supernodal::SupernodalLltRef::new(raw, self.values());
                tail_solve_supernodal(&llt, first, y.as_mut(), self.par());
            }
            SymbolicCholeskyRaw::Simplicial(raw) => {
                let l = SparseColMatRef::<'_, u32, f64>::new(raw.factor(), self.values());
                forward_simplicial(l, first, y.as_mut());
                backward_simplicial(l, first, y.as_mut());
            }
        }
        DMatrix::from_fn(rows.len(), columns, |r, c| {
            y[(position(rows[r]) - first, c)]
        })
    }
}

/// `L L^T x = y` in place for the rows `first..` of a supernodal factor,
/// `y` zero above `first` (so the forward solve starts there) and only
/// the rows from `first` wanted (so the backward solve stops there).
fn tail_solve_supernodal(
    llt: &supernodal::SupernodalLltRef<'_, u32, f64>,
    first: usize,
    mut y: MatMut<'_, f64>,
    par: Par,
) {
    let columns = y.ncols();
    let tail: Vec<usize> = (0..llt.symbolic().n_supernodes())
        .filter(|&s| {
            let node = llt.supernode(s);
            node.start() + node.val().ncols() > first
        })
        .collect();
    // A supernode from `first` on: its rows above `first` multiply zeros
    // going forward and are not wanted coming back. Gives the diagonal
    // block, the block below it, the first row of `y` it holds, and the
    // rows of the block below.
    let part = |s: usize| {
        let node = llt.supernode(s);
        let size = node.val().ncols();
        let skip = first.saturating_sub(node.start());
        let (top, bottom) = node.val().split_at_row(size);
        (
            top.submatrix(skip, skip, size - skip, size - skip),
            bottom.subcols(skip, size - skip),
            node.start() + skip - first,
            node.pattern(),
        )
    };
    let mut below = Mat::<f64>::zeros(0, 0);
    for &s in &tail {
        let (top, bottom, row0, pattern) = part(s);
        let height = top.nrows();
        solve_lower_triangular_in_place(top, y.rb_mut().subrows_mut(row0, height), par);
        if pattern.is_empty() {
            continue;
        }
        below.resize_with(pattern.len(), columns, |_, _| 0.0);
        matmul(
            below.as_mut(),
            Accum::Replace,
            bottom,
            y.rb().subrows(row0, height),
            1.0,
            par,
        );
        for c in 0..columns {
            for (idx, &row) in pattern.iter().enumerate() {
                y[(row as usize - first, c)] -= below[(idx, c)];
            }
        }
    }
    for &s in tail.iter().rev() {
        let (top, bottom, row0, pattern) = part(s);
        let height = top.nrows();
        if !pattern.is_empty() {
            below.resize_with(pattern.len(), columns, |_, _| 0.0);
            for c in 0..columns {
                for (idx, &row) in pattern.iter().enumerate() {
                    below[(idx, c)] = y[(row as usize - first, c)];
                }
            }
            matmul(
                y.rb_mut().subrows_mut(row0, height),
                Accum::Add,
                bottom.transpose(),
                below.as_ref(),
                -1.0,
                par,
            );
        }
        solve_upper_triangular_in_place(top.transpose(), y.rb_mut().subrows_mut(row0, height), par);
    }
}

/// `L^T x = y` in place for the rows `first..` of a simplicial factor
/// (a row needs only the rows after it).
fn backward_simplicial(l: SparseColMatRef<'_, u32, f64>, first: usize, mut y: MatMut<'_, f64>) {
    for j in (first..l.ncols()).rev() {
        let rows = l.row_idx_of_col_raw(j);
        let values = l.val_of_col(j);
        let diagonal = values[0];
        for c in 0..y.ncols() {
            let mut v = y[(j - first, c)];
            for (&row, &lv) in rows[1..].iter().zip(&values[1..]) {
                v -= lv * y[(row as usize - first, c)];
            }
            y[(j - first, c)] = v / diagonal;
        }
    }
}

/// `Z^T Z` for `L Z = E` (`E` the unit columns at the positions
/// `starts`), for a supernodal factor: `z` holds the rows `first..` of
/// `E` on entry and is used as scratch.
///
/// Column `c` of `Z` is zero outside the supernodes on the elimination
/// tree's path from the one holding `starts[c]` to the root, so each
/// supernode solves, updates and multiplies only the columns whose path
/// passes through it: near the root that is all of them, in the
/// branches few. Each supernode's rows of `Z` are final once its
/// triangular solve is done, so their share of `Z^T Z` is added there
/// and never read again.
fn forward_supernodal_products(
    llt: &supernodal::SupernodalLltRef<'_, u32, f64>,
    first: usize,
    starts: &[usize],
    mut z: MatMut<'_, f64>,
    par: Par,
) -> Mat<f64> {
    let k = starts.len();
    let symbolic = llt.symbolic();
    let count = symbolic.n_supernodes();
    // Supernode of each row from `first` on.
    let mut supernode_of = vec![0u32; z.nrows()];
    for s in 0..count {
        let node = llt.supernode(s);
        let (begin, end) = (node.start(), node.start() + node.val().ncols());
        for row in begin.max(first)..end.max(first) {
            supernode_of[row - first] = s as u32;
        }
    }
    // The columns active in each supernode: walk each column's path up
    // the tree (a supernode's parent holds the first row below it).
    let mut active: Vec<Vec<u32>> = vec![Vec::new(); count];
    for (c, &p) in starts.iter().enumerate() {
        let mut s = supernode_of[p - first] as usize;
        loop {
            active[s].push(c as u32);
            match llt.supernode(s).pattern().iter().min() {
                Some(&row) => s = supernode_of[row as usize - first] as usize,
                None => break,
            }
        }
    }
    let mut product = Mat::<f64>::zeros(k, k);
    let mut top_z = Mat::<f64>::zeros(0, 0);
    let mut update = Mat::<f64>::zeros(0, 0);
    let mut block = Mat::<f64>::zeros(0, 0);
    for (s, columns) in active.iter().enumerate() {
        if columns.is_empty() {
            continue;
        }
        let node = llt.supernode(s);
        let values = node.val();
        let size = values.ncols();
        // A supernode straddling `first` has zero rows above it: they
        // contribute nothing, so solve from `first` within it.
        let skip = first.saturating_sub(node.start());
        let (top, bottom) = values.split_at_row(size);
        let top = top.submatrix(skip, skip, size - skip, size - skip);
        let bottom = bottom.subcols(skip, size - skip);
        let m = columns.len();
        let height = size - skip;
        let row0 = node.start() + skip - first;
        top_z.resize_with(height, m, |_, _| 0.0);
        for (j, &c) in columns.iter().enumerate() {
            for r in 0..height {
                top_z[(r, j)] = z[(row0 + r, c as usize)];
            }
        }
        solve_lower_triangular_in_place(top, top_z.as_mut(), par);
        block.resize_with(m, m, |_, _| 0.0);
        matmul(
            block.as_mut(),
            Accum::Replace,
            top_z.transpose(),
            top_z.as_ref(),
            1.0,
            par,
        );
        for (j, &c) in columns.iter().enumerate() {
            for (i, &r) in columns.iter().enumerate() {
                product[(r as usize, c as usize)] += block[(i, j)];
            }
        }
        let pattern = node.pattern();
        if pattern.is_empty() {
            continue;
        }
        update.resize_with(pattern.len(), m, |_, _| 0.0);
        matmul(
            update.as_mut(),
            Accum::Replace,
            bottom,
            top_z.as_ref(),
            1.0,
            par,
        );
        for (j, &c) in columns.iter().enumerate() {
            for (idx, &row) in pattern.iter().enumerate() {
                z[(row as usize - first, c as usize)] -= update[(idx, j)];
            }
        }
    }
    product
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

    /// `solve_rows` against full solves: right-hand sides nonzero from
    /// early, middle and late unknowns, rows asked early and late, on a
    /// simplicial and a supernodal factor.
    #[test]
    fn tail_solves_give_the_rows_of_full_solves() {
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
            let cases: [(&[usize], &[usize]); 4] = [
                (&[dim - 1, dim - 5], &[dim - 2, dim - 3]),
                (&[dim / 2, dim - 1], &[dim - 1, 3]),
                (&[0, dim / 3], &[dim / 3 + 1, dim - 1, 1]),
                (&[dim - 7], &[dim - 7]),
            ];
            for (nonzero, rows) in cases {
                let columns = 3;
                let mut b = vec![0.0; dim * columns];
                for (k, &u) in nonzero.iter().enumerate() {
                    for c in 0..columns {
                        b[c * dim + u] = 0.3 + k as f64 - 0.7 * c as f64;
                    }
                }
                let mut full = b.clone();
                factor.solve_in_place(&mut full, columns);
                let got = factor.solve_rows(&b, columns, rows);
                for (r, &u) in rows.iter().enumerate() {
                    for c in 0..columns {
                        let (g, e) = (got[(r, c)], full[c * dim + u]);
                        assert!(
                            (g - e).abs() <= 1e-9 * (1.0 + e.abs()),
                            "{landmarks} landmarks, B on {nonzero:?}, row {u} column {c}: {g} vs {e}"
                        );
                    }
                }
            }
        }
        assert_eq!(
            kinds,
            vec![false, true],
            "factor kinds tested (true: supernodal)"
        );
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
