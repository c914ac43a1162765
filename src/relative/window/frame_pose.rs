//! The pose of a frame between keyframes: a motion-only Levenberg-Marquardt
//! on the body pose (and the velocity when the IMU interval from the latest
//! keyframe is given) against the window's landmarks, held fixed. This is
//! how every frame gets a pose at frame rate, and how the paper's "scale of
//! the new frame's translation from already-known points" is found.
//!
//! Cost: robust reprojection errors of the frame's observations of known
//! landmarks + (IMU) the inertial residual from the latest keyframe, whose
//! state and biases are held, as a prior on the frame's pose and velocity.
//! After convergence, observations above `outlier_chi2` are dropped and
//! the pose is refined once more without them.

use std::time::Instant;

use nalgebra::{Matrix6, SMatrix, SVector, Vector2, Vector3};

use super::camera_imu::{reproject_exposed, BodyMotion, Exposure};
use super::inertial_link::{whitening, Matrix9};
use super::reprojection::{reproject, reprojection_error, GATE_SQ};
use super::state::{apply_update, nav_state, state_is_finite, FULL_DIM, POS, ROT, VEL};
use super::Window;
use crate::imu::{imu_residual, Preintegrated};
use crate::relative::types::{KeyframeState, TrackedFrame};

type Matrix9x9 = SMatrix<f64, 9, 9>;
type Vector9 = SVector<f64, 9>;

/// The answer of [`Window::track_frame`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FramePose {
    /// The frame's estimated state: the pose, and the velocity when the
    /// IMU interval from the latest keyframe was used (then with that
    /// keyframe's biases); otherwise velocity and biases as guessed.
    pub state: KeyframeState,
    /// Observations of known landmarks in the frame.
    pub matched: usize,
    /// Of those, the ones within the chi-square threshold at the end.
    pub inliers: usize,
    /// Gauss-Newton / LM iterations run.
    pub iterations: usize,
    /// Cost at the end (half the sum of robustified squared whitened errors).
    pub final_cost: f64,
    /// Enough inliers (`min_track_inliers`) and a finite state.
    pub good: bool,
    /// Covariance of the pose's `[dphi, dp]` given the landmarks and the
    /// latest keyframe, with the noise the window estimated
    /// ([`super::NoiseScale`]); None when the pose is not determined.
    pub pose_marginal: Option<Matrix6<f64>>,
    /// Wall time of the call, ms.
    pub ms: f64,
}

/// How the frame's residuals are weighed: `1 / pixel sigma` and the
/// inertial residual's square-root information.
struct Weights {
    inv_sigma: f64,
    /// What the image term is multiplied by: 1 / (estimated pixel noise
    /// scale)^2. A factor on the whole term rather than a smaller sigma,
    /// so that the robust kernel's threshold and the gate
    /// ([`super::reprojection::GATE_SQ`]) keep their size in pixels: with
    /// the sigma shrunk, a far guess put every observation past the gate
    /// and the pose went astray.
    vision_weight: f64,
    imu_sqrt_info: Option<Matrix9>,
}

/// The `[dphi, dp]` block of the inverse of the information `h` over the
/// first `dim` unknowns (6: pose, 9: pose and velocity).
fn pose_marginal(h: &Matrix9x9, dim: usize) -> Option<Matrix6<f64>> {
    let c = if dim == 9 {
        h.cholesky()?
            .inverse()
            .fixed_view::<6, 6>(0, 0)
            .into_owned()
    } else {
        h.fixed_view::<6, 6>(0, 0)
            .into_owned()
            .cholesky()?
            .inverse()
    };
    let c = (c + c.transpose()) * 0.5;
    c.iter().all(|v| v.is_finite()).then_some(c)
}

#[derive(Debug, Clone, Copy)]
pub(crate) struct TrackRow {
    point_world_m: Vector3<f64>,
    pixel: Vector2<f64>,
    camera: u8,
    active: bool,
}

#[derive(Debug, Clone, Default)]
pub(crate) struct TrackBuffers {
    rows: Vec<TrackRow>,
}

impl Window {
    /// Pose of a frame that is not a keyframe, from `guess` (e.g. the IMU
    /// prediction), its observations, and the IMU interval from the latest
    /// keyframe (used only with the IMU on and when its stamps run from the
    /// latest keyframe to `guess.t_ns`). Biases are the latest keyframe's
    /// when the IMU is used. The window is not changed.
    pub fn track_frame(
        &mut self,
        guess: KeyframeState,
        frame: &TrackedFrame,
        imu_from_latest: Option<&Preintegrated>,
    ) -> FramePose {
        let start = Instant::now();
        let mut out = FramePose {
            state: guess,
            matched: 0,
            inliers: 0,
            iterations: 0,
            final_cost: 0.0,
            good: false,
            pose_marginal: None,
            ms: 0.0,
        };
        if !state_is_finite(&guess) {
            out.ms = start.elapsed().as_secs_f64() * 1e3;
            return out;
        }
        let gravity = self.gravity_world_m_s2();
        let covariance_scale = self.covariance_pixel_scale();
        let rows = &mut self.track.rows;
        rows.clear();
        for o in &frame.observations {
            if (o.camera_index as usize) >= self.cameras.len()
                || !o.pixel.iter().all(|v| v.is_finite())
            {
                continue;
            }
            if let Some(lm) = self.landmarks.get(&o.landmark) {
                rows.push(TrackRow {
                    point_world_m: lm.position_world_m,
                    pixel: o.pixel,
                    camera: o.camera_index,
                    active: true,
                });
            }
        }
        out.matched = rows.len();
        let latest = self.keyframes.back().map(|k| k.state);
        let imu = match (self.use_imu, imu_from_latest, latest) {
            (true, Some(pre), Some(l))
                if pre.t_start_ns == l.t_ns && pre.t_end_ns == guess.t_ns && pre.dt_s > 0.0 =>
            {
                Some((pre, l))
            }
            _ => None,
        };
        let mut state = guess;
        if let Some((_, l)) = &imu {
            state.biases = l.biases;
        }
        let dim = if imu.is_some() { 9 } else { 6 };
        // Weighed with the noise the window estimated
        // ([`super::NoiseScale`]), as the window weighs the keyframes; the
        // robust kernel and the outlier gate keep their size in pixels.
        let scale = self.noise.scale();
        let inv_sigma = 1.0 / self.config.pixel_sigma;
        let k = self.config.huber_px / self.config.pixel_sigma;
        let estimated = Weights {
            inv_sigma,
            vision_weight: if self.use_imu {
                1.0 / (scale.pixel * scale.pixel)
            } else {
                1.0
            },
            imu_sqrt_info: imu
                .map(|(pre, _)| whitening(&pre.scaled_covariance(scale.gyro, scale.accel))),
        };
        let kernel = self.config.robust_kernel;
        let cameras = &self.cameras;
        // With the time offset refined, the images were taken `td` after
        // their stamps: project through the pose at exposure, as the
        // keyframes do ([`super::camera_imu`]); the state stays the body's
        // at the stamp.
        let exposure = self
            .camera_imu
            .as_ref()
            .filter(|_| self.use_imu && imu.is_some())
            .map(|c| (c.time_offset_s, &c.T_cam0_cam, self.frame_omega_body_rad_s));
        let motion = |s: &KeyframeState, omega: &Vector3<f64>| BodyMotion {
            omega_body_rad_s: *omega,
            velocity_world_m_s: s.velocity_world_m_s,
        };
        // The pose at exposure of a state, shared by all its rows.
        let exposed = |s: &KeyframeState| {
            exposure
                .as_ref()
                .map(|(td, _, omega)| Exposure::new(&s.T_world_body, &motion(s, omega), *td))
        };
        let project = |s: &KeyframeState, at: Option<&Exposure>, r: &TrackRow| match (&exposure, at)
        {
            (Some((_, t_c0c, omega)), Some(at)) => reproject_exposed(
                &cameras[r.camera as usize],
                r.camera as usize,
                &t_c0c[r.camera as usize],
                at,
                &motion(s, omega),
                &r.point_world_m,
                &r.pixel,
            )
            .map(|(p, _)| p),
            _ => reproject(
                &cameras[r.camera as usize],
                &s.T_world_body,
                &r.point_world_m,
                &r.pixel,
            ),
        };
        let error = |s: &KeyframeState, at: Option<&Exposure>, r: &TrackRow| {
            let pose = at.map_or(&s.T_world_body, |at| &at.pose);
            reprojection_error(
                &cameras[r.camera as usize],
                pose,
                &r.point_world_m,
                &r.pixel,
            )
        };

        // Cost and (optionally) normal equations of the frame's pose.
        let evaluate = |s: &KeyframeState,
                        rows: &[TrackRow],
                        normal: Option<(&mut Matrix9x9, &mut Vector9)>,
                        weights: &Weights|
         -> f64 {
            let inv_sigma = weights.inv_sigma;
            let vw = weights.vision_weight;
            let mut cost = 0.0;
            let mut h = Matrix9x9::zeros();
            let mut b = Vector9::zeros();
            let build = normal.is_some();
            let at = exposed(s);
            for r in rows.iter().filter(|r| r.active) {
                if build {
                    let Some(p) = project(s, at.as_ref(), r).filter(|p| p.depth_m > 0.0) else {
                        cost += 0.5 * vw * kernel.evaluate(GATE_SQ, k).0;
                        continue;
                    };
                    let e = p.error_px * inv_sigma;
                    let j = p.d_pose * inv_sigma;
                    let (rho, w) = kernel.evaluate(e.norm_squared(), k);
                    cost += 0.5 * vw * rho;
                    let mut hp = h.fixed_view_mut::<6, 6>(0, 0);
                    hp += j.transpose() * j * (w * vw);
                    let mut bp = b.fixed_rows_mut::<6>(0);
                    bp -= j.transpose() * e * (w * vw);
                } else {
                    match error(s, at.as_ref(), r) {
                        Some((e, depth)) if depth > 0.0 => {
                            cost += 0.5 * vw * kernel.evaluate((e * inv_sigma).norm_squared(), k).0
                        }
                        _ => cost += 0.5 * vw * kernel.evaluate(GATE_SQ, k).0,
                    }
                }
            }
            if let (Some((pre, l)), Some(sqrt_info)) = (&imu, &weights.imu_sqrt_info) {
                let res = imu_residual(pre, &nav_state(l), &nav_state(s), &l.biases, &gravity);
                let r = sqrt_info * res.residual;
                cost += 0.5 * r.norm_squared();
                if build {
                    // imu_residual orders [dphi, dv, dp]; ours is [dphi, dp, dv].
                    let mut j = Matrix9::zeros();
                    j.fixed_view_mut::<9, 3>(0, ROT)
                        .copy_from(&res.d_state_j.fixed_view::<9, 3>(0, 0));
                    j.fixed_view_mut::<9, 3>(0, VEL)
                        .copy_from(&res.d_state_j.fixed_view::<9, 3>(0, 3));
                    j.fixed_view_mut::<9, 3>(0, POS)
                        .copy_from(&res.d_state_j.fixed_view::<9, 3>(0, 6));
                    let j = sqrt_info * j;
                    h += j.transpose() * j;
                    b -= j.transpose() * r;
                }
            }
            if let Some((hh, bb)) = normal {
                *hh = h;
                *bb = b;
            }
            cost
        };

        let mut iterations = 0;
        let mut cost = 0.0;
        for phase in 0..2 {
            let mut lambda = 1e-4;
            let mut h = Matrix9x9::zeros();
            let mut b = Vector9::zeros();
            cost = evaluate(&state, rows, Some((&mut h, &mut b)), &estimated);
            for _ in 0..self.config.track_max_iterations {
                iterations += 1;
                let mut accepted = false;
                let mut converged = false;
                for _ in 0..8 {
                    let mut a = h;
                    for i in 0..9 {
                        if i < dim {
                            a[(i, i)] += lambda * h[(i, i)].max(1e-6);
                        } else {
                            a[(i, i)] = 1.0;
                        }
                    }
                    let Some(chol) = a.cholesky() else {
                        lambda *= 10.0;
                        continue;
                    };
                    let delta = chol.solve(&b);
                    let mut candidate = state;
                    let mut full = [0.0; FULL_DIM];
                    full[..dim].copy_from_slice(&delta.as_slice()[..dim]);
                    apply_update(&mut candidate, &full[..if dim == 9 { FULL_DIM } else { 6 }]);
                    let new_cost = evaluate(&candidate, rows, None, &estimated);
                    if new_cost.is_finite() && new_cost <= cost {
                        converged = cost - new_cost <= 1e-6 * cost || delta.amax() < 1e-12;
                        state = candidate;
                        cost = new_cost;
                        accepted = true;
                        lambda = (lambda * 0.1).max(1e-10);
                        break;
                    }
                    lambda *= 10.0;
                }
                if !accepted || converged {
                    break;
                }
                cost = evaluate(&state, rows, Some((&mut h, &mut b)), &estimated);
            }
            // Drop the outliers and refine once.
            let chi2 = self.config.outlier_chi2;
            let mut dropped = 0;
            let at = exposed(&state);
            for r in rows.iter_mut().filter(|r| r.active) {
                let keep = matches!(
                    error(&state, at.as_ref(), r),
                    Some((e, depth)) if depth > 0.0 && (e * inv_sigma).norm_squared() <= chi2
                );
                if !keep {
                    r.active = false;
                    dropped += 1;
                }
            }
            if dropped == 0 || phase == 1 {
                break;
            }
        }
        out.inliers = rows.iter().filter(|r| r.active).count();
        out.iterations = iterations;
        out.final_cost = cost;
        out.good = state_is_finite(&state) && out.inliers >= self.config.min_track_inliers;
        if out.good {
            // The information at the answer.
            let mut h = Matrix9x9::zeros();
            let mut b = Vector9::zeros();
            // Published with the covariance's pixel sigma
            // ([`Window::covariance_pixel_scale`]).
            let published = Weights {
                vision_weight: if self.use_imu {
                    1.0 / (covariance_scale * covariance_scale)
                } else {
                    1.0
                },
                ..estimated
            };
            evaluate(&state, rows, Some((&mut h, &mut b)), &published);
            out.pose_marginal =
                pose_marginal(&h, dim).map(|m| m * self.vision_only_covariance_factor());
        }
        out.state = state;
        out.ms = start.elapsed().as_secs_f64() * 1e3;
        out
    }
}
