//! Sensor I/O for rigslam.
//!
//! This crate is the lowest layer: it knows sensors, bytes and clocks, never
//! SLAM. The sample types every other crate consumes live here:
//! [`ImuSample`] and [`Frame`]/[`StereoFrame`], all stamped with i64
//! nanoseconds (host `CLOCK_MONOTONIC` live, dataset time on replay).

#![warn(missing_docs)]

pub mod camera;
pub mod clock_sync;
pub mod frame;
pub mod imu_sample;
pub mod yei;

pub use frame::{BayerPattern, Frame, FrameError, Image, PixelFormat, StereoFrame};
pub use imu_sample::ImuSample;

/// Nanoseconds per second, for converting `t_ns` stamps.
pub const NS_PER_S: i64 = 1_000_000_000;
