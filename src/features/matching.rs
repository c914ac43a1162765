//! Brute-force Hamming matching of binary descriptors with Lowe's ratio
//! test ("Distinctive image features from scale-invariant keypoints",
//! IJCV 2004, sec. 7.1), a mutual (cross) check, and an optional search
//! window around a predicted position. One pass over all pairs gives each
//! query's best and second best and each train descriptor's best. The
//! Hamming distance uses the POPCNT instruction when the CPU has it
//! (checked once at run time).

use crate::features::orb::Descriptor;

/// Hamming distance of two 256-bit descriptors.
#[inline(always)]
pub fn hamming(a: &Descriptor, b: &Descriptor) -> u32 {
    (a[0] ^ b[0]).count_ones()
        + (a[1] ^ b[1]).count_ones()
        + (a[2] ^ b[2]).count_ones()
        + (a[3] ^ b[3]).count_ones()
}

/// Acceptance rules.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MatchConfig {
    /// Largest accepted distance, bits (of 256).
    pub max_distance: u32,
    /// Best / second best distance must be below this (`None`: no test).
    pub ratio: Option<f32>,
    /// Keep a match only if the query is also the train descriptor's best.
    pub mutual: bool,
}

impl Default for MatchConfig {
    fn default() -> Self {
        Self {
            max_distance: 64,
            ratio: Some(0.8),
            mutual: true,
        }
    }
}

/// Only pairs whose train position lies within `radius_px` of the query's
/// predicted position are compared.
#[derive(Debug, Clone, Copy)]
pub struct SearchWindow<'a> {
    /// Per query descriptor: where it is expected in the train image, px.
    pub predicted: &'a [[f32; 2]],
    /// Per train descriptor: its position, px.
    pub train_positions: &'a [[f32; 2]],
    /// Largest distance between the predicted and the train position, px.
    pub radius_px: f32,
}

/// One accepted correspondence.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Match {
    /// Index of the query descriptor.
    pub query: u32,
    /// Index of the train descriptor.
    pub train: u32,
    /// Hamming distance between the two, bits (of 256).
    pub distance: u32,
}

/// A matcher with its per-train buffer.
#[derive(Debug, Clone, Default)]
pub struct Matcher {
    config: MatchConfig,
    /// Best (distance, query) per train descriptor.
    train_best: Vec<(u32, u32)>,
    /// Best, second best distance and best train per query.
    query_best: Vec<(u32, u32, u32)>,
}

impl Matcher {
    /// A matcher with `config` and empty buffers.
    pub fn new(config: MatchConfig) -> Self {
        Self {
            config,
            ..Self::default()
        }
    }

    /// Matches `query` against `train` into `out` (cleared first), in query order.
    /// A window whose slices do not have one entry per descriptor is ignored
    /// for the missing entries (those queries get no match).
    pub fn match_into(
        &mut self,
        query: &[Descriptor],
        train: &[Descriptor],
        window: Option<&SearchWindow>,
        out: &mut Vec<Match>,
    ) {
        out.clear();
        self.train_best.clear();
        self.train_best.resize(train.len(), (u32::MAX, u32::MAX));
        self.query_best.clear();
        self.query_best
            .resize(query.len(), (u32::MAX, u32::MAX, u32::MAX));
        #[cfg(target_arch = "x86_64")]
        {
            if std::arch::is_x86_feature_detected!("popcnt") {
                // SAFETY: the CPU has POPCNT, checked just above.
                unsafe { self.scan_popcnt(query, train, window) };
            } else {
                self.scan(query, train, window);
            }
        }
        #[cfg(not(target_arch = "x86_64"))]
        self.scan(query, train, window);

        let c = self.config;
        for (i, &(best, second, j)) in self.query_best.iter().enumerate() {
            if best > c.max_distance || j == u32::MAX {
                continue;
            }
            if let Some(ratio) = c.ratio {
                if second != u32::MAX && best as f32 >= ratio * second as f32 {
                    continue;
                }
            }
            if c.mutual && self.train_best[j as usize].1 != i as u32 {
                continue;
            }
            out.push(Match {
                query: i as u32,
                train: j,
                distance: best,
            });
        }
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "popcnt")]
    unsafe fn scan_popcnt(
        &mut self,
        query: &[Descriptor],
        train: &[Descriptor],
        window: Option<&SearchWindow>,
    ) {
        self.scan(query, train, window);
    }

    #[inline(always)]
    fn scan(&mut self, query: &[Descriptor], train: &[Descriptor], window: Option<&SearchWindow>) {
        for (i, q) in query.iter().enumerate() {
            let (mut best, mut second, mut best_j) = (u32::MAX, u32::MAX, u32::MAX);
            let centre = match window {
                Some(w) => match w.predicted.get(i) {
                    Some(p) if p[0].is_finite() && p[1].is_finite() => Some(*p),
                    _ => continue,
                },
                None => None,
            };
            for (j, t) in train.iter().enumerate() {
                if let (Some(w), Some(p)) = (window, centre) {
                    let Some(tp) = w.train_positions.get(j) else {
                        continue;
                    };
                    let (dx, dy) = (tp[0] - p[0], tp[1] - p[1]);
                    if !(dx * dx + dy * dy <= w.radius_px * w.radius_px) {
                        continue;
                    }
                }
                let d = hamming(q, t);
                if d < best {
                    second = best;
                    best = d;
                    best_j = j as u32;
                } else if d < second {
                    second = d;
                }
                let tb = &mut self.train_best[j];
                if d < tb.0 {
                    *tb = (d, i as u32);
                }
            }
            self.query_best[i] = (best, second, best_j);
        }
    }
}

/// Convenience: one-off matching with a fresh [`Matcher`].
pub fn match_descriptors(
    query: &[Descriptor],
    train: &[Descriptor],
    config: &MatchConfig,
    window: Option<&SearchWindow>,
) -> Vec<Match> {
    let mut out = Vec::new();
    Matcher::new(*config).match_into(query, train, window, &mut out);
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    fn random_descriptors(n: usize, seed: u64) -> Vec<Descriptor> {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        (0..n)
            .map(|_| [rng.gen(), rng.gen(), rng.gen(), rng.gen()])
            .collect()
    }

    /// Flips `bits` distinct random bits.
    fn perturb(d: &Descriptor, bits: usize, rng: &mut impl Rng) -> Descriptor {
        let mut out = *d;
        let mut flipped = std::collections::HashSet::new();
        while flipped.len() < bits {
            let b = rng.gen_range(0..256);
            if flipped.insert(b) {
                out[b / 64] ^= 1u64 << (b % 64);
            }
        }
        out
    }

    #[test]
    fn hamming_counts_differing_bits() {
        let a = [0u64, u64::MAX, 0b1011, 1 << 63];
        let b = [0u64, 0, 0b0001, 0];
        assert_eq!(hamming(&a, &b), 64 + 2 + 1);
        assert_eq!(hamming(&a, &a), 0);
    }

    #[test]
    fn noisy_copies_find_their_originals_and_distractors_are_refused() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(9);
        let train = random_descriptors(300, 1);
        // Queries 0..200 are copies with 20 flipped bits; 200..300 are unrelated.
        let mut query: Vec<Descriptor> = train[..200]
            .iter()
            .map(|d| perturb(d, 20, &mut rng))
            .collect();
        query.extend(random_descriptors(100, 2));
        let matches = match_descriptors(&query, &train, &MatchConfig::default(), None);
        let correct = matches.iter().filter(|m| m.query == m.train).count();
        assert_eq!(correct, 200);
        assert_eq!(
            matches.len(),
            200,
            "random descriptors sit ~128 bits away, beyond 64"
        );
        assert!(matches.iter().all(|m| m.distance == 20));
    }

    #[test]
    fn the_ratio_test_and_the_mutual_check_refuse_ambiguous_matches() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let base = random_descriptors(1, 5)[0];
        // Two train descriptors nearly equally close to the query.
        let train = vec![perturb(&base, 10, &mut rng), perturb(&base, 11, &mut rng)];
        let query = vec![base];
        let strict = MatchConfig {
            ratio: Some(0.8),
            mutual: false,
            ..MatchConfig::default()
        };
        assert!(match_descriptors(&query, &train, &strict, None).is_empty());
        let loose = MatchConfig {
            ratio: None,
            mutual: false,
            ..MatchConfig::default()
        };
        assert_eq!(match_descriptors(&query, &train, &loose, None).len(), 1);
        // Mutual: two queries share one best train; only the closer keeps it.
        let train = vec![base];
        let query = vec![perturb(&base, 5, &mut rng), perturb(&base, 9, &mut rng)];
        let mutual = MatchConfig {
            ratio: None,
            mutual: true,
            ..MatchConfig::default()
        };
        let m = match_descriptors(&query, &train, &mutual, None);
        assert_eq!(
            m,
            vec![Match {
                query: 0,
                train: 0,
                distance: 5
            }]
        );
        let one_way = MatchConfig {
            mutual: false,
            ..mutual
        };
        assert_eq!(match_descriptors(&query, &train, &one_way, None).len(), 2);
    }

    #[test]
    fn the_search_window_excludes_far_candidates() {
        let train = random_descriptors(3, 7);
        let query = vec![train[2]];
        let train_positions = [[10.0, 10.0], [50.0, 50.0], [300.0, 300.0]];
        let near = SearchWindow {
            predicted: &[[12.0, 9.0]],
            train_positions: &train_positions,
            radius_px: 20.0,
        };
        assert!(match_descriptors(&query, &train, &MatchConfig::default(), Some(&near)).is_empty());
        let around = SearchWindow {
            predicted: &[[290.0, 305.0]],
            ..near
        };
        let m = match_descriptors(&query, &train, &MatchConfig::default(), Some(&around));
        assert_eq!(
            m,
            vec![Match {
                query: 0,
                train: 2,
                distance: 0
            }]
        );
        // Missing or non-finite predictions give no match rather than a panic.
        let broken = SearchWindow {
            predicted: &[[f32::NAN, 0.0]],
            ..near
        };
        assert!(
            match_descriptors(&query, &train, &MatchConfig::default(), Some(&broken)).is_empty()
        );
        let short = SearchWindow {
            predicted: &[],
            ..near
        };
        assert!(
            match_descriptors(&query, &train, &MatchConfig::default(), Some(&short)).is_empty()
        );
        assert!(match_descriptors(&[], &train, &MatchConfig::default(), None).is_empty());
        assert!(match_descriptors(&query, &[], &MatchConfig::default(), None).is_empty());
    }
}
