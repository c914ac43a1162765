//! Recording the raw streams and the poses to MCAP, on a thread of its
//! own: the sensor and SLAM threads hand records over a bounded channel
//! without waiting (a full channel drops the record and counts it), the
//! recorder writes `rigslam-<n>.mcap` files, starts a new one at
//! `rotate_mib`, deletes the oldest to stay within `budget_mib`, and
//! closes the current file properly when the daemon stops (its summary
//! and index written, so it opens in Foxglove and replays).
//!
//! Each file has the raw streams (`/imu0`, `/cam0`, `/cam1`), the pose
//! estimates with covariance and both frames (`/rigslam/pose`), the poses
//! for Foxglove's 3D panel (`/rigslam/pose_map`, `/rigslam/pose_odom`),
//! the transform tree map -> odom -> body -> cam0/cam1/imu (`/tf`), each
//! camera's calibration (`/cam0/calibration`, `/cam1/calibration`), the
//! tracked landmarks as points over camera 0's image (`/cam0/tracks`) and
//! as a point cloud in the odometry frame (`/rigslam/landmarks`), and the
//! daemon's status (`/rigslam/status`). With `format = "ros2"` it has the
//! ROS 2 topics [`crate::recording::ros2`] lists instead (no status, no
//! tracks or landmark cloud).

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::mpsc::{self, Receiver, SyncSender, TrySendError};
use std::sync::Arc;
use std::thread::JoinHandle;

use foxglove::messages::{
    packed_element_field, points_annotation, CameraCalibration, Color, FrameTransform,
    FrameTransforms, ImageAnnotations, PackedElementField, Point2, PointCloud, PointsAnnotation,
    PoseInFrame,
};
use nalgebra::Isometry3;

use crate::recording::schemas::{timestamp, StatusProto};
use crate::recording::{ros2, ChannelId, Format, McapRecorder, RecordedPose, RecordingError};
use crate::relative::RigModel;
use crate::sensors::yei::device::host_monotonic_ns;
use crate::sensors::ImuSample;

use super::config::RecordingConfig;
use super::slam_stage::FrameItem;

/// Records in flight before new ones are dropped.
const CHANNEL_BOUND: usize = 4096;

/// What the sensor and SLAM threads hand to the recorder (and the viewer),
/// with the host time it was handed over.
#[derive(Clone)]
pub(super) enum Record {
    Imu(ImuSample, i64),
    Frame(FrameItem, i64),
    Pose(Box<RecordedPose>, i64),
    Landmarks(Box<Landmarks>, i64),
    Status(StatusProto, i64),
}

/// The landmarks the relative stage tracked in a frame, with the frame's
/// odometry-frame pose: the tracks on the image and the map around the
/// robot, as the viewer and the recording show them.
#[derive(Clone, Debug)]
pub struct Landmarks {
    /// The frame's stamp, ns.
    pub t_ns: i64,
    /// Body position in the odometry frame, m.
    pub position_odom_m: [f64; 3],
    /// `R_odom_body`, x, y, z, w.
    pub orientation_odom_body_xyzw: [f64; 4],
    /// Each landmark in the body frame, m.
    pub points_body_m: Vec<[f64; 3]>,
}

/// One consumer's bounded channel and its drop count.
#[derive(Clone)]
struct Out {
    tx: SyncSender<Record>,
    dropped: Arc<AtomicU64>,
}

/// The producers' end; cheap to clone. It hands every record to each
/// consumer it was joined with ([`Self::and`]) without waiting.
#[derive(Clone)]
pub struct RecordSender {
    outs: Vec<Out>,
}

impl RecordSender {
    /// A sender to one consumer's channel.
    pub(super) fn to(tx: SyncSender<Record>) -> Self {
        Self {
            outs: vec![Out {
                tx,
                dropped: Arc::new(AtomicU64::new(0)),
            }],
        }
    }

    /// A sender that hands every record to this one's consumers and `other`'s.
    pub fn and(mut self, other: RecordSender) -> RecordSender {
        self.outs.extend(other.outs);
        self
    }

    fn send(&self, record: Record) {
        let Some((last, rest)) = self.outs.split_last() else {
            return;
        };
        for out in rest {
            out.offer(record.clone());
        }
        last.offer(record);
    }

    /// Hands an IMU sample over, stamped with the host's `CLOCK_MONOTONIC` now; dropped
    /// and counted if a channel is full.
    pub fn imu(&self, sample: &ImuSample) {
        self.send(Record::Imu(*sample, host_monotonic_ns()));
    }

    /// Hands a frame over, stamped with the host's `CLOCK_MONOTONIC` now; dropped and
    /// counted if a channel is full.
    pub fn frame(&self, frame: &FrameItem) {
        self.send(Record::Frame(frame.clone(), host_monotonic_ns()));
    }

    /// Hands a published pose over, stamped with the host's `CLOCK_MONOTONIC` now;
    /// dropped and counted if a channel is full.
    pub fn pose(&self, pose: RecordedPose) {
        self.send(Record::Pose(Box::new(pose), host_monotonic_ns()));
    }

    /// Hands a frame's tracked landmarks over; dropped and counted if a
    /// channel is full.
    pub fn landmarks(&self, landmarks: Landmarks) {
        self.send(Record::Landmarks(Box::new(landmarks), host_monotonic_ns()));
    }

    /// Hands a status over; dropped and counted if a channel is full.
    pub fn status(&self, status: StatusProto) {
        self.send(Record::Status(status, host_monotonic_ns()));
    }

    /// Records dropped because a consumer was behind (all of this
    /// sender's consumers together).
    pub fn dropped(&self) -> u64 {
        self.outs
            .iter()
            .map(|o| o.dropped.load(Ordering::Relaxed))
            .sum()
    }
}

impl Out {
    fn offer(&self, record: Record) {
        if let Err(TrySendError::Full(_)) = self.tx.try_send(record) {
            self.dropped.fetch_add(1, Ordering::Relaxed);
        }
    }
}

/// The recorder's thread; it returns the files it closed.
pub type RecorderThread = JoinHandle<Result<Vec<PathBuf>, RecordingError>>;

/// Starts the recorder thread. It ends, closing its file, when every
/// [`RecordSender`] is dropped.
///
/// `attachments` (name, bytes) go into every file, so that each one
/// replays on its own (the rig's calibration); `rig` gives each file its
/// camera calibrations and the body's static transforms.
pub fn spawn_recorder(
    config: RecordingConfig,
    attachments: crate::recording::Attachments,
    rig: RigModel,
) -> Result<(RecordSender, RecorderThread), RecordingError> {
    std::fs::create_dir_all(&config.dir).map_err(|source| RecordingError::Create {
        path: config.dir.clone(),
        source,
    })?;
    let (tx, rx) = mpsc::sync_channel(CHANNEL_BOUND);
    let handle = std::thread::Builder::new()
        .name("recorder".into())
        .spawn(move || record_loop(&config, &attachments, &rig, rx))
        .map_err(|source| RecordingError::Create {
            path: PathBuf::from("(recorder thread)"),
            source,
        })?;
    Ok((RecordSender::to(tx), handle))
}

/// The file being written and its channels.
struct OpenFile {
    recorder: McapRecorder,
    channels: Channels,
    rig: RigModel,
}

/// The channels of a file, by format.
enum Channels {
    Foxglove(FoxgloveChannels),
    Ros2(Ros2Channels),
}

struct FoxgloveChannels {
    imu: ChannelId,
    cams: [ChannelId; 2],
    pose: ChannelId,
    pose_map: ChannelId,
    pose_odom: ChannelId,
    tf: ChannelId,
    status: ChannelId,
    tracks: ChannelId,
    landmarks: ChannelId,
}

struct Ros2Channels {
    imu: ChannelId,
    cams: [ChannelId; 2],
    /// Each camera's `CameraInfo` channel and message, written with every
    /// image under its stamp (what `image_proc` and other nodes pair).
    infos: Vec<(ChannelId, ros2::messages::CameraInfo)>,
    odom: ChannelId,
    tf: ChannelId,
    /// Per-sample variances of the IMU's rate and specific force.
    imu_variances: Option<[f64; 2]>,
}

/// Frame ids of the transform tree (REP-105).
pub(super) const MAP: &str = ros2::convert::MAP;
pub(super) const ODOM: &str = ros2::convert::ODOM;
pub(super) const BODY: &str = ros2::convert::BODY;

fn open_file(
    config: &RecordingConfig,
    attachments: &[(String, Vec<u8>)],
    rig: &RigModel,
) -> Result<OpenFile, RecordingError> {
    let dir = &config.dir;
    // Wall-clock-free name: the next free number, so files sort by age.
    let next = list_recordings(dir)
        .iter()
        .filter_map(|(p, _)| number_of(p))
        .max()
        .map_or(0, |n| n + 1);
    let path = dir.join(format!("rigslam-{next:06}.mcap"));
    let mut recorder = McapRecorder::create_with(
        &path,
        config.compression,
        config.compression_level,
        crate::recording::ClockMapping::now(),
        config.format,
    )?;
    for (name, data) in attachments {
        recorder.attach(name, "application/x-yaml", data)?;
    }
    let channels = match config.format {
        Format::Foxglove => Channels::Foxglove(foxglove_channels(&mut recorder, rig)?),
        Format::Ros2 => Channels::Ros2(ros2_channels(&mut recorder, rig)?),
    };
    tracing::info!("recording to {}", path.display());
    Ok(OpenFile {
        recorder,
        channels,
        rig: rig.clone(),
    })
}

/// Registers the protobuf channels and writes what does not change while
/// the file is written: the cameras' calibrations and where the sensors
/// sit on the body, stamped 0 so that they hold from the start.
fn foxglove_channels(
    recorder: &mut McapRecorder,
    rig: &RigModel,
) -> Result<FoxgloveChannels, RecordingError> {
    let none = Default::default();
    let imu = recorder.add_imu_channel("/imu0", &none)?;
    let cams = [
        recorder.add_image_channel("/cam0")?,
        recorder.add_image_channel("/cam1")?,
    ];
    let pose = recorder.add_pose_channel("/rigslam/pose")?;
    let pose_map = recorder.add_channel::<PoseInFrame>("/rigslam/pose_map", &none)?;
    let pose_odom = recorder.add_channel::<PoseInFrame>("/rigslam/pose_odom", &none)?;
    let tf = recorder.add_channel::<FrameTransforms>("/tf", &none)?;
    let status = recorder.add_channel::<StatusProto>("/rigslam/status", &none)?;
    let tracks = recorder.add_channel::<ImageAnnotations>("/cam0/tracks", &none)?;
    let landmarks = recorder.add_channel::<PointCloud>("/rigslam/landmarks", &none)?;
    // What does not change while the file is written: the cameras'
    // calibrations and where the sensors sit on the body, stamped 0 so
    // that they hold from the start.
    let now = host_monotonic_ns();
    for (i, camera) in rig.cameras.iter().enumerate().take(2) {
        let name = format!("cam{i}");
        let channel =
            recorder.add_channel::<CameraCalibration>(&format!("/{name}/calibration"), &none)?;
        recorder.write(channel, &camera_calibration(camera, &name), now)?;
    }
    recorder.write(tf, &static_transforms(rig), now)?;
    Ok(FoxgloveChannels {
        imu,
        cams,
        pose,
        pose_map,
        pose_odom,
        tf,
        status,
        tracks,
        landmarks,
    })
}

/// Registers the ROS 2 channels and writes, once per file, the body's
/// static transforms (`/tf_static`, offered transient-local); the cameras'
/// `CameraInfo` goes with every image.
fn ros2_channels(
    recorder: &mut McapRecorder,
    rig: &RigModel,
) -> Result<Ros2Channels, RecordingError> {
    use ros2::messages::{CameraInfo, Image, Imu, Odometry, TfMessage};
    let stream = ros2::channel_metadata(false);
    let latched = ros2::channel_metadata(true);
    let imu = recorder.add_channel::<Imu>(ros2::IMU_TOPIC, &stream)?;
    let cams = [
        recorder.add_channel::<Image>(&ros2::image_topic(0), &stream)?,
        recorder.add_channel::<Image>(&ros2::image_topic(1), &stream)?,
    ];
    let odom = recorder.add_channel::<Odometry>(ros2::ODOM_TOPIC, &stream)?;
    let tf = recorder.add_channel::<TfMessage>(ros2::TF_TOPIC, &stream)?;
    let tf_static = recorder.add_channel::<TfMessage>(ros2::TF_STATIC_TOPIC, &latched)?;
    let now = host_monotonic_ns();
    let mut infos = Vec::new();
    for (i, camera) in rig.cameras.iter().enumerate().take(2) {
        let channel = recorder.add_channel::<CameraInfo>(&ros2::camera_info_topic(i), &stream)?;
        infos.push((
            channel,
            ros2::convert::camera_info(camera, &format!("cam{i}")),
        ));
    }
    recorder.write(tf_static, &ros2::convert::static_transforms(rig), now)?;
    Ok(Ros2Channels {
        imu,
        cams,
        infos,
        odom,
        tf,
        imu_variances: rig.imu.as_ref().map(ros2::convert::imu_variances),
    })
}

/// A camera's calibration as Foxglove's image and 3D panels read it
/// (ROS's `CameraInfo` conventions: `plumb_bob` is OpenCV's k1, k2, p1,
/// p2, k3; `kannala_brandt` the equidistant k1..k4).
pub(super) fn camera_calibration(
    camera: &crate::rig::CameraCalibration,
    frame_id: &str,
) -> CameraCalibration {
    let model = &camera.model;
    let [fx, fy, cx, cy] = model.pinhole();
    let distortion_model = match model {
        crate::camera::CameraModel::PinholeRadtan(_) => "plumb_bob",
        crate::camera::CameraModel::PinholeEquidistant(_) => "kannala_brandt",
    };
    CameraCalibration {
        timestamp: Some(timestamp(0)),
        frame_id: frame_id.to_owned(),
        width: model.width(),
        height: model.height(),
        distortion_model: distortion_model.to_owned(),
        d: model.distortion_coefficients(),
        k: vec![fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0],
        r: vec![1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
        p: vec![fx, 0.0, cx, 0.0, 0.0, fy, cy, 0.0, 0.0, 0.0, 1.0, 0.0],
    }
}

/// `parent <- child` (maps child coordinates into the parent frame).
fn transform(t_ns: i64, parent: &str, child: &str, pose: &Isometry3<f64>) -> FrameTransform {
    let t = pose.translation.vector;
    let q = pose.rotation.coords;
    FrameTransform {
        timestamp: Some(timestamp(t_ns)),
        parent_frame_id: parent.to_owned(),
        child_frame_id: child.to_owned(),
        translation: Some(foxglove::messages::Vector3 {
            x: t.x,
            y: t.y,
            z: t.z,
        }),
        rotation: Some(foxglove::messages::Quaternion {
            x: q.x,
            y: q.y,
            z: q.z,
            w: q.w,
        }),
    }
}

/// A pose for the 3D panel.
pub(super) fn pose_in_frame(t_ns: i64, frame: &str, p: [f64; 3], q: [f64; 4]) -> PoseInFrame {
    PoseInFrame {
        timestamp: Some(timestamp(t_ns)),
        frame_id: frame.to_owned(),
        pose: Some(foxglove::messages::Pose {
            position: Some(foxglove::messages::Vector3 {
                x: p[0],
                y: p[1],
                z: p[2],
            }),
            orientation: Some(foxglove::messages::Quaternion {
                x: q[0],
                y: q[1],
                z: q[2],
                w: q[3],
            }),
        }),
    }
}

/// The tracked landmarks projected into camera 0 as points over its image
/// (`/cam0/tracks`); `None` without a camera.
pub(super) fn tracks_annotation(rig: &RigModel, l: &Landmarks) -> Option<ImageAnnotations> {
    let camera = rig.cameras.first()?;
    let cam_from_body = camera.T_body_cam.inverse();
    let points = l
        .points_body_m
        .iter()
        .filter_map(|p| {
            let p_cam = cam_from_body * nalgebra::Point3::new(p[0], p[1], p[2]);
            camera.model.project(&p_cam.coords)
        })
        .map(|px| Point2 { x: px.x, y: px.y })
        .collect();
    Some(ImageAnnotations {
        timestamp: Some(timestamp(l.t_ns)),
        circles: vec![],
        points: vec![PointsAnnotation {
            timestamp: Some(timestamp(l.t_ns)),
            r#type: points_annotation::Type::Points as i32,
            points,
            outline_color: Some(Color {
                r: 0.1,
                g: 1.0,
                b: 0.2,
                a: 1.0,
            }),
            outline_colors: vec![],
            fill_color: None,
            thickness: 4.0,
            metadata: vec![],
        }],
        texts: vec![],
        metadata: vec![],
    })
}

/// The tracked landmarks in the odometry frame (`/rigslam/landmarks`):
/// the map around the robot, x, y, z as 32-bit floats.
pub(super) fn landmark_cloud(l: &Landmarks) -> PointCloud {
    let odom_from_body = isometry(l.position_odom_m, l.orientation_odom_body_xyzw);
    let mut data = Vec::with_capacity(l.points_body_m.len() * 12);
    for p in &l.points_body_m {
        let q = odom_from_body * nalgebra::Point3::new(p[0], p[1], p[2]);
        for v in [q.x, q.y, q.z] {
            data.extend_from_slice(&(v as f32).to_le_bytes());
        }
    }
    let field = |name: &str, offset| PackedElementField {
        name: name.to_owned(),
        offset,
        r#type: packed_element_field::NumericType::Float32 as i32,
    };
    PointCloud {
        timestamp: Some(timestamp(l.t_ns)),
        frame_id: ODOM.to_owned(),
        pose: Some(foxglove::messages::Pose {
            position: Some(foxglove::messages::Vector3 {
                x: 0.0,
                y: 0.0,
                z: 0.0,
            }),
            orientation: Some(foxglove::messages::Quaternion {
                x: 0.0,
                y: 0.0,
                z: 0.0,
                w: 1.0,
            }),
        }),
        point_stride: 12,
        fields: vec![field("x", 0), field("y", 4), field("z", 8)],
        data: data.into(),
    }
}

/// Where the sensors sit on the body, stamped 0 (they hold from the start).
pub(super) fn static_transforms(rig: &RigModel) -> FrameTransforms {
    let mut transforms: Vec<FrameTransform> = rig
        .cameras
        .iter()
        .take(2)
        .enumerate()
        .map(|(i, camera)| transform(0, BODY, &format!("cam{i}"), &camera.T_body_cam))
        .collect();
    if let Some(imu) = &rig.imu {
        transforms.push(transform(0, BODY, "imu", &imu.T_body_imu));
    }
    FrameTransforms { transforms }
}

/// map -> odom and odom -> body at a pose.
pub(super) fn pose_transforms(p: &RecordedPose) -> FrameTransforms {
    FrameTransforms {
        transforms: vec![
            transform(
                p.t_ns,
                MAP,
                ODOM,
                &isometry(p.translation_world_odom_m, p.rotation_world_odom_xyzw),
            ),
            transform(
                p.t_ns,
                ODOM,
                BODY,
                &isometry(p.position_odom_m, p.orientation_odom_body_xyzw),
            ),
        ],
    }
}

/// An isometry from a translation and an x, y, z, w quaternion.
fn isometry(t: [f64; 3], q: [f64; 4]) -> Isometry3<f64> {
    Isometry3::from_parts(
        nalgebra::Translation3::new(t[0], t[1], t[2]),
        nalgebra::UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(
            q[3], q[0], q[1], q[2],
        )),
    )
}

impl OpenFile {
    fn write_imu(&mut self, s: &ImuSample, receipt: i64) -> Result<(), RecordingError> {
        let r = &mut self.recorder;
        match &self.channels {
            Channels::Foxglove(c) => r.write_imu(c.imu, s, receipt),
            Channels::Ros2(c) => r.write(c.imu, &ros2::convert::imu(s, c.imu_variances), receipt),
        }
    }

    fn write_frame(&mut self, f: &FrameItem, receipt: i64) -> Result<(), RecordingError> {
        let r = &mut self.recorder;
        let sides = std::iter::once(&f.left).chain(&f.right).enumerate();
        for (i, side) in sides {
            let name = if i == 0 { "cam0" } else { "cam1" };
            match &self.channels {
                Channels::Foxglove(c) => {
                    r.write_image(c.cams[i], f.t_ns, &side.image, name, receipt)?
                }
                Channels::Ros2(c) => {
                    r.write(
                        c.cams[i],
                        &ros2::convert::image(f.t_ns, &side.image, name),
                        receipt,
                    )?;
                    if let Some((channel, info)) = c.infos.get(i) {
                        let mut info = info.clone();
                        info.header = ros2::messages::Header::new(f.t_ns, name);
                        r.write(*channel, &info, receipt)?;
                    }
                }
            }
        }
        Ok(())
    }

    fn write_status(&mut self, s: &StatusProto, receipt: i64) -> Result<(), RecordingError> {
        match &self.channels {
            Channels::Foxglove(c) => self.recorder.write(c.status, s, receipt),
            // No ROS message carries it; the ROS 2 files leave it out.
            Channels::Ros2(_) => Ok(()),
        }
    }

    fn write_landmarks(&mut self, l: &Landmarks, receipt: i64) -> Result<(), RecordingError> {
        let Channels::Foxglove(c) = &self.channels else {
            // The ROS 2 files keep to the messages ROS tools replay.
            return Ok(());
        };
        if let Some(tracks) = tracks_annotation(&self.rig, l) {
            self.recorder.write(c.tracks, &tracks, receipt)?;
        }
        self.recorder
            .write(c.landmarks, &landmark_cloud(l), receipt)
    }

    fn write_pose(&mut self, p: &RecordedPose, receipt: i64) -> Result<(), RecordingError> {
        let r = &mut self.recorder;
        let c = match &self.channels {
            Channels::Foxglove(c) => c,
            Channels::Ros2(c) => {
                r.write(c.odom, &ros2::convert::odometry(p), receipt)?;
                return r.write(c.tf, &ros2::convert::pose_transforms(p), receipt);
            }
        };
        r.write_pose(c.pose, p, receipt)?;
        r.write(
            c.pose_map,
            &pose_in_frame(
                p.t_ns,
                MAP,
                p.position_world_m,
                p.orientation_world_body_xyzw,
            ),
            receipt,
        )?;
        r.write(
            c.pose_odom,
            &pose_in_frame(
                p.t_ns,
                ODOM,
                p.position_odom_m,
                p.orientation_odom_body_xyzw,
            ),
            receipt,
        )?;
        r.write(c.tf, &pose_transforms(p), receipt)
    }
}

fn number_of(path: &Path) -> Option<u64> {
    path.file_stem()?
        .to_str()?
        .strip_prefix("rigslam-")?
        .parse()
        .ok()
}

/// The recordings in `dir`, oldest first, with their sizes.
pub fn list_recordings(dir: &Path) -> Vec<(PathBuf, u64)> {
    let mut files: Vec<(PathBuf, u64)> = std::fs::read_dir(dir)
        .into_iter()
        .flatten()
        .flatten()
        .map(|e| e.path())
        .filter(|p| number_of(p).is_some() && p.extension().is_some_and(|x| x == "mcap"))
        .map(|p| {
            let size = std::fs::metadata(&p).map_or(0, |m| m.len());
            (p, size)
        })
        .collect();
    files.sort_by_key(|(p, _)| number_of(p));
    files
}

/// Deletes the oldest closed recordings until the total (with `reserve`
/// bytes for the file being written) fits `budget` bytes.
fn enforce_budget(dir: &Path, budget: u64, reserve: u64) {
    let files = list_recordings(dir);
    let mut total: u64 = files.iter().map(|(_, s)| s).sum::<u64>() + reserve;
    for (path, size) in files {
        if total <= budget {
            break;
        }
        match std::fs::remove_file(&path) {
            Ok(()) => {
                tracing::info!("recording budget: deleted {}", path.display());
                total = total.saturating_sub(size);
            }
            Err(e) => tracing::warn!("recording budget: cannot delete {}: {e}", path.display()),
        }
    }
}

fn record_loop(
    config: &RecordingConfig,
    attachments: &[(String, Vec<u8>)],
    rig: &RigModel,
    rx: Receiver<Record>,
) -> Result<Vec<PathBuf>, RecordingError> {
    let rotate = config.rotate_mib.max(1) << 20;
    let budget = config.budget_mib << 20;
    let open = || open_file(config, attachments, rig);
    enforce_budget(&config.dir, budget, rotate);
    let mut file = open()?;
    let mut closed = Vec::new();
    for record in rx {
        match record {
            Record::Imu(s, receipt) => file.write_imu(&s, receipt)?,
            Record::Frame(f, receipt) => file.write_frame(&f, receipt)?,
            Record::Pose(p, receipt) => file.write_pose(&p, receipt)?,
            Record::Status(s, receipt) => file.write_status(&s, receipt)?,
            Record::Landmarks(l, receipt) => file.write_landmarks(&l, receipt)?,
        }
        if file.recorder.bytes() >= rotate {
            let next = open()?;
            let done = std::mem::replace(&mut file, next);
            closed.push(done.recorder.finish()?);
            enforce_budget(&config.dir, budget, rotate);
        }
    }
    closed.push(file.recorder.finish()?);
    Ok(closed)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sensors::Frame;

    fn frame(t_ns: i64) -> FrameItem {
        // 512x512 noise: ~350 KB of base64 JSON per image, as a camera's.
        let pixels: Vec<u8> = (0..512u32 * 512)
            .map(|i| (i.wrapping_mul(2_654_435_761) >> 24) as u8)
            .collect();
        let image = rigslam_drivers::Image::mono8(512, 512, pixels).expect("image");
        let f = |camera_index| Frame {
            t_ns,
            seq: 0,
            camera_index,
            image: image.clone(),
        };
        FrameItem {
            t_ns,
            left: f(0),
            right: Some(f(1)),
            arrival_ns: 0,
        }
    }

    #[test]
    fn tracks_land_where_the_camera_sees_them_and_the_cloud_is_in_the_odometry_frame() {
        use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
        let model = crate::camera::CameraModel::from_kalibr(
            640,
            480,
            "radtan",
            &[400.0, 400.0, 320.0, 240.0],
            &[0.0; 4],
        )
        .expect("camera");
        // The camera looks along the body's x axis (camera z = body x),
        // 0.1 m ahead of the body origin.
        let body_from_cam = Isometry3::from_parts(
            Translation3::new(0.1, 0.0, 0.0),
            UnitQuaternion::from_matrix(&nalgebra::Matrix3::new(
                0.0, 0.0, 1.0, -1.0, 0.0, 0.0, 0.0, -1.0, 0.0,
            )),
        );
        let rig = RigModel {
            cameras: vec![crate::rig::CameraCalibration {
                model,
                T_body_cam: body_from_cam,
                rate_hz: 20.0,
                time_shift_cam_imu_s: 0.0,
            }],
            imu: None,
        };
        let quarter =
            UnitQuaternion::from_axis_angle(&Vector3::z_axis(), std::f64::consts::FRAC_PI_2);
        let q = quarter.coords;
        let l = Landmarks {
            t_ns: 7,
            position_odom_m: [1.0, 0.0, 0.0],
            orientation_odom_body_xyzw: [q.x, q.y, q.z, q.w],
            // On the optical axis 2.1 m ahead; 0.5 m left of it at 2.1 m
            // (camera x = -body y); behind the camera.
            points_body_m: vec![[2.1, 0.0, 0.0], [2.1, -0.5, 0.0], [-1.0, 0.0, 0.0]],
        };
        let tracks = tracks_annotation(&rig, &l).expect("a camera");
        let points = &tracks.points[0].points;
        assert_eq!(points.len(), 2, "the point behind the camera is left out");
        assert!((points[0].x - 320.0).abs() < 1e-9 && (points[0].y - 240.0).abs() < 1e-9);
        // x = cx + fx * 0.5 / 2.0
        assert!((points[1].x - 420.0).abs() < 1e-9, "{:?}", points[1]);
        // The cloud: odom = (1, 0, 0) + Rz(90 deg) * body.
        let cloud = landmark_cloud(&l);
        assert_eq!(cloud.frame_id, "odom");
        assert_eq!(cloud.data.len(), 3 * 12);
        let f = |i: usize| f32::from_le_bytes(cloud.data[4 * i..4 * i + 4].try_into().expect("4"));
        let first = [f(0), f(1), f(2)];
        let expected = [1.0f32, 2.1, 0.0];
        for k in 0..3 {
            assert!((first[k] - expected[k]).abs() < 1e-6, "{first:?}");
        }
    }

    #[test]
    fn files_rotate_stay_within_the_budget_and_close_complete() {
        let dir = tempfile::tempdir().expect("tempdir");
        let config = RecordingConfig {
            enabled: true,
            dir: dir.path().to_path_buf(),
            budget_mib: 3,
            rotate_mib: 1,
            compression: crate::recording::Compression::None,
            compression_level: 0,
            format: Format::Foxglove,
        };
        let rig = RigModel {
            cameras: vec![],
            imu: None,
        };
        let (tx, handle) = spawn_recorder(config, vec![], rig).expect("recorder");
        for i in 0..12 {
            tx.frame(&frame(i * 50_000_000));
            tx.imu(&ImuSample {
                t_ns: i * 50_000_000,
                gyro_rad_s: [0.0; 3],
                accel_m_s2: [0.0, 0.0, 9.81],
            });
        }
        assert_eq!(tx.dropped(), 0);
        drop(tx);
        let written = handle.join().expect("recorder thread").expect("recording");
        // 12 frames of ~0.7 MB in 1 MiB files.
        assert!(written.len() >= 6, "{written:?}");
        let left = list_recordings(dir.path());
        let total: u64 = left.iter().map(|(_, s)| s).sum();
        // The budget counts a whole file ahead for the one being written;
        // a file ends at the first message past rotate_mib.
        assert!(total <= (3 + 1) << 20, "{total} bytes in {left:?}");
        assert!(left.len() < written.len(), "nothing was deleted: {left:?}");
        // The newest survive, each complete (its summary written).
        let newest: Vec<&PathBuf> = written.iter().rev().take(left.len()).collect();
        for (path, _) in &left {
            assert!(newest.contains(&path), "{path:?} is not among the newest");
            crate::recording::channel_counts(path).expect("a complete file");
        }
    }
}
