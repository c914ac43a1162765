//! `rigslam imu`: read a YEI 3-Space, print its identity, the measured rate,
//! timing jitter and error counters (`--json` for machines).

use std::time::{Duration, Instant};

use std::collections::BTreeMap;

use anyhow::Context;
use rigslam::recording::McapRecorder;
use rigslam::sensors::yei::device::{YeiConfig, YeiDevice, YeiSample};
use rigslam::sensors::yei::simulated::{SimConfig, SimulatedYei};

#[derive(clap::Args)]
pub struct ImuArgs {
    /// Serial device of the sensor, e.g. /dev/ttyACM0.
    #[arg(long, required_unless_present = "simulate")]
    port: Option<String>,
    /// Line speed (the YEI factory default is 115200).
    #[arg(long, default_value_t = 115_200)]
    baud: u32,
    /// Streaming rate to configure, Hz.
    #[arg(long, default_value_t = 200.0)]
    rate_hz: f64,
    /// How long to read, seconds.
    #[arg(long, default_value_t = 5.0)]
    seconds: f64,
    /// Print one JSON object: serial, firmware, samples, rate_hz, jitter_us
    /// (standard deviation of the intervals between host stamps),
    /// checksum_errors, resyncs, drops, gyro_mean_rad_s, accel_mean_m_s2.
    #[arg(long)]
    json: bool,
    /// Serve a simulated sensor on a pseudo-terminal and read that instead
    /// of hardware (no --port needed).
    #[arg(long, conflicts_with = "port")]
    simulate: bool,
    /// Record the samples to this MCAP file (channel /imu0).
    #[arg(long)]
    record: Option<std::path::PathBuf>,
}

#[derive(serde::Serialize)]
struct ImuReport {
    port: String,
    serial: String,
    firmware: String,
    samples: u64,
    rate_hz: f64,
    jitter_us: f64,
    receipt_jitter_us: f64,
    checksum_errors: u64,
    resyncs: u64,
    drops: u64,
    wraps: u64,
    reconnects: u64,
    queue_overflows: u64,
    gyro_mean_rad_s: [f64; 3],
    accel_mean_m_s2: [f64; 3],
}

fn interval_std_us(stamps_ns: &[i64]) -> f64 {
    if stamps_ns.len() < 3 {
        return 0.0;
    }
    let d: Vec<f64> = stamps_ns
        .windows(2)
        .map(|w| (w[1] - w[0]) as f64 * 1e-3)
        .collect();
    let mean = d.iter().sum::<f64>() / d.len() as f64;
    (d.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (d.len() - 1) as f64).sqrt()
}

pub fn run(args: ImuArgs) -> anyhow::Result<()> {
    anyhow::ensure!(
        args.rate_hz > 0.0 && args.rate_hz <= 10_000.0,
        "--rate-hz must be in (0, 10000], got {}",
        args.rate_hz
    );
    anyhow::ensure!(
        args.seconds > 0.0,
        "--seconds must be positive, got {}",
        args.seconds
    );
    let sim = if args.simulate {
        Some(SimulatedYei::start(SimConfig::default()).context("starting the simulated YEI")?)
    } else {
        None
    };
    let port = match (&sim, &args.port) {
        (Some(sim), _) => sim.path().to_string_lossy().into_owned(),
        (None, Some(p)) => p.clone(),
        (None, None) => anyhow::bail!("--port DEV or --simulate is needed"),
    };
    let mut config = YeiConfig::new(port.clone());
    config.baud = args.baud;
    config.interval_us = (1e6 / args.rate_hz).round() as u32;
    let device =
        YeiDevice::open(config).with_context(|| format!("opening the YEI 3-Space on {port}"))?;
    let identity = device.identity().clone();
    if !args.json {
        println!(
            "YEI 3-Space serial {} firmware {} on {port} at {} baud; reading {:.1} s at {} Hz",
            identity.serial_hex(),
            identity.firmware,
            args.baud,
            args.seconds,
            args.rate_hz
        );
    }
    let mut recorder = match &args.record {
        Some(path) => {
            let mut rec = McapRecorder::create(path, rigslam::recording::Compression::Zstd)?;
            let meta = BTreeMap::from([
                ("device".to_string(), "YEI 3-Space".to_string()),
                ("serial".to_string(), identity.serial_hex()),
                ("firmware".to_string(), identity.firmware.clone()),
                ("port".to_string(), port.clone()),
            ]);
            let channel = rec.add_imu_channel("/imu0", &meta)?;
            Some((rec, channel))
        }
        None => None,
    };
    let mut samples: Vec<YeiSample> = Vec::new();
    let start = Instant::now();
    let until = start + Duration::from_secs_f64(args.seconds);
    while Instant::now() < until {
        if let Some(s) = device.recv_timeout(Duration::from_millis(20)) {
            if let Some((rec, channel)) = &mut recorder {
                rec.write_imu(*channel, &s.imu, s.receipt_t_ns)?;
            }
            samples.push(s);
        }
    }
    let stats = device.close();
    if let Some((rec, _)) = recorder {
        let path = rec.finish()?;
        if !args.json {
            println!("recorded {} samples to {}", samples.len(), path.display());
        }
    }
    anyhow::ensure!(
        !samples.is_empty(),
        "no IMU samples from {port} in {:.1} s although the handshake worked; check the cable and the stream rate",
        args.seconds
    );
    let n = samples.len() as f64;
    let mean = |f: &dyn Fn(&YeiSample) -> [f64; 3]| {
        let mut m = [0.0; 3];
        for s in &samples {
            for (acc, v) in m.iter_mut().zip(f(s)) {
                *acc += v / n;
            }
        }
        m
    };
    let span_s = match (samples.first(), samples.last()) {
        (Some(a), Some(b)) if b.sensor_t_us > a.sensor_t_us => {
            (b.sensor_t_us - a.sensor_t_us) as f64 * 1e-6
        }
        _ => 0.0,
    };
    let stamps: Vec<i64> = samples.iter().map(|s| s.imu.t_ns).collect();
    let receipts: Vec<i64> = samples.iter().map(|s| s.receipt_t_ns).collect();
    let report = ImuReport {
        port,
        serial: identity.serial_hex(),
        firmware: identity.firmware,
        samples: samples.len() as u64,
        rate_hz: if span_s > 0.0 {
            (n - 1.0) / span_s
        } else {
            0.0
        },
        jitter_us: interval_std_us(&stamps),
        receipt_jitter_us: interval_std_us(&receipts),
        checksum_errors: stats.checksum_errors,
        resyncs: stats.resyncs,
        drops: stats.drops,
        wraps: stats.wraps,
        reconnects: stats.reconnects,
        queue_overflows: stats.queue_overflows,
        gyro_mean_rad_s: mean(&|s| s.imu.gyro_rad_s),
        accel_mean_m_s2: mean(&|s| s.imu.accel_m_s2),
    };
    if args.json {
        println!("{}", serde_json::to_string(&report)?);
    } else {
        println!(
            "{} samples, {:.2} Hz (sensor clock), jitter {:.1} us (host stamps), {:.1} us (receipt)",
            report.samples, report.rate_hz, report.jitter_us, report.receipt_jitter_us
        );
        println!(
            "checksum errors {}, resyncs {}, drops {}, wraps {}, reconnects {}, queue overflows {}",
            report.checksum_errors,
            report.resyncs,
            report.drops,
            report.wraps,
            report.reconnects,
            report.queue_overflows
        );
        let [gx, gy, gz] = report.gyro_mean_rad_s;
        let [ax, ay, az] = report.accel_mean_m_s2;
        println!(
            "mean gyro [{gx:.5} {gy:.5} {gz:.5}] rad/s, mean accel [{ax:.4} {ay:.4} {az:.4}] m/s^2"
        );
    }
    Ok(())
}
