//! rigslam's samples, frames, poses and rig as the ROS 2 messages of
//! [`super::messages`], in REP-103/105 terms: frames `map`, `odom`,
//! `body` (the IMU-centred body frame the poses are of), `cam0`, `cam1`
//! and `imu`; stamps on the sensors' clock as the recording keeps them.

use nalgebra::{Isometry3, Matrix3, Matrix6, Quaternion, UnitQuaternion, Vector3};

use super::messages::{
    CameraInfo, Header, Image, Imu, Odometry, RegionOfInterest, TfMessage, TransformStamped,
};
use crate::recording::RecordedPose;
use crate::rig::{CameraCalibration, ImuCalibration, RigModel};
use rigslam_drivers::ImuSample;

/// The map frame (where the absolute stage places the robot).
pub const MAP: &str = "map";
/// The odometry frame (the relative stage's, continuous).
pub const ODOM: &str = "odom";
/// The body frame the poses are of.
pub const BODY: &str = "body";
/// The IMU's frame (its samples are in it).
pub const IMU_FRAME: &str = "imu";

/// Per-sample variances of the IMU's angular rate and specific force,
/// (rad/s)^2 and (m/s^2)^2: the rig's white-noise densities made
/// discrete at its sample rate (`sigma_d = sigma_c sqrt(rate)`).
pub fn imu_variances(imu: &ImuCalibration) -> [f64; 2] {
    if !(imu.rate_hz.is_finite() && imu.rate_hz > 0.0) {
        return [0.0; 2];
    }
    let noise = crate::imu::noise::DiscreteNoise::from_continuous(&imu.noise, 1.0 / imu.rate_hz);
    [
        noise.gyro_sigma_rad_s.powi(2),
        noise.accel_sigma_m_s2.powi(2),
    ]
}

/// A diagonal 3x3 covariance, row-major.
fn diagonal(variance: f64) -> [f64; 9] {
    let mut out = [0.0; 9];
    for i in 0..3 {
        out[4 * i] = variance;
    }
    out
}

/// An IMU sample as `sensor_msgs/Imu` in the `imu` frame: the raw
/// sample, no orientation (`orientation_covariance[0] = -1`, as ROS says
/// for an IMU that gives none), and `variances` (from
/// [`imu_variances`]; zeros, "unknown", without a calibrated IMU) on the
/// diagonals.
pub fn imu(sample: &ImuSample, variances: Option<[f64; 2]>) -> Imu {
    let [gyro, accel] = variances.unwrap_or([0.0; 2]);
    let mut orientation_covariance = [0.0; 9];
    orientation_covariance[0] = -1.0;
    Imu {
        header: Header::new(sample.t_ns, IMU_FRAME),
        orientation_xyzw: [0.0, 0.0, 0.0, 1.0],
        orientation_covariance,
        angular_velocity: sample.gyro_rad_s,
        angular_velocity_covariance: diagonal(gyro),
        linear_acceleration: sample.accel_m_s2,
        linear_acceleration_covariance: diagonal(accel),
    }
}

/// A frame as an 8-bit grey `sensor_msgs/Image` (`mono8`, rows without
/// padding; other pixel formats converted to grey).
pub fn image(t_ns: i64, image: &rigslam_drivers::Image, frame_id: &str) -> Image {
    Image {
        header: Header::new(t_ns, frame_id),
        height: image.height(),
        width: image.width(),
        encoding: "mono8".to_owned(),
        is_bigendian: 0,
        step: image.width(),
        data: crate::recording::grey_bytes(image),
    }
}

fn rotation(q: [f64; 4]) -> UnitQuaternion<f64> {
    UnitQuaternion::from_quaternion(Quaternion::new(q[3], q[0], q[1], q[2]))
}

/// The pose's covariance about the odometry frame's axes: the published
/// one is of the map-frame pose about the map's axes (position error,
/// then rotation error about fixed axes, as ROS's), turned by
/// `R_odom_map` with the map -> odom transform taken as exact. Zeros
/// (ROS's "unknown") when the pose has none.
fn odom_covariance(p: &RecordedPose) -> [f64; 36] {
    if !p.covariance.iter().all(|c| c.is_finite()) {
        return [0.0; 36];
    }
    if p.rotation_world_odom_xyzw == [0.0, 0.0, 0.0, 1.0] {
        return p.covariance;
    }
    let r: Matrix3<f64> = rotation(p.rotation_world_odom_xyzw)
        .to_rotation_matrix()
        .matrix()
        .transpose();
    let mut turn = Matrix6::zeros();
    turn.fixed_view_mut::<3, 3>(0, 0).copy_from(&r);
    turn.fixed_view_mut::<3, 3>(3, 3).copy_from(&r);
    let world = Matrix6::from_row_slice(&p.covariance);
    let odom = turn * world * turn.transpose();
    let mut out = [0.0; 36];
    for row in 0..6 {
        for col in 0..6 {
            out[6 * row + col] = odom[(row, col)];
        }
    }
    out
}

/// A pose as `nav_msgs/Odometry`: the body's pose in the odometry frame
/// with its covariance, and its velocity in the body frame (ROS puts the
/// twist in the child frame) when the pose has one, else zeros. The
/// angular velocity is not estimated: zeros; the twist's covariance is
/// not given: zeros.
pub fn odometry(p: &RecordedPose) -> Odometry {
    let velocity_valid = p.flags & crate::publish::POSE_FLAG_VELOCITY_VALID != 0
        && p.velocity_world_m_s.iter().all(|v| v.is_finite());
    let linear_velocity = if velocity_valid {
        let v =
            rotation(p.orientation_world_body_xyzw).inverse() * Vector3::from(p.velocity_world_m_s);
        [v.x, v.y, v.z]
    } else {
        [0.0; 3]
    };
    Odometry {
        header: Header::new(p.t_ns, ODOM),
        child_frame_id: BODY.to_owned(),
        position: p.position_odom_m,
        orientation_xyzw: p.orientation_odom_body_xyzw,
        pose_covariance: odom_covariance(p),
        linear_velocity,
        angular_velocity: [0.0; 3],
        twist_covariance: [0.0; 36],
    }
}

/// `parent <- child` at `t_ns`, from a translation and an x, y, z, w
/// rotation as they are.
fn transform(
    t_ns: i64,
    parent: &str,
    child: &str,
    translation: [f64; 3],
    rotation_xyzw: [f64; 4],
) -> TransformStamped {
    TransformStamped {
        header: Header::new(t_ns, parent),
        child_frame_id: child.to_owned(),
        translation,
        rotation_xyzw,
    }
}

/// The transforms of one pose for `/tf`: `map -> odom`, `odom -> body`.
pub fn pose_transforms(p: &RecordedPose) -> TfMessage {
    TfMessage {
        transforms: vec![
            transform(
                p.t_ns,
                MAP,
                ODOM,
                p.translation_world_odom_m,
                p.rotation_world_odom_xyzw,
            ),
            transform(
                p.t_ns,
                ODOM,
                BODY,
                p.position_odom_m,
                p.orientation_odom_body_xyzw,
            ),
        ],
    }
}

fn isometry_transform(parent: &str, child: &str, pose: &Isometry3<f64>) -> TransformStamped {
    let t = pose.translation.vector;
    let q = pose.rotation.coords;
    transform(0, parent, child, [t.x, t.y, t.z], [q.x, q.y, q.z, q.w])
}

/// Where the sensors sit on the body, for `/tf_static`: `body -> cam0`,
/// `body -> cam1` and `body -> imu`, stamped 0 (static transforms hold at
/// every time).
pub fn static_transforms(rig: &RigModel) -> TfMessage {
    let mut transforms: Vec<TransformStamped> = rig
        .cameras
        .iter()
        .take(2)
        .enumerate()
        .map(|(i, c)| isometry_transform(BODY, &format!("cam{i}"), &c.T_body_cam))
        .collect();
    if let Some(imu) = &rig.imu {
        transforms.push(isometry_transform(BODY, IMU_FRAME, &imu.T_body_imu));
    }
    TfMessage { transforms }
}

/// A camera's calibration as `sensor_msgs/CameraInfo` (stamped 0: it
/// holds for the whole file): `plumb_bob` is OpenCV's k1, k2, p1, p2, k3,
/// `equidistant` the fisheye k1..k4; the images are not rectified, so R
/// is the identity and P the intrinsics.
pub fn camera_info(camera: &CameraCalibration, frame_id: &str) -> CameraInfo {
    let model = &camera.model;
    let [fx, fy, cx, cy] = model.pinhole();
    let distortion_model = match model {
        crate::camera::CameraModel::PinholeRadtan(_) => "plumb_bob",
        crate::camera::CameraModel::PinholeEquidistant(_) => "equidistant",
    };
    CameraInfo {
        header: Header::new(0, frame_id),
        height: model.height(),
        width: model.width(),
        distortion_model: distortion_model.to_owned(),
        d: model.distortion_coefficients(),
        k: [fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0],
        r: [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
        p: [fx, 0.0, cx, 0.0, 0.0, fy, cy, 0.0, 0.0, 0.0, 1.0, 0.0],
        binning_x: 0,
        binning_y: 0,
        roi: RegionOfInterest::default(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pose() -> RecordedPose {
        let mut p = RecordedPose::map_only(
            7,
            1,
            [1.0, 2.0, 3.0],
            [
                0.0,
                0.0,
                std::f64::consts::FRAC_1_SQRT_2,
                std::f64::consts::FRAC_1_SQRT_2,
            ],
            [1.0, 0.0, 0.0],
        );
        p.flags = crate::publish::POSE_FLAG_VELOCITY_VALID;
        p
    }

    /// The body turned +90 degrees about z: moving along the map's x is
    /// moving along the body's -y.
    #[test]
    fn the_twist_is_in_the_body_frame() {
        let o = odometry(&pose());
        assert!((o.linear_velocity[0]).abs() < 1e-15, "{o:?}");
        assert!((o.linear_velocity[1] + 1.0).abs() < 1e-15, "{o:?}");
        assert_eq!(o.position, [1.0, 2.0, 3.0]);
        assert_eq!(
            (o.header.frame_id.as_str(), o.child_frame_id.as_str()),
            (ODOM, BODY)
        );
        // No velocity estimate: zeros.
        let mut p = pose();
        p.flags = 0;
        assert_eq!(odometry(&p).linear_velocity, [0.0; 3]);
    }

    #[test]
    fn the_covariance_is_turned_into_the_odometry_frame() {
        let mut p = pose();
        // Unknown: zeros.
        assert_eq!(odometry(&p).pose_covariance, [0.0; 36]);
        // Variance along the map's x only; odom turned +90 degrees about
        // z in the map: that is the odometry frame's -y, variance on y.
        let mut c = [0.0; 36];
        c[0] = 4.0;
        c[6 * 5 + 5] = 0.5;
        p.covariance = c;
        assert_eq!(odometry(&p).pose_covariance, c, "identity: as it is");
        p.rotation_world_odom_xyzw = [
            0.0,
            0.0,
            std::f64::consts::FRAC_1_SQRT_2,
            std::f64::consts::FRAC_1_SQRT_2,
        ];
        let turned = odometry(&p).pose_covariance;
        assert!((turned[0]).abs() < 1e-12, "{turned:?}");
        assert!((turned[7] - 4.0).abs() < 1e-12, "{turned:?}");
        assert!((turned[35] - 0.5).abs() < 1e-12, "{turned:?}");
    }

    #[test]
    fn imu_messages_say_there_is_no_orientation() {
        let s = ImuSample {
            t_ns: 5_000_000_123,
            gyro_rad_s: [0.1, 0.2, 0.3],
            accel_m_s2: [0.0, 0.0, 9.81],
        };
        let m = imu(&s, Some([1e-4, 4e-2]));
        assert_eq!(m.orientation_covariance[0], -1.0);
        assert_eq!(m.angular_velocity, s.gyro_rad_s);
        assert_eq!(m.linear_acceleration, s.accel_m_s2);
        assert_eq!(m.angular_velocity_covariance[4], 1e-4);
        assert_eq!(m.linear_acceleration_covariance[8], 4e-2);
        assert_eq!(m.linear_acceleration_covariance[1], 0.0);
        assert_eq!((m.header.stamp.sec, m.header.stamp.nanosec), (5, 123));
        assert_eq!(imu(&s, None).angular_velocity_covariance, [0.0; 9]);
    }

    /// EuRoC's ADIS16448 at 200 Hz: sigma_d = 1.6968e-4 * sqrt(200).
    #[test]
    fn imu_variances_are_the_densities_made_discrete() {
        let calibration = ImuCalibration {
            T_body_imu: Isometry3::identity(),
            rate_hz: 200.0,
            noise: crate::rig::ImuNoise::EUROC_ADIS16448,
            intrinsics: Default::default(),
        };
        let [g, a] = imu_variances(&calibration);
        assert!((g - 1.6968e-4f64.powi(2) * 200.0).abs() < 1e-15, "{g}");
        assert!((a - 2.0e-3f64.powi(2) * 200.0).abs() < 1e-15, "{a}");
    }
}
