//! TUM trajectory files: `t[s] tx ty tz qx qy qz qw`, one pose per line,
//! `#` comments. Pose of the body frame in the world frame.

use std::fmt::Write as _;
use std::path::Path;

use nalgebra::{Quaternion, UnitQuaternion, Vector3};

use super::error::DatasetError;
use super::text::{check_not_decreasing, data_lines, parse_fields, parse_seconds_ns, read_text};
use crate::text_file::write_atomically;
use crate::trajectory::{StampedPose, Trajectory};

/// Reads a TUM file. Stamps may repeat but not go back: published
/// estimates repeat a stamp now and then (evo's V1_02 sample does, 4
/// times) and evo keeps both poses, so we do too. Stamps are converted from their decimal text to i64
/// ns exactly (rounding only digits past the nanosecond): going through
/// f64 would lose about 0.2 us near 1.4e9 s.
pub fn read_tum(path: &Path) -> Result<Trajectory, DatasetError> {
    parse_tum(&read_text(path)?, path)
}

/// Parses the text of a TUM file; `path` names it in errors.
pub fn parse_tum(text: &str, path: &Path) -> Result<Trajectory, DatasetError> {
    let mut poses = Vec::new();
    let mut stamps = Vec::new();
    for (line_no, line) in data_lines(text) {
        let f: [f64; 8] = parse_fields(path, line_no, line, ' ')?;
        let q = Quaternion::new(f[7], f[4], f[5], f[6]);
        let orientation = unit_quaternion(path, line_no, q)?;
        if !f.iter().all(|v| v.is_finite()) {
            return Err(DatasetError::malformed(path, line_no, "non-finite value"));
        }
        let stamp = line
            .split_whitespace()
            .next()
            .expect("8 fields were parsed");
        let t_ns = seconds_to_ns(path, line_no, stamp)?;
        stamps.push((line_no, t_ns));
        poses.push(StampedPose::new(
            t_ns,
            Vector3::new(f[1], f[2], f[3]),
            orientation,
        ));
    }
    check_not_decreasing(path, stamps)?;
    Ok(Trajectory::new(poses))
}

/// Writes a TUM file with nanosecond-exact seconds (9 decimals), atomically
/// (a reader sees the old file or the new one, never a part).
pub fn write_tum(path: &Path, trajectory: &Trajectory) -> Result<(), DatasetError> {
    write_atomically(path, tum_text(trajectory).as_bytes()).map_err(|e| DatasetError::io(path, e))
}

/// The text of a TUM file of `trajectory`.
pub(crate) fn tum_text(trajectory: &Trajectory) -> String {
    let mut out = String::from("# timestamp[s] tx ty tz qx qy qz qw (T_world_body)\n");
    for p in &trajectory.poses {
        let t = p.position();
        let q = p.orientation();
        // Sign apart: -0.5 s must print as -0.500000000, not -1.500000000.
        let sign = if p.t_ns < 0 { "-" } else { "" };
        let secs = p.t_ns.unsigned_abs() / 1_000_000_000;
        let nanos = p.t_ns.unsigned_abs() % 1_000_000_000;
        writeln!(
            out,
            "{sign}{secs}.{nanos:09} {:.9} {:.9} {:.9} {:.9} {:.9} {:.9} {:.9}",
            t.x, t.y, t.z, q.i, q.j, q.k, q.w
        )
        .expect("writing to a String cannot fail");
    }
    out
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

/// A stamp in decimal seconds as exact nanoseconds.
pub(crate) fn seconds_to_ns(path: &Path, line: usize, field: &str) -> Result<i64, DatasetError> {
    parse_seconds_ns(field).ok_or_else(|| {
        DatasetError::malformed(
            path,
            line,
            format!("timestamp {field:?} is not a finite number of seconds in range"),
        )
    })
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
            StampedPose::new(-1_500_000_001, Vector3::new(0.5, 0.0, 0.0), q),
            StampedPose::new(-499_999_999, Vector3::new(0.5, 0.0, 0.0), q),
            StampedPose::new(1_403_715_273_262_142_976, Vector3::new(1.0, 2.0, 3.0), q),
            StampedPose::new(
                1_403_715_273_312_143_104,
                Vector3::new(-1.5, 0.25, 0.0),
                q.inverse(),
            ),
        ]);
        write_tum(&path, &traj).expect("write");
        let back = read_tum(&path).expect("read");
        assert_eq!(back.len(), 4);
        for (a, b) in traj.poses.iter().zip(&back.poses) {
            assert_eq!(a.t_ns, b.t_ns);
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
        let err = read_tum(&path).expect_err("order").to_string();
        assert!(
            err.contains("bad.tum:2: timestamp 1000000000 ns goes back"),
            "{err}"
        );
        // A repeated stamp is kept, as evo keeps it.
        std::fs::write(
            &path,
            "1.0 0 0 0 0 0 0 1\n1.0 1 0 0 0 0 0 1\n2 0 0 0 0 0 0 1\n",
        )
        .expect("write");
        let t = read_tum(&path).expect("repeated stamp");
        assert_eq!(t.len(), 3);
        assert_eq!(t.poses[1].position().x, 1.0);
        assert!(read_tum(&dir.path().join("missing.tum"))
            .expect_err("missing")
            .to_string()
            .contains("missing.tum"));
    }
}
