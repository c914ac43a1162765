//! OpenVINS: `kalibr_imucam_chain.yaml` (cameras with `T_imu_cam`, camera
//! to IMU) and `kalibr_imu_chain.yaml` (noise, and the intrinsics in its
//! "kalibr" model).
//!
//! OpenVINS corrects a raw sample as `R_GYROtoIMU * Dw * (w_m - b_g)` with
//! `Dw = Tw^-1` and, in its "kalibr" model, only the lower triangle of `Dw`
//! kept (likewise `Da`, `R_ACCtoIMU`). Ours is `S w_m + b`. Writing
//! `S = Q L` (Q a rotation, L lower-triangular with a positive diagonal)
//! gives `R_GYROtoIMU = Q`, `Dw = L` exactly; our constant offset `b` has
//! no place in the file (OpenVINS estimates its biases online from zero),
//! which the notes say.

use nalgebra::Matrix3;
use serde::Serialize;

use super::{radtan4, rows4, Export, ExportError, ExportFile};
use rigslam::rig::{CameraCalibration, ImuCalibration};

#[allow(non_snake_case)]
#[derive(Serialize)]
struct Camera {
    T_imu_cam: [[f64; 4]; 4],
    cam_overlaps: Vec<u32>,
    camera_model: &'static str,
    distortion_coeffs: Vec<f64>,
    distortion_model: &'static str,
    intrinsics: [f64; 4],
    resolution: [u32; 2],
    rostopic: String,
    timeshift_cam_imu: f64,
}

#[allow(non_snake_case)]
#[derive(Serialize)]
struct Imu {
    T_i_b: [[f64; 4]; 4],
    accelerometer_noise_density: f64,
    accelerometer_random_walk: f64,
    gyroscope_noise_density: f64,
    gyroscope_random_walk: f64,
    rostopic: &'static str,
    time_offset: f64,
    update_rate: f64,
    model: &'static str,
    Tw: [[f64; 3]; 3],
    R_IMUtoGYRO: [[f64; 3]; 3],
    Ta: [[f64; 3]; 3],
    R_IMUtoACC: [[f64; 3]; 3],
    Tg: [[f64; 3]; 3],
}

#[derive(Serialize)]
struct ImuChain {
    imu0: Imu,
}

fn rows3(m: &Matrix3<f64>) -> [[f64; 3]; 3] {
    [0, 1, 2].map(|r| [m[(r, 0)], m[(r, 1)], m[(r, 2)]])
}

/// `S = Q L`: Q a rotation, L lower-triangular with a positive diagonal,
/// from the Cholesky factor of `S^T S = L^T L` taken in reversed order.
/// `None` when `S` is singular or reflects.
pub fn ql_decomposition(s: &Matrix3<f64>) -> Option<(Matrix3<f64>, Matrix3<f64>)> {
    if s.determinant() <= 0.0 {
        return None;
    }
    let flip = Matrix3::new(0.0, 0.0, 1.0, 0.0, 1.0, 0.0, 1.0, 0.0, 0.0);
    let m = s.transpose() * s;
    // flip M flip = C C^T (C lower) <=> M = U U^T with U = flip C flip upper.
    let c = (flip * m * flip).cholesky()?.l();
    let l = (flip * c * flip).transpose();
    let q = s * l.try_inverse()?;
    Some((q, l))
}

/// OpenVINS reads its configs with OpenCV's YAML parser.
fn yaml(value: &impl Serialize) -> String {
    super::opencv_yaml::to_string(value)
}

pub fn export(cameras: &[CameraCalibration], imu: &ImuCalibration) -> Result<Export, ExportError> {
    let n = cameras.len() as u32;
    let mut chain = std::collections::BTreeMap::new();
    for (i, c) in cameras.iter().enumerate() {
        let [fx, fy, cx, cy] = c.model.pinhole();
        let (model, coefficients) = match c.model {
            rigslam::camera::CameraModel::PinholeEquidistant(_) => {
                ("equidistant", c.model.distortion_coefficients())
            }
            _ => ("radtan", radtan4(c, i)?.to_vec()),
        };
        chain.insert(
            format!("cam{i}"),
            Camera {
                // The body is the IMU: T_imu_cam = T_body_cam.
                T_imu_cam: rows4(&c.T_body_cam),
                cam_overlaps: (0..n).filter(|&j| j != i as u32).collect(),
                camera_model: "pinhole",
                distortion_coeffs: coefficients,
                distortion_model: model,
                intrinsics: [fx, fy, cx, cy],
                resolution: [c.model.width(), c.model.height()],
                rostopic: format!("/cam{i}/image_raw"),
                timeshift_cam_imu: c.time_shift_cam_imu_s,
            },
        );
    }
    let i = &imu.intrinsics;
    let mut notes = Vec::new();
    let (q_g, l_g) = ql_decomposition(&i.gyro_scale).ok_or_else(|| {
        ExportError::Camera("the gyroscope scale matrix is singular or reflects".into())
    })?;
    let (q_a, l_a) = ql_decomposition(&i.accel_scale).ok_or_else(|| {
        ExportError::Camera("the accelerometer scale matrix is singular or reflects".into())
    })?;
    let tw = l_g
        .try_inverse()
        .expect("triangular with a positive diagonal");
    let ta = l_a
        .try_inverse()
        .expect("triangular with a positive diagonal");
    if i.gyro_offset_rad_s.norm() > 0.0 || i.accel_offset_m_s2.norm() > 0.0 {
        notes.push(format!(
            "OpenVINS has no fixed sensor offset: its online bias estimate starts at zero and must absorb gyro {:.2e} rad/s, accel {:.2e} m/s^2",
            i.gyro_offset_rad_s.norm(),
            i.accel_offset_m_s2.norm()
        ));
    }
    let n = &imu.noise;
    let imu_chain = ImuChain {
        imu0: Imu {
            T_i_b: rows4(&imu.T_body_imu.inverse()),
            accelerometer_noise_density: n.accelerometer_noise_density,
            accelerometer_random_walk: n.accelerometer_random_walk,
            gyroscope_noise_density: n.gyroscope_noise_density,
            gyroscope_random_walk: n.gyroscope_random_walk,
            rostopic: "/imu0",
            time_offset: 0.0,
            update_rate: imu.rate_hz,
            model: "kalibr",
            Tw: rows3(&tw),
            // R_GYROtoIMU = Q, so R_IMUtoGYRO = Q^T.
            R_IMUtoGYRO: rows3(&q_g.transpose()),
            Ta: rows3(&ta),
            R_IMUtoACC: rows3(&q_a.transpose()),
            Tg: [[0.0; 3]; 3],
        },
    };
    Ok(Export {
        files: vec![
            ExportFile {
                name: "kalibr_imucam_chain.yaml".into(),
                text: yaml(&chain),
            },
            ExportFile {
                name: "kalibr_imu_chain.yaml".into(),
                text: yaml(&imu_chain),
            },
        ],
        notes,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ql_reproduces_the_matrix_with_a_rotation_and_a_lower_triangle() {
        let s = Matrix3::new(
            1.015, 0.01, -0.006, 0.004, 0.99, 0.012, -0.003, 0.008, 1.005,
        );
        let (q, l) = ql_decomposition(&s).expect("invertible");
        assert!((q * l - s).amax() < 1e-12);
        assert!((q.transpose() * q - Matrix3::identity()).amax() < 1e-12);
        assert!((q.determinant() - 1.0).abs() < 1e-12);
        assert_eq!([l[(0, 1)], l[(0, 2)], l[(1, 2)]], [0.0, 0.0, 0.0]);
        assert!(l[(0, 0)] > 0.0 && l[(1, 1)] > 0.0 && l[(2, 2)] > 0.0);
        assert!(ql_decomposition(&Matrix3::from_diagonal_element(-1.0)).is_none());
    }
}
