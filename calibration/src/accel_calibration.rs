//! Accelerometer scale/misalignment `S` and bias `b` from still poses: at
//! rest every corrected reading `S a_i + b` has the magnitude of local
//! gravity (paper eq. 14; Tedaldi et al. ICRA 2014, eq. 10), so
//! `min sum_i (|S a_i + b| - g)^2` over the poses' mean readings `a_i`.
//! Magnitudes cannot see a rotation of the output frame, so `S` is upper
//! triangular (the body x axis along the accelerometer's x, y in its x-y
//! plane): 6 + 3 unknowns. With fewer than 9 distinct poses (the six faces
//! of the Ferraris protocol) only the diagonal scale is observable and the
//! model drops to 3 + 3 unknowns. Solved twice, by the down-hill simplex
//! as in the paper and by Levenberg-Marquardt, and the two compared.

use nalgebra::{DMatrix, DVector, Matrix3, Vector3};

use crate::error::CalibrationError;
use crate::nelder_mead::{self, NelderMeadOptions};

/// Which entries of `S` are estimated.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum AccelModel {
    /// Upper-triangular `S` (scale + misalignment) and `b`: 9 unknowns.
    UpperTriangular,
    /// Diagonal `S` and `b`: 6 unknowns.
    Diagonal,
}

impl AccelModel {
    pub fn unknowns(self) -> usize {
        match self {
            AccelModel::UpperTriangular => 9,
            AccelModel::Diagonal => 6,
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            AccelModel::UpperTriangular => "upper-triangular S (scale + misalignment) + b",
            AccelModel::Diagonal => "diagonal S (scale only) + b",
        }
    }

    /// `(S, b)` from the parameter vector.
    pub fn unpack(self, p: &[f64]) -> (Matrix3<f64>, Vector3<f64>) {
        match self {
            AccelModel::UpperTriangular => (
                Matrix3::new(p[0], p[1], p[2], 0.0, p[3], p[4], 0.0, 0.0, p[5]),
                Vector3::new(p[6], p[7], p[8]),
            ),
            AccelModel::Diagonal => (
                Matrix3::from_diagonal(&Vector3::new(p[0], p[1], p[2])),
                Vector3::new(p[3], p[4], p[5]),
            ),
        }
    }

    /// The identity calibration's parameters.
    fn identity(self) -> Vec<f64> {
        match self {
            AccelModel::UpperTriangular => vec![1.0, 0.0, 0.0, 1.0, 0.0, 1.0, 0.0, 0.0, 0.0],
            AccelModel::Diagonal => vec![1.0, 1.0, 1.0, 0.0, 0.0, 0.0],
        }
    }

    /// (row, column) of `S` for each scale parameter, in order.
    fn scale_entries(self) -> &'static [(usize, usize)] {
        match self {
            AccelModel::UpperTriangular => &[(0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)],
            AccelModel::Diagonal => &[(0, 0), (1, 1), (2, 2)],
        }
    }
}

/// One solver's answer.
#[derive(Debug, Clone, PartialEq)]
pub struct AccelFit {
    pub scale: Matrix3<f64>,
    pub bias_m_s2: Vector3<f64>,
    /// `|S a_i + b| - g` per pose.
    pub residuals_m_s2: Vec<f64>,
    pub rms_m_s2: f64,
    /// Cost evaluations (simplex) or iterations (LM).
    pub work: usize,
}

/// Both solvers and how far apart they ended.
#[derive(Debug, Clone, PartialEq)]
pub struct AccelCalibration {
    pub model: AccelModel,
    pub gravity_m_s2: f64,
    /// `|a_i| - g` per pose before calibration.
    pub residuals_before_m_s2: Vec<f64>,
    pub rms_before_m_s2: f64,
    pub nelder_mead: AccelFit,
    pub levenberg_marquardt: AccelFit,
    /// Largest absolute difference between the two solutions' entries of S.
    pub scale_agreement: f64,
    /// Largest absolute difference between the two biases, m/s^2.
    pub bias_agreement_m_s2: f64,
}

fn residuals(model: AccelModel, p: &[f64], means: &[Vector3<f64>], g: f64) -> Vec<f64> {
    let (s, b) = model.unpack(p);
    means.iter().map(|a| (s * a + b).norm() - g).collect()
}

fn rms(r: &[f64]) -> f64 {
    (r.iter().map(|x| x * x).sum::<f64>() / r.len().max(1) as f64).sqrt()
}

fn fit_from(model: AccelModel, p: &[f64], means: &[Vector3<f64>], g: f64, work: usize) -> AccelFit {
    let (scale, bias_m_s2) = model.unpack(p);
    let residuals_m_s2 = residuals(model, p, means, g);
    AccelFit {
        scale,
        bias_m_s2,
        rms_m_s2: rms(&residuals_m_s2),
        residuals_m_s2,
        work,
    }
}

/// The down-hill simplex on the summed squared magnitude errors.
pub fn fit_nelder_mead(model: AccelModel, means: &[Vector3<f64>], g: f64) -> AccelFit {
    let cost = |p: &[f64]| {
        residuals(model, p, means, g)
            .iter()
            .map(|r| r * r)
            .sum::<f64>()
    };
    let options = NelderMeadOptions {
        initial_step: 0.02,
        ..Default::default()
    };
    let result = nelder_mead::minimize(cost, &model.identity(), &options);
    fit_from(model, &result.x, means, g, result.evaluations)
}

/// Residuals `|S a_i + b| - g` and their Jacobian in the parameters:
/// `d r_i / d S_jk = u_j a_k / |u|`, `d r_i / d b_j = u_j / |u|`, `u = S a_i + b`.
pub fn residuals_and_jacobian(
    model: AccelModel,
    p: &[f64],
    means: &[Vector3<f64>],
    g: f64,
) -> (DVector<f64>, DMatrix<f64>) {
    let entries = model.scale_entries();
    let (s, b) = model.unpack(p);
    let mut jac = DMatrix::<f64>::zeros(means.len(), model.unknowns());
    let mut res = DVector::<f64>::zeros(means.len());
    for (i, a) in means.iter().enumerate() {
        let u = s * a + b;
        let norm = u.norm();
        res[i] = norm - g;
        for (c, &(j, k)) in entries.iter().enumerate() {
            jac[(i, c)] = u[j] * a[k] / norm;
        }
        for j in 0..3 {
            jac[(i, entries.len() + j)] = u[j] / norm;
        }
    }
    (res, jac)
}

/// Levenberg-Marquardt with the analytic Jacobian of [`residuals_and_jacobian`].
pub fn fit_levenberg_marquardt(
    model: AccelModel,
    means: &[Vector3<f64>],
    g: f64,
) -> Result<AccelFit, CalibrationError> {
    let n_params = model.unknowns();
    let mut p = model.identity();
    let mut lambda = 1e-3;
    let mut cost = residuals(model, &p, means, g)
        .iter()
        .map(|r| r * r)
        .sum::<f64>();
    let mut iterations = 0;
    for _ in 0..200 {
        iterations += 1;
        let (res, jac) = residuals_and_jacobian(model, &p, means, g);
        let jtj = jac.transpose() * &jac;
        let jtr = jac.transpose() * &res;
        let mut accepted = false;
        while lambda < 1e12 {
            let mut damped = jtj.clone();
            for d in 0..n_params {
                damped[(d, d)] += lambda * jtj[(d, d)].max(1e-12);
            }
            let Some(step) = damped.cholesky().map(|c| c.solve(&(-&jtr))) else {
                lambda *= 10.0;
                continue;
            };
            let trial: Vec<f64> = p.iter().zip(step.iter()).map(|(a, d)| a + d).collect();
            let trial_cost = residuals(model, &trial, means, g)
                .iter()
                .map(|r| r * r)
                .sum::<f64>();
            if trial_cost <= cost {
                let small = step.amax() < 1e-13;
                p = trial;
                cost = trial_cost;
                lambda = (lambda / 10.0).max(1e-12);
                accepted = true;
                if small {
                    return Ok(fit_from(model, &p, means, g, iterations));
                }
                break;
            }
            lambda *= 10.0;
        }
        if !accepted {
            // No step reduces the cost: at the minimum to machine precision.
            return Ok(fit_from(model, &p, means, g, iterations));
        }
    }
    if cost.is_finite() {
        Ok(fit_from(model, &p, means, g, iterations))
    } else {
        Err(CalibrationError::NoConvergence(
            "the accelerometer fit diverged: check the units (--accel-unit) and the static poses"
                .into(),
        ))
    }
}

/// Fits `model` to the poses' mean raw readings with both solvers.
pub fn calibrate_accelerometer(
    model: AccelModel,
    means: &[Vector3<f64>],
    gravity_m_s2: f64,
) -> Result<AccelCalibration, CalibrationError> {
    let residuals_before_m_s2: Vec<f64> = means.iter().map(|a| a.norm() - gravity_m_s2).collect();
    let nelder_mead = fit_nelder_mead(model, means, gravity_m_s2);
    let levenberg_marquardt = fit_levenberg_marquardt(model, means, gravity_m_s2)?;
    let scale_agreement = (nelder_mead.scale - levenberg_marquardt.scale).amax();
    let bias_agreement_m_s2 = (nelder_mead.bias_m_s2 - levenberg_marquardt.bias_m_s2).amax();
    Ok(AccelCalibration {
        model,
        gravity_m_s2,
        rms_before_m_s2: rms(&residuals_before_m_s2),
        residuals_before_m_s2,
        nelder_mead,
        levenberg_marquardt,
        scale_agreement,
        bias_agreement_m_s2,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// Raw readings of 18 random still poses for a known `S`, `b`:
    /// `a_r = S^-1 (R^T g_up - b)`, exactly (no noise).
    fn poses(s: &Matrix3<f64>, b: &Vector3<f64>, g: f64, seed: u64) -> Vec<Vector3<f64>> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let s_inv = s.try_inverse().expect("test S is invertible");
        (0..18)
            .map(|_| {
                let dir = Vector3::new(
                    rng.gen_range(-1.0..1.0),
                    rng.gen_range(-1.0..1.0),
                    rng.gen_range(-1.0..1.0),
                )
                .normalize();
                s_inv * (dir * g - b)
            })
            .collect()
    }

    #[test]
    fn both_solvers_recover_a_known_upper_triangular_calibration() {
        let s = Matrix3::new(1.02, 0.01, -0.015, 0.0, 0.985, 0.008, 0.0, 0.0, 1.01);
        let b = Vector3::new(0.12, -0.25, 0.18);
        let means = poses(&s, &b, 9.81, 7);
        let cal = calibrate_accelerometer(AccelModel::UpperTriangular, &means, 9.81).expect("fits");
        for fit in [&cal.nelder_mead, &cal.levenberg_marquardt] {
            assert!((fit.scale - s).amax() < 1e-6, "{:?}", fit.scale);
            assert!((fit.bias_m_s2 - b).amax() < 1e-6, "{:?}", fit.bias_m_s2);
            assert!(fit.rms_m_s2 < 1e-8);
        }
        assert!(cal.rms_before_m_s2 > 0.05);
        assert!(cal.scale_agreement < 1e-6 && cal.bias_agreement_m_s2 < 1e-6);
    }

    #[test]
    fn the_jacobian_matches_central_differences() {
        let s = Matrix3::new(1.02, 0.01, -0.015, 0.0, 0.985, 0.008, 0.0, 0.0, 1.01);
        let means = poses(&s, &Vector3::new(0.1, 0.2, -0.1), 9.81, 3);
        for (model, p) in [
            (
                AccelModel::UpperTriangular,
                vec![1.01, 0.02, -0.01, 0.99, 0.005, 1.03, 0.1, -0.2, 0.3],
            ),
            (AccelModel::Diagonal, vec![1.01, 0.99, 1.03, 0.1, -0.2, 0.3]),
        ] {
            let (_, jac) = residuals_and_jacobian(model, &p, &means, 9.81);
            let h = 1e-6;
            for c in 0..model.unknowns() {
                let (mut plus, mut minus) = (p.clone(), p.clone());
                plus[c] += h;
                minus[c] -= h;
                let (rp, _) = residuals_and_jacobian(model, &plus, &means, 9.81);
                let (rm, _) = residuals_and_jacobian(model, &minus, &means, 9.81);
                let fd = (rp - rm) / (2.0 * h);
                assert!(
                    (fd - jac.column(c)).amax() < 1e-7,
                    "{model:?} parameter {c}"
                );
            }
        }
    }

    #[test]
    fn the_diagonal_model_is_exact_on_six_faces() {
        let s = Matrix3::from_diagonal(&Vector3::new(1.01, 0.99, 1.03));
        let b = Vector3::new(-0.3, 0.2, 0.1);
        let s_inv = s.try_inverse().expect("invertible");
        let means: Vec<Vector3<f64>> = [1.0, -1.0]
            .iter()
            .flat_map(|sign| (0..3).map(move |k| Vector3::ith(k, sign * 9.81)))
            .map(|up| s_inv * (up - b))
            .collect();
        let cal = calibrate_accelerometer(AccelModel::Diagonal, &means, 9.81).expect("fits");
        for fit in [&cal.nelder_mead, &cal.levenberg_marquardt] {
            assert!((fit.scale - s).amax() < 1e-7, "{:?}", fit.scale);
            assert!((fit.bias_m_s2 - b).amax() < 1e-7, "{:?}", fit.bias_m_s2);
        }
    }
}
