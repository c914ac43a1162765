//! Levenberg-Marquardt over pinhole + radial-tangential intrinsics and every
//! view's board pose, started from Zhang's closed form (Zhang 2000,
//! section 3.3, with the distortion of OpenCV / Kalibr `radtan`), with
//! per-view errors and outlier views reported and left out.

use nalgebra::{DMatrix, DVector, Matrix3, SMatrix, Vector2, Vector3};
use rigslam::camera::PinholeRadtan;
use rigslam::imu::so3;

use crate::homography::homography_dlt;
use crate::zhang::{intrinsics_from_homographies, pose_from_homography};

/// Why intrinsics could not be estimated, with what to recollect.
#[derive(Debug, thiserror::Error)]
pub enum IntrinsicsError {
    #[error("only {found} usable views; need at least {needed}: collect more images with the board tilted in different directions")]
    TooFewViews { found: usize, needed: usize },
    #[error("aspect ratio {0}: fx / fy must be a positive finite number (1 for square pixels)")]
    BadAspectRatio(f64),
    #[error("the views do not constrain the camera (boards nearly parallel to the sensor?): recollect with the board tilted by 20-45 degrees in several directions")]
    Degenerate,
}

/// Which intrinsics [`calibrate_intrinsics_with`] holds, and whether it
/// leaves outlier views out. The default frees all nine and rejects
/// outliers, as [`calibrate_intrinsics`] does.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct IntrinsicsOptions {
    /// Hold `fx / fy` at this ratio (OpenCV's `CALIB_FIX_ASPECT_RATIO`;
    /// its sample writes `aspectRatio: 1` for fx = fy).
    pub fix_aspect_ratio: Option<f64>,
    /// Hold k3 at zero (OpenCV's `CALIB_FIX_K3`; Kalibr's 4-coefficient radtan).
    pub fix_k3: bool,
    /// Leave views whose RMS is far above the median out of the final fit.
    pub reject_outlier_views: bool,
}

impl Default for IntrinsicsOptions {
    fn default() -> Self {
        Self {
            fix_aspect_ratio: None,
            fix_k3: false,
            reject_outlier_views: true,
        }
    }
}

impl IntrinsicsOptions {
    /// Folds the held intrinsics out of a 2x9 intrinsic Jacobian: with
    /// `fy = fx / a` the fx column becomes `d/dfx + d/dfy / a` and the fy
    /// column zero; a fixed k3 has a zero column. Zero columns keep their
    /// parameter where [`Self::enforce`] puts it.
    fn fold_jacobian(&self, j: &mut SMatrix<f64, 2, 9>) {
        if let Some(a) = self.fix_aspect_ratio {
            let fy_column = j.column(1).into_owned();
            let mut fx_column = j.column_mut(0);
            fx_column += fy_column / a;
            j.column_mut(1).fill(0.0);
        }
        if self.fix_k3 {
            j.column_mut(8).fill(0.0);
        }
    }

    /// Puts the held intrinsics at their values.
    fn enforce(&self, camera: &mut PinholeRadtan) {
        if let Some(a) = self.fix_aspect_ratio {
            camera.fy = camera.fx / a;
        }
        if self.fix_k3 {
            camera.distortion[4] = 0.0;
        }
    }
}

/// Fewest views accepted.
pub const MIN_VIEWS: usize = 3;
/// A view is an outlier when its RMS exceeds this multiple of the median...
const OUTLIER_MEDIAN_FACTOR: f64 = 3.0;
/// ...and this absolute floor, px.
const OUTLIER_FLOOR_PX: f64 = 0.6;

/// One view's pose and fit.
#[derive(Debug, Clone)]
#[allow(non_snake_case)]
pub struct ViewFit {
    /// Maps board coordinates into the camera.
    pub R_cam_board: Matrix3<f64>,
    pub t_cam_board: Vector3<f64>,
    /// Root-mean-square reprojection error, px (over both coordinates' norms).
    pub rms_px: f64,
    /// Per-corner residual, observed minus predicted, px.
    pub residuals_px: Vec<Vector2<f64>>,
    /// Left out of the final solution as an outlier.
    pub outlier: bool,
}

/// Result of [`calibrate_intrinsics`].
#[derive(Debug, Clone)]
pub struct IntrinsicsCalibration {
    pub camera: PinholeRadtan,
    /// The closed-form start `[fx, fy, cx, cy]`.
    pub zhang_pinhole: [f64; 4],
    pub views: Vec<ViewFit>,
    /// RMS over the corners of the views used, px.
    pub rms_px: f64,
    pub views_used: usize,
    pub iterations: usize,
}

fn pose_point(r: &Matrix3<f64>, t: &Vector3<f64>, p: &Vector3<f64>) -> Vector3<f64> {
    r * p + t
}

/// Sum of squared residuals of the given views.
fn cost(
    camera: &PinholeRadtan,
    poses: &[(Matrix3<f64>, Vector3<f64>)],
    board: &[Vector3<f64>],
    views: &[Vec<Vector2<f64>>],
    active: &[bool],
) -> f64 {
    let mut total = 0.0;
    for (k, view) in views.iter().enumerate().filter(|(k, _)| active[*k]) {
        let (r, t) = &poses[k];
        for (p, obs) in board.iter().zip(view) {
            total += match camera.project(&pose_point(r, t, p)) {
                Some(px) => (obs - px).norm_squared(),
                None => 1e6,
            };
        }
    }
    total
}

fn with_intrinsics(camera: &PinholeRadtan, x: &[f64]) -> PinholeRadtan {
    PinholeRadtan {
        fx: x[0],
        fy: x[1],
        cx: x[2],
        cy: x[3],
        distortion: [x[4], x[5], x[6], x[7], x[8]],
        ..camera.clone()
    }
}

/// Levenberg-Marquardt on the active views; returns the iteration count.
/// Pose updates are on the left: `R <- Exp(dphi) R`, `t <- t + dt`.
fn refine(
    camera: &mut PinholeRadtan,
    poses: &mut [(Matrix3<f64>, Vector3<f64>)],
    board: &[Vector3<f64>],
    views: &[Vec<Vector2<f64>>],
    active: &[bool],
    max_iterations: usize,
    options: &IntrinsicsOptions,
) -> usize {
    let n_params = 9 + 6 * views.len();
    let mut lambda = 1e-3;
    let mut current = cost(camera, poses, board, views, active);
    let mut iterations = 0;
    for _ in 0..max_iterations {
        iterations += 1;
        let mut jtj = DMatrix::<f64>::zeros(n_params, n_params);
        let mut jtr = DVector::<f64>::zeros(n_params);
        for (k, view) in views.iter().enumerate().filter(|(k, _)| active[*k]) {
            let (r, t) = &poses[k];
            let base = 9 + 6 * k;
            for (p, obs) in board.iter().zip(view) {
                let p_cam = pose_point(r, t, p);
                let Some((px, d_px_d_point, d_px_d_intr)) = camera.project_with_jacobians(&p_cam)
                else {
                    continue;
                };
                let residual = px - obs;
                let mut d_px_d_intr = d_px_d_intr;
                options.fold_jacobian(&mut d_px_d_intr);
                let mut j = SMatrix::<f64, 2, 15>::zeros();
                j.fixed_view_mut::<2, 9>(0, 0).copy_from(&d_px_d_intr);
                // d(Exp(dphi) R p + t)/d dphi = -[R p]x.
                let rp = r * p;
                j.fixed_view_mut::<2, 3>(0, 9)
                    .copy_from(&(d_px_d_point * -so3::hat(&rp)));
                j.fixed_view_mut::<2, 3>(0, 12).copy_from(&d_px_d_point);
                let jtj_local = j.transpose() * j;
                let jtr_local = j.transpose() * residual;
                let index = |a: usize| if a < 9 { a } else { base + a - 9 };
                for a in 0..15 {
                    jtr[index(a)] += jtr_local[a];
                    for b in 0..15 {
                        jtj[(index(a), index(b))] += jtj_local[(a, b)];
                    }
                }
            }
        }
        let mut improved = false;
        while lambda < 1e10 {
            let mut damped = jtj.clone();
            for i in 0..n_params {
                // Parameters of inactive views have zero rows; keep them fixed.
                damped[(i, i)] +=
                    lambda * jtj[(i, i)].max(1e-9) + if jtj[(i, i)] == 0.0 { 1.0 } else { 0.0 };
            }
            let Some(chol) = damped.cholesky() else {
                lambda *= 10.0;
                continue;
            };
            let delta = chol.solve(&-&jtr);
            let intr: Vec<f64> = [camera.fx, camera.fy, camera.cx, camera.cy]
                .iter()
                .chain(camera.distortion.iter())
                .zip(delta.iter())
                .map(|(x, d)| x + d)
                .collect();
            let mut trial_camera = with_intrinsics(camera, &intr);
            options.enforce(&mut trial_camera);
            let trial_poses: Vec<(Matrix3<f64>, Vector3<f64>)> = poses
                .iter()
                .enumerate()
                .map(|(k, (r, t))| {
                    let d = delta.rows(9 + 6 * k, 6);
                    (
                        so3::exp(&Vector3::new(d[0], d[1], d[2])) * r,
                        t + Vector3::new(d[3], d[4], d[5]),
                    )
                })
                .collect();
            let trial = cost(&trial_camera, &trial_poses, board, views, active);
            if trial < current {
                improved = current - trial > 1e-12 * current;
                *camera = trial_camera;
                poses.copy_from_slice(&trial_poses);
                current = trial;
                lambda = (lambda * 0.3).max(1e-12);
                break;
            }
            lambda *= 10.0;
        }
        if !improved {
            break;
        }
    }
    iterations
}

fn view_fit(
    camera: &PinholeRadtan,
    pose: &(Matrix3<f64>, Vector3<f64>),
    board: &[Vector3<f64>],
    view: &[Vector2<f64>],
) -> ViewFit {
    let residuals_px: Vec<Vector2<f64>> = board
        .iter()
        .zip(view)
        .map(
            |(p, obs)| match camera.project(&pose_point(&pose.0, &pose.1, p)) {
                Some(px) => obs - px,
                None => Vector2::new(f64::INFINITY, f64::INFINITY),
            },
        )
        .collect();
    let rms_px = (residuals_px.iter().map(|r| r.norm_squared()).sum::<f64>()
        / residuals_px.len() as f64)
        .sqrt();
    ViewFit {
        R_cam_board: pose.0,
        t_cam_board: pose.1,
        rms_px,
        residuals_px,
        outlier: false,
    }
}

fn median(values: &mut [f64]) -> f64 {
    values.sort_by(f64::total_cmp);
    values[values.len() / 2]
}

/// Intrinsics from views of a planar board: `board` holds the corners in
/// board coordinates (z = 0), `views[k][i]` the pixel of corner `i` in view
/// `k`. Zhang's closed form, then LM over all views; views whose RMS is
/// more than three times the median (and above 0.6 px) are marked
/// outliers and the LM is rerun without them.
pub fn calibrate_intrinsics(
    width: u32,
    height: u32,
    board: &[Vector3<f64>],
    views: &[Vec<Vector2<f64>>],
) -> Result<IntrinsicsCalibration, IntrinsicsError> {
    calibrate_intrinsics_with(width, height, board, views, &IntrinsicsOptions::default())
}

/// [`calibrate_intrinsics`] with some intrinsics held or outlier rejection
/// off (see [`IntrinsicsOptions`]).
pub fn calibrate_intrinsics_with(
    width: u32,
    height: u32,
    board: &[Vector3<f64>],
    views: &[Vec<Vector2<f64>>],
    options: &IntrinsicsOptions,
) -> Result<IntrinsicsCalibration, IntrinsicsError> {
    if let Some(a) = options.fix_aspect_ratio {
        if !(a > 0.0 && a.is_finite()) {
            return Err(IntrinsicsError::BadAspectRatio(a));
        }
    }
    if views.len() < MIN_VIEWS {
        return Err(IntrinsicsError::TooFewViews {
            found: views.len(),
            needed: MIN_VIEWS,
        });
    }
    let plane: Vec<Vector2<f64>> = board.iter().map(|p| p.xy()).collect();
    let homographies: Vec<Matrix3<f64>> = views
        .iter()
        .map(|v| homography_dlt(&plane, v).ok_or(IntrinsicsError::Degenerate))
        .collect::<Result<_, _>>()?;
    let zhang_pinhole =
        intrinsics_from_homographies(&homographies).ok_or(IntrinsicsError::Degenerate)?;
    if !zhang_pinhole.iter().all(|v| v.is_finite()) {
        return Err(IntrinsicsError::Degenerate);
    }
    let mut camera = PinholeRadtan::new(width, height, zhang_pinhole, [0.0; 5])
        .map_err(|_| IntrinsicsError::Degenerate)?;
    if let Some(a) = options.fix_aspect_ratio {
        // The start closest to Zhang's with fx / fy = a: the same area fx fy.
        camera.fx = (camera.fx * camera.fy * a).sqrt();
        options.enforce(&mut camera);
    }
    let mut poses: Vec<(Matrix3<f64>, Vector3<f64>)> = homographies
        .iter()
        .map(|h| pose_from_homography(h, zhang_pinhole))
        .collect();
    let mut active = vec![true; views.len()];
    let mut iterations = refine(&mut camera, &mut poses, board, views, &active, 100, options);
    let mut rms: Vec<f64> = (0..views.len())
        .map(|k| view_fit(&camera, &poses[k], board, &views[k]).rms_px)
        .collect();
    let threshold = (OUTLIER_MEDIAN_FACTOR * median(&mut rms.clone())).max(OUTLIER_FLOOR_PX);
    if options.reject_outlier_views {
        for (k, r) in rms.iter_mut().enumerate() {
            active[k] = *r <= threshold;
        }
    }
    let views_used = active.iter().filter(|&&a| a).count();
    if views_used < MIN_VIEWS {
        return Err(IntrinsicsError::TooFewViews {
            found: views_used,
            needed: MIN_VIEWS,
        });
    }
    if views_used < views.len() {
        iterations += refine(&mut camera, &mut poses, board, views, &active, 100, options);
    }
    // Outlier views keep their pose re-fitted to the final intrinsics so
    // their reported error is meaningful.
    let fixed = camera.clone();
    for k in (0..views.len()).filter(|&k| !active[k]) {
        let only = (0..views.len()).map(|j| j == k).collect::<Vec<_>>();
        refine_pose_only(&fixed, &mut poses, board, views, &only);
    }
    let fits: Vec<ViewFit> = (0..views.len())
        .map(|k| ViewFit {
            outlier: !active[k],
            ..view_fit(&camera, &poses[k], board, &views[k])
        })
        .collect();
    let (sum_sq, count) = fits
        .iter()
        .filter(|f| !f.outlier)
        .flat_map(|f| f.residuals_px.iter())
        .fold((0.0, 0usize), |(s, n), r| (s + r.norm_squared(), n + 1));
    Ok(IntrinsicsCalibration {
        camera,
        zhang_pinhole,
        views: fits,
        rms_px: (sum_sq / count as f64).sqrt(),
        views_used,
        iterations,
    })
}

/// LM on one view's pose with the intrinsics held, on undistorted
/// normalised coordinates.
fn refine_pose_only(
    camera: &PinholeRadtan,
    poses: &mut [(Matrix3<f64>, Vector3<f64>)],
    board: &[Vector3<f64>],
    views: &[Vec<Vector2<f64>>],
    only: &[bool],
) {
    let k = only.iter().position(|&o| o).expect("one view selected");
    let (r, t) = poses[k];
    let pts: Vec<Vector3<f64>> = board.to_vec();
    let normalised: Vec<Vector2<f64>> = views[k]
        .iter()
        .map(|px| {
            camera
                .unproject(px)
                .map_or(Vector2::zeros(), |ray| ray.xy())
        })
        .collect();
    let selected = vec![true; pts.len()];
    let (r, t) =
        rigslam::two_view::pnp::refine_absolute_pose(&r, &t, &pts, &normalised, &selected, 20);
    poses[k] = (r, t);
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Rotation3;
    use rand::{Rng, SeedableRng};

    type Synthetic = (PinholeRadtan, Vec<Vector3<f64>>, Vec<Vec<Vector2<f64>>>);

    /// Synthetic views of a 9x6 board through a known distorted camera,
    /// with uniform noise of +-`noise_px`; view 4's corners are corrupted by 3 px.
    fn synthetic_views(noise_px: f64) -> Synthetic {
        let truth = PinholeRadtan::new(
            640,
            480,
            [536.0, 534.0, 342.0, 236.0],
            [-0.27, 0.05, 0.0015, -0.0003, 0.02],
        )
        .expect("valid");
        synthetic_views_of(truth, noise_px)
    }

    fn synthetic_views_of(truth: PinholeRadtan, noise_px: f64) -> Synthetic {
        let board: Vec<Vector3<f64>> = (0..54)
            .map(|i| Vector3::new((i % 9) as f64 * 0.025, (i / 9) as f64 * 0.025, 0.0))
            .collect();
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let mut views = Vec::new();
        for k in 0..10 {
            let angle = k as f64 * 0.6;
            let rv = Vector3::new(
                0.4 * angle.cos(),
                0.4 * angle.sin(),
                0.2 * (k as f64 - 5.0) / 5.0,
            );
            let r = Rotation3::from_scaled_axis(rv).into_inner();
            let t = Vector3::new(
                -0.1 + 0.03 * angle.sin(),
                -0.06 + 0.02 * angle.cos(),
                0.3 + 0.02 * k as f64,
            );
            let view: Vec<Vector2<f64>> = board
                .iter()
                .map(|p| {
                    let px = truth.project(&(r * p + t)).expect("in front");
                    px + Vector2::new(rng.gen_range(-1.0..1.0), rng.gen_range(-1.0..1.0)) * noise_px
                })
                .collect();
            views.push(view);
        }
        for (i, c) in views[4].iter_mut().enumerate() {
            c.x += if i % 2 == 0 { 3.0 } else { -3.0 };
        }
        (truth, board, views)
    }

    #[test]
    fn recovers_exact_camera_without_noise_despite_an_outlier_view() {
        let (truth, board, views) = synthetic_views(0.0);
        let result = calibrate_intrinsics(640, 480, &board, &views).expect("solvable");
        let c = &result.camera;
        let estimate = [c.fx, c.fy, c.cx, c.cy].into_iter().chain(c.distortion);
        let expected = [truth.fx, truth.fy, truth.cx, truth.cy]
            .into_iter()
            .chain(truth.distortion);
        for (e, t) in estimate.zip(expected) {
            assert!((e - t).abs() < 1e-6 * t.abs().max(1.0), "{c:?}");
        }
        assert!(result.views[4].outlier);
        assert!(result.rms_px < 1e-6);
    }

    #[test]
    fn noisy_views_fit_to_the_noise_level() {
        let (truth, board, views) = synthetic_views(0.17);
        let result = calibrate_intrinsics(640, 480, &board, &views).expect("solvable");
        let c = &result.camera;
        // Uniform noise of +-0.17 px: RMS of the 2-D residual 0.139 px.
        assert!((c.fx - truth.fx).abs() < 1.0, "fx {}", c.fx);
        assert!((c.fy - truth.fy).abs() < 1.0, "fy {}", c.fy);
        assert!((c.cx - truth.cx).abs() < 1.0, "cx {}", c.cx);
        assert!((c.cy - truth.cy).abs() < 1.0, "cy {}", c.cy);
        // k1, k2, k3 trade off against each other over a limited field, so
        // compare the distortion as a function over the field the views cover.
        let mut worst_px: f64 = 0.0;
        for corner in views
            .iter()
            .enumerate()
            .filter(|(k, _)| *k != 4)
            .flat_map(|(_, v)| v)
        {
            let ray = truth.unproject(corner).expect("inside the fold radius");
            let d = truth.project(&ray).expect("in view") - c.project(&ray).expect("in view");
            worst_px = worst_px.max(d.norm());
        }
        assert!(worst_px < 1.0, "projections differ by {worst_px} px");
        assert!(result.views[4].outlier);
        assert_eq!(result.views_used, 9);
        assert!(result.rms_px < 0.15, "rms {}", result.rms_px);
    }

    fn assert_recovers(c: &PinholeRadtan, truth: &PinholeRadtan) {
        let estimate = [c.fx, c.fy, c.cx, c.cy].into_iter().chain(c.distortion);
        let expected = [truth.fx, truth.fy, truth.cx, truth.cy]
            .into_iter()
            .chain(truth.distortion);
        for (e, t) in estimate.zip(expected) {
            assert!((e - t).abs() < 1e-6 * t.abs().max(1.0), "{c:?}");
        }
    }

    #[test]
    fn held_aspect_ratio_and_k3_recover_a_camera_that_has_them() {
        // fx / fy = 1.004 and k3 = 0 in the truth; held, the other seven
        // intrinsics are recovered exactly and the held ones stay put.
        let truth = PinholeRadtan::new(
            640,
            480,
            [536.0, 536.0 / 1.004, 342.0, 236.0],
            [-0.27, 0.05, 0.0015, -0.0003, 0.0],
        )
        .expect("valid");
        let (truth, board, views) = synthetic_views_of(truth, 0.0);
        let options = IntrinsicsOptions {
            fix_aspect_ratio: Some(1.004),
            fix_k3: true,
            ..IntrinsicsOptions::default()
        };
        let result =
            calibrate_intrinsics_with(640, 480, &board, &views, &options).expect("solvable");
        assert_recovers(&result.camera, &truth);
        assert!((result.camera.fx / result.camera.fy - 1.004).abs() < 1e-12);
        assert_eq!(result.camera.distortion[4], 0.0);
        assert!(result.views[4].outlier);
    }

    #[test]
    fn a_held_aspect_ratio_is_kept_when_the_truth_differs() {
        // Truth fx / fy = 536 / 534; held at 1 the fit must keep fx = fy
        // (between the two) and pay for it in residuals.
        let (_, board, views) = synthetic_views(0.0);
        let options = IntrinsicsOptions {
            fix_aspect_ratio: Some(1.0),
            ..IntrinsicsOptions::default()
        };
        let result =
            calibrate_intrinsics_with(640, 480, &board, &views, &options).expect("solvable");
        assert_eq!(result.camera.fx, result.camera.fy);
        assert!(
            result.camera.fx > 534.0 && result.camera.fx < 536.0,
            "{:?}",
            result.camera
        );
        assert!(result.rms_px > 1e-3, "rms {}", result.rms_px);
    }

    #[test]
    fn without_rejection_the_corrupted_view_stays_in() {
        let (_, board, views) = synthetic_views(0.0);
        let options = IntrinsicsOptions {
            reject_outlier_views: false,
            ..IntrinsicsOptions::default()
        };
        let result =
            calibrate_intrinsics_with(640, 480, &board, &views, &options).expect("solvable");
        assert_eq!(result.views_used, views.len());
        assert!(result.views.iter().all(|v| !v.outlier));
        assert!(result.rms_px > 0.1, "rms {}", result.rms_px);
    }

    #[test]
    fn a_non_positive_aspect_ratio_is_an_error() {
        let (_, board, views) = synthetic_views(0.0);
        for a in [0.0, -1.0, f64::NAN] {
            let options = IntrinsicsOptions {
                fix_aspect_ratio: Some(a),
                ..IntrinsicsOptions::default()
            };
            assert!(matches!(
                calibrate_intrinsics_with(640, 480, &board, &views, &options),
                Err(IntrinsicsError::BadAspectRatio(_))
            ));
        }
    }

    #[test]
    fn too_few_views_is_an_error() {
        let board = vec![Vector3::zeros(); 4];
        let views = vec![vec![Vector2::zeros(); 4]; 2];
        assert!(matches!(
            calibrate_intrinsics(640, 480, &board, &views),
            Err(IntrinsicsError::TooFewViews { found: 2, .. })
        ));
    }
}
