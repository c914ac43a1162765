//! Camera models: how a 3-D point in the camera frame lands on the image
//! and back.
//!
//! Two models, both as Kalibr names them and OpenCV implements them:
//!
//! - [`PinholeRadtan`]: pinhole with radial-tangential (Brown-Conrady)
//!   distortion, k1 k2 p1 p2 k3 (Kalibr `pinhole` + `radtan`; EuRoC's
//!   VI-Sensor).
//! - [`PinholeEquidistant`]: pinhole with the equidistant fisheye
//!   distortion of Kannala and Brandt, k1..k4 on the angle of incidence
//!   (Kalibr `pinhole` + `equidistant`, OpenCV `fisheye`).
//!
//! Each model has a *fold* limit beyond which its distortion polynomial
//! stops being monotone and the image folds back on itself; `project`
//! refuses points beyond it and `unproject` returns only rays inside it.
//!
//! Every model offers `project`, `unproject` (a ray on the z = 1 plane),
//! `project_with_jacobians` (pixel w.r.t. point and intrinsics; the
//! intrinsic vector's length is model-specific, so it lives on the model
//! type) and `unproject_with_jacobian` (ray w.r.t. pixel). The enum
//! exposes the model-independent ones. The pinhole and the chain rule
//! through it are written once ([`pinhole`]); a model is its
//! [`Distortion`] of the normalised plane plus its intrinsic Jacobian. A
//! new model (e.g. double sphere) is one more variant and one more file.

pub mod equidistant;
pub mod pinhole;
mod polynomial;
pub mod radtan;

#[cfg(test)]
mod finite_difference;

use nalgebra::{Matrix2x3, Matrix3x2, Vector2, Vector3};

pub use equidistant::PinholeEquidistant;
pub use pinhole::{Distortion, Pinhole};
pub use radtan::PinholeRadtan;

/// Why camera parameters were rejected. Readers wrap it with the file and
/// field the values came from.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CameraError {
    /// The image width or height is zero.
    #[error("image size {width}x{height}: both sides must be non-zero")]
    EmptyImage {
        /// Image width as given, pixels.
        width: u32,
        /// Image height as given, pixels.
        height: u32,
    },
    /// An intrinsic or distortion coefficient is NaN or infinite.
    #[error("camera parameter `{name}` = {value} is not a finite number")]
    NotFinite {
        /// The parameter's name as the model lists it (`fx`, `cy`, `k2`, `p1`, ...).
        name: &'static str,
        /// The offending value.
        value: f64,
    },
    /// A focal length is zero or negative.
    #[error("focal length `{name}` = {value} must be positive")]
    NonPositiveFocalLength {
        /// `fx` or `fy`.
        name: &'static str,
        /// The offending value, pixels.
        value: f64,
    },
    /// [`CameraModel::from_kalibr`] was given a distortion model name other
    /// than `radtan`, `radial-tangential` or `equidistant`.
    #[error("distortion model `{name}` is not one of radtan, radial-tangential, equidistant")]
    UnknownDistortionModel {
        /// The name as read.
        name: String,
    },
    /// A Kalibr/EuRoC parameter list has the wrong number of values for the
    /// model.
    #[error("`{field}` lists {got} values, expected {expected}")]
    WrongLength {
        /// The list: `intrinsics` or `distortion_coefficients`.
        field: &'static str,
        /// The accepted length(s), with the values' names.
        expected: &'static str,
        /// How many values the list had.
        got: usize,
    },
}

/// A calibrated camera, whatever its projection model.
#[derive(Debug, Clone, PartialEq)]
pub enum CameraModel {
    /// Pinhole with radial-tangential distortion (Kalibr `radtan`).
    PinholeRadtan(PinholeRadtan),
    /// Pinhole with equidistant fisheye distortion (Kalibr `equidistant`).
    PinholeEquidistant(PinholeEquidistant),
}

impl CameraModel {
    /// A pinhole camera from Kalibr/EuRoC lists, its distortion named as
    /// Kalibr (`radtan`, `equidistant`) or EuRoC's `sensor.yaml`
    /// (`radial-tangential`) names it. See [`PinholeRadtan::from_kalibr`]
    /// and [`PinholeEquidistant::from_kalibr`] for the lists.
    pub fn from_kalibr(
        width: u32,
        height: u32,
        distortion_model: &str,
        intrinsics: &[f64],
        distortion: &[f64],
    ) -> Result<Self, CameraError> {
        match distortion_model {
            "radtan" | "radial-tangential" => {
                PinholeRadtan::from_kalibr(width, height, intrinsics, distortion).map(Self::from)
            }
            "equidistant" => PinholeEquidistant::from_kalibr(width, height, intrinsics, distortion)
                .map(Self::from),
            other => Err(CameraError::UnknownDistortionModel {
                name: other.to_owned(),
            }),
        }
    }

    /// Kalibr's name of the distortion model: `radtan` or `equidistant`
    /// (EuRoC's `sensor.yaml` spells the first `radial-tangential`).
    pub fn kalibr_distortion_model(&self) -> &'static str {
        match self {
            CameraModel::PinholeRadtan(_) => "radtan",
            CameraModel::PinholeEquidistant(_) => "equidistant",
        }
    }

    /// fx, fy, cx, cy in pixels.
    pub fn pinhole(&self) -> [f64; 4] {
        match self {
            CameraModel::PinholeRadtan(c) => [c.fx, c.fy, c.cx, c.cy],
            CameraModel::PinholeEquidistant(c) => c.pinhole(),
        }
    }

    /// Distortion coefficients in the model's own order: k1 k2 p1 p2 k3
    /// (radtan, five even when k3 = 0) or k1 k2 k3 k4 (equidistant).
    pub fn distortion_coefficients(&self) -> Vec<f64> {
        match self {
            CameraModel::PinholeRadtan(c) => c.distortion.to_vec(),
            CameraModel::PinholeEquidistant(c) => c.distortion().to_vec(),
        }
    }

    /// Pixel of a point in the camera frame (z forward); `None` behind the
    /// camera or beyond the model's fold limit.
    pub fn project(&self, p_cam: &Vector3<f64>) -> Option<Vector2<f64>> {
        match self {
            CameraModel::PinholeRadtan(c) => c.project(p_cam),
            CameraModel::PinholeEquidistant(c) => c.project(p_cam),
        }
    }

    /// Pixel and its Jacobian with respect to the point in the camera
    /// frame (2x3).
    pub fn project_with_point_jacobian(
        &self,
        p_cam: &Vector3<f64>,
    ) -> Option<(Vector2<f64>, Matrix2x3<f64>)> {
        match self {
            CameraModel::PinholeRadtan(c) => c
                .project_with_jacobians(p_cam)
                .map(|(px, d_point, _)| (px, d_point)),
            CameraModel::PinholeEquidistant(c) => c
                .project_with_jacobians(p_cam)
                .map(|(px, d_point, _)| (px, d_point)),
        }
    }

    /// Ray through a pixel as a point on the z = 1 plane; `None` where the
    /// model cannot be inverted.
    pub fn unproject(&self, px: &Vector2<f64>) -> Option<Vector3<f64>> {
        match self {
            CameraModel::PinholeRadtan(c) => c.unproject(px),
            CameraModel::PinholeEquidistant(c) => c.unproject(px),
        }
    }

    /// Ray through a pixel (z = 1) and its Jacobian with respect to the
    /// pixel (3x2, last row zero), e.g. to propagate a pixel covariance
    /// onto the ray.
    pub fn unproject_with_jacobian(
        &self,
        px: &Vector2<f64>,
    ) -> Option<(Vector3<f64>, Matrix3x2<f64>)> {
        match self {
            CameraModel::PinholeRadtan(c) => c.unproject_with_jacobian(px),
            CameraModel::PinholeEquidistant(c) => c.unproject_with_jacobian(px),
        }
    }

    /// Image width, pixels.
    pub fn width(&self) -> u32 {
        match self {
            CameraModel::PinholeRadtan(c) => c.width,
            CameraModel::PinholeEquidistant(c) => c.width(),
        }
    }

    /// Image height, pixels.
    pub fn height(&self) -> u32 {
        match self {
            CameraModel::PinholeRadtan(c) => c.height,
            CameraModel::PinholeEquidistant(c) => c.height(),
        }
    }
}

impl From<PinholeRadtan> for CameraModel {
    fn from(camera: PinholeRadtan) -> Self {
        CameraModel::PinholeRadtan(camera)
    }
}

impl From<PinholeEquidistant> for CameraModel {
    fn from(camera: PinholeEquidistant) -> Self {
        CameraModel::PinholeEquidistant(camera)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The enum forwards to each model: same pixels, rays and Jacobians.
    #[test]
    fn enum_forwards_to_the_model() {
        let radtan = PinholeRadtan::new(
            752,
            480,
            [458.654, 457.296, 367.215, 248.375],
            [-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05, 0.0],
        )
        .expect("valid parameters");
        let fisheye = PinholeEquidistant::new(
            512,
            512,
            [190.978, 190.973, 254.932, 256.897],
            [0.0035, 0.0007, -0.0021, 0.0002],
        )
        .expect("valid parameters");
        let p = Vector3::new(0.4, -0.3, 2.0);
        let px = Vector2::new(100.0, 50.0);

        let model = CameraModel::from(radtan.clone());
        assert_eq!((model.width(), model.height()), (752, 480));
        assert_eq!(model.project(&p), radtan.project(&p));
        let (pixel, d_point, _) = radtan.project_with_jacobians(&p).expect("projects");
        assert_eq!(
            model.project_with_point_jacobian(&p),
            Some((pixel, d_point))
        );
        assert_eq!(model.unproject(&px), radtan.unproject(&px));
        assert_eq!(
            model.unproject_with_jacobian(&px),
            radtan.unproject_with_jacobian(&px)
        );

        let model = CameraModel::from(fisheye.clone());
        assert_eq!((model.width(), model.height()), (512, 512));
        assert_eq!(model.project(&p), fisheye.project(&p));
        let (pixel, d_point, _) = fisheye.project_with_jacobians(&p).expect("projects");
        assert_eq!(
            model.project_with_point_jacobian(&p),
            Some((pixel, d_point))
        );
        assert_eq!(model.unproject(&px), fisheye.unproject(&px));
        assert_eq!(
            model.unproject_with_jacobian(&px),
            fisheye.unproject_with_jacobian(&px)
        );
        assert!(model.unproject(&px).is_some());
    }

    #[test]
    fn from_kalibr_dispatches_on_the_model_name() {
        let pinhole = [458.654, 457.296, 367.215, 248.375];
        let four = [-0.28, 0.07, 0.0002, 0.00002];
        for name in ["radtan", "radial-tangential"] {
            let model = CameraModel::from_kalibr(752, 480, name, &pinhole, &four).expect("valid");
            let expected = PinholeRadtan::from_kalibr(752, 480, &pinhole, &four).expect("valid");
            assert_eq!(model, CameraModel::PinholeRadtan(expected));
            assert_eq!(model.kalibr_distortion_model(), "radtan");
            assert_eq!(model.pinhole(), pinhole);
            assert_eq!(
                model.distortion_coefficients(),
                [-0.28, 0.07, 0.0002, 0.00002, 0.0]
            );
        }
        let model =
            CameraModel::from_kalibr(752, 480, "equidistant", &pinhole, &four).expect("valid");
        assert_eq!(model.kalibr_distortion_model(), "equidistant");
        assert_eq!(model.distortion_coefficients(), four);
        assert_eq!(
            CameraModel::from_kalibr(752, 480, "fov", &pinhole, &four),
            Err(CameraError::UnknownDistortionModel { name: "fov".into() })
        );
        // Errors of the model's own constructor come through.
        assert!(matches!(
            CameraModel::from_kalibr(752, 480, "equidistant", &pinhole, &four[..2]),
            Err(CameraError::WrongLength { got: 2, .. })
        ));
    }
}
