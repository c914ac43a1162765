//! Consistency checks of an estimator: chi-square bounds for the average
//! normalised estimation error squared (NEES) over Monte-Carlo runs
//! (Bar-Shalom, Li, Kirubarajan, "Estimation with Applications to Tracking
//! and Navigation", sec. 5.4.2).

/// Quantile of the chi-square distribution with `dof` degrees of freedom
/// at the standard-normal quantile `z` (Wilson-Hilferty cube-root
/// approximation; relative error below 1e-3 for `dof >= 30`).
pub fn chi_square_quantile(dof: usize, z: f64) -> f64 {
    let k = dof as f64;
    let a = 2.0 / (9.0 * k);
    k * (1.0 - a + z * a.sqrt()).powi(3)
}

/// Two-sided 95% bounds of the average NEES of `runs` independent runs of
/// a `dim`-dimensional state: `runs * ANEES ~ chi2(dim * runs)`.
pub fn anees_bounds_95(dim: usize, runs: usize) -> (f64, f64) {
    const Z_975: f64 = 1.959_963_984_540_054;
    let dof = dim * runs;
    (
        chi_square_quantile(dof, -Z_975) / runs as f64,
        chi_square_quantile(dof, Z_975) / runs as f64,
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quantiles_match_published_tables() {
        // NIST/SEMATECH e-Handbook, table 1.3.6.7.4 (upper critical values
        // of the chi-square distribution): chi2(100) at 0.975 = 129.561,
        // at 0.025 = 74.222; chi2(50) at 0.975 = 71.420, at 0.025 = 32.357.
        for (dof, z, expected) in [
            (100, 1.959964, 129.561),
            (100, -1.959964, 74.222),
            (50, 1.959964, 71.420),
            (50, -1.959964, 32.357),
        ] {
            let q = chi_square_quantile(dof, z);
            assert!((q - expected).abs() < 2e-3 * expected, "{dof} {z}: {q}");
        }
    }
}
