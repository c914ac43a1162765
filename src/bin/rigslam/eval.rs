//! `rigslam eval`: score an estimated trajectory against ground truth.

use std::path::{Path, PathBuf};

use anyhow::Context;
use rigslam::eval::{evaluate, Alignment, EvalOptions};
use rigslam::plot::evaluation::write_plot;
use rigslam::trajectory::Trajectory;

#[derive(clap::Args)]
pub struct EvalArgs {
    /// Estimated trajectory, TUM format (t[s] tx ty tz qx qy qz qw).
    #[arg(long)]
    estimate: PathBuf,
    /// Ground truth: EuRoC csv (state_groundtruth_estimate0/data.csv), TUM,
    /// or KITTI poses.txt.
    #[arg(long)]
    groundtruth: PathBuf,
    /// Transformation fitted before measuring ATE: se3 for metric (stereo,
    /// VIO), sim3 for monocular, posyaw for VIO (yaw + translation only).
    #[arg(long, value_enum, default_value_t = Alignment::Se3)]
    align: Alignment,
    /// Largest time difference of an associated pose pair, ms.
    #[arg(long, default_value_t = 10.0)]
    max_dt_ms: f64,
    /// Added to the estimate's stamps before association, s.
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
    t_offset_s: f64,
    /// Scale the estimate by true/estimated path length before the final
    /// drift (monocular runs, the paper's configuration 1).
    #[arg(long)]
    scale_by_path: bool,
    /// Travelled distance of the RPE pose pairs, m.
    #[arg(long, default_value_t = 1.0)]
    rpe_delta_m: f64,
    /// Print one JSON object on stdout instead of the table.
    #[arg(long)]
    json: bool,
    /// Draw the aligned top view and the error over time (.png or .svg).
    #[arg(long)]
    plot: Option<PathBuf>,
}

pub fn run(args: EvalArgs) -> anyhow::Result<()> {
    anyhow::ensure!(
        args.max_dt_ms.is_finite() && args.max_dt_ms >= 0.0,
        "--max-dt-ms must be a finite number >= 0, got {}",
        args.max_dt_ms
    );
    anyhow::ensure!(
        args.t_offset_s.is_finite() && args.t_offset_s.abs() < 1e9,
        "--t-offset-s must be finite and below 1e9 s, got {}",
        args.t_offset_s
    );
    anyhow::ensure!(
        args.rpe_delta_m.is_finite() && args.rpe_delta_m > 0.0,
        "--rpe-delta-m must be > 0, got {}",
        args.rpe_delta_m
    );
    let estimate = load(&args.estimate, "estimate")?;
    let ground_truth = load(&args.groundtruth, "ground truth")?;
    let options = EvalOptions {
        alignment: args.align,
        max_dt_ns: (args.max_dt_ms * 1e6).round() as i64,
        t_offset_ns: (args.t_offset_s * 1e9).round() as i64,
        scale_by_path: args.scale_by_path,
        rpe_delta_m: args.rpe_delta_m,
        // evo's default relative tolerance, 10 % of the distance.
        rpe_tol_m: 0.1 * args.rpe_delta_m,
    };
    let evaluation = evaluate(&estimate, &ground_truth, &options).with_context(|| {
        format!(
            "evaluating {} against {}",
            args.estimate.display(),
            args.groundtruth.display()
        )
    })?;
    if let Some(path) = &args.plot {
        write_plot(path, &evaluation)?;
        tracing::info!("plot written to {}", path.display());
    }
    if args.json {
        println!("{}", serde_json::to_string(&evaluation.report)?);
    } else {
        print!("{}", evaluation.report.to_table());
    }
    Ok(())
}

fn load(path: &Path, what: &str) -> anyhow::Result<Trajectory> {
    rigslam::dataset::read_trajectory_any(path).with_context(|| format!("reading the {what}"))
}
