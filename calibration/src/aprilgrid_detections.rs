//! Per-frame target detections as the yac / Kalibr tools export them: one
//! `<t_ns>.csv` per camera frame with
//! `ts,tag_rows,tag_cols,tag_size,tag_spacing,kp_x,kp_y,p_x,p_y,p_z,tag_id,corner_idx`
//! (pixel keypoints and the matching target points in metres), and the
//! camera's pose against the target from them by PnP with known intrinsics.

use std::path::{Path, PathBuf};

use nalgebra::{Matrix3, Vector2, Vector3};
use rigslam::camera::PinholeRadtan;
use rigslam::dataset::text::data_lines;
use rigslam::dataset::DatasetError;
use rigslam::two_view::{estimate_absolute_pose, AbsolutePoseConfig};

/// The corners seen in one frame.
#[derive(Debug, Clone)]
pub struct TargetDetection {
    pub t_ns: i64,
    pub keypoints_px: Vec<Vector2<f64>>,
    pub target_points_m: Vec<Vector3<f64>>,
    /// Tag edge length written in the file, m.
    pub tag_size_m: f64,
}

/// Reads one detection file. Rows are checked for 12 numeric fields.
pub fn read_detection_file(path: &Path) -> Result<TargetDetection, DatasetError> {
    let text = std::fs::read_to_string(path).map_err(|e| DatasetError::Io {
        path: path.to_path_buf(),
        source: e,
    })?;
    let stem_t_ns: Option<i64> = path
        .file_stem()
        .and_then(|s| s.to_str())
        .and_then(|s| s.parse().ok());
    let mut out = TargetDetection {
        t_ns: stem_t_ns.unwrap_or(0),
        keypoints_px: Vec::new(),
        target_points_m: Vec::new(),
        tag_size_m: 0.0,
    };
    for (line_no, line) in data_lines(&text) {
        let fields: Vec<&str> = line.split(',').map(str::trim).collect();
        if fields.len() != 12 {
            return Err(DatasetError::malformed(
                path,
                line_no,
                format!("expected 12 comma-separated fields (ts, tag_rows, tag_cols, tag_size, tag_spacing, kp_x, kp_y, p_x, p_y, p_z, tag_id, corner_idx), found {}", fields.len()),
            ));
        }
        let number = |i: usize| -> Result<f64, DatasetError> {
            fields[i]
                .parse::<f64>()
                .ok()
                .filter(|v| v.is_finite())
                .ok_or_else(|| {
                    DatasetError::malformed(
                        path,
                        line_no,
                        format!("field {} is not a finite number: {:?}", i + 1, fields[i]),
                    )
                })
        };
        let t_ns: i64 = fields[0].parse().map_err(|_| {
            DatasetError::malformed(
                path,
                line_no,
                format!("timestamp {:?} is not an integer (ns)", fields[0]),
            )
        })?;
        out.t_ns = t_ns;
        out.tag_size_m = number(3)?;
        out.keypoints_px.push(Vector2::new(number(5)?, number(6)?));
        out.target_points_m
            .push(Vector3::new(number(7)?, number(8)?, number(9)?));
    }
    Ok(out)
}

/// Every `*.csv` in `dir`, in time order. Empty files (no corners) are kept
/// with no keypoints.
pub fn read_detection_dir(dir: &Path) -> Result<Vec<TargetDetection>, DatasetError> {
    let entries = std::fs::read_dir(dir).map_err(|e| DatasetError::Io {
        path: dir.to_path_buf(),
        source: e,
    })?;
    let mut files: Vec<PathBuf> = entries
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|e| e == "csv"))
        .collect();
    files.sort();
    let mut out = files
        .iter()
        .map(|f| read_detection_file(f))
        .collect::<Result<Vec<_>, _>>()?;
    out.sort_by_key(|d| d.t_ns);
    Ok(out)
}

/// The camera's pose against the target at one frame.
#[derive(Debug, Clone, Copy)]
#[allow(non_snake_case)]
pub struct TargetPose {
    pub t_ns: i64,
    /// Orientation of the camera in the target frame.
    pub R_target_cam: Matrix3<f64>,
    /// Camera centre in the target frame, m.
    pub p_target_cam: Vector3<f64>,
    pub rms_px: f64,
    pub corners: usize,
    /// Information (inverse covariance) of `p_target_cam` with the
    /// orientation marginalised out, 1/m^2, for the fit's pixel noise.
    pub position_information: Matrix3<f64>,
    /// Regression of the orientation error on the position error
    /// (`Sigma_theta_p Sigma_pp^-1` of the PnP covariance, rad/m): the
    /// expected orientation error (right perturbation of `R_target_cam`)
    /// when the camera centre is off by `e_p`, is `K e_p`.
    pub orientation_given_position: Matrix3<f64>,
}

/// Marginal information of the camera centre from the PnP Jacobian:
/// `P_cam = R_cam_target (X - p)`, rotation perturbed on the right of
/// `R_target_cam`; the 6x6 Gauss-Newton information is inverted and its
/// position block inverted back.
fn position_information(
    camera: &PinholeRadtan,
    r_cam_target: &Matrix3<f64>,
    t_cam_target: &Vector3<f64>,
    points: &[Vector3<f64>],
    sigma_px: f64,
) -> Option<(Matrix3<f64>, Matrix3<f64>)> {
    let mut info = nalgebra::Matrix6::<f64>::zeros();
    for p in points {
        let p_cam = r_cam_target * p + t_cam_target;
        let (_, d_px_d_point, _) = camera.project_with_jacobians(&p_cam)?;
        let mut j = nalgebra::SMatrix::<f64, 2, 6>::zeros();
        j.fixed_view_mut::<2, 3>(0, 0)
            .copy_from(&(d_px_d_point * -r_cam_target));
        j.fixed_view_mut::<2, 3>(0, 3)
            .copy_from(&(d_px_d_point * rigslam::imu::so3::hat(&p_cam)));
        info += j.transpose() * j;
    }
    let covariance = info.try_inverse()?;
    let position = covariance.fixed_view::<3, 3>(0, 0).into_owned();
    let position_inverse = position.try_inverse()?;
    let orientation_given_position =
        covariance.fixed_view::<3, 3>(3, 0).into_owned() * position_inverse;
    Some((
        position_inverse / (sigma_px * sigma_px),
        orientation_given_position,
    ))
}

/// Fewest corners for a frame's PnP to be trusted.
pub const MIN_CORNERS: usize = 12;
/// Frames whose PnP fit is worse than this are dropped, px.
const MAX_POSE_RMS_PX: f64 = 2.0;

/// PnP (P3P + MSAC + LM, `rigslam::two_view`) on every frame with enough
/// corners; frames that fail or fit badly are left out.
pub fn target_poses(camera: &PinholeRadtan, detections: &[TargetDetection]) -> Vec<TargetPose> {
    let config = AbsolutePoseConfig {
        refine_iterations: 20,
        ..AbsolutePoseConfig::for_pixels(2.0, camera.fx)
    };
    let mut out = Vec::new();
    for d in detections
        .iter()
        .filter(|d| d.keypoints_px.len() >= MIN_CORNERS)
    {
        let mut points = Vec::new();
        let mut normalised = Vec::new();
        let mut pixels = Vec::new();
        for (kp, p) in d.keypoints_px.iter().zip(&d.target_points_m) {
            if let Some(ray) = camera.unproject(kp) {
                points.push(*p);
                normalised.push(ray.xy());
                pixels.push(*kp);
            }
        }
        if points.len() < MIN_CORNERS {
            continue;
        }
        let Ok(pose) = estimate_absolute_pose(&points, &normalised, &config) else {
            continue;
        };
        let r_cam_target = pose.T_cam_world.rotation.to_rotation_matrix().into_inner();
        let t_cam_target = pose.T_cam_world.translation.vector;
        let sum_sq: f64 = points
            .iter()
            .zip(&pixels)
            .map(|(p, px)| {
                camera
                    .project(&(r_cam_target * p + t_cam_target))
                    .map_or(1e6, |q| (q - px).norm_squared())
            })
            .sum();
        let rms_px = (sum_sq / points.len() as f64).sqrt();
        if rms_px > MAX_POSE_RMS_PX || pose.inlier_count < points.len() * 9 / 10 {
            continue;
        }
        let Some((info, orientation_given_position)) = position_information(
            camera,
            &r_cam_target,
            &t_cam_target,
            &points,
            rms_px.max(0.1),
        ) else {
            continue;
        };
        out.push(TargetPose {
            t_ns: d.t_ns,
            R_target_cam: r_cam_target.transpose(),
            p_target_cam: -(r_cam_target.transpose() * t_cam_target),
            rms_px,
            corners: points.len(),
            position_information: info,
            orientation_given_position,
        });
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::Write;

    /// `orientation_given_position` against finite differences: with the
    /// camera centre held `dp` away from the truth, the orientation that
    /// best fits the (exact) corners, found by Gauss-Newton on a numerical
    /// Jacobian, is off by `K dp`.
    #[test]
    fn orientation_given_position_matches_refitting_the_orientation() {
        use rigslam::imu::so3;
        let camera = PinholeRadtan {
            width: 752,
            height: 480,
            fx: 458.654,
            fy: 457.296,
            cx: 367.215,
            cy: 248.375,
            distortion: [-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05, 0.0],
        };
        let points: Vec<Vector3<f64>> = (0..12)
            .flat_map(|i| (0..12).map(move |j| Vector3::new(i as f64 * 0.05, j as f64 * 0.05, 0.0)))
            .collect();
        // Camera about 0.9 m from the grid's centre, looking at it obliquely.
        let r_target_cam = so3::exp(&Vector3::new(2.9, 0.25, -0.1));
        let p_target_cam =
            Vector3::new(0.35, 0.2, 0.0) - r_target_cam * Vector3::new(0.02, -0.03, 0.9);
        let project = |r_tc: &Matrix3<f64>, p: &Vector3<f64>| -> Vec<f64> {
            points
                .iter()
                .flat_map(|x| {
                    let q = camera
                        .project(&(r_tc.transpose() * (x - p)))
                        .expect("in front");
                    [q.x, q.y]
                })
                .collect()
        };
        let observed = project(&r_target_cam, &p_target_cam);
        let r_cam_target = r_target_cam.transpose();
        let (_, k) = position_information(
            &camera,
            &r_cam_target,
            &-(r_cam_target * p_target_cam),
            &points,
            0.5,
        )
        .expect("well-posed");
        for dp in [
            Vector3::new(1e-3, 0.0, 0.0),
            Vector3::new(0.0, -1e-3, 0.0),
            Vector3::new(0.0, 0.0, 1e-3),
        ] {
            let p = p_target_cam + dp;
            let mut theta = Vector3::zeros();
            for _ in 0..10 {
                let residual = |t: &Vector3<f64>| -> Vec<f64> {
                    project(&(r_target_cam * so3::exp(t)), &p)
                        .iter()
                        .zip(&observed)
                        .map(|(a, b)| a - b)
                        .collect()
                };
                let r0 = residual(&theta);
                let h = 1e-7;
                let columns: Vec<Vec<f64>> = (0..3)
                    .map(|c| {
                        let mut t = theta;
                        t[c] += h;
                        residual(&t)
                            .iter()
                            .zip(&r0)
                            .map(|(a, b)| (a - b) / h)
                            .collect()
                    })
                    .collect();
                let mut jtj = Matrix3::zeros();
                let mut jtr = Vector3::zeros();
                for i in 0..r0.len() {
                    let row = Vector3::new(columns[0][i], columns[1][i], columns[2][i]);
                    jtj += row * row.transpose();
                    jtr += row * r0[i];
                }
                theta -= jtj.try_inverse().expect("full rank") * jtr;
            }
            let predicted = k * dp;
            assert!(
                (theta - predicted).norm() < 0.02 * theta.norm() + 1e-7,
                "dp {dp:?}: refit {theta:?} vs K dp {predicted:?}"
            );
        }
    }

    #[test]
    fn reads_rows_and_names_the_bad_line() {
        let dir = tempfile::tempdir().expect("temp dir");
        let good = dir.path().join("100.csv");
        let mut f = std::fs::File::create(&good).expect("create");
        writeln!(
            f,
            "#ts,tag_rows,tag_cols,tag_size,tag_spacing,kp_x,kp_y,p_x,p_y,p_z,tag_id,corner_idx"
        )
        .expect("write");
        writeln!(f, "100,6,6,0.088,0.3,10.5,20.25,0.0,0.088,0.0,0,3").expect("write");
        drop(f);
        let d = read_detection_file(&good).expect("valid");
        assert_eq!(d.t_ns, 100);
        assert_eq!(d.keypoints_px, vec![Vector2::new(10.5, 20.25)]);
        assert_eq!(d.target_points_m, vec![Vector3::new(0.0, 0.088, 0.0)]);

        let bad = dir.path().join("200.csv");
        std::fs::write(&bad, "200,6,6,0.088,0.3,10.5,x,0,0,0,0,0\n").expect("write");
        let message = read_detection_file(&bad)
            .expect_err("bad field")
            .to_string();
        assert!(message.contains("200.csv:1:"), "{message}");
    }
}
