//! Held keyframes keep their cameras when the camera-IMU calibration moves.
//!
//! The window stores every keyframe as a body (IMU) pose, velocity and
//! biases. What a held keyframe's images fixed, though, is its camera's
//! pose: its body pose is that camera pose through the calibration of the
//! solve that last moved it. If the held body pose stayed put while the
//! window refines the calibration (camera 0 in the body, the time offset),
//! every held camera would move with the calibration, and the held
//! keyframes' images would pull the calibration back towards the value
//! they were held at. The refinement could then only creep, by what the
//! free keyframes ask of it against the held ones: after a start in
//! flight with a file 1 deg, 10 mm and 5 ms off, the rotation stalled
//! 0.3-0.9 deg and the time offset up to 4 ms from the truth, and a freed
//! lever arm walked to 20-35 mm.
//!
//! So a held keyframe keeps camera 0's pose at exposure and the camera's
//! velocity `u = v + R (omega x t)`, and its body state follows the
//! calibration ([`follow`], after every step). Its observations then do
//! not depend on the calibration's rotation, translation or time offset
//! (the window leaves those columns of its rows out; the stereo rotation
//! still moves camera 1). The boundary keyframe, whose velocity and biases
//! are estimated and which begins the first inertial link, hands the
//! calibration on to that link through its body state
//! ([`state_jacobian`]), and its velocity prior moves with its velocity.
//!
//! With the step `[dphi_c, dt_c, d td, dpsi_s]` of
//! [`super::camera_imu`], the body's turn rate `omega`, `R` and `t` the
//! rotation and translation of camera 0 in the body (`R_bc`), `Q =
//! Exp(omega td)` and `R_e = R_wb Q` the body's attitude at exposure, to
//! first order:
//!
//! - `dtheta = -Q R_bc dphi_c - omega d td` (right perturbation of the body attitude),
//! - `dv = R_wb [omega x t]x dtheta - R_wb [omega]x dt_c`,
//! - `dp = -R_e dt_c - R_e [t]x R_bc dphi_c - v d td - td dv`.

use nalgebra::{Isometry3, Matrix3, SMatrix, Translation3, UnitQuaternion, Vector3};

use super::camera_imu::{
    pose_at_exposure, BodyMotion, CameraImuState, CALIB_DIM, CALIB_POS, CALIB_ROT, CALIB_TIME,
};
use super::inertial::INERTIAL_COLS;
use crate::imu::so3::{exp, hat};
use crate::relative::types::KeyframeState;

/// The part of the calibration a held keyframe's body state follows:
/// camera 0's pose in the body and the time offset of the frames.
#[allow(non_snake_case)]
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Mount {
    /// Camera 0 in the body (IMU) frame.
    pub T_body_cam0: Isometry3<f64>,
    /// What the frames lag behind the IMU clock beyond the file's time shift, s.
    pub time_offset_s: f64,
}

impl Mount {
    /// The refinement's current estimate.
    pub(crate) fn of(c: &CameraImuState) -> Self {
        Self {
            T_body_cam0: c.T_body_cam0,
            time_offset_s: c.time_offset_s,
        }
    }
}

/// Moves a held keyframe's body state from the calibration `from` to `to`
/// keeping camera 0's pose at exposure and the camera's velocity
/// (`omega_body`: the body's turn rate at the keyframe). Returns the
/// change of the body velocity.
pub(crate) fn follow(
    state: &mut KeyframeState,
    omega_body: &Vector3<f64>,
    from: &Mount,
    to: &Mount,
) -> Vector3<f64> {
    let motion = BodyMotion {
        omega_body_rad_s: *omega_body,
        velocity_world_m_s: state.velocity_world_m_s,
    };
    let camera =
        pose_at_exposure(&state.T_world_body, &motion, from.time_offset_s) * from.T_body_cam0;
    let camera_velocity = state.velocity_world_m_s
        + state.T_world_body.rotation * omega_body.cross(&from.T_body_cam0.translation.vector);
    let exposed = camera * to.T_body_cam0.inverse();
    let rotation =
        exposed.rotation * UnitQuaternion::from_scaled_axis(-omega_body * to.time_offset_s);
    let velocity =
        camera_velocity - rotation * omega_body.cross(&to.T_body_cam0.translation.vector);
    let position = exposed.translation.vector - velocity * to.time_offset_s;
    let change = velocity - state.velocity_world_m_s;
    state.T_world_body = Isometry3::from_parts(Translation3::from(position), rotation);
    state.velocity_world_m_s = velocity;
    change
}

/// The derivative of `[dtheta, dp, dv]` (the body state's error state:
/// attitude, position, velocity) of a held keyframe with respect to the
/// calibration step, as [`follow`] moves it (module doc).
pub(crate) fn state_jacobian(
    state: &KeyframeState,
    omega_body: &Vector3<f64>,
    mount: &Mount,
) -> SMatrix<f64, 9, CALIB_DIM> {
    let r_bc: Matrix3<f64> = mount.T_body_cam0.rotation.to_rotation_matrix().into_inner();
    let t = mount.T_body_cam0.translation.vector;
    let r_wb: Matrix3<f64> = state
        .T_world_body
        .rotation
        .to_rotation_matrix()
        .into_inner();
    let q = exp(&(omega_body * mount.time_offset_s));
    let r_e = r_wb * q;
    let mut d_theta = SMatrix::<f64, 3, CALIB_DIM>::zeros();
    d_theta
        .fixed_view_mut::<3, 3>(0, CALIB_ROT)
        .copy_from(&(-q * r_bc));
    d_theta
        .fixed_view_mut::<3, 1>(0, CALIB_TIME)
        .copy_from(&(-omega_body));
    let mut d_p = SMatrix::<f64, 3, CALIB_DIM>::zeros();
    d_p.fixed_view_mut::<3, 3>(0, CALIB_ROT)
        .copy_from(&(-r_e * hat(&t) * r_bc));
    d_p.fixed_view_mut::<3, 3>(0, CALIB_POS).copy_from(&(-r_e));
    d_p.fixed_view_mut::<3, 1>(0, CALIB_TIME)
        .copy_from(&(-state.velocity_world_m_s));
    let mut d_v = r_wb * hat(&omega_body.cross(&t)) * d_theta;
    let mut d_v_pos = d_v.fixed_view_mut::<3, 3>(0, CALIB_POS);
    d_v_pos -= r_wb * hat(omega_body);
    // The body at exposure is `td` ahead on the new velocity.
    d_p -= d_v * mount.time_offset_s;
    let mut out = SMatrix::<f64, 9, CALIB_DIM>::zeros();
    out.fixed_view_mut::<3, CALIB_DIM>(0, 0).copy_from(&d_theta);
    out.fixed_view_mut::<3, CALIB_DIM>(3, 0).copy_from(&d_p);
    out.fixed_view_mut::<3, CALIB_DIM>(6, 0).copy_from(&d_v);
    out
}

/// The first inertial link's Jacobian with respect to the calibration
/// step, through its first keyframe (the boundary, held, following its
/// camera): `j` is the link's Jacobian ([`super::inertial::inertial_factor`]),
/// whose first nine columns are that keyframe's attitude, position and
/// velocity.
pub(crate) fn boundary_link_columns(
    j: &SMatrix<f64, 9, INERTIAL_COLS>,
    boundary: &KeyframeState,
    omega_body: &Vector3<f64>,
    mount: &Mount,
) -> SMatrix<f64, 9, CALIB_DIM> {
    j.fixed_view::<9, 9>(0, 0) * state_jacobian(boundary, omega_body, mount)
}

impl super::Window {
    /// The first inertial link's columns on the calibration step and the
    /// calibration's first column in the solve, when the link reaches it
    /// (held keyframes following a calibration the solve refines): `j`
    /// is the link's Jacobian, `boundary` its first keyframe. The solve,
    /// the covariance's held-pose coupling and the noise test of the link
    /// all need the same term.
    pub(super) fn following_link_calibration(
        &self,
        j: &SMatrix<f64, 9, INERTIAL_COLS>,
        boundary: &super::state::Keyframe,
    ) -> Option<(SMatrix<f64, 9, CALIB_DIM>, usize)> {
        let c = self
            .camera_imu
            .as_ref()
            .filter(|c| c.held_keyframes_follow())?;
        let oc = self.problem.calib_offset?;
        Some((
            boundary_link_columns(
                j,
                &boundary.state,
                &boundary.omega_body_rad_s,
                &Mount::of(c),
            ),
            oc,
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::imu::so3::log;
    use crate::imu::ImuBiases;

    fn state() -> KeyframeState {
        KeyframeState {
            t_ns: 0,
            T_world_body: Isometry3::from_parts(
                Translation3::new(0.4, -1.2, 0.9),
                UnitQuaternion::from_scaled_axis(Vector3::new(0.3, -0.5, 1.1)),
            ),
            velocity_world_m_s: Vector3::new(0.7, -0.2, 0.3),
            biases: ImuBiases::default(),
        }
    }

    fn mount() -> Mount {
        Mount {
            T_body_cam0: Isometry3::from_parts(
                Translation3::new(-0.02, -0.064, 0.01),
                UnitQuaternion::from_scaled_axis(Vector3::new(0.01, 0.02, 1.57)),
            ),
            time_offset_s: 0.004,
        }
    }

    fn stepped(m: &Mount, d: &[f64; CALIB_DIM]) -> Mount {
        let v3 = |o: usize| Vector3::new(d[o], d[o + 1], d[o + 2]);
        let mut out = *m;
        out.T_body_cam0.rotation =
            m.T_body_cam0.rotation * UnitQuaternion::from_scaled_axis(v3(CALIB_ROT));
        out.T_body_cam0.translation.vector += v3(CALIB_POS);
        out.time_offset_s += d[CALIB_TIME];
        out
    }

    #[test]
    fn the_camera_keeps_its_pose_at_exposure_and_its_velocity() {
        let omega = Vector3::new(0.8, -0.4, 1.3);
        let (from, to) = (
            mount(),
            stepped(
                &mount(),
                &[
                    0.02, -0.01, 0.015, 0.01, 0.008, -0.005, -0.005, 0.0, 0.0, 0.0,
                ],
            ),
        );
        let mut s = state();
        let before = s;
        let camera = |s: &KeyframeState, m: &Mount| {
            let motion = BodyMotion {
                omega_body_rad_s: omega,
                velocity_world_m_s: s.velocity_world_m_s,
            };
            pose_at_exposure(&s.T_world_body, &motion, m.time_offset_s) * m.T_body_cam0
        };
        let velocity = |s: &KeyframeState, m: &Mount| {
            s.velocity_world_m_s
                + s.T_world_body.rotation * omega.cross(&m.T_body_cam0.translation.vector)
        };
        let change = follow(&mut s, &omega, &from, &to);
        let (a, b) = (camera(&before, &from), camera(&s, &to));
        let moved = (a.translation.vector - b.translation.vector).norm();
        assert!(moved < 1e-12, "camera moved {moved} m");
        assert!(a.rotation.angle_to(&b.rotation) < 1e-12);
        assert!((velocity(&before, &from) - velocity(&s, &to)).norm() < 1e-12);
        assert!((change - (s.velocity_world_m_s - before.velocity_world_m_s)).norm() < 1e-15);
        // A real change: the body moved by about the lever arm's step.
        assert!(
            (s.T_world_body.translation.vector - before.T_world_body.translation.vector).norm()
                > 5e-3
        );
    }

    #[test]
    fn the_state_jacobian_matches_finite_differences() {
        let omega = Vector3::new(0.8, -0.4, 1.3);
        let base = state();
        let m = mount();
        let jac = state_jacobian(&base, &omega, &m);
        let h = 1e-6;
        for k in 0..CALIB_DIM {
            let moved = |sign: f64| {
                let mut d = [0.0; CALIB_DIM];
                d[k] = sign * h;
                let mut s = base;
                follow(&mut s, &omega, &m, &stepped(&m, &d));
                let dtheta = log(&(base
                    .T_world_body
                    .rotation
                    .to_rotation_matrix()
                    .into_inner()
                    .transpose()
                    * s.T_world_body.rotation.to_rotation_matrix().into_inner()));
                let mut e = nalgebra::SVector::<f64, 9>::zeros();
                e.fixed_rows_mut::<3>(0).copy_from(&dtheta);
                e.fixed_rows_mut::<3>(3).copy_from(
                    &(s.T_world_body.translation.vector - base.T_world_body.translation.vector),
                );
                e.fixed_rows_mut::<3>(6)
                    .copy_from(&(s.velocity_world_m_s - base.velocity_world_m_s));
                e
            };
            let numeric = (moved(1.0) - moved(-1.0)) / (2.0 * h);
            let analytic = jac.column(k);
            let err = (numeric - analytic).norm();
            assert!(
                err < 1e-7 * (1.0 + analytic.norm()),
                "column {k}: numeric {numeric:?} analytic {analytic:?}"
            );
        }
        // The stereo rotation moves no held body.
        assert!(
            jac.columns(super::super::camera_imu::CALIB_STEREO, 3)
                .norm()
                == 0.0
        );
    }
}
