//! `rigslam-calibrate export`: every file has every key its loader reads,
//! in the shape it reads it (schemas made from each project's public
//! example configuration, fixtures/calibration_export/PROVENANCE.md), and
//! the values mean what ours mean, checked through each project's own
//! documented formulas.

use std::path::{Path, PathBuf};
use std::process::Command;

use nalgebra::{Matrix3, Matrix4, Vector3};
use rigslam::imu::ImuIntrinsics;
use rigslam::rig::euroc::{euroc_cam0, euroc_cam1, euroc_imu0};
use rigslam::rig::{kalibr, RigModel};
use rigslam_calibration::export::{export, ExportTarget};
use serde_yaml::Value;

const BIN: &str = env!("CARGO_BIN_EXE_rigslam-calibrate");

fn fixtures() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../fixtures/calibration_export")
}

fn rig() -> RigModel {
    let mut cam0 = euroc_cam0();
    cam0.time_shift_cam_imu_s = 0.0025;
    let mut cam1 = euroc_cam1();
    cam1.time_shift_cam_imu_s = 0.0025;
    let mut imu = euroc_imu0();
    imu.intrinsics = ImuIntrinsics {
        gyro_scale: Matrix3::new(
            1.01, 0.002, -0.001, 0.003, 0.99, 0.004, -0.002, 0.001, 1.005,
        ),
        gyro_offset_rad_s: Vector3::new(0.002, -0.001, 0.003),
        // Lower-triangular, which every target can carry.
        accel_scale: Matrix3::new(1.02, 0.0, 0.0, 0.01, 0.98, 0.0, -0.005, 0.003, 1.01),
        accel_offset_m_s2: Vector3::new(0.1, -0.05, 0.2),
    };
    RigModel {
        cameras: vec![cam0, cam1],
        imu: Some(imu),
    }
}

/// Parses a YAML file as OpenCV writes them (directive line, `!!` tags).
fn opencv_yaml(text: &str) -> Value {
    let body: String = text
        .lines()
        .filter(|l| !l.starts_with('%'))
        .map(|l| l.replace(" !!opencv-matrix", ""))
        .collect::<Vec<_>>()
        .join("\n");
    serde_yaml::from_str(&body).expect("valid YAML")
}

fn numbers(v: &Value) -> Option<Vec<f64>> {
    v.as_sequence()?.iter().map(|x| x.as_f64()).collect()
}

fn shape_ok(v: &Value, shape: &str) -> bool {
    let (kind, size) = shape.split_once(':').unwrap_or((shape, ""));
    let dims: Vec<usize> = size.split('x').filter_map(|d| d.parse().ok()).collect();
    match kind {
        "string" => v.is_string(),
        "number" => v.as_f64().is_some(),
        "integer" => v.as_i64().is_some(),
        "integers" => v.as_sequence().is_some_and(|s| {
            s.iter().all(|x| x.as_i64().is_some()) && dims.first().is_none_or(|n| s.len() == *n)
        }),
        "numbers" => numbers(v).is_some_and(|s| dims.first().is_none_or(|n| s.len() == *n)),
        "matrix" => v.as_sequence().is_some_and(|rows| {
            rows.len() == dims[0]
                && rows
                    .iter()
                    .all(|r| numbers(r).is_some_and(|r| r.len() == dims[1]))
        }),
        "opencv-matrix" => {
            v["rows"].as_u64() == Some(dims[0] as u64)
                && v["cols"].as_u64() == Some(dims[1] as u64)
                && v["dt"].as_str() == Some("d")
                && numbers(&v["data"]).is_some_and(|d| d.len() == dims[0] * dims[1])
        }
        "poses" => v.as_sequence().is_some_and(|s| {
            s.iter().all(|p| {
                ["px", "py", "pz", "qx", "qy", "qz", "qw"]
                    .iter()
                    .all(|k| p[*k].as_f64().is_some())
            })
        }),
        "cameras" => v.as_sequence().is_some_and(|s| {
            s.iter()
                .all(|c| c["camera_type"].is_string() && c["intrinsics"]["fx"].as_f64().is_some())
        }),
        "resolutions" => v.as_sequence().is_some_and(|s| {
            s.iter()
                .all(|r| r.as_sequence().is_some_and(|r| r.len() == 2))
        }),
        other => panic!("unknown shape {other}"),
    }
}

/// Every key of `schema` present with its shape; the problems otherwise.
fn schema_problems(doc: &Value, schema: &str) -> Vec<String> {
    let schema: serde_json::Map<String, serde_json::Value> =
        serde_json::from_str(&std::fs::read_to_string(fixtures().join(schema)).expect("fixture"))
            .expect("schema JSON");
    let mut out = Vec::new();
    for (path, shape) in schema {
        let shape = shape.as_str().expect("shape string");
        let parts: Vec<&str> = path.split('.').collect();
        let roots: Vec<&Value> = if parts[0] == "camN" {
            doc.as_mapping()
                .expect("mapping")
                .iter()
                .filter(|(k, _)| k.as_str().is_some_and(|k| k.starts_with("cam")))
                .map(|(_, v)| v)
                .collect()
        } else {
            vec![&doc[parts[0]]]
        };
        assert!(!roots.is_empty(), "{path}: no entry");
        for root in roots {
            let v = parts[1..].iter().fold(root, |v, k| &v[*k]);
            if !shape_ok(v, shape) {
                out.push(format!("{path}: expected {shape}, found {v:?}"));
            }
        }
    }
    out
}

fn file<'a>(e: &'a rigslam_calibration::export::Export, name: &str) -> &'a str {
    &e.files
        .iter()
        .find(|f| f.name == name)
        .unwrap_or_else(|| panic!("{name} written"))
        .text
}

fn matrix<const R: usize, const C: usize>(v: &Value) -> nalgebra::SMatrix<f64, R, C> {
    nalgebra::SMatrix::from_fn(|r, c| v[r][c].as_f64().expect("number"))
}

#[test]
fn openvins_files_have_its_keys_and_its_intrinsic_model_reproduces_ours() {
    let rig = rig();
    let e = export(&rig, ExportTarget::Openvins).expect("exports");
    let chain = opencv_yaml(file(&e, "kalibr_imucam_chain.yaml"));
    let imu = opencv_yaml(file(&e, "kalibr_imu_chain.yaml"));
    assert_eq!(
        schema_problems(&chain, "openvins_kalibr_imucam_chain.json"),
        Vec::<String>::new()
    );
    assert_eq!(
        schema_problems(&imu, "openvins_kalibr_imu_chain.json"),
        Vec::<String>::new()
    );
    for (i, cam) in rig.cameras.iter().enumerate() {
        let t: Matrix4<f64> = matrix(&chain[format!("cam{i}").as_str()]["T_imu_cam"]);
        assert!((t - cam.T_body_cam.to_homogeneous()).amax() < 1e-12);
        assert_eq!(
            chain[format!("cam{i}").as_str()]["timeshift_cam_imu"].as_f64(),
            Some(0.0025)
        );
    }
    // OpenVINS: w = R_GYROtoIMU Dw (w_m - b), Dw = Tw^-1, kalibr model keeps
    // Dw's lower triangle: that must give our S.
    let i = &rig.imu.as_ref().expect("imu").intrinsics;
    for (t, r, s) in [
        ("Tw", "R_IMUtoGYRO", i.gyro_scale),
        ("Ta", "R_IMUtoACC", i.accel_scale),
    ] {
        let tw: Matrix3<f64> = matrix(&imu["imu0"][t]);
        let d = tw.try_inverse().expect("invertible");
        let lower = Matrix3::from_fn(|r, c| if c <= r { d[(r, c)] } else { 0.0 });
        let r_imu_to: Matrix3<f64> = matrix(&imu["imu0"][r]);
        assert!((r_imu_to.transpose() * lower - s).amax() < 1e-9, "{t}");
    }
    assert!(e.notes.iter().any(|n| n.contains("bias")), "{:?}", e.notes);
}

#[test]
fn basalt_file_has_its_keys_and_its_calibration_formula_reproduces_ours() {
    let rig = rig();
    let e = export(&rig, ExportTarget::Basalt).expect("exports");
    let doc: Value = serde_yaml::from_str(file(&e, "calibration.json")).expect("JSON is YAML");
    assert_eq!(
        schema_problems(&doc, "basalt_calibration.json"),
        Vec::<String>::new()
    );
    let v = &doc["value0"];
    assert_eq!(
        v["intrinsics"][0]["camera_type"].as_str(),
        Some("pinhole-radtan8")
    );
    assert_eq!(v["cam_time_offset_ns"].as_i64(), Some(2_500_000));
    // Basalt: accel (I + L) a - b with L from parameters 3..9 (column 0,
    // then (1,1), (2,1), (2,2)); gyro (I + M) w - b with M column-major.
    let a = numbers(&v["calib_accel_bias"]).expect("9");
    let g = numbers(&v["calib_gyro_bias"]).expect("12");
    let l = Matrix3::new(a[3], 0.0, 0.0, a[4], a[6], 0.0, a[5], a[7], a[8]);
    let m = Matrix3::from_column_slice(&g[3..12]);
    let i = rig.imu.as_ref().expect("imu").intrinsics;
    let raw = rigslam::sensors::ImuSample {
        t_ns: 0,
        gyro_rad_s: [0.3, -0.2, 0.5],
        accel_m_s2: [1.0, 2.0, 9.0],
    };
    let ours = i.correct(&raw);
    let basalt_a =
        (Matrix3::identity() + l) * Vector3::from(raw.accel_m_s2) - Vector3::new(a[0], a[1], a[2]);
    let basalt_g =
        (Matrix3::identity() + m) * Vector3::from(raw.gyro_rad_s) - Vector3::new(g[0], g[1], g[2]);
    assert!((basalt_a - Vector3::from(ours.accel_m_s2)).amax() < 1e-12);
    assert!((basalt_g - Vector3::from(ours.gyro_rad_s)).amax() < 1e-12);
    // T_imu_cam is the camera's pose in the IMU frame.
    let p = &v["T_imu_cam"][1];
    let t = rig.cameras[1].T_body_cam.translation.vector;
    assert!((p["px"].as_f64().expect("px") - t.x).abs() < 1e-12);
}

#[test]
fn vins_files_have_its_keys_and_its_clock_convention() {
    let rig = rig();
    let e = export(&rig, ExportTarget::Vins).expect("exports");
    let config = opencv_yaml(file(&e, "vins_config.yaml"));
    assert_eq!(
        schema_problems(&config, "vins_config.json"),
        Vec::<String>::new()
    );
    for cam in ["cam0.yaml", "cam1.yaml"] {
        let c = opencv_yaml(file(&e, cam));
        assert_eq!(
            schema_problems(&c, "vins_camera.json"),
            Vec::<String>::new()
        );
    }
    assert!(file(&e, "vins_config.yaml").contains("body_T_cam0: !!opencv-matrix"));
    let data = numbers(&config["body_T_cam1"]["data"]).expect("16");
    let t = Matrix4::from_row_slice(&data);
    assert!((t - rig.cameras[1].T_body_cam.to_homogeneous()).amax() < 1e-12);
    // "image clock + td = IMU clock" is Kalibr's t_imu = t_cam + shift.
    assert_eq!(config["td"].as_f64(), Some(0.0025));
    assert!(
        e.notes.iter().any(|n| n.contains("intrinsics")),
        "{:?}",
        e.notes
    );
}

#[test]
fn what_a_format_cannot_carry_is_refused_or_said() {
    let mut rig = rig();
    let [fx, fy, cx, cy] = rig.cameras[0].model.pinhole();
    rig.cameras[0].model = rigslam::camera::CameraModel::from_kalibr(
        752,
        480,
        "radtan",
        &[fx, fy, cx, cy],
        &[-0.28, 0.07, 0.0, 0.0, 0.01],
    )
    .expect("valid");
    for target in [
        ExportTarget::Openvins,
        ExportTarget::Basalt,
        ExportTarget::Vins,
    ] {
        let e = export(&rig, target).expect_err("k3").to_string();
        assert!(e.contains("k3"), "{target:?}: {e}");
    }
    let mut rig = self::rig();
    rig.imu.as_mut().expect("imu").intrinsics.accel_scale[(0, 2)] = 0.004;
    let e = export(&rig, ExportTarget::Basalt).expect("exports");
    assert!(
        e.notes.iter().any(|n| n.contains("lower-triangular")),
        "{:?}",
        e.notes
    );
}

#[test]
fn the_cli_exports_a_calibration_folder() {
    let dir = tempfile::tempdir().expect("temp dir");
    let folder = dir.path().join("rig");
    std::fs::create_dir(&folder).expect("mkdir");
    let r = rig();
    std::fs::write(
        folder.join("camchain-imucam.yaml"),
        kalibr::camchain_yaml(&r.cameras, true).expect("writes"),
    )
    .expect("write");
    let imu = r.imu.as_ref().expect("imu");
    std::fs::write(
        folder.join("imu.yaml"),
        kalibr::imu_yaml(&imu.noise, imu.rate_hz),
    )
    .expect("write");
    let out = dir.path().join("openvins");
    let run = Command::new(BIN)
        .args(["export", "--to", "openvins"])
        .arg(&folder)
        .arg("--out")
        .arg(&out)
        .output()
        .expect("runs");
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    assert!(
        out.join("kalibr_imucam_chain.yaml").exists() && out.join("kalibr_imu_chain.yaml").exists()
    );
    let empty = dir.path().join("empty");
    std::fs::create_dir(&empty).expect("mkdir");
    let run = Command::new(BIN)
        .args(["export", "--to", "basalt"])
        .arg(&empty)
        .arg("--out")
        .arg(dir.path().join("b"))
        .output()
        .expect("runs");
    assert!(!run.status.success());
    assert!(String::from_utf8_lossy(&run.stderr).contains("camchain-imucam.yaml"));
}
