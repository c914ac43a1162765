//! The files the calibration writes for the daemon: Kalibr's `imu.yaml`
//! (continuous-time noise, read back by `rigslam::imu::read_kalibr_imu_yaml`)
//! and the IMU intrinsics `x_c = S x_r + b`.

use std::path::Path;

use nalgebra::{Matrix3, Vector3};
use rigslam::dataset::text::read_text;
use rigslam::dataset::DatasetError;
use rigslam::imu::ImuIntrinsics;
use rigslam::rig::ImuNoise;
use serde::{Deserialize, Serialize};

/// Kalibr's `imu.yaml`.
pub fn kalibr_imu_yaml(noise: &ImuNoise, rate_hz: f64, comment: &str) -> String {
    let mut out = String::new();
    for line in comment.lines() {
        out.push_str(&format!("# {line}\n"));
    }
    out.push_str(&format!(
        "rostopic: /imu0\nupdate_rate: {rate_hz}\n\
         accelerometer_noise_density: {:.6e}  # m/s^2/sqrt(Hz)\n\
         accelerometer_random_walk: {:.6e}  # m/s^3/sqrt(Hz)\n\
         gyroscope_noise_density: {:.6e}  # rad/s/sqrt(Hz)\n\
         gyroscope_random_walk: {:.6e}  # rad/s^2/sqrt(Hz)\n",
        noise.accelerometer_noise_density,
        noise.accelerometer_random_walk,
        noise.gyroscope_noise_density,
        noise.gyroscope_random_walk,
    ));
    out
}

/// The intrinsics file: rows of S, biases in SI (accel m/s^2, gyro rad/s).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct IntrinsicsFile {
    pub model: String,
    pub accel_scale_matrix: [[f64; 3]; 3],
    pub accel_bias: [f64; 3],
    pub gyro_scale_matrix: [[f64; 3]; 3],
    pub gyro_bias: [f64; 3],
}

fn rows(m: &Matrix3<f64>) -> [[f64; 3]; 3] {
    [0, 1, 2].map(|r| [m[(r, 0)], m[(r, 1)], m[(r, 2)]])
}

impl IntrinsicsFile {
    pub fn from_intrinsics(i: &ImuIntrinsics) -> Self {
        Self {
            model: "x_c = S x_r + b (accel m/s^2, gyro rad/s)".into(),
            accel_scale_matrix: rows(&i.accel_scale),
            accel_bias: i.accel_offset_m_s2.into(),
            gyro_scale_matrix: rows(&i.gyro_scale),
            gyro_bias: i.gyro_offset_rad_s.into(),
        }
    }

    pub fn intrinsics(&self) -> ImuIntrinsics {
        let m = |r: &[[f64; 3]; 3]| Matrix3::from_fn(|i, j| r[i][j]);
        ImuIntrinsics {
            gyro_scale: m(&self.gyro_scale_matrix),
            gyro_offset_rad_s: Vector3::from(self.gyro_bias),
            accel_scale: m(&self.accel_scale_matrix),
            accel_offset_m_s2: Vector3::from(self.accel_bias),
        }
    }
}

/// Reads what [`IntrinsicsFile`] writes.
pub fn read_intrinsics_yaml(path: &Path) -> Result<ImuIntrinsics, DatasetError> {
    parse_intrinsics_yaml(&read_text(path)?, path)
}

/// Parses the text of what [`IntrinsicsFile`] writes; `path` names it in
/// errors.
pub fn parse_intrinsics_yaml(text: &str, path: &Path) -> Result<ImuIntrinsics, DatasetError> {
    let file: IntrinsicsFile = serde_yaml::from_str(text).map_err(|e| {
        let line = e.location().map_or(0, |l| l.line());
        DatasetError::malformed(path, line, format!("not an IMU intrinsics file: {e}"))
    })?;
    Ok(file.intrinsics())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_kalibr_file_reads_back_through_the_core() {
        let noise = ImuNoise {
            gyroscope_noise_density: 1.234567e-4,
            gyroscope_random_walk: 2.5e-6,
            accelerometer_noise_density: 1.1e-3,
            accelerometer_random_walk: 4.4e-5,
        };
        let dir = tempfile::tempdir().expect("temp dir");
        let p = dir.path().join("imu.yaml");
        std::fs::write(&p, kalibr_imu_yaml(&noise, 100.0, "test\nsecond line")).expect("write");
        let (back, rate) = rigslam::imu::read_kalibr_imu_yaml(&p).expect("valid Kalibr file");
        assert_eq!(rate, 100.0);
        assert!((back.gyroscope_noise_density / noise.gyroscope_noise_density - 1.0).abs() < 1e-6);
        assert!(
            (back.accelerometer_random_walk / noise.accelerometer_random_walk - 1.0).abs() < 1e-6
        );
    }

    #[test]
    fn intrinsics_round_trip() {
        let i = ImuIntrinsics {
            gyro_scale: Matrix3::new(1.01, 0.002, 0.0, 0.0, 0.99, 0.0, 0.003, 0.0, 1.0),
            gyro_offset_rad_s: Vector3::new(0.001, 0.0, -0.002),
            accel_scale: Matrix3::new(1.02, 0.01, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.98),
            accel_offset_m_s2: Vector3::new(0.1, -0.2, 0.0),
        };
        let dir = tempfile::tempdir().expect("temp dir");
        let p = dir.path().join("imu_intrinsics.yaml");
        std::fs::write(
            &p,
            serde_yaml::to_string(&IntrinsicsFile::from_intrinsics(&i)).expect("serialises"),
        )
        .expect("write");
        assert_eq!(read_intrinsics_yaml(&p).expect("reads"), i);
        std::fs::write(&p, "accel_scale_matrix: 3\n").expect("write");
        let e = read_intrinsics_yaml(&p).expect_err("garbled").to_string();
        assert!(e.contains("not an IMU intrinsics file"), "{e}");
    }
}
