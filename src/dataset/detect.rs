//! Telling formats apart by their contents: which dataset layout a folder
//! holds, which trajectory format a file is in.

use std::path::Path;

use super::error::DatasetError;
use super::euroc::reader::mav0_of;
use super::euroc::EurocDataset;
use super::groundtruth::read_euroc_trajectory;
use super::kitti::{read_kitti_poses, KittiSequence};
use super::text::{data_lines, read_text};
use super::tum::read_tum;
use crate::trajectory::Trajectory;

/// A dataset of either layout `--dataset` accepts.
#[derive(Debug, Clone)]
pub enum Dataset {
    /// A EuRoC ASL folder (`mav0/`).
    Euroc(EurocDataset),
    /// A KITTI odometry sequence folder.
    Kitti(KittiSequence),
}

/// Opens a EuRoC ASL folder (holding `mav0/`, or `mav0` itself) or a KITTI
/// odometry sequence (`image_0/`, `image_l/` or `image_2/` with `calib.txt`).
pub fn open_dataset(path: &Path) -> Result<Dataset, DatasetError> {
    std::fs::metadata(path).map_err(|e| DatasetError::io(path, e))?;
    if mav0_of(path).is_some() {
        return EurocDataset::open(path).map(Dataset::Euroc);
    }
    let kitti = ["image_0", "image_l", "image_2"]
        .iter()
        .any(|d| path.join(d).is_dir());
    if kitti {
        return KittiSequence::open(path).map(Dataset::Kitti);
    }
    Err(DatasetError::layout(
        path,
        "not a dataset: expected EuRoC ASL (mav0/ with camN/, imu0/) \
         or KITTI odometry (image_0/ or image_l/ with calib.txt)",
    ))
}

/// Reads any trajectory file we know, told apart by its first data line:
/// commas -> EuRoC CSV (17-column ground truth or 8-column t, p, q wxyz);
/// 8 whitespace-separated numbers -> TUM (`t[s] p q xyzw`); 12 -> KITTI
/// `poses.txt`, stamped from `times.txt` beside it or at i/10 s.
pub fn read_trajectory_any(path: &Path) -> Result<Trajectory, DatasetError> {
    let text = read_text(path)?;
    let Some((line_no, first)) = data_lines(&text).next() else {
        return Err(DatasetError::layout(path, "holds no poses"));
    };
    if first.contains(',') {
        return read_euroc_trajectory(path);
    }
    match first.split_whitespace().count() {
        8 => read_tum(path),
        12 => read_kitti_poses(path),
        n => Err(DatasetError::malformed(
            path,
            line_no,
            format!(
                "cannot tell the trajectory format: {n} fields \
                 (EuRoC csv has 17 or 8 comma-separated, TUM 8, KITTI 12)"
            ),
        )),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector3;

    #[test]
    fn trajectory_formats_are_told_apart() {
        let dir = tempfile::tempdir().expect("temp dir");
        let write = |name: &str, text: &str| {
            let p = dir.path().join(name);
            std::fs::write(&p, text).expect("write");
            p
        };
        // The same two poses in each format; the second is at (1, 2, 3),
        // turned half about z.
        let tum = write(
            "a.tum",
            "# t x y z qx qy qz qw\n0.5 0 0 0 0 0 0 1\n0.6 1 2 3 0 0 1 0\n",
        );
        let euroc = write(
            "a.csv",
            "#t,x,y,z,qw,qx,qy,qz\n500000000,0,0,0,1,0,0,0\n600000000,1,2,3,0,0,0,1\n",
        );
        let kitti = write(
            "poses.txt",
            "1 0 0 0 0 1 0 0 0 0 1 0\n-1 0 0 1 0 -1 0 2 0 0 1 3\n",
        );
        for (path, t1_ns) in [
            (&tum, 600_000_000),
            (&euroc, 600_000_000),
            (&kitti, 100_000_000),
        ] {
            let t = read_trajectory_any(path).expect("reads");
            assert_eq!(t.len(), 2, "{}", path.display());
            assert_eq!(t.poses[1].t_ns, t1_ns, "{}", path.display());
            assert_eq!(t.poses[1].position(), Vector3::new(1.0, 2.0, 3.0));
            let x = t.poses[1].orientation() * Vector3::x();
            assert!((x + Vector3::x()).norm() < 1e-12, "{}", path.display());
        }
        // times.txt beside poses.txt sets the stamps.
        write("times.txt", "1.5\n2.25\n");
        assert_eq!(
            read_trajectory_any(&kitti).expect("reads").poses[1].t_ns,
            2_250_000_000
        );

        let err = read_trajectory_any(&write("x.txt", "# only a comment\n")).expect_err("empty");
        assert!(matches!(err, DatasetError::Layout { .. }), "{err}");
        let err = read_trajectory_any(&write("y.txt", "#\n1 2 3 4\n")).expect_err("4 fields");
        assert!(err.to_string().contains("y.txt:2: cannot tell"), "{err}");
        let err = read_trajectory_any(&write("z.txt", "\u{1}\u{2}garbage")).expect_err("garbage");
        assert!(err.to_string().contains("z.txt:1"), "{err}");
    }

    #[test]
    fn unknown_folders_are_layout_errors() {
        let dir = tempfile::tempdir().expect("temp dir");
        let err = open_dataset(dir.path()).expect_err("empty folder");
        assert!(matches!(err, DatasetError::Layout { .. }), "{err}");
        assert!(err.to_string().contains("not a dataset"));
        let err = open_dataset(&dir.path().join("absent")).expect_err("absent");
        assert!(matches!(err, DatasetError::Io { .. }), "{err}");
        // A mav0 folder with neither cameras nor IMU.
        std::fs::create_dir(dir.path().join("mav0")).expect("mkdir");
        let err = open_dataset(dir.path()).expect_err("empty mav0");
        assert!(err.to_string().contains("neither camN/ nor imu0/"), "{err}");
    }
}
