//! A recorded trajectory sampled as it is: the pose at any instant is
//! interpolated between the two recorded poses around it (position
//! linearly, orientation by slerp), with no fitted spline.
//!
//! This is the second way to render a recorded flight, kept for the
//! evaluation set: a sequence rendered this way shares no fitting step
//! with the spline renderings the estimator is developed on. It has no
//! second derivative worth the name (the acceleration is zero between
//! samples and infinite at them), so it only serves with a real IMU log;
//! [`super::sequence`] refuses it with a synthetic IMU.

use nalgebra::{Isometry3, Translation3, Vector3};

use super::motion_state::MotionState;
use crate::imu::so3::log;
use crate::trajectory::{StampedPose, Trajectory};

/// Why a trajectory cannot be sampled.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum InterpolationError {
    #[error("the trajectory has {0} poses; at least 2 are needed")]
    /// Fewer than two poses (the field is how many there are).
    TooShort(usize),
    #[error("the trajectory's stamps are not strictly increasing at pose {index} (t = {t_ns} ns)")]
    /// A stamp is not after the previous one.
    NotIncreasing {
        /// Index of the pose.
        index: usize,
        /// Its stamp, ns.
        t_ns: i64,
    },
    #[error("pose {index} (t = {t_ns} ns) is not finite")]
    /// A pose has a NaN or infinite value.
    NotFinite {
        /// Index of the pose.
        index: usize,
        /// Its stamp, ns.
        t_ns: i64,
    },
}

/// The recorded poses, interpolated.
#[derive(Debug, Clone)]
pub struct InterpolatedMotion {
    poses: Vec<StampedPose>,
}

impl InterpolatedMotion {
    /// Checks `trajectory` (at least two poses, strictly increasing stamps, finite values) and
    /// keeps a copy to interpolate.
    pub fn new(trajectory: &Trajectory) -> Result<Self, InterpolationError> {
        let poses = trajectory.poses.clone();
        if poses.len() < 2 {
            return Err(InterpolationError::TooShort(poses.len()));
        }
        for (index, p) in poses.iter().enumerate() {
            let finite = p.position().iter().all(|v| v.is_finite())
                && p.orientation().coords.iter().all(|v| v.is_finite());
            if !finite {
                return Err(InterpolationError::NotFinite {
                    index,
                    t_ns: p.t_ns,
                });
            }
            if index > 0 && p.t_ns <= poses[index - 1].t_ns {
                return Err(InterpolationError::NotIncreasing {
                    index,
                    t_ns: p.t_ns,
                });
            }
        }
        Ok(Self { poses })
    }

    /// Stamp of the first pose, ns.
    pub fn start_ns(&self) -> i64 {
        self.poses[0].t_ns
    }

    /// Stamp of the last pose, ns.
    pub fn end_ns(&self) -> i64 {
        self.poses[self.poses.len() - 1].t_ns
    }

    /// Pose at `t_ns` (clamped to the span); the velocity and the angular
    /// rate are those of the recorded interval around it, the
    /// acceleration zero.
    pub fn state(&self, t_ns: i64) -> MotionState {
        let t_ns = t_ns.clamp(self.start_ns(), self.end_ns());
        let k = self
            .poses
            .partition_point(|p| p.t_ns <= t_ns)
            .clamp(1, self.poses.len() - 1);
        let (a, b) = (&self.poses[k - 1], &self.poses[k]);
        let span_s = (b.t_ns - a.t_ns) as f64 * 1e-9;
        let u = (t_ns - a.t_ns) as f64 * 1e-9 / span_s;
        let (qa, qb) = (a.orientation(), b.orientation());
        let rotation = qa.slerp(&qb, u);
        let position = a.position() * (1.0 - u) + b.position() * u;
        let relative = (qa.inverse() * qb).to_rotation_matrix().into_inner();
        MotionState {
            T_world_body: Isometry3::from_parts(Translation3::from(position), rotation),
            velocity_world_m_s: (b.position() - a.position()) / span_s,
            accel_world_m_s2: Vector3::zeros(),
            omega_body_rad_s: log(&relative) / span_s,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::UnitQuaternion;

    fn pose(t_s: f64, x: f64, yaw: f64) -> StampedPose {
        StampedPose::new(
            (t_s * 1e9) as i64,
            Vector3::new(x, 0.0, 0.0),
            UnitQuaternion::from_euler_angles(0.0, 0.0, yaw),
        )
    }

    #[test]
    fn interpolates_between_and_reproduces_the_recorded_poses() {
        let m = InterpolatedMotion::new(&Trajectory::new(vec![
            pose(1.0, 0.0, 0.0),
            pose(1.1, 0.2, 0.1),
            pose(1.2, 0.2, 0.3),
        ]))
        .unwrap();
        let at = |t_s: f64| m.state((t_s * 1e9) as i64);
        assert!((at(1.1).T_world_body.translation.x - 0.2).abs() < 1e-12);
        assert!((at(1.1).T_world_body.rotation.euler_angles().2 - 0.1).abs() < 1e-12);
        let mid = at(1.15);
        assert!((mid.T_world_body.translation.x - 0.2).abs() < 1e-12);
        assert!((mid.T_world_body.rotation.euler_angles().2 - 0.2).abs() < 1e-9);
        assert!((at(1.05).velocity_world_m_s.x - 2.0).abs() < 1e-9);
        assert!((at(1.15).omega_body_rad_s.z - 2.0).abs() < 1e-9);
        // Clamped outside the span.
        assert!((at(0.5).T_world_body.translation.x).abs() < 1e-12);
        assert!((at(2.0).T_world_body.rotation.euler_angles().2 - 0.3).abs() < 1e-12);
    }

    #[test]
    fn refuses_short_unordered_or_non_finite_trajectories() {
        let err = |poses| InterpolatedMotion::new(&Trajectory::new(poses)).unwrap_err();
        assert_eq!(
            err(vec![pose(1.0, 0.0, 0.0)]),
            InterpolationError::TooShort(1)
        );
        assert!(matches!(
            err(vec![pose(1.0, 0.0, 0.0), pose(1.0, 1.0, 0.0)]),
            InterpolationError::NotIncreasing { index: 1, .. }
        ));
        assert!(matches!(
            err(vec![pose(1.0, 0.0, 0.0), pose(1.1, f64::NAN, 0.0)]),
            InterpolationError::NotFinite { index: 1, .. }
        ));
    }
}
