//! The README's first command, end to end: `rigslam demo` must simulate,
//! read back every image, estimate and score, and report it as JSON.

use std::process::Command;

#[test]
fn demo_runs_the_whole_chain_and_reports_measured_numbers() {
    let out = tempfile::tempdir().expect("temp dir");
    let output = Command::new(env!("CARGO_BIN_EXE_rigslam"))
        .args(["demo", "--duration-s", "2", "--json", "--out"])
        .arg(out.path())
        // Hermetic: the real-recording part is exercised by the eval and dataset tests.
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

    // 2 s at 20 Hz, both ends included, and every image read back.
    assert_eq!(report["simulation"]["frames"], 41);
    assert_eq!(
        report["times"]["images_read"],
        report["simulation"]["images"]
    );
    assert!(report["simulation"]["render_fps"].as_f64().expect("fps") > 0.0);
    assert!(report["real"].is_null());

    // Dead reckoning from the true state with the true initial biases over
    // 2 s of EuRoC-grade noise: the expected position error is ~1 cm
    // (sigma_a sqrt(T^3/3) + g sigma_g sqrt(T^5/20)); 10 cm would mean
    // the chain (frames, signs, stamps) is broken, not noisy.
    let eval = &report["synthetic"];
    assert_eq!(eval["align"], "none");
    assert!(eval["matched_poses"].as_u64().expect("count") >= 400);
    let ate = eval["ate_rmse_m"].as_f64().expect("ate");
    assert!(ate.is_finite() && ate < 0.1, "ATE {ate} m");
    assert!(out.path().join("estimate.tum").is_file());
    assert!(out.path().join("synthetic.png").is_file());
    assert!(out.path().join("sequence/mav0/cam0/data.csv").is_file());
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
