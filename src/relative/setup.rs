//! What both relative estimators (the window's [`super::odometry`] and the
//! filter's [`super::ekf_odometry`]) start from, and why they may fail to.

use super::config::RelativeConfig;
use super::estimator::{RigModel, SensorMode};
use super::tracker::{Tracker, TrackerConfig};

/// Why the stage could not be set up.
#[derive(Debug, thiserror::Error)]
pub enum OdometryError {
    #[error(transparent)]
    /// The rig lacks a camera or the IMU the mode needs.
    Rig(#[from] super::estimator::RigError),
    #[error(transparent)]
    /// A setting is out of range.
    Config(#[from] super::config::ConfigError),
    #[error("setting up the relative stage: {0}")]
    /// The estimator refused the rig or the settings (the message says why).
    Setup(String),
}

/// What both estimators start from: the rig and config checked for
/// `mode`, the rig cut down to the cameras (and IMU) the mode uses, and
/// the tracker on those cameras.
pub(super) fn front_end(
    mode: SensorMode,
    rig: &RigModel,
    config: &RelativeConfig,
) -> Result<(RigModel, Tracker), OdometryError> {
    rig.check(mode)?;
    config.validate()?;
    let cameras = if mode.uses_stereo() {
        rig.cameras[..2].to_vec()
    } else {
        rig.cameras[..1].to_vec()
    };
    let tracker_config = TrackerConfig {
        target_features: config.features,
        klt_affine: config.klt_affine,
        first_patch: config.track_first_patch.enabled_in(mode),
        ..TrackerConfig::default()
    };
    let tracker = Tracker::new(tracker_config, &cameras, mode.uses_stereo())
        .map_err(|e| OdometryError::Setup(e.to_string()))?;
    let used = RigModel {
        cameras,
        imu: if mode.uses_imu() {
            rig.imu.clone()
        } else {
            None
        },
    };
    Ok((used, tracker))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::relative::ModeSwitch;
    use crate::rig::euroc::{euroc_cam0, euroc_cam1, euroc_imu0};

    #[test]
    fn the_first_patch_switch_reaches_the_tracker_of_the_modes_it_names() {
        let rig = RigModel {
            cameras: vec![euroc_cam0(), euroc_cam1()],
            imu: Some(euroc_imu0()),
        };
        let first_patch = |switch, mode| {
            let config = RelativeConfig {
                track_first_patch: switch,
                ..RelativeConfig::default()
            };
            front_end(mode, &rig, &config)
                .expect("a front end")
                .1
                .config()
                .first_patch
        };
        assert_eq!(
            RelativeConfig::default().track_first_patch,
            ModeSwitch::Auto
        );
        for mode in SensorMode::ALL {
            let auto = mode == SensorMode::StereoInertial;
            assert_eq!(first_patch(ModeSwitch::Auto, mode), auto, "{mode:?}");
            assert!(first_patch(ModeSwitch::On, mode), "{mode:?}");
            assert!(!first_patch(ModeSwitch::Off, mode), "{mode:?}");
        }
    }
}
