//! Tests of the map optimisation against independent dense references.

use nalgebra::{DMatrix, DVector, Matrix3, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::covariance::{exact_covariance, submatrix_covariance};
use super::laplacian::{dense_full_laplacian, BlockLaplacian};
use super::simulate::{simulate_city, CityOptions};
use super::solve::{solve_pcg, CgOptions};
use super::*;

fn random_spd(rng: &mut ChaCha8Rng) -> Matrix3<f64> {
    let m = Matrix3::from_fn(|_, _| rng.gen_range(-1.0..1.0));
    m * m.transpose() + Matrix3::identity() * 0.2
}

/// A connected random graph: a random tree plus `extra` random edges, with
/// exact or noisy measurements of true positions.
fn random_problem(
    n: u32,
    extra: usize,
    noise_m: f64,
    reference: u32,
    seed: u64,
) -> (MapProblem, Vec<Vector3<f64>>) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let truth: Vec<Vector3<f64>> = (0..n)
        .map(|_| Vector3::from_fn(|_, _| rng.gen_range(-20.0..20.0)))
        .collect();
    let mut pairs: Vec<(u32, u32)> = (1..n).map(|j| (rng.gen_range(0..j), j)).collect();
    for _ in 0..extra {
        let (a, b) = (rng.gen_range(0..n), rng.gen_range(0..n));
        if a != b {
            pairs.push((a, b));
        }
    }
    let edges = pairs
        .into_iter()
        .map(|(i, j)| MapEdge {
            i,
            j,
            y_m: truth[j as usize] - truth[i as usize]
                + Vector3::from_fn(|_, _| rng.gen_range(-noise_m..=noise_m)),
            info: random_spd(&mut rng),
        })
        .collect();
    (
        MapProblem {
            landmark_count: n,
            reference,
            edges,
        },
        truth,
    )
}

/// Dense reference: the full Laplacian with the reference's rows and
/// columns removed, solved by dense Cholesky.
fn dense_solve(problem: &MapProblem) -> Vec<Vector3<f64>> {
    let (a, b) = dense_full_laplacian(problem);
    let keep: Vec<usize> = (0..a.nrows())
        .filter(|k| k / 3 != problem.reference as usize)
        .collect();
    let a = DMatrix::from_fn(keep.len(), keep.len(), |r, c| a[(keep[r], keep[c])]);
    let b = DVector::from_fn(keep.len(), |r, _| b[keep[r]]);
    let x = a
        .cholesky()
        .expect("reduced A is positive definite")
        .solve(&b);
    let mut out = vec![Vector3::zeros(); problem.landmark_count as usize];
    for (k, &row) in keep.iter().enumerate() {
        out[row / 3][row % 3] = x[k];
    }
    out
}

fn max_diff(a: &[Vector3<f64>], b: &[Vector3<f64>]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).norm())
        .fold(0.0, f64::max)
}

#[test]
fn noise_free_graphs_are_recovered_exactly() {
    for (n, extra, reference, seed) in [
        (2, 0, 0, 1),
        (10, 5, 3, 2),
        (300, 900, 150, 3),
        (1000, 0, 999, 4),
    ] {
        let (problem, truth) = random_problem(n, extra, 0.0, reference, seed);
        let (solution, report) = EdgeMapSolver::new(SolverChoice::Cholesky, 1)
            .solve(&problem)
            .unwrap();
        let r = truth[reference as usize];
        let expected: Vec<_> = truth.iter().map(|p| p - r).collect();
        let err = max_diff(&solution, &expected);
        assert!(err < 1e-9, "n={n}: max error {err} m");
        assert_eq!(solution[reference as usize], Vector3::zeros());
        assert_eq!(report.method, "cholesky");
    }
}

#[test]
fn sparse_solve_equals_dense_solve() {
    for seed in 0..5 {
        let (problem, _) = random_problem(40, 60, 0.5, seed as u32 % 40, 10 + seed);
        let (solution, _) = EdgeMapSolver::new(SolverChoice::Cholesky, 1)
            .solve(&problem)
            .unwrap();
        let dense = dense_solve(&problem);
        let err = max_diff(&solution, &dense);
        assert!(err < 1e-9, "seed {seed}: {err}");
        // And the assembled sparse A equals the dense reduced one entry by entry.
        let sparse_a = BlockLaplacian::assemble(&problem).to_dense();
        let (full, _) = dense_full_laplacian(&problem);
        let r = problem.reference as usize;
        let keep: Vec<usize> = (0..full.nrows()).filter(|k| k / 3 != r).collect();
        let reduced = DMatrix::from_fn(keep.len(), keep.len(), |a, b| full[(keep[a], keep[b])]);
        assert!((sparse_a - reduced).abs().max() < 1e-12);
    }
}

#[test]
fn laplacian_without_reference_has_nullity_three() {
    let (problem, _) = random_problem(25, 30, 0.1, 0, 5);
    let (a, _) = dense_full_laplacian(&problem);
    let eigen = a.symmetric_eigenvalues();
    let scale = eigen.amax();
    let null = eigen.iter().filter(|v| v.abs() < 1e-10 * scale).count();
    assert_eq!(null, 3, "eigenvalues {eigen}");
    assert!(eigen.iter().all(|&v| v > -1e-10 * scale), "A must be PSD");
    // The null space is the common translation: A [t; t; ...] = 0.
    let t = DVector::from_fn(a.nrows(), |k, _| [1.0, -2.0, 0.5][k % 3]);
    assert!((&a * t).amax() < 1e-10 * scale);
}

#[test]
fn fixing_the_reference_gives_symmetric_positive_definite_a() {
    let (problem, _) = random_problem(25, 30, 0.1, 7, 6);
    let a = BlockLaplacian::assemble(&problem).to_dense();
    assert_eq!(a, a.transpose());
    let eigen = a.symmetric_eigenvalues();
    assert!(eigen.min() > 1e-8 * eigen.max(), "eigenvalues {eigen}");
}

#[test]
fn covariance_equals_the_dense_inverse() {
    let (problem, _) = random_problem(30, 40, 0.1, 4, 7);
    let mut solver = EdgeMapSolver::new(SolverChoice::Cholesky, 1);
    solver.solve(&problem).unwrap();
    let laplacian = BlockLaplacian::assemble(&problem);
    let inverse = laplacian.to_dense().try_inverse().unwrap();
    let visible = [0u32, 4, 9, 17, 29];
    let exact = exact_covariance(solver.factor().unwrap(), &problem, &visible);
    let unknowns: Vec<usize> = visible
        .iter()
        .filter_map(|&id| problem.unknown_of(id))
        .collect();
    assert_eq!(exact.nrows(), 3 * unknowns.len());
    for (a, &ua) in unknowns.iter().enumerate() {
        for (b, &ub) in unknowns.iter().enumerate() {
            for r in 0..3 {
                for c in 0..3 {
                    let d = exact[(3 * a + r, 3 * b + c)] - inverse[(3 * ua + r, 3 * ub + c)];
                    assert!(
                        d.abs() < 1e-10 * inverse.amax(),
                        "block ({a},{b}) differs by {d}"
                    );
                }
            }
        }
    }
    // The sub-matrix rule with every landmark inside is exact, with none
    // outside it is an underestimate (exact - approximate is PSD).
    let whole = submatrix_covariance(&laplacian, &problem, &visible, 30);
    assert!((&whole - &exact).amax() < 1e-10 * exact.amax());
    let local = submatrix_covariance(&laplacian, &problem, &visible, 0);
    let gap = (&exact - &local).symmetric_eigenvalues();
    assert!(gap.min() > -1e-10 * exact.amax(), "{gap}");
    assert!(
        gap.max() > 1e-6 * exact.amax(),
        "the local approximation should differ"
    );
}

#[test]
fn symbolic_factorisation_is_reused_while_the_pattern_holds() {
    let (mut problem, truth) = random_problem(200, 400, 0.0, 0, 8);
    let mut solver = EdgeMapSolver::new(SolverChoice::Cholesky, 1);
    let (_, first) = solver.solve(&problem).unwrap();
    assert!(!first.symbolic_reused);
    // New information on the same edges: same pattern, new values.
    let mut rng = ChaCha8Rng::seed_from_u64(9);
    for e in &mut problem.edges {
        e.info = random_spd(&mut rng);
    }
    let (solution, second) = solver.solve(&problem).unwrap();
    assert!(second.symbolic_reused);
    let expected: Vec<_> = truth.iter().map(|p| p - truth[0]).collect();
    assert!(max_diff(&solution, &expected) < 1e-9);
}

#[test]
fn conjugate_gradient_agrees_with_cholesky() {
    let (problem, _) = random_problem(300, 600, 0.3, 0, 11);
    let (cholesky, _) = EdgeMapSolver::new(SolverChoice::Cholesky, 1)
        .solve(&problem)
        .unwrap();
    let (cg, report) = EdgeMapSolver::new(SolverChoice::ConjugateGradient, 1)
        .solve(&problem)
        .unwrap();
    assert_eq!(report.method, "pcg");
    assert!(report.cg_iterations > 0);
    assert!(
        max_diff(&cholesky, &cg) < 1e-6,
        "{}",
        max_diff(&cholesky, &cg)
    );
    // Warm start from the solution: converges at once.
    let laplacian = BlockLaplacian::assemble(&problem);
    let mut x: Vec<f64> = cholesky
        .iter()
        .enumerate()
        .filter(|(id, _)| *id != 0)
        .flat_map(|(_, p)| [p.x, p.y, p.z])
        .collect();
    let iterations = solve_pcg(
        &laplacian,
        &mut x,
        &CgOptions {
            rel_tol: 1e-8,
            max_iterations: 100,
        },
    )
    .unwrap();
    assert_eq!(iterations, 0);
}

#[test]
fn disconnected_graph_names_the_unplaced_component() {
    let (mut problem, _) = random_problem(6, 0, 0.0, 0, 12);
    // Cut every edge touching landmarks 4 and 5, then join them to each other.
    problem.edges.retain(|e| e.i < 4 && e.j < 4);
    problem.edges.push(MapEdge {
        i: 4,
        j: 5,
        y_m: Vector3::x(),
        info: Matrix3::identity(),
    });
    let err = EdgeMapSolver::new(SolverChoice::Cholesky, 1)
        .solve(&problem)
        .unwrap_err();
    match &err {
        EdgeMapError::Disconnected {
            reference,
            unplaced,
        } => {
            assert_eq!(*reference, 0);
            assert_eq!(unplaced, &vec![vec![4, 5]]);
        }
        other => panic!("{other:?}"),
    }
    assert!(err.to_string().contains("{4, 5}"), "{err}");
}

#[test]
fn simulated_drive_without_noise_is_recovered_exactly() {
    for policy in [
        EdgePolicy::AllPairs,
        EdgePolicy::KNearest(3),
        EdgePolicy::SpanningTree,
    ] {
        let sim = simulate_city(&CityOptions {
            landmarks: 400,
            add_noise: false,
            policy,
            seed: 3,
            ..Default::default()
        });
        assert!(
            sim.problem.landmark_count >= 395,
            "{}",
            sim.problem.landmark_count
        );
        let (solution, _) = EdgeMapSolver::new(SolverChoice::Cholesky, 1)
            .solve(&sim.problem)
            .unwrap();
        let err = max_diff(&solution, &sim.truth_relative_m());
        assert!(err < 1e-8, "{policy}: {err}");
    }
}

#[test]
fn refilling_reweighted_edges_equals_a_fresh_assembly() {
    // Repeated pairs (edges listed twice add up) and the reference in the
    // middle, as in a running map.
    let (mut problem, _) = random_problem(40, 80, 0.1, 13, 11);
    let doubled: Vec<MapEdge> = problem.edges[..10].to_vec();
    problem.edges.extend(doubled);
    let mut laplacian = BlockLaplacian::assemble(&problem);
    let mut rng = ChaCha8Rng::seed_from_u64(12);
    for edge in &mut problem.edges {
        edge.info *= rng.gen_range(0.05..1.0);
        edge.y_m *= 1.1;
    }
    laplacian.refill(&problem);
    let fresh = BlockLaplacian::assemble(&problem);
    assert!(laplacian.same_pattern(&fresh));
    assert_eq!(laplacian.values, fresh.values);
    assert_eq!(laplacian.rhs, fresh.rhs);
    // And it is the reweighted problem's A, not the first one's.
    let (full, _) = dense_full_laplacian(&problem);
    let keep: Vec<usize> = (0..3 * 40).filter(|&k| k / 3 != 13).collect();
    let reduced = full.select_rows(&keep).select_columns(&keep);
    assert!((laplacian.to_dense() - reduced).amax() < 1e-12);
}
