//! Time offset between camera and IMU from angular velocity: the camera's
//! mean rate over each frame interval (from its target poses) against the
//! gyroscope's mean over the same interval shifted by a candidate offset.
//! A coarse search maximises the normalised cross-correlation of the
//! angular speeds (rotation-invariant, so it needs no extrinsics); a fine
//! search minimises the residual of the hand-eye rotation fit
//! ([`crate::hand_eye`]) and interpolates the minimum with a parabola.
//!
//! Convention as Kalibr: `t_imu = t_cam + timeshift_cam_imu`.

use nalgebra::Vector3;
use rigslam::imu::so3;

use crate::aprilgrid_detections::TargetPose;
use crate::hand_eye::{rotation_from_angular_velocities, HandEyeRotation};

/// The camera's mean angular velocity over one frame interval.
#[derive(Debug, Clone, Copy)]
pub struct CameraRate {
    /// Interval start and end, camera clock, s.
    pub t0_s: f64,
    pub t1_s: f64,
    /// In the camera frame, rad/s.
    pub w_cam_rad_s: Vector3<f64>,
}

/// Mean angular velocities of consecutive poses no more than
/// `max_gap_s` apart: `Log(R_k^T R_k+1) / dt` (camera frame).
pub fn camera_rates(poses: &[TargetPose], t_origin_ns: i64, max_gap_s: f64) -> Vec<CameraRate> {
    poses
        .windows(2)
        .filter_map(|w| {
            let dt_s = (w[1].t_ns - w[0].t_ns) as f64 * 1e-9;
            (dt_s > 0.0 && dt_s <= max_gap_s).then(|| CameraRate {
                t0_s: (w[0].t_ns - t_origin_ns) as f64 * 1e-9,
                t1_s: (w[1].t_ns - t_origin_ns) as f64 * 1e-9,
                w_cam_rad_s: so3::log(&(w[0].R_target_cam.transpose() * w[1].R_target_cam)) / dt_s,
            })
        })
        .collect()
}

/// Gyroscope samples on a time axis in seconds.
#[derive(Debug, Clone)]
pub struct GyroSeries {
    pub t_s: Vec<f64>,
    pub w_rad_s: Vec<Vector3<f64>>,
}

impl GyroSeries {
    /// Linear interpolation; `None` outside the samples.
    pub fn at(&self, t_s: f64) -> Option<Vector3<f64>> {
        let n = self.t_s.len();
        if n < 2 || t_s < self.t_s[0] || t_s > self.t_s[n - 1] {
            return None;
        }
        let k = self.t_s.partition_point(|&t| t <= t_s).clamp(1, n - 1);
        let (ta, tb) = (self.t_s[k - 1], self.t_s[k]);
        let a = (t_s - ta) / (tb - ta);
        Some(self.w_rad_s[k - 1] * (1.0 - a) + self.w_rad_s[k] * a)
    }

    /// Mean over `[t0, t1]` (trapezoid on 16 sub-intervals).
    pub fn mean(&self, t0_s: f64, t1_s: f64) -> Option<Vector3<f64>> {
        const STEPS: usize = 16;
        let mut acc = Vector3::zeros();
        for i in 0..=STEPS {
            let w = if i == 0 || i == STEPS { 0.5 } else { 1.0 };
            acc += self.at(t0_s + (t1_s - t0_s) * i as f64 / STEPS as f64)? * w;
        }
        Some(acc / STEPS as f64)
    }
}

/// Pairs (camera rate, gyro mean over the interval shifted by `shift_s`).
fn paired(
    rates: &[CameraRate],
    gyro: &GyroSeries,
    shift_s: f64,
) -> (Vec<Vector3<f64>>, Vec<Vector3<f64>>) {
    rates
        .iter()
        .filter_map(|r| {
            Some((
                r.w_cam_rad_s,
                gyro.mean(r.t0_s + shift_s, r.t1_s + shift_s)?,
            ))
        })
        .unzip()
}

/// Normalised cross-correlation of the angular speeds at one shift.
fn speed_correlation(rates: &[CameraRate], gyro: &GyroSeries, shift_s: f64) -> f64 {
    let (cam, imu) = paired(rates, gyro, shift_s);
    let a: Vec<f64> = cam.iter().map(|w| w.norm()).collect();
    let b: Vec<f64> = imu.iter().map(|w| w.norm()).collect();
    let n = a.len() as f64;
    if a.len() < 3 {
        return 0.0;
    }
    let (ma, mb) = (a.iter().sum::<f64>() / n, b.iter().sum::<f64>() / n);
    let cov: f64 = a.iter().zip(&b).map(|(x, y)| (x - ma) * (y - mb)).sum();
    let va: f64 = a.iter().map(|x| (x - ma).powi(2)).sum();
    let vb: f64 = b.iter().map(|y| (y - mb).powi(2)).sum();
    cov / (va * vb).sqrt().max(1e-300)
}

/// The result of [`estimate_time_offset`].
#[derive(Debug, Clone)]
pub struct TimeOffsetEstimate {
    /// `t_imu = t_cam + timeshift_cam_imu_s`.
    pub timeshift_cam_imu_s: f64,
    /// Angular-speed correlation against the shift (s, correlation).
    pub correlation_curve: Vec<(f64, f64)>,
    /// Peak correlation of the speeds.
    pub peak_correlation: f64,
    /// Hand-eye fit at the chosen shift.
    pub hand_eye: HandEyeRotation,
    /// Intervals used.
    pub pairs: usize,
}

/// Coarse search over `[-max_shift_s, max_shift_s]` in 1 ms steps, fine
/// search in 0.1 ms steps within 5 ms of the peak. `None` when the rates
/// and the gyro do not overlap or the motion does not fix the rotation.
pub fn estimate_time_offset(
    rates: &[CameraRate],
    gyro: &GyroSeries,
    max_shift_s: f64,
) -> Option<TimeOffsetEstimate> {
    let steps = (max_shift_s / 1e-3).round() as i64;
    let correlation_curve: Vec<(f64, f64)> = (-steps..=steps)
        .map(|i| {
            let s = i as f64 * 1e-3;
            (s, speed_correlation(rates, gyro, s))
        })
        .collect();
    let &(coarse, peak_correlation) = correlation_curve
        .iter()
        .max_by(|a, b| a.1.total_cmp(&b.1))?;
    let residual = |s: f64| {
        let (cam, imu) = paired(rates, gyro, s);
        rotation_from_angular_velocities(&cam, &imu).map(|f| f.rms_rad_s)
    };
    let fine: Vec<(f64, f64)> = (-50..=50)
        .filter_map(|i| {
            let s = coarse + i as f64 * 1e-4;
            Some((s, residual(s)?))
        })
        .collect();
    let k = fine
        .iter()
        .enumerate()
        .min_by(|a, b| a.1 .1.total_cmp(&b.1 .1))?
        .0;
    let mut shift = fine[k].0;
    if k > 0 && k + 1 < fine.len() {
        let (y0, y1, y2) = (fine[k - 1].1, fine[k].1, fine[k + 1].1);
        let denom = y0 - 2.0 * y1 + y2;
        if denom > 0.0 {
            shift += 0.5 * (y0 - y2) / denom * 1e-4;
        }
    }
    let (cam, imu) = paired(rates, gyro, shift);
    let hand_eye = rotation_from_angular_velocities(&cam, &imu)?;
    Some(TimeOffsetEstimate {
        timeshift_cam_imu_s: shift,
        correlation_curve,
        peak_correlation,
        hand_eye,
        pairs: cam.len(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Matrix3, Rotation3};

    /// A camera rotating with a known rate profile, seen at 20 Hz; the gyro
    /// at 200 Hz in a rotated frame, with bias, and its clock `shift` ahead.
    #[test]
    fn recovers_shift_rotation_and_bias() {
        let r_imu_cam = Rotation3::from_euler_angles(0.1, 1.5, -0.4).into_inner();
        let bias = Vector3::new(0.004, -0.01, 0.02);
        let true_shift_s = 0.0123;
        let w_cam = |t: f64| {
            Vector3::new(
                (1.3 * t).sin(),
                0.8 * (0.7 * t).cos(),
                0.6 * (2.1 * t).sin(),
            )
        };
        // Integrate the camera orientation finely.
        let dt = 1e-4;
        let mut r = Matrix3::identity();
        let mut poses = Vec::new();
        for step in 0..=200_000 {
            let t = step as f64 * dt;
            if step % 500 == 0 {
                poses.push(TargetPose {
                    t_ns: (t * 1e9).round() as i64,
                    R_target_cam: r,
                    p_target_cam: Vector3::zeros(),
                    rms_px: 0.0,
                    corners: 0,
                    position_information: Matrix3::identity(),
                    orientation_given_position: Matrix3::zeros(),
                });
            }
            r *= so3::exp(&(w_cam(t + 0.5 * dt) * dt));
        }
        let gyro_t: Vec<f64> = (0..4000).map(|k| k as f64 * 0.005).collect();
        let gyro = GyroSeries {
            w_rad_s: gyro_t
                .iter()
                .map(|&t| r_imu_cam * w_cam(t - true_shift_s) + bias)
                .collect(),
            t_s: gyro_t,
        };
        let rates = camera_rates(&poses, 0, 0.06);
        let est = estimate_time_offset(&rates, &gyro, 0.05).expect("overlapping");
        assert!(
            (est.timeshift_cam_imu_s - true_shift_s).abs() < 2e-4,
            "{}",
            est.timeshift_cam_imu_s
        );
        let angle = so3::log(&(est.hand_eye.R_imu_cam.transpose() * r_imu_cam)).norm();
        assert!(angle < 1e-3, "rotation error {angle} rad");
        assert!((est.hand_eye.gyro_bias_rad_s - bias).norm() < 1e-3);
    }
}
