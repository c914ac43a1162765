//! The paper's EKF variant of the relative stage as a
//! [`RelativeEstimator`] (`rigslam run --estimator ekf`): the same
//! tracker, the filter of [`super::ekf`] instead of the window. A baseline
//! to compare the window against, in the inertial modes only.
//!
//! It starts from a static start (gravity and gyro bias from the IMU at
//! rest, the images still); a start in flight needs the window's
//! visual-inertial alignment, which this baseline does not have: it stays
//! initialising until the rig rests.

use std::collections::VecDeque;

use nalgebra::{Isometry3, Translation3, Vector3};

use crate::imu::ImuBiases;
use crate::sensors::ImuSample;

use super::config::RelativeConfig;
use super::ekf::{EkfConfig, EkfFilter, InitialSigmas};
use super::estimator::{FrameInput, FrameTimings, RelativeEstimator, RigModel, SensorMode};
use super::imu_buffer::ImuBuffer;
use super::initializer::StaticStartConfig;
use super::setup::{front_end, OdometryError};
use super::tracker::Tracker;
use super::types::{KeyframeState, RelativeOutput, TrackingState};

/// Tracker + EKF.
pub struct EkfOdometry {
    rig: RigModel,
    tracker: Tracker,
    filter: EkfFilter,
    imu: ImuBuffer,
    /// Samples not yet given to the filter (it must not run past a frame
    /// it has not seen).
    pending: VecDeque<ImuSample>,
    last_output: Option<RelativeOutput>,
    previous_position: Option<Vector3<f64>>,
    gyro_bias_rad_s: Vector3<f64>,
    timings: FrameTimings,
    frames: u64,
    frames_out_of_order: u64,
    tracker_errors: u64,
    resets: u64,
    /// Last frame whose update used an observation (or at which the IMU
    /// said the rig rests); `None` before the filter starts.
    last_seen_ns: Option<i64>,
    /// How long the IMU alone may carry the filter in motion before the
    /// run is declared lost ([`RelativeConfig::imu_only_max_s`]).
    imu_only_max_ns: i64,
    /// Times the filter flew on the IMU alone for longer than that.
    imu_only_losses: u64,
}

impl EkfOdometry {
    /// The EKF baseline for `mode`, on the cameras and IMU of `rig` the
    /// mode uses; it stays initialising until the IMU says the rig rests.
    /// Fails with [`OdometryError::Setup`] for a mode without the IMU (the
    /// filter propagates with it) or when the tracker or the filter refuses
    /// the rig or the settings, [`OdometryError::Rig`] when the rig lacks a
    /// camera or the IMU, and [`OdometryError::Config`] when a setting is
    /// out of range.
    pub fn new(
        mode: SensorMode,
        rig: &RigModel,
        config: &RelativeConfig,
    ) -> Result<Self, OdometryError> {
        if !mode.uses_imu() {
            return Err(OdometryError::Setup(format!(
                "the EKF baseline propagates with the IMU: use mono-inertial or stereo-inertial, not {mode}"
            )));
        }
        let (used, tracker) = front_end(mode, rig, config)?;
        let filter = EkfFilter::new(
            EkfConfig {
                pixel_sigma: config.pixel_sigma_px,
                ..EkfConfig::default()
            },
            &used,
        )
        .map_err(|e| OdometryError::Setup(e.to_string()))?;
        let imu = used.imu.as_ref().expect("checked: inertial mode");
        let (noise, intrinsics) = (imu.noise, imu.intrinsics);
        Ok(Self {
            rig: used,
            tracker,
            filter,
            imu: ImuBuffer::new(noise, intrinsics),
            pending: VecDeque::new(),
            last_output: None,
            previous_position: None,
            gyro_bias_rad_s: Vector3::zeros(),
            timings: FrameTimings::default(),
            frames: 0,
            frames_out_of_order: 0,
            tracker_errors: 0,
            resets: 0,
            last_seen_ns: None,
            imu_only_max_ns: (config.imu_only_max_s * 1e9).round() as i64,
            imu_only_losses: 0,
        })
    }

    fn output(
        &mut self,
        state: KeyframeState,
        tracking: TrackingState,
        landmarks: bool,
    ) -> RelativeOutput {
        let landmarks = if landmarks {
            let mut body = self.filter.landmarks_in_body();
            for l in &mut body {
                l.descriptor = self.tracker.descriptor(l.id);
            }
            body
        } else {
            Vec::new()
        };
        let out =
            RelativeOutput::from_state(&state, tracking, self.previous_position, landmarks, None);
        if tracking == TrackingState::Tracking {
            self.previous_position = Some(state.T_world_body.translation.vector);
        }
        self.last_output = Some(out.clone());
        out
    }

    fn waiting(&mut self, t_ns: i64, tracking: TrackingState) -> RelativeOutput {
        let mut state = self.last_output.as_ref().map_or(
            KeyframeState {
                t_ns,
                T_world_body: Isometry3::identity(),
                velocity_world_m_s: Vector3::zeros(),
                biases: ImuBiases::default(),
            },
            |o| KeyframeState {
                t_ns,
                T_world_body: o.T_world_body,
                velocity_world_m_s: o.velocity_world_m_s,
                biases: o.biases,
            },
        );
        state.t_ns = t_ns;
        self.output(state, tracking, false)
    }

    /// A static start at `t_ns`, when the IMU says so.
    fn static_start(&self, t_ns: i64) -> Option<KeyframeState> {
        let noise = self.rig.imu.as_ref()?.noise;
        let rest = self
            .imu
            .static_start(t_ns, &noise, &StaticStartConfig::default())?;
        let position = self
            .last_output
            .as_ref()
            .map_or(Vector3::zeros(), |o| o.T_world_body.translation.vector);
        Some(KeyframeState {
            t_ns,
            T_world_body: Isometry3::from_parts(Translation3::from(position), rest.R_world_body),
            velocity_world_m_s: Vector3::zeros(),
            biases: ImuBiases {
                gyro_rad_s: rest.gyro_bias_rad_s,
                accel_m_s2: Vector3::zeros(),
            },
        })
    }
}

impl RelativeEstimator for EkfOdometry {
    fn push_imu(&mut self, sample: &ImuSample) {
        self.imu.push(sample);
        // The filter propagates with corrected samples, as the buffer keeps them.
        let corrected = self
            .rig
            .imu
            .as_ref()
            .map_or(*sample, |imu| imu.intrinsics.correct(sample));
        self.pending.push_back(corrected);
    }

    fn push_frame(&mut self, frame: &FrameInput<'_>) -> RelativeOutput {
        self.timings.clear();
        let t_ns = frame.t_ns;
        if let Some(last) = &self.last_output {
            if t_ns <= last.t_ns {
                self.frames_out_of_order += 1;
                return last.clone();
            }
        }
        self.frames += 1;
        let prediction = self.last_output.as_ref().and_then(|last| {
            self.imu.camera_rotation(
                last.t_ns,
                t_ns,
                &self.gyro_bias_rad_s,
                &self.rig.cameras[0].T_body_cam,
            )
        });
        let tracker = &mut self.tracker;
        let tracked = match self
            .timings
            .time("track", || tracker.track(frame, prediction.as_ref()))
        {
            Ok(t) => t,
            Err(e) => {
                tracing::warn!("frame at {t_ns} ns not tracked: {e}");
                self.tracker_errors += 1;
                return self.waiting(t_ns, TrackingState::Lost);
            }
        };
        if !self.filter.is_initialized() {
            // Samples before the start are of no use to the filter.
            while self.pending.front().is_some_and(|s| s.t_ns <= t_ns) {
                self.pending.pop_front();
            }
            return match self.static_start(t_ns) {
                Some(state) => {
                    self.filter.initialize(state, &InitialSigmas::default());
                    self.last_seen_ns = Some(t_ns);
                    self.gyro_bias_rad_s = state.biases.gyro_rad_s;
                    self.output(state, TrackingState::Tracking, false)
                }
                None => self.waiting(t_ns, TrackingState::Initializing),
            };
        }
        let filter = &mut self.filter;
        let pending = &mut self.pending;
        let update = self.timings.time("ekf", || {
            while pending.front().is_some_and(|s| s.t_ns <= t_ns) {
                if let Some(s) = pending.pop_front() {
                    filter.propagate(&s);
                }
            }
            filter.update(&tracked)
        });
        let state = update.state;
        let finite = state
            .T_world_body
            .translation
            .vector
            .iter()
            .all(|v| v.is_finite())
            && state.velocity_world_m_s.iter().all(|v| v.is_finite());
        if !finite {
            self.resets += 1;
            self.filter.reset();
            self.tracker.reset();
            return self.waiting(t_ns, TrackingState::Lost);
        }
        // With no landmark observed the filter integrates the IMU alone
        // and drifts without bound (mono-inertial on the real-IMU V1_02
        // rendering: 260 m). At rest that is harmless; in motion, after
        // `imu_only_max_s`, the run is lost: reset, and start again at
        // the next rest (this baseline has no start in flight).
        if update.accepted > 0 || self.static_start(t_ns).is_some() {
            self.last_seen_ns = Some(t_ns);
        }
        if self
            .last_seen_ns
            .is_some_and(|seen| t_ns - seen > self.imu_only_max_ns)
        {
            tracing::warn!(
                "EKF: no landmark observed for {:.2} s in motion; lost, waiting for a rest to restart",
                (t_ns - self.last_seen_ns.unwrap_or(t_ns)) as f64 * 1e-9
            );
            self.imu_only_losses += 1;
            self.resets += 1;
            self.last_seen_ns = None;
            self.filter.reset();
            self.tracker.reset();
            return self.waiting(t_ns, TrackingState::Lost);
        }
        self.gyro_bias_rad_s = state.biases.gyro_rad_s;
        self.imu.discard_before(t_ns - 2_000_000_000);
        self.output(state, TrackingState::Tracking, true)
    }

    fn last_timings(&self) -> &FrameTimings {
        &self.timings
    }

    fn counters(&self) -> Vec<(&'static str, u64)> {
        vec![
            ("frames", self.frames),
            ("frames_out_of_order", self.frames_out_of_order),
            ("tracker_errors", self.tracker_errors),
            ("resets", self.resets),
            ("imu_only_losses", self.imu_only_losses),
            ("imu_samples_dropped", self.imu.dropped()),
            ("ekf_samples_ignored", self.filter.ignored_samples()),
        ]
    }
}
