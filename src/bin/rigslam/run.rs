//! `rigslam run`: a recorded sequence through the relative stage; the
//! trajectory (TUM), a one-line summary, and a report with per-stage
//! timings and, when the dataset has ground truth, the accuracy.

use std::collections::BTreeMap;
use std::path::PathBuf;

use anyhow::Context;
use indicatif::{ProgressBar, ProgressStyle};
use rigslam::dataset::{
    groundtruth_trajectory, open_dataset, read_trajectory_any, write_tum, Dataset, SensorStream,
    StreamOptions,
};
use rigslam::eval::plot::write_plot;
use rigslam::eval::{evaluate, Alignment, EvalOptions};
use rigslam::relative::{
    build_estimator, EstimatorKind, RelativeConfig, RigModel, SensorMode,
};
use rigslam::run::{resident_memory_mib, run_stream, RunOptions, RunReport};
use rigslam::trajectory::Trajectory;

#[derive(clap::Args)]
pub struct RunArgs {
    /// The sequence: a EuRoC ASL folder (holding mav0/, or mav0 itself) or
    /// a KITTI odometry folder (image_0/ or image_l/ with calib.txt).
    #[arg(long)]
    dataset: PathBuf,
    /// Sensors to use: mono, mono-inertial, stereo, stereo-inertial.
    /// Default: stereo-inertial when the dataset has cam1 and imu0,
    /// mono-inertial with cam0 and imu0 only, mono for KITTI.
    #[arg(long)]
    mode: Option<SensorMode>,
    /// The relative-stage estimator: `window` (the paper's windowed
    /// optimisation) or `ekf` (the paper's EKF baseline).
    #[arg(long, value_enum, default_value_t = EstimatorKind::Window)]
    estimator: EstimatorKind,
    /// Write the body trajectory here (TUM: t[s] tx ty tz qx qy qz qw).
    #[arg(long)]
    trajectory: Option<PathBuf>,
    /// Estimator settings (TOML; see `rigslam run --print-config`).
    #[arg(long)]
    config: Option<PathBuf>,
    /// Print the default settings as TOML and exit.
    #[arg(long)]
    print_config: bool,
    /// Write the JSON report (timings per stage, counts, accuracy) here.
    #[arg(long)]
    report: Option<PathBuf>,
    /// Print the report as one JSON object on stdout instead of the summary.
    #[arg(long)]
    json: bool,
    /// Pace the frames by their stamps instead of running as fast as possible.
    #[arg(long)]
    realtime: bool,
    /// Start at this time into the sequence, s.
    #[arg(long, default_value_t = 0.0)]
    start_s: f64,
    /// Stop after this many frames.
    #[arg(long)]
    max_frames: Option<usize>,
    /// Ground truth to score against (default: the dataset's own, if any).
    #[arg(long)]
    groundtruth: Option<PathBuf>,
    /// Alignment for the accuracy: default se3 for metric modes, sim3 for mono.
    #[arg(long, value_enum)]
    align: Option<Alignment>,
    /// Draw the aligned trajectory and its error (.png or .svg).
    #[arg(long)]
    plot: Option<PathBuf>,
    /// No progress bar.
    #[arg(long)]
    quiet: bool,
}

pub fn run(args: RunArgs) -> anyhow::Result<()> {
    if args.print_config {
        print!("{}", RelativeConfig::default().to_toml()?);
        return Ok(());
    }
    anyhow::ensure!(
        args.start_s.is_finite() && args.start_s >= 0.0,
        "--start-s must be a finite number >= 0, got {}",
        args.start_s
    );
    let config = match &args.config {
        Some(path) => RelativeConfig::from_toml_file(path)?,
        None => RelativeConfig::default(),
    };
    let dataset = open_dataset(&args.dataset)
        .with_context(|| format!("opening the dataset {}", args.dataset.display()))?;
    let rig = rig_of(&dataset);
    let mode = match args.mode {
        Some(m) => m,
        None => default_mode(&rig),
    };
    rig.check(mode)
        .with_context(|| format!("dataset {}", args.dataset.display()))?;
    let mut estimator = build_estimator(args.estimator, mode, &rig, &config)?;

    let first_ns = first_frame_ns(&dataset).context("the dataset lists no frames")?;
    let mut stream = SensorStream::new(
        &dataset,
        StreamOptions {
            stereo: mode.uses_stereo(),
            imu: mode.uses_imu(),
            start_ns: Some(first_ns + (args.start_s * 1e9).round() as i64),
            max_frames: args.max_frames,
        },
    )?;
    let bar = if args.quiet || args.json {
        ProgressBar::hidden()
    } else {
        let bar = ProgressBar::new(stream.frames_listed() as u64);
        bar.set_style(
            ProgressStyle::with_template(
                "{spinner} {elapsed_precise} [{bar:30}] {pos}/{len} frames {per_sec} {msg}",
            )
            .expect("valid template")
            .progress_chars("=> "),
        );
        bar
    };
    let outcome = run_stream(
        &mut stream,
        estimator.as_mut(),
        RunOptions {
            realtime: args.realtime,
        },
        |output| {
            bar.inc(1);
            bar.set_message(format!("{:?}", output.state).to_lowercase());
        },
    )
    .context("reading the dataset")?;
    bar.finish_and_clear();

    if let Some(path) = &args.trajectory {
        if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(dir)
                .with_context(|| format!("creating {}", dir.display()))?;
        }
        write_tum(path, &outcome.trajectory)?;
    }

    let ground_truth = match &args.groundtruth {
        Some(path) => Some(read_trajectory_any(path)?),
        None => dataset_groundtruth(&dataset),
    };
    let align = args.align.unwrap_or(match mode {
        SensorMode::Mono => Alignment::Sim3,
        _ => Alignment::Se3,
    });
    let evaluation = match &ground_truth {
        Some(gt) if outcome.trajectory.len() >= 3 => {
            let options = EvalOptions {
                alignment: align,
                scale_by_path: mode == SensorMode::Mono,
                ..EvalOptions::default()
            };
            match evaluate(&outcome.trajectory, gt, &options) {
                Ok(e) => Some(e),
                Err(e) => {
                    tracing::warn!("no accuracy: {e}");
                    None
                }
            }
        }
        _ => None,
    };
    if let (Some(path), Some(e)) = (&args.plot, &evaluation) {
        write_plot(path, e)?;
    }

    let (frame_stats, stages) = outcome.timing_report();
    let (rss_now, rss_peak) = resident_memory_mib();
    let counters: BTreeMap<String, u64> = estimator
        .counters()
        .into_iter()
        .map(|(k, v)| (k.to_string(), v))
        .collect();
    let sequence_s = outcome.sequence_s();
    let stream_counts = stream.counts();
    let report = RunReport {
        dataset: args.dataset.display().to_string(),
        mode: mode.name().to_string(),
        estimator: args.estimator.name().to_string(),
        frames: stream_counts.frames,
        imu_samples: stream_counts.imu_samples,
        wall_s: outcome.wall_s,
        sequence_s,
        realtime_factor: if outcome.wall_s > 0.0 {
            sequence_s / outcome.wall_s
        } else {
            0.0
        },
        mean_ms_per_frame: frame_stats.map_or(0.0, |s| s.mean_ms),
        p50_ms_per_frame: frame_stats.map_or(0.0, |s| s.p50_ms),
        p99_ms_per_frame: frame_stats.map_or(0.0, |s| s.p99_ms),
        max_ms_per_frame: frame_stats.map_or(0.0, |s| s.max_ms),
        stages,
        initialized_at_s: outcome
            .initialized_at_ns
            .zip(outcome.first_frame_ns)
            .map(|(a, b)| (a - b) as f64 * 1e-9),
        lost_count: outcome.lost_count,
        lost_frames: outcome.lost_frames,
        poses_written: outcome.trajectory.len(),
        stream: stream_counts,
        counters,
        peak_rss_mib: rss_peak,
        rss_at_10pct_mib: outcome.rss_at_10pct_mib,
        rss_at_end_mib: rss_now,
        eval: evaluation.as_ref().map(|e| e.report.clone()),
    };
    if let Some(path) = &args.report {
        let text = serde_json::to_string_pretty(&report).expect("report serialises");
        std::fs::write(path, text + "\n")
            .with_context(|| format!("writing the report {}", path.display()))?;
    }
    if args.json {
        println!(
            "{}",
            serde_json::to_string(&report).expect("report serialises")
        );
    } else {
        println!("{}", summary_line(&report));
    }
    Ok(())
}

/// `mono-inertial 2912 frames in 9.1 s (16.0x real time), 3.1 ms/frame mean, 7.9 ms p99; initialised at 0.0 s, lost 0x; ATE 0.041 m (se3), scale error 0.6 %, final drift 0.31 %`
fn summary_line(r: &RunReport) -> String {
    let mut line = format!(
        "{} ({}) {} frames in {:.1} s ({:.1}x real time), {:.2} ms/frame mean, {:.2} ms p99; ",
        r.mode,
        r.estimator,
        r.frames,
        r.wall_s,
        r.realtime_factor,
        r.mean_ms_per_frame,
        r.p99_ms_per_frame
    );
    match r.initialized_at_s {
        Some(t) => line += &format!("initialised at {t:.2} s, "),
        None => line += "never initialised, ",
    }
    line += &format!("lost {}x, {} poses", r.lost_count, r.poses_written);
    if let Some(e) = &r.eval {
        line += &format!("; ATE {:.3} m ({})", e.ate_rmse_m, e.align.name());
        if let Some(s) = e.scale_error {
            line += &format!(", scale error {:.2} %", 100.0 * s);
        }
        if let Some(d) = e.final_drift_pct {
            line += &format!(", final drift {d:.2} %");
        }
    }
    line
}

fn rig_of(dataset: &Dataset) -> RigModel {
    match dataset {
        Dataset::Euroc(d) => RigModel {
            cameras: d.cameras.iter().map(|c| c.calibration.clone()).collect(),
            imu: d.imu.as_ref().map(|i| i.calibration.clone()),
        },
        Dataset::Kitti(k) => RigModel {
            cameras: vec![k.camera.clone()],
            imu: None,
        },
    }
}

fn default_mode(rig: &RigModel) -> SensorMode {
    match (rig.cameras.len() >= 2, rig.imu.is_some()) {
        (true, true) => SensorMode::StereoInertial,
        (false, true) => SensorMode::MonoInertial,
        (true, false) => SensorMode::Stereo,
        (false, false) => SensorMode::Mono,
    }
}

fn first_frame_ns(dataset: &Dataset) -> Option<i64> {
    match dataset {
        Dataset::Euroc(d) => d.cameras.first()?.frames.first().map(|f| f.t_ns),
        Dataset::Kitti(k) => k.frames.first().map(|f| f.t_ns),
    }
}

fn dataset_groundtruth(dataset: &Dataset) -> Option<Trajectory> {
    match dataset {
        Dataset::Euroc(d) => d.groundtruth.as_deref().map(groundtruth_trajectory),
        Dataset::Kitti(k) => k.groundtruth.clone(),
    }
}
