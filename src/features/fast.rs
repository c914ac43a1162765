//! FAST-9 corners (Rosten & Drummond, "Machine learning for high-speed
//! corner detection", ECCV 2006): a pixel is a corner when 9 contiguous
//! pixels of the 16 on a radius-3 Bresenham circle are all brighter than
//! centre + threshold, or all darker than centre - threshold. Score: the
//! largest threshold at which it still is one (the paper's V), used for
//! 3x3 non-maximum suppression.
//!
//! With AVX2 (checked at run time) 32 pixels go through a compass
//! pre-test at once and, where any passes, through the whole segment test
//! and score in saturated 8-bit arithmetic; without it, and at row ends,
//! each pixel gets the test as two 16-bit masks checked for a run of 9
//! set bits.

use crate::features::pyramid::GreyImage;

/// A corner in the pixel grid of the image it was found in.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Corner {
    /// Column, px (0 at the left edge).
    pub x: u32,
    /// Row, px (0 at the top edge).
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
    scores: Vec<u8>,
    width: usize,
    height: usize,
    candidates: Vec<Corner>,
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
fn arc_score(diffs: &[i16; 16]) -> u8 {
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
    (best - 1).max(0) as u8
}

/// The whole FAST-9 test and score on 32 pixels at a time for x in
/// [x0, x1) of row `y`: a compass pre-test first (a 9-arc covers two
/// adjacent compass pixels), and for a block where any pixel passes it,
/// the score of all 32 as saturated differences: bright d_k = (p_k - c)+,
/// dark d_k = (c - p_k)+, the smallest d over each 9-arc by doubling runs
/// (min of 2, 4, 8, then 9), the largest over arcs and polarities. A
/// pixel is a corner when that best exceeds the threshold, and its score
/// is best - 1 (at least 1), as [`arc_score`]. Writes scores into
/// `scores_row` (0 for non-corners) and pushes corners; returns where the
/// vector loop stopped (the caller finishes the row).
///
/// # Safety
/// The CPU must have AVX2; rows y - 3..=y + 3 exist, x0 >= 3 and
/// x1 + 3 <= width.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn segment_test_avx2(
    image: &GreyImage,
    y: usize,
    x0: usize,
    x1: usize,
    threshold: u8,
    scores_row: &mut [u8],
    out: &mut Vec<Corner>,
) -> usize {
    use std::arch::x86_64::*;
    let w = image.width as isize;
    let offsets: [isize; 16] = CIRCLE.map(|(dx, dy)| dy as isize * w + dx as isize);
    let t = _mm256_set1_epi8(threshold as i8);
    let one = _mm256_set1_epi8(1);
    let zero = _mm256_setzero_si256();
    // Plain loops, no closures: a closure would not inherit AVX2 and
    // would not be inlined.
    let mut x = x0;
    // Lanes at the start of this block that an earlier block already did:
    // the row's last block is moved back to end at x1 (when the row is
    // that long) instead of leaving up to 31 pixels to the scalar test.
    let mut done_lanes = 0;
    loop {
        if x + 32 > x1 {
            if x >= x1 || x1 - x0 < 32 || done_lanes != 0 {
                break;
            }
            done_lanes = x - (x1 - 32);
            x = x1 - 32;
        }
        let centre = image.data.as_ptr().add(y * image.width + x);
        let c = _mm256_loadu_si256(centre as *const __m256i);
        let hi = _mm256_adds_epu8(c, t);
        let lo = _mm256_subs_epu8(c, t);
        // Per compass pixel (N, E, S, W): 0xFF where NOT brighter / NOT darker.
        let mut not_bright = [zero; 4];
        let mut not_dark = [zero; 4];
        for k in 0..4 {
            let p = _mm256_loadu_si256(centre.offset(offsets[4 * k]) as *const __m256i);
            not_bright[k] = _mm256_cmpeq_epi8(_mm256_subs_epu8(p, hi), zero);
            not_dark[k] = _mm256_cmpeq_epi8(_mm256_subs_epu8(lo, p), zero);
        }
        let reject = _mm256_and_si256(no_adjacent_pair(not_bright), no_adjacent_pair(not_dark));
        let store = scores_row.as_mut_ptr().add(x) as *mut __m256i;
        if _mm256_movemask_epi8(reject) == -1 {
            _mm256_storeu_si256(store, zero);
            x += 32;
            continue;
        }
        let mut bright = [zero; 16];
        let mut dark = [zero; 16];
        for k in 0..16 {
            let p = _mm256_loadu_si256(centre.offset(offsets[k]) as *const __m256i);
            bright[k] = _mm256_subs_epu8(p, c);
            dark[k] = _mm256_subs_epu8(c, p);
        }
        let best = _mm256_max_epu8(best_arc9(&bright), best_arc9(&dark));
        // Corner: best > threshold, i.e. best - threshold (saturated) != 0.
        let not_corner = _mm256_cmpeq_epi8(_mm256_subs_epu8(best, t), zero);
        let score = _mm256_max_epu8(_mm256_subs_epu8(best, one), one);
        _mm256_storeu_si256(store, _mm256_andnot_si256(not_corner, score));
        let mut corners = !(_mm256_movemask_epi8(not_corner) as u32) & (u32::MAX << done_lanes);
        while corners != 0 {
            let xi = x + corners.trailing_zeros() as usize;
            out.push(Corner {
                x: xi as u32,
                y: y as u32,
                score: f32::from(scores_row[xi]),
            });
            corners &= corners - 1;
        }
        x += 32;
    }
    x
}

/// 0xFF in lanes where no two circularly adjacent masks of `m` are both 0.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
unsafe fn no_adjacent_pair(m: [std::arch::x86_64::__m256i; 4]) -> std::arch::x86_64::__m256i {
    use std::arch::x86_64::*;
    _mm256_and_si256(
        _mm256_and_si256(_mm256_or_si256(m[0], m[1]), _mm256_or_si256(m[1], m[2])),
        _mm256_and_si256(_mm256_or_si256(m[2], m[3]), _mm256_or_si256(m[3], m[0])),
    )
}

/// Per lane, the largest over the 16 circular 9-arcs of the smallest `d`
/// on the arc (runs of 2, 4, 8, then 9 by doubling).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
unsafe fn best_arc9(d: &[std::arch::x86_64::__m256i; 16]) -> std::arch::x86_64::__m256i {
    use std::arch::x86_64::*;
    let mut m2 = *d;
    for i in 0..16 {
        m2[i] = _mm256_min_epu8(d[i], d[(i + 1) % 16]);
    }
    let mut m4 = m2;
    for i in 0..16 {
        m4[i] = _mm256_min_epu8(m2[i], m2[(i + 2) % 16]);
    }
    let mut best = _mm256_setzero_si256();
    for i in 0..16 {
        let m8 = _mm256_min_epu8(m4[i], m4[(i + 4) % 16]);
        best = _mm256_max_epu8(best, _mm256_min_epu8(m8, d[(i + 8) % 16]));
    }
    best
}

/// FAST-9 score of the pixel at `centre_index` (stride `w`), or `None`
/// when it is not a corner at `threshold`.
#[inline]
fn corner_score(
    data: &[u8],
    centre_index: usize,
    offsets: &[isize; 16],
    threshold: u8,
) -> Option<u8> {
    let c = i16::from(data[centre_index]);
    let t = i16::from(threshold);
    let mut diffs = [0i16; 16];
    let (mut bright, mut dark) = (0u32, 0u32);
    for (k, &o) in offsets.iter().enumerate() {
        let d = i16::from(data[(centre_index as isize + o) as usize]) - c;
        diffs[k] = d;
        bright |= ((d > t) as u32) << k;
        dark |= ((d < -t) as u32) << k;
    }
    (has_arc9(bright) || has_arc9(dark)).then(|| arc_score(&diffs).max(1))
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
    let data = &image.data;
    #[cfg(target_arch = "x86_64")]
    let avx2 = std::arch::is_x86_feature_detected!("avx2");
    for y in border..h - border {
        let (x0, x1) = (border, w - border);
        let scores_row = &mut scratch.scores[y * w..(y + 1) * w];
        // SAFETY: AVX2 was detected; rows y +- 3 exist (border >= 3) and
        // x0 >= 3, x1 + 3 <= w.
        #[cfg(target_arch = "x86_64")]
        let vector_end = if avx2 {
            unsafe {
                segment_test_avx2(
                    image,
                    y,
                    x0,
                    x1,
                    threshold,
                    scores_row,
                    &mut scratch.candidates,
                )
            }
        } else {
            x0
        };
        #[cfg(not(target_arch = "x86_64"))]
        let vector_end = x0;
        for x in vector_end..x1 {
            if let Some(score) = corner_score(data, y * w + x, &offsets, threshold) {
                scores_row[x] = score;
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
