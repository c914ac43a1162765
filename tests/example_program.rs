//! `examples/poses_from_dataset.rs`, the shortest way to run the pipeline
//! from code, gives the same poses as `rigslam run` on the same folder:
//! the example's loop is the whole of what a user needs.

use std::path::PathBuf;
use std::process::Command;

use rigslam::dataset::trajectory_out::{write_trajectory, TrajectoryFormat};
use rigslam::run::dataset_run::{run_dataset, DatasetRun};
use rigslam::shared_data;

/// `target/<profile>/examples/poses_from_dataset`, which `cargo test` builds
/// beside the test binaries (`target/<profile>/deps/`).
fn example_binary() -> PathBuf {
    let test_exe = std::env::current_exe().expect("test binary path");
    let profile_dir = test_exe
        .parent()
        .and_then(|deps| deps.parent())
        .expect("target/<profile>/deps/<test>");
    let binary = profile_dir.join("examples").join("poses_from_dataset");
    assert!(
        binary.exists(),
        "{} is missing: `cargo test` (or `cargo build --all-targets`) builds it",
        binary.display()
    );
    binary
}

#[test]
fn the_example_gives_the_poses_of_rigslam_run() {
    let Some(euroc) = shared_data::path_or_skip("euroc/V1_01_micro") else {
        return;
    };
    let dir = tempfile::tempdir().expect("temp dir");
    let from_example = dir.path().join("example.tum");
    let status = Command::new(example_binary())
        .arg(&euroc)
        .arg(&from_example)
        .status()
        .expect("run the example");
    assert!(status.success(), "the example failed: {status}");

    let result =
        run_dataset(&euroc, &DatasetRun::default(), |_, _| {}).expect("rigslam run's path");
    assert!(
        result.outcome.trajectory.len() > 20,
        "too few poses to compare"
    );
    let from_run = dir.path().join("run.tum");
    write_trajectory(&from_run, &result.outcome.trajectory, TrajectoryFormat::Tum).expect("write");

    let (example, run) = (
        std::fs::read_to_string(&from_example).expect("the example wrote its file"),
        std::fs::read_to_string(&from_run).expect("written above"),
    );
    assert_eq!(
        example.lines().count(),
        run.lines().count(),
        "pose counts differ"
    );
    assert!(
        example == run,
        "the example's poses differ from rigslam run's"
    );
}

#[test]
fn the_example_explains_its_arguments() {
    let output = Command::new(example_binary())
        .output()
        .expect("run the example");
    assert!(!output.status.success());
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(
        stderr.contains("usage: poses_from_dataset DIR OUT.tum"),
        "{stderr}"
    );
}
