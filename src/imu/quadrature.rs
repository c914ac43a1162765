//! Integration weights for one step between IMU samples.
//!
//! The paper's inter-frame integration (eq. 25) replaces each integral over
//! a sample step by a second-order interpolating quadrature over three
//! samples whose spacing need not be even. We do not have the paper's text
//! for eq. 25, so it is implemented as what such a rule is: the exact
//! integral of the quadratic (Lagrange) interpolant through three samples at
//! uneven times t0 < t1 < t2, over the step (or the part of it inside the
//! frame interval). The double integral (for position) is the exact double
//! integral of the same interpolant. Linear and constant interpolants give
//! the midpoint/trapezoid and Euler rules in the same form.
//!
//! A rule is a list of up to three nodes with one weight each for the
//! single and the double integral over `[lo, hi]`:
//! `int_lo^hi f ~ sum single[n] f(t_n)`,
//! `int_lo^hi int_lo^s f(u) du ds ~ sum double[n] f(t_n)`.

/// Weights of one step's integrals over up to three nodes.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StepRule {
    /// Sample indices of the nodes; only the first `count` are used.
    pub nodes: [usize; 3],
    /// Number of nodes used: 1 (Euler), 2 (midpoint) or 3 (quadratic).
    pub count: usize,
    /// Weights of the single integral over the step, s.
    pub single: [f64; 3],
    /// Weights of the double integral over the step, s^2.
    pub double: [f64; 3],
}

/// Exact single and double integrals over `[0, h_s]` of the Lagrange basis
/// polynomials through `count` nodes at `tau_s` (times relative to the
/// step's start; any order, distinct).
pub fn lagrange_weights(tau_s: &[f64], h_s: f64) -> ([f64; 3], [f64; 3]) {
    let mut single = [0.0; 3];
    let mut double = [0.0; 3];
    let (h2, h3, h4) = (h_s * h_s, h_s * h_s * h_s, h_s * h_s * h_s * h_s);
    for n in 0..tau_s.len() {
        // Basis n as c0 + c1 s + c2 s^2 (product of (s - tau_m)/(tau_n - tau_m)).
        let mut c = [1.0, 0.0, 0.0];
        for (m, &tau_m) in tau_s.iter().enumerate() {
            if m == n {
                continue;
            }
            let d = 1.0 / (tau_s[n] - tau_m);
            c = [
                -tau_m * c[0] * d,
                (c[0] - tau_m * c[1]) * d,
                (c[1] - tau_m * c[2]) * d,
            ];
        }
        single[n] = c[0] * h_s + c[1] * h2 / 2.0 + c[2] * h3 / 3.0;
        double[n] = c[0] * h2 / 2.0 + c[1] * h3 / 6.0 + c[2] * h4 / 12.0;
    }
    (single, double)
}

/// The rule that holds node `k`'s value over the step (Euler, zero-order hold).
pub fn euler_rule(k: usize, h_s: f64) -> StepRule {
    StepRule {
        nodes: [k, 0, 0],
        count: 1,
        single: [h_s, 0.0, 0.0],
        double: [h_s * h_s / 2.0, 0.0, 0.0],
    }
}

/// The rule of the interpolant through `nodes` (2 or 3 of them), whose
/// times relative to the step's start are `tau_s`, over `[0, h_s]`.
pub fn interpolating_rule(nodes: &[usize], tau_s: &[f64], h_s: f64) -> StepRule {
    let (single, double) = lagrange_weights(tau_s, h_s);
    let mut rule = StepRule {
        nodes: [0; 3],
        count: nodes.len(),
        single,
        double,
    };
    rule.nodes[..nodes.len()].copy_from_slice(nodes);
    rule
}

/// Worst ratio of neighbouring spacings a three-node rule may have; beyond
/// it the quadratic amplifies noise (a derivative from two close samples)
/// and the neighbouring triple or the linear rule is used instead.
pub const MAX_SPACING_RATIO: f64 = 4.0;

/// Chooses the three nodes for the raw step `[t_k, t_k+1]` among the
/// samples `0..len`: the triple reaching back (k-1, k, k+1), or, where it
/// does not exist or is too uneven, the one reaching forward (k, k+1, k+2);
/// `None` when neither is usable. Preferring one side consistently matters:
/// with the back triple on every step, each interior sample's weights over
/// the three steps it touches sum to exactly its share of time (on even
/// spacing 5/12 + 8/12 + (-1/12) of a step), whereas switching sides from step to step (as
/// picking the "better" of two near-equal spacings would) gives samples
/// weights from 1/3 to 3/2 and amplifies noise and vibration.
pub fn choose_triple(t_ns: impl Fn(usize) -> i64, k: usize, len: usize) -> Option<[usize; 3]> {
    let usable = |a: usize| {
        let h0 = (t_ns(a + 1) - t_ns(a)) as f64;
        let h1 = (t_ns(a + 2) - t_ns(a + 1)) as f64;
        h0.max(h1) / h0.min(h1) <= MAX_SPACING_RATIO
    };
    if k >= 1 && k + 1 < len && usable(k - 1) {
        Some([k - 1, k, k + 1])
    } else if k + 2 < len && usable(k) {
        Some([k, k + 1, k + 2])
    } else {
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// f(t) = 2 - 3 t + 5 t^2 and its integrals from lo.
    fn f(t: f64) -> f64 {
        2.0 - 3.0 * t + 5.0 * t * t
    }
    fn big_f(t: f64) -> f64 {
        2.0 * t - 1.5 * t * t + 5.0 / 3.0 * t * t * t
    }
    fn double(lo: f64, hi: f64) -> f64 {
        // int_lo^hi (F(s) - F(lo)) ds with F' = f, F(0) = 0.
        let gg = |t: f64| t * t - 0.5 * t * t * t + 5.0 / 12.0 * t.powi(4);
        gg(hi) - gg(lo) - big_f(lo) * (hi - lo)
    }

    #[test]
    fn quadratic_rule_is_exact_for_quadratics_on_uneven_nodes() {
        // Nodes at uneven times; integrate over a sub-step not at a node.
        let times = [0.1, 0.13, 0.2];
        let (lo, hi) = (0.115, 0.13);
        let tau: Vec<f64> = times.iter().map(|t| t - lo).collect();
        let rule = interpolating_rule(&[0, 1, 2], &tau, hi - lo);
        let single: f64 = (0..3).map(|n| rule.single[n] * f(times[n])).sum();
        let dbl: f64 = (0..3).map(|n| rule.double[n] * f(times[n])).sum();
        assert!((single - (big_f(hi) - big_f(lo))).abs() < 1e-15);
        assert!((dbl - double(lo, hi)).abs() < 1e-16);
    }

    #[test]
    fn linear_rule_is_the_trapezoid() {
        let rule = interpolating_rule(&[4, 5], &[0.0, 0.01], 0.01);
        assert!((rule.single[0] - 0.005).abs() < 1e-18 && (rule.single[1] - 0.005).abs() < 1e-18);
        assert!((rule.double[0] - 1e-4 / 3.0).abs() < 1e-18);
        assert!((rule.double[1] - 1e-4 / 6.0).abs() < 1e-18);
        assert_eq!(&rule.nodes[..rule.count], &[4, 5]);
    }

    #[test]
    fn triple_choice_reaches_back_and_refuses_bad_spacing() {
        let t = [0, 5, 10, 11, 16, 21];
        let at = |i: usize| t[i] as i64;
        // Step 1 (5..10): back (0,1,2) even.
        assert_eq!(choose_triple(at, 1, 6), Some([0, 1, 2]));
        // Step 0 has no back triple: forward (0,1,2).
        assert_eq!(choose_triple(at, 0, 6), Some([0, 1, 2]));
        // Step 2 (10..11): back ratio 5, forward (2,3,4) ratio 5: refused.
        assert_eq!(choose_triple(at, 2, 6), None);
        // Step 3 (11..16): back (2,3,4) ratio 5, forward (3,4,5) even.
        assert_eq!(choose_triple(at, 3, 6), Some([3, 4, 5]));
        // Two samples only: nothing.
        assert_eq!(choose_triple(at, 0, 2), None);
    }
}
