//! Pinhole projection with the equidistant fisheye distortion of Kannala
//! and Brandt (Kalibr `pinhole` + `equidistant`, OpenCV `cv::fisheye`).
//!
//! # The model
//!
//! Kannala & Brandt, "A generic camera model and calibration method for
//! conventional, wide-angle, and fish-eye lenses", PAMI 2006, eq. 6,
//! truncated as Kalibr and OpenCV do: with `x = X / Z`, `y = Y / Z`,
//! `r = sqrt(x^2 + y^2)` and the angle of incidence `theta = atan(r)`,
//!
//! ```text
//! theta_d = theta (1 + k1 theta^2 + k2 theta^4 + k3 theta^6 + k4 theta^8)
//! x_d     = (theta_d / r) x,   y_d = (theta_d / r) y    (x_d = x at r = 0)
//! u       = fx x_d + cx,       v   = fy y_d + cy
//! ```
//!
//! # Where the model can be inverted
//!
//! The distortion is radial only, so it is invertible exactly where
//! `theta -> theta_d` increases:
//!
//! ```text
//! d theta_d / d theta = 1 + 3 k1 theta^2 + 5 k2 theta^4 + 7 k3 theta^6 + 9 k4 theta^8 > 0.
//! ```
//!
//! The first zero of that derivative (the fold angle)
//! and the z = 1 plane's own limit of 90 degrees bound the valid angles;
//! [`PinholeEquidistant::max_valid_theta`] returns the smaller. Rays are
//! returned on the z = 1 plane like every model here, so fields of view
//! beyond 180 degrees are out of reach by design.

use std::f64::consts::FRAC_PI_2;

use nalgebra::{Matrix2, Matrix2x3, Matrix3x2, SMatrix, Vector2, Vector3};

use super::pinhole::{self, Distortion, Pinhole};
use super::polynomial;
use super::CameraError;

/// Names of the intrinsics in the order
/// [`PinholeEquidistant::project_with_jacobians`] differentiates them.
pub const EQUIDISTANT_INTRINSIC_NAMES: [&str; 8] = ["fx", "fy", "cx", "cy", "k1", "k2", "k3", "k4"];

/// Below this normalised radius the distortion is the identity to double
/// precision (`theta / r = 1 - r^2 / 3 + ...`).
const SMALL_RADIUS: f64 = 1e-8;

/// Pinhole camera with Kannala-Brandt equidistant distortion. Fields are
/// private because the fold angle is computed once at construction; build
/// it with [`Self::new`] or [`Self::from_kalibr`].
#[derive(Debug, Clone, PartialEq)]
pub struct PinholeEquidistant {
    width: u32,
    height: u32,
    fx: f64,
    fy: f64,
    cx: f64,
    cy: f64,
    /// k1..k4 on the angle of incidence.
    distortion: [f64; 4],
    /// Largest angle of incidence (rad) the model is valid below.
    max_valid_theta: f64,
}

impl PinholeEquidistant {
    /// A validated camera: non-zero image size, finite intrinsics and
    /// distortion, positive focal lengths. `pinhole = [fx, fy, cx, cy]` in
    /// pixels, `distortion = [k1, k2, k3, k4]`.
    pub fn new(
        width: u32,
        height: u32,
        pinhole: [f64; 4],
        distortion: [f64; 4],
    ) -> Result<Self, CameraError> {
        pinhole::validate(
            width,
            height,
            pinhole,
            &distortion,
            &EQUIDISTANT_INTRINSIC_NAMES,
        )?;
        let [fx, fy, cx, cy] = pinhole;
        let [k1, k2, k3, k4] = distortion;
        // d theta_d / d theta as a polynomial in t = theta^2.
        let slope = [1.0, 3.0 * k1, 5.0 * k2, 7.0 * k3, 9.0 * k4];
        let max_valid_theta = polynomial::smallest_positive_root(&slope, FRAC_PI_2 * FRAC_PI_2)
            .map_or(FRAC_PI_2, f64::sqrt);
        Ok(Self {
            width,
            height,
            fx,
            fy,
            cx,
            cy,
            distortion,
            max_valid_theta,
        })
    }

    /// A camera from Kalibr lists: `intrinsics: [fu, fv, cu, cv]` and
    /// `distortion_coeffs: [k1, k2, k3, k4]`.
    pub fn from_kalibr(
        width: u32,
        height: u32,
        intrinsics: &[f64],
        distortion: &[f64],
    ) -> Result<Self, CameraError> {
        let pinhole = pinhole::pinhole_from_kalibr(intrinsics)?;
        let coefficients: [f64; 4] =
            distortion
                .try_into()
                .map_err(|_| CameraError::WrongLength {
                    field: "distortion_coefficients",
                    expected: "4 (k1, k2, k3, k4)",
                    got: distortion.len(),
                })?;
        Self::new(width, height, pinhole, coefficients)
    }

    /// Image width, pixels.
    pub fn width(&self) -> u32 {
        self.width
    }

    /// Image height, pixels.
    pub fn height(&self) -> u32 {
        self.height
    }

    /// fx, fy, cx, cy in pixels.
    pub fn pinhole(&self) -> [f64; 4] {
        [self.fx, self.fy, self.cx, self.cy]
    }

    /// k1, k2, k3, k4.
    pub fn distortion(&self) -> [f64; 4] {
        self.distortion
    }

    /// Largest angle of incidence (rad) below which the model is
    /// invertible: the first zero of `d theta_d / d theta`, or pi/2 (the
    /// z = 1 plane's limit) if that comes first.
    pub fn max_valid_theta(&self) -> f64 {
        self.max_valid_theta
    }

    /// `theta_d(theta)` as a polynomial in theta (odd powers up to 9).
    fn theta_d_polynomial(&self) -> [f64; 10] {
        let [k1, k2, k3, k4] = self.distortion;
        [0.0, 1.0, 0.0, k1, 0.0, k2, 0.0, k3, 0.0, k4]
    }

    /// `theta_d` and `d theta_d / d theta`.
    fn theta_d_and_slope(&self, theta: f64) -> (f64, f64) {
        let [k1, k2, k3, k4] = self.distortion;
        let t = theta * theta;
        let poly = 1.0 + t * (k1 + t * (k2 + t * (k3 + t * k4)));
        let slope = 1.0 + t * (3.0 * k1 + t * (5.0 * k2 + t * (7.0 * k3 + t * 9.0 * k4)));
        (theta * poly, slope)
    }

    fn pinhole_model(&self) -> Pinhole {
        Pinhole::from_array(self.pinhole())
    }

    /// Pixel of a point in the camera frame; `None` behind the camera or
    /// at or beyond [`Self::max_valid_theta`].
    pub fn project(&self, p_cam: &Vector3<f64>) -> Option<Vector2<f64>> {
        self.pinhole_model().project(self, p_cam)
    }

    /// Pixel of a point with the analytic Jacobians of the pixel with
    /// respect to the point (2x3) and to the intrinsics (2x8, columns in
    /// the order of [`EQUIDISTANT_INTRINSIC_NAMES`]). The distortion
    /// columns are `d x_d / d k_i = (x / r) theta^(2i+1)`.
    #[allow(clippy::type_complexity)]
    pub fn project_with_jacobians(
        &self,
        p_cam: &Vector3<f64>,
    ) -> Option<(Vector2<f64>, Matrix2x3<f64>, SMatrix<f64, 2, 8>)> {
        let projection = self
            .pinhole_model()
            .project_with_point_jacobian(self, p_cam)?;
        let xn = projection.xn;
        let r = xn.norm();
        let theta = r.atan();
        let theta_over_r = if r < SMALL_RADIUS { 1.0 } else { theta / r };
        let mut d_px_d_intrinsics = SMatrix::<f64, 2, 8>::zeros();
        d_px_d_intrinsics
            .fixed_view_mut::<2, 4>(0, 0)
            .copy_from(&Pinhole::intrinsic_jacobian(&projection.xd));
        let mut theta_power = theta_over_r * theta * theta;
        for column in 4..8 {
            d_px_d_intrinsics[(0, column)] = self.fx * xn.x * theta_power;
            d_px_d_intrinsics[(1, column)] = self.fy * xn.y * theta_power;
            theta_power *= theta * theta;
        }
        Some((projection.px, projection.d_px_d_point, d_px_d_intrinsics))
    }

    /// Ray through a pixel as a point on the z = 1 plane; `None` if the
    /// pixel lies beyond the image of [`Self::max_valid_theta`] or is not
    /// finite. The distortion is radial, so inversion is one-dimensional:
    /// solve `theta_d(theta) = |x_d|` on the valid (monotone) range by
    /// bracketed Newton-bisection, then `x = x_d tan(theta) / |x_d|`.
    pub fn unproject(&self, px: &Vector2<f64>) -> Option<Vector3<f64>> {
        self.pinhole_model().unproject(self, px)
    }

    /// The ray of [`Self::unproject`] with its Jacobian with respect to the
    /// pixel (3x2, last row zero): `D(x)^-1 diag(1/fx, 1/fy)`.
    pub fn unproject_with_jacobian(
        &self,
        px: &Vector2<f64>,
    ) -> Option<(Vector3<f64>, Matrix3x2<f64>)> {
        self.pinhole_model().unproject_with_jacobian(self, px)
    }
}

/// The equidistant distortion, invertible below the fold angle.
impl Distortion for PinholeEquidistant {
    /// Distorts a point on the normalised (z = 1) plane.
    fn distort(&self, xn: &Vector2<f64>) -> Vector2<f64> {
        let r = xn.norm();
        if r < SMALL_RADIUS {
            return *xn;
        }
        let (theta_d, _) = self.theta_d_and_slope(r.atan());
        xn * (theta_d / r)
    }

    /// Jacobian of [`Self::distort`] with respect to the undistorted point:
    /// with `s(r) = theta_d / r`, `D = s I + (s'(r) / r) x x^T` and
    /// `s'(r) / r = (theta_d'(theta) / (1 + r^2) - s) / r^2`.
    fn distort_jacobian(&self, xn: &Vector2<f64>) -> Matrix2<f64> {
        let r = xn.norm();
        if r < SMALL_RADIUS {
            return Matrix2::identity();
        }
        let r2 = r * r;
        let (theta_d, slope) = self.theta_d_and_slope(r.atan());
        let s = theta_d / r;
        let ds_dr_over_r = (slope / (1.0 + r2) - s) / r2;
        Matrix2::identity() * s + xn * xn.transpose() * ds_dr_over_r
    }

    fn is_invertible_at(&self, xn: &Vector2<f64>) -> bool {
        xn.norm().atan() < self.max_valid_theta
    }

    /// The distortion is radial, so inversion is one-dimensional: solve
    /// `theta_d(theta) = |x_d|` on the valid (monotone) range by bracketed
    /// Newton-bisection, then `x = x_d tan(theta) / |x_d|`.
    fn undistort(&self, target: &Vector2<f64>) -> Option<Vector2<f64>> {
        let theta_d = target.norm();
        if theta_d == 0.0 {
            return Some(Vector2::zeros());
        }
        let (theta_d_max, _) = self.theta_d_and_slope(self.max_valid_theta);
        if theta_d >= theta_d_max {
            return None;
        }
        let theta = polynomial::solve_increasing(
            &self.theta_d_polynomial(),
            theta_d,
            0.0,
            self.max_valid_theta,
        );
        let r = theta.tan();
        if !(r.is_finite() && theta < self.max_valid_theta) {
            return None;
        }
        Some(target * (r / theta_d))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::finite_difference::{central_difference, max_relative_error};
    use nalgebra::SVector;

    /// A 512x512 fisheye with the parameters TUM VI publishes for its
    /// Kalibr `equidistant` cam0 (quoted from memory, not read from a
    /// file: the tests only need a realistic strong fisheye).
    const PINHOLE: [f64; 4] = [190.978, 190.973, 254.932, 256.897];
    const DISTORTION: [f64; 4] = [
        0.0034823894022493434,
        0.0007150348452162257,
        -0.0020532361418706202,
        0.00020293673591811182,
    ];

    fn fisheye() -> PinholeEquidistant {
        PinholeEquidistant::new(512, 512, PINHOLE, DISTORTION).expect("valid parameters")
    }

    /// Pixels over the image on a 16 px grid plus its corners that have a
    /// ray (corners of a fisheye image can lie beyond 90 degrees).
    fn pixels_with_rays(camera: &PinholeEquidistant, step: usize) -> Vec<Vector2<f64>> {
        let (w, h) = (camera.width as f64, camera.height as f64);
        let mut pixels = vec![
            Vector2::new(-0.5, -0.5),
            Vector2::new(w - 0.5, -0.5),
            Vector2::new(-0.5, h - 0.5),
            Vector2::new(w - 0.5, h - 0.5),
            Vector2::new(camera.cx, camera.cy),
            Vector2::new(camera.cx + 1e-10, camera.cy),
        ];
        for u in (0..camera.width).step_by(step) {
            for v in (0..camera.height).step_by(step) {
                pixels.push(Vector2::new(u as f64, v as f64));
            }
        }
        pixels
    }

    #[test]
    fn new_and_from_kalibr_validate_parameters() {
        assert_eq!(
            PinholeEquidistant::new(0, 512, PINHOLE, DISTORTION),
            Err(CameraError::EmptyImage {
                width: 0,
                height: 512
            })
        );
        let err = PinholeEquidistant::new(512, 512, PINHOLE, [0.0, f64::NAN, 0.0, 0.0]);
        assert!(
            matches!(err, Err(CameraError::NotFinite { name: "k2", .. })),
            "{err:?}"
        );
        let err = PinholeEquidistant::new(512, 512, [-1.0, 1.0, 0.0, 0.0], DISTORTION);
        assert!(
            matches!(
                err,
                Err(CameraError::NonPositiveFocalLength { name: "fx", .. })
            ),
            "{err:?}"
        );
        let err = PinholeEquidistant::from_kalibr(512, 512, &PINHOLE, &DISTORTION[..3]);
        assert!(
            matches!(
                err,
                Err(CameraError::WrongLength {
                    field: "distortion_coefficients",
                    got: 3,
                    ..
                })
            ),
            "{err:?}"
        );
        let camera = PinholeEquidistant::from_kalibr(512, 512, &PINHOLE, &DISTORTION)
            .expect("valid parameters");
        assert_eq!(camera.pinhole(), PINHOLE);
        assert_eq!(camera.distortion(), DISTORTION);
        assert_eq!((camera.width(), camera.height()), (512, 512));
    }

    /// Reference pixels from OpenCV 5.0.0 (opencv-python-headless
    /// 5.0.0.93), `cv2.fisheye.projectPoints(pts, zeros(3), zeros(3), K, D)`
    /// with K and D as above; run once, numbers pasted here.
    #[test]
    fn project_agrees_with_opencv_fisheye_project_points() {
        let points = [
            Vector3::new(0.3, -0.2, 1.0),
            Vector3::new(-1.1, -0.7, 1.3),
            Vector3::new(2.0, 1.5, 2.5),
            Vector3::new(0.0, 0.0, 4.0),
            Vector3::new(-0.4, 0.9, 0.8),
        ];
        let opencv = [
            (309.94330248437797, 220.22375851197825),
            (127.90028132693391, 176.0607500030655),
            (375.1631239489516, 347.06798213106924),
            (254.932, 256.897),
            (185.85194686973188, 412.3230502230888),
        ];
        let camera = fisheye();
        for (p, (u, v)) in points.iter().zip(opencv) {
            let px = camera.project(p).expect("in front of the camera");
            assert!(
                (px - Vector2::new(u, v)).norm() < 1e-6,
                "{p:?}: {px:?} vs ({u}, {v})"
            );
        }
    }

    #[test]
    fn unproject_round_trips_every_pixel_with_a_ray() {
        let camera = fisheye();
        let (theta_d_max, _) = camera.theta_d_and_slope(camera.max_valid_theta());
        let mut round_tripped = 0;
        for px in pixels_with_rays(&camera, 1) {
            let target = Vector2::new(
                (px.x - camera.cx) / camera.fx,
                (px.y - camera.cy) / camera.fy,
            );
            match camera.unproject(&px) {
                Some(ray) => {
                    let back = camera.project(&ray).expect("unprojected ray projects");
                    assert!((back - px).norm() < 1e-6, "{px:?} -> {back:?}");
                    round_tripped += 1;
                }
                // Only pixels beyond the image of the 90-degree circle lack a ray.
                None => assert!(target.norm() >= theta_d_max * (1.0 - 1e-9), "{px:?}"),
            }
        }
        assert!(round_tripped > 512 * 512 / 2);
    }

    #[test]
    fn fold_angle_matches_the_closed_form_for_k1_only() {
        // d theta_d / d theta = 1 + 3 k1 theta^2 vanishes at 1/sqrt(3|k1|).
        let camera = PinholeEquidistant::new(512, 512, PINHOLE, [-0.5, 0.0, 0.0, 0.0])
            .expect("valid parameters");
        let expected = 1.0 / 1.5_f64.sqrt();
        assert!((camera.max_valid_theta() - expected).abs() < 1e-14);
        let inside = Vector3::new((0.99 * expected).tan(), 0.0, 1.0);
        let beyond = Vector3::new((1.01 * expected).tan(), 0.0, 1.0);
        assert!(camera.project(&inside).is_some());
        assert!(camera.project(&beyond).is_none());
        // A pixel beyond the fold's image has no ray.
        let (theta_d_max, _) = camera.theta_d_and_slope(expected);
        let px = Vector2::new(camera.cx + 1.01 * theta_d_max * camera.fx, camera.cy);
        assert_eq!(camera.unproject(&px), None);
        // Without a fold the z = 1 plane's 90 degrees is the limit.
        assert_eq!(fisheye().max_valid_theta(), FRAC_PI_2);
        assert!(fisheye().project(&Vector3::new(1.0, 0.0, 0.0)).is_none());
    }

    #[test]
    fn point_and_intrinsics_jacobians_match_finite_differences() {
        let camera = fisheye();
        let parameters = SVector::<f64, 8>::from_row_slice(&[
            PINHOLE[0],
            PINHOLE[1],
            PINHOLE[2],
            PINHOLE[3],
            DISTORTION[0],
            DISTORTION[1],
            DISTORTION[2],
            DISTORTION[3],
        ]);
        let (mut worst_point, mut worst_intrinsics) = (0.0_f64, 0.0_f64);
        for px in pixels_with_rays(&camera, 16) {
            let Some(ray) = camera.unproject(&px) else {
                continue;
            };
            for depth_m in [0.4, 3.0, 25.0] {
                let p = ray * depth_m;
                let (_, d_point, d_intrinsics) =
                    camera.project_with_jacobians(&p).expect("projects");
                let numeric = central_difference(
                    |q: &SVector<f64, 3>| camera.project(q).expect("neighbour projects"),
                    &p,
                    1e-6,
                );
                worst_point = worst_point.max(max_relative_error(&d_point, &numeric, 1.0));
                let numeric = central_difference(
                    |q: &SVector<f64, 8>| {
                        let perturbed = PinholeEquidistant::new(
                            512,
                            512,
                            [q[0], q[1], q[2], q[3]],
                            [q[4], q[5], q[6], q[7]],
                        )
                        .expect("perturbed parameters are valid");
                        perturbed.project(&p).expect("neighbour projects")
                    },
                    &parameters,
                    1e-6,
                );
                worst_intrinsics =
                    worst_intrinsics.max(max_relative_error(&d_intrinsics, &numeric, 1.0));
            }
        }
        assert!(worst_point < 1e-6, "d px / d point: {worst_point:e}");
        assert!(
            worst_intrinsics < 1e-6,
            "d px / d intrinsics: {worst_intrinsics:e}"
        );
    }

    #[test]
    fn unproject_jacobian_matches_finite_differences() {
        let camera = fisheye();
        let mut worst = 0.0_f64;
        for px in pixels_with_rays(&camera, 8) {
            // Stay clear of the 90-degree circle where rays go to infinity.
            let Some(ray) = camera.unproject(&px) else {
                continue;
            };
            if ray.xy().norm().atan() > 1.3 {
                continue;
            }
            let (same, analytic) = camera.unproject_with_jacobian(&px).expect("unprojects");
            assert_eq!(same, ray);
            let numeric = central_difference(
                |q: &SVector<f64, 2>| camera.unproject(q).expect("neighbour unprojects"),
                &px,
                1e-2 / px.abs().max().max(1.0),
            );
            worst = worst.max(max_relative_error(&analytic, &numeric, 1e-4));
        }
        assert!(worst < 1e-6, "d ray / d px: {worst:e}");
    }
}
