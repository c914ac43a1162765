//! Kalibr's calibration files, read and written through serde types:
//! `camchain.yaml` / `camchain-imucam.yaml` (one `camN:` entry per camera:
//! intrinsics, distortion, resolution and, after the camera-IMU step,
//! `T_cam_imu` and `timeshift_cam_imu`) and `imu.yaml` (continuous-time
//! noise and rate, flat as Kalibr takes it in or under `imu0:` as it
//! writes its results).
//!
//! Writing follows the rules Kalibr's own reader enforces (its
//! `CameraParameters` / `ImuParameters` checks): a known camera model with
//! four pinhole intrinsics, `radtan` or `equidistant` with exactly four
//! coefficients, `resolution` as two integers, every number a float, a
//! `rostopic` string, `T_cn_cnm1` on every camera after the first, and
//! `cam_overlaps` naming existing cameras. [`kalibr_problems`] checks a
//! file against those rules.

use std::collections::BTreeMap;
use std::path::Path;

use nalgebra::{Isometry3, Matrix4};
use serde::{Deserialize, Serialize};

use super::{CameraCalibration, ImuCalibration, ImuNoise};
use crate::camera::CameraModel;
use crate::rig::sensor_yaml::{plausible_noise, rigid_from_row_major};
use crate::rig::ImuIntrinsics;
use crate::text_file::DatasetError;

/// One `camN:` entry of a Kalibr camera chain.
#[allow(non_snake_case)]
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct KalibrCamera {
    /// Maps IMU coordinates into this camera (camera-IMU results only).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub T_cam_imu: Option<[[f64; 4]; 4]>,
    /// Maps the previous camera's coordinates into this one (cameras
    /// after the first).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub T_cn_cnm1: Option<[[f64; 4]; 4]>,
    #[serde(default)]
    /// Indices of the cameras whose views overlap this one's (Kalibr writes it; rigslam does not
    /// use it).
    pub cam_overlaps: Vec<u32>,
    /// Projection model; only `pinhole` is read.
    pub camera_model: String,
    /// Distortion coefficients, in the order of `distortion_model`.
    pub distortion_coeffs: Vec<f64>,
    /// `radtan`, `equidistant` or `none`.
    pub distortion_model: String,
    /// `[fu, fv, pu, pv]` for the pinhole model, px.
    pub intrinsics: Vec<f64>,
    /// `[width, height]`, px.
    pub resolution: [u32; 2],
    /// Kalibr requires it; rigslam does not use it.
    #[serde(default)]
    pub rostopic: String,
    /// `t_imu = t_cam + shift`, s (camera-IMU results only).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub timeshift_cam_imu: Option<f64>,
}

/// A camera chain: `cam0`, `cam1`, ... in order.
pub type KalibrCamchain = BTreeMap<String, KalibrCamera>;

/// Kalibr's `imu.yaml` noise block.
#[allow(non_snake_case)]
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct KalibrImu {
    /// m/s^2/sqrt(Hz)
    pub accelerometer_noise_density: f64,
    /// m/s^3/sqrt(Hz)
    pub accelerometer_random_walk: f64,
    /// rad/s/sqrt(Hz)
    pub gyroscope_noise_density: f64,
    /// rad/s^2/sqrt(Hz)
    pub gyroscope_random_walk: f64,
    #[serde(default = "default_imu_topic")]
    /// Kalibr requires it; rigslam does not use it \[`/imu0`\].
    pub rostopic: String,
    /// Hz
    pub update_rate: f64,
    /// Maps the body into this IMU (Kalibr's multi-IMU results; identity
    /// for `imu0`, which is the body).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub T_i_b: Option<[[f64; 4]; 4]>,
}

fn default_imu_topic() -> String {
    "/imu0".into()
}

/// `imu.yaml` as Kalibr takes it in (flat) or writes its results (`imu0:`).
#[derive(Debug, Clone, Deserialize)]
#[serde(untagged)]
enum KalibrImuFile {
    Nested { imu0: KalibrImu },
    Flat(KalibrImu),
}

/// The largest `timeshift_cam_imu` taken as a clock offset, s. More is a
/// unit mistake (ms or ns written as s) or clocks that were never synced.
pub const MAX_TIME_SHIFT_S: f64 = 0.2;

fn rows(m: &Matrix4<f64>) -> [[f64; 4]; 4] {
    [0, 1, 2, 3].map(|r| [m[(r, 0)], m[(r, 1)], m[(r, 2)], m[(r, 3)]])
}

fn row_major(rows: &[[f64; 4]; 4]) -> Vec<f64> {
    rows.iter().flatten().copied().collect()
}

/// Drops OpenCV's `%YAML:1.0` directive, which YAML parsers reject.
fn without_directives(text: &str) -> String {
    text.lines()
        .map(|l| if l.starts_with('%') { "" } else { l })
        .collect::<Vec<_>>()
        .join("\n")
}

fn yaml_error(path: &Path, what: &str, e: serde_yaml::Error) -> DatasetError {
    let line = e.location().map_or(0, |l| l.line());
    DatasetError::malformed(path, line, format!("not a Kalibr {what}: {e}"))
}

/// Whether `text` looks like a Kalibr camera chain (a `cam0:` mapping at
/// the top), as opposed to a EuRoC `sensor.yaml`.
pub fn is_camchain(text: &str) -> bool {
    serde_yaml::from_str::<serde_yaml::Value>(&without_directives(text))
        .ok()
        .and_then(|v| v.get("cam0").map(|c| c.is_mapping()))
        .unwrap_or(false)
}

/// Parses a camera chain's text; `path` names it in errors.
pub fn parse_camchain(text: &str, path: &Path) -> Result<KalibrCamchain, DatasetError> {
    let chain: KalibrCamchain = serde_yaml::from_str(&without_directives(text))
        .map_err(|e| yaml_error(path, "camera chain", e))?;
    for i in 0..chain.len() {
        if !chain.contains_key(&format!("cam{i}")) {
            return Err(DatasetError::malformed(
                path,
                1,
                format!(
                    "cameras must be named cam0, cam1, ... without gaps; found {:?}",
                    chain.keys().collect::<Vec<_>>()
                ),
            ));
        }
    }
    if chain.is_empty() {
        return Err(DatasetError::malformed(path, 1, "no cam0 entry"));
    }
    Ok(chain)
}

/// The rig's cameras from a `camchain-imucam.yaml`, cam0 first. Every
/// camera needs `T_cam_imu`: a plain `camchain.yaml` (intrinsics only)
/// is refused with what to run.
pub fn cameras_from_camchain(
    text: &str,
    path: &Path,
) -> Result<Vec<CameraCalibration>, DatasetError> {
    let chain = parse_camchain(text, path)?;
    (0..chain.len())
        .map(|i| {
            let name = format!("cam{i}");
            let cam = &chain[&name];
            let field = |f: &str| format!("{name}.{f}");
            let model = camera_model(cam, path, &name)?;
            let t_cam_imu = cam.T_cam_imu.as_ref().ok_or_else(|| {
                DatasetError::bad_field(
                    path,
                    field("T_cam_imu"),
                    "missing: this chain has intrinsics only; run `rigslam-calibrate camera-imu` for the camera-IMU extrinsics and time shift",
                )
            })?;
            let t_cam_imu = rigid_from_row_major(&row_major(t_cam_imu))
                .map_err(|m| DatasetError::bad_field(path, field("T_cam_imu"), m))?;
            let shift = cam.timeshift_cam_imu.unwrap_or(0.0);
            check_time_shift(shift)
                .map_err(|m| DatasetError::bad_field(path, field("timeshift_cam_imu"), m))?;
            Ok(CameraCalibration {
                model,
                T_body_cam: t_cam_imu.inverse(),
                rate_hz: 0.0,
                time_shift_cam_imu_s: shift,
            })
        })
        .collect()
}

/// A time shift that is a plausible clock offset.
pub fn check_time_shift(shift_s: f64) -> Result<f64, String> {
    if !shift_s.is_finite() {
        return Err(format!("{shift_s} is not a number of seconds"));
    }
    if shift_s.abs() > MAX_TIME_SHIFT_S {
        return Err(format!(
            "{shift_s} s is not a clock offset between a camera and an IMU on one rig (at most {MAX_TIME_SHIFT_S} s): \
             Kalibr's timeshift_cam_imu is in seconds (t_imu = t_cam + shift); a value this large means ms or ns \
             written as s, or clocks that were never synchronised"
        ));
    }
    Ok(shift_s)
}

fn camera_model(cam: &KalibrCamera, path: &Path, name: &str) -> Result<CameraModel, DatasetError> {
    let bad = |f: &str, m: String| DatasetError::bad_field(path, format!("{name}.{f}"), m);
    if cam.camera_model != "pinhole" {
        return Err(bad(
            "camera_model",
            format!(
                "{:?} is not supported (rigslam's cameras are \"pinhole\" with radtan or equidistant distortion)",
                cam.camera_model
            ),
        ));
    }
    let (model, coefficients) = match cam.distortion_model.as_str() {
        "none" if cam.distortion_coeffs.is_empty() => ("radtan", vec![0.0; 4]),
        other => (other, cam.distortion_coeffs.clone()),
    };
    CameraModel::from_kalibr(
        cam.resolution[0],
        cam.resolution[1],
        model,
        &cam.intrinsics,
        &coefficients,
    )
    .map_err(|e| bad("intrinsics", e.to_string()))
}

/// Parses an `imu.yaml`'s text (flat or under `imu0:`) into the rig's IMU:
/// the body is the IMU unless `T_i_b` says otherwise; no intrinsic
/// correction (that comes from its own file).
pub fn imu_from_kalibr(text: &str, path: &Path) -> Result<ImuCalibration, DatasetError> {
    let imu = match serde_yaml::from_str::<KalibrImuFile>(&without_directives(text))
        .map_err(|e| yaml_error(path, "imu.yaml (the four noise values and update_rate)", e))?
    {
        KalibrImuFile::Nested { imu0 } => imu0,
        KalibrImuFile::Flat(imu) => imu,
    };
    let noise = |field: &str, v: f64, max: f64, typical: f64| {
        plausible_noise(v, max, typical).map_err(|m| DatasetError::bad_field(path, field, m))
    };
    if !(imu.update_rate.is_finite() && imu.update_rate > 0.0) {
        return Err(DatasetError::bad_field(
            path,
            "update_rate",
            format!("expected a positive rate in Hz, found {}", imu.update_rate),
        ));
    }
    let t_body_imu = match &imu.T_i_b {
        Some(t) => rigid_from_row_major(&row_major(t))
            .map_err(|m| DatasetError::bad_field(path, "T_i_b", m))?
            .inverse(),
        None => Isometry3::identity(),
    };
    Ok(ImuCalibration {
        T_body_imu: t_body_imu,
        rate_hz: imu.update_rate,
        noise: ImuNoise {
            gyroscope_noise_density: noise(
                "gyroscope_noise_density",
                imu.gyroscope_noise_density,
                0.1,
                0.005,
            )?,
            gyroscope_random_walk: noise(
                "gyroscope_random_walk",
                imu.gyroscope_random_walk,
                0.1,
                0.0001,
            )?,
            accelerometer_noise_density: noise(
                "accelerometer_noise_density",
                imu.accelerometer_noise_density,
                2.0,
                0.02,
            )?,
            accelerometer_random_walk: noise(
                "accelerometer_random_walk",
                imu.accelerometer_random_walk,
                1.0,
                0.003,
            )?,
        },
        intrinsics: ImuIntrinsics::IDENTITY,
    })
}

/// The Kalibr entry of one camera. `T_cam_imu` and the time shift are
/// written when `with_imu`; `previous` (the camera before it in the chain)
/// gives `T_cn_cnm1`. Radial-tangential with a non-zero k3 cannot be
/// written for Kalibr (it has four coefficients) and is refused.
pub fn kalibr_camera(
    camera: &CameraCalibration,
    previous: Option<&CameraCalibration>,
    topic: &str,
    overlaps: Vec<u32>,
    with_imu: bool,
) -> Result<KalibrCamera, String> {
    let model = &camera.model;
    let mut coefficients = model.distortion_coefficients();
    if let CameraModel::PinholeRadtan(_) = model {
        if coefficients.get(4).is_some_and(|k3| *k3 != 0.0) {
            return Err(format!(
                "radial-tangential with k3 = {} has no Kalibr form (Kalibr's radtan has k1, k2, p1, p2): calibrate with k3 fixed at 0",
                coefficients[4]
            ));
        }
        coefficients.truncate(4);
    }
    let t_cam_body = camera.T_body_cam.inverse();
    Ok(KalibrCamera {
        T_cam_imu: with_imu.then(|| rows(&t_cam_body.to_homogeneous())),
        T_cn_cnm1: previous.map(|p| rows(&(t_cam_body * p.T_body_cam).to_homogeneous())),
        cam_overlaps: overlaps,
        camera_model: "pinhole".into(),
        distortion_coeffs: coefficients,
        distortion_model: model.kalibr_distortion_model().into(),
        intrinsics: model.pinhole().to_vec(),
        resolution: [model.width(), model.height()],
        rostopic: topic.into(),
        timeshift_cam_imu: with_imu.then_some(camera.time_shift_cam_imu_s),
    })
}

/// A whole chain's YAML text (`camchain-imucam.yaml` when `with_imu`,
/// else `camchain.yaml`); every camera overlaps every other.
pub fn camchain_yaml(cameras: &[CameraCalibration], with_imu: bool) -> Result<String, String> {
    let n = cameras.len() as u32;
    let mut chain = KalibrCamchain::new();
    for (i, camera) in cameras.iter().enumerate() {
        let previous = i.checked_sub(1).map(|p| &cameras[p]);
        let overlaps = (0..n).filter(|&j| j != i as u32).collect();
        chain.insert(
            format!("cam{i}"),
            kalibr_camera(
                camera,
                previous,
                &format!("/cam{i}/image_raw"),
                overlaps,
                with_imu,
            )?,
        );
    }
    serde_yaml::to_string(&chain).map_err(|e| e.to_string())
}

/// Kalibr's flat `imu.yaml` for `noise` at `rate_hz`.
pub fn imu_yaml(noise: &ImuNoise, rate_hz: f64) -> String {
    let file = KalibrImu {
        accelerometer_noise_density: noise.accelerometer_noise_density,
        accelerometer_random_walk: noise.accelerometer_random_walk,
        gyroscope_noise_density: noise.gyroscope_noise_density,
        gyroscope_random_walk: noise.gyroscope_random_walk,
        rostopic: default_imu_topic(),
        update_rate: rate_hz,
        T_i_b: None,
    };
    serde_yaml::to_string(&file).expect("a struct of numbers and strings serialises")
}

/// What Kalibr's own reader would object to in a camera chain or an
/// `imu.yaml` (its `ConfigReader` rules; `kind` is "camchain" or "imu"),
/// checked on the YAML values so that a float written as an integer is
/// caught as Kalibr's `isinstance(..., float)` would catch it.
pub fn kalibr_problems(text: &str, kind: &str) -> Vec<String> {
    let mut out = Vec::new();
    let doc: serde_yaml::Value = match serde_yaml::from_str(text) {
        Ok(d) => d,
        Err(e) => return vec![format!("not YAML: {e}")],
    };
    let is_float = |v: &serde_yaml::Value| matches!(v, serde_yaml::Value::Number(n) if n.is_f64());
    let is_int = |v: &serde_yaml::Value| matches!(v, serde_yaml::Value::Number(n) if n.is_i64() || n.is_u64());
    let floats = |v: Option<&serde_yaml::Value>| -> Option<Vec<f64>> {
        v?.as_sequence()?
            .iter()
            .map(|x| if is_float(x) { x.as_f64() } else { None })
            .collect()
    };
    let matrix = |v: Option<&serde_yaml::Value>| -> bool {
        v.and_then(|m| m.as_sequence()).is_some_and(|rows| {
            rows.len() == 4
                && rows.iter().all(|r| {
                    r.as_sequence()
                        .is_some_and(|r| r.len() == 4 && r.iter().all(|x| x.as_f64().is_some()))
                })
        })
    };
    match kind {
        "imu" => {
            let imu = doc.get("imu0").unwrap_or(&doc);
            if !imu.get("rostopic").is_some_and(|t| t.is_string()) {
                out.push("rostopic: missing or not a string".into());
            }
            for key in [
                "update_rate",
                "accelerometer_noise_density",
                "accelerometer_random_walk",
                "gyroscope_noise_density",
                "gyroscope_random_walk",
            ] {
                match imu.get(key).and_then(|v| v.as_f64()) {
                    Some(v) if v > 0.0 => {}
                    _ => out.push(format!("{key}: missing or not positive")),
                }
            }
        }
        _ => {
            let Some(map) = doc.as_mapping() else {
                return vec!["not a mapping of cameras".into()];
            };
            let n = map.len();
            for i in 0..n {
                let name = format!("cam{i}");
                let Some(cam) = doc.get(&name) else {
                    out.push(format!("{name}: missing (cameras are cam0..cam{})", n - 1));
                    continue;
                };
                let p = |m: &str| format!("{name}.{m}");
                if !cam.get("rostopic").is_some_and(|t| t.is_string()) {
                    out.push(p("rostopic: missing or not a string"));
                }
                let model = cam.get("camera_model").and_then(|m| m.as_str());
                let wanted = match model {
                    Some("pinhole") => Some(4),
                    Some("omni") => Some(5),
                    Some("ds") | Some("eucm") => Some(6),
                    _ => None,
                };
                match (wanted, floats(cam.get("intrinsics"))) {
                    (None, _) => out.push(p("camera_model: not one of pinhole, omni, ds, eucm")),
                    (Some(k), Some(v)) if v.len() == k && v.iter().all(|x| *x >= 0.0) => {}
                    (Some(k), _) => {
                        out.push(p(&format!("intrinsics: expected {k} non-negative floats")))
                    }
                }
                let coefficients = match cam.get("distortion_model").and_then(|m| m.as_str()) {
                    Some("radtan") | Some("equidistant") => Some(4),
                    Some("fov") => Some(1),
                    Some("none") => Some(0),
                    _ => None,
                };
                match (coefficients, floats(cam.get("distortion_coeffs"))) {
                    (None, _) => out.push(p(
                        "distortion_model: not one of radtan, equidistant, fov, none",
                    )),
                    (Some(k), Some(v)) if v.len() == k => {}
                    (Some(k), _) => out.push(p(&format!(
                        "distortion_coeffs: the model takes exactly {k} floats"
                    ))),
                }
                let resolution_ok = cam
                    .get("resolution")
                    .and_then(|r| r.as_sequence())
                    .is_some_and(|r| r.len() == 2 && r.iter().all(is_int));
                if !resolution_ok {
                    out.push(p("resolution: expected two integers"));
                }
                if let Some(overlaps) = cam.get("cam_overlaps") {
                    let ok = overlaps.as_sequence().is_some_and(|o| {
                        o.iter()
                            .all(|c| c.as_u64().is_some_and(|c| (c as usize) < n))
                    });
                    if !ok {
                        out.push(p("cam_overlaps: must list existing camera numbers"));
                    }
                }
                if i > 0 && !matrix(cam.get("T_cn_cnm1")) {
                    out.push(p("T_cn_cnm1: missing or not a 4x4 matrix"));
                }
                if let Some(t) = cam.get("T_cam_imu") {
                    if !matrix(Some(t)) {
                        out.push(p("T_cam_imu: not a 4x4 matrix"));
                    }
                }
                if let Some(shift) = cam.get("timeshift_cam_imu") {
                    if !is_float(shift) {
                        out.push(p("timeshift_cam_imu: not a float"));
                    }
                }
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rig::euroc::{euroc_cam0, euroc_cam1, euroc_imu0};

    fn p() -> &'static Path {
        Path::new("camchain-imucam.yaml")
    }

    #[test]
    fn a_written_chain_passes_kalibrs_rules_and_reads_back() {
        let mut cam0 = euroc_cam0();
        cam0.time_shift_cam_imu_s = -0.00125;
        let cameras = vec![cam0, euroc_cam1()];
        let text = camchain_yaml(&cameras, true).expect("writes");
        assert_eq!(kalibr_problems(&text, "camchain"), Vec::<String>::new());
        assert!(is_camchain(&text));
        let back = cameras_from_camchain(&text, p()).expect("reads");
        assert_eq!(back.len(), 2);
        for (a, b) in cameras.iter().zip(&back) {
            assert_eq!(a.model, b.model);
            assert_eq!(a.time_shift_cam_imu_s, b.time_shift_cam_imu_s);
            let d = a.T_body_cam.inverse() * b.T_body_cam;
            assert!(d.translation.vector.norm() < 1e-12 && d.rotation.angle() < 1e-12);
        }
        // T_cn_cnm1 is the stereo extrinsic cam0 -> cam1.
        let chain = parse_camchain(&text, p()).expect("parses");
        let t10 = chain["cam1"].T_cn_cnm1.expect("cam1 has it");
        let expected = (cameras[1].T_body_cam.inverse() * cameras[0].T_body_cam).to_homogeneous();
        assert!((Matrix4::from_fn(|r, c| t10[r][c]) - expected).amax() < 1e-12);
    }

    #[test]
    fn kalibrs_rules_catch_what_kalibr_would_refuse() {
        let text = camchain_yaml(&[euroc_cam0(), euroc_cam1()], true).expect("writes");
        let broken = [
            (
                "distortion_coeffs:\n  - -0.28340811",
                "distortion_coeffs:\n  - 0.0\n  - -0.28340811",
            ),
            ("rostopic: /cam0/image_raw", "topic: /cam0/image_raw"),
            ("camera_model: pinhole", "camera_model: fisheye"),
            ("- 752\n", "- 752.5\n"),
        ];
        for (from, to) in broken {
            assert!(text.contains(from), "{from:?} not in\n{text}");
            let bad = text.replacen(from, to, 1);
            assert!(
                !kalibr_problems(&bad, "camchain").is_empty(),
                "{to:?} passed"
            );
        }
        let no_baseline = camchain_yaml(&[euroc_cam0(), euroc_cam1()], true)
            .expect("writes")
            .replace("T_cn_cnm1", "T_other");
        assert!(kalibr_problems(&no_baseline, "camchain")
            .iter()
            .any(|m| m.contains("T_cn_cnm1")));
    }

    #[test]
    fn a_radtan_k3_is_refused_rather_than_dropped() {
        let mut cam = euroc_cam0();
        let [fx, fy, cx, cy] = cam.model.pinhole();
        cam.model = CameraModel::from_kalibr(
            752,
            480,
            "radtan",
            &[fx, fy, cx, cy],
            &[-0.28, 0.07, 0.0, 0.0, 0.01],
        )
        .expect("valid");
        let e = camchain_yaml(&[cam], true).expect_err("k3 has no Kalibr form");
        assert!(e.contains("k3"), "{e}");
    }

    #[test]
    fn a_camera_only_chain_asks_for_the_camera_imu_step() {
        let text = camchain_yaml(&[euroc_cam0()], false).expect("writes");
        assert_eq!(kalibr_problems(&text, "camchain"), Vec::<String>::new());
        let e = cameras_from_camchain(&text, p())
            .expect_err("no T_cam_imu")
            .to_string();
        assert!(e.contains("T_cam_imu") && e.contains("camera-imu"), "{e}");
    }

    #[test]
    fn bad_extrinsics_and_time_shifts_are_named() {
        let text = camchain_yaml(&[euroc_cam0()], true).expect("writes");
        let mut chain = parse_camchain(&text, p()).expect("parses");
        let cam = chain.get_mut("cam0").expect("cam0");
        cam.timeshift_cam_imu = Some(2.5);
        let shifted = serde_yaml::to_string(&chain).expect("writes");
        let e = cameras_from_camchain(&shifted, p())
            .expect_err("seconds")
            .to_string();
        assert!(e.contains("timeshift_cam_imu") && e.contains("2.5"), "{e}");
        let cam = chain.get_mut("cam0").expect("cam0");
        cam.timeshift_cam_imu = Some(0.0);
        cam.T_cam_imu = Some([
            [2.0, 0.0, 0.0, 0.0],
            [0.0, 1.0, 0.0, 0.0],
            [0.0, 0.0, 1.0, 0.0],
            [0.0, 0.0, 0.0, 1.0],
        ]);
        let scaled = serde_yaml::to_string(&chain).expect("writes");
        let e = cameras_from_camchain(&scaled, p())
            .expect_err("not a rotation")
            .to_string();
        assert!(e.contains("cam0.T_cam_imu"), "{e}");
    }

    #[test]
    fn imu_yaml_round_trips_flat_and_nested() {
        let imu = euroc_imu0();
        let text = imu_yaml(&imu.noise, imu.rate_hz);
        assert_eq!(kalibr_problems(&text, "imu"), Vec::<String>::new());
        let back = imu_from_kalibr(&text, Path::new("imu.yaml")).expect("reads");
        assert_eq!(back.noise, imu.noise);
        assert_eq!(back.rate_hz, 200.0);
        let nested = format!(
            "imu0:\n{}",
            text.lines().map(|l| format!("  {l}\n")).collect::<String>()
        );
        let back = imu_from_kalibr(&nested, Path::new("imu.yaml")).expect("reads nested");
        assert_eq!(back.noise, imu.noise);
        let degrees = text.replace(
            &format!(
                "gyroscope_noise_density: {}",
                imu.noise.gyroscope_noise_density
            ),
            "gyroscope_noise_density: 0.5",
        );
        let e = imu_from_kalibr(&degrees, Path::new("imu.yaml"))
            .expect_err("implausible")
            .to_string();
        assert!(e.contains("gyroscope_noise_density"), "{e}");
    }
}
