//! The relative stage's face to the pipeline: IMU samples and frames go in
//! in time order, one [`RelativeOutput`] per frame comes out. The window
//! estimator (the paper's method) and the EKF baseline both implement
//! [`RelativeEstimator`], so `rigslam run`, the daemon and the tests drive
//! either through the same calls.

use std::fmt;
use std::str::FromStr;

pub use crate::rig::RigModel;
use crate::sensors::{Image, ImuSample};

use super::types::RelativeOutput;

/// Which modes a behaviour is on in (`[relative] track_first_patch`,
/// `[absolute] correction_gate`, `wait_accel_bias`); each key says why its
/// `auto` is what it is. A settings file may also give `true` (`on`) or
/// `false` (`off`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum ModeSwitch {
    /// Stereo-inertial only.
    Auto,
    /// Every mode it applies to.
    On,
    /// No mode.
    Off,
}

impl ModeSwitch {
    /// Whether it is on in `mode`.
    pub fn enabled_in(self, mode: SensorMode) -> bool {
        match self {
            ModeSwitch::Off => false,
            ModeSwitch::On => true,
            ModeSwitch::Auto => mode == SensorMode::StereoInertial,
        }
    }
}

impl<'de> serde::Deserialize<'de> for ModeSwitch {
    fn deserialize<D: serde::Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        struct Visitor;
        impl serde::de::Visitor<'_> for Visitor {
            type Value = ModeSwitch;
            fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
                f.write_str("\"auto\", \"on\" or \"off\" (or true / false)")
            }
            fn visit_bool<E: serde::de::Error>(self, on: bool) -> Result<ModeSwitch, E> {
                Ok(if on { ModeSwitch::On } else { ModeSwitch::Off })
            }
            fn visit_str<E: serde::de::Error>(self, v: &str) -> Result<ModeSwitch, E> {
                match v {
                    "auto" => Ok(ModeSwitch::Auto),
                    "on" => Ok(ModeSwitch::On),
                    "off" => Ok(ModeSwitch::Off),
                    other => Err(E::unknown_variant(other, &["auto", "on", "off"])),
                }
            }
        }
        deserializer.deserialize_any(Visitor)
    }
}

/// Which sensors the stage uses (`rigslam run --mode`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
#[serde(rename_all = "kebab-case")]
pub enum SensorMode {
    /// One camera, no IMU: the paper's configuration 1; scale arbitrary
    /// (the first translation has unit length), evaluate with sim3.
    Mono,
    /// One camera and the IMU: the paper's configuration 2.
    MonoInertial,
    /// Both cameras of a stereo rig: metric depth from the first frame.
    Stereo,
    /// Both cameras and the IMU.
    StereoInertial,
}

impl SensorMode {
    /// Every mode, from `mono` to `stereo-inertial`.
    pub const ALL: [SensorMode; 4] = [
        SensorMode::Mono,
        SensorMode::MonoInertial,
        SensorMode::Stereo,
        SensorMode::StereoInertial,
    ];

    /// Whether the mode needs the IMU.
    pub fn uses_imu(self) -> bool {
        matches!(self, SensorMode::MonoInertial | SensorMode::StereoInertial)
    }

    /// Whether the mode needs a second (right) camera.
    pub fn uses_stereo(self) -> bool {
        matches!(self, SensorMode::Stereo | SensorMode::StereoInertial)
    }

    /// Lower-case name as the command line and settings files spell it (`mono`, `mono-inertial`,
    /// `stereo`, `stereo-inertial`).
    pub fn name(self) -> &'static str {
        match self {
            SensorMode::Mono => "mono",
            SensorMode::MonoInertial => "mono-inertial",
            SensorMode::Stereo => "stereo",
            SensorMode::StereoInertial => "stereo-inertial",
        }
    }
}

impl fmt::Display for SensorMode {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for SensorMode {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        SensorMode::ALL
            .into_iter()
            .find(|m| m.name() == s)
            .ok_or_else(|| {
                format!(
                    "unknown mode {s:?}: expected mono, mono-inertial, stereo or stereo-inertial"
                )
            })
    }
}

/// Why a rig cannot serve a mode.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum RigError {
    #[error("mode {mode} needs {needed} camera(s), the rig has {have}")]
    /// The mode needs more cameras than the rig has.
    TooFewCameras {
        /// The mode asked for.
        mode: SensorMode,
        /// Cameras it needs.
        needed: usize,
        /// Cameras the rig has.
        have: usize,
    },
    #[error("mode {mode} needs an IMU, the rig has none (imu0/ missing?)")]
    /// The mode needs an IMU and the rig has none.
    NoImu {
        /// The mode asked for.
        mode: SensorMode,
    },
}

impl RigModel {
    /// Checks that the rig has what `mode` needs.
    pub fn check(&self, mode: SensorMode) -> Result<(), RigError> {
        let needed = if mode.uses_stereo() { 2 } else { 1 };
        if self.cameras.len() < needed {
            return Err(RigError::TooFewCameras {
                mode,
                needed,
                have: self.cameras.len(),
            });
        }
        if mode.uses_imu() && self.imu.is_none() {
            return Err(RigError::NoImu { mode });
        }
        Ok(())
    }
}

/// One camera exposure of the rig: the left image and, in the stereo
/// modes, the right one taken at the same instant.
#[derive(Debug, Clone, Copy)]
pub struct FrameInput<'a> {
    /// Exposure stamp, ns (the clock the IMU samples are stamped in).
    pub t_ns: i64,
    /// The left (cam0) image, or the only one.
    pub left: &'a Image,
    /// The right (cam1) image taken at the same instant (stereo modes).
    pub right: Option<&'a Image>,
}

/// Milliseconds spent per named stage on the last frame (`"track"`,
/// `"imu"`, `"window"`, ...). `rigslam run --report` aggregates them.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct FrameTimings {
    /// Stage name and its time on the last frame, ms, in the order they ran.
    pub stages_ms: Vec<(&'static str, f64)>,
}

impl FrameTimings {
    /// Forgets the last frame's timings.
    pub fn clear(&mut self) {
        self.stages_ms.clear();
    }

    /// Adds `ms` to stage `name` (created on first use).
    pub fn add(&mut self, name: &'static str, ms: f64) {
        match self.stages_ms.iter_mut().find(|(n, _)| *n == name) {
            Some((_, v)) => *v += ms,
            None => self.stages_ms.push((name, ms)),
        }
    }

    /// Runs `f`, adding its wall time to stage `name`.
    pub fn time<T>(&mut self, name: &'static str, f: impl FnOnce() -> T) -> T {
        let start = std::time::Instant::now();
        let out = f();
        self.add(name, start.elapsed().as_secs_f64() * 1e3);
        out
    }
}

/// Stage 1 as the pipeline drives it. Samples and frames arrive in time
/// order as the sensors deliver them; an IMU sample stamped after a frame
/// may arrive before that frame. Bad input (non-finite samples, stamps
/// going back, black frames) is dropped and counted, never a panic.
pub trait RelativeEstimator {
    /// One IMU sample (ignored in the vision-only modes).
    fn push_imu(&mut self, sample: &ImuSample);

    /// One frame; the answer for it. Call after pushing the IMU samples up
    /// to (and preferably one past) the frame's stamp.
    fn push_frame(&mut self, frame: &FrameInput<'_>) -> RelativeOutput;

    /// Work the last frame left for after its answer went out (the
    /// windowed estimator optimises a keyframe's window after giving the
    /// keyframe's pose as tracked), and the frame's answer as it then
    /// stands; None when nothing was left. The next `push_frame` does the
    /// work first if the caller has not, so the estimates never depend on
    /// when (or whether) this is called; a caller that publishes poses
    /// calls it after publishing, to keep the work off the frame's latency.
    fn finish_frame(&mut self) -> Option<RelativeOutput> {
        None
    }

    /// Whether the last frame left work for [`Self::finish_frame`].
    fn work_pending(&self) -> bool {
        false
    }

    /// Where the time of the last `push_frame` (and `finish_frame`) went.
    fn last_timings(&self) -> &FrameTimings;

    /// Counters for the run report (dropped samples, lost events, ...).
    fn counters(&self) -> Vec<(&'static str, u64)>;

    /// The multipliers on the declared IMU noise the estimator weighs the
    /// IMU with now (None: no IMU, or weighted as declared, unadapted).
    fn imu_noise_scale(&self) -> Option<crate::relative::window::NoiseScale> {
        None
    }

    /// True while an estimated noise scale sits at a bound of its range
    /// that says the declared noise is wrong (not the pixel scale's floor).
    fn noise_at_bound(&self) -> bool {
        false
    }

    /// The camera-IMU calibration as refined online (None: not refined).
    fn camera_imu(&self) -> Option<crate::relative::window::CameraImuEstimate> {
        None
    }

    /// Gravity in the world of the outputs as the estimator holds it now,
    /// m/s^2 (None: no IMU, or not estimated yet).
    fn gravity_world_m_s2(&self) -> Option<nalgebra::Vector3<f64>> {
        None
    }

    /// True while the estimate still rests on a start in motion: after
    /// the visual-inertial alignment of a moving start (or a resume in
    /// motion), until every keyframe it placed has left the window. Those
    /// first windows carry the alignment's velocity, bias and gravity
    /// errors; the absolute stage takes no landmarks from them.
    fn settling(&self) -> bool {
        false
    }

    /// The turn that took the last output (of `push_frame` or
    /// `finish_frame`) from the estimator's own world, which its first
    /// keyframe fixes and which never turns, into the level world it was
    /// given in ([`super::level`]): `T_world_body` is this times the
    /// estimator's own pose. Identity where nothing levels the outputs.
    fn levelling(&self) -> nalgebra::Isometry3<f64> {
        nalgebra::Isometry3::identity()
    }

    /// How well the accelerometer bias is known now: the largest one-sigma
    /// of the newest solved keyframe's, m/s^2, once the window runs with
    /// the IMU (infinite until its first solve; None without the IMU, at
    /// rest, where the pose is held, and while a moving start runs
    /// vision-only before its alignment). Until it is small,
    /// gravity and the bias are not told apart and the attitude may be off
    /// by about sigma / g.
    fn accel_bias_sigma_m_s2(&self) -> Option<f64> {
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn modes_round_trip_through_their_names() {
        for m in SensorMode::ALL {
            assert_eq!(m.name().parse::<SensorMode>(), Ok(m));
        }
        let err = "stereo_inertial".parse::<SensorMode>().unwrap_err();
        assert!(err.contains("stereo-inertial"), "{err}");
    }

    #[test]
    fn mode_switches_read_as_a_settings_file_writes_them() {
        #[derive(serde::Deserialize)]
        struct Table {
            switch: ModeSwitch,
        }
        let read = |text: &str| toml::from_str::<Table>(text).map(|t| t.switch);
        assert_eq!(read("switch = \"auto\"").ok(), Some(ModeSwitch::Auto));
        assert_eq!(read("switch = \"on\"").ok(), Some(ModeSwitch::On));
        assert_eq!(read("switch = \"off\"").ok(), Some(ModeSwitch::Off));
        // A key that was a boolean keeps its meaning.
        assert_eq!(read("switch = true").ok(), Some(ModeSwitch::On));
        assert_eq!(read("switch = false").ok(), Some(ModeSwitch::Off));
        for wrong in ["switch = \"sometimes\"", "switch = 3"] {
            let error = read(wrong).expect_err(wrong).to_string();
            assert!(error.contains("auto"), "{wrong}: {error}");
        }
    }

    #[test]
    fn rig_check_names_what_is_missing() {
        let rig = RigModel {
            cameras: vec![],
            imu: None,
        };
        assert_eq!(
            rig.check(SensorMode::Stereo),
            Err(RigError::TooFewCameras {
                mode: SensorMode::Stereo,
                needed: 2,
                have: 0
            })
        );
    }

    #[test]
    fn timings_add_up_per_stage() {
        let mut t = FrameTimings::default();
        t.add("track", 1.0);
        t.add("window", 2.0);
        t.add("track", 0.5);
        assert_eq!(t.stages_ms, vec![("track", 1.5), ("window", 2.0)]);
    }
}
