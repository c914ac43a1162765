//! Inertial integration: a plain strapdown integrator over raw samples
//! (reference and simulator check); preintegration for the estimator will
//! sit beside it.

pub mod strapdown;

pub use strapdown::{integrate, step, ImuBiases, NavState, StrapdownError, GRAVITY_M_S2};
