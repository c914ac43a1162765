//! Subpixel tag corners. On an AprilGrid every tag corner touches a corner
//! square, so it is an x-junction (dark tag and square on one diagonal,
//! white gaps on the other) of two straight edges: the tag's side, which
//! runs on as the square's side past the corner. Two stages:
//!
//! 1. [`refine_junction`]: every pixel `p` near a junction `q` either has
//!    no gradient or lies on an edge through `q`, so `g(p)^T (p - q) = 0`;
//!    least squares gives `q = (sum w g g^T)^-1 sum w g g^T p` (Förstner
//!    and Gülch 1987, the equation of OpenCV's `cornerSubPix`), iterated
//!    with the window recentred. The window is a parallelogram along the
//!    tag's two sides reaching [`REACH_CELLS`] tag cells each way (less
//!    for gaps under 2.3 cells), inside
//!    the tag's 2-cell border and the 3-cell gaps, so no other edge is in
//!    it however obliquely the tag is seen. Pulls a corner that is a pixel
//!    or two off onto the junction.
//! 2. [`refine_by_edges`]: each of the two edges fitted as a line over the
//!    stretch from 1 to 2.5 cells either side of the junction, and the
//!    corner put where they meet. Several times the pixels of the window,
//!    so a half to a third of its noise; lines this short are straight in
//!    a distorted lens too. Grids with gaps under 2.5 cells (spacing under
//!    0.25) leave too short a stretch of the corner square's side, and
//!    keep the window's corner.
//!
//! Pixels: centres at integer coordinates; sums run over whole pixels with
//! central-difference gradients, as values interpolated between pixels
//! would bend sharp edges by an amount that depends on where the corner
//! falls within its pixel.

use nalgebra::{Matrix2, Vector2};

use crate::chessboard::GreyImage;

/// Window half-width along each side, tag cells (a tag is 10 cells).
pub const REACH_CELLS: f64 = 1.4;
/// Gaussian weight of the window, cells.
const WEIGHT_SIGMA_SHARE: f64 = 0.6;
/// Stretch of each edge used by [`refine_by_edges`], cells from the
/// junction: clear of the junction's core, within the tag's side (10
/// cells) and the corner square's (3 cells).
const EDGE_FROM_CELLS: f64 = 1.0;
const EDGE_TO_CELLS: f64 = 2.5;
/// Half-width of the band about each edge, cells: inside the 2-cell
/// border and the 3-cell gaps.
const EDGE_BAND_CELLS: f64 = 0.8;
/// Refits of the two edges about the latest corner.
const EDGE_ITERATIONS: usize = 4;
/// Largest move from the first estimate, cells.
const MAX_SHIFT_CELLS: f64 = 1.2;

/// Refines the junction near `start`; `along_a` and `along_b` are one tag
/// cell along the tag's two sides from this corner, px. The sums run over
/// whole pixels (gradients by central differences of pixel values): values
/// interpolated between pixels would bend sharp edges by an amount that
/// depends on where the corner falls within its pixel. `None` if it
/// drifts off, leaves the image or the window has no junction.
pub fn refine_junction(
    image: &GreyImage,
    start: Vector2<f64>,
    along_a: Vector2<f64>,
    along_b: Vector2<f64>,
    gap_cells: f64,
) -> Option<Vector2<f64>> {
    // Inside the corner square and the gaps when they are narrow.
    let reach_cells = REACH_CELLS.min(0.6 * gap_cells);
    // Pixel offset -> (s, t) in cells along the two sides.
    let to_cells = Matrix2::from_columns(&[along_a, along_b]).try_inverse()?;
    let reach_px = reach_cells * along_a.norm().max(along_b.norm()) + 1.0;
    let sigma = WEIGHT_SIGMA_SHARE * reach_cells;
    let max_shift = MAX_SHIFT_CELLS * along_a.norm().min(along_b.norm());
    let (w, h) = (image.width as i64, image.height as i64);
    let mut q = start;
    for _ in 0..15 {
        let (x0, x1) = (
            (q.x - reach_px).floor() as i64,
            (q.x + reach_px).ceil() as i64,
        );
        let (y0, y1) = (
            (q.y - reach_px).floor() as i64,
            (q.y + reach_px).ceil() as i64,
        );
        if x0 < 1 || y0 < 1 || x1 >= w - 1 || y1 >= h - 1 {
            return None;
        }
        let mut a = Matrix2::<f64>::zeros();
        let mut b = Vector2::<f64>::zeros();
        for y in y0..=y1 {
            for x in x0..=x1 {
                let p = Vector2::new(x as f64, y as f64);
                let st = to_cells * (p - q);
                if st.x.abs() > reach_cells || st.y.abs() > reach_cells {
                    continue;
                }
                let at = |xx: i64, yy: i64| f64::from(image.pixels[(yy * w + xx) as usize]);
                let g =
                    Vector2::new(at(x + 1, y) - at(x - 1, y), at(x, y + 1) - at(x, y - 1)) * 0.5;
                let weight = (-st.norm_squared() / (2.0 * sigma * sigma)).exp();
                let ggt = g * g.transpose() * weight;
                a += ggt;
                b += ggt * p;
            }
        }
        // Both edge directions must be present: a junction, not an edge.
        let eigen = a.symmetric_eigenvalues();
        if eigen.min() <= 1e-3 * eigen.max() {
            return None;
        }
        let next = a.try_inverse()? * b;
        let moved = (next - q).norm();
        q = next;
        if (q - start).norm() > max_shift {
            return None;
        }
        if moved < 1e-3 {
            break;
        }
    }
    Some(q)
}

/// The edge through a junction at `q` along the unit direction `along`:
/// pixels within `band_px` of the line whose distance along it from `q`
/// is between `from_px` and `to_px` either way, weighted by the square of
/// their gradient across the line; the line through their weighted mean
/// along their principal direction. Returns (point, unit direction).
fn edge_line(
    image: &GreyImage,
    q: Vector2<f64>,
    along: Vector2<f64>,
    from_px: f64,
    to_px: f64,
    band_px: f64,
) -> Option<(Vector2<f64>, Vector2<f64>)> {
    let across = Vector2::new(-along.y, along.x);
    let reach = to_px + band_px + 1.0;
    let (w, h) = (image.width as i64, image.height as i64);
    let (x0, x1) = ((q.x - reach).floor() as i64, (q.x + reach).ceil() as i64);
    let (y0, y1) = ((q.y - reach).floor() as i64, (q.y + reach).ceil() as i64);
    if x0 < 1 || y0 < 1 || x1 >= w - 1 || y1 >= h - 1 {
        return None;
    }
    let at = |x: i64, y: i64| f64::from(image.pixels[(y * w + x) as usize]);
    let (mut sum_w, mut mean) = (0.0, Vector2::zeros());
    let mut samples = Vec::new();
    for y in y0..=y1 {
        for x in x0..=x1 {
            let p = Vector2::new(x as f64, y as f64);
            let d = p - q;
            let (t, off) = (d.dot(&along).abs(), d.dot(&across).abs());
            if off >= band_px || t < from_px || t > to_px {
                continue;
            }
            let g = Vector2::new(at(x + 1, y) - at(x - 1, y), at(x, y + 1) - at(x, y - 1)) * 0.5;
            // Tapered to zero at the band's edges, so no row of pixels
            // enters or leaves the sum abruptly as `q` moves.
            let taper = (1.0 - (off / band_px).powi(2)).powi(2);
            let weight = g.dot(&across).powi(2) * taper;
            sum_w += weight;
            mean += p * weight;
            samples.push((p, weight));
        }
    }
    if sum_w <= 0.0 {
        return None;
    }
    mean /= sum_w;
    let mut covariance = Matrix2::<f64>::zeros();
    for (p, weight) in samples {
        let d = p - mean;
        covariance += d * d.transpose() * weight;
    }
    let eigen = covariance.symmetric_eigen();
    let major = if eigen.eigenvalues[0] > eigen.eigenvalues[1] {
        0
    } else {
        1
    };
    Some((mean, eigen.eigenvectors.column(major).into_owned()))
}

/// Where two lines (point, direction) meet.
fn meet(
    a: &(Vector2<f64>, Vector2<f64>),
    b: &(Vector2<f64>, Vector2<f64>),
) -> Option<Vector2<f64>> {
    let m = Matrix2::from_columns(&[a.1, -b.1]);
    let st = m.try_inverse()? * (b.0 - a.0);
    Some(a.0 + a.1 * st.x)
}

/// The junction as the meeting point of its two edges, each a line fitted
/// over `EDGE_FROM_CELLS..EDGE_TO_CELLS` cells either side of the
/// junction (the tag's side one way, the corner square's the other): many
/// more pixels than the window of [`refine_junction`], so less noise.
/// `None` if an edge is missing or the lines meet far from `q`.
pub fn refine_by_edges(
    image: &GreyImage,
    q: Vector2<f64>,
    along_a: Vector2<f64>,
    along_b: Vector2<f64>,
    gap_cells: f64,
) -> Option<Vector2<f64>> {
    // Short of the corner square's far corner when the gaps are narrow;
    // too short a stretch is left to the junction window.
    let to_cells = EDGE_TO_CELLS.min(gap_cells - 0.5);
    if to_cells < EDGE_FROM_CELLS + 1.0 {
        return Some(q);
    }
    let cell = along_a.norm().min(along_b.norm());
    let mut corner = q;
    for _ in 0..EDGE_ITERATIONS {
        // Each edge's band reaches across it by a share of the cells of
        // the other side, the direction the border's width is measured in.
        let line = |along: Vector2<f64>, other: Vector2<f64>| {
            edge_line(
                image,
                corner,
                along.normalize(),
                EDGE_FROM_CELLS * along.norm(),
                to_cells * along.norm(),
                EDGE_BAND_CELLS * other.norm(),
            )
        };
        corner = meet(&line(along_a, along_b)?, &line(along_b, along_a)?)?;
    }
    ((corner - q).norm() < 0.5 * cell).then_some(corner)
}

/// The four corners of `quad` (clockwise as seen) refined, or `None` if
/// any one does not settle (off the image, occluded, not a junction).
/// `spacing_ratio` is the target's gap over tag size (the corner squares
/// are that wide).
pub fn refine_quad(
    image: &GreyImage,
    quad: &[Vector2<f64>; 4],
    spacing_ratio: f64,
) -> Option<[Vector2<f64>; 4]> {
    let gap_cells = 10.0 * spacing_ratio;
    let mut out = *quad;
    for k in 0..4 {
        let next = (quad[(k + 1) % 4] - quad[k]) / 10.0;
        let previous = (quad[(k + 3) % 4] - quad[k]) / 10.0;
        let junction = refine_junction(image, quad[k], next, previous, gap_cells)?;
        out[k] = refine_by_edges(image, junction, next, previous, gap_cells)?;
    }
    Some(out)
}
