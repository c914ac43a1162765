//! IMU noise: Kalibr's continuous-time densities and random walks (the
//! rig's [`ImuNoise`], read from `imu.yaml` or EuRoC's `imu0/sensor.yaml`
//! by [`crate::rig`]) and their discrete-time equivalents for the actual spacing of the samples (Kalibr wiki,
//! "IMU Noise Model": `sigma_d = sigma_c / sqrt(dt)` for white noise,
//! `sigma_bd = sigma_bc sqrt(dt)` for the bias random walk).

use nalgebra::{Matrix6, Vector6};

use crate::rig::ImuNoise;

/// Standard deviations of one sample's noise for a spacing of `dt_s`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DiscreteNoise {
    /// Sample spacing the sigmas are for, s.
    pub dt_s: f64,
    /// rad/s, per sample.
    pub gyro_sigma_rad_s: f64,
    /// m/s^2, per sample.
    pub accel_sigma_m_s2: f64,
    /// rad/s, bias change over one sample step.
    pub gyro_bias_step_sigma_rad_s: f64,
    /// m/s^2, bias change over one sample step.
    pub accel_bias_step_sigma_m_s2: f64,
}

impl DiscreteNoise {
    /// The discrete noise of samples `dt_s` apart (`dt_s` > 0).
    pub fn from_continuous(noise: &ImuNoise, dt_s: f64) -> Self {
        let root = dt_s.sqrt();
        Self {
            dt_s,
            gyro_sigma_rad_s: noise.gyroscope_noise_density / root,
            accel_sigma_m_s2: noise.accelerometer_noise_density / root,
            gyro_bias_step_sigma_rad_s: noise.gyroscope_random_walk * root,
            accel_bias_step_sigma_m_s2: noise.accelerometer_random_walk * root,
        }
    }
}

/// Covariance of the bias change `[d b_g, d b_a]` over `dt_s` under the
/// random walk: what links the biases of two frames in the estimator.
pub fn bias_walk_covariance(noise: &ImuNoise, dt_s: f64) -> Matrix6<f64> {
    let g = noise.gyroscope_random_walk.powi(2) * dt_s;
    let a = noise.accelerometer_random_walk.powi(2) * dt_s;
    Matrix6::from_diagonal(&Vector6::new(g, g, g, a, a, a))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn discrete_noise_scales_with_the_actual_spacing() {
        let n = ImuNoise::EUROC_ADIS16448;
        let d = DiscreteNoise::from_continuous(&n, 0.005);
        // sigma_d^2 dt = sigma_c^2 (white), sigma_bd^2 / dt = sigma_bc^2 (walk).
        assert!(
            (d.gyro_sigma_rad_s.powi(2) * 0.005 - n.gyroscope_noise_density.powi(2)).abs() < 1e-20
        );
        assert!(
            (d.accel_sigma_m_s2.powi(2) * 0.005 - n.accelerometer_noise_density.powi(2)).abs()
                < 1e-18
        );
        assert!(
            (d.accel_bias_step_sigma_m_s2.powi(2) / 0.005 - n.accelerometer_random_walk.powi(2))
                .abs()
                < 1e-18
        );
        // A dropped sample doubles the spacing: white noise shrinks by sqrt 2.
        let d2 = DiscreteNoise::from_continuous(&n, 0.010);
        assert!((d.gyro_sigma_rad_s / d2.gyro_sigma_rad_s - 2f64.sqrt()).abs() < 1e-12);
        let walk = bias_walk_covariance(&n, 2.0);
        assert!((walk[(0, 0)] - 2.0 * n.gyroscope_random_walk.powi(2)).abs() < 1e-24);
        assert!((walk[(5, 5)] - 2.0 * n.accelerometer_random_walk.powi(2)).abs() < 1e-20);
    }
}
