//! Which co-visible landmark pairs of a frame become edge measurements.
//!
//! The paper links landmarks seen together; how many pairs to keep trades
//! the map's accuracy (more independent paths between landmarks) against the
//! cost of fusion and of the solve (edges = nonzero blocks of A). The
//! numbers that chose the default are in bench/README.md, "Edge map".

use nalgebra::Vector3;

/// A rule picking edge pairs among one frame's observations.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum EdgePolicy {
    /// Every co-visible pair: m (m - 1) / 2 edges for m landmarks.
    AllPairs,
    /// Each landmark to its k nearest co-visible landmarks (positions in
    /// the body frame), plus the spanning tree's pairs, deduplicated: at
    /// most (k + 1) m edges. The tree is needed: k nearest neighbours alone
    /// split a street into its two sides, which no edge would then join.
    KNearest(usize),
    /// A minimum spanning tree over the co-visible landmarks (Euclidean
    /// distance): m - 1 edges, the least that keeps the frame connected.
    SpanningTree,
    /// No landmark pairs: each frame becomes a node of the map joined to
    /// every landmark it sees ([`super::EdgeMap::add_frame_node`]). The
    /// frame's information is then kept exactly (the frame marginal of
    /// all pairs, without its m^2 edges and their fill-in), at the price
    /// of one 3-vector unknown per frame. `every` > 1 keeps only every
    /// so many tracking frames: consecutive frames of a sliding-window
    /// estimator carry mostly the same information (their landmark
    /// errors are strongly correlated), so the map loses little and its
    /// unknowns and fill shrink. [`EdgePolicy::pairs`] gives no pairs for
    /// it; the caller adds the frame node.
    FrameNodes {
        /// Keep one tracking frame in this many (1: every frame).
        every: usize,
    },
}

impl std::fmt::Display for EdgePolicy {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            EdgePolicy::AllPairs => write!(f, "all"),
            EdgePolicy::KNearest(k) => write!(f, "knn:{k}"),
            EdgePolicy::SpanningTree => write!(f, "mst"),
            EdgePolicy::FrameNodes { every: 1 } => write!(f, "frame"),
            EdgePolicy::FrameNodes { every } => write!(f, "frame:{every}"),
        }
    }
}

impl std::str::FromStr for EdgePolicy {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "all" => Ok(EdgePolicy::AllPairs),
            "mst" => Ok(EdgePolicy::SpanningTree),
            "frame" => Ok(EdgePolicy::FrameNodes { every: 1 }),
            _ => {
                let count = |prefix| match s.strip_prefix(prefix).map(str::parse::<usize>) {
                    Some(Ok(k)) if k >= 1 => Some(k),
                    _ => None,
                };
                if let Some(k) = count("knn:") {
                    Ok(EdgePolicy::KNearest(k))
                } else if let Some(every) = count("frame:") {
                    Ok(EdgePolicy::FrameNodes { every })
                } else {
                    Err(format!(
                        "unknown edge policy `{s}`: expected all, frame, frame:N, mst or knn:K (N, K >= 1)"
                    ))
                }
            }
        }
    }
}

impl EdgePolicy {
    /// Index pairs `(a, b)`, `a < b`, into `positions` (one frame's
    /// landmarks), sorted and without duplicates.
    pub fn pairs(&self, positions: &[Vector3<f64>]) -> Vec<(usize, usize)> {
        let m = positions.len();
        let mut pairs = Vec::new();
        match *self {
            EdgePolicy::FrameNodes { .. } => {}
            EdgePolicy::AllPairs => {
                pairs.reserve(m * m.saturating_sub(1) / 2);
                for a in 0..m {
                    for b in a + 1..m {
                        pairs.push((a, b));
                    }
                }
            }
            EdgePolicy::KNearest(k) => {
                let mut by_distance: Vec<(f64, usize)> = Vec::with_capacity(m);
                for a in 0..m {
                    by_distance.clear();
                    by_distance.extend(
                        (0..m)
                            .filter(|&b| b != a)
                            .map(|b| ((positions[b] - positions[a]).norm_squared(), b)),
                    );
                    let k = k.min(by_distance.len());
                    if k == 0 {
                        continue;
                    }
                    by_distance.select_nth_unstable_by(k - 1, |x, y| x.0.total_cmp(&y.0));
                    for &(_, b) in &by_distance[..k] {
                        pairs.push((a.min(b), a.max(b)));
                    }
                }
                pairs.extend(EdgePolicy::SpanningTree.pairs(positions));
                pairs.sort_unstable();
                pairs.dedup();
            }
            EdgePolicy::SpanningTree => {
                // Prim's algorithm on the complete graph, O(m^2).
                if m < 2 {
                    return pairs;
                }
                let mut in_tree = vec![false; m];
                let mut best = vec![(f64::INFINITY, 0usize); m];
                in_tree[0] = true;
                for b in 1..m {
                    best[b] = ((positions[b] - positions[0]).norm_squared(), 0);
                }
                for _ in 1..m {
                    let (next, &(_, parent)) = best
                        .iter()
                        .enumerate()
                        .filter(|(b, _)| !in_tree[*b])
                        .min_by(|x, y| x.1 .0.total_cmp(&y.1 .0))
                        .expect("a vertex outside the tree remains");
                    in_tree[next] = true;
                    pairs.push((next.min(parent), next.max(parent)));
                    for b in 0..m {
                        if !in_tree[b] {
                            let d = (positions[b] - positions[next]).norm_squared();
                            if d < best[b].0 {
                                best[b] = (d, next);
                            }
                        }
                    }
                }
                pairs.sort_unstable();
            }
        }
        pairs
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn line(m: usize) -> Vec<Vector3<f64>> {
        (0..m)
            .map(|k| Vector3::new((k * k) as f64, 0.0, 0.0))
            .collect()
    }

    #[test]
    fn pair_counts_follow_the_definitions() {
        let p = line(6);
        assert_eq!(EdgePolicy::AllPairs.pairs(&p).len(), 15);
        // On a line with growing gaps the spanning tree is the chain.
        assert_eq!(
            EdgePolicy::SpanningTree.pairs(&p),
            vec![(0, 1), (1, 2), (2, 3), (3, 4), (4, 5)]
        );
        // Nearest neighbour of each point at x = k^2: the previous one,
        // except for 0 (its nearest is 1): again the chain.
        assert_eq!(EdgePolicy::KNearest(1).pairs(&p).len(), 5);
        assert!(EdgePolicy::KNearest(2).pairs(&p).contains(&(0, 2)));
    }

    #[test]
    fn k_nearest_keeps_two_clusters_connected() {
        // Two tight clusters far apart: 2-nearest links stay inside each
        // cluster; the spanning tree adds the one bridge.
        let mut p: Vec<Vector3<f64>> = (0..3)
            .map(|k| Vector3::new(k as f64 * 0.1, 0.0, 0.0))
            .collect();
        p.extend((0..3).map(|k| Vector3::new(k as f64 * 0.1, 10.0, 0.0)));
        let pairs = EdgePolicy::KNearest(2).pairs(&p);
        let bridges = pairs.iter().filter(|(a, b)| (*a < 3) != (*b < 3)).count();
        assert_eq!(bridges, 1, "{pairs:?}");
    }

    #[test]
    fn parses_its_own_names() {
        for p in [
            EdgePolicy::AllPairs,
            EdgePolicy::KNearest(4),
            EdgePolicy::SpanningTree,
            EdgePolicy::FrameNodes { every: 1 },
            EdgePolicy::FrameNodes { every: 5 },
        ] {
            assert_eq!(p.to_string().parse::<EdgePolicy>().unwrap(), p);
        }
        assert!(EdgePolicy::FrameNodes { every: 1 }
            .pairs(&line(6))
            .is_empty());
        assert!("frame:0".parse::<EdgePolicy>().is_err());
        assert!("knn:0".parse::<EdgePolicy>().is_err());
    }
}
