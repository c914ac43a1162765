//! Calibration tools for rigslam: IMU intrinsics and noise, camera
//! intrinsics, camera-IMU extrinsics and time offset. Built on the core's
//! camera model and IMU code (see the Calibration issue).

pub use rigslam::camera;

pub mod aprilgrid_detections;
pub mod banded_cholesky;
pub mod camchain_yaml;
pub mod camera_imu_batch;
pub mod camera_imu_report;
pub mod camera_report;
pub mod chessboard;
pub mod hand_eye;
pub mod homography;
pub mod intrinsics_lm;
pub mod time_offset;
pub mod zhang;
