//! The map solve of the absolute stage, packaged to run off the frame-rate
//! path: a [`MapSolveRequest`] (a snapshot of the fused edges and the last
//! solution) goes to a [`MapSolveWorker`], which may live on another
//! thread, and a [`SolvedMap`] comes back.
//!
//! The worker keeps what carries over between solves: the fill-reducing
//! ordering and the symbolic Cholesky factorisation
//! ([`IncrementalSymbolic`]: the symbolic part is reused whole while the
//! sparsity pattern is unchanged, as in [`crate::edge_map::EdgeMapSolver`], and the
//! ordering is reused with new landmarks appended when it changes). For
//! very large maps it solves by conjugate gradient instead, warm-started
//! from the previous solution the request carries, extended to landmarks
//! added since by chaining their fused edges from already placed
//! neighbours.

use std::collections::VecDeque;
use std::time::Instant;

use nalgebra::Vector3;

use crate::edge_map::laplacian::BlockLaplacian;
use crate::edge_map::ordering_reuse::{IncrementalSymbolic, OrderingReuse, SymbolicPath};
use crate::edge_map::problem::{MapEdge, MapProblem};
use crate::edge_map::solve::{
    cholesky_solution, solve_pcg, CgOptions, CholeskyFactor, SolveReport, SolverChoice,
};
use crate::edge_map::EdgeMapError;

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
    /// Map ids whose joint covariance `Σ_L(V, V)` (eq. 59) the worker
    /// computes from the factor right after the solve, so that the frames
    /// that use the map read it instead of solving for it: the landmarks in
    /// view when the solve was asked for.
    pub covariance_of: Vec<u32>,
}

/// The joint covariance of some landmarks of a solved map.
#[derive(Clone, Debug, Default)]
pub struct CovarianceBlocks {
    /// Row/column block of each map id in `matrix`.
    pub slot: std::collections::HashMap<u32, usize>,
    /// `Σ_L(V, V)`, m^2, 3 rows and columns per landmark (world-frame
    /// axes; zero for the reference).
    pub matrix: nalgebra::DMatrix<f64>,
}

impl CovarianceBlocks {
    /// The joint covariance of `ids` (3 rows and columns per id, in the
    /// order given), m^2; `None` if one of them has no slot.
    pub fn select(&self, ids: &[u32]) -> Option<nalgebra::DMatrix<f64>> {
        let slots: Option<Vec<usize>> = ids.iter().map(|id| self.slot.get(id).copied()).collect();
        let slots = slots?;
        let m = ids.len();
        Some(nalgebra::DMatrix::from_fn(3 * m, 3 * m, |r, c| {
            self.matrix[(3 * slots[r / 3] + r % 3, 3 * slots[c / 3] + c % 3)]
        }))
    }
}

/// A solved map: landmark positions relative to the reference, and what
/// the position filter needs for their covariances (eq. 59).
pub struct SolvedMap {
    /// The [`MapSolveRequest::version`] this answers; a stage ignores a
    /// result older than the map it already holds.
    pub version: u64,
    /// Position of each map id relative to the reference, world-frame
    /// axes, m; None for a landmark outside the reference's connected
    /// component.
    pub positions_m: Vec<Option<Vector3<f64>>>,
    /// The solved problem (the reference's component, renumbered).
    pub problem: MapProblem,
    /// Id in `problem` of each map id.
    pub local_id: Vec<Option<u32>>,
    /// `A` of `problem`.
    pub laplacian: BlockLaplacian,
    /// Cholesky factor of `A` (None after a conjugate-gradient solve).
    pub factor: Option<CholeskyFactor>,
    /// Timings and solver statistics of this solve.
    pub report: SolveReport,
    /// Iterations a cold start (from zero) needed on the same system, when
    /// the worker was asked to measure it.
    pub cold_cg_iterations: Option<usize>,
    /// How the symbolic factorisation was obtained (Cholesky solves).
    pub symbolic_path: Option<SymbolicPath>,
    /// `Σ_L(V, V)` of the request's `covariance_of` (Cholesky solves).
    pub covariance: Option<CovarianceBlocks>,
}

impl SolvedMap {
    /// Row block of map id `id` in `A` (None for the reference and for
    /// landmarks not in the solved map).
    pub fn unknown_of(&self, id: u32) -> Option<usize> {
        let local = (*self.local_id.get(id as usize)?)?;
        self.problem.unknown_of(local)
    }
}

/// Fresh AMD once appended landmarks exceed this share of those ordered
/// (measured in bench/README.md, "Kalman position filter").
pub const DEFAULT_REFRESH_FRACTION: f64 = 0.1;

/// Solves map requests; keeps the symbolic factorisation between them.
pub struct MapSolveWorker {
    symbolic: IncrementalSymbolic,
    /// Cholesky, conjugate gradient, or chosen by map size.
    pub choice: SolverChoice,
    /// Stopping rule of the conjugate-gradient solves.
    pub cg: CgOptions,
    /// Also run every CG solve from a cold start (zero) and report its
    /// iterations (measurement only; doubles the CG cost).
    pub measure_cold_start: bool,
    /// Down-weight edges that disagree with the solved map and solve
    /// again (Cholesky path only; None: plain least squares).
    pub robust: Option<RobustWeights>,
    /// This worker's last solution by map id: where
    /// [`RobustWeights::from_previous`] takes the first weights. The
    /// worker's own, not the request's (the map the stage had installed),
    /// so that the weights do not depend on when solves were installed.
    last_positions_m: Vec<Option<Vector3<f64>>>,
}

/// Huber reweighting of a solved map's edges: an edge whose residual
/// `r = y - (L_j - L_i)` has `chi2 = r^T S r` above `threshold_chi2` gets
/// its information scaled by `sqrt(threshold_chi2 / chi2)`, and the map is
/// solved again, `iterations` times at most. One wrong landmark
/// association (two places merged into one landmark) otherwise pulls every
/// frame and landmark near it, since the least-squares map has no other
/// defence; reweighting needs no new symbolic factorisation (the pattern
/// is the same).
///
/// With `from_previous`, the worker's previous solution gives the first
/// weights (at its positions), so the first factorisation is already
/// reweighted and the reweighting carries on from solve to solve: one
/// reweighted solve per map solve instead of two keeps the development
/// and held-apart accuracy at about a fifth less solve CPU
/// (docs/results/map-solve-cost-2026-11-28.md).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RobustWeights {
    /// Squared Mahalanobis residual (unitless) above which an edge is
    /// down-weighted; the default 16.27 is the 99.9 % quantile of a
    /// chi-square with 3 dof.
    pub threshold_chi2: f64,
    /// Upper bound on the reweighted solves after the first; they stop
    /// early once the weights no longer change. Default 1.
    pub iterations: usize,
    /// Weigh the edges at the previous map's positions before the first
    /// solve, when there is a previous map. Default true.
    pub from_previous: bool,
    /// The weights have settled when none moved by more than this (weights
    /// run from 0 to 1): the solution stands without another
    /// factorisation. 0 re-solves whenever any weight changed at all.
    /// Huber weights are continuous in the residual, so a weight below 1
    /// moves a little at every solve and exact equality almost never
    /// holds: every solve factorised twice. Between two solves a few
    /// frames apart the weights usually move by far less than 5 %; a new
    /// recognition or a wrong edge moves them by far more. Default
    /// [`SETTLED_WITHIN`] (0.05).
    pub settled_within: f64,
}

impl Default for RobustWeights {
    fn default() -> Self {
        Self {
            // 3 dof, 99.9 %.
            threshold_chi2: 16.27,
            iterations: 1,
            from_previous: true,
            settled_within: SETTLED_WITHIN,
        }
    }
}

/// [`RobustWeights::settled_within`] by default.
pub const SETTLED_WITHIN: f64 = 0.05;

impl RobustWeights {
    /// The weight of each edge of `original` (same order as
    /// `problem.edges`) at the solution `x` of `problem`.
    pub fn weights(&self, problem: &MapProblem, original: &[MapEdge], x: &[f64]) -> Vec<f64> {
        let at = |id: u32| match problem.unknown_of(id) {
            Some(u) => Vector3::new(x[3 * u], x[3 * u + 1], x[3 * u + 2]),
            None => Vector3::zeros(),
        };
        original
            .iter()
            .map(|e| {
                let r = e.y_m - (at(e.j) - at(e.i));
                let chi2 = r.dot(&(e.info * r));
                if chi2 > self.threshold_chi2 {
                    (self.threshold_chi2 / chi2).sqrt()
                } else {
                    1.0
                }
            })
            .collect()
    }
}

impl MapSolveWorker {
    /// A worker solving with `choice`, default CG options, no robust
    /// reweighting, no cold-start measurement, and ordering reuse that
    /// appends new landmarks until they exceed [`DEFAULT_REFRESH_FRACTION`]
    /// of those the last fresh AMD ordered.
    /// `threads`: 1 runs sequentially, more uses faer's rayon parallelism.
    pub fn new(choice: SolverChoice, threads: usize) -> Self {
        Self {
            symbolic: IncrementalSymbolic::new(
                OrderingReuse::AppendNew {
                    refresh_fraction: DEFAULT_REFRESH_FRACTION,
                },
                if threads <= 1 {
                    faer::Par::Seq
                } else {
                    faer::Par::rayon(threads)
                },
            ),
            choice,
            cg: CgOptions::default(),
            measure_cold_start: false,
            robust: None,
            last_positions_m: Vec::new(),
        }
    }

    /// Changes how a changed pattern's ordering is obtained.
    pub fn set_ordering(&mut self, ordering: OrderingReuse) {
        self.symbolic.policy = ordering;
    }

    /// Solves one request: the reference's connected component (landmarks
    /// that no edge joins to it yet are left out), by sparse Cholesky or,
    /// for large maps, by PCG warm-started from the previous solution.
    pub fn solve(&mut self, request: MapSolveRequest) -> Result<SolvedMap, EdgeMapError> {
        let start = Instant::now();
        let start_cpu_ms = thread_cpu_ms();
        let MapSolveRequest {
            version,
            problem: full,
            previous_m,
            covariance_of,
        } = request;
        let (problem, kept) = full.into_reference_component();
        // The reference's component is connected by construction: A is
        // positive definite on it.
        let mut problem = problem;
        let mut report = SolveReport::default();
        let has_previous = previous_m.iter().any(Option::is_some);
        let use_cg = match self.choice {
            SolverChoice::Cholesky => false,
            SolverChoice::ConjugateGradient => true,
            SolverChoice::Auto { cg_above_landmarks } => {
                problem.landmark_count as usize > cg_above_landmarks && has_previous
            }
        };
        // The unweighted edges (only needed to reweigh them).
        let original = match self.robust {
            Some(_) if !use_cg => problem.edges.clone(),
            _ => Vec::new(),
        };
        // The weights A holds (None: all 1).
        let mut weighed: Option<Vec<f64>> = None;
        let solved_before = self.last_positions_m.iter().any(Option::is_some);
        if let Some(robust) = self
            .robust
            .filter(|r| !use_cg && r.from_previous && solved_before)
        {
            // Weights at the previous map (new landmarks placed through
            // their edges): the map moves little between solves, so the
            // first factorisation is already a reweighted one. Applied
            // before A is assembled: one fill instead of two.
            let t = Instant::now();
            let placed = warm_start(&problem, &kept, &self.last_positions_m);
            let weights = robust.weights(&problem, &original, &placed);
            report.downweighted_edges = weights.iter().filter(|&&w| w < 1.0).count();
            apply_weights(&mut problem, &original, &weights);
            weighed = Some(weights);
            report.reweight_ms += ms_since(t);
        }
        let mut laplacian = BlockLaplacian::assemble(&problem);
        // The component split and the assembly.
        report.assemble_ms = ms_since(start) - report.reweight_ms;
        let mut cold_cg_iterations = None;
        let mut symbolic_path = None;
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
            let (mut factor, path) =
                self.symbolic
                    .factorize(&laplacian, &problem, &kept, &mut report)?;
            symbolic_path = Some(path);
            report.factor_ms = ms_since(t);
            let mut x = cholesky_solution(&factor, &laplacian, &mut report);
            if let Some(robust) = self.robust {
                for _ in 0..robust.iterations {
                    let t = Instant::now();
                    let weights = robust.weights(&problem, &original, &x);
                    let downweighted = weights.iter().filter(|&&w| w < 1.0).count();
                    report.downweighted_edges = downweighted;
                    let settled = match &weighed {
                        None => downweighted == 0,
                        Some(held) => held
                            .iter()
                            .zip(&weights)
                            .all(|(a, b)| (a - b).abs() <= robust.settled_within),
                    };
                    if settled {
                        report.reweight_ms += ms_since(t);
                        break;
                    }
                    apply_weights(&mut problem, &original, &weights);
                    // Same edges, new weights: the pattern (and with it the
                    // symbolic factorisation) is unchanged.
                    laplacian.refill(&problem);
                    weighed = Some(weights);
                    report.reweight_ms += ms_since(t);
                    let t = Instant::now();
                    let mut discard = SolveReport::default();
                    factor = self
                        .symbolic
                        .factorize(&laplacian, &problem, &kept, &mut discard)?
                        .0;
                    report.factor_ms += ms_since(t);
                    x.copy_from_slice(&laplacian.rhs);
                    factor.solve_in_place(&mut x, 1);
                    report.robust_iterations += 1;
                }
            }
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
        let covariance = factor.as_ref().map(|factor| {
            let t = Instant::now();
            let blocks = covariance_blocks(factor, &problem, &local_id, &covariance_of);
            report.covariance_ms = ms_since(t);
            blocks
        });
        self.last_positions_m.clone_from(&positions_m);
        report.total_ms = ms_since(start);
        report.cpu_ms = thread_cpu_ms() - start_cpu_ms;
        Ok(SolvedMap {
            covariance,
            version,
            positions_m,
            problem,
            local_id,
            laplacian,
            factor,
            report,
            cold_cg_iterations,
            symbolic_path,
        })
    }
}

/// Scales each edge's information of `original` by its weight.
fn apply_weights(problem: &mut MapProblem, original: &[MapEdge], weights: &[f64]) {
    for (edge, (o, w)) in problem.edges.iter_mut().zip(original.iter().zip(weights)) {
        edge.info = o.info * *w;
    }
}

/// `Σ_L(V, V)` of the map ids `ids` (those in the solved component; the
/// others get no slot): forward solves with the factor
/// ([`CholeskyFactor::inverse_entries`]).
fn covariance_blocks(
    factor: &CholeskyFactor,
    problem: &MapProblem,
    local_id: &[Option<u32>],
    ids: &[u32],
) -> CovarianceBlocks {
    let mut slot = std::collections::HashMap::with_capacity(ids.len());
    let mut unknowns = Vec::with_capacity(ids.len());
    for &id in ids {
        let Some(Some(local)) = local_id.get(id as usize).copied() else {
            continue;
        };
        if slot.contains_key(&id) {
            continue;
        }
        slot.insert(id, unknowns.len());
        unknowns.push(problem.unknown_of(local));
    }
    let m = unknowns.len();
    // The reference landmark has no unknowns: its rows stay zero.
    let mut scalar = Vec::with_capacity(3 * m);
    let mut slot_of = Vec::with_capacity(3 * m);
    for (k, u) in unknowns.iter().enumerate() {
        if let Some(u) = u {
            for c in 0..3 {
                scalar.push(3 * u + c);
                slot_of.push(3 * k + c);
            }
        }
    }
    let entries = factor.inverse_entries(&scalar);
    let mut matrix = nalgebra::DMatrix::zeros(3 * m, 3 * m);
    for (a, &ra) in slot_of.iter().enumerate() {
        for (b, &rb) in slot_of.iter().enumerate() {
            matrix[(ra, rb)] = entries[(a, b)];
        }
    }
    CovarianceBlocks { slot, matrix }
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

/// CPU time the calling thread has used, ms: unlike wall time, it does not
/// count the time a niced solve thread waits while the frame path runs on
/// its core.
fn thread_cpu_ms() -> f64 {
    let mut now = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: clock_gettime writes one timespec through a valid pointer.
    let ok = unsafe { libc::clock_gettime(libc::CLOCK_THREAD_CPUTIME_ID, &mut now) } == 0;
    if ok {
        now.tv_sec as f64 * 1e3 + now.tv_nsec as f64 * 1e-6
    } else {
        0.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::edge_map::simulate::{simulate_city, CityOptions};

    #[test]
    fn robust_weights_contain_a_wrong_association() {
        // A simulated drive with frame nodes, measured without noise;
        // then one landmark's edges from its later frames are moved by
        // 1.5 m, as when a lookalike was recognised as that landmark.
        let city = simulate_city(&CityOptions {
            landmarks: 400,
            policy: crate::edge_map::EdgePolicy::FrameNodes { every: 1 },
            add_noise: false,
            ..CityOptions::default()
        });
        let truth = city.truth_relative_m();
        let mut problem = city.problem.clone();
        let landmark = (1..problem.landmark_count)
            .filter(|&id| !city.frame_node[id as usize])
            .max_by_key(|&id| {
                problem
                    .edges
                    .iter()
                    .filter(|e| e.i == id || e.j == id)
                    .count()
            })
            .expect("a landmark");
        let edges: Vec<usize> = (0..problem.edges.len())
            .filter(|&k| problem.edges[k].i == landmark || problem.edges[k].j == landmark)
            .collect();
        let wrong = &edges[edges.len() / 2..];
        for &k in wrong {
            let e = &mut problem.edges[k];
            let shift = Vector3::new(1.5, 0.0, 0.0);
            e.y_m += if e.j == landmark { shift } else { -shift };
        }
        let solve = |worker: &mut MapSolveWorker, problem: &MapProblem| {
            let solved = worker
                .solve(MapSolveRequest {
                    version: 1,
                    problem: problem.clone(),
                    previous_m: Vec::new(),
                    covariance_of: Vec::new(),
                })
                .expect("solve");
            let worst = (0..problem.landmark_count)
                .filter(|&id| id != landmark && !city.frame_node[id as usize])
                .map(|id| {
                    (solved.positions_m[id as usize].expect("placed") - truth[id as usize]).norm()
                })
                .fold(0.0, f64::max);
            (worst, solved.report.downweighted_edges)
        };
        let worker_with = |robust| {
            let mut worker = MapSolveWorker::new(SolverChoice::Cholesky, 1);
            worker.robust = robust;
            worker
        };
        let (plain, _) = solve(&mut worker_with(None), &problem);
        assert!(plain > 0.02, "the wrong edges should hurt: {plain}");
        // The default on a map's first solve (one reweighted solve), then
        // on the next solve of the same map, which starts from the first's
        // weights: the error is contained by then.
        let mut worker = worker_with(Some(RobustWeights::default()));
        let (first, _) = solve(&mut worker, &problem);
        let (next, downweighted) = solve(&mut worker, &problem);
        assert!(first < 0.5 * plain, "first solve {first} vs plain {plain}");
        assert!(next < 0.2 * plain, "next solve {next} vs plain {plain}");
        assert!(
            downweighted >= wrong.len() / 2,
            "{downweighted} of {}",
            wrong.len()
        );
        // A map solved before the wrong recognition, then no reweighted
        // solve after the first: the weights taken at the previous map
        // alone must contain the error, and without them nothing does.
        let mut before = city.problem.clone();
        before.edges.retain(|e| e.i != landmark && e.j != landmark);
        before.edges.extend(
            edges[..edges.len() / 2]
                .iter()
                .map(|&k| city.problem.edges[k]),
        );
        let after_a_clean_map = |from_previous| {
            let mut worker = worker_with(Some(RobustWeights {
                iterations: 0,
                from_previous,
                ..RobustWeights::default()
            }));
            solve(&mut worker, &before);
            solve(&mut worker, &problem).0
        };
        let (from_previous, unweighted) = (after_a_clean_map(true), after_a_clean_map(false));
        assert!(
            from_previous < 0.2 * plain,
            "weights from the previous map: {from_previous} vs plain {plain}"
        );
        assert!(unweighted > 0.9 * plain, "{unweighted} vs plain {plain}");
    }

    #[test]
    fn weights_that_barely_move_need_no_second_factorisation() {
        // A noisy drive with a few wrong edges: some weights below 1.
        let city = simulate_city(&CityOptions {
            landmarks: 300,
            policy: crate::edge_map::EdgePolicy::FrameNodes { every: 1 },
            ..CityOptions::default()
        });
        let mut problem = city.problem.clone();
        for e in problem.edges.iter_mut().step_by(97) {
            e.y_m += Vector3::new(0.8, -0.4, 0.2);
        }
        let clean = city.problem.clone();
        let solve = |worker: &mut MapSolveWorker, problem: &MapProblem| {
            worker
                .solve(MapSolveRequest {
                    version: 1,
                    problem: problem.clone(),
                    previous_m: Vec::new(),
                    covariance_of: Vec::new(),
                })
                .expect("solve")
        };
        let worker_with = |settled_within| {
            let mut worker = MapSolveWorker::new(SolverChoice::Cholesky, 1);
            worker.robust = Some(RobustWeights {
                settled_within,
                ..RobustWeights::default()
            });
            worker
        };
        // The same map solved again: its weights start where the last
        // solve left them and move by rounding-sized amounts only.
        let (mut exact, mut tolerant) = (worker_with(0.0), worker_with(SETTLED_WITHIN));
        let mut last = (None, None);
        for round in 0..3 {
            let a = solve(&mut exact, &problem);
            let b = solve(&mut tolerant, &problem);
            assert!(a.report.downweighted_edges > 0);
            if round == 2 {
                assert_eq!(a.report.robust_iterations, 1, "exact weights re-solve");
                assert_eq!(b.report.robust_iterations, 0, "settled weights do not");
            }
            last = (Some(a), Some(b));
        }
        let (a, b) = (last.0.expect("solved"), last.1.expect("solved"));
        let apart = a
            .positions_m
            .iter()
            .zip(&b.positions_m)
            .map(|(p, q)| (p.expect("placed") - q.expect("placed")).norm())
            .fold(0.0, f64::max);
        assert!(apart < 1e-3, "settled and re-solved maps {apart} m apart");
        // After a map that was a third larger, the weights taken at its
        // positions are far from those at the new solution: solved again.
        let mut stretched = clean;
        for e in &mut stretched.edges {
            e.y_m *= 1.3;
        }
        let mut worker = worker_with(SETTLED_WITHIN);
        solve(&mut worker, &stretched);
        let moved = solve(&mut worker, &problem);
        assert_eq!(moved.report.robust_iterations, 1);
    }

    /// The map as it was when only landmarks `0..n` existed (ids are
    /// assigned in the order the drive creates them).
    pub(crate) fn prefix(problem: &MapProblem, n: u32) -> MapProblem {
        MapProblem {
            landmark_count: n,
            reference: problem.reference,
            edges: problem
                .edges
                .iter()
                .filter(|e| e.i < n && e.j < n)
                .copied()
                .collect(),
        }
    }

    /// A growing map solved by CG from the previous solution: same answer
    /// as Cholesky, in fewer iterations than from zero.
    #[test]
    fn warm_started_cg_on_a_growing_map_agrees_with_cholesky_in_fewer_iterations() {
        let city = simulate_city(&CityOptions {
            landmarks: 1500,
            ..CityOptions::default()
        });
        let mut cg = MapSolveWorker::new(SolverChoice::ConjugateGradient, 1);
        cg.measure_cold_start = true;
        cg.cg.rel_tol = 1e-12;
        cg.cg.max_iterations = 100_000;
        let mut cholesky = MapSolveWorker::new(SolverChoice::Cholesky, 1);
        let mut previous: Vec<Option<Vector3<f64>>> = Vec::new();
        let (mut warm_total, mut cold_total) = (0, 0);
        for (version, n) in (1000..=1500).step_by(50).enumerate() {
            let problem = prefix(&city.problem, n);
            let request = MapSolveRequest {
                version: version as u64,
                problem,
                previous_m: previous.clone(),
                covariance_of: Vec::new(),
            };
            let reference = cholesky.solve(request.clone()).unwrap();
            let solved = cg.solve(request).unwrap();
            assert_eq!(solved.report.method, "pcg");
            for (a, b) in solved.positions_m.iter().zip(&reference.positions_m) {
                match (a, b) {
                    (Some(a), Some(b)) => assert!((a - b).norm() < 1e-6, "{a} vs {b}"),
                    (None, None) => {}
                    _ => panic!("the two solves placed different landmarks"),
                }
            }
            if version > 0 {
                warm_total += solved.report.cg_iterations;
                cold_total += solved.cold_cg_iterations.unwrap();
            }
            previous = solved.positions_m;
        }
        assert!(
            warm_total < cold_total,
            "warm {warm_total} vs cold {cold_total} iterations"
        );
    }

    /// The covariance blocks a solve computes for the landmarks in view
    /// equal the dense inverse of A at those rows and columns (zero for the
    /// reference), and landmarks outside the solved map get no slot.
    #[test]
    fn requested_covariance_blocks_equal_the_dense_inverse() {
        let city = simulate_city(&CityOptions {
            landmarks: 120,
            ..CityOptions::default()
        });
        let mut problem = city.problem.clone();
        problem.landmark_count += 1; // one landmark no edge reaches
        let ids = vec![37, 0, 5, 119, 120, 64];
        let mut worker = MapSolveWorker::new(SolverChoice::Cholesky, 1);
        let solved = worker
            .solve(MapSolveRequest {
                version: 1,
                problem,
                previous_m: Vec::new(),
                covariance_of: ids.clone(),
            })
            .expect("solve");
        let blocks = solved.covariance.as_ref().expect("Cholesky gives blocks");
        assert!(!blocks.slot.contains_key(&120));
        let inverse = solved
            .laplacian
            .to_dense()
            .try_inverse()
            .expect("A is invertible");
        let kept: Vec<u32> = ids.iter().copied().filter(|&id| id != 120).collect();
        let joint = blocks.select(&kept).expect("all slotted");
        for (a, &ia) in kept.iter().enumerate() {
            for (b, &ib) in kept.iter().enumerate() {
                for r in 0..3 {
                    for c in 0..3 {
                        let expected = match (solved.unknown_of(ia), solved.unknown_of(ib)) {
                            (Some(u), Some(v)) => inverse[(3 * u + r, 3 * v + c)],
                            _ => 0.0,
                        };
                        let got = joint[(3 * a + r, 3 * b + c)];
                        assert!(
                            (got - expected).abs() <= 1e-9 * (1.0 + expected.abs()),
                            "({ia},{ib}) [{r},{c}]: {got} vs {expected}"
                        );
                    }
                }
            }
        }
        assert!(blocks.select(&[120]).is_none());
    }

    /// Warm- vs cold-started CG iterations on a growing simulated map (not a
    /// check; `--ignored --nocapture` prints the table in bench/README.md).
    #[test]
    #[ignore = "measurement, not a check: prints warm vs cold CG iterations (--ignored --nocapture)"]
    fn print_warm_start_table() {
        use crate::edge_map::simulate::{simulate_city, CityOptions};
        let landmarks: usize = std::env::var("RIGSLAM_WARM_LANDMARKS")
            .ok()
            .and_then(|s| s.parse().ok())
            .unwrap_or(10_000);
        let city = simulate_city(&CityOptions {
            landmarks,
            ..CityOptions::default()
        });
        let step = 15u32; // about 5 frames of new landmarks (2 m per frame, 1.5 per m)
        let solves = 6;
        let top = city.problem.landmark_count;
        for rel_tol in [1e-4, 1e-6, 1e-8, 1e-10] {
            let mut cg = MapSolveWorker::new(SolverChoice::ConjugateGradient, 1);
            cg.measure_cold_start = true;
            cg.cg.rel_tol = rel_tol;
            cg.cg.max_iterations = 200_000;
            let mut cholesky = MapSolveWorker::new(SolverChoice::Cholesky, 1);
            let mut previous: Vec<Option<Vector3<f64>>> = Vec::new();
            let (mut warm, mut cold, mut worst) = (0usize, 0usize, 0.0f64);
            let (mut warm_ms, mut cold_ms) = (0.0, 0.0);
            for k in 0..=solves {
                let n = top - (solves - k) as u32 * step;
                let request = MapSolveRequest {
                    version: k as u64,
                    problem: tests::prefix(&city.problem, n),
                    previous_m: previous.clone(),
                    covariance_of: Vec::new(),
                };
                let reference = cholesky.solve(request.clone()).unwrap();
                let t = Instant::now();
                let solved = cg.solve(request).unwrap();
                let both_ms = ms_since(t);
                if k > 0 {
                    warm += solved.report.cg_iterations;
                    cold += solved.cold_cg_iterations.unwrap();
                    warm_ms += solved.report.solve_ms;
                    cold_ms += both_ms - solved.report.solve_ms;
                    for (a, b) in solved.positions_m.iter().zip(&reference.positions_m) {
                        if let (Some(a), Some(b)) = (a, b) {
                            worst = worst.max((a - b).norm());
                        }
                    }
                }
                previous = solved.positions_m;
            }
            println!(
                "| {top} | {rel_tol:e} | {:.0} | {:.0} | {:.2} | {:.0} / {:.0} | {worst:.1e} |",
                warm as f64 / solves as f64,
                cold as f64 / solves as f64,
                cold as f64 / warm.max(1) as f64,
                warm_ms / solves as f64,
                cold_ms / solves as f64,
            );
        }
    }
}
