//! The default rig: EuRoC's VI-Sensor cameras and ADIS16448 IMU, values
//! copied from `mav0/cam0/sensor.yaml`, `mav0/cam1/sensor.yaml` and
//! `mav0/imu0/sensor.yaml` of the EuRoC MAV dataset (V1_01_easy).

use nalgebra::{Isometry3, Matrix3, Rotation3, Translation3, UnitQuaternion, Vector3};

use crate::camera::{CameraModel, PinholeRadtan};
use crate::rig::{CameraCalibration, ImuCalibration, ImuNoise};

/// A rigid transform from the upper 3x4 of a row-major 4x4 matrix; the
/// rotation is projected onto SO(3) (the yaml's is orthonormal to ~1e-9).
#[allow(non_snake_case)]
fn rigid(T: [f64; 12]) -> Isometry3<f64> {
    let r = Matrix3::new(T[0], T[1], T[2], T[4], T[5], T[6], T[8], T[9], T[10]);
    let rotation = Rotation3::from_matrix_eps(&r, 1e-12, 100, Rotation3::identity());
    Isometry3::from_parts(
        Translation3::from(Vector3::new(T[3], T[7], T[11])),
        UnitQuaternion::from_rotation_matrix(&rotation),
    )
}

/// EuRoC cam0 (left).
pub fn euroc_cam0() -> CameraCalibration {
    CameraCalibration {
        time_shift_cam_imu_s: 0.0,
        model: CameraModel::PinholeRadtan(PinholeRadtan {
            width: 752,
            height: 480,
            fx: 458.654,
            fy: 457.296,
            cx: 367.215,
            cy: 248.375,
            distortion: [-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05, 0.0],
        }),
        T_body_cam: rigid([
            0.0148655429818,
            -0.999880929698,
            0.00414029679422,
            -0.0216401454975,
            0.999557249008,
            0.0149672133247,
            0.025715529948,
            -0.064676986768,
            -0.0257744366974,
            0.00375618835797,
            0.999660727178,
            0.00981073058949,
        ]),
        rate_hz: 20.0,
    }
}

/// EuRoC cam1 (right).
pub fn euroc_cam1() -> CameraCalibration {
    CameraCalibration {
        time_shift_cam_imu_s: 0.0,
        model: CameraModel::PinholeRadtan(PinholeRadtan {
            width: 752,
            height: 480,
            fx: 457.587,
            fy: 456.134,
            cx: 379.999,
            cy: 255.238,
            distortion: [-0.28368365, 0.07451284, -0.00010473, -3.55590700e-05, 0.0],
        }),
        T_body_cam: rigid([
            0.0125552670891,
            -0.999755099723,
            0.0182237714554,
            -0.0198435579556,
            0.999598781151,
            0.0130119051815,
            0.0251588363115,
            0.0453689425024,
            -0.0253898008918,
            0.0179005838253,
            0.999517347078,
            0.00786212447038,
        ]),
        rate_hz: 20.0,
    }
}

/// EuRoC imu0: the body frame itself, 200 Hz, ADIS16448 noise.
pub fn euroc_imu0() -> ImuCalibration {
    ImuCalibration {
        intrinsics: super::ImuIntrinsics::IDENTITY,
        T_body_imu: Isometry3::identity(),
        rate_hz: 200.0,
        noise: ImuNoise::EUROC_ADIS16448,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stereo_baseline_is_euroc_s() {
        // EuRoC's stereo baseline is about 11 cm along cam0's x axis.
        let t_cam0_cam1 = euroc_cam0().T_body_cam.inverse() * euroc_cam1().T_body_cam;
        let b = t_cam0_cam1.translation.vector;
        assert!((b.norm() - 0.1101).abs() < 1e-3, "{b}");
        assert!(b.x > 0.109);
    }
}
