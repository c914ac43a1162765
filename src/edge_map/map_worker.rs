//! The map solve of the absolute stage, packaged to run off the frame-rate
//! path: a [`MapSolveRequest`] (a snapshot of the fused edges and the last
//! solution) goes to a [`MapSolveWorker`], which may live on another
//! thread, and a [`SolvedMap`] comes back.
//!
//! The worker keeps what carries over between solves: the symbolic
//! Cholesky factorisation (reused by [`EdgeMapSolver`] while the sparsity
//! pattern is unchanged) and, for very large maps, the conjugate-gradient
//! warm start: the last solution, extended to landmarks added since by
//! chaining their fused edges from already placed neighbours.

use std::collections::VecDeque;
use std::time::Instant;

use nalgebra::Vector3;

use super::laplacian::BlockLaplacian;
use super::problem::MapProblem;
use super::solve::{
    check_connected, solve_pcg, CgOptions, CholeskyFactor, EdgeMapSolver, SolveReport, SolverChoice,
};
use super::EdgeMapError;

/// A snapshot of the map to solve.
#[derive(Clone, Debug)]
pub struct MapSolveRequest {
    /// Increases with every request of a stage.
    pub version: u64,
    /// Landmarks by map id, the reference fixed at the origin.
    pub problem: MapProblem,
    /// The previous solution by map id (relative to the reference), for
    /// the conjugate-gradient warm start.
    pub previous_m: Vec<Option<Vector3<f64>>>,
}

/// A solved map: landmark positions relative to the reference, and what
/// the position filter needs for their covariances (eq. 59).
pub struct SolvedMap {
    pub version: u64,
    /// Position of each map id relative to the reference, m; None for a
    /// landmark outside the reference's connected component.
    pub positions_m: Vec<Option<Vector3<f64>>>,
    /// The solved problem (the reference's component, renumbered).
    pub problem: MapProblem,
    /// Id in `problem` of each map id.
    pub local_id: Vec<Option<u32>>,
    /// `A` of `problem`.
    pub laplacian: BlockLaplacian,
    /// Cholesky factor of `A` (None after a conjugate-gradient solve).
    pub factor: Option<CholeskyFactor>,
    pub report: SolveReport,
    /// Iterations a cold start (from zero) needed on the same system, when
    /// the worker was asked to measure it.
    pub cold_cg_iterations: Option<usize>,
}

impl SolvedMap {
    /// Row block of map id `id` in `A` (None for the reference and for
    /// landmarks not in the solved map).
    pub fn unknown_of(&self, id: u32) -> Option<usize> {
        let local = (*self.local_id.get(id as usize)?)?;
        self.problem.unknown_of(local)
    }
}

/// Solves map requests; keeps the symbolic factorisation between them.
pub struct MapSolveWorker {
    solver: EdgeMapSolver,
    pub choice: SolverChoice,
    pub cg: CgOptions,
    /// Also run every CG solve from a cold start (zero) and report its
    /// iterations (measurement only; doubles the CG cost).
    pub measure_cold_start: bool,
}

impl MapSolveWorker {
    pub fn new(choice: SolverChoice, threads: usize) -> Self {
        Self {
            solver: EdgeMapSolver::new(SolverChoice::Cholesky, threads),
            choice,
            cg: CgOptions::default(),
            measure_cold_start: false,
        }
    }

    /// Solves one request: the reference's connected component (landmarks
    /// that no edge joins to it yet are left out), by sparse Cholesky or,
    /// for large maps, by PCG warm-started from the previous solution.
    pub fn solve(&mut self, request: MapSolveRequest) -> Result<SolvedMap, EdgeMapError> {
        let start = Instant::now();
        let MapSolveRequest {
            version,
            problem: full,
            previous_m,
        } = request;
        let (problem, kept) = if full.components().len() > 1 {
            full.reference_component()
        } else {
            let kept = (0..full.landmark_count).collect();
            (full, kept)
        };
        check_connected(&problem)?;
        let laplacian = BlockLaplacian::assemble(&problem);
        let mut report = SolveReport {
            assemble_ms: ms_since(start),
            ..Default::default()
        };
        let has_previous = previous_m.iter().any(Option::is_some);
        let use_cg = match self.choice {
            SolverChoice::Cholesky => false,
            SolverChoice::ConjugateGradient => true,
            SolverChoice::Auto { cg_above_landmarks } => {
                problem.landmark_count as usize > cg_above_landmarks && has_previous
            }
        };
        let mut cold_cg_iterations = None;
        let (x, factor) = if use_cg {
            let mut x = warm_start(&problem, &kept, &previous_m);
            if self.measure_cold_start {
                let mut cold = vec![0.0; laplacian.dim()];
                cold_cg_iterations = Some(solve_pcg(&laplacian, &mut cold, &self.cg)?);
            }
            let t = Instant::now();
            report.cg_iterations = solve_pcg(&laplacian, &mut x, &self.cg)?;
            report.solve_ms = ms_since(t);
            report.method = "pcg";
            (x, None)
        } else {
            let t = Instant::now();
            let factor = self.solver.factorize(&laplacian, &mut report)?;
            report.factor_ms = ms_since(t);
            report.factor_nnz = factor.nnz();
            let t = Instant::now();
            let mut x = laplacian.rhs.clone();
            factor.solve_in_place(&mut x, 1);
            report.solve_ms = ms_since(t);
            report.method = "cholesky";
            (x, Some(factor))
        };
        let mut positions_m = vec![None; kept.iter().map(|&k| k as usize + 1).max().unwrap_or(0)];
        let mut local_id = vec![None; positions_m.len()];
        for (local, &id) in kept.iter().enumerate() {
            local_id[id as usize] = Some(local as u32);
            positions_m[id as usize] = Some(match problem.unknown_of(local as u32) {
                Some(u) => Vector3::new(x[3 * u], x[3 * u + 1], x[3 * u + 2]),
                None => Vector3::zeros(),
            });
        }
        report.total_ms = ms_since(start);
        Ok(SolvedMap {
            version,
            positions_m,
            problem,
            local_id,
            laplacian,
            factor,
            report,
            cold_cg_iterations,
        })
    }
}

/// The CG starting point: the previous solution where there is one; a
/// landmark added since is placed from an already placed neighbour through
/// their fused edge (breadth first), or at the origin if none is reachable.
fn warm_start(problem: &MapProblem, kept: &[u32], previous_m: &[Option<Vector3<f64>>]) -> Vec<f64> {
    let n = problem.landmark_count as usize;
    let mut placed: Vec<Option<Vector3<f64>>> = kept
        .iter()
        .map(|&id| previous_m.get(id as usize).copied().flatten())
        .collect();
    placed[problem.reference as usize] = Some(Vector3::zeros());
    let mut adjacency: Vec<Vec<(u32, Vector3<f64>)>> = vec![Vec::new(); n];
    for e in &problem.edges {
        adjacency[e.i as usize].push((e.j, e.y_m));
        adjacency[e.j as usize].push((e.i, -e.y_m));
    }
    let mut queue: VecDeque<u32> = (0..n as u32)
        .filter(|&k| placed[k as usize].is_some())
        .collect();
    while let Some(k) = queue.pop_front() {
        let base = placed[k as usize].expect("queued landmarks are placed");
        for &(other, y) in &adjacency[k as usize] {
            if placed[other as usize].is_none() {
                placed[other as usize] = Some(base + y);
                queue.push_back(other);
            }
        }
    }
    let mut x = vec![0.0; 3 * (n - 1)];
    for (local, p) in placed.iter().enumerate() {
        if let (Some(u), Some(p)) = (problem.unknown_of(local as u32), p) {
            x[3 * u..3 * u + 3].copy_from_slice(p.as_slice());
        }
    }
    x
}

fn ms_since(t: Instant) -> f64 {
    t.elapsed().as_secs_f64() * 1e3
}
