//! `examples/python/echo_pose.py`, the Python reader the README shows,
//! receives the poses a rigslam publisher sends, every field exact: the
//! ctypes layout there matches `PoseMessage`, and the payload type name,
//! size and alignment match what iceoryx2 checks when it opens the service.
//!
//! It needs a Python with iceoryx2's binding (the daemon's iceoryx2
//! version): `RIGSLAM_PYTHON`, which `scripts/test` points at the venv it
//! makes in `target/py`. Without one the test skips, except with `CI` set.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::atomic::Ordering;
use std::time::Duration;

use nalgebra::{Isometry3, Matrix6, Translation3, UnitQuaternion, Vector3};
use rigslam::publish::{IpcConfig, PoseMessage, PosePublisher};
use rigslam::relative::TrackingState;

#[path = "common/python.rs"]
mod python_env;

/// A Python that imports iceoryx2, or `None` (skip) outside CI.
fn python() -> Option<PathBuf> {
    python_env::python_with("iceoryx2", "iceoryx2==0.10.0")
}

/// Pose `i`: every field depends on `i`, so a shifted or garbled field is seen.
fn message(i: u64) -> PoseMessage {
    let f = i as f64;
    let pose = Isometry3::from_parts(
        Translation3::new(f + 0.125, -2.0 * f + 1.0 / 3.0, 0.5 + f),
        UnitQuaternion::from_euler_angles(0.01 * f, -0.02 * f, 0.03 * f),
    );
    let covariance = Matrix6::from_fn(|r, c| {
        if r == c {
            1e-4 * (r as f64 + 1.0 + f)
        } else {
            1e-6 * (r + c) as f64
        }
    });
    PoseMessage::new(1_000_000 * i as i64 + 17, TrackingState::Tracking, &pose)
        .with_velocity(&Vector3::new(0.1 * f, 0.2, -f))
        .with_covariance(&covariance)
        .with_world_odom(&Isometry3::from_parts(
            Translation3::new(0.01 * f, -0.5, 0.25 + f),
            UnitQuaternion::from_euler_angles(0.0, 0.0, 0.001 * f),
        ))
}

#[test]
fn the_python_reader_receives_every_field() {
    let Some(python) = python() else {
        return;
    };
    let root = tempfile::tempdir().expect("temp dir for the iceoryx2 root");
    let config = IpcConfig {
        service_prefix: format!("rigslam_test_{}_python", std::process::id()),
        root_path: Some(root.path().to_path_buf()),
        group: None,
    };
    let mut publisher = PosePublisher::open(&config).expect("publisher");
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/python/echo_pose.py");
    let mut reader = Command::new(python)
        .arg(&script)
        .args(["--json", "--count", "5", "--timeout-s", "20", "--root-path"])
        .arg(root.path())
        .args(["--service", &format!("{}/pose", config.service_prefix)])
        .stdout(Stdio::piped())
        .spawn()
        .expect("start the Python reader");
    let stdout = reader.stdout.take().expect("piped");

    // Publish until the reader has its five poses (it may join late).
    let (done, lines) = python_env::read_lines(stdout);
    let mut sent = Vec::new();
    for i in 0..3000u64 {
        if done.load(Ordering::SeqCst) {
            break;
        }
        let m = message(i);
        let sequence = publisher.publish(&m).expect("publish");
        sent.push((sequence, m));
        std::thread::sleep(Duration::from_millis(10));
    }
    let lines = lines.join().expect("reader thread");
    let status = reader.wait().expect("reader exits");
    assert!(
        status.success(),
        "the Python reader failed: {status}; printed {lines:?}"
    );
    assert_eq!(lines.len(), 5, "{lines:?}");

    for line in &lines {
        let got: serde_json::Value = serde_json::from_str(line).expect("one JSON object per line");
        let sequence = got["sequence"].as_u64().expect("sequence");
        let (_, m) = sent
            .iter()
            .find(|(s, _)| *s == sequence)
            .expect("a sequence that was sent");
        let floats = |key: &str| -> Vec<f64> {
            got[key]
                .as_array()
                .expect(key)
                .iter()
                .map(|v| v.as_f64().expect("number"))
                .collect()
        };
        assert_eq!(got["t_ns"].as_i64(), Some(m.t_ns), "{line}");
        assert_eq!(got["tracking_state"], "tracking", "{line}");
        assert_eq!(got["flags"].as_u64(), Some(m.flags as u64), "{line}");
        assert_eq!(floats("position_world_m"), m.position_world_m, "{line}");
        assert_eq!(
            floats("orientation_world_body_xyzw"),
            m.orientation_world_body_xyzw,
            "{line}"
        );
        assert_eq!(floats("velocity_world_m_s"), m.velocity_world_m_s, "{line}");
        assert_eq!(floats("covariance"), m.covariance, "{line}");
        assert_eq!(floats("position_odom_m"), m.position_odom_m, "{line}");
        assert_eq!(
            floats("orientation_odom_body_xyzw"),
            m.orientation_odom_body_xyzw,
            "{line}"
        );
        assert_eq!(
            floats("translation_world_odom_m"),
            m.translation_world_odom_m,
            "{line}"
        );
        assert_eq!(
            floats("rotation_world_odom_xyzw"),
            m.rotation_world_odom_xyzw,
            "{line}"
        );
    }
}

/// The binding the scripts and the example install is the iceoryx2 the
/// daemon is built with: a shared-memory layout is only promised between
/// equal versions.
#[test]
fn the_python_binding_pin_is_the_daemons_iceoryx2() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let lock = std::fs::read_to_string(root.join("Cargo.lock")).expect("Cargo.lock");
    let version = lock
        .split("[[package]]")
        .find(|p| p.contains("\nname = \"iceoryx2\"\n"))
        .and_then(|p| p.lines().find_map(|l| l.strip_prefix("version = \"")))
        .map(|v| v.trim_end_matches('"').to_string())
        .expect("iceoryx2 in Cargo.lock");
    let pin = format!("iceoryx2=={version}");
    for file in [
        "scripts/test",
        "examples/python/echo_pose.py",
        "examples/ros2/pose_bridge.py",
        "docs/ros2.md",
        "README.md",
    ] {
        let text = std::fs::read_to_string(root.join(file)).expect(file);
        assert!(text.contains(&pin), "{file} must install {pin}");
    }
}
