//! The README's first command, end to end: `rigslam demo` must render a
//! sequence, play it through rigslamd with `rigslam echo` subscribed, run
//! the relative stage on it in two modes as `rigslam run` does, score it
//! all, and report it as JSON.

use std::process::Command;

#[test]
fn demo_runs_the_whole_chain_and_reports_measured_numbers() {
    let out = tempfile::tempdir().expect("temp dir");
    let output = Command::new(env!("CARGO_BIN_EXE_rigslam"))
        .args(["demo", "--duration-s", "6", "--json", "--out"])
        .arg(out.path())
        // Hermetic: the real recordings are exercised by tests/run_real.rs.
        .args(["--real-data", "/nonexistent"])
        .output()
        .expect("run rigslam demo");
    assert!(
        output.status.success(),
        "demo failed: {}",
        String::from_utf8_lossy(&output.stderr)
    );
    let report: serde_json::Value =
        serde_json::from_slice(&output.stdout).expect("one JSON object on stdout");

    // 6 s at 20 Hz, both ends included.
    assert_eq!(report["simulation"]["frames"], 121);
    let runs = report["runs"].as_array().expect("runs");
    assert_eq!(runs.len(), 2, "no real data: the two synthetic runs only");
    for (run, mode) in runs.iter().zip(["stereo-inertial", "mono-inertial"]) {
        assert_eq!(run["mode"], mode);
        assert_eq!(run["frames"], 121);
        let eval = &run["eval"];
        assert_eq!(eval["align"], "se3");
        let ate = eval["ate_rmse_m"].as_f64().expect("ate");
        // Stereo-inertial on EuRoC-grade noise reaches a few cm; 0.2 m
        // would mean the chain (frames, signs, stamps) is broken.
        assert!(ate.is_finite() && ate < 0.2, "{mode}: ATE {ate} m");
        assert!(run["mean_ms_per_frame"].as_f64().expect("ms") > 0.0);
    }
    // The live part: rigslamd replayed the sequence at its pace and a
    // `rigslam echo` subscriber got every pose, as good as the offline run.
    let live = &report["live"];
    assert_eq!(live["frames"], 121, "{live}");
    assert_eq!(live["poses_received"], 121, "{live}");
    assert_eq!(live["poses_missed"], 0, "{live}");
    let live_ate = live["eval"]["ate_rmse_m"].as_f64().expect("live ATE");
    let offline_ate = runs[0]["eval"]["ate_rmse_m"].as_f64().expect("ATE");
    assert!(live_ate < 0.2, "live ATE {live_ate} m");
    assert!(
        (live_ate - offline_ate).abs() < 0.05,
        "live ATE {live_ate} m against {offline_ate} m offline"
    );
    // The daemon runs both stages: the map-frame poses and the
    // odometry-frame ones (the relative stage's, which the offline run
    // also gives) are both scored.
    let live_odom_ate = live["eval_odom"]["ate_rmse_m"]
        .as_f64()
        .expect("live odometry-frame ATE");
    assert!(
        (live_odom_ate - offline_ate).abs() < 0.05,
        "live odometry-frame ATE {live_odom_ate} m against {offline_ate} m offline"
    );
    assert!(live["frame_to_pose_p50_ms"].as_f64().expect("latency") > 0.0);
    assert!(out.path().join("live_stereo-inertial.tum").is_file());
    assert!(out.path().join("live_stereo-inertial_odom.tum").is_file());
    assert!(out.path().join("synthetic_stereo-inertial.tum").is_file());
    assert!(out.path().join("synthetic_stereo-inertial.png").is_file());
    assert!(out.path().join("sequence/mav0/cam1/data.csv").is_file());
}

#[test]
fn demo_rejects_a_too_short_sequence() {
    let output = Command::new(env!("CARGO_BIN_EXE_rigslam"))
        .args([
            "demo",
            "--duration-s",
            "0.1",
            "--out",
            "/tmp/unused-rigslam-demo",
        ])
        .output()
        .expect("run rigslam demo");
    assert!(!output.status.success());
    assert!(String::from_utf8_lossy(&output.stderr).contains("--duration-s"));
}
