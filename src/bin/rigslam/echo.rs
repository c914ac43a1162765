//! `rigslam echo`: subscribe to a published stream, print each sample, the
//! measured rate and the latency (`--json` for machines).

use std::io::Write;
use std::path::PathBuf;
use std::time::Duration;

use anyhow::Context;
use rigslam::daemon::health::rate_words;
use rigslam::dataset::write_tum;
use rigslam::publish::{
    IpcConfig, Message, PoseMessage, StatusMessage, Stream, Subscription, DEFAULT_SERVICE_PREFIX,
    MAX_SUBSCRIBER_BUFFER,
};
use rigslam::relative::TrackingState;
use rigslam::sensors::yei::device::host_monotonic_ns;
use rigslam::trajectory::{StampedPose, Trajectory};

#[derive(clap::Args)]
pub struct EchoArgs {
    /// Service to read: a full name (`rigslam/pose`, `rigslam/pose_fast`,
    /// `rigslam/status`, or another prefix) or only the stream
    /// (`pose`, `pose_fast`, `status`) under the `rigslam` prefix. A name
    /// ending in `status` carries status messages, any other poses.
    #[arg(long, default_value = "rigslam/pose")]
    service: String,
    /// Stop after this many samples (0: until the stream goes quiet).
    #[arg(long, default_value_t = 0)]
    count: u64,
    /// Stop when no sample has come for this long, seconds.
    #[arg(long, default_value_t = 10.0)]
    timeout_s: f64,
    /// iceoryx2 root path of the publisher (rigslamd's `publish.root_path`);
    /// iceoryx2's default, /tmp/iceoryx2/, when not given.
    #[arg(long)]
    root_path: Option<PathBuf>,
    /// Print one JSON object at the end and nothing per sample: received,
    /// rate_hz, latency_p50_us, latency_p99_us (now - the message's t_ns on
    /// CLOCK_MONOTONIC, over the latency_samples samples whose stamp is on
    /// this host's clock: a latency from 0 to 60 s; null when none is, as
    /// in a replay, which keeps the recording's stamps),
    /// transport_latency_p50_us, transport_latency_p99_us (now - the
    /// publisher's send time), missed (sequence gaps), service.
    #[arg(long)]
    json: bool,
    /// Print one line per this many samples (the rest are still measured).
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u64).range(1..))]
    every: u64,
    /// Pose streams: also write every received pose that is tracking to
    /// this file as a TUM trajectory (`t[s] tx ty tz qx qy qz qw`), for
    /// `rigslam eval`.
    #[arg(long)]
    tum: Option<PathBuf>,
    /// Pose streams: also write the odometry-frame pose of every tracking
    /// sample (the relative stage's, which a map correction never moves)
    /// to this file as a TUM trajectory. With `--tum`, the two frames side
    /// by side: `rigslam eval` scores each.
    #[arg(long)]
    tum_odom: Option<PathBuf>,
    /// Also write the `--json` object to this file (the per-sample lines
    /// still go to stdout).
    #[arg(long)]
    report: Option<PathBuf>,
    /// Create this (empty) file once subscribed: a script can start the
    /// publisher after it and know the first sample will be seen.
    #[arg(long)]
    ready_file: Option<PathBuf>,
}

#[derive(serde::Serialize)]
struct EchoReport {
    service: String,
    received: u64,
    missed: u64,
    rate_hz: f64,
    /// Over the samples stamped on this host's clock ([`on_host_clock`]);
    /// None (null) when none was (a replay's dataset stamps): that
    /// "latency" would be a clock offset.
    latency_p50_us: Option<f64>,
    latency_p99_us: Option<f64>,
    /// How many samples the latency is over.
    latency_samples: u64,
    transport_latency_p50_us: f64,
    transport_latency_p99_us: f64,
}

/// What was measured per sample.
#[derive(Default)]
struct Measurements {
    receive_t_ns: Vec<i64>,
    latency_us: Vec<f64>,
    transport_latency_us: Vec<f64>,
}

pub fn run(args: EchoArgs) -> anyhow::Result<()> {
    if !(args.timeout_s.is_finite() && args.timeout_s > 0.0) {
        anyhow::bail!(
            "--timeout-s must be a positive number of seconds, got {}",
            args.timeout_s
        );
    }
    let service = if args.service.contains('/') {
        args.service.clone()
    } else {
        let stream = Stream::from_suffix(&args.service).with_context(|| {
            format!(
                "--service {:?}: expected a full service name (prefix/stream) or one of pose, pose_fast, status",
                args.service
            )
        })?;
        stream.service_name(DEFAULT_SERVICE_PREFIX)
    };
    let (prefix, _) = service
        .rsplit_once('/')
        .expect("the name was given or built with a '/'");
    let config = IpcConfig {
        service_prefix: prefix.to_string(),
        root_path: args.root_path.clone(),
        group: None,
    };
    if (args.tum.is_some() || args.tum_odom.is_some()) && service.ends_with("status") {
        anyhow::bail!("--tum and --tum-odom need a pose stream, not {service}");
    }
    let mut tracked = Vec::new();
    let mut tracked_odom = Vec::new();
    let (measured, missed, stdout_closed) = if service.ends_with("status") {
        echo::<StatusMessage>(&args, &config, &service, &mut |m, latency_us, print| {
            if print {
                print_line(&status_line(m, latency_us))?;
            }
            Ok(())
        })?
    } else {
        echo::<PoseMessage>(&args, &config, &service, &mut |m, latency_us, print| {
            if print {
                print_line(&pose_line(m, latency_us))?;
            }
            if m.state() == Some(TrackingState::Tracking) {
                if args.tum.is_some() {
                    tracked.push(StampedPose {
                        t_ns: m.t_ns,
                        T_world_body: m.T_world_body(),
                    });
                }
                if args.tum_odom.is_some() {
                    tracked_odom.push(StampedPose {
                        t_ns: m.t_ns,
                        T_world_body: m.T_odom_body(),
                    });
                }
            }
            Ok(())
        })?
    };
    if let Some(path) = &args.tum {
        write_tum(path, &Trajectory::new(tracked))
            .with_context(|| format!("writing --tum {}", path.display()))?;
    }
    if let Some(path) = &args.tum_odom {
        write_tum(path, &Trajectory::new(tracked_odom))
            .with_context(|| format!("writing --tum-odom {}", path.display()))?;
    }
    if stdout_closed {
        // The reader of the lines went away (`rigslam echo | head`): the
        // files asked for are written, and there is nobody to tell more.
        return Ok(());
    }
    let received = measured.receive_t_ns.len() as u64;
    if received == 0 {
        anyhow::bail!(
            "no sample on {service} within {} s (is rigslamd running, with the same root path?)",
            args.timeout_s
        );
    }
    if args.count > 0 && received < args.count {
        eprintln!(
            "warning: {service} went quiet for {} s after {received} of {} samples",
            args.timeout_s, args.count
        );
    }
    let latency = LatencySummary::of(&measured.latency_us);
    let report = EchoReport {
        service,
        received,
        missed,
        rate_hz: rate_hz(&measured.receive_t_ns),
        latency_p50_us: latency.as_ref().map(|l| l.p50_us),
        latency_p99_us: latency.as_ref().map(|l| l.p99_us),
        latency_samples: latency.as_ref().map_or(0, |l| l.samples),
        transport_latency_p50_us: percentile(&measured.transport_latency_us, 0.50),
        transport_latency_p99_us: percentile(&measured.transport_latency_us, 0.99),
    };
    if let Some(path) = &args.report {
        std::fs::write(path, serde_json::to_string(&report)? + "\n")
            .with_context(|| format!("writing --report {}", path.display()))?;
    }
    let summary = if args.json {
        serde_json::to_string(&report)?
    } else {
        let latency = match &latency {
            Some(l) if l.samples < received => format!(
                "p50 {:.1} us p99 {:.1} us over the {} samples stamped on this host's clock",
                l.p50_us, l.p99_us, l.samples
            ),
            Some(l) => format!("p50 {:.1} us p99 {:.1} us", l.p50_us, l.p99_us),
            None => latency_text(None),
        };
        format!(
            "{}: {} received, {} missed, {:.1} Hz, latency {latency}, transport p50 {:.1} us p99 {:.1} us",
            report.service,
            report.received,
            report.missed,
            report.rate_hz,
            report.transport_latency_p50_us,
            report.transport_latency_p99_us
        )
    };
    match print_line(&summary) {
        Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => Ok(()),
        other => other.context("writing to standard output"),
    }
}

/// One line to standard output; an error (a closed pipe: `| head`) is
/// returned, where `println!` would panic.
fn print_line(line: &str) -> std::io::Result<()> {
    let mut out = std::io::stdout().lock();
    writeln!(out, "{line}")?;
    out.flush()
}

/// Reads samples until `count`, until the stream is quiet for the
/// timeout, or until standard output is closed (`on_sample` returns a
/// broken pipe); returns the measurements, the sequence gaps seen and
/// whether standard output was closed.
fn echo<T: Message>(
    args: &EchoArgs,
    config: &IpcConfig,
    service: &str,
    on_sample: &mut dyn FnMut(&T, f64, bool) -> std::io::Result<()>,
) -> anyhow::Result<(Measurements, u64, bool)> {
    // A large buffer: echo wants every sample, and a gap is reported.
    let mut subscriber = Subscription::<T>::open_service(config, service, MAX_SUBSCRIBER_BUFFER)
        .with_context(|| format!("subscribing to {service}"))?;
    if let Some(path) = &args.ready_file {
        std::fs::write(path, b"")
            .with_context(|| format!("writing the ready file {}", path.display()))?;
    }
    let timeout = Duration::from_secs_f64(args.timeout_s);
    let mut measured = Measurements::default();
    let mut batch = Vec::new();
    'outer: while args.count == 0 || (measured.receive_t_ns.len() as u64) < args.count {
        if !subscriber.wait(timeout)? {
            break;
        }
        batch.clear();
        subscriber.take_all(&mut batch)?;
        let now_ns = host_monotonic_ns();
        for message in &batch {
            let latency_us = (now_ns - message.t_ns()) as f64 / 1e3;
            measured.receive_t_ns.push(now_ns);
            measured.latency_us.push(latency_us);
            measured
                .transport_latency_us
                .push((now_ns - message.published_t_ns()) as f64 / 1e3);
            let n = measured.receive_t_ns.len() as u64;
            let print = !args.json && (n - 1) % args.every == 0;
            match on_sample(message, latency_us, print) {
                Ok(()) => {}
                Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => {
                    return Ok((measured, subscriber.missed(), true));
                }
                Err(e) => return Err(e).context("writing to standard output"),
            }
            if args.count > 0 && measured.receive_t_ns.len() as u64 >= args.count {
                break 'outer;
            }
        }
    }
    Ok((measured, subscriber.missed(), false))
}

fn pose_line(m: &PoseMessage, latency_us: f64) -> String {
    let state = match m.state() {
        Some(s) => format!("{s:?}").to_lowercase(),
        None => format!("state{}", m.tracking_state),
    };
    let [px, py, pz] = m.position_world_m;
    let [qx, qy, qz, qw] = m.orientation_world_body_xyzw;
    let [vx, vy, vz] = m.velocity_world_m_s;
    // With the absolute stage: the relative stage's (odometry) position too.
    let odom = if m.flags & rigslam::publish::POSE_FLAG_MAP_CORRECTED != 0 {
        let [ox, oy, oz] = m.position_odom_m;
        format!(" odom_p=[{ox:.4} {oy:.4} {oz:.4}] m")
    } else {
        String::new()
    };
    format!(
        "#{} t={:.6} s {state} p=[{px:.4} {py:.4} {pz:.4}] m q_xyzw=[{qx:.4} {qy:.4} {qz:.4} {qw:.4}] v=[{vx:.3} {vy:.3} {vz:.3}] m/s{odom} latency={}",
        m.sequence,
        m.t_ns as f64 * 1e-9,
        latency_text(on_host_clock(latency_us)),
    )
}

/// The latency `now - t_ns` when the stamp is on this host's
/// `CLOCK_MONOTONIC`, None when it is not: a replay publishes the
/// recording's stamps (EuRoC's are Unix times of 2014), a simulation its
/// own clock, and their "latency" is a clock offset, negative or of hours
/// or days, that says nothing. The rule: from 0 to 60 s. A stamp on the
/// host clock is never in the future, and no pose worth reading is a
/// minute old; a live daemon's poses are milliseconds old.
fn on_host_clock(latency_us: f64) -> Option<f64> {
    (0.0..MAX_LATENCY_US)
        .contains(&latency_us)
        .then_some(latency_us)
}

/// Beyond this a "latency" is a clock mismatch, us (1 min).
const MAX_LATENCY_US: f64 = 60e6;

/// The latency percentiles over the samples stamped on this host's clock.
#[derive(Debug, PartialEq)]
struct LatencySummary {
    p50_us: f64,
    p99_us: f64,
    samples: u64,
}

impl LatencySummary {
    /// None when no sample's stamp is on this host's clock.
    fn of(latencies_us: &[f64]) -> Option<Self> {
        let on_host: Vec<f64> = latencies_us
            .iter()
            .filter_map(|&l| on_host_clock(l))
            .collect();
        (!on_host.is_empty()).then(|| Self {
            p50_us: percentile(&on_host, 0.50),
            p99_us: percentile(&on_host, 0.99),
            samples: on_host.len() as u64,
        })
    }
}

/// A latency for people, "n/a" with the reason when there is none.
fn latency_text(latency_us: Option<f64>) -> String {
    match latency_us {
        Some(us) => format!("{us:.1} us"),
        None => "n/a (stamps not on this host's clock)".into(),
    }
}

fn status_line(m: &StatusMessage, _latency_us: f64) -> String {
    let queues: Vec<String> = m
        .queues_in_use()
        .iter()
        .map(|q| format!("{} {}/{}", q.name_str(), q.len, q.capacity))
        .collect();
    format!(
        "#{} camera {} imu {} pose {}, drops camera {} imu {} pose {}, latency p50 {:.0} us p99 {:.0} us, health 0x{:x}, noise scale gyro {:.2} accel {:.2} pixel {:.2}, camera-imu {:.3} deg {:.4} m {:+.5} s from the file, queues [{}]",
        m.sequence,
        rate_words(m.camera_rate_hz, 1),
        rate_words(m.imu_rate_hz, 1),
        rate_words(m.pose_rate_hz, 1),
        m.camera_drops,
        m.imu_drops,
        m.pose_drops,
        m.latency_p50_us,
        m.latency_p99_us,
        m.sensor_health,
        m.imu_noise_scale_gyro,
        m.imu_noise_scale_accel,
        m.pixel_noise_scale,
        m.camera_imu_rotation_deg,
        m.camera_imu_translation_m,
        m.camera_imu_time_offset_s,
        queues.join(", ")
    )
}

/// Samples per second between the first and last receipt (0 for fewer
/// than two samples, or all in one wake-up).
fn rate_hz(receive_t_ns: &[i64]) -> f64 {
    match (receive_t_ns.first(), receive_t_ns.last()) {
        (Some(&first), Some(&last)) if last > first => {
            (receive_t_ns.len() - 1) as f64 / ((last - first) as f64 * 1e-9)
        }
        _ => 0.0,
    }
}

/// Nearest-rank percentile, `q` in [0, 1]; 0 for no values.
fn percentile(values: &[f64], q: f64) -> f64 {
    if values.is_empty() {
        return 0.0;
    }
    let mut sorted = values.to_vec();
    sorted.sort_by(f64::total_cmp);
    let rank = (q * sorted.len() as f64).ceil() as usize;
    sorted[rank.clamp(1, sorted.len()) - 1]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nearest_rank_percentiles() {
        let values: Vec<f64> = (1..=100).rev().map(f64::from).collect();
        assert_eq!(percentile(&values, 0.5), 50.0);
        assert_eq!(percentile(&values, 0.99), 99.0);
        assert_eq!(percentile(&[7.0], 0.99), 7.0);
    }

    #[test]
    fn replay_stamps_give_no_latency_number() {
        assert_eq!(latency_text(on_host_clock(12.34)), "12.3 us");
        assert_eq!(on_host_clock(0.0), Some(0.0));
        // A day old (a simulated clock from 0), in the future (a
        // dataset's 2014 Unix stamps against the host's uptime), a
        // minute or more old, no number.
        for latency_us in [86_400e6, -1.4e15, -5.0, 60e6, f64::NAN] {
            assert_eq!(on_host_clock(latency_us), None, "{latency_us}");
        }
        assert!(latency_text(None).starts_with("n/a"));
    }

    /// The percentiles are over the samples stamped on the host clock
    /// only (say a daemon restarted from a replay to the live rig while
    /// echo listened), and there are none without such samples.
    #[test]
    fn latency_percentiles_leave_out_other_clocks() {
        let mixed = [300.0, -1.4e15, 100.0, 86_400e6, 200.0];
        assert_eq!(
            LatencySummary::of(&mixed),
            Some(LatencySummary {
                p50_us: 200.0,
                p99_us: 300.0,
                samples: 3
            })
        );
        assert_eq!(LatencySummary::of(&[-1.4e15, 86_400e6]), None);
        assert_eq!(LatencySummary::of(&[]), None);
    }

    #[test]
    fn rate_over_the_receive_span() {
        // 11 samples over 0.5 s: 10 intervals, 20 Hz.
        let t: Vec<i64> = (0..11).map(|i| i * 50_000_000).collect();
        assert!((rate_hz(&t) - 20.0).abs() < 1e-9);
        assert_eq!(rate_hz(&[5]), 0.0);
    }
}
