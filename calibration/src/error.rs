//! What can go wrong in an IMU calibration, each variant saying what to
//! recollect: the technician reads these, not a stack trace.

use rigslam::dataset::DatasetError;

#[derive(Debug, thiserror::Error)]
pub enum CalibrationError {
    /// The file could not be read or parsed (names file and line).
    #[error(transparent)]
    Data(#[from] DatasetError),
    /// Not enough distinct still orientations for the unknowns.
    #[error(
        "too few static poses: found {found} distinct still orientation(s) in {intervals} static interval(s), \
         need at least {needed}; recollect holding the IMU still for 2 s or more in each of at least {needed} \
         different orientations (12 or more, spread over the sphere, give the full scale/misalignment)"
    )]
    TooFewPoses {
        found: usize,
        intervals: usize,
        needed: usize,
    },
    /// A log that should be still is not.
    #[error(
        "the log is not static: {what} at t = {t_s:.1} s; recollect with the rig still \
         (on a table, nobody touching it) for the whole recording"
    )]
    NotStatic { what: String, t_s: f64 },
    /// Too short for what was asked.
    #[error("{0}")]
    TooShort(String),
    /// The rotations of the Ferraris protocol are missing or unusable.
    #[error("{0}")]
    Rotations(String),
    /// The optimiser did not converge (should not happen on sane data).
    #[error("{0}")]
    NoConvergence(String),
    #[error("cannot write {path}: {message}")]
    Write { path: String, message: String },
}
