//! Strapdown inertial navigation: attitude, velocity and position from
//! gyroscope and accelerometer samples in a gravity-aligned world (z up,
//! g = 9.81 m/s^2 downwards).
//!
//! Each interval between two samples is one classical Runge-Kutta (RK4)
//! step of q' = q (x) [0, w/2], v' = R(q) f + g, p' = v, with the
//! bias-corrected measurements interpolated linearly across the interval
//! (Titterton & Weston, "Strapdown Inertial Navigation Technology", 2nd
//! ed., ch. 11; Savage 1998). Its error is dominated by that linear
//! interpolation, O(dt^2) per unit time.

use nalgebra::{Quaternion, UnitQuaternion, Vector3};

use crate::sensors::ImuSample;

/// Magnitude of gravity in the world frame, m/s^2.
pub const GRAVITY_M_S2: f64 = 9.81;

/// Gravity in the z-up world frame.
pub fn gravity_world_m_s2() -> Vector3<f64> {
    Vector3::new(0.0, 0.0, -GRAVITY_M_S2)
}

/// Attitude, position and velocity of the body (IMU) in the world.
#[allow(non_snake_case)]
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NavState {
    /// Stamp, ns (the IMU's clock).
    pub t_ns: i64,
    /// Maps body coordinates into the world frame.
    pub R_world_body: UnitQuaternion<f64>,
    /// Body origin in the world frame (z up, gravity along -z), m.
    pub position_world_m: Vector3<f64>,
    /// Body velocity in the world frame, m/s.
    pub velocity_world_m_s: Vector3<f64>,
}

/// Sensor biases subtracted from every sample.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct ImuBiases {
    /// Gyroscope bias in the IMU frame, rad/s.
    pub gyro_rad_s: Vector3<f64>,
    /// Accelerometer bias in the IMU frame, m/s^2.
    pub accel_m_s2: Vector3<f64>,
}

impl From<&crate::dataset::GroundTruthState> for ImuBiases {
    /// The biases a ground-truth state records (EuRoC's estimate).
    fn from(gt: &crate::dataset::GroundTruthState) -> Self {
        Self {
            gyro_rad_s: gt.gyro_bias_rad_s,
            accel_m_s2: gt.accel_bias_m_s2,
        }
    }
}

#[derive(Debug, thiserror::Error, PartialEq)]
/// Why strapdown integration could not run.
pub enum StrapdownError {
    #[error("IMU sample {index} at {t_ns} ns does not come after the previous one")]
    /// A sample's stamp is not after the previous sample's.
    NotTimeOrdered {
        /// Its index in the samples given.
        index: usize,
        /// Its stamp, ns.
        t_ns: i64,
    },
    #[error("initial state at {state_ns} ns but the first sample is at {sample_ns} ns")]
    /// The first sample is not at the initial state's stamp (integration starts exactly there).
    StartMismatch {
        /// Stamp of the initial state, ns.
        state_ns: i64,
        /// Stamp of the first sample, ns.
        sample_ns: i64,
    },
    #[error("IMU sample {index} at {t_ns} ns is not finite")]
    /// A sample has a NaN or infinite value.
    NotFinite {
        /// Its index in the samples given.
        index: usize,
        /// Its stamp, ns.
        t_ns: i64,
    },
}

struct Derivative {
    q: Quaternion<f64>,
    v: Vector3<f64>,
    p: Vector3<f64>,
}

fn derivative(
    q: &Quaternion<f64>,
    v: &Vector3<f64>,
    w: &Vector3<f64>,
    f: &Vector3<f64>,
) -> Derivative {
    let rotation = UnitQuaternion::new_normalize(*q);
    Derivative {
        q: q * Quaternion::from_imag(*w * 0.5),
        v: rotation * f + gravity_world_m_s2(),
        p: *v,
    }
}

/// One RK4 step from `s0` (at `state.t_ns`) to `s1`.
pub fn step(state: &NavState, s0: &ImuSample, s1: &ImuSample, biases: &ImuBiases) -> NavState {
    let dt_s = (s1.t_ns - s0.t_ns) as f64 * 1e-9;
    let w0 = Vector3::from(s0.gyro_rad_s) - biases.gyro_rad_s;
    let w1 = Vector3::from(s1.gyro_rad_s) - biases.gyro_rad_s;
    let f0 = Vector3::from(s0.accel_m_s2) - biases.accel_m_s2;
    let f1 = Vector3::from(s1.accel_m_s2) - biases.accel_m_s2;
    let wm = (w0 + w1) * 0.5;
    let fm = (f0 + f1) * 0.5;
    let q = state.R_world_body.into_inner();
    let v = state.velocity_world_m_s;
    let p = state.position_world_m;
    let k1 = derivative(&q, &v, &w0, &f0);
    let h2 = dt_s * 0.5;
    let k2 = derivative(&(q + k1.q * h2), &(v + k1.v * h2), &wm, &fm);
    let k3 = derivative(&(q + k2.q * h2), &(v + k2.v * h2), &wm, &fm);
    let k4 = derivative(&(q + k3.q * dt_s), &(v + k3.v * dt_s), &w1, &f1);
    let sixth = dt_s / 6.0;
    NavState {
        t_ns: s1.t_ns,
        R_world_body: UnitQuaternion::new_normalize(
            q + (k1.q + (k2.q + k3.q) * 2.0 + k4.q) * sixth,
        ),
        velocity_world_m_s: v + (k1.v + (k2.v + k3.v) * 2.0 + k4.v) * sixth,
        position_world_m: p + (k1.p + (k2.p + k3.p) * 2.0 + k4.p) * sixth,
    }
}

/// Integrates from `initial` (stamped at the first sample) through all
/// `samples` with constant `biases`; returns the state at every sample
/// stamp, the initial state first.
pub fn integrate(
    initial: &NavState,
    samples: &[ImuSample],
    biases: &ImuBiases,
) -> Result<Vec<NavState>, StrapdownError> {
    let Some(first) = samples.first() else {
        return Ok(vec![*initial]);
    };
    if first.t_ns != initial.t_ns {
        return Err(StrapdownError::StartMismatch {
            state_ns: initial.t_ns,
            sample_ns: first.t_ns,
        });
    }
    for (index, s) in samples.iter().enumerate() {
        if !s.is_finite() {
            return Err(StrapdownError::NotFinite {
                index,
                t_ns: s.t_ns,
            });
        }
        if index > 0 && s.t_ns <= samples[index - 1].t_ns {
            return Err(StrapdownError::NotTimeOrdered {
                index,
                t_ns: s.t_ns,
            });
        }
    }
    let mut states = Vec::with_capacity(samples.len());
    states.push(*initial);
    for pair in samples.windows(2) {
        let next = step(
            states.last().expect("starts non-empty"),
            &pair[0],
            &pair[1],
            biases,
        );
        states.push(next);
    }
    Ok(states)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample(t_ns: i64, gyro: [f64; 3], accel: [f64; 3]) -> ImuSample {
        ImuSample {
            t_ns,
            gyro_rad_s: gyro,
            accel_m_s2: accel,
        }
    }

    #[test]
    fn at_rest_stays_put() {
        let s0 = NavState {
            t_ns: 0,
            R_world_body: UnitQuaternion::identity(),
            position_world_m: Vector3::new(1.0, 2.0, 3.0),
            velocity_world_m_s: Vector3::zeros(),
        };
        let samples: Vec<_> = (0..=200)
            .map(|k| sample(k * 5_000_000, [0.0; 3], [0.0, 0.0, GRAVITY_M_S2]))
            .collect();
        let end = *integrate(&s0, &samples, &ImuBiases::default())
            .unwrap()
            .last()
            .unwrap();
        assert!((end.position_world_m - s0.position_world_m).norm() < 1e-12);
        assert_eq!(end.t_ns, 1_000_000_000);
    }

    #[test]
    fn constant_rate_and_thrust_match_closed_form() {
        // Spinning at w about body z with specific force (0,0,g) + a_z:
        // attitude exp(w t z), position p0 + a_z t^2 / 2 along z.
        let w = 0.8;
        let a_z = 0.5;
        let s0 = NavState {
            t_ns: 0,
            R_world_body: UnitQuaternion::identity(),
            position_world_m: Vector3::zeros(),
            velocity_world_m_s: Vector3::zeros(),
        };
        let samples: Vec<_> = (0..=400)
            .map(|k| sample(k * 5_000_000, [0.0, 0.0, w], [0.0, 0.0, GRAVITY_M_S2 + a_z]))
            .collect();
        let end = *integrate(&s0, &samples, &ImuBiases::default())
            .unwrap()
            .last()
            .unwrap();
        let expected = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), w * 2.0);
        assert!(end.R_world_body.angle_to(&expected) < 1e-10);
        assert!((end.position_world_m - Vector3::new(0.0, 0.0, a_z * 2.0)).norm() < 1e-9);
    }

    #[test]
    fn biases_are_subtracted() {
        let b = ImuBiases {
            gyro_rad_s: Vector3::new(0.01, -0.02, 0.03),
            accel_m_s2: Vector3::new(0.1, 0.2, -0.3),
        };
        let s0 = NavState {
            t_ns: 0,
            R_world_body: UnitQuaternion::identity(),
            position_world_m: Vector3::zeros(),
            velocity_world_m_s: Vector3::zeros(),
        };
        let samples: Vec<_> = (0..=100)
            .map(|k| {
                sample(
                    k * 5_000_000,
                    b.gyro_rad_s.into(),
                    (b.accel_m_s2 + Vector3::new(0.0, 0.0, GRAVITY_M_S2)).into(),
                )
            })
            .collect();
        let end = *integrate(&s0, &samples, &b).unwrap().last().unwrap();
        assert!(end.position_world_m.norm() < 1e-12);
        assert!(end.R_world_body.angle() < 1e-12);
    }

    #[test]
    fn rejects_unordered_and_mismatched_input() {
        let s0 = NavState {
            t_ns: 5,
            R_world_body: UnitQuaternion::identity(),
            position_world_m: Vector3::zeros(),
            velocity_world_m_s: Vector3::zeros(),
        };
        let bad_start = [sample(0, [0.0; 3], [0.0; 3])];
        assert!(matches!(
            integrate(&s0, &bad_start, &ImuBiases::default()),
            Err(StrapdownError::StartMismatch { .. })
        ));
        let unordered = [sample(5, [0.0; 3], [0.0; 3]), sample(5, [0.0; 3], [0.0; 3])];
        assert_eq!(
            integrate(&s0, &unordered, &ImuBiases::default()),
            Err(StrapdownError::NotTimeOrdered { index: 1, t_ns: 5 })
        );
        let nan = [sample(5, [f64::NAN, 0.0, 0.0], [0.0; 3])];
        assert!(matches!(
            integrate(&s0, &nan, &ImuBiases::default()),
            Err(StrapdownError::NotFinite { .. })
        ));
    }
}
