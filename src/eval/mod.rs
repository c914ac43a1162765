//! Trajectory evaluation: association, alignment, ATE, RPE, drift.
