//! Landmark covariance (paper eq. 59): the blocks of `A^-1` (reference
//! removed) for the landmarks a frame sees.
//!
//! Exact: solve `A X = E` against the 3m unit columns of the m visible
//! landmarks with the Cholesky factor and read the m x m blocks of X.
//! Approximate (the paper's sub-matrix rule): invert the principal
//! sub-matrix of A over the visible landmarks, optionally grown by `hops`
//! rings of graph neighbours, and read the visible blocks. The sub-matrix
//! inverse treats the landmarks outside it as known, so it is smaller than
//! the exact covariance (in the positive semi-definite order); growing the
//! sub-graph closes the gap.

use std::collections::HashMap;

use nalgebra::DMatrix;

use super::laplacian::BlockLaplacian;
use super::problem::MapProblem;
use super::solve::CholeskyFactor;

/// Joint covariance (3m x 3m, m^2) of `visible` (distinct landmark ids, the
/// reference excluded: it is fixed and has none) by solving against the
/// needed columns of the identity.
pub fn exact_covariance(
    factor: &CholeskyFactor,
    problem: &MapProblem,
    visible: &[u32],
) -> DMatrix<f64> {
    let unknowns: Vec<usize> = visible
        .iter()
        .filter_map(|&id| problem.unknown_of(id))
        .collect();
    let dim = 3 * (problem.landmark_count as usize - 1);
    let columns = 3 * unknowns.len();
    let mut rhs = vec![0.0; dim * columns];
    for (k, &u) in unknowns.iter().enumerate() {
        for c in 0..3 {
            rhs[(3 * k + c) * dim + 3 * u + c] = 1.0;
        }
    }
    factor.solve_in_place(&mut rhs, columns);
    DMatrix::from_fn(columns, columns, |r, c| {
        let (k, a) = (r / 3, r % 3);
        rhs[c * dim + 3 * unknowns[k] + a]
    })
}

/// The paper's approximation: the visible blocks of the inverse of A's
/// principal sub-matrix over the visible landmarks and their neighbours up
/// to `hops` edges away.
pub fn submatrix_covariance(
    laplacian: &BlockLaplacian,
    problem: &MapProblem,
    visible: &[u32],
    hops: usize,
) -> DMatrix<f64> {
    let visible_unknowns: Vec<usize> = visible
        .iter()
        .filter_map(|&id| problem.unknown_of(id))
        .collect();
    // Grow the set by graph rings.
    let mut adjacency: HashMap<usize, Vec<usize>> = HashMap::new();
    if hops > 0 {
        for e in &problem.edges {
            if let (Some(a), Some(b)) = (problem.unknown_of(e.i), problem.unknown_of(e.j)) {
                adjacency.entry(a).or_default().push(b);
                adjacency.entry(b).or_default().push(a);
            }
        }
    }
    let mut local: HashMap<usize, usize> = HashMap::new();
    let mut order: Vec<usize> = Vec::new();
    for &u in &visible_unknowns {
        if !local.contains_key(&u) {
            local.insert(u, order.len());
            order.push(u);
        }
    }
    let distinct_visible = order.len();
    let mut frontier = order.clone();
    for _ in 0..hops {
        let mut next = Vec::new();
        for u in frontier {
            for &w in adjacency.get(&u).map(Vec::as_slice).unwrap_or(&[]) {
                if !local.contains_key(&w) {
                    local.insert(w, order.len());
                    order.push(w);
                    next.push(w);
                }
            }
        }
        frontier = next;
    }
    let size = 3 * order.len();
    let mut sub = DMatrix::zeros(size, size);
    for (lv, &v) in order.iter().enumerate() {
        for c in 0..3 {
            let col = 3 * v + c;
            for p in laplacian.col_ptr[col] as usize..laplacian.col_ptr[col + 1] as usize {
                let row = laplacian.row_idx[p] as usize;
                if let Some(&lu) = local.get(&(row / 3)) {
                    let (r, cc) = (3 * lu + row % 3, 3 * lv + c);
                    sub[(r, cc)] = laplacian.values[p];
                    sub[(cc, r)] = laplacian.values[p];
                }
            }
        }
    }
    let inverse = sub
        .cholesky()
        .expect("a principal sub-matrix of a positive definite A is positive definite")
        .inverse();
    let m = 3 * distinct_visible;
    inverse.view((0, 0), (m, m)).into_owned()
}
