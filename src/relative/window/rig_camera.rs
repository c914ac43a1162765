//! A rig camera as the window's hot loops use it: the calibration plus the
//! radtan model's fold radius computed once. `PinholeRadtan::project`
//! finds that radius (polynomial roots) on every call, which was half the
//! window's time; this wrapper gives the same answers through the same
//! pinhole chain (`camera::pinhole`) with the radius cached.

use nalgebra::{Matrix2, Matrix2x3, Vector2, Vector3};

use crate::camera::{CameraModel, Distortion, Pinhole, PinholeRadtan};
use crate::rig::CameraCalibration;

#[derive(Debug, Clone, PartialEq)]
/// One camera of the rig as the window projects with it: the calibration with the distortion's
/// validity radius cached.
pub struct RigCamera {
    /// Intrinsics, distortion and pose on the body.
    pub calibration: CameraCalibration,
    /// Radtan only: the normalised radius where the distortion folds.
    radtan_max_radius: Option<f64>,
}

/// A radtan camera whose fold radius was computed once.
struct FoldKnown<'a> {
    camera: &'a PinholeRadtan,
    max_radius: f64,
}

impl Distortion for FoldKnown<'_> {
    fn distort(&self, xn: &Vector2<f64>) -> Vector2<f64> {
        self.camera.distort(xn)
    }

    fn distort_jacobian(&self, xn: &Vector2<f64>) -> Matrix2<f64> {
        self.camera.distort_jacobian(xn)
    }

    fn is_invertible_at(&self, xn: &Vector2<f64>) -> bool {
        xn.norm() < self.max_radius
    }

    fn undistort(&self, xd: &Vector2<f64>) -> Option<Vector2<f64>> {
        self.camera.undistort(xd)
    }
}

impl RigCamera {
    /// The camera for `calibration`.
    pub fn new(calibration: CameraCalibration) -> Self {
        let radtan_max_radius = match &calibration.model {
            CameraModel::PinholeRadtan(c) => Some(c.max_valid_radius()),
            CameraModel::PinholeEquidistant(_) => None,
        };
        Self {
            calibration,
            radtan_max_radius,
        }
    }

    /// Same as [`CameraModel::project`].
    pub fn project(&self, p_cam: &Vector3<f64>) -> Option<Vector2<f64>> {
        match (&self.calibration.model, self.radtan_max_radius) {
            (CameraModel::PinholeRadtan(camera), Some(max_radius)) => {
                let pinhole = Pinhole::from_array([camera.fx, camera.fy, camera.cx, camera.cy]);
                pinhole.project(&FoldKnown { camera, max_radius }, p_cam)
            }
            (model, _) => model.project(p_cam),
        }
    }

    /// Same as [`CameraModel::project_with_point_jacobian`].
    pub fn project_with_point_jacobian(
        &self,
        p_cam: &Vector3<f64>,
    ) -> Option<(Vector2<f64>, Matrix2x3<f64>)> {
        match (&self.calibration.model, self.radtan_max_radius) {
            (CameraModel::PinholeRadtan(camera), Some(max_radius)) => {
                let pinhole = Pinhole::from_array([camera.fx, camera.fy, camera.cx, camera.cy]);
                pinhole
                    .project_with_point_jacobian(&FoldKnown { camera, max_radius }, p_cam)
                    .map(|p| (p.px, p.d_px_d_point))
            }
            (model, _) => model.project_with_point_jacobian(p_cam),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::PinholeRadtan;
    use crate::rig::euroc::euroc_cam0;

    #[test]
    fn answers_exactly_as_the_camera_model() {
        // EuRoC's cam0 does not fold; with k1 alone it folds at r ~ 1.09.
        let mut folding = euroc_cam0();
        folding.model = CameraModel::PinholeRadtan(
            PinholeRadtan::new(
                752,
                480,
                [458.654, 457.296, 367.215, 248.375],
                [-0.28, 0.0, 0.0, 0.0, 0.0],
            )
            .expect("valid"),
        );
        for (cal, expect_fold) in [(euroc_cam0(), false), (folding, true)] {
            let cam = RigCamera::new(cal.clone());
            let (mut compared, mut folded) = (0, 0);
            for i in -40..=40 {
                for j in -30..=30 {
                    for z in [-1.0, 1e-20, 0.5, 2.0] {
                        let p = Vector3::new(i as f64 * 0.05, j as f64 * 0.05, z);
                        assert_eq!(cam.project(&p), cal.model.project(&p), "{p}");
                        assert_eq!(
                            cam.project_with_point_jacobian(&p),
                            cal.model.project_with_point_jacobian(&p),
                            "{p}"
                        );
                        let some = cal.model.project(&p).is_some();
                        compared += some as usize;
                        folded += (z > 0.1 && !some) as usize;
                    }
                }
            }
            assert!(compared > 1000, "{compared}");
            assert_eq!(folded > 100, expect_fold, "{folded}");
        }
    }
}
