//! `rigslam-calibrate imu`: accelerometer scale/misalignment and bias from
//! still poses (simplex and Levenberg-Marquardt), gyroscope bias and, with
//! one turn about each axis (Ferraris), its scale. Writes the intrinsics
//! YAML, a Markdown report with a residual plot beside it, and a verdict.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::Context;
use nalgebra::{Matrix3, Vector3};
use rigslam_calibration::gyro_calibration::{read_section_list, rotations_from_sections};
use rigslam_calibration::imu_calibration::{
    calibrate_imu_session, imu_verdict, ImuCalibrationOptions,
};
use rigslam_calibration::imu_log::read_imu_log;
use rigslam_calibration::layout_args::LayoutArgs;
use rigslam_calibration::plots::plot_static_residuals;
use rigslam_calibration::report::imu_report;
use serde_json::json;

#[derive(clap::Args)]
pub struct ImuArgs {
    /// The session log (CSV, optionally .gz).
    #[arg(long)]
    input: PathBuf,
    #[command(flatten)]
    layout: LayoutArgs,
    /// imucal-style section list (JSON {name: {start, end}}): its x_rot,
    /// y_rot, z_rot sections are the turns; without it they are found.
    #[arg(long)]
    sections: Option<PathBuf>,
    /// The rig's calibration folder (created if need be): the intrinsics (imu_intrinsics.yaml) goes
    /// there, with its report and plot beside it.
    #[arg(long, value_name = "DIR", default_value = "calibration")]
    out: PathBuf,
    /// Local gravity magnitude.
    #[arg(long, default_value_t = rigslam::imu::GRAVITY_M_S2)]
    gravity_m_s2: f64,
    /// Still-window length for the static detector.
    #[arg(long, default_value_t = 0.5)]
    window_s: f64,
    /// Shortest still interval that counts as a pose.
    #[arg(long, default_value_t = 1.0)]
    min_still_s: f64,
    /// Print one JSON object on stdout (the verdict goes to stderr).
    #[arg(long)]
    json: bool,
}

fn rows(m: &Matrix3<f64>) -> serde_json::Value {
    json!((0..3)
        .map(|r| [m[(r, 0)], m[(r, 1)], m[(r, 2)]])
        .collect::<Vec<_>>())
}

fn vec3(v: &Vector3<f64>) -> serde_json::Value {
    json!([v.x, v.y, v.z])
}

fn beside(output: &Path, suffix: &str) -> PathBuf {
    let stem = output
        .file_stem()
        .and_then(|s| s.to_str())
        .unwrap_or("imu_intrinsics");
    output.with_file_name(format!("{stem}{suffix}"))
}

pub fn run(args: ImuArgs) -> anyhow::Result<()> {
    let output = crate::output_file(&args.out, rigslam::rig::folder::IMU_INTRINSICS)?;
    let start = Instant::now();
    let layout = args.layout.layout().map_err(anyhow::Error::msg)?;
    let log = read_imu_log(&args.input, &layout)?;
    let rotations = match &args.sections {
        Some(path) => Some(rotations_from_sections(&read_section_list(
            path,
            log.samples.len(),
        )?)),
        None => None,
    };
    let mut options = ImuCalibrationOptions {
        gravity_m_s2: args.gravity_m_s2,
        ..Default::default()
    };
    options.detector.window_s = args.window_s;
    options.detector.min_duration_s = args.min_still_s;
    let cal = calibrate_imu_session(&log.samples, log.rate_hz, rotations, &options)
        .with_context(|| format!("calibrating {}", args.input.display()))?;
    let verdict = imu_verdict(&cal);

    let yaml = rigslam::rig::imu_intrinsics_file::intrinsics_yaml(&cal.intrinsics);
    rigslam::rig::folder::write_atomically(
        &output,
        format!(
            "# rigslam-calibrate imu --input {}\n{yaml}",
            args.input.display()
        )
        .as_bytes(),
    )
    .with_context(|| format!("writing {}", output.display()))?;
    let png = beside(&output, "_residuals.png");
    plot_static_residuals(
        &png,
        &cal.accel.residuals_before_m_s2,
        &cal.accel.levenberg_marquardt.residuals_m_s2,
    )?;
    let report_path = beside(&output, "_report.md");
    let file_name = |p: &Path| {
        p.file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default()
    };
    let report = imu_report(
        &cal,
        &args.input.display().to_string(),
        &file_name(&output),
        &file_name(&png),
        &verdict,
    );
    std::fs::write(&report_path, report)
        .with_context(|| format!("writing {}", report_path.display()))?;

    let a = &cal.accel;
    let fit_json = |f: &rigslam_calibration::accel_calibration::AccelFit| json!({"accel_scale_matrix": rows(&f.scale), "accel_bias": vec3(&f.bias_m_s2), "rms_m_s2": f.rms_m_s2, "work": f.work});
    if args.json {
        let out = json!({
            "accel_scale_matrix": rows(&cal.intrinsics.accel_scale),
            "accel_bias": vec3(&cal.intrinsics.accel_offset_m_s2),
            "gyro_bias": vec3(&cal.intrinsics.gyro_offset_rad_s),
            "gyro_scale_matrix": cal.gyro_scale.as_ref().ok().map(|g| rows(&g.scale)),
            "accel_model": a.model.name(),
            "samples": log.samples.len(),
            "rate_hz": log.rate_hz,
            "static_intervals": cal.intervals.len(),
            "distinct_poses": cal.distinct_poses,
            "gravity_residual_rms_before_m_s2": a.rms_before_m_s2,
            "gravity_residual_rms_after_m_s2": a.levenberg_marquardt.rms_m_s2,
            "nelder_mead": fit_json(&a.nelder_mead),
            "levenberg_marquardt": fit_json(&a.levenberg_marquardt),
            "nm_lm_scale_agreement": a.scale_agreement,
            "nm_lm_bias_agreement_m_s2": a.bias_agreement_m_s2,
            "gyro_offset_raw_rad_s": vec3(&cal.gyro_offset_raw_rad_s),
            "rotations": cal.rotations.iter().map(|r| json!({"axis": (["x", "y", "z"][r.axis]), "start": r.start, "end": r.end})).collect::<Vec<_>>(),
            "verdict": verdict,
            "report": report_path.display().to_string(),
            "total_ms": start.elapsed().as_secs_f64() * 1e3,
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
