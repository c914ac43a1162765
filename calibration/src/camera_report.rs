//! The camera calibration report for people: a coverage picture (where on
//! the sensor the corners fell, with the residuals magnified), per-view RMS
//! bars, a Markdown page linking both, and a one-line verdict.

use std::path::Path;

use plotters::prelude::*;

use crate::intrinsics_lm::IntrinsicsCalibration;

/// Residual arrows are drawn this many times their length.
const RESIDUAL_MAGNIFICATION: f64 = 20.0;
/// Verdict thresholds on the RMS, px.
const GOOD_RMS_PX: f64 = 0.5;
const USABLE_RMS_PX: f64 = 1.0;

/// Corners covering less than this fraction of the sensor (bounding box)
/// leave the distortion poorly determined at the edges.
const MIN_COVERAGE: f64 = 0.5;

/// Fraction of the sensor inside the bounding box of all used corners.
pub fn coverage_fraction(
    cal: &IntrinsicsCalibration,
    views_px: &[Vec<nalgebra::Vector2<f64>>],
) -> f64 {
    let (mut lo, mut hi) = (
        nalgebra::Vector2::new(f64::MAX, f64::MAX),
        nalgebra::Vector2::new(f64::MIN, f64::MIN),
    );
    for (fit, view) in cal.views.iter().zip(views_px) {
        if fit.outlier {
            continue;
        }
        for c in view {
            lo = lo.inf(c);
            hi = hi.sup(c);
        }
    }
    let area = ((hi.x - lo.x) * (hi.y - lo.y)).max(0.0);
    area / (cal.camera.width as f64 * cal.camera.height as f64)
}

/// A sentence a technician can act on.
pub fn verdict(cal: &IntrinsicsCalibration, coverage: f64) -> String {
    let outliers: Vec<usize> = cal
        .views
        .iter()
        .enumerate()
        .filter(|(_, v)| v.outlier)
        .map(|(k, _)| k)
        .collect();
    let mut parts = Vec::new();
    if cal.rms_px <= GOOD_RMS_PX {
        parts.push(format!(
            "GOOD: reprojection error {:.2} px over {} views",
            cal.rms_px, cal.views_used
        ));
    } else if cal.rms_px <= USABLE_RMS_PX {
        parts.push(format!(
            "USABLE: reprojection error {:.2} px; for better results use a flat, rigid board and sharp, well-lit images",
            cal.rms_px
        ));
    } else {
        parts.push(format!(
            "POOR: reprojection error {:.2} px; recollect with a flat board, no motion blur and the focus locked",
            cal.rms_px
        ));
    }
    if !outliers.is_empty() {
        parts.push(format!(
            "views {outliers:?} fit badly and were left out (blurred or the board bent?)"
        ));
    }
    if coverage < MIN_COVERAGE {
        parts.push(format!(
            "corners cover only {:.0}% of the sensor: add views with the board near the edges and corners of the image",
            100.0 * coverage
        ));
    }
    parts.join("; ")
}

/// Writes `<prefix>_coverage.png`, `<prefix>_per_view_rms.png` and
/// `<prefix>_report.md` into `dir` (the prefix names the camera, so both
/// cameras of a rig report into one calibration folder).
pub fn write_camera_report(
    dir: &Path,
    cal: &IntrinsicsCalibration,
    names: &[String],
    views_px: &[Vec<nalgebra::Vector2<f64>>],
    missing: &[String],
    verdict: &str,
    prefix: &str,
) -> anyhow::Result<()> {
    let coverage_png = format!("{prefix}_coverage.png");
    let per_view_png = format!("{prefix}_per_view_rms.png");
    draw_coverage(&dir.join(&coverage_png), cal, views_px)?;
    draw_per_view(&dir.join(&per_view_png), cal, names)?;
    let c = &cal.camera;
    let mut md = String::new();
    md.push_str("# Camera calibration report\n\n");
    md.push_str(&format!("**Verdict:** {verdict}\n\n"));
    md.push_str("| quantity | value |\n|---|---|\n");
    md.push_str(&format!("| fx, fy (px) | {:.3}, {:.3} |\n", c.fx, c.fy));
    md.push_str(&format!("| cx, cy (px) | {:.3}, {:.3} |\n", c.cx, c.cy));
    md.push_str(&format!("| k1 k2 p1 p2 k3 | {:?} |\n", c.distortion));
    md.push_str(&format!("| RMS reprojection (px) | {:.4} |\n", cal.rms_px));
    md.push_str(&format!(
        "| views used / found | {} / {} |\n",
        cal.views_used,
        cal.views.len()
    ));
    md.push_str(&format!(
        "| Zhang closed form fx fy cx cy | {:.2} {:.2} {:.2} {:.2} |\n\n",
        cal.zhang_pinhole[0], cal.zhang_pinhole[1], cal.zhang_pinhole[2], cal.zhang_pinhole[3]
    ));
    md.push_str(&format!("## Per-view errors\n\n![per-view RMS]({per_view_png})\n\n| view | RMS (px) | max (px) | board distance (m) | status |\n|---|---|---|---|---|\n"));
    for (fit, name) in cal.views.iter().zip(names) {
        let max = fit
            .residuals_px
            .iter()
            .map(|r| r.norm())
            .fold(0.0, f64::max);
        md.push_str(&format!(
            "| {name} | {:.3} | {:.3} | {:.3} | {} |\n",
            fit.rms_px,
            max,
            fit.t_cam_board.norm(),
            if fit.outlier {
                "outlier, left out"
            } else {
                "used"
            }
        ));
    }
    for name in missing {
        md.push_str(&format!("| {name} | - | - | - | board not found |\n"));
    }
    md.push_str(&format!(
        "\n## Coverage\n\nEach dot is a detected corner (one colour per view); the lines are the residuals magnified {RESIDUAL_MAGNIFICATION}x.\n\n![coverage]({coverage_png})\n"
    ));
    std::fs::write(dir.join(format!("{prefix}_report.md")), md)?;
    Ok(())
}

fn draw_coverage(
    path: &Path,
    cal: &IntrinsicsCalibration,
    views_px: &[Vec<nalgebra::Vector2<f64>>],
) -> anyhow::Result<()> {
    let (w, h) = (cal.camera.width as f64, cal.camera.height as f64);
    let root = BitMapBackend::new(path, (cal.camera.width + 80, cal.camera.height + 80))
        .into_drawing_area();
    root.fill(&WHITE)?;
    let mut chart = ChartBuilder::on(&root)
        .caption("corner coverage (residuals x20)", ("sans-serif", 18))
        .margin(10)
        .x_label_area_size(25)
        .y_label_area_size(40)
        .build_cartesian_2d(0.0..w, h..0.0)?;
    chart.configure_mesh().disable_mesh().draw()?;
    for (k, (fit, view)) in cal.views.iter().zip(views_px).enumerate() {
        let color = Palette99::pick(k).to_rgba();
        let color = if fit.outlier {
            RGBAColor(150, 150, 150, 1.0)
        } else {
            color
        };
        chart.draw_series(
            view.iter()
                .map(|c| Circle::new((c.x, c.y), 2, color.filled())),
        )?;
        chart.draw_series(view.iter().zip(&fit.residuals_px).map(|(c, r)| {
            let end = c + r * RESIDUAL_MAGNIFICATION;
            PathElement::new(vec![(c.x, c.y), (end.x, end.y)], color)
        }))?;
    }
    root.present()?;
    Ok(())
}

fn draw_per_view(path: &Path, cal: &IntrinsicsCalibration, names: &[String]) -> anyhow::Result<()> {
    let root = BitMapBackend::new(path, (800, 400)).into_drawing_area();
    root.fill(&WHITE)?;
    let top = cal.views.iter().map(|v| v.rms_px).fold(0.1, f64::max) * 1.1;
    let mut chart = ChartBuilder::on(&root)
        .caption(
            "reprojection RMS per view (grey: outlier)",
            ("sans-serif", 18),
        )
        .margin(10)
        .x_label_area_size(40)
        .y_label_area_size(50)
        .build_cartesian_2d(0.0..cal.views.len() as f64, 0.0..top)?;
    chart
        .configure_mesh()
        .y_desc("RMS (px)")
        .x_labels(cal.views.len())
        .x_label_formatter(&|x| names.get(*x as usize).cloned().unwrap_or_default())
        .draw()?;
    chart.draw_series(cal.views.iter().enumerate().map(|(k, v)| {
        let color = if v.outlier {
            RGBColor(150, 150, 150)
        } else {
            RGBColor(31, 119, 180)
        };
        Rectangle::new(
            [(k as f64 + 0.15, 0.0), (k as f64 + 0.85, v.rms_px)],
            color.filled(),
        )
    }))?;
    root.present()?;
    Ok(())
}
