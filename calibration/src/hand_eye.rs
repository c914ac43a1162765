//! Camera-IMU rotation from angular velocities (the rotational part of
//! hand-eye calibration): the gyroscope reads `w_imu = R_imu_cam w_cam + b_g`,
//! so after removing the means the rotation is an orthogonal Procrustes
//! problem, solved in closed form by SVD (Arun, Huang and Blostein,
//! "Least-squares fitting of two 3-D point sets", PAMI 1987).

use nalgebra::{Matrix3, Vector3};

/// The fit of [`rotation_from_angular_velocities`].
#[derive(Debug, Clone, Copy)]
#[allow(non_snake_case)]
pub struct HandEyeRotation {
    pub R_imu_cam: Matrix3<f64>,
    /// Gyroscope bias, rad/s.
    pub gyro_bias_rad_s: Vector3<f64>,
    /// RMS of `w_imu - R w_cam - b`, rad/s.
    pub rms_rad_s: f64,
}

/// `R_imu_cam` and the gyroscope bias from paired angular velocities
/// (camera frame, IMU frame) over the same intervals. `None` with fewer than
/// three pairs or motion about a single axis (the rotation is not determined).
pub fn rotation_from_angular_velocities(
    w_cam: &[Vector3<f64>],
    w_imu: &[Vector3<f64>],
) -> Option<HandEyeRotation> {
    let n = w_cam.len();
    if n < 3 || w_imu.len() != n {
        return None;
    }
    let mean_cam = w_cam.iter().sum::<Vector3<f64>>() / n as f64;
    let mean_imu = w_imu.iter().sum::<Vector3<f64>>() / n as f64;
    let mut h = Matrix3::zeros();
    for (c, i) in w_cam.iter().zip(w_imu) {
        h += (c - mean_cam) * (i - mean_imu).transpose();
    }
    let svd = h.svd(true, true);
    let singular = svd.singular_values;
    // Motion about one axis only leaves the rotation about it undetermined.
    if singular[1] < 1e-6 * singular[0] {
        return None;
    }
    let (u, v_t) = (svd.u?, svd.v_t?);
    let d = (v_t.transpose() * u.transpose()).determinant().signum();
    let r = v_t.transpose() * Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, d)) * u.transpose();
    let bias = mean_imu - r * mean_cam;
    let sum_sq: f64 = w_cam
        .iter()
        .zip(w_imu)
        .map(|(c, i)| (i - r * c - bias).norm_squared())
        .sum();
    Some(HandEyeRotation {
        R_imu_cam: r,
        gyro_bias_rad_s: bias,
        rms_rad_s: (sum_sq / n as f64).sqrt(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Rotation3;

    #[test]
    fn recovers_rotation_and_bias_exactly() {
        let r = Rotation3::from_euler_angles(0.3, -1.2, 2.0).into_inner();
        let bias = Vector3::new(0.01, -0.02, 0.005);
        let w_cam: Vec<Vector3<f64>> = (0..50)
            .map(|k| {
                let t = k as f64 * 0.1;
                Vector3::new(t.sin(), (1.7 * t).cos(), 0.5 * (0.3 * t).sin())
            })
            .collect();
        let w_imu: Vec<Vector3<f64>> = w_cam.iter().map(|w| r * w + bias).collect();
        let fit = rotation_from_angular_velocities(&w_cam, &w_imu).expect("well-posed");
        assert!((fit.R_imu_cam - r).norm() < 1e-12);
        assert!((fit.gyro_bias_rad_s - bias).norm() < 1e-12);
    }

    #[test]
    fn single_axis_motion_is_rejected() {
        let w_cam: Vec<Vector3<f64>> = (0..20).map(|k| Vector3::new(0.0, 0.0, k as f64)).collect();
        assert!(rotation_from_angular_velocities(&w_cam, &w_cam).is_none());
    }
}
