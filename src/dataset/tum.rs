//! TUM trajectory files: `t[s] tx ty tz qx qy qz qw`, one pose per line,
//! `#` comments. Pose of the body frame in the world frame.

use std::io::Write;
use std::path::Path;

use nalgebra::{Quaternion, UnitQuaternion, Vector3};

use super::error::DatasetError;
use super::text::{data_lines, parse_fields};
use crate::trajectory::{StampedPose, Trajectory};

/// Reads a TUM file. Seconds are converted to i64 ns, rounding to the
/// nearest nanosecond (f64 seconds keep about 0.2 us near 1.4e9 s).
pub fn read_tum(path: &Path) -> Result<Trajectory, DatasetError> {
    let text = std::fs::read_to_string(path).map_err(|e| DatasetError::io(path, e))?;
    let mut poses = Vec::new();
    for (line_no, line) in data_lines(&text) {
        let f: [f64; 8] = parse_fields(path, line_no, line, ' ')?;
        let q = Quaternion::new(f[7], f[4], f[5], f[6]);
        let orientation = unit_quaternion(path, line_no, q)?;
        let t_ns = seconds_to_ns(path, line_no, f[0])?;
        poses.push(StampedPose::new(
            t_ns,
            Vector3::new(f[1], f[2], f[3]),
            orientation,
        ));
    }
    check_ordered(path, &poses)?;
    Ok(Trajectory::new(poses))
}

/// Writes a TUM file with nanosecond-exact seconds (9 decimals).
pub fn write_tum(path: &Path, trajectory: &Trajectory) -> Result<(), DatasetError> {
    let file = std::fs::File::create(path).map_err(|e| DatasetError::io(path, e))?;
    let mut out = std::io::BufWriter::new(file);
    let io = |e| DatasetError::io(path, e);
    writeln!(out, "# timestamp[s] tx ty tz qx qy qz qw (T_world_body)").map_err(io)?;
    for p in &trajectory.poses {
        let t = p.position();
        let q = p.orientation();
        let secs = p.t_ns.div_euclid(1_000_000_000);
        let nanos = p.t_ns.rem_euclid(1_000_000_000);
        writeln!(
            out,
            "{secs}.{nanos:09} {:.9} {:.9} {:.9} {:.9} {:.9} {:.9} {:.9}",
            t.x, t.y, t.z, q.i, q.j, q.k, q.w
        )
        .map_err(io)?;
    }
    out.flush().map_err(io)
}

/// Normalises a quaternion read from a file, rejecting ones far from unit norm.
pub(crate) fn unit_quaternion(
    path: &Path,
    line: usize,
    q: Quaternion<f64>,
) -> Result<UnitQuaternion<f64>, DatasetError> {
    let n = q.norm();
    if !n.is_finite() || (n - 1.0).abs() > 1e-2 {
        return Err(DatasetError::malformed(
            path,
            line,
            format!("quaternion norm {n} is not 1"),
        ));
    }
    Ok(UnitQuaternion::from_quaternion(q))
}

pub(crate) fn seconds_to_ns(path: &Path, line: usize, t_s: f64) -> Result<i64, DatasetError> {
    let ns = (t_s * 1e9).round();
    if !ns.is_finite() || ns.abs() > i64::MAX as f64 {
        return Err(DatasetError::malformed(
            path,
            line,
            format!("timestamp {t_s} s out of range"),
        ));
    }
    Ok(ns as i64)
}

/// Poses must move forward in time; evaluation and association depend on it.
pub(crate) fn check_ordered(path: &Path, poses: &[StampedPose]) -> Result<(), DatasetError> {
    match poses.windows(2).position(|w| w[1].t_ns <= w[0].t_ns) {
        Some(i) => Err(DatasetError::malformed(
            path,
            0,
            format!(
                "timestamps do not increase at pose {} ({} ns after {} ns)",
                i + 1,
                poses[i + 1].t_ns,
                poses[i].t_ns
            ),
        )),
        None => Ok(()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_keeps_nanoseconds() {
        let dir = tempfile::tempdir().expect("temp dir");
        let path = dir.path().join("t.tum");
        let q = UnitQuaternion::from_euler_angles(0.1, -0.2, 0.3);
        let traj = Trajectory::new(vec![
            StampedPose::new(1_403_715_273_262_142_976, Vector3::new(1.0, 2.0, 3.0), q),
            StampedPose::new(
                1_403_715_273_312_143_104,
                Vector3::new(-1.5, 0.25, 0.0),
                q.inverse(),
            ),
        ]);
        write_tum(&path, &traj).expect("write");
        let back = read_tum(&path).expect("read");
        assert_eq!(back.len(), 2);
        for (a, b) in traj.poses.iter().zip(&back.poses) {
            // f64 seconds near 1.4e9 resolve ~0.24 us.
            assert!((a.t_ns - b.t_ns).abs() < 500);
            assert!((a.position() - b.position()).norm() < 1e-8);
            assert!(a.orientation().angle_to(&b.orientation()) < 1e-8);
        }
    }

    #[test]
    fn bad_rows_name_file_and_line() {
        let dir = tempfile::tempdir().expect("temp dir");
        let path = dir.path().join("bad.tum");
        std::fs::write(&path, "# header\n1.0 0 0 0 0 0 0 1\n2.0 0 0 0 0 0 1\n").expect("write");
        let err = read_tum(&path).expect_err("short row").to_string();
        assert!(err.contains("bad.tum:3"), "{err}");
        std::fs::write(&path, "1.0 0 0 0 0 0 0 1\n2.0 0 0 x 0 0 0 1\n").expect("write");
        let err = read_tum(&path).expect_err("not a number").to_string();
        assert!(err.contains("bad.tum:2") && err.contains("x"), "{err}");
        std::fs::write(&path, "1.0 0 0 0 0 0 0 2\n").expect("write");
        assert!(read_tum(&path)
            .expect_err("norm")
            .to_string()
            .contains("norm"));
        std::fs::write(&path, "2.0 0 0 0 0 0 0 1\n1.0 0 0 0 0 0 0 1\n").expect("write");
        assert!(read_tum(&path)
            .expect_err("order")
            .to_string()
            .contains("do not increase"));
        assert!(read_tum(&dir.path().join("missing.tum"))
            .expect_err("missing")
            .to_string()
            .contains("missing.tum"));
    }
}
