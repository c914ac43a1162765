//! Synthetic scenes for the window's tests: points on the walls, floor and
//! ceiling of a room, the simulator's smooth EuRoC-like motion, exact
//! projections through the EuRoC radtan cameras, and a noise-free IMU
//! synthesised from the same motion and preintegrated between keyframes.

use nalgebra::{Isometry3, UnitQuaternion, Vector2, Vector3, Vector6};
use rand::Rng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};

use super::rig_camera::RigCamera;
use crate::imu::{ImuBiases, IntegrationScheme, Preintegrated, Preintegrator};
use crate::relative::types::{KeyframeState, Observation, TrackedFrame};
use crate::rig::euroc::{euroc_cam0, euroc_cam1, euroc_imu0};
use crate::rig::RigModel;
use crate::simulate::imu_synth::{synthesize, ImuSynthConfig, SynthImu};
use crate::simulate::motion::{BuiltinMotion, Motion};

pub(crate) const START_NS: i64 = 500_000_000;
pub(crate) const KEYFRAME_SPACING_NS: i64 = 250_000_000;

pub(crate) struct Scene {
    pub motion: Motion,
    pub points: Vec<Vector3<f64>>,
    pub rig: RigModel,
    pub imu: SynthImu,
    pub biases: ImuBiases,
}

pub(crate) fn keyframe_time(k: usize) -> i64 {
    START_NS + k as i64 * KEYFRAME_SPACING_NS
}

impl Scene {
    /// `n_points` on the room's surfaces (10 x 9 x 3.5 m around the
    /// motion), motion of `duration_s`.
    pub fn new(rng: &mut ChaCha8Rng, n_points: usize, duration_s: f64) -> Self {
        let (x0, x1, y0, y1, z0, z1) = (-5.0, 5.0, -4.5, 4.5, 0.0, 3.5);
        let faces = [
            (x1 - x0) * (y1 - y0),
            (x1 - x0) * (y1 - y0),
            (x1 - x0) * (z1 - z0),
            (x1 - x0) * (z1 - z0),
            (y1 - y0) * (z1 - z0),
            (y1 - y0) * (z1 - z0),
        ];
        let total: f64 = faces.iter().sum();
        let points = (0..n_points)
            .map(|_| {
                let mut a = rng.gen::<f64>() * total;
                let mut face = 0;
                while face < 5 && a > faces[face] {
                    a -= faces[face];
                    face += 1;
                }
                let (u, v): (f64, f64) = (rng.gen(), rng.gen());
                let x = x0 + u * (x1 - x0);
                let y = y0 + v * (y1 - y0);
                let zy = z0 + v * (z1 - z0);
                let zx = z0 + u * (z1 - z0);
                match face {
                    0 => Vector3::new(x, y, z0),
                    1 => Vector3::new(x, y, z1),
                    2 => Vector3::new(x, y0, zy),
                    3 => Vector3::new(x, y1, zy),
                    4 => Vector3::new(x0, y0 + u * (y1 - y0), zx.min(z1)),
                    _ => Vector3::new(x1, y0 + u * (y1 - y0), zx.min(z1)),
                }
            })
            .collect();
        let motion = Motion::Builtin(BuiltinMotion::standard(0, duration_s));
        let biases = ImuBiases {
            gyro_rad_s: Vector3::new(0.004, -0.006, 0.003),
            accel_m_s2: Vector3::new(0.05, -0.03, 0.04),
        };
        let imu = synthesize(
            &motion,
            0,
            motion.end_ns(),
            &ImuSynthConfig {
                rate_hz: 200.0,
                noise: None,
                initial_biases: biases,
                seed: 1,
            },
        );
        let rig = RigModel {
            cameras: vec![euroc_cam0(), euroc_cam1()],
            imu: Some(euroc_imu0()),
        };
        Self {
            motion,
            points,
            rig,
            imu,
            biases,
        }
    }

    pub fn truth(&self, t_ns: i64) -> KeyframeState {
        let s = self.motion.state(t_ns);
        KeyframeState {
            t_ns,
            T_world_body: s.T_world_body,
            velocity_world_m_s: s.velocity_world_m_s,
            biases: self.biases,
        }
    }

    /// What the cameras see at `t_ns` (landmark id = point index), with
    /// Gaussian pixel noise and a share of gross outliers (uniform pixels).
    pub fn frame(
        &self,
        t_ns: i64,
        stereo: bool,
        noise_px: f64,
        outlier_rate: f64,
        rng: &mut ChaCha8Rng,
    ) -> TrackedFrame {
        let pose = self.motion.state(t_ns).T_world_body;
        let cameras: Vec<RigCamera> = self.rig.cameras[..if stereo { 2 } else { 1 }]
            .iter()
            .cloned()
            .map(RigCamera::new)
            .collect();
        let mut observations = Vec::new();
        for (i, p) in self.points.iter().enumerate() {
            for (c, cam) in cameras.iter().enumerate() {
                let p_cam =
                    (pose * cam.calibration.T_body_cam).inverse_transform_point(&(*p).into());
                if !(p_cam.z > 0.3 && p_cam.z < 20.0) {
                    continue;
                }
                let Some(px) = cam.project(&p_cam.coords) else {
                    continue;
                };
                let model = &cam.calibration.model;
                let (w, h) = (model.width() as f64, model.height() as f64);
                if !(px.x >= 0.0 && px.y >= 0.0 && px.x < w && px.y < h) {
                    continue;
                }
                let pixel = if outlier_rate > 0.0 && rng.gen::<f64>() < outlier_rate {
                    Vector2::new(rng.gen::<f64>() * w, rng.gen::<f64>() * h)
                } else {
                    let n: Vector2<f64> =
                        Vector2::new(StandardNormal.sample(rng), StandardNormal.sample(rng));
                    px + n * noise_px
                };
                observations.push(Observation {
                    landmark: i as u64,
                    camera_index: c as u8,
                    pixel,
                });
            }
        }
        TrackedFrame {
            t_ns,
            observations,
            is_keyframe: true,
        }
    }

    /// The IMU between two stamps, integrated with the true biases.
    pub fn preintegrate(&self, t0_ns: i64, t1_ns: i64) -> Preintegrated {
        Preintegrator::new(IntegrationScheme::Quadratic, euroc_imu0().noise)
            .integrate(&self.imu.samples, t0_ns, t1_ns, &self.biases)
            .expect("the synthetic samples cover the motion")
    }
}

/// `state` moved by `position_m` and `rotation_rad` in random directions,
/// velocity by `velocity_m_s`, biases by `gyro_bias`, `accel_bias`.
pub(crate) fn perturb(
    state: &KeyframeState,
    rng: &mut ChaCha8Rng,
    position_m: f64,
    rotation_rad: f64,
    velocity_m_s: f64,
) -> KeyframeState {
    let mut dir = || {
        let v: Vector3<f64> = Vector3::new(
            StandardNormal.sample(&mut *rng),
            StandardNormal.sample(&mut *rng),
            StandardNormal.sample(&mut *rng),
        );
        v.normalize()
    };
    let mut s = *state;
    s.T_world_body.translation.vector += dir() * position_m;
    s.T_world_body.rotation =
        s.T_world_body.rotation * UnitQuaternion::from_scaled_axis(dir() * rotation_rad);
    s.velocity_world_m_s += dir() * velocity_m_s;
    s.biases.gyro_rad_s += dir() * 0.003;
    s.biases.accel_m_s2 += dir() * 0.03;
    s
}

/// Position (m) and rotation (deg) error of `estimate` against `truth`.
pub(crate) fn pose_error(estimate: &KeyframeState, truth: &KeyframeState) -> (f64, f64) {
    let dp =
        (estimate.T_world_body.translation.vector - truth.T_world_body.translation.vector).norm();
    let dr = (truth.T_world_body.rotation.inverse() * estimate.T_world_body.rotation)
        .angle()
        .to_degrees();
    (dp, dr)
}

/// The window's pose perturbation `[dphi (body), dp (world)]` that takes
/// `from` to `to`: `R_to = R_from Exp(dphi)`, `p_to = p_from + dp`.
pub(crate) fn pose_difference(from: &Isometry3<f64>, to: &Isometry3<f64>) -> Vector6<f64> {
    let r_from = from.rotation.to_rotation_matrix().into_inner();
    let r_to = to.rotation.to_rotation_matrix().into_inner();
    let mut d = Vector6::zeros();
    d.fixed_rows_mut::<3>(0)
        .copy_from(&crate::imu::so3::log(&(r_from.transpose() * r_to)));
    d.fixed_rows_mut::<3>(3)
        .copy_from(&(to.translation.vector - from.translation.vector));
    d
}
