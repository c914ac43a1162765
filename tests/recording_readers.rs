//! Recordings as other tools read them. The Python `mcap` package (the
//! MCAP project's own reader, with `mcap-protobuf-support` decoding every
//! message through the descriptors the file carries) reads a recording
//! `rigslamd` made, with CRC checks on, through its summary and indexes
//! and again as a stream, and must find what rigslam's own reader finds:
//! the same messages on every channel, the same values, images with the
//! same pixels. `tests/readers/check_mcap.py` is the Python side.
//!
//! `@mcap/core`, the TypeScript reader Foxglove uses, reads the same
//! files the same two ways (`tests/readers/check_mcap.mjs`, decoding with
//! protobufjs) and prints its findings in the Python script's shape: it
//! must find what rigslam's reader finds, and exactly what the Python
//! reader finds, value for value.
//!
//! The Python side needs a Python with those packages: `RIGSLAM_PYTHON`,
//! which `scripts/test` points at the venv it makes in `target/py`. The
//! TypeScript side needs Node.js and the packages of
//! `tests/readers/package-lock.json` in `RIGSLAM_JS`, which `scripts/test`
//! installs into `target/js`. Without them the tests skip, except with
//! `CI` set.

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

#[path = "common/python.rs"]
mod python_env;

/// A Python that imports the MCAP readers, or `None` (skip) outside CI.
fn python() -> Option<PathBuf> {
    python_env::python_with(
        "mcap, mcap_protobuf, zstandard, lz4",
        "mcap mcap-protobuf-support zstandard lz4",
    )
}

/// What `check_mcap.py` found in `file`.
fn python_reads(python: &Path, file: &Path) -> Value {
    python_env::script_json(python, "check_mcap.py", file)
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

/// The packages `check_mcap.mjs` loads, checked by loading each.
const TYPESCRIPT_PACKAGES: &str = r#"
const load = require("module").createRequire(require("path").resolve(process.argv[1], "package.json"));
for (const p of ["@mcap/core", "@foxglove/crc", "@foxglove/wasm-zstd", "@foxglove/wasm-lz4",
                 "protobufjs", "protobufjs/ext/descriptor"]) load(p);
"#;

/// The directory whose `node_modules` holds the TypeScript MCAP reader
/// (`RIGSLAM_JS`), with a Node.js that loads it, or `None` (skip) outside CI.
fn typescript() -> Option<PathBuf> {
    let candidate = std::env::var_os("RIGSLAM_JS").map(PathBuf::from);
    let usable = candidate.as_ref().is_some_and(|dir| {
        Command::new("node")
            .args(["-e", TYPESCRIPT_PACKAGES])
            .arg(dir)
            .status()
            .is_ok_and(|s| s.success())
    });
    if usable {
        return candidate;
    }
    assert!(
        std::env::var_os("CI").is_none(),
        "CI is set but RIGSLAM_JS ({candidate:?}) holds no node_modules that Node.js loads \
         @mcap/core, @foxglove/crc, @foxglove/wasm-zstd, @foxglove/wasm-lz4 and protobufjs from \
         (scripts/test installs them into target/js from tests/readers/package-lock.json)"
    );
    eprintln!(
        "skipping: set RIGSLAM_JS to a directory where `npm ci` ran on tests/readers/package*.json"
    );
    None
}

/// What `check_mcap.mjs` found in `file`, in the shape of `check_mcap.py`.
fn typescript_reads(packages: &Path, file: &Path) -> Value {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/readers/check_mcap.mjs");
    let out = Command::new("node")
        .arg(script)
        .arg(file)
        .env("RIGSLAM_JS", packages)
        .output()
        .expect("run node");
    assert!(
        out.status.success(),
        "check_mcap.mjs failed on {}: {}",
        file.display(),
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).expect("JSON from check_mcap.mjs")
}

/// Where `a` and `b` differ, as JSON pointers with both values: keys on
/// one side only, lists of other lengths, and leaves that differ. Numbers
/// are equal only when both are integers of one value or both are floats
/// of one bit pattern, so 1 and 1.0 differ, and so do 0.0 and -0.0.
fn differences(a: &Value, b: &Value) -> Vec<String> {
    fn walk(a: &Value, b: &Value, at: &mut String, found: &mut Vec<String>) {
        let len = at.len();
        match (a, b) {
            (Value::Object(x), Value::Object(y)) => {
                for key in x.keys().chain(y.keys().filter(|k| !x.contains_key(*k))) {
                    at.push('/');
                    at.push_str(&key.replace('~', "~0").replace('/', "~1"));
                    match (x.get(key), y.get(key)) {
                        (Some(u), Some(v)) => walk(u, v, at, found),
                        (Some(_), None) => found.push(format!("{at}: only in the first")),
                        _ => found.push(format!("{at}: only in the second")),
                    }
                    at.truncate(len);
                }
            }
            (Value::Array(x), Value::Array(y)) => {
                if x.len() != y.len() {
                    found.push(format!("{at}: {} items vs {}", x.len(), y.len()));
                }
                for (i, (u, v)) in x.iter().zip(y).enumerate() {
                    at.push_str(&format!("/{i}"));
                    walk(u, v, at, found);
                    at.truncate(len);
                }
            }
            (Value::Number(x), Value::Number(y)) => {
                let same = match (x.is_f64(), y.is_f64()) {
                    (true, true) => x.as_f64().map(f64::to_bits) == y.as_f64().map(f64::to_bits),
                    (false, false) => x == y,
                    _ => false,
                };
                if !same {
                    found.push(format!("{at}: {x} vs {y}"));
                }
            }
            _ if a == b => {}
            _ => found.push(format!("{at}: {a} vs {b}")),
        }
    }
    let mut found = Vec::new();
    walk(a, b, &mut String::new(), &mut found);
    found
}

/// Fails unless `theirs` is `ours` value for value, naming the first differences.
fn assert_same_reading(ours_name: &str, ours: &Value, theirs_name: &str, theirs: &Value) {
    let found = differences(ours, theirs);
    assert!(
        found.is_empty(),
        "{ours_name} and {theirs_name} read the file differently, at {} places; the first:\n{}",
        found.len(),
        found[..found.len().min(20)].join("\n")
    );
}

/// Changes to a reader's output of a daemon recording that the
/// comparison must catch, each as (what, where, the changed output): a
/// value off by one unit in the last place, an image CRC, an integer
/// printed as a float, a value's sign, two messages swapped, one
/// message more, a metadata entry dropped, another compression.
fn altered_readings(out: &Value) -> Vec<(&'static str, &'static str, Value)> {
    fn altered(out: &Value, at: &str, change: impl FnOnce(&mut Value)) -> Value {
        let mut v = out.clone();
        change(
            v.pointer_mut(at)
                .unwrap_or_else(|| panic!("{at} in the reading")),
        );
        v
    }
    let bumped = |x: &mut Value| {
        let f = x.as_f64().expect("float");
        *x = serde_json::json!(f64::from_bits(f.to_bits() + 1));
    };
    vec![
        (
            "an IMU value one ulp off",
            "/values/~1imu0/3/6",
            altered(out, "/values/~1imu0/3/6", bumped),
        ),
        (
            "an image CRC",
            "/values/~1cam1/2/7",
            altered(out, "/values/~1cam1/2/7", |x| {
                *x = serde_json::json!(x.as_u64().expect("crc") ^ 1)
            }),
        ),
        (
            "a count as a float",
            "/messages/~1imu0",
            altered(out, "/messages/~1imu0", |x| {
                *x = serde_json::json!(x.as_u64().expect("count") as f64)
            }),
        ),
        (
            "a value's sign",
            "/values/~1rigslam~1pose_map/0/3",
            altered(out, "/values/~1rigslam~1pose_map/0/3", |x| {
                *x = serde_json::json!(-x.as_f64().expect("float"))
            }),
        ),
        (
            "two images swapped",
            "/values/~1cam0",
            altered(out, "/values/~1cam0", |x| {
                x.as_array_mut().expect("images").swap(0, 1)
            }),
        ),
        (
            "one log time more",
            "/log_times/~1tf",
            altered(out, "/log_times/~1tf", |x| {
                let times = x.as_array_mut().expect("times");
                times.push(times[0].clone());
            }),
        ),
        (
            "a metadata entry dropped",
            "/metadata/rigslam.clock/unix_ns",
            altered(out, "/metadata/rigslam.clock", |x| {
                x.as_object_mut().expect("entries").remove("unix_ns");
            }),
        ),
        (
            "another compression",
            "/chunk_compression/0",
            altered(out, "/chunk_compression/0", |x| {
                *x = serde_json::json!("lz4")
            }),
        ),
    ]
}

/// The comparison finds each alteration of `out`, there and nowhere else.
fn assert_comparison_catches_alterations(out: &Value) {
    for (what, at, changed) in altered_readings(out) {
        let found = differences(out, &changed);
        let here = |d: &String| {
            d.strip_prefix(at)
                .is_some_and(|rest| rest.starts_with(':') || rest.starts_with('/'))
        };
        assert!(!found.is_empty(), "{what} at {at} went unnoticed");
        assert!(found.iter().all(here), "{what} at {at}: found {found:?}");
    }
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

#[test]
fn the_typescript_mcap_reader_reads_a_daemon_recording_as_the_python_one_does() {
    let Some(packages) = typescript() else { return };
    let Some(rec) = record_micro("recording_readers_ts") else {
        return;
    };
    let ts = typescript_reads(&packages, &rec.file);
    assert_reads_as_rigslam_wrote_it("@mcap/core", &ts, &rec);
    // The comparison below can fail: on this very reading it catches each
    // kind of change, where it was made.
    assert_comparison_catches_alterations(&ts);
    let Some(python) = python() else { return };
    let py = python_reads(&python, &rec.file);
    assert_same_reading("mcap (Python)", &py, "@mcap/core", &ts);
}

#[test]
fn the_typescript_mcap_reader_reads_lz4_and_uncompressed_recordings_as_the_python_one_does() {
    let Some(packages) = typescript() else { return };
    let python = python();
    let dir = tempfile::tempdir().expect("tempdir");
    for (compression, name) in [(Compression::Lz4, "lz4"), (Compression::None, "")] {
        let path = dir.path().join(format!("r-{name}.mcap"));
        record_synthetic(&path, compression);
        let ts = typescript_reads(&packages, &path);
        assert_reads_synthetic("@mcap/core", &ts, name);
        if let Some(python) = &python {
            let py = python_reads(python, &path);
            assert_same_reading("mcap (Python)", &py, "@mcap/core", &ts);
        }
    }
}

#[test]
fn comparing_two_readings_finds_every_kind_of_difference() {
    let reading = serde_json::json!({
        "messages": {"/imu0": 4, "/cam0": 2, "/cam1": 3, "/rigslam/pose_map": 1, "/tf": 1},
        "values": {
            "/imu0": [[1, 0.5, 1e-5, 2.0, 0.25, 9.81, -3.5], [2, 0.5, 1e-5, 2.0, 0.25, 9.81, -3.5],
                      [3, 0.5, 1e-5, 2.0, 0.25, 9.81, -3.5], [4, 0.5, 1e-5, 2.0, 0.25, 9.81, -3.5]],
            "/cam0": [[1, 5, 752, 480, 752, "mono8", "cam0", 11], [1, 6, 752, 480, 752, "mono8", "cam0", 12]],
            "/cam0/calibration": [["cam0", 752, 480, "plumb_bob", [1.0, 0.0], [0.0]]],
            "/cam1": [[1, 5, 752, 480, 752, "mono8", "cam1", 13], [1, 6, 752, 480, 752, "mono8", "cam1", 14],
                      [1, 7, 752, 480, 752, "mono8", "cam1", 15]],
            "/rigslam/pose_map": [["map", 1, 5, 0.0, 0.0, 0.0]],
            "/tf": [[["map", "odom"], ["odom", "body"]]]
        },
        "log_times": {"/tf": [1795768780353023466u64]},
        "statistics_messages": 11,
        "chunk_indexes": 2,
        "chunk_compression": ["zstd"],
        "attachments": ["calibration/cam0.yaml"],
        "metadata": {"rigslam.clock": {"unix_ns": "1795768780353023466", "monotonic_ns": "4"}},
        "streamed_messages": 11
    });
    assert_eq!(
        differences(&reading, &reading.clone()),
        Vec::<String>::new()
    );
    assert_comparison_catches_alterations(&reading);
    // Keys on either side only, and integers beyond f64's 53 bits.
    let mut more = reading.clone();
    more["values"]["/rigslam/status"] = serde_json::json!([]);
    assert_eq!(differences(&reading, &more).len(), 1);
    assert_eq!(differences(&more, &reading).len(), 1);
    let mut later = reading.clone();
    later["log_times"]["/tf"][0] = serde_json::json!(1795768780353023467u64);
    assert_eq!(
        differences(&reading, &later),
        vec!["/log_times/~1tf/0: 1795768780353023466 vs 1795768780353023467"]
    );
}
