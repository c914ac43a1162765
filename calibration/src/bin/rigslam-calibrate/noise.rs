//! `rigslam-calibrate noise`: overlapping Allan deviation of a still log,
//! white noise and random walk per axis, written as Kalibr's imu.yaml with
//! a Markdown report and Allan plot beside it.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::Context;
use rigslam_calibration::calibration_files::kalibr_imu_yaml;
use rigslam_calibration::imu_log::read_imu_log;
use rigslam_calibration::layout_args::LayoutArgs;
use rigslam_calibration::noise_calibration::{
    calibrate_noise, noise_warnings, StillnessLimits, AXIS_NAMES,
};
use rigslam_calibration::plots::plot_allan;
use rigslam_calibration::report::noise_report;
use serde_json::json;

#[derive(clap::Args)]
pub struct NoiseArgs {
    /// The still log (CSV, optionally .gz); EuRoC imu0 layout unless the layout flags say otherwise.
    #[arg(long)]
    input: PathBuf,
    #[command(flatten)]
    layout: LayoutArgs,
    /// The rig's calibration folder (created if need be): Kalibr's imu.yaml goes
    /// there, with its report and plot beside it.
    #[arg(long, value_name = "DIR", default_value = "calibration")]
    out: PathBuf,
    /// Cluster times per decade.
    #[arg(long, default_value_t = 10)]
    points_per_decade: usize,
    /// Print one JSON object on stdout (the verdict goes to stderr).
    #[arg(long)]
    json: bool,
}

fn beside(output: &Path, suffix: &str) -> PathBuf {
    let stem = output.file_stem().and_then(|s| s.to_str()).unwrap_or("imu");
    output.with_file_name(format!("{stem}{suffix}"))
}

pub fn run(args: NoiseArgs) -> anyhow::Result<()> {
    let output = crate::output_file(&args.out, rigslam::rig::folder::IMU_NOISE)?;
    let start = Instant::now();
    let layout = args.layout.layout().map_err(anyhow::Error::msg)?;
    let log = read_imu_log(&args.input, &layout)?;
    let read_ms = start.elapsed().as_secs_f64() * 1e3;
    let cal = calibrate_noise(
        &log.samples,
        log.rate_hz,
        args.points_per_decade,
        &StillnessLimits::default(),
    )
    .with_context(|| format!("analysing {}", args.input.display()))?;
    let warnings = noise_warnings(&cal);
    let comment = format!(
        "rigslam-calibrate noise --input {}\n{} samples at {:.1} Hz; overlapping Allan deviation; largest axis of each sensor",
        args.input.display(),
        cal.samples,
        cal.rate_hz
    );
    rigslam::rig::folder::write_atomically(
        &output,
        kalibr_imu_yaml(&cal.noise, cal.rate_hz, &comment).as_bytes(),
    )
    .with_context(|| format!("writing {}", output.display()))?;
    let png = beside(&output, "_allan.png");
    plot_allan(&png, &cal.curves, &cal.axes)?;
    let report_path = beside(&output, "_report.md");
    let file_name = |p: &Path| {
        p.file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default()
    };
    let report = noise_report(
        &cal,
        &args.input.display().to_string(),
        &file_name(&output),
        &file_name(&png),
        &warnings,
    );
    std::fs::write(&report_path, report)
        .with_context(|| format!("writing {}", report_path.display()))?;
    let verdict: Vec<String> = if warnings.is_empty() {
        vec![format!(
            "noise measured on all six axes over {:.2} h: gyro {:.2e} rad/s/sqrt(Hz), accel {:.2e} m/s^2/sqrt(Hz)",
            cal.duration_s / 3600.0,
            cal.noise.gyroscope_noise_density,
            cal.noise.accelerometer_noise_density
        )]
    } else {
        warnings
    };
    if args.json {
        let out = json!({
            "gyroscope_noise_density": cal.noise.gyroscope_noise_density,
            "gyroscope_random_walk": cal.noise.gyroscope_random_walk,
            "accelerometer_noise_density": cal.noise.accelerometer_noise_density,
            "accelerometer_random_walk": cal.noise.accelerometer_random_walk,
            "per_axis": AXIS_NAMES.iter().zip(&cal.axes).map(|(name, a)| json!({
                "axis": name,
                "noise_density": a.white_noise_density,
                "random_walk": a.random_walk,
                "bias_instability": a.bias_instability,
                "tau_floor_s": a.tau_floor_s,
                "white_points": a.white_points,
                "walk_points": a.walk_points,
            })).collect::<Vec<_>>(),
            "samples": cal.samples,
            "rate_hz": cal.rate_hz,
            "duration_s": cal.duration_s,
            "read_ms": read_ms,
            "allan_ms": cal.allan_ms,
            "total_ms": start.elapsed().as_secs_f64() * 1e3,
            "verdict": verdict,
            "report": report_path.display().to_string(),
        });
        println!("{out}");
        for line in &verdict {
            eprintln!("{line}");
        }
    } else {
        for line in &verdict {
            println!("{line}");
        }
        println!(
            "wrote {}, {} and {}",
            output.display(),
            report_path.display(),
            png.display()
        );
    }
    Ok(())
}
