//! How far an IMU log disagrees with the ground truth of the motion it
//! measured: the accelerometer and gyroscope noise densities an estimator
//! should assume for it, measured instead of copied from a datasheet.
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
//!
//! The gyroscope the same way ([`gyro_agreement`]): its integrated
//! bias-corrected rate against the ground truth's change of attitude.
//! V1_02: 0.0007 rad/s/sqrt(Hz) over 0.25 s windows, four times the
//! datasheet's 0.00017; about 1 mrad/s of disagreement over 1 s, mostly
//! the ground truth's own attitude noise (a fitted misalignment of about
//! 2 mrad removes a quarter of its variance at most). Images rendered
//! along that ground truth carry the same attitude, so to an estimator
//! fusing them with this log the disagreement is gyroscope noise: weighted
//! by the datasheet, it is read as a gyroscope bias that wanders 1 mrad/s.

use crate::sensors::ImuSample;
use nalgebra::{UnitQuaternion, Vector3};

use super::strapdown::gravity_world_m_s2;
use crate::dataset::GroundTruthState;

/// The disagreement of an IMU log with a ground truth over windows of
/// one length.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AccelAgreement {
    /// Window length `T`, s.
    pub window_s: f64,
    /// Windows compared (each wholly inside the ground truth).
    pub windows: usize,
    /// RMS of the velocity error `e` per world axis, m/s.
    pub rms_velocity_error_m_s: Vector3<f64>,
    /// `rms(e) / sqrt(T)` over the three axes: the white-noise density
    /// that would explain the error, m/s^2/sqrt(Hz).
    pub noise_density_m_s2_sqrt_hz: f64,
}

/// The disagreement of a gyroscope log with a ground truth's attitude
/// over windows of one length.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GyroAgreement {
    /// Window length `T`, s.
    pub window_s: f64,
    /// Windows compared (each wholly inside the ground truth).
    pub windows: usize,
    /// RMS of the rotation error `e` per body axis, rad.
    pub rms_angle_error_rad: Vector3<f64>,
    /// `rms(e) / sqrt(T)` over the three axes: the white-noise density
    /// that would explain the error, rad/s/sqrt(Hz).
    pub noise_density_rad_s_sqrt_hz: f64,
}

/// The ground truth interpolated at one instant.
struct GroundTruthAt {
    attitude: UnitQuaternion<f64>,
    velocity_m_s: Vector3<f64>,
    gyro_bias_rad_s: Vector3<f64>,
    accel_bias_m_s2: Vector3<f64>,
}

/// The ground truth at `t_ns` (linear in position, velocity and biases,
/// slerp in attitude), `None` outside its span. `hint` is where the last
/// look-up ended, so a sweep in time order costs O(1) per call.
fn groundtruth_at(gt: &[GroundTruthState], t_ns: i64, hint: &mut usize) -> Option<GroundTruthAt> {
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
    let b = gt.get(*hint + 1).unwrap_or(a);
    let span = (b.t_ns - a.t_ns) as f64;
    let s = if span > 0.0 {
        (t_ns - a.t_ns) as f64 / span
    } else {
        0.0
    };
    Some(GroundTruthAt {
        attitude: a.T_world_body.rotation.slerp(&b.T_world_body.rotation, s),
        velocity_m_s: a.velocity_m_s.lerp(&b.velocity_m_s, s),
        gyro_bias_rad_s: a.gyro_bias_rad_s.lerp(&b.gyro_bias_rad_s, s),
        accel_bias_m_s2: a.accel_bias_m_s2.lerp(&b.accel_bias_m_s2, s),
    })
}

/// Consecutive whole windows of `window_s` over the stamps `t_ns`
/// (time-ordered): `(first, last)` sample indices, each window starting
/// where the previous one ended. A step longer than three typical ones is
/// a gap in the log: no window spans it. `None` when the window length is
/// not a positive number or there are fewer than two stamps.
fn whole_windows(t_ns: &[i64], window_s: f64) -> Option<Vec<(usize, usize)>> {
    if !(window_s.is_finite() && window_s > 0.0) {
        return None;
    }
    let mut steps: Vec<i64> = t_ns.windows(2).map(|w| w[1] - w[0]).collect();
    if steps.is_empty() {
        return None;
    }
    let middle = steps.len() / 2;
    let median_step_ns = *steps.select_nth_unstable(middle).1;
    let max_step_ns = 3 * median_step_ns;
    let window_ns = (window_s * 1e9).round() as i64;
    let mut out = Vec::new();
    let mut i = 0;
    while i < t_ns.len() {
        let end_ns = t_ns[i] + window_ns;
        let mut j = i;
        while j + 1 < t_ns.len() && t_ns[j + 1] <= end_ns && t_ns[j + 1] - t_ns[j] <= max_step_ns {
            j += 1;
        }
        // A whole window only: its last sample within half a step of the
        // end. A gap ends it early; the next window starts after the gap.
        if t_ns[j] < end_ns - median_step_ns / 2 {
            if j + 1 >= t_ns.len() {
                break;
            }
            i = j + 1;
            continue;
        }
        out.push((i, j));
        i = j;
    }
    Some(out)
}

/// The ground truth and `samples` (both time-ordered) compared over
/// consecutive whole windows of `window_s`: `at_sample` turns each sample
/// inside the ground truth's span into what the comparison needs,
/// `window_error` turns a window's run of them into a 3-vector error.
/// Returns the number of windows and the per-axis mean square error;
/// `None` when no whole window fits.
fn mean_square_error<T>(
    gt: &[GroundTruthState],
    samples: &[ImuSample],
    window_s: f64,
    at_sample: impl Fn(&ImuSample, GroundTruthAt) -> T,
    window_error: impl Fn(&[(i64, T)]) -> Vector3<f64>,
) -> Option<(usize, Vector3<f64>)> {
    let mut hint = 0;
    let inside: Vec<(i64, T)> = samples
        .iter()
        .filter_map(|s| Some((s.t_ns, at_sample(s, groundtruth_at(gt, s.t_ns, &mut hint)?))))
        .collect();
    let stamps: Vec<i64> = inside.iter().map(|s| s.0).collect();
    let windows = whole_windows(&stamps, window_s)?;
    if windows.is_empty() {
        return None;
    }
    let sum_sq: Vector3<f64> = windows
        .iter()
        .map(|&(i, j)| {
            let e = window_error(&inside[i..=j]);
            e.component_mul(&e)
        })
        .sum();
    Some((windows.len(), sum_sq / windows.len() as f64))
}

/// Seconds from `a` to `b`.
fn seconds(a: i64, b: i64) -> f64 {
    (b - a) as f64 * 1e-9
}

/// Compares `samples` (time-ordered) with `gt` (time-ordered, with
/// velocities and accelerometer biases) over consecutive windows of
/// `window_s` seconds. `None` when no whole window fits.
pub fn accel_agreement(
    gt: &[GroundTruthState],
    samples: &[ImuSample],
    window_s: f64,
) -> Option<AccelAgreement> {
    let g = gravity_world_m_s2();
    let (windows, mean_sq) = mean_square_error(
        gt,
        samples,
        window_s,
        // World-frame bias-corrected specific force, and the velocity.
        |s, at| {
            let f = at.attitude * (Vector3::from(s.accel_m_s2) - at.accel_bias_m_s2);
            (f, at.velocity_m_s)
        },
        |run| {
            let integral: Vector3<f64> = run
                .windows(2)
                .map(|w| (w[0].1 .0 + w[1].1 .0) * (0.5 * seconds(w[0].0, w[1].0)))
                .sum();
            let (first, last) = (&run[0], &run[run.len() - 1]);
            last.1 .1 - first.1 .1 - g * seconds(first.0, last.0) - integral
        },
    )?;
    Some(AccelAgreement {
        window_s,
        windows,
        rms_velocity_error_m_s: mean_sq.map(f64::sqrt),
        noise_density_m_s2_sqrt_hz: (mean_sq.sum() / 3.0).sqrt() / window_s.sqrt(),
    })
}

/// Compares the gyroscope of `samples` (time-ordered) with the attitude
/// of `gt` (with gyroscope biases) over consecutive windows of
/// `window_s`: the bias-corrected rates integrated over the window (mean
/// of neighbouring samples, exponential map) against the ground truth's
/// rotation over it, `e = Log((R_i^T R_j)^T prod Exp((w - b_g) dt))`.
/// For white gyroscope noise of density `sigma_c`, `e` has standard
/// deviation `sigma_c sqrt(T)` per axis. `None` when no whole window fits.
pub fn gyro_agreement(
    gt: &[GroundTruthState],
    samples: &[ImuSample],
    window_s: f64,
) -> Option<GyroAgreement> {
    let (windows, mean_sq) = mean_square_error(
        gt,
        samples,
        window_s,
        |s, at| {
            (
                Vector3::from(s.gyro_rad_s) - at.gyro_bias_rad_s,
                at.attitude,
            )
        },
        |run| {
            let integrated = run.windows(2).fold(UnitQuaternion::identity(), |q, w| {
                let dt = seconds(w[0].0, w[1].0);
                q * UnitQuaternion::from_scaled_axis((w[0].1 .0 + w[1].1 .0) * (0.5 * dt))
            });
            let truth = run[0].1 .1.inverse() * run[run.len() - 1].1 .1;
            (truth.inverse() * integrated).scaled_axis()
        },
    )?;
    Some(GyroAgreement {
        window_s,
        windows,
        rms_angle_error_rad: mean_sq.map(f64::sqrt),
        noise_density_rad_s_sqrt_hz: (mean_sq.sum() / 3.0).sqrt() / window_s.sqrt(),
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
    /// at 200 Hz, with constant biases both share.
    fn circle(seconds: f64) -> (Vec<GroundTruthState>, Vec<ImuSample>) {
        let (r, w, roll_rate) = (1.5, 0.8, 0.3);
        let bias = Vector3::new(0.05, -0.1, 0.2);
        let gyro_bias = Vector3::new(0.01, -0.02, 0.005);
        let attitude =
            |t: f64| UnitQuaternion::from_euler_angles(0.2 * (roll_rate * t).sin(), 0.1, w * t);
        let mut gt = Vec::new();
        let mut imu = Vec::new();
        let n = (seconds * 200.0) as i64;
        for k in 0..=n {
            let t_ns = 1_000_000_000 + k * 5_000_000;
            let t = k as f64 * 0.005;
            let p = Vector3::new(r * (w * t).cos(), r * (w * t).sin(), 1.0);
            let v = Vector3::new(-r * w * (w * t).sin(), r * w * (w * t).cos(), 0.0);
            let a = Vector3::new(-r * w * w * (w * t).cos(), -r * w * w * (w * t).sin(), 0.0);
            let q = attitude(t);
            let specific = q.inverse() * (a - gravity_world_m_s2()) + bias;
            // Body rate by a central difference of the attitude.
            let h = 1e-5;
            let rate = (attitude(t - h).inverse() * attitude(t + h)).scaled_axis() / (2.0 * h);
            gt.push(GroundTruthState {
                t_ns,
                T_world_body: Isometry3::from_parts(Translation3::from(p), q),
                velocity_m_s: v,
                gyro_bias_rad_s: gyro_bias,
                accel_bias_m_s2: bias,
            });
            imu.push(ImuSample {
                t_ns,
                gyro_rad_s: (rate + gyro_bias).into(),
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
    fn ideal_gyroscope_agrees_with_its_ground_truth() {
        let (gt, imu) = circle(60.0);
        let a = gyro_agreement(&gt, &imu, 1.0).expect("windows");
        assert!(a.windows >= 59, "{}", a.windows);
        // Integration error only: a bias left in would be 0.02 rad/s, a
        // rotation composed in the wrong order about 1e-3.
        assert!(a.noise_density_rad_s_sqrt_hz < 1e-5, "{a:?}");
    }

    #[test]
    fn gyroscope_white_noise_density_is_recovered() {
        let (gt, mut imu) = circle(400.0);
        let density = 0.001;
        let normal = Normal::new(0.0, density / 0.005f64.sqrt()).expect("sigma > 0");
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        for s in &mut imu {
            for c in &mut s.gyro_rad_s {
                *c += normal.sample(&mut rng);
            }
        }
        for window_s in [0.25, 1.0] {
            let a = gyro_agreement(&gt, &imu, window_s).expect("windows");
            let ratio = a.noise_density_rad_s_sqrt_hz / density;
            assert!((ratio - 1.0).abs() < 0.1, "{a:?}");
        }
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
    fn real_v1_02_imu_is_far_noisier_than_its_datasheet() {
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
        // The gyroscope: 0.00017 rad/s/sqrt(Hz) in EuRoC's sensor.yaml,
        // 0.0007 against the ground truth's attitude.
        let gyro = gyro_agreement(&gt, &imu, 0.25).expect("windows");
        assert!(gyro.windows > 100, "{gyro:?}");
        assert!(
            (0.0005..0.0009).contains(&gyro.noise_density_rad_s_sqrt_hz),
            "{gyro:?}"
        );
    }
}
