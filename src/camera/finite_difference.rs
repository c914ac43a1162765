//! Central finite differences, the independent reference every analytic
//! camera Jacobian is tested against.

use nalgebra::{SMatrix, SVector};

/// `d f / d x` by central differences with step `relative_step *
/// max(|x_i|, 1)` per coordinate (truncation error O(h^2)).
pub fn central_difference<const N: usize, const M: usize>(
    f: impl Fn(&SVector<f64, N>) -> SVector<f64, M>,
    x: &SVector<f64, N>,
    relative_step: f64,
) -> SMatrix<f64, M, N> {
    let mut jacobian = SMatrix::<f64, M, N>::zeros();
    for i in 0..N {
        let h = relative_step * x[i].abs().max(1.0);
        let mut plus = *x;
        let mut minus = *x;
        plus[i] += h;
        minus[i] -= h;
        jacobian.set_column(i, &((f(&plus) - f(&minus)) / (2.0 * h)));
    }
    jacobian
}

/// Largest entry-wise error of `analytic` against `numeric`, relative to
/// `max(|numeric_ij|, floor)`: a relative error for entries above `floor`,
/// an absolute error (divided by `floor`) below it, where finite
/// differences only resolve absolute values.
pub fn max_relative_error<const M: usize, const N: usize>(
    analytic: &SMatrix<f64, M, N>,
    numeric: &SMatrix<f64, M, N>,
    floor: f64,
) -> f64 {
    analytic
        .iter()
        .zip(numeric.iter())
        .map(|(a, n)| (a - n).abs() / n.abs().max(floor))
        .fold(0.0, f64::max)
}
