//! Overlapping Allan deviation (IEEE Std 952-1997, annex C; Riley, NIST
//! SP 1065, eq. 18) of a rate signal sampled at `rate_hz`, at log-spaced
//! cluster sizes. With `theta_k = sum_{i<k} y_i / rate` (N + 1 values)
//! and `tau = m / rate`,
//! `avar(tau) = sum_{k=0}^{N-2m} (theta_{k+2m} - 2 theta_{k+m} + theta_k)^2 / (2 tau^2 (N + 1 - 2m))`.

/// Cluster sizes `m_k = floor(10^(k / per_decade) + 1/2)`, k = 0, 1, ...,
/// up to `n / 4` samples, without repeats.
pub fn cluster_sizes(n: usize, per_decade: usize) -> Vec<usize> {
    let mut out: Vec<usize> = Vec::new();
    let per_decade = per_decade.max(1) as f64;
    for k in 0.. {
        let m = (10f64.powf(k as f64 / per_decade) + 0.5).floor() as usize;
        if m > n / 4 {
            break;
        }
        if out.last() != Some(&m) {
            out.push(m);
        }
    }
    out
}

/// One axis's Allan deviation curve.
#[derive(Debug, Clone, PartialEq)]
pub struct AllanCurve {
    pub tau_s: Vec<f64>,
    pub adev: Vec<f64>,
}

/// The overlapping Allan deviation of `y` at the cluster sizes `m`.
pub fn overlapping_adev(y: &[f64], rate_hz: f64, m: &[usize]) -> AllanCurve {
    let n = y.len();
    let mean = y.iter().sum::<f64>() / n.max(1) as f64;
    // Integrate the mean-free signal: the second differences ignore a
    // linear trend in theta, and smaller numbers keep precision.
    let mut theta = Vec::with_capacity(n + 1);
    let mut acc = 0.0;
    theta.push(0.0);
    for v in y {
        acc += (v - mean) / rate_hz;
        theta.push(acc);
    }
    let mut tau_s = Vec::with_capacity(m.len());
    let mut adev = Vec::with_capacity(m.len());
    for &mj in m {
        if mj == 0 || 2 * mj > n {
            continue;
        }
        let count = n + 1 - 2 * mj;
        let sum: f64 = theta[..count]
            .iter()
            .zip(&theta[mj..mj + count])
            .zip(&theta[2 * mj..2 * mj + count])
            .map(|((t0, t1), t2)| {
                let d = t2 - 2.0 * t1 + t0;
                d * d
            })
            .sum();
        let tau = mj as f64 / rate_hz;
        tau_s.push(tau);
        adev.push((sum / (2.0 * tau * tau * count as f64)).sqrt());
    }
    AllanCurve { tau_s, adev }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;
    use rand_distr::{Distribution, Normal};

    #[test]
    fn cluster_sizes_are_log_spaced_and_unique() {
        let m = cluster_sizes(1000, 10);
        assert_eq!(&m[..8], &[1, 2, 3, 4, 5, 6, 8, 10]);
        assert_eq!(*m.last().expect("non-empty"), 200);
        assert!(m.windows(2).all(|w| w[1] > w[0]));
    }

    #[test]
    fn matches_the_definition_on_a_tiny_series() {
        // y = 1, 3, 2, 6 at 1 Hz; m = 1: theta = 0,1,4,6,12 (mean-free
        // shifts theta by a line, which second differences ignore);
        // d = 4-2+0, 6-8+1, 12-12+4 = 2, -1, 4; avar = 21 / (2 * 3).
        let c = overlapping_adev(&[1.0, 3.0, 2.0, 6.0], 1.0, &[1, 2]);
        assert!((c.adev[0] - (21.0f64 / 6.0).sqrt()).abs() < 1e-12);
        // m = 2: d = 12 - 8 + 0 = 4; avar = 16 / (2 * 4 * 1).
        assert!((c.adev[1] - 2.0f64.sqrt()).abs() < 1e-12);
        assert_eq!(c.tau_s, vec![1.0, 2.0]);
    }

    #[test]
    fn white_noise_falls_as_one_over_root_tau() {
        // White rate noise of density q (per sqrt Hz): adev(tau) = q / sqrt(tau).
        let rate_hz: f64 = 100.0;
        let q = 0.01;
        let normal = Normal::new(0.0, q * rate_hz.sqrt()).expect("valid sigma");
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let y: Vec<f64> = (0..200_000).map(|_| normal.sample(&mut rng)).collect();
        let c = overlapping_adev(&y, rate_hz, &[1, 10, 100]);
        for (tau, adev) in c.tau_s.iter().zip(&c.adev) {
            let expected = q / tau.sqrt();
            assert!(
                (adev / expected - 1.0).abs() < 0.05,
                "tau {tau}: {adev} vs {expected}"
            );
        }
    }
}
