//! FAST-9 corners (Rosten & Drummond, "Machine learning for high-speed
//! corner detection", ECCV 2006): a pixel is a corner when 9 contiguous
//! pixels of the 16 on a radius-3 Bresenham circle are all brighter than
//! centre + threshold, or all darker than centre - threshold. Score: the
//! largest threshold at which it still is one (the paper's V), used for
//! 3x3 non-maximum suppression.
//!
//! Per row a branch-free pre-test on the four compass pixels (a 9-arc
//! covers at least two adjacent ones) discards most pixels; survivors get
//! the full test as two 16-bit masks checked for a run of 9 set bits.

use crate::features::pyramid::GreyImage;

/// A corner in the pixel grid of the image it was found in.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Corner {
    pub x: u32,
    pub y: u32,
    /// FAST score, or whatever score a later stage put here.
    pub score: f32,
}

/// Circle offsets (dx, dy) in order around the circle, starting at the top.
pub const CIRCLE: [(i32, i32); 16] = [
    (0, -3),
    (1, -3),
    (2, -2),
    (3, -1),
    (3, 0),
    (3, 1),
    (2, 2),
    (1, 3),
    (0, 3),
    (-1, 3),
    (-2, 2),
    (-3, 1),
    (-3, 0),
    (-3, -1),
    (-2, -2),
    (-1, -3),
];

/// Buffers reused between calls.
#[derive(Debug, Clone, Default)]
pub struct FastScratch {
    /// Score per pixel of the current call's corners, zero elsewhere (kept
    /// zero between calls by clearing only what was set).
    scores: Vec<u16>,
    width: usize,
    height: usize,
    candidates: Vec<Corner>,
    row_candidates: Vec<u32>,
}

/// True when `mask` (16 bits, circular) holds 9 contiguous set bits.
#[inline]
fn has_arc9(mask: u32) -> bool {
    let m = mask | (mask << 16);
    let run2 = m & (m >> 1);
    let run4 = run2 & (run2 >> 2);
    let run8 = run4 & (run4 >> 4);
    (run8 & (m >> 8)) != 0
}

/// FAST score: max over 9-arcs of the smallest |difference| on the arc,
/// over both polarities, minus one (the largest passing threshold).
#[inline]
fn arc_score(diffs: &[i16; 16]) -> u16 {
    let mut best = 0i16;
    for sign in [1i16, -1] {
        let mut ext = [0i16; 25];
        for (k, e) in ext.iter_mut().enumerate() {
            *e = sign * diffs[k % 16];
        }
        let mut m2 = [0i16; 24];
        for i in 0..24 {
            m2[i] = ext[i].min(ext[i + 1]);
        }
        let mut m4 = [0i16; 22];
        for i in 0..22 {
            m4[i] = m2[i].min(m2[i + 2]);
        }
        for i in 0..16 {
            let m9 = m4[i].min(m4[i + 4]).min(ext[i + 8]);
            best = best.max(m9);
        }
    }
    (best - 1).max(0) as u16
}

/// The compass pre-test on 16 pixels at a time for x in [x0, x1); pushes
/// the x of every pixel that passes and returns where the vector loop
/// stopped (the caller finishes the row).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "sse2")]
unsafe fn pretest_sse2(
    up: &[u8],
    mid: &[u8],
    down: &[u8],
    x0: usize,
    x1: usize,
    threshold: u8,
    out: &mut Vec<u32>,
) -> usize {
    use std::arch::x86_64::*;
    let t = _mm_set1_epi8(threshold as i8);
    let zero = _mm_setzero_si128();
    let load = |row: &[u8], x: usize| _mm_loadu_si128(row.as_ptr().add(x) as *const __m128i);
    let mut x = x0;
    while x + 16 <= x1 {
        let c = load(mid, x);
        let hi = _mm_adds_epu8(c, t);
        let lo = _mm_subs_epu8(c, t);
        let ring = [
            load(up, x),
            load(mid, x + 3),
            load(down, x),
            load(mid, x - 3),
        ];
        // 0xFF where a compass pixel is NOT brighter / NOT darker.
        let not_bright = ring.map(|p| _mm_cmpeq_epi8(_mm_subs_epu8(p, hi), zero));
        let not_dark = ring.map(|p| _mm_cmpeq_epi8(_mm_subs_epu8(lo, p), zero));
        // No adjacent pair both brighter: every pair has a "not".
        let no_pair = |m: [__m128i; 4]| {
            _mm_and_si128(
                _mm_and_si128(_mm_or_si128(m[0], m[1]), _mm_or_si128(m[1], m[2])),
                _mm_and_si128(_mm_or_si128(m[2], m[3]), _mm_or_si128(m[3], m[0])),
            )
        };
        let reject = _mm_and_si128(no_pair(not_bright), no_pair(not_dark));
        let mut pass = !(_mm_movemask_epi8(reject) as u32) & 0xffff;
        while pass != 0 {
            out.push((x + pass.trailing_zeros() as usize) as u32);
            pass &= pass - 1;
        }
        x += 16;
    }
    x
}

/// Detects FAST-9 corners at least `border` pixels (>= 3) from every edge,
/// with 3x3 non-maximum suppression on the FAST score. Appends to `out`
/// (cleared first). Allocates nothing once `scratch` has seen this size.
pub fn detect_fast9(
    image: &GreyImage,
    threshold: u8,
    border: usize,
    scratch: &mut FastScratch,
    out: &mut Vec<Corner>,
) {
    out.clear();
    let border = border.max(3);
    let (w, h) = (image.width, image.height);
    if w <= 2 * border || h <= 2 * border {
        return;
    }
    if scratch.width != w || scratch.height != h {
        scratch.scores.clear();
        scratch.scores.resize(w * h, 0);
        scratch.width = w;
        scratch.height = h;
    }
    scratch.candidates.clear();
    let offsets: [isize; 16] = CIRCLE.map(|(dx, dy)| dy as isize * w as isize + dx as isize);
    let t = threshold;
    let data = &image.data;
    for y in border..h - border {
        let up = image.row(y - 3);
        let mid = image.row(y);
        let down = image.row(y + 3);
        let (x0, x1) = (border, w - border);
        // Pre-test: two adjacent compass pixels both brighter or both darker.
        scratch.row_candidates.clear();
        // SAFETY: SSE2 is part of the x86_64 baseline; loads stay in the
        // rows: x - 3 >= 0 and x + 3 + 16 <= x1 + 3 <= w.
        #[cfg(target_arch = "x86_64")]
        let vector_end =
            unsafe { pretest_sse2(up, mid, down, x0, x1, t, &mut scratch.row_candidates) };
        #[cfg(not(target_arch = "x86_64"))]
        let vector_end = x0;
        for x in vector_end..x1 {
            let c = mid[x];
            let hi = c.saturating_add(t);
            let lo = c.saturating_sub(t);
            let (n, e, s, wv) = (up[x], mid[x + 3], down[x], mid[x - 3]);
            let b = ((n > hi) as u8)
                | (((e > hi) as u8) << 1)
                | (((s > hi) as u8) << 2)
                | (((wv > hi) as u8) << 3);
            let d = ((n < lo) as u8)
                | (((e < lo) as u8) << 1)
                | (((s < lo) as u8) << 2)
                | (((wv < lo) as u8) << 3);
            let adjacent = |m: u8| (m & (m >> 1 | m << 3)) & 0xf;
            if adjacent(b) | adjacent(d) != 0 {
                scratch.row_candidates.push(x as u32);
            }
        }
        for &x in &scratch.row_candidates {
            let x = x as usize;
            let centre_index = y * w + x;
            let c = i16::from(data[centre_index]);
            let mut diffs = [0i16; 16];
            let (mut bright, mut dark) = (0u32, 0u32);
            for (k, &o) in offsets.iter().enumerate() {
                let p = i16::from(data[(centre_index as isize + o) as usize]);
                let d = p - c;
                diffs[k] = d;
                bright |= ((d > i16::from(t)) as u32) << k;
                dark |= ((d < -i16::from(t)) as u32) << k;
            }
            if has_arc9(bright) || has_arc9(dark) {
                let score = arc_score(&diffs).max(1);
                scratch.scores[centre_index] = score;
                scratch.candidates.push(Corner {
                    x: x as u32,
                    y: y as u32,
                    score: f32::from(score),
                });
            }
        }
    }
    // 3x3 non-maximum suppression; ties keep the first in raster order.
    for c in &scratch.candidates {
        let (x, y) = (c.x as usize, c.y as usize);
        let s = scratch.scores[y * w + x];
        let mut keep = true;
        'neighbours: for dy in -1isize..=1 {
            for dx in -1isize..=1 {
                if dx == 0 && dy == 0 {
                    continue;
                }
                let n =
                    scratch.scores[((y as isize + dy) as usize) * w + (x as isize + dx) as usize];
                let earlier = dy < 0 || (dy == 0 && dx < 0);
                if n > s || (n == s && earlier) {
                    keep = false;
                    break 'neighbours;
                }
            }
        }
        if keep {
            out.push(*c);
        }
    }
    for c in &scratch.candidates {
        scratch.scores[c.y as usize * w + c.x as usize] = 0;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Brute-force FAST-9 straight from the definition, no pre-test.
    fn is_corner_reference(img: &GreyImage, x: usize, y: usize, t: u8) -> bool {
        let c = i32::from(img.at(x, y));
        let ring: Vec<i32> = CIRCLE
            .iter()
            .map(|&(dx, dy)| i32::from(img.at((x as i32 + dx) as usize, (y as i32 + dy) as usize)))
            .collect();
        (0..16).any(|s| (0..9).all(|k| ring[(s + k) % 16] > c + i32::from(t)))
            || (0..16).any(|s| (0..9).all(|k| ring[(s + k) % 16] < c - i32::from(t)))
    }

    fn noise_image(w: usize, h: usize, seed: u64) -> GreyImage {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        // Blocky noise so corners of every polarity exist.
        let blocks: Vec<u8> = (0..(w / 4 + 1) * (h / 4 + 1)).map(|_| rng.gen()).collect();
        let data = (0..h)
            .flat_map(|y| {
                let b = &blocks;
                (0..w).map(move |x| b[(y / 4) * (w / 4 + 1) + x / 4])
            })
            .collect();
        GreyImage::from_vec(w, h, data).unwrap()
    }

    #[test]
    fn detection_before_suppression_matches_the_definition() {
        let img = noise_image(80, 60, 1);
        let mut scratch = FastScratch::default();
        let mut out = Vec::new();
        detect_fast9(&img, 20, 3, &mut scratch, &mut out);
        let found: std::collections::HashSet<(u32, u32)> =
            scratch.candidates.iter().map(|c| (c.x, c.y)).collect();
        let mut count = 0;
        for y in 3..57 {
            for x in 3..77 {
                let expected = is_corner_reference(&img, x, y, 20);
                count += expected as usize;
                assert_eq!(found.contains(&(x as u32, y as u32)), expected, "({x},{y})");
            }
        }
        assert!(count > 50, "the test image must have corners, has {count}");
        assert!(!out.is_empty() && out.len() < count);
    }

    #[test]
    fn score_is_the_largest_threshold_that_still_detects() {
        let img = noise_image(60, 40, 2);
        let mut scratch = FastScratch::default();
        let mut out = Vec::new();
        detect_fast9(&img, 10, 3, &mut scratch, &mut out);
        for c in scratch.candidates.iter().take(200) {
            let s = c.score as u32;
            let (x, y) = (c.x as usize, c.y as usize);
            assert!(is_corner_reference(&img, x, y, s as u8));
            assert!(s >= 254 || !is_corner_reference(&img, x, y, (s + 1) as u8));
        }
    }

    #[test]
    fn survivors_are_local_maxima_and_scratch_is_left_clean() {
        let img = noise_image(100, 80, 3);
        let mut scratch = FastScratch::default();
        let mut out = Vec::new();
        detect_fast9(&img, 15, 3, &mut scratch, &mut out);
        let all: std::collections::HashMap<(u32, u32), f32> = scratch
            .candidates
            .iter()
            .map(|c| ((c.x, c.y), c.score))
            .collect();
        for c in &out {
            for dy in -1i32..=1 {
                for dx in -1i32..=1 {
                    let n = ((c.x as i32 + dx) as u32, (c.y as i32 + dy) as u32);
                    if n != (c.x, c.y) {
                        assert!(all.get(&n).map_or(true, |&s| s <= c.score));
                    }
                }
            }
        }
        assert!(scratch.scores.iter().all(|&s| s == 0));
    }

    #[test]
    fn flat_tiny_and_saturated_images_give_no_corners() {
        let mut scratch = FastScratch::default();
        let mut out = vec![Corner {
            x: 0,
            y: 0,
            score: 0.0,
        }];
        for img in [
            GreyImage::filled(50, 50, 0),
            GreyImage::filled(50, 50, 255),
            GreyImage::filled(50, 50, 128),
            GreyImage::filled(6, 6, 0),
            GreyImage::filled(1, 1, 0),
        ] {
            detect_fast9(&img, 1, 3, &mut scratch, &mut out);
            assert!(out.is_empty());
        }
    }
}
