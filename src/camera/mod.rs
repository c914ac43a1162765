//! Camera models: how a 3-D point in the camera frame lands on the image
//! and back. Pinhole with OpenCV radial-tangential distortion today; the
//! enum leaves room for an equidistant (fisheye) model.

pub mod radtan;

use nalgebra::{Vector2, Vector3};

pub use radtan::PinholeRadtan;

/// A calibrated camera, whatever its projection model.
#[derive(Debug, Clone, PartialEq)]
pub enum CameraModel {
    PinholeRadtan(PinholeRadtan),
}

impl CameraModel {
    /// Pixel of a point in the camera frame (z forward); `None` behind the camera.
    pub fn project(&self, p_cam: &Vector3<f64>) -> Option<Vector2<f64>> {
        match self {
            CameraModel::PinholeRadtan(c) => c.project(p_cam),
        }
    }
    /// Ray through a pixel as a point on the z = 1 plane; `None` where the
    /// model cannot be inverted.
    pub fn unproject(&self, px: &Vector2<f64>) -> Option<Vector3<f64>> {
        match self {
            CameraModel::PinholeRadtan(c) => c.unproject(px),
        }
    }
    pub fn width(&self) -> u32 {
        match self {
            CameraModel::PinholeRadtan(c) => c.width,
        }
    }
    pub fn height(&self) -> u32 {
        match self {
            CameraModel::PinholeRadtan(c) => c.height,
        }
    }
}
