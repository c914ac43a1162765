//! Reading noise parameters off an Allan deviation curve (IEEE Std
//! 952-1997, annex C; El-Sheimy et al., "Analysis and modeling of inertial
//! sensors using Allan variance", IEEE TIM 57(1), 2008):
//! - white noise (angle/velocity random walk): slope -1/2, `adev = N / sqrt(tau)`,
//!   read at tau = 1 s; `N` is Kalibr's noise density (unit/s/sqrt(Hz)).
//! - bias random walk (rate random walk): slope +1/2, `adev = K sqrt(tau / 3)`,
//!   read at tau = 3 s; `K` is Kalibr's random walk (unit/s^2/sqrt(Hz)).
//! - bias instability: the flat floor, `B = min adev / 0.664`.
//!
//! Each line is fitted (fixed slope, geometric mean of the intercepts
//! weighted by the number of independent clusters, `T / tau`) over the
//! points whose local log-log slope is within 0.1 of its slope,
//! on its side of the minimum; then each fit is repeated with the other
//! term subtracted in variance (`adev^2 = N^2/tau + K^2 tau/3` where the
//! two meet), which removes the bias of reading a line in the bend.

use crate::allan::AllanCurve;

/// `sqrt(2 ln 2 / pi)`: the floor of a flicker bias over its instability.
pub const BIAS_INSTABILITY_FACTOR: f64 = 0.664;
const SLOPE_TOLERANCE: f64 = 0.1;

/// One axis's noise, in the units of the signal (rad/s or m/s^2).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AxisNoise {
    /// N: unit/s^0 per sqrt(Hz) (e.g. rad/s/sqrt(Hz)).
    pub white_noise_density: f64,
    /// K: unit/s per sqrt(Hz) (e.g. rad/s^2/sqrt(Hz)).
    pub random_walk: f64,
    /// B: unit (e.g. rad/s).
    pub bias_instability: f64,
    /// Cluster time of the floor, s.
    pub tau_floor_s: f64,
    /// Points on the slope -1/2 line (0: the nearest point was used).
    pub white_points: usize,
    /// Points on the slope +1/2 line (0: not reached; `random_walk` is
    /// then an upper bound from the longest cluster time).
    pub walk_points: usize,
}

fn local_slopes(curve: &AllanCurve) -> Vec<f64> {
    let n = curve.tau_s.len();
    let lt: Vec<f64> = curve.tau_s.iter().map(|t| t.ln()).collect();
    let ls: Vec<f64> = curve.adev.iter().map(|s| s.ln()).collect();
    (0..n)
        .map(|i| {
            let a = i.saturating_sub(1);
            let b = (i + 1).min(n - 1);
            if a == b {
                0.0
            } else {
                (ls[b] - ls[a]) / (lt[b] - lt[a])
            }
        })
        .collect()
}

/// Weighted geometric mean of `(value, weight)`, skipping non-positive values.
fn geometric_mean(values: impl Iterator<Item = (f64, f64)>) -> Option<f64> {
    let (sum, weight) = values
        .filter(|(v, _)| *v > 0.0 && v.is_finite())
        .fold((0.0, 0.0), |(s, w), (v, wv)| (s + wv * v.ln(), w + wv));
    (weight > 0.0).then(|| (sum / weight).exp())
}

/// Fits N, K and B to one curve (at least 3 points).
pub fn fit_axis(curve: &AllanCurve) -> AxisNoise {
    let n = curve.tau_s.len();
    let slopes = local_slopes(curve);
    let floor = (0..n)
        .min_by(|&a, &b| curve.adev[a].total_cmp(&curve.adev[b]))
        .expect("a curve has points");
    let mut white: Vec<usize> = (0..=floor)
        .filter(|&i| (slopes[i] + 0.5).abs() <= SLOPE_TOLERANCE)
        .collect();
    let white_points = white.len();
    if white.is_empty() {
        white.push(
            (0..=floor)
                .min_by(|&a, &b| (slopes[a] + 0.5).abs().total_cmp(&(slopes[b] + 0.5).abs()))
                .expect("floor >= 0"),
        );
    }
    let walk: Vec<usize> = (floor..n)
        .filter(|&i| (slopes[i] - 0.5).abs() <= SLOPE_TOLERANCE)
        .collect();
    let (t, s) = (&curve.tau_s, &curve.adev);
    // The relative error of an Allan variance falls as 1 / sqrt(clusters):
    // weight each point by its number of independent clusters, T / tau.
    let t_end = t[n - 1] * 4.0;
    let weight = |i: usize| t_end / t[i];
    // N^2 tau = adev^2 - K^2 tau / 3 on the white side; K^2 tau / 3 = adev^2 - N^2 / tau on the walk side.
    let fit_white = |k: f64| {
        geometric_mean(white.iter().map(|&i| {
            (
                ((s[i] * s[i] - k * k * t[i] / 3.0) * t[i]).sqrt(),
                weight(i),
            )
        }))
        .unwrap_or(s[white[0]] * t[white[0]].sqrt())
    };
    let fit_walk = |nd: f64| {
        geometric_mean(walk.iter().map(|&i| {
            (
                (3.0 * (s[i] * s[i] - nd * nd / t[i]) / t[i]).sqrt(),
                weight(i),
            )
        }))
    };
    let mut white_density = fit_white(0.0);
    let mut random_walk = fit_walk(0.0);
    for _ in 0..3 {
        white_density = fit_white(random_walk.unwrap_or(0.0));
        random_walk = fit_walk(white_density).or(random_walk);
    }
    let random_walk = random_walk.unwrap_or_else(|| s[n - 1] * (3.0 / t[n - 1]).sqrt());
    AxisNoise {
        white_noise_density: white_density,
        random_walk,
        bias_instability: s[floor] / BIAS_INSTABILITY_FACTOR,
        tau_floor_s: t[floor],
        white_points,
        walk_points: walk.len(),
    }
}

/// The fitted white-noise line at `tau_s`.
pub fn white_line(noise: &AxisNoise, tau_s: f64) -> f64 {
    noise.white_noise_density / tau_s.sqrt()
}

/// The fitted random-walk line at `tau_s`.
pub fn walk_line(noise: &AxisNoise, tau_s: f64) -> f64 {
    noise.random_walk * (tau_s / 3.0).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::allan::cluster_sizes;

    #[test]
    fn reads_both_lines_off_an_analytic_curve() {
        // adev^2 = N^2 / tau + K^2 tau / 3 exactly, N = 2e-3, K = 4e-5.
        let (nd, k) = (2e-3, 4e-5);
        let tau_s: Vec<f64> = cluster_sizes(4_000_000, 10)
            .iter()
            .map(|&m| m as f64 / 100.0)
            .collect();
        let adev = tau_s
            .iter()
            .map(|&t| (nd * nd / t + k * k * t / 3.0).sqrt())
            .collect();
        let fit = fit_axis(&AllanCurve { tau_s, adev });
        assert!((fit.white_noise_density / nd - 1.0).abs() < 1e-3, "{fit:?}");
        assert!((fit.random_walk / k - 1.0).abs() < 1e-3, "{fit:?}");
        assert!(fit.white_points > 5 && fit.walk_points > 5, "{fit:?}");
        // The floor of this curve is at tau = sqrt(3) N / K with adev = sqrt(2 N K / sqrt 3).
        let floor = (2.0 * nd * k / 3f64.sqrt()).sqrt();
        assert!((fit.bias_instability * BIAS_INSTABILITY_FACTOR / floor - 1.0).abs() < 0.01);
    }

    #[test]
    fn a_short_log_bounds_the_walk_from_above() {
        let (nd, k) = (2e-3, 4e-5);
        let tau_s: Vec<f64> = (0..20).map(|i| 0.01 * 1.5f64.powi(i)).collect();
        let adev = tau_s
            .iter()
            .map(|&t| (nd * nd / t + k * k * t / 3.0).sqrt())
            .collect();
        let fit = fit_axis(&AllanCurve { tau_s, adev });
        assert_eq!(fit.walk_points, 0);
        assert!(fit.random_walk > k);
    }
}
