//! Poses in a level world. The window estimates gravity's direction in
//! its own world, which its first keyframe fixes. That world is levelled
//! by the first guess of gravity: at rest, the accelerometer's mean with
//! the biases still unknown, so it is tilted by as much as the biases
//! lean it (about 0.6 deg per 0.1 m/s^2). As the rig turns the biases
//! separate from the tilt and gravity's direction in that world moves
//! away from -z (about a degree on a rendered EuRoC flight with an ideal
//! IMU), while the attitudes stay in the first guess's world.
//!
//! The outputs are turned so that the estimated gravity points along -z,
//! as an odometry frame should (REP-105: z up). The target is the
//! smallest rotation taking the estimate onto -z (no yaw); the turn
//! follows it through a first-order filter of time constant `tau`
//! (`level_time_constant_s`), because the estimate jitters by tenths of a
//! degree from solve to solve with a real IMU and following each step
//! bends the path (measured: following at once cost 30 % of ATE on the
//! development set, and 20 s cost nothing; see bench/accuracy). Each
//! time the turn changes it is changed about the current position:
//! positions do not jump, and the motion after it is level. Velocity, the translation since the
//! last output and the covariance (with its origin) turn with the pose;
//! body-frame landmarks and biases do not change. The absolute stage's
//! map turns more slowly ([`LevelFollower`] with its own time constant,
//! `crate::slam_pipeline` and its `map_world`).

use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};

use super::estimator::{FrameInput, FrameTimings, RelativeEstimator};
use super::types::RelativeOutput;
use crate::sensors::ImuSample;

/// `estimator` with its outputs levelled by its gravity estimate,
/// followed with the time constant `tau_s` (0: at once).
pub fn levelled(estimator: Box<dyn RelativeEstimator>, tau_s: f64) -> Box<dyn RelativeEstimator> {
    Box::new(Levelled {
        inner: estimator,
        level: LevelFollower::new(tau_s),
    })
}

struct Levelled {
    inner: Box<dyn RelativeEstimator>,
    level: LevelFollower,
}

/// A turn of a world that does not turn into a level one, following a
/// gravity estimate given in the first through a first-order filter of
/// time constant `tau_s` (0: at once; infinite: never turns), each change
/// made about the body's position so that positions do not jump.
#[derive(Clone, Copy, Debug)]
pub struct LevelFollower {
    tau_s: f64,
    /// Maps the world that does not turn into the level one.
    level: Isometry3<f64>,
    /// The last stamp the level was updated at.
    last_ns: Option<i64>,
}

impl LevelFollower {
    /// The identity, following gravity with the time constant `tau_s`.
    pub fn new(tau_s: f64) -> Self {
        Self {
            tau_s,
            level: Isometry3::identity(),
            last_ns: None,
        }
    }

    /// The turn now.
    pub fn level(&self) -> Isometry3<f64> {
        self.level
    }

    /// Follows `gravity` (m/s^2, in the world that does not turn) at
    /// `t_ns`, with the body at `position_m` (same world); a gravity that
    /// gives no direction is ignored.
    pub fn follow(&mut self, gravity: &Vector3<f64>, t_ns: i64, position_m: &Vector3<f64>) {
        let Some(target) = turn_to_down(gravity) else {
            return;
        };
        let dt_s = self
            .last_ns
            .map_or(0.0, |t| (t_ns - t).max(0) as f64 * 1e-9);
        self.last_ns = Some(t_ns);
        let share = if self.tau_s > 0.0 {
            1.0 - (-dt_s / self.tau_s).exp()
        } else {
            1.0
        };
        let turn = self.level.rotation.slerp(&target, share);
        if turn.angle_to(&self.level.rotation) > 0.0 {
            let p_level = self.level.transform_point(&(*position_m).into()).coords;
            self.level =
                Isometry3::from_parts(Translation3::from(p_level - turn * position_m), turn);
        }
    }
}

/// The smallest rotation taking `gravity` onto -z; None for a zero or
/// non-finite vector (or one pointing up, which no estimate does).
fn turn_to_down(gravity: &Vector3<f64>) -> Option<UnitQuaternion<f64>> {
    if !gravity.iter().all(|v| v.is_finite()) || gravity.norm() == 0.0 {
        return None;
    }
    UnitQuaternion::rotation_between(gravity, &-Vector3::z())
}

impl Levelled {
    fn level(&mut self, mut out: RelativeOutput) -> RelativeOutput {
        if out.state == super::types::TrackingState::Tracking {
            if let Some(g) = self.inner.gravity_world_m_s2() {
                self.level
                    .follow(&g, out.t_ns, &out.T_world_body.translation.vector);
            }
        }
        out.move_to_world(&self.level.level());
        out
    }
}

impl RelativeEstimator for Levelled {
    fn push_imu(&mut self, sample: &ImuSample) {
        self.inner.push_imu(sample);
    }

    fn push_frame(&mut self, frame: &FrameInput<'_>) -> RelativeOutput {
        let out = self.inner.push_frame(frame);
        self.level(out)
    }

    fn finish_frame(&mut self) -> Option<RelativeOutput> {
        let out = self.inner.finish_frame()?;
        Some(self.level(out))
    }

    fn work_pending(&self) -> bool {
        self.inner.work_pending()
    }

    fn last_timings(&self) -> &FrameTimings {
        self.inner.last_timings()
    }

    fn counters(&self) -> Vec<(&'static str, u64)> {
        self.inner.counters()
    }

    fn imu_noise_scale(&self) -> Option<crate::relative::window::NoiseScale> {
        self.inner.imu_noise_scale()
    }

    fn noise_at_bound(&self) -> bool {
        self.inner.noise_at_bound()
    }

    fn camera_imu(&self) -> Option<crate::relative::window::CameraImuEstimate> {
        self.inner.camera_imu()
    }

    fn settling(&self) -> bool {
        self.inner.settling()
    }

    fn levelling(&self) -> Isometry3<f64> {
        self.level.level()
    }

    fn accel_bias_sigma_m_s2(&self) -> Option<f64> {
        self.inner.accel_bias_sigma_m_s2()
    }

    fn gravity_world_m_s2(&self) -> Option<Vector3<f64>> {
        self.inner
            .gravity_world_m_s2()
            .map(|g| self.level.level().rotation * g)
    }
}

#[cfg(test)]
mod tests {
    use std::collections::VecDeque;
    use std::sync::Arc;

    use nalgebra::Unit;

    use super::*;
    use crate::eval::consistency::{relative_pose_error, CovariancePose};
    use crate::relative::types::{PoseCovariance, TrackingState};
    use crate::sensors::Image;
    use crate::trajectory::{StampedPose, Trajectory};

    /// Gives scripted outputs and gravity estimates.
    struct Scripted {
        outputs: VecDeque<(RelativeOutput, Option<Vector3<f64>>)>,
        gravity: Option<Vector3<f64>>,
        timings: FrameTimings,
    }

    impl RelativeEstimator for Scripted {
        fn push_imu(&mut self, _: &ImuSample) {}

        fn push_frame(&mut self, frame: &FrameInput<'_>) -> RelativeOutput {
            let (out, g) = self.outputs.pop_front().expect("a scripted output");
            self.gravity = g;
            RelativeOutput {
                t_ns: frame.t_ns,
                ..out
            }
        }

        fn last_timings(&self) -> &FrameTimings {
            &self.timings
        }

        fn counters(&self) -> Vec<(&'static str, u64)> {
            Vec::new()
        }

        fn gravity_world_m_s2(&self) -> Option<Vector3<f64>> {
            self.gravity
        }
    }

    fn output(
        p: Vector3<f64>,
        rotation: UnitQuaternion<f64>,
        state: TrackingState,
    ) -> RelativeOutput {
        RelativeOutput {
            T_world_body: Isometry3::from_parts(Translation3::from(p), rotation),
            velocity_world_m_s: Vector3::new(1.0, 0.0, 0.0),
            delta_translation_world_m: Vector3::new(0.05, 0.0, 0.0),
            state,
            ..RelativeOutput::tracking_at_origin(0, Vec::new())
        }
    }

    /// Gravity tilted by `deg` about `axis` from straight down.
    fn tilted(axis: Vector3<f64>, deg: f64) -> Vector3<f64> {
        UnitQuaternion::from_axis_angle(&Unit::new_normalize(axis), deg.to_radians())
            * Vector3::new(0.0, 0.0, -9.81)
    }

    /// The levelled outputs of `script`, one frame every 50 ms.
    fn run_with(
        script: Vec<(RelativeOutput, Option<Vector3<f64>>)>,
        tau_s: f64,
    ) -> Vec<RelativeOutput> {
        let n = script.len();
        let mut e = levelled(
            Box::new(Scripted {
                outputs: script.into(),
                gravity: None,
                timings: FrameTimings::default(),
            }),
            tau_s,
        );
        let image = Image::new(
            2,
            2,
            2,
            crate::sensors::PixelFormat::Mono8,
            Arc::from(vec![0u8; 4]),
        )
        .expect("image");
        (0..n)
            .map(|i| {
                e.push_frame(&FrameInput {
                    t_ns: i as i64 * 50_000_000,
                    left: &image,
                    right: None,
                })
            })
            .collect()
    }

    /// Following the estimate at once.
    fn run(script: Vec<(RelativeOutput, Option<Vector3<f64>>)>) -> Vec<RelativeOutput> {
        run_with(script, 0.0)
    }

    #[test]
    fn the_level_follows_a_moved_estimate_with_its_time_constant() {
        // The estimate moves 1 deg and stays: after one time constant the
        // turn has covered 1 - 1/e of it, after five nearly all; the first
        // frame (no time elapsed) is not turned.
        let g = tilted(Vector3::x(), 1.0);
        let p = Vector3::zeros();
        let q = UnitQuaternion::identity();
        let tau_s = 2.0;
        let frames = 1 + (5.0 * tau_s / 0.05) as usize;
        let out = run_with(
            vec![(output(p, q, TrackingState::Tracking), Some(g)); frames],
            tau_s,
        );
        let turned = |i: usize| out[i].T_world_body.rotation.angle().to_degrees();
        assert!(turned(0) < 1e-12);
        let one_tau = (tau_s / 0.05) as usize;
        assert!(
            (turned(one_tau) - (1.0 - (-1f64).exp())).abs() < 1e-6,
            "{}",
            turned(one_tau)
        );
        assert!(
            (turned(frames - 1) - (1.0 - (-5f64).exp())).abs() < 1e-6,
            "{}",
            turned(frames - 1)
        );
        // Always about the same axis: no heading is added.
        let axis = out[frames - 1]
            .T_world_body
            .rotation
            .axis()
            .expect("turned");
        assert!(axis.z.abs() < 1e-9, "{axis:?}");
    }

    #[test]
    fn the_estimated_gravity_points_down_in_the_outputs() {
        let g = tilted(Vector3::new(1.0, 1.0, 0.0), 1.2);
        let q = UnitQuaternion::from_euler_angles(0.3, -0.2, 1.0);
        let out = run(vec![(
            output(Vector3::new(2.0, -1.0, 0.5), q, TrackingState::Tracking),
            Some(g),
        )]);
        // The body sees gravity where the estimator says; in the output's
        // world that direction is straight down.
        let g_body = q.inverse() * g;
        let down = out[0].T_world_body.rotation * g_body;
        assert!(
            (down - Vector3::new(0.0, 0.0, -9.81)).norm() < 1e-9,
            "{down}"
        );
        // The turn has no yaw: it is about the horizontal axis of the tilt,
        // which stays where it was, and the horizontal direction across
        // it only leans (its heading is kept).
        let turned = |v: Vector3<f64>| out[0].T_world_body.rotation * (q.inverse() * v);
        let along = turned(Vector3::new(1.0, 1.0, 0.0));
        assert!(
            (along - Vector3::new(1.0, 1.0, 0.0)).norm() < 1e-9,
            "{along}"
        );
        let across = turned(Vector3::new(1.0, -1.0, 0.0));
        assert!(across.z.abs() > 1e-3, "{across}");
        let heading = Vector3::new(across.x, across.y, 0.0);
        assert!(
            heading.cross(&Vector3::new(1.0, -1.0, 0.0)).norm() < 1e-9,
            "{across}"
        );
        // The position is where it was: the first turn is about it.
        assert!(
            (out[0].T_world_body.translation.vector - Vector3::new(2.0, -1.0, 0.5)).norm() < 1e-12
        );
    }

    #[test]
    fn positions_do_not_jump_when_the_estimate_moves_and_later_motion_is_level() {
        let p = Vector3::new(5.0, 3.0, 1.0);
        let q = UnitQuaternion::identity();
        let g1 = tilted(Vector3::x(), 0.5);
        let g2 = tilted(Vector3::new(0.3, 1.0, 0.0), 1.5);
        let step = Vector3::new(1.0, 0.0, 0.0);
        let out = run(vec![
            (output(p, q, TrackingState::Tracking), Some(g1)),
            (output(p, q, TrackingState::Tracking), Some(g2)),
            (output(p + step, q, TrackingState::Tracking), Some(g2)),
        ]);
        let at = |i: usize| out[i].T_world_body.translation.vector;
        assert!((at(0) - at(1)).norm() < 1e-12, "{} -> {}", at(0), at(1));
        // The step after the change is turned by the new level.
        let turn = turn_to_down(&g2).expect("a turn");
        assert!(((at(2) - at(1)) - turn * step).norm() < 1e-12);
        assert!((out[2].velocity_world_m_s - turn * Vector3::new(1.0, 0.0, 0.0)).norm() < 1e-12);
        assert!(
            (out[2].delta_translation_world_m - turn * Vector3::new(0.05, 0.0, 0.0)).norm() < 1e-12
        );
        // The attitude takes the new level at once.
        assert!(out[1].T_world_body.rotation.angle_to(&turn) < 1e-12);
    }

    #[test]
    fn frames_without_a_pose_or_without_an_estimate_keep_the_last_level() {
        let p = Vector3::new(1.0, 0.0, 0.0);
        let q = UnitQuaternion::identity();
        let g = tilted(Vector3::y(), 0.8);
        let out = run(vec![
            (output(p, q, TrackingState::Tracking), Some(g)),
            (
                output(p, q, TrackingState::Lost),
                Some(tilted(Vector3::x(), 3.0)),
            ),
            (output(p, q, TrackingState::Tracking), None),
        ]);
        let turn = turn_to_down(&g).expect("a turn");
        for o in &out {
            assert!(o.T_world_body.rotation.angle_to(&turn) < 1e-12);
        }
        // Without any gravity estimate (vision-only modes) the outputs
        // pass unchanged, to the bit.
        let plain = output(Vector3::new(1.0, 2.0, 3.0), q, TrackingState::Tracking);
        assert_eq!(
            run(vec![(plain.clone(), None)])[0],
            RelativeOutput { t_ns: 0, ..plain }
        );
    }

    #[test]
    fn the_covariance_turns_with_the_pose() {
        // A pose and its origin, a covariance, and a ground truth the
        // error is measured against: turning the world changes neither
        // the error's size nor its size relative to the covariance.
        let origin = Isometry3::from_parts(
            Translation3::new(0.5, 0.2, 0.0),
            UnitQuaternion::from_euler_angles(0.01, 0.02, 0.3),
        );
        let q = UnitQuaternion::from_euler_angles(-0.02, 0.01, 0.9);
        let p = Vector3::new(3.0, 1.0, 0.2);
        let mut a = nalgebra::Matrix6::<f64>::identity() * 1e-4;
        a[(0, 4)] = 5e-5;
        a[(4, 0)] = 5e-5;
        let mut out = output(p, q, TrackingState::Tracking);
        out.pose_covariance = Some(PoseCovariance {
            matrix: a,
            origin_t_ns: 0,
            T_world_origin: origin,
        });
        let g = tilted(Vector3::new(1.0, 0.4, 0.0), 2.0);
        let raw = out.clone();
        let turned = &run(vec![(out, Some(g))])[0];
        let truth = Trajectory::new(vec![
            StampedPose {
                t_ns: 0,
                T_world_body: origin * Isometry3::translation(0.01, 0.0, 0.0),
            },
            StampedPose {
                t_ns: 1_000_000_000,
                T_world_body: raw.T_world_body * Isometry3::translation(0.0, 0.02, -0.01),
            },
        ]);
        let nees = |o: &RelativeOutput| {
            let c = o.pose_covariance.expect("covariance");
            let pose = CovariancePose {
                t_ns: 1_000_000_000,
                T_world_body: o.T_world_body,
                covariance: c,
            };
            let e = relative_pose_error(&pose, &truth).expect("covered");
            (
                e.norm(),
                e.dot(&c.matrix.cholesky().expect("spd").solve(&e)),
            )
        };
        let (size_raw, nees_raw) = nees(&raw);
        let (size_turned, nees_turned) = nees(turned);
        assert!(size_raw > 0.01);
        assert!(
            (size_raw - size_turned).abs() < 1e-12,
            "{size_raw} {size_turned}"
        );
        assert!(
            (nees_raw - nees_turned).abs() < 1e-6 * nees_raw,
            "{nees_raw} {nees_turned}"
        );
    }
}
