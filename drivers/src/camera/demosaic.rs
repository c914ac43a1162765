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
    /// Width or height is below 2: there is no full Bayer cell.
    #[error("Bayer image {width}x{height} is smaller than 2x2")]
    TooSmall {
        /// Image width, pixels.
        width: usize,
        /// Image height, pixels.
        height: usize,
    },
    /// The input ends before its last row does, or `stride < width`.
    #[error("Bayer input holds {got} B, {width}x{height} with stride {stride} needs {needed} B")]
    ShortInput {
        /// Bytes the input held.
        got: usize,
        /// Bytes the image needs: `stride * (height - 1) + width`.
        needed: usize,
        /// Image width, pixels.
        width: usize,
        /// Image height, pixels.
        height: usize,
        /// Given row stride, bytes.
        stride: usize,
    },
    /// The output buffer is too short (RGB: `3 * width * height` bytes,
    /// grey: `width * height`).
    #[error("output holds {got} B, needs {needed} B")]
    ShortOutput {
        /// Bytes the output held.
        got: usize,
        /// Bytes the output needs.
        needed: usize,
    },
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
/// a time, every neighbour read through the mirrored border.
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
            let horiz = (at(xi - 1, yi) + at(xi + 1, yi)).div_ceil(2);
            let vert = (at(xi, yi - 1) + at(xi, yi + 1)).div_ceil(2);
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
/// tightly packed), without the RGB image. Allocates its scratch per call;
/// [`GreyDemosaic`] keeps it between frames.
pub fn bilinear_grey(
    src: &[u8],
    width: usize,
    height: usize,
    stride: usize,
    pattern: BayerPattern,
    out: &mut [u8],
) -> Result<(), DemosaicError> {
    GreyDemosaic::new().run(src, width, height, stride, pattern, out)
}

/// Per-column luma weights of one Bayer row kind: for column `x`, the
/// weight of the centre value, the horizontal, vertical, cross (4 edge
/// neighbours) and diagonal means. They alternate with the column parity.
#[derive(Debug, Default, Clone)]
struct RowWeights {
    centre: Vec<u16>,
    horiz: Vec<u16>,
    vert: Vec<u16>,
    cross: Vec<u16>,
    diag: Vec<u16>,
}

impl RowWeights {
    fn fill(&mut self, width: usize, sites: [Site; 2]) {
        let columns = [weights(sites[0]), weights(sites[1])];
        let all = [
            &mut self.centre,
            &mut self.horiz,
            &mut self.vert,
            &mut self.cross,
            &mut self.diag,
        ];
        for (k, v) in all.into_iter().enumerate() {
            v.clear();
            v.extend((0..width).map(|x| columns[x & 1][k] as u16));
        }
    }
}

/// The grey demosaic with its scratch (per-column weights, a row of
/// vertical sums) kept between calls, so steady-state frames allocate
/// nothing.
///
/// Interior pixels run as straight-line 16-bit arithmetic over whole rows,
/// which the compiler vectorises (AVX2 when the CPU has it, chosen at run
/// time); the first and last columns take the mirrored scalar path.
#[derive(Debug, Default, Clone)]
pub struct GreyDemosaic {
    key: Option<(usize, BayerPattern)>,
    /// Weights for even rows and odd rows.
    rows: [RowWeights; 2],
    vertical_sums: Vec<u16>,
}

impl GreyDemosaic {
    /// A demosaicer with empty scratch; the first [`run`](Self::run) sizes it.
    pub fn new() -> Self {
        Self::default()
    }

    /// Same contract as [`bilinear_grey`].
    pub fn run(
        &mut self,
        src: &[u8],
        width: usize,
        height: usize,
        stride: usize,
        pattern: BayerPattern,
        out: &mut [u8],
    ) -> Result<(), DemosaicError> {
        check(src, width, height, stride, out.len(), width * height)?;
        if self.key != Some((width, pattern)) {
            for (y, row) in self.rows.iter_mut().enumerate() {
                row.fill(width, [site(pattern, 0, y), site(pattern, 1, y)]);
            }
            self.vertical_sums.resize(width, 0);
            self.key = Some((width, pattern));
        }
        for y in 0..height {
            let up = &src[mirror(y as isize - 1, height) * stride..][..width];
            let cur = &src[y * stride..][..width];
            let down = &src[mirror(y as isize + 1, height) * stride..][..width];
            let dst = &mut out[y * width..(y + 1) * width];
            let w = &self.rows[y & 1];
            grey_row(up, cur, down, w, &mut self.vertical_sums, dst);
            let sites = [site(pattern, 0, y), site(pattern, 1, y)];
            let last = width - 1;
            dst[0] = grey_pixel(up, cur, down, 0, weights(sites[0]));
            dst[last] = grey_pixel(up, cur, down, last, weights(sites[last & 1]));
        }
        Ok(())
    }
}

/// Weights of (centre, horizontal mean, vertical mean, cross mean, diagonal
/// mean) in the luma of a photosite of this kind: R = 77, G = 150, B = 29.
fn weights(s: Site) -> [u32; 5] {
    match s {
        Site::Red => [77, 0, 0, 150, 29],
        Site::Blue => [29, 0, 0, 150, 77],
        Site::GreenRedRow => [150, 77, 29, 0, 0],
        Site::GreenBlueRow => [150, 29, 77, 0, 0],
    }
}

/// One pixel through mirrored neighbours (the border columns).
fn grey_pixel(up: &[u8], cur: &[u8], down: &[u8], x: usize, w: [u32; 5]) -> u8 {
    let n = cur.len();
    let l = mirror(x as isize - 1, n);
    let r = mirror(x as isize + 1, n);
    let v = |a: &[u8], i: usize| u32::from(a[i]);
    let lr = v(cur, l) + v(cur, r);
    let ud = v(up, x) + v(down, x);
    let dg = v(up, l) + v(up, r) + v(down, l) + v(down, r);
    let value = w[0] * v(cur, x)
        + w[1] * ((lr + 1) >> 1)
        + w[2] * ((ud + 1) >> 1)
        + w[3] * ((lr + ud + 2) >> 2)
        + w[4] * ((dg + 2) >> 2)
        + 128;
    (value >> 8) as u8
}

/// Interior columns `1..width-1` of one output row.
fn grey_row(up: &[u8], cur: &[u8], down: &[u8], w: &RowWeights, sums: &mut [u16], dst: &mut [u8]) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU has AVX2 (checked just above); the function is
        // safe Rust compiled with AVX2 enabled.
        unsafe { grey_row_avx2(up, cur, down, w, sums, dst) };
        return;
    }
    grey_row_portable(up, cur, down, w, sums, dst);
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn grey_row_avx2(
    up: &[u8],
    cur: &[u8],
    down: &[u8],
    w: &RowWeights,
    sums: &mut [u16],
    dst: &mut [u8],
) {
    grey_row_portable(up, cur, down, w, sums, dst)
}

/// 16-bit lanes never overflow: means are <= 255 and the weights of a pixel
/// add up to 256, so the sum is at most 255 * 256 + 128 < 2^16.
#[inline(always)]
fn grey_row_portable(
    up: &[u8],
    cur: &[u8],
    down: &[u8],
    w: &RowWeights,
    sums: &mut [u16],
    dst: &mut [u8],
) {
    let width = cur.len();
    let (up, down, sums) = (&up[..width], &down[..width], &mut sums[..width]);
    for x in 0..width {
        sums[x] = u16::from(up[x]) + u16::from(down[x]);
    }
    let n = width - 2;
    let (cl, cc, cr) = (&cur[..n], &cur[1..n + 1], &cur[2..n + 2]);
    let (sl, sc, sr) = (&sums[..n], &sums[1..n + 1], &sums[2..n + 2]);
    let wc = &w.centre[1..n + 1];
    let wh = &w.horiz[1..n + 1];
    let wv = &w.vert[1..n + 1];
    let wx = &w.cross[1..n + 1];
    let wd = &w.diag[1..n + 1];
    let out = &mut dst[1..n + 1];
    for i in 0..n {
        let lr = u16::from(cl[i]) + u16::from(cr[i]);
        let ud = sc[i];
        let dg = sl[i] + sr[i];
        let value = wc[i] * u16::from(cc[i])
            + wh[i] * ((lr + 1) >> 1)
            + wv[i] * ((ud + 1) >> 1)
            + wx[i] * ((lr + ud + 2) >> 2)
            + wd[i] * ((dg + 2) >> 2)
            + 128;
        out[i] = (value >> 8) as u8;
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
    fn portable_and_dispatched_rows_agree() {
        // On an AVX2 machine the other tests run the AVX2 build of the row
        // kernel; this one pins the portable build to it.
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        let width = 77;
        let rows: Vec<Vec<u8>> = (0..3)
            .map(|_| (0..width).map(|_| rng.gen()).collect())
            .collect();
        for p in PATTERNS {
            for y in 0..2 {
                let mut w = RowWeights::default();
                w.fill(width, [site(p, 0, y), site(p, 1, y)]);
                let mut sums = vec![0u16; width];
                let (mut a, mut b) = (vec![0u8; width], vec![0u8; width]);
                grey_row(&rows[0], &rows[1], &rows[2], &w, &mut sums, &mut a);
                grey_row_portable(&rows[0], &rows[1], &rows[2], &w, &mut sums, &mut b);
                assert_eq!(a[1..width - 1], b[1..width - 1], "{p:?} row {y}");
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
