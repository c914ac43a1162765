//! Pictures for people, behind the `plot` feature (on by default; a
//! program that only needs poses builds the library without it and
//! without plotters): [`evaluation`] draws an estimate against ground
//! truth, [`loop_comparison`] the absolute stage's error over laps. The
//! helpers here give every figure of the workspace (the calibration
//! reports use them too) the same backends, fonts and legend.

use std::path::Path;

use plotters::coord::Shift;
use plotters::prelude::*;

pub mod evaluation;
pub mod loop_comparison;

/// Tick labels.
pub const LABEL_FONT: (&str, u32) = ("sans-serif", 16);
/// Axis descriptions.
pub const AXIS_FONT: (&str, u32) = ("sans-serif", 18);

/// What a drawing step returns on a backend `DB`.
pub type DrawResult<DB> = Result<(), DrawingAreaErrorKind<<DB as DrawingBackend>::ErrorType>>;

/// A picture that can be drawn on any plotters backend.
pub trait Figure {
    /// Draws the whole picture on `root` (already sized, not yet filled).
    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> DrawResult<DB>;
}

/// Writes `figure` to `path` as PNG or SVG, chosen by the file's extension
/// (either case), `size_px` wide and high. The error is a sentence for the
/// user: an unknown extension or what the backend reported.
pub fn write_figure(path: &Path, size_px: (u32, u32), figure: &impl Figure) -> Result<(), String> {
    let extension = path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase);
    match extension.as_deref() {
        Some("png") => {
            let root = BitMapBackend::new(path, size_px).into_drawing_area();
            figure.draw(&root).map_err(|e| e.to_string())?;
            root.present().map_err(|e| e.to_string())
        }
        Some("svg") => {
            let root = SVGBackend::new(path, size_px).into_drawing_area();
            figure.draw(&root).map_err(|e| e.to_string())?;
            root.present().map_err(|e| e.to_string())
        }
        _ => Err("unknown image type: the file name must end in .png or .svg".into()),
    }
}

/// The legend every figure uses: white, slightly see-through, framed,
/// at `position`.
pub fn draw_legend<'a, DB, CT>(
    chart: &mut ChartContext<'a, DB, CT>,
    position: SeriesLabelPosition,
) -> DrawResult<DB>
where
    DB: DrawingBackend + 'a,
    CT: CoordTranslate,
{
    chart
        .configure_series_labels()
        .position(position)
        .label_font(LABEL_FONT)
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .draw()
}

/// A legend entry for a line of `style`: a short stroke at `(x, y)`.
pub fn legend_line(x: i32, y: i32, style: ShapeStyle) -> PathElement<(i32, i32)> {
    PathElement::new(vec![(x, y), (x + 25, y)], style)
}

/// Axis ranges holding every point with 5 % margins, widened on one axis
/// so that a metre is as long in x as in y on a plot of `size_px`.
pub fn equal_aspect_ranges<'a>(
    points: impl Iterator<Item = &'a (f64, f64)>,
    size_px: (u32, u32),
) -> (std::ops::Range<f64>, std::ops::Range<f64>) {
    let (mut x0, mut x1, mut y0, mut y1) = (
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::INFINITY,
        f64::NEG_INFINITY,
    );
    for &(x, y) in points {
        x0 = x0.min(x);
        x1 = x1.max(x);
        y0 = y0.min(y);
        y1 = y1.max(y);
    }
    if !x0.is_finite() {
        return (-1.0..1.0, -1.0..1.0);
    }
    let span = ((x1 - x0).max(y1 - y0) * 1.1).max(1e-3);
    // Plot area roughly the drawing area less the label margins.
    let aspect = (size_px.1 as f64 - 110.0).max(1.0) / (size_px.0 as f64 - 105.0).max(1.0);
    let (x_span, y_span) = if aspect < 1.0 {
        (span / aspect, span)
    } else {
        (span, span * aspect)
    };
    let (xc, yc) = (0.5 * (x0 + x1), 0.5 * (y0 + y1));
    (
        xc - 0.5 * x_span..xc + 0.5 * x_span,
        yc - 0.5 * y_span..yc + 0.5 * y_span,
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn equal_aspect_ranges_give_a_metre_the_same_pixels_on_both_axes() {
        let points = [(0.0, 0.0), (4.0, 1.0)];
        let size = (1105, 610);
        let (x, y) = equal_aspect_ranges(points.iter(), size);
        let px_per_m_x = (size.0 as f64 - 105.0) / (x.end - x.start);
        let px_per_m_y = (size.1 as f64 - 110.0) / (y.end - y.start);
        assert!(
            (px_per_m_x - px_per_m_y).abs() < 1e-9,
            "{px_per_m_x} {px_per_m_y}"
        );
        assert!(x.start < 0.0 && x.end > 4.0 && y.start < 0.0 && y.end > 1.0);
    }
}
