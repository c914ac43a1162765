//! Real roots of univariate polynomials of degree at most 10 by Sturm
//! sequences (isolation by bisection, then safeguarded Newton).
//!
//! The five-point solver needs the real roots of a degree-10 polynomial
//! (Nistér 2004, section 3.2.2, which also isolates them with Sturm
//! sequences), the P3P solver those of a quartic. Everything lives on the
//! stack: no allocation per call.

/// Largest degree handled.
pub const MAX_DEGREE: usize = 10;

/// Coefficients, lowest power first: `c[i]` multiplies `z^i`.
pub type Coefficients = [f64; MAX_DEGREE + 1];

/// At most [`MAX_DEGREE`] real roots, in increasing order.
#[derive(Debug, Clone, Copy)]
pub struct RealRoots {
    roots: [f64; MAX_DEGREE],
    len: usize,
}

impl RealRoots {
    /// The roots, in increasing order.
    pub fn as_slice(&self) -> &[f64] {
        &self.roots[..self.len]
    }

    fn push(&mut self, z: f64) {
        if self.len < MAX_DEGREE {
            self.roots[self.len] = z;
            self.len += 1;
        }
    }
}

/// `p(z)` by Horner's rule, `p` of degree `degree`.
pub fn evaluate(p: &[f64], degree: usize, z: f64) -> f64 {
    let mut acc = p[degree];
    for i in (0..degree).rev() {
        acc = acc * z + p[i];
    }
    acc
}

/// `(p(z), p'(z))` by Horner's rule.
fn evaluate_with_derivative(p: &[f64], degree: usize, z: f64) -> (f64, f64) {
    let mut value = p[degree];
    let mut derivative = 0.0;
    for i in (0..degree).rev() {
        derivative = derivative * z + value;
        value = value * z + p[i];
    }
    (value, derivative)
}

/// Degree of `p` once coefficients below `tolerance` times its largest are
/// treated as zero; `None` for the zero polynomial.
fn effective_degree(p: &[f64], degree: usize, tolerance: f64) -> Option<usize> {
    let scale = p[..=degree].iter().fold(0.0_f64, |m, c| m.max(c.abs()));
    if scale == 0.0 || !scale.is_finite() {
        return None;
    }
    (0..=degree).rev().find(|&i| p[i].abs() > tolerance * scale)
}

/// Sturm chain of a polynomial: `s0 = p`, `s1 = p'`,
/// `s_{k+1} = -rem(s_{k-1}, s_k)`.
struct SturmChain {
    polys: [Coefficients; MAX_DEGREE + 1],
    degrees: [usize; MAX_DEGREE + 1],
    len: usize,
}

impl SturmChain {
    fn new(p: &Coefficients, degree: usize) -> Self {
        let mut polys = [[0.0; MAX_DEGREE + 1]; MAX_DEGREE + 1];
        let mut degrees = [0; MAX_DEGREE + 1];
        polys[0] = *p;
        degrees[0] = degree;
        for i in 1..=degree {
            polys[1][i - 1] = i as f64 * p[i];
        }
        degrees[1] = degree - 1;
        let mut len = 2;
        while degrees[len - 1] > 0 && len <= MAX_DEGREE {
            let (num, num_deg) = (polys[len - 2], degrees[len - 2]);
            let (den, den_deg) = (polys[len - 1], degrees[len - 1]);
            let mut rem = num;
            // Long division: cancel the leading terms of `rem` down to
            // degree < den_deg.
            for k in (den_deg..=num_deg).rev() {
                let q = rem[k] / den[den_deg];
                for j in 0..=den_deg {
                    rem[k - den_deg + j] -= q * den[j];
                }
                rem[k] = 0.0;
            }
            let num_scale = num[..=num_deg].iter().fold(0.0_f64, |m, c| m.max(c.abs()));
            let rem_scale = rem[..den_deg].iter().fold(0.0_f64, |m, c| m.max(c.abs()));
            if rem_scale <= 1e-14 * num_scale {
                // Zero remainder: p has multiple roots; the chain ends at
                // their gcd, which still counts distinct roots correctly.
                break;
            }
            let rem_deg = effective_degree(&rem, den_deg - 1, 1e-14)
                .expect("the remainder was checked to be non-zero");
            for (dst, src) in polys[len].iter_mut().zip(rem.iter()) {
                *dst = -src;
            }
            degrees[len] = rem_deg;
            len += 1;
        }
        Self {
            polys,
            degrees,
            len,
        }
    }

    /// Sign changes along the chain at `z` (zeros skipped).
    fn sign_changes(&self, z: f64) -> u32 {
        let mut changes = 0;
        let mut last = 0.0;
        for k in 0..self.len {
            let v = evaluate(&self.polys[k], self.degrees[k], z);
            if v != 0.0 {
                if last != 0.0 && (v > 0.0) != (last > 0.0) {
                    changes += 1;
                }
                last = v;
            }
        }
        changes
    }
}

/// Distinct real roots of `p` (lowest power first; trailing entries past
/// the true degree may be zero). Returns an empty set for the zero or a
/// constant polynomial or non-finite coefficients.
pub fn real_roots(p: &Coefficients) -> RealRoots {
    let mut out = RealRoots {
        roots: [0.0; MAX_DEGREE],
        len: 0,
    };
    if p.iter().any(|c| !c.is_finite()) {
        return out;
    }
    let Some(degree) = effective_degree(p, MAX_DEGREE, 1e-14) else {
        return out;
    };
    if degree == 0 {
        return out;
    }
    // Monic, so that the chain and the bound are well scaled.
    let mut monic = [0.0; MAX_DEGREE + 1];
    for i in 0..=degree {
        monic[i] = p[i] / p[degree];
    }
    if degree == 1 {
        out.push(-monic[0]);
        return out;
    }
    // Cauchy's bound: every root satisfies |z| < 1 + max |a_i|.
    let bound = 1.0 + monic[..degree].iter().fold(0.0_f64, |m, c| m.max(c.abs()));
    let chain = SturmChain::new(&monic, degree);

    // Depth-first bisection over (lo, hi], carrying the sign changes at
    // both ends; the number of distinct roots inside is their difference.
    let mut stack = [(0.0, 0.0, 0_u32, 0_u32); 64];
    let mut top = 0;
    let (lo0, hi0) = (-bound, bound);
    stack[top] = (lo0, hi0, chain.sign_changes(lo0), chain.sign_changes(hi0));
    top += 1;
    while top > 0 {
        top -= 1;
        let (lo, hi, c_lo, c_hi) = stack[top];
        let count = c_lo.saturating_sub(c_hi);
        if count == 0 {
            continue;
        }
        let width = hi - lo;
        let tiny = width <= 1e-13 * (1.0 + lo.abs().max(hi.abs()));
        if count == 1 || tiny {
            if let Some(z) = polish_root(&monic, degree, lo, hi) {
                out.push(z);
            } else if tiny {
                out.push(0.5 * (lo + hi));
            } else {
                // Sign-change-free bracket with one root (root touching an
                // end): keep bisecting.
                push_halves(&chain, &mut stack, &mut top, lo, hi, c_lo, c_hi);
            }
            continue;
        }
        push_halves(&chain, &mut stack, &mut top, lo, hi, c_lo, c_hi);
    }
    out.roots[..out.len].sort_by(|a, b| a.total_cmp(b));
    out
}

fn push_halves(
    chain: &SturmChain,
    stack: &mut [(f64, f64, u32, u32); 64],
    top: &mut usize,
    lo: f64,
    hi: f64,
    c_lo: u32,
    c_hi: u32,
) {
    if *top + 2 > stack.len() {
        return;
    }
    let mid = 0.5 * (lo + hi);
    let c_mid = chain.sign_changes(mid);
    // Upper half first so the lower is processed first (order is not
    // needed, roots are sorted at the end).
    stack[*top] = (mid, hi, c_mid, c_hi);
    stack[*top + 1] = (lo, mid, c_lo, c_mid);
    *top += 2;
}

/// The single root of `p` in `[lo, hi]` when `p` changes sign there:
/// Newton steps kept inside a shrinking bracket, bisection when Newton
/// leaves it or stalls.
fn polish_root(p: &Coefficients, degree: usize, mut lo: f64, mut hi: f64) -> Option<f64> {
    let mut f_lo = evaluate(p, degree, lo);
    let f_hi = evaluate(p, degree, hi);
    if f_lo == 0.0 {
        return Some(lo);
    }
    if f_hi == 0.0 {
        return Some(hi);
    }
    if (f_lo > 0.0) == (f_hi > 0.0) {
        return None;
    }
    let mut z = 0.5 * (lo + hi);
    for _ in 0..200 {
        let (f, df) = evaluate_with_derivative(p, degree, z);
        if f == 0.0 {
            return Some(z);
        }
        if (f > 0.0) == (f_lo > 0.0) {
            lo = z;
            f_lo = f;
        } else {
            hi = z;
        }
        let newton = z - f / df;
        let next = if df != 0.0 && newton > lo && newton < hi {
            newton
        } else {
            0.5 * (lo + hi)
        };
        if (next - z).abs() <= 4.0 * f64::EPSILON * z.abs().max(1e-300) || hi - lo <= 0.0 {
            return Some(next);
        }
        z = next;
    }
    Some(z)
}

/// Product of two polynomials given with their degrees.
pub fn multiply(a: &[f64], deg_a: usize, b: &[f64], deg_b: usize, out: &mut [f64]) {
    for c in out[..=deg_a + deg_b].iter_mut() {
        *c = 0.0;
    }
    for i in 0..=deg_a {
        for j in 0..=deg_b {
            out[i + j] += a[i] * b[j];
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn from_roots(roots: &[f64]) -> Coefficients {
        let mut p = [0.0; MAX_DEGREE + 1];
        p[0] = 1.0;
        for (deg, &r) in roots.iter().enumerate() {
            let mut next = [0.0; MAX_DEGREE + 1];
            multiply(&p, deg, &[-r, 1.0], 1, &mut next);
            p = next;
        }
        p
    }

    #[test]
    fn finds_all_roots_of_a_degree_ten_polynomial() {
        let roots = [-7.5, -3.0, -1.25, -0.5, 0.1, 0.3, 2.0, 4.5, 9.0, 31.0];
        let found = real_roots(&from_roots(&roots));
        assert_eq!(found.as_slice().len(), roots.len());
        for (a, b) in found.as_slice().iter().zip(&roots) {
            assert!((a - b).abs() < 1e-8 * (1.0 + b.abs()), "{a} vs {b}");
        }
    }

    #[test]
    fn skips_complex_roots() {
        // (z^2 + 1)(z - 2)(z + 3): real roots -3 and 2 only.
        let mut p = [0.0; MAX_DEGREE + 1];
        let q = from_roots(&[2.0, -3.0]);
        multiply(&q, 2, &[1.0, 0.0, 1.0], 2, &mut p);
        let found = real_roots(&p);
        assert_eq!(found.as_slice().len(), 2);
        assert!((found.as_slice()[0] + 3.0).abs() < 1e-12);
        assert!((found.as_slice()[1] - 2.0).abs() < 1e-12);
    }

    #[test]
    fn double_root_is_reported_once() {
        let found = real_roots(&from_roots(&[1.0, 1.0, -2.0]));
        assert_eq!(found.as_slice().len(), 2, "{:?}", found.as_slice());
        assert!((found.as_slice()[1] - 1.0).abs() < 1e-6);
    }

    #[test]
    fn degenerate_inputs_give_no_roots() {
        assert!(real_roots(&[0.0; MAX_DEGREE + 1]).as_slice().is_empty());
        let mut constant = [0.0; MAX_DEGREE + 1];
        constant[0] = 3.0;
        assert!(real_roots(&constant).as_slice().is_empty());
        let mut nan = from_roots(&[1.0, 2.0]);
        nan[1] = f64::NAN;
        assert!(real_roots(&nan).as_slice().is_empty());
    }
}
