//! rigslam: the SLAM core.
//!
//! Follow one frame through the modules in this order: sensor samples come
//! from `rigslam_drivers` (re-exported as [`sensors`]); [`dataset`] reads
//! and writes recorded sequences; [`camera`] projects and unprojects;
//! [`trajectory`] holds timestamped poses; [`eval`] scores an estimate
//! against ground truth; [`simulate`] renders synthetic sequences;
//! [`two_view`] estimates relative and absolute poses from correspondences;
//! [`publish`] sends poses to other processes over shared memory.

pub use rigslam_drivers as sensors;

pub mod camera;
pub mod daemon;
pub mod dataset;
pub mod edge_map;
pub mod eval;
pub mod features;
pub mod imu;
pub mod publish;
pub mod recording;
pub mod relative;
pub mod rig;
pub mod run;
pub mod shared_data;
pub mod simulate;
pub mod trajectory;
pub mod two_view;
