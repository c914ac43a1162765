//! The IMU side of the relative stage between frames: accepted samples
//! kept for as long as an interval may still need them, preintegrated on
//! demand between any two stamps (keyframe to frame, frame to frame).

use nalgebra::{Isometry3, Rotation3, Vector3};

use crate::imu::{
    ImuBiases, ImuIntrinsics, ImuStream, IntegrationScheme, IntervalConfig, Preintegrated,
    Preintegrator,
};
use crate::rig::ImuNoise;

use super::initializer::{detect_static_start, StaticStart, StaticStartConfig};
use crate::sensors::ImuSample;

/// Samples of the stream with the preintegrator that reads them.
pub struct ImuBuffer {
    stream: ImuStream,
    preintegrator: Preintegrator,
    interval: IntervalConfig,
    dropped: u64,
}

impl ImuBuffer {
    /// A buffer that corrects every raw sample by `intrinsics` (the
    /// rig's `imu_intrinsics.yaml`) and weighs it by `noise`.
    pub fn new(noise: ImuNoise, intrinsics: ImuIntrinsics) -> Self {
        Self {
            stream: ImuStream::new(intrinsics),
            preintegrator: Preintegrator::new(IntegrationScheme::Quadratic, noise),
            interval: IntervalConfig::default(),
            dropped: 0,
        }
    }

    /// Accepts a sample; non-finite ones and stamps that do not increase
    /// are dropped and counted.
    pub fn push(&mut self, sample: &ImuSample) {
        if !self.stream.push(sample) {
            self.dropped += 1;
        }
    }

    /// Samples dropped so far (non-finite, or a stamp not after the previous one).
    pub fn dropped(&self) -> u64 {
        self.dropped
    }

    /// The accepted, corrected samples held, strictly increasing in time.
    pub fn samples(&self) -> &[ImuSample] {
        self.stream.samples()
    }

    /// Forgets what no interval starting at or after `t_ns` needs.
    pub fn discard_before(&mut self, t_ns: i64) {
        self.stream.discard_before(t_ns);
    }

    /// The interval `[t_start_ns, t_end_ns]` preintegrated with `biases`;
    /// `None` when the samples do not cover it (a camera that starts
    /// before the IMU) or leave a gap in it longer than the interval
    /// limit (25 ms): integrated across, a gap would stand for motion
    /// nobody measured. An interval with dropped samples comes back
    /// marked unreliable.
    pub fn preintegrate(
        &mut self,
        t_start_ns: i64,
        t_end_ns: i64,
        biases: &ImuBiases,
    ) -> Option<Preintegrated> {
        let interval = self
            .stream
            .interval(t_start_ns, t_end_ns, &self.interval)
            .ok()
            .filter(|i| i.report.long_gaps == 0)?;
        self.preintegrator
            .integrate_interval(&interval, biases)
            .ok()
    }

    /// Rotation of the body at `t_end_ns` in the body at `t_start_ns`,
    /// from the gyroscope alone (for the tracker's prediction).
    #[allow(non_snake_case)]
    pub fn rotation(
        &mut self,
        t_start_ns: i64,
        t_end_ns: i64,
        gyro_bias_rad_s: &Vector3<f64>,
    ) -> Option<Rotation3<f64>> {
        let biases = ImuBiases {
            gyro_rad_s: *gyro_bias_rad_s,
            accel_m_s2: Vector3::zeros(),
        };
        let pre = self.preintegrate(t_start_ns, t_end_ns, &biases)?;
        Some(Rotation3::from_matrix_unchecked(pre.delta_R))
    }

    /// The samples and the preintegrator together, for callers that
    /// integrate several intervals themselves (the alignment).
    pub fn parts(&mut self) -> (&[ImuSample], &mut Preintegrator) {
        (self.stream.samples(), &mut self.preintegrator)
    }

    /// A static start ending at `t_ns` when the samples show one: over the
    /// configured window, or less while the IMU has not run that long (a
    /// camera that starts with the IMU), but over 0.4 s at least.
    pub fn static_start(
        &self,
        t_ns: i64,
        noise: &ImuNoise,
        config: &StaticStartConfig,
    ) -> Option<StaticStart> {
        let available_s = (t_ns - self.samples().first()?.t_ns) as f64 * 1e-9;
        if available_s < 0.4 {
            return None;
        }
        let config = StaticStartConfig {
            window_s: config.window_s.min(available_s),
            ..config.clone()
        };
        let window_ns = (config.window_s * 1e9) as i64;
        let samples = self.between(t_ns - window_ns - 50_000_000, t_ns + 50_000_000);
        match detect_static_start(samples, t_ns, noise, &config) {
            Ok(rest) => Some(rest),
            Err(e) => {
                tracing::debug!("not at rest at {t_ns} ns: {e}");
                None
            }
        }
    }

    /// The gyroscope's rotation of a camera mounted at `T_body_cam`: the
    /// camera at `t_end_ns` in the camera at `t_start_ns` (the tracker's
    /// prediction).
    #[allow(non_snake_case)]
    pub fn camera_rotation(
        &mut self,
        t_start_ns: i64,
        t_end_ns: i64,
        gyro_bias_rad_s: &Vector3<f64>,
        T_body_cam: &Isometry3<f64>,
    ) -> Option<Rotation3<f64>> {
        let r_body = self.rotation(t_start_ns, t_end_ns, gyro_bias_rad_s)?;
        let r_bc = T_body_cam.rotation.to_rotation_matrix();
        Some(r_bc.inverse() * r_body * r_bc)
    }

    /// Samples with stamps in `[t_start_ns, t_end_ns]`.
    pub fn between(&self, t_start_ns: i64, t_end_ns: i64) -> &[ImuSample] {
        let s = self.stream.samples();
        let a = s.partition_point(|x| x.t_ns < t_start_ns);
        let b = s.partition_point(|x| x.t_ns <= t_end_ns);
        &s[a..b.max(a)]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample(t_ns: i64, gz: f64) -> ImuSample {
        ImuSample {
            t_ns,
            gyro_rad_s: [0.0, 0.0, gz],
            accel_m_s2: [0.0, 0.0, 9.81],
        }
    }

    #[test]
    fn rotation_about_z_integrates_the_rate() {
        let mut buf = ImuBuffer::new(ImuNoise::EUROC_ADIS16448, ImuIntrinsics::IDENTITY);
        for k in 0..=200 {
            buf.push(&sample(k * 5_000_000, 0.5));
        }
        let r = buf
            .rotation(100_000_000, 600_000_000, &Vector3::zeros())
            .expect("covered");
        // 0.5 rad/s for 0.5 s.
        assert!((r.angle() - 0.25).abs() < 1e-9, "{}", r.angle());
        assert!(r.axis().expect("axis").z > 0.999);
        // A gyro bias equal to the rate cancels it.
        let r = buf
            .rotation(100_000_000, 600_000_000, &Vector3::new(0.0, 0.0, 0.5))
            .expect("covered");
        assert!(r.angle() < 1e-12);
    }

    #[test]
    fn bad_samples_are_counted_and_gaps_refused() {
        let mut buf = ImuBuffer::new(ImuNoise::EUROC_ADIS16448, ImuIntrinsics::IDENTITY);
        buf.push(&sample(0, 0.0));
        buf.push(&sample(5_000_000, f64::NAN));
        buf.push(&sample(5_000_000, 0.0));
        buf.push(&sample(5_000_000, 0.0));
        buf.push(&sample(1_000_000, 0.0));
        assert_eq!(buf.dropped(), 3);
        assert_eq!(buf.samples().len(), 2);
        // Not covered past the last sample: the camera ran ahead.
        assert!(buf
            .preintegrate(0, 9_000_000, &ImuBiases::default())
            .is_none());
        let pre = buf
            .preintegrate(0, 5_000_000, &ImuBiases::default())
            .expect("covered");
        assert!(!pre.reliable, "a NaN sample inside marks it unreliable");
    }

    /// An interval across a gap longer than 25 ms is refused: integrated
    /// across, 0.3 s without samples read as 0.3 s of the last rate.
    #[test]
    fn an_interval_across_a_long_gap_is_refused() {
        let mut buf = ImuBuffer::new(ImuNoise::EUROC_ADIS16448, ImuIntrinsics::IDENTITY);
        for k in (0..=40).chain(100..=140) {
            buf.push(&sample(k * 5_000_000, 0.5));
        }
        let b = ImuBiases::default();
        assert!(buf.preintegrate(0, 200_000_000, &b).is_some());
        assert!(buf.preintegrate(500_000_000, 700_000_000, &b).is_some());
        assert!(buf.preintegrate(150_000_000, 550_000_000, &b).is_none());
        // 20 ms between samples is within the limit.
        let mut sparse = ImuBuffer::new(ImuNoise::EUROC_ADIS16448, ImuIntrinsics::IDENTITY);
        for k in 0..=20 {
            sparse.push(&sample(k * 20_000_000, 0.5));
        }
        assert!(sparse.preintegrate(0, 400_000_000, &b).is_some());
    }
}
