//! The filter's state: the nominal navigation state of the body, the
//! landmarks in the state vector, and the layout of the error state that
//! the covariance describes.
//!
//! Error state (the covariance's rows and columns, in this order):
//! `[dtheta (3), dp (3), dv (3), db_g (3), db_a (3), dl_1 (3), ..., dl_N (3)]`.
//! The orientation error is a *right* (body-frame) perturbation,
//! `R = R_hat Exp(dtheta)`; all other errors are additive
//! (`x = x_hat + dx`). Landmarks are world-frame xyz: with stereo (metric
//! depth on the first frame) and with mono delayed initialisation (the
//! point is triangulated before it enters the state) the first estimate
//! is already well localised, so the non-linearity inverse depth exists
//! to handle (points of unknown depth entering the state) never arises,
//! and xyz keeps the measurement Jacobian and the hand-over to the
//! absolute stage (body-frame xyz with a 3x3 covariance) simple.

use nalgebra::{Matrix3, SMatrix, UnitQuaternion, Vector3};

use crate::imu::ImuBiases;
use crate::relative::types::{KeyframeState, LandmarkId};

/// Error-state dimension of the body part.
pub(crate) const NAV_DIM: usize = 15;
pub(crate) const THETA: usize = 0;
pub(crate) const POS: usize = 3;
pub(crate) const VEL: usize = 6;
pub(crate) const BG: usize = 9;
pub(crate) const BA: usize = 12;

pub(crate) type Matrix15 = SMatrix<f64, 15, 15>;

/// Nominal navigation state of the body (IMU) in the world.
#[allow(non_snake_case)]
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct NavNominal {
    pub t_ns: i64,
    pub R_world_body: UnitQuaternion<f64>,
    pub position_world_m: Vector3<f64>,
    pub velocity_world_m_s: Vector3<f64>,
    pub gyro_bias_rad_s: Vector3<f64>,
    pub accel_bias_m_s2: Vector3<f64>,
}

impl NavNominal {
    pub fn from_keyframe(state: &KeyframeState) -> Self {
        Self {
            t_ns: state.t_ns,
            R_world_body: state.T_world_body.rotation,
            position_world_m: state.T_world_body.translation.vector,
            velocity_world_m_s: state.velocity_world_m_s,
            gyro_bias_rad_s: state.biases.gyro_rad_s,
            accel_bias_m_s2: state.biases.accel_m_s2,
        }
    }

    pub fn to_keyframe(self) -> KeyframeState {
        KeyframeState {
            t_ns: self.t_ns,
            T_world_body: nalgebra::Isometry3::from_parts(
                nalgebra::Translation3::from(self.position_world_m),
                self.R_world_body,
            ),
            velocity_world_m_s: self.velocity_world_m_s,
            biases: ImuBiases {
                gyro_rad_s: self.gyro_bias_rad_s,
                accel_m_s2: self.accel_bias_m_s2,
            },
        }
    }

    pub fn rotation(&self) -> Matrix3<f64> {
        *self.R_world_body.to_rotation_matrix().matrix()
    }

    /// `x <- x (+) dx` for the 15 navigation error components
    /// (`dx[0..15]`, layout above).
    pub fn inject(&mut self, dx: &[f64]) {
        let v = |i: usize| Vector3::new(dx[i], dx[i + 1], dx[i + 2]);
        self.R_world_body *= UnitQuaternion::from_scaled_axis(v(THETA));
        self.position_world_m += v(POS);
        self.velocity_world_m_s += v(VEL);
        self.gyro_bias_rad_s += v(BG);
        self.accel_bias_m_s2 += v(BA);
    }

    pub fn is_finite(&self) -> bool {
        let q = self.R_world_body.as_ref().coords;
        q.iter()
            .chain(self.position_world_m.iter())
            .chain(self.velocity_world_m_s.iter())
            .chain(self.gyro_bias_rad_s.iter())
            .chain(self.accel_bias_m_s2.iter())
            .all(|x| x.is_finite())
    }
}

/// One landmark in the state vector.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct StateLandmark {
    pub id: LandmarkId,
    pub position_world_m: Vector3<f64>,
    /// Frame counter of the last frame that observed it.
    pub last_seen_frame: u64,
    /// Frames in a row whose observations of it the gate rejected.
    pub consecutive_rejections: u32,
}

/// First column of landmark slot `k` in the error state.
pub(crate) fn landmark_column(k: usize) -> usize {
    NAV_DIM + 3 * k
}
