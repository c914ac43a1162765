//! Error metrics of an aligned estimate against its matched ground truth.

use nalgebra::{Isometry3, Vector3};

/// Summary statistics of a list of errors, in the errors' unit.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct ErrorStats {
    /// Root mean square.
    pub rmse: f64,
    /// Mean.
    pub mean: f64,
    /// Median.
    pub median: f64,
    /// Largest.
    pub max: f64,
    /// Smallest.
    pub min: f64,
    /// Population standard deviation (divides by n, as evo does).
    pub std: f64,
    /// Number of errors (at least 1).
    pub count: usize,
}

impl ErrorStats {
    /// `None` for an empty list. The median of an even count is the mean
    /// of the two middle values (numpy's convention).
    pub fn of(errors: &[f64]) -> Option<Self> {
        if errors.is_empty() {
            return None;
        }
        let n = errors.len() as f64;
        let mean = errors.iter().sum::<f64>() / n;
        let mean_sq = errors.iter().map(|e| e * e).sum::<f64>() / n;
        let var = errors.iter().map(|e| (e - mean).powi(2)).sum::<f64>() / n;
        let mut sorted = errors.to_vec();
        sorted.sort_by(f64::total_cmp);
        let mid = sorted.len() / 2;
        let median = if sorted.len() % 2 == 1 {
            sorted[mid]
        } else {
            0.5 * (sorted[mid - 1] + sorted[mid])
        };
        Some(Self {
            rmse: mean_sq.sqrt(),
            mean,
            median,
            max: sorted[sorted.len() - 1],
            min: sorted[0],
            std: var.sqrt(),
            count: errors.len(),
        })
    }
}

/// Absolute trajectory error: the distance between each aligned estimated
/// position and its true position, m.
#[allow(non_snake_case)]
pub fn ate_errors_m(T_world_est: &[Isometry3<f64>], T_world_gt: &[Isometry3<f64>]) -> Vec<f64> {
    T_world_est
        .iter()
        .zip(T_world_gt)
        .map(|(e, g)| (e.translation.vector - g.translation.vector).norm())
        .collect()
}

/// The relative pose error between poses i and j:
/// `E = (Q_i^-1 Q_j)^-1 (P_i^-1 P_j)` with Q the truth and P the estimate
/// (Sturm et al., "A benchmark for the evaluation of RGB-D SLAM systems",
/// IROS 2012, eq. 1; evo's `RPE`). Returns (|translation of E| m, angle of E rad).
#[allow(non_snake_case)]
pub fn relative_error(
    T_world_est: &[Isometry3<f64>],
    T_world_gt: &[Isometry3<f64>],
    i: usize,
    j: usize,
) -> (f64, f64) {
    let gt_ij = T_world_gt[i].inverse() * T_world_gt[j];
    let est_ij = T_world_est[i].inverse() * T_world_est[j];
    let e = gt_ij.inverse() * est_ij;
    // atan2 keeps full precision for small angles, where acos(w) does not.
    let q = e.rotation.quaternion();
    let angle_rad = 2.0 * q.imag().norm().atan2(q.w.abs());
    (e.translation.vector.norm(), angle_rad)
}

/// Relative error between consecutive matched poses: translation m and
/// rotation deg per pair (n - 1 pairs).
#[allow(non_snake_case)]
pub fn rpe_per_frame(
    T_world_est: &[Isometry3<f64>],
    T_world_gt: &[Isometry3<f64>],
) -> (Vec<f64>, Vec<f64>) {
    (1..T_world_est.len())
        .map(|j| {
            let (t_m, r_rad) = relative_error(T_world_est, T_world_gt, j - 1, j);
            (t_m, r_rad.to_degrees())
        })
        .unzip()
}

/// Relative errors over a fixed travelled distance.
#[derive(Debug, Clone, Default)]
pub struct RpeOverDistance {
    /// (start, end) matched-pose indices of each pair.
    pub pairs: Vec<(usize, usize)>,
    /// Ground-truth path length between start and end, m.
    pub distances_m: Vec<f64>,
    /// Relative translation error of the pair, m.
    pub trans_errors_m: Vec<f64>,
    /// Relative rotation error of the pair, deg.
    pub rot_errors_deg: Vec<f64>,
}

impl RpeOverDistance {
    /// Mean of translation error over distance, m/m: the drift rate.
    pub fn mean_trans_m_per_m(&self) -> Option<f64> {
        let n = self.pairs.len();
        (n > 0).then(|| {
            self.trans_errors_m
                .iter()
                .zip(&self.distances_m)
                .map(|(e, d)| e / d)
                .sum::<f64>()
                / n as f64
        })
    }
    /// Mean of rotation error over distance, deg/m.
    pub fn mean_rot_deg_per_m(&self) -> Option<f64> {
        let n = self.pairs.len();
        (n > 0).then(|| {
            self.rot_errors_deg
                .iter()
                .zip(&self.distances_m)
                .map(|(e, d)| e / d)
                .sum::<f64>()
                / n as f64
        })
    }
}

/// Pairs every matched pose i with the later matched pose j whose
/// ground-truth path length from i (summed over matched poses) is closest
/// to `delta_m`, kept when within `tol_m` of it (the first such j on ties),
/// and computes their relative error. This is evo's `--delta_unit m
/// --all_pairs --delta_tol` selection.
#[allow(non_snake_case)]
pub fn rpe_over_distance(
    T_world_est: &[Isometry3<f64>],
    T_world_gt: &[Isometry3<f64>],
    delta_m: f64,
    tol_m: f64,
) -> RpeOverDistance {
    let gt_positions: Vec<Vector3<f64>> = T_world_gt.iter().map(|t| t.translation.vector).collect();
    let travelled_m = cumulative_path_m(&gt_positions);
    let mut out = RpeOverDistance::default();
    for i in 0..travelled_m.len().saturating_sub(1) {
        // Distances from i to every later pose, non-decreasing; evo takes
        // the first index minimising |d - delta|, computed in this order
        // (subtract, then compare) so that boundary cases round alike.
        let later = &travelled_m[i + 1..];
        let off_by = |k: usize| ((later[k] - travelled_m[i]) - delta_m).abs();
        // The minimum is beside the first distance at or past delta.
        let k = later.partition_point(|&d| d - travelled_m[i] < delta_m);
        let mut first = match k.checked_sub(1) {
            Some(before) if k == later.len() || off_by(before) <= off_by(k) => before,
            _ => k,
        };
        // evo takes the first index with the minimal value: walk back over
        // a plateau (poses that did not move).
        while first > 0 && off_by(first - 1) == off_by(first) {
            first -= 1;
        }
        let distance_m = later[first] - travelled_m[i];
        if (distance_m - delta_m).abs() > tol_m {
            continue;
        }
        let j = i + 1 + first;
        let (t_m, r_rad) = relative_error(T_world_est, T_world_gt, i, j);
        out.pairs.push((i, j));
        out.distances_m.push(distance_m);
        out.trans_errors_m.push(t_m);
        out.rot_errors_deg.push(r_rad.to_degrees());
    }
    out
}

/// Path length from the first position to each position, m.
pub fn cumulative_path_m(positions: &[Vector3<f64>]) -> Vec<f64> {
    let mut sum = 0.0;
    let mut out = Vec::with_capacity(positions.len());
    for (k, p) in positions.iter().enumerate() {
        if k > 0 {
            sum += (p - positions[k - 1]).norm();
        }
        out.push(sum);
    }
    out
}

/// Sum of segment lengths, m.
pub fn path_length_m(positions: &[Vector3<f64>]) -> f64 {
    positions.windows(2).map(|w| (w[1] - w[0]).norm()).sum()
}

/// The paper's final drift (eq. 72): the distance between the final
/// estimated and final true positions over the length of the true path,
/// in percent, with the estimate anchored at its first pose.
///
/// Anchoring: the first matched estimated pose is made equal to the first
/// matched true pose, i.e. `T_gt0 * T_est0^-1` is applied to the whole
/// estimate. With `scale_by_path` (monocular runs, the paper's
/// configuration 1) the estimate's displacements from its first pose are
/// also multiplied by `est_to_gt_path_ratio` (true over estimated path
/// length) before anchoring. `true_path_m` is the length of the true path
/// between the first and the last matched stamps.
#[allow(non_snake_case)]
pub fn final_drift_pct(
    T_world_est: &[Isometry3<f64>],
    T_world_gt: &[Isometry3<f64>],
    true_path_m: f64,
    path_scale: f64,
) -> Option<f64> {
    let (first_est, last_est) = (T_world_est.first()?, T_world_est.last()?);
    let (first_gt, last_gt) = (T_world_gt.first()?, T_world_gt.last()?);
    if true_path_m <= 0.0 {
        return None;
    }
    let T_gt_est = first_gt * first_est.inverse();
    let displacement = path_scale * (last_est.translation.vector - first_est.translation.vector);
    // The anchor maps p_est0 to p_gt0 and rotates displacements by its rotation.
    let anchored_last = first_gt.translation.vector + T_gt_est.rotation * displacement;
    Some(100.0 * (anchored_last - last_gt.translation.vector).norm() / true_path_m)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion};

    fn pose(x: f64, y: f64, z: f64, yaw: f64) -> Isometry3<f64> {
        Isometry3::from_parts(
            Translation3::new(x, y, z),
            UnitQuaternion::from_euler_angles(0.0, 0.0, yaw),
        )
    }

    #[test]
    fn stats_match_hand_computed_values() {
        let s = ErrorStats::of(&[3.0, 1.0, 4.0, 2.0]).expect("non-empty");
        assert_eq!(s.mean, 2.5);
        assert_eq!(s.median, 2.5);
        assert_eq!((s.min, s.max), (1.0, 4.0));
        assert!((s.rmse - 7.5f64.sqrt()).abs() < 1e-15);
        assert!((s.std - 1.25f64.sqrt()).abs() < 1e-15);
        assert_eq!(ErrorStats::of(&[5.0, 1.0, 3.0]).expect("odd").median, 3.0);
        assert!(ErrorStats::of(&[]).is_none());
    }

    #[test]
    fn rpe_sees_a_constant_bias_per_step_and_not_a_global_offset() {
        // Truth walks 1 m along x per step; the estimate walks 1.1 m, and is
        // moved and rotated as a whole, which RPE must not see.
        let offset = pose(5.0, -2.0, 1.0, 0.7);
        let gt: Vec<_> = (0..6).map(|k| pose(k as f64, 0.0, 0.0, 0.0)).collect();
        let est: Vec<_> = (0..6)
            .map(|k| offset * pose(1.1 * k as f64, 0.0, 0.0, 0.0))
            .collect();
        let (t, r) = rpe_per_frame(&est, &gt);
        assert_eq!(t.len(), 5);
        assert!(t.iter().all(|e| (e - 0.1).abs() < 1e-12), "{t:?}");
        assert!(r.iter().all(|e| e.abs() < 1e-9), "{r:?}");
        let d = rpe_over_distance(&est, &gt, 2.0, 0.1);
        assert_eq!(d.pairs, vec![(0, 2), (1, 3), (2, 4), (3, 5)]);
        assert!((d.mean_trans_m_per_m().expect("pairs") - 0.1).abs() < 1e-12);
    }

    #[test]
    fn rpe_rotation_is_reported_in_degrees() {
        let gt: Vec<_> = (0..3).map(|k| pose(k as f64, 0.0, 0.0, 0.0)).collect();
        let est: Vec<_> = (0..3)
            .map(|k| pose(k as f64, 0.0, 0.0, (2.0 * k as f64).to_radians()))
            .collect();
        let (_, r) = rpe_per_frame(&est, &gt);
        assert!(r.iter().all(|e| (e - 2.0).abs() < 1e-9), "{r:?}");
    }

    #[test]
    fn rpe_over_distance_skips_pairs_outside_tolerance() {
        // Steps of 0.3 m: from each start 0.9 or 1.2 m, never within 0.05 of 1 m.
        let gt: Vec<_> = (0..10)
            .map(|k| pose(0.3 * k as f64, 0.0, 0.0, 0.0))
            .collect();
        assert!(rpe_over_distance(&gt, &gt, 1.0, 0.05).pairs.is_empty());
        // With 0.1 m tolerance (plus rounding) 0.9 m, 3 steps on, is closer
        // than 1.2 m and taken, for starts 0..=6; start 7 reaches 0.6 m only.
        let d = rpe_over_distance(&gt, &gt, 1.0, 0.1 + 1e-9);
        assert_eq!(d.pairs[0], (0, 3));
        assert_eq!(d.pairs.len(), 7);
    }

    #[test]
    fn final_drift_anchors_at_the_first_pose() {
        // Truth: 10 m along x. Estimate: starts elsewhere, rotated by 90 deg
        // about z, and ends 0.5 m short: after anchoring the drift is 5 %.
        let gt = vec![pose(0.0, 0.0, 0.0, 0.0), pose(10.0, 0.0, 0.0, 0.0)];
        let rot = std::f64::consts::FRAC_PI_2;
        let est = vec![pose(3.0, 3.0, 0.0, rot), pose(3.0, 12.5, 0.0, rot)];
        let pct = final_drift_pct(&est, &gt, 10.0, 1.0).expect("defined");
        assert!((pct - 5.0).abs() < 1e-9, "{pct}");
        // A monocular estimate at half scale, scaled back by path lengths.
        let half = vec![pose(3.0, 3.0, 0.0, rot), pose(3.0, 8.0, 0.0, rot)];
        let pct = final_drift_pct(&half, &gt, 10.0, 2.0).expect("defined");
        assert!(pct.abs() < 1e-9, "{pct}");
    }
}
