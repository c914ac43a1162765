//! Publish -> receive latency between two processes (target: p99
//! under 100 us), at the IMU rate of `pose_fast` (10 kHz) and at a camera
//! rate (20 Hz).
//!
//! This process publishes `PoseMessage`s at a fixed rate; a `rigslam echo
//! --json` child subscribes, blocks on the event service, and measures
//! `now - published_t_ns` on CLOCK_MONOTONIC for every sample. Not a
//! criterion bench: the quantity is a latency distribution at a paced rate,
//! not the time of a loop body.
//!
//! `cargo bench -p rigslam --bench publish` (add `-- --quick` for a short
//! run, `-- --spin` to pace the publisher by spinning instead of sleeping).
//! Prints one JSON object per rate.

use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use nalgebra::Isometry3;
use rigslam::publish::{IpcConfig, PoseMessage, PosePublisher};
use rigslam::relative::types::TrackingState;
use rigslam::sensors::yei::device::host_monotonic_ns;

/// Publishes on `<prefix>/pose_fast` at `rate_hz` until the echo child has
/// received `count` samples; returns echo's report plus what was sent.
fn run(rate_hz: f64, count: u64, spin: bool) -> serde_json::Value {
    let root = tempfile::tempdir().expect("temp dir for the iceoryx2 root");
    let config = IpcConfig {
        service_prefix: format!("rigslam_bench_{}_{}", std::process::id(), rate_hz as u64),
        root_path: Some(root.path().to_path_buf()),
        group: None,
    };
    let mut publisher = PosePublisher::open(&config).expect("publisher");
    let mut echo = Command::new(env!("CARGO_BIN_EXE_rigslam"))
        .args(["echo", "--service"])
        .arg(format!("{}/pose_fast", config.service_prefix))
        .args(["--count", &count.to_string(), "--timeout-s", "10", "--json"])
        .arg("--root-path")
        .arg(root.path())
        .stdout(Stdio::piped())
        .spawn()
        .expect("start rigslam echo");
    let period = Duration::from_secs_f64(1.0 / rate_hz);
    let start = Instant::now();
    let mut sent = 0u64;
    let mut next = start;
    // How long publish() itself takes (copy into shared memory + notify),
    // to tell the sender's share of the latency from the wake-up's.
    let mut publish_call_us = Vec::new();
    loop {
        if echo.try_wait().expect("poll echo").is_some() {
            break;
        }
        let msg = PoseMessage::new(
            host_monotonic_ns(),
            TrackingState::Tracking,
            &Isometry3::identity(),
        );
        let before = Instant::now();
        publisher.publish_fast(&msg).expect("publish");
        publish_call_us.push(before.elapsed().as_secs_f64() * 1e6);
        sent += 1;
        next += period;
        // Absolute deadlines, so the mean rate holds when a sleep
        // overshoots. Sleeping only is how a driver thread blocked on its
        // read behaves; spinning the last 200 us gives a steadier rate but
        // takes a core from the subscriber on this 2-core machine.
        let margin = if spin {
            Duration::from_micros(200)
        } else {
            Duration::ZERO
        };
        loop {
            let now = Instant::now();
            if now >= next {
                break;
            }
            let left = next - now;
            if left > margin {
                std::thread::sleep(left - margin);
            } else {
                std::hint::spin_loop();
            }
        }
    }
    let elapsed_s = start.elapsed().as_secs_f64();
    let output = echo.wait_with_output().expect("echo output");
    assert!(output.status.success(), "rigslam echo failed");
    let mut report: serde_json::Value =
        serde_json::from_slice(&output.stdout).expect("echo prints one JSON object");
    report["target_rate_hz"] = rate_hz.into();
    report["publisher_spins"] = spin.into();
    publish_call_us.sort_by(f64::total_cmp);
    let at = |q: f64| {
        publish_call_us
            [((q * publish_call_us.len() as f64) as usize).min(publish_call_us.len() - 1)]
    };
    report["publish_call_p50_us"] = at(0.50).into();
    report["publish_call_p99_us"] = at(0.99).into();
    report["sent"] = sent.into();
    report["publish_rate_hz"] = (sent as f64 / elapsed_s).into();
    report
}

fn main() {
    let quick = std::env::args().any(|a| a == "--quick");
    let spin = std::env::args().any(|a| a == "--spin");
    // (rate, samples): 10 kHz for 5 s, 20 Hz for 30 s (2 s and 10 s quick).
    let runs = if quick {
        [(10_000.0, 20_000), (20.0, 200)]
    } else {
        [(10_000.0, 50_000), (20.0, 600)]
    };
    for (rate_hz, count) in runs {
        println!("{}", run(rate_hz, count, spin));
    }
}
