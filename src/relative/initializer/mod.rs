//! Initialisation mode of the relative stage: from
//! nothing to a metric, gravity-aligned state.
//!
//! Three independent pieces, in the order a start uses them:
//! - [`static_start`]: the rig is at rest (told from the IMU alone, and
//!   conservatively): gravity direction, gyroscope bias and zero velocity
//!   straight away.
//! - [`bootstrap`]: the vision-only start of the mono modes: two views
//!   with enough parallax, five-point MSAC, the first translation set to
//!   unit length, triangulated landmarks; and PnP for the frames between.
//! - [`alignment`]: the IMU compared with the vision-only motion of a few
//!   keyframes to estimate the scale, gravity, the velocities and the
//!   gyroscope bias, with a certainty for the scale that tells the caller
//!   when to switch to the tightly coupled mode.

pub mod alignment;
pub mod bootstrap;
pub mod static_start;

pub use alignment::{
    align, align_mono, align_stereo, align_with_reintegration, estimate_gyro_bias, Alignment,
    AlignmentConfig, AlignmentError, GyroBiasEstimate, ScaleMode, VisionKeyframe,
};
pub use bootstrap::{
    bootstrap_two_view, pnp_frame, Bootstrap, BootstrapConfig, BootstrapRefusal, Landmark,
    PnpConfig, PnpFrame,
};
pub use static_start::{detect_static_start, StaticRefusal, StaticStart, StaticStartConfig};

use nalgebra::{UnitQuaternion, Vector3};

/// The rotation `R_world_frame` that maps `up_frame` (the direction
/// opposite to gravity, in some frame) onto the world's +z, with zero yaw
/// (the z-y-x Euler yaw of the result is 0). `None` when `up_frame` is
/// zero or not finite.
pub fn level_rotation(up_frame: &Vector3<f64>) -> Option<UnitQuaternion<f64>> {
    let n = up_frame.norm();
    if !(n.is_finite() && n > 0.0) {
        return None;
    }
    let up = up_frame / n;
    let z = Vector3::z();
    let minimal = UnitQuaternion::rotation_between(&up, &z).unwrap_or_else(|| {
        // Antiparallel: half a turn about any horizontal axis.
        UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f64::consts::PI)
    });
    let (_, _, yaw) = minimal.euler_angles();
    // A rotation about world z keeps z where it is, so removing the yaw
    // keeps `up` mapped onto z.
    Some(UnitQuaternion::from_axis_angle(&Vector3::z_axis(), -yaw) * minimal)
}

/// The real V1_02 IMU and ground truth for the tests (`None` when
/// ../shared/data is missing outside CI).
#[cfg(test)]
fn v1_02_imu_and_truth() -> Option<(
    Vec<crate::sensors::ImuSample>,
    Vec<crate::dataset::GroundTruthState>,
)> {
    let dir = crate::shared_data::shared_data_dir()?.join("euroc/ground_truth");
    let imu = crate::dataset::read_euroc_imu_csv(&dir.join("V1_02_imu0.csv"))
        .expect("V1_02 IMU")
        .samples;
    let truth = crate::dataset::read_euroc_groundtruth(&dir.join("V1_02_groundtruth.csv"))
        .expect("V1_02 ground truth");
    Some((imu, truth))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn level_rotation_maps_up_to_z_with_zero_yaw() {
        let ups = [
            Vector3::new(0.3, -0.2, 0.9),
            Vector3::new(9.0, 0.1, -3.6),
            Vector3::new(0.0, 0.0, -1.0),
            Vector3::new(0.0, 0.0, 2.0),
            Vector3::new(-1.0, 0.0, 0.0),
        ];
        for up in ups {
            let r = level_rotation(&up).expect("non-zero");
            let mapped = r * up.normalize();
            assert!(
                (mapped - Vector3::z()).norm() < 1e-12,
                "{up:?} -> {mapped:?}"
            );
            let (_, _, yaw) = r.euler_angles();
            assert!(yaw.abs() < 1e-12, "yaw {yaw}");
        }
        assert!(level_rotation(&Vector3::zeros()).is_none());
        assert!(level_rotation(&Vector3::new(f64::NAN, 0.0, 1.0)).is_none());
    }
}
