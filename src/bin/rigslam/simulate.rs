//! `rigslam simulate`: render a synthetic EuRoC ASL dataset.

use std::path::PathBuf;

use anyhow::Context;
use rigslam::simulate::{simulate, ImuSource, SimConfig};

#[derive(clap::Args)]
pub struct SimulateArgs {
    /// Output folder; `mav0/` is written inside it.
    #[arg(long)]
    out: PathBuf,
    /// Ground truth to follow (EuRoC state_groundtruth csv or TUM); the
    /// built-in motion when absent.
    #[arg(long)]
    trajectory: Option<PathBuf>,
    /// Sequence length in seconds (default: 30 s built-in, or the whole file).
    #[arg(long)]
    duration_s: Option<f64>,
    /// IMU: `synth` (from the motion, EuRoC ADIS16448 noise) or
    /// `real:FILE` (a real EuRoC imu0 csv recorded with --trajectory).
    #[arg(long, default_value = "synth", value_parser = parse_imu)]
    imu: ImuSource,
    /// Render cam1 too (EuRoC's right camera).
    #[arg(long)]
    stereo: bool,
    /// Seed of the scene, textures, image noise and IMU noise.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Synthesise ideal IMU samples (no white noise, no bias walk).
    #[arg(long)]
    ideal_imu: bool,
    /// No progress bar.
    #[arg(long)]
    no_progress: bool,
    /// Print the report as one JSON object on stdout.
    #[arg(long)]
    json: bool,
}

fn parse_imu(s: &str) -> Result<ImuSource, String> {
    match s {
        "synth" => Ok(ImuSource::Synthetic),
        _ => match s.strip_prefix("real:") {
            Some(path) if !path.is_empty() => Ok(ImuSource::Real(PathBuf::from(path))),
            _ => Err(format!("expected `synth` or `real:FILE`, got `{s}`")),
        },
    }
}

pub fn run(args: SimulateArgs) -> anyhow::Result<()> {
    let config = SimConfig {
        trajectory: args.trajectory,
        duration_s: args.duration_s,
        imu: args.imu,
        stereo: args.stereo,
        seed: args.seed,
        imu_noise: if args.ideal_imu {
            None
        } else {
            SimConfig::default().imu_noise
        },
        show_progress: !args.no_progress && !args.json,
        ..SimConfig::default()
    };
    let report = simulate(&config, &args.out)
        .with_context(|| format!("simulating into {}", args.out.display()))?;
    if args.json {
        println!("{}", serde_json::to_string(&report)?);
    } else {
        println!(
            "simulate: {} frames ({} images, {:.1} s), {} IMU samples, path {:.1} m, room {:.1} x {:.1} x {:.1} m with {} boxes; \
             render {:.1} images/s (ray casting only, one thread; {} per CPU-second), {:.1} images/s with PNG writing; setup {:.2} s, total {:.1} s; wrote {}",
            report.frames,
            report.images,
            report.duration_s,
            report.imu_samples,
            report.path_length_m,
            report.room_size_m[0],
            report.room_size_m[1],
            report.room_size_m[2],
            report.boxes,
            report.render_fps,
            report
                .render_cpu_fps
                .map_or("n/a".to_string(), |f| format!("{f:.1}")),
            report.render_write_fps,
            report.setup_s,
            report.total_s,
            args.out.display()
        );
    }
    Ok(())
}
