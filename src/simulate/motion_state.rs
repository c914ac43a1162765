//! The body's kinematic state at one instant: what every motion source
//! ([`super::motion`], [`super::interpolated`]) gives the renderer and the
//! IMU synthesiser.

use nalgebra::{Isometry3, Vector3};

/// The body's kinematic state at one instant.
#[allow(non_snake_case)]
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MotionState {
    /// Body pose: maps body coordinates into the world frame.
    pub T_world_body: Isometry3<f64>,
    /// Body velocity in the world frame, m/s.
    pub velocity_world_m_s: Vector3<f64>,
    /// Body acceleration in the world frame (gravity not included), m/s^2.
    pub accel_world_m_s2: Vector3<f64>,
    /// Angular rate expressed in the body frame (what a gyroscope measures).
    pub omega_body_rad_s: Vector3<f64>,
}
