//! Pictures of an evaluation for people: the top view (x-y) of both
//! trajectories after alignment above, the ATE over time below. PNG or SVG
//! by the file's extension.

use std::path::Path;

use plotters::coord::Shift;
use plotters::prelude::*;

use super::{draw_legend, equal_aspect_ranges, legend_line, write_figure, DrawResult, Figure};
use super::{AXIS_FONT, LABEL_FONT};
use crate::eval::report::Evaluation;
use crate::eval::{Alignment, EvalError};

const WIDTH_PX: u32 = 1000;
const HEIGHT_PX: u32 = 1300;
const TRUTH_COLOR: RGBColor = RGBColor(40, 40, 40);
const ESTIMATE_COLOR: RGBColor = RGBColor(214, 39, 40);
const ERROR_COLOR: RGBColor = RGBColor(31, 119, 180);

/// Draws `evaluation` into `path`: `.png` or `.svg`.
pub fn write_plot(path: &Path, evaluation: &Evaluation) -> Result<(), EvalError> {
    write_figure(path, (WIDTH_PX, HEIGHT_PX), &EvaluationFigure(evaluation)).map_err(|message| {
        EvalError::Plot {
            path: path.to_path_buf(),
            message,
        }
    })
}

struct EvaluationFigure<'a>(&'a Evaluation);

impl Figure for EvaluationFigure<'_> {
    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> DrawResult<DB> {
        root.fill(&WHITE)?;
        let (top, bottom) = root.split_vertically(HEIGHT_PX * 7 / 10);
        draw_top_view(&top, self.0)?;
        draw_error_over_time(&bottom, self.0)
    }
}

/// x-y of truth and aligned estimate, with equal metres on both axes.
fn draw_top_view<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    ev: &Evaluation,
) -> DrawResult<DB> {
    let truth: Vec<(f64, f64)> = ev
        .matched
        .T_world_gt
        .iter()
        .map(|t| (t.translation.x, t.translation.y))
        .collect();
    let estimate: Vec<(f64, f64)> = ev
        .T_world_est_aligned
        .iter()
        .map(|t| (t.translation.x, t.translation.y))
        .collect();
    let (x_range, y_range) =
        equal_aspect_ranges(truth.iter().chain(&estimate), area.dim_in_pixel());
    let r = &ev.report;
    let aligned = match r.align {
        Alignment::None => "without alignment".to_string(),
        other => format!("after {} alignment", other.name()),
    };
    let caption = format!(
        "Top view {aligned}: ATE rmse {:.3} m over {:.1} m, {} poses",
        r.ate_rmse_m, r.path_length_m, r.matched_poses
    );
    let mut chart = ChartBuilder::on(area)
        .caption(caption, ("sans-serif", 24))
        .margin(15)
        .x_label_area_size(45)
        .y_label_area_size(60)
        .build_cartesian_2d(x_range, y_range)?;
    chart
        .configure_mesh()
        .x_desc("x [m]")
        .y_desc("y [m]")
        .label_style(LABEL_FONT)
        .axis_desc_style(AXIS_FONT)
        .draw()?;
    chart
        .draw_series(LineSeries::new(
            truth.iter().copied(),
            TRUTH_COLOR.stroke_width(2),
        ))?
        .label("ground truth")
        .legend(|(x, y)| legend_line(x, y, TRUTH_COLOR.stroke_width(2)));
    chart
        .draw_series(LineSeries::new(
            estimate.iter().copied(),
            ESTIMATE_COLOR.stroke_width(2),
        ))?
        .label("estimate (aligned)")
        .legend(|(x, y)| legend_line(x, y, ESTIMATE_COLOR.stroke_width(2)));
    if let (Some(start), Some(end)) = (truth.first(), truth.last()) {
        chart
            .draw_series([Circle::new(*start, 6, TRUTH_COLOR.filled())])?
            .label("start")
            .legend(|(x, y)| Circle::new((x + 12, y), 5, TRUTH_COLOR.filled()));
        chart
            .draw_series([TriangleMarker::new(*end, 8, TRUTH_COLOR.filled())])?
            .label("end")
            .legend(|(x, y)| TriangleMarker::new((x + 12, y), 6, TRUTH_COLOR.filled()));
    }
    draw_legend(&mut chart, SeriesLabelPosition::UpperRight)
}

/// ATE of each matched pose against seconds since the first.
fn draw_error_over_time<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    ev: &Evaluation,
) -> DrawResult<DB> {
    let t0_ns = ev.matched.t_ns[0];
    let points: Vec<(f64, f64)> = ev
        .matched
        .t_ns
        .iter()
        .zip(&ev.ate_errors_m)
        .map(|(&t, &e)| ((t - t0_ns) as f64 * 1e-9, e))
        .collect();
    let t_max_s = points.last().map_or(1.0, |p| p.0).max(1e-3);
    let e_max_m = ev.report.ate_max_m.max(1e-6) * 1.1;
    let mut chart = ChartBuilder::on(area)
        .caption(
            "Translation error after alignment (ATE)",
            ("sans-serif", 22),
        )
        .margin(15)
        .x_label_area_size(45)
        .y_label_area_size(60)
        .build_cartesian_2d(0.0..t_max_s, 0.0..e_max_m)?;
    chart
        .configure_mesh()
        .x_desc("time since first matched pose [s]")
        .y_desc("ATE [m]")
        .label_style(LABEL_FONT)
        .axis_desc_style(AXIS_FONT)
        .draw()?;
    chart
        .draw_series(LineSeries::new(points, ERROR_COLOR.stroke_width(2)))?
        .label("ATE")
        .legend(|(x, y)| legend_line(x, y, ERROR_COLOR.stroke_width(2)));
    let rmse = ev.report.ate_rmse_m;
    chart
        .draw_series(LineSeries::new(
            [(0.0, rmse), (t_max_s, rmse)],
            ERROR_COLOR.mix(0.6).stroke_width(1),
        ))?
        .label(format!("rmse {rmse:.3} m"))
        .legend(|(x, y)| legend_line(x, y, ERROR_COLOR.mix(0.6).into()));
    draw_legend(&mut chart, SeriesLabelPosition::UpperRight)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::eval::{evaluate, EvalOptions};
    use crate::trajectory::{StampedPose, Trajectory};
    use nalgebra::{UnitQuaternion, Vector3};

    fn evaluation() -> Evaluation {
        let gt = Trajectory::new(
            (0..200)
                .map(|k| {
                    let s = k as f64 * 0.05;
                    StampedPose::new(
                        k as i64 * 50_000_000,
                        Vector3::new(3.0 * s.cos(), 2.0 * s.sin(), 0.0),
                        UnitQuaternion::from_euler_angles(0.0, 0.0, s),
                    )
                })
                .collect(),
        );
        let est = Trajectory::new(
            gt.poses
                .iter()
                .enumerate()
                .map(|(k, p)| {
                    let drift = Vector3::new(0.002 * k as f64, 0.0, 0.0);
                    StampedPose::new(p.t_ns, p.position() + drift, p.orientation())
                })
                .collect(),
        );
        evaluate(&est, &gt, &EvalOptions::default()).expect("evaluates")
    }

    #[test]
    fn writes_png_and_svg() {
        let ev = evaluation();
        let dir = tempfile::tempdir().expect("temp dir");
        let png = dir.path().join("eval.png");
        let svg = dir.path().join("eval.svg");
        write_plot(&png, &ev).expect("png");
        write_plot(&svg, &ev).expect("svg");

        let png_bytes = std::fs::read(&png).expect("png exists");
        assert!(png_bytes.starts_with(b"\x89PNG\r\n\x1a\n"), "not a PNG");
        let image = image::load_from_memory(&png_bytes).expect("PNG decodes");
        assert_eq!((image.width(), image.height()), (WIDTH_PX, HEIGHT_PX));
        // Something was drawn in the estimate's colour, not only background.
        let rgb = image.to_rgb8();
        let red = rgb
            .pixels()
            .filter(|p| p.0 == [ESTIMATE_COLOR.0, ESTIMATE_COLOR.1, ESTIMATE_COLOR.2])
            .count();
        assert!(red > 500, "only {red} estimate-coloured pixels");

        let svg_text = std::fs::read_to_string(&svg).expect("svg exists");
        assert!(
            svg_text.starts_with("<svg"),
            "{}",
            &svg_text[..40.min(svg_text.len())]
        );
        assert!(svg_text.contains("<polyline") || svg_text.contains("<path"));
        assert!(svg_text.contains("x [m]") && svg_text.contains("ATE [m]"));
        assert!(svg_text.contains("estimate (aligned)"));
    }

    #[test]
    fn unknown_extension_is_an_error() {
        let ev = evaluation();
        let err = write_plot(Path::new("/tmp/plot.jpg"), &ev).expect_err("jpg not supported");
        assert!(err.to_string().contains(".png or .svg"), "{err}");
    }
}
