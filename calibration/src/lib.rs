//! Calibration tools for rigslam: IMU intrinsics and noise, camera
//! intrinsics, camera-IMU extrinsics and time offset. Built on the core's
//! camera model and IMU code.

pub use rigslam::camera;

pub mod accel_calibration;
pub mod allan;
pub mod aprilgrid;
pub mod aprilgrid_detections;
pub mod banded_cholesky;
pub mod calibration_files;
pub mod camchain_yaml;
pub mod camera_imu_batch;
pub mod camera_imu_report;
pub mod camera_report;
pub mod chessboard;
pub mod error;
pub mod export;
pub mod folder_check;
pub mod gyro_calibration;
pub mod hand_eye;
pub mod homography;
pub mod imu_calibration;
pub mod imu_log;
pub mod intrinsics_lm;
pub mod layout_args;
pub mod nelder_mead;
pub mod noise_calibration;
pub mod noise_fit;
pub mod plots;
pub mod report;
pub mod static_detection;
pub mod stereo_extrinsic;
pub mod time_offset;
pub mod zhang;
