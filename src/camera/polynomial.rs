//! Real roots of the small polynomials that bound where a distortion model
//! is invertible (the derivative of the radial map, see
//! [`super::PinholeRadtan::max_valid_radius`]).
//!
//! Roots are isolated by recursion on the derivative: between two
//! consecutive real roots of `p'` the polynomial `p` is monotone, so each
//! such interval holds at most one root of `p`, found by bisection to the
//! last bit. This is exact up to rounding for any degree, needs no complex
//! arithmetic and has no convergence failure modes.

/// Bisection steps: enough to reach adjacent floating-point numbers on any
/// interval the callers use (width below 2^60 times the answer).
const BISECTION_STEPS: usize = 200;

/// Value of `sum_i coeffs[i] * t^i` (Horner).
pub(crate) fn evaluate(coeffs: &[f64], t: f64) -> f64 {
    coeffs.iter().rev().fold(0.0, |acc, &c| acc * t + c)
}

/// Coefficients of the derivative, lowest degree first.
fn derivative(coeffs: &[f64]) -> Vec<f64> {
    coeffs
        .iter()
        .enumerate()
        .skip(1)
        .map(|(i, &c)| i as f64 * c)
        .collect()
}

/// Coefficients without trailing (highest-degree) zeros.
fn trimmed(coeffs: &[f64]) -> &[f64] {
    let len = coeffs.iter().rposition(|&c| c != 0.0).map_or(0, |i| i + 1);
    &coeffs[..len]
}

/// Cauchy's bound: every real root of the polynomial has magnitude below
/// `1 + max_i |c_i / c_n|`. `None` for a constant polynomial.
pub(crate) fn root_magnitude_bound(coeffs: &[f64]) -> Option<f64> {
    let p = trimmed(coeffs);
    let (&lead, rest) = p.split_last()?;
    if rest.is_empty() {
        return None;
    }
    Some(1.0 + rest.iter().map(|c| (c / lead).abs()).fold(0.0, f64::max))
}

/// Sorted real roots of the polynomial in the closed interval `[lo, hi]`.
/// A polynomial that is identically zero is reported as having none.
pub(crate) fn roots_in(coeffs: &[f64], lo: f64, hi: f64) -> Vec<f64> {
    let p = trimmed(coeffs);
    if p.len() <= 1 || lo.is_nan() || hi.is_nan() || lo > hi {
        return Vec::new();
    }
    // Breakpoints: the interval ends and the stationary points inside.
    let mut breakpoints = vec![lo];
    breakpoints.extend(
        roots_in(&derivative(p), lo, hi)
            .into_iter()
            .filter(|&t| t > lo && t < hi),
    );
    breakpoints.push(hi);

    let mut roots: Vec<f64> = Vec::new();
    let push = |t: f64, roots: &mut Vec<f64>| {
        if roots.last() != Some(&t) {
            roots.push(t);
        }
    };
    for pair in breakpoints.windows(2) {
        let (a, b) = (pair[0], pair[1]);
        let (pa, pb) = (evaluate(p, a), evaluate(p, b));
        if pa == 0.0 {
            push(a, &mut roots);
        }
        if pa != 0.0 && pb != 0.0 && (pa < 0.0) != (pb < 0.0) {
            push(bisect(p, a, b, pa), &mut roots);
        }
        if pb == 0.0 {
            push(b, &mut roots);
        }
    }
    roots
}

/// Root of a polynomial monotone on `[a, b]` with a sign change there.
fn bisect(p: &[f64], mut a: f64, mut b: f64, pa: f64) -> f64 {
    let a_negative = pa < 0.0;
    for _ in 0..BISECTION_STEPS {
        let mid = 0.5 * (a + b);
        if mid <= a || mid >= b {
            break;
        }
        if (evaluate(p, mid) < 0.0) == a_negative {
            a = mid;
        } else {
            b = mid;
        }
    }
    0.5 * (a + b)
}

/// Smallest root in `(0, hi]` of a polynomial, or `None` if it has none
/// there.
pub(crate) fn smallest_positive_root(coeffs: &[f64], hi: f64) -> Option<f64> {
    roots_in(coeffs, 0.0, hi).into_iter().find(|&t| t > 0.0)
}

/// Iterations of [`solve_increasing`]; Newton converges in a handful, the
/// bisection fallback needs at most ~60 on a bracket of width 1.
const SOLVE_MAX_ITERATIONS: usize = 200;

/// `t` in `[lo, hi]` with `p(t) = value`, for a polynomial increasing on
/// `[lo, hi]` with `p(lo) <= value <= p(hi)`: Newton's method, falling back
/// to bisection whenever a step would leave the current bracket, so it
/// cannot diverge.
pub(crate) fn solve_increasing(coeffs: &[f64], value: f64, mut lo: f64, mut hi: f64) -> f64 {
    let slope_coeffs = derivative(coeffs);
    let tolerance = 4.0 * f64::EPSILON * value.abs().max(f64::MIN_POSITIVE);
    let mut t = lo + 0.5 * (hi - lo);
    for _ in 0..SOLVE_MAX_ITERATIONS {
        let residual = evaluate(coeffs, t) - value;
        if residual.abs() <= tolerance {
            break;
        }
        if residual < 0.0 {
            lo = t;
        } else {
            hi = t;
        }
        if hi - lo <= f64::EPSILON * hi.abs() {
            break;
        }
        let slope = evaluate(&slope_coeffs, t);
        let newton = t - residual / slope;
        t = if slope > 0.0 && newton > lo && newton < hi {
            newton
        } else {
            lo + 0.5 * (hi - lo)
        };
    }
    t
}

#[cfg(test)]
mod tests {
    use super::*;

    /// (t - 1)(t - 2)(t - 5) = t^3 - 8 t^2 + 17 t - 10.
    const CUBIC: [f64; 4] = [-10.0, 17.0, -8.0, 1.0];

    #[test]
    fn finds_every_root_of_a_cubic_with_known_roots() {
        let roots = roots_in(&CUBIC, -100.0, 100.0);
        assert_eq!(roots.len(), 3, "{roots:?}");
        for (found, expected) in roots.iter().zip([1.0, 2.0, 5.0]) {
            assert!((found - expected).abs() < 1e-13, "{found} vs {expected}");
        }
    }

    #[test]
    fn restricts_to_the_interval_and_reports_the_smallest_positive() {
        assert_eq!(roots_in(&CUBIC, 1.5, 4.0).len(), 1);
        let first = smallest_positive_root(&CUBIC, 10.0).expect("roots exist");
        assert!((first - 1.0).abs() < 1e-13);
        assert_eq!(smallest_positive_root(&CUBIC, 0.5), None);
    }

    #[test]
    fn polynomial_without_real_roots_has_none() {
        // t^2 + 1
        assert!(roots_in(&[1.0, 0.0, 1.0], -1e6, 1e6).is_empty());
        // constant and all-zero polynomials
        assert!(roots_in(&[3.0], -1.0, 1.0).is_empty());
        assert!(roots_in(&[0.0, 0.0], -1.0, 1.0).is_empty());
    }

    #[test]
    fn double_root_is_found_once() {
        // (t - 3)^2 = t^2 - 6 t + 9: touches zero at a stationary point.
        let roots = roots_in(&[9.0, -6.0, 1.0], 0.0, 10.0);
        assert_eq!(roots.len(), 1, "{roots:?}");
        assert!((roots[0] - 3.0).abs() < 1e-7);
    }

    #[test]
    fn solves_an_increasing_polynomial_to_machine_precision() {
        // t + t^3 is increasing everywhere; t = 1.3 gives 3.497.
        let p = [0.0, 1.0, 0.0, 1.0];
        let value = evaluate(&p, 1.3);
        let t = solve_increasing(&p, value, 0.0, 10.0);
        assert!((t - 1.3).abs() < 1e-14, "{t}");
        // Bracket ends are reachable.
        assert!(solve_increasing(&p, 0.0, 0.0, 10.0).abs() < 1e-14);
    }

    #[test]
    fn cauchy_bound_contains_the_roots() {
        let bound = root_magnitude_bound(&CUBIC).expect("cubic is not constant");
        assert!(bound > 5.0, "{bound}");
        // Highest-degree zeros are ignored: 2 t - 4 has its root at 2.
        let bound = root_magnitude_bound(&[-4.0, 2.0, 0.0]).expect("linear");
        assert!(bound > 2.0);
        assert_eq!(root_magnitude_bound(&[1.0, 0.0]), None);
    }
}
