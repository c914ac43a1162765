//! The SLAM pipeline: both stages of the method as one object that IMU
//! samples and frames go into, in time order. The relative stage (the
//! windowed visual-inertial odometry, or the EKF baseline) gives each
//! frame's pose in its own world frame; on its output either the absolute
//! stage builds a map and corrects the position ([`AbsoluteStage`]), or a
//! localiser places the robot in a saved map ([`MapLocaliser`]), or
//! nothing does. `rigslam run` ([`crate::run`]) and the daemon's SLAM
//! thread ([`crate::daemon::slam_stage`]) both drive one of these, built
//! from the same [`SlamSettings`], so that the same input gives the same
//! poses in both.

use std::sync::Arc;
use std::time::Instant;

use crate::absolute::localise::{LocalisedPose, MapLocaliser};
use crate::absolute::map_file::SavedMap;
use crate::absolute::{AbsoluteStage, CorrectedPose};
use crate::relative::config::ConfigError;
use crate::relative::level::LevelFollower;
use crate::relative::{
    build_estimator, EstimatorKind, FrameInput, OdometryError, RelativeEstimator, RelativeOutput,
    RigModel, SensorMode, TrackingState,
};
use crate::sensors::ImuSample;
use crate::slam_config::SlamSettings;
use nalgebra::{Isometry3, Matrix3, Vector3};

mod map_world;
use map_world::{into_map_world, into_published_world, map_into_published_world};

/// Relocalising an inertial run in a map made by one: the transform
/// between their gravity-aligned worlds may tilt z by at most this. On
/// V1_02 the right fit of one frame tilted it by 5.4 deg (76 inliers); a
/// wrong fit in another room by 176 deg (7 inliers, upside down).
const RELOCALISE_MAX_TILT_DEG: f64 = 15.0;

/// Localising a mono-inertial run: the scale between its world and the
/// map may differ from 1 by at most this factor either way. Its scale is
/// metric to a few per cent (1-2 % off over the accuracy sets); a map
/// made by another mono-inertial session carries its own error of the
/// same size.
const RELOCALISE_MAX_SCALE_RATIO: f64 = 1.2;

/// Localising a monocular run: a relocalisation is taken when a fit this
/// many frames later (half a second at 20 Hz) agrees with it. Early in a
/// monocular run, and on tracks just begun, landmark depths are poor; a
/// fit to ten of them can be tens of degrees and decimetres off and is
/// consistent over the frames that see the same landmarks.
const RELOCALISE_CONFIRM_FRAMES: usize = 10;

/// What follows the relative stage.
#[derive(Debug, Clone, Default)]
pub enum SecondStage {
    /// Nothing: the relative stage's poses are the answer.
    #[default]
    None,
    /// The absolute stage builds a map and corrects the position.
    BuildMap,
    /// The robot is placed in this saved map.
    Localise(Arc<SavedMap>),
}

impl SecondStage {
    /// What `settings` ask for with no saved map: the absolute stage when
    /// `[absolute] enabled`, nothing otherwise.
    pub fn from_settings(settings: &SlamSettings) -> Self {
        if settings.absolute.enabled {
            SecondStage::BuildMap
        } else {
            SecondStage::None
        }
    }
}

/// Why a pipeline could not be built.
#[derive(Debug, thiserror::Error)]
pub enum PipelineError {
    /// The relative stage refused the rig or mode.
    #[error(transparent)]
    Relative(#[from] OdometryError),
    /// A setting is out of range.
    #[error(transparent)]
    Config(#[from] ConfigError),
}

/// One frame through the pipeline.
#[derive(Debug, Clone)]
pub struct PipelineFrame {
    /// The relative stage's answer (its own world frame).
    pub relative: RelativeOutput,
    /// The absolute stage's answer, when it runs.
    pub corrected: Option<CorrectedPose>,
    /// The pose in the saved map, when localising and localised.
    pub localised: Option<LocalisedPose>,
    /// Time the second stage took on this frame, ms (0 without one).
    pub second_stage_ms: f64,
}

impl PipelineFrame {
    /// The covariance published with the map-frame position: the absolute
    /// stage's (None before its filter starts), else the localiser's; None
    /// without a second-stage pose.
    pub fn map_position_covariance_m2(&self) -> Option<Matrix3<f64>> {
        match (&self.corrected, &self.localised) {
            (Some(corrected), _) => corrected.position_covariance_m2,
            (None, Some(localised)) => Some(localised.position_covariance_m2),
            (None, None) => None,
        }
    }
}

/// The relative stage with what follows it.
pub struct SlamPipeline {
    mode: SensorMode,
    relative: Box<dyn RelativeEstimator>,
    absolute: Option<AbsoluteStage>,
    localiser: Option<MapLocaliser>,
    /// The stamp of the last relative answer the second stage took, and
    /// where it was if it was tracking (as published, and in the absolute
    /// stage's world): the motion of the next one is measured from it.
    last_taken: Option<(i64, Option<(Vector3<f64>, Vector3<f64>)>)>,
    /// Frames whose landmarks the second stage did not get because the
    /// relative stage was settling ([`RelativeEstimator::settling`], or
    /// its accelerometer bias not yet known to
    /// `wait_accel_bias_sigma_m_s2`), and whether the last frame taken
    /// was one of them.
    held_back_frames: u64,
    holding_back: bool,
    /// `[absolute] wait_accel_bias_sigma_m_s2` in this mode (0: no wait).
    wait_accel_bias_sigma_m_s2: f64,
    /// `[absolute] wait_accel_bias_max_s`.
    wait_accel_bias_max_s: f64,
    /// The wait for the accelerometer bias under way: the stamp of its
    /// first frame, and whether it outlasted `wait_accel_bias_max_s`
    /// (the second stage then takes the landmarks until the bias is
    /// known, which ends the wait).
    bias_wait_since_ns: Option<i64>,
    bias_wait_gave_up: bool,
    /// Waits that outlasted `wait_accel_bias_max_s`.
    bias_waits_given_up: u64,
    /// The relative stage's levelling of its last output
    /// ([`RelativeEstimator::levelling`]) ...
    levelling: Isometry3<f64>,
    /// ... and the map's slower one (`[absolute] level_time_constant_s`):
    /// the absolute stage is given the outputs in its world and its
    /// answers are turned back into the relative stage's ([`map_world`]).
    map_level: LevelFollower,
}

impl SlamPipeline {
    /// The pipeline for `rig` in `mode` with `kind` as the relative
    /// stage, `settings` for both stages, and `second` after it.
    pub fn new(
        kind: EstimatorKind,
        mode: SensorMode,
        rig: &RigModel,
        settings: &SlamSettings,
        second: SecondStage,
    ) -> Result<Self, PipelineError> {
        let relative = build_estimator(kind, mode, rig, &settings.relative)?;
        let (absolute, localiser) = match second {
            SecondStage::None => (None, None),
            SecondStage::BuildMap => {
                let config = settings
                    .absolute
                    .to_config_in(mode)
                    .map_err(ConfigError::from)?;
                (Some(AbsoluteStage::new(config)), None)
            }
            SecondStage::Localise(map) => {
                let mut config = settings
                    .absolute
                    .to_localise_config()
                    .map_err(ConfigError::from)?;
                // Inertial runs have gravity along -z; so has a map made
                // by one (a vision-only map does not, and is not gated).
                if mode.uses_imu() {
                    config.max_tilt_rad = Some(RELOCALISE_MAX_TILT_DEG.to_radians());
                }
                // One camera: the relative stage's lengths are its own
                // (arbitrary without the IMU, a few per cent off with it).
                if !mode.uses_stereo() {
                    config.fit_scale = true;
                    config.confirm_after_frames = RELOCALISE_CONFIRM_FRAMES;
                    if mode.uses_imu() {
                        config.max_scale_ratio = Some(RELOCALISE_MAX_SCALE_RATIO);
                    }
                }
                (None, Some(MapLocaliser::new(&map, config)))
            }
        };
        Ok(Self {
            mode,
            relative,
            absolute,
            localiser,
            last_taken: None,
            held_back_frames: 0,
            holding_back: false,
            wait_accel_bias_sigma_m_s2: settings.absolute.wait_accel_bias_sigma_in(mode),
            wait_accel_bias_max_s: settings.absolute.wait_accel_bias_max_s,
            bias_wait_since_ns: None,
            bias_wait_gave_up: false,
            bias_waits_given_up: 0,
            levelling: Isometry3::identity(),
            map_level: LevelFollower::new(settings.absolute.level_time_constant_s),
        })
    }

    /// The sensor mode it runs in.
    pub fn mode(&self) -> SensorMode {
        self.mode
    }

    /// One IMU sample (raw: the relative stage applies the rig's IMU
    /// intrinsics).
    pub fn push_imu(&mut self, sample: &ImuSample) {
        self.relative.push_imu(sample);
    }

    /// One frame, after the IMU samples up to it and the first one past
    /// it: its pose, as soon as it is known. On a keyframe the relative
    /// stage answers with the pose as tracked and optimises its window in
    /// [`Self::finish_frame`]; the second stage then carries its last
    /// correction to that pose (the map->odom transform of the frame
    /// before) and takes the frame itself, optimised, in `finish_frame`.
    /// Call `finish_frame` after using the answer; this does it first if
    /// the caller did not, so the poses never depend on the caller.
    pub fn push_frame(&mut self, input: &FrameInput<'_>) -> PipelineFrame {
        self.finish_frame();
        let relative = self.relative.push_frame(input);
        self.note_levelling(&relative);
        if !self.relative.work_pending() {
            return self.second_stage(relative);
        }
        self.carried(relative)
    }

    /// The second stage's last correction carried to `relative`, which it
    /// does not take (now).
    fn carried(&self, mut relative: RelativeOutput) -> PipelineFrame {
        let start = Instant::now();
        let delta = self.measure_from_taken(&mut relative);
        let corrected = self.absolute.as_ref().map(|stage| {
            let back = self.map_to_published();
            let in_map_world = self.into_map_world(&relative, &back);
            into_published_world(stage.carry(&in_map_world), &back)
        });
        let localised = self
            .localiser
            .as_ref()
            .and_then(|localiser| localiser.carry(&relative));
        relative.delta_translation_world_m = delta;
        PipelineFrame {
            relative,
            corrected,
            localised,
            second_stage_ms: start.elapsed().as_secs_f64() * 1e3,
        }
    }

    /// The work the last frame left (see [`Self::push_frame`]): the
    /// relative stage's window optimisation and the second stage on the
    /// optimised frame. Their answer for that frame, which is not the one
    /// published but what the estimate goes on from (None when nothing
    /// was left).
    pub fn finish_frame(&mut self) -> Option<PipelineFrame> {
        let refined = self.relative.finish_frame()?;
        self.note_levelling(&refined);
        Some(self.second_stage(refined))
    }

    /// Measures `output`'s motion from the answer the second stage took
    /// last (the relative stage measures it from its own last answer,
    /// which the second stage may not have taken: an answer repeated for
    /// a frame out of order); the relative stage's own measure, to be put
    /// back once the second stage has used it.
    fn measure_from_taken(&self, output: &mut RelativeOutput) -> Vector3<f64> {
        let delta = match self.last_taken {
            Some((_, Some((last, _)))) if output.state == TrackingState::Tracking => {
                output.T_world_body.translation.vector - last
            }
            _ => Vector3::zeros(),
        };
        std::mem::replace(&mut output.delta_translation_world_m, delta)
    }

    /// Notes the relative stage's levelling of `output`, which it just
    /// gave, and lets the map's level follow its gravity estimate.
    fn note_levelling(&mut self, output: &RelativeOutput) {
        self.levelling = self.relative.levelling();
        if output.state != TrackingState::Tracking {
            return;
        }
        if let Some(gravity) = self.relative.gravity_world_m_s2() {
            let back = self.levelling.inverse();
            let position = back
                .transform_point(&output.T_world_body.translation.vector.into())
                .coords;
            self.map_level
                .follow(&(back.rotation * gravity), output.t_ns, &position);
        }
    }

    /// Takes the absolute stage's world into the one the relative stage
    /// publishes in now.
    fn map_to_published(&self) -> Isometry3<f64> {
        self.levelling * self.map_level.level().inverse()
    }

    /// `output` (as published, its motion measured from the last answer
    /// taken) in the absolute stage's world, its motion measured there
    /// (the levels may have turned since: turning the published motion
    /// back would leave the turn's share in it).
    /// `map_to_published` is [`Self::map_to_published`].
    fn into_map_world(
        &self,
        output: &RelativeOutput,
        map_to_published: &Isometry3<f64>,
    ) -> RelativeOutput {
        let mut own = into_map_world(output, map_to_published);
        if let Some((_, Some((_, last)))) = self.last_taken {
            if own.state == TrackingState::Tracking {
                own.delta_translation_world_m = own.T_world_body.translation.vector - last;
            }
        }
        own
    }

    /// The second stage on a relative-stage output.
    fn second_stage(&mut self, mut relative: RelativeOutput) -> PipelineFrame {
        if !self.has_second_stage() {
            return PipelineFrame {
                relative,
                corrected: None,
                localised: None,
                second_stage_ms: 0.0,
            };
        }
        if self
            .last_taken
            .is_some_and(|(t_ns, _)| relative.t_ns <= t_ns)
        {
            // The second stage takes frames in time order: an answer not
            // newer than the last it took (the relative stage's last
            // answer again, for a frame out of order) gets the correction
            // carried to it.
            return self.carried(relative);
        }
        let start = Instant::now();
        let delta = self.measure_from_taken(&mut relative);
        // While the relative stage settles after a start in motion its
        // landmarks carry the alignment's errors, and until it knows its
        // accelerometer bias its attitude may carry the bias: the second
        // stage gets the motion without them (no map anchor, no edges, no
        // corrections from those frames; the pose passes through).
        let held_back;
        // (The bias wait's clock runs while the stage settles too.)
        let waits_for_bias = self.waits_for_bias(relative.t_ns);
        let settling = self.relative.settling() || waits_for_bias;
        if self.holding_back && !settling {
            tracing::info!(
                frames = self.held_back_frames,
                "the relative stage has settled: the second stage takes its landmarks"
            );
        }
        self.holding_back = settling;
        let input = if settling && !relative.landmarks.is_empty() {
            self.held_back_frames += 1;
            held_back = RelativeOutput {
                landmarks: Vec::new(),
                ..relative.clone()
            };
            &held_back
        } else {
            &relative
        };
        let back = self.map_to_published();
        let in_map_world = self
            .absolute
            .is_some()
            .then(|| self.into_map_world(input, &back));
        let corrected = self
            .absolute
            .as_mut()
            .zip(in_map_world.as_ref())
            .map(|(stage, input)| into_published_world(stage.push(input), &back));
        let localised = self
            .localiser
            .as_mut()
            .and_then(|localiser| localiser.push(input));
        relative.delta_translation_world_m = delta;
        self.last_taken = Some((
            relative.t_ns,
            (relative.state == TrackingState::Tracking).then(|| {
                let p = relative.T_world_body.translation.vector;
                let in_map_world = back.inverse_transform_point(&p.into());
                (p, in_map_world.coords)
            }),
        ));
        PipelineFrame {
            relative,
            corrected,
            localised,
            second_stage_ms: start.elapsed().as_secs_f64() * 1e3,
        }
    }

    /// The relative stage (timings, counters, noise scale, camera-IMU
    /// estimate).
    pub fn relative(&self) -> &dyn RelativeEstimator {
        self.relative.as_ref()
    }

    /// Whether a second stage runs and waits for the relative stage to
    /// settle (its last frame was held back).
    pub fn second_stage_waiting(&self) -> bool {
        self.holding_back && self.has_second_stage()
    }

    /// Frames whose landmarks the second stage was not given while the
    /// relative stage settled (None without a second stage).
    pub fn held_back_frames(&self) -> Option<u64> {
        self.has_second_stage().then_some(self.held_back_frames)
    }

    /// Waits that outlasted `[absolute] wait_accel_bias_max_s`: the
    /// second stage started without the accelerometer bias known.
    pub fn bias_waits_given_up(&self) -> u64 {
        self.bias_waits_given_up
    }

    /// Whether the second stage waits, at the frame stamped `t_ns`, for
    /// the accelerometer bias: the relative stage uses the IMU, knows its
    /// bias no better than `wait_accel_bias_sigma_m_s2`, and has not for
    /// longer than `wait_accel_bias_max_s`. A rest (the pose held, no
    /// sigma) neither waits nor ends the wait under way; a known bias
    /// does.
    fn waits_for_bias(&mut self, t_ns: i64) -> bool {
        if self.wait_accel_bias_sigma_m_s2 <= 0.0 {
            return false;
        }
        let Some(sigma) = self.relative.accel_bias_sigma_m_s2() else {
            return false;
        };
        if sigma <= self.wait_accel_bias_sigma_m_s2 {
            self.bias_wait_since_ns = None;
            self.bias_wait_gave_up = false;
            return false;
        }
        let since = *self.bias_wait_since_ns.get_or_insert(t_ns);
        if self.bias_wait_gave_up {
            return false;
        }
        let waited_s = (t_ns - since) as f64 * 1e-9;
        if waited_s < self.wait_accel_bias_max_s {
            return true;
        }
        self.bias_wait_gave_up = true;
        self.bias_waits_given_up += 1;
        tracing::warn!(
            waited_s,
            sigma_m_s2 = sigma,
            wanted_m_s2 = self.wait_accel_bias_sigma_m_s2,
            "the accelerometer bias is still not known after [absolute] wait_accel_bias_max_s: \
             the second stage takes the landmarks anyway, and its attitude may be off by about \
             sigma / 9.81 rad (turn the rig to tell the bias from gravity)"
        );
        false
    }

    fn has_second_stage(&self) -> bool {
        self.absolute.is_some() || self.localiser.is_some()
    }

    /// The absolute stage, when it runs.
    pub fn absolute(&self) -> Option<&AbsoluteStage> {
        self.absolute.as_ref()
    }

    /// The absolute stage, when it runs (to finish or save its map).
    pub fn absolute_mut(&mut self) -> Option<&mut AbsoluteStage> {
        self.absolute.as_mut()
    }

    /// The absolute stage's last solved map for saving, in the world the
    /// poses are published in ([`AbsoluteStage::solved_map`]).
    pub fn solved_map(&self) -> Option<SavedMap> {
        let map = self.absolute.as_ref()?.solved_map()?;
        Some(map_into_published_world(map, &self.map_to_published()))
    }

    /// The absolute stage's map solved with every edge so far, for saving,
    /// in the world the poses are published in
    /// ([`AbsoluteStage::finish_map`]).
    pub fn finish_map(&mut self) -> Option<SavedMap> {
        let map = self.absolute.as_mut()?.finish_map()?;
        Some(map_into_published_world(map, &self.map_to_published()))
    }

    /// The localiser, when localising in a saved map.
    pub fn localiser(&self) -> Option<&MapLocaliser> {
        self.localiser.as_ref()
    }

    /// Does the work the last frame left and waits for the absolute
    /// stage's map solve in flight, if any (end of a run).
    pub fn finish(&mut self) {
        self.finish_frame();
        if let Some(stage) = self.absolute.as_mut() {
            stage.wait_for_solve();
        }
    }
}

#[cfg(test)]
mod tests;
