//! `rigslam demo`: the README's first command. Renders a synthetic EuRoC
//! sequence (stereo images, IMU with EuRoC's noise, ground truth), runs
//! the relative stage on it in the stereo-inertial and mono-inertial
//! modes exactly as `rigslam run` does, and scores both; then, when
//! ../shared/data is beside the repository, does the same on real
//! recordings: EuRoC V1_01 at rest (static start, drift) and KITTI seq_a
//! (mono). Every number printed is measured on this run.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{bail, Context};
use serde::Serialize;

use rigslam::dataset::write_tum;
use rigslam::eval::plot::write_plot;
use rigslam::relative::SensorMode;
use rigslam::run::dataset_run::{run_dataset, summary_line, DatasetRun};
use rigslam::run::RunReport;
use rigslam::simulate::{simulate, SimConfig, SimReport};

#[derive(clap::Args)]
pub struct DemoArgs {
    /// Folder for the generated dataset, the estimates and the plots.
    #[arg(long, default_value = "out/demo")]
    out: PathBuf,
    /// Length of the generated sequence, s.
    #[arg(long, default_value_t = 20.0)]
    duration_s: f64,
    /// Seed of the scene, textures and IMU noise.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// The real recordings (../shared/data); skipped when missing.
    #[arg(long, default_value = "../shared/data")]
    real_data: PathBuf,
    /// Print one JSON object instead of the human summary.
    #[arg(long)]
    json: bool,
}

#[derive(Serialize)]
struct DemoReport {
    dataset: PathBuf,
    simulation: SimReport,
    simulate_s: f64,
    runs: Vec<RunReport>,
}

pub fn run(args: DemoArgs) -> anyhow::Result<()> {
    if !(args.duration_s.is_finite() && args.duration_s >= 3.0) {
        bail!("--duration-s must be at least 3 s, got {}", args.duration_s);
    }
    let dataset_dir = args.out.join("sequence");
    if dataset_dir.exists() {
        std::fs::remove_dir_all(&dataset_dir)
            .with_context(|| format!("cannot clear {}", dataset_dir.display()))?;
    }
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("cannot create {}", args.out.display()))?;
    let config = SimConfig {
        duration_s: Some(args.duration_s),
        seed: args.seed,
        stereo: true,
        show_progress: !args.json,
        ..SimConfig::default()
    };
    let started = Instant::now();
    let simulation = simulate(&config, &dataset_dir).context("simulating the demo sequence")?;
    let simulate_s = started.elapsed().as_secs_f64();
    if !args.json {
        println!(
            "rigslam demo: rendered {} stereo frames ({:.0} s, {:.1} m path) with EuRoC's calibration and IMU noise in {:.1} s",
            simulation.frames, simulation.duration_s, simulation.path_length_m, simulate_s
        );
    }

    let mut jobs: Vec<(String, PathBuf, SensorMode)> = vec![
        (
            "synthetic".into(),
            dataset_dir.clone(),
            SensorMode::StereoInertial,
        ),
        (
            "synthetic".into(),
            dataset_dir.clone(),
            SensorMode::MonoInertial,
        ),
    ];
    let euroc = args.real_data.join("euroc/V1_01_micro");
    let kitti = args.real_data.join("kitti/seq_a");
    if euroc.is_dir() {
        jobs.push((
            "real EuRoC V1_01, at rest".into(),
            euroc,
            SensorMode::StereoInertial,
        ));
    }
    if kitti.is_dir() {
        jobs.push(("real KITTI seq_a".into(), kitti, SensorMode::Mono));
    }
    if jobs.len() == 2 && !args.json {
        println!(
            "({} is missing: the real recordings are skipped)",
            args.real_data.display()
        );
    }
    let mut runs = Vec::new();
    for (label, dir, mode) in jobs {
        let run = DatasetRun {
            mode: Some(mode),
            ..DatasetRun::default()
        };
        let result = run_dataset(&dir, &run, |_, _| {})
            .with_context(|| format!("running {mode} on {}", dir.display()))?;
        let stem = format!(
            "{}_{}",
            label.split_whitespace().next().unwrap_or("run"),
            mode
        );
        write_tum(
            &args.out.join(format!("{stem}.tum")),
            &result.outcome.trajectory,
        )?;
        if let Some(e) = &result.evaluation {
            write_plot(&args.out.join(format!("{stem}.png")), e)?;
        }
        if !args.json {
            println!("  {label}: {}", summary_line(&result.report));
        }
        runs.push(result.report);
    }
    let report = DemoReport {
        dataset: dataset_dir,
        simulation,
        simulate_s,
        runs,
    };
    if args.json {
        println!("{}", serde_json::to_string(&report)?);
    } else {
        print_footer(&args.out);
    }
    Ok(())
}

fn print_footer(out: &Path) {
    println!(
        "trajectories (TUM) and plots in {}; `rigslam run --help` runs any EuRoC or KITTI folder",
        out.display()
    );
}
