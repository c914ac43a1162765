//! The absolute stage's edge map (paper eq. 41-59).
//!
//! Follow the data: a frame's landmark observations become edge
//! measurements for the pairs an [`policy::EdgePolicy`] picks ([`edge`],
//! eq. 41-43, fused in information form); the fused edges form a
//! [`problem::MapProblem`]; [`laplacian`] assembles `A L = B` (eq. 47-57)
//! as a sparse block Laplacian with the reference landmark removed;
//! [`solve`] solves it (faer sparse Cholesky, or warm-started PCG for very
//! large maps); [`covariance`] recovers landmark covariances (eq. 59).
//! [`edges_file`] reads and writes the stand-alone problem format of
//! `rigslam map solve`, and [`simulate`] generates problems from simulated
//! observations.
//!
//! The absolute stage itself, [`absolute::AbsoluteStage`], runs all of it
//! per frame of the relative stage: edges fused, the map solved every few
//! frames off the frame-rate path ([`map_worker`]), and the robot position
//! corrected by the Kalman filter of eq. 60-71 ([`position_filter`]);
//! [`simulate_relative`] simulates its input and [`nees`] checks the
//! filter's consistency.

pub mod absolute;
pub mod covariance;
pub mod edge;
pub mod edges_file;
mod inverse_blocks;
pub mod laplacian;
pub mod localise;
pub mod loop_run;
pub mod map_file;
pub mod map_worker;
pub mod nees;
pub mod ordering_reuse;
pub mod policy;
pub mod position_filter;
pub mod problem;
pub mod recognition;
pub mod settings;
pub mod simulate;
pub mod simulate_relative;
pub mod solve;
#[cfg(test)]
mod tests;

use std::path::PathBuf;

pub use absolute::{
    AbsoluteConfig, AbsoluteStage, AbsoluteStats, CorrectedPose, EdgeWeighting, LandmarkCovariance,
    MapReference, SolveMode,
};
pub use edge::{EdgeMap, FusedEdge, LandmarkObservation};
pub use laplacian::BlockLaplacian;
pub use policy::EdgePolicy;
pub use position_filter::PositionFilter;
pub use problem::{MapEdge, MapProblem};
pub use solve::{EdgeMapSolver, SolveReport, SolverChoice};

/// What can go wrong reading or solving an edge map.
#[derive(Debug, thiserror::Error)]
pub enum EdgeMapError {
    #[error("{path}: {source}")]
    /// An edges file could not be read or written.
    Io {
        /// The file.
        path: PathBuf,
        /// The I/O error.
        source: std::io::Error,
    },
    /// A line of an edges file that cannot be used.
    #[error("{path}:{line}: {message}")]
    Line {
        /// The file.
        path: PathBuf,
        /// 1-based line number.
        line: usize,
        /// What is wrong with it.
        message: String,
    },
    #[error(
        "the edge graph is not connected: {} cannot be placed relative to reference landmark {reference}",
        describe_components(unplaced)
    )]
    /// Some landmarks have no chain of edges to the reference, so the map cannot place them.
    Disconnected {
        /// Id of the reference landmark (fixed at the origin).
        reference: u32,
        /// Landmark ids of each component that does not hold the reference.
        unplaced: Vec<Vec<u32>>,
    },
    #[error("A is not positive definite (an edge information matrix is indefinite, or the graph is degenerate)")]
    /// The system matrix A is not positive definite (an edge information matrix is indefinite, or
    /// the graph is degenerate).
    NotPositiveDefinite,
    #[error("solver: {0}")]
    /// The sparse solver failed (its message).
    Solver(String),
}

fn describe_components(components: &[Vec<u32>]) -> String {
    let shown: Vec<String> = components
        .iter()
        .take(5)
        .map(|c| {
            let ids: Vec<String> = c.iter().take(6).map(u32::to_string).collect();
            let more = if c.len() > 6 { ", ..." } else { "" };
            format!("{{{}{more}}} ({} landmarks)", ids.join(", "), c.len())
        })
        .collect();
    let more = if components.len() > 5 {
        format!(" and {} more components", components.len() - 5)
    } else {
        String::new()
    };
    format!(
        "{} component(s) {}{more}",
        components.len(),
        shown.join(", ")
    )
}
