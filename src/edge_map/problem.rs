//! A stand-alone edge-map problem: landmarks, fused edges and the reference.

use nalgebra::{Matrix3, Vector3};

use super::edge::{EdgeChanges, EdgeMap, FusedEdge};

/// One fused edge as the map optimisation sees it: `y_m` estimates
/// `L_j - L_i` (world frame) with information `info = Σ^-1`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MapEdge {
    /// Id of the landmark the edge starts at.
    pub i: u32,
    /// Id of the landmark the edge ends at.
    pub j: u32,
    /// Estimate of `L_j - L_i`, world frame, m.
    pub y_m: Vector3<f64>,
    /// Information of that estimate (inverse covariance), m^-2.
    pub info: Matrix3<f64>,
}

impl MapEdge {
    /// The fused edge `(i, j)` as the map optimisation sees it; None while
    /// its information is singular (no mean yet).
    pub fn from_fused((i, j): (u32, u32), edge: &FusedEdge) -> Option<Self> {
        edge.mean().map(|y_m| MapEdge {
            i,
            j,
            y_m,
            info: edge.info,
        })
    }
}

/// A map's problem kept up to date from the edge map's changes
/// ([`EdgeMap::take_changes`]) on the thread that solves it: the edges stay
/// sorted by landmark pair, and a change is merged in place of the edge it
/// replaces, so a solve neither sorts every edge again nor recomputes the
/// mean of edges that did not change. The problem equals
/// [`MapProblem::from_edge_map`] of the map the changes came from.
#[derive(Clone, Debug, Default)]
pub struct ProblemMirror {
    landmark_count: u32,
    /// Sorted by `(i, j)`, `i < j`; edges without a mean left out.
    edges: Vec<MapEdge>,
}

impl ProblemMirror {
    /// An empty mirror.
    pub fn new() -> Self {
        Self::default()
    }

    /// Merges `changes` (each edge's whole fused value).
    pub fn apply_changes(&mut self, changes: &EdgeChanges) {
        self.landmark_count = self.landmark_count.max(changes.landmark_count);
        let mut changed: Vec<&((u32, u32), FusedEdge)> = changes.edges.iter().collect();
        if !changed.windows(2).all(|w| w[0].0 < w[1].0) {
            // `take_changes` gives them sorted and unique; the last of a
            // repeated key is its latest value.
            changed.sort_by_key(|c| c.0);
            changed.reverse();
            changed.dedup_by_key(|c| c.0);
            changed.reverse();
        }
        if changed.is_empty() {
            return;
        }
        let old = std::mem::take(&mut self.edges);
        let mut merged = Vec::with_capacity(old.len() + changed.len());
        let mut old = old.into_iter().peekable();
        for &&(key, ref edge) in &changed {
            while let Some(e) = old.next_if(|e| (e.i, e.j) < key) {
                merged.push(e);
            }
            old.next_if(|e| (e.i, e.j) == key);
            merged.extend(MapEdge::from_fused(key, edge));
        }
        merged.extend(old);
        self.edges = merged;
    }

    /// The problem with `reference` fixed at the origin (a copy).
    pub fn problem(&self, reference: u32) -> MapProblem {
        MapProblem {
            landmark_count: self.landmark_count,
            reference,
            edges: self.edges.clone(),
        }
    }
}

/// Landmarks `0..landmark_count`, edges between them, and the reference
/// landmark fixed at the origin (it removes the nullity 3 of A, eq. 57).
#[derive(Clone, Debug, Default)]
pub struct MapProblem {
    /// Number of landmarks (and frame nodes); ids run `0..landmark_count`.
    pub landmark_count: u32,
    /// Id of the landmark fixed at the origin.
    pub reference: u32,
    /// The fused edges.
    pub edges: Vec<MapEdge>,
}

impl MapProblem {
    /// Every fused edge of the map (sorted by landmark pair), with the
    /// reference landmark given.
    pub fn from_edge_map(map: &EdgeMap, reference: u32) -> Self {
        let edges = map
            .sorted_edges()
            .into_iter()
            .filter_map(|(key, e)| MapEdge::from_fused(key, &e))
            .collect();
        Self {
            landmark_count: map.landmark_count(),
            reference,
            edges,
        }
    }

    /// Unknown index of a landmark: ids after the reference shift down by
    /// one; the reference has none.
    pub fn unknown_of(&self, id: u32) -> Option<usize> {
        use std::cmp::Ordering;
        match id.cmp(&self.reference) {
            Ordering::Less => Some(id as usize),
            Ordering::Equal => None,
            Ordering::Greater => Some(id as usize - 1),
        }
    }

    /// Landmark id of an unknown index (inverse of [`Self::unknown_of`]).
    pub fn id_of(&self, unknown: usize) -> u32 {
        if (unknown as u32) < self.reference {
            unknown as u32
        } else {
            unknown as u32 + 1
        }
    }

    /// Landmark ids grouped by connected component, the reference's
    /// component first. A problem is solvable when there is only one.
    pub fn components(&self) -> Vec<Vec<u32>> {
        let n = self.landmark_count as usize;
        let mut parent: Vec<u32> = (0..self.landmark_count).collect();
        fn find(parent: &mut [u32], mut x: u32) -> u32 {
            while parent[x as usize] != x {
                let up = parent[parent[x as usize] as usize];
                parent[x as usize] = up;
                x = up;
            }
            x
        }
        for e in &self.edges {
            let (a, b) = (find(&mut parent, e.i), find(&mut parent, e.j));
            if a != b {
                parent[a.max(b) as usize] = a.min(b);
            }
        }
        let mut by_root: std::collections::BTreeMap<u32, Vec<u32>> = Default::default();
        for id in 0..n as u32 {
            let root = find(&mut parent, id);
            by_root.entry(root).or_default().push(id);
        }
        let mut components: Vec<Vec<u32>> = by_root.into_values().collect();
        if let Some(k) = components.iter().position(|c| c.contains(&self.reference)) {
            components.swap(0, k);
        }
        components
    }

    /// The sub-problem of the reference's connected component, landmarks
    /// renumbered in their old order; also returns the old id of each new id.
    pub fn reference_component(&self) -> (MapProblem, Vec<u32>) {
        self.component_problem(self.components().swap_remove(0))
    }

    /// [`Self::reference_component`], taking the problem: when it is
    /// connected, it is returned as it is (no copy), and the components
    /// are found once either way.
    pub fn into_reference_component(self) -> (MapProblem, Vec<u32>) {
        let mut components = self.components();
        if components.len() <= 1 {
            // Connected (or empty): every landmark, in order.
            let kept = components.pop().unwrap_or_default();
            return (self, kept);
        }
        self.component_problem(components.swap_remove(0))
    }

    /// The sub-problem of the landmarks `keep` (all edges within them).
    fn component_problem(&self, mut keep: Vec<u32>) -> (MapProblem, Vec<u32>) {
        keep.sort_unstable();
        let mut new_id = vec![u32::MAX; self.landmark_count as usize];
        for (k, &old) in keep.iter().enumerate() {
            new_id[old as usize] = k as u32;
        }
        let edges = self
            .edges
            .iter()
            .filter(|e| new_id[e.i as usize] != u32::MAX)
            .map(|e| MapEdge {
                i: new_id[e.i as usize],
                j: new_id[e.j as usize],
                ..*e
            })
            .collect();
        let problem = MapProblem {
            landmark_count: keep.len() as u32,
            reference: new_id[self.reference as usize],
            edges,
        };
        (problem, keep)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Matrix3, Vector3};
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    #[test]
    fn taking_the_reference_component_equals_copying_it() {
        let edge = |i, j| MapEdge {
            i,
            j,
            y_m: Vector3::new(f64::from(j) - f64::from(i), 0.0, 0.0),
            info: Matrix3::identity(),
        };
        // Two components: {0, 1, 3} with the reference 1, and {2, 4}.
        let split = MapProblem {
            landmark_count: 5,
            reference: 1,
            edges: vec![edge(0, 1), edge(1, 3), edge(2, 4)],
        };
        let (copied, copied_ids) = split.reference_component();
        let (taken, taken_ids) = split.clone().into_reference_component();
        assert_eq!(taken_ids, vec![0, 1, 3]);
        assert_eq!(taken_ids, copied_ids);
        assert_eq!(taken.edges, copied.edges);
        assert_eq!(
            (taken.landmark_count, taken.reference),
            (copied.landmark_count, copied.reference)
        );
        // Connected: the problem itself and every id.
        let joined = MapProblem {
            edges: vec![edge(0, 1), edge(1, 3), edge(2, 4), edge(3, 4)],
            ..split
        };
        let (same, ids) = joined.clone().into_reference_component();
        assert_eq!(ids, vec![0, 1, 2, 3, 4]);
        assert_eq!(same.edges, joined.edges);
        // Empty: nothing, no panic.
        let (empty, none) = MapProblem::default().into_reference_component();
        assert!(none.is_empty() && empty.edges.is_empty());
    }

    /// Fed only the changes, the mirror's problem is the one built from
    /// the whole map, edges without a mean (no information yet) included.
    #[test]
    fn a_problem_mirror_fed_the_changes_equals_the_problem_of_the_map() {
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let mut map = EdgeMap::new();
        map.track_changes();
        let mut mirror = ProblemMirror::new();
        let mut singular = 0;
        for round in 0..8 {
            for _ in 0..60 {
                // Later rounds mostly revisit old pairs and add a few new.
                let top = 20 + 5 * round;
                let i = rng.gen_range(0..top);
                let j = rng.gen_range(0..top);
                let y = Vector3::from_fn(|_, _| rng.gen_range(-5.0..5.0));
                let info = if rng.gen_bool(0.05) {
                    singular += 1;
                    Matrix3::zeros()
                } else {
                    let m = Matrix3::from_fn(|_, _| rng.gen_range(-1.0..1.0));
                    m * m.transpose() + Matrix3::identity() * 0.1
                };
                map.add_measurement(i, j, &y, &info);
            }
            let changes = map.take_changes();
            assert!(!changes.edges.is_empty());
            // Each key once, sorted.
            assert!(changes.edges.windows(2).all(|w| w[0].0 < w[1].0));
            mirror.apply_changes(&changes);
            let want = MapProblem::from_edge_map(&map, 0);
            let got = mirror.problem(0);
            assert_eq!(got.landmark_count, want.landmark_count);
            assert_eq!(got.edges, want.edges, "round {round}");
        }
        assert!(singular > 0);
        assert!(map.take_changes().edges.is_empty());
        // Unsorted, repeated changes: the last value of a key wins.
        let mut one = EdgeMap::new();
        one.add_measurement(3, 4, &Vector3::new(1.0, 0.0, 0.0), &Matrix3::identity());
        let first = *one.edge(3, 4).expect("edge");
        one.add_measurement(3, 4, &Vector3::new(3.0, 0.0, 0.0), &Matrix3::identity());
        let second = *one.edge(3, 4).expect("edge");
        let mut mirror = ProblemMirror::new();
        mirror.apply_changes(&EdgeChanges {
            landmark_count: 5,
            edges: vec![((3, 4), first), ((1, 2), first), ((3, 4), second)],
        });
        let edges = mirror.problem(0).edges;
        assert_eq!(edges.len(), 2);
        assert_eq!((edges[0].i, edges[0].j), (1, 2));
        assert!((edges[1].y_m - Vector3::new(2.0, 0.0, 0.0)).norm() < 1e-12);
    }
}
