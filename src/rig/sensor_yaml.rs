//! EuRoC / Kalibr `sensor.yaml` files: a camera's pinhole intrinsics
//! (radial-tangential or equidistant distortion) and `T_BS`, or an IMU's
//! `T_BS`, rate and continuous-time noise. They begin with OpenCV's `%YAML:1.0` directive, which YAML
//! parsers reject, so directive lines are dropped before parsing.

use std::fmt::Write as _;
use std::path::Path;

use nalgebra::{Isometry3, Matrix3, Matrix4, Rotation3, Translation3, UnitQuaternion};
use serde_yaml::Value;

use super::{CameraCalibration, ImuCalibration, ImuNoise};
use crate::camera::{CameraError, CameraModel};
use crate::text_file::text::read_text;
use crate::text_file::DatasetError;

/// How far `R^T R` may be from identity in a file's `T_BS` (EuRoC prints
/// 12 digits; Kalibr 16).
const ROTATION_TOLERANCE: f64 = 1e-6;

/// Reads a camera `sensor.yaml`.
pub fn read_camera_yaml(path: &Path) -> Result<CameraCalibration, DatasetError> {
    parse_camera_yaml(&read_text(path)?, path)
}

/// Parses the text of a camera `sensor.yaml`; `path` names it in errors
/// (a file, or where the text came from, e.g. a recording's attachment).
pub fn parse_camera_yaml(text: &str, path: &Path) -> Result<CameraCalibration, DatasetError> {
    let doc = parse_doc(text, path)?;
    let f = Fields { path, doc: &doc };
    let camera_model = f.string("camera_model")?;
    if camera_model != "pinhole" {
        return Err(f.bad(
            "camera_model",
            format!("{camera_model:?} is not supported (only \"pinhole\")"),
        ));
    }
    // ROS's camera_info calls radial-tangential `plumb_bob`.
    let distortion_model = match f.string("distortion_model")?.as_str() {
        "plumb_bob" => "radtan".to_owned(),
        other => other.to_owned(),
    };
    let resolution = f.numbers("resolution")?;
    let (width, height) = match resolution[..] {
        [w, h] if is_u32(w) && is_u32(h) => (w as u32, h as u32),
        _ => {
            return Err(f.bad(
                "resolution",
                format!("expected two positive integers [width, height], found {resolution:?}"),
            ))
        }
    };
    let intrinsics = f.numbers("intrinsics")?;
    let coefficients = f.numbers("distortion_coefficients")?;
    // The camera constructor checks sizes, finiteness and focal lengths.
    let model =
        CameraModel::from_kalibr(width, height, &distortion_model, &intrinsics, &coefficients)
            .map_err(|e| f.bad(camera_error_field(&e), e.to_string()))?;
    Ok(CameraCalibration {
        model,
        T_body_cam: f.transform("T_BS")?,
        // Optional: the camera's rate is the driver's business; a file
        // without it reads as 0 (unknown).
        rate_hz: if f.doc.get("rate_hz").is_some() {
            f.positive("rate_hz")?
        } else {
            0.0
        },
        // Not part of EuRoC's layout; rigslam writes it when not zero.
        time_shift_cam_imu_s: if f.doc.get("timeshift_cam_imu").is_some() {
            f.number("timeshift_cam_imu")?
        } else {
            0.0
        },
    })
}

/// Reads an IMU `sensor.yaml` with Kalibr's noise names.
pub fn read_imu_yaml(path: &Path) -> Result<ImuCalibration, DatasetError> {
    parse_imu_yaml(&read_text(path)?, path)
}

/// Parses the text of an IMU `sensor.yaml`; `path` names it in errors.
pub fn parse_imu_yaml(text: &str, path: &Path) -> Result<ImuCalibration, DatasetError> {
    let doc = parse_doc(text, path)?;
    let f = Fields { path, doc: &doc };
    Ok(ImuCalibration {
        intrinsics: crate::rig::ImuIntrinsics::IDENTITY,
        T_body_imu: f.transform("T_BS")?,
        rate_hz: f.positive("rate_hz")?,
        noise: ImuNoise {
            gyroscope_noise_density: f.plausible_noise("gyroscope_noise_density", 0.1, 0.005)?,
            gyroscope_random_walk: f.plausible_noise("gyroscope_random_walk", 0.1, 0.0001)?,
            accelerometer_noise_density: f.plausible_noise(
                "accelerometer_noise_density",
                2.0,
                0.02,
            )?,
            accelerometer_random_walk: f.plausible_noise(
                "accelerometer_random_walk",
                1.0,
                0.003,
            )?,
        },
    })
}

/// A camera `sensor.yaml` in EuRoC's layout. Numbers are printed in their
/// shortest exact form, so reading the file back gives the same values.
/// Radial-tangential is written with EuRoC's name and its k3 only when it
/// is not zero (Kalibr's radtan has four); equidistant with Kalibr's name
/// and k1..k4.
pub fn camera_yaml(name: &str, calib: &CameraCalibration) -> String {
    let model = &calib.model;
    let mut coefficients = model.distortion_coefficients();
    let distortion_model = match model {
        CameraModel::PinholeRadtan(_) => {
            if coefficients[4] == 0.0 {
                coefficients.truncate(4);
            }
            "radial-tangential"
        }
        CameraModel::PinholeEquidistant(_) => model.kalibr_distortion_model(),
    };
    let [fx, fy, cx, cy] = model.pinhole();
    let mut s = String::new();
    s.push_str("%YAML:1.0\n# General sensor definitions.\nsensor_type: camera\n");
    let _ = writeln!(s, "comment: {name}, written by rigslam\n");
    s.push_str("# Sensor extrinsics wrt. the body-frame.\n");
    s.push_str(&transform_yaml("T_BS", &calib.T_body_cam));
    s.push_str("\n# Camera specific definitions.\n");
    if calib.rate_hz > 0.0 {
        let _ = writeln!(s, "rate_hz: {}", calib.rate_hz);
    }
    if calib.time_shift_cam_imu_s != 0.0 {
        let _ = writeln!(s, "timeshift_cam_imu: {}", calib.time_shift_cam_imu_s);
    }
    let _ = writeln!(s, "resolution: [{}, {}]", model.width(), model.height());
    s.push_str("camera_model: pinhole\n");
    let _ = writeln!(s, "intrinsics: [{fx}, {fy}, {cx}, {cy}] #fu, fv, cu, cv");
    let _ = writeln!(s, "distortion_model: {distortion_model}");
    let _ = writeln!(s, "distortion_coefficients: [{}]", join(&coefficients));
    s
}

/// An IMU `sensor.yaml` in EuRoC's layout with Kalibr's noise names.
pub fn imu_yaml(calib: &ImuCalibration) -> String {
    let n = &calib.noise;
    let mut s = String::new();
    s.push_str("%YAML:1.0\nsensor_type: imu\ncomment: IMU, written by rigslam\n\n");
    s.push_str("# Sensor extrinsics wrt. the body-frame.\n");
    s.push_str(&transform_yaml("T_BS", &calib.T_body_imu));
    let _ = writeln!(s, "rate_hz: {}\n", calib.rate_hz);
    s.push_str("# inertial sensor noise model parameters (continuous time)\n");
    let _ = writeln!(
        s,
        "gyroscope_noise_density: {}     # [ rad / s / sqrt(Hz) ]",
        n.gyroscope_noise_density
    );
    let _ = writeln!(
        s,
        "gyroscope_random_walk: {}       # [ rad / s^2 / sqrt(Hz) ]",
        n.gyroscope_random_walk
    );
    let _ = writeln!(
        s,
        "accelerometer_noise_density: {} # [ m / s^2 / sqrt(Hz) ]",
        n.accelerometer_noise_density
    );
    let _ = writeln!(
        s,
        "accelerometer_random_walk: {}   # [ m / s^3 / sqrt(Hz) ]",
        n.accelerometer_random_walk
    );
    s
}

/// The `sensor.yaml` of a ground-truth folder: identity `T_BS`.
pub fn groundtruth_yaml() -> String {
    let mut s = String::from(
        "%YAML:1.0\nsensor_type: visual-inertial\ncomment: ground truth, written by rigslam\n\n",
    );
    s.push_str(&transform_yaml("T_BS", &Isometry3::identity()));
    s
}

fn transform_yaml(key: &str, t: &Isometry3<f64>) -> String {
    let m = t.to_homogeneous();
    let rows: Vec<String> = (0..4)
        .map(|r| join(&[m[(r, 0)], m[(r, 1)], m[(r, 2)], m[(r, 3)]]))
        .collect();
    format!(
        "{key}:\n  cols: 4\n  rows: 4\n  data: [{},\n         {},\n         {},\n         {}]\n",
        rows[0], rows[1], rows[2], rows[3]
    )
}

fn join(values: &[f64]) -> String {
    values
        .iter()
        .map(|v| v.to_string())
        .collect::<Vec<_>>()
        .join(", ")
}

/// A whole number that fits a `u32`; zero is left to the camera
/// constructor, which names it.
fn is_u32(v: f64) -> bool {
    v >= 0.0 && v <= u32::MAX as f64 && v.fract() == 0.0
}

/// The `sensor.yaml` field a rejected camera parameter came from.
fn camera_error_field(e: &CameraError) -> &'static str {
    match e {
        CameraError::EmptyImage { .. } => "resolution",
        CameraError::UnknownDistortionModel { .. } => "distortion_model",
        CameraError::WrongLength { field, .. } => field,
        CameraError::NonPositiveFocalLength { .. } => "intrinsics",
        CameraError::NotFinite { name, .. } => {
            if matches!(*name, "fx" | "fy" | "cx" | "cy") {
                "intrinsics"
            } else {
                "distortion_coefficients"
            }
        }
    }
}

/// Parses a YAML file after dropping `%` directive lines.
fn parse_doc(text: &str, path: &Path) -> Result<Value, DatasetError> {
    let body: String = text
        .lines()
        .map(|l| if l.starts_with('%') { "" } else { l })
        .collect::<Vec<_>>()
        .join("\n");
    let doc: Value = serde_yaml::from_str(&body).map_err(|e| {
        let line = e.location().map_or(0, |l| l.line());
        DatasetError::malformed(path, line, format!("not valid YAML: {e}"))
    })?;
    if !doc.is_mapping() {
        return Err(DatasetError::malformed(path, 1, "expected a YAML mapping"));
    }
    Ok(doc)
}

/// What a sensor.yaml without one of the IMU's noise figures is told.
const MISSING_NOISE: &str = "missing: the IMU's noise figures (continuous time, SI units per sqrt(Hz), Kalibr's convention) come from its datasheet, or from `rigslam-calibrate noise` on a log recorded at rest; the estimator refines the weighting online from there";

/// Typed access to a parsed YAML mapping, each error naming the field.
struct Fields<'a> {
    path: &'a Path,
    doc: &'a Value,
}

impl Fields<'_> {
    fn bad(&self, field: &str, message: impl Into<String>) -> DatasetError {
        DatasetError::bad_field(self.path, field, message)
    }

    fn get(&self, field: &str) -> Result<&Value, DatasetError> {
        match self.doc.get(field) {
            Some(v) => Ok(untag(v)),
            None => Err(self.bad(field, "missing")),
        }
    }

    fn string(&self, field: &str) -> Result<String, DatasetError> {
        self.get(field)?
            .as_str()
            .map(str::to_owned)
            .ok_or_else(|| self.bad(field, "expected a string"))
    }

    fn number(&self, field: &str) -> Result<f64, DatasetError> {
        as_number(self.get(field)?).ok_or_else(|| self.bad(field, "expected a number"))
    }

    fn positive(&self, field: &str) -> Result<f64, DatasetError> {
        let v = self.number(field)?;
        if v.is_finite() && v > 0.0 {
            Ok(v)
        } else {
            Err(self.bad(
                field,
                format!("expected a positive finite number, found {v}"),
            ))
        }
    }

    /// A noise figure: positive, and at most `max` (SI units per
    /// sqrt(Hz)); above that it is a unit or convention mistake (deg
    /// instead of rad, a per-sample sigma, a variance), and weighing the
    /// IMU by it would throw the IMU away. `typical` is a consumer MEMS
    /// part's value, for the message.
    fn plausible_noise(&self, field: &str, max: f64, typical: f64) -> Result<f64, DatasetError> {
        if self.doc.get(field).is_none() {
            return Err(self.bad(field, MISSING_NOISE));
        }
        let v = self.positive(field)?;
        plausible_noise(v, max, typical).map_err(|m| self.bad(field, m))
    }

    fn numbers(&self, field: &str) -> Result<Vec<f64>, DatasetError> {
        numbers_of(self.get(field)?).ok_or_else(|| self.bad(field, "expected a list of numbers"))
    }

    /// A 4x4 rigid transform, either `{rows: 4, cols: 4, data: [16]}` or a
    /// list of 16 numbers or of four rows of four.
    fn transform(&self, field: &str) -> Result<Isometry3<f64>, DatasetError> {
        let v = self.get(field)?;
        let data = match v.get("data") {
            Some(d) => {
                for key in ["rows", "cols"] {
                    if let Some(n) = v.get(key) {
                        if as_number(untag(n)) != Some(4.0) {
                            return Err(self.bad(field, format!("`{key}` must be 4")));
                        }
                    }
                }
                numbers_of(untag(d))
            }
            None => numbers_of(v).or_else(|| {
                let rows = v.as_sequence()?;
                let mut out = Vec::new();
                for r in rows {
                    out.extend(numbers_of(untag(r))?);
                }
                Some(out)
            }),
        }
        .ok_or_else(|| self.bad(field, "expected a 4x4 matrix (rows, cols, data)"))?;
        rigid_from_row_major(&data).map_err(|m| self.bad(field, m))
    }
}

/// Checks a continuous-time IMU noise density `v` (SI units per
/// sqrt(Hz), Kalibr's convention) as the `sensor.yaml` reader does, for
/// readers of other layouts (Kalibr's `imu.yaml`): `v` must be positive
/// and finite and at most `max`; a larger value is a unit or convention
/// mistake (degrees, a per-sample sigma, a variance). `typical` (a
/// consumer MEMS part's value) only goes into the error message, which is
/// the `Err` string.
pub fn plausible_noise(v: f64, max: f64, typical: f64) -> Result<f64, String> {
    if !(v.is_finite() && v > 0.0) {
        return Err(format!("expected a positive finite number, found {v}"));
    }
    if v <= max {
        Ok(v)
    } else {
        Err(format!(
            "{v} is not a plausible noise figure (at most {max}; a consumer MEMS IMU has about {typical}): \
             give it in SI units per sqrt(Hz), as a continuous-time density (Kalibr's convention), \
             not in degrees, per sample or as a variance"
        ))
    }
}

/// Checks and converts 16 row-major numbers into a rigid transform.
pub fn rigid_from_row_major(data: &[f64]) -> Result<Isometry3<f64>, String> {
    if data.len() != 16 {
        return Err(format!("expected 16 numbers, found {}", data.len()));
    }
    if !data.iter().all(|v| v.is_finite()) {
        return Err("values must be finite".into());
    }
    let m = Matrix4::from_row_slice(data);
    let last = m.row(3);
    if (last - nalgebra::RowVector4::new(0.0, 0.0, 0.0, 1.0)).amax() > 1e-9 {
        return Err(format!("last row must be [0, 0, 0, 1], found {last}"));
    }
    let r: Matrix3<f64> = m.fixed_view::<3, 3>(0, 0).into_owned();
    rigid_from_parts(&r, m[(0, 3)], m[(1, 3)], m[(2, 3)], ROTATION_TOLERANCE)
}

/// A rotation matrix (checked for orthonormality within `tolerance` and
/// for handedness, then projected onto SO(3)) and a translation as a
/// rigid transform.
pub fn rigid_from_parts(
    r: &Matrix3<f64>,
    x: f64,
    y: f64,
    z: f64,
    tolerance: f64,
) -> Result<Isometry3<f64>, String> {
    let orthonormality = (r.transpose() * r - Matrix3::identity()).amax();
    // NaN fails the first test too.
    if orthonormality.is_nan() || orthonormality > tolerance || r.determinant() <= 0.0 {
        return Err(format!(
            "rotation part is not a rotation (|R^T R - I| = {orthonormality:.2e}, det = {:.6})",
            r.determinant()
        ));
    }
    let rotation = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_eps(
        r,
        1e-15,
        100,
        Rotation3::identity(),
    ));
    Ok(Isometry3::from_parts(Translation3::new(x, y, z), rotation))
}

fn untag(v: &Value) -> &Value {
    match v {
        Value::Tagged(t) => untag(&t.value),
        other => other,
    }
}

fn as_number(v: &Value) -> Option<f64> {
    match untag(v) {
        Value::Number(n) => n.as_f64(),
        Value::String(s) => s.trim().parse().ok(),
        _ => None,
    }
}

fn numbers_of(v: &Value) -> Option<Vec<f64>> {
    untag(v).as_sequence()?.iter().map(as_number).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    const EUROC_CAM0: &str = "%YAML:1.0
# General sensor definitions.
sensor_type: camera
comment: VI-Sensor cam0 (MT9M034)
T_BS:
  cols: 4
  rows: 4
  data: [0.0148655429818, -0.999880929698, 0.00414029679422, -0.0216401454975,
         0.999557249008, 0.0149672133247, 0.025715529948, -0.064676986768,
        -0.0257744366974, 0.00375618835797, 0.999660727178, 0.00981073058949,
         0.0, 0.0, 0.0, 1.0]
rate_hz: 20
resolution: [752, 480]
camera_model: pinhole
intrinsics: [458.654, 457.296, 367.215, 248.375] #fu, fv, cu, cv
distortion_model: radial-tangential
distortion_coefficients: [-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05]
";

    fn write(dir: &Path, text: &str) -> std::path::PathBuf {
        let path = dir.join("sensor.yaml");
        std::fs::write(&path, text).expect("write yaml");
        path
    }

    #[test]
    fn reads_euroc_camera_yaml() {
        let dir = tempfile::tempdir().expect("temp dir");
        let calib = read_camera_yaml(&write(dir.path(), EUROC_CAM0)).expect("valid yaml");
        let CameraModel::PinholeRadtan(c) = &calib.model else {
            panic!("expected a pinhole-radtan camera");
        };
        assert_eq!((c.width, c.height), (752, 480));
        assert_eq!(
            [c.fx, c.fy, c.cx, c.cy],
            [458.654, 457.296, 367.215, 248.375]
        );
        assert_eq!(
            c.distortion,
            [-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05, 0.0]
        );
        assert_eq!(calib.rate_hz, 20.0);
        let t = calib.T_body_cam.translation.vector;
        assert_eq!(
            [t.x, t.y, t.z],
            [-0.0216401454975, -0.064676986768, 0.00981073058949]
        );
        let r = calib.T_body_cam.rotation.to_rotation_matrix();
        assert!((r[(1, 0)] - 0.999557249008).abs() < 1e-9);
        assert!((r[(0, 1)] + 0.999880929698).abs() < 1e-9);
    }

    #[test]
    fn camera_yaml_round_trips() {
        let dir = tempfile::tempdir().expect("temp dir");
        let calib = read_camera_yaml(&write(dir.path(), EUROC_CAM0)).expect("valid yaml");
        let mut with_k3 = calib.clone();
        let CameraModel::PinholeRadtan(c) = &mut with_k3.model else {
            panic!("expected a pinhole-radtan camera");
        };
        c.distortion[4] = -0.0123;
        // Kalibr's calibration of the TUM-VI fisheye cam0.
        let fisheye = CameraCalibration {
            time_shift_cam_imu_s: 0.0,
            model: CameraModel::from_kalibr(
                512,
                512,
                "equidistant",
                &[
                    190.97847715128717,
                    190.9733070521226,
                    254.93170605935475,
                    256.8974428996504,
                ],
                &[
                    0.0034823894022493434,
                    0.0007150348452162257,
                    -0.0020532361418706202,
                    0.00020293673591811182,
                ],
            )
            .expect("valid fisheye"),
            ..calib.clone()
        };
        for original in [calib, with_k3, fisheye] {
            let text = camera_yaml("cam0", &original);
            let back = read_camera_yaml(&write(dir.path(), &text)).expect("written yaml reads");
            assert_eq!(back.model, original.model);
            assert_eq!(back.rate_hz, original.rate_hz);
            assert_eq!(back.T_body_cam.translation, original.T_body_cam.translation);
            assert!(
                back.T_body_cam
                    .rotation
                    .angle_to(&original.T_body_cam.rotation)
                    < 1e-15
            );
        }
    }

    /// The model named in the file decides the variant and how many
    /// coefficients it takes; ROS's `plumb_bob` is radial-tangential.
    #[test]
    fn distortion_model_selects_the_camera() {
        let dir = tempfile::tempdir().expect("temp dir");
        let radtan = read_camera_yaml(&write(dir.path(), EUROC_CAM0)).expect("radtan");
        let text = EUROC_CAM0.replace("radial-tangential", "plumb_bob");
        let plumb_bob = read_camera_yaml(&write(dir.path(), &text)).expect("plumb_bob");
        assert_eq!(plumb_bob.model, radtan.model);

        let text = EUROC_CAM0.replace("radial-tangential", "equidistant");
        let fisheye = read_camera_yaml(&write(dir.path(), &text)).expect("equidistant");
        let CameraModel::PinholeEquidistant(c) = &fisheye.model else {
            panic!("expected a pinhole-equidistant camera");
        };
        assert_eq!(c.pinhole(), [458.654, 457.296, 367.215, 248.375]);
        assert_eq!(
            c.distortion(),
            [-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05]
        );
        assert!(camera_yaml("cam0", &fisheye).contains("distortion_model: equidistant\n"));
    }

    #[test]
    fn imu_yaml_round_trips() {
        let dir = tempfile::tempdir().expect("temp dir");
        let calib = ImuCalibration {
            intrinsics: crate::rig::ImuIntrinsics::IDENTITY,
            T_body_imu: Isometry3::from_parts(
                Translation3::new(0.01, -0.02, 0.3),
                UnitQuaternion::from_euler_angles(0.1, 0.2, -0.3),
            ),
            rate_hz: 200.0,
            noise: ImuNoise::EUROC_ADIS16448,
        };
        let back = read_imu_yaml(&write(dir.path(), &imu_yaml(&calib))).expect("reads");
        assert_eq!(back.noise, calib.noise);
        assert_eq!(back.rate_hz, 200.0);
        assert!(
            back.T_body_imu
                .rotation
                .angle_to(&calib.T_body_imu.rotation)
                < 1e-15
        );
        assert_eq!(back.T_body_imu.translation, calib.T_body_imu.translation);
    }

    /// Noise figures of zero, below zero, absurd (1e3: deg instead of
    /// rad, a variance, ...) or missing are refused, naming the key.
    #[test]
    fn implausible_or_missing_imu_noise_is_refused_by_name() {
        let dir = tempfile::tempdir().expect("temp dir");
        let calib = ImuCalibration {
            intrinsics: crate::rig::ImuIntrinsics::IDENTITY,
            T_body_imu: Isometry3::identity(),
            rate_hz: 200.0,
            noise: ImuNoise::EUROC_ADIS16448,
        };
        let good = imu_yaml(&calib);
        for key in [
            "gyroscope_noise_density",
            "gyroscope_random_walk",
            "accelerometer_noise_density",
            "accelerometer_random_walk",
        ] {
            let line = good
                .lines()
                .find(|l| l.starts_with(key))
                .expect("the writer writes every key")
                .to_string();
            for (value, says) in [
                ("0.0", "positive"),
                ("-0.002", "positive"),
                ("1000.0", "not a plausible noise figure"),
            ] {
                let text = good.replace(&line, &format!("{key}: {value}"));
                let err = read_imu_yaml(&write(dir.path(), &text))
                    .unwrap_err()
                    .to_string();
                assert!(
                    err.contains(key) && err.contains(says),
                    "{key}={value}: {err}"
                );
            }
            let text = good.replace(&line, "");
            let err = read_imu_yaml(&write(dir.path(), &text))
                .unwrap_err()
                .to_string();
            assert!(
                err.contains(key) && err.contains("rigslam-calibrate noise"),
                "{key} missing: {err}"
            );
        }
    }

    /// Each broken variant must fail with an error naming the field.
    #[test]
    fn bad_fields_are_named() {
        let dir = tempfile::tempdir().expect("temp dir");
        let cases: [(&str, &str, &str); 18] = [
            ("resolution: [752, 480]", "resolution: [752]", "resolution"),
            (
                "resolution: [752, 480]",
                "resolution: [752, -480]",
                "resolution",
            ),
            (
                "resolution: [752, 480]",
                "resolution: [752.5, 480]",
                "resolution",
            ),
            (
                "intrinsics: [458.654, 457.296, 367.215, 248.375]",
                "intrinsics: [458.654, 457.296, 367.215]",
                "intrinsics",
            ),
            (
                "intrinsics: [458.654, 457.296, 367.215, 248.375]",
                "intrinsics: [458.654, .nan, 367.215, 1]",
                "intrinsics",
            ),
            (
                "camera_model: pinhole",
                "camera_model: omni",
                "camera_model",
            ),
            (
                "distortion_model: radial-tangential",
                "distortion_model: fov",
                "distortion_model",
            ),
            (
                "distortion_model: radial-tangential",
                "distortion_model: [radtan]",
                "distortion_model",
            ),
            ("resolution: [752, 480]", "resolution: [0, 480]", "resolution"),
            (
                "intrinsics: [458.654, 457.296, 367.215, 248.375]",
                "intrinsics: [458.654, -457.296, 367.215, 248.375]",
                "intrinsics",
            ),
            (
                "intrinsics: [458.654, 457.296, 367.215, 248.375]",
                "intrinsics: [458.654, 457.296, .inf, 248.375]",
                "intrinsics",
            ),
            (", 1.76187114e-05]", ", .nan]", "distortion_coefficients"),
            // Equidistant takes exactly four.
            (
                "distortion_model: radial-tangential\ndistortion_coefficients: [-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05]",
                "distortion_model: equidistant\ndistortion_coefficients: [-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05, 0.1]",
                "distortion_coefficients",
            ),
            (", 1.76187114e-05]", "]", "distortion_coefficients"),
            ("0.0, 0.0, 0.0, 1.0]", "0.0, 0.0, 1.0, 1.0]", "T_BS"),
            (
                "0.0148655429818, -0.999880929698",
                "0.5, -0.999880929698",
                "T_BS",
            ),
            ("0.0, 0.0, 0.0, 1.0]", "0.0, 0.0, 1.0]", "T_BS"),
            ("rate_hz: 20", "rate_hz: zero", "rate_hz"),
        ];
        for (from, to, field) in cases {
            assert!(EUROC_CAM0.contains(from), "{from}");
            let path = write(dir.path(), &EUROC_CAM0.replace(from, to));
            let err = read_camera_yaml(&path).expect_err(to);
            assert!(
                matches!(&err, DatasetError::BadField { field: f, .. } if f == field),
                "{to}: {err}"
            );
        }
        // Missing fields: cut the field's text (for T_BS its whole block).
        for (field, from, to) in [
            ("T_BS", "T_BS:", "rate_hz:"),
            ("intrinsics", "intrinsics:", "distortion_model:"),
            ("resolution", "resolution:", "camera_model:"),
        ] {
            let (a, b) = (
                EUROC_CAM0.find(from).expect("in text"),
                EUROC_CAM0.find(to).expect("in text"),
            );
            let text = format!("{}{}", &EUROC_CAM0[..a], &EUROC_CAM0[b..]);
            let err = read_camera_yaml(&write(dir.path(), &text)).expect_err(field);
            assert!(
                matches!(&err, DatasetError::BadField { field: f, message, .. } if f == field && message == "missing"),
                "{field}: {err}"
            );
        }
    }

    #[test]
    fn broken_yaml_is_an_error_not_a_panic() {
        let dir = tempfile::tempdir().expect("temp dir");
        for text in [
            "",
            "%YAML:1.0\n",
            "just a string",
            "T_BS: [1, 2\nrate_hz: 20",
            &EUROC_CAM0[..EUROC_CAM0.len() / 2],
            "\u{0}\u{1}\u{2}garbage: [",
        ] {
            let path = write(dir.path(), text);
            assert!(read_camera_yaml(&path).is_err(), "{text:?}");
            assert!(read_imu_yaml(&path).is_err(), "{text:?}");
        }
        std::fs::write(dir.path().join("bin.yaml"), [0xffu8, 0xfe, 0x00, 0x80]).expect("write");
        assert!(read_camera_yaml(&dir.path().join("bin.yaml")).is_err());
    }
}
