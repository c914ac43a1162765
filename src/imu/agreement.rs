//! How far an IMU log disagrees with the ground truth of the motion it
//! measured: the accelerometer noise density an estimator should assume
//! for it, measured instead of copied from a datasheet.
//!
//! Over consecutive windows of `window_s` the ground truth's velocity
//! change is compared with the integral of the bias-corrected specific
//! force, rotated by the ground-truth attitude (trapezoid rule):
//!
//! `e = (v_j - v_i - g T) - sum_k R_k (a_k - b_a,k) dt_k`
//!
//! For white accelerometer noise of density `sigma_c` (m/s^2/sqrt(Hz)),
//! `e` is a velocity random walk with standard deviation `sigma_c sqrt(T)`
//! per axis, so `sigma_c = rms(e) / sqrt(T)`. Anything else the log does
//! not share with the ground truth (vibration, scale and misalignment,
//! bias drift the ground truth does not follow, the ground truth's own
//! attitude error times gravity) counts too: what matters to an estimator
//! fusing this log with images rendered from that ground truth.
//!
//! On the real V1_02 ADIS16448 against its ground truth the result is
//! 0.020 m/s^2/sqrt(Hz) over 0.25 s windows and 0.032 over 1 s, ten to
//! fifteen times the datasheet's 0.002 (EuRoC's `sensor.yaml`): the error
//! is not white, its mean over a window falls slower than `1/sqrt(T)`
//! (0.042 m/s^2 RMS over 0.25 s, 0.032 over 1 s, 0.020 over 4 s). Over
//! short windows the ground truth's own velocity noise (~4 mm/s) adds a
//! little (about 0.006 m/s^2/sqrt(Hz) at 0.25 s, in quadrature).

use crate::sensors::ImuSample;
use nalgebra::{UnitQuaternion, Vector3};

use super::strapdown::gravity_world_m_s2;
use crate::dataset::GroundTruthState;

/// The disagreement of an IMU log with a ground truth over windows of
/// one length.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AccelAgreement {
    pub window_s: f64,
    /// Windows compared (each wholly inside the ground truth).
    pub windows: usize,
    /// RMS of the velocity error `e` per world axis, m/s.
    pub rms_velocity_error_m_s: Vector3<f64>,
    /// `rms(e) / sqrt(T)` over the three axes: the white-noise density
    /// that would explain the error, m/s^2/sqrt(Hz).
    pub noise_density_m_s2_sqrt_hz: f64,
}

/// The ground truth at `t_ns` (linear in position, velocity and biases,
/// slerp in attitude), `None` outside its span. `hint` is where the last
/// look-up ended, so a sweep in time order costs O(1) per call.
fn groundtruth_at(
    gt: &[GroundTruthState],
    t_ns: i64,
    hint: &mut usize,
) -> Option<(UnitQuaternion<f64>, Vector3<f64>, Vector3<f64>)> {
    if gt.is_empty() || t_ns < gt[0].t_ns || t_ns > gt[gt.len() - 1].t_ns {
        return None;
    }
    while *hint + 1 < gt.len() && gt[*hint + 1].t_ns <= t_ns {
        *hint += 1;
    }
    while *hint > 0 && gt[*hint].t_ns > t_ns {
        *hint -= 1;
    }
    let a = &gt[*hint];
    let Some(b) = gt.get(*hint + 1) else {
        return Some((a.T_world_body.rotation, a.velocity_m_s, a.accel_bias_m_s2));
    };
    let span = (b.t_ns - a.t_ns) as f64;
    let s = if span > 0.0 {
        (t_ns - a.t_ns) as f64 / span
    } else {
        0.0
    };
    let q = a.T_world_body.rotation.slerp(&b.T_world_body.rotation, s);
    let v = a.velocity_m_s.lerp(&b.velocity_m_s, s);
    let ba = a.accel_bias_m_s2.lerp(&b.accel_bias_m_s2, s);
    Some((q, v, ba))
}

/// Compares `samples` (time-ordered) with `gt` (time-ordered, with
/// velocities and accelerometer biases) over consecutive windows of
/// `window_s` seconds. `None` when no whole window fits.
pub fn accel_agreement(
    gt: &[GroundTruthState],
    samples: &[ImuSample],
    window_s: f64,
) -> Option<AccelAgreement> {
    if !(window_s.is_finite() && window_s > 0.0) {
        return None;
    }
    // World-frame bias-corrected specific force and velocity at each
    // sample inside the ground truth's span.
    let mut hint = 0;
    let inside: Vec<(i64, Vector3<f64>, Vector3<f64>)> = samples
        .iter()
        .filter_map(|s| {
            let (q, v, ba) = groundtruth_at(gt, s.t_ns, &mut hint)?;
            let f = q * (Vector3::from(s.accel_m_s2) - ba);
            Some((s.t_ns, f, v))
        })
        .collect();
    let g = gravity_world_m_s2();
    let window_ns = (window_s * 1e9).round() as i64;
    // A step longer than three typical ones is a gap in the log: no
    // window spans it.
    let mut steps: Vec<i64> = inside.windows(2).map(|w| w[1].0 - w[0].0).collect();
    if steps.is_empty() {
        return None;
    }
    let middle = steps.len() / 2;
    let median_step_ns = *steps.select_nth_unstable(middle).1;
    let max_step_ns = 3 * median_step_ns;
    let mut sum_sq = Vector3::zeros();
    let mut windows = 0usize;
    let mut i = 0;
    while i < inside.len() {
        let end_ns = inside[i].0 + window_ns;
        let mut integral = Vector3::zeros();
        let mut j = i;
        while j + 1 < inside.len()
            && inside[j + 1].0 <= end_ns
            && inside[j + 1].0 - inside[j].0 <= max_step_ns
        {
            let dt = (inside[j + 1].0 - inside[j].0) as f64 * 1e-9;
            integral += (inside[j].1 + inside[j + 1].1) * (0.5 * dt);
            j += 1;
        }
        // A whole window only: its last sample within half a step of the
        // end. A gap ends it early; the next window starts after the gap.
        if inside[j].0 < end_ns - median_step_ns / 2 {
            if j + 1 >= inside.len() {
                break;
            }
            i = j + 1;
            continue;
        }
        let t_s = (inside[j].0 - inside[i].0) as f64 * 1e-9;
        let e = inside[j].2 - inside[i].2 - g * t_s - integral;
        sum_sq += e.component_mul(&e);
        windows += 1;
        i = j;
    }
    if windows == 0 {
        return None;
    }
    let mean_sq = sum_sq / windows as f64;
    Some(AccelAgreement {
        window_s,
        windows,
        rms_velocity_error_m_s: mean_sq.map(f64::sqrt),
        noise_density_m_s2_sqrt_hz: (mean_sq.sum() / 3.0).sqrt() / window_s.sqrt(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Isometry3, Translation3};
    use rand::SeedableRng;
    use rand_distr::{Distribution, Normal};

    /// A body flying a horizontal circle (radius 1.5 m, 0.8 rad/s) while
    /// yawing with it and rolling slowly: ground truth and ideal samples
    /// at 200 Hz, with a constant accelerometer bias both share.
    fn circle(seconds: f64) -> (Vec<GroundTruthState>, Vec<ImuSample>) {
        let (r, w, roll_rate) = (1.5, 0.8, 0.3);
        let bias = Vector3::new(0.05, -0.1, 0.2);
        let mut gt = Vec::new();
        let mut imu = Vec::new();
        let n = (seconds * 200.0) as i64;
        for k in 0..=n {
            let t_ns = 1_000_000_000 + k * 5_000_000;
            let t = k as f64 * 0.005;
            let p = Vector3::new(r * (w * t).cos(), r * (w * t).sin(), 1.0);
            let v = Vector3::new(-r * w * (w * t).sin(), r * w * (w * t).cos(), 0.0);
            let a = Vector3::new(-r * w * w * (w * t).cos(), -r * w * w * (w * t).sin(), 0.0);
            let q = UnitQuaternion::from_euler_angles(0.2 * (roll_rate * t).sin(), 0.1, w * t);
            let specific = q.inverse() * (a - gravity_world_m_s2()) + bias;
            gt.push(GroundTruthState {
                t_ns,
                T_world_body: Isometry3::from_parts(Translation3::from(p), q),
                velocity_m_s: v,
                gyro_bias_rad_s: Vector3::zeros(),
                accel_bias_m_s2: bias,
            });
            imu.push(ImuSample {
                t_ns,
                gyro_rad_s: [0.0; 3],
                accel_m_s2: specific.into(),
            });
        }
        (gt, imu)
    }

    #[test]
    fn ideal_samples_agree_with_their_ground_truth() {
        let (gt, imu) = circle(60.0);
        let a = accel_agreement(&gt, &imu, 1.0).expect("windows");
        assert!(a.windows >= 59, "{}", a.windows);
        // Trapezoid error only: a wrong sign of gravity, a rotation the
        // wrong way or a bias left in would be metres per second.
        assert!(a.noise_density_m_s2_sqrt_hz < 1e-4, "{a:?}");
    }

    #[test]
    fn white_noise_density_is_recovered() {
        let (gt, mut imu) = circle(400.0);
        let density = 0.02;
        let sigma = density / 0.005f64.sqrt();
        let normal = Normal::new(0.0, sigma).expect("sigma > 0");
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        for s in &mut imu {
            for c in &mut s.accel_m_s2 {
                *c += normal.sample(&mut rng);
            }
        }
        let a = accel_agreement(&gt, &imu, 1.0).expect("windows");
        // 400 windows x 3 axes: the RMS is within about 3 % (1 sigma).
        let ratio = a.noise_density_m_s2_sqrt_hz / density;
        assert!((ratio - 1.0).abs() < 0.1, "{a:?}");
        // A longer window sees the same density for white noise.
        let b = accel_agreement(&gt, &imu, 4.0).expect("windows");
        assert!(
            (b.noise_density_m_s2_sqrt_hz / density - 1.0).abs() < 0.2,
            "{b:?}"
        );
    }

    #[test]
    fn a_gap_in_the_log_skips_its_window() {
        let (gt, imu) = circle(20.0);
        let with_gap: Vec<ImuSample> = imu
            .iter()
            .filter(|s| !(3_000_000_000..3_500_000_000).contains(&s.t_ns))
            .copied()
            .collect();
        let full = accel_agreement(&gt, &imu, 1.0).expect("windows");
        let gapped = accel_agreement(&gt, &with_gap, 1.0).expect("windows");
        assert!(
            gapped.windows < full.windows,
            "{} vs {}",
            gapped.windows,
            full.windows
        );
        assert!(gapped.noise_density_m_s2_sqrt_hz < 1e-4, "{gapped:?}");
    }

    #[test]
    fn real_v1_02_accelerometer_is_far_noisier_than_its_datasheet() {
        use crate::dataset::{read_euroc_groundtruth, read_euroc_imu_csv};
        let Some(dir) = crate::shared_data::path_or_skip("euroc/ground_truth") else {
            return;
        };
        let gt = read_euroc_groundtruth(&dir.join("V1_02_groundtruth.csv")).expect("gt");
        let imu = read_euroc_imu_csv(&dir.join("V1_02_imu0.csv"))
            .expect("imu")
            .samples;
        let short = accel_agreement(&gt, &imu, 0.25).expect("windows");
        let long = accel_agreement(&gt, &imu, 1.0).expect("windows");
        assert!(long.windows > 70, "{long:?}");
        // EuRoC's sensor.yaml says 0.002; the flight shows 0.02-0.03,
        // more over longer windows (not white noise).
        assert!(
            (0.015..0.025).contains(&short.noise_density_m_s2_sqrt_hz),
            "{short:?}"
        );
        assert!(
            (0.025..0.04).contains(&long.noise_density_m_s2_sqrt_hz),
            "{long:?}"
        );
    }
}
