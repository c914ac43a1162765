//! `rigslam camera` end to end: the pattern camera's report has the keys
//! its users rely on, and a missing device or an unknown format gives an
//! error that names it and says what to check.

use std::process::Command;

fn rigslam(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_rigslam"))
        .args(args)
        .output()
        .expect("rigslam runs")
}

#[test]
fn json_report_has_the_contract_keys() {
    let out = rigslam(&[
        "camera",
        "--driver",
        "fake",
        "--seconds",
        "0.3",
        "--rate-hz",
        "40",
        "--width",
        "64",
        "--height",
        "48",
        "--json",
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let report: serde_json::Value =
        serde_json::from_slice(&out.stdout).expect("one JSON object on stdout");
    for key in [
        "frames",
        "rate_hz",
        "drops",
        "width",
        "height",
        "format",
        "timestamp_source",
    ] {
        assert!(report.get(key).is_some(), "missing {key}: {report}");
    }
    assert_eq!(report["width"], 64);
    assert_eq!(report["height"], 48);
    assert_eq!(report["format"], "mono8");
    assert_eq!(report["drops"], 0);
    assert!(report["frames"].as_u64().expect("count") >= 2, "{report}");
    // The pattern camera stamps frames exactly 25 ms apart.
    let rate = report["rate_hz"].as_f64().expect("number");
    assert!((rate - 40.0).abs() < 1e-6, "{rate}");
}

#[test]
fn bad_devices_and_formats_say_what_to_check() {
    let out = rigslam(&["camera", "--driver", "v4l2", "--device", "/dev/video-nope"]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("/dev/video-nope") && err.contains("v4l2-ctl"),
        "{err}"
    );

    let out = rigslam(&["camera", "--driver", "v4l2", "--format", "MJPG"]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("MJPG") && err.contains("YUYV"), "{err}");
}
