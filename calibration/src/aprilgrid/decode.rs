//! Reading a tag's code off a candidate quadrilateral.
//!
//! Tag cell coordinates `(u, v)`: `u` from the quad's first corner towards
//! its second, `v` from its first towards its fourth, one unit per cell; a
//! Kalibr tag is 10 cells across (a black border 2 cells wide around 6x6
//! data cells). A homography maps the cells onto the image. The threshold
//! of each data cell is the mean of two planes in `(u, v)` fitted to the
//! grey levels along the middle of the black border and of the white gap
//! around the tag, which follows a brightness gradient across the tag.
//! Cells are sharpened against their neighbours before the threshold and
//! the code is matched softly (`tag36h11::decode_soft`), so tags whose
//! cells blur into each other (cells of 2.5 px under a 1.5 px blur) still
//! read.

use nalgebra::{Matrix3, Vector2, Vector3};

use super::tag36h11::{self, DATA_CELLS};
use super::target::AprilGridTarget;
use crate::chessboard::GreyImage;
use crate::homography::homography_dlt;

/// Cells across a tag.
const CELLS: f64 = 10.0;
/// Border width, cells.
const BORDER: f64 = 2.0;
/// Least white-minus-black contrast, grey levels.
const MIN_CONTRAST: f64 = 15.0;
/// Weight of a data cell's difference from its neighbours added to it.
const SHARPEN: f64 = 0.5;
/// Largest sum of the margins of the cells read wrong (see `decode_soft`).
const MAX_SOFT_COST: f64 = 0.6;
/// Share of border and gap samples that must be on the right side of the
/// threshold.
const MIN_AGREEMENT: f64 = 0.85;

/// A tag read off the image.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DecodedTag {
    pub id: usize,
    /// Corners in the target's order (corner_idx 0..3: the tag's
    /// bottom-left, bottom-right, top-right, top-left as printed), image
    /// pixels.
    pub corners_px: [Vector2<f64>; 4],
    /// Data bits that differ from the codeword.
    pub hamming: u32,
}

struct Sampler<'a> {
    image: &'a GreyImage,
    h: Matrix3<f64>,
}

impl Sampler<'_> {
    /// Grey level at `(u, v)` (bilinear): one sample, as a mean over the
    /// cell would blur small cells further.
    fn at(&self, u: f64, v: f64) -> Option<f64> {
        let p = self.h * Vector3::new(u, v, 1.0);
        if p.z.abs() < 1e-12 {
            return None;
        }
        self.image.sample(p.x / p.z, p.y / p.z).map(f64::from)
    }
}

/// Least-squares plane `a + b u + c v` through `(u, v, grey)` samples; the
/// mean if the points are degenerate.
fn fit_plane(samples: &[(f64, f64, f64)]) -> impl Fn(f64, f64) -> f64 {
    let mut ata = Matrix3::<f64>::zeros();
    let mut atb = Vector3::<f64>::zeros();
    for &(u, v, g) in samples {
        let row = Vector3::new(1.0, u, v);
        ata += row * row.transpose();
        atb += row * g;
    }
    let mean = atb[0] / (samples.len().max(1) as f64);
    let coefficients = ata
        .try_inverse()
        .map(|inv| inv * atb)
        .unwrap_or(Vector3::new(mean, 0.0, 0.0));
    move |u, v| coefficients[0] + coefficients[1] * u + coefficients[2] * v
}

/// The tag inside `quad` (image pixels, clockwise as seen), if its border
/// and gap look right and its code is within `max_hamming` bits of the
/// codeword of a tag on `target`.
pub fn decode_quad(
    image: &GreyImage,
    quad: &[Vector2<f64>; 4],
    target: &AprilGridTarget,
    max_hamming: u32,
) -> Option<DecodedTag> {
    let cell_corners = [
        Vector2::new(0.0, 0.0),
        Vector2::new(CELLS, 0.0),
        Vector2::new(CELLS, CELLS),
        Vector2::new(0.0, CELLS),
    ];
    let sampler = Sampler {
        image,
        h: homography_dlt(&cell_corners, quad)?,
    };
    // The middle line of the border, away from the white around it.
    let mut black = Vec::new();
    for k in 0..CELLS as usize {
        let along = k as f64 + 0.5;
        let (near, far) = (0.5 * BORDER, CELLS - 0.5 * BORDER);
        for (u, v) in [(along, near), (along, far), (near, along), (far, along)] {
            black.push((u, v, sampler.at(u, v)?));
        }
    }
    // The middle of the gap between tags, away from the corner squares.
    let gap = -(0.5 * target.tag_spacing_ratio * CELLS).min(2.0);
    let mut white = Vec::new();
    for k in 1..CELLS as usize - 1 {
        let along = k as f64 + 0.5;
        for (u, v) in [
            (along, gap),
            (along, CELLS - gap),
            (gap, along),
            (CELLS - gap, along),
        ] {
            white.push((u, v, sampler.at(u, v)?));
        }
    }
    let black_level = fit_plane(&black);
    let white_level = fit_plane(&white);
    let threshold = |u: f64, v: f64| 0.5 * (black_level(u, v) + white_level(u, v));
    let middle = 0.5 * CELLS;
    if white_level(middle, middle) - black_level(middle, middle) < MIN_CONTRAST {
        return None;
    }
    let agree = |samples: &[(f64, f64, f64)], dark: bool| {
        samples
            .iter()
            .filter(|&&(u, v, g)| (g < threshold(u, v)) == dark)
            .count() as f64
            >= MIN_AGREEMENT * samples.len() as f64
    };
    if !agree(&black, true) || !agree(&white, false) {
        return None;
    }
    // Every cell's grey level, then each data cell sharpened against its
    // four neighbours (`v + SHARPEN (v - mean of neighbours)`): blur pulls a
    // lone white cell among black ones below the midway threshold, the
    // contrast with its neighbours pushes it back; flat areas are
    // unchanged, so the thresholds still hold.
    let mut cells = [[0.0f64; 10]; 10];
    for (row, cells_in_row) in cells.iter_mut().enumerate() {
        for (col, cell) in cells_in_row.iter_mut().enumerate() {
            *cell = sampler.at(col as f64 + 0.5, row as f64 + 0.5)?;
        }
    }
    // Each data cell's margin over its threshold, in units of the local
    // white-minus-black contrast: about +-0.5 for a clear cell, near 0 for
    // one blurred into its neighbours.
    let mut margins = [0.0f64; DATA_CELLS * DATA_CELLS];
    for (i, margin) in margins.iter_mut().enumerate() {
        let (row, col) = (i / DATA_CELLS + 2, i % DATA_CELLS + 2);
        let neighbours = 0.25
            * (cells[row - 1][col]
                + cells[row + 1][col]
                + cells[row][col - 1]
                + cells[row][col + 1]);
        let value = cells[row][col] + SHARPEN * (cells[row][col] - neighbours);
        let (u, v) = (col as f64 + 0.5, row as f64 + 0.5);
        let contrast = (white_level(u, v) - black_level(u, v)).max(MIN_CONTRAST);
        *margin = (value - threshold(u, v)) / contrast;
    }
    let found = tag36h11::decode_soft(&margins, target.tag_count(), max_hamming, MAX_SOFT_COST)?;
    // After `k` clockwise quarter turns of the reading the tag is upright:
    // its top-left corner is the quad corner that turned into the reading's
    // top-left.
    let k = found.quarter_turns as usize;
    let top_left = (4 - k) % 4;
    let at = |offset: usize| quad[(top_left + offset) % 4];
    Some(DecodedTag {
        id: found.id,
        corners_px: [at(3), at(2), at(1), at(0)],
        hamming: found.hamming,
    })
}
