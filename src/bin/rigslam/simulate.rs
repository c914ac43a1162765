//! `rigslam simulate`: render a synthetic EuRoC ASL dataset.

use std::path::PathBuf;

use anyhow::Context;
use rigslam::rig::ImuNoise;
use rigslam::simulate::{simulate, ImuSource, SimConfig, SplineConfig};

#[derive(clap::Args)]
pub struct SimulateArgs {
    /// Output folder; `mav0/` is written inside it, and `scene.json` beside
    /// it (the room and boxes in the ground truth's frame, for checking
    /// landmarks and maps against their surfaces:
    /// `bench/accuracy/landmark_truth.py`).
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
    /// How the motion follows --trajectory: `through` (a cubic spline
    /// through the ground truth at every knot) or `smooth` (control poses
    /// on the ground truth, which smooths it). Default: `through` with
    /// `--imu real:`, so the images move as the real IMU measured, and
    /// `smooth` with the synthetic IMU, which differentiates the spline.
    /// `none`: no spline, the recorded poses interpolated at each stamp
    /// (position linearly, orientation by slerp); real IMU only.
    #[arg(long, value_enum)]
    spline: Option<SplineFit>,
    /// Knot spacing of that spline, s. Default: 0.01 for `through`, 0.05
    /// for `smooth`.
    #[arg(long)]
    knot_spacing_s: Option<f64>,
    /// Render cam1 too (EuRoC's right camera).
    #[arg(long)]
    stereo: bool,
    /// Boxes in the room (furniture-sized, textured) [12].
    #[arg(long, default_value_t = 12)]
    boxes: usize,
    /// Texture cell size of the room's surfaces, mm [5].
    #[arg(long, default_value_t = 5.0)]
    texel_mm: f32,
    /// What a real IMU log's imu0/sensor.yaml declares: `measured` (the
    /// log's noise against the rendered motion where it is above the
    /// datasheet's: what the ground truth reveals) or `datasheet` (the
    /// ADIS16448's own values: what a user on a robot has).
    #[arg(long, value_enum, default_value_t = DeclaredNoise::Measured)]
    declared_noise: DeclaredNoise,
    /// Seed of the scene, textures, image noise and IMU noise.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Synthesise ideal IMU samples (no white noise, no bias walk).
    #[arg(long, conflicts_with = "imu_noise")]
    ideal_imu: bool,
    /// Noise of the synthetic IMU: `euroc` (the ADIS16448 of EuRoC) or
    /// `yei` (the paper's YEI 3-Space levels: 0.08 m/s^2 and 0.8 deg/s
    /// standard deviation per sample at the IMU rate, EuRoC's bias walks).
    /// Written to imu0/sensor.yaml as continuous-time densities.
    #[arg(long, value_enum, default_value_t = NoiseLevel::Euroc)]
    imu_noise: NoiseLevel,
    /// No progress bar.
    #[arg(long)]
    no_progress: bool,
    /// Print the report as one JSON object on stdout.
    #[arg(long)]
    json: bool,
}

#[derive(Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
enum SplineFit {
    Through,
    Smooth,
    None,
}

#[derive(Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
enum DeclaredNoise {
    Measured,
    Datasheet,
}

/// The spline the options ask for; `None` (the library's choice by IMU
/// source) when neither is given.
fn spline_config(
    fit: Option<SplineFit>,
    knot_spacing_s: Option<f64>,
    imu: &ImuSource,
) -> Option<SplineConfig> {
    if fit.is_none() && knot_spacing_s.is_none() || fit == Some(SplineFit::None) {
        return None;
    }
    let base = match fit {
        Some(SplineFit::Through) => SplineConfig::REAL_IMU,
        Some(SplineFit::Smooth) => SplineConfig::SYNTHETIC_IMU,
        Some(SplineFit::None) | None => SplineConfig::for_imu(imu),
    };
    Some(SplineConfig {
        knot_spacing_s: knot_spacing_s.unwrap_or(base.knot_spacing_s),
        ..base
    })
}

#[derive(Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
enum NoiseLevel {
    Euroc,
    Yei,
}

/// The paper's YEI 3-Space noise as continuous densities for samples
/// `1 / rate_hz` apart: a per-sample sigma `s` is a density `s * sqrt(dt)`.
fn yei_noise(rate_hz: f64) -> ImuNoise {
    let root_dt = (1.0 / rate_hz).sqrt();
    ImuNoise {
        accelerometer_noise_density: 0.08 * root_dt,
        gyroscope_noise_density: 0.8f64.to_radians() * root_dt,
        ..ImuNoise::EUROC_ADIS16448
    }
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
        spline: spline_config(args.spline, args.knot_spacing_s, &args.imu),
        interpolate_poses: args.spline == Some(SplineFit::None),
        declare_measured_noise: args.declared_noise == DeclaredNoise::Measured,
        box_count: args.boxes,
        texel_m: args.texel_mm * 1e-3,
        trajectory: args.trajectory,
        duration_s: args.duration_s,
        imu: args.imu,
        stereo: args.stereo,
        seed: args.seed,
        imu_noise: match (args.ideal_imu, args.imu_noise) {
            (true, _) => None,
            (false, NoiseLevel::Euroc) => SimConfig::default().imu_noise,
            (false, NoiseLevel::Yei) => Some(yei_noise(SimConfig::default().imu_rate_hz)),
        },
        show_progress: !args.no_progress && !args.json,
        ..SimConfig::default()
    };
    if args.spline == Some(SplineFit::None) && args.knot_spacing_s.is_some() {
        anyhow::bail!("--knot-spacing-s needs a spline; --spline none interpolates the poses");
    }
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
        if let (Some(a), Some(g)) = (
            report.imu_accel_noise_measured,
            report.imu_gyro_noise_measured,
        ) {
            println!(
                "simulate: the IMU log against the rendered motion: accelerometer {a:.4} m/s^2/sqrt(Hz), gyroscope {g:.6} rad/s/sqrt(Hz) (0.25 s windows); imu0/sensor.yaml says {}",
                if args.declared_noise == DeclaredNoise::Measured {
                    "the larger of these and the datasheet's"
                } else {
                    "the datasheet's (--declared-noise datasheet)"
                }
            );
        }
    }
    Ok(())
}
