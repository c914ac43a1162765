//! Frames on the IMU's clock. A camera whose clock runs `shift` behind the
//! IMU's (Kalibr's `timeshift_cam_imu`, `t_imu = t_cam + shift`) has its
//! frames restamped before the estimator sees them, so every interval is
//! preintegrated between the instants the images were really taken. Poses
//! come out on the IMU clock, as `pose_fast` does.

use super::estimator::{FrameInput, FrameTimings, RelativeEstimator};
use super::types::RelativeOutput;
use crate::rig::RigModel;
use crate::sensors::ImuSample;

/// `estimator`, restamping frames by camera 0's time shift when it is
/// not zero.
pub fn on_imu_clock(
    estimator: Box<dyn RelativeEstimator>,
    rig: &RigModel,
) -> Box<dyn RelativeEstimator> {
    let shift_ns = rig.frame_shift_ns();
    if shift_ns == 0 {
        estimator
    } else {
        Box::new(ShiftedFrames {
            inner: estimator,
            shift_ns,
        })
    }
}

struct ShiftedFrames {
    inner: Box<dyn RelativeEstimator>,
    shift_ns: i64,
}

impl RelativeEstimator for ShiftedFrames {
    fn push_imu(&mut self, sample: &ImuSample) {
        self.inner.push_imu(sample);
    }

    fn push_frame(&mut self, frame: &FrameInput<'_>) -> RelativeOutput {
        self.inner.push_frame(&FrameInput {
            t_ns: frame.t_ns.saturating_add(self.shift_ns),
            ..*frame
        })
    }

    fn finish_frame(&mut self) -> Option<RelativeOutput> {
        self.inner.finish_frame()
    }

    fn work_pending(&self) -> bool {
        self.inner.work_pending()
    }

    fn last_timings(&self) -> &FrameTimings {
        self.inner.last_timings()
    }

    fn counters(&self) -> Vec<(&'static str, u64)> {
        self.inner.counters()
    }

    fn imu_noise_scale(&self) -> Option<crate::relative::window::NoiseScale> {
        self.inner.imu_noise_scale()
    }

    fn noise_at_bound(&self) -> bool {
        self.inner.noise_at_bound()
    }

    fn camera_imu(&self) -> Option<crate::relative::window::CameraImuEstimate> {
        self.inner.camera_imu()
    }

    fn gravity_world_m_s2(&self) -> Option<nalgebra::Vector3<f64>> {
        self.inner.gravity_world_m_s2()
    }

    fn settling(&self) -> bool {
        self.inner.settling()
    }

    fn levelling(&self) -> nalgebra::Isometry3<f64> {
        self.inner.levelling()
    }

    fn accel_bias_sigma_m_s2(&self) -> Option<f64> {
        self.inner.accel_bias_sigma_m_s2()
    }
}
