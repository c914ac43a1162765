//! Finding the still parts of a calibration session: a sample is static
//! when the window of `window_s` around it has small accelerometer spread
//! and small angular rate (the usual variance detector, e.g. Tedaldi et
//! al., "A robust and easy to implement method for IMU calibration without
//! external equipments", ICRA 2014, sec. IV). Runs of static samples at
//! least `min_duration_s` long become [`StaticInterval`]s.

use nalgebra::Vector3;
use rigslam::sensors::ImuSample;

/// Thresholds of the detector (SI units).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StaticDetector {
    pub window_s: f64,
    /// Root of the summed per-axis accelerometer variance in the window.
    pub max_accel_std_m_s2: f64,
    /// Largest mean angular rate in the window (allows a raw gyro bias).
    pub max_gyro_rate_rad_s: f64,
    /// Root of the summed per-axis gyro variance in the window.
    pub max_gyro_std_rad_s: f64,
    pub min_duration_s: f64,
}

impl Default for StaticDetector {
    fn default() -> Self {
        Self {
            window_s: 0.5,
            max_accel_std_m_s2: 0.1,
            max_gyro_rate_rad_s: 0.1,
            max_gyro_std_rad_s: 0.05,
            min_duration_s: 1.0,
        }
    }
}

/// One still interval: samples `start..end` and their means (raw, SI).
#[derive(Debug, Clone, PartialEq)]
pub struct StaticInterval {
    pub start: usize,
    pub end: usize,
    pub accel_mean_m_s2: Vector3<f64>,
    pub gyro_mean_rad_s: Vector3<f64>,
    /// Root of the summed per-axis accelerometer variance over the interval.
    pub accel_std_m_s2: f64,
}

impl StaticInterval {
    pub fn len(&self) -> usize {
        self.end - self.start
    }

    pub fn is_empty(&self) -> bool {
        self.end == self.start
    }

    /// Summarises `samples[start..end]`.
    pub fn from_samples(samples: &[ImuSample], start: usize, end: usize) -> Self {
        let part = &samples[start..end];
        let n = part.len().max(1) as f64;
        let mut accel = Vector3::zeros();
        let mut gyro = Vector3::zeros();
        for s in part {
            accel += Vector3::from(s.accel_m_s2);
            gyro += Vector3::from(s.gyro_rad_s);
        }
        accel /= n;
        gyro /= n;
        let var: f64 = part
            .iter()
            .map(|s| (Vector3::from(s.accel_m_s2) - accel).norm_squared())
            .sum::<f64>()
            / n;
        Self {
            start,
            end,
            accel_mean_m_s2: accel,
            gyro_mean_rad_s: gyro,
            accel_std_m_s2: var.sqrt(),
        }
    }
}

/// Running sums of a 3-vector signal and its square, for O(1) window moments.
struct Prefix {
    sum: Vec<[f64; 3]>,
    sum_sq: Vec<[f64; 3]>,
}

impl Prefix {
    fn new(values: impl Iterator<Item = [f64; 3]>, len: usize) -> Self {
        let mut sum = Vec::with_capacity(len + 1);
        let mut sum_sq = Vec::with_capacity(len + 1);
        let (mut s, mut q) = ([0.0; 3], [0.0; 3]);
        sum.push(s);
        sum_sq.push(q);
        for v in values {
            for k in 0..3 {
                s[k] += v[k];
                q[k] += v[k] * v[k];
            }
            sum.push(s);
            sum_sq.push(q);
        }
        Self { sum, sum_sq }
    }

    /// (mean, summed variance) over `a..b`.
    fn moments(&self, a: usize, b: usize) -> (Vector3<f64>, f64) {
        let n = (b - a) as f64;
        let mut mean = Vector3::zeros();
        let mut var = 0.0;
        for k in 0..3 {
            let m = (self.sum[b][k] - self.sum[a][k]) / n;
            mean[k] = m;
            var += ((self.sum_sq[b][k] - self.sum_sq[a][k]) / n - m * m).max(0.0);
        }
        (mean, var)
    }
}

impl StaticDetector {
    /// Per sample: is the window centred on it still?
    pub fn static_mask(&self, samples: &[ImuSample], rate_hz: f64) -> Vec<bool> {
        let n = samples.len();
        let half = ((self.window_s * rate_hz / 2.0).round() as usize).max(1);
        if n < 2 * half + 1 {
            return vec![false; n];
        }
        // Centre the accelerometer on its first sample: the variance by
        // sums of squares then does not cancel catastrophically.
        let a0 = samples[0].accel_m_s2;
        let accel = Prefix::new(
            samples.iter().map(|s| {
                [
                    s.accel_m_s2[0] - a0[0],
                    s.accel_m_s2[1] - a0[1],
                    s.accel_m_s2[2] - a0[2],
                ]
            }),
            n,
        );
        let gyro = Prefix::new(samples.iter().map(|s| s.gyro_rad_s), n);
        (0..n)
            .map(|i| {
                if i < half || i + half >= n {
                    return false;
                }
                let (a, b) = (i - half, i + half + 1);
                let (_, accel_var) = accel.moments(a, b);
                let (gyro_mean, gyro_var) = gyro.moments(a, b);
                accel_var.sqrt() <= self.max_accel_std_m_s2
                    && gyro_var.sqrt() <= self.max_gyro_std_rad_s
                    && gyro_mean.norm() <= self.max_gyro_rate_rad_s
            })
            .collect()
    }

    /// The still intervals of at least `min_duration_s`, in time order.
    pub fn detect(&self, samples: &[ImuSample], rate_hz: f64) -> Vec<StaticInterval> {
        let mask = self.static_mask(samples, rate_hz);
        let min_len = (self.min_duration_s * rate_hz).ceil() as usize;
        let mut out = Vec::new();
        let mut i = 0;
        while i < mask.len() {
            if !mask[i] {
                i += 1;
                continue;
            }
            let start = i;
            while i < mask.len() && mask[i] {
                i += 1;
            }
            if i - start >= min_len.max(2) {
                out.push(StaticInterval::from_samples(samples, start, i));
            }
        }
        out
    }
}

/// Number of orientations among the intervals that differ by more than
/// `min_angle_deg` (greedy clustering of the gravity directions).
pub fn distinct_orientations(intervals: &[StaticInterval], min_angle_deg: f64) -> usize {
    let cos_min = min_angle_deg.to_radians().cos();
    let mut centres: Vec<Vector3<f64>> = Vec::new();
    for interval in intervals {
        let Some(dir) = interval.accel_mean_m_s2.try_normalize(1e-9) else {
            continue;
        };
        if centres.iter().all(|c| c.dot(&dir) < cos_min) {
            centres.push(dir);
        }
    }
    centres.len()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample(i: usize, gyro: [f64; 3], accel: [f64; 3]) -> ImuSample {
        ImuSample {
            t_ns: i as i64 * 10_000_000,
            gyro_rad_s: gyro,
            accel_m_s2: accel,
        }
    }

    #[test]
    fn finds_the_still_parts_between_rotations() {
        // 100 Hz: 3 s still on z, 2 s turning about x at 1.5 rad/s, 3 s still on y.
        let mut samples = Vec::new();
        for i in 0..300 {
            samples.push(sample(i, [0.01, 0.0, 0.0], [0.0, 0.0, 9.81]));
        }
        for i in 300..500 {
            let angle = 1.5 * (i - 300) as f64 * 0.01;
            samples.push(sample(
                i,
                [1.5, 0.0, 0.0],
                [0.0, 9.81 * angle.sin(), 9.81 * angle.cos()],
            ));
        }
        for i in 500..800 {
            samples.push(sample(i, [0.01, 0.0, 0.0], [0.0, 9.81, 0.0]));
        }
        let found = StaticDetector::default().detect(&samples, 100.0);
        assert_eq!(found.len(), 2, "{found:?}");
        // The window (0.5 s) keeps the edges 25 samples away from the motion.
        assert_eq!((found[0].start, found[0].end), (25, 275));
        assert_eq!((found[1].start, found[1].end), (525, 775));
        assert!((found[1].accel_mean_m_s2 - Vector3::new(0.0, 9.81, 0.0)).norm() < 1e-12);
        assert_eq!(distinct_orientations(&found, 10.0), 2);
        let same = vec![found[0].clone(), found[0].clone()];
        assert_eq!(distinct_orientations(&same, 10.0), 1);
    }

    #[test]
    fn a_shaking_log_has_no_static_interval() {
        let samples: Vec<ImuSample> = (0..1000)
            .map(|i| {
                sample(
                    i,
                    [0.0; 3],
                    [0.0, 0.0, 9.81 + if i % 2 == 0 { 0.5 } else { -0.5 }],
                )
            })
            .collect();
        assert!(StaticDetector::default().detect(&samples, 100.0).is_empty());
    }
}
