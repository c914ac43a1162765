//! Recordings as other tools read them. The Python `mcap` package (the
//! MCAP project's own reader, with `mcap-protobuf-support` decoding every
//! message through the descriptors the file carries) reads a recording
//! `rigslamd` made, with CRC checks on, through its summary and indexes
//! and again as a stream, and must find what rigslam's own reader finds:
//! the same messages on every channel, the same values, images with the
//! same pixels. `tests/readers/check_mcap.py` is the Python side.
//!
//! It needs a Python with those packages: `RIGSLAM_PYTHON`, which
//! `scripts/test` points at the venv it makes in `target/py`. Without one
//! the test skips, except with `CI` set.

use std::collections::BTreeMap;
use std::ops::ControlFlow;
use std::path::{Path, PathBuf};
use std::process::Command;

use rigslam::dataset::SensorEvent;
use rigslam::recording::{
    for_each_sensor_event, read_imu_channel, read_pose_channel, Compression, McapRecorder,
    ReplayItem, SensorTopics,
};
use rigslam::shared_data;
use serde_json::Value;

/// A Python that imports the MCAP readers, or `None` (skip) outside CI.
fn python() -> Option<PathBuf> {
    let candidate = std::env::var_os("RIGSLAM_PYTHON").map(PathBuf::from);
    let usable = candidate.as_ref().is_some_and(|p| {
        Command::new(p)
            .args(["-c", "import mcap, mcap_protobuf, zstandard, lz4"])
            .status()
            .is_ok_and(|s| s.success())
    });
    if usable {
        return candidate;
    }
    assert!(
        std::env::var_os("CI").is_none(),
        "CI is set but RIGSLAM_PYTHON ({candidate:?}) is not a Python with mcap, \
         mcap-protobuf-support, zstandard and lz4 (scripts/test makes one in target/py)"
    );
    eprintln!("skipping: set RIGSLAM_PYTHON to a Python with `pip install mcap mcap-protobuf-support zstandard lz4`");
    None
}

/// What `check_mcap.py` found in `file`.
fn python_reads(python: &Path, file: &Path) -> Value {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/readers/check_mcap.py");
    let out = Command::new(python)
        .arg(script)
        .arg(file)
        .output()
        .expect("run python");
    assert!(
        out.status.success(),
        "check_mcap.py failed on {}: {}",
        file.display(),
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).expect("JSON from check_mcap.py")
}

fn f64s(v: &Value) -> Vec<f64> {
    v.as_array()
        .expect("array")
        .iter()
        .map(|x| x.as_f64().expect("number"))
        .collect()
}

fn unix_now_ns() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .expect("after 1970")
        .as_nanos() as u64
}

/// A recording `rigslamd` made of EuRoC's V1_01_micro, replayed as fast
/// as it goes, with the Unix times around the run.
struct DaemonRecording {
    _dir: tempfile::TempDir,
    file: PathBuf,
    before: u64,
    after: u64,
}

/// Records V1_01_micro with the daemon, or `None` (skip) without the data.
fn record_micro(service_prefix: &str) -> Option<DaemonRecording> {
    let euroc = shared_data::path_or_skip("euroc/V1_01_micro")?;
    let dir = tempfile::tempdir().expect("tempdir");
    let before = unix_now_ns();
    let status = Command::new(env!("CARGO_BIN_EXE_rigslamd"))
        .arg("--replay")
        .arg(&euroc)
        .arg("--as-fast-as-possible")
        .arg("--record")
        .arg(dir.path())
        .args(["--service-prefix", service_prefix])
        .arg("--root-path")
        .arg(dir.path().join("iox"))
        .env_remove("NOTIFY_SOCKET")
        .output()
        .expect("run rigslamd");
    assert!(
        status.status.success(),
        "{}",
        String::from_utf8_lossy(&status.stderr)
    );
    let after = unix_now_ns();
    let files = rigslam::daemon::recorder::list_recordings(dir.path());
    assert_eq!(files.len(), 1, "{files:?}");
    let file = files[0].0.clone();
    Some(DaemonRecording {
        _dir: dir,
        file,
        before,
        after,
    })
}

/// Fails unless `out`, what `reader` printed of `rec`'s file, is what
/// rigslam's own reader finds there.
fn assert_reads_as_rigslam_wrote_it(reader: &str, out: &Value, rec: &DaemonRecording) {
    let (file, before, after) = (&rec.file, rec.before, rec.after);

    // Summary, indexes, compression, attachments and the clock mapping.
    let ours = rigslam::recording::channel_counts(file).expect("closed file");
    let total: u64 = ours.values().sum();
    let theirs: BTreeMap<String, u64> =
        serde_json::from_value(out["messages"].clone()).expect("counts");
    let ours_nonzero: BTreeMap<String, u64> = ours.into_iter().filter(|(_, n)| *n > 0).collect();
    assert_eq!(theirs, ours_nonzero, "{reader}: messages per topic");
    assert_eq!(out["statistics_messages"], total, "{reader}: statistics");
    assert_eq!(out["streamed_messages"], total, "{reader}: streamed");
    assert!(out["chunk_indexes"].as_u64().expect("count") >= 2);
    assert_eq!(out["chunk_compression"], serde_json::json!(["zstd"]));
    for name in [
        "calibration/cam0.yaml",
        "calibration/cam1.yaml",
        "calibration/imu0.yaml",
    ] {
        assert!(
            out["attachments"]
                .as_array()
                .expect("names")
                .iter()
                .any(|n| n == name),
            "{name} not attached: {}",
            out["attachments"]
        );
    }
    assert!(out["metadata"]["rigslam.clock"]["unix_ns"].is_string());
    // Log times on the epoch, within the run.
    for (topic, times) in out["log_times"].as_object().expect("topics") {
        for t in times.as_array().expect("times") {
            let t = t.as_u64().expect("ns");
            assert!(
                (before..=after).contains(&t),
                "{reader}, {topic}: log time {t} outside the run ({before}..{after})"
            );
        }
    }

    // IMU samples: every value exact.
    let imu = read_imu_channel(file, "/imu0").expect("imu");
    let imu_values = out["values"]["/imu0"].as_array().expect("imu values");
    assert_eq!(imu_values.len(), imu.len());
    for (s, v) in imu.iter().zip(imu_values) {
        let v = v.as_array().expect("fields");
        assert_eq!(v[0].as_i64(), Some(s.t_ns));
        let numbers = f64s(&Value::Array(v[1..].to_vec()));
        let expected: Vec<f64> = s.gyro_rad_s.iter().chain(&s.accel_m_s2).copied().collect();
        assert_eq!(numbers, expected, "sample at {}", s.t_ns);
    }

    // Images: stamps, sizes and every pixel (CRC-32 of the data).
    let mut frames = Vec::new();
    for_each_sensor_event(
        file,
        SensorTopics {
            stereo: true,
            imu: false,
        },
        |item| {
            if let ReplayItem::Event(SensorEvent::Frame { left, right, .. }) = item {
                frames.push((left, right.expect("stereo")));
            }
            ControlFlow::Continue(())
        },
    )
    .expect("replay");
    for (topic, side) in [("/cam0", 0), ("/cam1", 1)] {
        let values = out["values"][topic].as_array().expect("images");
        assert_eq!(values.len(), frames.len(), "{topic}");
        for (v, (l, r)) in values.iter().zip(&frames) {
            let frame = if side == 0 { l } else { r };
            let t_ns = v[0].as_i64().expect("s") * 1_000_000_000 + v[1].as_i64().expect("ns");
            assert_eq!(t_ns, frame.t_ns);
            assert_eq!(v[2], frame.image.width());
            assert_eq!(v[3], frame.image.height());
            assert_eq!(v[5], "mono8");
            assert_eq!(v[6], format!("cam{side}"));
            assert_eq!(
                v[7],
                crc32fast::hash(frame.image.data()),
                "{topic} at {t_ns}"
            );
        }
    }

    // Poses: both frames and the covariance.
    let poses = read_pose_channel(file, "/rigslam/pose").expect("poses");
    let pose_values = out["values"]["/rigslam/pose"].as_array().expect("poses");
    assert_eq!(pose_values.len(), poses.len());
    assert!(poses.len() > 50);
    for (p, v) in poses.iter().zip(pose_values) {
        let v = v.as_array().expect("fields");
        assert_eq!(v[0].as_i64(), Some(p.t_ns));
        assert_eq!(v[1], p.tracking_state);
        assert_eq!(v[2], p.flags);
        let numbers = f64s(&Value::Array(v[3..16].to_vec()));
        let expected: Vec<f64> = p
            .position_world_m
            .iter()
            .chain(&p.orientation_world_body_xyzw)
            .chain(&p.position_odom_m)
            .chain(&p.translation_world_odom_m)
            .copied()
            .collect();
        assert_eq!(numbers, expected, "pose at {}", p.t_ns);
        let covariance_len = if p.covariance.iter().all(|c| c.is_nan()) {
            0
        } else {
            36
        };
        assert_eq!(v[16], covariance_len);
    }
    for (topic, frame) in [("/rigslam/pose_map", "map"), ("/rigslam/pose_odom", "odom")] {
        let values = out["values"][topic].as_array().expect(topic);
        assert_eq!(values.len(), poses.len(), "{topic}");
        assert!(values.iter().all(|v| v[0] == frame), "{topic}");
    }

    // The transform tree: the sensors on the body first, then map -> odom
    // -> body with every pose.
    let tf = out["values"]["/tf"].as_array().expect("tf");
    assert_eq!(tf.len(), poses.len() + 1);
    assert_eq!(
        tf[0],
        serde_json::json!([["body", "cam0"], ["body", "cam1"], ["body", "imu"]])
    );
    assert!(tf[1..]
        .iter()
        .all(|t| *t == serde_json::json!([["map", "odom"], ["odom", "body"]])));

    // Each camera's calibration, as the rig has it.
    let rig = rigslam::recording::rig_of_recording(file)
        .expect("read")
        .expect("a rig");
    for (i, camera) in rig.cameras.iter().enumerate() {
        let v = &out["values"][format!("/cam{i}/calibration")][0];
        let [fx, fy, cx, cy] = camera.model.pinhole();
        assert_eq!(v[0], format!("cam{i}"));
        assert_eq!(v[1], camera.model.width());
        assert_eq!(v[3], "plumb_bob");
        assert_eq!(f64s(&v[4]), vec![fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0]);
        assert_eq!(f64s(&v[5]), camera.model.distortion_coefficients());
    }
}

/// The IMU sample `k` of `record_synthetic`'s files.
fn synthetic_sample(k: i64) -> rigslam::sensors::ImuSample {
    rigslam::sensors::ImuSample {
        t_ns: k * 5_000_000,
        gyro_rad_s: [k as f64 * 1e-3, 1.0 / 3.0, -0.5],
        accel_m_s2: [0.25, 9.81, k as f64],
    }
}

/// The image with sample `k` (every tenth) of `record_synthetic`'s files.
fn synthetic_image(k: i64) -> rigslam::sensors::Image {
    let pixels = (0..320 * 240u32)
        .map(|i| (i % 251) as u8 ^ k as u8)
        .collect();
    rigslam::sensors::Image::mono8(320, 240, pixels).expect("image")
}

/// A file the recorder itself writes with `compression`: 400 IMU samples
/// on `/imu0` and 40 images on `/cam0`.
fn record_synthetic(path: &Path, compression: Compression) {
    let mut rec = McapRecorder::create(path, compression).expect("create");
    let imu = rec
        .add_imu_channel("/imu0", &BTreeMap::new())
        .expect("channel");
    let cam = rec.add_image_channel("/cam0").expect("channel");
    for k in 0..400i64 {
        let s = synthetic_sample(k);
        rec.write_imu(imu, &s, s.t_ns).expect("imu");
        if k % 10 == 0 {
            rec.write_image(cam, s.t_ns, &synthetic_image(k), "cam0", s.t_ns)
                .expect("image");
        }
    }
    rec.finish().expect("finish");
}

/// Fails unless `out`, what `reader` printed of a `record_synthetic`
/// file, has its chunks compressed as `compression` names and every
/// sample and pixel that was written.
fn assert_reads_synthetic(reader: &str, out: &Value, compression: &str) {
    assert_eq!(
        out["chunk_compression"],
        serde_json::json!([compression]),
        "{reader}"
    );
    assert_eq!(out["messages"]["/imu0"], 400, "{reader}");
    assert_eq!(out["messages"]["/cam0"], 40, "{reader}");
    assert_eq!(out["streamed_messages"], 440, "{reader}");
    let imu = out["values"]["/imu0"].as_array().expect("imu values");
    assert_eq!(imu.len(), 400, "{reader}");
    for (k, v) in (0..).zip(imu) {
        let s = synthetic_sample(k);
        assert_eq!(v[0], s.t_ns, "{reader}");
        let expected: Vec<f64> = s.gyro_rad_s.iter().chain(&s.accel_m_s2).copied().collect();
        assert_eq!(
            f64s(&Value::Array(v.as_array().expect("v")[1..].to_vec())),
            expected,
            "{reader}: sample {k}"
        );
    }
    let images = out["values"]["/cam0"].as_array().expect("images");
    assert_eq!(images.len(), 40, "{reader}");
    for (k, v) in (0..).step_by(10).zip(images) {
        let image = synthetic_image(k);
        assert_eq!(v[2], 320, "{reader}");
        assert_eq!(v[3], 240, "{reader}");
        assert_eq!(v[7], crc32fast::hash(image.data()), "{reader}: image {k}");
    }
}

#[test]
fn the_python_mcap_reader_reads_a_daemon_recording_as_rigslam_wrote_it() {
    let Some(python) = python() else { return };
    let Some(rec) = record_micro("recording_readers_py") else {
        return;
    };
    let py = python_reads(&python, &rec.file);
    assert_reads_as_rigslam_wrote_it("mcap (Python)", &py, &rec);
}

#[test]
fn the_python_mcap_reader_reads_lz4_and_uncompressed_recordings() {
    let Some(python) = python() else { return };
    let dir = tempfile::tempdir().expect("tempdir");
    for (compression, name) in [(Compression::Lz4, "lz4"), (Compression::None, "")] {
        let path = dir.path().join(format!("r-{name}.mcap"));
        record_synthetic(&path, compression);
        assert_reads_synthetic("mcap (Python)", &python_reads(&python, &path), name);
    }
}
