//! Solving `A L = B` (paper eq. 57): faer's sparse Cholesky with the
//! symbolic factorisation kept while the sparsity pattern is unchanged, and
//! a warm-started block-Jacobi preconditioned conjugate gradient for maps
//! too large to factor every few frames.
//!
//! The fill-reducing ordering is computed on the landmark graph (one node
//! per 3x3 block, AMD) and expanded to the three coordinates of each
//! landmark: nine times fewer entries to order than the scalar matrix, and
//! every landmark's coordinates stay together, which gives the supernodal
//! factorisation dense 3-column blocks at least.

use std::sync::Arc;
use std::time::Instant;

use faer::dyn_stack::{MemBuffer, MemStack};
use faer::linalg::solvers::LltError;
use faer::sparse::linalg::amd;
use faer::sparse::linalg::cholesky::{
    factorize_symbolic_cholesky, CholeskySymbolicParams, LltRef, SymbolicCholesky,
    SymmetricOrdering,
};
use faer::sparse::{SparseColMatRef, SymbolicSparseColMatRef};
use faer::{Conj, MatMut, Par, Side};
use nalgebra::{Matrix3, Vector3};

use super::laplacian::BlockLaplacian;
use super::problem::MapProblem;
use super::EdgeMapError;

/// How `A L = B` is solved.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum SolverChoice {
    /// Sparse Cholesky every time.
    Cholesky,
    /// Preconditioned CG, warm-started from the last solution.
    ConjugateGradient,
    /// Cholesky up to `cg_above_landmarks` landmarks, CG above once a
    /// previous solution exists to start from.
    Auto {
        /// Landmark count (reference included) above which CG is used.
        cg_above_landmarks: usize,
    },
}

/// Conjugate-gradient stopping rule.
#[derive(Clone, Copy, Debug)]
pub struct CgOptions {
    /// Stop when `|B - A L| <= rel_tol |B|`.
    pub rel_tol: f64,
    /// Iterations allowed before the solve fails with
    /// [`EdgeMapError::Solver`].
    pub max_iterations: usize,
}

impl Default for CgOptions {
    fn default() -> Self {
        Self {
            rel_tol: 1e-10,
            max_iterations: 10_000,
        }
    }
}

/// What one solve did and how long each part took.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct SolveReport {
    /// Connectivity check and assembly of `A` and `B`, ms.
    pub assemble_ms: f64,
    /// Ordering + symbolic analysis; 0 when the cached one was reused.
    pub symbolic_ms: f64,
    /// Fill-reducing ordering of the landmark graph (part of `symbolic_ms`).
    pub order_ms: f64,
    /// Symbolic (when done) + numeric factorisation.
    pub factor_ms: f64,
    /// Triangular solves with the factor, or the whole CG run, ms.
    pub solve_ms: f64,
    /// Robust reweighting: the edges' weights and the refill of `A` and
    /// `B` for each reweighted solve, ms (map worker only; their
    /// factorisations count in `factor_ms`).
    pub reweight_ms: f64,
    /// Covariance blocks asked for with the solve (map worker only).
    pub covariance_ms: f64,
    /// Wall time of the whole solve, ms.
    pub total_ms: f64,
    /// CPU time of the whole solve, ms (map worker only): below
    /// `total_ms` when the solving thread shared its core.
    pub cpu_ms: f64,
    /// Whether the cached symbolic factorisation was reused whole because
    /// the pattern was unchanged (false for CG).
    pub symbolic_reused: bool,
    /// `"cholesky"` or `"pcg"`.
    pub method: &'static str,
    /// CG only.
    pub cg_iterations: usize,
    /// Entries of the Cholesky factor (0 for CG).
    pub factor_nnz: usize,
    /// Robust reweighting: solves after the first (0 without it).
    pub robust_iterations: usize,
    /// Robust reweighting: edges whose weight was below 1 at the last
    /// reweighting (0 without it).
    pub downweighted_edges: usize,
}

/// A Cholesky factor of A with its symbolic part.
pub struct CholeskyFactor {
    symbolic: Arc<SymbolicCholesky<u32>>,
    values: Vec<f64>,
    par: Par,
}

impl CholeskyFactor {
    /// Solves `A X = R` in place for every column of `rhs` (column-major,
    /// `dim` rows).
    pub fn solve_in_place(&self, rhs: &mut [f64], columns: usize) {
        let dim = self.symbolic.nrows();
        if dim == 0 {
            return;
        }
        let mut buffer = MemBuffer::new(
            self.symbolic
                .solve_in_place_scratch::<f64>(columns, self.par),
        );
        let rhs = MatMut::from_column_major_slice_mut(rhs, dim, columns);
        LltRef::new(&self.symbolic, &self.values).solve_in_place_with_conj(
            Conj::No,
            rhs,
            self.par,
            MemStack::new(&mut buffer),
        );
    }

    /// Stored values of the factor (faer's supernodal or simplicial
    /// layout): the fill measure reported as [`SolveReport::factor_nnz`].
    pub fn nnz(&self) -> usize {
        self.values.len()
    }

    pub(super) fn symbolic(&self) -> &SymbolicCholesky<u32> {
        &self.symbolic
    }

    pub(super) fn values(&self) -> &[f64] {
        &self.values
    }

    pub(super) fn par(&self) -> Par {
        self.par
    }
}

/// Keeps what can be reused between map solves: the symbolic factorisation
/// (while the pattern is unchanged) and the last solution (CG warm start).
pub struct EdgeMapSolver {
    /// Cholesky, conjugate gradient, or chosen by map size.
    pub choice: SolverChoice,
    /// Stopping rule of the conjugate-gradient solves.
    pub cg: CgOptions,
    par: Par,
    cached: Option<PatternSymbolic>,
    last_solution: Vec<f64>,
    factor: Option<CholeskyFactor>,
}

impl EdgeMapSolver {
    /// `threads`: 1 runs sequentially, more uses faer's rayon parallelism.
    pub fn new(choice: SolverChoice, threads: usize) -> Self {
        Self {
            choice,
            cg: CgOptions::default(),
            par: if threads <= 1 {
                Par::Seq
            } else {
                Par::rayon(threads)
            },
            cached: None,
            last_solution: Vec::new(),
            factor: None,
        }
    }

    /// The factor of the last Cholesky solve (for covariances, eq. 59).
    pub fn factor(&self) -> Option<&CholeskyFactor> {
        self.factor.as_ref()
    }

    /// Solves the map problem: landmark positions by id, the reference at
    /// the origin. Checks connectivity first (a disconnected graph leaves
    /// A singular).
    pub fn solve(
        &mut self,
        problem: &MapProblem,
    ) -> Result<(Vec<Vector3<f64>>, SolveReport), EdgeMapError> {
        let start = Instant::now();
        check_connected(problem)?;
        let laplacian = BlockLaplacian::assemble(problem);
        let mut report = SolveReport {
            assemble_ms: ms_since(start),
            ..Default::default()
        };
        let x = self.solve_laplacian(&laplacian, &mut report)?;
        report.total_ms = ms_since(start);
        let mut positions = vec![Vector3::zeros(); problem.landmark_count as usize];
        for (u, chunk) in x.chunks_exact(3).enumerate() {
            positions[problem.id_of(u) as usize] = Vector3::new(chunk[0], chunk[1], chunk[2]);
        }
        Ok((positions, report))
    }

    /// Solves an assembled system; fills the factor/solve parts of `report`.
    pub fn solve_laplacian(
        &mut self,
        laplacian: &BlockLaplacian,
        report: &mut SolveReport,
    ) -> Result<Vec<f64>, EdgeMapError> {
        let use_cg = match self.choice {
            SolverChoice::Cholesky => false,
            SolverChoice::ConjugateGradient => true,
            SolverChoice::Auto { cg_above_landmarks } => {
                laplacian.node_count + 1 > cg_above_landmarks
                    && self.last_solution.len() == laplacian.dim()
            }
        };
        if use_cg {
            let t = Instant::now();
            let mut x = if self.last_solution.len() == laplacian.dim() {
                std::mem::take(&mut self.last_solution)
            } else {
                vec![0.0; laplacian.dim()]
            };
            let iterations = solve_pcg(laplacian, &mut x, &self.cg)?;
            report.solve_ms = ms_since(t);
            report.cg_iterations = iterations;
            report.method = "pcg";
            self.factor = None;
            self.last_solution = x.clone();
            return Ok(x);
        }
        let t = Instant::now();
        let factor = self.factorize(laplacian, report)?;
        report.factor_ms = ms_since(t);
        let x = cholesky_solution(&factor, laplacian, report);
        self.factor = Some(factor);
        self.last_solution = x.clone();
        Ok(x)
    }

    /// Cholesky factor of A, reusing the symbolic factorisation when the
    /// pattern matches the cached one.
    pub fn factorize(
        &mut self,
        laplacian: &BlockLaplacian,
        report: &mut SolveReport,
    ) -> Result<CholeskyFactor, EdgeMapError> {
        let reuse = matches!(&self.cached, Some(cached) if cached.fits(laplacian));
        report.symbolic_reused = reuse;
        let cached = match self.cached.take() {
            Some(cached) if reuse => cached,
            _ => {
                let t = Instant::now();
                let (fwd, inv) = block_amd_ordering(laplacian)?;
                report.order_ms = ms_since(t);
                let symbolic = PatternSymbolic::analyse(laplacian, &fwd, &inv)?;
                report.symbolic_ms = ms_since(t);
                symbolic
            }
        };
        let factor = cached.numeric(laplacian, self.par);
        self.cached = Some(cached);
        factor
    }
}

/// A symbolic Cholesky factorisation and the sparsity pattern it was
/// computed for: while a new Laplacian has the same pattern, only the
/// numeric factorisation is redone.
pub struct PatternSymbolic {
    col_ptr: Vec<u32>,
    row_idx: Vec<u32>,
    symbolic: Arc<SymbolicCholesky<u32>>,
}

impl PatternSymbolic {
    /// Symbolic factorisation of `laplacian`'s upper triangle eliminated in
    /// the order `fwd` (scalar indices; `inv` its inverse permutation).
    pub fn analyse(
        laplacian: &BlockLaplacian,
        fwd: &[u32],
        inv: &[u32],
    ) -> Result<Self, EdgeMapError> {
        let dim = laplacian.dim();
        let perm = faer::perm::PermRef::new_checked(fwd, inv, dim);
        let symbolic = factorize_symbolic_cholesky(
            upper_pattern(laplacian),
            Side::Upper,
            SymmetricOrdering::Custom(perm),
            CholeskySymbolicParams::default(),
        )
        .map_err(|e| EdgeMapError::Solver(format!("symbolic factorisation: {e:?}")))?;
        Ok(Self {
            col_ptr: laplacian.col_ptr.clone(),
            row_idx: laplacian.row_idx.clone(),
            symbolic: Arc::new(symbolic),
        })
    }

    /// Whether `laplacian` has the pattern this was computed for.
    pub fn fits(&self, laplacian: &BlockLaplacian) -> bool {
        self.col_ptr == laplacian.col_ptr && self.row_idx == laplacian.row_idx
    }

    /// Numeric factorisation of `laplacian` (whose pattern [`Self::fits`]).
    pub fn numeric(
        &self,
        laplacian: &BlockLaplacian,
        par: Par,
    ) -> Result<CholeskyFactor, EdgeMapError> {
        CholeskyFactor::numeric(Arc::clone(&self.symbolic), laplacian, par)
    }
}

/// The sparsity pattern of the Laplacian's stored (upper) triangle.
fn upper_pattern(laplacian: &BlockLaplacian) -> SymbolicSparseColMatRef<'_, u32> {
    let dim = laplacian.dim();
    SymbolicSparseColMatRef::new_checked(dim, dim, &laplacian.col_ptr, None, &laplacian.row_idx)
}

/// `A^-1 B` by the factor of A; fills the factor size, the solve time and
/// the method of `report`.
pub fn cholesky_solution(
    factor: &CholeskyFactor,
    laplacian: &BlockLaplacian,
    report: &mut SolveReport,
) -> Vec<f64> {
    report.factor_nnz = factor.nnz();
    let t = Instant::now();
    let mut x = laplacian.rhs.clone();
    factor.solve_in_place(&mut x, 1);
    report.solve_ms = ms_since(t);
    report.method = "cholesky";
    x
}

impl CholeskyFactor {
    /// Numeric factorisation of `laplacian` on a symbolic factorisation of
    /// its pattern (computed here or elsewhere, e.g. with a reused
    /// ordering).
    pub fn numeric(
        symbolic: Arc<SymbolicCholesky<u32>>,
        laplacian: &BlockLaplacian,
        par: Par,
    ) -> Result<Self, EdgeMapError> {
        let mut values = vec![0.0; symbolic.len_val()];
        let matrix = SparseColMatRef::new(upper_pattern(laplacian), &laplacian.values);
        let mut buffer =
            MemBuffer::new(symbolic.factorize_numeric_llt_scratch::<f64>(par, Default::default()));
        symbolic
            .factorize_numeric_llt(
                &mut values,
                matrix,
                Side::Upper,
                Default::default(),
                par,
                MemStack::new(&mut buffer),
                Default::default(),
            )
            .map_err(|_: LltError| EdgeMapError::NotPositiveDefinite)?;
        Ok(CholeskyFactor {
            symbolic,
            values,
            par,
        })
    }
}

fn ms_since(t: Instant) -> f64 {
    t.elapsed().as_secs_f64() * 1e3
}

/// AMD on the landmark graph, expanded to the three coordinates of each
/// landmark. Returns (forward, inverse) scalar permutations.
pub(crate) fn block_amd_ordering(
    laplacian: &BlockLaplacian,
) -> Result<(Vec<u32>, Vec<u32>), EdgeMapError> {
    let n = laplacian.node_count;
    let mut node_fwd = vec![0u32; n];
    let mut node_inv = vec![0u32; n];
    let pattern = SymbolicSparseColMatRef::new_checked(
        n,
        n,
        &laplacian.node_col_ptr,
        None,
        &laplacian.node_row_idx,
    );
    let mut buffer = MemBuffer::new(amd::order_scratch::<u32>(n, laplacian.node_row_idx.len()));
    amd::order(
        &mut node_fwd,
        &mut node_inv,
        pattern,
        amd::Control::default(),
        MemStack::new(&mut buffer),
    )
    .map_err(|e| EdgeMapError::Solver(format!("AMD ordering: {e:?}")))?;
    let mut fwd = vec![0u32; 3 * n];
    let mut inv = vec![0u32; 3 * n];
    for k in 0..n {
        for c in 0..3u32 {
            fwd[3 * k + c as usize] = 3 * node_fwd[k] + c;
            inv[3 * node_fwd[k] as usize + c as usize] = 3 * k as u32 + c;
        }
    }
    Ok((fwd, inv))
}

/// Fails with the components that cannot be placed when the edge graph is
/// not connected (A would be singular).
pub fn check_connected(problem: &MapProblem) -> Result<(), EdgeMapError> {
    let components = problem.components();
    if components.len() <= 1 {
        return Ok(());
    }
    Err(EdgeMapError::Disconnected {
        reference: problem.reference,
        unplaced: components[1..].to_vec(),
    })
}

/// Block-Jacobi preconditioned conjugate gradient on `A x = B`, starting
/// from `x` (warm start). Returns the number of iterations.
pub fn solve_pcg(
    laplacian: &BlockLaplacian,
    x: &mut [f64],
    options: &CgOptions,
) -> Result<usize, EdgeMapError> {
    let dim = laplacian.dim();
    let n = laplacian.node_count;
    let mut precond = Vec::with_capacity(n);
    for u in 0..n {
        let block: Matrix3<f64> = laplacian.diagonal_block(u);
        precond.push(
            block
                .try_inverse()
                .ok_or(EdgeMapError::NotPositiveDefinite)?,
        );
    }
    let apply_precond = |r: &[f64], z: &mut [f64]| {
        for u in 0..n {
            let v = precond[u] * Vector3::new(r[3 * u], r[3 * u + 1], r[3 * u + 2]);
            z[3 * u..3 * u + 3].copy_from_slice(v.as_slice());
        }
    };
    let b_norm = laplacian.rhs.iter().map(|v| v * v).sum::<f64>().sqrt();
    let tol = options.rel_tol * b_norm.max(f64::MIN_POSITIVE);
    let mut r = vec![0.0; dim];
    laplacian.mul(x, &mut r);
    for k in 0..dim {
        r[k] = laplacian.rhs[k] - r[k];
    }
    let mut z = vec![0.0; dim];
    apply_precond(&r, &mut z);
    let mut p = z.clone();
    let mut rz: f64 = r.iter().zip(&z).map(|(a, b)| a * b).sum();
    let mut q = vec![0.0; dim];
    for iteration in 0..options.max_iterations {
        let r_norm = r.iter().map(|v| v * v).sum::<f64>().sqrt();
        if r_norm <= tol {
            return Ok(iteration);
        }
        laplacian.mul(&p, &mut q);
        let pq: f64 = p.iter().zip(&q).map(|(a, b)| a * b).sum();
        if pq <= 0.0 {
            return Err(EdgeMapError::NotPositiveDefinite);
        }
        let alpha = rz / pq;
        for k in 0..dim {
            x[k] += alpha * p[k];
            r[k] -= alpha * q[k];
        }
        apply_precond(&r, &mut z);
        let rz_next: f64 = r.iter().zip(&z).map(|(a, b)| a * b).sum();
        let beta = rz_next / rz;
        rz = rz_next;
        for k in 0..dim {
            p[k] = z[k] + beta * p[k];
        }
    }
    Err(EdgeMapError::Solver(format!(
        "conjugate gradient did not reach relative residual {} in {} iterations",
        options.rel_tol, options.max_iterations
    )))
}
