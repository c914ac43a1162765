//! Stage 2, absolute motion: the relative stage's outputs in, a map of
//! landmarks and a corrected robot position out (paper eq. 41-71).
//!
//! Follow a frame: [`stage::AbsoluteStage`] takes each
//! [`crate::relative::RelativeOutput`] and hands it to its parts. The
//! `recogniser` gives new tracks that are landmarks mapped before their
//! old identity ([`recognition`]'s gates, confirmed over frames); the
//! `map_builder` adds the frame's edges to the [`crate::edge_map`] (the
//! linear maths) and keeps which track is which unknown
//! (`landmark_registry`) and where its frame nodes were taken
//! (`node_places`); the map is solved every few frames off the
//! frame-rate path ([`map_worker`], scheduled by mode in
//! [`solve_schedule`]); the relative stage's orientation is corrected by
//! an offset the map's landmarks measure ([`orientation_filter`]); and the
//! robot position is corrected with the Kalman filter of eq. 60-71
//! ([`position_filter`], checked by [`nees`]), whose cross-covariance
//! with the map's errors [`map_cross_covariance`] keeps between solves;
//! what the relative stage's attitude at mapping time puts in the map is
//! added to the published covariance by `mapping_attitude`.
//! What the stage is built with is [`config`], read from the settings
//! file's table by [`settings`]. A map outlives the run through
//! [`map_file`]; [`localise`] places a robot in a saved map.
//! [`simulate_relative`] simulates the stage's input and [`loop_run`]
//! measures it over laps of a room.

pub mod config;
mod landmark_registry;
pub mod localise;
pub mod loop_run;
mod map_builder;
pub mod map_cross_covariance;
pub mod map_file;
pub mod map_worker;
pub mod mapping_attitude;
pub mod nees;
mod node_places;
pub mod orientation_filter;
pub mod position_filter;
mod recogniser;
pub mod recognition;
pub mod settings;
pub mod simulate_relative;
pub mod solve_schedule;
pub mod stage;
mod window_share;

pub use position_filter::PositionFilter;
pub use stage::{
    AbsoluteConfig, AbsoluteStage, AbsoluteStats, CorrectedPose, EdgeWeighting, LandmarkCovariance,
    MapReference, SolveMode,
};
