//! The relative stage's settings as a user writes them (the `[relative]`
//! table of `rigslam run --config FILE`, the daemon's `[slam.relative]`;
//! the file itself is [`crate::slam_config`]): TOML with defaults for
//! every key, checked once into the typed configs of the parts.

use crate::relative::estimator::ModeSwitch;
use crate::relative::window::{
    CameraImuRefinementConfig, HeldKeyframesFollow, NoiseAdaptationConfig, NoiseScale,
};

/// Which estimator runs the relative stage.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
#[serde(rename_all = "kebab-case")]
pub enum EstimatorKind {
    /// The paper's windowed Levenberg-Marquardt optimisation.
    Window,
    /// The paper's EKF variant, a baseline (inertial modes, static start).
    Ekf,
}

impl EstimatorKind {
    /// Lower-case name as the command line and settings files spell it.
    pub fn name(self) -> &'static str {
        match self {
            EstimatorKind::Window => "window",
            EstimatorKind::Ekf => "ekf",
        }
    }
}

/// Which inertial modes a behaviour of the relative stage is on in; each
/// key that takes it says why its "auto" is what it is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
#[serde(rename_all = "kebab-case")]
pub enum InertialModes {
    /// Stereo-inertial only.
    Auto,
    /// Both inertial modes.
    On,
    /// Neither.
    Off,
}

impl InertialModes {
    /// Whether the behaviour is on in `mode`.
    pub fn enabled_in(self, mode: crate::relative::SensorMode) -> bool {
        use crate::relative::SensorMode;
        match self {
            InertialModes::Off => false,
            InertialModes::On => mode.uses_imu(),
            InertialModes::Auto => mode == SensorMode::StereoInertial,
        }
    }
}

/// Where the window refines the camera-IMU calibration online ("off": the
/// calibration file's camera-IMU transformation and time shift are used as
/// they are).
pub type CameraImuRefinement = InertialModes;

/// Where the visual-inertial alignment of a start in motion waits for a
/// full window ("off": it is tried once `init_keyframes` span
/// `init_min_span_s`).
pub type FullWindowAlignment = InertialModes;

/// Settings of the relative stage. Every key has a default; unknown keys
/// are refused so that a typo does not silently keep the default.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RelativeConfig {
    /// Features kept in the left image.
    pub features: usize,
    /// Follow each feature from frame to frame with an affine warp of its
    /// KLT window, not only a shift. A shift-only fit errs by a few
    /// hundredths of a pixel per frame where the view turns or scales,
    /// always the same way, so a track drifts: on a rendered room 0.86 px
    /// (median) after 21-40 frames, against 0.31 px with the warp, and the
    /// inertial modes' ATE falls by about a third on the accuracy sets (see
    /// docs/results/klt-affine-2026-12-05.md), for about 1.6 ms more a
    /// frame on one core (docs/results/klt-affine-default-2026-12-05.md).
    /// Off: the shift-only fit.
    pub klt_affine: bool,
    /// At each keyframe, move every track to where the patch it started
    /// from aligns (affine warp, gain and offset), when that is within a
    /// pixel of where it was followed: a track followed from frame to
    /// frame gathers each frame's error (0.04 px after one frame, 0.17-0.20
    /// px after 64 on the renderings), its first patch does not (0.04-0.05
    /// px at every age; docs/results/track-error-2026-12-07.md). `auto`
    /// (the default): stereo-inertial only. There, pooled over four copies
    /// of every accuracy set, both stages' ATE falls 16-35 % on the
    /// consistent-IMU and held-apart sets; mono-inertial gains on the
    /// development set but its held-apart scale is worse on every copy,
    /// and stereo without the IMU re-initialised on three of 23 runs with it
    /// (docs/results/first-patch-modes-2026-12-07.md). About 2 ms a frame
    /// on one core.
    pub track_first_patch: ModeSwitch,
    /// Keyframes kept in the window (L).
    pub window_keyframes: usize,
    /// Newest keyframes optimised (M); the oldest L-M are held fixed.
    pub window_free: usize,
    /// Standard deviation of a feature position, px (the paper: 1 px).
    pub pixel_sigma_px: f64,
    /// Keyframes needed (and the time they must span, s) before the
    /// visual-inertial alignment is tried in the inertial modes.
    pub init_keyframes: usize,
    /// Time the keyframes must span before the alignment is tried, s; a
    /// full window is tried whatever it spans (in fast motion it may span
    /// less, and waiting would never start).
    pub init_min_span_s: f64,
    /// A start in motion aligns the IMU with the images only once the
    /// window is full (`window_keyframes`), not at `init_keyframes`: the
    /// longest stretch of turns the window holds tells the gyroscope bias,
    /// velocity and gravity best, and the first windows after the
    /// alignment keep what it found. The first pose of a start in motion
    /// comes 0.5-2 s later. "auto" (stereo-inertial: there it improved the
    /// starts in flight of both the development and the held-apart sets,
    /// in mono-inertial it did not), "on" or "off".
    pub init_full_window: FullWindowAlignment,
    /// Largest relative standard deviation of the scale at which the
    /// mono-inertial stage switches from initialisation to hybrid.
    pub init_max_scale_rel_std: f64,
    /// Consecutive frames without a usable pose before tracking is lost.
    pub lost_after_frames: usize,
    /// After a loss, how long the IMU alone may carry the state before a
    /// full re-initialisation is needed, s.
    pub imu_only_max_s: f64,
    /// Leaving a rest, how long the IMU alone may carry the state before
    /// the images place a frame, s. The rest measured the velocity (zero)
    /// and the biases, so the IMU drifts far less than after a loss in
    /// motion; a monocular window has no landmarks until the motion gives
    /// parallax, which a gentle start (a robot leaving its dock) takes a few
    /// seconds to give.
    pub imu_only_after_rest_max_s: f64,
    /// Largest speed, m/s, at which a keyframe solve's correction of the
    /// position reaches the published pose (`relative/published_position.rs`);
    /// 0 publishes it at once. A keyframe's pose goes out before its solve,
    /// and a solve that moves it (a monocular window's scale settling after
    /// a gentle start moved one by 3.5 cm) would otherwise reach the next
    /// frame as one step. At 0.2 m/s and 20 Hz a correction of up to 1 cm
    /// is out by the next frame.
    pub published_correction_m_s: f64,
    /// Estimate online how much noisier (or quieter) the IMU is than its
    /// calibration declares, from the window's inertial residuals, and
    /// weigh it by that (`relative/window/noise_adaptation.rs`).
    pub imu_noise_adaptation: bool,
    /// Multipliers on the declared gyroscope and accelerometer noise
    /// densities to start from (and keep, with the adaptation off).
    pub imu_noise_scale_gyro: f64,
    /// Multiplier on the declared accelerometer noise density to start from (see
    /// `imu_noise_scale_gyro`).
    pub imu_noise_scale_accel: f64,
    /// Horizon of the adaptation, s.
    pub imu_noise_adaptation_memory_s: f64,
    /// Bounds of either multiplier.
    pub imu_noise_scale_min: f64,
    /// Upper bound of either multiplier.
    pub imu_noise_scale_max: f64,
    /// Estimate the bias random walks' scales too (off: measured worse
    /// in mono-inertial, see the adaptation's module doc).
    pub imu_walk_adaptation: bool,
    /// How many consecutive inertial links the adaptation tests together
    /// (1, the default: each link alone; 2-6: the oldest links of each
    /// solve joined, where an error slow against one link shows; measured
    /// better in mono-inertial on real IMUs and worse in stereo-inertial,
    /// see the adaptation's module doc).
    pub imu_noise_adaptation_joined_links: usize,
    /// Refine the camera-IMU calibration online, starting from the
    /// calibration file (`relative/window/camera_imu.rs`): camera 0's
    /// rotation in the IMU frame, the frames' time offset, the stereo
    /// pair's rotation, and (only as far as its sigma lets it, see below)
    /// camera 0's translation. "auto" (stereo-inertial: there it improved
    /// the held-apart evaluation set, in mono-inertial it did not), "on"
    /// (both inertial modes) or "off".
    pub camera_imu_refinement: CameraImuRefinement,
    /// How far the file may be off, one sigma: rotation (deg),
    /// translation (m), time offset (s). The translation's default, 0.5 mm,
    /// holds it: the lever arm hardly shows in ordinary motion, and freed
    /// (0.03) it wandered and cost accuracy (bench/README.md).
    pub camera_imu_rotation_sigma_deg: f64,
    /// How far the file's camera 0 translation may be off, one sigma, m.
    pub camera_imu_translation_sigma_m: f64,
    /// How far the file's time shift may be off, one sigma, s.
    pub camera_imu_time_offset_sigma_s: f64,
    /// How far the stereo calibration's rotation between the cameras may
    /// be off, one sigma, deg.
    pub camera_imu_stereo_rotation_sigma_deg: f64,
    /// Share of a solve's information about the calibration carried to
    /// the next one, in [0, 1).
    pub camera_imu_carry_weight: f64,
    /// Hold the calibration at the file until a solve's data test it
    /// wrong, three solves in a row (a score test at 99.9 %), and refine
    /// it from then on; false refines from the first solve. A correct
    /// file refined at once swung by up to 1.6 deg in the first seconds
    /// and cost 7-12 % of the ATE (`relative/window/camera_imu.rs`).
    pub camera_imu_hold_until_tested: bool,
    /// After a start in flight, when the test releases the calibration,
    /// the window forgets what its boundary prior says of the gyroscope
    /// bias (back to `gyro_bias_prior_sigma_rad_s`): the visual-inertial
    /// alignment in motion read the gyroscope through the file's rotation,
    /// and the bias it found holds a wrong rotation short of the truth.
    /// Off by default: it costs a correct file where the images disagree
    /// with the IMU (docs/results/camera-imu-bias-release-2026-12-07.md).
    pub camera_imu_release_frees_gyro_bias: bool,
    /// When the held keyframes' body poses follow the refined
    /// calibration, their cameras staying where their images put them
    /// (`relative/window/held_cameras.rs`): "in-flight" (after a start in
    /// motion; the default), "on" or "off". Held body poses tie the calibration to the
    /// value they were held at: after a start in flight with a wrong file
    /// the rotation and time offset stalled short of the truth. From
    /// rest the calibration converges before the held keyframes turn,
    /// and following there lets it take up the renderings' disagreement
    /// between truth and IMU (docs/results/held-cameras-2026-12-06.md).
    pub camera_imu_held_keyframes_follow: HeldKeyframesFollow,
    /// Turn the poses so that the estimated gravity points along -z
    /// (`relative/level.rs`): an odometry frame with z up. The window's
    /// own world is levelled by the first guess of gravity, made before
    /// the accelerometer biases are known, and stays tilted by up to a
    /// degree. Inertial modes only; vision-only poses are untouched.
    pub level_poses: bool,
    /// Carry the published pose covariance with the measurements that
    /// consecutive window solves share (a prior centred on the last
    /// solve's estimate is wrong the way this solve's own measurements
    /// are), and the gravity prior's sensitivity from the prior the solve
    /// weighed. Consistent on data with exactly the declared noise (off,
    /// the poses from the origin are too sure and the gravity too
    /// cautious there). On the renderings, whose features are better than
    /// the declared pixel sigma, it is cautious by about that much, with
    /// sigmas 2-10 times closer to the errors than off; the map frame
    /// needs `[absolute] mapping_attitude_covariance` with it
    /// (docs/results/map-attitude-covariance-2026-12-07.md).
    pub covariance_shared_measurements: bool,
    /// The pixel sigma the inertial modes' published covariance is
    /// computed with, on `pixel_sigma_px`: `max(gain * estimate, floor)`,
    /// the estimate being what the window's residuals show. The residuals
    /// show only the white part of a feature's error; what is slow along
    /// a track moves its landmark, not its residuals, and reaches the
    /// poses all the same.
    pub covariance_pixel_gain: f64,
    /// See `covariance_pixel_gain`. 0.5 by default, chosen on the
    /// development set (whole-matrix NEES per dof of the relative stage
    /// and of the map frame from its origin, both inertial modes, nearest
    /// 1; at 1 the covariance was 2-3 times too cautious on every set, at
    /// the measured sigma alone 2-10 times too sure), then checked on the
    /// held-apart set (docs/results/covariance-pixel-floor-2026-12-07.md).
    /// Only on keyframes an inertial link reaches: a stereo start in
    /// flight's image-only keyframes are weighed at the estimate
    /// (docs/results/covariance-image-only-keyframes-2026-12-07.md).
    pub covariance_pixel_floor: f64,
    /// How quickly the level follows the gravity estimate, s (a
    /// first-order filter; 0 follows at once). Slow enough that the
    /// estimate's jitter between solves (tenths of a degree) does not bend
    /// the path, quick enough to take out the world's tilt within a
    /// minute.
    pub level_time_constant_s: f64,
}

impl Default for RelativeConfig {
    fn default() -> Self {
        Self {
            features: 150,
            klt_affine: true,
            track_first_patch: ModeSwitch::Auto,
            window_keyframes: 10,
            window_free: 7,
            pixel_sigma_px: 1.0,
            init_keyframes: 6,
            init_min_span_s: 1.0,
            init_full_window: FullWindowAlignment::Auto,
            init_max_scale_rel_std: 0.03,
            lost_after_frames: 3,
            imu_only_max_s: 1.0,
            imu_only_after_rest_max_s: 3.0,
            published_correction_m_s: 0.2,
            imu_noise_adaptation: true,
            imu_noise_scale_gyro: 1.0,
            imu_noise_scale_accel: 1.0,
            imu_noise_adaptation_joined_links: 1,
            imu_noise_adaptation_memory_s: 20.0,
            imu_noise_scale_min: 0.1,
            imu_noise_scale_max: 100.0,
            imu_walk_adaptation: false,
            camera_imu_refinement: CameraImuRefinement::Auto,
            camera_imu_rotation_sigma_deg: 2.0,
            camera_imu_translation_sigma_m: 0.0005,
            camera_imu_time_offset_sigma_s: 0.01,
            camera_imu_stereo_rotation_sigma_deg: 0.2,
            camera_imu_carry_weight: 0.9,
            camera_imu_hold_until_tested: true,
            camera_imu_release_frees_gyro_bias: false,
            camera_imu_held_keyframes_follow: HeldKeyframesFollow::InFlight,
            level_poses: true,
            covariance_shared_measurements: true,
            covariance_pixel_gain: 1.0,
            covariance_pixel_floor: 0.5,
            level_time_constant_s: 20.0,
        }
    }
}

/// A setting out of range, with its key.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ConfigError {
    #[error("reading {path}: {message}")]
    /// The settings file could not be read.
    Read {
        /// The file.
        path: String,
        /// The I/O error.
        message: String,
    },
    #[error("{path}: {message}")]
    /// The settings file is not valid TOML, has unknown keys, or puts keys in the wrong table.
    Parse {
        /// The file (or what the text came from).
        path: String,
        /// The parser's message.
        message: String,
    },
    #[error("{0}")]
    /// Settings that contradict each other (the message says which).
    Invalid(String),
    #[error("{key} = {value} is out of range: {allowed}")]
    /// A setting is out of range.
    OutOfRange {
        /// The setting's key.
        key: &'static str,
        /// Its value, as written.
        value: String,
        /// The allowed range.
        allowed: &'static str,
    },
}

impl RelativeConfig {
    /// Checks every value against its allowed range.
    pub fn validate(&self) -> Result<(), ConfigError> {
        let range = |key, ok: bool, value: String, allowed| {
            if ok {
                Ok(())
            } else {
                Err(ConfigError::OutOfRange {
                    key,
                    value,
                    allowed,
                })
            }
        };
        range(
            "features",
            (20..=2000).contains(&self.features),
            self.features.to_string(),
            "20 to 2000",
        )?;
        range(
            "window_keyframes",
            (3..=50).contains(&self.window_keyframes),
            self.window_keyframes.to_string(),
            "3 to 50",
        )?;
        range(
            "window_free",
            self.window_free >= 1 && self.window_free < self.window_keyframes,
            self.window_free.to_string(),
            "1 to window_keyframes - 1",
        )?;
        range(
            "init_keyframes",
            (3..=self.window_keyframes).contains(&self.init_keyframes),
            self.init_keyframes.to_string(),
            "3 to window_keyframes",
        )?;
        range(
            "init_max_scale_rel_std",
            self.init_max_scale_rel_std > 0.0 && self.init_max_scale_rel_std < 1.0,
            self.init_max_scale_rel_std.to_string(),
            "between 0 and 1",
        )?;
        range(
            "lost_after_frames",
            (1..=100).contains(&self.lost_after_frames),
            self.lost_after_frames.to_string(),
            "1 to 100",
        )?;
        range(
            "published_correction_m_s",
            self.published_correction_m_s.is_finite()
                && (0.0..=100.0).contains(&self.published_correction_m_s),
            self.published_correction_m_s.to_string(),
            "0 to 100",
        )?;
        for (key, v) in [
            ("pixel_sigma_px", self.pixel_sigma_px),
            ("covariance_pixel_gain", self.covariance_pixel_gain),
        ] {
            range(
                key,
                v.is_finite() && v > 0.0,
                v.to_string(),
                "a positive number",
            )?;
        }
        for (key, v) in [
            ("init_min_span_s", self.init_min_span_s),
            ("imu_only_max_s", self.imu_only_max_s),
            ("imu_only_after_rest_max_s", self.imu_only_after_rest_max_s),
            ("covariance_pixel_floor", self.covariance_pixel_floor),
            ("level_time_constant_s", self.level_time_constant_s),
        ] {
            range(
                key,
                v.is_finite() && v >= 0.0,
                v.to_string(),
                "a number >= 0",
            )?;
        }
        if let Err(message) = self.noise_adaptation().validate() {
            return Err(ConfigError::Invalid(message));
        }
        if let Err(message) = self
            .camera_imu_refinement(crate::relative::SensorMode::StereoInertial)
            .validate()
        {
            return Err(ConfigError::Invalid(message));
        }
        Ok(())
    }

    /// The window's camera-IMU refinement from these settings, in `mode`.
    pub fn camera_imu_refinement(
        &self,
        mode: crate::relative::SensorMode,
    ) -> CameraImuRefinementConfig {
        CameraImuRefinementConfig {
            enabled: self.camera_imu_refinement.enabled_in(mode),
            rotation_sigma_deg: self.camera_imu_rotation_sigma_deg,
            translation_sigma_m: self.camera_imu_translation_sigma_m,
            time_offset_sigma_s: self.camera_imu_time_offset_sigma_s,
            stereo_rotation_sigma_deg: self.camera_imu_stereo_rotation_sigma_deg,
            carry_weight: self.camera_imu_carry_weight,
            hold_until_tested: self.camera_imu_hold_until_tested,
            release_frees_gyro_bias: self.camera_imu_release_frees_gyro_bias,
            held_keyframes_follow: self.camera_imu_held_keyframes_follow,
            ..CameraImuRefinementConfig::default()
        }
    }

    /// The window's IMU noise adaptation from these settings.
    pub fn noise_adaptation(&self) -> NoiseAdaptationConfig {
        NoiseAdaptationConfig {
            enabled: self.imu_noise_adaptation,
            initial: NoiseScale {
                gyro: self.imu_noise_scale_gyro,
                accel: self.imu_noise_scale_accel,
                pixel: 1.0,
                gyro_walk: 1.0,
                accel_walk: 1.0,
            },
            memory_s: self.imu_noise_adaptation_memory_s,
            min_scale: self.imu_noise_scale_min,
            max_scale: self.imu_noise_scale_max,
            adapt_walk: self.imu_walk_adaptation,
            joined_links: self.imu_noise_adaptation_joined_links,
            ..NoiseAdaptationConfig::default()
        }
    }
}
