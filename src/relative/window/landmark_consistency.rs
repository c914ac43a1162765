//! The landmark test: after a solve, every landmark's inlier observations
//! together, in the pixel noise the features show
//! ([`super::noise_adaptation`]), against the chi-square quantile of
//! their degrees of freedom (two per observation less the point's three).
//!
//! The per-observation gate (`outlier_chi2`, in declared pixels) catches
//! a match that is far off once; it lets through a track that is a little
//! off in every frame. A stereo match across an occlusion boundary, or a
//! left-image track of a T-junction (where a box's edge crosses the wall
//! behind it, a point that slides along the edge as the rig moves), is
//! such a track: each of its errors stays under the gate, all of them
//! together are many sigma, and its pull on the window (on the stereo
//! pair's refined yaw first of all) is systematic. A landmark that fails
//! is taken out with every observation and its track is never
//! triangulated again while the window sees it. The test is made in the
//! inertial solves only, which are whitened with the measured pixel
//! noise; a vision-only solve keeps the declared one.

use super::Window;

/// The test's settings (defaults in brackets).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LandmarkTest {
    /// Probability of the chi-square quantile \[0.999\].
    pub probability: f64,
    /// The test's pixel sigma over the measured one \[4\]. Tracks'
    /// errors have heavy tails (on a rendered sequence the 95th
    /// percentile of a landmark's squared error per degree of freedom is
    /// 4-6 times the mean, where a Gaussian's is 1.5-2), and each landmark
    /// taken out lowers the measured sigma: in the measured sigma itself
    /// the test took out a third of the landmarks and drove the pixel
    /// scale to its bound. Of 2, 2.8 and 4 (on four copies of the
    /// accuracy sets, docs/results/landmark-test-2026-12-04.md), 4 is the
    /// one that keeps the calibration chain's tracking within its bar;
    /// beyond about 6 nothing is taken out.
    pub sigma_factor: f64,
}

impl Default for LandmarkTest {
    fn default() -> Self {
        Self {
            probability: 0.999,
            sigma_factor: 4.0,
        }
    }
}

impl LandmarkTest {
    /// Checks the probability is in [0.5, 1) and the factor at least 1.
    pub fn validate(&self) -> Result<(), String> {
        if !(self.probability >= 0.5 && self.probability < 1.0) {
            return Err(format!(
                "landmark_test probability must be in [0.5, 1), got {}",
                self.probability
            ));
        }
        if !(self.sigma_factor.is_finite() && self.sigma_factor >= 1.0) {
            return Err(format!(
                "landmark_test sigma_factor must be finite and at least 1, got {}",
                self.sigma_factor
            ));
        }
        Ok(())
    }
}

/// The standard normal quantile at `p` in (0, 1) (Abramowitz and Stegun
/// 26.2.23, absolute error under 4.5e-4).
fn normal_quantile(p: f64) -> f64 {
    let upper = p >= 0.5;
    let q = if upper { 1.0 - p } else { p };
    let t = (-2.0 * q.ln()).sqrt();
    let z = t
        - (2.515517 + 0.802853 * t + 0.010328 * t * t)
            / (1.0 + 1.432788 * t + 0.189269 * t * t + 0.001308 * t * t * t);
    if upper {
        z
    } else {
        -z
    }
}

/// The chi-square quantile with `dof` degrees of freedom at `p` in (0, 1)
/// (Wilson and Hilferty's cube-root approximation: within 4 % at one
/// degree of freedom and p = 0.999, within 2 % from five on and 1 % from ten).
pub(crate) fn chi_square_quantile(dof: usize, p: f64) -> f64 {
    let k = dof.max(1) as f64;
    let a = 2.0 / (9.0 * k);
    let c = 1.0 - a + normal_quantile(p) * a.sqrt();
    k * c.max(0.0).powi(3)
}

impl Window {
    /// Takes out the landmarks whose inlier observations together fail the
    /// test (see the module); returns how many observations that flagged
    /// and how many landmarks it took out. Call after the per-observation
    /// gate, with the rows' errors current.
    pub(super) fn flag_inconsistent_landmarks(&mut self) -> (usize, usize) {
        // Only where the solve is whitened with the measured pixel noise:
        // without the IMU it keeps the declared sigma
        // ([`Window::vision_only_covariance_factor`]), and the test there
        // lost track on every development sequence.
        let Some(test) = self.config.landmark_test.filter(|_| self.use_imu) else {
            return (0, 0);
        };
        let gate = self.config.outlier_chi2;
        // `sq_error` is in declared pixels; the test is in the measured
        // ones, times the test's factor.
        let sigma = self.noise.scale().pixel * test.sigma_factor;
        let to_measured = 1.0 / (sigma * sigma);
        let (mut flagged, mut taken) = (0, 0);
        let problem = &self.problem;
        for lm in &problem.landmarks {
            let rows = &problem.rows[lm.rows.clone()];
            let (mut sum, mut m) = (0.0, 0usize);
            for r in rows.iter().filter(|r| r.valid && r.sq_error <= gate) {
                sum += r.sq_error * to_measured;
                m += 1;
            }
            if m < 2 || sum <= chi_square_quantile(2 * m - 3, test.probability) {
                continue;
            }
            for r in rows {
                let o = &mut self.keyframes[r.kf].observations[r.obs_index];
                if !o.outlier {
                    o.outlier = true;
                    flagged += 1;
                }
            }
            self.landmarks.remove(&lm.id);
            self.pending.remove(&lm.id);
            self.rejected.insert(lm.id);
            taken += 1;
        }
        (flagged, taken)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::relative::window::synthetic::{keyframe_time, Scene};
    use crate::relative::window::WindowConfig;
    use nalgebra::Vector2;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;
    use std::collections::HashMap;

    /// Landmarks whose tracks slide: in every keyframe their pixels are
    /// 2 px off where the point projects, in a direction that turns from
    /// keyframe to keyframe and differs between the cameras. Each error
    /// is under the per-observation gate (2.45 px at the declared 1 px);
    /// the features are 0.15 px sharp (a rendered sequence's KLT matches:
    /// 0.165 px rms).
    fn slides(id: u64) -> bool {
        id % 41 == 0
    }

    /// Stereo-inertial sliding over 30 keyframes; returns the window and
    /// the landmarks the reports say were taken out.
    fn sliding_run(test: Option<LandmarkTest>) -> (Window, usize) {
        let mut r = ChaCha8Rng::seed_from_u64(71);
        let scene = Scene::new(&mut r, 1500, 9.0);
        let config = WindowConfig {
            use_imu: true,
            landmark_test: test,
            ..WindowConfig::default()
        };
        let mut w = Window::new(config, &scene.rig).expect("valid");
        let mut taken = 0;
        for k in 0..30 {
            let t = keyframe_time(k);
            let imu = (k > 0).then(|| scene.preintegrate(keyframe_time(k - 1), t));
            let mut frame = scene.frame(t, true, 0.15, 0.0, &mut r);
            for o in frame.observations.iter_mut().filter(|o| slides(o.landmark)) {
                let a = 0.9 * k as f64 + 2.0 * f64::from(o.camera_index);
                o.pixel += 2.0 * Vector2::new(a.cos(), a.sin());
            }
            w.push_keyframe(scene.truth(t), &frame, imu)
                .expect("valid keyframe");
            taken += w.optimize().inconsistent_landmarks;
        }
        (w, taken)
    }

    #[test]
    fn sliding_tracks_under_the_observation_gate_are_taken_out() {
        let (without, none) = sliding_run(None);
        let (with, taken) = sliding_run(Some(LandmarkTest::default()));
        // The sliding tracks the last window saw in at least five
        // keyframes: enough views for the test to see them (it needs
        // about that many at this size of error), and the clean landmarks.
        let mut views: HashMap<u64, usize> = HashMap::new();
        for k in &with.keyframes {
            let mut ids: Vec<u64> = k.observations.iter().map(|o| o.landmark).collect();
            ids.dedup();
            for id in ids {
                *views.entry(id).or_default() += 1;
            }
        }
        let long: Vec<u64> = views
            .iter()
            .filter(|(id, n)| slides(**id) && **n >= 5)
            .map(|(id, _)| *id)
            .collect();
        let mapped_long = |w: &Window| {
            long.iter()
                .filter(|id| w.landmarks.contains_key(id))
                .count()
        };
        let clean = |w: &Window| w.landmarks.keys().filter(|id| !slides(**id)).count();
        println!(
            "{} sliding tracks seen in 5 or more keyframes; mapped without the test {}, with it {}; clean landmarks mapped {} and {}; {taken} taken out over the run, pixel scale {:.3}",
            long.len(),
            mapped_long(&without),
            mapped_long(&with),
            clean(&without),
            clean(&with),
            with.noise.scale().pixel,
        );
        assert_eq!(none, 0);
        assert!(long.len() >= 5, "{} long sliding tracks", long.len());
        // Without the test the observation gate keeps them all.
        assert_eq!(mapped_long(&without), long.len());
        assert_eq!(mapped_long(&with), 0);
        // At most one clean landmark in a hundred goes with them.
        let clean_lost = clean(&without).saturating_sub(clean(&with));
        assert!(
            clean_lost * 100 <= clean(&without),
            "{clean_lost} clean landmarks of {} lost",
            clean(&without)
        );
        // A track taken out is not triangulated again.
        assert!(with
            .rejected
            .iter()
            .all(|id| !with.landmarks.contains_key(id)));
        assert!(long.iter().all(|id| with.rejected.contains(id)));
    }

    #[test]
    fn bad_settings_are_refused() {
        for (probability, sigma_factor) in [
            (0.3, 2.0),
            (1.0, 2.0),
            (f64::NAN, 2.0),
            (0.99, 0.5),
            (0.99, f64::INFINITY),
        ] {
            let t = LandmarkTest {
                probability,
                sigma_factor,
            };
            assert!(t.validate().is_err(), "{t:?}");
            let config = WindowConfig {
                landmark_test: Some(t),
                ..WindowConfig::default()
            };
            let err = config.validate().expect_err("refused");
            assert!(err.to_string().contains("landmark test"), "{err}");
        }
        assert!(LandmarkTest::default().validate().is_ok());
    }

    #[test]
    fn the_quantiles_match_the_chi_square_tables() {
        // Values from the chi-square distribution's tables.
        for (dof, p, table) in [
            (1, 0.999, 10.828),
            (2, 0.999, 13.816),
            (5, 0.999, 20.515),
            (10, 0.999, 29.588),
            (17, 0.99, 33.409),
            (20, 0.999, 45.315),
            (37, 0.999, 69.346),
            (3, 0.5, 2.366),
            (4, 0.95, 9.488),
        ] {
            let q = chi_square_quantile(dof, p);
            let tolerance = match dof {
                0..=4 => 0.04,
                5..=9 => 0.02,
                _ => 0.01,
            };
            assert!(
                (q / table - 1.0).abs() < tolerance,
                "dof {dof} p {p}: {q} against {table}"
            );
        }
    }

    #[test]
    fn the_normal_quantile_is_odd_and_matches_its_table() {
        for (p, z) in [(0.5, 0.0), (0.975, 1.95996), (0.999, 3.09023)] {
            assert!((normal_quantile(p) - z).abs() < 5e-4, "p {p}");
            assert!((normal_quantile(1.0 - p) + z).abs() < 5e-4, "p {p}");
        }
    }
}
