//! Calibration tools for rigslam: IMU intrinsics and noise, camera
//! intrinsics, camera-IMU extrinsics and time offset. Built on the core's
//! camera model and IMU code (see the Calibration issue).

pub use rigslam::camera;

pub mod camera_report;
pub mod chessboard;
pub mod homography;
pub mod intrinsics_lm;
pub mod zhang;
