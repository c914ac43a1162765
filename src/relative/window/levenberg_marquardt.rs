//! The Levenberg-Marquardt loop of the window (eq. 35-40): linearise every
//! term at the current estimate, solve the damped normal equations with the
//! Schur complement ([`super::schur`]), keep the step if the cost falls
//! (and lower the damping), else undo it and raise the damping. After
//! convergence, observations whose squared whitened error exceeds
//! `outlier_chi2` are flagged, as are all those of a landmark that fails
//! the landmark test ([`super::landmark_consistency`]), and the problem
//! is solved again without them; then the marginals that feed the eq. 34 prior and the absolute
//! stage are read from the inverse of the reduced system.

use std::time::Instant;

use nalgebra::{DMatrix, Matrix2, SMatrix, SVector, Vector2, Vector3};

use super::camera_imu::{reproject_exposed, BodyMotion, Exposure, CALIB_DIM, CALIB_STEREO};
use super::inertial::{
    bias_walk_factor, inertial_factor, tangent_basis, update_direction, GRAVITY_COL, INERTIAL_COLS,
};
use super::marginalise::{marginalise_boundary, LinkEnd};
use super::prior::{GravityPrior, OldestFreePrior};
use super::reprojection::{reproject, reprojection_error, GATE_SQ};
use super::schur::{self, Chunk, LandmarkBlock, ObservationRow};
use super::state::{apply_update, inertially_linked, Keyframe, BG, FULL_DIM, POSE_DIM, VEL};
use super::{held_cameras, Window};
use crate::imu::so3::hat;
use crate::relative::types::{BodyLandmark, WindowSupport};

/// Squared whitened error charged for an observation whose landmark does
/// not project (behind the camera): a step that pushes points behind the
/// cameras must not look like a cost decrease.
const INVALID_SQ_ERROR: f64 = GATE_SQ;

/// The estimated part of the newest fixed keyframe: `[v, b_g, b_a]`.
const BOUNDARY_DIM: usize = 9;

/// A step that lowers the cost by less than this share ends the loop.
const RELATIVE_DECREASE: f64 = 1e-6;

/// What one [`Window::optimize`] did.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct WindowReport {
    /// LM iterations run.
    pub iterations: usize,
    /// Cost (half the sum of robustified squared whitened errors) before
    /// and after.
    pub initial_cost: f64,
    /// Cost after the optimisation.
    pub final_cost: f64,
    /// Keyframes in the window.
    pub keyframes: usize,
    /// Keyframes optimised (the newest `keyframes_free`).
    pub free_keyframes: usize,
    /// Landmarks and observations in the problem.
    pub landmarks: usize,
    /// Observations in the problem.
    pub observations: usize,
    /// Observations flagged as outliers by this call.
    pub new_outliers: usize,
    /// Landmarks taken out with their tracks by this call: their inlier
    /// observations together failed the landmark test.
    pub inconsistent_landmarks: usize,
    /// True when the marginals came from the inverted reduced system (see
    /// [`Window::landmarks_in_body`]).
    pub exact_marginals: bool,
    /// Wall time of the call, ms.
    pub ms: f64,
}

impl Window {
    /// Optimises the free keyframes, gravity (IMU on) and the landmarks
    /// they see.
    pub fn optimize(&mut self) -> WindowReport {
        let start = Instant::now();
        let mut report = WindowReport::default();
        self.state_covariance = None;
        self.body_landmarks.clear();
        let n = self.keyframes.len();
        // Once, when asked: the oldest alone (`hold_oldest_only_next_solve`).
        let n_fixed = if std::mem::take(&mut self.hold_oldest_only_once) {
            1.min(n)
        } else {
            self.fixed_count()
        };
        report.keyframes = n;
        if n < 2 || n_fixed >= n {
            report.ms = start.elapsed().as_secs_f64() * 1e3;
            return report;
        }
        report.free_keyframes = n - n_fixed;
        self.refresh_velocity_prior(n_fixed);
        // The calibration was released after a start in flight and the
        // settings say to free the gyroscope bias then
        // (`camera_imu_release_frees_gyro_bias`): the boundary's bias came
        // from an alignment that read the gyroscope through the file's
        // wrong rotation, and held about as tight as it found it, it kept
        // the calibration short of the truth (0.2-0.3 deg on consistent-IMU
        // renderings with a file 1 deg off). Back to the configured
        // sigma, the window's data decide it again with the calibration.
        if std::mem::take(&mut self.widen_gyro_bias_next_solve) {
            let sigma = self.config.gyro_bias_prior_sigma_rad_s;
            if let Some(prior) = self.velocity_prior.as_mut() {
                prior.widen_gyro_bias(sigma);
            }
        }
        // As in ORB-SLAM's local bundle adjustment: half the iterations
        // with every observation under the robust kernel, then the
        // outliers out and the rest without them.
        let max_iterations = self.config.max_iterations;
        self.build_problem(n_fixed);
        let first = max_iterations.div_ceil(2);
        let (iterations, initial, last, converged) = self.run_lm(first);
        report.initial_cost = initial;
        report.final_cost = last;
        report.iterations = iterations;
        let flagged = self.flag_outliers(&mut report);
        if flagged > 0 || !converged {
            if flagged > 0 {
                self.build_problem(n_fixed);
            }
            let rest = max_iterations.saturating_sub(iterations).max(2);
            let (iterations, _, last, _) = self.run_lm(rest);
            report.final_cost = last;
            report.iterations += iterations;
            self.flag_outliers(&mut report);
        }
        if report.new_outliers > 0 {
            self.build_problem(n_fixed);
        }
        report.landmarks = self.problem.landmarks.len();
        report.observations = self.problem.rows.len();
        report.exact_marginals = self.compute_marginals();
        self.measure_noise();
        report.ms = start.elapsed().as_secs_f64() * 1e3;
        report
    }

    /// Moves the eq. 34 prior to the boundary (the newest fixed keyframe)
    /// when it changed: marginalised from the previous boundary prior and
    /// the departing link when both ends have a marginal
    /// ([`super::marginalise`]); else centred on the estimate with
    /// `prior_weight` times the last solve's marginal information (or the
    /// configured sigmas).
    fn refresh_velocity_prior(&mut self, n_fixed: usize) {
        if !self.use_imu || n_fixed == 0 || n_fixed >= self.keyframes.len() {
            return;
        }
        let kf = &self.keyframes[n_fixed - 1];
        if self.velocity_prior.map(|p| p.seq) == Some(kf.seq) {
            return;
        }
        let c = &self.config;
        let marginalised = n_fixed
            .checked_sub(2)
            .filter(|_| c.marginalise_boundary)
            .map(|i| &self.keyframes[i])
            .and_then(|old| {
                let previous = self.velocity_prior.filter(|p| p.seq == old.seq)?;
                // The chain starts once the previous boundary was itself
                // optimised as a free keyframe (after a handover it was
                // not: its prior is then the configured sigmas).
                old.state_marginal?;
                marginalise_boundary(
                    &previous,
                    &old.state,
                    LinkEnd {
                        state: &kf.state,
                        marginal: kf.state_marginal.as_ref()?,
                    },
                    kf.seq,
                    kf.imu.as_ref()?,
                    &self.noise.scale().walk(kf.bias_walk_sqrt_info.as_ref()?),
                    &self.gravity_dir,
                    &tangent_basis(&self.gravity_dir),
                    &self.gravity_prior,
                    c.boundary_pose_covariance_scale,
                    c.boundary_prior_memory_s,
                )
            });
        let prior = marginalised
            .or_else(|| {
                kf.state_marginal.and_then(|m| {
                    let m9 = m.fixed_view::<9, 9>(VEL, VEL).into_owned();
                    OldestFreePrior::from_covariance(kf.seq, &kf.state, &m9, c.prior_weight)
                })
            })
            .unwrap_or_else(|| {
                OldestFreePrior::isotropic(
                    kf.seq,
                    &kf.state,
                    [
                        c.velocity_prior_sigma_m_s,
                        self.start_gyro_bias_sigma_rad_s
                            .unwrap_or(c.gyro_bias_prior_sigma_rad_s),
                        c.accel_bias_prior_sigma_m_s2,
                    ],
                )
            });
        self.velocity_prior = Some(prior);
    }

    /// Gathers the observations of landmarks with at least two inlier
    /// observations, one of them in a free keyframe, sorted by landmark.
    pub(super) fn build_problem(&mut self, n_fixed: usize) {
        let n = self.keyframes.len();
        let p = &mut self.problem;
        let sd = if self.use_imu { FULL_DIM } else { POSE_DIM };
        p.n_fixed = n_fixed;
        p.state_dim = sd;
        let free = n - n_fixed;
        p.gravity_offset = self.use_imu.then_some(free * sd);
        p.boundary_offset = self.use_imu.then_some(free * sd + 2);
        let base = free * sd + if self.use_imu { 2 + BOUNDARY_DIM } else { 0 };
        p.calib_offset = (self.use_imu && self.camera_imu.is_some()).then_some(base);
        let dim = base
            + if p.calib_offset.is_some() {
                CALIB_DIM
            } else {
                0
            };
        p.eq.reset(dim);
        p.rows.clear();
        p.landmarks.clear();
        p.index.clear();
        p.counts.clear();
        for (pos, kf) in self.keyframes.iter().enumerate() {
            for (i, o) in kf.observations.iter().enumerate() {
                if o.outlier {
                    continue;
                }
                let Some(lm) = self.landmarks.get(&o.landmark) else {
                    continue;
                };
                let idx = *p.index.entry(o.landmark).or_insert_with(|| {
                    p.landmarks
                        .push(LandmarkBlock::new(o.landmark, lm.position_world_m));
                    p.counts.push((0, false));
                    p.landmarks.len() - 1
                });
                p.counts[idx].0 += 1;
                p.counts[idx].1 |= pos >= n_fixed;
                let mut row = ObservationRow::new(pos, i, o.camera, idx);
                row.offset = (pos >= n_fixed).then(|| (pos - n_fixed) * sd);
                p.rows.push(row);
            }
        }
        p.remap.clear();
        let mut kept = 0;
        for &(count, seen_free) in &p.counts {
            if count >= 2 && seen_free {
                p.remap.push(kept);
                kept += 1;
            } else {
                p.remap.push(usize::MAX);
            }
        }
        let mut j = 0;
        p.landmarks.retain(|_| {
            let keep = p.remap[j] != usize::MAX;
            j += 1;
            keep
        });
        p.rows.retain(|r| p.remap[r.landmark] != usize::MAX);
        for r in p.rows.iter_mut() {
            r.landmark = p.remap[r.landmark];
        }
        p.rows
            .sort_unstable_by_key(|r| (r.landmark, r.kf, r.obs_index));
        let mut start = 0;
        for (j, lm) in p.landmarks.iter_mut().enumerate() {
            let mut end = start;
            while end < p.rows.len() && p.rows[end].landmark == j {
                end += 1;
            }
            lm.rows = start..end;
            start = end;
        }
        p.stereo_rows = p.rows.iter().filter(|r| r.camera == 1).count();
    }

    /// The iterations; returns (iterations, initial cost, final cost,
    /// converged) and writes the landmarks back.
    pub(super) fn run_lm(&mut self, max_iterations: usize) -> (usize, f64, f64, bool) {
        let mut lambda = 1e-4;
        let mut cost = self.linearize(true);
        let initial = cost;
        let mut iterations = 0;
        let mut converged = cost <= 1e-24;
        while iterations < max_iterations && !converged {
            iterations += 1;
            let mut accepted = false;
            for _ in 0..10 {
                let solved = {
                    let p = &mut self.problem;
                    schur::solve_step(&mut p.eq, &p.rows, &mut p.landmarks, lambda, p.calib_offset)
                };
                if !solved {
                    lambda *= 10.0;
                    continue;
                }
                self.save_backup();
                let step = self.apply_step();
                let new_cost = self.linearize(false);
                if new_cost.is_finite() && new_cost <= cost {
                    converged = cost - new_cost <= RELATIVE_DECREASE * cost
                        || step < 1e-12
                        || new_cost <= 1e-24;
                    cost = new_cost;
                    accepted = true;
                    lambda = (lambda * 0.1).max(1e-10);
                    break;
                }
                self.restore_backup();
                lambda *= 10.0;
                if step < 1e-12 {
                    converged = true;
                    break;
                }
            }
            if !accepted {
                converged = true;
            }
            if converged {
                break;
            }
            cost = self.linearize(true);
        }
        for lm in &self.problem.landmarks {
            if let Some(l) = self.landmarks.get_mut(&lm.id) {
                l.position_world_m = lm.position_world_m;
            }
        }
        (iterations, initial, cost, converged)
    }

    /// Evaluates the cost at the current estimate; with `build`, also
    /// linearises every term into the normal equations.
    pub(super) fn linearize(&mut self, build: bool) -> f64 {
        let covariance_scale = self.covariance_pixel_scale();
        let p = &mut self.problem;
        let keyframes = &self.keyframes;
        // Whitened with the pixel sigma the features show
        // ([`super::noise_adaptation`]); `sq_error` stays in declared
        // units so that the outlier gates keep their size in pixels.
        // Without the IMU only the published covariance takes it
        // ([`Window::vision_only_covariance_factor`]).
        let pixel_scale = match (self.use_imu, p.covariance_pixels) {
            (false, _) => 1.0,
            (true, false) => self.noise.scale().pixel,
            (true, true) => covariance_scale,
        };
        let walk_scale = self.noise.scale();
        let sigma = self.config.pixel_sigma * pixel_scale;
        let inv_sigma = 1.0 / sigma;
        let to_declared = pixel_scale * pixel_scale;
        let k = self.config.huber_px / sigma;
        let kernel = self.config.robust_kernel;
        let invalid_cost = 0.5 * kernel.evaluate(INVALID_SQ_ERROR, k).0;
        if build {
            p.eq.reset(p.eq.dim);
            p.gravity_basis = tangent_basis(&self.gravity_dir);
        }
        let mut cost = 0.0;
        let calib = p.calib_offset.and(self.camera_imu.as_ref());
        let follow = calib.is_some_and(|c| c.held_keyframes_follow());
        // The published covariance's floor is for keyframes an inertial
        // link reaches. A stereo start in flight keeps the keyframes the
        // window had on the images alone unlinked until they leave; their
        // observations take the estimate (times the gain) without the
        // floor. At the floor a fast start's carried covariance was 3-10
        // times its errors for the whole run; at the estimate well-tied
        // image-only keyframes are about three times too sure, so this
        // trades one error for a smaller one
        // (docs/results/covariance-image-only-keyframes-2026-12-07.md).
        let image_only_scale = (self.use_imu && p.covariance_pixels)
            .then(|| self.config.covariance_pixel_gain * self.noise.scale().pixel);
        // Each keyframe's pose at exposure, shared by its observations.
        let exposures: Vec<Exposure> = match calib {
            Some(c) => keyframes
                .iter()
                .map(|kf| {
                    Exposure::new(
                        &kf.state.T_world_body,
                        &keyframe_motion(kf),
                        c.time_offset_s,
                    )
                })
                .collect(),
            None => Vec::new(),
        };
        for row in p.rows.iter_mut() {
            let kf = &keyframes[row.kf];
            let (inv_sigma, to_declared, k) = match image_only_scale {
                Some(s) if !inertially_linked(keyframes, row.kf) => {
                    let sigma = self.config.pixel_sigma * s;
                    (1.0 / sigma, s * s, self.config.huber_px / sigma)
                }
                _ => (inv_sigma, to_declared, k),
            };
            let obs = &kf.observations[row.obs_index];
            let camera = &self.cameras[row.camera as usize];
            let point = p.landmarks[row.landmark].position_world_m;
            let error = if let Some(c) = calib {
                let motion = keyframe_motion(kf);
                let exposure = &exposures[row.kf];
                if build {
                    reproject_exposed(
                        camera,
                        row.camera as usize,
                        &c.T_cam0_cam[row.camera as usize],
                        exposure,
                        &motion,
                        &point,
                        &obs.pixel,
                    )
                    .filter(|(r, _)| r.depth_m > 0.0)
                    .map(|(r, mut d_calib)| {
                        if follow && row.kf < p.n_fixed {
                            // A held keyframe's camera stays where its
                            // images put it (`held_cameras`).
                            d_calib.columns_mut(0, CALIB_STEREO).fill(0.0);
                        }
                        row.d_pose = r.d_pose * inv_sigma;
                        row.d_point = r.d_point * inv_sigma;
                        row.d_calib = d_calib * inv_sigma;
                        r.error_px
                    })
                } else {
                    reprojection_error(camera, &exposure.pose, &point, &obs.pixel)
                        .filter(|(_, depth)| *depth > 0.0)
                        .map(|(e, _)| e)
                }
            } else if build {
                reproject(camera, &kf.state.T_world_body, &point, &obs.pixel)
                    .filter(|r| r.depth_m > 0.0)
                    .map(|r| {
                        row.d_pose = r.d_pose * inv_sigma;
                        row.d_point = r.d_point * inv_sigma;
                        r.error_px
                    })
            } else {
                reprojection_error(camera, &kf.state.T_world_body, &point, &obs.pixel)
                    .filter(|(_, depth)| *depth > 0.0)
                    .map(|(e, _)| e)
            };
            match error {
                Some(e) => {
                    row.valid = true;
                    row.residual = e * inv_sigma;
                    let whitened = row.residual.norm_squared();
                    row.sq_error = whitened * to_declared;
                    let (rho, weight) = kernel.evaluate(whitened, k);
                    row.weight = weight;
                    cost += 0.5 * rho;
                }
                None => {
                    row.valid = false;
                    row.weight = 0.0;
                    row.sq_error = INVALID_SQ_ERROR;
                    cost += invalid_cost;
                }
            }
        }
        if build {
            schur::accumulate_observations(
                &mut p.eq,
                &mut p.rows,
                &mut p.landmarks,
                p.calib_offset,
            );
        }
        if let (Some(oc), Some(c)) = (p.calib_offset, calib) {
            for (r, j) in c.prior_factors() {
                cost += 0.5 * r.norm_squared();
                if build {
                    p.eq.add_factor(
                        &r,
                        &j,
                        &[Chunk {
                            col: 0,
                            len: CALIB_DIM,
                            offset: Some(oc),
                        }],
                    );
                }
            }
        }

        let n = keyframes.len();
        let (nf, sd) = (p.n_fixed, p.state_dim);
        let offset = |pos: usize| (pos >= nf).then(|| (pos - nf) * sd);
        if self.use_imu {
            // From the newest fixed keyframe (its pose held, its velocity
            // and biases estimated) through the free ones.
            let ob = p.boundary_offset;
            // Columns of keyframe `pos`'s [v, b_g, b_a] in the system.
            let rest = |pos: usize| {
                if pos + 1 == nf {
                    ob
                } else {
                    offset(pos).map(|o| o + VEL)
                }
            };
            for pos in nf.max(1)..n {
                let (ki, kj) = (&keyframes[pos - 1], &keyframes[pos]);
                if let Some(link) = &kj.imu {
                    let (r, j) = inertial_factor(
                        link,
                        &ki.state,
                        &kj.state,
                        &self.gravity_dir,
                        &p.gravity_basis,
                    );
                    cost += 0.5 * r.norm_squared();
                    let chunks = [
                        Chunk {
                            col: 0,
                            len: VEL,
                            offset: offset(pos - 1),
                        },
                        Chunk {
                            col: VEL,
                            len: BOUNDARY_DIM,
                            offset: rest(pos - 1),
                        },
                        Chunk {
                            col: FULL_DIM,
                            len: FULL_DIM,
                            offset: offset(pos),
                        },
                        Chunk {
                            col: GRAVITY_COL,
                            len: 2,
                            offset: p.gravity_offset,
                        },
                    ];
                    let boundary_calibration = match (follow && pos == nf, calib, p.calib_offset) {
                        (true, Some(c), Some(oc)) => Some((c, oc)),
                        _ => None,
                    };
                    if let (true, Some((c, oc))) = (build, boundary_calibration) {
                        // The boundary's body state follows the
                        // calibration: the link reaches it through it.
                        let mut joined = SMatrix::<f64, 9, { INERTIAL_COLS + CALIB_DIM }>::zeros();
                        joined
                            .fixed_view_mut::<9, INERTIAL_COLS>(0, 0)
                            .copy_from(&j);
                        joined
                            .fixed_view_mut::<9, CALIB_DIM>(0, INERTIAL_COLS)
                            .copy_from(&held_cameras::boundary_link_columns(
                                &j,
                                &ki.state,
                                &ki.omega_body_rad_s,
                                &held_cameras::Mount::of(c),
                            ));
                        let calibration = Chunk {
                            col: INERTIAL_COLS,
                            len: CALIB_DIM,
                            offset: Some(oc),
                        };
                        let [first, boundary, second, gravity] = chunks;
                        p.eq.add_factor(
                            &r,
                            &joined,
                            &[first, boundary, second, gravity, calibration],
                        );
                    } else if build {
                        p.eq.add_factor(&r, &j, &chunks);
                    }
                }
                if let Some(declared) = &kj.bias_walk_sqrt_info {
                    let sqrt_info = walk_scale.walk(declared);
                    let (r, j) = bias_walk_factor(&sqrt_info, &ki.state, &kj.state);
                    cost += 0.5 * r.norm_squared();
                    if build {
                        let bias = |pos: usize| rest(pos).map(|o| o + (BG - VEL));
                        p.eq.add_factor(
                            &r,
                            &j,
                            &[
                                Chunk {
                                    col: 0,
                                    len: 6,
                                    offset: bias(pos - 1),
                                },
                                Chunk {
                                    col: 6,
                                    len: 6,
                                    offset: bias(pos),
                                },
                            ],
                        );
                    }
                }
            }
            // Eq. 34: the prior on the newest fixed keyframe's [v, b_g, b_a].
            if let Some(prior) = &self.velocity_prior {
                if nf >= 1 && keyframes[nf - 1].seq == prior.seq {
                    let (r, j) = prior.factor(&keyframes[nf - 1].state);
                    cost += 0.5 * r.norm_squared();
                    if build {
                        p.eq.add_factor(
                            &r,
                            &j,
                            &[Chunk {
                                col: 0,
                                len: BOUNDARY_DIM,
                                offset: ob,
                            }],
                        );
                    }
                }
            }
            if let Some(og) = p.gravity_offset {
                let (r, j) = self
                    .gravity_prior
                    .factor(&self.gravity_dir, &p.gravity_basis);
                cost += 0.5 * r.norm_squared();
                if build {
                    p.eq.add_factor(
                        &r,
                        &j,
                        &[Chunk {
                            col: 0,
                            len: 2,
                            offset: Some(og),
                        }],
                    );
                }
            }
        } else if p.stereo_rows == 0 && nf == 1 && n >= 2 {
            if let Some(anchor) = self
                .scale_anchor
                .filter(|a| a.seq_first == keyframes[0].seq && a.seq_second == keyframes[1].seq)
            {
                let (r, j) = anchor.factor(
                    &keyframes[0].state.T_world_body.translation.vector,
                    &keyframes[1].state.T_world_body.translation.vector,
                );
                cost += 0.5 * r * r;
                if build {
                    p.eq.add_factor(
                        &SVector::<f64, 1>::new(r),
                        &SMatrix::<f64, 1, 3>::from(j),
                        &[Chunk {
                            col: 0,
                            len: 3,
                            offset: offset(1).map(|o| o + 3),
                        }],
                    );
                }
            }
        }
        cost
    }

    pub(super) fn save_backup(&mut self) {
        let p = &mut self.problem;
        p.backup_states.clear();
        p.backup_states
            .extend(self.keyframes.iter().map(|k| k.state));
        p.backup_landmarks.clear();
        p.backup_landmarks
            .extend(p.landmarks.iter().map(|l| l.position_world_m));
        p.backup_gravity = self.gravity_dir;
        p.backup_calibration = self.camera_imu.as_ref().map(|c| c.values());
        p.backup_velocity_prior = self.velocity_prior;
    }

    pub(super) fn restore_backup(&mut self) {
        let p = &mut self.problem;
        for (kf, s) in self.keyframes.iter_mut().zip(&p.backup_states) {
            kf.state = *s;
        }
        for (l, b) in p.landmarks.iter_mut().zip(&p.backup_landmarks) {
            l.position_world_m = *b;
        }
        self.gravity_dir = p.backup_gravity;
        self.velocity_prior = p.backup_velocity_prior;
        if let (Some(c), Some(v)) = (self.camera_imu.as_mut(), &p.backup_calibration) {
            c.restore(v);
            c.place(&mut self.cameras);
        }
    }

    /// Applies the solved step; returns its largest component.
    pub(super) fn apply_step(&mut self) -> f64 {
        let p = &mut self.problem;
        let sd = p.state_dim;
        let delta = p.eq.delta.as_slice();
        for (slot, kf) in self.keyframes.iter_mut().skip(p.n_fixed).enumerate() {
            apply_update(&mut kf.state, &delta[slot * sd..(slot + 1) * sd]);
        }
        let mut largest = p.eq.delta.amax();
        for l in p.landmarks.iter_mut() {
            l.position_world_m += l.delta;
            largest = largest.max(l.delta.amax());
        }
        if let Some(og) = p.gravity_offset {
            let d = Vector2::new(delta[og], delta[og + 1]);
            self.gravity_dir = update_direction(&self.gravity_dir, &p.gravity_basis, &d);
        }
        let mut mounts = None;
        if let (Some(oc), Some(c)) = (p.calib_offset, self.camera_imu.as_mut()) {
            let from = held_cameras::Mount::of(c);
            c.apply(&delta[oc..oc + CALIB_DIM]);
            c.place(&mut self.cameras);
            if c.held_keyframes_follow() {
                mounts = Some((from, held_cameras::Mount::of(c)));
            }
        }
        if let (Some(ob), Some(kf)) = (p.boundary_offset, p.n_fixed.checked_sub(1)) {
            let s = &mut self.keyframes[kf].state;
            let v3 = |o: usize| Vector3::new(delta[o], delta[o + 1], delta[o + 2]);
            s.velocity_world_m_s += v3(ob);
            s.biases.gyro_rad_s += v3(ob + 3);
            s.biases.accel_m_s2 += v3(ob + 6);
        }
        if let Some((from, to)) = mounts {
            self.held_follow_calibration(&from, &to);
        }
        largest
    }

    /// The held keyframes keep their cameras when the calibration moved
    /// from `from` to `to` ([`held_cameras`]): their body states follow,
    /// and the boundary's velocity prior with its velocity.
    fn held_follow_calibration(&mut self, from: &held_cameras::Mount, to: &held_cameras::Mount) {
        let n_fixed = self.problem.n_fixed;
        for kf in self.keyframes.iter_mut().take(n_fixed) {
            let change = held_cameras::follow(&mut kf.state, &kf.omega_body_rad_s, from, to);
            if let Some(prior) = self.velocity_prior.as_mut().filter(|p| p.seq == kf.seq) {
                let mut mean = prior.mean.fixed_rows_mut::<3>(0);
                mean += change;
            }
        }
    }

    /// Flags observations above the chi-square threshold at the current
    /// estimate, then the landmarks that fail the landmark test
    /// ([`super::landmark_consistency`]); adds them to the report and
    /// returns how many observations were newly flagged.
    pub(super) fn flag_outliers(&mut self, report: &mut WindowReport) -> usize {
        self.linearize(false);
        let chi2 = self.config.outlier_chi2;
        let mut flagged = 0;
        for row in &self.problem.rows {
            if row.valid && row.sq_error <= chi2 {
                continue;
            }
            let o = &mut self.keyframes[row.kf].observations[row.obs_index];
            if !o.outlier {
                o.outlier = true;
                flagged += 1;
            }
        }
        let (more, landmarks) = self.flag_inconsistent_landmarks();
        report.new_outliers += flagged + more;
        report.inconsistent_landmarks += landmarks;
        flagged + more
    }

    /// Linearises at the final estimate, inverts the reduced system and
    /// keeps what the next solve and the absolute stage need: the free
    /// velocities' marginals, the gravity prior, the body-frame landmarks.
    pub(super) fn compute_marginals(&mut self) -> bool {
        // The published covariance's own system when its pixel sigma is
        // not the estimate's: inverted, and its coupling to the held
        // poses taken, before the estimator's system replaces it.
        let published = (self.use_imu && self.covariance_pixel_scale() != self.noise.scale().pixel)
            .then(|| {
                self.problem.covariance_pixels = true;
                self.linearize(true);
                self.problem.covariance_pixels = false;
                let p = &mut self.problem;
                schur::reduced_inverse(&mut p.eq, &p.rows, &mut p.landmarks, p.calib_offset).map(
                    |cov| {
                        let coupling = self.held_pose_coupling();
                        (cov, coupling)
                    },
                )
            });
        self.linearize(true);
        let cov = {
            let p = &mut self.problem;
            schur::reduced_inverse(&mut p.eq, &p.rows, &mut p.landmarks, p.calib_offset)
        };
        if let (Some(oc), Some(c)) = (self.problem.calib_offset, self.camera_imu.as_mut()) {
            c.after_solve(
                cov.as_ref()
                    .map(|m| m.fixed_view::<CALIB_DIM, CALIB_DIM>(oc, oc).into_owned()),
            );
            if c.take_release_in_flight() {
                tracing::info!(
                    "camera-IMU calibration released after a start in flight: the gyroscope bias the alignment found through the file's rotation is freed to {} rad/s (camera_imu_release_frees_gyro_bias)",
                    self.config.gyro_bias_prior_sigma_rad_s
                );
                self.widen_gyro_bias_next_solve = true;
            }
            let e = c.estimate();
            tracing::trace!(
                t_ns = self.keyframes.back().map_or(0, |k| k.state.t_ns),
                rotation_from_file_deg = e.rotation_from_file_deg,
                translation_from_file_m = e.translation_from_file_m,
                time_offset_s = e.time_offset_s,
                "camera-IMU estimate"
            );
        }
        let weighed_gravity_prior = self.gravity_prior;
        if let Some(cov) = &cov {
            let p = &self.problem;
            for (slot, kf) in self.keyframes.iter_mut().skip(p.n_fixed).enumerate() {
                let o = slot * p.state_dim;
                kf.pose_marginal = Some(cov.fixed_view::<6, 6>(o, o).into_owned());
            }
            if self.use_imu {
                for (slot, kf) in self.keyframes.iter_mut().skip(p.n_fixed).enumerate() {
                    let o = slot * p.state_dim;
                    kf.state_marginal = Some(cov.fixed_view::<15, 15>(o, o).into_owned());
                }
            }
            if let Some(og) = p.gravity_offset {
                let c2: Matrix2<f64> = cov.fixed_view::<2, 2>(og, og).into_owned();
                let prior = GravityPrior::from_marginal(
                    self.gravity_dir,
                    p.gravity_basis,
                    &c2,
                    self.config.gravity_prior_weight,
                );
                if let Some(prior) = prior {
                    self.gravity_prior = prior;
                }
            }
        }
        self.update_pose_covariances(self.problem.n_fixed);
        match (published, &cov) {
            (Some(Some((c, coupling))), _) => {
                self.propagate_pose_covariances(&c, &coupling, &weighed_gravity_prior)
            }
            // Without the IMU the chain stays: carried by the
            // propagation, the vision-only covariance in the estimated
            // pixel noise scored 11.5 on the development set (the chain
            // 1.3); see docs/results/pose-covariance-2026-12-02.md.
            (None, Some(c)) if self.use_imu => {
                let coupling = self.held_pose_coupling();
                self.propagate_pose_covariances(c, &coupling, &weighed_gravity_prior);
            }
            _ => {}
        }
        self.fill_body_landmarks(cov.as_ref());
        let exact = cov.is_some();
        self.state_covariance = cov;
        exact
    }

    /// Landmarks the newest keyframe sees, in its body frame, with their
    /// covariance (see [`Window::landmarks_in_body`]).
    fn fill_body_landmarks(&mut self, cov: Option<&DMatrix<f64>>) {
        self.body_landmarks.clear();
        let Some(newest) = self.keyframes.back() else {
            return;
        };
        let mut z = std::mem::take(&mut self.problem.z_buffer);
        let p = &self.problem;
        if z.nrows() != p.eq.dim {
            z = DMatrix::<f64>::zeros(p.eq.dim, 3);
        }
        let newest_pos = self.keyframes.len() - 1;
        let newest_offset =
            (newest_pos >= p.n_fixed).then(|| (newest_pos - p.n_fixed) * p.state_dim);
        let r_wb = newest
            .state
            .T_world_body
            .rotation
            .to_rotation_matrix()
            .into_inner();
        let r_bw = r_wb.transpose();
        let t = newest.state.T_world_body.translation.vector;
        let chi2 = self.config.outlier_chi2;
        let mut observing: Vec<usize> = Vec::new();
        for lm in &p.landmarks {
            let rows = &p.rows[lm.rows.clone()];
            let seen = rows
                .iter()
                .any(|r| r.kf == newest_pos && r.valid && r.sq_error <= chi2);
            if !seen || !lm.usable {
                continue;
            }
            let p_body = r_bw * (lm.position_world_m - t);
            let covariance = match cov {
                Some(s_inv) => {
                    // Z = S^-1 Y with Y_a = W_a V^-1 (only the keyframes
                    // seeing the landmark); Sigma_xl = -Z.
                    z.fill(0.0);
                    for r in rows {
                        if let Some(o) = r.offset.filter(|_| r.valid) {
                            let y = r.w_block * lm.v_inv;
                            z.gemm(1.0, &s_inv.columns(o, 6), &y, 1.0);
                        }
                    }
                    let y_calib = p.calib_offset.map(|oc| (oc, lm.w_calib * lm.v_inv));
                    if let Some((oc, y)) = &y_calib {
                        z.gemm(1.0, &s_inv.columns(*oc, CALIB_DIM), y, 1.0);
                    }
                    let mut sigma_ll = lm.v_inv;
                    for r in rows {
                        if let Some(o) = r.offset.filter(|_| r.valid) {
                            let y = r.w_block * lm.v_inv;
                            sigma_ll += y.transpose() * z.fixed_view::<6, 3>(o, 0);
                        }
                    }
                    if let Some((oc, y)) = &y_calib {
                        sigma_ll += y.transpose() * z.fixed_view::<CALIB_DIM, 3>(*oc, 0);
                    }
                    let mut c = r_bw * sigma_ll * r_wb;
                    if let Some(on) = newest_offset {
                        let mut jn = SMatrix::<f64, 3, 6>::zeros();
                        jn.fixed_view_mut::<3, 3>(0, 0).copy_from(&hat(&p_body));
                        jn.fixed_view_mut::<3, 3>(0, 3).copy_from(&(-r_bw));
                        let zn: SMatrix<f64, 6, 3> = z.fixed_view::<6, 3>(on, 0).into_owned();
                        let snn: SMatrix<f64, 6, 6> = s_inv.fixed_view::<6, 6>(on, on).into_owned();
                        let cross = jn * zn * r_wb;
                        c += jn * snn * jn.transpose() - cross - cross.transpose();
                    }
                    c
                }
                None => r_bw * lm.v_inv * r_wb,
            };
            let covariance = (covariance + covariance.transpose()) * 0.5;
            if covariance.iter().all(|v| v.is_finite()) && p_body.iter().all(|v| v.is_finite()) {
                // Keyframes with a valid observation (one row per camera).
                observing.clear();
                observing.extend(rows.iter().filter(|r| r.valid).map(|r| r.kf));
                observing.sort_unstable();
                observing.dedup();
                let support = observing.last().map(|&newest| WindowSupport {
                    keyframes: u16::try_from(observing.len()).unwrap_or(u16::MAX),
                    newest_keyframe: self.keyframes[newest].seq,
                });
                self.body_landmarks.push(BodyLandmark {
                    id: lm.id,
                    position_body_m: p_body,
                    covariance_body_m2: covariance,
                    descriptor: None,
                    support,
                });
            }
        }
        self.problem.z_buffer = z;
    }
}

/// The body's motion at keyframe `kf`, for its pose at exposure.
fn keyframe_motion(kf: &Keyframe) -> BodyMotion {
    BodyMotion {
        omega_body_rad_s: kf.omega_body_rad_s,
        velocity_world_m_s: kf.state.velocity_world_m_s,
    }
}

#[cfg(test)]
impl Window {
    pub(super) fn refresh_velocity_prior_for_tests(&mut self, n_fixed: usize) {
        self.refresh_velocity_prior(n_fixed);
    }
}
