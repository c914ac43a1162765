//! `rigslam imu` end to end against the simulated YEI 3-Space on a pty.

use std::process::Command;

#[test]
fn imu_json_report_has_the_contract_keys() {
    let out = Command::new(env!("CARGO_BIN_EXE_rigslam"))
        .args([
            "imu",
            "--simulate",
            "--seconds",
            "1",
            "--rate-hz",
            "500",
            // 500 Hz of 32-byte packets needs more than the factory 115200
            // baud; the driver refuses the rate otherwise.
            "--baud",
            "921600",
            "--json",
        ])
        .output()
        .expect("run rigslam");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let report: serde_json::Value = serde_json::from_slice(&out.stdout).expect("one JSON object");
    for key in [
        "serial",
        "firmware",
        "samples",
        "rate_hz",
        "jitter_us",
        "checksum_errors",
        "resyncs",
        "drops",
        "gyro_mean_rad_s",
        "accel_mean_m_s2",
    ] {
        assert!(report.get(key).is_some(), "missing {key}: {report}");
    }
    assert_eq!(report["serial"], "12345678");
    assert_eq!(report["firmware"], "25Apr2013A00");
    // Rate from the sensor clock: exactly the configured 500 Hz.
    let rate = report["rate_hz"].as_f64().expect("number");
    assert!((rate - 500.0).abs() < 1e-6, "{rate}");
    assert_eq!(report["drops"], 0);
    // The simulated motion holds accel z near 1 g.
    let az = report["accel_mean_m_s2"][2].as_f64().expect("number");
    assert!((az - 9.81).abs() < 0.05, "{az}");
}

#[test]
fn imu_wrong_port_says_what_to_check() {
    let out = Command::new(env!("CARGO_BIN_EXE_rigslam"))
        .args(["imu", "--port", "/dev/ttyNOPE", "--seconds", "1"])
        .output()
        .expect("run rigslam");
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("/dev/ttyNOPE") && err.contains("check the path"),
        "{err}"
    );
}

#[test]
fn imu_records_what_it_reports() {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("imu.mcap");
    let out = Command::new(env!("CARGO_BIN_EXE_rigslam"))
        .args([
            "imu",
            "--simulate",
            "--seconds",
            "0.5",
            "--json",
            "--record",
        ])
        .arg(&path)
        .output()
        .expect("run rigslam");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let report: serde_json::Value = serde_json::from_slice(&out.stdout).expect("one JSON object");
    let samples = rigslam::recording::read_imu_channel(&path, "/imu0").expect("recording");
    assert_eq!(
        samples.len() as u64,
        report["samples"].as_u64().expect("count")
    );
    let n = samples.len() as f64;
    let mean_az = samples.iter().map(|s| s.accel_m_s2[2]).sum::<f64>() / n;
    let reported = report["accel_mean_m_s2"][2].as_f64().expect("number");
    assert!((mean_az - reported).abs() < 1e-9, "{mean_az} vs {reported}");
    assert!(samples.windows(2).all(|w| w[1].t_ns > w[0].t_ns));
}
