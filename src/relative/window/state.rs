//! Keyframes as the window keeps them, and the error state the
//! Levenberg-Marquardt steps live in.
//!
//! Per keyframe the step is `[dphi, dp, dv, d b_g, d b_a]` (15 numbers; the
//! first 6 alone when the IMU is off): `R <- R Exp(dphi)` (right
//! perturbation, as in [`crate::imu::residual`]), `p <- p + dp` and
//! `v <- v + dv` in the world frame, biases additive.

use std::collections::VecDeque;

use nalgebra::{Matrix6, SMatrix, UnitQuaternion, Vector2, Vector3, Vector6};

use super::inertial_link::InertialLink;
use crate::imu::NavState;
use crate::relative::types::{KeyframeState, LandmarkId};

/// Offsets inside one keyframe's block of the step.
pub const ROT: usize = 0;
/// Offset of the position error `dp`, world frame, m.
pub const POS: usize = 3;
/// Offset of the velocity error `dv`, world frame, m/s.
pub const VEL: usize = 6;
/// Offset of the gyro bias error, rad/s.
pub const BG: usize = 9;
/// Offset of the accel bias error, m/s^2.
pub const BA: usize = 12;
/// Block sizes: pose only (vision) or the full navigation state.
pub const POSE_DIM: usize = 6;
/// Size of the full navigation block: rotation, position, velocity, gyro and accel biases (3 each).
pub const FULL_DIM: usize = 15;

/// One observation as a keyframe keeps it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct KeyframeObservation {
    pub landmark: LandmarkId,
    pub camera: u8,
    pub pixel: Vector2<f64>,
    /// Set once the observation failed the chi-square test after an
    /// optimisation; it is left out of every later one.
    pub outlier: bool,
}

/// A keyframe in the window.
#[derive(Debug, Clone)]
pub(crate) struct Keyframe {
    /// Unique, increasing keyframe number.
    pub seq: u64,
    pub state: KeyframeState,
    pub observations: Vec<KeyframeObservation>,
    /// The preintegrated IMU from the previous keyframe to this one.
    pub imu: Option<InertialLink>,
    /// `1 / sigma` of the bias random walk from the previous keyframe.
    /// As declared: [`super::NoiseScale::walk`] scales it where it is used.
    pub bias_walk_sqrt_info: Option<Vector6<f64>>,
    /// Marginal covariance of `[dphi, dp, dv, d b_g, d b_a]` after the
    /// last optimisation in which this keyframe was free (source of the
    /// eq. 34 prior once it is the boundary).
    pub state_marginal: Option<SMatrix<f64, 15, 15>>,
    /// Marginal covariance of `[dphi, dp]` given the fixed keyframes,
    /// from the last optimisation in which this keyframe was free.
    pub pose_marginal: Option<Matrix6<f64>>,
    /// Covariance of `[dphi, dp]` relative to the window's origin
    /// ([`super::pose_covariance`]); zero for the origin.
    pub pose_covariance: Option<Matrix6<f64>>,
    /// Angular rate of the body at the keyframe (gyroscope less bias),
    /// for the time offset ([`super::camera_imu`]).
    pub omega_body_rad_s: Vector3<f64>,
}

/// True when an inertial link reaches keyframe `i` (from the one before
/// or to the one after). A stereo start in flight keeps the keyframes
/// the window had on the images alone unlinked until they leave.
pub(crate) fn inertially_linked(keyframes: &VecDeque<Keyframe>, i: usize) -> bool {
    keyframes[i].imu.is_some() || keyframes.get(i + 1).is_some_and(|k| k.imu.is_some())
}

pub(crate) fn nav_state(s: &KeyframeState) -> NavState {
    NavState {
        t_ns: s.t_ns,
        R_world_body: s.T_world_body.rotation,
        position_world_m: s.T_world_body.translation.vector,
        velocity_world_m_s: s.velocity_world_m_s,
    }
}

/// Applies one keyframe's step (`delta.len()` is 6 or 15).
pub(crate) fn apply_update(state: &mut KeyframeState, delta: &[f64]) {
    let v3 = |o: usize| Vector3::new(delta[o], delta[o + 1], delta[o + 2]);
    let q = state.T_world_body.rotation * UnitQuaternion::from_scaled_axis(v3(ROT));
    state.T_world_body.rotation = UnitQuaternion::new_normalize(q.into_inner());
    state.T_world_body.translation.vector += v3(POS);
    if delta.len() >= FULL_DIM {
        state.velocity_world_m_s += v3(VEL);
        state.biases.gyro_rad_s += v3(BG);
        state.biases.accel_m_s2 += v3(BA);
    }
}

pub(crate) fn state_is_finite(s: &KeyframeState) -> bool {
    s.T_world_body.rotation.coords.iter().all(|v| v.is_finite())
        && s.T_world_body
            .translation
            .vector
            .iter()
            .all(|v| v.is_finite())
        && s.velocity_world_m_s.iter().all(|v| v.is_finite())
        && s.biases.gyro_rad_s.iter().all(|v| v.is_finite())
        && s.biases.accel_m_s2.iter().all(|v| v.is_finite())
}
