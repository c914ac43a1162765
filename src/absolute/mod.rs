//! Stage 2, absolute motion: the relative stage's outputs in, a map of
//! landmarks and a corrected robot position out (paper eq. 41-71).
//!
//! Follow a frame: [`stage::AbsoluteStage`] takes each
//! [`crate::relative::RelativeOutput`], recognises landmarks it has mapped
//! before ([`recognition`]), adds the frame's edges to the
//! [`crate::edge_map`] (the linear maths), has the map solved every few
//! frames off the frame-rate path ([`map_worker`], scheduled by mode in
//! `solve_schedule`) and corrects the robot
//! position with the Kalman filter of eq. 60-71 ([`position_filter`],
//! checked by [`nees`]). Its settings file table is [`settings`]. A map
//! outlives the run through [`map_file`]; [`localise`] places a robot in a
//! saved map. [`simulate_relative`] simulates the stage's input and
//! [`loop_run`] measures it over laps of a room.

pub mod localise;
pub mod loop_run;
pub mod map_file;
pub mod map_worker;
pub mod nees;
pub mod position_filter;
pub mod recognition;
pub mod settings;
pub mod simulate_relative;
pub mod solve_schedule;
pub mod stage;

pub use position_filter::PositionFilter;
pub use stage::{
    AbsoluteConfig, AbsoluteStage, AbsoluteStats, CorrectedPose, EdgeWeighting, LandmarkCovariance,
    MapReference, SolveMode,
};
