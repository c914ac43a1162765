//! Subpixel tag corners. On an AprilGrid every tag corner touches a corner
//! square, so it is an x-junction (dark tag and square on one diagonal,
//! white gaps on the other). Every pixel `p` near a junction `q` either
//! has no gradient or lies on an edge through `q`, so `g(p)^T (p - q) = 0`;
//! least squares gives `q = (sum w g g^T)^-1 sum w g g^T p` (Förstner and
//! Gülch 1987, the equation of OpenCV's `cornerSubPix`), iterated with the
//! window recentred.
//!
//! The window is not a square of pixels but a parallelogram along the
//! tag's two sides at the corner, reaching [`REACH_CELLS`] tag cells each
//! way: inside the tag's 2-cell black border on one side and the 3-cell
//! gaps and corner square on the other, so no edge but the junction's two
//! is in it however obliquely the tag is seen. A point-symmetric window on
//! a point-symmetric junction leaves no bias from blur.

use nalgebra::{Matrix2, Vector2};

use crate::chessboard::GreyImage;

/// Window half-width along each side, tag cells (a tag is 10 cells).
pub const REACH_CELLS: f64 = 1.4;
/// Samples from the centre to the window's edge along each side.
const STEPS: i32 = 7;
/// Largest move from the first estimate, cells.
const MAX_SHIFT_CELLS: f64 = 1.2;

/// Refines the junction near `start`; `along_a` and `along_b` are one tag
/// cell along the tag's two sides from this corner, px. `None` if it
/// drifts off, leaves the image or the window has no junction.
pub fn refine_junction(
    image: &GreyImage,
    start: Vector2<f64>,
    along_a: Vector2<f64>,
    along_b: Vector2<f64>,
) -> Option<Vector2<f64>> {
    let step = REACH_CELLS / STEPS as f64;
    let sigma = 0.6 * REACH_CELLS;
    let max_shift = MAX_SHIFT_CELLS * along_a.norm().min(along_b.norm());
    let mut q = start;
    for _ in 0..15 {
        let mut a = Matrix2::<f64>::zeros();
        let mut b = Vector2::<f64>::zeros();
        for i in -STEPS..=STEPS {
            for j in -STEPS..=STEPS {
                let (s, t) = (i as f64 * step, j as f64 * step);
                let p = q + along_a * s + along_b * t;
                let gx = image.sample(p.x + 1.0, p.y)? - image.sample(p.x - 1.0, p.y)?;
                let gy = image.sample(p.x, p.y + 1.0)? - image.sample(p.x, p.y - 1.0)?;
                let g = Vector2::new(f64::from(gx), f64::from(gy)) * 0.5;
                let weight = (-(s * s + t * t) / (2.0 * sigma * sigma)).exp();
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

/// The four corners of `quad` (clockwise as seen) refined, or `None` if
/// any one does not settle (off the image, occluded, not a junction).
pub fn refine_quad(image: &GreyImage, quad: &[Vector2<f64>; 4]) -> Option<[Vector2<f64>; 4]> {
    let mut out = *quad;
    for k in 0..4 {
        let next = (quad[(k + 1) % 4] - quad[k]) / 10.0;
        let previous = (quad[(k + 3) % 4] - quad[k]) / 10.0;
        out[k] = refine_junction(image, quad[k], next, previous)?;
    }
    Some(out)
}
