//! Our camera calibration against OpenCV 5.0 run on the same 13 real
//! chessboard images (fixtures/opencv/chessboard_9x6_25mm.json, made by
//! bench/peers/opencv_chessboard.sh; provenance in fixtures/opencv/README.md).
//! It separates the three things that could make our focal length differ
//! from the reference left_intrinsics.yml: the solver and model (our LM on
//! OpenCV's own corners against cv2.calibrateCamera, under the reference's
//! flags too), the corners (ours against cv2.cornerSubPix), and the
//! reference's corner window.

use std::process::Command;

use nalgebra::{Vector2, Vector3};
use rigslam::shared_data::shared_data_dir;
use rigslam_calibration::chessboard::{detect_chessboard, ChessboardConfig, GreyImage};
use rigslam_calibration::intrinsics_lm::{
    calibrate_intrinsics, calibrate_intrinsics_with, IntrinsicsOptions,
};
use serde_json::Value;

const BIN: &str = env!("CARGO_BIN_EXE_rigslam-calibrate");
/// fx = fy of ../shared/data/calib/chessboard_9x6_25mm/left_intrinsics.yml.
const REFERENCE_F_PX: f64 = 535.915_733_961_632;

fn fixture() -> Value {
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../fixtures/opencv/chessboard_9x6_25mm.json"
    );
    serde_json::from_str(&std::fs::read_to_string(path).expect("fixture present"))
        .expect("fixture is JSON")
}

fn views(value: &Value) -> Vec<Vec<Vector2<f64>>> {
    value
        .as_array()
        .expect("a list of views")
        .iter()
        .map(|view| {
            view.as_array()
                .expect("a list of corners")
                .iter()
                .map(|c| Vector2::new(c[0].as_f64().unwrap(), c[1].as_f64().unwrap()))
                .collect()
        })
        .collect()
}

fn board() -> Vec<Vector3<f64>> {
    (0..54)
        .map(|i| Vector3::new((i % 9) as f64 * 0.025, (i / 9) as f64 * 0.025, 0.0))
        .collect()
}

/// Our detector's corners of the fixture's images, in the fixture's order,
/// each view put in OpenCV's corner order (the two detectors may start the
/// grid at different board corners): each of OpenCV's corners takes our
/// nearest one, which is unambiguous as corners are 24 px or more apart.
fn our_corners(names: &[Value], opencv: &[Vec<Vector2<f64>>]) -> Option<Vec<Vec<Vector2<f64>>>> {
    let dir = shared_data_dir()?.join("calib/chessboard_9x6_25mm");
    Some(
        names
            .iter()
            .zip(opencv)
            .map(|(name, theirs)| {
                let img = image::open(dir.join(name.as_str().unwrap()))
                    .expect("a readable JPEG")
                    .to_luma8();
                let grey = GreyImage::from_luma8(
                    img.width() as usize,
                    img.height() as usize,
                    img.as_raw(),
                );
                let ours = detect_chessboard(&grey, 9, 6, &ChessboardConfig::default())
                    .expect("board found")
                    .corners_px;
                theirs
                    .iter()
                    .map(|t| {
                        let nearest = ours
                            .iter()
                            .min_by(|a, b| (*a - t).norm().total_cmp(&(*b - t).norm()))
                            .expect("corners");
                        assert!((nearest - t).norm() < 8.0, "{name}: no corner near {t}");
                        *nearest
                    })
                    .collect()
            })
            .collect(),
    )
}

fn rms(a: &[Vector2<f64>], b: &[Vector2<f64>]) -> f64 {
    (a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).norm_squared())
        .sum::<f64>()
        / a.len() as f64)
        .sqrt()
}

#[test]
fn our_solver_reproduces_calibrate_camera_on_opencvs_corners_under_each_flag_set() {
    let f = fixture();
    let corners = views(&f["corners_px"]);
    for (name, run) in f["calibrations"].as_object().expect("runs") {
        let flags = run["flags"].as_u64().unwrap();
        // CALIB_FIX_ASPECT_RATIO = 2, CALIB_FIX_K3 = 128; OpenCV keeps every view.
        let options = IntrinsicsOptions {
            fix_aspect_ratio: (flags & 2 != 0).then_some(1.0),
            fix_k3: flags & 128 != 0,
            reject_outlier_views: false,
        };
        let cal =
            calibrate_intrinsics_with(640, 480, &board(), &corners, &options).expect("solvable");
        let c = &cal.camera;
        println!(
            "{name}: ours fx {:.4} fy {:.4} cx {:.4} cy {:.4} rms {:.5}; OpenCV fx {:.4} fy {:.4} cx {:.4} cy {:.4} rms {:.5}",
            c.fx, c.fy, c.cx, c.cy, cal.rms_px,
            run["fx"].as_f64().unwrap(), run["fy"].as_f64().unwrap(),
            run["cx"].as_f64().unwrap(), run["cy"].as_f64().unwrap(),
            run["rms_px"].as_f64().unwrap()
        );
        for (ours, key) in [(c.fx, "fx"), (c.fy, "fy"), (c.cx, "cx"), (c.cy, "cy")] {
            let theirs = run[key].as_f64().unwrap();
            assert!(
                (ours - theirs).abs() < 0.02,
                "{name} {key}: {ours} vs {theirs}"
            );
        }
        let theirs: Vec<f64> = run["k1_k2_p1_p2_k3"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_f64().unwrap())
            .collect();
        for (ours, theirs) in c.distortion.iter().zip(&theirs) {
            assert!(
                (ours - theirs).abs() < 1e-3,
                "{name}: {:?} vs {theirs:?}",
                c.distortion
            );
        }
        assert!((cal.rms_px - run["rms_px"].as_f64().unwrap()).abs() < 1e-4);
    }
}

#[test]
fn our_corners_agree_with_corner_sub_pix_at_our_window_size() {
    let f = fixture();
    let names = f["images"].as_array().unwrap().clone();
    let win5 = views(&f["corners_win5_px"]);
    let win11 = views(&f["corners_px"]);
    let Some(ours) = our_corners(&names, &win5) else {
        return;
    };
    let mut all_5 = Vec::new();
    for (k, name) in names.iter().enumerate() {
        let d5 = rms(&ours[k], &win5[k]);
        let d11 = rms(&ours[k], &win11[k]);
        let mean: Vector2<f64> = ours[k]
            .iter()
            .zip(&win5[k])
            .map(|(a, b)| a - b)
            .sum::<Vector2<f64>>()
            / 54.0;
        println!(
            "{name}: ours - cornerSubPix(5x5 half window) rms {d5:.3} px, mean ({:+.3}, {:+.3}); vs (11x11) rms {d11:.3} px",
            mean.x, mean.y
        );
        assert!(mean.norm() < 0.03, "{name}: mean offset {mean}");
        all_5.push(d5);
    }
    all_5.sort_by(f64::total_cmp);
    // Measured 2026-11-23: median 0.035 px, worst view 0.048 px; the mean
    // offset of every view is below 0.02 px (no bias).
    assert!(all_5[all_5.len() / 2] < 0.06, "median {all_5:?}");
    assert!(all_5[all_5.len() - 1] < 0.1, "worst {all_5:?}");
}

#[test]
fn like_for_like_our_focal_length_matches_opencv_at_a_window_that_fits_the_squares() {
    let f = fixture();
    let names = f["images"].as_array().unwrap().clone();
    let win11 = views(&f["corners_px"]);
    // The fixture is OpenCV's reference procedure: under the reference's
    // flags it lands within 0.05 % of left_intrinsics.yml.
    let reproduced = f["calibrations"]["fix_aspect"]["fx"].as_f64().unwrap();
    assert!(
        (reproduced / REFERENCE_F_PX - 1.0).abs() < 5e-4,
        "{reproduced}"
    );
    let Some(ours) = our_corners(&names, &win11) else {
        return;
    };
    let cal = calibrate_intrinsics(640, 480, &board(), &ours).expect("solvable");
    let held = calibrate_intrinsics_with(
        640,
        480,
        &board(),
        &ours,
        &IntrinsicsOptions {
            fix_aspect_ratio: Some(1.0),
            ..IntrinsicsOptions::default()
        },
    )
    .expect("solvable");
    let sweep = &f["window_sweep_flags0"];
    for window in 3..=11 {
        let run = &sweep[window.to_string()];
        println!(
            "OpenCV cornerSubPix half window {window}: fx {:.2} fy {:.2} rms {:.3}",
            run["fx"].as_f64().unwrap(),
            run["fy"].as_f64().unwrap(),
            run["rms_px"].as_f64().unwrap()
        );
    }
    println!(
        "ours: fx {:.3} fy {:.3} rms {:.3}; fx = fy held: {:.3} rms {:.3}; reference {REFERENCE_F_PX:.3}",
        cal.camera.fx, cal.camera.fy, cal.rms_px, held.camera.fx, held.rms_px
    );
    // Our detector's window is 11x11 px, OpenCV's half window 5.
    let opencv = &sweep["5"];
    for (ours, key) in [(cal.camera.fx, "fx"), (cal.camera.fy, "fy")] {
        let theirs = opencv[key].as_f64().unwrap();
        assert!(
            (ours / theirs - 1.0).abs() < 1e-3,
            "{key}: {ours} vs OpenCV {theirs}"
        );
    }
    assert!(cal.rms_px <= opencv["rms_px"].as_f64().unwrap() + 0.01);
}

#[test]
fn the_cli_holds_the_aspect_ratio_when_asked_and_refuses_a_bad_one() {
    let Some(dir) = shared_data_dir().map(|d| d.join("calib/chessboard_9x6_25mm")) else {
        return;
    };
    let out = tempfile::tempdir().expect("temp dir");
    let run = |extra: &[&str]| {
        Command::new(BIN)
            .args(["camera", "--images"])
            .arg(&dir)
            .args(["--board", "9x6", "--square", "0.025", "--json", "--out"])
            .arg(out.path())
            .args(extra)
            .output()
            .expect("runs")
    };
    let held = run(&["--fix-aspect-ratio"]);
    assert!(
        held.status.success(),
        "{}",
        String::from_utf8_lossy(&held.stderr)
    );
    let json: Value = serde_json::from_slice(&held.stdout).expect("JSON on stdout");
    assert_eq!(json["fx"], json["fy"]);
    assert_eq!(json["distortion"][4].as_f64(), Some(0.0));
    assert_eq!(json["fix_aspect_ratio"].as_f64(), Some(1.0));
    println!(
        "--fix-aspect-ratio (k3 held at 0 by default): fx = fy {} rms {}",
        json["fx"], json["rms_px"]
    );
    // The camera's entry of the rig's Kalibr chain, valid by Kalibr's rules.
    let chain = std::fs::read_to_string(out.path().join("camchain.yaml")).expect("written");
    assert_eq!(
        rigslam::rig::kalibr::kalibr_problems(&chain, "camchain"),
        Vec::<String>::new()
    );
    let cam = rigslam_calibration::camchain_yaml::parse_intrinsics(
        &chain,
        &out.path().join("camchain.yaml"),
        "cam0",
    )
    .expect("reads back");
    assert_eq!(Some(cam.fx), json["fx"].as_f64());
    assert!(out.path().join("cam0_camera_report.md").exists());
    // With k3 estimated the chain is left alone (Kalibr has no k3) and
    // the output says so.
    let free = Command::new(BIN)
        .args(["camera", "--images"])
        .arg(&dir)
        .args(["--board", "9x6", "--square", "0.025", "--free-k3", "--out"])
        .arg(out.path())
        .output()
        .expect("runs");
    assert!(free.status.success());
    let said = String::from_utf8_lossy(&free.stdout);
    assert!(
        said.contains("not written") && said.contains("k3"),
        "{said}"
    );
    assert_eq!(
        std::fs::read_to_string(out.path().join("camchain.yaml")).expect("still there"),
        chain
    );
    let bad = run(&["--fix-aspect-ratio=0"]);
    assert!(!bad.status.success());
    let message = String::from_utf8_lossy(&bad.stderr);
    assert!(message.contains("positive"), "{message}");
}
