//! One IMU measurement in SI units.

/// A gyroscope + accelerometer sample, in the IMU's own (sensor) frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ImuSample {
    /// Time of the measurement, i64 nanoseconds.
    pub t_ns: i64,
    /// Angular rate, rad/s.
    pub gyro_rad_s: [f64; 3],
    /// Specific force, m/s^2.
    pub accel_m_s2: [f64; 3],
}

impl ImuSample {
    /// True when every component is finite: NaN or infinite samples are
    /// dropped (and counted) by whoever receives them, never integrated.
    pub fn is_finite(&self) -> bool {
        self.gyro_rad_s
            .iter()
            .chain(self.accel_m_s2.iter())
            .all(|v| v.is_finite())
    }

    /// Largest angular rate any IMU reports, rad/s (MEMS gyroscopes
    /// saturate at 2000 deg/s, 35 rad/s).
    pub const MAX_GYRO_RAD_S: f64 = 100.0;
    /// Largest specific force any IMU reports, m/s^2 (MEMS accelerometers
    /// saturate at 16 to 200 g).
    pub const MAX_ACCEL_M_S2: f64 = 2000.0;

    /// True when every component is finite and within what a sensor can
    /// report ([`Self::MAX_GYRO_RAD_S`], [`Self::MAX_ACCEL_M_S2`]): a value
    /// beyond is a damaged sample (a flipped exponent bit), never motion.
    pub fn is_plausible(&self) -> bool {
        self.is_finite()
            && self
                .gyro_rad_s
                .iter()
                .all(|v| v.abs() <= Self::MAX_GYRO_RAD_S)
            && self
                .accel_m_s2
                .iter()
                .all(|v| v.abs() <= Self::MAX_ACCEL_M_S2)
    }

    /// Time in seconds, for printing and plots.
    pub fn t_s(&self) -> f64 {
        self.t_ns as f64 * 1e-9
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn values_beyond_any_sensor_are_not_plausible() {
        let s = ImuSample {
            t_ns: 1,
            gyro_rad_s: [0.1, -34.0, 0.0],
            accel_m_s2: [0.0, 150.0, 9.81],
        };
        assert!(s.is_plausible());
        let mut gyro = s;
        gyro.gyro_rad_s[2] = -1e3;
        assert!(gyro.is_finite() && !gyro.is_plausible());
        let mut accel = s;
        accel.accel_m_s2[0] = 3.0e4;
        assert!(!accel.is_plausible());
        let mut nan = s;
        nan.accel_m_s2[1] = f64::NAN;
        assert!(!nan.is_plausible());
    }

    #[test]
    fn nan_sample_is_not_finite() {
        let mut s = ImuSample {
            t_ns: 1,
            gyro_rad_s: [0.0; 3],
            accel_m_s2: [0.0, 0.0, 9.81],
        };
        assert!(s.is_finite());
        s.accel_m_s2[1] = f64::NAN;
        assert!(!s.is_finite());
        s.accel_m_s2[1] = 0.0;
        s.gyro_rad_s[2] = f64::INFINITY;
        assert!(!s.is_finite());
    }
}
