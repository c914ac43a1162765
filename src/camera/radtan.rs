//! Pinhole projection with OpenCV's radial-tangential distortion
//! (k1, k2, p1, p2, k3), Kalibr's `pinhole` + `radtan`.
//!
//! # The model
//!
//! A point `P = (X, Y, Z)` in the camera frame (z forward, Z > 0) lands on
//! the normalised plane at `x = X / Z`, `y = Y / Z`; with `r^2 = x^2 + y^2`
//! the distortion is (OpenCV's `projectPoints`, Brown-Conrady):
//!
//! ```text
//! radial = 1 + k1 r^2 + k2 r^4 + k3 r^6
//! x_d    = x radial + 2 p1 x y + p2 (r^2 + 2 x^2)
//! y_d    = y radial + p1 (r^2 + 2 y^2) + 2 p2 x y
//! u      = fx x_d + cx
//! v      = fy y_d + cy
//! ```
//!
//! # Where the model can be inverted
//!
//! Along a ray of the normalised plane the radial part maps `r` to
//! `r_d(r) = r radial(r)`, with derivative
//!
//! ```text
//! d r_d / d r = 1 + 3 k1 r^2 + 5 k2 r^4 + 7 k3 r^6.
//! ```
//!
//! Where that derivative first reaches zero, the *fold radius*, the image
//! of the plane folds back on itself: points beyond it land on pixels that
//! points inside it already own. [`PinholeRadtan::max_valid_radius`]
//! computes it (infinite when the derivative never vanishes); `project`
//! refuses points at or beyond it and `unproject` only returns rays inside
//! it, so the two are inverse bijections on that disc. The tangential terms
//! (|p| ~ 1e-4 for real lenses) are left out of the fold criterion;
//! `unproject` still checks that the full 2x2 Jacobian keeps a positive
//! determinant at every ray it returns.
//!
//! EuRoC's VI-Sensor (`V1_01/mav0/cam{0,1}/sensor.yaml`, k3 = 0): the
//! quadratic `1 + 3 k1 s + 5 k2 s^2` in `s = r^2` has no real root
//! (discriminant `9 k1^2 - 20 k2 = -0.756` for cam0, `-0.766` for cam1),
//! so neither camera folds: the fold radius is infinite. Over the image
//! the derivative stays above 0.511 (cam0) and 0.514 (cam1), its minimum
//! being at `r = 1.07`, while the farthest image corner (outer edge of the
//! corner pixel) lies at normalised radius 1.372 (cam0) and 1.373 (cam1).
//! Unprojection therefore converges over every pixel of both images
//! (round-trip error below 5e-11 px, measured by the tests).
//! Truncating the same lens to k1 alone would fold at
//! `r = 1 / sqrt(3 |k1|) = 1.085`, inside the image: its radial map peaks
//! at distorted radius 0.723 and about a fifth of the pixels (the corners)
//! would have no ray (test `folding_model_refuses_points_and_pixels_beyond_the_fold`).

use nalgebra::{Matrix2, Matrix2x3, Matrix3x2, SMatrix, Vector2, Vector3};

use super::pinhole::{self, Distortion, Pinhole};
use super::polynomial;
use super::CameraError;

/// Pinhole camera with radial-tangential distortion, as OpenCV and Kalibr
/// (`pinhole` + `radtan`) define it. See the module documentation for the
/// equations. The fields are public but only [`Self::new`] and
/// [`Self::from_kalibr`] validate them.
#[derive(Debug, Clone, PartialEq)]
pub struct PinholeRadtan {
    /// Image width, pixels.
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
    /// Focal length along x, pixels.
    pub fx: f64,
    /// Focal length along y, pixels.
    pub fy: f64,
    /// Principal point x, pixels.
    pub cx: f64,
    /// Principal point y, pixels.
    pub cy: f64,
    /// k1, k2, p1, p2, k3 (OpenCV's order), on the normalised plane.
    pub distortion: [f64; 5],
}

/// Newton iterations allowed when inverting the distortion.
const UNDISTORT_MAX_ITERATIONS: usize = 50;
/// Convergence threshold on the distorted normalised coordinates
/// (5e-11 px for a 500 px focal length).
const UNDISTORT_TOLERANCE: f64 = 1e-13;
/// Smallest step fraction the backtracking line search tries.
const MIN_STEP_FRACTION: f64 = 1e-6;

/// Names of the intrinsics in the order [`PinholeRadtan::project_with_jacobians`]
/// differentiates them.
pub const RADTAN_INTRINSIC_NAMES: [&str; 9] =
    ["fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3"];

impl PinholeRadtan {
    /// A validated camera: non-zero image size, finite intrinsics and
    /// distortion, positive focal lengths. `pinhole = [fx, fy, cx, cy]`
    /// in pixels, `distortion = [k1, k2, p1, p2, k3]`.
    pub fn new(
        width: u32,
        height: u32,
        pinhole: [f64; 4],
        distortion: [f64; 5],
    ) -> Result<Self, CameraError> {
        // `pinhole` then `distortion` is the Jacobian's column order.
        pinhole::validate(width, height, pinhole, &distortion, &RADTAN_INTRINSIC_NAMES)?;
        let [fx, fy, cx, cy] = pinhole;
        Ok(Self {
            width,
            height,
            fx,
            fy,
            cx,
            cy,
            distortion,
        })
    }

    /// A camera from Kalibr/EuRoC lists: `intrinsics: [fu, fv, cu, cv]`
    /// and `distortion_coefficients` with 4 values (Kalibr's radtan,
    /// k1 k2 p1 p2; k3 = 0) or 5 (OpenCV's k1 k2 p1 p2 k3).
    pub fn from_kalibr(
        width: u32,
        height: u32,
        intrinsics: &[f64],
        distortion: &[f64],
    ) -> Result<Self, CameraError> {
        let pinhole = pinhole::pinhole_from_kalibr(intrinsics)?;
        let coefficients = match *distortion {
            [k1, k2, p1, p2] => [k1, k2, p1, p2, 0.0],
            [k1, k2, p1, p2, k3] => [k1, k2, p1, p2, k3],
            _ => {
                return Err(CameraError::WrongLength {
                    field: "distortion_coefficients",
                    expected: "4 (k1, k2, p1, p2) or 5 (k1, k2, p1, p2, k3)",
                    got: distortion.len(),
                })
            }
        };
        Self::new(width, height, pinhole, coefficients)
    }

    /// Coefficients of `d r_d / d r` as a polynomial in `s = r^2`:
    /// `1 + 3 k1 s + 5 k2 s^2 + 7 k3 s^3`.
    fn radial_derivative_polynomial(&self) -> [f64; 4] {
        let [k1, k2, _, _, k3] = self.distortion;
        [1.0, 3.0 * k1, 5.0 * k2, 7.0 * k3]
    }

    /// Fold radius on the normalised plane: the smallest `r > 0` where
    /// `d(r radial(r))/dr = 1 + 3 k1 r^2 + 5 k2 r^4 + 7 k3 r^6` reaches
    /// zero, or `f64::INFINITY` if it never does. Beyond it the model is
    /// not invertible (see the module documentation); `project` returns
    /// `None` there and `unproject` never returns a ray beyond it.
    pub fn max_valid_radius(&self) -> f64 {
        let [k1, k2, _, _, k3] = self.distortion;
        if k3 == 0.0 {
            // The common case (EuRoC, most OpenCV calibrations): the
            // derivative is the quadratic 1 + 3 k1 s + 5 k2 s^2 in s = r^2,
            // solved in closed form. `project` asks for this on every
            // call, so it must be cheap.
            return smallest_positive_quadratic_root(5.0 * k2, 3.0 * k1, 1.0)
                .map_or(f64::INFINITY, f64::sqrt);
        }
        self.max_valid_radius_by_root_search()
    }

    /// The fold radius by the general root search (any k3).
    fn max_valid_radius_by_root_search(&self) -> f64 {
        let g = self.radial_derivative_polynomial();
        polynomial::root_magnitude_bound(&g)
            .and_then(|bound| polynomial::smallest_positive_root(&g, bound))
            .map_or(f64::INFINITY, f64::sqrt)
    }

    /// Distorted radius `r radial(r)` the fold radius maps to: the largest
    /// normalised image radius the radial part reaches (infinite when the
    /// model does not fold).
    pub fn max_valid_distorted_radius(&self) -> f64 {
        let r = self.max_valid_radius();
        if r.is_finite() {
            self.radial_map(r)
        } else {
            f64::INFINITY
        }
    }

    /// `r_d(r) = r radial(r)`, the radial part of the distortion.
    fn radial_map(&self, r: f64) -> f64 {
        let [k1, k2, _, _, k3] = self.distortion;
        let r2 = r * r;
        r * (1.0 + r2 * (k1 + r2 * (k2 + r2 * k3)))
    }

    /// fx, fy, cx, cy.
    fn pinhole_model(&self) -> Pinhole {
        Pinhole::from_array([self.fx, self.fy, self.cx, self.cy])
    }

    /// Pixel of a point in the camera frame; `None` behind the camera
    /// (z <= machine epsilon) or at or beyond the fold radius.
    pub fn project(&self, p_cam: &Vector3<f64>) -> Option<Vector2<f64>> {
        self.pinhole_model().project(self, p_cam)
    }

    /// Pixel of a point with the analytic Jacobians of the pixel with
    /// respect to the point (2x3) and to the intrinsics (2x9, columns in
    /// the order of [`RADTAN_INTRINSIC_NAMES`]: fx fy cx cy k1 k2 p1 p2 k3).
    /// `None` where [`Self::project`] is `None`.
    ///
    /// Chain rule: `d px / d P = diag(fx, fy) * D(x) * d x / d P` with `D`
    /// the [`Self::distort_jacobian`] and
    /// `d x / d P = [[1/Z, 0, -X/Z^2], [0, 1/Z, -Y/Z^2]]`; the intrinsic
    /// columns differentiate the model equations term by term.
    #[allow(clippy::type_complexity)]
    pub fn project_with_jacobians(
        &self,
        p_cam: &Vector3<f64>,
    ) -> Option<(Vector2<f64>, Matrix2x3<f64>, SMatrix<f64, 2, 9>)> {
        let projection = self
            .pinhole_model()
            .project_with_point_jacobian(self, p_cam)?;
        let (xn, d) = (projection.xn, projection.xd);
        let (x, y) = (xn.x, xn.y);
        let r2 = x * x + y * y;
        let (fx, fy) = (self.fx, self.fy);
        #[rustfmt::skip]
        let d_px_d_intrinsics = SMatrix::<f64, 2, 9>::from_row_slice(&[
            // fx   fy   cx   cy   k1          k2               p1                        p2                        k3
            d.x,  0.0, 1.0, 0.0, fx * x * r2, fx * x * r2 * r2, fx * 2.0 * x * y,          fx * (r2 + 2.0 * x * x), fx * x * r2 * r2 * r2,
            0.0,  d.y, 0.0, 1.0, fy * y * r2, fy * y * r2 * r2, fy * (r2 + 2.0 * y * y),   fy * 2.0 * x * y,        fy * y * r2 * r2 * r2,
        ]);
        Some((projection.px, projection.d_px_d_point, d_px_d_intrinsics))
    }

    /// Ray through a pixel as a point on the z = 1 plane; `None` if no
    /// point inside the fold radius distorts onto the pixel (or the pixel
    /// is not finite).
    ///
    /// Inverts the distortion in two steps: the radial part alone is a
    /// monotone function of `r` inside the fold radius, so a bracketed
    /// Newton-bisection on `r radial(r) = r_d` gives a starting point that
    /// is exact for p1 = p2 = 0; a damped 2-D Newton iteration (step
    /// halved until the residual decreases and the iterate stays inside the
    /// fold radius) then adds the tangential terms.
    pub fn unproject(&self, px: &Vector2<f64>) -> Option<Vector3<f64>> {
        self.pinhole_model().unproject(self, px)
    }

    /// The ray of [`Self::unproject`] with its Jacobian with respect to the
    /// pixel (3x2; the last row is zero since the ray stays on z = 1):
    /// `d x / d px = D(x)^-1 diag(1/fx, 1/fy)` by the inverse function
    /// theorem, with `D` the [`Self::distort_jacobian`] at the solution.
    pub fn unproject_with_jacobian(
        &self,
        px: &Vector2<f64>,
    ) -> Option<(Vector3<f64>, Matrix3x2<f64>)> {
        self.pinhole_model().unproject_with_jacobian(self, px)
    }

    /// Undistorted point `x` with `distort(x) = target` and `|x| < r_max`.
    fn undistort_inside(&self, target: &Vector2<f64>, r_max: f64) -> Option<Vector2<f64>> {
        let r_d = target.norm();
        if r_d == 0.0 {
            // distort(0) = 0 whatever the coefficients.
            return Some(Vector2::zeros());
        }
        let r0 = self.invert_radial(r_d, r_max);
        let mut xn = target * (r0 / r_d);
        let mut residual = self.distort(&xn) - target;
        let mut converged = false;
        for _ in 0..UNDISTORT_MAX_ITERATIONS {
            if residual.norm() <= UNDISTORT_TOLERANCE {
                converged = true;
                break;
            }
            let step = self.distort_jacobian(&xn).lu().solve(&residual)?;
            let mut fraction = 1.0;
            loop {
                let candidate = xn - step * fraction;
                if candidate.norm() < r_max {
                    let candidate_residual = self.distort(&candidate) - target;
                    if candidate_residual.norm() < residual.norm() {
                        xn = candidate;
                        residual = candidate_residual;
                        break;
                    }
                }
                fraction *= 0.5;
                if fraction < MIN_STEP_FRACTION {
                    return None;
                }
            }
        }
        let converged = converged || residual.norm() <= UNDISTORT_TOLERANCE;
        let orientation_kept = self.distort_jacobian(&xn).determinant() > 0.0;
        (converged && orientation_kept && xn.norm() < r_max).then_some(xn)
    }

    /// Undistorted radius whose radial image is `r_d`, restricted to
    /// `[0, r_max)` where the radial map increases. If `r_d` lies beyond
    /// what that interval reaches, returns a radius just inside `r_max`
    /// (the 2-D iteration then decides, usually by failing).
    fn invert_radial(&self, r_d: f64, r_max: f64) -> f64 {
        let [k1, k2, _, _, k3] = self.distortion;
        // r_d(r) = r + k1 r^3 + k2 r^5 + k3 r^7
        let radial_map = [0.0, 1.0, 0.0, k1, 0.0, k2, 0.0, k3];
        let (mut lo, mut hi) = (0.0_f64, r_d.max(1.0));
        if r_max.is_finite() {
            hi = r_max;
            if self.radial_map(hi) < r_d {
                return r_max * (1.0 - 1e-9);
            }
        } else {
            // No fold: r radial(r) increases without bound, so doubling
            // brackets the root.
            while self.radial_map(hi) < r_d {
                lo = hi;
                hi *= 2.0;
            }
        }
        polynomial::solve_increasing(&radial_map, r_d, lo, hi)
    }
}

/// The radial-tangential distortion, invertible inside the fold radius.
impl Distortion for PinholeRadtan {
    /// Distorts a point on the normalised (z = 1) plane.
    fn distort(&self, xn: &Vector2<f64>) -> Vector2<f64> {
        let [k1, k2, p1, p2, k3] = self.distortion;
        let (x, y) = (xn.x, xn.y);
        let r2 = x * x + y * y;
        let radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3));
        Vector2::new(
            x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x),
            y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y,
        )
    }

    /// Jacobian of [`Self::distort`] with respect to the undistorted point.
    fn distort_jacobian(&self, xn: &Vector2<f64>) -> Matrix2<f64> {
        let [k1, k2, p1, p2, k3] = self.distortion;
        let (x, y) = (xn.x, xn.y);
        let r2 = x * x + y * y;
        let radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3));
        let dradial_dr2 = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2);
        Matrix2::new(
            radial + 2.0 * x * x * dradial_dr2 + 2.0 * p1 * y + 6.0 * p2 * x,
            2.0 * x * y * dradial_dr2 + 2.0 * p1 * x + 2.0 * p2 * y,
            2.0 * x * y * dradial_dr2 + 2.0 * p1 * x + 2.0 * p2 * y,
            radial + 2.0 * y * y * dradial_dr2 + 6.0 * p1 * y + 2.0 * p2 * x,
        )
    }

    fn is_invertible_at(&self, xn: &Vector2<f64>) -> bool {
        xn.norm() < self.max_valid_radius()
    }

    fn undistort(&self, xd: &Vector2<f64>) -> Option<Vector2<f64>> {
        self.undistort_inside(xd, self.max_valid_radius())
    }
}

/// Smallest positive root of `a s^2 + b s + c` (c != 0), by the
/// cancellation-free form of the quadratic formula.
fn smallest_positive_quadratic_root(a: f64, b: f64, c: f64) -> Option<f64> {
    if a == 0.0 {
        let s = -c / b;
        return (b != 0.0 && s > 0.0).then_some(s);
    }
    let disc = b * b - 4.0 * a * c;
    if disc < 0.0 {
        return None;
    }
    let q = -0.5 * (b + b.signum() * disc.sqrt());
    let roots = [q / a, if q != 0.0 { c / q } else { f64::NAN }];
    roots
        .into_iter()
        .filter(|s| s.is_finite() && *s > 0.0)
        .min_by(f64::total_cmp)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::finite_difference::{central_difference, max_relative_error};
    use nalgebra::{SVector, Vector2, Vector3};

    /// `../shared/data/euroc/V1_01_micro/mav0/cam0/sensor.yaml`, copied so
    /// that the numerical tests run without the data;
    /// `constants_match_euroc_sensor_yaml` checks the copy against the file.
    const CAM0_PINHOLE: [f64; 4] = [458.654, 457.296, 367.215, 248.375];
    const CAM0_DISTORTION: [f64; 4] = [-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05];
    /// Same for `cam1/sensor.yaml`.
    const CAM1_PINHOLE: [f64; 4] = [457.587, 456.134, 379.999, 255.238];
    const CAM1_DISTORTION: [f64; 4] = [-0.28368365, 0.07451284, -0.00010473, -3.55590700e-05];
    const EUROC_WIDTH: u32 = 752;
    const EUROC_HEIGHT: u32 = 480;

    fn euroc_cam0() -> PinholeRadtan {
        PinholeRadtan::from_kalibr(EUROC_WIDTH, EUROC_HEIGHT, &CAM0_PINHOLE, &CAM0_DISTORTION)
            .expect("EuRoC cam0 calibration is valid")
    }

    fn euroc_cam1() -> PinholeRadtan {
        PinholeRadtan::from_kalibr(EUROC_WIDTH, EUROC_HEIGHT, &CAM1_PINHOLE, &CAM1_DISTORTION)
            .expect("EuRoC cam1 calibration is valid")
    }

    /// cam0's lens truncated to k1: folds inside the image.
    fn euroc_cam0_k1_only() -> PinholeRadtan {
        PinholeRadtan::new(
            EUROC_WIDTH,
            EUROC_HEIGHT,
            CAM0_PINHOLE,
            [CAM0_DISTORTION[0], 0.0, 0.0, 0.0, 0.0],
        )
        .expect("valid parameters")
    }

    /// The numbers in the list after `key:` on its line of a sensor.yaml.
    fn yaml_list(text: &str, key: &str) -> Vec<f64> {
        let line = text
            .lines()
            .find(|l| l.trim_start().starts_with(key))
            .unwrap_or_else(|| panic!("sensor.yaml has no `{key}` line"));
        let inside = line
            .split_once('[')
            .and_then(|(_, rest)| rest.split_once(']'))
            .unwrap_or_else(|| panic!("`{key}` is not a one-line list"))
            .0;
        inside
            .split(',')
            .map(|v| v.trim().parse().expect("sensor.yaml list holds numbers"))
            .collect()
    }

    #[test]
    fn constants_match_euroc_sensor_yaml() {
        let root = concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../shared/data/euroc/V1_01_micro/mav0"
        );
        for (camera, pinhole, distortion) in [
            ("cam0", CAM0_PINHOLE, CAM0_DISTORTION),
            ("cam1", CAM1_PINHOLE, CAM1_DISTORTION),
        ] {
            let path = format!("{root}/{camera}/sensor.yaml");
            let text = match std::fs::read_to_string(&path) {
                Ok(text) => text,
                Err(e) if std::env::var_os("CI").is_none() => {
                    let _ = e; // data absent outside CI: nothing to compare against
                    return;
                }
                Err(e) => panic!("{path}: {e} (CI requires ../shared/data)"),
            };
            assert_eq!(yaml_list(&text, "intrinsics:"), pinhole, "{path}");
            assert_eq!(
                yaml_list(&text, "distortion_coefficients:"),
                distortion,
                "{path}"
            );
            assert_eq!(
                yaml_list(&text, "resolution:"),
                [EUROC_WIDTH as f64, EUROC_HEIGHT as f64]
            );
        }
    }

    #[test]
    fn new_rejects_invalid_parameters_with_the_offending_name() {
        let ok_pinhole = [400.0, 400.0, 320.0, 240.0];
        let ok_distortion = [0.0; 5];
        assert_eq!(
            PinholeRadtan::new(0, 480, ok_pinhole, ok_distortion),
            Err(CameraError::EmptyImage {
                width: 0,
                height: 480
            })
        );
        assert_eq!(
            PinholeRadtan::new(640, 0, ok_pinhole, ok_distortion),
            Err(CameraError::EmptyImage {
                width: 640,
                height: 0
            })
        );
        let err = PinholeRadtan::new(640, 480, [400.0, 400.0, f64::NAN, 240.0], ok_distortion);
        assert!(
            matches!(err, Err(CameraError::NotFinite { name: "cx", .. })),
            "{err:?}"
        );
        let err = PinholeRadtan::new(640, 480, ok_pinhole, [0.0, 0.0, 0.0, 0.0, f64::INFINITY]);
        assert!(
            matches!(err, Err(CameraError::NotFinite { name: "k3", .. })),
            "{err:?}"
        );
        assert_eq!(
            PinholeRadtan::new(640, 480, [400.0, -1.0, 320.0, 240.0], ok_distortion),
            Err(CameraError::NonPositiveFocalLength {
                name: "fy",
                value: -1.0
            })
        );
        assert_eq!(
            PinholeRadtan::new(640, 480, [0.0, 400.0, 320.0, 240.0], ok_distortion),
            Err(CameraError::NonPositiveFocalLength {
                name: "fx",
                value: 0.0
            })
        );
        let camera = PinholeRadtan::new(640, 480, ok_pinhole, [0.1, 0.2, 0.3, 0.4, 0.5])
            .expect("valid parameters");
        assert_eq!(camera.distortion, [0.1, 0.2, 0.3, 0.4, 0.5]);
        assert_eq!(
            (camera.fx, camera.fy, camera.cx, camera.cy),
            (400.0, 400.0, 320.0, 240.0)
        );
    }

    #[test]
    fn from_kalibr_takes_four_or_five_coefficients() {
        let four = euroc_cam0();
        let [k1, k2, p1, p2] = CAM0_DISTORTION;
        assert_eq!(four.distortion, [k1, k2, p1, p2, 0.0]);
        let five = PinholeRadtan::from_kalibr(752, 480, &CAM0_PINHOLE, &[k1, k2, p1, p2, 0.01])
            .expect("five coefficients are OpenCV's");
        assert_eq!(five.distortion, [k1, k2, p1, p2, 0.01]);
        for bad in [&[k1, k2, p1][..], &[k1, k2, p1, p2, 0.0, 0.0][..], &[][..]] {
            let err = PinholeRadtan::from_kalibr(752, 480, &CAM0_PINHOLE, bad);
            assert!(
                matches!(err, Err(CameraError::WrongLength { field: "distortion_coefficients", got, .. }) if got == bad.len()),
                "{err:?}"
            );
        }
        let err = PinholeRadtan::from_kalibr(752, 480, &CAM0_PINHOLE[..3], &CAM0_DISTORTION);
        assert!(
            matches!(
                err,
                Err(CameraError::WrongLength {
                    field: "intrinsics",
                    got: 3,
                    ..
                })
            ),
            "{err:?}"
        );
    }

    /// Reference pixels from OpenCV 5.0.0 (opencv-python-headless
    /// 5.0.0.93), `cv2.projectPoints(pts, zeros(3), zeros(3), K, D)` with
    /// K from cam0 and D as named; run once, numbers pasted here.
    #[test]
    fn project_agrees_with_opencv_project_points() {
        let points = [
            Vector3::new(0.3, -0.2, 1.0),
            Vector3::new(-1.1, -0.7, 1.3),
            Vector3::new(2.0, 1.5, 2.5),
            Vector3::new(0.0, 0.0, 4.0),
            Vector3::new(-0.4, 0.9, 0.8),
        ];
        let cam0_opencv = [
            (499.9055685393346, 160.1887446901026),
            (60.819362999637576, 54.0571538147978),
            (657.3901516358228, 465.44447781423526),
            (367.215, 248.375),
            (197.34860844007048, 629.6044013807245),
        ];
        // D = [-0.3, 0.1, 0.001, -0.002, -0.02] (k3 non-zero)
        let k3_opencv = [
            (499.33203584097197, 160.537944669248),
            (63.051909888105456, 56.43522355548072),
            (651.7639416, 462.2980688),
            (367.215, 248.375),
            (203.08440706901547, 614.149602657196),
        ];
        let k3_model =
            PinholeRadtan::new(752, 480, CAM0_PINHOLE, [-0.3, 0.1, 0.001, -0.002, -0.02])
                .expect("valid parameters");
        for (camera, expected) in [(euroc_cam0(), cam0_opencv), (k3_model, k3_opencv)] {
            for (p, (u, v)) in points.iter().zip(expected) {
                let px = camera
                    .project(p)
                    .expect("point is in front and inside the fold");
                assert!(
                    (px - Vector2::new(u, v)).norm() < 1e-6,
                    "{p:?}: {px:?} vs ({u}, {v})"
                );
            }
        }
    }

    /// Points in front of the camera whose pixels cover the image with a
    /// 16 px grid, its four corners and border, at three depths.
    fn points_over_image(camera: &PinholeRadtan) -> Vec<Vector3<f64>> {
        let (w, h) = (camera.width as f64, camera.height as f64);
        let mut pixels = vec![
            Vector2::new(-0.5, -0.5),
            Vector2::new(w - 0.5, -0.5),
            Vector2::new(-0.5, h - 0.5),
            Vector2::new(w - 0.5, h - 0.5),
            Vector2::new(camera.cx, camera.cy),
        ];
        for u in (0..camera.width).step_by(16) {
            for v in (0..camera.height).step_by(16) {
                pixels.push(Vector2::new(u as f64, v as f64));
            }
        }
        let mut points = Vec::new();
        for px in pixels {
            let ray = camera.unproject(&px).expect("EuRoC pixels unproject");
            for depth_m in [0.4, 3.0, 25.0] {
                points.push(ray * depth_m);
            }
        }
        points
    }

    #[test]
    fn point_jacobian_matches_finite_differences_over_euroc_images() {
        for camera in [euroc_cam0(), euroc_cam1()] {
            let mut worst = 0.0_f64;
            for p in points_over_image(&camera) {
                let (_, analytic, _) = camera.project_with_jacobians(&p).expect("projects");
                let numeric = central_difference(
                    |q: &SVector<f64, 3>| camera.project(q).expect("neighbour projects"),
                    &p,
                    1e-6,
                );
                worst = worst.max(max_relative_error(&analytic, &numeric, 1.0));
            }
            assert!(worst < 1e-6, "d px / d point: max relative error {worst:e}");
        }
    }

    #[test]
    fn intrinsics_jacobian_matches_finite_differences_over_euroc_images() {
        // A non-zero k3 so that its column is exercised with a value too.
        let mut with_k3 = euroc_cam0();
        with_k3.distortion[4] = 0.01;
        for camera in [euroc_cam0(), euroc_cam1(), with_k3] {
            let parameters = SVector::<f64, 9>::from_row_slice(&[
                camera.fx,
                camera.fy,
                camera.cx,
                camera.cy,
                camera.distortion[0],
                camera.distortion[1],
                camera.distortion[2],
                camera.distortion[3],
                camera.distortion[4],
            ]);
            let mut worst = 0.0_f64;
            for p in points_over_image(&camera) {
                let (_, _, analytic) = camera.project_with_jacobians(&p).expect("projects");
                let numeric = central_difference(
                    |q: &SVector<f64, 9>| {
                        let perturbed = PinholeRadtan {
                            fx: q[0],
                            fy: q[1],
                            cx: q[2],
                            cy: q[3],
                            distortion: [q[4], q[5], q[6], q[7], q[8]],
                            ..camera.clone()
                        };
                        perturbed.project(&p).expect("neighbour projects")
                    },
                    &parameters,
                    1e-6,
                );
                worst = worst.max(max_relative_error(&analytic, &numeric, 1.0));
            }
            assert!(
                worst < 1e-6,
                "d px / d intrinsics: max relative error {worst:e}"
            );
        }
    }

    #[test]
    fn unproject_jacobian_matches_finite_differences_over_euroc_images() {
        for camera in [euroc_cam0(), euroc_cam1()] {
            let mut worst = 0.0_f64;
            let (w, h) = (camera.width as f64, camera.height as f64);
            let mut pixels = vec![
                Vector2::new(-0.5, -0.5),
                Vector2::new(w - 0.5, -0.5),
                Vector2::new(-0.5, h - 0.5),
                Vector2::new(w - 0.5, h - 0.5),
            ];
            for u in (0..camera.width).step_by(8) {
                for v in (0..camera.height).step_by(8) {
                    pixels.push(Vector2::new(u as f64, v as f64));
                }
            }
            for px in pixels {
                let (ray, analytic) = camera.unproject_with_jacobian(&px).expect("unprojects");
                assert_eq!(Some(ray), camera.unproject(&px));
                let numeric = central_difference(
                    |q: &SVector<f64, 2>| camera.unproject(q).expect("neighbour unprojects"),
                    &px,
                    1e-2 / px.abs().max().max(1.0),
                );
                // Entries are ~1/f = 2e-3 rad/px; the floor keeps the
                // zero third row absolute.
                worst = worst.max(max_relative_error(&analytic, &numeric, 1e-4));
            }
            assert!(worst < 1e-6, "d ray / d px: max relative error {worst:e}");
        }
    }

    /// Every pixel centre of both EuRoC cameras, plus the outer edges of
    /// the border pixels (half a pixel further out), unprojects to a ray
    /// that projects back onto it.
    #[test]
    fn unproject_round_trips_every_pixel_of_euroc_cam0_and_cam1() {
        for camera in [euroc_cam0(), euroc_cam1()] {
            let (w, h) = (camera.width as f64, camera.height as f64);
            let mut pixels: Vec<Vector2<f64>> = (0..camera.width)
                .flat_map(|u| (0..camera.height).map(move |v| Vector2::new(u as f64, v as f64)))
                .collect();
            for u in 0..=(2 * camera.width) {
                let u = u as f64 * 0.5 - 0.5;
                pixels.push(Vector2::new(u, -0.5));
                pixels.push(Vector2::new(u, h - 0.5));
            }
            for v in 0..=(2 * camera.height) {
                let v = v as f64 * 0.5 - 0.5;
                pixels.push(Vector2::new(-0.5, v));
                pixels.push(Vector2::new(w - 0.5, v));
            }
            let mut worst_px = 0.0_f64;
            for px in &pixels {
                let ray = camera
                    .unproject(px)
                    .unwrap_or_else(|| panic!("{px:?} does not unproject"));
                assert_eq!(ray.z, 1.0);
                let back = camera.project(&ray).expect("unprojected ray projects");
                worst_px = worst_px.max((back - px).norm());
            }
            assert!(worst_px < 1e-6, "round trip error {worst_px:e} px");
        }
    }

    #[test]
    fn project_then_unproject_recovers_the_ray() {
        let camera = euroc_cam0();
        for p in points_over_image(&camera) {
            let px = camera.project(&p).expect("projects");
            let ray = camera.unproject(&px).expect("unprojects");
            let expected = p / p.z;
            assert!((ray - expected).norm() < 1e-9, "{ray:?} vs {expected:?}");
        }
    }

    /// The radial derivative polynomial's smallest positive root against
    /// closed forms: k1 only, `r^2 = 1 / (3 |k1|)`; k1 and k2, the smaller
    /// root of `1 + 3 k1 s + 5 k2 s^2`.
    #[test]
    fn closed_form_fold_radius_agrees_with_the_root_search() {
        for (k1, k2) in [
            (-0.3, 0.05),
            (-0.5, 0.01),
            (-0.28, 0.07),
            (0.1, -0.02),
            (-0.9, 0.3),
            (0.0, -0.1),
            (-0.2, 0.0),
        ] {
            let camera = PinholeRadtan {
                width: 640,
                height: 480,
                fx: 500.0,
                fy: 500.0,
                cx: 320.0,
                cy: 240.0,
                distortion: [k1, k2, 0.0, 0.0, 0.0],
            };
            let fast = camera.max_valid_radius();
            let general = camera.max_valid_radius_by_root_search();
            assert!(
                (fast.is_infinite() && general.is_infinite())
                    || (fast - general).abs() < 1e-9 * general,
                "k1 {k1} k2 {k2}: {fast} vs {general}"
            );
        }
    }

    #[test]
    fn fold_radius_matches_closed_forms() {
        let k1_only = euroc_cam0_k1_only();
        let expected = 1.0 / (3.0 * CAM0_DISTORTION[0].abs()).sqrt();
        assert!((k1_only.max_valid_radius() - expected).abs() < 1e-14);

        let (k1, k2) = (-0.5, 0.05);
        let camera = PinholeRadtan::new(
            640,
            480,
            [400.0, 400.0, 320.0, 240.0],
            [k1, k2, 0.0, 0.0, 0.0],
        )
        .expect("valid parameters");
        let (a, b) = (5.0 * k2, 3.0 * k1);
        let s = (-b - (b * b - 4.0 * a).sqrt()) / (2.0 * a);
        assert!((camera.max_valid_radius() - s.sqrt()).abs() < 1e-14);

        // With k3 the derivative is a cubic in r^2; at the fold it is zero
        // and positive just inside.
        let camera = PinholeRadtan::new(
            640,
            480,
            [400.0, 400.0, 320.0, 240.0],
            [-0.3, 0.1, 0.0, 0.0, -0.05],
        )
        .expect("valid parameters");
        let r = camera.max_valid_radius();
        let slope = |r: f64| {
            let r2 = r * r;
            1.0 + 3.0 * -0.3 * r2 + 5.0 * 0.1 * r2 * r2 + 7.0 * -0.05 * r2 * r2 * r2
        };
        assert!(r.is_finite());
        assert!(slope(r).abs() < 1e-12, "{}", slope(r));
        assert!((0..1000).all(|i| slope(r * i as f64 / 1000.0) > 0.0));

        // No distortion never folds.
        let pinhole = PinholeRadtan::new(640, 480, [400.0, 400.0, 320.0, 240.0], [0.0; 5])
            .expect("valid parameters");
        assert_eq!(pinhole.max_valid_radius(), f64::INFINITY);
    }

    /// EuRoC's cameras do not fold: the radial derivative has no positive
    /// root, and over the whole image (up to the corners' undistorted radii
    /// of about 1.37) it stays above 0.5, so `unproject` is well
    /// conditioned everywhere.
    #[test]
    fn euroc_cameras_do_not_fold_and_stay_well_conditioned_to_the_corners() {
        for camera in [euroc_cam0(), euroc_cam1()] {
            assert_eq!(camera.max_valid_radius(), f64::INFINITY);
            assert_eq!(camera.max_valid_distorted_radius(), f64::INFINITY);
            let (w, h) = (camera.width as f64, camera.height as f64);
            let corner_radius = [
                (-0.5, -0.5),
                (w - 0.5, -0.5),
                (-0.5, h - 0.5),
                (w - 0.5, h - 0.5),
            ]
            .iter()
            .map(|&(u, v)| {
                let ray = camera
                    .unproject(&Vector2::new(u, v))
                    .expect("corner unprojects");
                ray.xy().norm()
            })
            .fold(0.0, f64::max);
            assert!(
                corner_radius > 1.3 && corner_radius < 1.4,
                "{corner_radius}"
            );
            let g = camera.radial_derivative_polynomial();
            let min_slope = (0..=10_000)
                .map(|i| corner_radius * i as f64 / 10_000.0)
                .map(|r| polynomial::evaluate(&g, r * r))
                .fold(f64::INFINITY, f64::min);
            assert!(min_slope > 0.5, "{min_slope}");
        }
    }

    /// Where unprojection cannot converge: cam0's lens truncated to k1
    /// folds at r = 1.085, inside the image. Points beyond do not project,
    /// pixels beyond the fold's image (the corners) do not unproject, and a
    /// pixel that a point beyond the fold would also reach unprojects to
    /// the point inside.
    #[test]
    fn folding_model_refuses_points_and_pixels_beyond_the_fold() {
        let camera = euroc_cam0_k1_only();
        let r_fold = camera.max_valid_radius();
        let r_d_max = camera.max_valid_distorted_radius();
        assert!((r_d_max - camera.radial_map(r_fold)).abs() < 1e-15);

        let direction = Vector2::new(0.8, -0.6);
        let at = |r: f64| {
            let xy = direction * r;
            Vector3::new(xy.x, xy.y, 1.0)
        };
        assert!(camera.project(&at(0.999 * r_fold)).is_some());
        assert!(camera.project(&at(r_fold)).is_none());
        assert!(camera.project(&at(1.2 * r_fold)).is_none());

        // The image corners lie beyond r_d_max: no ray.
        let corner = Vector2::new(-0.5, -0.5);
        let corner_r_d = Vector2::new(
            (corner.x - camera.cx) / camera.fx,
            (corner.y - camera.cy) / camera.fy,
        )
        .norm();
        assert!(corner_r_d > r_d_max);
        assert_eq!(camera.unproject(&corner), None);

        // A point beyond the fold distorts onto a pixel that a point inside
        // also reaches; unproject returns the inside one.
        let outside = 1.3 * r_fold;
        let xn_outside = direction * outside;
        let pixel = {
            let d = camera.distort(&xn_outside);
            Vector2::new(camera.fx * d.x + camera.cx, camera.fy * d.y + camera.cy)
        };
        let ray = camera
            .unproject(&pixel)
            .expect("pixel has a preimage inside the fold");
        assert!(ray.xy().norm() < r_fold);
        assert!((camera.project(&ray).expect("inside the fold") - pixel).norm() < 1e-6);

        // Every pixel of the image either round-trips or is beyond r_d_max.
        let mut refused = 0;
        for u in (0..camera.width).step_by(4) {
            for v in (0..camera.height).step_by(4) {
                let px = Vector2::new(u as f64, v as f64);
                let r_d = Vector2::new(
                    (px.x - camera.cx) / camera.fx,
                    (px.y - camera.cy) / camera.fy,
                )
                .norm();
                match camera.unproject(&px) {
                    Some(ray) => {
                        assert!(ray.xy().norm() < r_fold);
                        let back = camera.project(&ray).expect("inside the fold");
                        assert!((back - px).norm() < 1e-6, "{px:?}");
                    }
                    None => {
                        assert!(
                            r_d > r_d_max * (1.0 - 1e-9),
                            "{px:?} refused inside the fold image"
                        );
                        refused += 1;
                    }
                }
            }
        }
        assert!(refused > 0, "the truncated lens folds inside the image");
    }

    #[test]
    fn non_finite_pixels_and_points_behind_are_refused() {
        let camera = euroc_cam0();
        assert_eq!(camera.unproject(&Vector2::new(f64::NAN, 3.0)), None);
        assert_eq!(camera.unproject(&Vector2::new(f64::INFINITY, 3.0)), None);
        assert_eq!(camera.project(&Vector3::new(0.1, 0.2, -1.0)), None);
        assert_eq!(camera.project(&Vector3::new(0.1, 0.2, 0.0)), None);
        assert_eq!(camera.project(&Vector3::new(0.1, 0.2, f64::NAN)), None);
        assert!(camera
            .project_with_jacobians(&Vector3::new(0.1, 0.2, -1.0))
            .is_none());
    }
}
