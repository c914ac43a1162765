//! The absolute stage's settings as a user writes them: the `[absolute]`
//! table of `rigslam run --config FILE` (and of the daemon's `[slam]`),
//! every key with a default, turned into an [`AbsoluteConfig`].

use super::config::{AbsoluteConfig, LandmarkCovariance};
use super::localise::LocaliseConfig;
use super::map_worker::RobustWeights;
use super::recognition::RecognitionConfig;
use super::solve_schedule::SolveMode;
use crate::edge_map::policy::EdgePolicy;
use crate::relative::SensorMode;

/// The landmark innovation gate's value by default, a chi-square with 3
/// dof: 16.27 is its 99.9 % point.
pub const DEFAULT_CORRECTION_GATE_CHI2: f64 = 16.27;

/// The accelerometer bias sigma the second stage waits for by default,
/// m/s^2 ([`AbsoluteSettings::wait_accel_bias_sigma_m_s2`]).
pub const DEFAULT_WAIT_ACCEL_BIAS_SIGMA_M_S2: f64 = 0.02;

/// The longest the second stage waits for the accelerometer bias, s
/// ([`AbsoluteSettings::wait_accel_bias_max_s`]).
pub const DEFAULT_WAIT_ACCEL_BIAS_MAX_S: f64 = 10.0;

/// How slowly the map's world follows the relative stage's gravity
/// estimate by default, s ([`AbsoluteSettings::level_time_constant_s`]).
pub const DEFAULT_LEVEL_TIME_CONSTANT_S: f64 = 40.0;

pub use crate::relative::ModeSwitch;

/// The `[absolute]` table.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct AbsoluteSettings {
    /// Run the absolute stage after the relative one: the map is built and
    /// the position corrected (`rigslam run --absolute` sets it).
    pub enabled: bool,
    /// Which edges a frame adds to the map: `frame` (a node for the
    /// frame joined to each landmark it sees), `frame:N` (the same for
    /// every N-th tracking frame), or landmark pairs: `all` co-visible
    /// pairs, a spanning tree `mst`, or `knn:K` nearest neighbours.
    pub policy: String,
    /// Map solve every this many frames (the paper: 5).
    pub solve_every_frames: usize,
    /// Where the map is solved: `pipelined` (its own thread; the solve
    /// requested at frame n is used from frame n + solve_every_frames on,
    /// that frame waiting for it if needed: repeatable; the daemon on
    /// live frames does not wait, and installs a late solve on the first
    /// frame after it is done), `background` (its
    /// own thread, never waited for: frames use the newest solved map,
    /// which depends on timing) or `inline` (on the frame path: the map
    /// requested at frame n is used from frame n + 1).
    pub solve: String,
    /// Covariance of the visible landmarks in the correction: `exact`
    /// (blocks of A^-1 from the factor, consistent, cost grows with the
    /// map) or `submatrix` (the paper's approximation, cheap, overconfident).
    pub covariance: String,
    /// Rings of neighbours of the sub-matrix approximation.
    pub submatrix_hops: usize,
    /// At most this many (the most precise) visible landmarks correct a frame.
    pub max_correction_landmarks: usize,
    /// Prediction noise, m per sqrt(m) travelled.
    pub translation_sigma_per_sqrt_m: f64,
    /// Multiplies the relative stage's landmark covariances (>= 1 when its
    /// covariances are too small; see the corrections' mean NIS per dof in
    /// the report, about 1 when right). Default 2, not the library's 1:
    /// on the real-IMU V1_02 renderings the NIS per dof is 0.9-1.4 at 2
    /// and 0.4-0.7 at 4, and the ATE lower at 2 (bench/README.md).
    pub landmark_covariance_scale: f64,
    /// Recognise landmarks that come back under a new track id.
    pub recognition: bool,
    /// Largest descriptor distance of a recognised landmark, bits of 256.
    pub recognition_max_hamming: u32,
    /// Chi-square gate on the predicted position (3 dof).
    pub recognition_gate_chi2: f64,
    /// Landmarks whose measured position is less certain than this
    /// (largest standard deviation, m, after landmark_covariance_scale)
    /// are not recognised: a wide gate holds lookalikes.
    pub recognition_max_sigma_m: f64,
    /// A track joins a map landmark only after being recognised as that
    /// landmark in this many consecutive frames (1: at once).
    pub recognition_confirm_frames: u32,
    /// ... and once the track's position is this certain (largest
    /// standard deviation, m, after landmark_covariance_scale; 0: any).
    pub recognition_confirm_max_sigma_m: f64,
    /// A recognition must put the robot within this distance (m, plus
    /// three of the track's standard deviations: along each of its axes
    /// for the map's recognitions, its largest for the localiser's) of
    /// where the frame's landmarks already in the map put it.
    pub recognition_consensus_gate_m: f64,
    /// A new track that looks like a map landmark near where it is waits
    /// this many frames for its recognition before it becomes a new
    /// landmark (0 or 1: at once; each duplicate made then stays in the map).
    pub recognition_new_landmark_after_frames: u32,
    /// Down-weight map edges that disagree with the solved map by more
    /// than a chi-square of 16.3 (3 dof, 0.1%) and solve again (Huber, two
    /// rounds): a wrong recognition then bends the map less.
    pub robust_map: bool,
    /// Join consecutive frame nodes by the relative stage's translation
    /// (frame policies only), so a frame that sees only new landmarks
    /// stays connected to the map.
    pub odometry_edges: bool,
    /// How far those edges trust the relative stage's motion between two
    /// nodes, m per sqrt(m) travelled (the position filter's own
    /// prediction noise is translation_sigma_per_sqrt_m).
    pub odometry_sigma_per_sqrt_m: f64,
    /// A frame node gives the map only what a landmark's window estimate
    /// gained since the landmark's last node (the share of its window
    /// keyframes that are new), not the whole estimate again: frames
    /// between two keyframes hand on the same estimate. The published
    /// position covariance counts the same repetition (the gain does
    /// not).
    pub count_window_once: bool,
    /// The published map-frame covariance adds what the relative stage's
    /// attitude error puts in the robot's position: the map's landmarks
    /// were placed through the heading of their mapping frames, turned
    /// about wherever the robot was when that heading error grew, and the
    /// robot sees them through the heading of now (a heading sigma that
    /// grew by s rad while the robot was d metres from where it is now
    /// places it about d*s off). It comes from the relative stage's
    /// published rotation covariance; without it the covariance knows
    /// only the landmarks' measured noise and the filter's.
    pub mapping_attitude_covariance: bool,
    /// A landmark joined to this many frame nodes counts as mapped; a
    /// frame whose landmarks are mostly mapped adds no node, so a robot
    /// that keeps revisiting the same room stops growing its map (0:
    /// every frame adds one, the map grows for as long as the robot runs).
    pub frame_node_saturation: usize,
    /// A place (a 0.5 m cube and a viewing direction, about 45 degrees)
    /// takes frame nodes on at most this many passes of the robot, so the
    /// map stops growing on revisits where recognition misses landmarks
    /// seen again (0: no limit).
    pub node_passes_per_place: usize,
    /// Correct the orientation as well as the position: the map's
    /// landmarks estimate an offset of the relative stage's orientation
    /// that wanders by this much, rad per sqrt(s) (0: the paper's filter,
    /// which takes the relative stage's orientation as exact). Localising
    /// in a saved map (`--load-map`) corrects its heading the same way.
    pub orientation_sigma_rad_per_sqrt_s: f64,
    /// Estimate the scale of the map over the relative stage's window (a
    /// monocular window's scale wanders), letting it wander by this much
    /// per sqrt(s); 0: the window's lengths are the map's.
    pub scale_sigma_per_sqrt_s: f64,
    /// Where a landmark is left out of a position correction when its own
    /// innovation exceeds `correction_gate_chi2`, as the localiser does
    /// with its recognised landmarks: `auto` (stereo-inertial: there it
    /// improved both stages on the development, held-apart and
    /// consistent-IMU sets, on every copy of a negligibly perturbed rig;
    /// in mono-inertial it made the held-apart half worse: with one
    /// camera the window's lengths wander, and the landmarks that
    /// disagree most are the ones that pull a drifting track back), `on`
    /// or `off`.
    pub correction_gate: ModeSwitch,
    /// The gate, a chi-square with 3 dof (16.27: 99.9 %); 0: off whatever
    /// `correction_gate` says.
    pub correction_gate_chi2: f64,
    /// Where the second stage (map or localiser) takes no landmarks while
    /// the relative stage knows its accelerometer bias no better than
    /// `wait_accel_bias_sigma_m_s2`: after a start from rest gravity and
    /// the bias are told apart only once the rig turns, until then the
    /// attitude may be off by about sigma / g, and landmarks mapped then
    /// pull the robot later; the pose passes through meanwhile. `auto`
    /// (stereo-inertial: there it improved the two stages on the
    /// development, held-apart and consistent-IMU sets on every copy; in
    /// mono-inertial, where the bias is known later, the map lost more
    /// than it gained on both halves), `on` (both inertial modes) or
    /// `off`.
    pub wait_accel_bias: ModeSwitch,
    /// The bias sigma waited for, m/s^2 (0.02: 0.12 deg of tilt, 9 mm at
    /// 4.5 m; 0: no wait whatever `wait_accel_bias` says).
    pub wait_accel_bias_sigma_m_s2: f64,
    /// The longest the wait lasts, s of frame stamps from its first frame
    /// (10: the sets' starts from rest know their bias within 2-4 s of
    /// moving; a rig that moves without turning, a vehicle driving
    /// straight, would otherwise never be mapped). Past it the map
    /// starts anyway and the log says so; `inf` waits for as long as it
    /// takes.
    pub wait_accel_bias_max_s: f64,
    /// The map is built in the relative stage's own world levelled by its
    /// gravity estimate through a filter of this time constant, s; what
    /// the stage answers is turned into the level the relative stage
    /// publishes in (`[relative] level_time_constant_s`, 20 s). Each turn
    /// of the map's world bends the map (the landmarks a frame node gave
    /// were turned by the level of its time), so it turns more slowly
    /// than the published poses: a start in flight's first degree of tilt
    /// no longer stays in the map; followed at all, the estimator's own
    /// roll and pitch drift does not either. `inf`: never turns (the
    /// estimator's own world); 0: at once.
    pub level_time_constant_s: f64,
}

impl Default for AbsoluteSettings {
    fn default() -> Self {
        let config = AbsoluteConfig::default();
        let recognition = RecognitionConfig::default();
        Self {
            enabled: false,
            policy: config.policy.to_string(),
            solve_every_frames: config.solve_every_frames,
            solve: match config.solve_mode {
                SolveMode::Inline => "inline",
                SolveMode::Background => "background",
                SolveMode::Pipelined | SolveMode::Manual => "pipelined",
            }
            .into(),
            covariance: "exact".into(),
            submatrix_hops: 2,
            max_correction_landmarks: config.max_correction_landmarks,
            translation_sigma_per_sqrt_m: config.translation_sigma_per_sqrt_m,
            landmark_covariance_scale: REAL_DATA_COVARIANCE_SCALE,
            recognition: config.recognition.is_some(),
            recognition_max_hamming: recognition.max_hamming,
            recognition_gate_chi2: recognition.gate_chi2,
            recognition_max_sigma_m: recognition.max_landmark_sigma_m,
            recognition_confirm_frames: recognition.confirm_frames,
            recognition_consensus_gate_m: recognition.consensus_gate_m,
            recognition_new_landmark_after_frames: recognition.new_landmark_after_frames,
            recognition_confirm_max_sigma_m: if recognition.confirm_max_sigma_m.is_finite() {
                recognition.confirm_max_sigma_m
            } else {
                0.0
            },
            robust_map: config.robust.is_some(),
            odometry_edges: config.odometry_edges,
            odometry_sigma_per_sqrt_m: config.odometry_sigma_per_sqrt_m,
            count_window_once: config.count_window_once,
            mapping_attitude_covariance: config.mapping_attitude_covariance,
            frame_node_saturation: config.frame_node_saturation,
            node_passes_per_place: config.node_passes_per_place,
            orientation_sigma_rad_per_sqrt_s: config.orientation_sigma_rad_per_sqrt_s,
            scale_sigma_per_sqrt_s: config.scale_sigma_per_sqrt_s,
            correction_gate: ModeSwitch::Auto,
            correction_gate_chi2: DEFAULT_CORRECTION_GATE_CHI2,
            wait_accel_bias: ModeSwitch::Auto,
            wait_accel_bias_sigma_m_s2: DEFAULT_WAIT_ACCEL_BIAS_SIGMA_M_S2,
            wait_accel_bias_max_s: DEFAULT_WAIT_ACCEL_BIAS_MAX_S,
            level_time_constant_s: DEFAULT_LEVEL_TIME_CONSTANT_S,
        }
    }
}

/// The window's landmark covariances are this much too small on real
/// frames (measured by the corrections' NIS, bench/README.md).
pub const REAL_DATA_COVARIANCE_SCALE: f64 = 2.0;

/// A setting out of range: its key (under `absolute.`), value and what is
/// allowed.
#[derive(Debug, Clone, PartialEq)]
pub struct SettingError {
    /// The dotted key, e.g. `absolute.policy`.
    pub key: &'static str,
    /// Its value, as written.
    pub value: String,
    /// What is allowed.
    pub allowed: &'static str,
}

impl AbsoluteSettings {
    /// The stage's configuration, or the first setting out of range. The
    /// mode is not known here, so an `auto` correction gate is left on;
    /// a run builds its stage with [`Self::to_config_in`].
    pub fn to_config(&self) -> Result<AbsoluteConfig, SettingError> {
        let bad = |key, value: String, allowed| SettingError {
            key,
            value,
            allowed,
        };
        let positive = |key, value: f64, allowed| {
            if value.is_finite() && value > 0.0 {
                Ok(value)
            } else {
                Err(bad(key, value.to_string(), allowed))
            }
        };
        let policy: EdgePolicy = self.policy.parse().map_err(|_| {
            bad(
                "absolute.policy",
                self.policy.clone(),
                "all, frame, frame:N, mst or knn:K",
            )
        })?;
        let covariance = match self.covariance.as_str() {
            "exact" => LandmarkCovariance::Exact,
            "submatrix" => LandmarkCovariance::SubMatrix {
                hops: self.submatrix_hops,
            },
            other => {
                return Err(bad(
                    "absolute.covariance",
                    other.into(),
                    "exact or submatrix",
                ))
            }
        };
        if !(1..=1000).contains(&self.solve_every_frames) {
            return Err(bad(
                "absolute.solve_every_frames",
                self.solve_every_frames.to_string(),
                "1 to 1000",
            ));
        }
        if self.submatrix_hops > 20 {
            return Err(bad(
                "absolute.submatrix_hops",
                self.submatrix_hops.to_string(),
                "0 to 20",
            ));
        }
        if !(1..=500).contains(&self.max_correction_landmarks) {
            return Err(bad(
                "absolute.max_correction_landmarks",
                self.max_correction_landmarks.to_string(),
                "1 to 500",
            ));
        }
        let translation_sigma = positive(
            "absolute.translation_sigma_per_sqrt_m",
            self.translation_sigma_per_sqrt_m,
            "a positive number",
        )?;
        let odometry_sigma = positive(
            "absolute.odometry_sigma_per_sqrt_m",
            self.odometry_sigma_per_sqrt_m,
            "a positive number",
        )?;
        let scale = self.landmark_covariance_scale;
        if !(scale.is_finite() && (0.01..=1000.0).contains(&scale)) {
            return Err(bad(
                "absolute.landmark_covariance_scale",
                scale.to_string(),
                "0.01 to 1000",
            ));
        }
        let solve_mode = match self.solve.as_str() {
            "pipelined" => SolveMode::Pipelined,
            "background" => SolveMode::Background,
            "inline" => SolveMode::Inline,
            _ => {
                return Err(bad(
                    "absolute.solve",
                    self.solve.clone(),
                    "pipelined, background or inline",
                ))
            }
        };
        if self.recognition_max_hamming > 128 {
            return Err(bad(
                "absolute.recognition_max_hamming",
                self.recognition_max_hamming.to_string(),
                "0 to 128 (unrelated descriptors differ by about 128 bits)",
            ));
        }
        positive(
            "absolute.recognition_max_sigma_m",
            self.recognition_max_sigma_m,
            "a positive number of metres",
        )?;
        if !(1..=100).contains(&self.recognition_confirm_frames) {
            return Err(bad(
                "absolute.recognition_confirm_frames",
                self.recognition_confirm_frames.to_string(),
                "1 to 100 frames",
            ));
        }
        let consensus = self.recognition_consensus_gate_m;
        if !(consensus.is_finite() && consensus >= 0.0) {
            return Err(bad(
                "absolute.recognition_consensus_gate_m",
                consensus.to_string(),
                "a number of metres, 0 or more",
            ));
        }
        let confirm_sigma = self.recognition_confirm_max_sigma_m;
        if !(confirm_sigma.is_finite() && confirm_sigma >= 0.0) {
            return Err(bad(
                "absolute.recognition_confirm_max_sigma_m",
                confirm_sigma.to_string(),
                "a number of metres, 0 for no limit",
            ));
        }
        positive(
            "absolute.recognition_gate_chi2",
            self.recognition_gate_chi2,
            "a positive number",
        )?;
        let orientation = self.orientation_sigma_rad_per_sqrt_s;
        if !(orientation.is_finite() && (0.0..=0.1).contains(&orientation)) {
            return Err(bad(
                "absolute.orientation_sigma_rad_per_sqrt_s",
                orientation.to_string(),
                "0 (off) to 0.1 rad per sqrt(s)",
            ));
        }
        let scale_walk = self.scale_sigma_per_sqrt_s;
        if !(scale_walk.is_finite() && (0.0..=0.1).contains(&scale_walk)) {
            return Err(bad(
                "absolute.scale_sigma_per_sqrt_s",
                scale_walk.to_string(),
                "0 (off) to 0.1 per sqrt(s)",
            ));
        }
        let correction_gate = self.correction_gate_chi2;
        if !(correction_gate.is_finite() && correction_gate >= 0.0) {
            return Err(bad(
                "absolute.correction_gate_chi2",
                correction_gate.to_string(),
                "0 (off) or a positive chi-square (3 dof; 16.27 is 99.9 %)",
            ));
        }
        let wait = self.wait_accel_bias_sigma_m_s2;
        if !(wait.is_finite() && wait >= 0.0) {
            return Err(bad(
                "absolute.wait_accel_bias_sigma_m_s2",
                wait.to_string(),
                "0 (no wait) or a positive number of m/s^2",
            ));
        }
        let wait_max = self.wait_accel_bias_max_s;
        if wait_max.is_nan() || wait_max <= 0.0 {
            return Err(bad(
                "absolute.wait_accel_bias_max_s",
                wait_max.to_string(),
                "a positive number of seconds (inf: no limit; to not wait at all, set wait_accel_bias = \"off\")",
            ));
        }
        let level = self.level_time_constant_s;
        if level.is_nan() || level < 0.0 {
            return Err(bad(
                "absolute.level_time_constant_s",
                level.to_string(),
                "0 (at once) or a positive number of seconds (inf: the map's world never turns)",
            ));
        }
        Ok(AbsoluteConfig {
            policy,
            solve_every_frames: self.solve_every_frames,
            covariance,
            max_correction_landmarks: self.max_correction_landmarks,
            translation_sigma_per_sqrt_m: translation_sigma,
            landmark_covariance_scale: scale,
            solve_mode,
            recognition: self.recognition.then(|| self.recognition_config()),
            robust: self.robust_map.then(RobustWeights::default),
            odometry_edges: self.odometry_edges,
            odometry_sigma_per_sqrt_m: odometry_sigma,
            count_window_once: self.count_window_once,
            mapping_attitude_covariance: self.mapping_attitude_covariance,
            frame_node_saturation: self.frame_node_saturation,
            node_passes_per_place: self.node_passes_per_place,
            orientation_sigma_rad_per_sqrt_s: orientation,
            scale_sigma_per_sqrt_s: scale_walk,
            correction_gate_chi2: (correction_gate > 0.0
                && self.correction_gate != ModeSwitch::Off)
                .then_some(correction_gate),
            ..AbsoluteConfig::default()
        })
    }

    /// The accelerometer bias sigma the second stage waits for in `mode`,
    /// m/s^2 (0: it does not wait); see `wait_accel_bias`.
    pub fn wait_accel_bias_sigma_in(&self, mode: SensorMode) -> f64 {
        if self.wait_accel_bias.enabled_in(mode) {
            self.wait_accel_bias_sigma_m_s2
        } else {
            0.0
        }
    }

    /// [`Self::to_config`] for a run in `mode`: the settings that depend on
    /// the sensors (`correction_gate`) applied.
    pub fn to_config_in(&self, mode: SensorMode) -> Result<AbsoluteConfig, SettingError> {
        let mut config = self.to_config()?;
        if !self.correction_gate.enabled_in(mode) {
            config.correction_gate_chi2 = None;
        }
        Ok(config)
    }

    /// The recognition gates of this table, for the absolute stage and the
    /// localiser alike (checked by [`Self::to_config`]).
    fn recognition_config(&self) -> RecognitionConfig {
        RecognitionConfig {
            max_hamming: self.recognition_max_hamming,
            gate_chi2: self.recognition_gate_chi2,
            max_landmark_sigma_m: self.recognition_max_sigma_m,
            confirm_frames: self.recognition_confirm_frames,
            consensus_gate_m: self.recognition_consensus_gate_m,
            new_landmark_after_frames: self.recognition_new_landmark_after_frames,
            confirm_max_sigma_m: if self.recognition_confirm_max_sigma_m > 0.0 {
                self.recognition_confirm_max_sigma_m
            } else {
                f64::INFINITY
            },
            ..RecognitionConfig::default()
        }
    }

    /// The localiser's settings (`--load-map`): the recognition gates,
    /// increment noise and correction size of this table, checked as for
    /// the absolute stage (the first setting out of range otherwise).
    pub fn to_localise_config(&self) -> Result<LocaliseConfig, SettingError> {
        let stage = self.to_config()?;
        Ok(LocaliseConfig {
            recognition: self.recognition_config(),
            translation_sigma_per_sqrt_m: stage.translation_sigma_per_sqrt_m,
            max_correction_landmarks: stage.max_correction_landmarks,
            landmark_covariance_scale: stage.landmark_covariance_scale,
            orientation_sigma_rad_per_sqrt_s: stage.orientation_sigma_rad_per_sqrt_s,
            ..LocaliseConfig::default()
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_defaults_are_the_stages_defaults() {
        let config = AbsoluteSettings::default().to_config().expect("valid");
        let stage = AbsoluteConfig::default();
        assert_eq!(config.policy, stage.policy);
        assert_eq!(config.covariance, stage.covariance);
        assert_eq!(config.recognition, stage.recognition);
        assert_eq!(config.solve_every_frames, stage.solve_every_frames);
        assert_eq!(config.solve_mode, stage.solve_mode);
        assert_eq!(config.robust, stage.robust);
        assert_eq!(config.odometry_edges, stage.odometry_edges);
        assert_eq!(
            config.odometry_sigma_per_sqrt_m,
            stage.odometry_sigma_per_sqrt_m
        );
        assert_eq!(config.count_window_once, stage.count_window_once);
        assert_eq!(
            config.mapping_attitude_covariance,
            stage.mapping_attitude_covariance
        );
        assert_eq!(config.frame_node_saturation, stage.frame_node_saturation);
        assert_eq!(config.node_passes_per_place, stage.node_passes_per_place);
        assert_eq!(
            config.translation_sigma_per_sqrt_m,
            stage.translation_sigma_per_sqrt_m
        );
        assert_eq!(
            config.max_correction_landmarks,
            stage.max_correction_landmarks
        );
        assert_eq!(
            config.orientation_sigma_rad_per_sqrt_s,
            stage.orientation_sigma_rad_per_sqrt_s
        );
        assert_eq!(config.scale_sigma_per_sqrt_s, stage.scale_sigma_per_sqrt_s);
        // Except two on purpose: real frames' covariances are inflated,
        // and the correction gate is on where the mode wants it (the
        // stage alone, as the simulations drive it, has none).
        assert_eq!(stage.landmark_covariance_scale, 1.0);
        assert_eq!(config.landmark_covariance_scale, REAL_DATA_COVARIANCE_SCALE);
        assert_eq!(stage.correction_gate_chi2, None);
        assert_eq!(
            config.correction_gate_chi2,
            Some(DEFAULT_CORRECTION_GATE_CHI2)
        );
    }

    #[test]
    fn the_accelerometer_bias_wait_follows_the_mode() {
        use ModeSwitch::{Auto, Off, On};
        use SensorMode::{MonoInertial, StereoInertial};
        let default = AbsoluteSettings::default();
        assert_eq!(default.wait_accel_bias, Auto);
        let sigma = DEFAULT_WAIT_ACCEL_BIAS_SIGMA_M_S2;
        assert_eq!(default.wait_accel_bias_sigma_in(StereoInertial), sigma);
        assert_eq!(default.wait_accel_bias_sigma_in(MonoInertial), 0.0);
        for (setting, si, mi) in [(On, sigma, sigma), (Off, 0.0, 0.0), (Auto, sigma, 0.0)] {
            let s = AbsoluteSettings {
                wait_accel_bias: setting,
                ..Default::default()
            };
            assert_eq!(
                s.wait_accel_bias_sigma_in(StereoInertial),
                si,
                "{setting:?}"
            );
            assert_eq!(s.wait_accel_bias_sigma_in(MonoInertial), mi, "{setting:?}");
        }
        let zero = AbsoluteSettings {
            wait_accel_bias: On,
            wait_accel_bias_sigma_m_s2: 0.0,
            ..Default::default()
        };
        assert_eq!(zero.wait_accel_bias_sigma_in(StereoInertial), 0.0);
        // The wait's limit: 10 s by default, `inf` for none.
        assert_eq!(default.wait_accel_bias_max_s, DEFAULT_WAIT_ACCEL_BIAS_MAX_S);
        let unlimited: AbsoluteSettings =
            toml::from_str("wait_accel_bias_max_s = inf\n").expect("inf is a TOML float");
        assert_eq!(unlimited.wait_accel_bias_max_s, f64::INFINITY);
        assert!(unlimited.to_config().is_ok());
        // The map's level: 40 s by default, `inf` and 0 both allowed.
        assert_eq!(default.level_time_constant_s, DEFAULT_LEVEL_TIME_CONSTANT_S);
        let never: AbsoluteSettings =
            toml::from_str("level_time_constant_s = inf\n").expect("inf is a TOML float");
        assert_eq!(never.level_time_constant_s, f64::INFINITY);
        assert!(never.to_config().is_ok());
        let at_once = AbsoluteSettings {
            level_time_constant_s: 0.0,
            ..Default::default()
        };
        assert!(at_once.to_config().is_ok());
    }

    #[test]
    fn the_correction_gate_follows_the_mode() {
        let gate = |setting: ModeSwitch, chi2: f64, mode: SensorMode| {
            AbsoluteSettings {
                correction_gate: setting,
                correction_gate_chi2: chi2,
                ..Default::default()
            }
            .to_config_in(mode)
            .expect("valid")
            .correction_gate_chi2
        };
        use ModeSwitch::{Auto, Off, On};
        use SensorMode::{Mono, MonoInertial, Stereo, StereoInertial};
        let on = Some(DEFAULT_CORRECTION_GATE_CHI2);
        // By default: stereo-inertial only.
        let default = AbsoluteSettings::default();
        assert_eq!(default.correction_gate, Auto);
        for (mode, want) in [
            (StereoInertial, on),
            (MonoInertial, None),
            (Stereo, None),
            (Mono, None),
        ] {
            assert_eq!(
                default
                    .to_config_in(mode)
                    .expect("valid")
                    .correction_gate_chi2,
                want,
                "{mode:?}"
            );
        }
        for mode in [StereoInertial, MonoInertial, Stereo, Mono] {
            assert_eq!(gate(On, 9.0, mode), Some(9.0), "{mode:?}");
            assert_eq!(gate(Off, 9.0, mode), None, "{mode:?}");
            // 0 is off whatever the switch says.
            assert_eq!(gate(On, 0.0, mode), None, "{mode:?}");
        }
        // As a user writes it.
        let written: AbsoluteSettings =
            toml::from_str("correction_gate = \"on\"\ncorrection_gate_chi2 = 11.3\n")
                .expect("parses");
        assert_eq!(
            written
                .to_config_in(MonoInertial)
                .expect("valid")
                .correction_gate_chi2,
            Some(11.3)
        );
        let error = toml::from_str::<AbsoluteSettings>("correction_gate = \"sometimes\"\n")
            .expect_err("not a choice")
            .to_string();
        assert!(
            error.contains("sometimes") || error.contains("auto"),
            "{error}"
        );
    }

    #[test]
    fn each_value_reaches_the_stage() {
        // Values unlike every default and unlike one another, so that a
        // setting read into the wrong field shows.
        let settings = AbsoluteSettings {
            translation_sigma_per_sqrt_m: 0.07,
            odometry_sigma_per_sqrt_m: 0.009,
            recognition_max_sigma_m: 0.3,
            recognition_consensus_gate_m: 0.45,
            recognition_confirm_max_sigma_m: 0.11,
            recognition_gate_chi2: 9.5,
            landmark_covariance_scale: 3.5,
            orientation_sigma_rad_per_sqrt_s: 3e-4,
            scale_sigma_per_sqrt_s: 2.5e-3,
            correction_gate: ModeSwitch::On,
            correction_gate_chi2: 12.5,
            max_correction_landmarks: 17,
            solve_every_frames: 7,
            frame_node_saturation: 13,
            node_passes_per_place: 7,
            recognition_max_hamming: 41,
            recognition_confirm_frames: 4,
            recognition_new_landmark_after_frames: 6,
            count_window_once: false,
            mapping_attitude_covariance: false,
            ..Default::default()
        };
        let config = settings.to_config().expect("valid");
        assert!(!config.count_window_once);
        assert!(!config.mapping_attitude_covariance);
        assert_eq!(config.translation_sigma_per_sqrt_m, 0.07);
        assert_eq!(config.odometry_sigma_per_sqrt_m, 0.009);
        assert_eq!(config.landmark_covariance_scale, 3.5);
        assert_eq!(config.orientation_sigma_rad_per_sqrt_s, 3e-4);
        assert_eq!(config.scale_sigma_per_sqrt_s, 2.5e-3);
        assert_eq!(config.correction_gate_chi2, Some(12.5));
        assert_eq!(config.max_correction_landmarks, 17);
        assert_eq!(config.solve_every_frames, 7);
        assert_eq!(config.frame_node_saturation, 13);
        assert_eq!(config.node_passes_per_place, 7);
        let recognition = config.recognition.expect("on");
        assert_eq!(recognition.max_landmark_sigma_m, 0.3);
        assert_eq!(recognition.consensus_gate_m, 0.45);
        assert_eq!(recognition.confirm_max_sigma_m, 0.11);
        assert_eq!(recognition.gate_chi2, 9.5);
        assert_eq!(recognition.max_hamming, 41);
        assert_eq!(recognition.confirm_frames, 4);
        assert_eq!(recognition.new_landmark_after_frames, 6);
        let localise = settings.to_localise_config().expect("valid");
        assert_eq!(localise.translation_sigma_per_sqrt_m, 0.07);
        assert_eq!(localise.landmark_covariance_scale, 3.5);
        assert_eq!(localise.max_correction_landmarks, 17);
    }

    #[test]
    fn each_bad_value_names_its_key() {
        let cases: [(&str, AbsoluteSettings); 23] = [
            (
                "absolute.level_time_constant_s",
                AbsoluteSettings {
                    level_time_constant_s: -1.0,
                    ..Default::default()
                },
            ),
            (
                "absolute.level_time_constant_s",
                AbsoluteSettings {
                    level_time_constant_s: f64::NAN,
                    ..Default::default()
                },
            ),
            (
                "absolute.wait_accel_bias_max_s",
                AbsoluteSettings {
                    wait_accel_bias_max_s: 0.0,
                    ..Default::default()
                },
            ),
            (
                "absolute.wait_accel_bias_max_s",
                AbsoluteSettings {
                    wait_accel_bias_max_s: f64::NAN,
                    ..Default::default()
                },
            ),
            (
                "absolute.wait_accel_bias_sigma_m_s2",
                AbsoluteSettings {
                    wait_accel_bias_sigma_m_s2: -0.01,
                    ..Default::default()
                },
            ),
            (
                "absolute.wait_accel_bias_sigma_m_s2",
                AbsoluteSettings {
                    wait_accel_bias_sigma_m_s2: f64::NAN,
                    ..Default::default()
                },
            ),
            (
                "absolute.scale_sigma_per_sqrt_s",
                AbsoluteSettings {
                    scale_sigma_per_sqrt_s: -1e-3,
                    ..Default::default()
                },
            ),
            (
                "absolute.scale_sigma_per_sqrt_s",
                AbsoluteSettings {
                    scale_sigma_per_sqrt_s: f64::NAN,
                    ..Default::default()
                },
            ),
            (
                "absolute.correction_gate_chi2",
                AbsoluteSettings {
                    correction_gate_chi2: -1.0,
                    ..Default::default()
                },
            ),
            (
                "absolute.correction_gate_chi2",
                AbsoluteSettings {
                    correction_gate_chi2: f64::NAN,
                    ..Default::default()
                },
            ),
            (
                "absolute.orientation_sigma_rad_per_sqrt_s",
                AbsoluteSettings {
                    orientation_sigma_rad_per_sqrt_s: -1e-4,
                    ..Default::default()
                },
            ),
            (
                "absolute.orientation_sigma_rad_per_sqrt_s",
                AbsoluteSettings {
                    orientation_sigma_rad_per_sqrt_s: f64::INFINITY,
                    ..Default::default()
                },
            ),
            (
                "absolute.recognition_confirm_frames",
                AbsoluteSettings {
                    recognition_confirm_frames: 0,
                    ..Default::default()
                },
            ),
            (
                "absolute.recognition_consensus_gate_m",
                AbsoluteSettings {
                    recognition_consensus_gate_m: f64::NAN,
                    ..Default::default()
                },
            ),
            (
                "absolute.recognition_confirm_max_sigma_m",
                AbsoluteSettings {
                    recognition_confirm_max_sigma_m: -0.1,
                    ..Default::default()
                },
            ),
            (
                "absolute.recognition_max_sigma_m",
                AbsoluteSettings {
                    recognition_max_sigma_m: -1.0,
                    ..Default::default()
                },
            ),
            (
                "absolute.solve",
                AbsoluteSettings {
                    solve: "later".into(),
                    ..Default::default()
                },
            ),
            (
                "absolute.policy",
                AbsoluteSettings {
                    policy: "frame:0".into(),
                    ..Default::default()
                },
            ),
            (
                "absolute.policy",
                AbsoluteSettings {
                    policy: "knn:0".into(),
                    ..Default::default()
                },
            ),
            (
                "absolute.covariance",
                AbsoluteSettings {
                    covariance: "dense".into(),
                    ..Default::default()
                },
            ),
            (
                "absolute.solve_every_frames",
                AbsoluteSettings {
                    solve_every_frames: 0,
                    ..Default::default()
                },
            ),
            (
                "absolute.translation_sigma_per_sqrt_m",
                AbsoluteSettings {
                    translation_sigma_per_sqrt_m: f64::NAN,
                    ..Default::default()
                },
            ),
            (
                "absolute.odometry_sigma_per_sqrt_m",
                AbsoluteSettings {
                    odometry_sigma_per_sqrt_m: 0.0,
                    ..Default::default()
                },
            ),
        ];
        for (key, settings) in cases {
            assert_eq!(settings.to_config().map(|_| ()).unwrap_err().key, key);
        }
        let submatrix = AbsoluteSettings {
            covariance: "submatrix".into(),
            submatrix_hops: 3,
            recognition: false,
            ..Default::default()
        }
        .to_config()
        .expect("valid");
        assert_eq!(
            submatrix.covariance,
            LandmarkCovariance::SubMatrix { hops: 3 }
        );
        assert_eq!(submatrix.recognition, None);
    }
}
