//! Criterion benchmarks of the image front end on two consecutive real
//! EuRoC frames (`../shared/data`), or on a synthetic pair when the data
//! is missing. `rigslam bench frontend` is the whole-sequence counterpart
//! compared with OpenCV.

use std::path::Path;

use criterion::{black_box, criterion_group, criterion_main, Criterion};
use rigslam::dataset::read_png;
use rigslam::features::{
    Corner, CornerConfig, CornerDetector, KltConfig, KltTracker, MatchConfig, Matcher, OrbConfig,
    OrbExtractor, Pyramid, PyramidConfig,
};
use rigslam::sensors::Image;

const EUROC_CAM0: &str = concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/../shared/data/euroc/V1_01_micro/mav0/cam0/data"
);

fn frame_pair() -> (Image, Image) {
    let mut paths: Vec<_> = std::fs::read_dir(Path::new(EUROC_CAM0))
        .map(|d| d.filter_map(|e| e.ok().map(|e| e.path())).collect())
        .unwrap_or_default();
    paths.sort();
    if paths.len() >= 2 {
        return (
            read_png(&paths[0]).expect("EuRoC frame decodes"),
            read_png(&paths[1]).expect("EuRoC frame decodes"),
        );
    }
    // Synthetic 752x480 texture, shifted by (1.5, 0.5) px in the second frame.
    let render = |dx: f64, dy: f64| {
        let pixels = (0..480 * 752)
            .map(|k| {
                let (x, y) = ((k % 752) as f64 - dx, (k / 752) as f64 - dy);
                (128.0 + 60.0 * (x / 7.0).sin() * (y / 5.0).cos() + 40.0 * ((x + y) / 11.0).sin())
                    as u8
            })
            .collect();
        Image::mono8(752, 480, pixels).expect("non-empty image")
    };
    (render(0.0, 0.0), render(1.5, 0.5))
}

fn frontend(c: &mut Criterion) {
    let (a, b) = frame_pair();
    let mut prev = Pyramid::new(PyramidConfig::klt()).unwrap();
    let mut cur = Pyramid::new(PyramidConfig::klt()).unwrap();
    prev.build(&a).unwrap();
    cur.build(&b).unwrap();

    c.bench_function("pyramid_klt_3_levels", |bench| {
        bench.iter(|| cur.build(black_box(&b)).unwrap())
    });

    let mut detector = CornerDetector::new(CornerConfig::default());
    let mut corners: Vec<Corner> = Vec::new();
    c.bench_function("corners_fast_shi_tomasi_200", |bench| {
        bench.iter(|| detector.detect(prev.level(0), &[], 200, &mut corners))
    });
    detector.detect(prev.level(0), &[], 200, &mut corners);
    let points: Vec<[f32; 2]> = corners.iter().map(|c| [c.x as f32, c.y as f32]).collect();

    let mut tracker = KltTracker::new(KltConfig::default()).unwrap();
    let (mut out, mut status) = (Vec::new(), Vec::new());
    c.bench_function("klt_track_200_forward_backward", |bench| {
        bench.iter(|| tracker.track(&prev, &cur, black_box(&points), None, &mut out, &mut status))
    });
    let mut affine = KltTracker::new(KltConfig {
        affine_refinement: true,
        ..KltConfig::default()
    })
    .unwrap();
    c.bench_function("klt_track_200_forward_backward_affine", |bench| {
        bench.iter(|| affine.track(&prev, &cur, black_box(&points), None, &mut out, &mut status))
    });

    let mut orb = OrbExtractor::new(OrbConfig::default()).unwrap();
    let (mut k0, mut d0, mut k1, mut d1) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    c.bench_function("orb_extract_1000", |bench| {
        bench.iter(|| orb.extract(black_box(&a), &mut k0, &mut d0).unwrap())
    });
    orb.extract(&a, &mut k0, &mut d0).unwrap();
    orb.extract(&b, &mut k1, &mut d1).unwrap();
    let mut matcher = Matcher::new(MatchConfig::default());
    let mut matches = Vec::new();
    c.bench_function("hamming_match_1000x1000_ratio_mutual", |bench| {
        bench.iter(|| matcher.match_into(black_box(&d0), &d1, None, &mut matches))
    });
}

criterion_group!(benches, frontend);
criterion_main!(benches);
