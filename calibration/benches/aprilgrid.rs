//! Speed of the AprilGrid detector on the real EuRoC cam0 image (752x480,
//! all 36 tags in view) and on an image without a grid (the chessboard
//! photograph), one thread. Results in bench/README.md.

use criterion::{criterion_group, criterion_main, Criterion};
use rigslam::shared_data::shared_data_dir;
use rigslam_calibration::aprilgrid::{detect_aprilgrid, AprilGridTarget};

fn bench(c: &mut Criterion) {
    let Some(data) = shared_data_dir() else {
        return;
    };
    let dir = data.join("calib/euroc_imu_april");
    let target = AprilGridTarget::from_yaml_file(&dir.join("target.yaml")).expect("target.yaml");
    let grid = image::open(dir.join("cam0_1403709395937837056.png"))
        .expect("image")
        .to_luma8();
    let empty = image::open(data.join("calib/chessboard_9x6_25mm/left01.jpg"))
        .expect("image")
        .to_luma8();
    let mut group = c.benchmark_group("aprilgrid");
    group.sample_size(30);
    group.bench_function("euroc_cam0_752x480", |b| {
        b.iter(|| detect_aprilgrid(&grid, &target))
    });
    group.bench_function("chessboard_no_grid", |b| {
        b.iter(|| detect_aprilgrid(&empty, &target))
    });
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
