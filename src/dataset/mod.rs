//! Reading and writing recorded sequences and trajectories: EuRoC ASL,
//! KITTI odometry, TUM trajectories.

pub mod error;
pub mod text;
pub mod tum;

pub use error::DatasetError;
pub use tum::{read_tum, write_tum};
