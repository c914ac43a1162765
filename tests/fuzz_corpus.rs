//! The fuzz targets of `tests/fuzz/` on the stable toolchain, so that a new
//! parser bug fails the ordinary test run without nightly: every corpus
//! file, the real recordings read in place, and a seeded random run of
//! mutations (how, and what fails it: `tests/fuzz/corpus_run.rs`). About
//! 20 s in release on one core.
//!
//! `cargo test --release --test fuzz_corpus -- --ignored write_seed_corpora`
//! rewrites the binary seeds (MCAP recordings, PNG datasets, shared-memory
//! messages) with the project's own writers.

#[path = "fuzz/entry_points.rs"]
mod entry_points;

#[path = "fuzz/corpus_run.rs"]
mod corpus_run;

use std::path::Path;

/// Where `corpus_run` finds the corpora and the real recordings.
const CORPUS_FROM_MANIFEST: &str = "tests/fuzz/corpus";
const SHARED_DATA_FROM_MANIFEST: &str = "../shared/data";

#[global_allocator]
static ALLOCATOR: corpus_run::Bounded = corpus_run::Bounded;

/// Real files that fit each target, read in place.
fn real_inputs(target: &str) -> Vec<(String, Vec<u8>)> {
    let files: &[&str] = match target {
        "sensor_yaml" => &[
            "euroc/V1_01_micro/mav0/cam0/sensor.yaml",
            "euroc/V1_01_micro/mav0/cam1/sensor.yaml",
            "euroc/V1_01_micro/mav0/imu0/sensor.yaml",
            "euroc/V1_01_micro/mav0/body.yaml",
            "euroc/V1_01_micro/mav0/state_groundtruth_estimate0/sensor.yaml",
            "calib/euroc_imu_april/imu_april/sequence.yaml",
            "calib/chessboard_9x6_25mm/left_intrinsics.yml",
        ],
        "dataset_text" => &[
            "euroc/V1_01_micro/mav0/imu0/data.csv",
            "euroc/V1_01_micro/mav0/cam0/data.csv",
            "euroc/V1_01_micro/mav0/state_groundtruth_estimate0/data.csv",
            "euroc/ground_truth/V1_01_gt_200hz.txt",
            "euroc/ground_truth/V1_01_gt_camrate.csv",
            "euroc/ground_truth/V1_02_estimate_sample.tum",
            "kitti/seq_a/poses.txt",
            "kitti/seq_a/calib.txt",
        ],
        "matches_file" => &["kitti/seq_a_matches.txt", "kitti/seq_a_gt_rel.txt"],
        _ => &[],
    };
    let mut out: Vec<_> = files.iter().filter_map(|f| corpus_run::real(f)).collect();
    if target == "dataset_dir" {
        out.extend(real_dataset_packs());
    }
    out
}

/// The real EuRoC and KITTI sequences packed as `dataset_dir` inputs (one
/// image each), in memory.
fn real_dataset_packs() -> Vec<(String, Vec<u8>)> {
    let pack = |name: &str, layout: u8, files: &[&str]| -> Option<(String, Vec<u8>)> {
        let mut data = vec![layout];
        for (i, f) in files.iter().enumerate() {
            if i > 0 {
                data.extend_from_slice(entry_points::SECTION);
            }
            data.extend(corpus_run::real(f)?.1);
        }
        Some((format!("{name} packed as a dataset_dir input"), data))
    };
    let euroc = "euroc/V1_01_micro/mav0";
    let png0 = format!("{euroc}/cam0/data/1403715273262142976.png");
    let png1 = format!("{euroc}/cam1/data/1403715273262142976.png");
    let files: Vec<String> = [
        "cam0/data.csv",
        "cam0/sensor.yaml",
        "",
        "imu0/data.csv",
        "imu0/sensor.yaml",
        "state_groundtruth_estimate0/data.csv",
        "cam1/data.csv",
        "cam1/sensor.yaml",
        "",
    ]
    .iter()
    .enumerate()
    .map(|(i, f)| match (i, *f) {
        (2, _) => png0.clone(),
        (8, _) => png1.clone(),
        (_, f) => format!("{euroc}/{f}"),
    })
    .collect();
    let files: Vec<&str> = files.iter().map(String::as_str).collect();
    [
        pack("euroc/V1_01_micro", 0, &files),
        pack(
            "kitti/seq_a",
            1,
            &[
                "kitti/seq_a/calib.txt",
                "kitti/seq_a/image_l/000000.png",
                "kitti/seq_a/poses.txt",
            ],
        ),
    ]
    .into_iter()
    .flatten()
    .collect()
}

/// Mutated inputs per target: about 20 s in all in release on one core
/// (the dataset folder and config targets write files per input).
fn mutations(target: &str) -> usize {
    match target {
        "dataset_dir" => 3_000,
        "daemon_config" => 50_000,
        "sensor_yaml" | "dataset_text" => 100_000,
        _ => 200_000,
    }
}

#[test]
fn every_corpus_file_and_mutation_parses_without_a_crash() {
    let mut failures = Vec::new();
    for (name, target) in entry_points::TARGETS {
        failures.extend(corpus_run::run_target(
            name,
            *target,
            &real_inputs(name),
            mutations(name),
            4096,
        ));
    }
    entry_points::remove_scratch();
    assert!(failures.is_empty(), "{}", failures.join("\n\n"));
}

/// Rewrites the binary seeds of `tests/fuzz/corpus/` with the project's
/// writers (run by hand; see the top of this file).
#[test]
#[ignore = "rewrites the committed seed corpora; run by hand"]
fn write_seed_corpora() {
    seeds::write(&Path::new(env!("CARGO_MANIFEST_DIR")).join(CORPUS_FROM_MANIFEST));
}

mod seeds {
    use std::collections::BTreeMap;
    use std::path::Path;

    use nalgebra::{Isometry3, Matrix6, Translation3, UnitQuaternion, Vector3};
    use rigslam::dataset::write_png;
    use rigslam::publish::{PoseMessage, QueueFill, StatusMessage};
    use rigslam::recording::{
        calibration_attachment_name, Compression, McapRecorder, RecordedPose,
    };
    use rigslam::relative::types::TrackingState;
    use rigslam::sensors::{Image, ImuSample};

    use super::entry_points::SECTION;

    const CAM_YAML: &str = include_str!("fuzz/corpus/sensor_yaml/cam_radtan.yaml");
    const IMU_YAML: &str = include_str!("fuzz/corpus/sensor_yaml/imu_euroc.yaml");

    fn png(width: u32, height: u32, seed: u8) -> Vec<u8> {
        let dir = tempfile::tempdir().expect("temp dir");
        let path = dir.path().join("seed.png");
        let pixels = (0..width * height)
            .map(|i| (i as u8).wrapping_mul(seed))
            .collect();
        let image = Image::mono8(width, height, pixels).expect("image");
        write_png(&path, &image).expect("png");
        std::fs::read(&path).expect("png bytes")
    }

    fn join(layout: u8, parts: &[&[u8]]) -> Vec<u8> {
        let mut data = vec![layout];
        for (i, p) in parts.iter().enumerate() {
            if i > 0 {
                data.extend_from_slice(SECTION);
            }
            data.extend_from_slice(p);
        }
        data
    }

    fn recording(path: &Path, stereo: bool, finish: bool, compression: Compression) {
        let mut rec = McapRecorder::create(path, compression).expect("create");
        let imu = rec
            .add_imu_channel(
                "/imu0",
                &BTreeMap::from([("serial".to_string(), "seed".to_string())]),
            )
            .expect("imu channel");
        let cam0 = rec.add_image_channel("/cam0").expect("cam0");
        let cam1 = rec.add_image_channel("/cam1").expect("cam1");
        let pose = rec.add_pose_channel("/pose").expect("pose");
        rec.attach(
            &calibration_attachment_name("cam0.yaml"),
            "application/yaml",
            CAM_YAML.as_bytes(),
        )
        .expect("attach");
        if stereo {
            rec.attach(
                &calibration_attachment_name("cam1.yaml"),
                "application/yaml",
                CAM_YAML.as_bytes(),
            )
            .expect("attach");
        }
        rec.attach(
            &calibration_attachment_name("imu0.yaml"),
            "application/yaml",
            IMU_YAML.as_bytes(),
        )
        .expect("attach");
        for k in 0..4i64 {
            let t = 1_000_000_000 + k * 5_000_000;
            let sample = ImuSample {
                t_ns: t,
                gyro_rad_s: [0.01 * k as f64, -0.02, 0.5],
                accel_m_s2: [0.1, 9.81, -0.2 * k as f64],
            };
            rec.write_imu(imu, &sample, t + 100).expect("imu");
            if k % 2 == 0 {
                let pixels = (0..12).map(|i| (i * 20 + k) as u8).collect();
                let image = Image::mono8(4, 3, pixels).expect("image");
                rec.write_image(cam0, t, &image, "cam0", t + 200)
                    .expect("cam0");
                if stereo {
                    rec.write_image(cam1, t, &image, "cam1", t + 300)
                        .expect("cam1");
                }
                let recorded = RecordedPose::map_only(
                    t,
                    1,
                    [0.1, 0.2, 0.3],
                    [0.0, 0.0, 0.0, 1.0],
                    [0.0, 0.0, 0.01],
                );
                rec.write_pose(pose, &recorded, t + 400).expect("pose");
            }
        }
        if finish {
            rec.finish().expect("finish");
        }
    }

    pub fn write(corpus: &Path) {
        // MCAP recordings as the daemon's recorder writes them: stereo
        // with the calibration attached (zstd chunks), and mono (lz4) cut
        // off before its summary (a recorder that died). The seeds without
        // "protobuf" in their names are the earlier JSON layout, kept as
        // they were written.
        let dir = corpus.join("mcap_recording");
        recording(
            &dir.join("stereo_imu_calibration_protobuf.mcap"),
            true,
            true,
            Compression::Zstd,
        );
        let tmp = tempfile::tempdir().expect("temp dir");
        let unfinished = tmp.path().join("unfinished.mcap");
        recording(&unfinished, false, true, Compression::Lz4);
        let mut bytes = std::fs::read(&unfinished).expect("bytes");
        bytes.truncate(bytes.len() * 2 / 3);
        std::fs::write(dir.join("mono_cut_off_protobuf.mcap"), bytes).expect("write");

        // Dataset folders: EuRoC stereo-inertial (cam1's listing names an
        // image that is not there) and KITTI with times and poses.
        let text =
            |name: &str| std::fs::read(corpus.join(name)).unwrap_or_else(|e| panic!("{name}: {e}"));
        let cam_csv = b"#timestamp [ns],filename\n1000000000,1000.png\n1010000000,1010.png\n";
        let imu_csv = text("dataset_text/imu.csv");
        let gt_csv = text("dataset_text/groundtruth.csv");
        let euroc = join(
            0,
            &[
                cam_csv,
                CAM_YAML.as_bytes(),
                &png(8, 6, 3),
                &imu_csv,
                IMU_YAML.as_bytes(),
                &gt_csv,
                cam_csv,
                CAM_YAML.as_bytes(),
                &png(8, 6, 5),
            ],
        );
        std::fs::write(corpus.join("dataset_dir/euroc_stereo_imu.bin"), euroc).expect("write");
        let kitti = join(
            1,
            &[
                &text("dataset_text/calib.txt"),
                &png(6, 4, 7),
                b"0.0\n0.1\n",
                &text("dataset_text/kitti_poses.txt"),
                &png(6, 4, 11),
            ],
        );
        std::fs::write(corpus.join("dataset_dir/kitti_two_frames.bin"), kitti).expect("write");

        // Shared-memory messages: three poses with a sequence gap, and a
        // status with two queues.
        let mut poses = Vec::new();
        for (sequence, state) in [
            (0, TrackingState::Initializing),
            (1, TrackingState::Tracking),
            (5, TrackingState::Lost),
        ] {
            let mut m = PoseMessage::new(
                1_000 + sequence as i64,
                state,
                &Isometry3::from_parts(
                    Translation3::new(1.0, -2.0, 0.5),
                    UnitQuaternion::from_euler_angles(0.1, 0.2, 0.3),
                ),
            )
            .with_velocity(&Vector3::new(0.1, 0.0, 0.0));
            if sequence == 1 {
                m = m.with_covariance(&Matrix6::identity());
            }
            m.sequence = sequence;
            poses.extend_from_slice(m.as_bytes());
        }
        let dir = corpus.join("pose_message");
        std::fs::write(dir.join("three_poses.bin"), poses).expect("write");
        let mut status = StatusMessage::default();
        status.set_queues(&[
            QueueFill::new("frames", 2, 4),
            QueueFill::new("imu", 100, 4096),
        ]);
        status.sequence = 7;
        std::fs::write(dir.join("status.bin"), status.as_bytes()).expect("write");
    }
}
