//! Inertial integration. A raw stream is corrected (the rig's
//! [`crate::rig::ImuIntrinsics`]) and cleaned ([`interval`]), cut at frame
//! stamps, and each interval is
//! preintegrated on the manifold with its covariance and bias Jacobians
//! ([`preintegration`], using the step rules of [`quadrature`] and the
//! noise of [`noise`]); [`residual`] turns a preintegrated interval into
//! the inertial error between two states. [`strapdown`] is the plain RK4
//! integrator used as a reference and by the simulator.

pub mod agreement;
pub mod chain;
pub mod interval;
pub mod noise;
pub mod preintegration;
pub mod quadrature;
pub mod residual;
pub mod so3;
pub mod strapdown;

pub use crate::rig::ImuIntrinsics;
pub use agreement::{accel_agreement, gyro_agreement, AccelAgreement, GyroAgreement};
pub use interval::{
    interpolate_sample, ImuInterval, ImuStream, IntervalConfig, IntervalError, IntervalReport,
};
pub use noise::{bias_walk_covariance, DiscreteNoise};
pub use preintegration::{IntegrationScheme, Preintegrated, PreintegrationError, Preintegrator};
pub use residual::{imu_residual, ImuResidual};
pub use strapdown::{integrate, step, ImuBiases, NavState, StrapdownError, GRAVITY_M_S2};
