//! The 256 point pairs of the BRIEF test, generated here (Calonder et al.,
//! "BRIEF: Binary robust independent elementary features", ECCV 2010,
//! sampling strategy G II): both points of a pair drawn from an isotropic
//! Gaussian with sigma = S / 5 for a patch of side S = 31, from a fixed
//! seed so that descriptors are comparable across runs and machines.
//! Points are kept within [`PATTERN_RADIUS_PX`] so that every rotation of
//! the pattern stays inside the orientation patch; the rotated copies are
//! tabulated in [`ROTATION_BINS`] steps.

use rand::SeedableRng;
use rand_distr::{Distribution, Normal};

/// Number of binary tests (bits) per descriptor.
pub const PATTERN_PAIRS: usize = 256;
/// Largest distance of a pattern point from the keypoint, px.
pub const PATTERN_RADIUS_PX: f64 = 13.0;
/// Patch side the sampling scale refers to, px.
pub const PATCH_SIZE_PX: f64 = 31.0;
/// Rotated copies of the pattern over a full turn (5.6 degrees apart).
pub const ROTATION_BINS: usize = 64;
/// Seed of the pattern; changing it changes every descriptor.
pub const PATTERN_SEED: u64 = 0x5EED_B21E_F256;

/// One test: bit = I(a) < I(b), offsets (dx, dy) in pixels.
pub type PointPair = [[i8; 2]; 2];

/// The unrotated pattern with real-valued points.
pub fn base_pattern() -> Vec<[[f64; 2]; 2]> {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(PATTERN_SEED);
    let normal = Normal::new(0.0, PATCH_SIZE_PX / 5.0).expect("sigma is positive and finite");
    let mut point = || loop {
        let p = [normal.sample(&mut rng), normal.sample(&mut rng)];
        if p[0].hypot(p[1]) <= PATTERN_RADIUS_PX {
            return p;
        }
    };
    let mut pairs = Vec::with_capacity(PATTERN_PAIRS);
    while pairs.len() < PATTERN_PAIRS {
        let (a, b) = (point(), point());
        // Two points rounding to the same pixel would make a constant bit.
        if a[0].round() != b[0].round() || a[1].round() != b[1].round() {
            pairs.push([a, b]);
        }
    }
    pairs
}

/// The pattern rotated to each of [`ROTATION_BINS`] angles (bin k at
/// 2 pi k / bins), rounded to whole pixels: `tables[k][i]`.
pub fn rotated_patterns() -> Vec<[PointPair; PATTERN_PAIRS]> {
    let base = base_pattern();
    (0..ROTATION_BINS)
        .map(|k| {
            let angle = 2.0 * std::f64::consts::PI * k as f64 / ROTATION_BINS as f64;
            let (s, c) = angle.sin_cos();
            let rotate = |p: [f64; 2]| {
                [
                    (c * p[0] - s * p[1]).round() as i8,
                    (s * p[0] + c * p[1]).round() as i8,
                ]
            };
            let mut table = [[[0i8; 2]; 2]; PATTERN_PAIRS];
            for (t, pair) in table.iter_mut().zip(&base) {
                *t = [rotate(pair[0]), rotate(pair[1])];
            }
            table
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_pattern_is_deterministic_gaussian_and_inside_the_patch() {
        let a = base_pattern();
        assert_eq!(a, base_pattern());
        assert_eq!(a.len(), PATTERN_PAIRS);
        let coords: Vec<f64> = a
            .iter()
            .flat_map(|p| [p[0][0], p[0][1], p[1][0], p[1][1]])
            .collect();
        let mean = coords.iter().sum::<f64>() / coords.len() as f64;
        let sd =
            (coords.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / coords.len() as f64).sqrt();
        assert!(mean.abs() < 0.5, "mean {mean}");
        // A N(0, 6.2) truncated to a 13 px disc has a per-axis sd near 5.3.
        assert!((4.5..6.2).contains(&sd), "sd {sd}");
        for table in rotated_patterns() {
            for pair in table {
                for p in pair {
                    assert!(f64::from(p[0]).hypot(f64::from(p[1])) <= PATTERN_RADIUS_PX + 0.75);
                }
            }
        }
    }

    #[test]
    fn a_quarter_turn_bin_is_the_exact_rotation() {
        let tables = rotated_patterns();
        let quarter = &tables[ROTATION_BINS / 4];
        for (p, q) in tables[0].iter().zip(quarter) {
            for k in 0..2 {
                // (x, y) -> (-y, x), up to rounding of .5 cases.
                assert!((i32::from(q[k][0]) + i32::from(p[k][1])).abs() <= 1);
                assert!((i32::from(q[k][1]) - i32::from(p[k][0])).abs() <= 1);
            }
        }
    }
}
