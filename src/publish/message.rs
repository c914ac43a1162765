//! The `#[repr(C)]` messages that go out over shared memory, and their
//! conversions from the estimator's types.
//!
//! The layouts are a contract with other processes, including C and C++
//! ones: `include/rigslam/pose_message.h` declares the same structs and
//! asserts every size and offset, and a test reads those numbers out of the
//! header and compares them with these types. Change a field here and the
//! header (and [`POSE_LAYOUT_VERSION`] / [`STATUS_LAYOUT_VERSION`]) with it.
//!
//! Every field is naturally aligned and the structs have no padding, so
//! the layout is the same under any C compiler on a 64-bit little-endian
//! Linux target.

#![allow(non_snake_case)]

use iceoryx2::prelude::ZeroCopySend;
use nalgebra::{Isometry3, Matrix6, Quaternion, Translation3, UnitQuaternion, Vector3};

use crate::imu::NavState;
use crate::relative::types::{RelativeOutput, TrackingState};

/// Layout version of [`PoseMessage`]; bump it on any change of the layout.
pub const POSE_LAYOUT_VERSION: u32 = 2;
/// Layout version of [`StatusMessage`]; bump it on any change of the layout.
pub const STATUS_LAYOUT_VERSION: u32 = 3;

/// [`PoseMessage::tracking_state`]: collecting frames, no metric pose yet.
pub const TRACKING_STATE_INITIALIZING: u32 = 0;
/// [`PoseMessage::tracking_state`]: the pose is metric and tracked.
pub const TRACKING_STATE_TRACKING: u32 = 1;
/// [`PoseMessage::tracking_state`]: tracking failed; do not use the pose.
pub const TRACKING_STATE_LOST: u32 = 2;

/// [`PoseMessage::flags`]: `covariance` holds an estimate. When clear the
/// covariance is unknown and every entry is NaN.
pub const POSE_FLAG_COVARIANCE_VALID: u32 = 1 << 0;
/// [`PoseMessage::flags`]: `velocity_world_m_s` holds an estimate.
pub const POSE_FLAG_VELOCITY_VALID: u32 = 1 << 1;
/// [`PoseMessage::flags`]: the pose was propagated with the IMU from the
/// last visual-inertial estimate (the `pose_fast` stream), not estimated
/// from a frame.
pub const POSE_FLAG_IMU_PROPAGATED: u32 = 1 << 2;
/// [`PoseMessage::flags`]: the absolute stage runs: the world pose is its
/// map-frame pose, which a correction may move, and the odometry fields
/// hold the relative stage's smooth pose and the `world <- odom`
/// transform between the two. When clear the two poses are the same and
/// the transform is the identity.
pub const POSE_FLAG_MAP_CORRECTED: u32 = 1 << 3;

/// One pose of the body (IMU) frame in the world frame, with the same
/// pose in the odometry frame.
///
/// Frames as REP-105 names them: the world frame is `map` (gravity-aligned,
/// where the absolute stage places the robot; a correction may move the
/// pose in it), the odometry frame is `odom` (the relative stage's: the
/// pose in it is continuous, corrections never move it), and
/// `T_world_odom` joins them (`T_world_body = T_world_odom T_odom_body`).
/// Without the absolute stage the two frames are one.
///
/// Byte layout (size 520, alignment 8, no padding):
///
/// | offset | field | type |
/// |---|---|---|
/// | 0 | `layout_version` | u32 |
/// | 4 | `tracking_state` | u32 |
/// | 8 | `flags` | u32 |
/// | 12 | `reserved` | u32 |
/// | 16 | `t_ns` | i64 |
/// | 24 | `published_t_ns` | i64 |
/// | 32 | `sequence` | u64 |
/// | 40 | `position_world_m` | f64\[3\] |
/// | 64 | `orientation_world_body_xyzw` | f64\[4\] |
/// | 96 | `velocity_world_m_s` | f64\[3\] |
/// | 120 | `covariance` | f64\[36\] |
/// | 408 | `position_odom_m` | f64\[3\] |
/// | 432 | `orientation_odom_body_xyzw` | f64\[4\] |
/// | 464 | `translation_world_odom_m` | f64\[3\] |
/// | 488 | `rotation_world_odom_xyzw` | f64\[4\] |
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("rigslam_pose_message_v2")]
#[repr(C)]
pub struct PoseMessage {
    /// [`POSE_LAYOUT_VERSION`] of the writer; a reader rejects others.
    pub layout_version: u32,
    /// [`TRACKING_STATE_INITIALIZING`], [`TRACKING_STATE_TRACKING`] or
    /// [`TRACKING_STATE_LOST`].
    pub tracking_state: u32,
    /// `POSE_FLAG_*` bits.
    pub flags: u32,
    /// Zero; keeps `t_ns` 8-aligned and leaves room for a later field.
    pub reserved: u32,
    /// Time the pose refers to, ns: host `CLOCK_MONOTONIC` live (the
    /// frame's or IMU sample's time mapped onto the host clock), dataset
    /// time on replay.
    pub t_ns: i64,
    /// Host `CLOCK_MONOTONIC` when the publisher sent this sample, ns; set by
    /// the publisher. `now - published_t_ns` is the transport latency.
    pub published_t_ns: i64,
    /// Per-service counter set by the publisher: 0 for the first sample,
    /// +1 for each next one, so a gap means the reader missed samples.
    pub sequence: u64,
    /// Position of the body origin in the world frame, m (x, y, z).
    pub position_world_m: [f64; 3],
    /// Orientation `R_world_body` (maps body coordinates into the world
    /// frame) as a unit Hamilton quaternion in the order **x, y, z, w**.
    pub orientation_world_body_xyzw: [f64; 4],
    /// Velocity of the body origin in the world frame, m/s (x, y, z).
    pub velocity_world_m_s: [f64; 3],
    /// 6x6 pose covariance, **row-major**, over the perturbation
    /// `(dx, dy, dz, drx, dry, drz)`: position error in the world frame (m)
    /// then rotation error as a rotation vector about the world axes (rad),
    /// `R_true = Exp([drx dry drz]) R_est` (fixed-axis, as in ROS
    /// `PoseWithCovariance`). Entry (row i, column j) is `covariance[6 i + j]`;
    /// units m^2, m rad and rad^2. All NaN when
    /// [`POSE_FLAG_COVARIANCE_VALID`] is clear.
    pub covariance: [f64; 36],
    /// Position of the body origin in the odometry frame, m.
    pub position_odom_m: [f64; 3],
    /// Orientation `R_odom_body`, Hamilton, order x, y, z, w.
    pub orientation_odom_body_xyzw: [f64; 4],
    /// Translation of `T_world_odom` (the odometry frame's origin in the
    /// world frame), m.
    pub translation_world_odom_m: [f64; 3],
    /// Rotation of `T_world_odom`, Hamilton, order x, y, z, w.
    pub rotation_world_odom_xyzw: [f64; 4],
}

/// The queue in front of one pipeline stage, as [`StatusMessage`] reports it.
///
/// Byte layout (size 24, alignment 4): `name` u8\[16\] at 0 (NUL-padded
/// ASCII, not necessarily NUL-terminated when 16 long), `len` u32 at 16,
/// `capacity` u32 at 20.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ZeroCopySend)]
#[type_name("rigslam_queue_fill_v1")]
#[repr(C)]
pub struct QueueFill {
    /// Queue name, NUL-padded ASCII (not NUL-terminated when all 16 bytes are used).
    pub name: [u8; 16],
    /// Items waiting when the status was taken.
    pub len: u32,
    /// Bound of the queue.
    pub capacity: u32,
}

/// [`StatusMessage::sensor_health`]: camera frames arrive at their rate.
pub const HEALTH_CAMERA_STREAMING: u32 = 1 << 0;
/// [`StatusMessage::sensor_health`]: IMU samples arrive at their rate.
pub const HEALTH_IMU_STREAMING: u32 = 1 << 1;
/// [`StatusMessage::sensor_health`]: the IMU is gone and being reconnected.
pub const HEALTH_IMU_RECONNECTING: u32 = 1 << 2;
/// [`StatusMessage::sensor_health`]: no camera frame for longer than the
/// configured stall time.
pub const HEALTH_CAMERA_STALLED: u32 = 1 << 3;
/// [`StatusMessage::sensor_health`]: a sensor's timestamps jumped since the
/// previous status.
pub const HEALTH_TIMESTAMP_JUMP: u32 = 1 << 4;
/// [`StatusMessage::sensor_health`]: a pipeline stage made no progress
/// within its watchdog time.
pub const HEALTH_STAGE_STUCK: u32 = 1 << 5;
/// [`StatusMessage::sensor_health`]: the estimated noise sits at a bound
/// of its range: the noise in the rig's sensor file is far from what the
/// sensors show (a unit mistake, or a much noisier IMU than declared).
/// Features more precise than a tenth of the declared pixel sigma (the
/// pixel scale at its floor) do not raise it.
pub const HEALTH_NOISE_AT_BOUND: u32 = 1 << 6;
/// [`StatusMessage::sensor_health`]: the camera-IMU calibration the
/// estimator refines online has wandered far from the calibration file
/// (the camera moved on its mount, or the file belongs to another rig):
/// recalibrate.
pub const HEALTH_CALIBRATION_DRIFT: u32 = 1 << 7;

/// How many queues [`StatusMessage::queues`] has room for.
pub const STATUS_MAX_QUEUES: usize = 8;

/// The daemon's health, published on `rigslam/status` about once a second.
///
/// Byte layout (size 344, alignment 8, no padding):
///
/// | offset | field | type |
/// |---|---|---|
/// | 0 | `layout_version` | u32 |
/// | 4 | `sensor_health` | u32 |
/// | 8 | `queue_count` | u32 |
/// | 12 | `reserved` | u32 |
/// | 16 | `t_ns` | i64 |
/// | 24 | `published_t_ns` | i64 |
/// | 32 | `sequence` | u64 |
/// | 40 | `camera_rate_hz` | f64 |
/// | 48 | `imu_rate_hz` | f64 |
/// | 56 | `pose_rate_hz` | f64 |
/// | 64 | `camera_drops` | u64 |
/// | 72 | `imu_drops` | u64 |
/// | 80 | `pose_drops` | u64 |
/// | 88 | `latency_p50_us` | f64 |
/// | 96 | `latency_p99_us` | f64 |
/// | 104 | `queues` | QueueFill\[8\] |
/// | 296 | `imu_noise_scale_gyro` | f64 |
/// | 304 | `imu_noise_scale_accel` | f64 |
/// | 312 | `pixel_noise_scale` | f64 |
/// | 320 | `camera_imu_rotation_deg` | f64 |
/// | 328 | `camera_imu_translation_m` | f64 |
/// | 336 | `camera_imu_time_offset_s` | f64 |
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("rigslam_status_message_v3")]
#[repr(C)]
pub struct StatusMessage {
    /// [`STATUS_LAYOUT_VERSION`] of the writer.
    pub layout_version: u32,
    /// `HEALTH_*` bits.
    pub sensor_health: u32,
    /// How many entries of `queues` are in use (at most [`STATUS_MAX_QUEUES`]).
    pub queue_count: u32,
    /// Zero.
    pub reserved: u32,
    /// Host `CLOCK_MONOTONIC` when the status was taken, ns.
    pub t_ns: i64,
    /// Host `CLOCK_MONOTONIC` when the publisher sent it, ns (set by the
    /// publisher).
    pub published_t_ns: i64,
    /// Per-service counter set by the publisher.
    pub sequence: u64,
    /// Camera frames per second over the last status period; when the
    /// camera began during it, over the time since its first frame. NaN
    /// while that first frame is the only one: not known yet (0 means
    /// none came).
    pub camera_rate_hz: f64,
    /// IMU samples per second, as `camera_rate_hz`.
    pub imu_rate_hz: f64,
    /// Poses published on `rigslam/pose` per second, as `camera_rate_hz`.
    pub pose_rate_hz: f64,
    /// Camera frames dropped since start (full queue or driver gap).
    pub camera_drops: u64,
    /// IMU samples dropped since start.
    pub imu_drops: u64,
    /// Poses that could not be published since start.
    pub pose_drops: u64,
    /// Frame arrival to pose published, median over the last period, us.
    pub latency_p50_us: f64,
    /// Frame arrival to pose published, 99th percentile, us.
    pub latency_p99_us: f64,
    /// Fill of the queue in front of each stage, first `queue_count` used.
    pub queues: [QueueFill; STATUS_MAX_QUEUES],
    /// The multipliers on the declared gyroscope and accelerometer noise
    /// densities and on the declared pixel sigma that the estimator
    /// weighs the measurements with, estimated online from its own
    /// residuals (1: as declared). NaN when there is no estimate (no IMU,
    /// or before the SLAM stage ran).
    pub imu_noise_scale_gyro: f64,
    /// Multiplier on the declared accelerometer noise density (see `imu_noise_scale_gyro`).
    pub imu_noise_scale_accel: f64,
    /// Multiplier on the declared pixel sigma (see `imu_noise_scale_gyro`).
    pub pixel_noise_scale: f64,
    /// How far the online estimate of camera 0's pose in the IMU frame
    /// is from the calibration file (rotation angle, deg; translation,
    /// m), and the frames' time offset it found beyond the file's time
    /// shift (s; positive: the images were taken after their stamps).
    /// NaN when the calibration is not refined (off, or no IMU).
    pub camera_imu_rotation_deg: f64,
    /// Distance of the online estimate of camera 0's position in the IMU
    /// frame from the file's, m (see `camera_imu_rotation_deg`).
    pub camera_imu_translation_m: f64,
    /// Time offset of the frames beyond the file's time shift, s (see `camera_imu_rotation_deg`).
    pub camera_imu_time_offset_s: f64,
}

/// A message of `size_of::<T>()` bytes as they lie in shared memory;
/// `None` for any other length. Only for the `#[repr(C)]` messages of this
/// module, whose fields are integers, floats and byte arrays: every bit
/// pattern is a valid value, so any bytes a publisher wrote can be read.
fn from_wire_bytes<T: Copy>(bytes: &[u8]) -> Option<T> {
    (bytes.len() == std::mem::size_of::<T>()).then(|| {
        // SAFETY: the length is checked, the read is unaligned, and every
        // bit pattern is a valid T (see above).
        unsafe { std::ptr::read_unaligned(bytes.as_ptr().cast::<T>()) }
    })
}

impl StatusMessage {
    /// The message in `bytes` as a reader finds it in shared memory;
    /// `None` when `bytes` is not [`std::mem::size_of::<StatusMessage>()`]
    /// long. Nothing is validated: see [`crate::publish::SampleCheck`].
    pub fn from_bytes(bytes: &[u8]) -> Option<Self> {
        from_wire_bytes(bytes)
    }

    /// The message's bytes exactly as they lie in shared memory.
    pub fn as_bytes(&self) -> &[u8] {
        // SAFETY: StatusMessage is repr(C), Copy, and has no padding (the
        // layout test checks that the field sizes add up to its size), so
        // every byte is initialised.
        unsafe {
            std::slice::from_raw_parts(
                (self as *const Self).cast::<u8>(),
                std::mem::size_of::<Self>(),
            )
        }
    }
}

impl QueueFill {
    /// An entry with `name` cut to 16 bytes (NUL-padded).
    pub fn new(name: &str, len: u32, capacity: u32) -> Self {
        let mut bytes = [0u8; 16];
        let n = name.len().min(bytes.len());
        bytes[..n].copy_from_slice(&name.as_bytes()[..n]);
        Self {
            name: bytes,
            len,
            capacity,
        }
    }

    /// The name without its NUL padding (lossy for non-UTF-8 bytes).
    pub fn name_str(&self) -> String {
        let end = self
            .name
            .iter()
            .position(|&b| b == 0)
            .unwrap_or(self.name.len());
        String::from_utf8_lossy(&self.name[..end]).into_owned()
    }
}

impl Default for QueueFill {
    fn default() -> Self {
        Self::new("", 0, 0)
    }
}

impl Default for StatusMessage {
    fn default() -> Self {
        Self {
            layout_version: STATUS_LAYOUT_VERSION,
            sensor_health: 0,
            queue_count: 0,
            reserved: 0,
            t_ns: 0,
            published_t_ns: 0,
            sequence: 0,
            camera_rate_hz: 0.0,
            imu_rate_hz: 0.0,
            pose_rate_hz: 0.0,
            camera_drops: 0,
            imu_drops: 0,
            pose_drops: 0,
            latency_p50_us: 0.0,
            latency_p99_us: 0.0,
            queues: [QueueFill::default(); STATUS_MAX_QUEUES],
            imu_noise_scale_gyro: f64::NAN,
            imu_noise_scale_accel: f64::NAN,
            pixel_noise_scale: f64::NAN,
            camera_imu_rotation_deg: f64::NAN,
            camera_imu_translation_m: f64::NAN,
            camera_imu_time_offset_s: f64::NAN,
        }
    }
}

impl StatusMessage {
    /// The queues in use.
    pub fn queues_in_use(&self) -> &[QueueFill] {
        let n = (self.queue_count as usize).min(STATUS_MAX_QUEUES);
        &self.queues[..n]
    }

    /// Sets the queue entries; more than [`STATUS_MAX_QUEUES`] are cut
    /// (the first ones are kept). Returns how many were kept.
    pub fn set_queues(&mut self, queues: &[QueueFill]) -> usize {
        let n = queues.len().min(STATUS_MAX_QUEUES);
        self.queues = [QueueFill::default(); STATUS_MAX_QUEUES];
        self.queues[..n].copy_from_slice(&queues[..n]);
        self.queue_count = n as u32;
        n
    }
}

/// The isometry of a position and an x, y, z, w quaternion (renormalised).
fn isometry(position: &[f64; 3], xyzw: &[f64; 4]) -> Isometry3<f64> {
    let [x, y, z, w] = *xyzw;
    let rotation = UnitQuaternion::from_quaternion(Quaternion::new(w, x, y, z));
    let [px, py, pz] = *position;
    Isometry3::from_parts(Translation3::new(px, py, pz), rotation)
}

/// The wire value of a tracking state.
pub fn tracking_state_code(state: TrackingState) -> u32 {
    match state {
        TrackingState::Initializing => TRACKING_STATE_INITIALIZING,
        TrackingState::Tracking => TRACKING_STATE_TRACKING,
        TrackingState::Lost => TRACKING_STATE_LOST,
    }
}

/// The tracking state of a wire value, `None` for a value this build does
/// not know.
pub fn tracking_state_from_code(code: u32) -> Option<TrackingState> {
    match code {
        TRACKING_STATE_INITIALIZING => Some(TrackingState::Initializing),
        TRACKING_STATE_TRACKING => Some(TrackingState::Tracking),
        TRACKING_STATE_LOST => Some(TrackingState::Lost),
        _ => None,
    }
}

impl PoseMessage {
    /// A message for `T_world_body` at `t_ns`, with no velocity and no
    /// covariance (their flags clear, covariance NaN). `sequence` and
    /// `published_t_ns` are left at zero for the publisher to set.
    pub fn new(t_ns: i64, state: TrackingState, T_world_body: &Isometry3<f64>) -> Self {
        let q = T_world_body.rotation;
        let p = T_world_body.translation.vector;
        Self {
            layout_version: POSE_LAYOUT_VERSION,
            tracking_state: tracking_state_code(state),
            flags: 0,
            reserved: 0,
            t_ns,
            published_t_ns: 0,
            sequence: 0,
            position_world_m: [p.x, p.y, p.z],
            orientation_world_body_xyzw: [q.i, q.j, q.k, q.w],
            velocity_world_m_s: [0.0; 3],
            covariance: [f64::NAN; 36],
            position_odom_m: [p.x, p.y, p.z],
            orientation_odom_body_xyzw: [q.i, q.j, q.k, q.w],
            translation_world_odom_m: [0.0; 3],
            rotation_world_odom_xyzw: [0.0, 0.0, 0.0, 1.0],
        }
    }

    /// Sets the pose in the odometry frame and the `world <- odom`
    /// transform, and flags [`POSE_FLAG_MAP_CORRECTED`].
    pub fn with_odometry(
        mut self,
        T_odom_body: &Isometry3<f64>,
        T_world_odom: &Isometry3<f64>,
    ) -> Self {
        let (p, q) = (T_odom_body.translation.vector, T_odom_body.rotation);
        self.position_odom_m = [p.x, p.y, p.z];
        self.orientation_odom_body_xyzw = [q.i, q.j, q.k, q.w];
        let (t, r) = (T_world_odom.translation.vector, T_world_odom.rotation);
        self.translation_world_odom_m = [t.x, t.y, t.z];
        self.rotation_world_odom_xyzw = [r.i, r.j, r.k, r.w];
        self.flags |= POSE_FLAG_MAP_CORRECTED;
        self
    }

    /// [`Self::with_odometry`] with the odometry pose that `T_world_odom`
    /// gives the world pose (`T_odom_body = T_world_odom^-1 T_world_body`).
    pub fn with_world_odom(self, T_world_odom: &Isometry3<f64>) -> Self {
        let T_odom_body = T_world_odom.inverse() * self.T_world_body();
        self.with_odometry(&T_odom_body, T_world_odom)
    }

    /// The pose in the odometry frame (the quaternion renormalised).
    pub fn T_odom_body(&self) -> Isometry3<f64> {
        isometry(&self.position_odom_m, &self.orientation_odom_body_xyzw)
    }

    /// The `world <- odom` transform (the quaternion renormalised).
    pub fn T_world_odom(&self) -> Isometry3<f64> {
        isometry(
            &self.translation_world_odom_m,
            &self.rotation_world_odom_xyzw,
        )
    }

    /// Sets the velocity and its flag.
    pub fn with_velocity(mut self, velocity_world_m_s: &Vector3<f64>) -> Self {
        self.velocity_world_m_s = [
            velocity_world_m_s.x,
            velocity_world_m_s.y,
            velocity_world_m_s.z,
        ];
        self.flags |= POSE_FLAG_VELOCITY_VALID;
        self
    }

    /// Sets the covariance (order and frame as documented on the field)
    /// and its flag.
    pub fn with_covariance(mut self, covariance: &Matrix6<f64>) -> Self {
        for row in 0..6 {
            for col in 0..6 {
                self.covariance[6 * row + col] = covariance[(row, col)];
            }
        }
        self.flags |= POSE_FLAG_COVARIANCE_VALID;
        self
    }

    /// The relative stage's answer for one frame (the `rigslam/pose`
    /// stream). The covariance is given separately (usually the output's
    /// own `pose_covariance`) so that a caller can publish another one.
    pub fn from_relative(output: &RelativeOutput, covariance: Option<&Matrix6<f64>>) -> Self {
        let msg = Self::new(output.t_ns, output.state, &output.T_world_body)
            .with_velocity(&output.velocity_world_m_s);
        match covariance {
            Some(c) => msg.with_covariance(c),
            None => msg,
        }
    }

    /// An IMU-propagated state (the `rigslam/pose_fast` stream), flagged
    /// [`POSE_FLAG_IMU_PROPAGATED`].
    pub fn from_nav_state(state: &NavState, tracking: TrackingState) -> Self {
        let T_world_body = Isometry3::from_parts(
            Translation3::from(state.position_world_m),
            state.R_world_body,
        );
        let mut msg =
            Self::new(state.t_ns, tracking, &T_world_body).with_velocity(&state.velocity_world_m_s);
        msg.flags |= POSE_FLAG_IMU_PROPAGATED;
        msg
    }

    /// The pose as an isometry (the quaternion renormalised).
    pub fn T_world_body(&self) -> Isometry3<f64> {
        isometry(&self.position_world_m, &self.orientation_world_body_xyzw)
    }

    /// The covariance as a matrix, `None` when the flag says it is unknown.
    pub fn covariance_matrix(&self) -> Option<Matrix6<f64>> {
        (self.flags & POSE_FLAG_COVARIANCE_VALID != 0)
            .then(|| Matrix6::from_row_slice(&self.covariance))
    }

    /// The tracking state, `None` for a code this build does not know.
    pub fn state(&self) -> Option<TrackingState> {
        tracking_state_from_code(self.tracking_state)
    }

    /// The message in `bytes` as a reader finds it in shared memory;
    /// `None` when `bytes` is not [`std::mem::size_of::<PoseMessage>()`]
    /// long. Nothing is validated: see [`crate::publish::SampleCheck`].
    pub fn from_bytes(bytes: &[u8]) -> Option<Self> {
        from_wire_bytes(bytes)
    }

    /// The message's bytes exactly as they lie in shared memory (what a C
    /// reader casts to `rigslam_pose_message_t`).
    pub fn as_bytes(&self) -> &[u8] {
        // SAFETY: PoseMessage is repr(C), Copy, and has no padding (the
        // layout test checks that the field sizes add up to its size), so
        // every byte is initialised.
        unsafe {
            std::slice::from_raw_parts(
                (self as *const Self).cast::<u8>(),
                std::mem::size_of::<Self>(),
            )
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::imu::ImuBiases;
    use nalgebra::Vector3;

    fn sample_output() -> RelativeOutput {
        let rotation = UnitQuaternion::from_euler_angles(0.1, -0.4, 2.0);
        RelativeOutput {
            t_ns: 1_234_567_890,
            state: TrackingState::Tracking,
            T_world_body: Isometry3::from_parts(Translation3::new(1.0, -2.0, 3.5), rotation),
            velocity_world_m_s: Vector3::new(0.5, 0.25, -0.125),
            biases: ImuBiases::default(),
            delta_translation_world_m: Vector3::zeros(),
            landmarks: Vec::new(),
            pose_covariance: None,
        }
    }

    #[test]
    fn quaternion_is_written_x_y_z_w() {
        // A rotation of pi/2 about z: q = (0, 0, sin(pi/4), cos(pi/4)) in
        // x y z w order, written out by hand, not through nalgebra.
        let rotation =
            UnitQuaternion::from_axis_angle(&Vector3::z_axis(), std::f64::consts::FRAC_PI_2);
        let msg = PoseMessage::new(
            0,
            TrackingState::Tracking,
            &Isometry3::from_parts(Translation3::new(0.0, 0.0, 0.0), rotation),
        );
        let h = std::f64::consts::FRAC_1_SQRT_2;
        let expected = [0.0, 0.0, h, h];
        for (got, want) in msg.orientation_world_body_xyzw.iter().zip(expected) {
            assert!(
                (got - want).abs() < 1e-15,
                "{:?}",
                msg.orientation_world_body_xyzw
            );
        }
    }

    #[test]
    fn relative_output_round_trips_through_the_message() {
        let output = sample_output();
        let mut covariance = Matrix6::zeros();
        for row in 0..6 {
            for col in 0..6 {
                covariance[(row, col)] = (10 * row + col) as f64;
            }
        }
        let msg = PoseMessage::from_relative(&output, Some(&covariance));
        assert_eq!(msg.layout_version, POSE_LAYOUT_VERSION);
        assert_eq!(msg.tracking_state, TRACKING_STATE_TRACKING);
        assert_eq!(msg.t_ns, output.t_ns);
        assert_eq!(msg.position_world_m, [1.0, -2.0, 3.5]);
        assert_eq!(msg.velocity_world_m_s, [0.5, 0.25, -0.125]);
        assert_eq!(
            msg.flags,
            POSE_FLAG_COVARIANCE_VALID | POSE_FLAG_VELOCITY_VALID
        );
        // Row-major: element (row 2, column 5) sits at 6 * 2 + 5.
        assert_eq!(msg.covariance[17], 25.0);
        assert_eq!(msg.covariance[6 * 5 + 2], 52.0);
        assert_eq!(msg.covariance_matrix(), Some(covariance));
        let back = msg.T_world_body();
        assert!((back.translation.vector - output.T_world_body.translation.vector).norm() < 1e-15);
        assert!(back.rotation.angle_to(&output.T_world_body.rotation) < 1e-12);
        assert_eq!(msg.state(), Some(TrackingState::Tracking));
    }

    #[test]
    fn missing_covariance_is_nan_and_flagged() {
        let msg = PoseMessage::from_relative(&sample_output(), None);
        assert_eq!(msg.flags & POSE_FLAG_COVARIANCE_VALID, 0);
        assert!(msg.covariance.iter().all(|c| c.is_nan()));
        assert_eq!(msg.covariance_matrix(), None);
    }

    #[test]
    fn nav_state_is_flagged_as_propagated() {
        let nav = NavState {
            t_ns: 42,
            R_world_body: UnitQuaternion::from_euler_angles(0.0, 0.0, 1.0),
            position_world_m: Vector3::new(4.0, 5.0, 6.0),
            velocity_world_m_s: Vector3::new(1.0, 0.0, 0.0),
        };
        let msg = PoseMessage::from_nav_state(&nav, TrackingState::Tracking);
        assert_ne!(msg.flags & POSE_FLAG_IMU_PROPAGATED, 0);
        assert_eq!(msg.position_world_m, [4.0, 5.0, 6.0]);
        assert_eq!(msg.velocity_world_m_s, [1.0, 0.0, 0.0]);
        assert_eq!(msg.t_ns, 42);
    }

    #[test]
    fn every_tracking_state_survives_its_code_and_unknown_codes_are_refused() {
        for state in [
            TrackingState::Initializing,
            TrackingState::Tracking,
            TrackingState::Lost,
        ] {
            assert_eq!(
                tracking_state_from_code(tracking_state_code(state)),
                Some(state)
            );
        }
        assert_eq!(tracking_state_from_code(3), None);
    }

    #[test]
    fn queue_names_are_cut_and_padded() {
        let q = QueueFill::new("a_very_long_stage_name", 3, 8);
        assert_eq!(q.name_str(), "a_very_long_stag");
        assert_eq!(QueueFill::new("klt", 1, 2).name_str(), "klt");
        let mut status = StatusMessage::default();
        let many: Vec<QueueFill> = (0..10)
            .map(|i| QueueFill::new(&i.to_string(), i, 10))
            .collect();
        assert_eq!(status.set_queues(&many), STATUS_MAX_QUEUES);
        assert_eq!(status.queues_in_use().len(), STATUS_MAX_QUEUES);
        assert_eq!(status.queues_in_use()[7].name_str(), "7");
    }
}
