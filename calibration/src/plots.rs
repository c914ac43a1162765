//! The report's pictures (PNG): the gravity-magnitude error of each still
//! pose before and after calibration, and the Allan deviation of each axis
//! on log-log axes with the fitted white-noise and random-walk lines.

use std::path::Path;

use plotters::prelude::*;
use rigslam::plot::{draw_legend, legend_line, AXIS_FONT, LABEL_FONT};

use crate::allan::AllanCurve;
use crate::error::CalibrationError;
use crate::noise_fit::{walk_line, white_line, AxisNoise};

const AXIS_COLORS: [RGBColor; 3] = [
    RGBColor(214, 39, 40),
    RGBColor(44, 160, 44),
    RGBColor(31, 119, 180),
];

fn plot_error(path: &Path, e: impl std::fmt::Display) -> CalibrationError {
    CalibrationError::Write {
        path: path.display().to_string(),
        message: e.to_string(),
    }
}

/// One point per pose: `|a| - g` before (grey) and after (blue), m/s^2,
/// above; the calibrated ones alone, on their own scale, below.
pub fn plot_static_residuals(
    path: &Path,
    before: &[f64],
    after: &[f64],
) -> Result<(), CalibrationError> {
    let draw = || -> Result<(), Box<dyn std::error::Error>> {
        let root = BitMapBackend::new(path, (1000, 800)).into_drawing_area();
        root.fill(&WHITE)?;
        let (top, bottom) = root.split_vertically(450);
        let x_range = -0.5f64..(before.len() as f64 - 0.5).max(0.5);
        let grey = RGBColor(120, 120, 120);
        let limit = before
            .iter()
            .chain(after)
            .fold(1e-6f64, |m, v| m.max(v.abs()))
            * 1.1;
        let mut chart = ChartBuilder::on(&top)
            .caption("Gravity-magnitude error per still pose", ("sans-serif", 24))
            .margin(15)
            .x_label_area_size(40)
            .y_label_area_size(75)
            .build_cartesian_2d(x_range.clone(), -limit..limit)?;
        chart
            .configure_mesh()
            .y_desc("|a| - g [m/s^2]")
            .label_style(LABEL_FONT)
            .axis_desc_style(AXIS_FONT)
            .draw()?;
        chart
            .draw_series(
                before
                    .iter()
                    .enumerate()
                    .map(|(i, &r)| Circle::new((i as f64, r), 5, grey.filled())),
            )?
            .label("raw")
            .legend(move |(x, y)| Circle::new((x + 10, y), 5, grey.filled()));
        chart
            .draw_series(
                after
                    .iter()
                    .enumerate()
                    .map(|(i, &r)| TriangleMarker::new((i as f64, r), 7, BLUE.filled())),
            )?
            .label("calibrated")
            .legend(|(x, y)| TriangleMarker::new((x + 10, y), 6, BLUE.filled()));
        draw_legend(&mut chart, SeriesLabelPosition::UpperRight)?;
        let after_mm: Vec<f64> = after.iter().map(|r| r * 1e3).collect();
        let limit_mm = after_mm.iter().fold(1e-3f64, |m, v| m.max(v.abs())) * 1.2;
        let mut zoom = ChartBuilder::on(&bottom)
            .caption("calibrated only", ("sans-serif", 20))
            .margin(15)
            .x_label_area_size(45)
            .y_label_area_size(75)
            .build_cartesian_2d(x_range, -limit_mm..limit_mm)?;
        zoom.configure_mesh()
            .x_desc("still pose (time order)")
            .y_desc("|a| - g [mm/s^2]")
            .label_style(LABEL_FONT)
            .axis_desc_style(AXIS_FONT)
            .draw()?;
        zoom.draw_series(
            after_mm
                .iter()
                .enumerate()
                .map(|(i, &r)| TriangleMarker::new((i as f64, r), 7, BLUE.filled())),
        )?;
        root.present()?;
        Ok(())
    };
    draw().map_err(|e| plot_error(path, e))
}

/// Two panels (gyro, accel): each axis's curve, dashed fitted lines.
pub fn plot_allan(
    path: &Path,
    curves: &[AllanCurve],
    axes: &[AxisNoise],
) -> Result<(), CalibrationError> {
    let draw = || -> Result<(), Box<dyn std::error::Error>> {
        let root = BitMapBackend::new(path, (1000, 1200)).into_drawing_area();
        root.fill(&WHITE)?;
        let panels = root.split_evenly((2, 1));
        for (panel, (sensor, unit)) in panels
            .iter()
            .zip([("Gyroscope", "rad/s"), ("Accelerometer", "m/s^2")])
        {
            let first = if sensor == "Gyroscope" { 0 } else { 3 };
            let (mut t_lo, mut t_hi, mut s_lo, mut s_hi) =
                (f64::INFINITY, 0.0f64, f64::INFINITY, 0.0f64);
            for c in &curves[first..first + 3] {
                for (&t, &s) in c.tau_s.iter().zip(&c.adev) {
                    t_lo = t_lo.min(t);
                    t_hi = t_hi.max(t);
                    s_lo = s_lo.min(s);
                    s_hi = s_hi.max(s);
                }
            }
            let mut chart = ChartBuilder::on(panel)
                .caption(
                    format!("{sensor}: overlapping Allan deviation"),
                    ("sans-serif", 24),
                )
                .margin(15)
                .x_label_area_size(45)
                .y_label_area_size(85)
                .build_cartesian_2d(
                    (t_lo..t_hi).log_scale(),
                    (s_lo * 0.5..s_hi * 2.0).log_scale(),
                )?;
            chart
                .configure_mesh()
                .x_desc("cluster time tau [s]")
                .y_desc(format!("Allan deviation [{unit}]"))
                .y_label_formatter(&|v| format!("{v:.0e}"))
                .label_style(LABEL_FONT)
                .axis_desc_style(AXIS_FONT)
                .draw()?;
            for k in 0..3 {
                let (c, a, color) = (&curves[first + k], &axes[first + k], AXIS_COLORS[k]);
                let name = ["x", "y", "z"][k];
                chart
                    .draw_series(LineSeries::new(
                        c.tau_s.iter().copied().zip(c.adev.iter().copied()),
                        color.stroke_width(2),
                    ))?
                    .label(format!(
                        "{name}: N {:.2e}, K {:.2e}, B {:.2e}",
                        a.white_noise_density, a.random_walk, a.bias_instability
                    ))
                    .legend(move |(x, y)| legend_line(x, y, color.stroke_width(2)));
                let white: Vec<(f64, f64)> = c
                    .tau_s
                    .iter()
                    .map(|&t| (t, white_line(a, t)))
                    .filter(|p| p.1 >= s_lo * 0.5)
                    .collect();
                let walk: Vec<(f64, f64)> = c
                    .tau_s
                    .iter()
                    .map(|&t| (t, walk_line(a, t)))
                    .filter(|p| p.1 >= s_lo * 0.5)
                    .collect();
                chart.draw_series(DashedLineSeries::new(
                    white,
                    6,
                    4,
                    color.mix(0.6).stroke_width(1),
                ))?;
                chart.draw_series(DashedLineSeries::new(
                    walk,
                    6,
                    4,
                    color.mix(0.6).stroke_width(1),
                ))?;
            }
            draw_legend(&mut chart, SeriesLabelPosition::UpperRight)?;
        }
        root.present()?;
        Ok(())
    };
    draw().map_err(|e| plot_error(path, e))
}
