//! Bilinear demosaicing of 8-bit Bayer images, to RGB and straight to grey.
//!
//! Bilinear interpolation (e.g. Ramanath et al., "Demosaicking methods for
//! Bayer color arrays", JEI 2002, sec. 2.1): each missing colour at a
//! photosite is the mean of the nearest photosites of that colour,
//!
//! - at R (B): G = mean of the 4 edge neighbours, B (R) = mean of the 4 diagonals;
//! - at G on an R row: R = mean of left/right, B = mean of up/down (and
//!   the other way round on a B row),
//!
//! each mean rounded to nearest (`(sum + n/2) / n`). Borders mirror the
//! image about its edge pixel (index -1 reads 1), which keeps the Bayer
//! phase, so every photosite is interpolated the same way.
//!
//! Grey is ITU-R BT.601 luma of those RGB values in 8-bit fixed point,
//! `Y = (77 R + 150 G + 29 B + 128) >> 8`; [`bilinear_grey`] computes
//! exactly `luma(bilinear_rgb(..))` without forming the RGB image.

use crate::BayerPattern;

/// Colour of a photosite, or which row a green one sits on.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Site {
    Red,
    Blue,
    /// Green on a row with red photosites.
    GreenRedRow,
    /// Green on a row with blue photosites.
    GreenBlueRow,
}

fn site(pattern: BayerPattern, x: usize, y: usize) -> Site {
    // Layout of the top-left 2x2 block, row-major.
    let block = match pattern {
        BayerPattern::Rggb => [Site::Red, Site::GreenRedRow, Site::GreenBlueRow, Site::Blue],
        BayerPattern::Bggr => [Site::Blue, Site::GreenBlueRow, Site::GreenRedRow, Site::Red],
        BayerPattern::Grbg => [Site::GreenRedRow, Site::Red, Site::Blue, Site::GreenBlueRow],
        BayerPattern::Gbrg => [Site::GreenBlueRow, Site::Blue, Site::Red, Site::GreenRedRow],
    };
    block[(y & 1) * 2 + (x & 1)]
}

/// Why a demosaic call cannot run.
#[derive(Debug, Clone, thiserror::Error, PartialEq, Eq)]
pub enum DemosaicError {
    #[error("Bayer image {width}x{height} is smaller than 2x2")]
    TooSmall { width: usize, height: usize },
    #[error("Bayer input holds {got} B, {width}x{height} with stride {stride} needs {needed} B")]
    ShortInput {
        got: usize,
        needed: usize,
        width: usize,
        height: usize,
        stride: usize,
    },
    #[error("output holds {got} B, needs {needed} B")]
    ShortOutput { got: usize, needed: usize },
}

fn check(
    src: &[u8],
    width: usize,
    height: usize,
    stride: usize,
    out_len: usize,
    out_needed: usize,
) -> Result<(), DemosaicError> {
    if width < 2 || height < 2 {
        return Err(DemosaicError::TooSmall { width, height });
    }
    let needed = stride.max(width) * (height - 1) + width;
    if src.len() < needed || stride < width {
        return Err(DemosaicError::ShortInput {
            got: src.len(),
            needed,
            width,
            height,
            stride,
        });
    }
    if out_len < out_needed {
        return Err(DemosaicError::ShortOutput {
            got: out_len,
            needed: out_needed,
        });
    }
    Ok(())
}

/// Mirrored index: -1 -> 1, n -> n-2.
#[inline]
fn mirror(i: isize, n: usize) -> usize {
    if i < 0 {
        (-i) as usize
    } else if i as usize >= n {
        2 * (n - 1) - i as usize
    } else {
        i as usize
    }
}

/// ITU-R BT.601 luma in 8-bit fixed point.
#[inline]
pub fn luma(r: u8, g: u8, b: u8) -> u8 {
    ((77 * u32::from(r) + 150 * u32::from(g) + 29 * u32::from(b) + 128) >> 8) as u8
}

/// Bilinear demosaic into interleaved RGB8 (`out` holds `3 * width * height`
/// bytes, tightly packed). The reference implementation: one photosite at
/// a time, every neighbour through [`mirror`].
pub fn bilinear_rgb(
    src: &[u8],
    width: usize,
    height: usize,
    stride: usize,
    pattern: BayerPattern,
    out: &mut [u8],
) -> Result<(), DemosaicError> {
    check(src, width, height, stride, out.len(), 3 * width * height)?;
    let at = |x: isize, y: isize| -> u32 {
        u32::from(src[mirror(y, height) * stride + mirror(x, width)])
    };
    for y in 0..height {
        for x in 0..width {
            let (xi, yi) = (x as isize, y as isize);
            let c = at(xi, yi);
            let cross = (at(xi - 1, yi) + at(xi + 1, yi) + at(xi, yi - 1) + at(xi, yi + 1) + 2) / 4;
            let diag = (at(xi - 1, yi - 1)
                + at(xi + 1, yi - 1)
                + at(xi - 1, yi + 1)
                + at(xi + 1, yi + 1)
                + 2)
                / 4;
            let horiz = (at(xi - 1, yi) + at(xi + 1, yi) + 1) / 2;
            let vert = (at(xi, yi - 1) + at(xi, yi + 1) + 1) / 2;
            let (r, g, b) = match site(pattern, x, y) {
                Site::Red => (c, cross, diag),
                Site::Blue => (diag, cross, c),
                Site::GreenRedRow => (horiz, c, vert),
                Site::GreenBlueRow => (vert, c, horiz),
            };
            let o = 3 * (y * width + x);
            out[o] = r as u8;
            out[o + 1] = g as u8;
            out[o + 2] = b as u8;
        }
    }
    Ok(())
}

/// Bilinear demosaic straight to grey: exactly
/// `luma(bilinear_rgb(src))` per pixel, into `out` (`width * height` bytes,
/// tightly packed), without the RGB image. The fast path the Bumblebee
/// splitter uses: interior rows run branch-free over column pairs.
pub fn bilinear_grey(
    src: &[u8],
    width: usize,
    height: usize,
    stride: usize,
    pattern: BayerPattern,
    out: &mut [u8],
) -> Result<(), DemosaicError> {
    check(src, width, height, stride, out.len(), width * height)?;
    for y in 0..height {
        let up = &src[mirror(y as isize - 1, height) * stride..][..width];
        let cur = &src[y * stride..][..width];
        let down = &src[mirror(y as isize + 1, height) * stride..][..width];
        let dst = &mut out[y * width..(y + 1) * width];
        grey_row(
            up,
            cur,
            down,
            dst,
            [site(pattern, 0, y), site(pattern, 1, y)],
        );
    }
    Ok(())
}

/// Weights of (centre, horizontal mean, vertical mean, cross mean, diagonal
/// mean) in the luma of a photosite of this kind.
#[inline(always)]
fn weights(s: Site) -> [u32; 5] {
    match s {
        Site::Red => [77, 0, 0, 150, 29],
        Site::Blue => [29, 0, 0, 150, 77],
        Site::GreenRedRow => [150, 77, 29, 0, 0],
        Site::GreenBlueRow => [150, 29, 77, 0, 0],
    }
}

#[inline(always)]
fn grey_at(w: [u32; 5], ul: u8, u: u8, ur: u8, l: u8, c: u8, r: u8, dl: u8, d: u8, dr: u8) -> u8 {
    let (ul, u, ur, l, c, r, dl, d, dr) = (
        u32::from(ul),
        u32::from(u),
        u32::from(ur),
        u32::from(l),
        u32::from(c),
        u32::from(r),
        u32::from(dl),
        u32::from(d),
        u32::from(dr),
    );
    let horiz = (l + r + 1) >> 1;
    let vert = (u + d + 1) >> 1;
    let cross = (l + r + u + d + 2) >> 2;
    let diag = (ul + ur + dl + dr + 2) >> 2;
    ((w[0] * c + w[1] * horiz + w[2] * vert + w[3] * cross + w[4] * diag + 128) >> 8) as u8
}

/// One output row; `sites` are the kinds of columns 0 and 1.
fn grey_row(up: &[u8], cur: &[u8], down: &[u8], dst: &mut [u8], sites: [Site; 2]) {
    let width = cur.len();
    let w_even = weights(sites[0]);
    let w_odd = weights(sites[1]);
    let pixel = |x: usize, w: [u32; 5]| {
        let l = mirror(x as isize - 1, width);
        let r = mirror(x as isize + 1, width);
        grey_at(
            w, up[l], up[x], up[r], cur[l], cur[x], cur[r], down[l], down[x], down[r],
        )
    };
    // Columns 0 and the last one mirror; the rest run over (odd, even) pairs.
    dst[0] = pixel(0, w_even);
    let pairs = (width - 2) / 2;
    for k in 0..pairs {
        let x = 2 * k + 1;
        let win = |a: &[u8]| -> [u8; 4] { [a[x - 1], a[x], a[x + 1], a[x + 2]] };
        let (u4, c4, d4) = (win(up), win(cur), win(down));
        dst[x] = grey_at(
            w_odd, u4[0], u4[1], u4[2], c4[0], c4[1], c4[2], d4[0], d4[1], d4[2],
        );
        dst[x + 1] = grey_at(
            w_even, u4[1], u4[2], u4[3], c4[1], c4[2], c4[3], d4[1], d4[2], d4[3],
        );
    }
    for x in (1 + 2 * pairs)..width {
        dst[x] = pixel(x, if x % 2 == 0 { w_even } else { w_odd });
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    const PATTERNS: [BayerPattern; 4] = [
        BayerPattern::Rggb,
        BayerPattern::Bggr,
        BayerPattern::Grbg,
        BayerPattern::Gbrg,
    ];

    /// Samples an RGB function through a Bayer filter.
    fn mosaic(
        width: usize,
        height: usize,
        pattern: BayerPattern,
        rgb: impl Fn(usize, usize) -> [u8; 3],
    ) -> Vec<u8> {
        let mut out = vec![0; width * height];
        for y in 0..height {
            for x in 0..width {
                let [r, g, b] = rgb(x, y);
                out[y * width + x] = match site(pattern, x, y) {
                    Site::Red => r,
                    Site::Blue => b,
                    Site::GreenRedRow | Site::GreenBlueRow => g,
                };
            }
        }
        out
    }

    #[test]
    fn a_uniform_colour_is_recovered_everywhere() {
        let (w, h) = (9, 7);
        for p in PATTERNS {
            let raw = mosaic(w, h, p, |_, _| [200, 90, 13]);
            let mut rgb = vec![0; 3 * w * h];
            bilinear_rgb(&raw, w, h, w, p, &mut rgb).expect("sizes match");
            for px in rgb.chunks_exact(3) {
                assert_eq!(px, [200, 90, 13], "{p:?}");
            }
            let mut grey = vec![0; w * h];
            bilinear_grey(&raw, w, h, w, p, &mut grey).expect("sizes match");
            assert!(grey.iter().all(|&g| g == luma(200, 90, 13)), "{p:?}");
        }
    }

    #[test]
    fn linear_ramps_are_exact_inside() {
        // Bilinear interpolation reproduces any function linear in x and y
        // (means of symmetric neighbours equal the centre value); even
        // values keep every mean an integer, so no rounding enters.
        let (w, h) = (12, 10);
        let ramp = |x: usize, y: usize| {
            [
                (10 + 8 * x + 2 * y) as u8,
                (200 - 6 * x - 4 * y) as u8,
                (30 + 4 * x + 10 * y) as u8,
            ]
        };
        for p in PATTERNS {
            let raw = mosaic(w, h, p, ramp);
            let mut rgb = vec![0; 3 * w * h];
            bilinear_rgb(&raw, w, h, w, p, &mut rgb).expect("sizes match");
            for y in 1..h - 1 {
                for x in 1..w - 1 {
                    let o = 3 * (y * w + x);
                    assert_eq!(rgb[o..o + 3], ramp(x, y), "{p:?} at ({x},{y})");
                }
            }
        }
    }

    #[test]
    fn hand_computed_rggb_block() {
        // R G R
        // G B G
        // R G R   (3x3, RGGB): the centre B photosite and the corner R.
        let raw = [10u8, 20, 30, 40, 50, 60, 70, 80, 90];
        let mut rgb = [0u8; 27];
        bilinear_rgb(&raw, 3, 3, 3, BayerPattern::Rggb, &mut rgb).expect("3x3");
        // Centre (B): R = diagonals (10+30+70+90+2)/4 = 50, G = (20+40+60+80+2)/4 = 50.
        assert_eq!(rgb[12..15], [50, 50, 50]);
        // Top-left R: mirrored neighbours are (1,0)=20 twice and (0,1)=40
        // twice -> G = (20+20+40+40+2)/4 = 30; B = 4 x (1,1) = 50.
        assert_eq!(rgb[0..3], [10, 30, 50]);
        // (1,0) G on the R row: R = (10+30+1)/2 = 20, B = (50+50+1)/2 = 50.
        assert_eq!(rgb[3..6], [20, 20, 50]);
    }

    #[test]
    fn grey_equals_luma_of_rgb_on_noise() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        for (w, h) in [(2, 2), (3, 5), (16, 9), (33, 17)] {
            let stride = w + 3;
            let raw: Vec<u8> = (0..stride * h).map(|_| rng.gen()).collect();
            for p in PATTERNS {
                let mut rgb = vec![0; 3 * w * h];
                bilinear_rgb(&raw, w, h, stride, p, &mut rgb).expect("sizes match");
                let mut grey = vec![0; w * h];
                bilinear_grey(&raw, w, h, stride, p, &mut grey).expect("sizes match");
                for (i, px) in rgb.chunks_exact(3).enumerate() {
                    assert_eq!(
                        grey[i],
                        luma(px[0], px[1], px[2]),
                        "{p:?} {w}x{h} pixel {i}"
                    );
                }
            }
        }
    }

    #[test]
    fn bad_sizes_are_errors() {
        let mut out = [0u8; 4];
        assert_eq!(
            bilinear_grey(&[0; 4], 1, 4, 1, BayerPattern::Rggb, &mut out),
            Err(DemosaicError::TooSmall {
                width: 1,
                height: 4
            })
        );
        assert!(matches!(
            bilinear_grey(&[0; 3], 2, 2, 2, BayerPattern::Rggb, &mut out),
            Err(DemosaicError::ShortInput { .. })
        ));
        assert!(matches!(
            bilinear_rgb(&[0; 4], 2, 2, 2, BayerPattern::Rggb, &mut out),
            Err(DemosaicError::ShortOutput { got: 4, needed: 12 })
        ));
    }
}
