//! Smooth body motion with analytic derivatives: what the renderer samples
//! at camera stamps and the IMU synthesiser differentiates.
//!
//! Two sources: a built-in sum of sinusoids (position, yaw, pitch, roll),
//! and a recorded trajectory fitted with uniform cubic B-splines, the
//! position as an ordinary spline and the orientation as a cumulative
//! spline on SO(3) (Kim, Kim & Shin 1995; Lovegrove, Patron-Perez & Sibley
//! 2013, "Spline Fusion", eq. 4-6). Both are C2 in position, so velocity
//! and acceleration are continuous, and C1 in orientation, so the angular
//! rate is continuous.

use nalgebra::{Isometry3, Matrix3, Translation3, UnitQuaternion, Vector3};

use super::interpolated::InterpolatedMotion;
pub use super::motion_state::MotionState;
use crate::trajectory::Trajectory;

/// A motion defined on `[start_ns, end_ns]`.
#[derive(Debug, Clone)]
pub enum Motion {
    /// The built-in sinusoidal loop.
    Builtin(BuiltinMotion),
    /// A cubic B-spline fitted to recorded poses.
    Spline(SplineMotion),
    /// Recorded poses interpolated, no fit ([`super::interpolated`]).
    Interpolated(InterpolatedMotion),
}

impl Motion {
    /// First instant the motion is defined at, ns.
    pub fn start_ns(&self) -> i64 {
        match self {
            Motion::Builtin(m) => m.start_ns,
            Motion::Spline(m) => m.start_ns(),
            Motion::Interpolated(m) => m.start_ns(),
        }
    }
    /// Last instant the motion is defined at, ns.
    pub fn end_ns(&self) -> i64 {
        match self {
            Motion::Builtin(m) => m.start_ns + (m.duration_s * 1e9).round() as i64,
            Motion::Spline(m) => m.end_ns(),
            Motion::Interpolated(m) => m.end_ns(),
        }
    }
    /// State at `t_ns` (clamped to the defined span).
    pub fn state(&self, t_ns: i64) -> MotionState {
        let t_ns = t_ns.clamp(self.start_ns(), self.end_ns());
        match self {
            Motion::Builtin(m) => m.state(t_ns),
            Motion::Spline(m) => m.state(t_ns),
            Motion::Interpolated(m) => m.state(t_ns),
        }
    }
}

/// One sinusoid `amplitude * sin(omega * t + phase)`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sinusoid {
    /// Amplitude (m for a position, rad for an angle).
    pub amplitude: f64,
    /// Angular frequency, rad/s.
    pub omega_rad_s: f64,
    /// Phase at `t = 0` (the motion's start), rad.
    pub phase_rad: f64,
}

impl Sinusoid {
    const fn new(amplitude: f64, omega_rad_s: f64, phase_rad: f64) -> Self {
        Self {
            amplitude,
            omega_rad_s,
            phase_rad,
        }
    }
}

/// Value, first and second derivative of a sum of sinusoids at `t_s`.
fn sum_of_sines(terms: &[Sinusoid], t_s: f64) -> (f64, f64, f64) {
    terms.iter().fold((0.0, 0.0, 0.0), |(v, d, dd), s| {
        let arg = s.omega_rad_s * t_s + s.phase_rad;
        let (sin, cos) = arg.sin_cos();
        (
            v + s.amplitude * sin,
            d + s.amplitude * s.omega_rad_s * cos,
            dd - s.amplitude * s.omega_rad_s * s.omega_rad_s * sin,
        )
    })
}

/// The built-in motion: each position coordinate and each Euler angle
/// (yaw about world z, then pitch, then roll, of a forward-looking frame)
/// is a constant plus a sum of sinusoids. EuRoC-like: speeds up to about
/// 1 m/s, rotation rates up to about 1 rad/s.
#[derive(Debug, Clone, PartialEq)]
pub struct BuiltinMotion {
    /// Stamp of the motion's start, ns.
    pub start_ns: i64,
    /// Length, s.
    pub duration_s: f64,
    /// Constant part of the body position in the world frame, m.
    pub centre_m: Vector3<f64>,
    /// Sinusoids added to the x, y and z world position, m.
    pub position: [Vec<Sinusoid>; 3],
    /// Yaw, pitch, roll of the forward frame (x forward, z up), rad.
    pub angles: [Vec<Sinusoid>; 3],
}

/// Maps body (EuRoC IMU) axes into the forward frame: the EuRoC cameras
/// look along body z and their image "down" is body -x, so body x is up,
/// body z forward and body y to the right (the forward frame's -y).
fn forward_from_body() -> Matrix3<f64> {
    Matrix3::new(
        0.0, 0.0, 1.0, //
        0.0, -1.0, 0.0, //
        1.0, 0.0, 0.0,
    )
}

impl BuiltinMotion {
    /// The default loop of `duration_s` seconds, starting at `start_ns`.
    pub fn standard(start_ns: i64, duration_s: f64) -> Self {
        Self {
            start_ns,
            duration_s,
            centre_m: Vector3::new(0.0, 0.0, 1.3),
            position: [
                vec![Sinusoid::new(1.4, 0.42, 0.0), Sinusoid::new(0.25, 1.3, 0.7)],
                vec![Sinusoid::new(1.2, 0.31, 1.1), Sinusoid::new(0.3, 1.05, 2.0)],
                vec![Sinusoid::new(0.3, 0.55, 0.3), Sinusoid::new(0.08, 1.9, 1.4)],
            ],
            angles: [
                vec![Sinusoid::new(1.1, 0.33, 0.2), Sinusoid::new(0.25, 1.2, 0.9)],
                vec![Sinusoid::new(0.18, 0.6, 1.7), Sinusoid::new(0.06, 2.1, 0.4)],
                vec![
                    Sinusoid::new(0.15, 0.75, 2.5),
                    Sinusoid::new(0.05, 2.4, 1.2),
                ],
            ],
        }
    }

    fn state(&self, t_ns: i64) -> MotionState {
        let t_s = (t_ns - self.start_ns) as f64 * 1e-9;
        let mut p = self.centre_m;
        let mut v = Vector3::zeros();
        let mut a = Vector3::zeros();
        for axis in 0..3 {
            let (x, dx, ddx) = sum_of_sines(&self.position[axis], t_s);
            p[axis] += x;
            v[axis] = dx;
            a[axis] = ddx;
        }
        let (yaw, yaw_rate, _) = sum_of_sines(&self.angles[0], t_s);
        let (pitch, pitch_rate, _) = sum_of_sines(&self.angles[1], t_s);
        let (roll, roll_rate, _) = sum_of_sines(&self.angles[2], t_s);
        let rz = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw);
        let ry = UnitQuaternion::from_axis_angle(&Vector3::y_axis(), pitch);
        let rx = UnitQuaternion::from_axis_angle(&Vector3::x_axis(), roll);
        let r_world_forward = rz * ry * rx;
        // Angular rate of R = Rz(yaw) Ry(pitch) Rx(roll) in the world frame.
        let omega_world = Vector3::z() * yaw_rate
            + rz * (Vector3::y() * pitch_rate)
            + (rz * ry) * (Vector3::x() * roll_rate);
        let r_forward_body = UnitQuaternion::from_matrix(&forward_from_body());
        let r_world_body = r_world_forward * r_forward_body;
        MotionState {
            T_world_body: Isometry3::from_parts(Translation3::from(p), r_world_body),
            velocity_world_m_s: v,
            accel_world_m_s2: a,
            omega_body_rad_s: r_world_body.inverse() * omega_world,
        }
    }
}

/// Uniform cubic B-spline through control poses spaced `knot_spacing_s`.
///
/// Control pose `j` sits at `t0 + j * h`; segment `i` (control poses
/// `i..=i+3`) covers `[t0 + (i+1) h, t0 + (i+2) h)`.
#[derive(Debug, Clone)]
pub struct SplineMotion {
    t0_ns: i64,
    knot_spacing_s: f64,
    positions: Vec<Vector3<f64>>,
    rotations: Vec<UnitQuaternion<f64>>,
    /// `log(R_{j-1}^T R_j)` for j >= 1 (index 0 unused).
    deltas: Vec<Vector3<f64>>,
}

/// Why a trajectory cannot be turned into a spline.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum MotionError {
    #[error("trajectory has {0} poses; a spline needs at least 2 spanning 4 knot intervals")]
    /// Too few poses (the field is how many there are).
    TooShort(usize),
    #[error("trajectory stamps are not strictly increasing")]
    /// The stamps do not strictly increase.
    NotTimeOrdered,
    #[error("knot spacing must be positive and finite, got {0} s")]
    /// The knot spacing (the field, s) is not positive and finite.
    BadKnotSpacing(f64),
}

/// Cumulative cubic B-spline basis and its first two derivatives in u,
/// entries 1..=3 (entry 0 is identically 1).
fn cumulative_basis(u: f64) -> ([f64; 4], [f64; 4], [f64; 4]) {
    let u2 = u * u;
    let u3 = u2 * u;
    (
        [
            1.0,
            (5.0 + 3.0 * u - 3.0 * u2 + u3) / 6.0,
            (1.0 + 3.0 * u + 3.0 * u2 - 2.0 * u3) / 6.0,
            u3 / 6.0,
        ],
        [
            0.0,
            (3.0 - 6.0 * u + 3.0 * u2) / 6.0,
            (3.0 + 6.0 * u - 6.0 * u2) / 6.0,
            u2 / 2.0,
        ],
        [0.0, u - 1.0, 1.0 - 2.0 * u, u],
    )
}

fn knot_ns(t0_ns: i64, knot_spacing_s: f64, j: usize) -> i64 {
    t0_ns + (j as f64 * knot_spacing_s * 1e9).round() as i64
}

/// `log(R_{j-1}^T R_j)` for j >= 1, with a zero in front.
fn rotation_deltas(rotations: &[UnitQuaternion<f64>]) -> Vec<Vector3<f64>> {
    std::iter::once(Vector3::zeros())
        .chain(
            rotations
                .windows(2)
                .map(|w| (w[0].inverse() * w[1]).scaled_axis()),
        )
        .collect()
}

/// The trajectory at every knot `t0 + j h` of its span (linear position,
/// slerp orientation between the two poses around each knot).
#[allow(clippy::type_complexity)]
fn sample_at_knots(
    trajectory: &Trajectory,
    knot_spacing_s: f64,
) -> Result<(i64, Vec<Vector3<f64>>, Vec<UnitQuaternion<f64>>), MotionError> {
    if !(knot_spacing_s.is_finite() && knot_spacing_s > 0.0) {
        return Err(MotionError::BadKnotSpacing(knot_spacing_s));
    }
    let poses = &trajectory.poses;
    if poses.len() < 2 {
        return Err(MotionError::TooShort(poses.len()));
    }
    if !trajectory.is_time_ordered() {
        return Err(MotionError::NotTimeOrdered);
    }
    let t0_ns = poses[0].t_ns;
    let span_s = (poses[poses.len() - 1].t_ns - t0_ns) as f64 * 1e-9;
    let count = (span_s / knot_spacing_s).floor() as usize + 1;
    if count < 5 {
        return Err(MotionError::TooShort(poses.len()));
    }
    let mut positions = Vec::with_capacity(count);
    let mut rotations: Vec<UnitQuaternion<f64>> = Vec::with_capacity(count);
    let mut k = 0;
    for j in 0..count {
        let t_ns = knot_ns(t0_ns, knot_spacing_s, j);
        while k + 2 < poses.len() && poses[k + 1].t_ns <= t_ns {
            k += 1;
        }
        let (a, b) = (&poses[k], &poses[k + 1]);
        let s = ((t_ns - a.t_ns) as f64 / (b.t_ns - a.t_ns) as f64).clamp(0.0, 1.0);
        positions.push(a.position().lerp(&b.position(), s));
        let qa = a.orientation();
        let mut qb = b.orientation();
        if qa.coords.dot(&qb.coords) < 0.0 {
            qb = UnitQuaternion::new_unchecked(-qb.into_inner());
        }
        rotations.push(qa.slerp(&qb, s));
    }
    Ok((t0_ns, positions, rotations))
}

/// Control positions whose spline passes through `samples` at knots
/// `1..=n-2`: `P_{j-1} + 4 P_j + P_{j+1} = 6 G_j` there. The end control
/// points keep the samples' second difference, `P_0 - 2 P_1 + P_2 = G_0 -
/// 2 G_1 + G_2` (and the same at the far end), which an interpolant of a
/// smooth curve satisfies to O(h^4); with it the first equation gives `P_1
/// = G_1 - (G_0 - 2 G_1 + G_2) / 6` outright. The rest is a strictly
/// diagonally dominant tridiagonal system, solved by the Thomas algorithm.
fn interpolating_positions(samples: &[Vector3<f64>]) -> Vec<Vector3<f64>> {
    let n = samples.len();
    debug_assert!(n >= 5, "sample_at_knots gives at least 5");
    let g = samples;
    let second_difference = |j: usize| g[j - 1] - 2.0 * g[j] + g[j + 1];
    let mut p = vec![Vector3::zeros(); n];
    p[1] = g[1] - second_difference(1) / 6.0;
    p[n - 2] = g[n - 2] - second_difference(n - 2) / 6.0;
    // Unknowns P_2..=P_{n-3}: row r is knot r + 2, with the known P_1 and
    // P_{n-2} moved to the right-hand side.
    let m = n.saturating_sub(4);
    if m > 0 {
        let rhs = |r: usize| {
            let j = r + 2;
            let mut d = 6.0 * g[j];
            if j == 2 {
                d -= p[1];
            }
            if j == n - 3 {
                d -= p[n - 2];
            }
            d
        };
        // Forward sweep (diagonal 4, off-diagonals 1): c' and d'.
        let mut c = vec![0.0; m];
        let mut d = vec![Vector3::zeros(); m];
        c[0] = 0.25;
        d[0] = rhs(0) / 4.0;
        for r in 1..m {
            let denom = 4.0 - c[r - 1];
            c[r] = 1.0 / denom;
            d[r] = (rhs(r) - d[r - 1]) / denom;
        }
        p[m + 1] = d[m - 1];
        for r in (0..m - 1).rev() {
            p[r + 2] = d[r] - c[r] * p[r + 3];
        }
    }
    p[0] = second_difference(1) + 2.0 * p[1] - p[2];
    p[n - 1] = second_difference(n - 2) + 2.0 * p[n - 2] - p[n - 3];
    p
}

/// Orientation of the spline at knot `j` (1..=n-2): segment `j - 1` at u
/// = 0, `R_{j-1} exp(5/6 Omega_j) exp(1/6 Omega_{j+1})`.
fn rotation_at_knot(
    rotations: &[UnitQuaternion<f64>],
    deltas: &[Vector3<f64>],
    j: usize,
) -> UnitQuaternion<f64> {
    rotations[j - 1]
        * UnitQuaternion::from_scaled_axis(deltas[j] * (5.0 / 6.0))
        * UnitQuaternion::from_scaled_axis(deltas[j + 1] * (1.0 / 6.0))
}

/// Control rotations whose cumulative spline passes through `samples` at
/// knots `1..=n-2` (see [`SplineMotion::fit_through`]); the end
/// increments keep the samples' second difference, as the positions do.
fn interpolating_rotations(samples: &[UnitQuaternion<f64>]) -> Vec<UnitQuaternion<f64>> {
    const TOLERANCE_RAD: f64 = 1e-10;
    const MAX_SWEEPS: usize = 200;
    let n = samples.len();
    let sample_deltas = rotation_deltas(samples);
    let mut rotations = samples.to_vec();
    let mut residuals = vec![Vector3::zeros(); n];
    for _ in 0..MAX_SWEEPS {
        let deltas = rotation_deltas(&rotations);
        let mut worst = 0.0f64;
        for j in 1..n - 1 {
            let at_knot = rotation_at_knot(&rotations, &deltas, j);
            residuals[j] = (at_knot.inverse() * samples[j]).scaled_axis();
            worst = worst.max(residuals[j].norm());
        }
        if worst < TOLERANCE_RAD {
            break;
        }
        for j in 1..n - 1 {
            rotations[j] *= UnitQuaternion::from_scaled_axis(residuals[j]);
        }
        // The end increments keep the samples' second difference:
        // Omega_1 - Omega_2 = D_1 - D_2 and likewise at the far end.
        let omega_2 = (rotations[1].inverse() * rotations[2]).scaled_axis();
        rotations[0] = rotations[1]
            * UnitQuaternion::from_scaled_axis(-(omega_2 + sample_deltas[1] - sample_deltas[2]));
        let omega_last = (rotations[n - 3].inverse() * rotations[n - 2]).scaled_axis();
        rotations[n - 1] = rotations[n - 2]
            * UnitQuaternion::from_scaled_axis(
                omega_last + sample_deltas[n - 1] - sample_deltas[n - 2],
            );
    }
    rotations
}

impl SplineMotion {
    /// Fits control poses to a trajectory by sampling it (linear position,
    /// slerp orientation) every `knot_spacing_s`. The spline smooths the
    /// trajectory: with control poses on the curve it passes about
    /// `h^2/6` times the second derivative beside it (see
    /// [`SplineMotion::fit_through`] for a spline through the samples).
    pub fn fit(trajectory: &Trajectory, knot_spacing_s: f64) -> Result<Self, MotionError> {
        let (t0_ns, positions, rotations) = sample_at_knots(trajectory, knot_spacing_s)?;
        Ok(Self::from_control_poses(
            t0_ns,
            knot_spacing_s,
            positions,
            rotations,
        ))
    }

    /// Fits a spline that passes through the trajectory at every knot of
    /// its span (knots `1..=n-2` of the `n` sampled every
    /// `knot_spacing_s`), so that between knots it departs from the
    /// trajectory only by what a cubic cannot follow, `O(h^4)`.
    ///
    /// At knot `j` a uniform cubic B-spline is worth `(P_{j-1} + 4 P_j +
    /// P_{j+1}) / 6`; the positions solve that tridiagonal system, closed
    /// by end control points that keep the samples' second difference.
    /// Orientations have no linear system: each control
    /// rotation is corrected on the right by the residual `log(S_j^T G_j)`
    /// of the spline at its knot, all at once, until the largest residual
    /// is below 1e-10 rad (the linearised iteration contracts by 2/3 or
    /// better per sweep, as Jacobi on the same (1, 4, 1)/6 matrix does).
    pub fn fit_through(trajectory: &Trajectory, knot_spacing_s: f64) -> Result<Self, MotionError> {
        let (t0_ns, samples_p, samples_r) = sample_at_knots(trajectory, knot_spacing_s)?;
        let positions = interpolating_positions(&samples_p);
        let rotations = interpolating_rotations(&samples_r);
        Ok(Self::from_control_poses(
            t0_ns,
            knot_spacing_s,
            positions,
            rotations,
        ))
    }

    fn from_control_poses(
        t0_ns: i64,
        knot_spacing_s: f64,
        positions: Vec<Vector3<f64>>,
        rotations: Vec<UnitQuaternion<f64>>,
    ) -> Self {
        let deltas = rotation_deltas(&rotations);
        Self {
            t0_ns,
            knot_spacing_s,
            positions,
            rotations,
            deltas,
        }
    }

    /// Knot spacing, s.
    pub fn knot_spacing_s(&self) -> f64 {
        self.knot_spacing_s
    }

    /// Stamp of knot `j` (control pose `j`'s time), ns.
    pub fn knot_ns(&self, j: usize) -> i64 {
        knot_ns(self.t0_ns, self.knot_spacing_s, j)
    }

    /// Number of knots (control poses); the spline spans knots `1..=n-2`.
    pub fn knot_count(&self) -> usize {
        self.positions.len()
    }

    /// First instant the spline is defined at (knot 1), ns.
    pub fn start_ns(&self) -> i64 {
        self.t0_ns + (self.knot_spacing_s * 1e9).round() as i64
    }
    /// Last instant the spline is defined at (knot n-2), ns.
    pub fn end_ns(&self) -> i64 {
        self.t0_ns + ((self.positions.len() - 2) as f64 * self.knot_spacing_s * 1e9).round() as i64
    }

    fn state(&self, t_ns: i64) -> MotionState {
        let h = self.knot_spacing_s;
        let s = (t_ns - self.t0_ns) as f64 * 1e-9 / h - 1.0;
        let i = (s.floor().max(0.0) as usize).min(self.positions.len() - 4);
        let u = s - i as f64;
        let (b, db, ddb) = cumulative_basis(u);
        let mut p = self.positions[i];
        let mut v = Vector3::zeros();
        let mut a = Vector3::zeros();
        for j in 1..=3 {
            let dp = self.positions[i + j] - self.positions[i + j - 1];
            p += b[j] * dp;
            v += db[j] / h * dp;
            a += ddb[j] / h / h * dp;
        }
        // R = R_i A_1 A_2 A_3 with A_j = exp(b_j Omega_j); body rate
        // omega = (A_2 A_3)^T b1' Omega_1 + A_3^T b2' Omega_2 + b3' Omega_3.
        let factors: [UnitQuaternion<f64>; 4] = std::array::from_fn(|j| {
            if j == 0 {
                UnitQuaternion::identity()
            } else {
                UnitQuaternion::from_scaled_axis(self.deltas[i + j] * b[j])
            }
        });
        let r = self.rotations[i] * factors[1] * factors[2] * factors[3];
        let mut omega = Vector3::zeros();
        let mut tail = UnitQuaternion::identity();
        for j in (1..=3).rev() {
            omega += tail.inverse() * (self.deltas[i + j] * (db[j] / h));
            tail = factors[j] * tail;
        }
        MotionState {
            T_world_body: Isometry3::from_parts(Translation3::from(p), r),
            velocity_world_m_s: v,
            accel_world_m_s2: a,
            omega_body_rad_s: omega,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::trajectory::StampedPose;

    /// Central differences of position, velocity and orientation against
    /// the analytic velocity, acceleration and body rate.
    fn check_derivatives(m: &Motion, tol_v: f64, tol_a: f64, tol_w: f64) {
        let dt_ns = 100_000; // 0.1 ms
        let dt_s = dt_ns as f64 * 1e-9;
        let span = m.end_ns() - m.start_ns();
        for k in 1..40 {
            let t = m.start_ns() + span * k / 40 + 12_345;
            let (s0, s1, sm) = (m.state(t - dt_ns), m.state(t + dt_ns), m.state(t));
            let v_fd = (s1.T_world_body.translation.vector - s0.T_world_body.translation.vector)
                / (2.0 * dt_s);
            let a_fd = (s1.velocity_world_m_s - s0.velocity_world_m_s) / (2.0 * dt_s);
            let w_fd = (s0.T_world_body.rotation.inverse() * s1.T_world_body.rotation)
                .scaled_axis()
                / (2.0 * dt_s);
            assert!((v_fd - sm.velocity_world_m_s).norm() < tol_v, "v at {t}");
            assert!((a_fd - sm.accel_world_m_s2).norm() < tol_a, "a at {t}");
            assert!(
                (w_fd - sm.omega_body_rad_s).norm() < tol_w,
                "w at {t}: {w_fd} vs {}",
                sm.omega_body_rad_s
            );
        }
    }

    #[test]
    fn builtin_derivatives_match_finite_differences() {
        let m = Motion::Builtin(BuiltinMotion::standard(0, 30.0));
        check_derivatives(&m, 1e-6, 1e-5, 1e-6);
    }

    #[test]
    fn builtin_speeds_are_euroc_like() {
        let m = Motion::Builtin(BuiltinMotion::standard(0, 60.0));
        let (mut v_max, mut w_max) = (0.0f64, 0.0f64);
        for k in 0..6000 {
            let s = m.state(k * 10_000_000);
            v_max = v_max.max(s.velocity_world_m_s.norm());
            w_max = w_max.max(s.omega_body_rad_s.norm());
        }
        assert!((0.5..1.6).contains(&v_max), "v_max {v_max}");
        assert!((0.3..1.3).contains(&w_max), "w_max {w_max}");
    }

    #[test]
    fn builtin_cameras_look_horizontally_at_rest_angles() {
        // With all angles zero the body z axis (the EuRoC cameras' optical
        // axis) points along world x and body x (image up) along world z.
        let r = UnitQuaternion::from_matrix(&forward_from_body());
        assert!((r * Vector3::z() - Vector3::x()).norm() < 1e-12);
        assert!((r * Vector3::x() - Vector3::z()).norm() < 1e-12);
        assert!((r.to_rotation_matrix().matrix().determinant() - 1.0).abs() < 1e-12);
    }

    fn sampled(m: &Motion, rate_hz: f64, duration_s: f64) -> Trajectory {
        let n = (duration_s * rate_hz) as i64;
        Trajectory::new(
            (0..=n)
                .map(|k| {
                    let t = (k as f64 / rate_hz * 1e9) as i64;
                    StampedPose {
                        t_ns: t,
                        T_world_body: m.state(t).T_world_body,
                    }
                })
                .collect(),
        )
    }

    #[test]
    fn spline_derivatives_match_finite_differences() {
        let truth = Motion::Builtin(BuiltinMotion::standard(0, 20.0));
        let spline =
            Motion::Spline(SplineMotion::fit(&sampled(&truth, 200.0, 20.0), 0.05).unwrap());
        check_derivatives(&spline, 1e-5, 1e-3, 1e-5);
    }

    #[test]
    fn spline_reproduces_a_smooth_trajectory() {
        // A uniform cubic B-spline with control points on a smooth curve
        // deviates by h^2/6 |p''| + O(h^4) (at a knot it is (P_-1 + 4 P_0 +
        // P_1) / 6 = P_0 + h^2/6 p''): bound it with the largest |p''| of
        // the curve and 10% for the higher-order terms.
        let h_s = 0.05;
        let truth = Motion::Builtin(BuiltinMotion::standard(0, 20.0));
        let a_max = (0..2000)
            .map(|k| truth.state(k * 10_000_000).accel_world_m_s2.norm())
            .fold(0.0, f64::max);
        let position_bound = 1.1 * h_s * h_s / 6.0 * a_max;
        let spline = SplineMotion::fit(&sampled(&truth, 200.0, 20.0), h_s).unwrap();
        let m = Motion::Spline(spline);
        let mut worst_p = 0.0f64;
        let mut worst_r = 0.0f64;
        let mut worst_v = 0.0f64;
        for k in 0..400 {
            let t = m.start_ns() + (m.end_ns() - m.start_ns()) * k / 400;
            let (a, b) = (m.state(t), truth.state(t));
            worst_p = worst_p.max(
                (a.T_world_body.translation.vector - b.T_world_body.translation.vector).norm(),
            );
            worst_r = worst_r.max(a.T_world_body.rotation.angle_to(&b.T_world_body.rotation));
            worst_v = worst_v.max((a.velocity_world_m_s - b.velocity_world_m_s).norm());
        }
        assert!(
            worst_p < position_bound,
            "position {worst_p} >= {position_bound}"
        );
        assert!(worst_r < 5e-4, "rotation {worst_r}");
        assert!(worst_v < 5e-3, "velocity {worst_v}");
    }

    #[test]
    fn fit_through_passes_through_the_samples_at_its_knots() {
        // Control poses on the curve leave the spline ~h^2/6 |p''| (about a
        // millimetre here) off the samples; the interpolating fit must hit
        // them to rounding, at every knot of its span including both ends.
        let truth = Motion::Builtin(BuiltinMotion::standard(0, 20.0));
        let trajectory = sampled(&truth, 200.0, 20.0);
        for h_s in [0.05, 0.02] {
            let spline = SplineMotion::fit_through(&trajectory, h_s).unwrap();
            let m = Motion::Spline(spline.clone());
            assert_eq!(m.start_ns(), spline.knot_ns(1));
            assert_eq!(m.end_ns(), spline.knot_ns(spline.knot_count() - 2));
            let (mut worst_p, mut worst_r) = (0.0f64, 0.0f64);
            for j in 1..spline.knot_count() - 1 {
                let t = spline.knot_ns(j);
                // The samples are exact states of `truth` at 5 ms steps and
                // every knot falls on one of them.
                assert_eq!(t % 5_000_000, 0);
                let (a, b) = (m.state(t).T_world_body, truth.state(t).T_world_body);
                worst_p = worst_p.max((a.translation.vector - b.translation.vector).norm());
                worst_r = worst_r.max(a.rotation.angle_to(&b.rotation));
            }
            assert!(worst_p < 1e-9, "h {h_s}: position {worst_p} m at a knot");
            assert!(worst_r < 1e-9, "h {h_s}: rotation {worst_r} rad at a knot");
        }
        // The test can tell the two fits apart.
        let smoothing = Motion::Spline(SplineMotion::fit(&trajectory, 0.05).unwrap());
        let t = smoothing.start_ns() + 1_000_000_000;
        let off = (smoothing.state(t).T_world_body.translation.vector
            - truth.state(t).T_world_body.translation.vector)
            .norm();
        assert!(off > 1e-5, "the smoothing fit is {off} m off at a knot");
    }

    #[test]
    fn fit_through_derivatives_match_finite_differences() {
        let truth = Motion::Builtin(BuiltinMotion::standard(0, 20.0));
        let trajectory = sampled(&truth, 200.0, 20.0);
        for h_s in [0.05, 0.01] {
            let spline = Motion::Spline(SplineMotion::fit_through(&trajectory, h_s).unwrap());
            check_derivatives(&spline, 1e-5, 1e-3, 1e-5);
        }
    }

    #[test]
    fn fit_through_follows_a_smooth_trajectory_between_knots() {
        // Through the samples, the error between knots is O(h^4) times the
        // fourth derivative: for the built-in motion and h = 0.05 s about
        // 1e-7 m and 1e-7 rad (measured 8.6e-8, 1.9e-7), against 3e-4 for
        // the smoothing fit; velocity and body rate, O(h^3), about 1e-5
        // (7.3e-6 m/s, 1.3e-5 rad/s) against 4e-4.
        let truth = Motion::Builtin(BuiltinMotion::standard(0, 20.0));
        let trajectory = sampled(&truth, 200.0, 20.0);
        let worst = |m: &Motion| {
            let (mut p, mut r, mut v, mut w) = (0.0f64, 0.0f64, 0.0f64, 0.0f64);
            for k in 0..997 {
                let t = m.start_ns() + (m.end_ns() - m.start_ns()) * k / 997;
                let (a, b) = (m.state(t), truth.state(t));
                p = p.max(
                    (a.T_world_body.translation.vector - b.T_world_body.translation.vector).norm(),
                );
                r = r.max(a.T_world_body.rotation.angle_to(&b.T_world_body.rotation));
                v = v.max((a.velocity_world_m_s - b.velocity_world_m_s).norm());
                w = w.max((a.omega_body_rad_s - b.omega_body_rad_s).norm());
            }
            [p, r, v, w]
        };
        let through = worst(&Motion::Spline(
            SplineMotion::fit_through(&trajectory, 0.05).unwrap(),
        ));
        let smoothing = worst(&Motion::Spline(
            SplineMotion::fit(&trajectory, 0.05).unwrap(),
        ));
        assert!(through[0] < 1e-6, "position {} m", through[0]);
        assert!(through[1] < 1e-6, "rotation {} rad", through[1]);
        assert!(through[2] < 3e-5, "velocity {} m/s", through[2]);
        assert!(through[3] < 5e-5, "body rate {} rad/s", through[3]);
        for (k, name) in ["position", "rotation", "velocity", "body rate"]
            .iter()
            .enumerate()
        {
            assert!(
                through[k] < 0.1 * smoothing[k],
                "{name}: through {} vs smoothing {}",
                through[k],
                smoothing[k]
            );
        }
    }

    #[test]
    fn spline_rejects_bad_input() {
        let one = Trajectory::new(vec![StampedPose::new(
            0,
            Vector3::zeros(),
            UnitQuaternion::identity(),
        )]);
        assert_eq!(
            SplineMotion::fit(&one, 0.05).unwrap_err(),
            MotionError::TooShort(1)
        );
        let truth = Motion::Builtin(BuiltinMotion::standard(0, 2.0));
        assert!(matches!(
            SplineMotion::fit(&sampled(&truth, 200.0, 2.0), 0.0),
            Err(MotionError::BadKnotSpacing(_))
        ));
    }
}
