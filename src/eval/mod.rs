//! Trajectory evaluation: association, alignment, ATE, RPE, drift.
//!
//! An estimate is scored in this order: [`associate`](mod@associate) pairs its poses with
//! ground-truth poses by time; [`align`] fits the requested transformation;
//! [`metrics`] computes the errors; [`report`] gathers them into the numbers
//! `rigslam eval` prints (`crate::plot::evaluation` draws them). [`consistency`] checks a
//! published covariance against the errors (NEES), [`map_consistency`] the
//! map-frame position covariance of the second stage; [`tilt`] scores roll and
//! pitch against gravity, which an alignment would hide.

pub mod align;
pub mod associate;
pub mod consistency;
pub mod error;
pub mod map_consistency;
pub mod metrics;
pub mod report;
pub mod tilt;

pub use align::{Alignment, Sim3};
pub use associate::{associate, MatchedPoses};
pub use error::EvalError;
pub use report::{evaluate, EvalOptions, EvalReport};
