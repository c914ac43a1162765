//! Synthetic IMU: what an ideal gyroscope and accelerometer riding the
//! motion measure, plus Kalibr's noise model.
//!
//! Gyro = body angular rate; accel = R_world_body^T (a_world - g) with
//! g = (0, 0, -9.81). Noise (Kalibr wiki "IMU Noise Model", after Trawny &
//! Roumeliotis): white noise of continuous density sigma_c becomes
//! sigma_c / sqrt(dt) per sample; each bias is a random walk whose
//! per-sample step has standard deviation sigma_b * sqrt(dt).

use nalgebra::Vector3;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};

use super::motion::Motion;
use crate::imu::strapdown::gravity_world_m_s2;
use crate::imu::ImuBiases;
use crate::rig::ImuNoise;
use crate::sensors::ImuSample;

/// How to synthesise the IMU stream.
#[derive(Debug, Clone, PartialEq)]
pub struct ImuSynthConfig {
    /// Sample rate, Hz.
    pub rate_hz: f64,
    /// Continuous-time densities; `None` gives ideal (noise-free, bias-free
    /// beyond `initial_biases`) measurements.
    pub noise: Option<ImuNoise>,
    /// Biases at the first sample.
    pub initial_biases: ImuBiases,
    /// Seed of the noise and bias random walk; the same seed gives the same stream.
    pub seed: u64,
}

impl Default for ImuSynthConfig {
    fn default() -> Self {
        Self {
            rate_hz: 200.0,
            noise: Some(ImuNoise::EUROC_ADIS16448),
            // Of the order EuRoC's ground truth reports for its ADIS16448.
            initial_biases: ImuBiases {
                gyro_rad_s: Vector3::new(-0.0021, 0.0207, 0.0758),
                accel_m_s2: Vector3::new(-0.0133, 0.1035, 0.0931),
            },
            seed: 0,
        }
    }
}

/// The samples and the true bias at each of them.
#[derive(Debug, Clone, PartialEq)]
pub struct SynthImu {
    /// The synthetic samples (specific force and rate in the body frame, stamps in the sequence's
    /// clock, ns).
    pub samples: Vec<ImuSample>,
    /// The true biases at each sample.
    pub biases: Vec<ImuBiases>,
}

/// Ideal measurement (no noise, no bias) at `t_ns`.
pub fn ideal_sample(motion: &Motion, t_ns: i64) -> ImuSample {
    let s = motion.state(t_ns);
    let r = s.T_world_body.rotation;
    let specific_force = r.inverse() * (s.accel_world_m_s2 - gravity_world_m_s2());
    ImuSample {
        t_ns,
        gyro_rad_s: s.omega_body_rad_s.into(),
        accel_m_s2: specific_force.into(),
    }
}

/// Samples every `1 / rate_hz` from `start_ns` while not past `end_ns`.
pub fn synthesize(
    motion: &Motion,
    start_ns: i64,
    end_ns: i64,
    config: &ImuSynthConfig,
) -> SynthImu {
    let period_ns = (1e9 / config.rate_hz).round() as i64;
    let dt_s = period_ns as f64 * 1e-9;
    let mut rng = ChaCha8Rng::seed_from_u64(config.seed);
    let normal3 = |rng: &mut ChaCha8Rng| {
        Vector3::new(
            StandardNormal.sample(rng),
            StandardNormal.sample(rng),
            StandardNormal.sample(rng),
        )
    };
    let mut bias = config.initial_biases;
    let count = ((end_ns - start_ns) / period_ns + 1).max(0) as usize;
    let mut samples = Vec::with_capacity(count);
    let mut biases = Vec::with_capacity(count);
    for k in 0..count {
        let t_ns = start_ns + k as i64 * period_ns;
        let ideal = ideal_sample(motion, t_ns);
        let mut gyro = Vector3::from(ideal.gyro_rad_s) + bias.gyro_rad_s;
        let mut accel = Vector3::from(ideal.accel_m_s2) + bias.accel_m_s2;
        biases.push(bias);
        if let Some(noise) = &config.noise {
            gyro += normal3(&mut rng) * (noise.gyroscope_noise_density / dt_s.sqrt());
            accel += normal3(&mut rng) * (noise.accelerometer_noise_density / dt_s.sqrt());
            bias.gyro_rad_s += normal3(&mut rng) * (noise.gyroscope_random_walk * dt_s.sqrt());
            bias.accel_m_s2 += normal3(&mut rng) * (noise.accelerometer_random_walk * dt_s.sqrt());
        }
        samples.push(ImuSample {
            t_ns,
            gyro_rad_s: gyro.into(),
            accel_m_s2: accel.into(),
        });
    }
    SynthImu { samples, biases }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::imu::{integrate, NavState};
    use crate::simulate::motion::BuiltinMotion;

    fn initial_state(motion: &Motion, t_ns: i64) -> NavState {
        let s = motion.state(t_ns);
        NavState {
            t_ns,
            R_world_body: s.T_world_body.rotation,
            position_world_m: s.T_world_body.translation.vector,
            velocity_world_m_s: s.velocity_world_m_s,
        }
    }

    /// Position and attitude error after integrating `duration_s` of ideal
    /// samples at `rate_hz` from the true initial state.
    fn integrate_back_error(rate_hz: f64, duration_s: f64) -> (f64, f64) {
        let motion = Motion::Builtin(BuiltinMotion::standard(0, duration_s));
        let config = ImuSynthConfig {
            rate_hz,
            noise: None,
            initial_biases: ImuBiases::default(),
            seed: 0,
        };
        let imu = synthesize(&motion, 0, motion.end_ns(), &config);
        let end = *integrate(
            &initial_state(&motion, 0),
            &imu.samples,
            &ImuBiases::default(),
        )
        .unwrap()
        .last()
        .unwrap();
        let truth = motion.state(end.t_ns);
        (
            (end.position_world_m - truth.T_world_body.translation.vector).norm(),
            end.R_world_body.angle_to(&truth.T_world_body.rotation),
        )
    }

    #[test]
    fn ideal_imu_integrates_back_to_the_trajectory() {
        // Error budget: the integrator interpolates the measurements
        // linearly between samples, which errs by at most dt^2/8 max|x''|.
        // Bound max|f''| and max|w''| by finite differences of the ideal
        // signal, then propagate over T: attitude <= T e_w, velocity <=
        // T (e_f + |f|max * attitude), position <= T/2 * velocity.
        let duration_s = 10.0;
        let rate_hz = 200.0;
        let dt_s = 1.0 / rate_hz;
        let motion = Motion::Builtin(BuiltinMotion::standard(0, duration_s));
        let h_ns = 10_000_000;
        let h_s = h_ns as f64 * 1e-9;
        let (mut f2_max, mut w2_max, mut f_max) = (0.0f64, 0.0f64, 0.0f64);
        for k in 1..999 {
            let t = k * h_ns;
            let [a, b, c] = [t - h_ns, t, t + h_ns].map(|t| ideal_sample(&motion, t));
            let second = |x: [f64; 3], y: [f64; 3], z: [f64; 3]| {
                (Vector3::from(x) - 2.0 * Vector3::from(y) + Vector3::from(z)).norm() / (h_s * h_s)
            };
            f2_max = f2_max.max(second(a.accel_m_s2, b.accel_m_s2, c.accel_m_s2));
            w2_max = w2_max.max(second(a.gyro_rad_s, b.gyro_rad_s, c.gyro_rad_s));
            f_max = f_max.max(Vector3::from(b.accel_m_s2).norm());
        }
        let e_w = dt_s * dt_s / 8.0 * w2_max;
        let e_f = dt_s * dt_s / 8.0 * f2_max;
        let attitude_bound = duration_s * e_w;
        let velocity_bound = duration_s * (e_f + f_max * attitude_bound);
        let position_bound = duration_s / 2.0 * velocity_bound;
        let (p_err, r_err) = integrate_back_error(rate_hz, duration_s);
        println!("after {duration_s} s at {rate_hz} Hz: position error {p_err:.3e} m (bound {position_bound:.3e}), attitude error {r_err:.3e} rad (bound {attitude_bound:.3e})");
        assert!(p_err < position_bound, "{p_err} >= {position_bound}");
        assert!(r_err < attitude_bound, "{r_err} >= {attitude_bound}");
        // The error must also shrink like dt^2: doubling the rate quarters it.
        let (p_err_400, _) = integrate_back_error(400.0, duration_s);
        println!(
            "at 400 Hz: position error {p_err_400:.3e} m, ratio {:.2}",
            p_err / p_err_400
        );
        assert!(p_err / p_err_400 > 3.0, "ratio {}", p_err / p_err_400);
    }

    #[test]
    fn noise_and_bias_walk_have_the_configured_statistics() {
        let motion = Motion::Builtin(BuiltinMotion::standard(0, 100.0));
        let noise = ImuNoise::EUROC_ADIS16448;
        let noisy = synthesize(
            &motion,
            0,
            motion.end_ns(),
            &ImuSynthConfig {
                noise: Some(noise),
                seed: 3,
                ..Default::default()
            },
        );
        let dt_s: f64 = 0.005;
        let n = noisy.samples.len();
        let (mut g2, mut a2, mut bg2, mut ba2) = (0.0, 0.0, 0.0, 0.0);
        for k in 0..n {
            let ideal = ideal_sample(&motion, noisy.samples[k].t_ns);
            let b = &noisy.biases[k];
            g2 += (Vector3::from(noisy.samples[k].gyro_rad_s)
                - Vector3::from(ideal.gyro_rad_s)
                - b.gyro_rad_s)
                .norm_squared();
            a2 += (Vector3::from(noisy.samples[k].accel_m_s2)
                - Vector3::from(ideal.accel_m_s2)
                - b.accel_m_s2)
                .norm_squared();
            if k > 0 {
                let p = &noisy.biases[k - 1];
                bg2 += (b.gyro_rad_s - p.gyro_rad_s).norm_squared();
                ba2 += (b.accel_m_s2 - p.accel_m_s2).norm_squared();
            }
        }
        let m = 3.0 * n as f64;
        let ratio = |measured_var: f64, sigma: f64| (measured_var / m).sqrt() / sigma;
        // 60000 draws: the sample std is within 1% of the truth (4 sigma).
        for (name, r) in [
            (
                "gyro white",
                ratio(g2, noise.gyroscope_noise_density / dt_s.sqrt()),
            ),
            (
                "accel white",
                ratio(a2, noise.accelerometer_noise_density / dt_s.sqrt()),
            ),
            (
                "gyro walk",
                ratio(bg2, noise.gyroscope_random_walk * dt_s.sqrt()),
            ),
            (
                "accel walk",
                ratio(ba2, noise.accelerometer_random_walk * dt_s.sqrt()),
            ),
        ] {
            assert!((r - 1.0).abs() < 0.015, "{name}: std ratio {r}");
        }
    }

    #[test]
    fn noisy_integration_error_matches_the_noise_level() {
        // With the true biases removed, what is left is white noise. Over T
        // the accelerometer's gives a position error per axis of std
        // sigma_a sqrt(T^3/3); the gyroscope's an attitude random walk
        // (std sigma_g sqrt(t) per axis) that tilts gravity into the two
        // horizontal axes, position std g sigma_g sqrt(T^5/20). Compare the
        // RMS over seeds with the prediction.
        let duration_s = 3.0;
        let noise = ImuNoise::EUROC_ADIS16448;
        let motion = Motion::Builtin(BuiltinMotion::standard(0, duration_s));
        let seeds = 100;
        let mut sum_sq = 0.0;
        for seed in 0..seeds {
            let imu = synthesize(
                &motion,
                0,
                motion.end_ns(),
                &ImuSynthConfig {
                    noise: Some(noise),
                    seed,
                    ..Default::default()
                },
            );
            let corrected: Vec<ImuSample> = imu
                .samples
                .iter()
                .zip(&imu.biases)
                .map(|(s, b)| ImuSample {
                    t_ns: s.t_ns,
                    gyro_rad_s: (Vector3::from(s.gyro_rad_s) - b.gyro_rad_s).into(),
                    accel_m_s2: (Vector3::from(s.accel_m_s2) - b.accel_m_s2).into(),
                })
                .collect();
            let end = *integrate(
                &initial_state(&motion, 0),
                &corrected,
                &ImuBiases::default(),
            )
            .unwrap()
            .last()
            .unwrap();
            let truth = motion.state(end.t_ns).T_world_body.translation.vector;
            sum_sq += (end.position_world_m - truth).norm_squared();
        }
        let t = duration_s;
        let accel_var = noise.accelerometer_noise_density.powi(2) * t.powi(3) / 3.0;
        let gyro_var = (GRAVITY * noise.gyroscope_noise_density).powi(2) * t.powi(5) / 20.0;
        let predicted_rms = (3.0 * accel_var + 2.0 * gyro_var).sqrt();
        let measured_rms = (sum_sq / seeds as f64).sqrt();
        println!("noisy integrate-back over {t} s: RMS position error {measured_rms:.3e} m, predicted {predicted_rms:.3e} m");
        // 120 squared normal terms: the RMS lies within +-25% of the truth
        // with probability > 99.9%.
        let r = measured_rms / predicted_rms;
        assert!((0.75..1.25).contains(&r), "ratio {r}");
    }

    const GRAVITY: f64 = crate::imu::GRAVITY_M_S2;
}
