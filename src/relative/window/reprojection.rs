//! The visual term of the window's cost (eq. 29-31): the distorted pixel
//! a landmark projects to in a camera of the rig, minus the measured one,
//! with analytic Jacobians, and the robust kernels that bound the pull of
//! outliers.
//!
//! `p_body = R^T (p_world - p)`, `p_cam = R_bc^T (p_body - t_bc)`, pixel
//! `= pi(p_cam)` through the camera model (distortion included). With the
//! body perturbed as `R Exp(dphi)`, `p + dp`:
//! `d p_body / d dphi = [p_body]x`, `d p_body / d dp = -R^T`,
//! `d p_body / d p_world = R^T`.

use nalgebra::{Isometry3, Matrix2x3, SMatrix, Vector2, Vector3};

use super::rig_camera::RigCamera;
use crate::imu::so3::hat;

/// 2x6 Jacobian of a pixel error with respect to a body pose `[dphi, dp]`.
pub type Matrix2x6 = SMatrix<f64, 2, 6>;

/// One linearised reprojection (pixels, not yet divided by sigma).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Reprojection {
    /// Predicted minus measured pixel.
    pub error_px: Vector2<f64>,
    /// d error / d [dphi, dp] of the body.
    pub d_pose: Matrix2x6,
    /// d error / d landmark (world).
    pub d_point: Matrix2x3<f64>,
    /// Depth of the landmark in the camera, window units (m when metric).
    pub depth_m: f64,
}

/// Landmark in the camera frame.
#[allow(non_snake_case)]
fn point_in_camera(
    camera: &RigCamera,
    T_world_body: &Isometry3<f64>,
    point_world_m: &Vector3<f64>,
) -> Vector3<f64> {
    camera
        .calibration
        .T_body_cam
        .inverse_transform_point(&T_world_body.inverse_transform_point(&(*point_world_m).into()))
        .coords
}

/// The reprojection error and its Jacobians; `None` when the point does
/// not project (behind the camera, outside the model's valid radius).
#[allow(non_snake_case)]
pub fn reproject(
    camera: &RigCamera,
    T_world_body: &Isometry3<f64>,
    point_world_m: &Vector3<f64>,
    pixel: &Vector2<f64>,
) -> Option<Reprojection> {
    let r_bw = T_world_body
        .rotation
        .to_rotation_matrix()
        .into_inner()
        .transpose();
    let p_body = r_bw * (point_world_m - T_world_body.translation.vector);
    let t_bc = &camera.calibration.T_body_cam;
    let r_cb = t_bc.rotation.to_rotation_matrix().into_inner().transpose();
    let p_cam = r_cb * (p_body - t_bc.translation.vector);
    let (px, d_px) = camera.project_with_point_jacobian(&p_cam)?;
    let d_body = d_px * r_cb;
    let d_point = d_body * r_bw;
    let mut d_pose = Matrix2x6::zeros();
    d_pose
        .fixed_view_mut::<2, 3>(0, 0)
        .copy_from(&(d_body * hat(&p_body)));
    d_pose.fixed_view_mut::<2, 3>(0, 3).copy_from(&(-d_point));
    Some(Reprojection {
        error_px: px - pixel,
        d_pose,
        d_point,
        depth_m: p_cam.z,
    })
}

/// The error alone (cost evaluation), with the depth in the camera.
#[allow(non_snake_case)]
pub fn reprojection_error(
    camera: &RigCamera,
    T_world_body: &Isometry3<f64>,
    point_world_m: &Vector3<f64>,
    pixel: &Vector2<f64>,
) -> Option<(Vector2<f64>, f64)> {
    let p_cam = point_in_camera(camera, T_world_body, point_world_m);
    let px = camera.project(&p_cam)?;
    Some((px - pixel, p_cam.z))
}

/// Robust kernel on the squared whitened error `s` (eq. 29's visual term
/// is `sum rho(|e / sigma|^2) / 2`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum RobustKernel {
    /// Quadratic up to the threshold, linear beyond.
    #[default]
    Huber,
    /// `k^2 log(1 + s / k^2)`: outliers' influence falls to zero.
    Cauchy,
    /// Plain least squares (no robustness; for comparison).
    Quadratic,
}

/// Squared whitened error (30 sigma) beyond which the robust kernels
/// give an observation no influence and a constant cost. Without it a
/// Huber kernel lets a landmark that projects absurdly far (near a
/// camera's plane, 1e7 px) dominate the cost and drag the poses away.
pub const GATE_SQ: f64 = 900.0;

impl RobustKernel {
    /// `(rho(s), rho'(s))` for threshold `k` (whitened units). `rho'` is the
    /// iteratively reweighted least squares weight: the gradient of
    /// `rho(|r|^2) / 2` is `rho' J^T r`, so the weighted normal equations
    /// have the true gradient. Huber and Cauchy are flat beyond
    /// [`GATE_SQ`].
    pub fn evaluate(self, s: f64, k: f64) -> (f64, f64) {
        match self {
            RobustKernel::Quadratic => (s, 1.0),
            _ if s >= GATE_SQ => (self.evaluate(GATE_SQ * (1.0 - 1e-12), k).0, 0.0),
            RobustKernel::Huber => {
                if s <= k * k {
                    (s, 1.0)
                } else {
                    let e = s.sqrt();
                    (2.0 * k * e - k * k, k / e)
                }
            }
            RobustKernel::Cauchy => {
                let k2 = k * k;
                (k2 * (s / k2).ln_1p(), 1.0 / (1.0 + s / k2))
            }
        }
    }
}
