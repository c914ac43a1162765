//! Edge-map costs: one edge fusion update (eq. 43) and the
//! assembly + factorisation + solve of A L = B on a simulated 10k-landmark
//! drive. The scaling table against CHOLMOD is made by
//! bench/peers/cholmod_map_scaling.sh; see bench/README.md.

use criterion::{criterion_group, criterion_main, Criterion};
use nalgebra::{Matrix3, Vector3};
use rigslam::edge_map::simulate::{simulate_city, CityOptions};
use rigslam::edge_map::{EdgeMapSolver, FusedEdge, SolverChoice};

fn fusion(c: &mut Criterion) {
    let info = Matrix3::new(2.0, 0.1, 0.0, 0.1, 3.0, 0.2, 0.0, 0.2, 1.0);
    let y = Vector3::new(1.0, 2.0, 3.0);
    let mut edge = FusedEdge::default();
    c.bench_function("edge fusion update", |b| {
        b.iter(|| edge.add(std::hint::black_box(&y), std::hint::black_box(&info)))
    });
}

fn solve(c: &mut Criterion) {
    let sim = simulate_city(&CityOptions {
        landmarks: 10_000,
        ..Default::default()
    });
    let mut group = c.benchmark_group("map solve 10k landmarks");
    group.sample_size(10);
    group.bench_function("cholesky, fresh analysis", |b| {
        b.iter(|| {
            EdgeMapSolver::new(SolverChoice::Cholesky, 1)
                .solve(&sim.problem)
                .expect("connected")
        })
    });
    let mut solver = EdgeMapSolver::new(SolverChoice::Cholesky, 1);
    group.bench_function("cholesky, reused analysis", |b| {
        b.iter(|| solver.solve(&sim.problem).expect("connected"))
    });
    group.finish();
}

criterion_group!(benches, fusion, solve);
criterion_main!(benches);
