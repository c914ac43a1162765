//! What can go wrong when scoring a trajectory, with the numbers a user
//! needs to see why.

/// Errors of association, alignment, metrics and plotting.
#[derive(Debug, thiserror::Error)]
pub enum EvalError {
    /// No estimated stamp fell within `max_dt_ms` of a ground-truth stamp.
    /// Both ranges are printed: seconds against nanoseconds, or two different
    /// clocks, are the usual cause.
    #[error(
        "no estimated pose matches a ground-truth pose within {max_dt_ms} ms \
         (estimate offset by {t_offset_s} s): estimate spans {est_first_s:.6} .. {est_last_s:.6} s \
         ({est_count} poses), ground truth spans {gt_first_s:.6} .. {gt_last_s:.6} s ({gt_count} poses); \
         check seconds vs nanoseconds, the clock both were stamped with, or --t-offset-s"
    )]
    NoMatches {
        /// Largest time difference allowed in a pair, ms.
        max_dt_ms: f64,
        /// Offset added to the estimate's stamps, s.
        t_offset_s: f64,
        /// First estimated stamp, s.
        est_first_s: f64,
        /// Last estimated stamp, s.
        est_last_s: f64,
        /// Poses in the estimate.
        est_count: usize,
        /// First ground-truth stamp, s.
        gt_first_s: f64,
        /// Last ground-truth stamp, s.
        gt_last_s: f64,
        /// Poses in the ground truth.
        gt_count: usize,
    },
    /// A trajectory without a single pose.
    #[error("the {which} trajectory is empty")]
    Empty {
        /// `estimated` or `ground-truth`.
        which: &'static str,
    },
    /// Too few matched poses for what was asked.
    #[error("{what} needs at least {needed} matched poses, found {found}")]
    TooFewPoses {
        /// What was asked (e.g. the alignment).
        what: &'static str,
        /// Matched poses it needs.
        needed: usize,
        /// Matched poses there are.
        found: usize,
    },
    /// The matched positions do not fix the alignment (all equal, or on a line).
    #[error("cannot align: {0}")]
    Degenerate(String),
    /// The plot could not be drawn or written.
    #[error("{path}: cannot draw the plot: {message}")]
    Plot {
        /// The file the plot was to be written to.
        path: std::path::PathBuf,
        /// The plotting library's error.
        message: String,
    },
}
