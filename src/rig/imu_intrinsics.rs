//! The IMU's intrinsic calibration, part of the rig, in the measurement
//! model of the paper (eq. 14-16): a raw reading `x_r` is corrected by
//! `x_c = S x_r + b` (scale and misalignment `S`, offset `b`, one pair per
//! sensor triad) before integration; what remains is the slowly varying
//! bias estimated online ([`crate::imu::ImuBiases`]) and white noise
//! ([`crate::imu::noise`]).

use nalgebra::{Matrix3, Vector3};

use crate::sensors::ImuSample;

/// `x_c = S x_r + b` for the gyroscope and the accelerometer, as
/// `rigslam-calibrate imu` estimates them.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ImuIntrinsics {
    /// Gyroscope `S` (scale and misalignment).
    pub gyro_scale: Matrix3<f64>,
    /// Gyroscope `b`, rad/s.
    pub gyro_offset_rad_s: Vector3<f64>,
    /// Accelerometer `S` (scale and misalignment).
    pub accel_scale: Matrix3<f64>,
    /// Accelerometer `b`, m/s^2.
    pub accel_offset_m_s2: Vector3<f64>,
}

impl Default for ImuIntrinsics {
    fn default() -> Self {
        Self::IDENTITY
    }
}

impl ImuIntrinsics {
    /// No correction (a sensor calibrated at the factory, like EuRoC's).
    pub const IDENTITY: ImuIntrinsics = ImuIntrinsics {
        gyro_scale: Matrix3::new(1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0),
        gyro_offset_rad_s: Vector3::new(0.0, 0.0, 0.0),
        accel_scale: Matrix3::new(1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0),
        accel_offset_m_s2: Vector3::new(0.0, 0.0, 0.0),
    };

    /// The corrected sample, eq. 14-16.
    pub fn correct(&self, raw: &ImuSample) -> ImuSample {
        let gyro = self.gyro_scale * Vector3::from(raw.gyro_rad_s) + self.gyro_offset_rad_s;
        let accel = self.accel_scale * Vector3::from(raw.accel_m_s2) + self.accel_offset_m_s2;
        ImuSample {
            t_ns: raw.t_ns,
            gyro_rad_s: gyro.into(),
            accel_m_s2: accel.into(),
        }
    }

    /// Whether this is exactly the identity correction (`S = I`, `b = 0`).
    pub fn is_identity(&self) -> bool {
        *self == Self::IDENTITY
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn correction_applies_scale_then_offset() {
        let intrinsics = ImuIntrinsics {
            gyro_scale: Matrix3::new(1.01, 0.002, 0.0, 0.0, 0.99, 0.0, 0.0, 0.0, 1.0),
            gyro_offset_rad_s: Vector3::new(0.001, 0.0, -0.002),
            accel_scale: Matrix3::identity() * 1.02,
            accel_offset_m_s2: Vector3::new(0.1, -0.2, 0.0),
        };
        let raw = ImuSample {
            t_ns: 7,
            gyro_rad_s: [1.0, 2.0, 3.0],
            accel_m_s2: [0.0, 0.0, 9.81],
        };
        let c = intrinsics.correct(&raw);
        assert_eq!(c.t_ns, 7);
        // Row by row, by hand: 1.01*1 + 0.002*2 + 0.001 = 1.015.
        assert!((c.gyro_rad_s[0] - 1.015).abs() < 1e-15);
        assert!((c.gyro_rad_s[1] - 1.98).abs() < 1e-15);
        assert!((c.gyro_rad_s[2] - 2.998).abs() < 1e-15);
        assert!((c.accel_m_s2[0] - 0.1).abs() < 1e-15);
        assert!((c.accel_m_s2[2] - 1.02 * 9.81).abs() < 1e-14);
        assert_eq!(ImuIntrinsics::IDENTITY.correct(&raw), raw);
        assert!(!intrinsics.is_identity());
    }
}
