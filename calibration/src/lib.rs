//! Calibration tools for rigslam: IMU intrinsics and noise, camera
//! intrinsics, camera-IMU extrinsics and time offset. Built on the core's
//! camera model and IMU code (see the Calibration issue).

pub use rigslam::camera;

pub mod accel_calibration;
pub mod allan;
pub mod calibration_files;
pub mod error;
pub mod gyro_calibration;
pub mod imu_calibration;
pub mod imu_log;
pub mod layout_args;
pub mod nelder_mead;
pub mod noise_calibration;
pub mod noise_fit;
pub mod plots;
pub mod report;
pub mod static_detection;
