//! Landmark initialisation and augmentation of the state.
//!
//! A landmark enters the state as a function of the current body pose
//! and of a point triangulated in the current left-camera frame,
//! `l = p_wb + R_wb (R_bc q + t_bc)`. Its covariance is the standard
//! EKF-SLAM augmentation: `P_ll = J P_xx J^T + R_wc Sigma_q R_wc^T` and
//! `P_lx = J P_x.`, with `J = dl/d[dtheta, dp] = [-R_wb [p_b]x, I]`.
//! `Sigma_q` is the triangulation's covariance, the inverse of the
//! Gauss-Newton information of the two pixel measurements about the
//! point with the two cameras held fixed:
//! `Sigma_q = sigma^2 (H_1^T H_1 + H_2^T H_2)^-1`.
//!
//! - Stereo: both views are the calibrated pair of the same instant, so
//!   the cameras are known exactly relative to each other.
//! - Mono (delayed): the first view is a past pose of the filter that is
//!   no longer in the state, and its error relative to the current pose
//!   is correlated with the state in a way the filter does not track (a
//!   cloned-pose filter would carry it; this one keeps the state small).
//!   Using the two-view information as if independent double-counts the
//!   filter's own motion estimate and made the filter overconfident
//!   (position NEES ~ 90 in the mono simulation). So the past view only
//!   supplies a soft depth: [`mono_point_covariance`] combines the
//!   current pixel's (lateral) information with a depth prior along the
//!   ray whose sigma is the larger of the inflated two-view depth sigma
//!   and `mono_depth_sigma_fraction` of the depth. The depth is then
//!   refined by the following frames' updates, as with inverse-depth
//!   initialisation, while xyz stays near-linear because the depth is
//!   already known to a fraction.

use nalgebra::{Matrix3, SMatrix, Vector2, Vector3};

use super::update::RigCamera;
use crate::imu::so3::hat;
use crate::two_view::{triangulate, TriangulationConfig};

pub(crate) type Matrix3x6 = SMatrix<f64, 3, 6>;

/// A landmark ready to be appended to the state.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct NewLandmark {
    pub position_world_m: Vector3<f64>,
    /// `dl / d[dtheta, dp]` of the current body pose.
    pub d_pose: Matrix3x6,
    /// Covariance of the triangulation, in the world frame.
    pub measurement_covariance_world: Matrix3<f64>,
}

/// `l = p + R (R_bc q + t_bc)` and its Jacobian with respect to the
/// body pose's error `[dtheta, dp]`.
pub(crate) fn landmark_from_camera_point(
    r_world_body: &Matrix3<f64>,
    p_world_body_m: &Vector3<f64>,
    camera: &RigCamera,
    point_cam_m: &Vector3<f64>,
) -> (Vector3<f64>, Matrix3x6) {
    let p_body = camera.r_body_cam * point_cam_m + camera.t_body_cam_m;
    let l = p_world_body_m + r_world_body * p_body;
    let mut d_pose = Matrix3x6::zeros();
    d_pose
        .fixed_view_mut::<3, 3>(0, 0)
        .copy_from(&(-r_world_body * hat(&p_body)));
    d_pose
        .fixed_view_mut::<3, 3>(0, 3)
        .copy_from(&Matrix3::identity());
    (l, d_pose)
}

/// Where a second view sits relative to the first (reference) camera:
/// `x_2 = R_21 x_1 + t_21`.
#[derive(Debug, Clone, Copy)]
pub(crate) struct RelativeView<'a> {
    pub camera: &'a RigCamera,
    pub r_21: Matrix3<f64>,
    pub t_21_m: Vector3<f64>,
}

/// Triangulates the reference camera's pixel `pixel_1` with the second
/// view's `pixel_2` and returns the point in the reference camera frame
/// with its covariance, or `None` when the rays do not give a
/// well-conditioned point in front of both cameras within
/// `max_reprojection_px` of both measurements.
pub(crate) fn triangulate_with_covariance(
    reference: &RigCamera,
    pixel_1: &Vector2<f64>,
    second: &RelativeView<'_>,
    pixel_2: &Vector2<f64>,
    config: &TriangulationConfig,
    sigma_px: f64,
    max_reprojection_px: f64,
) -> Option<(Vector3<f64>, Matrix3<f64>)> {
    let ray_1 = reference.model.unproject(pixel_1)?;
    let ray_2 = second.camera.model.unproject(pixel_2)?;
    let tri = triangulate(
        &second.r_21,
        &second.t_21_m,
        &ray_1.xy(),
        &ray_2.xy(),
        config,
    )
    .ok()?;
    let q1 = tri.point_c1;
    let q2 = second.r_21 * q1 + second.t_21_m;
    let (z1, j1) = reference.model.project_with_point_jacobian(&q1)?;
    let (z2, j2) = second.camera.model.project_with_point_jacobian(&q2)?;
    if (z1 - pixel_1).norm() > max_reprojection_px || (z2 - pixel_2).norm() > max_reprojection_px {
        return None;
    }
    let h2 = j2 * second.r_21;
    let information = (j1.transpose() * j1 + h2.transpose() * h2) / (sigma_px * sigma_px);
    let covariance = information.try_inverse()?;
    let covariance = (covariance + covariance.transpose()) * 0.5;
    if !covariance.iter().all(|v| v.is_finite()) || covariance.determinant() <= 0.0 {
        return None;
    }
    Some((q1, covariance))
}

/// Covariance of a mono landmark at `point_cam_m` (current camera frame):
/// the current pixel's information, `J^T J / sigma^2` (rank 2, across the
/// ray), plus a depth prior along the ray (see the module doc).
pub(crate) fn mono_point_covariance(
    camera: &RigCamera,
    point_cam_m: &Vector3<f64>,
    two_view_covariance: &Matrix3<f64>,
    sigma_px: f64,
    inflation: f64,
    depth_sigma_fraction: f64,
) -> Option<Matrix3<f64>> {
    let (_, j) = camera.model.project_with_point_jacobian(point_cam_m)?;
    let depth = point_cam_m.norm();
    let u = point_cam_m / depth;
    let two_view_var = u.dot(&(two_view_covariance * u)) * inflation;
    let depth_var = two_view_var.max((depth_sigma_fraction * depth).powi(2));
    let information = j.transpose() * j / (sigma_px * sigma_px) + u * u.transpose() / depth_var;
    let covariance = information.try_inverse()?;
    let covariance = (covariance + covariance.transpose()) * 0.5;
    covariance
        .iter()
        .all(|v| v.is_finite())
        .then_some(covariance)
}
