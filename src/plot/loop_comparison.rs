//! The absolute stage's error over laps of a room, against the relative
//! stage alone and against a map without recognition
//! ([`crate::absolute::loop_run`] computes the three).

use std::path::Path;

use plotters::coord::Shift;
use plotters::prelude::*;

use super::{draw_legend, legend_line, write_figure, DrawResult, Figure, AXIS_FONT, LABEL_FONT};
use crate::absolute::loop_run::LoopComparison;

const RELATIVE_COLOR: RGBColor = RGBColor(127, 127, 127);
const UNRECOGNISED_COLOR: RGBColor = RGBColor(255, 127, 14);
const RECOGNISED_COLOR: RGBColor = RGBColor(31, 119, 180);

/// Error over time of the three, as PNG or SVG by the file's extension.
pub fn write_loop_plot(path: &Path, c: &LoopComparison, title: &str) -> Result<(), String> {
    write_figure(path, (1100, 600), &LoopFigure { c, title })
        .map_err(|e| format!("{}: {e}", path.display()))
}

struct LoopFigure<'a> {
    c: &'a LoopComparison,
    title: &'a str,
}

impl Figure for LoopFigure<'_> {
    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> DrawResult<DB> {
        draw(root, self.c, self.title)
    }
}

fn draw<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    c: &LoopComparison,
    title: &str,
) -> DrawResult<DB> {
    root.fill(&WHITE)?;
    let t_end = c.t_s.last().copied().unwrap_or(1.0).max(1e-3);
    let largest = c
        .relative_error_m
        .iter()
        .copied()
        .chain(c.recognised_error_m.iter().flatten().copied())
        .chain(c.unrecognised_error_m.iter().flatten().copied())
        .filter(|e| e.is_finite())
        .fold(0.0f64, f64::max)
        .max(1e-3);
    let mut chart = ChartBuilder::on(root)
        .caption(title, ("sans-serif", 20))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(60)
        .build_cartesian_2d(0.0..t_end, 0.0..largest * 1.05)?;
    chart
        .configure_mesh()
        .x_desc("time (s)")
        .y_desc("position error (m)")
        .label_style(LABEL_FONT)
        .axis_desc_style(AXIS_FONT)
        .draw()?;
    // Lap boundaries.
    for lap in 1..c.laps {
        if let Some(k) = c.lap.iter().position(|&l| l == lap) {
            let t = c.t_s[k];
            chart.draw_series(LineSeries::new(
                [(t, 0.0), (t, largest * 1.05)],
                RGBColor(220, 220, 220).stroke_width(1),
            ))?;
        }
    }
    let series = |errors: Vec<(f64, f64)>| errors;
    chart
        .draw_series(LineSeries::new(
            series(
                c.t_s
                    .iter()
                    .copied()
                    .zip(c.relative_error_m.iter().copied())
                    .collect(),
            ),
            RELATIVE_COLOR.stroke_width(2),
        ))?
        .label("relative stage alone")
        .legend(|(x, y)| legend_line(x, y, RELATIVE_COLOR.stroke_width(2)));
    let present = |errors: &[Option<f64>]| -> Vec<(f64, f64)> {
        c.t_s
            .iter()
            .zip(errors)
            .filter_map(|(&t, e)| Some((t, (*e)?)))
            .collect()
    };
    chart
        .draw_series(LineSeries::new(
            present(&c.unrecognised_error_m),
            UNRECOGNISED_COLOR.stroke_width(2),
        ))?
        .label("absolute stage, new track = new landmark")
        .legend(|(x, y)| legend_line(x, y, UNRECOGNISED_COLOR.stroke_width(2)));
    chart
        .draw_series(LineSeries::new(
            present(&c.recognised_error_m),
            RECOGNISED_COLOR.stroke_width(2),
        ))?
        .label("absolute stage with landmark recognition")
        .legend(|(x, y)| legend_line(x, y, RECOGNISED_COLOR.stroke_width(2)));
    draw_legend(&mut chart, SeriesLabelPosition::UpperLeft)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn draws_each_curve_in_its_colour() {
        let c = LoopComparison {
            t_s: (0..100).map(|k| k as f64 * 0.1).collect(),
            lap: (0..100).map(|k| k / 50).collect(),
            relative_error_m: (0..100).map(|k| k as f64 * 0.01).collect(),
            recognised_error_m: (0..100).map(|k| (k > 10).then_some(0.05)).collect(),
            unrecognised_error_m: (0..100).map(|k| (k > 10).then_some(0.3)).collect(),
            recognised: 3,
            false_recognitions: 0,
            laps: 2,
            map_per_lap: Vec::new(),
        };
        let dir = tempfile::tempdir().expect("temp dir");
        let png = dir.path().join("loops.png");
        write_loop_plot(&png, &c, "two laps").expect("png");
        let image = image::open(&png).expect("PNG decodes").to_rgb8();
        assert_eq!(image.dimensions(), (1100, 600));
        for color in [RELATIVE_COLOR, UNRECOGNISED_COLOR, RECOGNISED_COLOR] {
            let n = image
                .pixels()
                .filter(|p| p.0 == [color.0, color.1, color.2])
                .count();
            assert!(n > 200, "{color:?}: {n} pixels");
        }
        let err = write_loop_plot(&dir.path().join("loops.jpg"), &c, "x").expect_err("jpg");
        assert!(
            err.contains("loops.jpg") && err.contains(".png or .svg"),
            "{err}"
        );
    }
}
