//! Attitude against gravity: how far each pose's roll and pitch are from
//! the truth's, whatever the heading. An inertial estimate observes the
//! direction of gravity, so unlike position and heading this error does
//! not drift and needs no alignment: it is the angle between the
//! world's up axis seen from the body in the estimate and in the ground
//! truth (both worlds z up, as EuRoC's and the rendered sequences' are).
//! An SE(3)-aligned ATE hides a world that is tilted as a whole; this
//! shows it.

use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

use super::consistency::interpolate;
use crate::trajectory::Trajectory;

/// Tilt error over a trajectory, deg.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct TiltReport {
    /// Poses the ground truth covers.
    pub poses: usize,
    /// Root mean square over them.
    pub rms_deg: f64,
    /// The largest.
    pub max_deg: f64,
}

/// The tilt error of every pose of `estimate` that `ground_truth` covers;
/// None when it covers none.
pub fn tilt_error(estimate: &Trajectory, ground_truth: &Trajectory) -> Option<TiltReport> {
    let up = Vector3::z();
    let (mut sum_sq, mut max, mut n) = (0.0f64, 0.0f64, 0usize);
    for pose in &estimate.poses {
        let Some(truth) = interpolate(ground_truth, pose.t_ns) else {
            continue;
        };
        let seen = pose.T_world_body.rotation.inverse() * up;
        let true_up = truth.rotation.inverse() * up;
        let deg = seen.angle(&true_up).to_degrees();
        sum_sq += deg * deg;
        max = max.max(deg);
        n += 1;
    }
    (n > 0).then(|| TiltReport {
        poses: n,
        rms_deg: (sum_sq / n as f64).sqrt(),
        max_deg: max,
    })
}

#[cfg(test)]
mod tests {
    use nalgebra::{Isometry3, Translation3, Unit, UnitQuaternion};

    use super::*;
    use crate::trajectory::StampedPose;

    fn trajectory(rotations: &[UnitQuaternion<f64>]) -> Trajectory {
        Trajectory::new(
            rotations
                .iter()
                .enumerate()
                .map(|(i, q)| StampedPose {
                    t_ns: i as i64 * 100_000_000,
                    T_world_body: Isometry3::from_parts(Translation3::new(i as f64, 0.0, 0.0), *q),
                })
                .collect(),
        )
    }

    #[test]
    fn heading_and_position_do_not_count_and_a_tilted_world_does() {
        let truth: Vec<UnitQuaternion<f64>> = (0..20)
            .map(|i| {
                UnitQuaternion::from_euler_angles(0.1 * (i as f64).sin(), -0.05, 0.3 * i as f64)
            })
            .collect();
        let gt = trajectory(&truth);
        // Another heading and other positions: no tilt error.
        let yawed: Vec<_> = truth
            .iter()
            .map(|q| UnitQuaternion::from_axis_angle(&Vector3::z_axis(), 0.7) * q)
            .collect();
        let mut shifted = trajectory(&yawed);
        for p in &mut shifted.poses {
            p.T_world_body.translation.vector += Vector3::new(3.0, -2.0, 1.0);
        }
        let r = tilt_error(&shifted, &gt).expect("covered");
        assert_eq!(r.poses, 20);
        assert!(r.rms_deg < 1e-6, "{}", r.rms_deg);
        // The whole world tilted by 1 deg about a horizontal axis: 1 deg on
        // every pose.
        let tilt = UnitQuaternion::from_axis_angle(
            &Unit::new_normalize(Vector3::new(1.0, 2.0, 0.0)),
            1f64.to_radians(),
        );
        let tilted: Vec<_> = truth.iter().map(|q| tilt * q).collect();
        let r = tilt_error(&trajectory(&tilted), &gt).expect("covered");
        assert!(
            (r.rms_deg - 1.0).abs() < 1e-9 && (r.max_deg - 1.0).abs() < 1e-9,
            "{r:?}"
        );
    }

    #[test]
    fn poses_outside_the_ground_truth_are_not_scored() {
        let gt = trajectory(&[UnitQuaternion::identity(); 3]);
        let mut late = trajectory(&[UnitQuaternion::identity(); 3]);
        for p in &mut late.poses {
            p.t_ns += 10_000_000_000;
        }
        assert!(tilt_error(&late, &gt).is_none());
    }
}
