//! Starts the threads of the daemon, reports their health, and stops them
//! in order: sources first, then the SLAM stage once it has drained its
//! queues, then the recorder, which closes its file.

use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::Duration;

use crate::publish::{PoseMessage, QueueFill, StatusMessage, StreamPublisher};
use crate::recording::{RecordedPose, RecordingError};
use crate::relative::{RelativeOutput, RigModel};
use crate::sensors::ImuSample;
use crate::slam_pipeline::PipelineError as SlamSetupError;

use super::config::{CameraSource, DaemonConfig, ImuSource, ReplayPace};
use super::health::{Health, HealthRules, RateBase};
use super::queue::{BoundedQueue, WhenFull};
use super::recorder::{spawn_recorder, RecordSender, RecorderThread};
use super::slam_stage::{run_stage, FrameItem, PoseSink, StageInputs, StageSettings};
use super::sources::{spawn_camera, spawn_replay, spawn_yei, SourceLinks};
use super::viewer::{spawn_viewer, ViewerThread};
use super::Doorbell;

/// Why the pipeline could not start or stopped badly.
#[derive(Debug, thiserror::Error)]
pub enum PipelineError {
    #[error("cannot start the {0} thread: {1}")]
    /// A thread (named by the first field) could not be spawned.
    Thread(&'static str, std::io::Error),
    #[error(transparent)]
    /// The recorder could not create or write its MCAP file.
    Recording(#[from] RecordingError),
    #[error("the SLAM stage failed: {0}")]
    /// The SLAM stage could not build its pipeline at start: the rig does not serve the mode,
    /// a setting is out of range, or the estimator refused the rig.
    Stage(#[from] SlamSetupError),
    #[error("the {0} thread panicked")]
    /// A pipeline thread (named by the field) panicked.
    Panicked(&'static str),
}

/// The iceoryx2 publishers of `pose` and `pose_fast`.
pub struct IpcSink {
    /// Publisher of `rigslam/pose`: one message per frame.
    pub pose: StreamPublisher<PoseMessage>,
    /// Publisher of `rigslam/pose_fast`: one message per IMU sample.
    pub pose_fast: StreamPublisher<PoseMessage>,
}

impl PoseSink for IpcSink {
    fn pose(&mut self, message: &PoseMessage, _output: &RelativeOutput) -> bool {
        match self.pose.publish(message) {
            Ok(_) => true,
            Err(e) => {
                tracing::warn!("{e}");
                false
            }
        }
    }

    fn pose_fast(&mut self, message: &PoseMessage) -> bool {
        self.pose_fast.publish(message).is_ok()
    }
}

/// Records every published pose, then hands it on.
struct RecordingSink {
    inner: Box<dyn PoseSink>,
    record: RecordSender,
}

impl PoseSink for RecordingSink {
    fn pose(&mut self, m: &PoseMessage, output: &RelativeOutput) -> bool {
        self.record.pose(RecordedPose {
            t_ns: m.t_ns,
            tracking_state: m.tracking_state,
            flags: m.flags,
            position_world_m: m.position_world_m,
            orientation_world_body_xyzw: m.orientation_world_body_xyzw,
            velocity_world_m_s: m.velocity_world_m_s,
            covariance: m.covariance,
            position_odom_m: m.position_odom_m,
            orientation_odom_body_xyzw: m.orientation_odom_body_xyzw,
            translation_world_odom_m: m.translation_world_odom_m,
            rotation_world_odom_xyzw: m.rotation_world_odom_xyzw,
        });
        if !output.landmarks.is_empty() {
            self.record.landmarks(super::recorder::Landmarks {
                t_ns: m.t_ns,
                position_odom_m: m.position_odom_m,
                orientation_odom_body_xyzw: m.orientation_odom_body_xyzw,
                points_body_m: output
                    .landmarks
                    .iter()
                    .map(|l| l.position_body_m.into())
                    .collect(),
            });
        }
        self.inner.pose(m, output)
    }

    fn pose_fast(&mut self, m: &PoseMessage) -> bool {
        self.inner.pose_fast(m)
    }
}

/// What a finished pipeline did.
#[derive(Debug, Clone, Default, serde::Serialize)]
pub struct PipelineReport {
    /// Frames the sources handed to the pipeline.
    pub frames: u64,
    /// IMU samples the sources handed to the pipeline.
    pub imu_samples: u64,
    /// Frame poses published.
    pub poses: u64,
    /// IMU-rate poses published.
    pub poses_fast: u64,
    /// Every frame and sample lost, whatever the cause: queue overflows,
    /// refused by the stage, skipped by the source.
    pub frame_drops: u64,
    /// IMU samples lost, whatever the cause (see `frame_drops`).
    pub imu_drops: u64,
    /// Of those, the ones a source left out as unreadable
    /// ([`super::health::Health::frames_skipped`]).
    pub frames_skipped: u64,
    /// IMU samples a source left out as unreadable.
    pub imu_skipped: u64,
    /// Poses the publisher failed to send.
    pub pose_drops: u64,
    /// Stamps that went back, or forward by more than a second.
    pub timestamp_jumps: u64,
    /// Records the recorder dropped because its channel was full.
    pub recording_drops: u64,
    /// Records the live view dropped because its channel was full.
    pub viewer_drops: u64,
    /// The MCAP files the recorder wrote and kept (older ones may have been deleted to stay within
    /// the budget).
    pub recordings: Vec<PathBuf>,
    /// A replay stopped on an error before its end.
    pub source_failed: bool,
    /// The replayed recording was cut short (it played as far as it goes).
    pub replay_cut: bool,
    /// Chunks or records of the replayed recording skipped as damaged.
    pub replay_damaged: u64,
    /// Frame arrival to pose published, every frame of the run (within
    /// 1 %, see [`super::health::LatencyHistogram`]).
    pub latency_p50_us: f64,
    /// 99th percentile of that latency, us.
    pub latency_p99_us: f64,
    /// Largest latency, us.
    pub latency_max_us: f64,
    /// The map on disk (`[map]`): what it did, in words (None without one).
    pub map: Option<String>,
    /// Saves of the map.
    pub map_saves: u64,
}

/// The running daemon pipeline.
pub struct Pipeline {
    health: Arc<Health>,
    stop: Arc<AtomicBool>,
    frames: Arc<BoundedQueue<FrameItem>>,
    imu: Arc<BoundedQueue<ImuSample>>,
    doorbell: Arc<Doorbell>,
    reload: Arc<Mutex<Option<RigModel>>>,
    sources: Vec<JoinHandle<()>>,
    stage: Option<JoinHandle<Result<(), SlamSetupError>>>,
    recorder: Option<RecorderThread>,
    /// The recorder's end alone (its drops).
    recording: Option<RecordSender>,
    viewer: Option<ViewerThread>,
    /// The viewer's end alone (its drops).
    viewing: Option<RecordSender>,
    /// Both ends: what the threads hand records to.
    record: Option<RecordSender>,
    rules: HealthRules,
    base: RateBase,
}

impl Pipeline {
    /// Starts the recorder (when enabled), the SLAM stage and the sources.
    pub fn start(
        config: &DaemonConfig,
        rig: RigModel,
        sink: Box<dyn PoseSink>,
    ) -> Result<Pipeline, PipelineError> {
        let replay = config.replays();
        let when_full = if replay {
            WhenFull::Wait
        } else {
            WhenFull::DropOldest
        };
        let p = &config.pipeline;
        let frames = Arc::new(BoundedQueue::new("frames", p.frame_queue, when_full));
        let imu = Arc::new(BoundedQueue::new("imu", p.imu_queue, when_full));
        let doorbell = Arc::new(Doorbell::default());
        let health = Arc::new(Health::new());
        let stop = Arc::new(AtomicBool::new(false));
        let reload = Arc::new(Mutex::new(None));

        let (record, recorder) = if config.recording.enabled {
            let attachments = match config.calibration_files() {
                Ok(Some(files)) => files,
                Ok(None) => crate::recording::calibration_attachments(&rig, config.slam.mode),
                Err(e) => {
                    tracing::warn!(
                        "recording the calibration as the rig model has it (not its files): {e}"
                    );
                    crate::recording::calibration_attachments(&rig, config.slam.mode)
                }
            };
            let (tx, handle) = spawn_recorder(config.recording.clone(), attachments, rig.clone())?;
            (Some(tx), Some(handle))
        } else {
            (None, None)
        };
        // The live view: a port that cannot be had is said, and the daemon
        // goes on publishing and recording without it.
        let (viewing, viewer) = if config.viewer.enabled {
            match spawn_viewer(&config.viewer, rig.clone()) {
                Ok((tx, thread)) => (Some(tx), Some(thread)),
                Err(e) => {
                    tracing::error!("{e}; running without the live view");
                    (None, None)
                }
            }
        } else {
            (None, None)
        };
        let recording = record;
        let record = match (recording.clone(), viewing.clone()) {
            (Some(r), Some(v)) => Some(r.and(v)),
            (r, v) => r.or(v),
        };
        let sink: Box<dyn PoseSink> = match &record {
            Some(r) => Box::new(RecordingSink {
                inner: sink,
                record: r.clone(),
            }),
            None => sink,
        };
        let mode = config.slam.mode;
        let settings = StageSettings {
            mode,
            estimator: config.slam.estimator,
            slam: config.slam.settings(),
            map: config.map.clone(),
            imu_wait: if replay {
                // The replay hands the sample past a frame over before
                // the frame: never wait on a finished replay's IMU.
                Duration::from_millis(50)
            } else {
                Duration::from_millis(30)
            },
            imu_stall_ns: (p.imu_stall_s * 1e9) as i64,
            max_pending_imu: p.imu_queue,
            live: !(replay
                && config
                    .replay
                    .as_ref()
                    .is_some_and(|r| r.pace == ReplayPace::AsFastAsPossible)),
        };
        let inputs = StageInputs {
            frames: frames.clone(),
            imu: imu.clone(),
            doorbell: doorbell.clone(),
            health: health.clone(),
            reload: reload.clone(),
        };
        let frame_shift_ns = rig.frame_shift_ns();
        // The estimator is built on the stage's thread (it is not Send);
        // a setup error comes back through the join.
        let stage = std::thread::Builder::new()
            .name("slam".into())
            .spawn(move || run_stage(settings, rig, inputs, sink))
            .map_err(|e| PipelineError::Thread("slam", e))?;

        let links = SourceLinks {
            frames: frames.clone(),
            imu: imu.clone(),
            doorbell: doorbell.clone(),
            health: health.clone(),
            stop: stop.clone(),
            record: record.clone(),
        };
        let mut sources = Vec::new();
        if replay {
            let r = config
                .replay
                .clone()
                .expect("check() refuses a replay source without [replay]");
            sources.push(
                spawn_replay(r, mode, frame_shift_ns, links)
                    .map_err(|e| PipelineError::Thread("replay", e))?,
            );
        } else {
            if config.camera.source != CameraSource::Replay {
                sources.push(
                    spawn_camera(config.camera.clone(), links.clone())
                        .map_err(|e| PipelineError::Thread("camera", e))?,
                );
            }
            if mode.uses_imu() && config.imu.source == ImuSource::Yei {
                sources.push(
                    spawn_yei(config.imu.clone(), links)
                        .map_err(|e| PipelineError::Thread("imu", e))?,
                );
            } else {
                imu.close();
            }
        }
        Ok(Pipeline {
            health,
            stop,
            frames,
            imu,
            doorbell,
            reload,
            sources,
            stage: Some(stage),
            recorder,
            recording,
            viewer,
            viewing,
            record,
            rules: HealthRules {
                camera_stall_ns: (p.camera_stall_s * 1e9) as i64,
                imu_stall_ns: (p.imu_stall_s * 1e9) as i64,
                stuck_ns: (p.stuck_after_s * 1e9) as i64,
                uses_imu: mode.uses_imu(),
            },
            base: RateBase::default(),
        })
    }

    /// The counters and health state the threads share, for a supervisor to read while the pipeline
    /// runs.
    pub fn health(&self) -> &Arc<Health> {
        &self.health
    }

    /// The status now (rates since the previous call).
    pub fn status(&mut self) -> StatusMessage {
        let queues = [
            QueueFill::new(
                "frames",
                self.frames.len() as u32,
                self.frames.capacity() as u32,
            ),
            QueueFill::new("imu", self.imu.len() as u32, self.imu.capacity() as u32),
        ];
        let status = self.health.status(
            &self.rules,
            &mut self.base,
            &queues,
            (self.frames.dropped(), self.imu.dropped()),
        );
        if let Some(record) = &self.record {
            record.status(crate::recording::schemas::StatusProto {
                t_ns: status.t_ns,
                sensor_health: status.sensor_health,
                health: super::health::health_words(status.sensor_health),
                camera_rate_hz: status.camera_rate_hz,
                imu_rate_hz: status.imu_rate_hz,
                pose_rate_hz: status.pose_rate_hz,
                camera_drops: status.camera_drops,
                imu_drops: status.imu_drops,
                pose_drops: status.pose_drops,
                latency_p50_us: status.latency_p50_us,
                latency_p99_us: status.latency_p99_us,
            });
        }
        status
    }

    /// The port the live view listens on, when it runs.
    pub fn viewer_port(&self) -> Option<u16> {
        self.viewer.as_ref().map(ViewerThread::port)
    }

    /// Whether the SLAM stage has stopped making progress.
    pub fn stuck(&self) -> bool {
        self.health.stage_stuck(
            crate::sensors::yei::device::host_monotonic_ns(),
            self.rules.stuck_ns,
        )
    }

    /// The SLAM stage has ended (a replay played out, or a setup error).
    pub fn finished(&self) -> bool {
        self.stage.as_ref().map_or(true, |s| s.is_finished())
    }

    /// Whether a replay stopped on an error before its end (the file
    /// could not be read on).
    pub fn source_failed(&self) -> bool {
        self.health.source_failed.load(Ordering::Relaxed)
    }

    /// Rebuilds the relative stage with a new rig at its next loop.
    pub fn reload(&self, rig: RigModel) {
        *self.reload.lock().unwrap_or_else(|e| e.into_inner()) = Some(rig);
        self.doorbell.ring();
    }

    /// Stops the sources, lets the stage drain, closes the recording.
    pub fn stop(mut self) -> Result<PipelineReport, PipelineError> {
        self.stop.store(true, Ordering::Relaxed);
        for s in self.sources.drain(..) {
            s.join().map_err(|_| PipelineError::Panicked("source"))?;
        }
        self.frames.close();
        self.imu.close();
        self.doorbell.ring();
        let stage = self
            .stage
            .take()
            .expect("stop consumes the pipeline, so the stage is joined once")
            .join()
            .map_err(|_| PipelineError::Panicked("slam"))?;
        let recording_drops = self.recording.as_ref().map_or(0, |r| r.dropped());
        let viewer_drops = self.viewing.as_ref().map_or(0, |r| r.dropped());
        self.record = None;
        self.recording = None;
        self.viewing = None;
        if let Some(viewer) = self.viewer.take() {
            viewer
                .join()
                .map_err(|()| PipelineError::Panicked("viewer"))?;
        }
        let recordings = match self.recorder.take() {
            Some(r) => r
                .join()
                .map_err(|_| PipelineError::Panicked("recorder"))??,
            None => vec![],
        };
        stage?;
        let h = &self.health;
        let latencies = h.run_latencies();
        Ok(PipelineReport {
            frames: h.frames_in.load(Ordering::Relaxed),
            imu_samples: h.imu_in.load(Ordering::Relaxed),
            poses: h.poses_out.load(Ordering::Relaxed),
            poses_fast: h.pose_fast_out.load(Ordering::Relaxed),
            frame_drops: self.frames.dropped() + h.input_drops().0,
            imu_drops: self.imu.dropped() + h.input_drops().1,
            frames_skipped: h.frames_skipped.load(Ordering::Relaxed),
            imu_skipped: h.imu_skipped.load(Ordering::Relaxed),
            pose_drops: h.pose_drops.load(Ordering::Relaxed),
            timestamp_jumps: h.timestamp_jumps.load(Ordering::Relaxed),
            recording_drops,
            viewer_drops,
            recordings,
            source_failed: h.source_failed.load(Ordering::Relaxed),
            replay_cut: h.replay_cut.load(Ordering::Relaxed),
            replay_damaged: h.replay_damaged.load(Ordering::Relaxed),
            map: h.map_words(),
            map_saves: h.map_saves.load(Ordering::Relaxed),
            latency_p50_us: latencies.quantile_us(0.5).unwrap_or(0.0),
            latency_p99_us: latencies.quantile_us(0.99).unwrap_or(0.0),
            latency_max_us: latencies.max_us(),
        })
    }
}
