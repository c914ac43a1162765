//! Pinhole projection with OpenCV's radial-tangential distortion
//! (k1, k2, p1, p2, k3).

use nalgebra::{Matrix2, Vector2, Vector3};

/// Pinhole camera with radial-tangential distortion, as OpenCV and Kalibr
/// (`pinhole` + `radtan`) define it.
#[derive(Debug, Clone, PartialEq)]
pub struct PinholeRadtan {
    pub width: u32,
    pub height: u32,
    /// fx, fy, cx, cy in pixels.
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
    /// k1, k2, p1, p2, k3.
    pub distortion: [f64; 5],
}

/// Newton iterations allowed when inverting the distortion.
const UNDISTORT_MAX_ITERATIONS: usize = 20;
/// Convergence threshold on the distorted normalised coordinates.
const UNDISTORT_TOLERANCE: f64 = 1e-12;

impl PinholeRadtan {
    /// Distorts a point on the normalised (z = 1) plane.
    pub fn distort(&self, xn: &Vector2<f64>) -> Vector2<f64> {
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
    pub fn distort_jacobian(&self, xn: &Vector2<f64>) -> Matrix2<f64> {
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

    pub fn project(&self, p_cam: &Vector3<f64>) -> Option<Vector2<f64>> {
        if p_cam.z <= f64::EPSILON {
            return None;
        }
        let d = self.distort(&Vector2::new(p_cam.x / p_cam.z, p_cam.y / p_cam.z));
        Some(Vector2::new(
            self.fx * d.x + self.cx,
            self.fy * d.y + self.cy,
        ))
    }

    /// Inverts the distortion by Newton's method from the distorted point.
    pub fn unproject(&self, px: &Vector2<f64>) -> Option<Vector3<f64>> {
        let target = Vector2::new((px.x - self.cx) / self.fx, (px.y - self.cy) / self.fy);
        let mut xn = target;
        for _ in 0..UNDISTORT_MAX_ITERATIONS {
            let residual = self.distort(&xn) - target;
            if residual.norm_squared() < UNDISTORT_TOLERANCE * UNDISTORT_TOLERANCE {
                return Some(Vector3::new(xn.x, xn.y, 1.0));
            }
            let step = self.distort_jacobian(&xn).lu().solve(&residual)?;
            xn -= step;
            if !xn.iter().all(|v| v.is_finite()) {
                return None;
            }
        }
        let residual = self.distort(&xn) - target;
        (residual.norm() < 1e-9).then(|| Vector3::new(xn.x, xn.y, 1.0))
    }
}
