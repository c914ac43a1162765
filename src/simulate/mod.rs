//! Synthetic sequences: scene, renderer, motion, IMU synthesis, EuRoC output.
//!
//! The data's way: [`motion`] gives the body's pose and derivatives at any
//! instant; [`scene`] (with [`texture`]) is the world; [`render`] turns a
//! camera pose into an image through the real camera model; [`imu_synth`]
//! turns the motion into IMU samples; [`sequence`] puts them together and
//! writes a EuRoC ASL dataset ([`simulate`]).

pub mod imu_synth;
pub mod interpolated;
pub mod motion;
pub mod motion_state;
mod progress;
pub mod render;
pub mod scene;
pub mod sequence;
pub mod texture;

pub use sequence::{simulate, ImuSource, SimConfig, SimError, SimReport, SplineConfig};
