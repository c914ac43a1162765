//! The camera-IMU report: the time-offset curves (angular-speed correlation
//! and the batch's projected cost), a Markdown page and a verdict.

use std::path::Path;

use plotters::prelude::*;

use crate::camera_imu_batch::BatchResult;
use crate::time_offset::TimeOffsetEstimate;

/// Standard gravity, m/s^2, for the scale check.
const GRAVITY_M_S2: f64 = 9.81;
/// Relative scale or gravity error flagged.
const SCALE_TOLERANCE: f64 = 0.03;
/// Gyro-correlation and batch offsets further apart than this disagree, s.
const OFFSET_AGREEMENT_S: f64 = 2e-3;

/// One camera's results.
#[derive(Debug, Clone)]
pub struct CameraImuResult {
    pub name: String,
    pub frames: usize,
    pub poses: usize,
    pub offset: TimeOffsetEstimate,
    pub batch: BatchResult,
}

fn camera_verdict(r: &CameraImuResult) -> Vec<String> {
    let mut problems = Vec::new();
    let s = r.batch.target_scale;
    if (s - 1.0).abs() > SCALE_TOLERANCE {
        problems.push(format!(
            "{}: the IMU sees the target {:.0}% {} than described: check the tag size (and spacing) in the target description",
            r.name,
            100.0 * (s - 1.0).abs(),
            if s > 1.0 { "larger" } else { "smaller" }
        ));
    }
    let g = r.batch.gravity_m_s2.norm();
    if (g / GRAVITY_M_S2 - 1.0).abs() > SCALE_TOLERANCE {
        problems.push(format!(
            "{}: gravity comes out as {g:.2} m/s^2: check the accelerometer units and the IMU file",
            r.name
        ));
    }
    if (r.batch.timeshift_cam_imu_s - r.offset.timeshift_cam_imu_s).abs() > OFFSET_AGREEMENT_S {
        problems.push(format!(
            "{}: the time offset from the gyro ({:.1} ms) and from the batch ({:.1} ms) disagree: recollect with faster, varied rotations",
            r.name,
            r.offset.timeshift_cam_imu_s * 1e3,
            r.batch.timeshift_cam_imu_s * 1e3
        ));
    }
    if r.offset.peak_correlation < 0.9 {
        problems.push(format!(
            "{}: camera and gyro rotation rates correlate only {:.2}: the detections may belong to another recording, or the rig barely rotated",
            r.name, r.offset.peak_correlation
        ));
    }
    if (r.poses as f64) < 0.5 * r.frames as f64 {
        problems.push(format!(
            "{}: the target was posed in only {} of {} frames: keep the whole target in view",
            r.name, r.poses, r.frames
        ));
    }
    problems
}

/// Writes `time_offset_<cam>.png` per camera and `camera_imu_report.md`;
/// returns the verdict.
pub fn write_camera_imu_report(dir: &Path, results: &[CameraImuResult]) -> anyhow::Result<String> {
    let mut problems = Vec::new();
    let mut md = String::from("# Camera-IMU calibration report\n\n");
    for r in results {
        problems.extend(camera_verdict(r));
        let plot = format!("time_offset_{}.png", r.name);
        draw_offset(&dir.join(&plot), r)?;
        let b = &r.batch;
        let t = b.T_cam_imu();
        md.push_str(&format!(
            "## {}\n\n| quantity | value |\n|---|---|\n",
            r.name
        ));
        md.push_str(&format!("| frames posed | {} of {} |\n", r.poses, r.frames));
        md.push_str(&format!("| time shift, gyro correlation (ms) | {:.3} (peak correlation {:.4}, {} intervals) |\n", r.offset.timeshift_cam_imu_s * 1e3, r.offset.peak_correlation, r.offset.pairs));
        md.push_str(&format!(
            "| time shift, batch (ms) | {:.3} |\n",
            b.timeshift_cam_imu_s * 1e3
        ));
        md.push_str(&format!(
            "| camera centre in IMU frame (m) | {:.5} {:.5} {:.5} |\n",
            b.p_imu_cam_m.x, b.p_imu_cam_m.y, b.p_imu_cam_m.z
        ));
        md.push_str(&format!(
            "| gravity norm (m/s^2) | {:.4} |\n",
            b.gravity_m_s2.norm()
        ));
        md.push_str(&format!(
            "| target scale seen by the IMU | {:.4} |\n",
            b.target_scale
        ));
        md.push_str(&format!(
            "| accel bias (m/s^2) | {:.4} {:.4} {:.4} |\n",
            b.accel_bias_m_s2.x, b.accel_bias_m_s2.y, b.accel_bias_m_s2.z
        ));
        md.push_str(&format!(
            "| gyro bias (rad/s) | {:.5} {:.5} {:.5} |\n",
            b.gyro_bias_rad_s.x, b.gyro_bias_rad_s.y, b.gyro_bias_rad_s.z
        ));
        md.push_str(&format!(
            "| residual RMS: accel (m/s^2), position (mm), rate (rad/s) | {:.4}, {:.2}, {:.4} |\n",
            b.accel_rms_m_s2,
            b.position_rms_m * 1e3,
            b.gyro_rms_rad_s
        ));
        md.push_str("\nT_cam_imu:\n\n```\n");
        for i in 0..4 {
            md.push_str(&format!(
                "{:>12.8} {:>12.8} {:>12.8} {:>12.8}\n",
                t[(i, 0)],
                t[(i, 1)],
                t[(i, 2)],
                t[(i, 3)]
            ));
        }
        md.push_str(&format!("```\n\n![time offset]({plot})\n\n"));
    }
    let verdict = if problems.is_empty() {
        "GOOD: rotation, translation and time offset are consistent between the gyro correlation and the batch, and the target scale agrees with gravity".to_string()
    } else {
        format!("CHECK: {}", problems.join("; "))
    };
    md.insert_str(0, &format!("**Verdict:** {verdict}\n\n"));
    std::fs::write(dir.join("camera_imu_report.md"), md)?;
    Ok(verdict)
}

fn draw_offset(path: &Path, r: &CameraImuResult) -> anyhow::Result<()> {
    let root = BitMapBackend::new(path, (900, 700)).into_drawing_area();
    root.fill(&WHITE)?;
    let (top, bottom) = root.split_vertically(350);
    let curve: Vec<(f64, f64)> = r
        .offset
        .correlation_curve
        .iter()
        .map(|&(s, c)| (s * 1e3, c))
        .collect();
    let (lo, hi) = curve
        .iter()
        .fold((f64::MAX, f64::MIN), |(a, b), p| (a.min(p.1), b.max(p.1)));
    let x_range = curve.first().map_or(-1.0, |p| p.0)..curve.last().map_or(1.0, |p| p.0);
    let mut chart = ChartBuilder::on(&top)
        .caption(
            format!("{}: angular-speed correlation vs time shift", r.name),
            ("sans-serif", 18),
        )
        .margin(10)
        .x_label_area_size(35)
        .y_label_area_size(55)
        .build_cartesian_2d(x_range, lo..hi + 1e-9)?;
    chart
        .configure_mesh()
        .x_desc("timeshift_cam_imu (ms)")
        .y_desc("correlation")
        .draw()?;
    chart.draw_series(LineSeries::new(curve, &BLUE))?;
    let cost: Vec<(f64, f64)> = r
        .batch
        .cost_curve
        .iter()
        .map(|&(s, c)| (s * 1e3, c))
        .collect();
    if cost.len() >= 2 {
        let (lo, hi) = cost
            .iter()
            .fold((f64::MAX, f64::MIN), |(a, b), p| (a.min(p.1), b.max(p.1)));
        let mut chart = ChartBuilder::on(&bottom)
            .caption(
                "batch cost vs time shift (rotation held, the rest re-solved)",
                ("sans-serif", 18),
            )
            .margin(10)
            .x_label_area_size(35)
            .y_label_area_size(70)
            .build_cartesian_2d(cost[0].0..cost[cost.len() - 1].0, lo..hi + 1e-9)?;
        chart
            .configure_mesh()
            .x_desc("timeshift_cam_imu (ms)")
            .y_desc("cost")
            .draw()?;
        chart.draw_series(LineSeries::new(cost, &RED))?;
    }
    root.present()?;
    Ok(())
}
