//! The body's kinematic state at one instant: what every motion source
//! ([`super::motion`], [`super::interpolated`]) gives the renderer and the
//! IMU synthesiser.

use nalgebra::{Isometry3, Vector3};

/// The body's kinematic state at one instant.
#[allow(non_snake_case)]
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MotionState {
    pub T_world_body: Isometry3<f64>,
    pub velocity_world_m_s: Vector3<f64>,
    pub accel_world_m_s2: Vector3<f64>,
    /// Angular rate expressed in the body frame (what a gyroscope measures).
    pub omega_body_rad_s: Vector3<f64>,
}
