//! Faults the daemon must survive, with the real YEI driver against the
//! simulated YEI 3-Space on a pseudo-terminal and the pattern camera: the
//! IMU unplugged and plugged back (status degraded, reconnect, ok again,
//! fast poses resume), and garbage on the serial line (the stream goes
//! on at its rate).

use std::path::PathBuf;
use std::sync::atomic::Ordering;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use rigslam::daemon::config::{CalibrationConfig, CameraSource, DaemonConfig, ImuSource};
use rigslam::daemon::health::is_healthy;
use rigslam::daemon::{check, Pipeline, PoseSink};
use rigslam::publish::{PoseMessage, StatusMessage, HEALTH_IMU_RECONNECTING, HEALTH_IMU_STREAMING};
use rigslam::relative::{RelativeOutput, SensorMode};
use rigslam::sensors::yei::simulated::{Fault, SimConfig, SimulatedYei};
use rigslam::shared_data;

#[derive(Clone, Default)]
struct Count {
    fast: Arc<Mutex<Vec<i64>>>,
}

impl PoseSink for Count {
    fn pose(&mut self, _: &PoseMessage, _: &RelativeOutput) -> bool {
        true
    }
    fn pose_fast(&mut self, m: &PoseMessage) -> bool {
        self.fast.lock().expect("lock").push(m.t_ns);
        true
    }
}

fn live_config(euroc: &std::path::Path, port: PathBuf) -> DaemonConfig {
    let mut config = DaemonConfig::replay(euroc, SensorMode::MonoInertial);
    config.replay = None;
    config.camera.source = CameraSource::Pattern;
    config.camera.rate_hz = Some(20.0);
    config.imu.source = ImuSource::Yei;
    config.imu.port = Some(port.display().to_string());
    config.calibration = Some(CalibrationConfig {
        cameras: vec![euroc.join("mav0/cam0/sensor.yaml")],
        imu: Some(euroc.join("mav0/imu0/sensor.yaml")),
        folder: None,
        imu_intrinsics: None,
    });
    config
}

/// Polls the status every 200 ms until `want` holds; returns the statuses seen.
fn wait_status(
    pipeline: &mut Pipeline,
    within: Duration,
    what: &str,
    want: impl Fn(&StatusMessage) -> bool,
) -> Vec<StatusMessage> {
    let deadline = Instant::now() + within;
    let mut seen = Vec::new();
    loop {
        std::thread::sleep(Duration::from_millis(200));
        let s = pipeline.status();
        seen.push(s);
        if want(&s) {
            return seen;
        }
        assert!(
            Instant::now() < deadline,
            "no status with {what} within {within:?}; health bits seen: {:?}",
            seen.iter().map(|s| s.sensor_health).collect::<Vec<_>>()
        );
    }
}

fn start(euroc: &std::path::Path) -> (SimulatedYei, Pipeline, Count) {
    let sim = SimulatedYei::start(SimConfig::default()).expect("simulated YEI");
    let config = live_config(euroc, sim.path().to_path_buf());
    let rig = check(&config, std::path::Path::new("(test)")).expect("valid config");
    let sink = Count::default();
    let pipeline = Pipeline::start(&config, rig, Box::new(sink.clone())).expect("start");
    (sim, pipeline, sink)
}

#[test]
fn imu_unplugged_and_back_degrades_then_recovers() {
    let Some(euroc) = shared_data::path_or_skip("euroc/V1_01_micro") else {
        return;
    };
    let (sim, mut pipeline, sink) = start(&euroc);
    wait_status(&mut pipeline, Duration::from_secs(10), "healthy", |s| {
        is_healthy(s, true)
    });
    sim.inject(Fault::ClosePort {
        reopen_after: Duration::from_millis(1500),
    });
    let degraded = wait_status(&mut pipeline, Duration::from_secs(5), "IMU degraded", |s| {
        !is_healthy(s, true)
    });
    let last = degraded.last().expect("a status");
    assert!(
        last.sensor_health & HEALTH_IMU_STREAMING == 0
            || last.sensor_health & HEALTH_IMU_RECONNECTING != 0,
        "{last:?}"
    );
    let unplugged_at = Instant::now();
    let fast_before = sink.fast.lock().expect("lock").len();
    wait_status(
        &mut pipeline,
        Duration::from_secs(15),
        "healthy again",
        |s| is_healthy(s, true) && s.imu_rate_hz > 100.0,
    );
    assert!(unplugged_at.elapsed() >= Duration::from_millis(500));
    assert!(pipeline.health().imu_reconnects.load(Ordering::Relaxed) >= 1);
    // Estimation output resumes: fast poses at the IMU rate again.
    std::thread::sleep(Duration::from_millis(500));
    let fast_after = sink.fast.lock().expect("lock").len();
    assert!(
        fast_after - fast_before > 80,
        "{} fast poses in the 0.5 s after recovery",
        fast_after - fast_before
    );
    let report = pipeline.stop().expect("stop");
    assert!(report.poses > 0, "{report:?}");
}

#[test]
fn garbage_on_the_serial_line_does_not_stop_the_stream() {
    let Some(euroc) = shared_data::path_or_skip("euroc/V1_01_micro") else {
        return;
    };
    let (sim, mut pipeline, _sink) = start(&euroc);
    wait_status(&mut pipeline, Duration::from_secs(10), "healthy", |s| {
        is_healthy(s, true)
    });
    let imu_before = pipeline.health().imu_in.load(Ordering::Relaxed);
    let started = Instant::now();
    for n in [17, 300, 1, 2048, 64] {
        sim.inject(Fault::Garbage(n));
        sim.inject(Fault::BadChecksum);
        std::thread::sleep(Duration::from_millis(200));
        let s = pipeline.status();
        assert!(is_healthy(&s, true), "after {n} garbage bytes: {s:?}");
    }
    let dt = started.elapsed().as_secs_f64();
    let rate = (pipeline.health().imu_in.load(Ordering::Relaxed) - imu_before) as f64 / dt;
    assert!(rate > 180.0, "IMU at {rate:.0} Hz with garbage on the line");
    assert!(sim.stats().garbage_bytes >= 2430);
    // The five packets with a bad checksum are counted as lost samples.
    let s = pipeline.status();
    assert!(s.imu_drops >= 5, "{s:?}");
    assert!(pipeline.health().imu_skipped.load(Ordering::Relaxed) >= 5);
    pipeline.stop().expect("stop");
}
