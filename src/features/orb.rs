//! ORB (Rublee et al., "ORB: an efficient alternative to SIFT or SURF",
//! ICCV 2011): FAST-9 corners on every level of a 1.2-ratio pyramid,
//! ranked by Harris response and spread by the grid, oriented by the
//! intensity centroid of a radius-15 disc (paper sec. 3.2), and described
//! by 256 BRIEF tests on the smoothed level, the pattern rotated to the
//! keypoint's angle (sec. 4, "steered BRIEF"; our own pattern, see
//! [`brief_pattern`](crate::features::brief_pattern)).
//!
//! All per-frame buffers (pyramid, smoothed levels, candidates) belong to
//! the [`OrbExtractor`] and are reused.

use crate::features::brief_pattern::{rotated_patterns, PointPair, PATTERN_PAIRS, ROTATION_BINS};
use crate::features::fast::{detect_fast9, Corner, FastScratch};
use crate::features::grid::{GridConfig, GridSelector};
use crate::features::pyramid::{GreyImage, Pyramid, PyramidConfig};
use crate::features::score::harris_score;
use crate::features::FeatureError;
use crate::sensors::Image;

/// A 256-bit binary descriptor, bit i of word i / 64 is test i.
pub type Descriptor = [u64; 4];

/// Radius of the orientation disc, px of the keypoint's level.
pub const ORIENTATION_RADIUS_PX: usize = 15;

/// An oriented keypoint.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Keypoint {
    /// Position in level-0 pixels (column).
    pub x: f32,
    /// Position in level-0 pixels (row).
    pub y: f32,
    /// Pyramid level it was found on.
    pub level: u8,
    /// Orientation, rad, in (-pi, pi], image axes (x right, y down).
    pub angle_rad: f32,
    /// Harris response on its level.
    pub response: f32,
}

/// Extraction parameters.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OrbConfig {
    /// Keypoints kept over all levels, at most \[1000\].
    pub max_features: usize,
    /// Pyramid levels including the image \[8\].
    pub levels: usize,
    /// Scale factor between consecutive levels, > 1 \[1.2\].
    pub scale: f32,
    /// FAST threshold, grey levels \[20\].
    pub fast_threshold: u8,
    /// Used on a level where the first threshold finds too few corners.
    pub fallback_fast_threshold: u8,
    /// Keypoints are at least this far from a level's edges, px (the
    /// orientation disc and the rotated pattern must fit).
    pub edge_px: usize,
    /// `k` of the Harris response `det - k trace^2` that ranks the corners \[0.04\].
    pub harris_k: f32,
    /// Grid bucket side on each level, px of that level.
    pub bucket_px: usize,
}

impl Default for OrbConfig {
    fn default() -> Self {
        Self {
            max_features: 1000,
            levels: 8,
            scale: 1.2,
            fast_threshold: 20,
            fallback_fast_threshold: 7,
            edge_px: 19,
            harris_k: 0.04,
            bucket_px: 30,
        }
    }
}

/// ORB extraction with owned buffers.
pub struct OrbExtractor {
    config: OrbConfig,
    pyramid: Pyramid,
    smoothed: GreyImage,
    row_sums: Vec<u16>,
    fast: FastScratch,
    candidates: Vec<Corner>,
    selected: Vec<Corner>,
    grid: GridSelector,
    patterns: Vec<[PointPair; PATTERN_PAIRS]>,
    /// Half-width of the orientation disc per row offset 0..=radius.
    disc_half_width: Vec<usize>,
}

impl OrbExtractor {
    /// An extractor with `config`; [`FeatureError::Config`] when `edge_px` leaves no room for the
    /// orientation disc, `max_features` is 0, or the pyramid settings are invalid.
    pub fn new(config: OrbConfig) -> Result<Self, FeatureError> {
        if config.edge_px < ORIENTATION_RADIUS_PX + 1 || config.max_features == 0 {
            return Err(FeatureError::Config(format!(
                "ORB needs edge_px >= {} and max_features > 0, got {config:?}",
                ORIENTATION_RADIUS_PX + 1
            )));
        }
        let pyramid = Pyramid::new(PyramidConfig {
            levels: config.levels,
            scale: config.scale,
            min_side_px: 2 * config.edge_px + 8,
        })?;
        let r = ORIENTATION_RADIUS_PX as f64;
        let disc_half_width = (0..=ORIENTATION_RADIUS_PX)
            .map(|dy| (r * r - (dy * dy) as f64).sqrt().floor() as usize)
            .collect();
        Ok(Self {
            config,
            pyramid,
            smoothed: GreyImage::default(),
            row_sums: Vec::new(),
            fast: FastScratch::default(),
            candidates: Vec::new(),
            selected: Vec::new(),
            grid: GridSelector::new(GridConfig {
                bucket_px: config.bucket_px,
                min_distance_px: 0.0,
            }),
            patterns: rotated_patterns(),
            disc_half_width,
        })
    }

    /// The settings it was built with.
    pub fn config(&self) -> &OrbConfig {
        &self.config
    }

    /// Keypoints and their descriptors (same order) of a sensor image.
    /// Images too small for one level give none.
    pub fn extract(
        &mut self,
        image: &Image,
        keypoints: &mut Vec<Keypoint>,
        descriptors: &mut Vec<Descriptor>,
    ) -> Result<(), FeatureError> {
        self.pyramid.build(image)?;
        self.extract_from_pyramid(keypoints, descriptors);
        Ok(())
    }

    /// As [`extract`](Self::extract), from a packed grey buffer.
    pub fn extract_grey(
        &mut self,
        width: usize,
        height: usize,
        pixels: &[u8],
        keypoints: &mut Vec<Keypoint>,
        descriptors: &mut Vec<Descriptor>,
    ) -> Result<(), FeatureError> {
        self.pyramid.build_from_grey(width, height, pixels)?;
        self.extract_from_pyramid(keypoints, descriptors);
        Ok(())
    }

    fn extract_from_pyramid(
        &mut self,
        keypoints: &mut Vec<Keypoint>,
        descriptors: &mut Vec<Descriptor>,
    ) {
        keypoints.clear();
        descriptors.clear();
        let c = self.config;
        let levels = self.pyramid.levels().len();
        // Features per level in geometric proportion to level area
        // (the paper's pyramid with a fixed total budget).
        let inv = 1.0 / f64::from(c.scale);
        let first = c.max_features as f64 * (1.0 - inv) / (1.0 - inv.powi(levels as i32));
        let mut carry = 0.0;
        for level in 0..levels {
            let want_f = first * inv.powi(level as i32) + carry;
            let want = if level + 1 == levels {
                c.max_features.saturating_sub(keypoints.len())
            } else {
                want_f.round() as usize
            };
            let image = self.pyramid.level(level);
            let edge = c.edge_px;
            detect_fast9(
                image,
                c.fast_threshold,
                edge,
                &mut self.fast,
                &mut self.candidates,
            );
            if self.candidates.len() < want && c.fallback_fast_threshold < c.fast_threshold {
                detect_fast9(
                    image,
                    c.fallback_fast_threshold,
                    edge,
                    &mut self.fast,
                    &mut self.candidates,
                );
            }
            // Keep the strongest 2x by FAST score before the costlier Harris.
            if self.candidates.len() > 2 * want {
                self.candidates
                    .select_nth_unstable_by(2 * want, |a, b| b.score.total_cmp(&a.score));
                self.candidates.truncate(2 * want);
            }
            for corner in &mut self.candidates {
                corner.score =
                    harris_score(image, corner.x as usize, corner.y as usize, 3, c.harris_k);
            }
            self.candidates.retain(|corner| corner.score > 0.0);
            self.grid.select(
                image.width,
                image.height,
                &mut self.candidates,
                &[],
                want,
                &mut self.selected,
            );
            carry = want_f - self.selected.len() as f64;
            if self.selected.is_empty() {
                continue;
            }
            smooth_binomial5(image, &mut self.smoothed, &mut self.row_sums);
            let scale = self.pyramid.scale_of(level);
            let image = self.pyramid.level(level);
            for corner in &self.selected {
                let (x, y) = (corner.x as usize, corner.y as usize);
                let angle = intensity_centroid_angle(image, x, y, &self.disc_half_width);
                let bin = ((angle / std::f32::consts::TAU * ROTATION_BINS as f32).round() as i64)
                    .rem_euclid(ROTATION_BINS as i64) as usize;
                descriptors.push(describe(&self.smoothed, x, y, &self.patterns[bin]));
                keypoints.push(Keypoint {
                    x: (corner.x as f32 + 0.5) * scale - 0.5,
                    y: (corner.y as f32 + 0.5) * scale - 0.5,
                    level: level as u8,
                    angle_rad: angle,
                    response: corner.score,
                });
            }
        }
    }
}

impl OrbExtractor {
    /// Oriented descriptors of given points of one image (e.g. KLT tracks
    /// at their birth, so that a landmark can be recognised after its
    /// track is lost): the point rounded to the nearest pixel of `image`,
    /// oriented and described as a level-0 keypoint would be. None for a
    /// point closer than `edge_px` to the border.
    pub fn describe_points(
        &mut self,
        image: &GreyImage,
        points: &[[f32; 2]],
        out: &mut Vec<Option<Descriptor>>,
    ) {
        out.clear();
        if points.is_empty() {
            return;
        }
        smooth_binomial5(image, &mut self.smoothed, &mut self.row_sums);
        let edge = self.config.edge_px as f32;
        let (w, h) = (image.width as f32, image.height as f32);
        out.extend(points.iter().map(|p| {
            let (x, y) = (p[0].round(), p[1].round());
            let inside = x >= edge && y >= edge && x < w - edge && y < h - edge;
            inside.then(|| {
                let (x, y) = (x as usize, y as usize);
                let angle = intensity_centroid_angle(image, x, y, &self.disc_half_width);
                let bin = ((angle / std::f32::consts::TAU * ROTATION_BINS as f32).round() as i64)
                    .rem_euclid(ROTATION_BINS as i64) as usize;
                describe(&self.smoothed, x, y, &self.patterns[bin])
            })
        }));
    }
}

/// atan2(m01, m10) of the disc of radius 15 around (x, y) (paper eq. 2-3).
#[inline(always)]
fn intensity_centroid_angle(image: &GreyImage, x: usize, y: usize, half_width: &[usize]) -> f32 {
    let (m01, m10) = centroid_moments(image, x, y, half_width);
    (m01 as f32).atan2(m10 as f32)
}

/// Moments (m01, m10) of the disc, with AVX2 where the CPU has it.
#[inline(always)]
fn centroid_moments(image: &GreyImage, x: usize, y: usize, half_width: &[usize]) -> (i32, i32) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: AVX2 detected; the function checks its own bounds.
        if let Some(m) = unsafe { centroid_moments_avx2(image, x, y, half_width) } {
            return m;
        }
    }
    centroid_moments_scalar(image, x, y, half_width)
}

/// [`centroid_moments_scalar`] over 32-byte rows x - 15 ..= x + 16: per
/// row offset dy, u8 x i8 multiply-adds with the column offsets (zero
/// outside the disc) give m10, and with a 0/1 disc mask the row sums for
/// m01; the same integers. `None` when the rows leave the image.
///
/// # Safety
/// The CPU must have AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn centroid_moments_avx2(
    image: &GreyImage,
    x: usize,
    y: usize,
    half_width: &[usize],
) -> Option<(i32, i32)> {
    use std::arch::x86_64::*;
    let r = ORIENTATION_RADIUS_PX;
    if x < r
        || y < r
        || x + r + 2 > image.width
        || y + r >= image.height
        || half_width.len() <= r
        || half_width.iter().any(|&hw| hw > r)
    {
        return None;
    }
    let load = |yy: usize| {
        _mm256_loadu_si256(image.data.as_ptr().add(yy * image.width + x - r) as *const __m256i)
    };
    let ones = _mm256_set1_epi16(1);
    // Byte j holds column offset j - 15.
    let column_offsets = _mm256_setr_epi8(
        -15, -14, -13, -12, -11, -10, -9, -8, -7, -6, -5, -4, -3, -2, -1, 0, 1, 2, 3, 4, 5, 6, 7,
        8, 9, 10, 11, 12, 13, 14, 15, 16,
    );
    let (mut m10, mut m01) = (_mm256_setzero_si256(), _mm256_setzero_si256());
    for dy in 0..=r {
        // 0xFF in the bytes whose column offset is within the disc's row.
        let in_disc = _mm256_cmpgt_epi8(
            _mm256_set1_epi8(half_width[dy] as i8 + 1),
            _mm256_abs_epi8(column_offsets),
        );
        let offset = _mm256_and_si256(in_disc, column_offsets);
        if dy == 0 {
            let row = _mm256_maddubs_epi16(load(y), offset);
            m10 = _mm256_add_epi32(m10, _mm256_madd_epi16(row, ones));
            continue;
        }
        let inside = _mm256_and_si256(in_disc, _mm256_set1_epi8(1));
        let (above, below) = (load(y - dy), load(y + dy));
        let weighted = _mm256_add_epi16(
            _mm256_maddubs_epi16(above, offset),
            _mm256_maddubs_epi16(below, offset),
        );
        m10 = _mm256_add_epi32(m10, _mm256_madd_epi16(weighted, ones));
        let column = _mm256_sub_epi16(
            _mm256_maddubs_epi16(below, inside),
            _mm256_maddubs_epi16(above, inside),
        );
        m01 = _mm256_add_epi32(m01, _mm256_madd_epi16(column, _mm256_set1_epi16(dy as i16)));
    }
    let sum = |v: __m256i| {
        let mut lanes = [0i32; 8];
        _mm256_storeu_si256(lanes.as_mut_ptr() as *mut __m256i, v);
        lanes.iter().sum::<i32>()
    };
    Some((sum(m01), sum(m10)))
}

/// The disc moments straight from their definition, row by row.
#[inline(always)]
fn centroid_moments_scalar(
    image: &GreyImage,
    x: usize,
    y: usize,
    half_width: &[usize],
) -> (i32, i32) {
    let r = ORIENTATION_RADIUS_PX;
    let (mut m10, mut m01) = (0i32, 0i32);
    let centre = image.row(y);
    for dx in 1..=r {
        m10 += dx as i32 * (i32::from(centre[x + dx]) - i32::from(centre[x - dx]));
    }
    for dy in 1..=r {
        let (above, below) = (image.row(y - dy), image.row(y + dy));
        let hw = half_width[dy];
        let mut column_sum = 0i32;
        for dx in 0..=2 * hw {
            let xx = x + dx - hw;
            let (a, b) = (i32::from(above[xx]), i32::from(below[xx]));
            column_sum += b - a;
            m10 += (dx as i32 - hw as i32) * (a + b);
        }
        m01 += dy as i32 * column_sum;
    }
    (m01, m10)
}

/// The 256 tests of a rotated pattern at (x, y) of the smoothed level.
#[inline(always)]
fn describe(
    smoothed: &GreyImage,
    x: usize,
    y: usize,
    pattern: &[PointPair; PATTERN_PAIRS],
) -> Descriptor {
    let w = smoothed.width as isize;
    let centre = (y * smoothed.width + x) as isize;
    let data = &smoothed.data;
    let at = |p: [i8; 2]| data[(centre + isize::from(p[1]) * w + isize::from(p[0])) as usize];
    let mut d = [0u64; 4];
    for (i, pair) in pattern.iter().enumerate() {
        let bit = (at(pair[0]) < at(pair[1])) as u64;
        d[i / 64] |= bit << (i % 64);
    }
    d
}

/// [1 4 6 4 1]^2 / 256 binomial smoothing (a Gaussian of sigma 1), borders
/// replicated; the paper smooths before the tests for noise robustness.
#[inline(always)]
fn smooth_binomial5(src: &GreyImage, dst: &mut GreyImage, row_sums: &mut Vec<u16>) {
    let (w, h) = (src.width, src.height);
    dst.width = w;
    dst.height = h;
    dst.data.resize(w * h, 0);
    row_sums.resize(w + 4, 0);
    let clamp = |v: isize, n: usize| v.clamp(0, n as isize - 1) as usize;
    for y in 0..h {
        let rows = [-2isize, -1, 0, 1, 2].map(|o| src.row(clamp(y as isize + o, h)));
        // Vertical pass into the middle of a buffer padded by 2 each side.
        let mid = &mut row_sums[2..w + 2];
        for (x, m) in mid.iter_mut().enumerate() {
            *m = u16::from(rows[0][x])
                + 4 * u16::from(rows[1][x])
                + 6 * u16::from(rows[2][x])
                + 4 * u16::from(rows[3][x])
                + u16::from(rows[4][x]);
        }
        row_sums[0] = row_sums[2];
        row_sums[1] = row_sums[2];
        row_sums[w + 2] = row_sums[w + 1];
        row_sums[w + 3] = row_sums[w + 1];
        let out = &mut dst.data[y * w..(y + 1) * w];
        let s = &row_sums[..];
        for (x, o) in out.iter_mut().enumerate() {
            // Max 16 * 4080 = 65280: fits u16.
            let v = s[x] + 4 * s[x + 1] + 6 * s[x + 2] + 4 * s[x + 3] + s[x + 4];
            *o = ((u32::from(v) + 128) >> 8) as u8;
        }
    }
}

#[cfg(test)]
mod tests;
