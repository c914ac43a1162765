//! Speed of the noise analysis (target: one million samples on six
//! axes in under 2 s): the still check, six overlapping Allan curves at 51
//! cluster times (one thread per axis) and the fits, on a simulated still
//! log of 1 000 000 samples at 100 Hz. Results in bench/README.md.

use criterion::{criterion_group, criterion_main, Criterion};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use rigslam::sensors::ImuSample;
use rigslam_calibration::allan::{cluster_sizes, overlapping_adev};
use rigslam_calibration::noise_calibration::{calibrate_noise, StillnessLimits};

fn still_log(n: usize) -> Vec<ImuSample> {
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    let gyro = Normal::new(0.0, 2e-3).expect("valid sigma");
    let accel = Normal::new(0.0, 2e-2).expect("valid sigma");
    (0..n)
        .map(|i| ImuSample {
            t_ns: i as i64 * 10_000_000,
            gyro_rad_s: [
                gyro.sample(&mut rng),
                gyro.sample(&mut rng),
                gyro.sample(&mut rng),
            ],
            accel_m_s2: [
                accel.sample(&mut rng),
                accel.sample(&mut rng),
                9.81 + accel.sample(&mut rng),
            ],
        })
        .collect()
}

fn bench(c: &mut Criterion) {
    let log = still_log(1_000_000);
    let mut group = c.benchmark_group("noise");
    group.sample_size(10);
    group.bench_function("calibrate_noise_1M_x6", |b| {
        b.iter(|| {
            calibrate_noise(&log, 100.0, 10, &StillnessLimits::default()).expect("a still log")
        })
    });
    let y: Vec<f64> = log.iter().map(|s| s.gyro_rad_s[0]).collect();
    let m = cluster_sizes(y.len(), 10);
    group.bench_function("overlapping_adev_1M_one_axis", |b| {
        b.iter(|| overlapping_adev(&y, 100.0, &m))
    });
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
