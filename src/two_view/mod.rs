//! Two-view geometry: the paper's chain after tracking. A frame's
//! correspondences with the previous one go through [`ransac`] (MSAC over
//! the [`five_point`](mod@five_point) solver, then [`essential`] decomposition, cheirality
//! and refinement) to a [`RelativePose`]; [`triangulation`] turns the
//! inliers into points (optimal two-view correction, then linear
//! triangulation); [`p3p`](mod@p3p) and [`pnp`] place a frame against known points.
//!
//! Inputs are normalised image coordinates (`K⁻¹` applied, distortion
//! removed, e.g. by [`crate::camera::CameraModel::unproject`]) or, for the
//! minimal solvers, bearing vectors. Poses follow `x_2 = R x_1 + t`
//! (`T_c2_c1`).

pub mod essential;
pub mod five_point;
pub mod p3p;
pub mod pnp;
pub mod polynomial;
pub mod ransac;
pub mod triangulation;

#[cfg(test)]
pub(crate) mod test_scenes;

pub use five_point::{five_point, EssentialSolutions};
pub use p3p::p3p;
pub use pnp::{estimate_absolute_pose, AbsolutePose, AbsolutePoseConfig};
pub use ransac::{estimate_relative_pose, RelativePose, RelativePoseConfig};
pub use triangulation::{triangulate, TriangulationConfig, TriangulationFailure};

/// Why a robust estimate could not be made.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum TwoViewError {
    #[error("need at least {needed} correspondences, got {got}")]
    /// Fewer correspondences than the minimal solver or the refinement needs.
    TooFewCorrespondences {
        /// Correspondences needed.
        needed: usize,
        /// Correspondences given.
        got: usize,
    },
    #[error("{first} points in the first set but {second} in the second")]
    /// The two point lists differ in length.
    LengthMismatch {
        /// Length of the first list.
        first: usize,
        /// Length of the second list.
        second: usize,
    },
    #[error("correspondence {index} has a coordinate that is not finite")]
    /// A correspondence has a NaN or infinite coordinate.
    NonFinite {
        /// Its index.
        index: usize,
    },
    #[error("setting `{key}` = {value} is outside the allowed range {allowed}")]
    /// A setting is out of range.
    InvalidConfig {
        /// The setting's name.
        key: &'static str,
        /// Its value.
        value: f64,
        /// The allowed range.
        allowed: &'static str,
    },
    #[error("no model is supported by enough inliers (best {best}, need {needed})")]
    /// No hypothesis has `min_inliers` inliers.
    NoConsensus {
        /// Inliers of the best hypothesis.
        best: usize,
        /// Inliers needed.
        needed: usize,
    },
}
