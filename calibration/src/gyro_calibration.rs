//! Gyroscope offset from the still parts and scale/misalignment from
//! whole turns about the axes (Ferraris et al., "Procedure for effortless
//! in-field calibration of three-axial rate gyro and accelerometers",
//! Sensors and Materials 7(5), 1995, eq. 13-15): with `w_k` the integral
//! of the offset-free raw rate over the turn about axis k and `theta_k`
//! its known angle, `S_g [w_x w_y w_z] = diag(theta)`, so
//! `S_g = diag(theta) W^-1`. In `x_c = S_g x_r + b_g`, `b_g = -S_g o_g`.

use std::collections::BTreeMap;
use std::path::Path;

use nalgebra::{Matrix3, Vector3};
use rigslam::dataset::DatasetError;
use rigslam::sensors::ImuSample;

use crate::error::CalibrationError;
use crate::static_detection::StaticInterval;

/// A turn about body axis `axis` (0 = x) over samples `start..end`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Rotation {
    pub axis: usize,
    pub start: usize,
    pub end: usize,
}

/// Sample-weighted mean raw rate over the still intervals: the raw offset `o_g`.
pub fn gyro_offset_from_static(intervals: &[StaticInterval]) -> Vector3<f64> {
    let total: usize = intervals.iter().map(StaticInterval::len).sum();
    let sum: Vector3<f64> = intervals
        .iter()
        .map(|i| i.gyro_mean_rad_s * i.len() as f64)
        .sum();
    sum / total.max(1) as f64
}

/// Integral of `gyro - offset` over `start..end` (rectangle rule, 1 / rate).
pub fn integrate_rate(
    samples: &[ImuSample],
    rotation: &Rotation,
    offset: &Vector3<f64>,
    rate_hz: f64,
) -> Vector3<f64> {
    samples[rotation.start..rotation.end]
        .iter()
        .map(|s| Vector3::from(s.gyro_rad_s) - offset)
        .sum::<Vector3<f64>>()
        / rate_hz
}

/// Turns between two still intervals in the same orientation whose
/// integrated rate exceeds 3/4 of a turn, mostly about one axis: the
/// rotations of a Ferraris session, found without a section list.
pub fn find_rotations(
    samples: &[ImuSample],
    intervals: &[StaticInterval],
    offset: &Vector3<f64>,
    rate_hz: f64,
) -> Vec<Rotation> {
    let mut out: Vec<Rotation> = Vec::new();
    for pair in intervals.windows(2) {
        let (before, after) = (&pair[0], &pair[1]);
        let same_pose = before.accel_mean_m_s2.angle(&after.accel_mean_m_s2) < 10f64.to_radians();
        if !same_pose {
            continue;
        }
        let candidate = Rotation {
            axis: 0,
            start: before.end,
            end: after.start,
        };
        let w = integrate_rate(samples, &candidate, offset, rate_hz);
        let axis = w.iamax();
        if w.norm() > 1.5 * std::f64::consts::PI && w[axis].abs() > 0.9 * w.norm() {
            if out.iter().any(|r| r.axis == axis) {
                continue;
            }
            out.push(Rotation { axis, ..candidate });
        }
    }
    out.sort_by_key(|r| r.axis);
    out
}

/// The Ferraris gyroscope scale.
#[derive(Debug, Clone, PartialEq)]
pub struct GyroScale {
    pub scale: Matrix3<f64>,
    /// Columns: integrated offset-free raw rate per turn, rad.
    pub integrated_rad: Matrix3<f64>,
    /// Known angle of each turn (the nearest whole number of turns), rad.
    pub expected_rad: Vector3<f64>,
}

/// `S_g = diag(theta) W^-1` from one turn per axis.
pub fn ferraris_gyro_scale(
    samples: &[ImuSample],
    rotations: &[Rotation],
    offset: &Vector3<f64>,
    rate_hz: f64,
) -> Result<GyroScale, CalibrationError> {
    let mut integrated = Matrix3::zeros();
    let mut expected = Vector3::zeros();
    for axis in 0..3 {
        let Some(rotation) = rotations.iter().find(|r| r.axis == axis) else {
            return Err(CalibrationError::Rotations(format!(
                "no full turn about the {} axis found: for the gyroscope scale, turn the IMU once \
                 (360 degrees) about each axis, standing still before and after each turn",
                ["x", "y", "z"][axis]
            )));
        };
        let w = integrate_rate(samples, rotation, offset, rate_hz);
        let turns = (w[axis] / std::f64::consts::TAU).round();
        if turns == 0.0 {
            return Err(CalibrationError::Rotations(format!(
                "the turn about the {} axis integrates to only {:.0} degrees: turn a full 360 degrees",
                ["x", "y", "z"][axis],
                w[axis].to_degrees()
            )));
        }
        integrated.set_column(axis, &w);
        expected[axis] = turns * std::f64::consts::TAU;
    }
    let inverse = integrated.try_inverse().ok_or_else(|| {
        CalibrationError::Rotations(
            "the three turns are not about three different axes: recollect them".into(),
        )
    })?;
    Ok(GyroScale {
        scale: Matrix3::from_diagonal(&expected) * inverse,
        integrated_rad: integrated,
        expected_rad: expected,
    })
}

/// imucal's section list (`{"x_p": {"start": 540, "end": 1271}, ...}`,
/// end exclusive) as name -> sample range.
pub fn read_section_list(
    path: &Path,
    samples: usize,
) -> Result<BTreeMap<String, (usize, usize)>, DatasetError> {
    let text = std::fs::read_to_string(path).map_err(|e| DatasetError::io(path, e))?;
    let doc: serde_json::Value = serde_json::from_str(&text)
        .map_err(|e| DatasetError::malformed(path, e.line(), format!("not valid JSON: {e}")))?;
    let map = doc.as_object().ok_or_else(|| {
        DatasetError::malformed(
            path,
            1,
            "expected an object of sections {name: {start, end}}",
        )
    })?;
    let mut out = BTreeMap::new();
    for (name, range) in map {
        let bound = |key: &str| -> Result<usize, DatasetError> {
            range
                .get(key)
                .and_then(serde_json::Value::as_u64)
                .map(|v| v as usize)
                .ok_or_else(|| {
                    DatasetError::bad_field(
                        path,
                        format!("{name}.{key}"),
                        "missing or not a sample index",
                    )
                })
        };
        let (start, end) = (bound("start")?, bound("end")?);
        if start >= end || end > samples {
            return Err(DatasetError::bad_field(
                path,
                name.clone(),
                format!("range {start}..{end} is empty or beyond the {samples} samples of the log: wrong section list for this file?"),
            ));
        }
        out.insert(name.clone(), (start, end));
    }
    Ok(out)
}

/// The `x_rot`, `y_rot`, `z_rot` sections of a section list.
pub fn rotations_from_sections(sections: &BTreeMap<String, (usize, usize)>) -> Vec<Rotation> {
    ["x_rot", "y_rot", "z_rot"]
        .iter()
        .enumerate()
        .filter_map(|(axis, name)| {
            sections
                .get(*name)
                .map(|&(start, end)| Rotation { axis, start, end })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::static_detection::StaticDetector;

    /// Still, one turn about `axis` at `rate` rad/s read through `s_true`
    /// and offset `o`, still again (100 Hz).
    fn turn_session(s_true: &Matrix3<f64>, o: &Vector3<f64>) -> Vec<ImuSample> {
        let s_inv = s_true.try_inverse().expect("invertible");
        let mut out = Vec::new();
        let mut push = |omega_true: Vector3<f64>| {
            let raw = s_inv * omega_true + o;
            let i = out.len() as i64;
            out.push(ImuSample {
                t_ns: i * 10_000_000,
                gyro_rad_s: raw.into(),
                accel_m_s2: [0.0, 0.0, 9.81],
            });
        };
        for axis in 0..3 {
            for _ in 0..300 {
                push(Vector3::zeros());
            }
            // -360 degrees over 4 s: 400 samples at -pi/2 rad/s.
            for _ in 0..400 {
                push(Vector3::ith(axis, -std::f64::consts::FRAC_PI_2));
            }
        }
        for _ in 0..300 {
            push(Vector3::zeros());
        }
        out
    }

    #[test]
    fn recovers_the_gyro_scale_from_three_found_turns() {
        let s_true = Matrix3::new(1.03, 0.004, -0.01, 0.002, 0.97, 0.006, 0.009, -0.003, 1.01);
        let o = Vector3::new(0.01, -0.005, 0.002);
        let samples = turn_session(&s_true, &o);
        let intervals = StaticDetector::default().detect(&samples, 100.0);
        let offset = gyro_offset_from_static(&intervals);
        assert!((offset - o).amax() < 1e-12);
        let rotations = find_rotations(&samples, &intervals, &offset, 100.0);
        assert_eq!(
            rotations.iter().map(|r| r.axis).collect::<Vec<_>>(),
            vec![0, 1, 2]
        );
        let g = ferraris_gyro_scale(&samples, &rotations, &offset, 100.0).expect("three turns");
        assert!((g.scale - s_true).amax() < 1e-9, "{}", g.scale);
        assert_eq!(g.expected_rad, Vector3::repeat(-std::f64::consts::TAU));
    }

    #[test]
    fn a_section_list_for_another_file_is_refused() {
        let dir = tempfile::tempdir().expect("temp dir");
        let p = dir.path().join("list.json");
        std::fs::write(&p, r#"{"x_rot": {"start": 100, "end": 20000}}"#).expect("write");
        let e = read_section_list(&p, 5000)
            .expect_err("beyond the log")
            .to_string();
        assert!(
            e.contains("x_rot") && e.contains("wrong section list"),
            "{e}"
        );
        std::fs::write(&p, r#"{"x_rot": {"start": 100}}"#).expect("write");
        let e = read_section_list(&p, 5000).expect_err("no end").to_string();
        assert!(e.contains("x_rot.end"), "{e}");
        std::fs::write(&p, "[1, 2").expect("write");
        assert!(read_section_list(&p, 5000).is_err());
        std::fs::write(
            &p,
            r#"{"x_rot": {"start": 100, "end": 400}, "y_p": {"start": 0, "end": 50}}"#,
        )
        .expect("write");
        let sections = read_section_list(&p, 5000).expect("valid");
        assert_eq!(
            rotations_from_sections(&sections),
            vec![Rotation {
                axis: 0,
                start: 100,
                end: 400
            }]
        );
    }

    #[test]
    fn a_missing_turn_says_which_axis_to_recollect() {
        let samples = turn_session(&Matrix3::identity(), &Vector3::zeros());
        let rotations = vec![Rotation {
            axis: 0,
            start: 300,
            end: 700,
        }];
        let e = ferraris_gyro_scale(&samples, &rotations, &Vector3::zeros(), 100.0)
            .expect_err("y and z missing")
            .to_string();
        assert!(e.contains("about the y axis"), "{e}");
    }
}
