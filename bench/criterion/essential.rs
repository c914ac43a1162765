//! Five-point solver and MSAC relative pose on the real KITTI matches
//! (`../shared/data/kitti/seq_a_matches.txt`); P3P on a synthetic triple.

use std::path::Path;

use criterion::{black_box, criterion_group, criterion_main, Criterion};
use nalgebra::{Vector2, Vector3};
use rigslam::dataset::matches_file::{normalise, read_matches};
use rigslam::two_view::{estimate_relative_pose, five_point, p3p, RelativePoseConfig};

const MATCHES: &str = concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/../shared/data/kitti/seq_a_matches.txt"
);

type Pair = (Vec<Vector2<f64>>, Vec<Vector2<f64>>);

fn kitti_pairs() -> Option<(f64, Vec<Pair>)> {
    let path = Path::new(MATCHES);
    let file = read_matches(path).ok()?;
    let camera = file.camera(path).ok()?;
    Some((
        file.pinhole[0],
        file.pairs.iter().map(|p| normalise(&camera, p)).collect(),
    ))
}

fn bench(c: &mut Criterion) {
    let Some((focal_px, pairs)) = kitti_pairs() else {
        eprintln!("skipping: {MATCHES} is missing");
        return;
    };
    let (x1, x2) = &pairs[0];
    let q1: [Vector3<f64>; 5] =
        std::array::from_fn(|i| Vector3::new(x1[i * 20].x, x1[i * 20].y, 1.0));
    let q2: [Vector3<f64>; 5] =
        std::array::from_fn(|i| Vector3::new(x2[i * 20].x, x2[i * 20].y, 1.0));
    c.bench_function("five_point (one minimal sample)", |b| {
        b.iter(|| five_point(black_box(&q1), black_box(&q2)))
    });
    let config = RelativePoseConfig::for_pixels(1.0, focal_px);
    c.bench_function("estimate_relative_pose (KITTI seq_a, 50 pairs)", |b| {
        b.iter(|| {
            for (x1, x2) in &pairs {
                black_box(estimate_relative_pose(x1, x2, &config).ok());
            }
        })
    });
    let bearings = [
        Vector3::new(0.1, 0.2, 1.0),
        Vector3::new(-0.3, 0.1, 1.0),
        Vector3::new(0.2, -0.25, 1.0),
    ];
    let world = [bearings[0] * 4.0, bearings[1] * 6.0, bearings[2] * 5.0];
    c.bench_function("p3p", |b| {
        b.iter(|| p3p(black_box(&bearings), black_box(&world)))
    });
}

criterion_group!(benches, bench);
criterion_main!(benches);
