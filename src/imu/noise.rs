//! IMU noise: Kalibr's continuous-time densities and random walks
//! (`imu.yaml`, or EuRoC's `imu0/sensor.yaml`) and their discrete-time
//! equivalents for the actual spacing of the samples (Kalibr wiki,
//! "IMU Noise Model": `sigma_d = sigma_c / sqrt(dt)` for white noise,
//! `sigma_bd = sigma_bc sqrt(dt)` for the bias random walk).

use std::path::Path;

use nalgebra::{Matrix6, Vector6};
use serde_yaml::Value;

use crate::rig::ImuNoise;
use crate::text_file::text::read_text;
use crate::text_file::DatasetError;

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

/// Reads Kalibr's `imu.yaml` (the four noise keys and `update_rate`, at
/// the top level or under `imu0:`) or a EuRoC `sensor.yaml` (`rate_hz`).
/// Returns the noise and the nominal rate in Hz.
pub fn read_kalibr_imu_yaml(path: &Path) -> Result<(ImuNoise, f64), DatasetError> {
    parse_kalibr_imu_yaml(&read_text(path)?, path)
}

/// Parses the text of a Kalibr `imu.yaml` or EuRoC `sensor.yaml`; `path`
/// names it in errors.
pub fn parse_kalibr_imu_yaml(text: &str, path: &Path) -> Result<(ImuNoise, f64), DatasetError> {
    // EuRoC files begin with OpenCV's `%YAML:1.0`, which YAML parsers reject.
    let body: String = text
        .lines()
        .filter(|l| !l.starts_with('%'))
        .collect::<Vec<_>>()
        .join("\n");
    let doc: Value = serde_yaml::from_str(&body).map_err(|e| {
        let line = e.location().map_or(0, |l| l.line());
        DatasetError::malformed(path, line, format!("not valid YAML: {e}"))
    })?;
    let doc = match doc.get("imu0") {
        Some(inner) if inner.is_mapping() => inner,
        _ => &doc,
    };
    let positive = |field: &str| -> Result<f64, DatasetError> {
        let value = doc
            .get(field)
            .ok_or_else(|| DatasetError::bad_field(path, field, "missing"))?;
        match value.as_f64() {
            Some(v) if v.is_finite() && v > 0.0 => Ok(v),
            _ => Err(DatasetError::bad_field(
                path,
                field,
                format!("expected a positive number, found {value:?}"),
            )),
        }
    };
    let noise = ImuNoise {
        gyroscope_noise_density: positive("gyroscope_noise_density")?,
        gyroscope_random_walk: positive("gyroscope_random_walk")?,
        accelerometer_noise_density: positive("accelerometer_noise_density")?,
        accelerometer_random_walk: positive("accelerometer_random_walk")?,
    };
    let rate_hz = if doc.get("update_rate").is_some() {
        positive("update_rate")?
    } else {
        positive("rate_hz")?
    };
    Ok((noise, rate_hz))
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

    #[test]
    fn reads_kalibr_and_euroc_files_and_names_bad_fields() {
        let dir = tempfile::tempdir().expect("temp dir");
        let kalibr = dir.path().join("imu.yaml");
        std::fs::write(
            &kalibr,
            "accelerometer_noise_density: 1.86e-03\naccelerometer_random_walk: 4.33e-04\n\
             gyroscope_noise_density: 1.87e-04\ngyroscope_random_walk: 2.66e-05\n\
             rostopic: /imu0\nupdate_rate: 200.0\n",
        )
        .expect("write");
        let (noise, rate) = read_kalibr_imu_yaml(&kalibr).expect("valid");
        assert_eq!(rate, 200.0);
        assert_eq!(noise.gyroscope_random_walk, 2.66e-05);
        assert_eq!(noise.accelerometer_noise_density, 1.86e-03);

        let euroc = concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../shared/data/euroc/V1_01_micro/mav0/imu0/sensor.yaml"
        );
        if Path::new(euroc).exists() {
            let (noise, rate) = read_kalibr_imu_yaml(Path::new(euroc)).expect("EuRoC yaml");
            assert_eq!(noise, ImuNoise::EUROC_ADIS16448);
            assert_eq!(rate, 200.0);
        }

        let bad = dir.path().join("bad.yaml");
        std::fs::write(
            &bad,
            "imu0:\n  accelerometer_noise_density: -1\n  accelerometer_random_walk: 1\n",
        )
        .expect("write");
        let err = read_kalibr_imu_yaml(&bad).expect_err("negative density");
        assert!(
            matches!(&err, DatasetError::BadField { field, .. } if field == "gyroscope_noise_density"),
            "{err}"
        );
        std::fs::write(&bad, "gyroscope_noise_density: 1\ngyroscope_random_walk: 1\naccelerometer_noise_density: x\n").expect("write");
        let err = read_kalibr_imu_yaml(&bad).expect_err("text density");
        assert!(
            err.to_string().contains("accelerometer_noise_density"),
            "{err}"
        );
    }
}
