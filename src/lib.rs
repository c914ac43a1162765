//! rigslam: the SLAM core.
//!
//! Follow one frame through the modules in this order (the picture and
//! the threads are in docs/architecture.md, the method and its equations
//! in docs/design.md): sensor samples come from `rigslam_drivers`
//! (re-exported as [`sensors`]), live through the [`daemon`]'s source
//! threads or replayed from a recording by [`dataset`] (EuRoC, KITTI,
//! TUM) and [`recording`] (MCAP), every text file through [`text_file`];
//! [`rig`] holds the calibration they come with (and reads its files) and
//! [`camera`] projects and unprojects. The relative stage, [`relative`],
//! tracks the image with [`features`] and [`two_view`], integrates the IMU
//! between frames with [`imu`] and optimises a window of keyframes; the
//! absolute stage, [`absolute`], turns its output into a linear map
//! ([`edge_map`], the maths) and a position filter (today in `rigslam run
//! --absolute`, driven by [`run`]). The [`daemon`] runs the relative stage
//! on its own thread and [`publish`] sends each pose to other processes
//! over shared memory. Offline, [`trajectory`] holds timestamped poses,
//! [`eval`] scores an estimate against ground truth (`plot`, behind the
//! feature of that name, draws it), [`simulate`] renders synthetic
//! sequences, and [`shared_data`] finds the real test recordings;
//! [`slam_config`] is the settings file of both stages, and [`console`]
//! what the binaries write on stderr. No two sibling modules depend on
//! each other (`tests/module_boundaries.rs` checks it).

#![warn(missing_docs)]

pub use rigslam_drivers as sensors;

pub mod absolute;
pub mod camera;
pub mod console;
pub mod daemon;
pub mod dataset;
pub mod edge_map;
pub mod eval;
pub mod features;
pub mod imu;
#[cfg(feature = "plot")]
pub mod plot;
pub mod publish;
pub mod recording;
pub mod relative;
pub mod rig;
pub mod run;
pub mod shared_data;
pub mod simulate;
pub mod slam_config;
pub mod slam_pipeline;
pub mod text_file;
pub mod thread_priority;
pub mod trajectory;
pub mod two_view;
