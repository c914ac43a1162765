//! What each fuzz target does with its bytes, shared by the cargo-fuzz
//! targets (`tests/fuzz/fuzz_targets/`, nightly) and the stable corpus
//! test (`tests/fuzz_corpus.rs`), so that both exercise the same entry
//! points: every parser of a file or message the robot reads.
//!
//! Each function takes any bytes. It panics only when a parser does:
//! by panicking itself, or by breaking a property checked here (an error
//! that does not name its input, a line number outside the text).
//! Allocation bounds and hangs are the harness's to catch (libFuzzer's
//! `-malloc_limit_mb` and `-timeout`; the corpus test's allocator).

#![allow(dead_code)]

use std::io::Cursor;
use std::ops::ControlFlow;
use std::path::{Component, Path, PathBuf};
use std::sync::OnceLock;

use rigslam::daemon::config::{check, DaemonConfig};
use rigslam::dataset::{DatasetError, SensorStream, StreamOptions};
use rigslam::publish::{PoseMessage, SampleCheck, StatusMessage};
use rigslam::recording::SensorTopics;

/// The name every input goes by; every error must carry it.
pub const NAME: &str = "fuzz-input";

/// The targets, by name (the folder of each one's corpus under
/// `tests/fuzz/corpus/`).
pub const TARGETS: &[(&str, fn(&[u8]))] = &[
    ("daemon_config", daemon_config),
    ("sensor_yaml", sensor_yaml),
    ("dataset_text", dataset_text),
    ("dataset_dir", dataset_dir),
    ("map_file", map_file),
    ("edges_file", edges_file),
    ("matches_file", matches_file),
    ("mcap_recording", mcap_recording),
    ("pose_message", pose_message),
];

fn text(data: &[u8]) -> std::borrow::Cow<'_, str> {
    String::from_utf8_lossy(data)
}

/// Panics unless `message` names `name`.
fn names(message: &str, name: &str) {
    assert!(
        message.contains(name),
        "the error does not name its input {name:?}: {message}"
    );
}

/// A line number of `text` (1-based; one past the last line for "the
/// file ends here").
fn line_in(line: usize, text: &str, message: &str) {
    let lines = text.split('\n').count();
    assert!(
        (1..=lines + 1).contains(&line),
        "line {line} is outside the {lines}-line input: {message}"
    );
}

/// The checks every [`DatasetError`] of a text parser must pass.
fn dataset_error(e: &DatasetError, text: &str) {
    let message = e.to_string();
    names(&message, NAME);
    if let DatasetError::Malformed { line, .. } = e {
        line_in(*line, text, &message);
    }
}

/// A folder of its own for this process; [`remove_scratch`] removes it.
fn scratch() -> &'static Path {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        let dir = std::env::temp_dir().join(format!("rigslam-fuzz-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("a scratch folder");
        dir
    })
}

/// Removes this process's scratch folder (statics are never dropped).
pub fn remove_scratch() {
    let _ = std::fs::remove_dir_all(scratch());
}

/// Valid calibration files beside the config, so that a config naming
/// them gets past the files to the rig checks.
const CAM0_YAML: &str = "%YAML:1.0
sensor_type: camera
T_BS:
  cols: 4
  rows: 4
  data: [0.0, -1.0, 0.0, -0.02, 1.0, 0.0, 0.0, -0.06, 0.0, 0.0, 1.0, 0.01, 0.0, 0.0, 0.0, 1.0]
rate_hz: 20
resolution: [752, 480]
camera_model: pinhole
intrinsics: [460.0, 458.0, 368.0, 248.0]
distortion_model: radial-tangential
distortion_coefficients: [-0.28, 0.07, 0.0002, 0.00002]
";

const IMU0_YAML: &str = "%YAML:1.0
sensor_type: imu
T_BS:
  cols: 4
  rows: 4
  data: [1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0]
rate_hz: 200
gyroscope_noise_density: 1.6968e-04
gyroscope_random_walk: 1.9393e-05
accelerometer_noise_density: 2.0000e-3
accelerometer_random_walk: 3.0000e-3
";

/// Whether `path` stays inside the folder it is relative to (the fuzzer
/// must not make the config read `/dev/zero` or the machine's files; the
/// recording folder is only looked at, not read).
fn stays_inside(path: &Path) -> bool {
    path.components().all(|c| matches!(c, Component::Normal(_)))
}

/// `rigslamd`'s config file: TOML parsing, then the checks of
/// `--check-config` (files named in it resolve in an empty scratch folder
/// holding `cam0.yaml`, `cam1.yaml` and `imu0.yaml`).
pub fn daemon_config(data: &[u8]) {
    let text = text(data);
    let Ok(config) = DaemonConfig::parse(&text) else {
        return;
    };
    let relative_paths_only = config.calibration.as_ref().map_or(true, |c| {
        c.cameras.iter().all(|p| stays_inside(p)) && c.imu.as_deref().map_or(true, stays_inside)
    }) && config
        .replay
        .as_ref()
        .map_or(true, |r| stays_inside(&r.dataset));
    if !relative_paths_only {
        return;
    }
    let dir = scratch().join("config");
    if !dir.is_dir() {
        std::fs::create_dir_all(&dir).expect("scratch folder");
        for (name, body) in [
            ("cam0.yaml", CAM0_YAML),
            ("cam1.yaml", CAM0_YAML),
            ("imu0.yaml", IMU0_YAML),
        ] {
            std::fs::write(dir.join(name), body).expect("calibration file");
        }
    }
    let file = dir.join(format!("{NAME}.toml"));
    std::fs::write(&file, text.as_bytes()).expect("config file");
    let config = match DaemonConfig::load(&file) {
        Ok(c) => c,
        Err(e) => panic!("parsed from text but not from its file: {e}"),
    };
    if let Err(problems) = check(&config, &file) {
        for p in problems {
            assert_eq!(p.file, file, "{p}");
            assert!(!p.key.is_empty() && !p.why.is_empty(), "{p:?}");
        }
    }
    let _ = config.calibration_files();
}

/// Calibration YAML the core reads: a EuRoC camera or IMU `sensor.yaml`
/// (as the daemon's `[calibration]` names them, or as a recording carries
/// them) and Kalibr's `imu.yaml`.
pub fn sensor_yaml(data: &[u8]) {
    let text = text(data);
    let path = Path::new(NAME);
    match rigslam::dataset::parse_camera_yaml(&text, path) {
        Ok(c) => {
            // A calibration that reads must be usable and writable.
            let _ = c.model.project(&nalgebra::Vector3::new(0.1, -0.2, 1.0));
            let _ = c.model.unproject(&nalgebra::Vector2::new(1.0, 2.0));
            let _ = rigslam::dataset::euroc::sensor_yaml::camera_yaml("cam0", &c);
        }
        Err(e) => dataset_error_yaml(&e),
    }
    match rigslam::dataset::parse_imu_yaml(&text, path) {
        Ok(i) => {
            let _ = rigslam::dataset::euroc::sensor_yaml::imu_yaml(&i);
        }
        Err(e) => dataset_error_yaml(&e),
    }
    if let Err(e) = rigslam::rig::kalibr::imu_from_kalibr(&text, path) {
        dataset_error_yaml(&e);
    }
}

/// YAML errors name the file; their line is 0 when the parser gives none.
fn dataset_error_yaml(e: &DatasetError) {
    names(&e.to_string(), NAME);
}

/// The line-oriented dataset files: EuRoC IMU and ground-truth CSVs, EuRoC
/// and TUM trajectories, KITTI `poses.txt`, `times.txt` and `calib.txt`.
pub fn dataset_text(data: &[u8]) {
    let text = text(data);
    let path = Path::new(NAME);
    let check = |r: Result<(), DatasetError>| {
        if let Err(e) = r {
            dataset_error(&e, &text);
        }
    };
    check(rigslam::dataset::euroc::imu_csv::parse_euroc_imu_csv(&text, path).map(drop));
    check(rigslam::dataset::groundtruth::parse_euroc_groundtruth(&text, path).map(drop));
    check(rigslam::dataset::groundtruth::parse_euroc_trajectory(&text, path).map(drop));
    check(rigslam::dataset::tum::parse_tum(&text, path).map(drop));
    let stamps = match rigslam::dataset::kitti::parse_times(&text, path) {
        Ok(s) => s,
        Err(e) => {
            dataset_error(&e, &text);
            (0..64).map(|i| i * 100_000_000).collect()
        }
    };
    check(rigslam::dataset::kitti::parse_kitti_poses_stamped(&text, path, &stamps).map(drop));
    for name in ["P0", "P2"] {
        check(rigslam::dataset::kitti::parse_projection(&text, path, name).map(drop));
    }
}

/// Where [`dataset_dir`] puts each section of its input.
const EUROC_FILES: [&str; 9] = [
    "mav0/cam0/data.csv",
    "mav0/cam0/sensor.yaml",
    "mav0/cam0/data/1000.png",
    "mav0/imu0/data.csv",
    "mav0/imu0/sensor.yaml",
    "mav0/state_groundtruth_estimate0/data.csv",
    "mav0/cam1/data.csv",
    "mav0/cam1/sensor.yaml",
    "mav0/cam1/data/1000.png",
];
const KITTI_FILES: [&str; 5] = [
    "calib.txt",
    "image_0/000000.png",
    "times.txt",
    "poses.txt",
    "image_0/000001.png",
];

/// What separates the files in a [`dataset_dir`] input.
pub const SECTION: &[u8] = b"\n--8<--\n";

/// Splits `data` at every [`SECTION`].
pub fn sections(data: &[u8]) -> Vec<&[u8]> {
    let mut out = Vec::new();
    let mut rest = data;
    while let Some(at) = rest.windows(SECTION.len()).position(|w| w == SECTION) {
        out.push(&rest[..at]);
        rest = &rest[at + SECTION.len()..];
    }
    out.push(rest);
    out
}

/// A whole dataset folder, as `rigslam run --dataset` and `rigslamd
/// --replay` open it: the first byte picks the layout (even: EuRoC,
/// odd: KITTI), the rest is split at [`SECTION`] lines into the files of
/// [`EUROC_FILES`] or [`KITTI_FILES`] in order (fewer sections, fewer
/// files). The dataset is opened, then streamed in every mode it allows.
pub fn dataset_dir(data: &[u8]) {
    let Some((&layout, rest)) = data.split_first() else {
        return;
    };
    let root = scratch().join("dataset");
    if root.exists() {
        std::fs::remove_dir_all(&root).expect("clear the scratch dataset");
    }
    let files: &[&str] = if layout % 2 == 0 {
        &EUROC_FILES
    } else {
        &KITTI_FILES
    };
    for (name, body) in files.iter().zip(sections(rest)) {
        let file = root.join(name);
        std::fs::create_dir_all(file.parent().expect("a folder")).expect("dataset folder");
        std::fs::write(&file, body).expect("dataset file");
    }
    std::fs::create_dir_all(&root).expect("dataset folder");
    let root_name = root.display().to_string();
    let dataset = match rigslam::dataset::open_dataset(&root) {
        Ok(d) => d,
        Err(e) => return names(&e.to_string(), &root_name),
    };
    for (stereo, imu) in [(false, false), (false, true), (true, false), (true, true)] {
        let options = StreamOptions {
            stereo,
            imu,
            start_ns: None,
            max_frames: None,
            imu_lead_ns: 0,
        };
        let stream = match SensorStream::new(&dataset, options) {
            Ok(s) => s,
            Err(e) => {
                names(&e.to_string(), &root_name);
                continue;
            }
        };
        for event in stream {
            if let Err(e) = event {
                names(&e.to_string(), &root_name);
                break;
            }
        }
    }
    let _ = rigslam::run::dataset_run::rig_of(&dataset);
}

/// A saved map, as `--load-map` reads it.
pub fn map_file(data: &[u8]) {
    let path = Path::new(NAME);
    match rigslam::absolute::map_file::SavedMap::read_from(Cursor::new(data), path) {
        Ok(_) => {}
        Err(e) => {
            let message = e.to_string();
            names(&message, NAME);
            if let rigslam::absolute::map_file::MapFileError::Parse { line, .. } = e {
                line_in(line, &text(data), &message);
            }
        }
    }
}

/// The edges file of `rigslam map solve` and the positions it writes.
pub fn edges_file(data: &[u8]) {
    let text = text(data);
    let path = Path::new(NAME);
    let check = |e: rigslam::edge_map::EdgeMapError| {
        let message = e.to_string();
        names(&message, NAME);
        if let rigslam::edge_map::EdgeMapError::Line { line, .. } = e {
            line_in(line, &text, &message);
        }
    };
    if let Err(e) = rigslam::edge_map::edges_file::parse_edges(&text, path) {
        check(e);
    }
    if let Err(e) = rigslam::edge_map::edges_file::parse_positions(&text, path) {
        check(e);
    }
}

/// The matches and relative-motion files of `rigslam bench essential`.
pub fn matches_file(data: &[u8]) {
    use rigslam::dataset::matches_file::{normalise, parse_matches, parse_relative_motions};
    let text = text(data);
    let path = Path::new(NAME);
    match parse_matches(path, &text) {
        Ok(file) => match file.camera(path) {
            Ok(camera) => {
                for pair in &file.pairs {
                    let _ = normalise(&camera, pair);
                }
            }
            Err(e) => dataset_error(&e, &text),
        },
        Err(e) => dataset_error(&e, &text),
    }
    if let Err(e) = parse_relative_motions(path, &text) {
        dataset_error(&e, &text);
    }
}

/// An MCAP recording as `rigslamd --replay` reads it: the checks of
/// `--check-config` (topics and counts, calibration attachments), then
/// every sensor event in each stream selection, and the channel readers.
pub fn mcap_recording(data: &[u8]) {
    let path = PathBuf::from(format!("{NAME}.mcap"));
    let named = |e: rigslam::recording::RecordingError| names(&e.to_string(), NAME);
    if let Err(e) = rigslam::recording::channel_counts_in(data, &path) {
        named(e);
    }
    if let Err(e) = rigslam::recording::rig_of_recording_in(data, &path) {
        named(e);
    }
    for (stereo, imu) in [(false, false), (true, true)] {
        let topics = SensorTopics { stereo, imu };
        if let Err(e) = rigslam::recording::for_each_sensor_event_in(data, &path, topics, |_| {
            ControlFlow::Continue(())
        }) {
            named(e);
        }
    }
    if let Err(e) = rigslam::recording::read_imu_channel_in(data, &path, "/imu0") {
        named(e);
    }
    if let Err(e) = rigslam::recording::read_pose_channel_in(data, &path, "/pose") {
        named(e);
    }
}

/// Pose and status messages as a subscriber takes them from shared
/// memory, whatever a publisher wrote: the input is cut into messages,
/// each checked in turn as one subscription would, then read through
/// every accessor.
pub fn pose_message(data: &[u8]) {
    let _ = PoseMessage::from_bytes(data);
    let _ = StatusMessage::from_bytes(data);
    let mut poses = SampleCheck::default();
    for chunk in data.chunks_exact(std::mem::size_of::<PoseMessage>()) {
        let message = PoseMessage::from_bytes(chunk).expect("a whole message");
        assert_eq!(message.as_bytes(), chunk);
        if let Err(e) = poses.accept("rigslam/pose", &message) {
            names(&e.to_string(), "rigslam/pose");
            continue;
        }
        let _ = message.T_world_body();
        let _ = message.covariance_matrix();
        let _ = message.state();
    }
    let _ = poses.missed();
    let mut statuses = SampleCheck::default();
    for chunk in data.chunks_exact(std::mem::size_of::<StatusMessage>()) {
        let message = StatusMessage::from_bytes(chunk).expect("a whole message");
        if let Err(e) = statuses.accept("rigslam/status", &message) {
            names(&e.to_string(), "rigslam/status");
            continue;
        }
        for q in message.queues_in_use() {
            let _ = q.name_str();
        }
    }
    let _ = statuses.missed();
}
