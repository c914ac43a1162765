//! The window's online refinement of the camera-IMU calibration, on a
//! rendered stereo-inertial sequence whose calibration file is wrong the
//! way a user's may be: camera 0 (and with it the stereo pair) rotated by
//! 1 deg and moved by 1 cm in the IMU frame, and a time shift 5 ms off.
//!
//! The sequence is 30 s of EuRoC V1_02's motion rendered with EuRoC's
//! calibration and an IMU synthesised from the motion with the datasheet's
//! noise, so the true calibration is exactly the rendering's. Runs: no
//! refinement; the default (rotation, time offset and stereo rotation
//! refined, the translation held); the translation freed too; and the
//! translation freed with the held keyframes' body states following the
//! calibration (`camera_imu_held_keyframes_follow`); and the default
//! started in flight, 12 s in, as it is and with the gyroscope bias freed
//! when the file's test releases the calibration
//! (`camera_imu_release_frees_gyro_bias`: the visual-inertial alignment in
//! motion found the bias through the wrong rotation, and held, the bias
//! holds the rotation back).
//! Asserted: the rotation converges to within 0.1 deg and the time offset
//! to within 0.5 ms of the truth in every refined run; a freed
//! translation gets no worse than the file; started in flight, freeing the
//! gyroscope bias brings the rotation closer; the default tracks the wrong
//! file better than no refinement; the status warning flags the wrong
//! file, not the right one, and `rigslamd` replaying the sequence with the
//! wrong camera files (1 deg, 1 cm) logs the warning, with the right ones
//! not.
//!
//! A correct file costs the default under 3 % of its ATE here (asserted):
//! with the first patch on (2026-12-07) the file's test never releases
//! it on this sequence (0.0037 m with and without the refinement; on
//! 2026-12-05 it was released at solve 6 and cost 0.0079 -> 0.0111 m,
//! docs/results/camera-imu-score-variance-2026-12-05.md).
//!
//! Not met, measured and printed (asserted with
//! `RIGSLAM_CAMERA_IMU_BARS=1`):
//! - The freed translation within 3 mm. This motion hardly shows the lever
//!   arm in 30 s: it ends 5-6 mm from the truth (2026-12-07; 8-10 mm
//!   before the first patch).
//! - The wrong file's ATE back to the true file's (0.0088 against 0.0037
//!   m, the lever arm held 10 mm off; 0.0069 m freed).

use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};

use rigslam::relative::{CameraImuRefinement, RelativeConfig, SensorMode};
use rigslam::rig::RigModel;
use rigslam::run::dataset_run::{rig_of, run_dataset, DatasetRun};
use rigslam::run::report::CameraImuReport;

#[path = "common/v1_02_synthetic.rs"]
mod v1_02_synthetic;
use v1_02_synthetic::render_v1_02_synthetic;

fn shared_data() -> std::path::PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data")
}

/// How a run refines the calibration.
#[derive(Clone, Copy, PartialEq)]
enum Refine {
    Off,
    /// The default: rotation, time offset and stereo rotation; the
    /// translation held.
    Default,
    /// The translation freed too (its sigma 3 cm).
    Translation,
    /// The translation freed (2 cm) and the held keyframes' body states
    /// following the calibration (`camera_imu_held_keyframes_follow`).
    Follow,
    /// The default, and the gyroscope bias freed when the test releases
    /// the calibration after a start in flight
    /// (`camera_imu_release_frees_gyro_bias`).
    FreeGyroBias,
}

/// (ATE, the refinement's final answer).
fn run(
    sequence: &std::path::Path,
    rig: &RigModel,
    refine: Refine,
) -> (f64, Option<CameraImuReport>) {
    run_from(sequence, rig, refine, 0.0)
}

/// [`run`] starting `start_s` into the sequence.
fn run_from(
    sequence: &std::path::Path,
    rig: &RigModel,
    refine: Refine,
    start_s: f64,
) -> (f64, Option<CameraImuReport>) {
    let mut config = RelativeConfig {
        camera_imu_refinement: if refine == Refine::Off {
            CameraImuRefinement::Off
        } else {
            CameraImuRefinement::On
        },
        ..RelativeConfig::default()
    };
    if refine == Refine::Translation {
        config.camera_imu_translation_sigma_m = 0.03;
    }
    if refine == Refine::FreeGyroBias {
        config.camera_imu_release_frees_gyro_bias = true;
    }
    if refine == Refine::Follow {
        config.camera_imu_translation_sigma_m = 0.02;
        config.camera_imu_held_keyframes_follow =
            rigslam::relative::window::HeldKeyframesFollow::On;
    }
    let run = DatasetRun {
        mode: Some(SensorMode::StereoInertial),
        rig: Some(rig.clone()),
        start_s,
        settings: rigslam::slam_config::SlamSettings {
            relative: config,
            ..Default::default()
        },
        ..DatasetRun::default()
    };
    let result = run_dataset(sequence, &run, |_, _| {}).expect("the run");
    (
        result.evaluation.expect("ground truth").report.ate_rmse_m,
        result.report.camera_imu,
    )
}

/// Angle (deg) and distance (m) of the refined camera 0 from `truth`.
#[allow(non_snake_case)]
fn from_truth(report: &CameraImuReport, truth: &Isometry3<f64>) -> (f64, f64) {
    let [w, x, y, z] = report.rotation_body_cam0_wxyz;
    let q = UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(w, x, y, z));
    let angle = (truth.rotation.inverse() * q).angle().to_degrees();
    let t = Vector3::from(report.translation_body_cam0_m);
    (angle, (t - truth.translation.vector).norm())
}

/// Where the run started in flight begins, s into the sequence: the rig
/// is moving and turning there.
const FLIGHT_START_S: f64 = 12.0;

#[test]
fn a_wrong_calibration_file_is_corrected_online() {
    let work = tempfile::tempdir().expect("temp dir");
    let sequence = work.path().join("sequence");
    render_v1_02_synthetic(
        &shared_data().join("euroc/ground_truth/V1_02_groundtruth.csv"),
        &sequence,
    );
    let dataset = rigslam::dataset::open_dataset(&sequence).expect("opens");
    let truth_rig = rig_of(&dataset);
    let truth = truth_rig.cameras[0].T_body_cam;

    // The wrong file: camera 0 rotated by 1 deg about an oblique axis and
    // moved by 1 cm, camera 1 kept in camera 0's frame, and a time shift
    // of +5 ms (the frames restamped 5 ms after they were taken).
    let axis = nalgebra::Unit::new_normalize(Vector3::new(0.6, -0.8, 0.0));
    let error = Isometry3::from_parts(
        Translation3::new(0.0, 0.0, 0.0),
        UnitQuaternion::from_axis_angle(&axis, 1f64.to_radians()),
    );
    let mut wrong = truth * error;
    wrong.translation.vector += Vector3::new(0.0, 0.006, 0.008);
    let mut wrong_rig = truth_rig.clone();
    for cam in wrong_rig.cameras.iter_mut() {
        cam.T_body_cam = wrong * truth.inverse() * cam.T_body_cam;
        cam.time_shift_cam_imu_s = 0.005;
    }

    let (ate_true_off, _) = run(&sequence, &truth_rig, Refine::Off);
    let (ate_true_on, est_true) = run(&sequence, &truth_rig, Refine::Default);
    let (ate_wrong_off, none) = run(&sequence, &wrong_rig, Refine::Off);
    let (ate_wrong_on, est_wrong) = run(&sequence, &wrong_rig, Refine::Default);
    let (ate_wrong_freed, est_freed) = run(&sequence, &wrong_rig, Refine::Translation);
    let (ate_wrong_follow, est_follow) = run(&sequence, &wrong_rig, Refine::Follow);
    let (ate_flight, est_flight) = run_from(&sequence, &wrong_rig, Refine::Default, FLIGHT_START_S);
    let (ate_flight_free, est_flight_free) =
        run_from(&sequence, &wrong_rig, Refine::FreeGyroBias, FLIGHT_START_S);
    assert!(none.is_none(), "refinement off reports no estimate");
    let est_true = est_true.expect("refined");
    let est_wrong = est_wrong.expect("refined");
    let est_freed = est_freed.expect("refined");
    let est_follow = est_follow.expect("refined");
    let est_flight = est_flight.expect("refined");
    let est_flight_free = est_flight_free.expect("refined");
    let (rot_true, trans_true) = from_truth(&est_true, &truth);
    let (rot_wrong, trans_wrong) = from_truth(&est_wrong, &truth);
    let (rot_freed, trans_freed) = from_truth(&est_freed, &truth);
    let (rot_follow, trans_follow) = from_truth(&est_follow, &truth);
    let (rot_flight, _) = from_truth(&est_flight, &truth);
    let (rot_flight_free, _) = from_truth(&est_flight_free, &truth);
    println!(
        "true file: ATE {ate_true_off:.4} m without refinement, {ate_true_on:.4} m with; estimate {rot_true:.3} deg, {:.1} mm, {:+.2} ms from the truth, stereo rotation moved {:.3} deg",
        trans_true * 1e3,
        est_true.time_offset_ms,
        est_true.stereo_rotation_from_file_deg
    );
    println!(
        "wrong file (1 deg, 10 mm, -5 ms): ATE {ate_wrong_off:.4} m without refinement, {ate_wrong_on:.4} m with; estimate {rot_wrong:.3} deg, {:.1} mm, {:+.2} ms from the truth",
        trans_wrong * 1e3,
        est_wrong.time_offset_ms + 5.0
    );
    println!(
        "wrong file, translation freed: ATE {ate_wrong_freed:.4} m; estimate {rot_freed:.3} deg, {:.1} mm, {:+.2} ms from the truth",
        trans_freed * 1e3,
        est_freed.time_offset_ms + 5.0
    );

    println!(
        "wrong file, translation freed, held keyframes following: ATE {ate_wrong_follow:.4} m; estimate {rot_follow:.3} deg, {:.1} mm, {:+.2} ms from the truth",
        trans_follow * 1e3,
        est_follow.time_offset_ms + 5.0
    );
    println!(
        "wrong file, started in flight at {FLIGHT_START_S} s: ATE {ate_flight:.4} m; estimate {rot_flight:.3} deg, {:+.2} ms from the truth, released at the file's test: {}",
        est_flight.time_offset_ms + 5.0,
        !est_flight.held_at_file
    );
    println!(
        "the same with the gyroscope bias freed at the release: ATE {ate_flight_free:.4} m; estimate {rot_flight_free:.3} deg, {:+.2} ms from the truth",
        est_flight_free.time_offset_ms + 5.0
    );
    for (what, rot, est) in [
        ("true file", rot_true, &est_true),
        ("wrong file", rot_wrong, &est_wrong),
        ("wrong file, translation freed", rot_freed, &est_freed),
        (
            "wrong file, held keyframes following",
            rot_follow,
            &est_follow,
        ),
        ("wrong file, started in flight", rot_flight, &est_flight),
        (
            "wrong file, started in flight, gyroscope bias freed",
            rot_flight_free,
            &est_flight_free,
        ),
    ] {
        assert!(rot < 0.1, "{what}: rotation {rot:.3} deg from the truth");
        let truth_ms = if std::ptr::eq(est, &est_true) {
            0.0
        } else {
            -5.0
        };
        assert!(
            (est.time_offset_ms - truth_ms).abs() < 0.5,
            "{what}: time offset {:.3} ms, the truth {truth_ms} ms",
            est.time_offset_ms
        );
    }
    for (what, trans) in [
        ("freed", trans_freed),
        ("freed, held keyframes following", trans_follow),
    ] {
        assert!(
            trans < 0.010,
            "translation {what}: {:.1} mm from the truth, the file 10 mm",
            trans * 1e3
        );
    }
    // The alignment in motion found the gyroscope bias through the wrong
    // rotation; freed at the release, the bias no longer holds the
    // calibration back.
    assert!(
        rot_flight_free < rot_flight,
        "started in flight: {rot_flight_free:.3} deg from the truth with the bias freed, {rot_flight:.3} deg without"
    );
    assert!(
        ate_wrong_on < 0.8 * ate_wrong_off,
        "{ate_wrong_on:.4} m with refinement, {ate_wrong_off:.4} m without"
    );
    assert!(
        est_wrong.far_from_file,
        "1 deg and 5 ms off: the status warns"
    );
    assert!(!est_true.far_from_file, "the true file is not flagged");

    // The daemon as a user runs it: a replay whose camera files are wrong
    // warns in its log; the same replay with the right files does not.
    let wrong_sequence = work.path().join("wrong_files");
    for dir in ["mav0/cam0", "mav0/cam1"] {
        std::fs::create_dir_all(wrong_sequence.join(dir)).expect("mkdir");
    }
    for link in [
        "mav0/imu0",
        "mav0/state_groundtruth_estimate0",
        "mav0/cam0/data",
        "mav0/cam1/data",
    ] {
        std::os::unix::fs::symlink(sequence.join(link), wrong_sequence.join(link)).expect("link");
    }
    for (i, cam) in wrong_rig.cameras.iter().enumerate() {
        let dir = format!("mav0/cam{i}");
        std::fs::copy(
            sequence.join(&dir).join("data.csv"),
            wrong_sequence.join(&dir).join("data.csv"),
        )
        .expect("copy data.csv");
        std::fs::write(
            wrong_sequence.join(&dir).join("sensor.yaml"),
            rigslam::dataset::euroc::sensor_yaml::camera_yaml(&format!("cam{i}"), cam),
        )
        .expect("write sensor.yaml");
    }
    let replay = |dir: &std::path::Path| {
        let out = std::process::Command::new(env!("CARGO_BIN_EXE_rigslamd"))
            .arg("--replay")
            .arg(dir)
            .arg("--as-fast-as-possible")
            .env("RUST_LOG", "info")
            .output()
            .expect("rigslamd runs");
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        format!(
            "{}{}",
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        )
    };
    let warned = |log: &str| log.contains("from the calibration file: the camera may have moved");
    let right_log = replay(&sequence);
    let wrong_log = replay(&wrong_sequence);
    assert!(
        warned(&wrong_log),
        "no warning with the wrong files:\n{wrong_log}"
    );
    assert!(
        !warned(&right_log),
        "a warning with the right files:\n{right_log}"
    );

    assert!(
        ate_true_on <= 1.03 * ate_true_off,
        "a correct file: {ate_true_on:.4} m refined, {ate_true_off:.4} m not"
    );
    if std::env::var_os("RIGSLAM_CAMERA_IMU_BARS").is_some() {
        assert!(trans_freed < 0.003, "{:.1} mm", trans_freed * 1e3);
        assert!(ate_wrong_on <= 1.05 * ate_true_off);
    }
}
