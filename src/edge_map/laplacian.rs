//! The map optimisation's normal equations `A L = B` (paper eq. 47-57),
//! assembled as a sparse block Laplacian.
//!
//! Minimising the edge inconsistency `Σ_ij (L_j - L_i - ŷ_ij)^T S_ij
//! (L_j - L_i - ŷ_ij)` over the landmark positions `L` gives, per edge,
//! `A_ii += S`, `A_jj += S`, `A_ij = A_ji -= S`, `B_i -= S ŷ`, `B_j += S ŷ`:
//! a block Laplacian whose null space is the common translation (nullity 3).
//! Fixing the reference landmark at the origin drops its block row and
//! column and makes A positive definite on a connected graph.
//!
//! Storage: the upper triangle in compressed sparse columns (CSC) with
//! `u32` indices, as faer's sparse Cholesky reads it, plus the node-level
//! pattern (one entry per 3x3 block) used for the fill-reducing ordering.

use nalgebra::{DMatrix, DVector};

use super::problem::MapProblem;

/// `A` (upper triangle, CSC, reference removed) and `B` (eq. 57).
#[derive(Clone, Debug)]
pub struct BlockLaplacian {
    /// Number of unknown landmarks (all but the reference).
    pub node_count: usize,
    /// Node-level upper pattern: column `v` lists the nodes `u <= v` with a
    /// block `A_uv`, sorted, the diagonal last. Column `v` spans
    /// `node_row_idx[node_col_ptr[v]..node_col_ptr[v + 1]]`
    /// (`node_count + 1` entries).
    pub node_col_ptr: Vec<u32>,
    /// Node (unknown landmark) index of each block in the node pattern,
    /// column by column as `node_col_ptr` delimits them.
    pub node_row_idx: Vec<u32>,
    /// Scalar upper CSC of `A`, dimension `3 * node_count`: column `c`
    /// spans `row_idx[col_ptr[c]..col_ptr[c + 1]]` and the same range of
    /// `values` (`3 * node_count + 1` entries).
    pub col_ptr: Vec<u32>,
    /// Scalar row of each stored entry of `A`, ascending within a column,
    /// never below the diagonal.
    pub row_idx: Vec<u32>,
    /// Stored entries of `A` (sums of edge information matrices), m^-2,
    /// parallel to `row_idx`.
    pub values: Vec<f64>,
    /// Right-hand side `B`, m^-1.
    pub rhs: Vec<f64>,
}

impl BlockLaplacian {
    /// Assembles A and B from the fused edges (eq. 54-57). Edges listed more
    /// than once add up. Cost: O(edges log degree).
    pub fn assemble(problem: &MapProblem) -> Self {
        let n = (problem.landmark_count as usize).saturating_sub(1);
        // Node pattern: count, fill, sort and deduplicate each column.
        let mut count = vec![1u32; n];
        let pairs = unknown_pairs(problem);
        for &(_, v) in pairs.iter().flatten() {
            count[v as usize] += 1;
        }
        let mut raw_ptr = vec![0u32; n + 1];
        for v in 0..n {
            raw_ptr[v + 1] = raw_ptr[v] + count[v];
        }
        let mut raw_rows = vec![0u32; raw_ptr[n] as usize];
        let mut fill = raw_ptr.clone();
        for &(u, v) in pairs.iter().flatten() {
            raw_rows[fill[v as usize] as usize] = u;
            fill[v as usize] += 1;
        }
        let mut node_col_ptr = vec![0u32; n + 1];
        let mut node_row_idx = Vec::with_capacity(raw_rows.len());
        for v in 0..n {
            let column = &mut raw_rows[raw_ptr[v] as usize..raw_ptr[v + 1] as usize];
            // The last slot was left for the diagonal.
            let last = column.len() - 1;
            column[last] = v as u32;
            column.sort_unstable();
            let start = node_row_idx.len();
            for &u in column.iter() {
                if node_row_idx.len() == start || *node_row_idx.last().expect("non-empty") != u {
                    node_row_idx.push(u);
                }
            }
            node_col_ptr[v + 1] = node_row_idx.len() as u32;
        }
        drop(raw_rows);

        // Scalar pattern: node column v with k blocks gives scalar columns
        // 3v + c with 3 (k - 1) off-diagonal rows and c + 1 diagonal rows.
        let dim = 3 * n;
        let mut col_ptr = vec![0u32; dim + 1];
        for v in 0..n {
            let k = node_col_ptr[v + 1] - node_col_ptr[v];
            for c in 0..3u32 {
                col_ptr[3 * v + c as usize + 1] = col_ptr[3 * v + c as usize] + 3 * (k - 1) + c + 1;
            }
        }
        let mut row_idx = vec![0u32; col_ptr[dim] as usize];
        for v in 0..n {
            let blocks = &node_row_idx[node_col_ptr[v] as usize..node_col_ptr[v + 1] as usize];
            for c in 0..3usize {
                let mut p = col_ptr[3 * v + c] as usize;
                for &u in blocks {
                    let rows = if u as usize == v { c + 1 } else { 3 };
                    for r in 0..rows {
                        row_idx[p] = 3 * u + r as u32;
                        p += 1;
                    }
                }
            }
        }

        let mut this = Self {
            node_count: n,
            node_col_ptr,
            node_row_idx,
            col_ptr,
            row_idx,
            values: Vec::new(),
            rhs: Vec::new(),
        };
        this.fill_values(problem, &pairs);
        this
    }

    /// Recomputes `A` and `B` in place for `problem`, whose edges join the
    /// same landmark pairs as those this was assembled from: only their
    /// information matrices or measurements changed (robust reweighting).
    /// The pattern is kept: nothing is counted, sorted or allocated, and
    /// the result equals a fresh [`Self::assemble`] bit for bit.
    pub fn refill(&mut self, problem: &MapProblem) {
        debug_assert_eq!(
            self.node_count,
            (problem.landmark_count as usize).saturating_sub(1),
            "refill with another problem's landmarks"
        );
        let pairs = unknown_pairs(problem);
        self.fill_values(problem, &pairs);
    }

    /// Slot of block `(u, v)`, `u < v`, among the blocks of node column
    /// `v`: entry `(r, c)` of the block is at
    /// `values[col_ptr[3 v + c] + 3 slot + r]`.
    fn slot(&self, u: u32, v: u32) -> usize {
        let blocks = &self.node_row_idx
            [self.node_col_ptr[v as usize] as usize..self.node_col_ptr[v as usize + 1] as usize];
        blocks
            .binary_search(&u)
            .expect("block in the assembled pattern")
    }

    fn fill_values(&mut self, problem: &MapProblem, pairs: &[Option<(u32, u32)>]) {
        self.values.clear();
        self.values.resize(self.row_idx.len(), 0.0);
        self.rhs.clear();
        self.rhs.resize(3 * self.node_count, 0.0);
        for (e, pair) in problem.edges.iter().zip(pairs) {
            let s = &e.info;
            let sy = s * e.y_m;
            for end in [(e.i, -1.0), (e.j, 1.0)] {
                if let Some(u) = problem.unknown_of(end.0) {
                    for r in 0..3 {
                        self.rhs[3 * u + r] += end.1 * sy[r];
                    }
                    // Diagonal block, upper triangle.
                    for c in 0..3 {
                        let diag_start = self.col_ptr[3 * u + c + 1] as usize - (c + 1);
                        for r in 0..=c {
                            self.values[diag_start + r] += s[(r, c)];
                        }
                    }
                }
            }
            if let Some((u, v)) = *pair {
                if u == v {
                    continue;
                }
                let slot = self.slot(u, v);
                for c in 0..3 {
                    let start = self.col_ptr[3 * v as usize + c] as usize + 3 * slot;
                    for r in 0..3 {
                        self.values[start + r] -= s[(r, c)];
                    }
                }
            }
        }
    }

    /// Dimension of A: 3 per unknown landmark.
    pub fn dim(&self) -> usize {
        3 * self.node_count
    }

    /// Whether `other` has exactly this sparsity pattern (then a symbolic
    /// factorisation of one serves the other).
    pub fn same_pattern(&self, other: &BlockLaplacian) -> bool {
        self.col_ptr == other.col_ptr && self.row_idx == other.row_idx
    }

    /// `y = A x` from the upper triangle (symmetric product).
    pub fn mul(&self, x: &[f64], y: &mut [f64]) {
        y.iter_mut().for_each(|v| *v = 0.0);
        for col in 0..self.dim() {
            let (start, end) = (self.col_ptr[col] as usize, self.col_ptr[col + 1] as usize);
            let xc = x[col];
            let mut acc = 0.0;
            for p in start..end {
                let row = self.row_idx[p] as usize;
                let a = self.values[p];
                y[row] += a * xc;
                if row != col {
                    acc += a * x[row];
                }
            }
            y[col] += acc;
        }
    }

    /// The 3x3 diagonal block of unknown `u`.
    pub fn diagonal_block(&self, u: usize) -> nalgebra::Matrix3<f64> {
        let mut m = nalgebra::Matrix3::zeros();
        for c in 0..3 {
            let diag_start = self.col_ptr[3 * u + c + 1] as usize - (c + 1);
            for r in 0..=c {
                m[(r, c)] = self.values[diag_start + r];
                m[(c, r)] = self.values[diag_start + r];
            }
        }
        m
    }

    /// A as a dense symmetric matrix (tests and small problems).
    pub fn to_dense(&self) -> DMatrix<f64> {
        let dim = self.dim();
        let mut a = DMatrix::zeros(dim, dim);
        for col in 0..dim {
            for p in self.col_ptr[col] as usize..self.col_ptr[col + 1] as usize {
                let row = self.row_idx[p] as usize;
                a[(row, col)] = self.values[p];
                a[(col, row)] = self.values[p];
            }
        }
        a
    }
}

/// The unknowns each edge joins, smaller first (None where an end is the
/// reference).
fn unknown_pairs(problem: &MapProblem) -> Vec<Option<(u32, u32)>> {
    problem
        .edges
        .iter()
        .map(|e| {
            let (a, b) = (problem.unknown_of(e.i)?, problem.unknown_of(e.j)?);
            Some(((a.min(b)) as u32, (a.max(b)) as u32))
        })
        .collect()
}

/// The full block Laplacian of all landmarks, no reference removed, dense:
/// written straight from the per-edge rule as an independent reference for
/// the sparse assembly, and to show its nullity of 3.
pub fn dense_full_laplacian(problem: &MapProblem) -> (DMatrix<f64>, DVector<f64>) {
    let dim = 3 * problem.landmark_count as usize;
    let mut a = DMatrix::zeros(dim, dim);
    let mut b = DVector::zeros(dim);
    for e in &problem.edges {
        let (i, j) = (3 * e.i as usize, 3 * e.j as usize);
        let sy = e.info * e.y_m;
        for r in 0..3 {
            b[i + r] -= sy[r];
            b[j + r] += sy[r];
            for c in 0..3 {
                a[(i + r, i + c)] += e.info[(r, c)];
                a[(j + r, j + c)] += e.info[(r, c)];
                a[(i + r, j + c)] -= e.info[(r, c)];
                a[(j + r, i + c)] -= e.info[(r, c)];
            }
        }
    }
    (a, b)
}
