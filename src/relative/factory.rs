//! The relative stage's factory: the estimator a config asks for, behind
//! the [`RelativeEstimator`] interface, on the IMU's clock, its poses
//! levelled by its gravity estimate. It sits above
//! the estimators (which know only the interface) so that no estimator
//! module depends on another.

use super::camera_clock::on_imu_clock;
use super::config::{EstimatorKind, RelativeConfig};
use super::ekf_odometry::EkfOdometry;
use super::estimator::{RelativeEstimator, RigModel, SensorMode};
use super::level::levelled;
use super::odometry::WindowOdometry;
use super::setup::OdometryError;

/// The estimator `kind` for `mode` on `rig`.
pub fn build_estimator(
    kind: EstimatorKind,
    mode: SensorMode,
    rig: &RigModel,
    config: &RelativeConfig,
) -> Result<Box<dyn RelativeEstimator>, OdometryError> {
    let estimator: Box<dyn RelativeEstimator> = match kind {
        EstimatorKind::Window => Box::new(WindowOdometry::new(mode, rig, config)?),
        EstimatorKind::Ekf => Box::new(EkfOdometry::new(mode, rig, config)?),
    };
    let estimator = if config.level_poses {
        levelled(estimator, config.level_time_constant_s)
    } else {
        estimator
    };
    Ok(on_imu_clock(estimator, rig))
}
