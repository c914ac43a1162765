//! A rig camera as the window's hot loops use it: the calibration plus the
//! radtan model's fold radius computed once. `PinholeRadtan::project`
//! finds that radius (polynomial roots) on every call, which was half the
//! window's time; this wrapper gives the same answers from the model's own
//! `distort` and `distort_jacobian` with the radius cached.

use nalgebra::{Matrix2, Matrix2x3, Vector2, Vector3};

use crate::camera::CameraModel;
use crate::rig::CameraCalibration;

#[derive(Debug, Clone, PartialEq)]
pub struct RigCamera {
    pub calibration: CameraCalibration,
    /// Radtan only: the normalised radius where the distortion folds.
    radtan_max_radius: Option<f64>,
}

impl RigCamera {
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
            (CameraModel::PinholeRadtan(c), Some(r_max)) => {
                let xn = normalise(p_cam, r_max)?;
                let d = c.distort(&xn);
                Some(Vector2::new(c.fx * d.x + c.cx, c.fy * d.y + c.cy))
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
            (CameraModel::PinholeRadtan(c), Some(r_max)) => {
                let xn = normalise(p_cam, r_max)?;
                let d = c.distort(&xn);
                let px = Vector2::new(c.fx * d.x + c.cx, c.fy * d.y + c.cy);
                let inv_z = 1.0 / p_cam.z;
                let dxn_dp = Matrix2x3::new(inv_z, 0.0, -xn.x * inv_z, 0.0, inv_z, -xn.y * inv_z);
                let focal = Matrix2::new(c.fx, 0.0, 0.0, c.fy);
                Some((px, focal * c.distort_jacobian(&xn) * dxn_dp))
            }
            (model, _) => model.project_with_point_jacobian(p_cam),
        }
    }
}

/// The radtan model's normalisation: `None` behind the camera or at or
/// beyond the fold radius.
fn normalise(p_cam: &Vector3<f64>, r_max: f64) -> Option<Vector2<f64>> {
    if p_cam.z.is_nan() || p_cam.z <= f64::EPSILON {
        return None;
    }
    let xn = Vector2::new(p_cam.x / p_cam.z, p_cam.y / p_cam.z);
    (xn.norm() < r_max).then_some(xn)
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
