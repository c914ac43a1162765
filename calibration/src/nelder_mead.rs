//! The down-hill simplex method (Nelder and Mead, "A simplex method for
//! function minimization", Computer Journal 7, 1965), the minimiser the
//! paper uses for the accelerometer calibration (eq. 14). Standard
//! coefficients: reflection 1, expansion 2, contraction 1/2, shrink 1/2.
//! A converged run is restarted from its best vertex with a fresh simplex
//! until a restart no longer improves (the simplex can collapse early in
//! higher dimensions).

/// When to stop.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NelderMeadOptions {
    /// Edge of the initial simplex along each coordinate.
    pub initial_step: f64,
    /// Stop when the function values of the simplex differ by less than
    /// this, relative to the best value (plus `f_tolerance * 1e-12` absolute) ...
    pub f_tolerance: f64,
    /// ... and the vertices are within this of the best one (max norm).
    pub x_tolerance: f64,
    pub max_evaluations: usize,
    pub max_restarts: usize,
}

impl Default for NelderMeadOptions {
    fn default() -> Self {
        Self {
            initial_step: 0.01,
            f_tolerance: 1e-10,
            x_tolerance: 1e-8,
            max_evaluations: 200_000,
            max_restarts: 20,
        }
    }
}

#[derive(Debug, Clone, PartialEq)]
pub struct NelderMeadResult {
    pub x: Vec<f64>,
    pub f: f64,
    pub evaluations: usize,
    pub restarts: usize,
    /// The tolerances were met before `max_evaluations`.
    pub converged: bool,
}

/// Minimises `f` from `x0`.
pub fn minimize(
    f: impl Fn(&[f64]) -> f64,
    x0: &[f64],
    options: &NelderMeadOptions,
) -> NelderMeadResult {
    let mut evaluations = 0;
    let mut best = x0.to_vec();
    let mut best_f = f(&best);
    let mut restarts = 0;
    let mut converged;
    loop {
        let (x, fx, evals, ok) = one_run(&f, &best, options, options.max_evaluations - evaluations);
        evaluations += evals;
        let improved = fx < best_f - options.f_tolerance * (best_f.abs() + 1e-12);
        if fx <= best_f {
            best = x;
            best_f = fx;
        }
        converged = ok;
        if !improved
            || !ok
            || restarts >= options.max_restarts
            || evaluations >= options.max_evaluations
        {
            break;
        }
        restarts += 1;
    }
    NelderMeadResult {
        x: best,
        f: best_f,
        evaluations,
        restarts,
        converged,
    }
}

fn one_run(
    f: &impl Fn(&[f64]) -> f64,
    x0: &[f64],
    options: &NelderMeadOptions,
    budget: usize,
) -> (Vec<f64>, f64, usize, bool) {
    let n = x0.len();
    let evaluations = std::cell::Cell::new(0usize);
    let eval = |x: &[f64]| {
        evaluations.set(evaluations.get() + 1);
        f(x)
    };
    let mut simplex: Vec<Vec<f64>> = Vec::with_capacity(n + 1);
    simplex.push(x0.to_vec());
    for i in 0..n {
        let mut v = x0.to_vec();
        v[i] += options.initial_step;
        simplex.push(v);
    }
    let mut values: Vec<f64> = simplex.iter().map(|v| eval(v)).collect();
    let mut converged = false;
    while evaluations.get() < budget {
        // Order: best first.
        let mut order: Vec<usize> = (0..=n).collect();
        order.sort_by(|&a, &b| values[a].total_cmp(&values[b]));
        simplex = order.iter().map(|&i| simplex[i].clone()).collect();
        values = order.iter().map(|&i| values[i]).collect();
        let spread_f = values[n] - values[0];
        let spread_x = simplex[1..]
            .iter()
            .flat_map(|v| v.iter().zip(&simplex[0]).map(|(a, b)| (a - b).abs()))
            .fold(0.0, f64::max);
        if spread_f <= options.f_tolerance * (values[0].abs() + 1e-12)
            && spread_x <= options.x_tolerance
        {
            converged = true;
            break;
        }
        let centroid: Vec<f64> = (0..n)
            .map(|k| simplex[..n].iter().map(|v| v[k]).sum::<f64>() / n as f64)
            .collect();
        let along = |t: f64| -> Vec<f64> {
            centroid
                .iter()
                .zip(&simplex[n])
                .map(|(c, w)| c + t * (w - c))
                .collect()
        };
        let reflected = along(-1.0);
        let f_r = eval(&reflected);
        if f_r < values[0] {
            let expanded = along(-2.0);
            let f_e = eval(&expanded);
            if f_e < f_r {
                simplex[n] = expanded;
                values[n] = f_e;
            } else {
                simplex[n] = reflected;
                values[n] = f_r;
            }
        } else if f_r < values[n - 1] {
            simplex[n] = reflected;
            values[n] = f_r;
        } else {
            // Contract towards the better of the worst and its reflection.
            let (t, f_ref) = if f_r < values[n] {
                (-0.5, f_r)
            } else {
                (0.5, values[n])
            };
            let contracted = along(t);
            let f_c = eval(&contracted);
            if f_c < f_ref {
                simplex[n] = contracted;
                values[n] = f_c;
            } else {
                for i in 1..=n {
                    let shrunk: Vec<f64> = simplex[0]
                        .iter()
                        .zip(&simplex[i])
                        .map(|(b, v)| b + 0.5 * (v - b))
                        .collect();
                    values[i] = eval(&shrunk);
                    simplex[i] = shrunk;
                }
            }
        }
    }
    let best = (0..=n)
        .min_by(|&a, &b| values[a].total_cmp(&values[b]))
        .expect("the simplex has n + 1 >= 1 vertices");
    (
        simplex[best].clone(),
        values[best],
        evaluations.get(),
        converged,
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn finds_the_rosenbrock_minimum() {
        let rosenbrock = |x: &[f64]| (1.0 - x[0]).powi(2) + 100.0 * (x[1] - x[0] * x[0]).powi(2);
        let options = NelderMeadOptions {
            initial_step: 0.5,
            ..Default::default()
        };
        let r = minimize(rosenbrock, &[-1.2, 1.0], &options);
        assert!(r.converged);
        assert!(
            (r.x[0] - 1.0).abs() < 1e-6 && (r.x[1] - 1.0).abs() < 1e-6,
            "{r:?}"
        );
    }

    #[test]
    fn finds_a_shifted_quadratic_in_nine_dimensions() {
        let centre: Vec<f64> = (0..9).map(|i| 0.1 * i as f64 - 0.3).collect();
        let f = |x: &[f64]| {
            x.iter()
                .zip(&centre)
                .enumerate()
                .map(|(i, (a, c))| (1.0 + i as f64) * (a - c).powi(2))
                .sum()
        };
        let r = minimize(f, &[0.0; 9], &NelderMeadOptions::default());
        assert!(r.converged, "{r:?}");
        for (a, c) in r.x.iter().zip(&centre) {
            assert!((a - c).abs() < 1e-7, "{r:?}");
        }
    }
}
