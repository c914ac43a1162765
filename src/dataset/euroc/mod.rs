//! The EuRoC ASL layout: `mav0/` holding `camN/` (`data.csv`, `data/<t_ns>.png`,
//! `sensor.yaml`), `imu0/` (`data.csv`, `sensor.yaml`) and
//! `state_groundtruth_estimate0/data.csv`. Reader, writer and the YAML
//! calibration files.

pub mod imu_csv;
pub mod reader;
pub use crate::rig::sensor_yaml;
pub mod writer;

pub use imu_csv::{read_euroc_imu_csv, write_euroc_imu_csv, ImuCsv};
pub use reader::{EurocCamera, EurocDataset, EurocImu, ImageEntry};
pub use sensor_yaml::{parse_camera_yaml, parse_imu_yaml, read_camera_yaml, read_imu_yaml};
pub use writer::EurocWriter;

/// Folder of the ground truth inside `mav0/`.
pub const GROUNDTRUTH_DIR: &str = "state_groundtruth_estimate0";
/// Folder of the IMU inside `mav0/`.
pub const IMU_DIR: &str = "imu0";
/// Header of a camera's `data.csv`.
pub const CAMERA_CSV_HEADER: &str = "#timestamp [ns],filename";

/// The N of a `camN` folder name, or `None` for any other name.
pub fn camera_number(name: &str) -> Option<u8> {
    let digits = name.strip_prefix("cam")?;
    if digits.is_empty() || !digits.bytes().all(|b| b.is_ascii_digit()) {
        return None;
    }
    digits.parse().ok()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn camera_numbers() {
        assert_eq!(camera_number("cam0"), Some(0));
        assert_eq!(camera_number("cam12"), Some(12));
        for bad in ["cam", "cam-1", "cam+1", "camx", "imu0", "cam999"] {
            assert_eq!(camera_number(bad), None, "{bad}");
        }
    }
}
