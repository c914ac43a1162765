//! The visual update: reprojection of the state's landmarks into the
//! cameras, per-observation chi-square gating, and the batch Kalman
//! update in Joseph form.
//!
//! Measurement model of landmark `l` (world) in camera `c`:
//! `z = pi_c(R_cb (R_wb^T (l - p_wb) - t_bc)) + n`, `n ~ N(0, sigma_px^2 I)`,
//! where `(R_bc, t_bc)` is the camera's `T_body_cam` and `pi_c` the
//! camera model with its distortion (the measurement is the distorted
//! pixel, as tracked). With `R_wb = R_hat Exp(dtheta)`, the body-frame
//! point moves by `[p_b]x dtheta`, which gives [`Projection`]'s blocks.

use nalgebra::{DMatrix, DVector, Matrix2, Matrix2x3, Matrix3, SMatrix, Vector2, Vector3};

use super::state::{NavNominal, NAV_DIM};
use crate::camera::CameraModel;
use crate::imu::so3::hat;

pub(crate) type Matrix2x6 = SMatrix<f64, 2, 6>;

/// A camera of the rig with its mounting split into the pieces the
/// model needs.
#[derive(Debug, Clone)]
pub(crate) struct RigCamera {
    pub model: CameraModel,
    pub r_body_cam: Matrix3<f64>,
    pub t_body_cam_m: Vector3<f64>,
}

impl RigCamera {
    /// The point in the camera frame of a body-frame point.
    pub fn body_to_cam(&self, p_body: &Vector3<f64>) -> Vector3<f64> {
        self.r_body_cam.tr_mul(&(p_body - self.t_body_cam_m))
    }
}

/// Predicted pixel of a landmark and its Jacobians with respect to the
/// error state's orientation and position (2x6, `[dtheta, dp]`) and to
/// the landmark (2x3). The velocity and bias columns are zero.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Projection {
    pub pixel: Vector2<f64>,
    pub d_pose: Matrix2x6,
    pub d_landmark: Matrix2x3<f64>,
}

/// Projects `landmark_world_m` into `camera`; `None` when the point is
/// behind the camera, nearer than `min_depth_m`, or outside the model.
pub(crate) fn project_landmark(
    nav: &NavNominal,
    camera: &RigCamera,
    landmark_world_m: &Vector3<f64>,
    min_depth_m: f64,
) -> Option<Projection> {
    let r = nav.rotation();
    let p_body = r.tr_mul(&(landmark_world_m - nav.position_world_m));
    let p_cam = camera.body_to_cam(&p_body);
    if !(p_cam.z > min_depth_m) {
        return None;
    }
    let (pixel, j_pi) = camera.model.project_with_point_jacobian(&p_cam)?;
    let j_body = j_pi * camera.r_body_cam.transpose();
    let d_landmark = j_body * r.transpose();
    let mut d_pose = Matrix2x6::zeros();
    d_pose
        .fixed_view_mut::<2, 3>(0, 0)
        .copy_from(&(j_body * hat(&p_body)));
    d_pose
        .fixed_view_mut::<2, 3>(0, 3)
        .copy_from(&(-d_landmark));
    Some(Projection {
        pixel,
        d_pose,
        d_landmark,
    })
}

/// One accepted 2-D observation in the batch.
#[derive(Debug, Clone, Copy)]
pub(crate) struct ObservationRow {
    /// First error-state column of the observed landmark.
    pub landmark_column: usize,
    pub d_pose: Matrix2x6,
    pub d_landmark: Matrix2x3<f64>,
    /// Measured minus predicted pixel.
    pub residual_px: Vector2<f64>,
}

/// Innovation covariance of one observation, `H P H^T + sigma^2 I`,
/// from the 9 columns its Jacobian touches.
pub(crate) fn innovation_covariance(
    covariance: &DMatrix<f64>,
    row: &ObservationRow,
    sigma_px: f64,
) -> Matrix2<f64> {
    let c = row.landmark_column;
    let ppp: SMatrix<f64, 6, 6> = covariance.fixed_view::<6, 6>(0, 0).into();
    let ppl: SMatrix<f64, 6, 3> = covariance.fixed_view::<6, 3>(0, c).into();
    let pll: Matrix3<f64> = covariance.fixed_view::<3, 3>(c, c).into();
    let cross = row.d_pose * ppl * row.d_landmark.transpose();
    row.d_pose * ppp * row.d_pose.transpose()
        + cross
        + cross.transpose()
        + row.d_landmark * pll * row.d_landmark.transpose()
        + Matrix2::identity() * (sigma_px * sigma_px)
}

/// Squared Mahalanobis distance of the observation's residual; `None`
/// when its innovation covariance is not positive definite.
pub(crate) fn mahalanobis_squared(
    covariance: &DMatrix<f64>,
    row: &ObservationRow,
    sigma_px: f64,
) -> Option<f64> {
    let s = innovation_covariance(covariance, row, sigma_px);
    let chol = s.cholesky()?;
    let whitened = chol.l().solve_lower_triangular(&row.residual_px)?;
    Some(whitened.norm_squared())
}

/// `out = M H^T` (n x 2k) for the sparse measurement Jacobian of `rows`.
fn times_h_transpose(m: &DMatrix<f64>, rows: &[ObservationRow], out: &mut DMatrix<f64>) {
    let n = m.nrows();
    out.resize_mut(n, 2 * rows.len(), 0.0);
    for (j, row) in rows.iter().enumerate() {
        let block = m.fixed_columns::<6>(0) * row.d_pose.transpose()
            + m.fixed_columns::<3>(row.landmark_column) * row.d_landmark.transpose();
        out.fixed_columns_mut::<2>(2 * j).copy_from(&block);
    }
}

/// Buffers of the batch update, kept between frames.
#[derive(Debug, Default)]
pub(crate) struct UpdateScratch {
    p_ht: DMatrix<f64>,
    s: DMatrix<f64>,
    residual: DVector<f64>,
}

/// The batch EKF update with all `rows`: returns the error-state
/// correction and replaces `covariance` with its Joseph-form posterior
/// `(I - K H) P (I - K H)^T + K R K^T`, symmetrised. `None` (and the
/// covariance untouched) when the innovation covariance is not positive
/// definite.
pub(crate) fn batch_update(
    covariance: &mut DMatrix<f64>,
    rows: &[ObservationRow],
    sigma_px: f64,
    scratch: &mut UpdateScratch,
) -> Option<DVector<f64>> {
    if rows.is_empty() {
        return None;
    }
    debug_assert!(covariance.nrows() >= NAV_DIM);
    let m = 2 * rows.len();
    let sigma2 = sigma_px * sigma_px;
    times_h_transpose(covariance, rows, &mut scratch.p_ht);
    // S = H (P H^T) + R.
    scratch.s.resize_mut(m, m, 0.0);
    scratch.residual.resize_vertically_mut(m, 0.0);
    for (i, row) in rows.iter().enumerate() {
        let block = row.d_pose * scratch.p_ht.fixed_rows::<6>(0)
            + row.d_landmark * scratch.p_ht.fixed_rows::<3>(row.landmark_column);
        scratch.s.fixed_rows_mut::<2>(2 * i).copy_from(&block);
        scratch
            .residual
            .fixed_rows_mut::<2>(2 * i)
            .copy_from(&row.residual_px);
    }
    for i in 0..m {
        scratch.s[(i, i)] += sigma2;
    }
    let s = (&scratch.s + scratch.s.transpose()) * 0.5;
    let chol = s.cholesky()?;
    // K^T = S^-1 (P H^T)^T.
    let gain_t = chol.solve(&scratch.p_ht.transpose());
    let dx = gain_t.tr_mul(&scratch.residual);
    if !dx.iter().all(|v| v.is_finite()) {
        return None;
    }
    // Joseph form without forming I - K H: P1 = P - K (H P);
    // P+ = P1 - (P1 H^T) K^T + K R K^T.
    covariance.gemm_tr(-1.0, &gain_t, &scratch.p_ht.transpose(), 1.0);
    times_h_transpose(covariance, rows, &mut scratch.p_ht);
    covariance.gemm(-1.0, &scratch.p_ht, &gain_t, 1.0);
    covariance.gemm_tr(sigma2, &gain_t, &gain_t, 1.0);
    symmetrize(covariance);
    Some(dx)
}

/// `P <- (P + P^T) / 2`, in place.
pub(crate) fn symmetrize(p: &mut DMatrix<f64>) {
    let n = p.nrows();
    for j in 0..n {
        for i in (j + 1)..n {
            let m = 0.5 * (p[(i, j)] + p[(j, i)]);
            p[(i, j)] = m;
            p[(j, i)] = m;
        }
    }
}
