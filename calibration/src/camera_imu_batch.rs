//! Joint batch refinement of the camera-IMU calibration over the whole
//! recording. The IMU position is a uniform cubic B-spline in time (the
//! trajectory states); its orientation comes from the camera's target poses
//! through the camera-IMU rotation, interpolated between frames with the
//! bias-corrected gyroscope. Three kinds of residual tie them together:
//!
//! - position: `p_imu(t_k + d) + R_world_imu(k) p_imu_cam - s p_world_cam(k)`
//!   for every posed frame (the lever arm `p_imu_cam` is the camera centre in
//!   the IMU frame);
//! - acceleration: `p_imu''(t_j) - R_world_imu(t_j) (f_j - b_a) - g_world`
//!   for every accelerometer sample;
//! - angular rate: `w_imu - b_g - R_imu_cam w_cam` over every frame interval.
//!
//! For a fixed time offset `d` and rotation `R_imu_cam` the spline, the lever
//! arm, the accelerometer bias and gravity enter linearly and are solved
//! exactly (banded normal equations with a Schur complement on the nine
//! global unknowns); the offset and rotation are then found by Nelder-Mead
//! over that projected cost (variable projection, Golub and Pereyra 1973).
//! Gravity is left free and the target's metric scale `s` is estimated, so
//! a wrong tag size shows as `s != 1`.
//! The residuals are weighted by their own RMS from a first solve.

use nalgebra::{Matrix3, Matrix4, SMatrix, SVector, Vector3};
use rigslam::imu::so3;
use rigslam::sensors::ImuSample;

use crate::aprilgrid_detections::TargetPose;
use crate::banded_cholesky::BandMatrix;

/// Knot spacing of the IMU position spline, s.
/// Two accelerometer samples per knot at 200 Hz: on the EuRoC recording
/// 0.04 s leaves 0.27 m/s^2 of accelerometer residual, 0.01 s 0.08 m/s^2.
pub const KNOT_SPACING_S: f64 = 0.01;
/// Spline support beyond the first and last frame, s: more than any
/// offset the search visits.
const SPLINE_MARGIN_S: f64 = 0.3;
/// Weight of the smoothness prior on the control points' second
/// differences (keeps gaps without data well-posed), 1/m.
const SMOOTHNESS_WEIGHT: f64 = 1e-3;

/// What the batch starts from (the gyro-correlation estimate).
#[derive(Debug, Clone)]
#[allow(non_snake_case)]
pub struct BatchInput<'a> {
    pub poses: &'a [TargetPose],
    pub imu: &'a [ImuSample],
    /// IMU time origin, ns (times inside are seconds from it).
    pub t_origin_ns: i64,
    pub R_imu_cam: Matrix3<f64>,
    pub gyro_bias_rad_s: Vector3<f64>,
    pub timeshift_cam_imu_s: f64,
}

/// The refined calibration and how well it fits.
#[derive(Debug, Clone)]
#[allow(non_snake_case)]
pub struct BatchResult {
    pub R_imu_cam: Matrix3<f64>,
    /// Camera centre in the IMU frame, m.
    pub p_imu_cam_m: Vector3<f64>,
    pub timeshift_cam_imu_s: f64,
    /// Gravity in the target frame, m/s^2 (free).
    pub gravity_m_s2: Vector3<f64>,
    /// Metric scale of the target seen by the IMU: the camera positions
    /// are multiplied by it. 1 for a correctly sized target; 1.1 means the
    /// target is 10% larger than its description says.
    pub target_scale: f64,
    pub accel_bias_m_s2: Vector3<f64>,
    pub gyro_bias_rad_s: Vector3<f64>,
    pub accel_rms_m_s2: f64,
    pub position_rms_m: f64,
    pub gyro_rms_rad_s: f64,
    pub accel_residuals: usize,
    pub position_residuals: usize,
    /// Projected cost against the time offset around the optimum (s, cost).
    pub cost_curve: Vec<(f64, f64)>,
}

impl BatchResult {
    /// `T_cam_imu` (maps IMU coordinates into the camera), Kalibr's convention.
    #[allow(non_snake_case)]
    pub fn T_cam_imu(&self) -> Matrix4<f64> {
        let r_cam_imu = self.R_imu_cam.transpose();
        let t = -(r_cam_imu * self.p_imu_cam_m);
        let mut m = Matrix4::identity();
        m.fixed_view_mut::<3, 3>(0, 0).copy_from(&r_cam_imu);
        m.fixed_view_mut::<3, 1>(0, 3).copy_from(&t);
        m
    }
}

/// Why the batch failed.
#[derive(Debug, thiserror::Error)]
pub enum BatchError {
    #[error("only {0} frame intervals overlap the IMU log; record the IMU and camera together for at least a minute")]
    TooLittleOverlap(usize),
    #[error("the normal equations are singular: the motion does not excite all axes; recollect moving and rotating the rig along and about all three axes")]
    Singular,
}

/// Uniform cubic B-spline basis at fraction `u` and its second derivative
/// (per knot spacing squared).
fn basis(u: f64) -> ([f64; 4], [f64; 4]) {
    let (u2, u3) = (u * u, u * u * u);
    (
        [
            (1.0 - u).powi(3) / 6.0,
            (3.0 * u3 - 6.0 * u2 + 4.0) / 6.0,
            (-3.0 * u3 + 3.0 * u2 + 3.0 * u + 1.0) / 6.0,
            u3 / 6.0,
        ],
        [1.0 - u, 3.0 * u - 2.0, 1.0 - 3.0 * u, u],
    )
}

/// Frames and IMU samples on one time axis (s from the IMU origin).
struct Prepared {
    frame_t_s: Vec<f64>,
    r_world_cam: Vec<Matrix3<f64>>,
    p_world_cam: Vec<Vector3<f64>>,
    position_information: Vec<Matrix3<f64>>,
    /// Consecutive frame pairs close enough to interpolate between.
    intervals: Vec<usize>,
    imu_t_s: Vec<f64>,
    gyro: Vec<Vector3<f64>>,
    accel: Vec<Vector3<f64>>,
}

impl Prepared {
    fn gyro_at(&self, t_s: f64) -> Option<Vector3<f64>> {
        let n = self.imu_t_s.len();
        if t_s < self.imu_t_s[0] || t_s > self.imu_t_s[n - 1] {
            return None;
        }
        let k = self.imu_t_s.partition_point(|&t| t <= t_s).clamp(1, n - 1);
        let (ta, tb) = (self.imu_t_s[k - 1], self.imu_t_s[k]);
        let a = (t_s - ta) / (tb - ta);
        Some(self.gyro[k - 1] * (1.0 - a) + self.gyro[k] * a)
    }
}

/// Weights (1 / sigma) of the three residual kinds; the position's
/// multiplies the PnP information's whitening.
#[derive(Debug, Clone, Copy)]
struct Weights {
    position: f64,
    accel: f64,
    gyro: f64,
}

struct LinearSolution {
    cost: f64,
    p_imu_cam: Vector3<f64>,
    accel_bias: Vector3<f64>,
    gravity: Vector3<f64>,
    target_scale: f64,
    gyro_bias: Vector3<f64>,
    accel_rms: f64,
    position_rms: f64,
    position_whitened_rms: f64,
    gyro_rms: f64,
    accel_count: usize,
    position_count: usize,
}

/// Unknowns besides the spline: lever arm (3), accelerometer bias (3),
/// gravity (3) and the metric scale of the target (1).
const GLOBALS: usize = 10;

/// Normal equations: banded spline block, dense coupling to the globals,
/// dense global block.
struct Normal {
    a: BandMatrix,
    b: Vec<[f64; GLOBALS]>,
    c: SMatrix<f64, GLOBALS, GLOBALS>,
    rhs_s: Vec<f64>,
    rhs_g: SVector<f64, GLOBALS>,
}

impl Normal {
    /// Adds `|S (sum_m coeff_m c_idx_m + G x_g - target)|^2` with the
    /// whitening `S^T S = info`.
    fn add(
        &mut self,
        spline: &[(usize, f64)],
        g: &SMatrix<f64, 3, GLOBALS>,
        target: &Vector3<f64>,
        info: &Matrix3<f64>,
    ) {
        let info_g = info * g;
        let info_t = info * target;
        for &(i, ci) in spline {
            for &(j, cj) in spline {
                for a in 0..3 {
                    for b in 0..3 {
                        let (row, col) = (3 * i + a, 3 * j + b);
                        if col <= row {
                            self.a.add(row, col, ci * cj * info[(a, b)]);
                        }
                    }
                }
            }
            for axis in 0..3 {
                for col in 0..GLOBALS {
                    self.b[3 * i + axis][col] += ci * info_g[(axis, col)];
                }
                self.rhs_s[3 * i + axis] += ci * info_t[axis];
            }
        }
        self.c += g.transpose() * info_g;
        self.rhs_g += g.transpose() * info_t;
    }
}

fn prepare(input: &BatchInput) -> Prepared {
    let frame_t_s: Vec<f64> = input
        .poses
        .iter()
        .map(|p| (p.t_ns - input.t_origin_ns) as f64 * 1e-9)
        .collect();
    let mut gaps: Vec<f64> = frame_t_s.windows(2).map(|w| w[1] - w[0]).collect();
    gaps.sort_by(f64::total_cmp);
    let max_gap_s = 1.5 * gaps.get(gaps.len() / 2).copied().unwrap_or(0.05);
    let intervals = (0..frame_t_s.len().saturating_sub(1))
        .filter(|&k| frame_t_s[k + 1] - frame_t_s[k] <= max_gap_s)
        .collect();
    Prepared {
        r_world_cam: input.poses.iter().map(|p| p.R_target_cam).collect(),
        p_world_cam: input.poses.iter().map(|p| p.p_target_cam).collect(),
        position_information: input.poses.iter().map(|p| p.position_information).collect(),
        frame_t_s,
        intervals,
        imu_t_s: input
            .imu
            .iter()
            .map(|s| (s.t_ns - input.t_origin_ns) as f64 * 1e-9)
            .collect(),
        gyro: input.imu.iter().map(|s| s.gyro_rad_s.into()).collect(),
        accel: input.imu.iter().map(|s| s.accel_m_s2.into()).collect(),
    }
}

/// Solves the linear unknowns for one offset and rotation.
fn solve_linear(
    prep: &Prepared,
    shift_s: f64,
    r_imu_cam: &Matrix3<f64>,
    weights: &Weights,
) -> Result<LinearSolution, BatchError> {
    let r_cam_imu = r_imu_cam.transpose();
    // Gyro rates over the frame intervals, and the bias for this rotation.
    let mut rate_pairs = Vec::new();
    for &k in &prep.intervals {
        let (t0, t1) = (prep.frame_t_s[k] + shift_s, prep.frame_t_s[k + 1] + shift_s);
        let w_cam =
            so3::log(&(prep.r_world_cam[k].transpose() * prep.r_world_cam[k + 1])) / (t1 - t0);
        let mut mean = Vector3::zeros();
        let steps = 8;
        let mut ok = true;
        for i in 0..=steps {
            match prep.gyro_at(t0 + (t1 - t0) * i as f64 / steps as f64) {
                Some(g) => mean += g * if i == 0 || i == steps { 0.5 } else { 1.0 },
                None => ok = false,
            }
        }
        if ok {
            rate_pairs.push((k, w_cam, mean / steps as f64));
        }
    }
    if rate_pairs.len() < 20 {
        return Err(BatchError::TooLittleOverlap(rate_pairs.len()));
    }
    let gyro_bias = rate_pairs
        .iter()
        .map(|(_, c, i)| i - r_imu_cam * c)
        .sum::<Vector3<f64>>()
        / rate_pairs.len() as f64;
    let gyro_sq: f64 = rate_pairs
        .iter()
        .map(|(_, c, i)| (i - gyro_bias - r_imu_cam * c).norm_squared())
        .sum();

    let knot = KNOT_SPACING_S;
    // Spline over the overlap.
    // The knots stay where they are when the offset changes (a grid that
    // moved with it made the cost jump between offsets).
    let first = prep.frame_t_s[rate_pairs[0].0];
    let last = prep.frame_t_s[rate_pairs[rate_pairs.len() - 1].0 + 1] + SPLINE_MARGIN_S;
    let t0 = first - SPLINE_MARGIN_S;
    let n_ctrl = ((last - t0) / knot).ceil() as usize + 4;
    let n = 3 * n_ctrl;
    let mut normal = Normal {
        a: BandMatrix::zeros(n, 11),
        b: vec![[0.0; GLOBALS]; n],
        c: SMatrix::zeros(),
        rhs_s: vec![0.0; n],
        rhs_g: SVector::zeros(),
    };
    let segment = |t: f64| {
        let x = (t - t0) / knot;
        let i = (x.floor() as usize).min(n_ctrl - 4);
        (i, x - i as f64)
    };
    type Row = ([(usize, f64); 4], SMatrix<f64, 3, GLOBALS>, Vector3<f64>);
    let mut accel_rows: Vec<Row> = Vec::new();
    let mut position_rows: Vec<(Row, Matrix3<f64>)> = Vec::new();
    let mut framed = vec![false; prep.frame_t_s.len()];
    let inv_h2 = 1.0 / (knot * knot);
    for &(k, _, _) in &rate_pairs {
        let (ta, tb) = (prep.frame_t_s[k] + shift_s, prep.frame_t_s[k + 1] + shift_s);
        let r_a = prep.r_world_cam[k] * r_cam_imu;
        let r_b = prep.r_world_cam[k + 1] * r_cam_imu;
        // Gyro-propagated orientation from frame k, corrected linearly to frame k+1.
        let first_sample = prep.imu_t_s.partition_point(|&t| t < ta);
        let last_sample = prep.imu_t_s.partition_point(|&t| t < tb);
        let mut stamps: Vec<f64> = prep.imu_t_s[first_sample..last_sample].to_vec();
        stamps.push(tb);
        let mut delta = Matrix3::identity();
        let mut previous = ta;
        let mut propagated = Vec::with_capacity(stamps.len());
        for &t in &stamps {
            if let Some(w) = prep.gyro_at(0.5 * (previous + t)) {
                delta *= so3::exp(&((w - gyro_bias) * (t - previous)));
            }
            propagated.push(delta);
            previous = t;
        }
        let end = propagated.pop().expect("tb was pushed");
        let correction = so3::log(&((r_a * end).transpose() * r_b));
        for (j, d) in (first_sample..last_sample).zip(&propagated) {
            let s = (prep.imu_t_s[j] - ta) / (tb - ta);
            let r_world_imu = r_a * d * so3::exp(&(correction * s));
            let (i, u) = segment(prep.imu_t_s[j]);
            let (_, dd) = basis(u);
            let spline = [
                (i, dd[0] * inv_h2),
                (i + 1, dd[1] * inv_h2),
                (i + 2, dd[2] * inv_h2),
                (i + 3, dd[3] * inv_h2),
            ];
            let mut g = SMatrix::<f64, 3, GLOBALS>::zeros();
            g.fixed_view_mut::<3, 3>(0, 3).copy_from(&r_world_imu);
            g.fixed_view_mut::<3, 3>(0, 6)
                .copy_from(&-Matrix3::identity());
            accel_rows.push((spline, g, r_world_imu * prep.accel[j]));
        }
        for f in [k, k + 1] {
            if framed[f] {
                continue;
            }
            framed[f] = true;
            let (i, u) = segment(prep.frame_t_s[f] + shift_s);
            let (b, _) = basis(u);
            let spline = [(i, b[0]), (i + 1, b[1]), (i + 2, b[2]), (i + 3, b[3])];
            let mut g = SMatrix::<f64, 3, GLOBALS>::zeros();
            g.fixed_view_mut::<3, 3>(0, 0)
                .copy_from(&(prep.r_world_cam[f] * r_cam_imu));
            g.set_column(9, &-prep.p_world_cam[f]);
            position_rows.push(((spline, g, Vector3::zeros()), prep.position_information[f]));
        }
    }
    let accel_info = Matrix3::identity() * weights.accel.powi(2);
    for (spline, g, target) in &accel_rows {
        normal.add(spline, g, target, &accel_info);
    }
    for ((spline, g, target), info) in &position_rows {
        normal.add(spline, g, target, &(info * weights.position.powi(2)));
    }
    let zero_g = SMatrix::<f64, 3, GLOBALS>::zeros();
    let smooth_info = Matrix3::identity() * SMOOTHNESS_WEIGHT.powi(2);
    for i in 1..n_ctrl - 1 {
        normal.add(
            &[(i - 1, 1.0), (i, -2.0), (i + 1, 1.0)],
            &zero_g,
            &Vector3::zeros(),
            &smooth_info,
        );
    }
    // Schur complement on the globals.
    let factor = normal.a.cholesky().ok_or(BatchError::Singular)?;
    let mut a_inv_b: Vec<Vec<f64>> = (0..GLOBALS)
        .map(|col| normal.b.iter().map(|row| row[col]).collect())
        .collect();
    for column in &mut a_inv_b {
        factor.solve_in_place(column);
    }
    let mut a_inv_rhs = normal.rhs_s.clone();
    factor.solve_in_place(&mut a_inv_rhs);
    let mut schur = normal.c;
    let mut reduced = normal.rhs_g;
    for r in 0..GLOBALS {
        for c in 0..GLOBALS {
            schur[(r, c)] -= (0..n).map(|i| normal.b[i][r] * a_inv_b[c][i]).sum::<f64>();
        }
        reduced[r] -= (0..n).map(|i| normal.b[i][r] * a_inv_rhs[i]).sum::<f64>();
    }
    // LU rather than Cholesky: the scale column nearly cancels against the
    // spline, and round-off can leave the complement slightly indefinite.
    let globals = schur.lu().solve(&reduced).ok_or(BatchError::Singular)?;
    let ctrl: Vec<f64> = (0..n)
        .map(|i| {
            a_inv_rhs[i]
                - (0..GLOBALS)
                    .map(|c| a_inv_b[c][i] * globals[c])
                    .sum::<f64>()
        })
        .collect();
    let residual =
        |spline: &[(usize, f64); 4], g: &SMatrix<f64, 3, GLOBALS>, target: &Vector3<f64>| {
            let mut v = g * globals - target;
            for &(i, c) in spline {
                v += Vector3::new(ctrl[3 * i], ctrl[3 * i + 1], ctrl[3 * i + 2]) * c;
            }
            v
        };
    let accel_sq: f64 = accel_rows
        .iter()
        .map(|(s, g, t)| residual(s, g, t).norm_squared())
        .sum();
    let position_sq: f64 = position_rows
        .iter()
        .map(|((s, g, t), _)| residual(s, g, t).norm_squared())
        .sum();
    // Whitened by the PnP information: ~1 if the pixel noise model holds.
    let position_whitened_sq: f64 = position_rows
        .iter()
        .map(|((s, g, t), info)| {
            let r = residual(s, g, t);
            (r.transpose() * info * r)[0]
        })
        .sum();
    let cost = accel_sq * weights.accel.powi(2)
        + position_whitened_sq * weights.position.powi(2)
        + gyro_sq * weights.gyro.powi(2);
    Ok(LinearSolution {
        cost,
        p_imu_cam: globals.fixed_rows::<3>(0).into_owned(),
        accel_bias: globals.fixed_rows::<3>(3).into_owned(),
        gravity: globals.fixed_rows::<3>(6).into_owned(),
        target_scale: globals[9],
        gyro_bias,
        accel_rms: (accel_sq / accel_rows.len() as f64).sqrt(),
        position_rms: (position_sq / position_rows.len() as f64).sqrt(),
        position_whitened_rms: (position_whitened_sq / (3 * position_rows.len()) as f64).sqrt(),
        gyro_rms: (gyro_sq / rate_pairs.len() as f64).sqrt(),
        accel_count: accel_rows.len(),
        position_count: position_rows.len(),
    })
}

/// Nelder-Mead minimisation (Nelder and Mead 1965; standard coefficients).
fn nelder_mead<const N: usize>(
    f: &mut dyn FnMut(&SVector<f64, N>) -> f64,
    start: SVector<f64, N>,
    step: f64,
    iterations: usize,
) -> SVector<f64, N> {
    let mut simplex: Vec<(SVector<f64, N>, f64)> = (0..=N)
        .map(|i| {
            let mut x = start;
            if i > 0 {
                x[i - 1] += step;
            }
            (x, f(&x))
        })
        .collect();
    for _ in 0..iterations {
        simplex.sort_by(|a, b| a.1.total_cmp(&b.1));
        let centroid = simplex[..N].iter().map(|s| s.0).sum::<SVector<f64, N>>() / N as f64;
        let worst = simplex[N];
        let reflected = centroid + (centroid - worst.0);
        let fr = f(&reflected);
        if fr < simplex[0].1 {
            let expanded = centroid + (centroid - worst.0) * 2.0;
            let fe = f(&expanded);
            simplex[N] = if fe < fr {
                (expanded, fe)
            } else {
                (reflected, fr)
            };
        } else if fr < simplex[N - 1].1 {
            simplex[N] = (reflected, fr);
        } else {
            let contracted = centroid + (worst.0 - centroid) * 0.5;
            let fc = f(&contracted);
            if fc < worst.1 {
                simplex[N] = (contracted, fc);
            } else {
                let best = simplex[0].0;
                for s in simplex.iter_mut().skip(1) {
                    s.0 = best + (s.0 - best) * 0.5;
                    s.1 = f(&s.0);
                }
            }
        }
        if (simplex[N].1 - simplex[0].1).abs() <= 1e-10 * simplex[0].1.abs() {
            break;
        }
    }
    simplex.sort_by(|a, b| a.1.total_cmp(&b.1));
    simplex[0].0
}

/// Refines offset, rotation, lever arm, biases and gravity (module doc).
pub fn refine_camera_imu(input: &BatchInput) -> Result<BatchResult, BatchError> {
    let prep = prepare(input);
    let r0 = input.R_imu_cam;
    // Parameters: offset in ms, rotation perturbation (R0 Exp(phi)) in mrad.
    let unpack = |x: &SVector<f64, 4>| {
        (
            x[0] * 1e-3,
            r0 * so3::exp(&(Vector3::new(x[1], x[2], x[3]) * 1e-3)),
        )
    };
    let start = SVector::<f64, 4>::new(input.timeshift_cam_imu_s * 1e3, 0.0, 0.0, 0.0);
    let nominal = Weights {
        position: 1.0,
        accel: 1.0 / 0.2,
        gyro: 1.0 / 0.02,
    };
    let first = solve_linear(&prep, input.timeshift_cam_imu_s, &r0, &nominal)?;
    let weights = Weights {
        position: 1.0 / first.position_whitened_rms.max(1e-3),
        accel: 1.0 / first.accel_rms.max(1e-3),
        gyro: 1.0 / first.gyro_rms.max(1e-4),
    };
    let mut objective = |x: &SVector<f64, 4>| {
        let (shift, r) = unpack(x);
        solve_linear(&prep, shift, &r, &weights).map_or(f64::INFINITY, |s| s.cost)
    };
    let best = nelder_mead(&mut objective, start, 1.0, 200);
    let (shift, r_imu_cam) = unpack(&best);
    let solution = solve_linear(&prep, shift, &r_imu_cam, &weights)?;
    let cost_curve = (-20..=20)
        .filter_map(|i| {
            let s = shift + i as f64 * 0.5e-3;
            solve_linear(&prep, s, &r_imu_cam, &weights)
                .ok()
                .map(|sol| (s, sol.cost))
        })
        .collect();
    Ok(BatchResult {
        R_imu_cam: r_imu_cam,
        p_imu_cam_m: solution.p_imu_cam,
        timeshift_cam_imu_s: shift,
        gravity_m_s2: solution.gravity,
        target_scale: solution.target_scale,
        accel_bias_m_s2: solution.accel_bias,
        gyro_bias_rad_s: solution.gyro_bias,
        accel_rms_m_s2: solution.accel_rms,
        position_rms_m: solution.position_rms,
        gyro_rms_rad_s: solution.gyro_rms,
        accel_residuals: solution.accel_count,
        position_residuals: solution.position_count,
        cost_curve,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    use nalgebra::Rotation3;

    /// A smooth synthetic rig motion: IMU position and orientation in the
    /// target frame, with the camera looking at the target.
    fn imu_pose(t: f64) -> (Matrix3<f64>, Vector3<f64>) {
        let p = Vector3::new(
            0.3 * (0.9 * t).sin(),
            0.2 * (1.3 * t).cos(),
            -1.0 + 0.15 * (0.7 * t).sin(),
        );
        let phi = Vector3::new(
            0.4 * (1.1 * t).sin(),
            0.35 * (0.8 * t).cos(),
            0.3 * (1.7 * t).sin(),
        );
        (so3::exp(&phi), p)
    }

    #[test]
    fn recovers_extrinsics_offset_bias_and_gravity_from_exact_data() {
        let r_imu_cam = Rotation3::from_euler_angles(0.02, -0.01, 1.55).into_inner();
        let p_imu_cam = Vector3::new(-0.02, -0.065, 0.01);
        let gravity = Vector3::new(0.3, -9.7, 1.4);
        let accel_bias = Vector3::new(0.05, -0.1, 0.08);
        let gyro_bias = Vector3::new(0.002, 0.02, -0.07);
        let shift_s = 0.004;
        // Camera poses at 20 Hz (camera clock = IMU clock - shift).
        let poses: Vec<TargetPose> = (0..400)
            .map(|k| {
                let t = k as f64 * 0.05;
                let (r, p) = imu_pose(t + shift_s);
                TargetPose {
                    t_ns: (t * 1e9).round() as i64,
                    R_target_cam: r * r_imu_cam,
                    p_target_cam: p + r * p_imu_cam,
                    rms_px: 0.1,
                    corners: 100,
                    position_information: Matrix3::identity() * 1e6,
                }
            })
            .collect();
        // IMU at 200 Hz from central differences of the analytic motion.
        let h = 1e-4;
        let imu: Vec<ImuSample> = (0..4000)
            .map(|j| {
                let t = j as f64 * 0.005;
                let (r, p) = imu_pose(t);
                let (r_next, p_next) = imu_pose(t + h);
                let (r_prev, p_prev) = imu_pose(t - h);
                let w = so3::log(&(r_prev.transpose() * r_next)) / (2.0 * h);
                let a = (p_next - 2.0 * p + p_prev) / (h * h);
                let f = r.transpose() * (a - gravity) + accel_bias;
                ImuSample {
                    t_ns: (t * 1e9).round() as i64,
                    gyro_rad_s: (w + gyro_bias).into(),
                    accel_m_s2: f.into(),
                }
            })
            .collect();
        let start = r_imu_cam * so3::exp(&Vector3::new(0.004, -0.003, 0.005));
        let result = refine_camera_imu(&BatchInput {
            poses: &poses,
            imu: &imu,
            t_origin_ns: 0,
            R_imu_cam: start,
            gyro_bias_rad_s: Vector3::zeros(),
            timeshift_cam_imu_s: 0.0055,
        })
        .expect("well-posed");
        let angle = so3::log(&(result.R_imu_cam.transpose() * r_imu_cam)).norm();
        assert!(angle < 1e-4, "rotation error {angle} rad");
        assert!(
            (result.p_imu_cam_m - p_imu_cam).norm() < 1e-3,
            "lever arm {}",
            result.p_imu_cam_m
        );
        assert!(
            (result.timeshift_cam_imu_s - shift_s).abs() < 2e-4,
            "shift {}",
            result.timeshift_cam_imu_s
        );
        assert!(
            (result.gravity_m_s2 - gravity).norm() < 0.02,
            "gravity {}",
            result.gravity_m_s2
        );
        assert!(
            (result.accel_bias_m_s2 - accel_bias).norm() < 0.02,
            "accel bias {}",
            result.accel_bias_m_s2
        );
        assert!(
            (result.gyro_bias_rad_s - gyro_bias).norm() < 1e-3,
            "gyro bias {}",
            result.gyro_bias_rad_s
        );
    }

    #[test]
    fn basis_is_a_partition_of_unity_with_zero_second_derivative_sum() {
        for k in 0..=10 {
            let (b, d) = basis(k as f64 / 10.0);
            assert!((b.iter().sum::<f64>() - 1.0).abs() < 1e-15);
            assert!(d.iter().sum::<f64>().abs() < 1e-15);
        }
    }

    #[test]
    fn second_derivative_matches_finite_differences() {
        let h = 1e-4;
        for k in 1..10 {
            let u = k as f64 / 10.0;
            let (_, d) = basis(u);
            let (bm, _) = basis(u - h);
            let (b0, _) = basis(u);
            let (bp, _) = basis(u + h);
            for m in 0..4 {
                let fd = (bp[m] - 2.0 * b0[m] + bm[m]) / (h * h);
                assert!((fd - d[m]).abs() < 1e-5, "m {m} u {u}: {fd} vs {}", d[m]);
            }
        }
    }
}
