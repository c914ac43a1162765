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

    /// Time in seconds, for printing and plots.
    pub fn t_s(&self) -> f64 {
        self.t_ns as f64 * 1e-9
    }
}

#[cfg(test)]
mod tests {
    use super::*;

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
