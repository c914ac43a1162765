//! Preintegration speed per IMU sample on the real V1_01 IMU: the same 200
//! intervals (every 14th between consecutive 20 Hz ground-truth stamps,
//! 2000 sample steps) that `bench/peers/gtsam_preintegration.sh` integrates
//! and times with GTSAM. Deltas, covariance and bias Jacobians, per scheme.
//!
//! `cargo bench -p rigslam --bench preintegration` (numbers in bench/README.md).

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use rigslam::dataset::{read_euroc_groundtruth, read_euroc_imu_csv};
use rigslam::imu::{
    ImuBiases, ImuIntrinsics, ImuStream, IntegrationScheme, IntervalConfig, Preintegrator,
};
use rigslam::rig::ImuNoise;

const INTERVALS: usize = 200;

fn bench(c: &mut Criterion) {
    let data = rigslam::shared_data::shared_data_dir()
        .expect("the benchmark needs ../shared/data")
        .join("euroc");
    let imu =
        read_euroc_imu_csv(&data.join("V1_01_micro/mav0/imu0/data.csv")).expect("V1_01 IMU reads");
    let gt = read_euroc_groundtruth(&data.join("ground_truth/V1_01_gt_camrate.csv"))
        .expect("V1_01 ground truth reads");
    let stream = ImuStream::from_samples(ImuIntrinsics::IDENTITY, &imu.samples);
    // The peer's choice: every stride-th interval over the whole flight.
    let stride = (gt.len() - 1) / INTERVALS;
    let work: Vec<_> = (0..INTERVALS)
        .map(|n| {
            let (a, b) = (&gt[n * stride], &gt[n * stride + 1]);
            let interval = stream
                .interval(a.t_ns, b.t_ns, &IntervalConfig::default())
                .expect("covered");
            let biases = ImuBiases {
                gyro_rad_s: a.gyro_bias_rad_s,
                accel_m_s2: a.accel_bias_m_s2,
            };
            (interval, biases)
        })
        .collect();
    let mut group = c.benchmark_group("preintegration");
    for scheme in IntegrationScheme::ALL {
        let mut integrator = Preintegrator::new(scheme, ImuNoise::EUROC_ADIS16448);
        let steps: usize = work
            .iter()
            .map(|(iv, b)| {
                integrator
                    .integrate_interval(iv, b)
                    .expect("integrable")
                    .steps
            })
            .sum();
        group.throughput(Throughput::Elements(steps as u64));
        group.bench_function(format!("{}_{steps}_samples", scheme.name()), |bencher| {
            bencher.iter(|| {
                let mut sum = 0.0;
                for (interval, biases) in &work {
                    let pre = integrator
                        .integrate_interval(interval, biases)
                        .expect("integrable");
                    sum += pre.delta_v_m_s.x + pre.covariance[(8, 8)];
                }
                std::hint::black_box(sum)
            })
        });
    }
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
