//! `camera-imu` from images and from a rigslamd recording: the AprilGrid is
//! found by our detector, the detections are written beside the
//! calibration, and too few views, or none, are named plainly.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::Arc;

use rigslam::recording::McapRecorder;
use rigslam::sensors::{Image, ImuSample, PixelFormat};

const BIN: &str = env!("CARGO_BIN_EXE_rigslam-calibrate");

fn april() -> Option<PathBuf> {
    rigslam::shared_data::path_or_skip("calib/euroc_imu_april")
}

fn run(args: &[&std::ffi::OsStr]) -> (bool, String) {
    let out = Command::new(BIN).args(args).output().expect("runs");
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into_owned() + &String::from_utf8_lossy(&out.stderr),
    )
}

fn imu_log(path: &Path, t0_ns: i64) {
    let mut text = String::from("#timestamp [ns],w_x,w_y,w_z,a_x,a_y,a_z\n");
    for i in 0..400i64 {
        text.push_str(&format!(
            "{},0.01,0.0,0.0,0.0,0.0,9.81\n",
            t0_ns + i * 5_000_000
        ));
    }
    std::fs::write(path, text).expect("write");
}

#[test]
fn images_of_the_real_grid_are_detected_and_too_few_views_are_named() {
    let Some(april) = april() else { return };
    let dir = tempfile::tempdir().expect("temp dir");
    let images = dir.path().join("images");
    let t0 = 1_403_709_395_937_837_056i64;
    for cam in ["cam0", "cam1"] {
        std::fs::create_dir_all(images.join(cam)).expect("mkdir");
        std::fs::copy(
            april.join(format!("{cam}_1403709395937837056.png")),
            images.join(cam).join(format!("{t0}.png")),
        )
        .expect("copy");
    }
    let imu = dir.path().join("imu0.csv");
    imu_log(&imu, t0 - 1_000_000_000);
    let out = dir.path().join("rig");
    let (ok, text) = run(&[
        "camera-imu".as_ref(),
        "--images".as_ref(),
        images.as_os_str(),
        "--target".as_ref(),
        april.join("target.yaml").as_os_str(),
        "--imu".as_ref(),
        imu.as_os_str(),
        "--intrinsics".as_ref(),
        april.join("imu_april/sequence.yaml").as_os_str(),
        "--out".as_ref(),
        out.as_os_str(),
    ]);
    assert!(!ok);
    // The one view was found and posed: the message counts it.
    assert!(
        text.contains("found in only 1 of 1 frames (need 50)"),
        "{text}"
    );
    let csv = std::fs::read_to_string(out.join(format!("detections/cam0/{t0}.csv")))
        .expect("detections written");
    assert_eq!(
        csv.lines().filter(|l| !l.starts_with('#')).count(),
        144,
        "36 tags x 4 corners"
    );

    // Images without the grid: none found, said as such.
    let chess =
        rigslam::shared_data::path_or_skip("calib/chessboard_9x6_25mm").expect("shared data");
    let blank = dir.path().join("no_grid");
    std::fs::create_dir_all(blank.join("cam0")).expect("mkdir");
    std::fs::copy(
        chess.join("left01.jpg"),
        blank.join("cam0").join(format!("{t0}.jpg")),
    )
    .expect("copy");
    let (ok, text) = run(&[
        "camera-imu".as_ref(),
        "--images".as_ref(),
        blank.as_os_str(),
        "--target".as_ref(),
        april.join("target.yaml").as_os_str(),
        "--imu".as_ref(),
        imu.as_os_str(),
        "--intrinsics".as_ref(),
        april.join("imu_april/sequence.yaml").as_os_str(),
        "--out".as_ref(),
        dir.path().join("rig2").as_os_str(),
    ]);
    assert!(!ok);
    assert!(text.contains("found in only 0 of 1 frames"), "{text}");
}

#[test]
fn a_recording_of_the_grid_gives_frames_and_imu() {
    let Some(april) = april() else { return };
    let dir = tempfile::tempdir().expect("temp dir");
    let path = dir.path().join("target.mcap");
    let mut recorder =
        McapRecorder::create(&path, rigslam::recording::Compression::Zstd).expect("create");
    let cam0 = recorder.add_image_channel("/cam0").expect("channel");
    let cam1 = recorder.add_image_channel("/cam1").expect("channel");
    let imu = recorder
        .add_imu_channel("/imu0", &BTreeMap::new())
        .expect("channel");
    let load = |name: &str| {
        let g = image::open(april.join(name)).expect("png").to_luma8();
        Image::new(
            g.width(),
            g.height(),
            g.width() as usize,
            PixelFormat::Mono8,
            Arc::from(g.into_raw()),
        )
        .expect("image")
    };
    let (left, right) = (
        load("cam0_1403709395937837056.png"),
        load("cam1_1403709395937837056.png"),
    );
    let t0 = 1_000_000_000i64;
    for i in 0..400i64 {
        let t = t0 + i * 5_000_000;
        let sample = ImuSample {
            t_ns: t,
            gyro_rad_s: [0.01, 0.0, 0.0],
            accel_m_s2: [0.0, 0.0, 9.81],
        };
        recorder.write_imu(imu, &sample, t).expect("imu");
        if i % 100 == 50 {
            recorder
                .write_image(cam0, t, &left, "cam0", t)
                .expect("image");
            recorder
                .write_image(cam1, t, &right, "cam1", t)
                .expect("image");
        }
    }
    recorder.finish().expect("finish");
    let (ok, text) = run(&[
        "camera-imu".as_ref(),
        "--recording".as_ref(),
        path.as_os_str(),
        "--target".as_ref(),
        april.join("target.yaml").as_os_str(),
        "--intrinsics".as_ref(),
        april.join("imu_april/sequence.yaml").as_os_str(),
        "--out".as_ref(),
        dir.path().join("rig").as_os_str(),
    ]);
    assert!(!ok);
    // Four stereo frames, the grid in each: too few for a calibration,
    // and said so after the IMU was read from the same file.
    assert!(
        text.contains("found in only 4 of 4 frames (need 50)"),
        "{text}"
    );
    assert!(
        dir.path()
            .join("rig/detections/cam1")
            .read_dir()
            .expect("written")
            .count()
            == 4
    );
}

#[test]
fn check_holds_a_folder_against_a_recording_of_another_camera() {
    let Some(april) = april() else { return };
    let dir = tempfile::tempdir().expect("temp dir");
    // The folder: EuRoC's rig (752x480).
    let folder = dir.path().join("rig");
    std::fs::create_dir(&folder).expect("mkdir");
    let cams = [
        rigslam::rig::euroc::euroc_cam0(),
        rigslam::rig::euroc::euroc_cam1(),
    ];
    std::fs::write(
        folder.join("camchain-imucam.yaml"),
        rigslam::rig::kalibr::camchain_yaml(&cams, true).expect("writes"),
    )
    .expect("write");
    // A recording whose camera gives 640x480 images.
    let path = dir.path().join("other.mcap");
    let mut recorder =
        McapRecorder::create(&path, rigslam::recording::Compression::Zstd).expect("create");
    let cam0 = recorder.add_image_channel("/cam0").expect("channel");
    let imu = recorder
        .add_imu_channel("/imu0", &BTreeMap::new())
        .expect("channel");
    let g = image::open(april.join("cam0_1403709395937837056.png"))
        .expect("png")
        .to_luma8();
    let small = image::imageops::crop_imm(&g, 0, 0, 640, 480).to_image();
    let frame = Image::new(
        640,
        480,
        640,
        PixelFormat::Mono8,
        Arc::from(small.into_raw()),
    )
    .expect("image");
    for i in 0..100i64 {
        let t = 1_000_000_000 + i * 5_000_000;
        let sample = ImuSample {
            t_ns: t,
            gyro_rad_s: [0.0; 3],
            accel_m_s2: [0.0, 0.0, 9.81],
        };
        recorder.write_imu(imu, &sample, t).expect("imu");
        if i % 10 == 0 {
            recorder
                .write_image(cam0, t, &frame, "cam0", t)
                .expect("image");
        }
    }
    recorder.finish().expect("finish");
    let (ok, text) = run(&[
        "check".as_ref(),
        folder.as_os_str(),
        "--dataset".as_ref(),
        path.as_os_str(),
    ]);
    assert!(!ok, "{text}");
    assert!(
        text.contains("PROBLEM") && text.contains("640x480") && text.contains("752x480"),
        "{text}"
    );
}
