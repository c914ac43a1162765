//! Localising in a saved map: `rigslam run --load-map`.
//!
//! The relative stage runs as usual in its own world frame. Until the
//! robot is localised, each tracking frame's landmarks are matched to the
//! map by descriptor alone (brute force over the map, ratio test) and a
//! rigid transform relative-world -> map is fitted to the matches by
//! three-point RANSAC and refined on the inliers. From then on that
//! transform is held fixed, the position filter of the absolute stage
//! (eq. 60-71) runs in the map frame — prediction from the rotated
//! increments, correction from the recognised map landmarks with their
//! saved covariances — and new tracks are recognised against the map by
//! descriptor and Mahalanobis distance as in [`super::recognition`].
//! When the relative stage loses tracking its world frame is no longer
//! the one the transform was fitted in, so the localiser starts over.
//!
//! A monocular relative stage has a scale of its own: arbitrary without
//! the IMU, and with it a few per cent off the map's and moving (a map
//! made in another session has its own error). There the transform is a
//! similarity (`fit_scale`): relative-world lengths times `s`, then the
//! rotation and the shift; increments and landmark offsets are scaled by
//! `s` before they reach the filter and the recognition, and every refit
//! updates `s` with the rotation. A rigid transform would leave the scale
//! difference to the corrections: a track that is pulled back a few
//! centimetres every frame and jumps at each refit.
//!
//! The transform's heading is corrected frame by frame
//! (`orientation_sigma_rad_per_sqrt_s`): the recognised landmarks'
//! directions from one another measure it with the robot's position
//! marginalised out ([`super::orientation_filter`], as the absolute stage
//! corrects its own), starting from a fit's uncertainty, and the gate
//! allows each landmark that uncertainty across its ray. A fit takes the
//! heading from the landmarks' 3D positions, whose depths a monocular
//! window knows far less well than their directions (a moving scale error
//! of a few per cent): in a mono-inertial map the fitted heading was 1-3
//! deg off, 5-15 cm across a landmark 3 m away, and the gate then refused
//! nearly every recognition. With the heading corrected, the refits give
//! the scale and the shift only.

use std::collections::HashMap;

use nalgebra::{DMatrix, Isometry3, Matrix3, Rotation3, Translation3, UnitQuaternion, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::map_file::SavedMap;
use super::mapping_attitude::AttitudeMoments;
use super::orientation_filter::{OrientationFilter, OrientationUpdate};
use super::position_filter::{LandmarkFix, PositionFilter};
use super::recognition::{
    consistent_recognitions, recognise_tracks, ConsensusGate, FramePlacement, LandmarkIndex,
    RecognitionConfig,
};
use super::window_share::WindowShares;
use crate::eval::align::umeyama;
use crate::features::matching::hamming;
use crate::features::orb::Descriptor;
use crate::relative::types::{LandmarkId, RelativeOutput, TrackingState, WindowSupport};

/// Settings of [`MapLocaliser`].
#[derive(Clone, Debug, PartialEq)]
pub struct LocaliseConfig {
    /// Gates for recognising new tracks once localised.
    pub recognition: RecognitionConfig,
    /// Relocalisation: largest descriptor distance of a match, bits.
    pub match_max_hamming: u32,
    /// Relocalisation: this many nearest map landmarks by descriptor are
    /// candidates for each landmark of the frame.
    pub candidates_per_landmark: usize,
    /// Relocalisation: a match is an inlier of a transform within this
    /// distance, m.
    pub inlier_m: f64,
    /// Relocalisation: at least this many inliers to accept a transform.
    pub min_inliers: usize,
    /// Relocalisation: RANSAC iterations per attempt.
    pub ransac_iterations: usize,
    /// Relocalisation: when both the map and the relative stage's world
    /// have gravity along -z (inertial modes), the transform between them
    /// can only turn about z; a hypothesis tilting z by more than this is
    /// rejected. None: any rotation (vision-only modes).
    pub max_tilt_rad: Option<f64>,
    /// Fit a scale between the relative stage's world and the map as
    /// well (monocular modes); false: rigid.
    pub fit_scale: bool,
    /// With `fit_scale`: a fit whose scale is further than this factor
    /// from 1 either way is rejected (inertial modes, whose scale is
    /// metric to a few per cent). None: any scale (vision-only mono).
    pub max_scale_ratio: Option<f64>,
    /// Increment noise of the filter's prediction, m per sqrt(m).
    pub translation_sigma_per_sqrt_m: f64,
    /// At most this many landmarks (the most precise) per correction.
    pub max_correction_landmarks: usize,
    /// Multiplies the relative stage's landmark covariances, as the
    /// absolute stage's setting of the same name.
    pub landmark_covariance_scale: f64,
    /// A landmark whose innovation exceeds this chi-square (3 dof) is left
    /// out of the correction and its association dropped.
    pub gate_chi2: f64,
    /// The relative-world -> map transform is refitted this often (frames)
    /// to the landmarks recognised over the last `refit_pairs`: one
    /// frame's fit leaves the rotation off by about a degree, which
    /// every offset to a landmark then carries. With the heading corrected
    /// (`orientation_sigma_rad_per_sqrt_s`), a refit keeps the rotation and
    /// changes the scale and the shift.
    pub refit_every_frames: usize,
    /// Recognised landmark pairs (relative world, map) the refit uses, newest first.
    pub refit_pairs: usize,
    /// The localisation is dropped (and the robot relocalised from
    /// scratch, its pose carried on in the map by the relative stage's
    /// motion meanwhile) after this many frames in a row whose recognised
    /// landmarks all failed the innovation gate: the map and the track
    /// disagree everywhere, which a right transform does not do for long
    /// (a turn without map landmarks in view tests nothing and does not
    /// count). A relocalisation from a few poorly placed landmarks can be
    /// wrong.
    pub drop_after_rejected_frames: usize,
    /// Once localised, the frame's landmarks are matched to the map by
    /// descriptor alone again this often (frames; 0: never), as a second
    /// opinion on the transform in use: when a fresh fit explains at
    /// least `second_opinion_ratio` times as many matches as the transform
    /// in use does on the same matches, it replaces it. The innovation gate
    /// cannot see a wrong transform that the recognitions follow: a track
    /// placed wrongly is recognised against the map landmarks near where it
    /// was put, and those agree with it.
    pub second_opinion_every_frames: usize,
    /// See `second_opinion_every_frames`.
    pub second_opinion_ratio: f64,
    /// A relocalisation is taken only when a fit from a frame at least
    /// this many frames later agrees with it (see [`fits_agree`]); 0: the
    /// first fit is taken (stereo modes, whose landmarks each frame
    /// places). A wrong fit from a few poorly placed landmarks holds for
    /// the frames that see the same landmarks, not for later ones.
    pub confirm_after_frames: usize,
    /// The heading of the transform in use is corrected frame by frame
    /// by the recognised landmarks' directions from one another, as the
    /// absolute stage corrects its orientation offset
    /// ([`super::orientation_filter`]), wandering by this much (rad per
    /// sqrt(s)); the refits then change the scale and the shift only. 0:
    /// the heading is the last fit's.
    pub orientation_sigma_rad_per_sqrt_s: f64,
    /// Sigma of a fit's rotation, per axis, rad: where the heading's
    /// correction starts after a relocalisation.
    pub fit_rotation_sigma_rad: f64,
    /// Seed of the RANSAC sampler; the same seed and input give the same result.
    pub seed: u64,
}

impl Default for LocaliseConfig {
    fn default() -> Self {
        Self {
            recognition: RecognitionConfig::default(),
            match_max_hamming: 50,
            candidates_per_landmark: 3,
            inlier_m: 0.3,
            min_inliers: 8,
            max_tilt_rad: None,
            fit_scale: false,
            max_scale_ratio: None,
            ransac_iterations: 1000,
            translation_sigma_per_sqrt_m: 0.02,
            max_correction_landmarks: 30,
            landmark_covariance_scale: 1.0,
            gate_chi2: 16.27,
            refit_every_frames: 10,
            refit_pairs: 600,
            drop_after_rejected_frames: 20,
            second_opinion_every_frames: 10,
            second_opinion_ratio: 2.0,
            confirm_after_frames: 0,
            orientation_sigma_rad_per_sqrt_s:
                super::config::DEFAULT_ORIENTATION_SIGMA_RAD_PER_SQRT_S,
            fit_rotation_sigma_rad: 1f64.to_radians(),
            seed: 0,
        }
    }
}

/// What the localiser did so far.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize)]
pub struct LocaliseStats {
    /// Frames pushed.
    pub frames: usize,
    /// Frames with a pose in the map.
    pub localised_frames: usize,
    /// Relocalisation attempts (frames matched by descriptor alone).
    pub attempts: usize,
    /// Times a transform to the map was accepted.
    pub relocalisations: usize,
    /// Times the relative stage lost tracking and localisation restarted.
    pub resets: usize,
    /// Tracks recognised as map landmarks.
    pub recognised: usize,
    /// Recognitions that placed the robot elsewhere than the frame's
    /// associated landmarks do (see [`consistent_recognitions`]).
    pub inconsistent_recognitions: usize,
    /// Frames the position filter corrected with map landmarks.
    pub corrections: usize,
    /// Landmarks left out of a correction by the innovation gate.
    pub gated_out: usize,
    /// Refits of the relative-world -> map transform.
    pub refits: usize,
    /// Localisations dropped because every recognised landmark failed the
    /// gate for `drop_after_rejected_frames` frames in a row.
    pub dropped: usize,
    /// Frames placed by the relative stage's motion alone after a drop,
    /// while relocalising (counted in `localised_frames` too).
    pub held_frames: usize,
    /// Fits a later frame's fit did not confirm (see
    /// `LocaliseConfig::confirm_after_frames`).
    pub unconfirmed: usize,
    /// Transforms replaced by a second opinion that explained more
    /// descriptor matches (see `LocaliseConfig::second_opinion_every_frames`).
    pub replaced: usize,
    /// Map lengths per relative-world length in the transform in use (1
    /// when rigid).
    pub scale: f64,
    /// Frames whose landmarks corrected the transform's heading.
    pub orientation_corrections: usize,
    /// Heading corrections refused as too large for one frame
    /// ([`super::orientation_filter::MAX_ORIENTATION_STEP_RAD`]).
    pub orientation_refused: usize,
}

/// The pose of one frame in the map frame, once localised.
#[allow(non_snake_case)]
#[derive(Clone, Debug, PartialEq)]
pub struct LocalisedPose {
    /// Frame stamp, ns.
    pub t_ns: i64,
    /// Body (IMU) pose in the map frame: maps body coordinates into the map frame.
    pub T_map_body: Isometry3<f64>,
    /// Covariance of the body position in the map frame, m^2: the
    /// filter's (how well the robot is placed among the landmarks it
    /// re-uses every frame) plus the map's own error at those landmarks
    /// (see `Localised::map_error_m2`).
    pub position_covariance_m2: Matrix3<f64>,
    /// Map landmarks used by this frame's correction.
    pub landmarks_used: usize,
    /// Placed by the relative stage's motion alone, the localisation
    /// having been dropped and not yet found again.
    pub carried: bool,
}

/// A transform relative-world -> map and the inliers it was fitted to.
#[allow(non_snake_case)]
#[derive(Clone, Debug)]
struct Fit {
    T_map_world: Isometry3<f64>,
    /// Map lengths per relative-world length: `map = T (s world)`.
    scale: f64,
    /// (track id, map index) of the inliers.
    inliers: Vec<(LandmarkId, u32)>,
    rms_m: f64,
}

#[allow(non_snake_case)]
struct Localised {
    T_map_world: Isometry3<f64>,
    /// Map lengths per relative-world length (see [`Fit::scale`]).
    scale: f64,
    filter: PositionFilter,
    /// Per map landmark: how much of its window estimate is new since its
    /// last correction (the published covariance counts repeated
    /// estimates).
    shares: WindowShares,
    /// (landmark in the relative world, in the map) of recent corrections.
    pairs: std::collections::VecDeque<(Vector3<f64>, Vector3<f64>)>,
    frames_since_refit: usize,
    /// Frames in a row whose tested landmarks all failed the gate.
    rejected_frames: usize,
    /// Frames since the last second opinion.
    frames_since_second_opinion: usize,
    /// The heading of the transform, corrected by the landmarks' directions.
    orientation: Option<OrientationFilter>,
    /// The localisation was dropped: the pose carries on in the map by
    /// the relative stage's motion alone (no recognition, correction or
    /// refit) until a new fit is confirmed, so the map-frame pose does
    /// not fall back to the relative stage's frame and jump.
    held: bool,
    /// The map's own error where the robot is: the mean saved covariance
    /// of the landmarks of the last correction (or of the fit). The filter
    /// corrects with the same landmarks frame after frame as if their
    /// errors were new each time, so its covariance says how well the
    /// robot is placed among them, not where they are; and neighbouring
    /// landmarks of a map err together (its drift), so their mean
    /// covariance, not its share among them, is added to what is
    /// published. Measured on the lap rooms: map-frame NEES per dof
    /// 100-2 700 without it, median 0.5-1.4 with it (inertial modes).
    map_error_m2: Matrix3<f64>,
}

/// Localises the relative stage's output in a saved map.
pub struct MapLocaliser {
    config: LocaliseConfig,
    positions_m: Vec<Vector3<f64>>,
    covariances_m2: Vec<Matrix3<f64>>,
    /// Per landmark, what the mapping run's attitude error put in it
    /// ([`super::mapping_attitude`]), when the map says.
    attitudes: Vec<Option<AttitudeMoments>>,
    descriptors: Vec<Option<Descriptor>>,
    index: LandmarkIndex,
    state: Option<Localised>,
    /// Track id -> map index, for the tracks recognised as map landmarks.
    associations: HashMap<LandmarkId, u32>,
    stats: LocaliseStats,
    /// A relocalisation waiting for a later frame's fit to confirm it,
    /// and the frames since it was made.
    candidate: Option<(Fit, usize)>,
    rng: ChaCha8Rng,
    candidates: Vec<u32>,
}

/// Grid cell of the map's landmark index, m.
const INDEX_CELL_M: f64 = 1.0;

impl MapLocaliser {
    /// A localiser in `map`, not localised yet.
    pub fn new(map: &SavedMap, config: LocaliseConfig) -> Self {
        let positions_m: Vec<Vector3<f64>> = map.landmarks.iter().map(|l| l.position_m).collect();
        let index =
            LandmarkIndex::build(positions_m.iter().map(|p| Some(*p)).collect(), INDEX_CELL_M);
        Self {
            rng: ChaCha8Rng::seed_from_u64(config.seed),
            config,
            covariances_m2: map.landmarks.iter().map(|l| l.covariance_m2).collect(),
            attitudes: map.landmarks.iter().map(|l| l.attitude).collect(),
            descriptors: map.landmarks.iter().map(|l| l.descriptor).collect(),
            positions_m,
            index,
            state: None,
            associations: HashMap::new(),
            stats: LocaliseStats {
                scale: 1.0,
                ..LocaliseStats::default()
            },
            candidates: Vec::new(),
            candidate: None,
        }
    }

    /// The map's own error at a robot at `robot_m` (map frame) placed
    /// against `landmarks`: the mean over them of the saved covariance
    /// and what the mapping run's attitude error put there
    /// ([`super::mapping_attitude`]: the heading error turned the map
    /// about where the mapping robot was when it grew).
    fn map_error_m2(
        &self,
        landmarks: impl Iterator<Item = u32>,
        robot_m: &Vector3<f64>,
    ) -> Matrix3<f64> {
        Self::map_error_at(
            &self.covariances_m2,
            &self.attitudes,
            &self.positions_m,
            landmarks,
            robot_m,
        )
    }

    /// [`Self::map_error_m2`] on the map's parts (borrowed apart from
    /// the state being corrected).
    fn map_error_at(
        covariances_m2: &[Matrix3<f64>],
        attitudes: &[Option<AttitudeMoments>],
        positions_m: &[Vector3<f64>],
        landmarks: impl Iterator<Item = u32>,
        robot_m: &Vector3<f64>,
    ) -> Matrix3<f64> {
        mean_of(landmarks.map(|m| {
            let m = m as usize;
            let attitude = attitudes[m].map_or_else(Matrix3::zeros, |a| {
                a.covariance_at(&(robot_m - positions_m[m]))
            });
            covariances_m2[m] + attitude
        }))
    }

    /// Counters so far.
    pub fn stats(&self) -> &LocaliseStats {
        &self.stats
    }

    /// The relative-world -> map transform in use, once localised.
    #[allow(non_snake_case)]
    pub fn T_map_world(&self) -> Option<Isometry3<f64>> {
        self.state.as_ref().map(|s| s.T_map_world)
    }

    /// The pose in the map of a frame the localiser has not taken yet
    /// (see [`crate::slam_pipeline::SlamPipeline::push_frame`]): its last
    /// position moved by the frame's relative motion, as `push` would
    /// before any correction; None when not localised. The localiser
    /// itself is unchanged.
    pub fn carry(&self, output: &RelativeOutput) -> Option<LocalisedPose> {
        let state = self.state.as_ref()?;
        if output.state != TrackingState::Tracking || !pose_is_finite(output) {
            return None;
        }
        let delta = state.T_map_world.rotation * (state.scale * output.delta_translation_world_m);
        let delta = if delta.iter().all(|v| v.is_finite()) {
            delta
        } else {
            Vector3::zeros()
        };
        let q =
            Matrix3::identity() * self.config.translation_sigma_per_sqrt_m.powi(2) * delta.norm();
        Some(LocalisedPose {
            t_ns: output.t_ns,
            T_map_body: Isometry3::from_parts(
                Translation3::from(state.filter.position_world_m() + delta),
                state.T_map_world.rotation * output.T_world_body.rotation,
            ),
            position_covariance_m2: state.filter.published_covariance_m2() + q + state.map_error_m2,
            landmarks_used: 0,
            carried: state.held,
        })
    }

    /// Processes one frame; the pose in the map once localised.
    pub fn push(&mut self, output: &RelativeOutput) -> Option<LocalisedPose> {
        self.stats.frames += 1;
        if output.state != TrackingState::Tracking || !pose_is_finite(output) {
            if self.state.take().is_some() {
                self.stats.resets += 1;
            }
            self.candidate = None;
            self.associations.clear();
            return None;
        }
        let used;
        match self.state.as_mut() {
            Some(state) => {
                if let Some(o) = state.orientation.as_mut() {
                    o.predict(output.t_ns);
                }
                let delta =
                    state.T_map_world.rotation * (state.scale * output.delta_translation_world_m);
                if delta.iter().all(|v| v.is_finite()) {
                    let q = Matrix3::identity()
                        * self.config.translation_sigma_per_sqrt_m.powi(2)
                        * delta.norm();
                    state.filter.predict(&delta, &q);
                }
                if state.held {
                    self.stats.attempts += 1;
                    match self.confirmed(output) {
                        Some(fit) => {
                            self.localise_at(output, fit);
                            used = self.correct(output);
                        }
                        None => {
                            self.stats.held_frames += 1;
                            used = 0;
                        }
                    }
                } else if let Some(fit) = self.second_opinion(output) {
                    self.stats.replaced += 1;
                    self.localise_at(output, fit);
                    used = self.correct(output);
                } else {
                    self.recognise_new(output);
                    used = self.correct(output);
                    self.drop_if_rejected();
                    self.refit();
                }
            }
            None => {
                self.stats.attempts += 1;
                let fit = self.confirmed(output)?;
                self.localise_at(output, fit);
                used = self.correct(output);
            }
        }
        let state = self.state.as_ref()?;
        self.stats.localised_frames += 1;
        let rotation = state.T_map_world.rotation * output.T_world_body.rotation;
        Some(LocalisedPose {
            t_ns: output.t_ns,
            T_map_body: Isometry3::from_parts(
                Translation3::from(state.filter.position_world_m()),
                rotation,
            ),
            position_covariance_m2: state.filter.published_covariance_m2() + state.map_error_m2,
            landmarks_used: used,
            carried: state.held,
        })
    }

    /// This frame's fit when it confirms the candidate made at least
    /// `confirm_after_frames` earlier; otherwise None, this frame's fit
    /// (if any) becoming the candidate when there is none or it could not
    /// be confirmed in time.
    fn confirmed(&mut self, output: &RelativeOutput) -> Option<Fit> {
        let wait = self.config.confirm_after_frames;
        if let Some((_, age)) = self.candidate.as_mut() {
            *age += 1;
        }
        let (fit, _) = self.relocalise(output, None)?;
        if wait == 0 {
            return Some(fit);
        }
        let body = output.T_world_body.translation.vector;
        match self.candidate.take() {
            Some((candidate, age)) if age >= wait && fits_agree(&candidate, &fit, &body) => {
                Some(fit)
            }
            // Too young to confirm: kept, unless much weaker than this one.
            Some((candidate, age)) if age < wait => {
                self.candidate = Some(if fit.inliers.len() > 2 * candidate.inliers.len() {
                    (fit, 0)
                } else {
                    (candidate, age)
                });
                None
            }
            Some((candidate, _)) => {
                tracing::debug!(
                    "a relocalisation ({} inliers, scale {:.4}) not confirmed at {:.2} s",
                    candidate.inliers.len(),
                    candidate.scale,
                    output.t_ns as f64 * 1e-9
                );
                self.stats.unconfirmed += 1;
                self.candidate = Some((fit, 0));
                None
            }
            None => {
                self.candidate = Some((fit, 0));
                None
            }
        }
    }

    /// Takes `fit` as the transform to the map from this frame on, the
    /// filter starting where it places the body.
    fn localise_at(&mut self, output: &RelativeOutput, fit: Fit) {
        let position = (fit.T_map_world
            * nalgebra::Point3::from(fit.scale * output.T_world_body.translation.vector))
        .coords;
        let z = fit.T_map_world.rotation * Vector3::z();
        tracing::info!(
            "relocalised in the map at {:.2} s: {} inliers, rms {:.3} m, transform turns {:.1} deg, tilts z by {:.2} deg, scale {:.4}",
            output.t_ns as f64 * 1e-9,
            fit.inliers.len(),
            fit.rms_m,
            fit.T_map_world.rotation.angle().to_degrees(),
            z.z.clamp(-1.0, 1.0).acos().to_degrees(),
            fit.scale
        );
        self.stats.scale = fit.scale;
        let variance = fit.rms_m.powi(2).max(1e-4) / fit.inliers.len() as f64 * 10.0;
        self.associations = fit.inliers.iter().copied().collect();
        self.state = Some(Localised {
            T_map_world: fit.T_map_world,
            scale: fit.scale,
            filter: PositionFilter::new(position, Matrix3::identity() * variance),
            shares: WindowShares::default(),
            pairs: Default::default(),
            frames_since_refit: 0,
            rejected_frames: 0,
            frames_since_second_opinion: 0,
            orientation: (self.config.orientation_sigma_rad_per_sqrt_s > 0.0).then(|| {
                OrientationFilter::starting_at(
                    self.config.orientation_sigma_rad_per_sqrt_s,
                    Matrix3::identity() * self.config.fit_rotation_sigma_rad.powi(2),
                )
            }),
            held: false,
            map_error_m2: self.map_error_m2(fit.inliers.iter().map(|&(_, m)| m), &position),
        });
        self.stats.relocalisations += 1;
    }

    /// Every `second_opinion_every_frames` while localised: a fit from
    /// descriptor matches alone, returned when it explains at least
    /// `second_opinion_ratio` times as many of them as the transform in
    /// use.
    fn second_opinion(&mut self, output: &RelativeOutput) -> Option<Fit> {
        let every = self.config.second_opinion_every_frames;
        let state = self.state.as_mut()?;
        state.frames_since_second_opinion += 1;
        if every == 0 || state.frames_since_second_opinion < every {
            return None;
        }
        state.frames_since_second_opinion = 0;
        let in_use = (state.T_map_world, state.scale);
        let (fit, explained) = self.relocalise(output, Some(in_use))?;
        tracing::debug!(
            "second opinion at {:.2} s: in use explains {explained}, fresh fit {} (rms {:.3} m, scale {:.4})",
            output.t_ns as f64 * 1e-9,
            fit.inliers.len(),
            fit.rms_m,
            fit.scale
        );
        if (fit.inliers.len() as f64) < self.config.second_opinion_ratio * explained as f64 {
            return None;
        }
        tracing::warn!(
            "the transform to the map in use explains {explained} of this frame's descriptor matches, a fresh fit {}: replaced",
            fit.inliers.len()
        );
        Some(fit)
    }

    /// Descriptor matches of the frame's landmarks to the whole map, then
    /// RANSAC over three-point rigid fits; with `in_use`, also how many of
    /// the matches that transform (and scale) explains.
    fn relocalise(
        &mut self,
        output: &RelativeOutput,
        in_use: Option<(Isometry3<f64>, f64)>,
    ) -> Option<(Fit, usize)> {
        // Per landmark of the frame: where it is in the relative world and
        // its nearest map landmarks by descriptor. No ratio test: a map
        // holds repeated textures and the same corner more than once, so
        // the right match is often not alone; RANSAC chooses.
        let mut queries: Vec<(LandmarkId, Vector3<f64>, Vec<u32>)> = Vec::new();
        let mut ranked: Vec<(u32, u32)> = Vec::with_capacity(self.descriptors.len());
        for l in &output.landmarks {
            let Some(d) = l.descriptor else { continue };
            let q = (output.T_world_body * nalgebra::Point3::from(l.position_body_m)).coords;
            if !q.iter().all(|v| v.is_finite()) {
                continue;
            }
            ranked.clear();
            ranked.extend(self.descriptors.iter().enumerate().filter_map(|(k, m)| {
                let h = hamming(&d, m.as_ref()?);
                (h <= self.config.match_max_hamming).then_some((h, k as u32))
            }));
            let keep = self.config.candidates_per_landmark.min(ranked.len());
            if keep == 0 {
                continue;
            }
            ranked.select_nth_unstable(keep - 1);
            ranked.truncate(keep);
            ranked.sort_unstable();
            queries.push((l.id, q, ranked.iter().map(|r| r.1).collect()));
        }
        if queries.len() < self.config.min_inliers.max(3) {
            return None;
        }
        let positions = &self.positions_m;
        let inlier_m = self.config.inlier_m;
        let max_tilt_rad = self.config.max_tilt_rad;
        let with_scale = self.config.fit_scale;
        let max_scale_ratio = self.config.max_scale_ratio;
        let acceptable = |(t, scale): &(Isometry3<f64>, f64)| {
            let z = t.rotation * Vector3::z();
            max_tilt_rad.map_or(true, |max| z.z.clamp(-1.0, 1.0).acos() <= max)
                && scale_within(max_scale_ratio, *scale)
        };
        // (query, map landmark) of the queries a transform places within
        // inlier_m of one of their candidates (the nearest).
        let inliers_of = |(t, scale): &(Isometry3<f64>, f64)| -> Vec<(usize, u32)> {
            queries
                .iter()
                .enumerate()
                .filter_map(|(k, (_, q, candidates))| {
                    let moved = (t * nalgebra::Point3::from(*scale * q)).coords;
                    candidates
                        .iter()
                        .map(|&m| ((moved - positions[m as usize]).norm(), m))
                        .filter(|(d, _)| *d <= inlier_m)
                        .min_by(|a, b| a.0.total_cmp(&b.0))
                        .map(|(_, m)| (k, m))
                })
                .collect()
        };
        let mut best: Vec<(usize, u32)> = Vec::new();
        let n = queries.len();
        for _ in 0..self.config.ransac_iterations {
            let picks = [0; 3].map(|_| {
                let k = self.rng.gen_range(0..n);
                let c = self.rng.gen_range(0..queries[k].2.len());
                (k, queries[k].2[c])
            });
            let [a, b, c] = picks;
            if a.0 == b.0 || b.0 == c.0 || a.0 == c.0 {
                continue;
            }
            let world = picks.map(|(k, _)| queries[k].1);
            let map = picks.map(|(_, m)| self.positions_m[m as usize]);
            // A rigid motion keeps distances, a similarity their ratios:
            // most wrong samples stop here.
            let (dw, dm) = (
                [0, 1, 2].map(|i| (world[i] - world[(i + 1) % 3]).norm()),
                [0, 1, 2].map(|i| (map[i] - map[(i + 1) % 3]).norm()),
            );
            let consistent = if with_scale {
                let s = dm[0] / dw[0].max(1e-12);
                (1..3).all(|i| (dm[i] - s * dw[i]).abs() <= 2.0 * inlier_m)
            } else {
                (0..3).all(|i| (dw[i] - dm[i]).abs() <= 2.0 * inlier_m)
            };
            if !consistent {
                continue;
            }
            // A degenerate (nearly collinear) sample fixes no rotation.
            if (world[1] - world[0]).cross(&(world[2] - world[0])).norm() < 1e-3 {
                continue;
            }
            let Some(t) = transform_fit(&world, &map, with_scale) else {
                continue;
            };
            if !acceptable(&t) {
                continue;
            }
            let inliers = inliers_of(&t);
            if inliers.len() > best.len() {
                best = inliers;
            }
        }
        if best.len() < self.config.min_inliers {
            return None;
        }
        // One map landmark per track and one track per map landmark.
        let distinct = |set: Vec<(usize, u32)>| -> Vec<(usize, u32)> {
            let mut taken = std::collections::HashSet::new();
            set.into_iter().filter(|&(_, m)| taken.insert(m)).collect()
        };
        let explained = in_use.map_or(0, |t| distinct(inliers_of(&t)).len());
        let fit = |set: &[(usize, u32)]| {
            let world: Vec<Vector3<f64>> = set.iter().map(|&(k, _)| queries[k].1).collect();
            let map: Vec<Vector3<f64>> = set.iter().map(|&(_, m)| positions[m as usize]).collect();
            transform_fit(&world, &map, with_scale)
        };
        let t = fit(&best)?;
        let refined = inliers_of(&t);
        if refined.len() < self.config.min_inliers {
            return None;
        }
        let t = fit(&refined)?;
        if !acceptable(&t) {
            return None;
        }
        let rms_m = (refined
            .iter()
            .map(|&(k, m)| {
                ((t.0 * nalgebra::Point3::from(t.1 * queries[k].1)).coords - positions[m as usize])
                    .norm_squared()
            })
            .sum::<f64>()
            / refined.len() as f64)
            .sqrt();
        let inliers: Vec<(LandmarkId, u32)> = distinct(refined)
            .into_iter()
            .map(|(k, m)| (queries[k].0, m))
            .collect();
        if inliers.len() < self.config.min_inliers {
            return None;
        }
        Some((
            Fit {
                T_map_world: t.0,
                scale: t.1,
                inliers,
                rms_m,
            },
            explained,
        ))
    }

    fn recognise_new(&mut self, output: &RelativeOutput) {
        let Some(state) = self.state.as_ref() else {
            return;
        };
        // Scaled: body offsets reach the map in its lengths.
        let rotation = *(state.T_map_world.rotation * output.T_world_body.rotation)
            .to_rotation_matrix()
            .matrix()
            * state.scale;
        let placement = FramePlacement {
            rotation,
            position_m: state.filter.position_world_m(),
            position_covariance_m2: state.filter.covariance_m2(),
            landmark_covariance_scale: self.config.landmark_covariance_scale,
        };
        let found = recognise_tracks(
            &self.index,
            &self.descriptors,
            &output.landmarks,
            &placement,
            |track| self.associations.get(&track).copied(),
            &self.config.recognition,
            &mut self.candidates,
        );
        let (found, inconsistent) = consistent_recognitions(
            &self.index,
            &output.landmarks,
            &rotation,
            |track| self.associations.get(&track).copied(),
            found,
            &self.config.recognition,
            self.config.landmark_covariance_scale,
            ConsensusGate::LargestSigma,
        );
        self.stats.inconsistent_recognitions += inconsistent;
        self.stats.recognised += found.len();
        self.associations.extend(found);
        // Tracks that ended are forgotten.
        if self.associations.len() > 4 * output.landmarks.len().max(64) {
            let live: std::collections::HashSet<LandmarkId> =
                output.landmarks.iter().map(|l| l.id).collect();
            self.associations.retain(|id, _| live.contains(id));
        }
    }

    /// Drops the localisation when the map and the track have disagreed
    /// for `drop_after_rejected_frames` frames in a row.
    fn drop_if_rejected(&mut self) {
        let limit = self.config.drop_after_rejected_frames;
        if limit == 0
            || self
                .state
                .as_ref()
                .map_or(true, |s| s.held || s.rejected_frames < limit)
        {
            return;
        }
        tracing::warn!(
            "localisation dropped: every recognised map landmark failed the gate for {limit} frames; relocalising, the pose carried on by the odometry meanwhile"
        );
        if let Some(state) = self.state.as_mut() {
            state.held = true;
        }
        self.candidate = None;
        self.associations.clear();
        self.stats.dropped += 1;
    }

    /// Refits the relative-world -> map transform to the recent pairs
    /// (only its scale and shift when the heading is corrected).
    fn refit(&mut self) {
        let Some(state) = self.state.as_mut().filter(|s| !s.held) else {
            return;
        };
        state.frames_since_refit += 1;
        if state.frames_since_refit < self.config.refit_every_frames
            || state.pairs.len() < 3 * self.config.min_inliers
        {
            return;
        }
        state.frames_since_refit = 0;
        let (world, map): (Vec<Vector3<f64>>, Vec<Vector3<f64>>) =
            state.pairs.iter().copied().unzip();
        let fitted = transform_fit(&world, &map, self.config.fit_scale);
        if let Some((t, scale)) = fitted.filter(|f| scale_within(self.config.max_scale_ratio, f.1))
        {
            // The heading corrected frame by frame is kept; the shift
            // follows the pairs' centroids with it.
            let t = if state.orientation.is_some() {
                let n = world.len() as f64;
                let cw = world.iter().sum::<Vector3<f64>>() / n;
                let cm = map.iter().sum::<Vector3<f64>>() / n;
                let r = state.T_map_world.rotation;
                Isometry3::from_parts(Translation3::from(cm - r * (scale * cw)), r)
            } else {
                t
            };
            state.T_map_world = t;
            state.scale = scale;
            self.stats.scale = scale;
            self.stats.refits += 1;
        }
    }

    /// The correction with the recognised landmarks in view: their saved
    /// covariances (block diagonal; the saved map keeps no cross terms).
    fn correct(&mut self, output: &RelativeOutput) -> usize {
        let Some(state) = self.state.as_mut() else {
            return 0;
        };
        // Scaled: body offsets reach the map in its lengths.
        let rotation = *(state.T_map_world.rotation * output.T_world_body.rotation)
            .to_rotation_matrix()
            .matrix()
            * state.scale;
        let p = state.filter.covariance_m2();
        let x = state.filter.position_world_m();
        let mut fixes: Vec<(f64, LandmarkFix, Vector3<f64>, Option<WindowSupport>)> = Vec::new();
        let mut rejected = Vec::new();
        for l in &output.landmarks {
            let Some(&map) = self.associations.get(&l.id) else {
                continue;
            };
            let landmark = self.positions_m[map as usize];
            let offset = rotation * l.position_body_m;
            let offset_covariance = rotation
                * (l.covariance_body_m2 * self.config.landmark_covariance_scale)
                * rotation.transpose();
            let mut s = p + offset_covariance + self.covariances_m2[map as usize];
            // A heading known to P turns the offset across itself.
            if let Some(o) = state.orientation.as_ref() {
                let j = -offset.cross_matrix();
                s += j * o.covariance_rad2() * j.transpose();
            }
            let r = landmark - offset - x;
            let chi2 = s.cholesky().map(|c| r.dot(&c.solve(&r)));
            match chi2 {
                Some(chi2) if chi2 <= self.config.gate_chi2 => fixes.push((
                    offset_covariance.trace(),
                    LandmarkFix {
                        landmark: map,
                        landmark_world_m: landmark,
                        offset_world_m: offset,
                        offset_covariance_m2: offset_covariance,
                        offset_new_share: state.shares.share(map, l.support),
                    },
                    (output.T_world_body * nalgebra::Point3::from(l.position_body_m)).coords,
                    l.support,
                )),
                _ => rejected.push(l.id),
            }
        }
        self.stats.gated_out += rejected.len();
        if fixes.is_empty() && !rejected.is_empty() {
            state.rejected_frames += 1;
        } else if !fixes.is_empty() {
            state.rejected_frames = 0;
        }
        for id in rejected {
            self.associations.remove(&id);
        }
        fixes.sort_by(|a, b| a.0.total_cmp(&b.0));
        fixes.truncate(self.config.max_correction_landmarks);
        if fixes.is_empty() {
            return 0;
        }
        for f in &fixes {
            state.pairs.push_back((f.2, f.1.landmark_world_m));
        }
        let supports: Vec<Option<WindowSupport>> = fixes.iter().map(|f| f.3).collect();
        let mut fixes: Vec<LandmarkFix> = fixes.into_iter().map(|f| f.1).collect();
        while state.pairs.len() > self.config.refit_pairs {
            state.pairs.pop_front();
        }
        let mut covariance = DMatrix::zeros(3 * fixes.len(), 3 * fixes.len());
        for (k, f) in fixes.iter().enumerate() {
            covariance
                .fixed_view_mut::<3, 3>(3 * k, 3 * k)
                .copy_from(&self.covariances_m2[f.landmark as usize]);
        }
        if let Some(o) = state.orientation.as_mut() {
            let update = o.correct_with(&mut fixes, &covariance, &x);
            if let OrientationUpdate::TooLarge(_) = update {
                self.stats.orientation_refused += 1;
            }
            if let OrientationUpdate::Applied(step) = update {
                self.stats.orientation_corrections += 1;
                let turn = UnitQuaternion::from_scaled_axis(step);
                // Turned about the body, whose place in the map stays.
                let body = state.scale * output.T_world_body.translation.vector;
                let placed = state.T_map_world * nalgebra::Point3::from(body);
                let rotation = turn * state.T_map_world.rotation;
                state.T_map_world = Isometry3::from_parts(
                    Translation3::from(placed.coords - rotation * body),
                    rotation,
                );
            }
        }
        state.map_error_m2 = Self::map_error_at(
            &self.covariances_m2,
            &self.attitudes,
            &self.positions_m,
            fixes.iter().map(|f| f.landmark),
            &x,
        );
        match state.filter.correct(&fixes, &covariance, None) {
            Ok(report) => {
                for (fix, &support) in fixes.iter().zip(&supports) {
                    state.shares.note_used(fix.landmark, support);
                }
                self.stats.corrections += 1;
                report.landmarks
            }
            Err(e) => {
                tracing::warn!("localisation correction skipped: {e}");
                0
            }
        }
    }
}

/// The mean of `covariances` (zero when there are none).
fn mean_of(covariances: impl Iterator<Item = Matrix3<f64>>) -> Matrix3<f64> {
    let (sum, n) = covariances.fold((Matrix3::zeros(), 0usize), |(s, n), c| (s + c, n + 1));
    if n == 0 {
        sum
    } else {
        sum / n as f64
    }
}

fn pose_is_finite(output: &RelativeOutput) -> bool {
    output
        .T_world_body
        .translation
        .vector
        .iter()
        .chain(output.T_world_body.rotation.coords.iter())
        .all(|v| v.is_finite())
}

/// Two fits of the relative world to the map agree when they turn it
/// within [`AGREE_DEG`] of each other and place the body at `body`
/// (relative world) within [`AGREE_M`]. A right fit of one frame is off
/// by about a degree and a few centimetres (its landmarks' errors); chance
/// matches give fits tens of degrees and decimetres apart.
fn fits_agree(a: &Fit, b: &Fit, body: &Vector3<f64>) -> bool {
    let place = |f: &Fit| (f.T_map_world * nalgebra::Point3::from(f.scale * body)).coords;
    a.T_map_world.rotation.angle_to(&b.T_map_world.rotation) <= AGREE_DEG.to_radians()
        && (place(a) - place(b)).norm() <= AGREE_M
}

/// See [`fits_agree`].
const AGREE_DEG: f64 = 3.0;
/// See [`fits_agree`].
const AGREE_M: f64 = 0.15;

/// `max` None: any finite positive scale; else within a factor `max` of 1.
fn scale_within(max: Option<f64>, scale: f64) -> bool {
    scale.is_finite() && scale > 0.0 && max.map_or(true, |m| scale <= m && scale >= 1.0 / m)
}

/// [`similarity_fit`] with `with_scale`, else [`rigid_fit`] with scale 1.
fn transform_fit(
    a: &[Vector3<f64>],
    b: &[Vector3<f64>],
    with_scale: bool,
) -> Option<(Isometry3<f64>, f64)> {
    if with_scale {
        similarity_fit(a, b)
    } else {
        rigid_fit(a, b).map(|t| (t, 1.0))
    }
}

/// The rigid transform `T` minimising `Σ |T a_k - b_k|²` (Kabsch, by SVD
/// of the centred cross-covariance, reflection excluded).
pub fn rigid_fit(a: &[Vector3<f64>], b: &[Vector3<f64>]) -> Option<Isometry3<f64>> {
    if a.len() != b.len() || a.len() < 3 {
        return None;
    }
    let n = a.len() as f64;
    let ca = a.iter().sum::<Vector3<f64>>() / n;
    let cb = b.iter().sum::<Vector3<f64>>() / n;
    let mut h = Matrix3::zeros();
    for (p, q) in a.iter().zip(b) {
        h += (q - cb) * (p - ca).transpose();
    }
    let svd = h.svd(true, true);
    let (u, v_t) = (svd.u?, svd.v_t?);
    let d = (u * v_t).determinant().signum();
    let r = u * Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, d)) * v_t;
    let rotation = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(r));
    let t = cb - rotation * ca;
    t.iter()
        .all(|v| v.is_finite())
        .then(|| Isometry3::from_parts(Translation3::from(t), rotation))
}

/// The similarity `b = T (s a)` minimising `Σ |T (s a_k) - b_k|²`
/// ([`crate::eval::align::umeyama`] with the scale), as a rigid transform
/// and the scale. None for mismatched lists, fewer than three pairs or
/// points that fix no rotation (all one point, or on a line).
pub fn similarity_fit(a: &[Vector3<f64>], b: &[Vector3<f64>]) -> Option<(Isometry3<f64>, f64)> {
    if a.len() != b.len() {
        return None;
    }
    let fit = umeyama(a, b, true).ok()?;
    let rotation = UnitQuaternion::from_rotation_matrix(&fit.rotation);
    (fit.scale.is_finite() && fit.scale > 0.0 && fit.translation.iter().all(|v| v.is_finite()))
        .then(|| {
            (
                Isometry3::from_parts(Translation3::from(fit.translation), rotation),
                fit.scale,
            )
        })
}

#[cfg(test)]
mod tests;
