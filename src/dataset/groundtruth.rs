//! EuRoC ground truth (`state_groundtruth_estimate0/data.csv`): per row
//! `t[ns], p xyz, q wxyz, v xyz, gyro bias xyz, accel bias xyz`, 17 columns,
//! comma separated, the pose of the body (IMU) frame in the world frame.

use std::io::Write;
use std::path::Path;

use nalgebra::{Isometry3, Quaternion, Translation3, Vector3};

use super::error::DatasetError;
use super::text::{check_euroc_header, check_increasing, data_lines, parse_stamped_row, read_text};
use super::tum::unit_quaternion;
use crate::trajectory::{StampedPose, Trajectory};

/// The EuRoC column header, written as the first line of every ground-truth file.
pub const EUROC_GROUNDTRUTH_HEADER: &str = "#timestamp, p_RS_R_x [m], p_RS_R_y [m], p_RS_R_z [m], \
q_RS_w [], q_RS_x [], q_RS_y [], q_RS_z [], v_RS_R_x [m s^-1], v_RS_R_y [m s^-1], v_RS_R_z [m s^-1], \
b_w_RS_S_x [rad s^-1], b_w_RS_S_y [rad s^-1], b_w_RS_S_z [rad s^-1], \
b_a_RS_S_x [m s^-2], b_a_RS_S_y [m s^-2], b_a_RS_S_z [m s^-2]";

/// The full state EuRoC's ground truth gives at one instant.
#[allow(non_snake_case)]
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GroundTruthState {
    /// Stamp, ns (EuRoC's clock, the one the sensors are stamped in).
    pub t_ns: i64,
    /// Maps body (IMU) coordinates into the world frame.
    pub T_world_body: Isometry3<f64>,
    /// Velocity of the body in the world frame.
    pub velocity_m_s: Vector3<f64>,
    /// Gyroscope bias, in the IMU frame.
    pub gyro_bias_rad_s: Vector3<f64>,
    /// Accelerometer bias, in the IMU frame.
    pub accel_bias_m_s2: Vector3<f64>,
}

impl GroundTruthState {
    /// The stamped pose `T_world_body`, dropping velocity and biases.
    pub fn pose(&self) -> StampedPose {
        StampedPose {
            t_ns: self.t_ns,
            T_world_body: self.T_world_body,
        }
    }
}

/// The poses of a ground-truth sequence, dropping velocity and biases.
pub fn groundtruth_trajectory(states: &[GroundTruthState]) -> Trajectory {
    Trajectory::new(states.iter().map(GroundTruthState::pose).collect())
}

/// Reads a 17-column EuRoC ground-truth CSV. Stamps must increase. A `#`
/// header, when there is one, must have 17 columns.
pub fn read_euroc_groundtruth(path: &Path) -> Result<Vec<GroundTruthState>, DatasetError> {
    parse_euroc_groundtruth(&read_text(path)?, path)
}

/// Parses the text of a ground-truth CSV; `path` names it in errors.
pub fn parse_euroc_groundtruth(
    text: &str,
    path: &Path,
) -> Result<Vec<GroundTruthState>, DatasetError> {
    check_euroc_header(
        path,
        text,
        &[17],
        "17 columns (t_ns, p xyz, q wxyz, v xyz, gyro bias xyz, accel bias xyz) \
         for EuRoC ground truth",
    )?;
    let mut states = Vec::new();
    let mut stamps = Vec::new();
    for (line_no, line) in data_lines(text) {
        let (t_ns, f) = parse_stamped_row::<16>(path, line_no, line, ',')?;
        let [px, py, pz, qw, qx, qy, qz, vx, vy, vz, gx, gy, gz, ax, ay, az] = f;
        let q = unit_quaternion(path, line_no, Quaternion::new(qw, qx, qy, qz))?;
        if !f.iter().all(|v| v.is_finite()) {
            return Err(DatasetError::malformed(path, line_no, "non-finite value"));
        }
        states.push(GroundTruthState {
            t_ns,
            T_world_body: Isometry3::from_parts(Translation3::new(px, py, pz), q),
            velocity_m_s: Vector3::new(vx, vy, vz),
            gyro_bias_rad_s: Vector3::new(gx, gy, gz),
            accel_bias_m_s2: Vector3::new(ax, ay, az),
        });
        stamps.push((line_no, t_ns));
    }
    check_increasing(path, stamps)?;
    Ok(states)
}

/// Reads the poses of a EuRoC-style CSV: the 17-column ground truth or
/// the 8-column `t[ns], p xyz, q wxyz` that some tools write. Every row
/// must have the first row's column count; a `#` header, when there is
/// one, must have 17 or 8 columns.
pub fn read_euroc_trajectory(path: &Path) -> Result<Trajectory, DatasetError> {
    parse_euroc_trajectory(&read_text(path)?, path)
}

/// Parses the text of a EuRoC-style trajectory CSV; `path` names it in
/// errors.
pub fn parse_euroc_trajectory(text: &str, path: &Path) -> Result<Trajectory, DatasetError> {
    check_euroc_header(
        path,
        text,
        &[17, 8],
        "17 (ground truth) or 8 (t_ns, p xyz, q wxyz) columns for a EuRoC trajectory",
    )?;
    let columns = data_lines(text)
        .next()
        .map(|(_, l)| l.split(',').count())
        .unwrap_or(17);
    if columns == 17 {
        return parse_euroc_groundtruth(text, path).map(|s| groundtruth_trajectory(&s));
    }
    let mut poses = Vec::new();
    let mut stamps = Vec::new();
    for (line_no, line) in data_lines(text) {
        let (t_ns, f) = parse_stamped_row::<7>(path, line_no, line, ',').map_err(|e| match e {
            DatasetError::Malformed { path, line, .. } if columns != 8 => DatasetError::malformed(
                path,
                line,
                format!("expected 17 (ground truth) or 8 (t, p, q) fields, found {columns}"),
            ),
            other => other,
        })?;
        let q = unit_quaternion(path, line_no, Quaternion::new(f[3], f[4], f[5], f[6]))?;
        if !f.iter().all(|v| v.is_finite()) {
            return Err(DatasetError::malformed(path, line_no, "non-finite value"));
        }
        poses.push(StampedPose::new(t_ns, Vector3::new(f[0], f[1], f[2]), q));
        stamps.push((line_no, t_ns));
    }
    check_increasing(path, stamps)?;
    Ok(Trajectory::new(poses))
}

/// Writes a 17-column EuRoC ground-truth CSV. Numbers are printed in
/// Rust's shortest form that reads back to the same f64.
pub fn write_euroc_groundtruth(
    path: &Path,
    states: &[GroundTruthState],
) -> Result<(), DatasetError> {
    let file = std::fs::File::create(path).map_err(|e| DatasetError::io(path, e))?;
    let mut out = std::io::BufWriter::new(file);
    let io = |e| DatasetError::io(path, e);
    writeln!(out, "{EUROC_GROUNDTRUTH_HEADER}").map_err(io)?;
    for s in states {
        let p = s.T_world_body.translation.vector;
        let q = s.T_world_body.rotation;
        let (v, bg, ba) = (s.velocity_m_s, s.gyro_bias_rad_s, s.accel_bias_m_s2);
        writeln!(
            out,
            "{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{}",
            s.t_ns,
            p.x,
            p.y,
            p.z,
            q.w,
            q.i,
            q.j,
            q.k,
            v.x,
            v.y,
            v.z,
            bg.x,
            bg.y,
            bg.z,
            ba.x,
            ba.y,
            ba.z
        )
        .map_err(io)?;
    }
    out.flush().map_err(io)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::UnitQuaternion;

    fn state(t_ns: i64, k: f64) -> GroundTruthState {
        GroundTruthState {
            t_ns,
            T_world_body: Isometry3::from_parts(
                Translation3::new(0.1 * k, -2.0, 1.0 / 3.0),
                UnitQuaternion::from_euler_angles(0.3 * k, -0.2, 1.1),
            ),
            velocity_m_s: Vector3::new(k, 0.5, -0.25),
            gyro_bias_rad_s: Vector3::new(-0.002, 0.02, 0.077 * k),
            accel_bias_m_s2: Vector3::new(-0.018, 0.066, 0.031),
        }
    }

    #[test]
    fn round_trip_is_exact_to_quaternion_normalisation() {
        let dir = tempfile::tempdir().expect("temp dir");
        let path = dir.path().join("gt.csv");
        let states: Vec<_> = (0..5)
            .map(|i| state(1_403_715_273_262_142_976 + i * 5_000_000, i as f64))
            .collect();
        write_euroc_groundtruth(&path, &states).expect("write");
        let back = read_euroc_groundtruth(&path).expect("read");
        assert_eq!(back.len(), states.len());
        for (a, b) in states.iter().zip(&back) {
            assert_eq!(a.t_ns, b.t_ns);
            // Translation, velocity and biases print exactly.
            assert_eq!(a.T_world_body.translation, b.T_world_body.translation);
            assert_eq!(a.velocity_m_s, b.velocity_m_s);
            assert_eq!(a.gyro_bias_rad_s, b.gyro_bias_rad_s);
            assert_eq!(a.accel_bias_m_s2, b.accel_bias_m_s2);
            // The quaternion is renormalised on reading: equal to rounding.
            assert!(a.T_world_body.rotation.angle_to(&b.T_world_body.rotation) < 1e-15);
        }
        let traj = read_euroc_trajectory(&path).expect("as trajectory");
        assert_eq!(traj.len(), 5);
        assert_eq!(traj.poses[3].t_ns, states[3].t_ns);
    }

    #[test]
    fn eight_column_csv_reads_as_trajectory() {
        let dir = tempfile::tempdir().expect("temp dir");
        let path = dir.path().join("est.csv");
        std::fs::write(
            &path,
            "#t,x,y,z,qw,qx,qy,qz\n10,1,2,3,1,0,0,0\n20,4,5,6,0,0,0,1\n",
        )
        .expect("write");
        let t = read_euroc_trajectory(&path).expect("read");
        assert_eq!(t.poses[1].t_ns, 20);
        assert_eq!(t.poses[1].position(), Vector3::new(4.0, 5.0, 6.0));
        // q = (w 0, z 1): a half turn about z.
        let r = t.poses[1].orientation() * Vector3::x();
        assert!((r - Vector3::new(-1.0, 0.0, 0.0)).norm() < 1e-15);
        // The 17-column reader refuses the 8-column file at its header...
        let err = read_euroc_groundtruth(&path).expect_err("8 columns");
        assert!(
            err.to_string()
                .contains("est.csv:1: header has 8 columns, as in a pose csv"),
            "{err}"
        );
        // ... or, without one, at its first row.
        std::fs::write(&path, "10,1,2,3,1,0,0,0\n").expect("write");
        let err = read_euroc_groundtruth(&path).expect_err("8 columns");
        assert!(
            err.to_string().contains("est.csv:1: expected 17 fields"),
            "{err}"
        );
    }

    #[test]
    fn malformed_files_are_errors_naming_the_line() {
        let dir = tempfile::tempdir().expect("temp dir");
        let path = dir.path().join("gt.csv");
        write_euroc_groundtruth(&path, &[state(1, 0.0), state(2, 1.0)]).expect("write");
        let good = std::fs::read_to_string(&path).expect("read back");

        // Truncated mid-row: the last row loses its tail.
        std::fs::write(&path, &good[..good.len() - 30]).expect("write");
        let err = read_euroc_groundtruth(&path).expect_err("truncated");
        assert!(
            err.to_string().contains("gt.csv:3: expected 17 fields"),
            "{err}"
        );

        // Stamps going backwards.
        let swapped: Vec<&str> = good.lines().collect();
        std::fs::write(
            &path,
            format!("{}\n{}\n{}\n", swapped[0], swapped[2], swapped[1]),
        )
        .expect("write");
        let err = read_euroc_groundtruth(&path).expect_err("order");
        assert!(err.to_string().contains("gt.csv:3: timestamp 1"), "{err}");

        // A header line that lost its '#'.
        std::fs::write(&path, &good[1..]).expect("write");
        let err = read_euroc_groundtruth(&path).expect_err("bare header");
        assert!(err.to_string().contains("gt.csv:1:"), "{err}");

        // An IMU file given as ground truth: 7 columns.
        std::fs::write(
            &path,
            "#timestamp [ns],w_x,w_y,w_z,a_x,a_y,a_z\n1,0,0,0,0,0,9.8\n",
        )
        .expect("write");
        for err in [
            read_euroc_trajectory(&path).expect_err("imu file"),
            read_euroc_groundtruth(&path)
                .map(|_| ())
                .expect_err("imu file"),
        ] {
            let message = err.to_string();
            assert!(
                message.contains("gt.csv:1: header has 7 columns, as in an IMU csv"),
                "{message}"
            );
            assert!(message.contains("; expected 17 "), "{message}");
        }
        // The same rows without a header still fail, at their first row.
        std::fs::write(&path, "1,0,0,0,0,0,9.8\n").expect("write");
        let err = read_euroc_trajectory(&path).expect_err("imu rows");
        assert!(
            err.to_string()
                .contains("gt.csv:1: expected 17 (ground truth) or 8"),
            "{err}"
        );

        // Garbage bytes.
        std::fs::write(&path, [0x89u8, b'P', b'N', b'G', 0, 0xff, b'\n', 3]).expect("write");
        assert!(read_euroc_groundtruth(&path).is_err());

        // A non-unit quaternion.
        std::fs::write(&path, "1,0,0,0,2,0,0,0,0,0,0,0,0,0,0,0,0\n").expect("write");
        let err = read_euroc_groundtruth(&path).expect_err("norm");
        assert!(
            err.to_string().contains("gt.csv:1: quaternion norm"),
            "{err}"
        );

        // Empty file: no states, not an error.
        std::fs::write(&path, "").expect("write");
        assert!(read_euroc_groundtruth(&path).expect("empty").is_empty());
    }
}
