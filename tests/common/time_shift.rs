//! A EuRoC folder whose camera clock says it runs behind the IMU's, for
//! the tests of frames that need the IMU past their stamp.

use std::path::{Path, PathBuf};

/// A copy of `root` (a EuRoC folder without a time shift) in `dir` whose
/// camera files say `timeshift_cam_imu: shift_s`; images, IMU and ground
/// truth linked, not copied.
pub fn with_time_shift(root: &Path, dir: &Path, shift_s: f64) -> PathBuf {
    let copy = dir.join("shifted");
    for link in ["mav0/imu0", "mav0/state_groundtruth_estimate0"] {
        std::fs::create_dir_all(copy.join(link).parent().expect("parent")).expect("mkdir");
        std::os::unix::fs::symlink(root.join(link), copy.join(link)).expect("link");
    }
    for cam in ["mav0/cam0", "mav0/cam1"] {
        std::fs::create_dir_all(copy.join(cam)).expect("mkdir");
        std::os::unix::fs::symlink(root.join(cam).join("data"), copy.join(cam).join("data"))
            .expect("link");
        std::fs::copy(
            root.join(cam).join("data.csv"),
            copy.join(cam).join("data.csv"),
        )
        .expect("copy");
        let yaml = std::fs::read_to_string(root.join(cam).join("sensor.yaml")).expect("yaml");
        assert!(
            !yaml.contains("timeshift_cam_imu"),
            "{} has a shift",
            root.display()
        );
        std::fs::write(
            copy.join(cam).join("sensor.yaml"),
            format!("{yaml}\ntimeshift_cam_imu: {shift_s}\n"),
        )
        .expect("write yaml");
    }
    copy
}
