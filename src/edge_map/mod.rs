//! The edge map of the absolute stage (paper eq. 41-59): the linear maths,
//! free of threads, recognition and persistence.
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
//! The absolute stage that runs all of it per frame is [`crate::absolute`].

pub mod covariance;
pub mod edge;
pub mod edges_file;
mod inverse_blocks;
pub mod laplacian;
pub mod ordering_reuse;
pub mod policy;
pub mod problem;
pub mod simulate;
pub mod solve;
#[cfg(test)]
mod tests;

use std::path::PathBuf;

pub use edge::{EdgeMap, FusedEdge, LandmarkObservation};
pub use laplacian::BlockLaplacian;
pub use policy::EdgePolicy;
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
