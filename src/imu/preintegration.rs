//! On-manifold preintegration of the IMU between two frames.
//!
//! Rotation, velocity and position deltas in the body frame at the
//! interval's start, reset at each frame (the paper's inter-frame
//! integration, eq. 21-28): the rotation is advanced by the angle-axis
//! exponential of the integrated rate, the velocity and position by the
//! integrals of the rotated specific force, with the biases held constant
//! over the interval. The integrals use one of three rules per sample step
//! ([`IntegrationScheme`]), the paper's being the quadratic one (eq. 25, see
//! [`super::quadrature`]).
//!
//! Alongside the deltas, the 9x9 covariance of `[dphi, dv, dp]` is
//! propagated step by step from the continuous-time noise densities
//! (divided by each step's actual length), and the first-order Jacobians of
//! the deltas with respect to the biases are accumulated, so a bias change
//! is applied without integrating again (Forster et al., "On-Manifold
//! Preintegration for Real-Time Visual-Inertial Odometry", TRO 2017,
//! sec. V-VI and appendix; the linearisation is generalised here from a
//! single held sample to the weighted nodes of each rule).
//!
//! Conventions: `dphi` perturbs the rotation on the right
//! (`dR Exp(dphi)`), `dv` and `dp` add in the start body frame.

use nalgebra::{Matrix3, SMatrix, UnitQuaternion, Vector3};

use super::interval::ImuInterval;
use super::quadrature::{choose_triple, euler_rule, interpolating_rule, StepRule};
use super::so3::{exp, exp_and_right_jacobian, hat, right_jacobian};
use super::strapdown::{ImuBiases, NavState};
use crate::rig::ImuNoise;
use crate::sensors::ImuSample;

/// 9x9 matrix over `[dphi, dv, dp]` (rad, m/s, m), the preintegration's covariance layout.
pub type Matrix9 = SMatrix<f64, 9, 9>;

/// How each step between two samples is integrated.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum IntegrationScheme {
    /// Each sample held until the next one, rotation at the step's start
    /// (GTSAM's and Forster's discretisation).
    Euler,
    /// The linear interpolant between the step's two samples integrated
    /// exactly: midpoint rate for the rotation, trapezoid for velocity.
    Midpoint,
    /// The paper's rule (eq. 25): the quadratic interpolant through three
    /// unevenly spaced samples integrated exactly; falls back to
    /// [`IntegrationScheme::Midpoint`] on a step with no well-spaced triple.
    Quadratic,
}

impl IntegrationScheme {
    /// Every scheme, in the order `euler`, `midpoint`, `quadratic` (for sweeps and option lists).
    pub const ALL: [IntegrationScheme; 3] = [Self::Euler, Self::Midpoint, Self::Quadratic];

    /// Lower-case name as the command line and settings files spell it.
    pub fn name(self) -> &'static str {
        match self {
            Self::Euler => "euler",
            Self::Midpoint => "midpoint",
            Self::Quadratic => "quadratic",
        }
    }
}

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
/// Why an interval could not be preintegrated.
pub enum PreintegrationError {
    #[error("interval ends at {t_end_ns} ns, not after its start {t_start_ns} ns")]
    /// The interval's end is not after its start.
    EmptyInterval {
        /// Interval start, ns.
        t_start_ns: i64,
        /// Interval end, ns.
        t_end_ns: i64,
    },
    #[error(
        "samples span {first_ns}..{last_ns} ns, which does not cover the interval \
         {t_start_ns}..{t_end_ns} ns"
    )]
    /// The samples do not reach back to the interval's start or forward to its end.
    NotCovered {
        /// Interval start, ns.
        t_start_ns: i64,
        /// Interval end, ns.
        t_end_ns: i64,
        /// Stamp of the first sample given, ns.
        first_ns: i64,
        /// Stamp of the last sample given, ns.
        last_ns: i64,
    },
    #[error("IMU sample {index} at {t_ns} ns is not finite")]
    /// A sample has a NaN or infinite value.
    NotFinite {
        /// Its index in the samples given.
        index: usize,
        /// Its stamp, ns.
        t_ns: i64,
    },
    #[error("IMU sample {index} at {t_ns} ns does not come after the previous one")]
    /// A sample's stamp is not after the previous sample's.
    NotIncreasing {
        /// Its index in the samples given.
        index: usize,
        /// Its stamp, ns.
        t_ns: i64,
    },
}

/// The preintegrated measurement of one interval.
#[allow(non_snake_case)]
#[derive(Debug, Clone, PartialEq)]
pub struct Preintegrated {
    /// Interval start (the earlier frame's stamp), ns.
    pub t_start_ns: i64,
    /// Interval end (the later frame's stamp), ns.
    pub t_end_ns: i64,
    /// Interval length, s.
    pub dt_s: f64,
    /// Rule the steps were integrated with.
    pub scheme: IntegrationScheme,
    /// The biases the deltas were integrated with (the linearisation point
    /// of the bias Jacobians).
    pub biases: ImuBiases,
    /// Rotation of the end body frame in the start body frame.
    pub delta_R: Matrix3<f64>,
    /// Velocity change in the start body frame, gravity excluded, m/s.
    pub delta_v_m_s: Vector3<f64>,
    /// Position change in the start body frame, gravity and initial velocity excluded, m.
    pub delta_p_m: Vector3<f64>,
    /// Covariance of `[dphi, dv, dp]` from the white measurement noise.
    pub covariance: Matrix9,
    /// The gyroscope's share of `covariance` (the rest is the
    /// accelerometer's): the propagation is linear in the two noise
    /// variances, so scaling the densities by `s_g` and `s_a` gives
    /// `s_g^2 covariance_gyro + s_a^2 (covariance - covariance_gyro)`
    /// without integrating again ([`Self::scaled_covariance`]).
    pub covariance_gyro: Matrix9,
    /// Jacobian of the rotation delta with respect to the gyro bias: `delta_R(bg + d) = delta_R
    /// Exp(d_R_d_bg d)`, rad per rad/s.
    pub d_R_d_bg: Matrix3<f64>,
    /// Jacobian of `delta_v_m_s` with respect to the gyro bias, m/s per rad/s.
    pub d_v_d_bg: Matrix3<f64>,
    /// Jacobian of `delta_v_m_s` with respect to the accel bias, s.
    pub d_v_d_ba: Matrix3<f64>,
    /// Jacobian of `delta_p_m` with respect to the gyro bias, m per rad/s.
    pub d_p_d_bg: Matrix3<f64>,
    /// Jacobian of `delta_p_m` with respect to the accel bias, s^2.
    pub d_p_d_ba: Matrix3<f64>,
    /// Sample steps integrated (partial ones at the ends included).
    pub steps: usize,
    /// False when the interval's samples were damaged (see
    /// [`super::interval::IntervalReport`]); the deltas are then the best
    /// that could be made of what was left.
    pub reliable: bool,
}

/// Deltas corrected to other biases to first order.
#[allow(non_snake_case)]
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CorrectedDeltas {
    /// Rotation of the end body frame in the start body frame.
    pub delta_R: Matrix3<f64>,
    /// Velocity change in the start body frame, gravity excluded, m/s.
    pub delta_v_m_s: Vector3<f64>,
    /// Position change in the start body frame, gravity and initial velocity excluded, m.
    pub delta_p_m: Vector3<f64>,
}

impl Preintegrated {
    /// The covariance had the gyroscope's and the accelerometer's noise
    /// densities been `gyro_scale` and `accel_scale` times those
    /// integrated with.
    pub fn scaled_covariance(&self, gyro_scale: f64, accel_scale: f64) -> Matrix9 {
        let accel = self.covariance - self.covariance_gyro;
        self.covariance_gyro * gyro_scale.powi(2) + accel * accel_scale.powi(2)
    }

    /// The deltas for `biases` instead of the integration biases, by the
    /// bias Jacobians (Forster eq. 44), without integrating again.
    pub fn corrected(&self, biases: &ImuBiases) -> CorrectedDeltas {
        let dbg = biases.gyro_rad_s - self.biases.gyro_rad_s;
        let dba = biases.accel_m_s2 - self.biases.accel_m_s2;
        CorrectedDeltas {
            delta_R: self.delta_R * exp(&(self.d_R_d_bg * dbg)),
            delta_v_m_s: self.delta_v_m_s + self.d_v_d_bg * dbg + self.d_v_d_ba * dba,
            delta_p_m: self.delta_p_m + self.d_p_d_bg * dbg + self.d_p_d_ba * dba,
        }
    }

    /// The state at the interval's end from the state at its start
    /// (Forster eq. 33 with the deltas corrected to `biases`).
    pub fn predict(
        &self,
        start: &NavState,
        biases: &ImuBiases,
        gravity_world_m_s2: &Vector3<f64>,
    ) -> NavState {
        let d = self.corrected(biases);
        let r_i = start.R_world_body.to_rotation_matrix().into_inner();
        let t = self.dt_s;
        NavState {
            t_ns: self.t_end_ns,
            R_world_body: UnitQuaternion::from_matrix(&(r_i * d.delta_R)),
            velocity_world_m_s: start.velocity_world_m_s
                + gravity_world_m_s2 * t
                + r_i * d.delta_v_m_s,
            position_world_m: start.position_world_m
                + start.velocity_world_m_s * t
                + gravity_world_m_s2 * (0.5 * t * t)
                + r_i * d.delta_p_m,
        }
    }
}

/// One step of the forward pass, kept for the second.
#[derive(Debug, Clone, Copy)]
struct Step {
    rule: StepRule,
    h_s: f64,
    /// Rotation and its gyro-bias Jacobian at the step's start.
    rot_lo: Matrix3<f64>,
    jac_lo: Matrix3<f64>,
    /// Exponential and right Jacobian of the step's rotation increment.
    exp_theta: Matrix3<f64>,
    jr_theta: Matrix3<f64>,
}

/// Integrates intervals; owns its scratch buffers so that integrating
/// allocates nothing once they have grown.
#[derive(Debug, Clone)]
pub struct Preintegrator {
    /// Rule each sample step is integrated with.
    pub scheme: IntegrationScheme,
    /// Continuous-time noise densities the covariance is propagated from.
    pub noise: ImuNoise,
    steps: Vec<Step>,
    /// Rotation from the start frame and its gyro-bias Jacobian at each
    /// sample the rules use, by sample index.
    node_rot: Vec<Matrix3<f64>>,
    node_jac: Vec<Matrix3<f64>>,
    /// Per node: rotated specific force `R (a - b_a)` and its gyro-bias
    /// sensitivity `-R [a - b_a]x J`, made once, used by up to three steps.
    node_force: Vec<Vector3<f64>>,
    node_force_bg: Vec<Matrix3<f64>>,
}

/// 3x3 blocks of the symmetric 9x9 covariance, row-major over (phi, v, p).
type Blocks = [[Matrix3<f64>; 3]; 3];

impl Preintegrator {
    /// A preintegrator with empty scratch buffers.
    pub fn new(scheme: IntegrationScheme, noise: ImuNoise) -> Self {
        Self {
            scheme,
            noise,
            steps: Vec::new(),
            node_rot: Vec::new(),
            node_jac: Vec::new(),
            node_force: Vec::new(),
            node_force_bg: Vec::new(),
        }
    }

    /// Preintegrates `samples` over `[t_start_ns, t_end_ns]` with constant
    /// `biases`. The samples must be finite with increasing stamps, one at or
    /// before the start and one at or after the end; one more on either side
    /// lets the quadratic rule use a centred triple at the ends.
    pub fn integrate(
        &mut self,
        samples: &[ImuSample],
        t_start_ns: i64,
        t_end_ns: i64,
        biases: &ImuBiases,
    ) -> Result<Preintegrated, PreintegrationError> {
        check_samples(samples, t_start_ns, t_end_ns)?;
        let n = samples.len();
        let k0 = samples.partition_point(|s| s.t_ns <= t_start_ns) - 1;
        let k1 = samples.partition_point(|s| s.t_ns < t_end_ns);
        let bg = biases.gyro_rad_s;
        let ba = biases.accel_m_s2;
        let needs_nodes = self.scheme != IntegrationScheme::Euler;
        if needs_nodes {
            self.node_rot.resize(n, Matrix3::zeros());
            self.node_jac.resize(n, Matrix3::zeros());
            self.node_force.resize(n, Vector3::zeros());
            self.node_force_bg.resize(n, Matrix3::zeros());
        }

        // Pass 1: rotation and its bias Jacobian, step by step.
        self.steps.clear();
        let mut rot = Matrix3::identity();
        let mut jac = Matrix3::zeros();
        for k in k0..k1 {
            let lo = samples[k].t_ns.max(t_start_ns);
            let hi = samples[k + 1].t_ns.min(t_end_ns);
            let rule = self.rule(samples, k, lo, hi);
            let h_s = (hi - lo) as f64 * 1e-9;
            let theta = rate_integral(&rule, samples, &bg);
            let (e, jr) = exp_and_right_jacobian(&theta);
            self.steps.push(Step {
                rule,
                h_s,
                rot_lo: rot,
                jac_lo: jac,
                exp_theta: e,
                jr_theta: jr,
            });
            jac = e.transpose() * jac - jr * h_s;
            rot *= e;
            if needs_nodes && hi == samples[k + 1].t_ns {
                self.node_rot[k + 1] = rot;
                self.node_jac[k + 1] = jac;
            }
        }
        let (rot_end, jac_end) = (rot, jac);
        if needs_nodes {
            self.fill_outer_nodes(samples, k0, k1, t_start_ns, t_end_ns, &bg, rot_end, jac_end);
            let used = k0.saturating_sub(1)..(k1 + 2).min(n);
            for (k, sample) in samples.iter().enumerate().take(used.end).skip(used.start) {
                let a = Vector3::from(sample.accel_m_s2) - ba;
                let r = &self.node_rot[k];
                self.node_force[k] = r * a;
                self.node_force_bg[k] = -(r * hat(&a)) * self.node_jac[k];
            }
        }

        // Pass 2: velocity, position, bias Jacobians and covariance.
        let var_g = self.noise.gyroscope_noise_density.powi(2);
        let var_a = self.noise.accelerometer_noise_density.powi(2);
        let mut dv = Vector3::zeros();
        let mut dp = Vector3::zeros();
        let (mut dv_dbg, mut dv_dba) = (Matrix3::zeros(), Matrix3::zeros());
        let (mut dp_dbg, mut dp_dba) = (Matrix3::zeros(), Matrix3::zeros());
        let mut cov: Blocks = [[Matrix3::zeros(); 3]; 3];
        let mut cov_gyro: Blocks = [[Matrix3::zeros(); 3]; 3];
        for step in &self.steps {
            let h = step.h_s;
            // Weighted sums over the rule's nodes: rotated specific force,
            // the rotations themselves, and the bias sensitivities.
            let mut inc_v = Vector3::zeros();
            let mut inc_p = Vector3::zeros();
            let mut rot_v = Matrix3::zeros();
            let mut rot_p = Matrix3::zeros();
            let mut inc_v_bg = Matrix3::zeros();
            let mut inc_p_bg = Matrix3::zeros();
            let rule = &step.rule;
            if needs_nodes {
                for m in 0..rule.count {
                    let k = rule.nodes[m];
                    let (w1, w2) = (rule.single[m], rule.double[m]);
                    let r = &self.node_rot[k];
                    inc_v += self.node_force[k] * w1;
                    inc_p += self.node_force[k] * w2;
                    rot_v += r * w1;
                    rot_p += r * w2;
                    inc_v_bg += self.node_force_bg[k] * w1;
                    inc_p_bg += self.node_force_bg[k] * w2;
                }
            } else {
                // Euler: the held sample, rotated at the step's start.
                let a = Vector3::from(samples[rule.nodes[0]].accel_m_s2) - ba;
                let f = step.rot_lo * a;
                let f_bg = -(step.rot_lo * hat(&a)) * step.jac_lo;
                let (w1, w2) = (rule.single[0], rule.double[0]);
                inc_v = f * w1;
                inc_p = f * w2;
                rot_v = step.rot_lo * w1;
                rot_p = step.rot_lo * w2;
                inc_v_bg = f_bg * w1;
                inc_p_bg = f_bg * w2;
            }
            let transition = (
                step.exp_theta.transpose(),
                hat(&inc_v) * step.rot_lo,
                hat(&inc_p) * step.rot_lo,
            );
            for c in [&mut cov, &mut cov_gyro] {
                propagate_covariance(c, &transition.0, &transition.1, &transition.2, h);
            }
            let jr = &step.jr_theta;
            let gyro_noise = jr * jr.transpose() * (var_g * h);
            cov[0][0] += gyro_noise;
            cov_gyro[0][0] += gyro_noise;
            let qa = var_a / h;
            cov[1][1] += rot_v * rot_v.transpose() * qa;
            cov[1][2] += rot_v * rot_p.transpose() * qa;
            cov[2][2] += rot_p * rot_p.transpose() * qa;

            dp_dba += dv_dba * h - rot_p;
            dp_dbg += dv_dbg * h + inc_p_bg;
            dv_dba -= rot_v;
            dv_dbg += inc_v_bg;
            dp += dv * h + inc_p;
            dv += inc_v;
        }
        let (covariance, covariance_gyro) = (symmetric(&cov), symmetric(&cov_gyro));
        Ok(Preintegrated {
            t_start_ns,
            t_end_ns,
            dt_s: (t_end_ns - t_start_ns) as f64 * 1e-9,
            scheme: self.scheme,
            biases: *biases,
            delta_R: rot_end,
            delta_v_m_s: dv,
            delta_p_m: dp,
            covariance,
            covariance_gyro,
            d_R_d_bg: jac_end,
            d_v_d_bg: dv_dbg,
            d_v_d_ba: dv_dba,
            d_p_d_bg: dp_dbg,
            d_p_d_ba: dp_dba,
            steps: self.steps.len(),
            reliable: true,
        })
    }

    /// Preintegrates an interval cut from an [`super::ImuStream`]; the
    /// result is marked unreliable when the interval's report says so.
    pub fn integrate_interval(
        &mut self,
        interval: &ImuInterval<'_>,
        biases: &ImuBiases,
    ) -> Result<Preintegrated, PreintegrationError> {
        let mut pre = self.integrate(
            interval.samples,
            interval.t_start_ns,
            interval.t_end_ns,
            biases,
        )?;
        pre.reliable = interval.report.reliable;
        Ok(pre)
    }

    /// The rule for the part `[lo, hi]` of the raw step `k` (between
    /// samples k and k+1).
    fn rule(&self, samples: &[ImuSample], k: usize, lo: i64, hi: i64) -> StepRule {
        let h_s = (hi - lo) as f64 * 1e-9;
        let tau = |i: usize| (samples[i].t_ns - lo) as f64 * 1e-9;
        let triple = match self.scheme {
            IntegrationScheme::Euler => return euler_rule(k, h_s),
            IntegrationScheme::Midpoint => None,
            IntegrationScheme::Quadratic => choose_triple(|i| samples[i].t_ns, k, samples.len()),
        };
        match triple {
            Some(t) => interpolating_rule(&t, &[tau(t[0]), tau(t[1]), tau(t[2])], h_s),
            None => interpolating_rule(&[k, k + 1], &[tau(k), tau(k + 1)], h_s),
        }
    }

    /// Rotations at the samples just outside the interval that the rules
    /// reach: backwards from the start (`Exp(-theta)`) and forwards from
    /// the end, with their gyro-bias Jacobians.
    #[allow(clippy::too_many_arguments)]
    fn fill_outer_nodes(
        &mut self,
        samples: &[ImuSample],
        k0: usize,
        k1: usize,
        t_start_ns: i64,
        t_end_ns: i64,
        bg: &Vector3<f64>,
        rot_end: Matrix3<f64>,
        jac_end: Matrix3<f64>,
    ) {
        // Backwards: R_k = R_k+1 Exp(theta)^T, J_k = Exp(theta) J_k+1 + J_r(-theta) h.
        let (mut rot, mut jac) = (Matrix3::identity(), Matrix3::zeros());
        let (mut k, mut hi) = (k0, t_start_ns);
        loop {
            let lo = samples[k].t_ns;
            if lo < hi {
                let rule = self.rule(samples, k, lo, hi);
                let h_s = (hi - lo) as f64 * 1e-9;
                let theta = rate_integral(&rule, samples, bg);
                let e = exp(&theta);
                jac = e * jac + right_jacobian(&-theta) * h_s;
                rot *= e.transpose();
            }
            self.node_rot[k] = rot;
            self.node_jac[k] = jac;
            if k == 0 || k + 1 == k0 {
                break;
            }
            hi = lo;
            k -= 1;
        }
        // Forwards from the end to k1 and one more.
        let (mut rot, mut jac) = (rot_end, jac_end);
        let mut lo = t_end_ns;
        for k in k1..(k1 + 2).min(samples.len()) {
            let hi = samples[k].t_ns;
            if lo < hi {
                let rule = self.rule(samples, k - 1, lo, hi);
                let h_s = (hi - lo) as f64 * 1e-9;
                let theta = rate_integral(&rule, samples, bg);
                let e = exp(&theta);
                jac = e.transpose() * jac - right_jacobian(&theta) * h_s;
                rot *= e;
            }
            self.node_rot[k] = rot;
            self.node_jac[k] = jac;
            lo = hi;
        }
    }
}

/// `int omega - b_g` over the rule's step.
fn rate_integral(rule: &StepRule, samples: &[ImuSample], bg: &Vector3<f64>) -> Vector3<f64> {
    let mut theta = Vector3::zeros();
    for m in 0..rule.count {
        theta += (Vector3::from(samples[rule.nodes[m]].gyro_rad_s) - bg) * rule.single[m];
    }
    theta
}

/// The symmetric 9x9 matrix of its upper blocks.
fn symmetric(blocks: &Blocks) -> Matrix9 {
    let mut m = Matrix9::zeros();
    for (r, row) in blocks.iter().enumerate() {
        for (c, block) in row.iter().enumerate().skip(r) {
            m.fixed_view_mut::<3, 3>(3 * r, 3 * c).copy_from(block);
            m.fixed_view_mut::<3, 3>(3 * c, 3 * r)
                .copy_from(&block.transpose());
        }
    }
    m
}

/// `P <- A P A^T` for the step's transition
/// `A = [[E, 0, 0], [-Cv, I, 0], [-Cp, h I, I]]`, i.e. `phi' = E phi`,
/// `v' = v - Cv phi`, `p' = p + h v - Cp phi`, written out by blocks
/// (about a fifth of the dense 9x9 product's multiplications).
fn propagate_covariance(
    p: &mut Blocks,
    e: &Matrix3<f64>,
    c_v: &Matrix3<f64>,
    c_p: &Matrix3<f64>,
    h: f64,
) {
    let (p_ff, p_fv, p_fp) = (p[0][0], p[0][1], p[0][2]);
    let (p_vv, p_vp, p_pp) = (p[1][1], p[1][2], p[2][2]);
    // Cov(phi, v') and Cov(phi, p') before phi is rotated by E.
    let g_fv = p_fv - p_ff * c_v.transpose();
    let g_fp = p_fp + p_fv * h - p_ff * c_p.transpose();
    // Cov(v, v') and Cov(v, p'), and Cov(p, p').
    let g_vv = p_vv - p_fv.transpose() * c_v.transpose();
    let g_vp = p_vp + p_vv * h - p_fv.transpose() * c_p.transpose();
    let g_pp = p_pp + p_vp.transpose() * h - p_fp.transpose() * c_p.transpose();
    p[0][0] = e * p_ff * e.transpose();
    p[0][1] = e * g_fv;
    p[0][2] = e * g_fp;
    let vv = g_vv - c_v * g_fv;
    p[1][1] = (vv + vv.transpose()) * 0.5;
    p[1][2] = g_vp - c_v * g_fp;
    let pp = g_pp + g_vp * h - c_p * g_fp;
    p[2][2] = (pp + pp.transpose()) * 0.5;
}

fn check_samples(
    samples: &[ImuSample],
    t_start_ns: i64,
    t_end_ns: i64,
) -> Result<(), PreintegrationError> {
    if t_end_ns <= t_start_ns {
        return Err(PreintegrationError::EmptyInterval {
            t_start_ns,
            t_end_ns,
        });
    }
    for (index, s) in samples.iter().enumerate() {
        if !s.is_finite() {
            return Err(PreintegrationError::NotFinite {
                index,
                t_ns: s.t_ns,
            });
        }
        if index > 0 && s.t_ns <= samples[index - 1].t_ns {
            return Err(PreintegrationError::NotIncreasing {
                index,
                t_ns: s.t_ns,
            });
        }
    }
    match (samples.first(), samples.last()) {
        (Some(first), Some(last)) if first.t_ns <= t_start_ns && last.t_ns >= t_end_ns => Ok(()),
        (first, last) => Err(PreintegrationError::NotCovered {
            t_start_ns,
            t_end_ns,
            first_ns: first.map_or(i64::MAX, |s| s.t_ns),
            last_ns: last.map_or(i64::MIN, |s| s.t_ns),
        }),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::imu::so3::log;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;
    use rand_distr::StandardNormal;

    const NOISE: ImuNoise = ImuNoise::EUROC_ADIS16448;

    /// A smooth motion: body rates and specific force as functions of time.
    fn gyro(t: f64) -> Vector3<f64> {
        Vector3::new(0.8 * (3.0 * t).sin(), -0.5 + 0.6 * t, 1.2 * (2.0 * t).cos())
    }
    fn accel(t: f64) -> Vector3<f64> {
        Vector3::new(0.3 + (5.0 * t).sin(), 9.81 * (t).cos(), -2.0 * t * t + 0.4)
    }

    /// Samples at ~200 Hz with jittered, uneven stamps over [-0.02, 0.14] s.
    fn samples(seed: u64) -> Vec<ImuSample> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut out = Vec::new();
        let mut t_ns: i64 = -20_000_000;
        while t_ns < 140_000_000 {
            let t = t_ns as f64 * 1e-9;
            out.push(ImuSample {
                t_ns,
                gyro_rad_s: gyro(t).into(),
                accel_m_s2: accel(t).into(),
            });
            t_ns += rng.gen_range(3_000_000..7_000_000);
        }
        out
    }

    fn biases() -> ImuBiases {
        ImuBiases {
            gyro_rad_s: Vector3::new(0.01, -0.02, 0.015),
            accel_m_s2: Vector3::new(0.1, -0.05, 0.2),
        }
    }

    /// Constant rate about z and constant body specific force along x:
    /// closed-form deltas.
    #[test]
    fn constant_rotation_matches_closed_form_and_schemes_rank_by_order() {
        let (w, a, t_end) = (2.0, 1.5, 0.1);
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let mut s = Vec::new();
        let mut t_ns = -5_000_000;
        while t_ns < 110_000_000 {
            s.push(ImuSample {
                t_ns,
                gyro_rad_s: [0.0, 0.0, w],
                accel_m_s2: [a, 0.0, 0.0],
            });
            t_ns += rng.gen_range(4_000_000..6_000_000);
        }
        let (c, sn) = ((w * t_end).cos(), (w * t_end).sin());
        let v = Vector3::new(sn, 1.0 - c, 0.0) * (a / w);
        let p = Vector3::new((1.0 - c) / w, t_end - sn / w, 0.0) * (a / w);
        let mut err = Vec::new();
        for scheme in IntegrationScheme::ALL {
            let pre = Preintegrator::new(scheme, NOISE)
                .integrate(&s, 0, 100_000_000, &ImuBiases::default())
                .expect("covered");
            let r = exp(&Vector3::new(0.0, 0.0, w * t_end));
            // A constant rate is integrated exactly by every rule.
            assert!(
                log(&(r.transpose() * pre.delta_R)).norm() < 1e-12,
                "{scheme:?}"
            );
            err.push(((pre.delta_v_m_s - v).norm(), (pre.delta_p_m - p).norm()));
        }
        // Euler is first order (its velocity error is about
        // h w a T / 2 = 7.5e-4 m/s here), the trapezoid second, the quadratic third.
        assert!(err[0].0 > 5e-4 && err[1].0 < err[0].0 / 50.0, "{err:?}");
        assert!(err[2].0 < err[1].0 / 50.0, "{err:?}");
        assert!(
            err[2].1 < err[1].1 / 20.0 && err[1].1 < err[0].1 / 20.0,
            "{err:?}"
        );
    }

    fn even_samples(step_ns: i64) -> Vec<ImuSample> {
        (-2..)
            .map(|k| k * step_ns)
            .take_while(|&t_ns| t_ns <= 110_000_000 + 2 * step_ns)
            .map(|t_ns| {
                let t = t_ns as f64 * 1e-9;
                ImuSample {
                    t_ns,
                    gyro_rad_s: gyro(t).into(),
                    accel_m_s2: accel(t).into(),
                }
            })
            .collect()
    }

    /// On a smooth motion with changing axis, each rule's error against a
    /// converged reference (the quadratic rule at 20 kHz) falls with its
    /// order: quadratic < midpoint < Euler at 200 Hz.
    #[test]
    fn schemes_rank_by_order_on_a_varying_motion() {
        let b = ImuBiases::default();
        let (t0, t1) = (1_000_000, 101_000_000);
        let fine = Preintegrator::new(IntegrationScheme::Quadratic, NOISE)
            .integrate(&even_samples(50_000), t0, t1, &b)
            .expect("covered");
        let coarse = even_samples(5_000_000);
        let err: Vec<(f64, f64)> = IntegrationScheme::ALL
            .iter()
            .map(|&scheme| {
                let pre = Preintegrator::new(scheme, NOISE)
                    .integrate(&coarse, t0, t1, &b)
                    .expect("covered");
                (
                    log(&(fine.delta_R.transpose() * pre.delta_R)).norm(),
                    (pre.delta_v_m_s - fine.delta_v_m_s).norm(),
                )
            })
            .collect();
        eprintln!("{err:?}");
        assert!(err[1].0 < err[0].0 / 10.0 && err[2].0 < err[1].0, "{err:?}");
        assert!(err[1].1 < err[0].1 / 10.0 && err[2].1 < err[1].1, "{err:?}");
    }

    #[test]
    fn bias_jacobians_match_reintegration() {
        let s = samples(2);
        let b = biases();
        let eps = 1e-6;
        for scheme in IntegrationScheme::ALL {
            let mut integrator = Preintegrator::new(scheme, NOISE);
            let pre = integrator
                .integrate(&s, 1_234_567, 101_000_001, &b)
                .expect("covered");
            for k in 0..6 {
                let shifted = |sign: f64| {
                    let mut bb = b;
                    if k < 3 {
                        bb.gyro_rad_s[k] += sign * eps;
                    } else {
                        bb.accel_m_s2[k - 3] += sign * eps;
                    }
                    integrator
                        .clone()
                        .integrate(&s, 1_234_567, 101_000_001, &bb)
                        .expect("covered")
                };
                let (plus, minus) = (shifted(1.0), shifted(-1.0));
                let d_r = (log(&(pre.delta_R.transpose() * plus.delta_R))
                    - log(&(pre.delta_R.transpose() * minus.delta_R)))
                    / (2.0 * eps);
                let d_v = (plus.delta_v_m_s - minus.delta_v_m_s) / (2.0 * eps);
                let d_p = (plus.delta_p_m - minus.delta_p_m) / (2.0 * eps);
                let (jr, jv, jp) = if k < 3 {
                    (
                        pre.d_R_d_bg.column(k).into_owned(),
                        pre.d_v_d_bg.column(k).into_owned(),
                        pre.d_p_d_bg.column(k).into_owned(),
                    )
                } else {
                    (
                        Vector3::zeros(),
                        pre.d_v_d_ba.column(k - 3).into_owned(),
                        pre.d_p_d_ba.column(k - 3).into_owned(),
                    )
                };
                assert!((d_r - jr).norm() < 1e-8, "{scheme:?} {k} R {d_r} {jr}");
                assert!((d_v - jv).norm() < 1e-7, "{scheme:?} {k} v {d_v} {jv}");
                assert!((d_p - jp).norm() < 1e-8, "{scheme:?} {k} p {d_p} {jp}");
            }
        }
    }

    #[test]
    fn bias_correction_is_close_to_reintegration() {
        let s = samples(3);
        let b = biases();
        let mut b2 = b;
        b2.gyro_rad_s += Vector3::new(2e-3, -1e-3, 3e-3);
        b2.accel_m_s2 += Vector3::new(0.02, 0.03, -0.01);
        for scheme in IntegrationScheme::ALL {
            let mut integrator = Preintegrator::new(scheme, NOISE);
            let pre = integrator
                .integrate(&s, 0, 100_000_000, &b)
                .expect("covered");
            let again = integrator
                .integrate(&s, 0, 100_000_000, &b2)
                .expect("covered");
            let fixed = pre.corrected(&b2);
            let uncorrected = (pre.delta_v_m_s - again.delta_v_m_s).norm();
            // First order: the error is second order in the bias change.
            assert!(log(&(fixed.delta_R.transpose() * again.delta_R)).norm() < 1e-8);
            assert!((fixed.delta_v_m_s - again.delta_v_m_s).norm() < uncorrected * 1e-3);
            assert!((fixed.delta_p_m - again.delta_p_m).norm() < 1e-7);
        }
    }

    /// Euler integration of [a, c] equals that of [a, b] composed with
    /// [b, c] exactly when b is a sample stamp, with a and c between
    /// samples (the partial steps at the ends are clipped).
    #[test]
    fn euler_intervals_compose_at_a_sample_stamp() {
        let s = samples(4);
        let b = biases();
        let mut integrator = Preintegrator::new(IntegrationScheme::Euler, NOISE);
        let (ta, tb, tc) = (-7_000_001, s[12].t_ns, 120_000_001);
        assert!(s.iter().all(|x| x.t_ns != ta && x.t_ns != tc));
        let ab = integrator.integrate(&s, ta, tb, &b).expect("covered");
        let bc = integrator.integrate(&s, tb, tc, &b).expect("covered");
        let ac = integrator.integrate(&s, ta, tc, &b).expect("covered");
        let r = ab.delta_R * bc.delta_R;
        let v = ab.delta_v_m_s + ab.delta_R * bc.delta_v_m_s;
        let p = ab.delta_p_m + ab.delta_v_m_s * bc.dt_s + ab.delta_R * bc.delta_p_m;
        assert!(log(&(r.transpose() * ac.delta_R)).norm() < 1e-13);
        assert!(
            (v - ac.delta_v_m_s).norm() < 1e-13,
            "{}",
            (v - ac.delta_v_m_s).norm()
        );
        assert!(
            (p - ac.delta_p_m).norm() < 1e-13,
            "{}",
            (p - ac.delta_p_m).norm()
        );
        assert_eq!(ab.steps + bc.steps, ac.steps);
    }

    /// The propagated covariance against the spread of 3000 integrations of
    /// noisy samples (white noise of the EuRoC densities at each sample's
    /// spacing). With 3000 draws a variance is known to 2.6 % (1 sigma); the
    /// tolerance is 12 % on every diagonal entry.
    #[test]
    fn covariance_matches_monte_carlo() {
        let clean = samples(5);
        let b = ImuBiases::default();
        let mut rng = ChaCha8Rng::seed_from_u64(6);
        for scheme in IntegrationScheme::ALL {
            let mut integrator = Preintegrator::new(scheme, NOISE);
            let pre = integrator
                .integrate(&clean, 0, 100_000_000, &b)
                .expect("covered");
            let runs = 3000;
            let mut second = Matrix9::zeros();
            for _ in 0..runs {
                let noisy: Vec<ImuSample> = clean
                    .iter()
                    .enumerate()
                    .map(|(k, s)| {
                        // Sample k's noise covers half of each adjacent step.
                        let prev = if k > 0 {
                            clean[k - 1].t_ns
                        } else {
                            s.t_ns - 5_000_000
                        };
                        let next = clean.get(k + 1).map_or(s.t_ns + 5_000_000, |n| n.t_ns);
                        let dt = (next - prev) as f64 * 0.5e-9;
                        let d = DiscreteNoiseSigmas::new(dt);
                        let mut g = s.gyro_rad_s;
                        let mut a = s.accel_m_s2;
                        for i in 0..3 {
                            g[i] += d.0 * rng.sample::<f64, _>(StandardNormal);
                            a[i] += d.1 * rng.sample::<f64, _>(StandardNormal);
                        }
                        ImuSample {
                            t_ns: s.t_ns,
                            gyro_rad_s: g,
                            accel_m_s2: a,
                        }
                    })
                    .collect();
                let x = integrator
                    .integrate(&noisy, 0, 100_000_000, &b)
                    .expect("covered");
                let mut e = SMatrix::<f64, 9, 1>::zeros();
                e.fixed_rows_mut::<3>(0)
                    .copy_from(&log(&(pre.delta_R.transpose() * x.delta_R)));
                e.fixed_rows_mut::<3>(3)
                    .copy_from(&(x.delta_v_m_s - pre.delta_v_m_s));
                e.fixed_rows_mut::<3>(6)
                    .copy_from(&(x.delta_p_m - pre.delta_p_m));
                second += e * e.transpose();
            }
            let empirical = second / runs as f64;
            for i in 0..9 {
                let ratio = empirical[(i, i)] / pre.covariance[(i, i)];
                assert!(
                    (ratio - 1.0).abs() < 0.12,
                    "{scheme:?} entry {i}: ratio {ratio}"
                );
            }
        }
    }

    /// Integrating with noise densities scaled by (3, 7) gives the
    /// covariance that `scaled_covariance(3, 7)` forms from the split.
    #[test]
    fn scaled_covariance_equals_integrating_with_scaled_noise() {
        let clean = samples(5);
        let b = ImuBiases::default();
        for scheme in IntegrationScheme::ALL {
            let pre = Preintegrator::new(scheme, NOISE)
                .integrate(&clean, 0, 100_000_000, &b)
                .expect("covered");
            let scaled_noise = ImuNoise {
                gyroscope_noise_density: NOISE.gyroscope_noise_density * 3.0,
                accelerometer_noise_density: NOISE.accelerometer_noise_density * 7.0,
                ..NOISE
            };
            let direct = Preintegrator::new(scheme, scaled_noise)
                .integrate(&clean, 0, 100_000_000, &b)
                .expect("covered");
            let formed = pre.scaled_covariance(3.0, 7.0);
            let err = (formed - direct.covariance).abs().max();
            assert!(
                err <= 1e-9 * direct.covariance.abs().max(),
                "{scheme:?}: {err:e}"
            );
            // The gyro share alone is what a noiseless accelerometer gives.
            let gyro_only = Preintegrator::new(
                scheme,
                ImuNoise {
                    accelerometer_noise_density: 0.0,
                    ..NOISE
                },
            )
            .integrate(&clean, 0, 100_000_000, &b)
            .expect("covered");
            let err = (pre.covariance_gyro - gyro_only.covariance).abs().max();
            assert!(
                err <= 1e-9 * pre.covariance.abs().max(),
                "{scheme:?}: {err:e}"
            );
            assert!(pre.covariance_gyro[(3, 3)] < pre.covariance[(3, 3)]);
        }
    }

    /// (gyro, accel) white-noise sigmas for a sample covering `dt` seconds.
    struct DiscreteNoiseSigmas(f64, f64);
    impl DiscreteNoiseSigmas {
        fn new(dt: f64) -> Self {
            let d = crate::imu::DiscreteNoise::from_continuous(&NOISE, dt);
            Self(d.gyro_sigma_rad_s, d.accel_sigma_m_s2)
        }
    }

    #[test]
    fn bad_input_is_an_error_not_a_panic() {
        let s = samples(7);
        let b = ImuBiases::default();
        let mut integrator = Preintegrator::new(IntegrationScheme::Quadratic, NOISE);
        assert!(matches!(
            integrator.integrate(&s, 50, 50, &b),
            Err(PreintegrationError::EmptyInterval { .. })
        ));
        assert!(matches!(
            integrator.integrate(&s, -50_000_000, 0, &b),
            Err(PreintegrationError::NotCovered { .. })
        ));
        assert!(matches!(
            integrator.integrate(&[], 0, 1, &b),
            Err(PreintegrationError::NotCovered { .. })
        ));
        let mut nan = s.clone();
        nan[4].accel_m_s2[1] = f64::NAN;
        assert_eq!(
            integrator.integrate(&nan, 0, 50_000_000, &b),
            Err(PreintegrationError::NotFinite {
                index: 4,
                t_ns: nan[4].t_ns
            })
        );
        let mut repeated = s.clone();
        repeated[6].t_ns = repeated[5].t_ns;
        assert!(matches!(
            integrator.integrate(&repeated, 0, 50_000_000, &b),
            Err(PreintegrationError::NotIncreasing { index: 6, .. })
        ));
    }
}
