//! `rigslam echo --json` against a publisher in this test process.

use std::process::Command;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::thread;
use std::time::Duration;

use nalgebra::Isometry3;
use rigslam::publish::{IpcConfig, PoseMessage, PosePublisher};
use rigslam::relative::types::TrackingState;
use rigslam::sensors::yei::device::host_monotonic_ns;

/// `rigslam echo --json --count COUNT` on poses published at about 1 kHz
/// with `t_ns = host clock + offset_ns`; its JSON report and how many were
/// sent.
fn echo_json(name: &str, offset_ns: i64) -> (serde_json::Value, u64) {
    const COUNT: u64 = 50;
    let (root, config) = private_ipc(name);
    let stop = Arc::new(AtomicBool::new(false));
    let publisher = publish_until_stopped(&config, &stop, move |_| {
        PoseMessage::new(
            host_monotonic_ns() + offset_ns,
            TrackingState::Tracking,
            &Isometry3::identity(),
        )
    });
    let output = Command::new(env!("CARGO_BIN_EXE_rigslam"))
        .args(["echo", "--service"])
        .arg(format!("{}/pose", config.service_prefix))
        .args(["--count", &COUNT.to_string(), "--timeout-s", "30", "--json"])
        .arg("--root-path")
        .arg(root.path())
        .output()
        .expect("run rigslam echo");
    stop.store(true, Ordering::Relaxed);
    let sent = publisher.join().expect("publisher thread");
    assert!(
        output.status.success(),
        "rigslam echo failed: {}",
        String::from_utf8_lossy(&output.stderr)
    );
    let stdout = String::from_utf8(output.stdout).expect("UTF-8 output");
    let report: serde_json::Value = serde_json::from_str(stdout.trim()).expect("one JSON object");
    assert_eq!(report["received"], COUNT);
    assert!(sent >= COUNT, "echo received {COUNT} of {sent} sent");
    assert_eq!(report["service"], format!("{}/pose", config.service_prefix));
    (report, sent)
}

/// A fresh iceoryx2 root and services under a prefix of this test
/// process's own (`rigslam_echo_NAME_PID`); the root lives as long as the
/// returned directory.
fn private_ipc(name: &str) -> (tempfile::TempDir, IpcConfig) {
    let root = tempfile::tempdir().expect("temp dir for the iceoryx2 root");
    let config = IpcConfig {
        service_prefix: format!("rigslam_echo_{name}_{}", std::process::id()),
        root_path: Some(root.path().to_path_buf()),
        group: None,
    };
    (root, config)
}

/// A thread that publishes `message(k)`, k = 0, 1, ..., on `config`'s
/// pose service at about 1 kHz until `stop` is set, and returns how many
/// it sent (the pacing only keeps the CPU free; nothing depends on it).
fn publish_until_stopped(
    config: &IpcConfig,
    stop: &Arc<AtomicBool>,
    message: impl Fn(i64) -> PoseMessage + Send + 'static,
) -> thread::JoinHandle<u64> {
    let config = config.clone();
    let stop = Arc::clone(stop);
    thread::spawn(move || {
        let mut publisher = PosePublisher::open(&config).expect("publisher");
        let mut sent = 0u64;
        while !stop.load(Ordering::Relaxed) {
            publisher.publish(&message(sent as i64)).expect("publish");
            sent += 1;
            thread::sleep(Duration::from_millis(1));
        }
        sent
    })
}

#[test]
fn echo_json_reports_the_samples_of_a_short_run() {
    let (report, _) = echo_json("host", 0);
    let number = |key: &str| {
        report[key]
            .as_f64()
            .unwrap_or_else(|| panic!("{key} is not a number in {report}"))
    };
    let rate_hz = number("rate_hz");
    assert!(rate_hz.is_finite() && rate_hz > 0.0, "rate_hz {rate_hz}");
    let (p50, p99) = (number("latency_p50_us"), number("latency_p99_us"));
    let (t50, t99) = (
        number("transport_latency_p50_us"),
        number("transport_latency_p99_us"),
    );
    assert!(t50 > 0.0 && t50 <= t99, "transport p50 {t50} p99 {t99}");
    assert!(p50 <= p99, "latency p50 {p50} p99 {p99}");
    // t_ns is stamped before publishing, so each sample's age is at least
    // its transport time, and so are the percentiles.
    assert!(
        p50 >= t50 && p99 >= t99,
        "latency {p50}/{p99} < transport {t50}/{t99}"
    );
    assert!(report["missed"].as_u64().is_some());
    // Every sample is stamped on the host clock.
    assert_eq!(report["latency_samples"], report["received"], "{report}");
}

/// Poses stamped on another clock: the latency is null, not a huge
/// number, and counted over no sample; the transport latency is still
/// measured. A replay publishes the dataset's stamps (2014 Unix times in
/// EuRoC, far ahead of the host's uptime: a large negative "latency"); a
/// clock an hour behind gives an hour.
#[test]
fn echo_json_gives_null_for_a_latency_on_another_clock() {
    let dataset_clock_ns = 1_403_715_273_262_142_976 - host_monotonic_ns();
    let hour_ns = 3_600_000_000_000;
    for (name, offset_ns) in [
        ("dataset_clock", dataset_clock_ns),
        ("hour_behind", -hour_ns),
    ] {
        let (report, _) = echo_json(name, offset_ns);
        assert!(report["latency_p50_us"].is_null(), "{name}: {report}");
        assert!(report["latency_p99_us"].is_null(), "{name}: {report}");
        assert_eq!(report["latency_samples"], 0, "{name}: {report}");
        let t50 = report["transport_latency_p50_us"].as_f64().expect("number");
        assert!(t50 > 0.0 && t50 < 60e6, "{name}: {report}");
    }
}

#[test]
fn echo_names_the_service_when_nothing_comes() {
    let root = tempfile::tempdir().expect("temp dir for the iceoryx2 root");
    let service = format!("rigslam_quiet_{}/pose", std::process::id());
    let output = Command::new(env!("CARGO_BIN_EXE_rigslam"))
        .args([
            "echo",
            "--service",
            &service,
            "--timeout-s",
            "0.2",
            "--json",
        ])
        .arg("--root-path")
        .arg(root.path())
        .output()
        .expect("run rigslam echo");
    assert!(!output.status.success());
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(
        stderr.contains(&service) && stderr.contains("no sample"),
        "{stderr}"
    );
    assert!(output.stdout.is_empty());
}

/// `--tum` writes the map-frame poses and `--tum-odom` the odometry-frame
/// ones: a publisher whose map->odom transform is a known shift and turn
/// gives two trajectories that differ by exactly that transform.
#[test]
#[allow(non_snake_case)]
fn echo_writes_the_map_and_odometry_frames_side_by_side() {
    use nalgebra::{Translation3, UnitQuaternion, Vector3};
    const COUNT: u64 = 30;
    let (root, config) = private_ipc("odom");
    let T_world_odom = Isometry3::from_parts(
        Translation3::new(0.4, -0.2, 0.05),
        UnitQuaternion::from_axis_angle(&Vector3::z_axis(), 0.3),
    );
    let stop = Arc::new(AtomicBool::new(false));
    let publisher = publish_until_stopped(&config, &stop, move |k| {
        // A body moving along a line, seen in the odometry frame.
        let T_odom_body = Isometry3::translation(0.01 * k as f64, 0.002 * k as f64, 1.0);
        PoseMessage::new(
            1_000_000_000 + k * 50_000_000,
            TrackingState::Tracking,
            &(T_world_odom * T_odom_body),
        )
        .with_odometry(&T_odom_body, &T_world_odom)
    });
    let dir = tempfile::tempdir().expect("temp dir");
    let (map_tum, odom_tum) = (dir.path().join("map.tum"), dir.path().join("odom.tum"));
    let output = Command::new(env!("CARGO_BIN_EXE_rigslam"))
        .args(["echo", "--service"])
        .arg(format!("{}/pose", config.service_prefix))
        .args(["--count", &COUNT.to_string(), "--timeout-s", "30", "--json"])
        .arg("--root-path")
        .arg(root.path())
        .arg("--tum")
        .arg(&map_tum)
        .arg("--tum-odom")
        .arg(&odom_tum)
        .output()
        .expect("run rigslam echo");
    stop.store(true, Ordering::Relaxed);
    publisher.join().expect("publisher thread");
    assert!(
        output.status.success(),
        "rigslam echo failed: {}",
        String::from_utf8_lossy(&output.stderr)
    );
    let map = rigslam::dataset::read_tum(&map_tum).expect("the map-frame file");
    let odom = rigslam::dataset::read_tum(&odom_tum).expect("the odometry-frame file");
    assert_eq!(map.len(), COUNT as usize);
    assert_eq!(odom.len(), COUNT as usize);
    for (m, o) in map.poses.iter().zip(&odom.poses) {
        assert_eq!(m.t_ns, o.t_ns);
        let T_world_body = T_world_odom * o.T_world_body;
        let off = (T_world_body.translation.vector - m.position()).norm();
        assert!(
            off < 1e-6,
            "map pose {m:?} vs odom pose through the transform {o:?}"
        );
        // And the two frames really differ.
        assert!((m.position() - o.position()).norm() > 0.1);
    }
}

/// `rigslam echo | head -n 3`: when the reader of its lines goes away,
/// echo stops quietly with success (no panic on the closed pipe) and
/// still writes the `--tum` file of what it received.
#[test]
fn echo_stops_quietly_when_its_output_is_closed() {
    use std::io::{BufRead, BufReader};
    use std::process::Stdio;
    let (root, config) = private_ipc("pipe");
    let stop = Arc::new(AtomicBool::new(false));
    let publisher = publish_until_stopped(&config, &stop, move |k| {
        PoseMessage::new(
            1_000_000_000 + k * 50_000_000,
            TrackingState::Tracking,
            &Isometry3::translation(0.01 * k as f64, 0.0, 0.0),
        )
    });
    let dir = tempfile::tempdir().expect("temp dir");
    let tum = dir.path().join("poses.tum");
    // Until the stream goes quiet: only the closed pipe can end it early.
    let mut child = Command::new(env!("CARGO_BIN_EXE_rigslam"))
        .args(["echo", "--service"])
        .arg(format!("{}/pose", config.service_prefix))
        .args(["--timeout-s", "30"])
        .arg("--root-path")
        .arg(root.path())
        .arg("--tum")
        .arg(&tum)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("start rigslam echo");
    let mut lines = BufReader::new(child.stdout.take().expect("piped stdout")).lines();
    for _ in 0..3 {
        let line = lines.next().expect("a line").expect("UTF-8 line");
        assert!(line.starts_with('#'), "{line}");
    }
    drop(lines);
    let output = child.wait_with_output().expect("rigslam echo ends");
    stop.store(true, Ordering::Relaxed);
    let sent = publisher.join().expect("publisher thread");
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(output.status.success(), "rigslam echo failed: {stderr}");
    assert!(!stderr.contains("panicked"), "{stderr}");
    let poses = rigslam::dataset::read_tum(&tum).expect("the --tum file");
    assert!(
        poses.len() >= 3 && poses.len() as u64 <= sent,
        "{} poses written, {sent} sent",
        poses.len()
    );
}
