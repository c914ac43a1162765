//! `rigslamd`: the rig's daemon. Reads the camera and the IMU (or a
//! recording), runs the SLAM stages, publishes poses over iceoryx2, talks
//! to systemd. See `rigslam::daemon` for the pipeline and src/publish/README.md
//! for what it publishes.

mod heap;
mod notify;
mod report;
mod signals;

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::Context;
use clap::Parser;
use rigslam::daemon::config::ReplayPace;
use rigslam::daemon::health::{health_words, is_healthy, rate_words};
use rigslam::daemon::{check, DaemonConfig, IpcSink, Pipeline};
use rigslam::publish::{cleanup_dead_nodes, PosePublisher};
use rigslam::relative::SensorMode;

use notify::Notifier;
use signals::{Signal, Signals};

#[derive(Parser)]
#[command(
    name = "rigslamd",
    version,
    about = "rigslam daemon: sensors -> SLAM -> poses over shared memory"
)]
struct Args {
    /// The daemon's config (TOML), e.g. /etc/rigslam/rig.toml.
    #[arg(long, conflicts_with = "replay")]
    config: Option<PathBuf>,
    /// Validate the config and the calibration files it names, print
    /// every problem (file: key: why), exit 0 when all is well, 1 otherwise.
    #[arg(long)]
    check_config: bool,
    /// Shorthand without a config file: replay this EuRoC folder or MCAP
    /// recording (with the calibration recorded in it).
    #[arg(long)]
    replay: Option<PathBuf>,
    /// With --replay: the SLAM mode (the richest the dataset allows by default).
    #[arg(long, requires = "replay")]
    mode: Option<SensorMode>,
    /// Replay as fast as the SLAM stage goes (overrides the config's pace).
    #[arg(long)]
    as_fast_as_possible: bool,
    /// Overrides `publish.service_prefix`.
    #[arg(long)]
    service_prefix: Option<String>,
    /// Overrides `publish.root_path` (iceoryx2's root directory).
    #[arg(long)]
    root_path: Option<PathBuf>,
    /// Overrides `recording`: record to this folder.
    #[arg(long)]
    record: Option<PathBuf>,
    /// At exit, write a JSON report (counts, latencies, CPU) to this file.
    #[arg(long)]
    report: Option<PathBuf>,
    /// Overrides `viewer`: serve the live view for Foxglove on this address
    /// and port (e.g. 127.0.0.1:8765; port 0 picks a free one, logged).
    #[arg(long, value_name = "ADDR:PORT")]
    viewer: Option<String>,
    /// Rewrite a recording cut short (power loss, SIGKILL) or damaged as a
    /// closed, indexed MCAP file with everything it still holds, then
    /// exit. The original is left as it is; the new file goes beside it
    /// as NAME.repaired.mcap (or to --repair-to).
    #[arg(long, value_name = "MCAP", conflicts_with_all = ["config", "replay", "check_config"])]
    repair: Option<PathBuf>,
    /// With --repair: where the repaired file goes.
    #[arg(long, value_name = "MCAP", requires = "repair")]
    repair_to: Option<PathBuf>,
}

fn main() -> std::process::ExitCode {
    let one_arena = heap::one_arena();
    rigslam::console::init_logging();
    if !one_arena {
        tracing::debug!("the C library kept its own malloc arenas");
    }
    let args = Args::parse();
    match run(args) {
        Ok(code) => code,
        Err(e) => {
            eprintln!("rigslamd: {}", rigslam::console::error_chain(&e));
            std::process::ExitCode::FAILURE
        }
    }
}

/// `--repair`: what the file held, what was lost, where the new one is.
fn repair(
    source: &std::path::Path,
    target: Option<&std::path::Path>,
) -> anyhow::Result<std::process::ExitCode> {
    let target = target.map_or_else(
        || rigslam::recording::repair::repaired_name(source),
        std::path::Path::to_path_buf,
    );
    let done = rigslam::recording::repair::repair(source, &target)?;
    println!("{}: {}", source.display(), done.source.end);
    for skipped in &done.source.skipped {
        println!("  skipped: {skipped}");
    }
    let total: u64 = done.messages.values().sum();
    println!(
        "recovered {total} messages and {} attachment(s):",
        done.attachments
    );
    for (topic, n) in &done.messages {
        println!("  {topic}: {n}");
    }
    println!("wrote {}", done.path.display());
    Ok(std::process::ExitCode::SUCCESS)
}

fn load(args: &Args) -> anyhow::Result<(DaemonConfig, PathBuf)> {
    let (mut config, file) = match (&args.config, &args.replay) {
        (Some(path), _) => (DaemonConfig::load(path)?, path.clone()),
        (None, Some(dataset)) => {
            let mode = match args.mode {
                Some(m) => m,
                None if rigslam::recording::is_mcap(dataset) => {
                    // The modes the recorded calibration serves, richest first.
                    match rigslam::recording::rig_of_recording(dataset)? {
                        Some(rig) => rigslam::run::dataset_run::default_mode(&rig),
                        None => anyhow::bail!(
                            "{} carries no calibration: replay it with --config and the rig's [calibration] files",
                            dataset.display()
                        ),
                    }
                }
                None => {
                    let d = rigslam::dataset::open_dataset(dataset)?;
                    rigslam::run::dataset_run::default_mode(&rigslam::run::dataset_run::rig_of(&d))
                }
            };
            (
                DaemonConfig::replay(dataset, mode),
                PathBuf::from("(--replay)"),
            )
        }
        (None, None) => anyhow::bail!("give --config FILE or --replay DATASET"),
    };
    if args.as_fast_as_possible {
        if let Some(r) = config.replay.as_mut() {
            r.pace = ReplayPace::AsFastAsPossible;
        }
    }
    if let Some(p) = &args.service_prefix {
        config.publish.service_prefix = p.clone();
    }
    if let Some(p) = &args.root_path {
        config.publish.root_path = Some(p.clone());
    }
    if let Some(dir) = &args.record {
        config.recording.enabled = true;
        config.recording.dir = dir.clone();
    }
    if let Some(listen) = &args.viewer {
        config.viewer.enabled = true;
        config.viewer.listen = listen.clone();
    }
    Ok((config, file))
}

fn run(args: Args) -> anyhow::Result<std::process::ExitCode> {
    if let Some(source) = &args.repair {
        return repair(source, args.repair_to.as_deref());
    }
    let (config, file) = load(&args)?;
    let rig = match check(&config, &file) {
        Ok(rig) => rig,
        Err(problems) => {
            for p in &problems {
                eprintln!("{p}");
            }
            eprintln!(
                "rigslamd: {} problem(s) in {}",
                problems.len(),
                file.display()
            );
            return Ok(std::process::ExitCode::FAILURE);
        }
    };
    if args.check_config {
        println!(
            "{}: ok ({} camera(s), {}, mode {})",
            file.display(),
            rig.cameras.len(),
            if rig.imu.is_some() { "IMU" } else { "no IMU" },
            config.slam.mode
        );
        return Ok(std::process::ExitCode::SUCCESS);
    }

    // Before any thread exists, so that every thread inherits the mask.
    let signals = Signals::block().context("blocking SIGTERM/SIGINT/SIGHUP")?;
    let notifier = Notifier::from_env();
    let watchdog = notify::watchdog_period();

    if let Some(root) = &config.publish.root_path {
        std::fs::create_dir_all(root)
            .with_context(|| format!("creating publish.root_path {}", root.display()))?;
    }
    match cleanup_dead_nodes(&config.publish) {
        Ok((0, 0)) => {}
        Ok((cleaned, failed)) => tracing::info!(
            "iceoryx2: removed the stale resources of {cleaned} dead process(es){}",
            if failed > 0 {
                format!(", {failed} could not be removed")
            } else {
                String::new()
            }
        ),
        Err(e) => tracing::warn!("iceoryx2 cleanup of dead processes: {e}"),
    }
    let publisher =
        PosePublisher::open(&config.publish).context("opening the iceoryx2 services")?;
    let group = publisher.group_name().unwrap_or("?").to_string();
    let (pose, pose_fast, mut status_publisher, node) = publisher.split();
    tracing::info!(
        "publishing {}, {} and {} to the daemon's user and group {group}",
        pose.service_name(),
        pose_fast.service_name(),
        status_publisher.service_name()
    );

    let started = Instant::now();
    let cpu_at_start = report::cpu_seconds();
    let mut pipeline = Pipeline::start(&config, rig, Box::new(IpcSink { pose, pose_fast }))?;
    let uses_imu = config.slam.mode.uses_imu();
    let status_period = Duration::from_secs_f64(config.pipeline.status_period_s);
    // Ping the watchdog at least twice per period systemd asked for.
    let tick = watchdog
        .map_or(status_period, |w| (w / 4).min(status_period))
        .min(Duration::from_millis(250));
    let mut next_status = Instant::now() + status_period;
    let mut ready = false;
    let mut was_stuck = false;
    let mut was_healthy = None;
    loop {
        match signals.wait(tick) {
            Some(Signal::Stop) => {
                tracing::info!("stop requested (SIGTERM/SIGINT)");
                break;
            }
            Some(Signal::Reload) => {
                notifier.reloading();
                reload(&args, &mut pipeline);
                notifier.ready("calibration reloaded");
            }
            None => {}
        }
        let stuck = pipeline.stuck();
        if stuck != was_stuck {
            if stuck {
                tracing::error!(
                    "the SLAM stage made no progress for {} s; the watchdog is no longer pinged",
                    config.pipeline.stuck_after_s
                );
            } else {
                tracing::info!("the SLAM stage is making progress again");
            }
            was_stuck = stuck;
        }
        if !stuck && watchdog.is_some() {
            notifier.watchdog();
        }
        if Instant::now() >= next_status {
            next_status += status_period;
            let status = pipeline.status();
            let words = health_words(status.sensor_health);
            let mut line = format!(
                "camera {}, imu {}, pose {}, latency p50 {:.1} ms p99 {:.1} ms, drops {}/{}; {words}",
                rate_words(status.camera_rate_hz, 1),
                rate_words(status.imu_rate_hz, 0),
                rate_words(status.pose_rate_hz, 1),
                status.latency_p50_us * 1e-3,
                status.latency_p99_us * 1e-3,
                status.camera_drops,
                status.imu_drops
            );
            if status.imu_noise_scale_gyro.is_finite() {
                line += &format!(
                    "; noise weighed {:.1}x gyro, {:.1}x accel, {:.2}x pixel as declared",
                    status.imu_noise_scale_gyro,
                    status.imu_noise_scale_accel,
                    status.pixel_noise_scale
                );
            }
            if status.camera_imu_rotation_deg.is_finite() {
                line += &format!(
                    "; camera-imu {:.2} deg, {:.1} mm, {:+.2} ms from the calibration file",
                    status.camera_imu_rotation_deg,
                    status.camera_imu_translation_m * 1e3,
                    status.camera_imu_time_offset_s * 1e3
                );
            }
            if let Some(waiting) = pipeline.health().waiting_words() {
                line += &format!("; {waiting}");
            } else if let Some(map) = pipeline.health().map_words() {
                line += &format!("; {map}");
            }
            if let Err(e) = status_publisher.publish(&status) {
                tracing::warn!("{e}");
            }
            // Connection segments of subscribers that joined meanwhile.
            if let Err(e) = node.narrow_new_files() {
                tracing::warn!("{e}");
            }
            let healthy = is_healthy(&status, uses_imu);
            if !ready && healthy {
                // Sensors stream and the pipeline runs.
                notifier.ready(&line);
                ready = true;
                tracing::info!("ready: {line}");
            } else {
                notifier.status(&line);
            }
            if was_healthy != Some(healthy) {
                if healthy {
                    tracing::info!("status ok: {line}");
                } else {
                    tracing::warn!("status degraded: {line}");
                }
                was_healthy = Some(healthy);
            }
        }
        if pipeline.finished() {
            tracing::info!("the input has ended");
            break;
        }
    }
    notifier.stopping();
    let report = pipeline.stop()?;
    let wall_s = started.elapsed().as_secs_f64();
    let cpu_s = report::cpu_seconds() - cpu_at_start;
    tracing::info!(
        "stopped: {} frames, {} poses, {} fast poses, latency p50 {:.0} us p99 {:.0} us, CPU {:.2} s over {:.2} s",
        report.frames,
        report.poses,
        report.poses_fast,
        report.latency_p50_us,
        report.latency_p99_us,
        cpu_s,
        wall_s
    );
    for r in &report.recordings {
        tracing::info!("recording closed: {}", r.display());
    }
    if let Some(path) = &args.report {
        report::write(path, &report, wall_s, cpu_s)?;
    }
    if report.source_failed {
        // The error itself was logged where it happened.
        eprintln!("rigslamd: the replay stopped on an error before the end of its input");
        return Ok(std::process::ExitCode::FAILURE);
    }
    Ok(std::process::ExitCode::SUCCESS)
}

/// SIGHUP: read the config's calibration again; on any problem keep the
/// running one and log why.
fn reload(args: &Args, pipeline: &mut Pipeline) {
    let loaded = load(args);
    let (config, file) = match loaded {
        Ok(c) => c,
        Err(e) => {
            tracing::error!(
                "reload refused, keeping the running calibration: {}",
                rigslam::console::error_chain(&e)
            );
            return;
        }
    };
    match check(&config, Path::new(&file)) {
        Ok(rig) => {
            tracing::info!("reloading the calibration from {}", file.display());
            pipeline.reload(rig);
        }
        Err(problems) => {
            for p in problems {
                tracing::error!("reload refused, keeping the running calibration: {p}");
            }
        }
    }
}
