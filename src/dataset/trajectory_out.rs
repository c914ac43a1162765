//! Writing a trajectory in the format the next tool wants: TUM (evo's
//! `tum`, stamps in seconds), EuRoC csv (evo's `euroc`, stamps in ns) or
//! KITTI poses (evo's `kitti`: a 3x4 `[R | t]` per line, no stamps).

use std::io::Write as _;
use std::path::Path;

use super::error::DatasetError;
use super::tum::write_tum;
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

/// Writes `trajectory` to `path` in `format`.
pub fn write_trajectory(
    path: &Path,
    trajectory: &Trajectory,
    format: TrajectoryFormat,
) -> Result<(), DatasetError> {
    if format == TrajectoryFormat::Tum {
        return write_tum(path, trajectory);
    }
    let file = std::fs::File::create(path).map_err(|e| DatasetError::io(path, e))?;
    let mut out = std::io::BufWriter::new(file);
    let io = |e| DatasetError::io(path, e);
    if format == TrajectoryFormat::Euroc {
        writeln!(
            out,
            "#timestamp [ns],p_RS_R_x [m],p_RS_R_y [m],p_RS_R_z [m],q_RS_w [],q_RS_x [],q_RS_y [],q_RS_z []"
        )
        .map_err(io)?;
    }
    for p in &trajectory.poses {
        let t = p.position();
        match format {
            TrajectoryFormat::Euroc => {
                let q = p.orientation();
                writeln!(
                    out,
                    "{},{:.9},{:.9},{:.9},{:.9},{:.9},{:.9},{:.9}",
                    p.t_ns, t.x, t.y, t.z, q.w, q.i, q.j, q.k
                )
            }
            _ => {
                let r = p.T_world_body.rotation.to_rotation_matrix();
                let m = r.matrix();
                writeln!(
                    out,
                    "{:.9} {:.9} {:.9} {:.9} {:.9} {:.9} {:.9} {:.9} {:.9} {:.9} {:.9} {:.9}",
                    m[(0, 0)],
                    m[(0, 1)],
                    m[(0, 2)],
                    t.x,
                    m[(1, 0)],
                    m[(1, 1)],
                    m[(1, 2)],
                    t.y,
                    m[(2, 0)],
                    m[(2, 1)],
                    m[(2, 2)],
                    t.z
                )
            }
        }
        .map_err(io)?;
    }
    out.flush().map_err(io)
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
    }
}
