//! `imu_intrinsics.yaml`: the IMU's intrinsic correction `x_c = S x_r + b`
//! as `rigslam-calibrate imu` writes it (rows of each `S`, biases in SI:
//! accelerometer m/s^2, gyroscope rad/s), read by the daemon and
//! `rigslam run` to correct every raw sample. A scale matrix that cannot
//! be inverted is refused: it would map different readings to one.

use std::path::Path;

use nalgebra::{Matrix3, Vector3};
use serde::{Deserialize, Serialize};

use crate::rig::ImuIntrinsics;
use crate::text_file::text::read_text;
use crate::text_file::DatasetError;

/// The intrinsics file: rows of S, biases in SI (accel m/s^2, gyro rad/s).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct IntrinsicsFile {
    /// Human-readable statement of the model, `x_c = S x_r + b (accel m/s^2, gyro rad/s)`; not
    /// interpreted when read.
    pub model: String,
    /// Accelerometer `S`, row by row.
    pub accel_scale_matrix: [[f64; 3]; 3],
    /// Accelerometer `b`, m/s^2.
    pub accel_bias: [f64; 3],
    /// Gyroscope `S`, row by row.
    pub gyro_scale_matrix: [[f64; 3]; 3],
    /// Gyroscope `b`, rad/s.
    pub gyro_bias: [f64; 3],
}

fn rows(m: &Matrix3<f64>) -> [[f64; 3]; 3] {
    [0, 1, 2].map(|r| [m[(r, 0)], m[(r, 1)], m[(r, 2)]])
}

impl IntrinsicsFile {
    /// The file contents for `i`.
    pub fn from_intrinsics(i: &ImuIntrinsics) -> Self {
        Self {
            model: "x_c = S x_r + b (accel m/s^2, gyro rad/s)".into(),
            accel_scale_matrix: rows(&i.accel_scale),
            accel_bias: i.accel_offset_m_s2.into(),
            gyro_scale_matrix: rows(&i.gyro_scale),
            gyro_bias: i.gyro_offset_rad_s.into(),
        }
    }

    /// The correction the file describes (no check that `S` is invertible; the reader does that).
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
    let values = file
        .accel_scale_matrix
        .iter()
        .chain(&file.gyro_scale_matrix)
        .flatten()
        .chain(&file.accel_bias)
        .chain(&file.gyro_bias);
    if values.clone().any(|v| !v.is_finite()) {
        return Err(DatasetError::malformed(
            path,
            1,
            "holds a value that is not a finite number",
        ));
    }
    let intrinsics = file.intrinsics();
    for (field, s) in [
        ("accel_scale_matrix", &intrinsics.accel_scale),
        ("gyro_scale_matrix", &intrinsics.gyro_scale),
    ] {
        // A real triad's S is near identity: det about 1, never near 0.
        let det = s.determinant();
        if !(0.5..=2.0).contains(&det) {
            return Err(DatasetError::bad_field(
                path,
                field,
                format!(
                    "determinant {det:.3e}: a sensor triad's scale and misalignment is close to the identity \
                     (determinant about 1); this matrix is singular or far off, recalibrate with `rigslam-calibrate imu`"
                ),
            ));
        }
    }
    Ok(intrinsics)
}

/// The file's YAML text.
pub fn intrinsics_yaml(intrinsics: &ImuIntrinsics) -> String {
    serde_yaml::to_string(&IntrinsicsFile::from_intrinsics(intrinsics))
        .expect("a struct of numbers and strings serialises")
}

#[cfg(test)]
mod tests {
    use super::*;

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

    #[test]
    fn a_singular_scale_matrix_is_refused() {
        let mut i = ImuIntrinsics::IDENTITY;
        i.gyro_scale[(2, 2)] = 0.0;
        let e = parse_intrinsics_yaml(&intrinsics_yaml(&i), Path::new("imu_intrinsics.yaml"))
            .expect_err("singular")
            .to_string();
        assert!(
            e.contains("gyro_scale_matrix") && e.contains("determinant"),
            "{e}"
        );
    }
}
