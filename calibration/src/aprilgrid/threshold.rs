//! Adaptive threshold into a dark/not-dark mask, and the erosion that cuts
//! the one-pixel bridges where a tag's corner touches a corner square.
//!
//! The threshold of each `TILE x TILE` tile is the midpoint of the darkest
//! and brightest pixel of the lightly smoothed image in the 3x3 tiles
//! around it (the AprilTag 3 scheme). Tiles whose neighbourhood has too
//! little contrast (inside a thick border, on a blank wall) take the mean
//! threshold of their neighbours, spread over a few passes; tiles no
//! contrast reaches stay undecided and their pixels count as not dark.
//! Dark pixels at strong saddles of the image are cleared (see
//! `threshold`).

use crate::chessboard::GreyImage;

/// Tile edge, px.
const TILE: usize = 4;
/// Least brightest-minus-darkest of a neighbourhood for its own threshold,
/// grey levels (of the smoothed image).
const MIN_CONTRAST: f32 = 20.0;
/// `-det(Hessian)` over contrast squared above which a dark pixel is a
/// saddle and is cleared (an ideal x-junction blurred by `sigma` px peaks
/// at about `0.1 / sigma^4`).
const SADDLE_STRENGTH: f32 = 0.008;
/// Passes that spread thresholds into flat tiles: reaches `FILL_PASSES *
/// TILE` px into a flat region.
const FILL_PASSES: usize = 12;

/// Row-major mask, `true` = dark.
#[derive(Debug, Clone)]
pub struct Mask {
    pub width: usize,
    pub height: usize,
    pub dark: Vec<bool>,
}

impl Mask {
    #[inline]
    pub fn at(&self, x: usize, y: usize) -> bool {
        self.dark[y * self.width + x]
    }
}

/// The dark mask of `smoothed` (see the module doc).
pub fn threshold(smoothed: &GreyImage) -> Mask {
    let (w, h) = (smoothed.width, smoothed.height);
    let (tw, th) = (w.div_ceil(TILE), h.div_ceil(TILE));
    let mut tile_min = vec![f32::MAX; tw * th];
    let mut tile_max = vec![f32::MIN; tw * th];
    for y in 0..h {
        for x in 0..w {
            let v = smoothed.pixels[y * w + x];
            let t = (y / TILE) * tw + x / TILE;
            tile_min[t] = tile_min[t].min(v);
            tile_max[t] = tile_max[t].max(v);
        }
    }
    // Threshold per tile from its 3x3 neighbourhood; NaN = undecided.
    let mut thresholds = vec![f32::NAN; tw * th];
    let mut tile_contrast = vec![0.0f32; tw * th];
    for ty in 0..th {
        for tx in 0..tw {
            let (mut lo, mut hi) = (f32::MAX, f32::MIN);
            for ny in ty.saturating_sub(1)..(ty + 2).min(th) {
                for nx in tx.saturating_sub(1)..(tx + 2).min(tw) {
                    lo = lo.min(tile_min[ny * tw + nx]);
                    hi = hi.max(tile_max[ny * tw + nx]);
                }
            }
            tile_contrast[ty * tw + tx] = hi - lo;
            if hi - lo >= MIN_CONTRAST {
                thresholds[ty * tw + tx] = 0.5 * (lo + hi);
            }
        }
    }
    for _ in 0..FILL_PASSES {
        let before = thresholds.clone();
        let mut changed = false;
        for ty in 0..th {
            for tx in 0..tw {
                if !before[ty * tw + tx].is_nan() {
                    continue;
                }
                let (mut sum, mut n) = (0.0f32, 0u32);
                for ny in ty.saturating_sub(1)..(ty + 2).min(th) {
                    for nx in tx.saturating_sub(1)..(tx + 2).min(tw) {
                        let v = before[ny * tw + nx];
                        if !v.is_nan() {
                            sum += v;
                            n += 1;
                        }
                    }
                }
                if n > 0 {
                    thresholds[ty * tw + tx] = sum / n as f32;
                    changed = true;
                }
            }
        }
        if !changed {
            break;
        }
    }
    let mut dark = vec![false; w * h];
    for y in 0..h {
        for x in 0..w {
            let t = thresholds[(y / TILE) * tw + x / TILE];
            // A NaN threshold compares false: undecided is not dark.
            dark[y * w + x] = smoothed.pixels[y * w + x] < t;
        }
    }
    // Saddles: where a tag's corner meets its corner square the dark
    // regions touch, through a neck that widens when the junction is seen
    // obliquely and blurred. `-det(Hessian)` peaks there (and at corners);
    // clearing the dark pixels where it is strong for the local contrast
    // separates the tag from the square.
    for y in 1..h.saturating_sub(1) {
        for x in 1..w.saturating_sub(1) {
            let i = y * w + x;
            if !dark[i] {
                continue;
            }
            let t = (y / TILE) * tw + x / TILE;
            let contrast = tile_contrast[t];
            if contrast < MIN_CONTRAST {
                continue;
            }
            let p = &smoothed.pixels;
            let ixx = p[i - 1] - 2.0 * p[i] + p[i + 1];
            let iyy = p[i - w] - 2.0 * p[i] + p[i + w];
            let ixy = 0.25 * (p[i + w + 1] - p[i + w - 1] - p[i - w + 1] + p[i - w - 1]);
            if ixy * ixy - ixx * iyy > SADDLE_STRENGTH * contrast * contrast {
                dark[i] = false;
            }
        }
    }
    Mask {
        width: w,
        height: h,
        dark,
    }
}

/// Keeps a dark pixel only if its 8 neighbours are dark too; the image's
/// edge rows and columns are cleared.
pub fn erode(mask: &Mask) -> Mask {
    let (w, h) = (mask.width, mask.height);
    let mut dark = vec![false; w * h];
    for y in 1..h.saturating_sub(1) {
        for x in 1..w.saturating_sub(1) {
            dark[y * w + x] = (y - 1..=y + 1).all(|yy| (x - 1..=x + 1).all(|xx| mask.at(xx, yy)));
        }
    }
    Mask {
        width: w,
        height: h,
        dark,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A dark square on a bright ground with a brightness ramp: the mask is
    /// the square, including its flat middle far from any edge.
    #[test]
    fn dark_square_under_a_ramp_is_dark_through_its_middle() {
        let (w, h) = (120, 100);
        let pixels = (0..w * h)
            .map(|i| {
                let (x, y) = (i % w, i / w);
                let ramp = 0.4 * x as f32;
                let inside = (30..90).contains(&x) && (20..80).contains(&y);
                if inside {
                    30.0 + ramp
                } else {
                    180.0 + ramp
                }
            })
            .collect();
        let image = GreyImage {
            width: w,
            height: h,
            pixels,
        };
        let mask = threshold(&image);
        for y in 0..h {
            for x in 0..w {
                let inside = (30..90).contains(&x) && (20..80).contains(&y);
                assert_eq!(mask.at(x, y), inside, "({x}, {y})");
            }
        }
        let eroded = erode(&mask);
        assert!(eroded.at(31, 21) && !eroded.at(30, 20) && !eroded.at(89, 50));
    }
}
