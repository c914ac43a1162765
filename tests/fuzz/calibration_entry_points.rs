//! The calibration tool's inputs, fuzzed like the core's
//! (`entry_points.rs`): shared by the cargo-fuzz target `kalibr_yaml` and
//! the stable corpus test `calibration/tests/fuzz_corpus.rs`.

#![allow(dead_code)]

use std::path::Path;

/// The name every input goes by; every error must carry it.
pub const NAME: &str = "fuzz-input";

/// The targets, by name (the folder of each one's corpus under
/// `tests/fuzz/corpus/`).
pub const TARGETS: &[(&str, fn(&[u8]))] = &[("kalibr_yaml", kalibr_yaml)];

/// `rigslam-calibrate`'s YAML inputs: the IMU intrinsics it writes and
/// reads back, and a Kalibr camchain's (or yac `sequence.yaml`'s) camera
/// intrinsics.
pub fn kalibr_yaml(data: &[u8]) {
    let text = String::from_utf8_lossy(data);
    let path = Path::new(NAME);
    if let Err(e) = rigslam_calibration::calibration_files::parse_intrinsics_yaml(&text, path) {
        named(&e.to_string());
    }
    for cam in ["cam0", "cam1"] {
        if let Err(e) = rigslam_calibration::camchain_yaml::parse_intrinsics(&text, path, cam) {
            named(&format!("{e:#}"));
        }
    }
}

fn named(message: &str) {
    assert!(
        message.contains(NAME),
        "the error does not name its input {NAME:?}: {message}"
    );
}
