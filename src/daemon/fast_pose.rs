//! The `rigslam/pose_fast` stream: the last frame's state carried forward
//! with every IMU sample by strapdown integration ([`crate::imu::strapdown`]),
//! with the biases the relative stage estimated for that frame.
//!
//! When a frame's answer arrives, the samples already received after the
//! frame are integrated again from the new state (silently: they were
//! published from the older one). Without frames the IMU alone carries the
//! pose for at most `imu_only_max_s`; after that the stream says "lost"
//! and holds the pose, until a frame brings tracking back.
//!
//! With the absolute stage the samples are propagated from the frame's
//! map-frame pose (what `rigslam/pose` carries), so that the two streams
//! agree, and each message also carries the pose in the odometry frame
//! through that frame's `T_world_odom`.

use std::collections::VecDeque;

use nalgebra::{Isometry3, Vector3};

use crate::imu::{strapdown, ImuBiases, NavState};
use crate::publish::PoseMessage;
use crate::relative::{RelativeOutput, TrackingState};
use crate::sensors::ImuSample;

/// Samples kept for integrating again after a frame's answer (2.5 s at
/// 200 Hz: more than a frame's processing ever lags behind the IMU).
const KEPT_SAMPLES: usize = 512;

/// Carries the last frame state forward with the IMU.
pub struct FastPropagator {
    imu_only_max_ns: i64,
    anchor: Option<Anchor>,
    /// State at `recent.back()`, when propagating.
    current: Option<NavState>,
    recent: VecDeque<ImuSample>,
}

#[derive(Debug, Clone, Copy)]
struct Anchor {
    t_ns: i64,
    state: TrackingState,
    nav: NavState,
    biases: ImuBiases,
    /// The frame's `T_world_odom` when the absolute stage runs.
    world_odom: Option<Isometry3<f64>>,
}

impl FastPropagator {
    /// A propagator with no frame state yet; the IMU alone carries the pose for at most
    /// `imu_only_max_s` seconds after the last frame (negative counts as 0).
    pub fn new(imu_only_max_s: f64) -> Self {
        Self {
            imu_only_max_ns: (imu_only_max_s.max(0.0) * 1e9) as i64,
            anchor: None,
            current: None,
            recent: VecDeque::with_capacity(KEPT_SAMPLES),
        }
    }

    /// A new frame answer: the anchor for the samples that follow.
    pub fn on_frame(&mut self, output: &RelativeOutput) {
        self.on_frame_in_map(output, None);
    }

    /// [`Self::on_frame`] with the absolute stage's answer for the frame:
    /// its map-frame pose and `T_world_odom` (None without one).
    #[allow(non_snake_case)]
    pub fn on_frame_in_map(
        &mut self,
        output: &RelativeOutput,
        map: Option<(Isometry3<f64>, Isometry3<f64>)>,
    ) {
        let (pose, velocity) = match &map {
            Some((T_world_body, T_world_odom)) => (
                *T_world_body,
                T_world_odom.rotation * output.velocity_world_m_s,
            ),
            None => (output.T_world_body, output.velocity_world_m_s),
        };
        let nav = NavState {
            t_ns: output.t_ns,
            R_world_body: pose.rotation,
            position_world_m: pose.translation.vector,
            velocity_world_m_s: velocity,
        };
        self.anchor = Some(Anchor {
            t_ns: output.t_ns,
            state: output.state,
            nav,
            biases: output.biases,
            world_odom: map.map(|(_, T_world_odom)| T_world_odom),
        });
        self.current = None;
        if output.state != TrackingState::Tracking || !finite(&nav) {
            return;
        }
        // Start at the frame stamp with the sample interpolated there,
        // then step through the samples already received after it.
        let after = self.recent.partition_point(|s| s.t_ns <= output.t_ns);
        let Some(first_after) = self.recent.get(after).copied() else {
            self.current = Some(nav);
            return;
        };
        let at_frame = match after.checked_sub(1).and_then(|i| self.recent.get(i)) {
            Some(before) => interpolate(before, &first_after, output.t_ns),
            None => ImuSample {
                t_ns: output.t_ns,
                ..first_after
            },
        };
        let mut state = nav;
        let mut previous = at_frame;
        for s in self.recent.range(after..) {
            state = strapdown::step(&state, &previous, s, &output.biases);
            previous = *s;
        }
        self.current = Some(state);
    }

    /// One IMU sample (in time order): the `pose_fast` message for it.
    pub fn on_imu(&mut self, sample: &ImuSample) -> PoseMessage {
        let message = self.propagate(sample);
        match self.anchor.and_then(|a| a.world_odom) {
            Some(world_odom) => message.with_world_odom(&world_odom),
            None => message,
        }
    }

    fn propagate(&mut self, sample: &ImuSample) -> PoseMessage {
        let previous = self.recent.back().copied();
        if self.recent.len() == KEPT_SAMPLES {
            self.recent.pop_front();
        }
        self.recent.push_back(*sample);
        let Some(anchor) = self.anchor else {
            return PoseMessage::from_nav_state(
                &rest_state(sample.t_ns),
                TrackingState::Initializing,
            );
        };
        if anchor.state != TrackingState::Tracking {
            return PoseMessage::from_nav_state(
                &NavState {
                    t_ns: sample.t_ns,
                    ..anchor.nav
                },
                anchor.state,
            );
        }
        let next = match (self.current, previous) {
            // The first sample after the frame: from the frame stamp.
            (Some(state), _) if state.t_ns == anchor.t_ns && sample.t_ns > anchor.t_ns => {
                let at_frame = match previous {
                    Some(p) if p.t_ns <= anchor.t_ns => interpolate(&p, sample, anchor.t_ns),
                    _ => ImuSample {
                        t_ns: anchor.t_ns,
                        ..*sample
                    },
                };
                Some(strapdown::step(&state, &at_frame, sample, &anchor.biases))
            }
            (Some(state), Some(p)) if sample.t_ns > state.t_ns && p.t_ns == state.t_ns => {
                Some(strapdown::step(&state, &p, sample, &anchor.biases))
            }
            (current, _) => current,
        };
        let within = sample.t_ns - anchor.t_ns <= self.imu_only_max_ns;
        match next {
            Some(state) if within && finite(&state) => {
                self.current = Some(state);
                PoseMessage::from_nav_state(&state, TrackingState::Tracking)
            }
            held => {
                // Past the IMU-only bound (or a sample out of order): lost,
                // the last pose held, no further integration.
                let hold = held.or(self.current).unwrap_or(anchor.nav);
                self.current = None;
                self.anchor = Some(Anchor {
                    state: TrackingState::Lost,
                    nav: hold,
                    ..anchor
                });
                PoseMessage::from_nav_state(
                    &NavState {
                        t_ns: sample.t_ns,
                        ..hold
                    },
                    TrackingState::Lost,
                )
            }
        }
    }
}

fn rest_state(t_ns: i64) -> NavState {
    NavState {
        t_ns,
        R_world_body: nalgebra::UnitQuaternion::identity(),
        position_world_m: Vector3::zeros(),
        velocity_world_m_s: Vector3::zeros(),
    }
}

fn finite(s: &NavState) -> bool {
    s.position_world_m.iter().all(|v| v.is_finite())
        && s.velocity_world_m_s.iter().all(|v| v.is_finite())
        && s.R_world_body.coords.iter().all(|v| v.is_finite())
}

/// The sample at `t_ns` between `a` and `b`, linearly.
fn interpolate(a: &ImuSample, b: &ImuSample, t_ns: i64) -> ImuSample {
    let span = (b.t_ns - a.t_ns) as f64;
    let w = if span > 0.0 {
        ((t_ns - a.t_ns) as f64 / span).clamp(0.0, 1.0)
    } else {
        1.0
    };
    let mix = |x: [f64; 3], y: [f64; 3]| std::array::from_fn(|i| x[i] + (y[i] - x[i]) * w);
    ImuSample {
        t_ns,
        gyro_rad_s: mix(a.gyro_rad_s, b.gyro_rad_s),
        accel_m_s2: mix(a.accel_m_s2, b.accel_m_s2),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::imu::GRAVITY_M_S2;
    use crate::publish::{TRACKING_STATE_LOST, TRACKING_STATE_TRACKING};
    use nalgebra::{Isometry3, Translation3, UnitQuaternion};

    fn output(t_ns: i64, state: TrackingState, v: Vector3<f64>) -> RelativeOutput {
        RelativeOutput {
            t_ns,
            state,
            T_world_body: Isometry3::from_parts(
                Translation3::new(1.0, 2.0, 3.0),
                UnitQuaternion::identity(),
            ),
            velocity_world_m_s: v,
            biases: ImuBiases::default(),
            delta_translation_world_m: Vector3::zeros(),
            landmarks: vec![],
            pose_covariance: None,
        }
    }

    fn level(t_ns: i64) -> ImuSample {
        ImuSample {
            t_ns,
            gyro_rad_s: [0.0; 3],
            accel_m_s2: [0.0, 0.0, GRAVITY_M_S2],
        }
    }

    #[test]
    fn constant_velocity_is_carried_then_lost_after_the_bound() {
        let mut p = FastPropagator::new(0.5);
        let v = Vector3::new(1.0, 0.0, 0.0);
        // Frame at 2.5 ms, samples every 5 ms.
        p.on_imu(&level(0));
        p.on_frame(&output(2_500_000, TrackingState::Tracking, v));
        let mut last = None;
        for k in 1..=100 {
            let t = k * 5_000_000;
            let m = p.on_imu(&level(t));
            let dt = (t - 2_500_000) as f64 * 1e-9;
            if dt <= 0.5 {
                assert_eq!(m.tracking_state, TRACKING_STATE_TRACKING, "at {dt} s");
                assert!((m.position_world_m[0] - (1.0 + dt)).abs() < 1e-9, "{m:?}");
            } else {
                assert_eq!(m.tracking_state, TRACKING_STATE_LOST, "at {dt} s");
                // Held, not integrated further.
                if let Some(held) = last {
                    assert_eq!(m.position_world_m, held);
                }
                last = Some(m.position_world_m);
            }
        }
        // A tracking frame brings the stream back.
        p.on_frame(&output(500_000_000, TrackingState::Tracking, v));
        let m = p.on_imu(&level(505_000_000));
        assert_eq!(m.tracking_state, TRACKING_STATE_TRACKING);
    }

    #[test]
    fn samples_received_before_the_answer_are_integrated_again() {
        let v = Vector3::new(0.0, 2.0, 0.0);
        let mut late = FastPropagator::new(1.0);
        late.on_imu(&level(0));
        late.on_imu(&level(5_000_000));
        late.on_imu(&level(10_000_000));
        // The answer for a frame at 2 ms comes after two later samples.
        late.on_frame(&output(2_000_000, TrackingState::Tracking, v));
        let a = late.on_imu(&level(15_000_000));
        let mut early = FastPropagator::new(1.0);
        early.on_imu(&level(0));
        early.on_frame(&output(2_000_000, TrackingState::Tracking, v));
        early.on_imu(&level(5_000_000));
        early.on_imu(&level(10_000_000));
        let b = early.on_imu(&level(15_000_000));
        assert_eq!(a.position_world_m, b.position_world_m);
        assert!((a.position_world_m[1] - (2.0 + 2.0 * 0.013)).abs() < 1e-9);
    }
}
