//! Writing a trajectory in the format the next tool wants: TUM (evo's
//! `tum`, stamps in seconds), EuRoC csv (evo's `euroc`, stamps in ns) or
//! KITTI poses (evo's `kitti`: a 3x4 `[R | t]` per line, no stamps).

use std::fmt::Write as _;
use std::path::Path;

use super::error::DatasetError;
use super::tum::tum_text;
use crate::text_file::write_atomically;
use crate::trajectory::Trajectory;

/// A trajectory file format.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
pub enum TrajectoryFormat {
    /// `t[s] tx ty tz qx qy qz qw`, space-separated.
    Tum,
    /// `t[ns],px,py,pz,qw,qx,qy,qz`, with EuRoC's header.
    Euroc,
    /// `r11 r12 r13 tx r21 r22 r23 ty r31 r32 r33 tz`, one pose a line.
    Kitti,
}

impl TrajectoryFormat {
    /// The format a file name asks for: `.csv` EuRoC, `.kitti` KITTI,
    /// anything else TUM.
    pub fn of_path(path: &Path) -> Self {
        match path
            .extension()
            .and_then(|x| x.to_str())
            .map(|x| x.to_ascii_lowercase())
            .as_deref()
        {
            Some("csv") => TrajectoryFormat::Euroc,
            Some("kitti") => TrajectoryFormat::Kitti,
            _ => TrajectoryFormat::Tum,
        }
    }
}

/// EuRoC's header, as in its ground truth csv (the first 8 columns).
const EUROC_HEADER: &str = "#timestamp [ns],p_RS_R_x [m],p_RS_R_y [m],p_RS_R_z [m],q_RS_w [],q_RS_x [],q_RS_y [],q_RS_z []";

/// Writes `trajectory` to `path` in `format`, atomically (a reader sees
/// the old file or the new one, never a part: a run killed while writing
/// leaves no cut trajectory to score).
pub fn write_trajectory(
    path: &Path,
    trajectory: &Trajectory,
    format: TrajectoryFormat,
) -> Result<(), DatasetError> {
    let text = match format {
        TrajectoryFormat::Tum => tum_text(trajectory),
        TrajectoryFormat::Euroc => euroc_text(trajectory),
        TrajectoryFormat::Kitti => kitti_text(trajectory),
    };
    write_atomically(path, text.as_bytes()).map_err(|e| DatasetError::io(path, e))
}

/// `t[ns],px,py,pz,qw,qx,qy,qz` lines under EuRoC's header.
fn euroc_text(trajectory: &Trajectory) -> String {
    let mut out = format!("{EUROC_HEADER}\n");
    for p in &trajectory.poses {
        let t = p.position();
        let q = p.orientation();
        writeln!(
            out,
            "{},{:.9},{:.9},{:.9},{:.9},{:.9},{:.9},{:.9}",
            p.t_ns, t.x, t.y, t.z, q.w, q.i, q.j, q.k
        )
        .expect("writing to a String cannot fail");
    }
    out
}

/// The 3x4 `[R | t]` of each pose, row-major, one pose a line, no header
/// and no stamps (KITTI's poses files, evo's `kitti` mode).
fn kitti_text(trajectory: &Trajectory) -> String {
    let mut out = String::new();
    for p in &trajectory.poses {
        let t = p.position();
        let r = p.T_world_body.rotation.to_rotation_matrix();
        let m = r.matrix();
        for row in 0..3 {
            let sep = if row == 0 { "" } else { " " };
            write!(
                out,
                "{sep}{:.9} {:.9} {:.9} {:.9}",
                m[(row, 0)],
                m[(row, 1)],
                m[(row, 2)],
                t[row]
            )
            .expect("writing to a String cannot fail");
        }
        out.push('\n');
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dataset::read_trajectory_any;
    use crate::trajectory::StampedPose;
    use nalgebra::{UnitQuaternion, Vector3};

    fn sample() -> Trajectory {
        Trajectory::new(
            (0..5)
                .map(|i| {
                    let f = i as f64;
                    StampedPose::new(
                        1_403_715_273_262_142_976 + i * 50_000_000,
                        Vector3::new(0.1 * f, -2.0 + f, 0.3 * f * f),
                        UnitQuaternion::from_euler_angles(0.1 * f, -0.2 * f, 0.7 * f),
                    )
                })
                .collect(),
        )
    }

    /// Each format read back by the project's readers (which tell the
    /// formats apart by their contents): the same poses, and the stamps
    /// where the format has them.
    #[test]
    fn every_format_reads_back_as_written() {
        let dir = tempfile::tempdir().expect("tempdir");
        let written = sample();
        for (name, format) in [
            ("t.tum", TrajectoryFormat::Tum),
            ("t.csv", TrajectoryFormat::Euroc),
            ("t.kitti", TrajectoryFormat::Kitti),
        ] {
            let path = dir.path().join(name);
            assert_eq!(TrajectoryFormat::of_path(&path), format);
            write_trajectory(&path, &written, format).expect("write");
            let read = read_trajectory_any(&path).expect("read back");
            assert_eq!(read.len(), written.len(), "{name}");
            for (a, b) in read.poses.iter().zip(&written.poses) {
                assert!((a.position() - b.position()).norm() < 1e-8, "{name}");
                assert!(a.orientation().angle_to(&b.orientation()) < 1e-8, "{name}");
                if format != TrajectoryFormat::Kitti {
                    assert_eq!(a.t_ns, b.t_ns, "{name}");
                }
            }
        }
        let kitti = std::fs::read_to_string(dir.path().join("t.kitti")).expect("read");
        assert!(kitti
            .lines()
            .all(|l| l.split_whitespace().count() == 12 && !l.starts_with('#')));
        let euroc = std::fs::read_to_string(dir.path().join("t.csv")).expect("read");
        assert_eq!(
            euroc.lines().next(),
            Some("#timestamp [ns],p_RS_R_x [m],p_RS_R_y [m],p_RS_R_z [m],q_RS_w [],q_RS_x [],q_RS_y [],q_RS_z []")
        );
    }

    /// Each KITTI line is `[R | t]` row by row: R orthonormal with
    /// determinant 1 and the rotation of the pose's quaternion, t its
    /// position (read here by hand, not by the reader, which would accept
    /// a transposed R as another rotation).
    #[test]
    fn kitti_lines_are_the_rotation_matrix_row_by_row() {
        let written = sample();
        let text = kitti_text(&written);
        assert_eq!(text.lines().count(), written.len());
        for (line, pose) in text.lines().zip(&written.poses) {
            let v: Vec<f64> = line
                .split(' ')
                .map(|x| x.parse().expect("a number"))
                .collect();
            assert_eq!(v.len(), 12, "{line}");
            let r = nalgebra::Matrix3::new(v[0], v[1], v[2], v[4], v[5], v[6], v[8], v[9], v[10]);
            assert!(
                (r.transpose() * r - nalgebra::Matrix3::identity()).amax() < 1e-8,
                "{line}"
            );
            assert!((r.determinant() - 1.0).abs() < 1e-8, "{line}");
            let expected = pose.orientation().to_rotation_matrix();
            assert!((r - expected.matrix()).amax() < 1e-8, "{line}");
            let t = Vector3::new(v[3], v[7], v[11]);
            assert!((t - pose.position()).norm() < 1e-8, "{line}");
        }
    }

    #[test]
    fn the_extension_names_the_format() {
        for (name, format) in [
            ("a.tum", TrajectoryFormat::Tum),
            ("a.txt", TrajectoryFormat::Tum),
            ("a", TrajectoryFormat::Tum),
            ("dir.csv/a.TUM", TrajectoryFormat::Tum),
            ("a.CSV", TrajectoryFormat::Euroc),
            ("a.kitti", TrajectoryFormat::Kitti),
        ] {
            assert_eq!(TrajectoryFormat::of_path(Path::new(name)), format, "{name}");
        }
    }

    /// The file is replaced whole, and no temporary is left beside it.
    #[test]
    fn a_write_replaces_the_file_and_leaves_nothing_else() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("t.csv");
        std::fs::write(
            &path,
            "a longer file that was there before, to be replaced whole\n".repeat(100),
        )
        .expect("write");
        let written = sample();
        write_trajectory(&path, &written, TrajectoryFormat::Euroc).expect("write");
        assert_eq!(
            std::fs::read_to_string(&path).expect("read"),
            euroc_text(&written)
        );
        let names: Vec<_> = std::fs::read_dir(dir.path())
            .expect("list")
            .map(|e| e.expect("entry").file_name())
            .collect();
        assert_eq!(names, vec![std::ffi::OsString::from("t.csv")]);
        let missing = dir.path().join("no such folder").join("t.tum");
        let err =
            write_trajectory(&missing, &written, TrajectoryFormat::Tum).expect_err("no folder");
        assert!(err.to_string().contains("no such folder"), "{err}");
    }
}
