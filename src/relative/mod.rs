//! Stage 1 of the method: relative motion by a tightly coupled windowed
//! visual-inertial odometry (paper Figure 8, eq. 29-40).
//!
//! A frame goes through [`types`] as follows: the tracker turns an image
//! (or a stereo pair) into a [`types::TrackedFrame`] of landmark
//! observations; until the scale is known the initialiser collects them;
//! afterwards the window optimises the newest keyframes with the IMU
//! intervals between them, and every frame leaves as a
//! [`types::RelativeOutput`] for the publisher and the absolute stage.

pub mod ekf;
pub mod estimator;
pub mod types;

pub use estimator::{
    FrameInput, FrameTimings, RelativeEstimator, RigError, RigModel, SensorMode,
};
pub use types::{
    BodyLandmark, KeyframeState, LandmarkId, Observation, RelativeOutput, TrackedFrame,
    TrackingState,
};
