//! The calibration chain as a technician walks it, no hand edits: the IMU
//! intrinsics from the real Ferraris session, the noise from the real
//! ADIS16405 static log and the camera-IMU extrinsics and time shift from
//! the real EuRoC AprilGrid recording, each step writing into one folder
//! with `--out`; then `rigslamd --check-config` on a config naming that
//! folder, and `rigslam-calibrate check`; then a EuRoC-calibrated sequence
//! run with the folder.
//!
//! The sequence is rendered with EuRoC's published calibration along real
//! V1_02 with its real IMU. The folder's IMU intrinsics belong to another
//! IMU (the Ferraris session's), so the sequence's raw samples are made to
//! carry that IMU's errors (`x_raw = S^-1 (x - b)`): the robot this chain
//! calibrated. The same run on EuRoC's published calibration files (with
//! the same intrinsics file) is the reference: the chain must be within
//! 10 % of it in both inertial modes, and leaving the intrinsics out must
//! be worse in both. The stereo pair's 0.02 deg rotation difference from
//! EuRoC's published one (a fraction of a pixel of disparity) cost
//! stereo-inertial four times its ATE until the estimator refined the
//! stereo rotation online with the camera-IMU calibration
//! (`camera_imu_refinement`, on by default). The rigslam run uses the
//! library's `run_dataset`, the estimator `rigslamd` runs.

use std::path::{Path, PathBuf};
use std::process::Command;

use rigslam::dataset::{read_euroc_imu_csv, write_euroc_imu_csv};
use rigslam::relative::SensorMode;
use rigslam::rig::folder::{load_folder, CAMCHAIN, IMU_INTRINSICS, IMU_NOISE};
use rigslam::rig::RigModel;
use rigslam::run::dataset_run::{rig_of, run_dataset, DatasetRun};
use rigslam::simulate::{simulate, ImuSource, SimConfig};

const BIN: &str = env!("CARGO_BIN_EXE_rigslam-calibrate");

/// `rigslamd`, built beside this crate's binary by the workspace build.
fn rigslamd() -> PathBuf {
    let path = Path::new(BIN).with_file_name("rigslamd");
    assert!(
        path.exists(),
        "{} not built: run the workspace's tests (cargo test --workspace)",
        path.display()
    );
    path
}

fn calibrate(args: &[&str], inputs: &[(&str, &Path)]) {
    let mut c = Command::new(BIN);
    c.args(args);
    for (flag, path) in inputs {
        c.arg(flag).arg(path);
    }
    let out = c.output().expect("rigslam-calibrate runs");
    assert!(
        out.status.success(),
        "{args:?} failed:\n{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
}

fn ate(sequence: &Path, rig: RigModel, mode: SensorMode) -> f64 {
    let run = DatasetRun {
        mode: Some(mode),
        rig: Some(rig),
        ..DatasetRun::default()
    };
    let result = run_dataset(sequence, &run, |_, _| {}).expect("the run");
    result.evaluation.expect("ground truth").report.ate_rmse_m
}

#[test]
fn from_three_real_recordings_to_a_tracking_run() {
    let Some(shared) = rigslam::shared_data::path_or_skip("calib") else {
        return;
    };
    let shared = shared.parent().expect("data folder").to_path_buf();
    let imu_dir = shared.join("imu");
    let april = shared.join("calib/euroc_imu_april/imu_april");
    let v1_02 = shared.join("euroc/ground_truth");
    let work = tempfile::tempdir().expect("temp dir");
    let folder = work.path().join("rig_calibration");

    // 1. The three steps, each into the folder.
    calibrate(
        &[
            "imu",
            "--columns",
            "skip,gx,gy,gz,ax,ay,az",
            "--gyro-unit",
            "deg/s",
            "--rate-hz",
            "102.4",
        ],
        &[
            (
                "--input",
                &imu_dir.join("imucal_ferraris_session_102p4hz.csv"),
            ),
            (
                "--sections",
                &imu_dir.join("imucal_ferraris_session_list.json"),
            ),
            ("--out", &folder),
        ],
    );
    calibrate(
        &[
            "noise",
            "--columns",
            "gx,gy,gz,ax,ay,az",
            "--gyro-unit",
            "deg/s",
            "--accel-unit",
            "g",
            "--rate-hz",
            "100",
        ],
        &[
            (
                "--input",
                &imu_dir.join("adis16405_static_100hz_2p78h.csv.gz"),
            ),
            ("--out", &folder),
        ],
    );
    calibrate(
        &["camera-imu"],
        &[
            ("--detections", &april),
            ("--imu", &april.join("imu0.csv")),
            ("--out", &folder),
        ],
    );
    for name in [CAMCHAIN, IMU_NOISE, IMU_INTRINSICS] {
        assert!(folder.join(name).exists(), "{name} not written");
    }
    let chain_text = std::fs::read_to_string(folder.join(CAMCHAIN)).expect("read");
    assert_eq!(
        rigslam::rig::kalibr::kalibr_problems(&chain_text, "camchain"),
        Vec::<String>::new()
    );
    let noise_text = std::fs::read_to_string(folder.join(IMU_NOISE)).expect("read");
    assert_eq!(
        rigslam::rig::kalibr::kalibr_problems(&noise_text, "imu"),
        Vec::<String>::new()
    );

    // 2. A sequence rendered with EuRoC's calibration, its raw IMU carrying
    // the errors of the IMU the folder's intrinsics were measured on.
    let sequence = work.path().join("sequence");
    simulate(
        &SimConfig {
            trajectory: Some(v1_02.join("V1_02_groundtruth.csv")),
            duration_s: Some(25.0),
            imu: ImuSource::Real(v1_02.join("V1_02_imu0.csv")),
            stereo: true,
            seed: 11,
            show_progress: false,
            ..SimConfig::default()
        },
        &sequence,
    )
    .expect("render");
    // 4. The daemon takes the folder as it is, for a replay of the sequence.
    let config = work.path().join("rigslamd.toml");
    std::fs::write(
        &config,
        format!(
            "[camera]\nsource = \"replay\"\n[imu]\nsource = \"replay\"\n\
             [replay]\ndataset = \"{}\"\npace = \"as-fast-as-possible\"\n\
             [calibration]\nfolder = \"{}\"\n[slam]\nmode = \"stereo-inertial\"\n",
            sequence.display(),
            folder.display()
        ),
    )
    .expect("write config");
    let out = Command::new(rigslamd())
        .arg("--config")
        .arg(&config)
        .arg("--check-config")
        .output()
        .expect("rigslamd runs");
    assert!(
        out.status.success(),
        "--check-config refused the folder:\n{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    let out = Command::new(BIN)
        .arg("check")
        .arg(&folder)
        .arg("--dataset")
        .arg(&sequence)
        .output()
        .expect("check runs");
    let verdict = String::from_utf8_lossy(&out.stdout);
    println!("{verdict}");
    assert!(
        out.status.success(),
        "{verdict}{}",
        String::from_utf8_lossy(&out.stderr)
    );

    let chain_rig = load_folder(&folder, true).expect("the folder reads");
    let intrinsics = chain_rig.imu.as_ref().expect("imu").intrinsics;
    assert!(!intrinsics.is_identity());
    let imu_csv = sequence.join("mav0/imu0/data.csv");
    let mut imu = read_euroc_imu_csv(&imu_csv).expect("rendered IMU");
    let (sa, sg) = (
        intrinsics
            .accel_scale
            .try_inverse()
            .expect("checked invertible"),
        intrinsics
            .gyro_scale
            .try_inverse()
            .expect("checked invertible"),
    );
    for s in imu.samples.iter_mut() {
        let a = sa * (nalgebra::Vector3::from(s.accel_m_s2) - intrinsics.accel_offset_m_s2);
        let g = sg * (nalgebra::Vector3::from(s.gyro_rad_s) - intrinsics.gyro_offset_rad_s);
        s.accel_m_s2 = a.into();
        s.gyro_rad_s = g.into();
    }
    write_euroc_imu_csv(&imu_csv, &imu.samples).expect("write raw IMU");

    // 3. The reference: EuRoC's published calibration (the sequence's own
    // sensor.yaml files), the same IMU intrinsics.
    let dataset = rigslam::dataset::open_dataset(&sequence).expect("opens");
    let mut published = rig_of(&dataset);
    if let Some(imu) = published.imu.as_mut() {
        imu.intrinsics = intrinsics;
    }
    let mut without_intrinsics = chain_rig.clone();
    if let Some(imu) = without_intrinsics.imu.as_mut() {
        imu.intrinsics = rigslam::imu::ImuIntrinsics::IDENTITY;
    }
    let mut measured = Vec::new();
    for mode in [SensorMode::MonoInertial, SensorMode::StereoInertial] {
        let ate_published = ate(&sequence, published.clone(), mode);
        let ate_chain = ate(&sequence, chain_rig.clone(), mode);
        let ate_raw = ate(&sequence, without_intrinsics.clone(), mode);
        println!(
            "{mode} ATE: published calibration {ate_published:.4} m, the chain's folder {ate_chain:.4} m ({:+.1} %), the chain without its IMU intrinsics {ate_raw:.4} m",
            (ate_chain / ate_published - 1.0) * 100.0
        );
        measured.push((mode, ate_published, ate_chain, ate_raw));
    }
    let rel = |r: &RigModel| r.cameras[0].T_body_cam.inverse() * r.cameras[1].T_body_cam;
    let stereo = rel(&published).inverse() * rel(&chain_rig);
    let cam0 = published.cameras[0].T_body_cam.inverse() * chain_rig.cameras[0].T_body_cam;
    println!(
        "chain vs published: cam0-IMU {:.2} mm {:.3} deg; stereo {:.2} mm {:.4} deg",
        cam0.translation.vector.norm() * 1e3,
        cam0.rotation.angle().to_degrees(),
        stereo.translation.vector.norm() * 1e3,
        stereo.rotation.angle().to_degrees()
    );
    // The camera-IMU step against EuRoC's published extrinsics (the
    // camera-IMU tests' bars), and the stereo pair, measured on the target
    // by both cameras at once, closer still.
    assert!(cam0.rotation.angle().to_degrees() < 0.5 && cam0.translation.vector.norm() < 0.01);
    assert!(
        stereo.rotation.angle().to_degrees() < 0.05 && stereo.translation.vector.norm() < 0.001
    );
    // The intrinsics are applied: leaving them out is worse in both modes.
    for (mode, _, chain, raw) in &measured {
        assert!(
            raw > chain,
            "{mode}: without the IMU intrinsics {raw:.4} m, with them {chain:.4} m"
        );
    }
    // The bar: within 10 % of the published calibration, in both modes.
    for (mode, published_ate, chain_ate, _) in &measured {
        assert!(
            *chain_ate <= 1.10 * published_ate,
            "{mode}: the chain's calibration tracks {chain_ate:.4} m against {published_ate:.4} m on the published one"
        );
    }

    // Every step wrote atomically: no temporary files are left.
    let leftovers: Vec<_> = std::fs::read_dir(&folder)
        .expect("list")
        .filter_map(|e| e.ok())
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| n.contains(".tmp"))
        .collect();
    assert!(leftovers.is_empty(), "{leftovers:?}");
}
