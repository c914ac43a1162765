//! `examples/ros2/pose_bridge.py`, the bridge docs/ros2.md shows, turns
//! the poses a rigslam publisher sends into the odometry and transforms a
//! ROS 2 recording holds: run with `--print` (no ROS needed), what it
//! would publish must be what `rigslam::recording::ros2::convert` writes
//! into a `format = "ros2"` file for the same pose.
//!
//! It needs a Python with iceoryx2's binding: `RIGSLAM_PYTHON`, which
//! `scripts/test` points at the venv it makes in `target/py`. Without one
//! the test skips, except with `CI` set. The ROS side of the bridge
//! (rclpy) is not run here.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::atomic::Ordering;
use std::time::Duration;

use nalgebra::{Isometry3, Matrix6, Translation3, UnitQuaternion, Vector3};
use rigslam::publish::{IpcConfig, PoseMessage, PosePublisher};
use rigslam::recording::ros2::convert;
use rigslam::recording::RecordedPose;
use rigslam::relative::TrackingState;
use serde_json::Value;

#[path = "common/python.rs"]
mod python_env;

/// A Python that imports iceoryx2, or `None` (skip) outside CI.
fn python() -> Option<PathBuf> {
    python_env::python_with("iceoryx2", "iceoryx2==0.10.0")
}

/// Pose `i`, tracked when `tracked`: the map -> odom rotation, the
/// covariance and the velocity all depend on `i`.
fn message(i: u64, tracked: bool) -> PoseMessage {
    let f = i as f64;
    let pose = Isometry3::from_parts(
        Translation3::new(f + 0.125, -2.0 * f + 1.0 / 3.0, 0.5 + f),
        UnitQuaternion::from_euler_angles(0.01 * f, -0.02 * f, 0.3 + 0.03 * f),
    );
    let covariance = Matrix6::from_fn(|r, c| {
        if r == c {
            1e-4 * (r as f64 + 1.0 + f)
        } else {
            1e-6 * (r + c) as f64
        }
    });
    let state = if tracked {
        TrackingState::Tracking
    } else {
        TrackingState::Lost
    };
    PoseMessage::new(1_000_000 * i as i64 + 17, state, &pose)
        .with_velocity(&Vector3::new(0.1 * f, 0.2, -f))
        .with_covariance(&covariance)
        .with_world_odom(&Isometry3::from_parts(
            Translation3::new(0.01 * f, -0.5, 0.25 + f),
            UnitQuaternion::from_euler_angles(0.1, -0.2, 0.5 + 0.01 * f),
        ))
}

/// The pose as the recorder gets it.
fn recorded(m: &PoseMessage) -> RecordedPose {
    RecordedPose {
        t_ns: m.t_ns,
        tracking_state: m.tracking_state,
        flags: m.flags,
        position_world_m: m.position_world_m,
        orientation_world_body_xyzw: m.orientation_world_body_xyzw,
        velocity_world_m_s: m.velocity_world_m_s,
        covariance: m.covariance,
        position_odom_m: m.position_odom_m,
        orientation_odom_body_xyzw: m.orientation_odom_body_xyzw,
        translation_world_odom_m: m.translation_world_odom_m,
        rotation_world_odom_xyzw: m.rotation_world_odom_xyzw,
    }
}

fn f64s(v: &Value) -> Vec<f64> {
    v.as_array()
        .unwrap_or_else(|| panic!("not an array: {v}"))
        .iter()
        .map(|x| x.as_f64().expect("number"))
        .collect()
}

fn close(a: &[f64], b: &[f64], what: &str) {
    assert_eq!(a.len(), b.len(), "{what}");
    for (x, y) in a.iter().zip(b) {
        assert!(
            (x - y).abs() <= 1e-12 * y.abs().max(1.0),
            "{what}: {a:?} vs {b:?}"
        );
    }
}

#[test]
fn the_bridge_publishes_what_a_ros2_recording_holds() {
    let Some(python) = python() else {
        return;
    };
    let root = tempfile::tempdir().expect("temp dir for the iceoryx2 root");
    let config = IpcConfig {
        service_prefix: format!("rigslam_test_{}_bridge", std::process::id()),
        root_path: Some(root.path().to_path_buf()),
        group: None,
    };
    let mut publisher = PosePublisher::open(&config).expect("publisher");
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/ros2/pose_bridge.py");
    let mut bridge = Command::new(python)
        .arg(&script)
        .args([
            "--print",
            "--count",
            "6",
            "--timeout-s",
            "20",
            "--root-path",
        ])
        .arg(root.path())
        .args(["--service", &format!("{}/pose", config.service_prefix)])
        .stdout(Stdio::piped())
        .spawn()
        .expect("start the bridge");
    let stdout = bridge.stdout.take().expect("piped");
    let (done, lines) = python_env::read_lines(stdout);
    // Every third pose is lost: the bridge leaves those out.
    let mut sent = Vec::new();
    for i in 0..3000u64 {
        if done.load(Ordering::SeqCst) {
            break;
        }
        let m = message(i, i % 3 != 2);
        publisher.publish(&m).expect("publish");
        sent.push(m);
        std::thread::sleep(Duration::from_millis(10));
    }
    let lines = lines.join().expect("reader thread");
    let status = bridge.wait().expect("bridge exits");
    assert!(
        status.success(),
        "the bridge failed: {status}; printed {lines:?}"
    );
    assert_eq!(lines.len(), 6, "{lines:?}");

    let mut rotated = 0;
    for line in &lines {
        let got: Value = serde_json::from_str(line).expect("one JSON object per line");
        let t_ns = got["stamp_ns"].as_i64().expect("stamp");
        let m = sent
            .iter()
            .find(|m| m.t_ns == t_ns)
            .expect("a pose that was sent");
        assert_eq!(m.tracking_state, 1, "a pose that is not tracked: {line}");
        let p = recorded(m);
        let odometry = convert::odometry(&p);
        let o = &got["odometry"];
        assert_eq!(
            (o["frame_id"].as_str(), o["child_frame_id"].as_str()),
            (
                Some(odometry.header.frame_id.as_str()),
                Some(odometry.child_frame_id.as_str())
            )
        );
        assert_eq!(f64s(&o["position"]), odometry.position);
        assert_eq!(f64s(&o["orientation_xyzw"]), odometry.orientation_xyzw);
        close(
            &f64s(&o["pose_covariance"]),
            &odometry.pose_covariance,
            "covariance",
        );
        close(
            &f64s(&o["linear_velocity"]),
            &odometry.linear_velocity,
            "velocity",
        );
        if odometry.pose_covariance != m.covariance {
            rotated += 1;
        }
        let tf = convert::pose_transforms(&p);
        let transforms = got["transforms"].as_array().expect("transforms");
        assert_eq!(transforms.len(), tf.transforms.len());
        for (t, expected) in transforms.iter().zip(&tf.transforms) {
            assert_eq!(t[0], expected.header.frame_id.as_str());
            assert_eq!(t[1], expected.child_frame_id.as_str());
            assert_eq!(f64s(&t[2]), expected.translation);
            assert_eq!(f64s(&t[3]), expected.rotation_xyzw);
        }
    }
    assert_eq!(
        rotated,
        lines.len(),
        "the covariance is turned into odom's axes"
    );
}
