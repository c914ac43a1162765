//! The rendering two tests share: 30 s of EuRoC V1_02's motion, stereo,
//! an IMU synthesised from the motion with the datasheet's noise (so the
//! true calibration and the true gravity are exactly the rendering's),
//! scene seed 7.

use std::path::Path;

use rigslam::simulate::{simulate, ImuSource, SimConfig};

/// Renders it into `out` from V1_02's ground truth `v1_02_groundtruth`.
pub fn render_v1_02_synthetic(v1_02_groundtruth: &Path, out: &Path) {
    simulate(
        &SimConfig {
            trajectory: Some(v1_02_groundtruth.to_path_buf()),
            duration_s: Some(30.0),
            imu: ImuSource::Synthetic,
            stereo: true,
            seed: 7,
            show_progress: false,
            ..SimConfig::default()
        },
        out,
    )
    .expect("render");
}
