//! A stand-alone edge-map problem: landmarks, fused edges and the reference.

use nalgebra::{Matrix3, Vector3};

use super::edge::EdgeMap;

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
            .filter_map(|((i, j), e)| {
                e.mean().map(|y_m| MapEdge {
                    i,
                    j,
                    y_m,
                    info: e.info,
                })
            })
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
        let mut keep = self.components().swap_remove(0);
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
