//! Stage 1 of the method: relative motion by a tightly coupled windowed
//! visual-inertial odometry (paper Figure 8, eq. 29-40).
//!
//! A frame goes through the modules in this order: [`tracker`] turns an
//! image (or a stereo pair) into a [`types::TrackedFrame`] of landmark
//! observations; [`imu_buffer`] holds the samples between frames; until
//! the state is metric [`initializer`] finds a static start, bootstraps
//! the mono modes and aligns the IMU with the vision-only [`window`];
//! afterwards the window optimises the newest keyframes with the IMU
//! intervals between them. [`odometry`] runs these steps per frame behind
//! the [`estimator::RelativeEstimator`] interface, and every frame leaves
//! as a [`types::RelativeOutput`] for the publisher and the absolute stage.

pub mod camera_clock;
pub mod config;
pub mod ekf;
pub mod ekf_odometry;
pub mod estimator;
pub mod factory;
pub mod imu_buffer;
pub mod initializer;
pub mod level;
pub mod odometry;
mod published_position;
pub mod setup;
pub mod tracker;
pub mod types;
pub mod window;

pub use config::{
    CameraImuRefinement, ConfigError, EstimatorKind, FullWindowAlignment, InertialModes,
    RelativeConfig,
};
pub use estimator::{
    FrameInput, FrameTimings, ModeSwitch, RelativeEstimator, RigError, RigModel, SensorMode,
};
pub use factory::build_estimator;
pub use odometry::WindowOdometry;
pub use setup::OdometryError;
pub use types::{
    BodyLandmark, KeyframeState, LandmarkId, Observation, PoseCovariance, RelativeOutput,
    TrackedFrame, TrackingState,
};
