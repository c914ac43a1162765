//! The live view (`[viewer]`): a Foxglove WebSocket server inside the
//! daemon with the recording's channels, so that an operator opens
//! Foxglove on `ws://127.0.0.1:8765` and sees the cameras with the tracked
//! landmarks over them, the trajectory, the landmarks around the robot and
//! the transform tree as the robot runs.
//!
//! The sensor and SLAM threads hand their records over the same kind of
//! bounded channel as the recorder's ([`RecordSender`]), never waiting; the
//! viewer thread turns them into Foxglove messages, images only while a
//! client is subscribed to them. The server (Foxglove's SDK, on its own
//! tokio threads) keeps a bounded backlog per client and drops the oldest
//! messages of one that does not read, so a slow or stuck client never
//! holds up the daemon. WebSocket has no latched topics: the camera
//! calibrations and the body's static transforms are sent again with every
//! status, so a client that connects late places everything within a
//! status period.

use std::sync::mpsc::{self, Receiver};
use std::sync::Arc;
use std::thread::JoinHandle;

use foxglove::messages::{
    CameraCalibration, FrameTransforms, ImageAnnotations, PointCloud, PoseInFrame, RawImage,
};
use foxglove::{Channel, Context, WebSocketServer, WebSocketServerHandle};

use super::config::ViewerConfig;
use super::recorder::{
    camera_calibration, landmark_cloud, pose_in_frame, pose_transforms, static_transforms,
    tracks_annotation, Record, RecordSender, MAP, ODOM,
};
use crate::recording::schemas::{timestamp, ImuSampleProto, PoseEstimateProto, StatusProto};
use crate::relative::RigModel;

/// Records in flight before new ones are dropped (a few seconds of
/// everything at 20 Hz stereo and 200 Hz IMU).
const CHANNEL_BOUND: usize = 2048;

/// How long the server's shutdown may wait for clients to close.
const CLOSE_WAIT: std::time::Duration = std::time::Duration::from_secs(2);

/// Messages the server keeps per client before dropping its oldest.
const CLIENT_BACKLOG: usize = 256;

/// Why the viewer could not start.
#[derive(Debug, thiserror::Error)]
pub enum ViewerError {
    /// `[viewer] listen` is not an address.
    #[error("viewer.listen: {0}")]
    Address(String),
    /// The server could not listen (the port is taken, or the address is
    /// not this machine's, or the service's sandbox forbids IP sockets).
    #[error("the viewer cannot listen on {listen}: {reason}{hint}")]
    Listen {
        /// The address.
        listen: String,
        /// The server's error.
        reason: String,
        /// What to check.
        hint: &'static str,
    },
    /// The viewer thread could not be spawned.
    #[error("cannot start the viewer thread: {0}")]
    Thread(std::io::Error),
}

/// The viewer's thread; it stops the server when every sender is dropped.
pub struct ViewerThread {
    thread: JoinHandle<()>,
    port: u16,
}

impl ViewerThread {
    /// The port the server listens on (the one asked for, or the one the
    /// system chose for port 0).
    pub fn port(&self) -> u16 {
        self.port
    }

    /// Waits for the thread, which ends once every sender is dropped.
    pub fn join(self) -> Result<(), ()> {
        self.thread.join().map_err(drop)
    }
}

/// The Foxglove channels, on a context of the daemon's own (kept alive
/// here: its channels close with it).
struct Channels {
    _context: Arc<Context>,
    imu: Channel<ImuSampleProto>,
    cams: [Channel<RawImage>; 2],
    calibrations: Vec<Channel<CameraCalibration>>,
    pose: Channel<PoseEstimateProto>,
    pose_map: Channel<PoseInFrame>,
    pose_odom: Channel<PoseInFrame>,
    tf: Channel<FrameTransforms>,
    status: Channel<StatusProto>,
    tracks: Channel<ImageAnnotations>,
    landmarks: Channel<PointCloud>,
}

impl Channels {
    fn new(context: &Arc<Context>, rig: &RigModel) -> Self {
        let channel = |topic: &str| context.channel_builder(topic);
        Self {
            _context: context.clone(),
            imu: channel("/imu0").build(),
            cams: [channel("/cam0").build(), channel("/cam1").build()],
            calibrations: (0..rig.cameras.len().min(2))
                .map(|i| channel(&format!("/cam{i}/calibration")).build())
                .collect(),
            pose: channel("/rigslam/pose").build(),
            pose_map: channel("/rigslam/pose_map").build(),
            pose_odom: channel("/rigslam/pose_odom").build(),
            tf: channel("/tf").build(),
            status: channel("/rigslam/status").build(),
            tracks: channel("/cam0/tracks").build(),
            landmarks: channel("/rigslam/landmarks").build(),
        }
    }
}

/// Starts the server on `[viewer] listen` and the thread that feeds it.
pub fn spawn_viewer(
    config: &ViewerConfig,
    rig: RigModel,
) -> Result<(RecordSender, ViewerThread), ViewerError> {
    let address = config.address().map_err(ViewerError::Address)?;
    let context = Context::new();
    let channels = Channels::new(&context, &rig);
    let server = WebSocketServer::new()
        .name("rigslamd")
        .context(&context)
        .bind(address.ip().to_string(), address.port())
        .message_backlog_size(CLIENT_BACKLOG)
        .start_blocking()
        .map_err(|e| {
            let reason = e.to_string();
            let hint = if reason.contains("in use") {
                ": another program (or another rigslamd) has this port; set [viewer] listen to a free one"
            } else if reason.contains("not permitted") || reason.contains("not supported") {
                ": under systemd, install systemd/viewer.conf as a drop-in (the unit allows no IP sockets by default)"
            } else {
                ""
            };
            ViewerError::Listen {
                listen: config.listen.clone(),
                reason,
                hint,
            }
        })?;
    let port = server.port();
    tracing::info!(
        "viewer: Foxglove WebSocket on ws://{}:{port} (open it in Foxglove: Open connection)",
        address.ip()
    );
    let (tx, rx) = mpsc::sync_channel(CHANNEL_BOUND);
    let thread = std::thread::Builder::new()
        .name("viewer".into())
        .spawn(move || view_loop(&channels, &rig, rx, server))
        .map_err(ViewerError::Thread)?;
    Ok((RecordSender::to(tx), ViewerThread { thread, port }))
}

fn view_loop(
    channels: &Channels,
    rig: &RigModel,
    rx: Receiver<Record>,
    server: WebSocketServerHandle,
) {
    send_statics(channels, rig);
    for record in rx {
        match record {
            Record::Imu(s, _) => channels.imu.log(&ImuSampleProto {
                t_ns: s.t_ns,
                gyro_rad_s: s.gyro_rad_s.to_vec(),
                accel_m_s2: s.accel_m_s2.to_vec(),
            }),
            Record::Frame(f, _) => {
                let halves = [Some(&f.left), f.right.as_ref()];
                for (channel, frame) in channels.cams.iter().zip(halves) {
                    // Copying the pixels costs; only for a subscriber.
                    if let (Some(frame), true) = (frame, channel.has_sinks()) {
                        channel.log(&raw_image(f.t_ns, frame));
                    }
                }
            }
            Record::Pose(p, _) => {
                channels.pose.log(&PoseEstimateProto::from(&*p));
                channels.pose_map.log(&pose_in_frame(
                    p.t_ns,
                    MAP,
                    p.position_world_m,
                    p.orientation_world_body_xyzw,
                ));
                channels.pose_odom.log(&pose_in_frame(
                    p.t_ns,
                    ODOM,
                    p.position_odom_m,
                    p.orientation_odom_body_xyzw,
                ));
                channels.tf.log(&pose_transforms(&p));
            }
            Record::Landmarks(l, _) => {
                if channels.tracks.has_sinks() {
                    if let Some(tracks) = tracks_annotation(rig, &l) {
                        channels.tracks.log(&tracks);
                    }
                }
                if channels.landmarks.has_sinks() {
                    channels.landmarks.log(&landmark_cloud(&l));
                }
            }
            Record::Status(s, _) => {
                channels.status.log(&s);
                send_statics(channels, rig);
            }
        }
    }
    // Every sender is gone: the daemon is stopping. Clients are closed
    // politely, but one that stopped reading cannot take the close, and
    // must not keep the daemon from exiting.
    let shutdown = server.stop();
    let (done, closed) = mpsc::channel();
    let waiter = std::thread::Builder::new()
        .name("viewer-close".into())
        .spawn(move || {
            shutdown.wait_blocking();
            let _ = done.send(());
        });
    if waiter.is_err() || closed.recv_timeout(CLOSE_WAIT).is_err() {
        tracing::warn!(
            "viewer: a client did not take the close within {} s (it stopped reading); left behind",
            CLOSE_WAIT.as_secs()
        );
    }
}

/// The camera calibrations and the body's static transforms.
fn send_statics(channels: &Channels, rig: &RigModel) {
    for (i, (channel, camera)) in channels.calibrations.iter().zip(&rig.cameras).enumerate() {
        channel.log(&camera_calibration(camera, &format!("cam{i}")));
    }
    channels.tf.log(&static_transforms(rig));
}

/// A frame as `foxglove.RawImage`, 8-bit grey.
fn raw_image(t_ns: i64, frame: &crate::sensors::Frame) -> RawImage {
    let image = &frame.image;
    RawImage {
        timestamp: Some(timestamp(t_ns)),
        frame_id: format!("cam{}", frame.camera_index),
        width: image.width(),
        height: image.height(),
        encoding: "mono8".to_owned(),
        step: image.width(),
        data: crate::recording::grey_bytes(image).into(),
    }
}
