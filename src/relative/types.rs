//! The values that travel between the parts of the relative stage and out
//! of it. Kept apart from the algorithms so that the tracker, the
//! initialiser, the window and the EKF baseline agree on one vocabulary.

use nalgebra::{Isometry3, Matrix3, Matrix6, Vector2, Vector3};

use crate::features::orb::Descriptor;
use crate::imu::ImuBiases;

/// Identifies one landmark (one feature track) for the whole run. Ids are
/// never reused, so a lost track that is found again gets a new id until
/// the absolute stage recognises it by its descriptor.
pub type LandmarkId = u64;

/// One landmark seen in one image.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Observation {
    /// The landmark (feature track) seen.
    pub landmark: LandmarkId,
    /// 0 = left (or only) camera, 1 = right camera of a stereo rig.
    pub camera_index: u8,
    /// Distorted pixel position, as measured in the image.
    pub pixel: Vector2<f64>,
}

/// What the tracker hands on for one frame.
#[derive(Debug, Clone, PartialEq)]
pub struct TrackedFrame {
    /// Exposure stamp, ns (the clock the sensors are stamped in).
    pub t_ns: i64,
    /// Every observation in this frame, left and right camera.
    pub observations: Vec<Observation>,
    /// The tracker's keyframe decision (see the tracker's policy).
    pub is_keyframe: bool,
}

impl TrackedFrame {
    /// Observations of one camera.
    pub fn in_camera(&self, camera_index: u8) -> impl Iterator<Item = &Observation> + '_ {
        self.observations
            .iter()
            .filter(move |o| o.camera_index == camera_index)
    }
}

/// The navigation state of one keyframe as the window estimates it.
#[allow(non_snake_case)]
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct KeyframeState {
    /// Keyframe stamp, ns.
    pub t_ns: i64,
    /// Body (IMU) pose: maps body coordinates into the world frame.
    pub T_world_body: Isometry3<f64>,
    /// Body velocity in the world frame, m/s.
    pub velocity_world_m_s: Vector3<f64>,
    /// IMU biases at the keyframe.
    pub biases: ImuBiases,
}

/// Where the relative stage is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum TrackingState {
    /// Collecting frames; no pose yet (or a vision-only pose of unknown
    /// scale in the mono modes before the IMU fixes it).
    Initializing,
    /// Poses are metric (or, in the `mono` mode, consistently scaled).
    Tracking,
    /// Tracking failed on this frame; the stage reinitialises.
    Lost,
}

/// A tracked landmark in the body frame of the current frame, with its
/// covariance: what the absolute stage turns into edges (eq. 41-42).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BodyLandmark {
    /// The landmark's track id.
    pub id: LandmarkId,
    /// Position in the current frame's body (IMU) frame, m.
    pub position_body_m: Vector3<f64>,
    /// Covariance of that position in the body frame, m^2.
    pub covariance_body_m2: Matrix3<f64>,
    /// ORB descriptor of the track at its birth (left image), when the
    /// tracker could describe it: how the absolute stage recognises the
    /// landmark after its track was lost or on returning to a place.
    pub descriptor: Option<Descriptor>,
    /// Which of the window's keyframes the estimate rests on, where the
    /// estimator keeps a window (None otherwise).
    pub support: Option<WindowSupport>,
}

/// The keyframes a landmark's window estimate rests on. The frames
/// between two keyframes hand on the same estimate, and consecutive
/// keyframes' estimates share most of their observations: whoever fuses
/// the estimates of several frames (the edge map) must count only what
/// each one adds.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct WindowSupport {
    /// Window keyframes observing the landmark.
    pub keyframes: u16,
    /// The number of the newest of them (keyframe numbers increase by one
    /// per keyframe, across re-initialisations).
    pub newest_keyframe: u64,
}

/// How uncertain a relative pose is: odometry drifts, so the covariance
/// grows with the way travelled since its origin, the keyframe that fixed
/// the window's frame (at the start and after each re-initialisation).
#[allow(non_snake_case)]
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PoseCovariance {
    /// Over `[dx dy dz drx dry drz]`: position error in the world frame
    /// (m), then the rotation error about the world axes (rad) with
    /// `R_true = Exp(dr) R_est`, as ROS `PoseWithCovariance` and the
    /// published pose message.
    pub matrix: Matrix6<f64>,
    /// Stamp and pose of the origin (zero covariance).
    pub origin_t_ns: i64,
    /// Pose of the origin: maps its body coordinates into the world frame.
    pub T_world_origin: Isometry3<f64>,
}

/// The relative stage's answer for one frame.
#[allow(non_snake_case)]
#[derive(Debug, Clone, PartialEq)]
pub struct RelativeOutput {
    /// Frame stamp, ns.
    pub t_ns: i64,
    /// Whether the pose is usable.
    pub state: TrackingState,
    /// Body (IMU) pose: maps body coordinates into the world frame.
    pub T_world_body: Isometry3<f64>,
    /// Body velocity in the world frame, m/s.
    pub velocity_world_m_s: Vector3<f64>,
    /// IMU biases estimated for this frame (zero in the vision-only modes).
    pub biases: ImuBiases,
    /// Translation of the body since the previous output, in the world
    /// frame: the Kalman position filter's prediction input (eq. 60).
    pub delta_translation_world_m: Vector3<f64>,
    /// Landmarks tracked in this frame, in its body frame, for the absolute stage.
    pub landmarks: Vec<BodyLandmark>,
    /// None while initialising or lost, and from estimators that keep
    /// none.
    pub pose_covariance: Option<PoseCovariance>,
}

impl RelativeOutput {
    /// The same output in another world, `by` taking this one into it:
    /// the pose, velocity, motion since the last output and covariance
    /// (with its origin) turn; the body-frame landmarks and the biases do
    /// not change.
    pub fn move_to_world(&mut self, by: &Isometry3<f64>) {
        let r: Matrix3<f64> = by.rotation.to_rotation_matrix().into_inner();
        self.T_world_body = by * self.T_world_body;
        self.velocity_world_m_s = r * self.velocity_world_m_s;
        self.delta_translation_world_m = r * self.delta_translation_world_m;
        if let Some(c) = self.pose_covariance.as_mut() {
            let mut d = Matrix6::zeros();
            d.fixed_view_mut::<3, 3>(0, 0).copy_from(&r);
            d.fixed_view_mut::<3, 3>(3, 3).copy_from(&r);
            c.matrix = d * c.matrix * d.transpose();
            c.T_world_origin = by * c.T_world_origin;
        }
    }

    /// The output for `state` with its `tracking` state: the translation
    /// since `previous_position_world_m` (the last tracked position, as the
    /// estimator keeps it) while tracking, zero otherwise or without one.
    pub fn from_state(
        state: &KeyframeState,
        tracking: TrackingState,
        previous_position_world_m: Option<Vector3<f64>>,
        landmarks: Vec<BodyLandmark>,
        pose_covariance: Option<PoseCovariance>,
    ) -> Self {
        let position = state.T_world_body.translation.vector;
        let delta = match (tracking, previous_position_world_m) {
            (TrackingState::Tracking, Some(p)) => position - p,
            _ => Vector3::zeros(),
        };
        Self {
            t_ns: state.t_ns,
            state: tracking,
            T_world_body: state.T_world_body,
            velocity_world_m_s: state.velocity_world_m_s,
            biases: state.biases,
            delta_translation_world_m: delta,
            landmarks,
            pose_covariance,
        }
    }
}

#[cfg(test)]
impl RelativeOutput {
    /// Test fixture: tracking at the world origin, at rest, seeing
    /// `landmarks`.
    pub(crate) fn tracking_at_origin(t_ns: i64, landmarks: Vec<BodyLandmark>) -> Self {
        Self {
            t_ns,
            state: TrackingState::Tracking,
            T_world_body: Isometry3::identity(),
            velocity_world_m_s: Vector3::zeros(),
            biases: ImuBiases::default(),
            delta_translation_world_m: Vector3::zeros(),
            landmarks,
            pose_covariance: None,
        }
    }
}
