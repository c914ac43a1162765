//! The files the calibration writes for the daemon: Kalibr's `imu.yaml`
//! (continuous-time noise) and the IMU intrinsics `x_c = S x_r + b`; the
//! types and readers live in `rigslam::rig` (the daemon reads them too).

use rigslam::rig::ImuNoise;

/// Kalibr's `imu.yaml` (through [`rigslam::rig::kalibr::imu_yaml`]) with
/// `comment` as `#` lines above it.
pub fn kalibr_imu_yaml(noise: &ImuNoise, rate_hz: f64, comment: &str) -> String {
    let mut out: String = comment.lines().map(|l| format!("# {l}\n")).collect();
    out.push_str(&rigslam::rig::kalibr::imu_yaml(noise, rate_hz));
    out
}

pub use rigslam::rig::imu_intrinsics_file::{
    parse_intrinsics_yaml, read_intrinsics_yaml, IntrinsicsFile,
};

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
        let text = std::fs::read_to_string(&p).expect("written above");
        let imu = rigslam::rig::kalibr::imu_from_kalibr(&text, &p).expect("valid Kalibr file");
        let (back, rate) = (imu.noise, imu.rate_hz);
        assert_eq!(rate, 100.0);
        assert!((back.gyroscope_noise_density / noise.gyroscope_noise_density - 1.0).abs() < 1e-6);
        assert!(
            (back.accelerometer_random_walk / noise.accelerometer_random_walk - 1.0).abs() < 1e-6
        );
    }
}
