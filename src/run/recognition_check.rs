//! The absolute stage's landmark recognitions checked against ground truth
//! (`rigslam run --absolute` on a dataset that has one): a track that was
//! recognised as a map landmark and that landmark's first track should be
//! the same point of the world. Each is placed in the world with the true
//! body pose of the frame where the relative stage knew it best (smallest
//! largest standard deviation), so what is left is their measurement
//! error; a wrong recognition shows as a distance far above it.
//!
//! Assumes the ground truth gives the body (IMU) frame's pose, as EuRoC's
//! `state_groundtruth_estimate0` and `rigslam simulate` do.

use std::collections::HashMap;

use nalgebra::Vector3;

use crate::relative::types::{LandmarkId, RelativeOutput};
use crate::trajectory::Trajectory;

/// Recognitions farther apart than this are counted as wrong, m.
pub const WRONG_M: f64 = 0.3;

/// The best sighting of each track, body frame.
#[derive(Debug, Default)]
pub struct SightingLog {
    best: HashMap<LandmarkId, Sighting>,
}

#[derive(Clone, Copy, Debug)]
struct Sighting {
    t_ns: i64,
    position_body_m: Vector3<f64>,
    largest_variance_m2: f64,
}

impl SightingLog {
    /// Keeps each landmark of the frame where it is more precise than in
    /// the frames before.
    pub fn note(&mut self, output: &RelativeOutput) {
        for l in &output.landmarks {
            let variance = l.covariance_body_m2.symmetric_eigenvalues().max();
            if !variance.is_finite() || !l.position_body_m.iter().all(|v| v.is_finite()) {
                continue;
            }
            let sighting = Sighting {
                t_ns: output.t_ns,
                position_body_m: l.position_body_m,
                largest_variance_m2: variance,
            };
            self.best
                .entry(l.id)
                .and_modify(|s| {
                    if variance < s.largest_variance_m2 {
                        *s = sighting;
                    }
                })
                .or_insert(sighting);
        }
    }
}

/// How the recognitions fared against ground truth.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct RecognitionCheck {
    /// Recognitions whose two tracks both fall inside the ground truth.
    pub checked: usize,
    /// Of them, farther apart than [`WRONG_M`] and than 1 m.
    pub wrong: usize,
    /// Of them, farther apart than 1 m.
    pub over_1_m: usize,
    /// Median distance between the two tracks' true positions, m.
    pub median_m: f64,
}

/// Checks `aliases` (a recognised track, the track its landmark was first
/// seen under) against `ground_truth`. None when none can be checked.
pub fn check_recognitions(
    log: &SightingLog,
    aliases: impl Iterator<Item = (LandmarkId, LandmarkId)>,
    ground_truth: &Trajectory,
) -> Option<RecognitionCheck> {
    let world = |track: LandmarkId| {
        let s = log.best.get(&track)?;
        let (position, rotation) = body_pose_at(ground_truth, s.t_ns)?;
        Some(position + rotation * s.position_body_m)
    };
    let mut distances: Vec<f64> = aliases
        .filter_map(|(recognised, first)| Some((world(recognised)? - world(first)?).norm()))
        .collect();
    if distances.is_empty() {
        return None;
    }
    distances.sort_by(f64::total_cmp);
    Some(RecognitionCheck {
        checked: distances.len(),
        wrong: distances.iter().filter(|&&d| d > WRONG_M).count(),
        over_1_m: distances.iter().filter(|&&d| d > 1.0).count(),
        median_m: distances[distances.len() / 2],
    })
}

/// The true body position (interpolated) and orientation (of the nearer
/// pose) at `t_ns`; None outside the ground truth or across a gap of over
/// 50 ms.
fn body_pose_at(
    ground_truth: &Trajectory,
    t_ns: i64,
) -> Option<(Vector3<f64>, nalgebra::Rotation3<f64>)> {
    const MAX_GAP_NS: i64 = 50_000_000;
    let poses = &ground_truth.poses;
    let after = poses.partition_point(|p| p.t_ns < t_ns);
    let b = poses.get(after)?;
    if b.t_ns == t_ns {
        return Some((b.position(), b.orientation().to_rotation_matrix()));
    }
    let a = poses.get(after.checked_sub(1)?)?;
    let gap = b.t_ns - a.t_ns;
    if gap <= 0 || gap > MAX_GAP_NS {
        return None;
    }
    let f = (t_ns - a.t_ns) as f64 / gap as f64;
    let position = a.position() * (1.0 - f) + b.position() * f;
    let nearer = if f < 0.5 { a } else { b };
    Some((position, nearer.orientation().to_rotation_matrix()))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::relative::types::BodyLandmark;
    use crate::trajectory::StampedPose;
    use nalgebra::{Matrix3, UnitQuaternion};

    /// The robot drives along x at 1 m/s, turned 90 deg about z; ground
    /// truth every 10 ms.
    fn truth() -> Trajectory {
        let turn = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), std::f64::consts::FRAC_PI_2);
        Trajectory::new(
            (0..=200)
                .map(|k| {
                    StampedPose::new(
                        k * 10_000_000,
                        Vector3::new(k as f64 * 0.01, 0.0, 0.0),
                        turn,
                    )
                })
                .collect(),
        )
    }

    /// Where the relative stage would see world point `p` at `t_ns`.
    fn seen(id: LandmarkId, p: Vector3<f64>, t_ns: i64, sigma_m: f64) -> RelativeOutput {
        let (position, rotation) = body_pose_at(&truth(), t_ns).expect("inside");
        RelativeOutput::tracking_at_origin(
            t_ns,
            vec![BodyLandmark {
                id,
                position_body_m: rotation.transpose() * (p - position),
                covariance_body_m2: Matrix3::identity() * sigma_m * sigma_m,
                descriptor: None,
                support: None,
            }],
        )
    }

    #[test]
    fn right_and_wrong_recognitions_are_told_apart() {
        let corner = Vector3::new(1.0, 2.0, 0.5);
        let mut log = SightingLog::default();
        // Track 1 first sees the corner at 0.2 s; track 2 is the same
        // corner at 1.5 s; track 3 is a lookalike 0.5 m away at 1.7 s, and
        // its less precise sighting at 1.8 s (placed 2 m off) is ignored.
        log.note(&seen(1, corner, 200_000_000, 0.01));
        log.note(&seen(2, corner, 1_500_000_000, 0.01));
        log.note(&seen(
            3,
            corner + Vector3::new(0.0, 0.5, 0.0),
            1_700_000_000,
            0.01,
        ));
        log.note(&seen(
            3,
            corner + Vector3::new(0.0, 2.0, 0.0),
            1_800_000_000,
            0.2,
        ));
        let check =
            check_recognitions(&log, [(2, 1), (3, 1)].into_iter(), &truth()).expect("two to check");
        assert_eq!(check.checked, 2);
        assert_eq!(check.wrong, 1);
        assert_eq!(check.over_1_m, 0);
        // A track never sighted, or outside the ground truth: not checked.
        let mut outside = SightingLog::default();
        outside.note(&seen(1, corner, 200_000_000, 0.01));
        let mut late = seen(4, corner, 1_000_000_000, 0.01);
        late.t_ns = 5_000_000_000;
        outside.note(&late);
        assert_eq!(
            check_recognitions(&outside, [(4, 1), (5, 1)].into_iter(), &truth()),
            None
        );
    }

    #[test]
    fn the_body_pose_is_interpolated_between_truth_samples() {
        let (p, _) = body_pose_at(&truth(), 15_000_000).expect("inside");
        assert!((p - Vector3::new(0.015, 0.0, 0.0)).norm() < 1e-12);
        assert!(body_pose_at(&truth(), -1).is_none());
        assert!(body_pose_at(&truth(), 2_000_000_001).is_none());
    }
}
