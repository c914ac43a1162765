//! Timestamped poses: what datasets hold as ground truth, what the pipeline
//! writes out and what the evaluation compares.

use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};

/// The pose of the body (IMU) frame in the world frame at one instant.
#[allow(non_snake_case)]
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StampedPose {
    /// Stamp, ns (the clock of the sensors the pose was estimated from, or the ground truth's).
    pub t_ns: i64,
    /// Maps body coordinates into the world frame.
    pub T_world_body: Isometry3<f64>,
}

impl StampedPose {
    /// The pose with body position `position` (world frame, m) and body-to-world rotation
    /// `orientation` at `t_ns`.
    pub fn new(t_ns: i64, position: Vector3<f64>, orientation: UnitQuaternion<f64>) -> Self {
        Self {
            t_ns,
            T_world_body: Isometry3::from_parts(Translation3::from(position), orientation),
        }
    }
    /// Body origin in the world frame, m.
    pub fn position(&self) -> Vector3<f64> {
        self.T_world_body.translation.vector
    }
    /// Body-to-world rotation.
    pub fn orientation(&self) -> UnitQuaternion<f64> {
        self.T_world_body.rotation
    }
    /// The stamp in seconds.
    pub fn t_s(&self) -> f64 {
        self.t_ns as f64 * 1e-9
    }
}

/// Poses in time order. Stamps never decrease but may repeat: TUM
/// estimates repeat one now and then and the readers keep both poses, as
/// evo does (see [`crate::dataset::read_tum`]). EuRoC ground truth and
/// what the pipeline writes strictly increase; code that divides by the
/// time between neighbours (interpolation, spline fitting) checks
/// [`Self::is_time_ordered`].
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Trajectory {
    /// The poses, in time order.
    pub poses: Vec<StampedPose>,
}

impl Trajectory {
    /// A trajectory of `poses`, taken as given (not sorted or checked).
    pub fn new(poses: Vec<StampedPose>) -> Self {
        Self { poses }
    }
    /// Number of poses.
    pub fn len(&self) -> usize {
        self.poses.len()
    }
    /// Whether there is no pose.
    pub fn is_empty(&self) -> bool {
        self.poses.is_empty()
    }
    /// Sum of the distances between consecutive positions, m.
    pub fn path_length_m(&self) -> f64 {
        self.poses
            .windows(2)
            .map(|w| (w[1].position() - w[0].position()).norm())
            .sum()
    }
    /// True when stamps strictly increase: no two poses share a stamp,
    /// so every gap between neighbours is positive.
    pub fn is_time_ordered(&self) -> bool {
        self.poses.windows(2).all(|w| w[0].t_ns < w[1].t_ns)
    }
    /// True when stamps never go back; repeats allowed. This is what every
    /// reader guarantees.
    pub fn is_non_decreasing(&self) -> bool {
        self.poses.windows(2).all(|w| w[0].t_ns <= w[1].t_ns)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn path_length_sums_segments() {
        let q = UnitQuaternion::identity();
        let t = Trajectory::new(vec![
            StampedPose::new(0, Vector3::new(0.0, 0.0, 0.0), q),
            StampedPose::new(1, Vector3::new(3.0, 4.0, 0.0), q),
            StampedPose::new(2, Vector3::new(3.0, 4.0, 2.0), q),
        ]);
        assert!((t.path_length_m() - 7.0).abs() < 1e-12);
    }

    #[test]
    fn strict_and_non_decreasing_order_differ_on_repeats() {
        let q = UnitQuaternion::identity();
        let at = |stamps: &[i64]| {
            Trajectory::new(
                stamps
                    .iter()
                    .map(|&t_ns| StampedPose::new(t_ns, Vector3::zeros(), q))
                    .collect(),
            )
        };
        let increasing = at(&[0, 1, 2]);
        assert!(increasing.is_time_ordered() && increasing.is_non_decreasing());
        let repeated = at(&[0, 1, 1, 2]);
        assert!(!repeated.is_time_ordered() && repeated.is_non_decreasing());
        let backwards = at(&[0, 2, 1]);
        assert!(!backwards.is_time_ordered() && !backwards.is_non_decreasing());
        for trivial in [at(&[]), at(&[5])] {
            assert!(trivial.is_time_ordered() && trivial.is_non_decreasing());
        }
    }
}
