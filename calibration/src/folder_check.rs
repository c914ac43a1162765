//! `rigslam-calibrate check DIR`: a technician's verdict on a rig
//! calibration folder. Every file is read as the daemon reads it, then the
//! files are checked against each other and, when a recording is given,
//! against what the sensors deliver: image sizes against each camera's
//! resolution (a problem), the IMU's rate against `update_rate` (a
//! warning), the stereo baseline and the time shift's size.

use std::path::Path;

use rigslam::rig::folder::{load_folder, read_folder, CAMCHAIN, IMU_INTRINSICS, IMU_NOISE};
use rigslam::rig::RigModel;

/// One line of the verdict.
#[derive(Debug, Clone, PartialEq)]
pub enum Finding {
    Ok(String),
    /// Works, but worth a look.
    Warning(String),
    /// The daemon would refuse it, or it would run wrong.
    Problem(String),
}

impl Finding {
    pub fn is_problem(&self) -> bool {
        matches!(self, Finding::Problem(_))
    }
}

impl std::fmt::Display for Finding {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Finding::Ok(m) => write!(f, "ok       {m}"),
            Finding::Warning(m) => write!(f, "warning  {m}"),
            Finding::Problem(m) => write!(f, "PROBLEM  {m}"),
        }
    }
}

/// What the sensors deliver, from a recording, to hold the files against.
#[derive(Debug, Clone, Default)]
pub struct Observed {
    /// Per camera, the size of its first image.
    pub image_sizes: Vec<(u32, u32)>,
    /// Median IMU rate, Hz.
    pub imu_rate_hz: Option<f64>,
}

/// A stereo baseline outside this range (m) is not a rig's.
const BASELINE_RANGE_M: (f64, f64) = (0.01, 2.0);
/// A time shift larger than this is unusual for hardware-synchronised
/// sensors (s); still accepted up to the reader's bound.
const LARGE_SHIFT_S: f64 = 0.05;

/// The verdict on `dir`, with `observed` when a recording was given.
pub fn check_folder(dir: &Path, observed: Option<&Observed>) -> Vec<Finding> {
    let mut out = Vec::new();
    let files = match read_folder(dir) {
        Ok(f) => f,
        Err(e) => return vec![Finding::Problem(e.to_string())],
    };
    for name in [CAMCHAIN, IMU_NOISE, IMU_INTRINSICS] {
        if !files.iter().any(|f| f.name == name) {
            out.push(match name {
                IMU_INTRINSICS => Finding::Warning(format!(
                    "{name} missing: raw IMU samples are used as they come (fine for a factory-calibrated IMU; otherwise run `rigslam-calibrate imu --out {}`)",
                    dir.display()
                )),
                IMU_NOISE => Finding::Warning(format!(
                    "{name} missing: only the vision-only modes can run (run `rigslam-calibrate noise --out {}`)",
                    dir.display()
                )),
                _ => Finding::Problem(format!(
                    "{name} missing: run `rigslam-calibrate camera-imu --out {}`",
                    dir.display()
                )),
            });
        }
    }
    let rig = match load_folder(dir, false) {
        Ok(rig) => rig,
        Err(e) => {
            out.push(Finding::Problem(e.to_string()));
            return out;
        }
    };
    out.push(Finding::Ok(format!(
        "the daemon reads this folder: {} camera(s){}",
        rig.cameras.len(),
        if rig.imu.is_some() {
            " and the IMU"
        } else {
            ""
        }
    )));
    agreement(&rig, observed, &mut out);
    out
}

fn agreement(rig: &RigModel, observed: Option<&Observed>, out: &mut Vec<Finding>) {
    for (i, c) in rig.cameras.iter().enumerate() {
        let shift = c.time_shift_cam_imu_s;
        let p = c.T_body_cam.translation.vector;
        out.push(Finding::Ok(format!(
            "cam{i}: {}x{}, {} distortion, {:.1} mm from the IMU, time shift {:+.3} ms (IMU clock = camera clock {} {:.3} ms)",
            c.model.width(),
            c.model.height(),
            c.model.kalibr_distortion_model(),
            p.norm() * 1e3,
            shift * 1e3,
            if shift >= 0.0 { "+" } else { "-" },
            shift.abs() * 1e3
        )));
        if shift.abs() > LARGE_SHIFT_S {
            out.push(Finding::Warning(format!(
                "cam{i}: a time shift of {:.1} ms is large for synchronised sensors: check its sign (Kalibr: t_imu = t_cam + shift) and that the camera and IMU stamp on one clock",
                shift * 1e3
            )));
        }
        if p.norm() > 1.0 {
            out.push(Finding::Warning(format!(
                "cam{i} is {:.2} m from the IMU: check T_cam_imu is in metres",
                p.norm()
            )));
        }
    }
    if let [a, b, ..] = rig.cameras.as_slice() {
        let baseline = (a.T_body_cam.inverse() * b.T_body_cam)
            .translation
            .vector
            .norm();
        if (BASELINE_RANGE_M.0..=BASELINE_RANGE_M.1).contains(&baseline) {
            out.push(Finding::Ok(format!(
                "stereo baseline {:.1} mm",
                baseline * 1e3
            )));
        } else {
            out.push(Finding::Problem(format!(
                "stereo baseline {baseline:.4} m is outside {}-{} m: the two T_cam_imu do not describe one rig",
                BASELINE_RANGE_M.0, BASELINE_RANGE_M.1
            )));
        }
        if (a.model.width(), a.model.height()) != (b.model.width(), b.model.height()) {
            out.push(Finding::Warning(
                "cam0 and cam1 have different resolutions: check each entry came from its own camera".into(),
            ));
        }
    }
    if let Some(imu) = &rig.imu {
        out.push(Finding::Ok(format!(
            "IMU: {} Hz; gyro {:.2e} rad/s/sqrt(Hz), accel {:.2e} m/s^2/sqrt(Hz){}",
            imu.rate_hz,
            imu.noise.gyroscope_noise_density,
            imu.noise.accelerometer_noise_density,
            if imu.intrinsics.is_identity() {
                String::new()
            } else {
                let s = imu.intrinsics.accel_scale;
                format!(
                    "; intrinsics: accel scale {:.4} {:.4} {:.4}",
                    s[(0, 0)],
                    s[(1, 1)],
                    s[(2, 2)]
                )
            }
        )));
    }
    let Some(seen) = observed else {
        return;
    };
    for (i, (c, &(w, h))) in rig.cameras.iter().zip(&seen.image_sizes).enumerate() {
        if (c.model.width(), c.model.height()) == (w, h) {
            out.push(Finding::Ok(format!(
                "cam{i}: the recording's images are {w}x{h}, as calibrated"
            )));
        } else {
            out.push(Finding::Problem(format!(
                "cam{i}: the recording's images are {w}x{h} but the calibration is for {}x{}: a calibration from another camera or another resolution; recalibrate at the resolution the robot runs",
                c.model.width(),
                c.model.height()
            )));
        }
    }
    if let (Some(imu), Some(rate)) = (&rig.imu, seen.imu_rate_hz) {
        if (rate / imu.rate_hz - 1.0).abs() <= 0.1 {
            out.push(Finding::Ok(format!(
                "IMU: the recording runs at {rate:.1} Hz, as imu.yaml says"
            )));
        } else {
            // Densities per sqrt(Hz) do not depend on the rate, and rigslam
            // does not use update_rate; Kalibr and OpenVINS convert with it.
            out.push(Finding::Warning(format!(
                "IMU: the recording runs at {rate:.1} Hz but imu.yaml says update_rate {}: were the noise values measured on this IMU? \
                 (rigslam uses the densities as they are; Kalibr and OpenVINS convert them with update_rate: set it to the sensor's rate before exporting)",
                imu.rate_hz
            )));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rigslam::rig::euroc::{euroc_cam0, euroc_cam1, euroc_imu0};
    use rigslam::rig::folder::write_atomically;
    use rigslam::rig::kalibr;

    fn folder(cam1: rigslam::rig::CameraCalibration) -> tempfile::TempDir {
        let dir = tempfile::tempdir().expect("temp dir");
        let chain = kalibr::camchain_yaml(&[euroc_cam0(), cam1], true).expect("writes");
        write_atomically(&dir.path().join(CAMCHAIN), chain.as_bytes()).expect("write");
        let imu = euroc_imu0();
        write_atomically(
            &dir.path().join(IMU_NOISE),
            kalibr::imu_yaml(&imu.noise, imu.rate_hz).as_bytes(),
        )
        .expect("write");
        dir
    }

    #[test]
    fn a_sound_folder_passes_and_a_foreign_recording_does_not() {
        let dir = folder(euroc_cam1());
        let findings = check_folder(dir.path(), None);
        assert!(!findings.iter().any(Finding::is_problem), "{findings:?}");
        assert!(
            findings
                .iter()
                .any(|f| f.to_string().contains("baseline 110")),
            "{findings:?}"
        );
        let foreign = Observed {
            image_sizes: vec![(640, 480), (752, 480)],
            imu_rate_hz: Some(100.0),
        };
        let findings = check_folder(dir.path(), Some(&foreign));
        let problems: Vec<String> = findings
            .iter()
            .filter(|f| f.is_problem())
            .map(ToString::to_string)
            .collect();
        assert_eq!(problems.len(), 1, "{problems:?}");
        assert!(problems[0].contains("640x480") && problems[0].contains("752x480"));
        assert!(findings.iter().any(|f| matches!(f, Finding::Warning(m) if m.contains("100.0 Hz") && m.contains("update_rate 200"))));
    }

    #[test]
    fn a_rig_whose_cameras_are_not_one_rig_is_a_problem() {
        let mut far = euroc_cam1();
        far.T_body_cam.translation.vector.x += 5.0;
        let dir = folder(far);
        let findings = check_folder(dir.path(), None);
        assert!(
            findings
                .iter()
                .any(|f| f.is_problem() && f.to_string().contains("baseline")),
            "{findings:?}"
        );
        let empty = tempfile::tempdir().expect("temp dir");
        let findings = check_folder(empty.path(), None);
        assert!(findings
            .iter()
            .any(|f| f.is_problem() && f.to_string().contains("camera-imu")));
    }
}
