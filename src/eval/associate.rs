//! Timestamp association of an estimate with its ground truth.

use nalgebra::Isometry3;

use super::error::EvalError;
use crate::trajectory::Trajectory;

/// Estimated and true poses paired by time, in increasing time order.
#[allow(non_snake_case)]
#[derive(Debug, Clone, Default)]
pub struct MatchedPoses {
    /// Index of each pair's pose in the estimate.
    pub est_index: Vec<usize>,
    /// Index of each pair's pose in the ground truth.
    pub gt_index: Vec<usize>,
    /// Ground-truth stamp of each pair, ns.
    pub t_ns: Vec<i64>,
    /// Estimated pose of each pair (body in the estimate's world).
    pub T_world_est: Vec<Isometry3<f64>>,
    /// Ground-truth pose of each pair (body in the ground-truth world).
    pub T_world_gt: Vec<Isometry3<f64>>,
}

impl MatchedPoses {
    /// Number of pairs.
    pub fn len(&self) -> usize {
        self.t_ns.len()
    }
    /// Whether no pose was paired.
    pub fn is_empty(&self) -> bool {
        self.t_ns.is_empty()
    }
}

/// Pairs each pose of the estimate with the ground-truth pose nearest in
/// time, at most `max_dt_ns` away, after adding `t_offset_ns` to the
/// estimate's stamps. One-to-one between distinct stamps.
///
/// The rule mirrors evo's `associate_trajectories` (evo 1.38,
/// `core/sync.py`) so that matched-pose counts and metrics agree with it:
/// the trajectory with fewer poses drives the search, each of its stamps
/// takes the nearest stamp of the other, a tie goes to the earlier stamp,
/// and a difference equal to the limit is accepted.
///
/// evo may give one pose of the denser trajectory to two poses of the
/// sparser one. When their stamps differ (the sparser trajectory is
/// locally denser) only the nearer keeps it here, so no true pose stands
/// for two different instants. When their stamps are equal (a file with a
/// repeated stamp, like the V1_02 sample estimate evo ships, 4 times) both
/// keep it, as in evo: both claim to be the pose at that instant.
pub fn associate(
    estimate: &Trajectory,
    ground_truth: &Trajectory,
    max_dt_ns: i64,
    t_offset_ns: i64,
) -> Result<MatchedPoses, EvalError> {
    if estimate.is_empty() {
        return Err(EvalError::Empty { which: "estimated" });
    }
    if ground_truth.is_empty() {
        return Err(EvalError::Empty {
            which: "ground-truth",
        });
    }
    let est_t_ns: Vec<i64> = estimate
        .poses
        .iter()
        .map(|p| p.t_ns + t_offset_ns)
        .collect();
    let gt_t_ns: Vec<i64> = ground_truth.poses.iter().map(|p| p.t_ns).collect();

    let est_drives = est_t_ns.len() <= gt_t_ns.len();
    let (short, long) = if est_drives {
        (&est_t_ns, &gt_t_ns)
    } else {
        (&gt_t_ns, &est_t_ns)
    };
    // Per pose of the sparser side: (index in the denser side, |dt|).
    let mut matches: Vec<Option<(usize, i64)>> =
        short.iter().map(|&t| nearest(long, t, max_dt_ns)).collect();
    // One-to-one: of the stamps that claim the same pose, the nearest (the
    // earlier on a tie) keeps it, with any pose that has exactly its stamp.
    let mut best_claim: Vec<Option<(i64, i64)>> = vec![None; long.len()];
    for (i, m) in matches.iter().enumerate() {
        if let Some((j, dt)) = *m {
            if best_claim[j].map_or(true, |(best_dt, _)| dt < best_dt) {
                best_claim[j] = Some((dt, short[i]));
            }
        }
    }
    for (i, m) in matches.iter_mut().enumerate() {
        if let Some((j, _)) = *m {
            let (_, best_t_ns) = best_claim[j].expect("every claim was recorded");
            if short[i] != best_t_ns {
                *m = None;
            }
        }
    }

    let mut out = MatchedPoses::default();
    for (i, m) in matches.iter().enumerate() {
        let Some((j, _)) = *m else { continue };
        let (ie, ig) = if est_drives { (i, j) } else { (j, i) };
        out.est_index.push(ie);
        out.gt_index.push(ig);
        out.t_ns.push(gt_t_ns[ig]);
        out.T_world_est.push(estimate.poses[ie].T_world_body);
        out.T_world_gt.push(ground_truth.poses[ig].T_world_body);
    }
    if out.is_empty() {
        return Err(EvalError::NoMatches {
            max_dt_ms: max_dt_ns as f64 * 1e-6,
            t_offset_s: t_offset_ns as f64 * 1e-9,
            est_first_s: estimate.poses[0].t_s(),
            est_last_s: estimate.poses[estimate.len() - 1].t_s(),
            est_count: estimate.len(),
            gt_first_s: ground_truth.poses[0].t_s(),
            gt_last_s: ground_truth.poses[ground_truth.len() - 1].t_s(),
            gt_count: ground_truth.len(),
        });
    }
    Ok(out)
}

/// Index and |dt| of the stamp in sorted `stamps_ns` nearest to `t_ns`,
/// ties to the earlier one, if within `max_dt_ns`.
fn nearest(stamps_ns: &[i64], t_ns: i64, max_dt_ns: i64) -> Option<(usize, i64)> {
    // First stamp strictly after t (evo: searchsorted side="right").
    let after = stamps_ns.partition_point(|&s| s <= t_ns);
    let candidates = [
        after.checked_sub(1).map(|j| (j, t_ns - stamps_ns[j])),
        (after < stamps_ns.len()).then(|| (after, stamps_ns[after] - t_ns)),
    ];
    candidates
        .into_iter()
        .flatten()
        .filter(|&(_, dt)| dt <= max_dt_ns)
        .min_by_key(|&(j, dt)| (dt, j))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::trajectory::StampedPose;
    use nalgebra::{UnitQuaternion, Vector3};

    fn traj(t_ns: &[i64]) -> Trajectory {
        Trajectory::new(
            t_ns.iter()
                .map(|&t| {
                    StampedPose::new(
                        t,
                        Vector3::new(t as f64, 0.0, 0.0),
                        UnitQuaternion::identity(),
                    )
                })
                .collect(),
        )
    }

    const MS: i64 = 1_000_000;

    #[test]
    fn nearest_within_limit_ties_to_earlier() {
        let gt = traj(&[0, 5 * MS, 10 * MS, 15 * MS, 20 * MS, 100 * MS]);
        // 7.5 ms is equally far from 5 and 10: the earlier wins. 60 ms is
        // 40 ms from anything: unmatched. 30 ms is exactly 10 ms from 20: kept.
        let est = traj(&[7 * MS + MS / 2, 11 * MS, 30 * MS, 60 * MS]);
        let m = associate(&est, &gt, 10 * MS, 0).expect("matches");
        assert_eq!(m.est_index, vec![0, 1, 2]);
        assert_eq!(m.gt_index, vec![1, 2, 4]);
        assert_eq!(m.t_ns, vec![5 * MS, 10 * MS, 20 * MS]);
    }

    #[test]
    fn offset_is_added_to_the_estimate() {
        let gt = traj(&[1000 * MS, 1100 * MS]);
        let est = traj(&[0, 100 * MS]);
        let m = associate(&est, &gt, 10 * MS, 1000 * MS).expect("matches");
        assert_eq!(m.gt_index, vec![0, 1]);
    }

    #[test]
    fn one_to_one_when_the_estimate_is_denser() {
        // The ground truth is sparser, so it drives: each of its two stamps
        // takes its nearest estimate stamp, the others stay unmatched.
        let gt = traj(&[0, 10 * MS]);
        let est = traj(&[-MS, MS / 2, 3 * MS, 9 * MS, 12 * MS]);
        let m = associate(&est, &gt, 10 * MS, 0).expect("matches");
        assert_eq!(m.gt_index, vec![0, 1]);
        assert_eq!(m.est_index, vec![1, 3]);
    }

    #[test]
    fn duplicate_claims_keep_the_closer_pose() {
        // Estimate (4 poses) is sparser than the ground truth (5 poses) but
        // locally denser: 0 and 4 ms both find gt 3 ms nearest.
        let gt = traj(&[3 * MS, 100 * MS, 200 * MS, 300 * MS, 400 * MS]);
        let est = traj(&[0, 4 * MS, 200 * MS, 300 * MS]);
        let m = associate(&est, &gt, 10 * MS, 0).expect("matches");
        assert_eq!(m.est_index, vec![1, 2, 3]);
        assert_eq!(m.gt_index, vec![0, 2, 3]);
    }

    #[test]
    fn repeated_stamps_share_their_partner() {
        let gt = traj(&[0, 5 * MS, 10 * MS, 15 * MS, 20 * MS]);
        let est = traj(&[MS, 11 * MS, 11 * MS, 19 * MS]);
        let m = associate(&est, &gt, 10 * MS, 0).expect("matches");
        assert_eq!(m.est_index, vec![0, 1, 2, 3]);
        assert_eq!(m.gt_index, vec![0, 2, 2, 4]);
    }

    #[test]
    fn no_match_error_prints_both_ranges() {
        // Estimate in seconds-as-ns by mistake: 1.4e9 ns = 1.4 s.
        let gt = traj(&[1_403_715_000 * 1_000_000_000, 1_403_715_001 * 1_000_000_000]);
        let est = traj(&[1_403_715_000, 1_403_715_001]);
        let err = associate(&est, &gt, 10 * MS, 0)
            .expect_err("nothing matches")
            .to_string();
        assert!(err.contains("1.403715 .. 1.403715 s"), "{err}");
        assert!(
            err.contains("1403715000.000000 .. 1403715001.000000 s"),
            "{err}"
        );
        assert!(err.contains("seconds vs nanoseconds"), "{err}");
    }
}
