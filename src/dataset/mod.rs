//! Reading and writing recorded sequences and trajectories: EuRoC ASL,
//! KITTI odometry, TUM trajectories, told apart by their contents.

pub mod detect;
pub use crate::text_file::error;
pub mod euroc;
pub mod groundtruth;
pub mod image_file;
pub mod kitti;
pub mod matches_file;
pub mod stream;
pub use crate::text_file::text;
pub mod trajectory_out;
pub mod tum;

pub use detect::{open_dataset, read_trajectory_any, Dataset};
pub use error::DatasetError;
pub use euroc::{
    parse_camera_yaml, parse_imu_yaml, read_camera_yaml, read_euroc_imu_csv, read_imu_yaml,
    write_euroc_imu_csv, EurocCamera, EurocDataset, EurocImu, EurocWriter, ImageEntry, ImuCsv,
};
pub use groundtruth::{
    groundtruth_trajectory, read_euroc_groundtruth, read_euroc_trajectory, write_euroc_groundtruth,
    GroundTruthState,
};
pub use image_file::{read_png, write_png};
pub use kitti::{read_kitti_poses, KittiSequence};
pub use stream::{SensorEvent, SensorStream, StreamCounts, StreamOptions};
pub use trajectory_out::{write_trajectory, TrajectoryFormat};
pub use tum::{read_tum, write_tum};
