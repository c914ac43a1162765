//! The `rigslam-calibrate imu` and `noise` commands end to end on logs
//! written here: the JSON keys users rely on, the files beside the
//! YAML, and a message that says what to recollect on bad input.

use std::path::Path;
use std::process::Command;

use nalgebra::{Matrix3, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

const BIN: &str = env!("CARGO_BIN_EXE_rigslam-calibrate");

/// EuRoC-layout session at 200 Hz: 16 still poses of 4 s joined by 1 s moves.
fn write_session(path: &Path, s: &Matrix3<f64>, b: &Vector3<f64>, poses: usize) {
    let mut rng = ChaCha8Rng::seed_from_u64(9);
    let noise = Normal::new(0.0, 0.02).expect("valid");
    let s_inv = s.try_inverse().expect("invertible");
    let mut text = String::from("#timestamp [ns],w_x,w_y,w_z,a_x,a_y,a_z\n");
    let mut i: i64 = 0;
    let mut up = Vector3::z();
    for _ in 0..poses {
        let next = Vector3::new(
            rng.gen_range(-1.0..1.0),
            rng.gen_range(-1.0..1.0),
            rng.gen_range(-1.0..1.0),
        )
        .normalize();
        for k in 0..1000 {
            let moving = k < 200;
            let dir = if moving {
                (up * (1.0 - k as f64 / 200.0) + next * (k as f64 / 200.0)).normalize()
            } else {
                next
            };
            let a = s_inv * (dir * 9.81 - b) + Vector3::from_fn(|_, _| noise.sample(&mut rng));
            let w = if moving {
                [0.8, -0.4, 0.5]
            } else {
                [0.002, -0.001, 0.003]
            };
            text.push_str(&format!(
                "{},{},{},{},{},{},{}\n",
                i * 5_000_000,
                w[0],
                w[1],
                w[2],
                a.x,
                a.y,
                a.z
            ));
            i += 1;
        }
        up = next;
    }
    std::fs::write(path, text).expect("temp dir is writable");
}

#[test]
fn imu_prints_the_promised_keys_and_writes_the_report() {
    let dir = tempfile::tempdir().expect("temp dir");
    let input = dir.path().join("session.csv");
    let s = Matrix3::new(1.015, 0.01, -0.006, 0.0, 0.99, 0.012, 0.0, 0.0, 1.005);
    let b = Vector3::new(0.2, -0.1, 0.25);
    write_session(&input, &s, &b, 16);
    let folder = dir.path().join("rig");
    let yaml = folder.join("imu_intrinsics.yaml");
    let out = Command::new(BIN)
        .args(["imu", "--json", "--input"])
        .arg(&input)
        .arg("--out")
        .arg(&folder)
        .output()
        .expect("runs");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).expect("one JSON object");
    let scale = Matrix3::from_fn(|i, j| v["accel_scale_matrix"][i][j].as_f64().expect("3x3"));
    let bias = Vector3::from_fn(|i, _| v["accel_bias"][i].as_f64().expect("3"));
    assert!((scale - s).amax() < 1e-3, "{scale}");
    assert!((bias - b).amax() < 1e-3, "{bias}");
    assert!(v["gyro_bias"].as_array().is_some_and(|a| a.len() == 3));
    // No turns in this session: no gyro scale, and the verdict says how to get one.
    assert!(v["gyro_scale_matrix"].is_null());
    assert!(String::from_utf8_lossy(&out.stderr).contains("turn the IMU once"));
    let back = rigslam_calibration::calibration_files::read_intrinsics_yaml(&yaml)
        .expect("the YAML reads back");
    assert!((back.accel_scale - scale).amax() < 1e-12);
    let report = std::fs::read_to_string(folder.join("imu_intrinsics_report.md"))
        .expect("report beside the YAML");
    assert!(report.contains("imu_intrinsics_residuals.png") && report.contains("Nelder-Mead"));
    assert!(
        folder
            .join("imu_intrinsics_residuals.png")
            .metadata()
            .expect("plot written")
            .len()
            > 1000
    );
}

#[test]
fn too_few_poses_and_garbled_files_say_what_to_do() {
    let dir = tempfile::tempdir().expect("temp dir");
    let input = dir.path().join("few.csv");
    write_session(&input, &Matrix3::identity(), &Vector3::zeros(), 4);
    let out = Command::new(BIN)
        .args(["imu", "--input"])
        .arg(&input)
        .arg("--out")
        .arg(dir.path().join("x"))
        .output()
        .expect("runs");
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("too few static poses") && err.contains("recollect"),
        "{err}"
    );

    let garbled = dir.path().join("garbled.csv");
    std::fs::write(
        &garbled,
        "#t,w,w,w,a,a,a\n0,0,0,0,0,0,9.8\n5000000,0,0,zero,0,0,9.8\n",
    )
    .expect("write");
    let out = Command::new(BIN)
        .args(["noise", "--input"])
        .arg(&garbled)
        .arg("--out")
        .arg(dir.path().join("y"))
        .output()
        .expect("runs");
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("garbled.csv:3"), "{err}");
}

#[test]
fn noise_refuses_a_moving_log_and_measures_a_still_one() {
    let dir = tempfile::tempdir().expect("temp dir");
    let mut rng = ChaCha8Rng::seed_from_u64(4);
    let white = Normal::new(0.0, 0.01).expect("valid");
    let mut still = String::new();
    let mut moving = String::new();
    for i in 0..60_000i64 {
        let g: [f64; 6] = std::array::from_fn(|_| white.sample(&mut rng));
        let line = |az: f64| {
            format!(
                "{},{},{},{},{},{},{}\n",
                i * 10_000_000,
                g[0],
                g[1],
                g[2],
                g[3],
                g[4],
                g[5] + az
            )
        };
        still.push_str(&line(9.81));
        // Someone lifts the rig after 5 minutes.
        moving.push_str(&line(if i > 30_000 && i < 30_300 { 12.0 } else { 9.81 }));
    }
    let (p_still, p_moving) = (dir.path().join("still.csv"), dir.path().join("moving.csv"));
    std::fs::write(&p_still, still).expect("write");
    std::fs::write(&p_moving, moving).expect("write");
    let out = Command::new(BIN)
        .args(["noise", "--input"])
        .arg(&p_moving)
        .arg("--out")
        .arg(dir.path().join("m"))
        .output()
        .expect("runs");
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("not static") && err.contains("t = 300.0 s") && err.contains("recollect"),
        "{err}"
    );

    let yaml = dir.path().join("imu.yaml");
    let out = Command::new(BIN)
        .args(["noise", "--json", "--input"])
        .arg(&p_still)
        .arg("--out")
        .arg(dir.path())
        .output()
        .expect("runs");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).expect("one JSON object");
    // White noise of 0.01 per sample at 100 Hz: density 0.01 / sqrt(100) = 1e-3.
    for key in ["gyroscope_noise_density", "accelerometer_noise_density"] {
        let d = v[key].as_f64().expect("number");
        assert!((d / 1e-3 - 1.0).abs() < 0.05, "{key} {d}");
    }
    assert!(v["gyroscope_random_walk"].is_f64() && v["accelerometer_random_walk"].is_f64());
    let text = std::fs::read_to_string(&yaml).expect("imu.yaml written");
    let imu =
        rigslam::rig::kalibr::imu_from_kalibr(&text, &yaml).expect("Kalibr file reads in the core");
    let (noise, rate) = (imu.noise, imu.rate_hz);
    assert_eq!(rate, 100.0);
    assert!(
        (noise.gyroscope_noise_density / v["gyroscope_noise_density"].as_f64().expect("number")
            - 1.0)
            .abs()
            < 1e-5
    );
    assert!(dir.path().join("imu_allan.png").exists() && dir.path().join("imu_report.md").exists());
}

/// The core's warnings reach `rigslam-calibrate`'s stderr (here: a
/// recording's IMU row that is not a number, read by `check --dataset`),
/// and as plain text: stderr is a pipe here, as under systemd, so no
/// colour codes, with `NO_COLOR` set or not.
#[test]
fn warnings_are_logged_without_colour_codes_off_a_terminal() {
    use rigslam::dataset::EurocWriter;
    use rigslam::sensors::{Image, ImuSample, PixelFormat};

    let dir = tempfile::tempdir().expect("tempdir");
    let recording = dir.path().join("recording");
    let mut writer = EurocWriter::create(&recording).expect("create");
    writer
        .write_camera("cam0", &rigslam::rig::euroc::euroc_cam0())
        .expect("camera");
    let image = Image::new(
        752,
        480,
        752,
        PixelFormat::Mono8,
        vec![128u8; 752 * 480].into(),
    )
    .expect("image");
    writer
        .add_image("cam0", 1_000_000_000, &image)
        .expect("png");
    let samples: Vec<ImuSample> = (0..400)
        .map(|i| ImuSample {
            t_ns: 1_000_000_000 + i * 5_000_000,
            gyro_rad_s: if i == 100 { [f64::NAN; 3] } else { [0.0; 3] },
            accel_m_s2: [0.0, 0.0, 9.81],
        })
        .collect();
    writer
        .write_imu(&rigslam::rig::euroc::euroc_imu0(), &samples)
        .expect("imu");
    writer.finish().expect("finish");

    for no_color in [None, Some("1")] {
        let mut cmd = Command::new(BIN);
        cmd.arg("check")
            .arg(dir.path().join("no calibration here"))
            .arg("--dataset")
            .arg(&recording)
            .env_remove("NO_COLOR")
            .env_remove("RUST_LOG");
        if let Some(v) = no_color {
            cmd.env("NO_COLOR", v);
        }
        let out = cmd.output().expect("runs");
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(
            err.contains("WARN") && err.contains("imu0/data.csv") && err.contains("left out"),
            "NO_COLOR={no_color:?}: {err}"
        );
        assert!(!err.contains("\x1b["), "NO_COLOR={no_color:?}: {err:?}");
    }
}

/// A step that fails says its error once and exits non-zero (anyhow's
/// `{:#}` repeated a cause the error already carried).
#[test]
fn a_missing_input_is_said_once() {
    let dir = tempfile::tempdir().expect("tempdir");
    let missing = dir.path().join("missing");
    let mut imu = Command::new(BIN);
    imu.arg("imu")
        .arg("--input")
        .arg(missing.join("session.csv"))
        .arg("--out")
        .arg(dir.path().join("out"));
    let mut check = Command::new(BIN);
    check
        .arg("check")
        .arg(dir.path())
        .arg("--dataset")
        .arg(missing.join("recording"));
    for mut cmd in [imu, check] {
        let out = cmd.output().expect("runs");
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "{err}");
        assert_eq!(err.matches("No such file or directory").count(), 1, "{err}");
        assert!(err.contains(&*missing.to_string_lossy()), "{err}");
    }
}
