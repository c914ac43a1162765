//! How noisy the IMU really is, estimated online from the window's own
//! inertial residuals (variance component estimation).
//!
//! The calibration declares white-noise densities for the gyroscope and
//! the accelerometer: a datasheet's, or Allan values measured at rest.
//! A rig in motion disagrees with its images by more than that
//! (vibration, a misalignment left over by the calibration, scale errors,
//! the time offset): on the real EuRoC V1_02 log the accelerometer is ten
//! to fifteen times, the gyroscope four times noisier than its datasheet
//! says. Weighted by the datasheet the window then trusts the IMU over
//! the camera, and a stereo rig with an IMU does worse than without.
//!
//! Each inertial link is measured once, in the solve in which it is the
//! oldest one optimised (its keyframes have then been in the window
//! longest). Its whitened residual splits into the rotation rows, which
//! only the gyroscope's noise reaches (the whitening is a lower-triangular
//! Cholesky factor over `[r_R, r_v, r_p]`), and the velocity and position
//! rows given the rotation, which are the accelerometer's (the gyroscope's
//! share there is under 1 % of the variance at keyframe spacing). For
//! each part, `chi2` is its squared whitened residual and its redundancy
//! `dof - tr(J Sigma J^T)` (Förstner's redundancy number: the share of
//! that part's noise left in the residual, `Sigma` the solve's posterior
//! covariance of the states the link touches). Then
//! `E[chi2] = redundancy * (true variance / weighted variance)`, so
//! `scale^2 <- scale^2 * sum(chi2) / sum(redundancy)` over a horizon of
//! `memory_s`, started from the declared value with the weight of
//! `prior_links` links, clamped to `[min_scale, max_scale]`.
//!
//! The bias random walk between the link's keyframes can be measured the
//! same way (its gyroscope and accelerometer rows; `adapt_walk`, off by
//! default): a real IMU's error is not white, and what is slow in it
//! looks like a bias that wanders faster than the datasheet's walk
//! allows. On the development renderings (real V1_02 IMU, datasheet
//! noise, seeds 0-5) it lets the accelerometer walk grow 16-20x and the
//! white-noise scale fall to 3-4x, which leaves stereo-inertial as it was
//! (mean ATE over seeds 0-3: 0.024 against 0.023 m) and makes
//! mono-inertial worse (0.052 against 0.048 m); the gyroscope walk's rows have no
//! redundancy left under the datasheet's walk and never move.
//!
//! A link can also be tested together with the next ones
//! (`joined_links`, in the window's module of that name): their intervals joined
//! into one, its residual the transported sum of theirs, its redundancy
//! exact for the solve. An error that is slow against one link adds up
//! there. On the real-IMU renderings the joined test asks for more than
//! one link's (two links: gyroscope 5.2x against 3.7x, accelerometer
//! 8.5x against 8.0x in mono-inertial), and from an overweighted start it
//! asks for it sooner; but with the window's three held keyframes it reads
//! white gyroscope noise about 1.6 times too high (their pose errors are
//! not in the solve's covariance), and measured on all three accuracy
//! sets it costs stereo-inertial 13 % on the development set. Off by
//! default (one link); see bench/accuracy/README.md.
//!
//! The same is done for the camera: the reprojection errors of the
//! solve's inlier observations against their redundancy (two per
//! observation less three per landmark and six per free keyframe), which
//! gives the pixel sigma the features really have. This matters as much
//! as the IMU's own residuals: an IMU whose error is slow (a drifting
//! misalignment, vibration below the keyframe rate) fits each link well
//! once the velocities and biases have bent towards it, and what it costs
//! shows in the images instead. Only the ratio of the two weights moves
//! the estimate; both are estimated so that the ratio is the data's.
//!
//! The scales multiply the declared densities in every inertial term of
//! the window (and in the boundary prior that carries them forward) and
//! the pixel sigma of its reprojection terms; the outlier gates stay in
//! declared pixels, the bias random walks keep their declared values.
//! Without the IMU the pixel sigma is measured too, but only the
//! published pose covariance takes it (the solve keeps the declared
//! sigma; see `Window::vision_only_covariance_factor`).

use nalgebra::Vector6;

/// Multipliers on the declared noise densities (standard deviations).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct NoiseScale {
    /// On the declared gyroscope noise density.
    pub gyro: f64,
    /// On the declared accelerometer noise density.
    pub accel: f64,
    /// On the declared pixel sigma of a feature.
    pub pixel: f64,
    /// On the declared bias random walks of the gyroscope and the
    /// accelerometer.
    pub gyro_walk: f64,
    /// On the declared accelerometer bias random walk.
    pub accel_walk: f64,
}

impl NoiseScale {
    /// Every multiplier 1: the noise as declared.
    pub const DECLARED: Self = Self {
        gyro: 1.0,
        accel: 1.0,
        pixel: 1.0,
        gyro_walk: 1.0,
        accel_walk: 1.0,
    };

    /// A bias walk's `1 / sigma` (gyro 3, accel 3) under these scales.
    pub fn walk(&self, declared_sqrt_info: &Vector6<f64>) -> Vector6<f64> {
        let mut s = *declared_sqrt_info;
        for k in 0..3 {
            s[k] /= self.gyro_walk;
            s[k + 3] /= self.accel_walk;
        }
        s
    }
}

/// Settings of the adaptation (defaults in brackets).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NoiseAdaptationConfig {
    /// Estimate the scale online [true]; false keeps the declared noise
    /// times `initial`.
    pub enabled: bool,
    /// The scale to start from (and keep, when not enabled) [1, 1].
    pub initial: NoiseScale,
    /// Horizon of the estimate, s of IMU links \[20\].
    pub memory_s: f64,
    /// Weight of the starting value, in links \[3\].
    pub prior_links: f64,
    /// Bounds of either scale [0.1, 100].
    pub min_scale: f64,
    /// Upper bound of either scale.
    pub max_scale: f64,
    /// Estimate the bias random walks' scales too [false].
    pub adapt_walk: bool,
    /// How many consecutive links each measurement joins [1]: with more
    /// than one, the oldest links of each solve are tested together
    /// (`super::joined_links`), which sees an error that is slow against
    /// one link.
    pub joined_links: usize,
}

impl Default for NoiseAdaptationConfig {
    fn default() -> Self {
        Self {
            enabled: true,
            initial: NoiseScale::DECLARED,
            memory_s: 20.0,
            prior_links: 3.0,
            min_scale: 0.1,
            max_scale: 100.0,
            adapt_walk: false,
            joined_links: 1,
        }
    }
}

impl NoiseAdaptationConfig {
    /// Checks that the horizon, prior weight and bounds are positive and finite, the bounds ordered
    /// and the initial gyro and accel scales within them; the message names the key.
    pub fn validate(&self) -> Result<(), String> {
        let positive = |name: &str, v: f64| {
            if v.is_finite() && v > 0.0 {
                Ok(())
            } else {
                Err(format!("{name} must be positive and finite, got {v}"))
            }
        };
        positive("imu_noise_adaptation_memory_s", self.memory_s)?;
        positive("imu_noise_adaptation_prior_links", self.prior_links)?;
        positive("imu_noise_scale_min", self.min_scale)?;
        positive("imu_noise_scale_max", self.max_scale)?;
        if !(1..=MAX_JOINED_LINKS).contains(&self.joined_links) {
            return Err(format!(
                "imu_noise_adaptation_joined_links must be between 1 and {MAX_JOINED_LINKS}, got {}",
                self.joined_links
            ));
        }
        if self.min_scale > self.max_scale {
            return Err(format!(
                "imu_noise_scale_min ({}) must not exceed imu_noise_scale_max ({})",
                self.min_scale, self.max_scale
            ));
        }
        for (name, v) in [
            ("imu_noise_scale_gyro", self.initial.gyro),
            ("imu_noise_scale_accel", self.initial.accel),
        ] {
            positive(name, v)?;
            if !(self.min_scale..=self.max_scale).contains(&v) {
                return Err(format!(
                    "{name} = {v} is outside [imu_noise_scale_min, imu_noise_scale_max] = [{}, {}]",
                    self.min_scale, self.max_scale
                ));
            }
        }
        Ok(())
    }
}

/// The most links one measurement may join (a window holds about ten).
pub const MAX_JOINED_LINKS: usize = 6;

/// One link's evidence: squared whitened residuals and redundancies of
/// its rotation rows and of its velocity and position rows, under the
/// scale it was whitened with.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LinkEvidence {
    /// Squared whitened residual of the rotation rows (3).
    pub chi2_rotation: f64,
    /// Redundancy of the rotation rows: 3 minus their leverage (how much of them other terms also
    /// measure).
    pub redundancy_rotation: f64,
    /// Squared whitened residual of the velocity and position rows (6).
    pub chi2_translation: f64,
    /// Redundancy of the velocity and position rows.
    pub redundancy_translation: f64,
    /// The bias walk's gyroscope and accelerometer rows.
    pub chi2_gyro_walk: f64,
    /// Redundancy of the gyroscope bias walk rows.
    pub redundancy_gyro_walk: f64,
    /// Squared whitened residual of the accelerometer bias walk rows (3).
    pub chi2_accel_walk: f64,
    /// Redundancy of the accelerometer bias walk rows.
    pub redundancy_accel_walk: f64,
    /// Length of the link, s.
    pub dt_s: f64,
}

/// The running estimate.
#[derive(Debug, Clone, PartialEq)]
pub struct NoiseAdaptation {
    config: NoiseAdaptationConfig,
    scale: NoiseScale,
    /// Forgetting sums in units of the declared noise: chi2 (times the
    /// scale's square it was whitened with) and redundancy.
    gyro_sums: (f64, f64),
    accel_sums: (f64, f64),
    pixel_sums: (f64, f64),
    gyro_walk_sums: (f64, f64),
    accel_walk_sums: (f64, f64),
    links: u64,
    /// Consecutive links with a scale at a bound (warned at the first).
    links_at_bound: u64,
    /// The pixel scale reached its floor since it was last above it
    /// (said once each time).
    pixel_at_floor: bool,
}

/// A redundancy below this share of the rows' count says the link is not
/// measured by anything else: its residual tells nothing (the first link
/// of a window, whose states nothing else reaches yet, has 1e-8).
///
/// Low redundancy is not the same as no evidence. An IMU weighed far
/// above its real noise leaves little of its noise in its own residual,
/// because the states bend towards it: declared at half the datasheet on
/// the real V1_02 log (about 32 times too small), mono-inertial links
/// have a translation redundancy of 0.03-0.13, and their squared
/// residuals still say the variance is 11 times what was weighed. The
/// sums weigh each link by its redundancy, so such a link counts for
/// what it measures. A floor of 5 % of the rows (the first version)
/// ignored all of them and held the scale at the value it started from
/// for the whole run.
const MIN_REDUNDANCY_SHARE: f64 = 1e-4;

impl NoiseAdaptation {
    /// An estimator starting from `config.initial`, weighted as `prior_links` links' worth.
    pub fn new(config: NoiseAdaptationConfig) -> Self {
        let s = config.initial;
        let w = config.prior_links;
        Self {
            config,
            scale: s,
            gyro_sums: (w * 3.0 * s.gyro * s.gyro, w * 3.0),
            accel_sums: (w * 6.0 * s.accel * s.accel, w * 6.0),
            pixel_sums: (w * 6.0 * s.pixel * s.pixel, w * 6.0),
            gyro_walk_sums: (w * 3.0 * s.gyro_walk * s.gyro_walk, w * 3.0),
            accel_walk_sums: (w * 3.0 * s.accel_walk * s.accel_walk, w * 3.0),
            links: 0,
            links_at_bound: 0,
            pixel_at_floor: false,
        }
    }

    /// The current multipliers.
    pub fn scale(&self) -> NoiseScale {
        self.scale
    }

    /// The settings it was built with.
    pub fn config(&self) -> &NoiseAdaptationConfig {
        &self.config
    }

    /// Links measured so far.
    pub fn links(&self) -> u64 {
        self.links
    }

    /// Whether a scale sits at a bound that says the declared noise is
    /// wrong: an IMU scale at either bound (the IMU far noisier, or far
    /// quieter, than the adaptation may follow), or the pixel scale at
    /// its ceiling (features far worse than declared). The pixel scale at
    /// its floor is not a fault: features more precise than a tenth of the
    /// declared sigma (sharp rendered images with the warped KLT reach
    /// it) are weighed at that tenth.
    pub fn at_bound(&self) -> bool {
        self.bounds_reached().next().is_some()
    }

    /// `v` at the lower bound of the scales.
    fn at_floor(&self, v: f64) -> bool {
        v <= self.config.min_scale * (1.0 + 1e-9)
    }

    /// `v` at the upper bound of the scales.
    fn at_ceiling(&self, v: f64) -> bool {
        v >= self.config.max_scale * (1.0 - 1e-9)
    }

    /// The scales at a bound that [`Self::at_bound`] counts: name, value
    /// and what it means.
    fn bounds_reached(&self) -> impl Iterator<Item = (&'static str, f64, &'static str)> + '_ {
        const NOISIER: &str = "the IMU disagrees with the images far more than its calibration declares; check the noise figures and the camera-IMU calibration";
        const QUIETER: &str = "the IMU agrees with the images far better than its calibration declares; check the noise figures (units: per sqrt(Hz))";
        const BLURRED: &str =
            "the features are far worse than pixel_sigma_px says; check the camera calibration";
        let s = &self.scale;
        [
            ("gyroscope noise", s.gyro),
            ("accelerometer noise", s.accel),
            ("gyroscope bias walk", s.gyro_walk),
            ("accelerometer bias walk", s.accel_walk),
        ]
        .into_iter()
        .filter_map(|(name, v)| {
            if self.at_ceiling(v) {
                Some((name, v, NOISIER))
            } else if self.at_floor(v) {
                Some((name, v, QUIETER))
            } else {
                None
            }
        })
        .chain(
            self.at_ceiling(s.pixel)
                .then_some(("pixel sigma", s.pixel, BLURRED)),
        )
    }

    /// The warning for the scales at a bound, each with what it means.
    fn bound_warning(&self) -> String {
        let said: Vec<String> = self
            .bounds_reached()
            .map(|(name, v, why)| format!("{name} at {v}x the declared: {why}"))
            .collect();
        format!(
            "IMU noise adaptation: a scale reached its bound [{}, {}]: {}",
            self.config.min_scale,
            self.config.max_scale,
            said.join("; ")
        )
    }

    /// Adds one solve's reprojection evidence: the squared whitened
    /// errors of its inlier observations (whitened with the current pixel
    /// scale) and their redundancy, over `dt_s` of keyframes.
    pub fn add_images(&mut self, chi2: f64, redundancy: f64, dt_s: f64) -> NoiseScale {
        let ok = [chi2, redundancy, dt_s].iter().all(|v| v.is_finite());
        if !self.config.enabled || !ok || redundancy < 1.0 || dt_s <= 0.0 {
            return self.scale;
        }
        let keep = (-dt_s / self.config.memory_s).exp();
        let s = self.scale.pixel;
        let sums = &mut self.pixel_sums;
        // The prior's weight is in links: scale it to this evidence's size
        // on the first solve so that it does not vanish at once.
        sums.0 = sums.0 * keep + chi2 * s * s;
        sums.1 = sums.1 * keep + redundancy;
        self.scale.pixel = (sums.0 / sums.1)
            .sqrt()
            .clamp(self.config.min_scale, self.config.max_scale);
        let at_floor = self.at_floor(self.scale.pixel);
        if at_floor && !self.pixel_at_floor {
            tracing::info!(
                "noise adaptation: the features are more precise than {} of the declared pixel sigma and are weighed at that (set pixel_sigma_px lower to weigh them fully)",
                self.config.min_scale
            );
        }
        self.pixel_at_floor = at_floor;
        self.scale
    }

    /// Adds one link's evidence and returns the new scale. Non-finite or
    /// unmeasured evidence is ignored.
    pub fn add(&mut self, e: &LinkEvidence) -> NoiseScale {
        if !self.config.enabled {
            return self.scale;
        }
        let finite = [
            e.chi2_rotation,
            e.redundancy_rotation,
            e.chi2_translation,
            e.redundancy_translation,
            e.chi2_gyro_walk,
            e.redundancy_gyro_walk,
            e.chi2_accel_walk,
            e.redundancy_accel_walk,
            e.dt_s,
        ]
        .iter()
        .all(|v| v.is_finite());
        if !finite || e.dt_s <= 0.0 {
            return self.scale;
        }
        let keep = (-e.dt_s / self.config.memory_s).exp();
        let (lo, hi) = (self.config.min_scale, self.config.max_scale);
        let update = |sums: &mut (f64, f64), chi2: f64, redundancy: f64, dof: f64, s: f64| {
            if !(redundancy >= MIN_REDUNDANCY_SHARE * dof) {
                return s;
            }
            // One link cannot ask for much more than the upper bound (twice
            // it): a residual the linearisation got wrong stays one link's
            // worth.
            let chi2 = chi2.min(redundancy * (2.0 * hi / s).powi(2));
            sums.0 = sums.0 * keep + chi2 * s * s;
            sums.1 = sums.1 * keep + redundancy;
            (sums.0 / sums.1).sqrt().clamp(lo, hi)
        };
        let gyro = update(
            &mut self.gyro_sums,
            e.chi2_rotation,
            e.redundancy_rotation,
            3.0,
            self.scale.gyro,
        );
        let accel = update(
            &mut self.accel_sums,
            e.chi2_translation,
            e.redundancy_translation,
            6.0,
            self.scale.accel,
        );
        let walk = self.config.adapt_walk;
        let gyro_walk = if !walk {
            self.scale.gyro_walk
        } else {
            update(
                &mut self.gyro_walk_sums,
                e.chi2_gyro_walk,
                e.redundancy_gyro_walk,
                3.0,
                self.scale.gyro_walk,
            )
        };
        let accel_walk = if !walk {
            self.scale.accel_walk
        } else {
            update(
                &mut self.accel_walk_sums,
                e.chi2_accel_walk,
                e.redundancy_accel_walk,
                3.0,
                self.scale.accel_walk,
            )
        };
        self.scale = NoiseScale {
            gyro,
            accel,
            pixel: self.scale.pixel,
            gyro_walk,
            accel_walk,
        };
        self.links += 1;
        if self.at_bound() {
            if self.links_at_bound == 0 {
                tracing::warn!("{}", self.bound_warning());
            }
            self.links_at_bound += 1;
        } else {
            self.links_at_bound = 0;
        }
        self.scale
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;
    use rand_distr::{ChiSquared, Distribution};

    /// Evidence drawn as the estimator would see it for a true scale
    /// `truth` while whitening with `current`: chi2 ~ redundancy-weighted
    /// chi-square times `(truth / current)^2`.
    fn draw(rng: &mut ChaCha8Rng, truth: NoiseScale, current: NoiseScale) -> LinkEvidence {
        let (rr, rt) = (2.4, 4.2);
        let chi_r: f64 = ChiSquared::new(rr).unwrap().sample(rng);
        let chi_t: f64 = ChiSquared::new(rt).unwrap().sample(rng);
        LinkEvidence {
            chi2_rotation: chi_r * (truth.gyro / current.gyro).powi(2),
            redundancy_rotation: rr,
            chi2_translation: chi_t * (truth.accel / current.accel).powi(2),
            redundancy_translation: rt,
            chi2_gyro_walk: 0.0,
            redundancy_gyro_walk: 0.0,
            chi2_accel_walk: 0.0,
            redundancy_accel_walk: 0.0,
            dt_s: 0.25,
        }
    }

    #[test]
    fn converges_to_the_true_scale_from_either_side() {
        let truth = NoiseScale {
            gyro: 4.0,
            accel: 12.0,
            pixel: 1.0,
            gyro_walk: 1.0,
            accel_walk: 1.0,
        };
        for start in [0.5, 1.0, 20.0] {
            let mut a = NoiseAdaptation::new(NoiseAdaptationConfig {
                initial: NoiseScale {
                    gyro: start,
                    accel: start,
                    pixel: 1.0,
                    gyro_walk: 1.0,
                    accel_walk: 1.0,
                },
                ..NoiseAdaptationConfig::default()
            });
            let mut rng = ChaCha8Rng::seed_from_u64(3);
            let mut log_err = Vec::new();
            for k in 0..400 {
                let e = draw(&mut rng, truth, a.scale());
                let s = a.add(&e);
                if k >= 200 {
                    log_err.push(((s.gyro / truth.gyro).ln(), (s.accel / truth.accel).ln()));
                }
            }
            let n = log_err.len() as f64;
            let mean_g = log_err.iter().map(|e| e.0).sum::<f64>() / n;
            let mean_a = log_err.iter().map(|e| e.1).sum::<f64>() / n;
            assert!(mean_g.abs() < 0.08, "start {start}: gyro off by {mean_g}");
            assert!(mean_a.abs() < 0.08, "start {start}: accel off by {mean_a}");
            assert!(!a.at_bound());
        }
    }

    /// Features three times sharper than declared: 300 observations of
    /// 100 landmarks per solve, errors of 0.33 declared sigmas.
    #[test]
    fn finds_the_pixel_sigma_the_features_have() {
        let mut a = NoiseAdaptation::new(NoiseAdaptationConfig::default());
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let redundancy: f64 = 2.0 * 300.0 - 3.0 * 100.0 - 6.0 * 7.0;
        for _ in 0..100 {
            let s = a.scale().pixel;
            let chi: f64 = ChiSquared::new(redundancy).unwrap().sample(&mut rng);
            a.add_images(chi * (0.33 / s).powi(2), redundancy, 0.25);
        }
        assert!(
            (a.scale().pixel / 0.33 - 1.0).abs() < 0.03,
            "{:?}",
            a.scale()
        );
        assert_eq!(a.scale().gyro, 1.0);
        // Nothing to learn from a solve without redundancy.
        let before = a.scale();
        assert_eq!(a.add_images(1e6, 0.5, 0.25), before);
    }

    /// The walk's scale moves only when asked to.
    #[test]
    fn the_bias_walk_scale_is_estimated_only_when_enabled() {
        let loud_walk = LinkEvidence {
            chi2_rotation: 2.0,
            redundancy_rotation: 2.0,
            chi2_translation: 4.0,
            redundancy_translation: 4.0,
            chi2_gyro_walk: 2.0,
            redundancy_gyro_walk: 2.0,
            chi2_accel_walk: 200.0,
            redundancy_accel_walk: 2.0,
            dt_s: 0.25,
        };
        let mut off = NoiseAdaptation::new(NoiseAdaptationConfig::default());
        let mut on = NoiseAdaptation::new(NoiseAdaptationConfig {
            adapt_walk: true,
            ..NoiseAdaptationConfig::default()
        });
        for _ in 0..200 {
            off.add(&loud_walk);
            let s = on.scale().accel_walk;
            on.add(&LinkEvidence {
                chi2_accel_walk: 200.0 / (s * s),
                ..loud_walk
            });
        }
        assert_eq!(off.scale().accel_walk, 1.0);
        assert!(
            (on.scale().accel_walk - 10.0).abs() < 0.5,
            "{:?}",
            on.scale()
        );
        assert!(
            (on.scale().gyro_walk - 1.0).abs() < 0.05,
            "{:?}",
            on.scale()
        );
    }

    /// An IMU declared far quieter than it is: the states bend towards it,
    /// so its links keep only `(current / truth)^2` of their redundancy
    /// (0.007 of the translation rows at the start here, as a mono-inertial
    /// window weighed at half the datasheet shows), and what they keep
    /// still says how much too small the weight is.
    #[test]
    fn climbs_out_of_an_overweighted_start() {
        let truth = NoiseScale {
            gyro: 4.0,
            accel: 12.0,
            ..NoiseScale::DECLARED
        };
        let start = NoiseScale {
            gyro: 0.5,
            accel: 0.5,
            ..NoiseScale::DECLARED
        };
        let mut a = NoiseAdaptation::new(NoiseAdaptationConfig {
            initial: start,
            ..NoiseAdaptationConfig::default()
        });
        let mut rng = ChaCha8Rng::seed_from_u64(9);
        let (r_rot, r_tr) = (2.4, 4.2);
        let mut last = start;
        for _ in 0..600 {
            let c = a.scale();
            let kept_g = (c.gyro / truth.gyro).powi(2).min(1.0);
            let kept_a = (c.accel / truth.accel).powi(2).min(1.0);
            let chi_r: f64 = ChiSquared::new(r_rot).unwrap().sample(&mut rng);
            let chi_t: f64 = ChiSquared::new(r_tr).unwrap().sample(&mut rng);
            let e = LinkEvidence {
                chi2_rotation: chi_r * kept_g * (truth.gyro / c.gyro).powi(2),
                redundancy_rotation: r_rot * kept_g,
                chi2_translation: chi_t * kept_a * (truth.accel / c.accel).powi(2),
                redundancy_translation: r_tr * kept_a,
                chi2_gyro_walk: 0.0,
                redundancy_gyro_walk: 0.0,
                chi2_accel_walk: 0.0,
                redundancy_accel_walk: 0.0,
                dt_s: 0.25,
            };
            last = a.add(&e);
        }
        assert!(
            (last.accel / truth.accel).ln().abs() < 0.25,
            "accel scale {} for a true {}",
            last.accel,
            truth.accel
        );
        assert!(
            (last.gyro / truth.gyro).ln().abs() < 0.25,
            "gyro scale {} for a true {}",
            last.gyro,
            truth.gyro
        );
    }

    #[test]
    fn clamps_at_the_bounds_and_says_so() {
        let mut a = NoiseAdaptation::new(NoiseAdaptationConfig::default());
        let mut rng = ChaCha8Rng::seed_from_u64(4);
        let truth = NoiseScale {
            gyro: 1e4,
            accel: 1.0,
            pixel: 1.0,
            gyro_walk: 1.0,
            accel_walk: 1.0,
        };
        for _ in 0..200 {
            let e = draw(&mut rng, truth, a.scale());
            a.add(&e);
        }
        assert_eq!(a.scale().gyro, 100.0);
        assert!(a.at_bound());
        let warning = a.bound_warning();
        assert!(
            warning.contains("gyroscope noise at 100x") && warning.contains("far more"),
            "{warning}"
        );
        assert!(!warning.contains("accelerometer"), "{warning}");
    }

    #[test]
    fn features_sharper_than_the_floor_are_not_a_fault_but_far_worse_ones_are() {
        let mut a = NoiseAdaptation::new(NoiseAdaptationConfig::default());
        // Reprojection errors a twentieth of the declared sigma: the
        // scale stops at its floor, 0.1, and nothing is flagged.
        for _ in 0..50 {
            let s = a.scale().pixel;
            a.add_images(100.0 * (0.05 / s).powi(2), 100.0, 0.5);
        }
        assert_eq!(a.scale().pixel, 0.1);
        assert!(!a.at_bound(), "{:?}", a.scale());
        // Errors 300 times the declared sigma: flagged, and said so.
        for _ in 0..200 {
            let s = a.scale().pixel;
            a.add_images(100.0 * (300.0 / s).powi(2), 100.0, 0.5);
        }
        assert_eq!(a.scale().pixel, 100.0);
        assert!(a.at_bound());
        let warning = a.bound_warning();
        assert!(warning.contains("pixel sigma at 100x"), "{warning}");
    }

    #[test]
    fn ignores_unmeasured_or_broken_evidence_and_stays_put_when_disabled() {
        let mut a = NoiseAdaptation::new(NoiseAdaptationConfig::default());
        let broken = LinkEvidence {
            chi2_rotation: f64::NAN,
            redundancy_rotation: 2.0,
            chi2_translation: 1.0,
            redundancy_translation: 4.0,
            chi2_gyro_walk: 1.0,
            redundancy_gyro_walk: 1.0,
            chi2_accel_walk: 1.0,
            redundancy_accel_walk: 1.0,
            dt_s: 0.2,
        };
        assert_eq!(a.add(&broken), NoiseScale::DECLARED);
        let unmeasured = LinkEvidence {
            chi2_rotation: 1e6,
            redundancy_rotation: 1e-8,
            chi2_translation: 1e6,
            redundancy_translation: 1e-8,
            chi2_gyro_walk: 1e6,
            redundancy_gyro_walk: 1e-8,
            chi2_accel_walk: 1e6,
            redundancy_accel_walk: 1e-8,
            dt_s: 0.2,
        };
        assert_eq!(a.add(&unmeasured), NoiseScale::DECLARED);
        let mut off = NoiseAdaptation::new(NoiseAdaptationConfig {
            enabled: false,
            ..NoiseAdaptationConfig::default()
        });
        let loud = LinkEvidence {
            chi2_rotation: 1e3,
            redundancy_rotation: 2.0,
            chi2_translation: 1e3,
            redundancy_translation: 4.0,
            chi2_gyro_walk: 1.0,
            redundancy_gyro_walk: 1.0,
            chi2_accel_walk: 1.0,
            redundancy_accel_walk: 1.0,
            dt_s: 0.2,
        };
        assert_eq!(off.add(&loud), NoiseScale::DECLARED);
        assert_eq!(a.add(&loud).gyro > 1.0, true);
    }

    #[test]
    fn validation_names_the_bad_key() {
        let bad = NoiseAdaptationConfig {
            initial: NoiseScale {
                gyro: 0.0,
                accel: 1.0,
                pixel: 1.0,
                gyro_walk: 1.0,
                accel_walk: 1.0,
            },
            ..NoiseAdaptationConfig::default()
        };
        assert!(bad.validate().unwrap_err().contains("noise_scale_gyro"));
        let bad = NoiseAdaptationConfig {
            min_scale: 10.0,
            max_scale: 1.0,
            ..NoiseAdaptationConfig::default()
        };
        assert!(bad.validate().unwrap_err().contains("noise_scale_min"));
        assert!(NoiseAdaptationConfig::default().validate().is_ok());
    }
}
