//! Image pyramids with owned, reused level buffers.
//!
//! Level 0 is the input as 8-bit grey (16-bit input is shifted down by its
//! significant bits, as [`Image::grey8_at`] does). Each further level is the
//! previous one shrunk by `scale`: by exactly 2 with a [1 2 1] x [1 2 1] / 16
//! blur sampled at even pixels (the KLT pyramid), by any other factor with
//! bilinear resampling (the ORB pyramid, 1.2 per level). Rebuilding for a
//! frame of the same size reuses every buffer.

use crate::features::FeatureError;
use crate::sensors::{Image, PixelFormat};

/// An owned, tightly packed 8-bit grey image (row `y` is
/// `data[y * width..(y + 1) * width]`).
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct GreyImage {
    /// Width, px.
    pub width: usize,
    /// Height, px.
    pub height: usize,
    /// Grey levels, row-major, `width * height` bytes.
    pub data: Vec<u8>,
}

impl GreyImage {
    /// A `width` x `height` image filled with `value`.
    pub fn filled(width: usize, height: usize, value: u8) -> Self {
        Self {
            width,
            height,
            data: vec![value; width * height],
        }
    }

    /// Wraps a packed buffer after checking its size.
    pub fn from_vec(width: usize, height: usize, data: Vec<u8>) -> Result<Self, FeatureError> {
        if width == 0 || height == 0 {
            return Err(FeatureError::Empty { width, height });
        }
        if data.len() < width * height {
            return Err(FeatureError::BufferTooShort {
                got: data.len(),
                width,
                height,
            });
        }
        Ok(Self {
            width,
            height,
            data,
        })
    }

    /// Row `y` (panics past the end, like slice indexing).
    #[inline]
    pub fn row(&self, y: usize) -> &[u8] {
        &self.data[y * self.width..(y + 1) * self.width]
    }

    /// Pixel at integer (x, y); callers keep inside the image.
    #[inline]
    pub fn at(&self, x: usize, y: usize) -> u8 {
        self.data[y * self.width + x]
    }

    /// Resizes in place, keeping the allocation when it is large enough.
    fn reshape(&mut self, width: usize, height: usize) {
        self.width = width;
        self.height = height;
        self.data.resize(width * height, 0);
    }

    /// Copies a sensor image in as 8-bit grey; 16-bit grey keeps its top
    /// 8 significant bits. Bayer mosaics are refused.
    pub fn assign_from(&mut self, image: &Image) -> Result<(), FeatureError> {
        let (width, height) = (image.width() as usize, image.height() as usize);
        if width == 0 || height == 0 {
            return Err(FeatureError::Empty { width, height });
        }
        let shift = match image.format() {
            PixelFormat::Mono8 => None,
            PixelFormat::Mono16 { significant_bits } => Some(significant_bits.saturating_sub(8)),
            other => {
                return Err(FeatureError::UnsupportedFormat {
                    format: format!("{other:?}"),
                })
            }
        };
        self.reshape(width, height);
        for y in 0..height {
            let src = image.row(y as u32).expect("y < height");
            let dst = &mut self.data[y * width..(y + 1) * width];
            match shift {
                None => dst.copy_from_slice(src),
                Some(shift) => {
                    for (d, s) in dst.iter_mut().zip(src.chunks_exact(2)) {
                        let v = u16::from_le_bytes([s[0], s[1]]);
                        *d = (u32::from(v) >> shift).min(255) as u8;
                    }
                }
            }
        }
        Ok(())
    }
}

/// How many levels and how much each shrinks.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PyramidConfig {
    /// Levels wanted, the input included (>= 1).
    pub levels: usize,
    /// Size ratio between consecutive levels (> 1).
    pub scale: f32,
    /// No level is made whose width or height would fall below this.
    pub min_side_px: usize,
}

impl PyramidConfig {
    /// Three halving levels, as the KLT tracker uses.
    pub fn klt() -> Self {
        Self {
            levels: 3,
            scale: 2.0,
            min_side_px: 16,
        }
    }

    /// Eight levels 1.2 apart, as ORB uses.
    pub fn orb() -> Self {
        Self {
            levels: 8,
            scale: 1.2,
            min_side_px: 32,
        }
    }

    fn validate(&self) -> Result<(), FeatureError> {
        if self.levels == 0 || !(self.scale > 1.0) || !self.scale.is_finite() {
            return Err(FeatureError::Config(format!(
                "pyramid needs levels >= 1 and a finite scale > 1, got {} levels, scale {}",
                self.levels, self.scale
            )));
        }
        Ok(())
    }
}

/// A pyramid whose level buffers live as long as it does.
#[derive(Debug, Clone)]
pub struct Pyramid {
    config: PyramidConfig,
    levels: Vec<GreyImage>,
    /// How many of `levels` hold the current frame.
    used: usize,
    /// Bilinear column table for the non-halving case: source column and
    /// weight (0..=256) of the right neighbour, per destination column.
    columns: ColumnTable,
    /// One source row blended vertically (both cases).
    row_buffer: Vec<u16>,
}

impl Pyramid {
    /// A pyramid with `config` and no levels built yet; [`FeatureError::Config`] unless `levels >=
    /// 1` and `scale` is finite and > 1.
    pub fn new(config: PyramidConfig) -> Result<Self, FeatureError> {
        config.validate()?;
        Ok(Self {
            config,
            levels: Vec::with_capacity(config.levels),
            used: 0,
            columns: ColumnTable::default(),
            row_buffer: Vec::new(),
        })
    }

    /// The settings it was built with.
    pub fn config(&self) -> &PyramidConfig {
        &self.config
    }

    /// Levels holding the current frame (fewer than configured for small images).
    pub fn levels(&self) -> &[GreyImage] {
        &self.levels[..self.used]
    }

    /// Level `i` of the current frame.
    pub fn level(&self, i: usize) -> &GreyImage {
        &self.levels()[i]
    }

    /// Size ratio of level `i` to level 0 (level-0 coordinates = level-i
    /// coordinates x this).
    pub fn scale_of(&self, i: usize) -> f32 {
        self.config.scale.powi(i as i32)
    }

    /// Rebuilds from a sensor image.
    pub fn build(&mut self, image: &Image) -> Result<(), FeatureError> {
        if self.levels.is_empty() {
            self.levels.push(GreyImage::default());
        }
        self.levels[0].assign_from(image)?;
        self.build_upper_levels();
        Ok(())
    }

    /// Rebuilds from a packed grey buffer.
    pub fn build_from_grey(
        &mut self,
        width: usize,
        height: usize,
        pixels: &[u8],
    ) -> Result<(), FeatureError> {
        if width == 0 || height == 0 {
            return Err(FeatureError::Empty { width, height });
        }
        if pixels.len() < width * height {
            return Err(FeatureError::BufferTooShort {
                got: pixels.len(),
                width,
                height,
            });
        }
        if self.levels.is_empty() {
            self.levels.push(GreyImage::default());
        }
        let base = &mut self.levels[0];
        base.reshape(width, height);
        base.data.copy_from_slice(&pixels[..width * height]);
        self.build_upper_levels();
        Ok(())
    }

    fn build_upper_levels(&mut self) {
        self.used = 1;
        for i in 1..self.config.levels {
            let prev = &self.levels[i - 1];
            let (w, h) = if self.config.scale == 2.0 {
                (prev.width.div_ceil(2), prev.height.div_ceil(2))
            } else {
                let s = self.scale_of(i);
                let base = &self.levels[0];
                (
                    (base.width as f32 / s).round() as usize,
                    (base.height as f32 / s).round() as usize,
                )
            };
            if w < self.config.min_side_px || h < self.config.min_side_px {
                break;
            }
            if self.levels.len() <= i {
                self.levels.push(GreyImage::default());
            }
            let (lower, upper) = self.levels.split_at_mut(i);
            let src = &lower[i - 1];
            let dst = &mut upper[0];
            dst.reshape(w, h);
            if self.config.scale == 2.0 {
                halve(src, dst, &mut self.row_buffer);
            } else {
                resample_bilinear(src, dst, &mut self.columns, &mut self.row_buffer);
            }
            self.used = i + 1;
        }
    }
}

/// dst(x, y) = ([1 2 1] x [1 2 1] / 16 blur of src)(2x, 2y), borders
/// replicated. Each source row triple is summed vertically once into
/// `vertical` (at most 4 x 255, a u16), then blurred across at every other
/// column: integer arithmetic, so the order of the sums changes nothing.
fn halve(src: &GreyImage, dst: &mut GreyImage, vertical: &mut Vec<u16>) {
    let (sw, sh) = (src.width, src.height);
    let clamp_y = |y: isize| y.clamp(0, sh as isize - 1) as usize;
    vertical.clear();
    vertical.resize(sw, 0);
    for y in 0..dst.height {
        let sy = 2 * y as isize;
        let (r0, r1, r2) = (
            src.row(clamp_y(sy - 1)),
            src.row(clamp_y(sy)),
            src.row(clamp_y(sy + 1)),
        );
        for (((v, &a), &b), &c) in vertical.iter_mut().zip(r0).zip(r1).zip(r2) {
            *v = u16::from(a) + 2 * u16::from(b) + u16::from(c);
        }
        let v = vertical.as_slice();
        let out = &mut dst.data[y * dst.width..(y + 1) * dst.width];
        let blur =
            |left: u16, centre: u16, right: u16| ((left + 2 * centre + right + 8) >> 4) as u8;
        // Columns whose three source columns are all inside: 1 <= x and
        // 2x + 1 < sw.
        let inner_end = (sw.saturating_sub(1) / 2).min(out.len());
        for x in 1..inner_end {
            let sx = 2 * x;
            out[x] = blur(v[sx - 1], v[sx], v[sx + 1]);
        }
        for x in (0..1.min(out.len())).chain(inner_end.max(1)..out.len()) {
            let sx = 2 * x;
            out[x] = blur(v[sx.saturating_sub(1)], v[sx], v[(sx + 1).min(sw - 1)]);
        }
    }
}

/// Per destination column of a resampling: the left source column and
/// the weight (0..=256) of its right neighbour, as separate i32 arrays so
/// that eight columns load as one vector.
#[derive(Debug, Clone, Default)]
struct ColumnTable {
    left: Vec<i32>,
    weight: Vec<i32>,
}

/// Bilinear resampling with pixel centres aligned: source coordinate
/// (x + 0.5) * sw / dw - 0.5. Weights in 8-bit fixed point.
fn resample_bilinear(
    src: &GreyImage,
    dst: &mut GreyImage,
    columns: &mut ColumnTable,
    row_buffer: &mut Vec<u16>,
) {
    let (sw, sh) = (src.width, src.height);
    let fx = sw as f32 / dst.width as f32;
    let fy = sh as f32 / dst.height as f32;
    columns.left.clear();
    columns.weight.clear();
    for x in 0..dst.width {
        let s = ((x as f32 + 0.5) * fx - 0.5).clamp(0.0, (sw - 1) as f32);
        let x0 = (s as usize).min(sw.saturating_sub(2));
        let w = ((s - x0 as f32) * 256.0).round() as i32;
        columns.left.push(x0 as i32);
        columns.weight.push(w.min(256));
    }
    let single_column = sw == 1;
    #[cfg(target_arch = "x86_64")]
    let avx2 = !single_column && std::arch::is_x86_feature_detected!("avx2");
    // Vertical blend of the two source rows first (a vector loop over the
    // whole row, exact in u16: at most 255 * 256), then the horizontal
    // blend at each column; the same integer sum as blending the other way.
    let mut blended = std::mem::take(row_buffer);
    blended.resize(sw, 0);
    for y in 0..dst.height {
        let s = ((y as f32 + 0.5) * fy - 0.5).clamp(0.0, (sh - 1) as f32);
        let y0 = (s as usize).min(sh.saturating_sub(2));
        let wy = (((s - y0 as f32) * 256.0).round() as u16).min(256);
        let top = src.row(y0);
        let bottom = src.row((y0 + 1).min(sh - 1));
        for ((v, &t), &b) in blended.iter_mut().zip(top).zip(bottom) {
            *v = u16::from(t) * (256 - wy) + u16::from(b) * wy;
        }
        let out = &mut dst.data[y * dst.width..(y + 1) * dst.width];
        let mut x = 0;
        // SAFETY: AVX2 detected; every left column + 1 < sw (sw >= 2).
        #[cfg(target_arch = "x86_64")]
        if avx2 {
            x = unsafe { blend_columns_avx2(&blended, columns, out) };
        }
        for x in x..out.len() {
            let x0 = columns.left[x] as usize;
            let x1 = if single_column { x0 } else { x0 + 1 };
            let wx = columns.weight[x] as u32;
            let v = u32::from(blended[x0]) * (256 - wx) + u32::from(blended[x1]) * wx;
            out[x] = ((v + (1 << 15)) >> 16) as u8;
        }
    }
    *row_buffer = blended;
}

/// The horizontal blend of [`resample_bilinear`] for 8 columns at a time:
/// one 32-bit gather fetches both u16 neighbours of each column. Returns
/// the first column it did not do.
///
/// # Safety
/// The CPU must have AVX2; every `columns.left` + 1 < `blended.len()`.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn blend_columns_avx2(blended: &[u16], columns: &ColumnTable, out: &mut [u8]) -> usize {
    use std::arch::x86_64::*;
    let n = out.len().min(columns.left.len());
    let low16 = _mm256_set1_epi32(0xffff);
    let full = _mm256_set1_epi32(256);
    let half = _mm256_set1_epi32(1 << 15);
    // Byte 2 of every 32-bit lane (the result after >> 16) to the low four
    // bytes of each 128-bit half.
    let pick = _mm256_setr_epi8(
        2, 6, 10, 14, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1, 2, 6, 10, 14, -1, -1, -1, -1,
        -1, -1, -1, -1, -1, -1, -1, -1,
    );
    let mut x = 0;
    while x + 8 <= n {
        let left = _mm256_loadu_si256(columns.left.as_ptr().add(x) as *const __m256i);
        let wx = _mm256_loadu_si256(columns.weight.as_ptr().add(x) as *const __m256i);
        let pair = _mm256_i32gather_epi32::<2>(blended.as_ptr() as *const i32, left);
        let v = _mm256_add_epi32(
            _mm256_mullo_epi32(_mm256_and_si256(pair, low16), _mm256_sub_epi32(full, wx)),
            _mm256_mullo_epi32(_mm256_srli_epi32::<16>(pair), wx),
        );
        let bytes = _mm256_shuffle_epi8(_mm256_add_epi32(v, half), pick);
        let p = out.as_mut_ptr().add(x) as *mut i32;
        p.write_unaligned(_mm_cvtsi128_si32(_mm256_castsi256_si128(bytes)));
        p.add(1)
            .write_unaligned(_mm_cvtsi128_si32(_mm256_extracti128_si256::<1>(bytes)));
        x += 8;
    }
    x
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ramp(width: usize, height: usize) -> Vec<u8> {
        (0..height)
            .flat_map(|y| (0..width).map(move |x| ((x + 2 * y) % 256) as u8))
            .collect()
    }

    #[test]
    fn halving_levels_have_halved_sizes_and_keep_a_constant_image() {
        let mut pyramid = Pyramid::new(PyramidConfig::klt()).unwrap();
        pyramid
            .build_from_grey(101, 64, &vec![77; 101 * 64])
            .unwrap();
        let sizes: Vec<_> = pyramid
            .levels()
            .iter()
            .map(|l| (l.width, l.height))
            .collect();
        assert_eq!(sizes, vec![(101, 64), (51, 32), (26, 16)]);
        for level in pyramid.levels() {
            assert!(level.data.iter().all(|&v| v == 77));
        }
    }

    #[test]
    fn halving_equals_the_blur_written_out_per_pixel_on_noise() {
        // Every pixel of odd and even sizes, borders included, against the
        // [1 2 1] x [1 2 1] / 16 blur with replicated borders, sampled at
        // (2x, 2y).
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        for (w, h) in [
            (203usize, 77usize),
            (202, 76),
            (1, 1),
            (2, 3),
            (5, 2),
            (752, 480),
        ] {
            let data: Vec<u8> = (0..w * h).map(|_| rng.gen()).collect();
            let src = GreyImage {
                width: w,
                height: h,
                data: data.clone(),
            };
            let mut dst = GreyImage::default();
            dst.reshape(w.div_ceil(2), h.div_ceil(2));
            halve(&src, &mut dst, &mut Vec::new());
            let at = |x: isize, y: isize| {
                let (x, y) = (x.clamp(0, w as isize - 1), y.clamp(0, h as isize - 1));
                u32::from(data[y as usize * w + x as usize])
            };
            for y in 0..dst.height {
                for x in 0..dst.width {
                    let (sx, sy) = (2 * x as isize, 2 * y as isize);
                    let mut sum = 8;
                    for (dy, wy) in [(-1, 1), (0, 2), (1, 1)] {
                        for (dx, wx) in [(-1, 1), (0, 2), (1, 1)] {
                            sum += wx * wy * at(sx + dx, sy + dy);
                        }
                    }
                    assert_eq!(
                        u32::from(dst.data[y * dst.width + x]),
                        sum >> 4,
                        "{w}x{h} at ({x}, {y})"
                    );
                }
            }
        }
    }

    #[test]
    fn resampling_equals_the_four_tap_fixed_point_formula_on_noise() {
        // Every pixel (the vector path and the scalar row end) against the
        // bilinear definition written out per pixel, on random grey values.
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let (w, h) = (203, 77);
        let pixels: Vec<u8> = (0..w * h).map(|_| rng.gen()).collect();
        let mut pyramid = Pyramid::new(PyramidConfig {
            levels: 2,
            scale: 1.2,
            min_side_px: 8,
        })
        .unwrap();
        pyramid.build_from_grey(w, h, &pixels).unwrap();
        let level = pyramid.level(1);
        let (fx, fy) = (
            w as f32 / level.width as f32,
            h as f32 / level.height as f32,
        );
        let tap = |s: f32, n: usize| {
            let s = s.clamp(0.0, (n - 1) as f32);
            let i = (s as usize).min(n - 2);
            (i, (((s - i as f32) * 256.0).round() as u32).min(256))
        };
        for y in 0..level.height {
            let (y0, wy) = tap((y as f32 + 0.5) * fy - 0.5, h);
            for x in 0..level.width {
                let (x0, wx) = tap((x as f32 + 0.5) * fx - 0.5, w);
                let p = |xx: usize, yy: usize| u32::from(pixels[yy * w + xx]);
                let top = p(x0, y0) * (256 - wx) + p(x0 + 1, y0) * wx;
                let bottom = p(x0, y0 + 1) * (256 - wx) + p(x0 + 1, y0 + 1) * wx;
                let expected = (top * (256 - wy) + bottom * wy + (1 << 15)) >> 16;
                assert_eq!(u32::from(level.at(x, y)), expected, "({x},{y})");
            }
        }
    }

    #[test]
    fn bilinear_level_of_a_linear_ramp_is_the_ramp_at_mapped_coordinates() {
        // For a ramp v = x + 2y (no wrap), bilinear resampling is exact:
        // level value at (x, y) = v at ((x+0.5) s - 0.5, (y+0.5) s - 0.5).
        let (w, h) = (120, 60);
        let mut pyramid = Pyramid::new(PyramidConfig {
            levels: 2,
            scale: 1.2,
            min_side_px: 8,
        })
        .unwrap();
        pyramid.build_from_grey(w, h, &ramp(w, h)).unwrap();
        let level = pyramid.level(1);
        assert_eq!((level.width, level.height), (100, 50));
        for y in 0..level.height {
            for x in 0..level.width {
                let sx = ((x as f32 + 0.5) * 1.2 - 0.5).clamp(0.0, (w - 1) as f32);
                let sy = ((y as f32 + 0.5) * 1.2 - 0.5).clamp(0.0, (h - 1) as f32);
                let expected = sx + 2.0 * sy;
                assert!(
                    (f32::from(level.at(x, y)) - expected).abs() <= 1.0,
                    "({x},{y}): {} vs {expected}",
                    level.at(x, y)
                );
            }
        }
    }

    #[test]
    fn rebuilding_the_same_size_reuses_the_buffers() {
        let mut pyramid = Pyramid::new(PyramidConfig::orb()).unwrap();
        pyramid.build_from_grey(320, 240, &ramp(320, 240)).unwrap();
        let pointers: Vec<_> = pyramid.levels().iter().map(|l| l.data.as_ptr()).collect();
        pyramid
            .build_from_grey(320, 240, &vec![5; 320 * 240])
            .unwrap();
        let again: Vec<_> = pyramid.levels().iter().map(|l| l.data.as_ptr()).collect();
        assert_eq!(pointers, again);
    }

    #[test]
    fn sixteen_bit_input_is_normalised_to_eight_bits() {
        let pixels: Vec<u16> = (0..64).map(|i| (i * 64) as u16).collect(); // 12-bit values
        let image = Image::mono16(8, 8, 12, &pixels).unwrap();
        let mut pyramid = Pyramid::new(PyramidConfig::klt()).unwrap();
        pyramid.build(&image).unwrap();
        let base = pyramid.level(0);
        for (i, &v) in base.data.iter().enumerate() {
            assert_eq!(v, image.grey8_at(i as u32 % 8, i as u32 / 8).unwrap());
            assert_eq!(u32::from(v), (i as u32 * 64) >> 4);
        }
        assert_eq!(
            pyramid.levels().len(),
            1,
            "8x8 is below min_side_px for level 1"
        );
    }

    #[test]
    fn bad_input_is_an_error_not_a_panic() {
        let mut pyramid = Pyramid::new(PyramidConfig::klt()).unwrap();
        assert_eq!(
            pyramid.build_from_grey(0, 10, &[]),
            Err(FeatureError::Empty {
                width: 0,
                height: 10
            })
        );
        assert!(matches!(
            pyramid.build_from_grey(10, 10, &[0; 50]),
            Err(FeatureError::BufferTooShort { .. })
        ));
        let bayer = Image::new(
            4,
            4,
            4,
            PixelFormat::Bayer8(crate::sensors::BayerPattern::Rggb),
            vec![0u8; 16].into(),
        )
        .unwrap();
        assert!(matches!(
            pyramid.build(&bayer),
            Err(FeatureError::UnsupportedFormat { .. })
        ));
        assert!(Pyramid::new(PyramidConfig {
            levels: 0,
            scale: 2.0,
            min_side_px: 1
        })
        .is_err());
        // A 1x1 image is a valid one-level pyramid.
        pyramid.build_from_grey(1, 1, &[9]).unwrap();
        assert_eq!(pyramid.levels().len(), 1);
    }
}
