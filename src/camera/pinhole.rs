//! What both camera models share: the pinhole between the normalised
//! (z = 1) plane and the pixels, and the chain rule through it. A model is
//! its [`Distortion`] on the normalised plane; [`Pinhole`] turns any
//! distortion into `project`, `unproject` and their Jacobians.
//!
//! ```text
//! x   = (X / Z, Y / Z)                 normalise (None behind the camera
//!                                      or where the distortion folds)
//! x_d = distort(x)                     the model's own part
//! px  = (fx x_d.x + cx, fy x_d.y + cy)
//!
//! d px / d P  = diag(fx, fy) D(x) [[1/Z, 0, -X/Z^2], [0, 1/Z, -Y/Z^2]]
//! d x / d px  = D(x)^-1 diag(1/fx, 1/fy)          (inverse function theorem)
//! ```
//!
//! with `D` the distortion's Jacobian.

use nalgebra::{Matrix2, Matrix2x3, Matrix2x4, Matrix3x2, Vector2, Vector3};

use super::CameraError;

/// A distortion of the normalised (z = 1) plane onto itself, invertible on
/// a region around the optical axis (inside the fold, see the module
/// documentation of each model).
pub trait Distortion {
    /// Distorts a point of the normalised plane.
    fn distort(&self, xn: &Vector2<f64>) -> Vector2<f64>;
    /// Jacobian of [`Self::distort`] with respect to the undistorted point.
    fn distort_jacobian(&self, xn: &Vector2<f64>) -> Matrix2<f64>;
    /// Whether `xn` lies inside the region where the distortion is
    /// invertible; `project` refuses points outside it.
    fn is_invertible_at(&self, xn: &Vector2<f64>) -> bool;
    /// The undistorted point inside the invertible region that distorts
    /// onto `xd`, if there is one.
    fn undistort(&self, xd: &Vector2<f64>) -> Option<Vector2<f64>>;
}

/// Focal lengths and principal point, pixels.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pinhole {
    /// Focal length along x, pixels.
    pub fx: f64,
    /// Focal length along y, pixels.
    pub fy: f64,
    /// Principal point x, pixels.
    pub cx: f64,
    /// Principal point y, pixels.
    pub cy: f64,
}

/// A projected point with what its Jacobians are made of.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Projection {
    /// The point on the normalised plane, undistorted.
    pub xn: Vector2<f64>,
    /// The same point distorted.
    pub xd: Vector2<f64>,
    /// The pixel.
    pub px: Vector2<f64>,
    /// Jacobian of the pixel with respect to the point in the camera frame.
    pub d_px_d_point: Matrix2x3<f64>,
}

impl Pinhole {
    /// From `[fx, fy, cx, cy]`.
    pub fn from_array([fx, fy, cx, cy]: [f64; 4]) -> Self {
        Self { fx, fy, cx, cy }
    }

    /// Normalised coordinates of a point in front of the camera (z above
    /// machine epsilon) where `distortion` is invertible.
    pub fn normalise(distortion: &impl Distortion, p_cam: &Vector3<f64>) -> Option<Vector2<f64>> {
        if p_cam.z.is_nan() || p_cam.z <= f64::EPSILON {
            return None;
        }
        let xn = Vector2::new(p_cam.x / p_cam.z, p_cam.y / p_cam.z);
        distortion.is_invertible_at(&xn).then_some(xn)
    }

    /// The pixel of a distorted normalised point.
    pub fn to_pixel(&self, xd: &Vector2<f64>) -> Vector2<f64> {
        Vector2::new(self.fx * xd.x + self.cx, self.fy * xd.y + self.cy)
    }

    /// Pixel of a point in the camera frame; `None` behind the camera or
    /// where the distortion is not invertible.
    pub fn project(
        &self,
        distortion: &impl Distortion,
        p_cam: &Vector3<f64>,
    ) -> Option<Vector2<f64>> {
        let xd = distortion.distort(&Self::normalise(distortion, p_cam)?);
        Some(self.to_pixel(&xd))
    }

    /// [`Self::project`] with the Jacobian of the pixel with respect to the
    /// point, and the intermediate points a model needs for its intrinsic
    /// Jacobian.
    pub fn project_with_point_jacobian(
        &self,
        distortion: &impl Distortion,
        p_cam: &Vector3<f64>,
    ) -> Option<Projection> {
        let xn = Self::normalise(distortion, p_cam)?;
        let xd = distortion.distort(&xn);
        let px = self.to_pixel(&xd);
        let inv_z = 1.0 / p_cam.z;
        let dxn_dp = Matrix2x3::new(inv_z, 0.0, -xn.x * inv_z, 0.0, inv_z, -xn.y * inv_z);
        let focal = Matrix2::new(self.fx, 0.0, 0.0, self.fy);
        let d_px_d_point = focal * distortion.distort_jacobian(&xn) * dxn_dp;
        Some(Projection {
            xn,
            xd,
            px,
            d_px_d_point,
        })
    }

    /// Jacobian of the pixel with respect to fx, fy, cx, cy (in that
    /// order) at the distorted point `xd`.
    pub fn intrinsic_jacobian(xd: &Vector2<f64>) -> Matrix2x4<f64> {
        Matrix2x4::new(xd.x, 0.0, 1.0, 0.0, 0.0, xd.y, 0.0, 1.0)
    }

    /// Ray through a pixel as a point on the z = 1 plane; `None` if the
    /// pixel is not finite or no point where the distortion is invertible
    /// lands on it.
    pub fn unproject(
        &self,
        distortion: &impl Distortion,
        px: &Vector2<f64>,
    ) -> Option<Vector3<f64>> {
        let xd = Vector2::new((px.x - self.cx) / self.fx, (px.y - self.cy) / self.fy);
        if !xd.iter().all(|v| v.is_finite()) {
            return None;
        }
        let xn = distortion.undistort(&xd)?;
        Some(Vector3::new(xn.x, xn.y, 1.0))
    }

    /// The ray of [`Self::unproject`] with its Jacobian with respect to the
    /// pixel (3x2; the last row is zero since the ray stays on z = 1).
    pub fn unproject_with_jacobian(
        &self,
        distortion: &impl Distortion,
        px: &Vector2<f64>,
    ) -> Option<(Vector3<f64>, Matrix3x2<f64>)> {
        let ray = self.unproject(distortion, px)?;
        let d_inv = distortion.distort_jacobian(&ray.xy()).try_inverse()?;
        let dxn_dpx = d_inv * Matrix2::new(1.0 / self.fx, 0.0, 0.0, 1.0 / self.fy);
        let mut jacobian = Matrix3x2::zeros();
        jacobian.fixed_view_mut::<2, 2>(0, 0).copy_from(&dxn_dpx);
        Some((ray, jacobian))
    }
}

/// Checks a model's parameters: non-zero image size, every value finite
/// (`names` gives each its name, pinhole first), positive focal lengths.
pub(crate) fn validate(
    width: u32,
    height: u32,
    pinhole: [f64; 4],
    distortion: &[f64],
    names: &[&'static str],
) -> Result<(), CameraError> {
    if width == 0 || height == 0 {
        return Err(CameraError::EmptyImage { width, height });
    }
    for (&value, &name) in pinhole.iter().chain(distortion).zip(names) {
        if !value.is_finite() {
            return Err(CameraError::NotFinite { name, value });
        }
    }
    let [fx, fy, _, _] = pinhole;
    for (value, name) in [(fx, "fx"), (fy, "fy")] {
        if value <= 0.0 {
            return Err(CameraError::NonPositiveFocalLength { name, value });
        }
    }
    Ok(())
}

/// Kalibr's `intrinsics: [fu, fv, cu, cv]` list as `[fx, fy, cx, cy]`.
pub(crate) fn pinhole_from_kalibr(intrinsics: &[f64]) -> Result<[f64; 4], CameraError> {
    intrinsics.try_into().map_err(|_| CameraError::WrongLength {
        field: "intrinsics",
        expected: "4 (fu, fv, cu, cv)",
        got: intrinsics.len(),
    })
}
