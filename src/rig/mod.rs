//! The rig's calibration as the rest of the core sees it: each camera's
//! model, mounting and clock offset, the IMU's mounting, noise and
//! intrinsic correction. Readers fill these from EuRoC `sensor.yaml`
//! files ([`crate::rig::sensor_yaml::read_camera_yaml`]), from Kalibr's
//! `camchain-imucam.yaml` and `imu.yaml` ([`kalibr`]) or from a whole
//! calibration folder as `rigslam-calibrate` writes it ([`folder`]); the
//! simulator writes them back out.

use nalgebra::Isometry3;

use crate::camera::CameraModel;

pub mod euroc;
pub mod folder;
pub mod imu_intrinsics;
pub mod imu_intrinsics_file;
pub use imu_intrinsics::ImuIntrinsics;
pub mod kalibr;
pub mod sensor_yaml;

/// One camera of the rig.
#[allow(non_snake_case)]
#[derive(Debug, Clone, PartialEq)]
pub struct CameraCalibration {
    /// Projection and distortion model with its parameters, px.
    pub model: CameraModel,
    /// Maps camera coordinates into the body (IMU) frame (EuRoC's `T_BS`).
    pub T_body_cam: Isometry3<f64>,
    /// Nominal frame rate, Hz; 0 when the file does not say (Kalibr's
    /// camchain has no rate).
    pub rate_hz: f64,
    /// Kalibr's `timeshift_cam_imu`: the IMU clock reads
    /// `t_imu = t_cam + shift` at the instant a frame is stamped `t_cam`, s.
    pub time_shift_cam_imu_s: f64,
}

impl CameraCalibration {
    /// [`Self::time_shift_cam_imu_s`] in whole nanoseconds.
    pub fn time_shift_ns(&self) -> i64 {
        (self.time_shift_cam_imu_s * 1e9).round() as i64
    }
}

/// Continuous-time IMU noise, Kalibr convention, SI units.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ImuNoise {
    /// rad/s/sqrt(Hz)
    pub gyroscope_noise_density: f64,
    /// rad/s^2/sqrt(Hz)
    pub gyroscope_random_walk: f64,
    /// m/s^2/sqrt(Hz)
    pub accelerometer_noise_density: f64,
    /// m/s^3/sqrt(Hz)
    pub accelerometer_random_walk: f64,
}

impl ImuNoise {
    /// The ADIS16448 values EuRoC ships in `imu0/sensor.yaml`.
    pub const EUROC_ADIS16448: ImuNoise = ImuNoise {
        gyroscope_noise_density: 1.6968e-04,
        gyroscope_random_walk: 1.9393e-05,
        accelerometer_noise_density: 2.0e-3,
        accelerometer_random_walk: 3.0e-3,
    };
}

/// The IMU: where it sits and how noisy it is.
#[allow(non_snake_case)]
#[derive(Debug, Clone, PartialEq)]
pub struct ImuCalibration {
    /// Maps IMU coordinates into the body frame (identity when the body is the IMU).
    pub T_body_imu: Isometry3<f64>,
    /// IMU sample rate, Hz (turns the noise densities into per-sample sigmas).
    pub rate_hz: f64,
    /// Noise densities and bias random walks (continuous time, Kalibr's convention).
    pub noise: ImuNoise,
    /// Scale, misalignment and offset applied to every raw sample before
    /// it is used (`rigslam-calibrate imu`; identity for a sensor
    /// calibrated at the factory).
    pub intrinsics: ImuIntrinsics,
}

/// The whole rig: camera 0 (left), camera 1 (right, stereo modes only)
/// and the IMU (inertial modes only). `crate::relative::RigModel::check`
/// says whether it serves a mode.
#[derive(Debug, Clone, PartialEq)]
pub struct RigModel {
    /// Camera 0 (left) first, then camera 1 (right) in the stereo modes.
    pub cameras: Vec<CameraCalibration>,
    /// The IMU; needed by the inertial modes only.
    pub imu: Option<ImuCalibration>,
}

impl RigModel {
    /// Camera 0's time shift, ns: frames are moved onto the IMU's clock by it.
    pub fn frame_shift_ns(&self) -> i64 {
        self.cameras
            .first()
            .map_or(0, CameraCalibration::time_shift_ns)
    }
}
