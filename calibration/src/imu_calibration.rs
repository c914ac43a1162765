//! `rigslam-calibrate imu` without the I/O: find the still poses, fit the
//! accelerometer ([`crate::accel_calibration`]), take the gyroscope offset
//! from the still parts and, when the session holds one whole turn about
//! each axis, its scale ([`crate::gyro_calibration`]); assemble the
//! core's [`ImuIntrinsics`] (`x_c = S x_r + b`) and the technician's verdict.

use nalgebra::{Matrix3, Vector3};
use rigslam::imu::ImuIntrinsics;
use rigslam::sensors::ImuSample;

use crate::accel_calibration::{calibrate_accelerometer, AccelCalibration, AccelModel};
use crate::error::CalibrationError;
use crate::gyro_calibration::{
    ferraris_gyro_scale, find_rotations, gyro_offset_from_static, GyroScale, Rotation,
};
use crate::static_detection::{distinct_orientations, StaticDetector, StaticInterval};

/// Fewest distinct still orientations for the diagonal model.
pub const MIN_POSES_DIAGONAL: usize = 6;
/// Fewest distinct still orientations for scale + misalignment.
pub const MIN_POSES_FULL: usize = 9;

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ImuCalibrationOptions {
    pub detector: StaticDetector,
    /// Local gravity magnitude, m/s^2.
    pub gravity_m_s2: f64,
    /// Still intervals closer than this in gravity direction are one pose.
    pub same_pose_deg: f64,
}

impl Default for ImuCalibrationOptions {
    fn default() -> Self {
        Self {
            detector: StaticDetector::default(),
            gravity_m_s2: rigslam::imu::GRAVITY_M_S2,
            same_pose_deg: 10.0,
        }
    }
}

#[derive(Debug, Clone)]
pub struct ImuSessionCalibration {
    pub intervals: Vec<StaticInterval>,
    pub distinct_poses: usize,
    pub accel: AccelCalibration,
    /// Raw gyro reading at rest, rad/s.
    pub gyro_offset_raw_rad_s: Vector3<f64>,
    /// Largest spread (max - min over the still intervals) of the mean raw rate, per axis, rad/s.
    pub gyro_offset_spread_rad_s: Vector3<f64>,
    pub rotations: Vec<Rotation>,
    /// `None` without one whole turn about each axis (or with `Err` text why).
    pub gyro_scale: Result<GyroScale, String>,
    /// The result: accelerometer from Levenberg-Marquardt, gyroscope from Ferraris (or identity scale).
    pub intrinsics: ImuIntrinsics,
}

/// Calibrates a session. `rotations`: the turns from a section list, or
/// `None` to find them between still intervals of the same pose.
pub fn calibrate_imu_session(
    samples: &[ImuSample],
    rate_hz: f64,
    rotations: Option<Vec<Rotation>>,
    options: &ImuCalibrationOptions,
) -> Result<ImuSessionCalibration, CalibrationError> {
    let intervals = options.detector.detect(samples, rate_hz);
    let distinct_poses = distinct_orientations(&intervals, options.same_pose_deg);
    let model = if distinct_poses >= MIN_POSES_FULL {
        AccelModel::UpperTriangular
    } else if distinct_poses >= MIN_POSES_DIAGONAL {
        AccelModel::Diagonal
    } else {
        return Err(CalibrationError::TooFewPoses {
            found: distinct_poses,
            intervals: intervals.len(),
            needed: MIN_POSES_DIAGONAL,
        });
    };
    let mut magnitudes: Vec<f64> = intervals.iter().map(|i| i.accel_mean_m_s2.norm()).collect();
    magnitudes.sort_by(f64::total_cmp);
    let at_rest = magnitudes[magnitudes.len() / 2];
    if (at_rest / options.gravity_m_s2 - 1.0).abs() > 0.2 {
        return Err(CalibrationError::Data(rigslam::dataset::DatasetError::Layout {
            path: "the IMU log".into(),
            message: format!(
                "at rest the accelerometer reads {at_rest:.3} where gravity is {:.3} m/s^2: wrong --accel-unit (g or m/s^2) or column order?",
                options.gravity_m_s2
            ),
        }));
    }
    let means: Vec<Vector3<f64>> = intervals.iter().map(|i| i.accel_mean_m_s2).collect();
    let accel = calibrate_accelerometer(model, &means, options.gravity_m_s2)?;
    let offset = gyro_offset_from_static(&intervals);
    let mut spread = Vector3::zeros();
    for k in 0..3 {
        let (lo, hi) = intervals
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), i| {
                (lo.min(i.gyro_mean_rad_s[k]), hi.max(i.gyro_mean_rad_s[k]))
            });
        spread[k] = hi - lo;
    }
    let rotations =
        rotations.unwrap_or_else(|| find_rotations(samples, &intervals, &offset, rate_hz));
    let gyro_scale =
        ferraris_gyro_scale(samples, &rotations, &offset, rate_hz).map_err(|e| e.to_string());
    if let Ok(g) = &gyro_scale {
        let turns = g.expected_rad.abs().max() / std::f64::consts::TAU;
        if turns > 3.0 {
            return Err(CalibrationError::Rotations(format!(
                "a turn integrates to {turns:.0} whole turns: wrong --gyro-unit (deg/s or rad/s)?"
            )));
        }
    }
    let gyro_matrix = gyro_scale
        .as_ref()
        .map(|g| g.scale)
        .unwrap_or_else(|_| Matrix3::identity());
    let intrinsics = ImuIntrinsics {
        gyro_scale: gyro_matrix,
        gyro_offset_rad_s: -(gyro_matrix * offset),
        accel_scale: accel.levenberg_marquardt.scale,
        accel_offset_m_s2: accel.levenberg_marquardt.bias_m_s2,
    };
    Ok(ImuSessionCalibration {
        intervals,
        distinct_poses,
        accel,
        gyro_offset_raw_rad_s: offset,
        gyro_offset_spread_rad_s: spread,
        rotations,
        gyro_scale,
        intrinsics,
    })
}

/// Lines for the technician: what went well, what to recollect.
pub fn imu_verdict(cal: &ImuSessionCalibration) -> Vec<String> {
    let mut out = Vec::new();
    let a = &cal.accel;
    out.push(format!(
        "accelerometer: {} poses ({} distinct), gravity-magnitude error {:.4} -> {:.4} m/s^2 RMS ({})",
        cal.intervals.len(),
        cal.distinct_poses,
        a.rms_before_m_s2,
        a.levenberg_marquardt.rms_m_s2,
        a.model.name()
    ));
    if a.model == AccelModel::Diagonal {
        out.push(format!(
            "accelerometer misalignment not estimated: only {} distinct poses; for it, add still poses in {} or more different orientations (tilted, not only the six faces)",
            cal.distinct_poses, MIN_POSES_FULL
        ));
    }
    if a.levenberg_marquardt.rms_m_s2 > 0.05 {
        out.push(format!(
            "accelerometer poses disagree ({:.3} m/s^2 RMS after calibration): hold each pose still and check the IMU is mounted firmly; recollect",
            a.levenberg_marquardt.rms_m_s2
        ));
    }
    if a.scale_agreement > 1e-4 || a.bias_agreement_m_s2 > 1e-3 {
        out.push(format!(
            "simplex and Levenberg-Marquardt disagree (S {:.1e}, b {:.1e} m/s^2): the poses constrain the model poorly; add poses in more orientations",
            a.scale_agreement, a.bias_agreement_m_s2
        ));
    }
    for (k, axis) in ["x", "y", "z"].iter().enumerate() {
        let spread_deg_s = cal.gyro_offset_spread_rad_s[k].to_degrees();
        if spread_deg_s > 0.5 {
            out.push(format!(
                "gyro {axis} bias unstable (moves {spread_deg_s:.2} deg/s between poses): recollect with the IMU warmed up and each pose held still"
            ));
        }
    }
    match &cal.gyro_scale {
        Ok(_) => out.push(format!(
            "gyroscope: scale and misalignment from {} turns (Ferraris)",
            cal.rotations.len()
        )),
        Err(why) => out.push(format!("gyroscope: bias only; scale not estimated: {why}")),
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;
    use rand_distr::{Distribution, Normal};

    /// A simulated session at 100 Hz: `poses` still orientations (5 s each,
    /// joined by 1 s moves), then a -360 degree turn about x, y and z, each
    /// between two stills. Raw readings through known `S`, `b` (accel) and
    /// `S_g`, `o_g` (gyro), with white noise.
    fn session(
        poses: usize,
        s_a: &Matrix3<f64>,
        b_a: &Vector3<f64>,
        s_g: &Matrix3<f64>,
        o_g: &Vector3<f64>,
        seed: u64,
    ) -> Vec<ImuSample> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let accel_noise = Normal::new(0.0, 0.02).expect("valid");
        let gyro_noise = Normal::new(0.0, 0.002).expect("valid");
        let (sa_inv, sg_inv) = (
            s_a.try_inverse().expect("inv"),
            s_g.try_inverse().expect("inv"),
        );
        let mut out: Vec<ImuSample> = Vec::new();
        let mut push = |up: Vector3<f64>, omega: Vector3<f64>, rng: &mut ChaCha8Rng| {
            let a = sa_inv * (up * 9.81 - b_a) + Vector3::from_fn(|_, _| accel_noise.sample(rng));
            let w = sg_inv * omega + o_g + Vector3::from_fn(|_, _| gyro_noise.sample(rng));
            let t_ns = out.len() as i64 * 10_000_000;
            out.push(ImuSample {
                t_ns,
                gyro_rad_s: w.into(),
                accel_m_s2: a.into(),
            });
        };
        let mut up = Vector3::z();
        for _ in 0..poses {
            let next = Vector3::new(
                rng.gen_range(-1.0..1.0),
                rng.gen_range(-1.0..1.0),
                rng.gen_range(-1.0..1.0),
            )
            .normalize();
            for i in 0..100 {
                // A moving second: rotate up towards next at ~1 rad/s.
                let f = i as f64 / 100.0;
                push(
                    (up * (1.0 - f) + next * f).normalize(),
                    Vector3::new(0.7, -0.5, 0.6),
                    &mut rng,
                );
            }
            up = next;
            for _ in 0..500 {
                push(up, Vector3::zeros(), &mut rng);
            }
        }
        // Turns about the axis that is up (gravity stays put in the body).
        for axis in 0..3 {
            let up = Vector3::ith(axis, 1.0);
            for _ in 0..300 {
                push(up, Vector3::zeros(), &mut rng);
            }
            for _ in 0..400 {
                push(
                    up,
                    Vector3::ith(axis, -std::f64::consts::FRAC_PI_2),
                    &mut rng,
                );
            }
            for _ in 0..300 {
                push(up, Vector3::zeros(), &mut rng);
            }
        }
        out
    }

    #[test]
    fn recovers_a_simulated_session_to_1e_3() {
        let s_a = Matrix3::new(1.02, 0.012, -0.008, 0.0, 0.985, 0.015, 0.0, 0.0, 1.01);
        let b_a = Vector3::new(0.15, -0.22, 0.31);
        let s_g = Matrix3::new(1.03, 0.004, -0.01, 0.002, 0.97, 0.006, 0.009, -0.003, 1.01);
        let o_g = Vector3::new(0.012, -0.007, 0.003);
        let samples = session(20, &s_a, &b_a, &s_g, &o_g, 5);
        let cal = calibrate_imu_session(&samples, 100.0, None, &ImuCalibrationOptions::default())
            .expect("good session");
        assert_eq!(cal.accel.model, AccelModel::UpperTriangular);
        assert!(cal.distinct_poses >= 15, "{}", cal.distinct_poses);
        for fit in [&cal.accel.nelder_mead, &cal.accel.levenberg_marquardt] {
            eprintln!(
                "S error {:.2e}, b error {:.2e} m/s^2",
                (fit.scale - s_a).amax(),
                (fit.bias_m_s2 - b_a).amax()
            );
            assert!((fit.scale - s_a).amax() < 1e-3, "{}", fit.scale - s_a);
            assert!(
                (fit.bias_m_s2 - b_a).amax() < 1e-3,
                "{}",
                fit.bias_m_s2 - b_a
            );
        }
        let g = cal.gyro_scale.as_ref().expect("three turns");
        eprintln!("S_g error {:.2e}", (g.scale - s_g).amax());
        assert!((g.scale - s_g).amax() < 1e-3, "{}", g.scale - s_g);
        assert!((cal.intrinsics.gyro_offset_rad_s + s_g * o_g).amax() < 1e-4);
        assert!(cal.accel.levenberg_marquardt.rms_m_s2 < 0.01 && cal.accel.rms_before_m_s2 > 0.1);
    }

    #[test]
    fn a_drifting_gyro_bias_is_named() {
        let i3 = Matrix3::identity();
        let mut samples = session(12, &i3, &Vector3::zeros(), &i3, &Vector3::zeros(), 3);
        // The z offset creeps by 0.02 rad/s (1.1 deg/s) over the session.
        let n = samples.len() as f64;
        for (i, s) in samples.iter_mut().enumerate() {
            s.gyro_rad_s[2] += 0.02 * i as f64 / n;
        }
        let cal = calibrate_imu_session(&samples, 100.0, None, &ImuCalibrationOptions::default())
            .expect("calibrates");
        let verdict = imu_verdict(&cal);
        assert!(
            verdict
                .iter()
                .any(|v| v.starts_with("gyro z bias unstable") && v.contains("recollect")),
            "{verdict:?}"
        );
        assert!(
            !verdict.iter().any(|v| v.starts_with("gyro x bias")),
            "{verdict:?}"
        );
    }

    #[test]
    fn too_few_poses_and_wrong_units_say_what_to_recollect() {
        let i3 = Matrix3::identity();
        let samples = session(3, &i3, &Vector3::zeros(), &i3, &Vector3::zeros(), 1);
        // The first three random poses only.
        let few: Vec<ImuSample> = samples[..1800].to_vec();
        let e = calibrate_imu_session(&few, 100.0, None, &ImuCalibrationOptions::default())
            .expect_err("3 poses")
            .to_string();
        assert!(
            e.contains("too few static poses") && e.contains("recollect"),
            "{e}"
        );
        let in_g: Vec<ImuSample> = session(12, &i3, &Vector3::zeros(), &i3, &Vector3::zeros(), 2)
            .into_iter()
            .map(|mut s| {
                s.accel_m_s2 = s.accel_m_s2.map(|a| a / 9.81);
                s
            })
            .collect();
        let e = calibrate_imu_session(&in_g, 100.0, None, &ImuCalibrationOptions::default())
            .expect_err("g units")
            .to_string();
        assert!(e.contains("--accel-unit"), "{e}");
    }
}
