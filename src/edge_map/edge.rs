//! Landmark-pair edges and their fusion in information form (paper eq. 41-43).
//!
//! An edge between landmarks `i` and `j` measures `y_ij = y_j - y_i`, the
//! difference of the two landmark positions seen from one robot pose, rotated
//! into the world frame with the relative stage's orientation (eq. 41); its
//! covariance is `Σ_yi + Σ_yj` (eq. 42). Every measurement of the same edge is
//! fused by information-weighted averaging (eq. 43):
//! `ŷ = (Σ S_k)^-1 Σ S_k y_k` with `S_k = Σ_k^-1`. Kept as the sums
//! `S = Σ S_k` and `b = Σ S_k y_k`, an update is two 3x3 additions: O(1),
//! and the order of the measurements cannot change the result beyond
//! floating-point rounding.

use std::collections::HashMap;

use nalgebra::{Matrix3, Vector3};

/// One fused edge in information form (eq. 43).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FusedEdge {
    /// `S = Σ_k Σ_k^-1`, the summed information, m^-2.
    pub info: Matrix3<f64>,
    /// `b = Σ_k Σ_k^-1 y_k`, the information-weighted sum of measurements, m^-1.
    pub info_y: Vector3<f64>,
    /// How many measurements were fused.
    pub count: u32,
}

impl Default for FusedEdge {
    fn default() -> Self {
        Self {
            info: Matrix3::zeros(),
            info_y: Vector3::zeros(),
            count: 0,
        }
    }
}

impl FusedEdge {
    /// Adds one measurement `y_world_m` with information `info = Σ^-1`
    /// (world frame). O(1).
    pub fn add(&mut self, y_world_m: &Vector3<f64>, info: &Matrix3<f64>) {
        self.info += info;
        self.info_y += info * y_world_m;
        self.count += 1;
    }

    /// Merges another fused edge of the same orientation (the sums add).
    pub fn merge(&mut self, other: &FusedEdge) {
        self.info += other.info;
        self.info_y += other.info_y;
        self.count += other.count;
    }

    /// The fused measurement `ŷ = S^-1 b` (eq. 43), or None while `S` is
    /// singular (no measurement yet).
    pub fn mean(&self) -> Option<Vector3<f64>> {
        self.info.cholesky().map(|c| c.solve(&self.info_y))
    }

    /// The fused covariance `S^-1`.
    pub fn covariance(&self) -> Option<Matrix3<f64>> {
        self.info.cholesky().map(|c| c.inverse())
    }
}

/// One landmark seen from one robot pose: position in the body frame with
/// its covariance, as the relative stage hands it over.
#[derive(Clone, Copy, Debug)]
pub struct LandmarkObservation {
    /// Map-wide landmark id.
    pub id: u32,
    /// Landmark position in the body frame, m.
    pub p_body_m: Vector3<f64>,
    /// Its covariance in the body frame, m^2.
    pub cov_body_m2: Matrix3<f64>,
}

/// The edge map: every fused edge, keyed by its ordered landmark pair
/// `(i, j)` with `i < j`, oriented as `y_ij = L_j - L_i`.
#[derive(Clone, Debug, Default)]
pub struct EdgeMap {
    edges: HashMap<(u32, u32), FusedEdge>,
    /// Number of landmarks: one more than the largest id seen.
    landmark_count: u32,
    /// Keys fused into since the last [`EdgeMap::take_changes`] (with
    /// repeats), when change tracking is on.
    touched: Option<Vec<(u32, u32)>>,
}

/// The edges of an [`EdgeMap`] fused into since the last
/// [`EdgeMap::take_changes`], with their new values: what a mirror of the
/// map elsewhere (the map solve thread) needs to catch up.
#[derive(Clone, Debug, Default)]
pub struct EdgeChanges {
    /// Number of landmarks (and frame nodes) in the map now.
    pub landmark_count: u32,
    /// Each changed edge, keyed by its (smaller, larger) landmark ids, with its new fused value.
    pub edges: Vec<((u32, u32), FusedEdge)>,
}

impl EdgeMap {
    /// An empty map.
    pub fn new() -> Self {
        Self::default()
    }

    /// Fuses one measurement of the edge from `i` to `j`: `y_world_m`
    /// estimates `L_j - L_i` with information `info` (eq. 43). Measurements
    /// given as `(j, i)` are flipped to the stored orientation (`-y`, same
    /// information). Self-edges are ignored.
    pub fn add_measurement(
        &mut self,
        i: u32,
        j: u32,
        y_world_m: &Vector3<f64>,
        info: &Matrix3<f64>,
    ) {
        if i == j {
            return;
        }
        self.landmark_count = self.landmark_count.max(i.max(j) + 1);
        let (key, y) = if i < j {
            ((i, j), *y_world_m)
        } else {
            ((j, i), -y_world_m)
        };
        self.edges.entry(key).or_default().add(&y, info);
        if let Some(touched) = &mut self.touched {
            touched.push(key);
        }
    }

    /// Starts recording which edges change, for [`EdgeMap::take_changes`].
    pub fn track_changes(&mut self) {
        self.touched.get_or_insert_with(Vec::new);
    }

    /// The edges changed since the last call (every edge the first time
    /// after [`EdgeMap::track_changes`] on a map that already had some).
    pub fn take_changes(&mut self) -> EdgeChanges {
        let mut keys = self.touched.replace(Vec::new()).unwrap_or_default();
        keys.sort_unstable();
        keys.dedup();
        EdgeChanges {
            landmark_count: self.landmark_count,
            edges: keys
                .into_iter()
                .filter_map(|k| Some((k, *self.edges.get(&k)?)))
                .collect(),
        }
    }

    /// Turns one frame's observations into edge measurements for the pairs
    /// the policy chose (eq. 41-42) and fuses them (eq. 43).
    /// `R_world_body` is the relative stage's orientation, taken as exact.
    #[allow(non_snake_case)]
    pub fn add_frame(
        &mut self,
        R_world_body: &Matrix3<f64>,
        observations: &[LandmarkObservation],
        pairs: &[(usize, usize)],
    ) {
        for &(a, b) in pairs {
            let (oa, ob) = (&observations[a], &observations[b]);
            let y_world_m = R_world_body * (ob.p_body_m - oa.p_body_m);
            let cov_world_m2 =
                R_world_body * (oa.cov_body_m2 + ob.cov_body_m2) * R_world_body.transpose();
            let Some(info) = cov_world_m2.try_inverse() else {
                continue;
            };
            // Symmetrise: the inverse of a symmetric matrix is symmetric up to rounding.
            let info = 0.5 * (info + info.transpose());
            self.add_measurement(oa.id, ob.id, &y_world_m, &info);
        }
    }

    /// The frame-node form of one frame's observations: the frame's own
    /// (unknown) position is node `frame_node`, and each landmark gets the
    /// edge from it, `y = R_world_body p_body` with information
    /// `(R Σ_body R^T)^-1`. That is the frame's measurement model itself,
    /// so the map's information about its landmarks with the frame node
    /// eliminated is exactly the frame's marginal (every landmark's noise
    /// counted once, positive definite for any covariances), with m edges
    /// per frame instead of m (m - 1) / 2.
    #[allow(non_snake_case)]
    pub fn add_frame_node(
        &mut self,
        R_world_body: &Matrix3<f64>,
        frame_node: u32,
        observations: &[LandmarkObservation],
    ) {
        for o in observations {
            let cov_world_m2 = R_world_body * o.cov_body_m2 * R_world_body.transpose();
            let Some(info) = cov_world_m2.try_inverse() else {
                continue;
            };
            let info = 0.5 * (info + info.transpose());
            self.add_measurement(frame_node, o.id, &(R_world_body * o.p_body_m), &info);
        }
    }

    /// The fused edge between `i` and `j` (in either order), if any.
    pub fn edge(&self, i: u32, j: u32) -> Option<&FusedEdge> {
        self.edges.get(&(i.min(j), i.max(j)))
    }

    /// Number of fused edges.
    pub fn edge_count(&self) -> usize {
        self.edges.len()
    }

    /// Number of landmarks (and frame nodes) in the map.
    pub fn landmark_count(&self) -> u32 {
        self.landmark_count
    }

    /// Ensures the map counts at least `n` landmarks (landmarks without
    /// edges still get an id).
    pub fn reserve_landmarks(&mut self, n: u32) {
        self.landmark_count = self.landmark_count.max(n);
    }

    /// Every edge, sorted by key, so that output is deterministic.
    pub fn sorted_edges(&self) -> Vec<((u32, u32), FusedEdge)> {
        let mut edges: Vec<_> = self.edges.iter().map(|(k, e)| (*k, *e)).collect();
        edges.sort_unstable_by_key(|(k, _)| *k);
        edges
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::seq::SliceRandom;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn random_spd(rng: &mut ChaCha8Rng) -> Matrix3<f64> {
        let m = Matrix3::from_fn(|_, _| rng.gen_range(-1.0..1.0));
        m * m.transpose() + Matrix3::identity() * 0.1
    }

    #[test]
    fn fusion_order_does_not_change_the_fused_edge() {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let measurements: Vec<(Vector3<f64>, Matrix3<f64>)> = (0..50)
            .map(|_| {
                (
                    Vector3::from_fn(|_, _| rng.gen_range(-5.0..5.0)),
                    random_spd(&mut rng),
                )
            })
            .collect();
        let mut forward = FusedEdge::default();
        for (y, s) in &measurements {
            forward.add(y, s);
        }
        let mut shuffled = measurements.clone();
        shuffled.shuffle(&mut rng);
        let mut other = FusedEdge::default();
        for (y, s) in &shuffled {
            other.add(y, s);
        }
        let (a, b) = (forward.mean().unwrap(), other.mean().unwrap());
        assert!((a - b).norm() <= 1e-12 * a.norm().max(1.0), "{a} vs {b}");
        assert!((forward.info - other.info).norm() <= 1e-12 * forward.info.norm());
        // Merging two halves fused apart gives the same edge too.
        let mut first = FusedEdge::default();
        let mut second = FusedEdge::default();
        for (k, (y, s)) in measurements.iter().enumerate() {
            if k % 2 == 0 {
                first.add(y, s)
            } else {
                second.add(y, s)
            }
        }
        first.merge(&second);
        assert!((first.mean().unwrap() - a).norm() <= 1e-12 * a.norm().max(1.0));
        assert_eq!(first.count, 50);
    }

    #[test]
    fn fused_edge_is_the_weighted_least_squares_estimate() {
        // Independent reference: minimise sum (y - y_k)^T S_k (y - y_k) by
        // setting the gradient to zero, written out for two measurements with
        // diagonal information: per axis (s1 y1 + s2 y2) / (s1 + s2).
        let mut e = FusedEdge::default();
        e.add(
            &Vector3::new(1.0, 2.0, 3.0),
            &Matrix3::from_diagonal(&Vector3::new(1.0, 4.0, 9.0)),
        );
        e.add(
            &Vector3::new(3.0, 0.0, 3.0),
            &Matrix3::from_diagonal(&Vector3::new(3.0, 4.0, 1.0)),
        );
        let m = e.mean().unwrap();
        let expected = Vector3::new((1.0 + 9.0) / 4.0, 8.0 / 8.0, 30.0 / 10.0);
        assert!((m - expected).norm() < 1e-14, "{m}");
        let c = e.covariance().unwrap();
        assert!((c[(0, 0)] - 0.25).abs() < 1e-15 && (c[(1, 1)] - 0.125).abs() < 1e-15);
    }

    #[test]
    fn reversed_measurement_is_flipped_into_the_stored_orientation() {
        let mut map = EdgeMap::new();
        let s = Matrix3::identity();
        map.add_measurement(3, 1, &Vector3::new(1.0, 0.0, 0.0), &s);
        map.add_measurement(1, 3, &Vector3::new(-3.0, 0.0, 0.0), &s);
        let e = map.edge(3, 1).unwrap();
        assert_eq!(e.count, 2);
        assert!((e.mean().unwrap() - Vector3::new(-2.0, 0.0, 0.0)).norm() < 1e-15);
        assert_eq!(map.landmark_count(), 4);
    }
}
