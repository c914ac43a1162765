//! The stereo extrinsic from the target itself: at every instant both
//! cameras saw the target, `T_cam0_cam1 = T_target_cam0^-1 T_target_cam1`
//! from the two PnP poses, averaged over all such instants (rotations by
//! their chordal mean, translations by their mean, after dropping pairs
//! far from the median). Chaining two separate camera-IMU estimates
//! instead leaves their independent errors (tenths of a degree each) in the
//! pair's relative rotation, which stereo triangulation turns into pixels
//! of disparity; seeing the target with both cameras at once measures the
//! relative pose directly.

use nalgebra::{Isometry3, Matrix3, Rotation3, Translation3, UnitQuaternion, Vector3};

use crate::aprilgrid_detections::TargetPose;

/// The averaged relative pose and how well the instants agree.
#[derive(Debug, Clone)]
#[allow(non_snake_case)]
pub struct StereoExtrinsic {
    /// Maps camera 1 coordinates into camera 0.
    pub T_cam0_cam1: Isometry3<f64>,
    /// Instants used / instants both cameras posed the target.
    pub pairs_used: usize,
    pub pairs: usize,
    /// RMS deviation of the used instants from the mean.
    pub rotation_rms_deg: f64,
    pub translation_rms_m: f64,
}

/// Instants whose relative pose is further than this from the median are
/// dropped (a PnP that converged wrong).
const MAX_ROTATION_OFF_DEG: f64 = 1.0;
const MAX_TRANSLATION_OFF_M: f64 = 0.01;

fn target_from_cam(p: &TargetPose) -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::from(p.p_target_cam),
        UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(p.R_target_cam)),
    )
}

fn chordal_mean(rotations: &[Matrix3<f64>]) -> UnitQuaternion<f64> {
    let sum: Matrix3<f64> = rotations.iter().sum();
    UnitQuaternion::from_matrix(&sum)
}

/// The stereo extrinsic from target poses of both cameras (matched by
/// stamp); `None` with fewer than 10 common instants.
pub fn stereo_extrinsic(cam0: &[TargetPose], cam1: &[TargetPose]) -> Option<StereoExtrinsic> {
    let relative: Vec<Isometry3<f64>> = cam0
        .iter()
        .filter_map(|a| {
            let b = cam1.iter().find(|b| b.t_ns == a.t_ns)?;
            Some(target_from_cam(a).inverse() * target_from_cam(b))
        })
        .collect();
    if relative.len() < 10 {
        return None;
    }
    let median = |values: &mut Vec<f64>| {
        values.sort_by(f64::total_cmp);
        values[values.len() / 2]
    };
    let centre_t = Vector3::from_fn(|k, _| {
        median(&mut relative.iter().map(|t| t.translation.vector[k]).collect())
    });
    let centre_r = chordal_mean(
        &relative
            .iter()
            .map(|t| t.rotation.to_rotation_matrix().into_inner())
            .collect::<Vec<_>>(),
    );
    let used: Vec<&Isometry3<f64>> = relative
        .iter()
        .filter(|t| {
            t.rotation.angle_to(&centre_r).to_degrees() <= MAX_ROTATION_OFF_DEG
                && (t.translation.vector - centre_t).norm() <= MAX_TRANSLATION_OFF_M
        })
        .collect();
    if used.len() < 10 {
        return None;
    }
    let rotation = chordal_mean(
        &used
            .iter()
            .map(|t| t.rotation.to_rotation_matrix().into_inner())
            .collect::<Vec<_>>(),
    );
    let translation: Vector3<f64> = used
        .iter()
        .map(|t| t.translation.vector)
        .sum::<Vector3<f64>>()
        / used.len() as f64;
    let n = used.len() as f64;
    let rotation_rms_deg = (used
        .iter()
        .map(|t| t.rotation.angle_to(&rotation).powi(2))
        .sum::<f64>()
        / n)
        .sqrt()
        .to_degrees();
    let translation_rms_m = (used
        .iter()
        .map(|t| (t.translation.vector - translation).norm_squared())
        .sum::<f64>()
        / n)
        .sqrt();
    Some(StereoExtrinsic {
        T_cam0_cam1: Isometry3::from_parts(Translation3::from(translation), rotation),
        pairs_used: used.len(),
        pairs: relative.len(),
        rotation_rms_deg,
        translation_rms_m,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pose(t_ns: i64, t: &Isometry3<f64>) -> TargetPose {
        TargetPose {
            t_ns,
            R_target_cam: t.rotation.to_rotation_matrix().into_inner(),
            p_target_cam: t.translation.vector,
            rms_px: 0.1,
            corners: 100,
            position_information: Matrix3::identity(),
            orientation_given_position: Matrix3::zeros(),
        }
    }

    #[test]
    fn recovers_a_known_pair_and_drops_a_wrong_instant() {
        let t01 = Isometry3::new(
            Vector3::new(0.11, 0.001, -0.002),
            Vector3::new(0.001, 0.004, -0.002),
        );
        let mut a = Vec::new();
        let mut b = Vec::new();
        for i in 0..40 {
            let f = i as f64;
            let cam0 = Isometry3::new(
                Vector3::new(0.3 + 0.01 * f, -0.2, -1.0 - 0.01 * f),
                Vector3::new(0.1 * (f * 0.3).sin(), 0.2, 0.05 * f.cos()),
            );
            // A little PnP noise on cam1 (alternating, zero mean).
            let wobble = Isometry3::new(
                Vector3::new(if i % 2 == 0 { 2e-4 } else { -2e-4 }, 0.0, 0.0),
                Vector3::new(0.0, if i % 2 == 0 { 1e-4 } else { -1e-4 }, 0.0),
            );
            let mut cam1 = cam0 * t01 * wobble;
            if i == 7 {
                cam1 = cam0 * Isometry3::new(Vector3::new(0.3, 0.0, 0.0), Vector3::zeros());
            }
            a.push(pose(i, &cam0));
            b.push(pose(i, &cam1));
        }
        let s = stereo_extrinsic(&a, &b).expect("enough pairs");
        assert_eq!((s.pairs, s.pairs_used), (40, 39));
        let d = t01.inverse() * s.T_cam0_cam1;
        assert!(
            d.translation.vector.norm() < 1e-5,
            "{}",
            d.translation.vector.norm()
        );
        assert!(d.rotation.angle() < 1e-5);
        assert!(stereo_extrinsic(&a[..5], &b[..5]).is_none());
    }

    /// The stereo refinement against a known pair: EuRoC's two cameras
    /// (their published intrinsics and stereo extrinsic), a 6 x 6 AprilGrid
    /// seen by both from 300 poses at 0.8-1.8 m, corners with 0.36 px of
    /// Gaussian noise per axis (a fit of 0.5 px RMS, as on the real EuRoC
    /// recording), the start 0.2 deg and 5 mm off. The yaw of camera 1
    /// about camera 0's vertical axis is what biases stereo depth; it must
    /// come back to well under the 0.023 deg by which the real recording's
    /// estimate and EuRoC's published pair differ.
    #[test]
    fn the_refinement_recovers_a_known_pair_from_noisy_corners() {
        use crate::aprilgrid_detections::TargetDetection;
        use rand::{Rng, SeedableRng};
        use rand_distr::{Distribution, StandardNormal};
        use rigslam::camera::CameraModel;
        let model = |c: rigslam::rig::CameraCalibration| match c.model {
            CameraModel::PinholeRadtan(p) => p,
            other => panic!("EuRoC's cameras are radtan, got {other:?}"),
        };
        let cal0 = rigslam::rig::euroc::euroc_cam0();
        let cal1 = rigslam::rig::euroc::euroc_cam1();
        let truth = cal0.T_body_cam.inverse() * cal1.T_body_cam;
        let (cam0, cam1) = (model(cal0), model(cal1));
        // Kalibr's 6 x 6 grid: 88 mm tags, 26.4 mm gaps, four corners each.
        let grid = crate::aprilgrid::AprilGridTarget {
            tag_rows: 6,
            tag_cols: 6,
            tag_size_m: 0.088,
            tag_spacing_ratio: 0.3,
        };
        let points: Vec<Vector3<f64>> = (0..grid.tag_count())
            .flat_map(|tag| (0..4).filter_map(move |corner| grid.corner_m(tag, corner)))
            .collect();
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        let mut detections = Vec::new();
        let mut poses = Vec::new();
        while poses.len() < 300 {
            let distance = rng.gen_range(0.8..1.8);
            let tilt = Vector3::new(
                rng.gen_range(-0.5..0.5),
                rng.gen_range(-0.5..0.5),
                rng.gen_range(-0.3..0.3),
            );
            let centre = Vector3::new(
                rng.gen_range(-0.15..0.15),
                rng.gen_range(-0.1..0.1),
                distance,
            );
            // Target frame to camera 0: the grid's middle at `centre`.
            let t_cam0_target =
                Isometry3::new(centre, tilt) * Isometry3::translation(-0.33, -0.33, 0.0);
            let mut seen = Vec::new();
            for (camera, t) in [
                (&cam0, t_cam0_target),
                (&cam1, truth.inverse() * t_cam0_target),
            ] {
                let mut keypoints = Vec::new();
                for x in &points {
                    let p = t * nalgebra::Point3::from(*x);
                    let Some(q) = camera
                        .project(&p.coords)
                        .filter(|q| q.x > 0.0 && q.y > 0.0 && q.x < 752.0 && q.y < 480.0)
                    else {
                        break;
                    };
                    let n = nalgebra::Vector2::new(
                        StandardNormal.sample(&mut rng),
                        StandardNormal.sample(&mut rng),
                    );
                    keypoints.push(q + 0.36 * n);
                }
                if keypoints.len() == points.len() {
                    seen.push(keypoints);
                }
            }
            if seen.len() == 2 {
                let t_ns = poses.len() as i64;
                for keypoints in seen {
                    detections.push(TargetDetection {
                        t_ns,
                        keypoints_px: keypoints,
                        target_points_m: points.clone(),
                        tag_size_m: 0.088,
                    });
                }
                poses.push(t_cam0_target);
            }
        }
        let instants: Vec<StereoInstant<'_>> = poses
            .iter()
            .zip(detections.chunks(2))
            .map(|(t, pair)| StereoInstant {
                cam0: &pair[0],
                cam1: &pair[1],
                T_cam0_target: *t,
            })
            .collect();
        let start = truth
            * Isometry3::new(
                Vector3::new(0.005, 0.0, 0.0),
                Vector3::new(0.0, 0.2f64.to_radians(), 0.0),
            );
        let r = refine_stereo(&cam0, &cam1, &instants, &start, 1.0).expect("refined");
        let d = truth.inverse() * r.T_cam0_cam1;
        let angle_deg = d.rotation.angle().to_degrees();
        // Camera 1's yaw about camera 0's vertical (y) axis.
        let yaw_deg = d.rotation.scaled_axis().y.to_degrees();
        println!(
            "300 instants, {:.3} px RMS: rotation {angle_deg:.5} deg from the truth (yaw {yaw_deg:+.5}), translation {:.3} mm",
            r.rms_px,
            d.translation.vector.norm() * 1e3
        );
        assert!((0.4..0.6).contains(&r.rms_px), "rms {}", r.rms_px);
        assert!(yaw_deg.abs() < 0.005, "yaw {yaw_deg} deg from the truth");
        assert!(angle_deg < 0.005, "{angle_deg} deg from the truth");
        assert!(
            d.translation.vector.norm() < 2e-4,
            "{} m",
            d.translation.vector.norm()
        );
    }
}

/// The stereo extrinsic refined on the corners themselves: one bundle
/// adjustment over every instant both cameras saw the target, unknowns the
/// target's pose in camera 0 per instant and `T_cam1_cam0`, residuals the
/// reprojection errors of both cameras (Huber, 1 px). Each instant's pose is
/// eliminated per step (Schur complement), so the cost is linear in the
/// instants. `target_scale` multiplies the target's points: the scale the
/// camera-IMU batch found the target to have (a tag size printed smaller
/// than declared moves every translation by the same factor).
#[derive(Debug, Clone)]
#[allow(non_snake_case)]
pub struct StereoRefinement {
    pub T_cam0_cam1: Isometry3<f64>,
    pub instants: usize,
    pub rms_px: f64,
    pub iterations: usize,
}

/// One instant both cameras posed: the corners of each.
#[allow(non_snake_case)]
pub struct StereoInstant<'a> {
    pub cam0: &'a crate::aprilgrid_detections::TargetDetection,
    pub cam1: &'a crate::aprilgrid_detections::TargetDetection,
    #[allow(non_snake_case)]
    pub T_cam0_target: Isometry3<f64>,
}

const HUBER_PX: f64 = 1.0;

fn increment(delta: &[f64]) -> Isometry3<f64> {
    Isometry3::new(
        Vector3::new(delta[3], delta[4], delta[5]),
        Vector3::new(delta[0], delta[1], delta[2]),
    )
}

/// Residuals (px) of one camera's corners for the target at `t` in it.
fn residuals(
    camera: &rigslam::camera::PinholeRadtan,
    d: &crate::aprilgrid_detections::TargetDetection,
    t: &Isometry3<f64>,
    scale: f64,
    out: &mut Vec<f64>,
) {
    for (kp, x) in d.keypoints_px.iter().zip(&d.target_points_m) {
        let p = t * nalgebra::Point3::from(x * scale);
        match camera.project(&p.coords) {
            Some(q) => {
                out.push(q.x - kp.x);
                out.push(q.y - kp.y);
            }
            // Keeps the residual count fixed; a point behind the camera
            // weighs nothing below.
            None => {
                out.push(f64::NAN);
                out.push(f64::NAN);
            }
        }
    }
}

fn huber_weight(rx: f64, ry: f64) -> f64 {
    let n = (rx * rx + ry * ry).sqrt();
    if !n.is_finite() {
        0.0
    } else if n <= HUBER_PX {
        1.0
    } else {
        HUBER_PX / n
    }
}

/// All residuals of one instant: camera 0's, then camera 1's.
fn instant_residuals(
    cams: (
        &rigslam::camera::PinholeRadtan,
        &rigslam::camera::PinholeRadtan,
    ),
    i: &StereoInstant<'_>,
    t0: &Isometry3<f64>,
    t10: &Isometry3<f64>,
    scale: f64,
) -> Vec<f64> {
    let mut r = Vec::with_capacity(2 * (i.cam0.keypoints_px.len() + i.cam1.keypoints_px.len()));
    residuals(cams.0, i.cam0, t0, scale, &mut r);
    residuals(cams.1, i.cam1, &(t10 * t0), scale, &mut r);
    r
}

/// Refines `T_cam0_cam1` from `initial`; `None` when the system is
/// degenerate or no instant is given.
#[allow(non_snake_case)]
pub fn refine_stereo(
    camera0: &rigslam::camera::PinholeRadtan,
    camera1: &rigslam::camera::PinholeRadtan,
    instants: &[StereoInstant<'_>],
    initial_T_cam0_cam1: &Isometry3<f64>,
    target_scale: f64,
) -> Option<StereoRefinement> {
    use nalgebra::{DMatrix, Matrix6, Vector6};
    if instants.is_empty() {
        return None;
    }
    let cams = (camera0, camera1);
    let mut t10 = initial_T_cam0_cam1.inverse();
    let mut poses: Vec<Isometry3<f64>> = instants.iter().map(|i| i.T_cam0_target).collect();
    let cost = |t10: &Isometry3<f64>, poses: &[Isometry3<f64>]| -> (f64, usize) {
        let mut sum = 0.0;
        let mut n = 0;
        for (i, t0) in instants.iter().zip(poses) {
            let r = instant_residuals(cams, i, t0, t10, target_scale);
            for pair in r.chunks(2) {
                let w = huber_weight(pair[0], pair[1]);
                if w > 0.0 {
                    sum += w * (pair[0] * pair[0] + pair[1] * pair[1]);
                    n += 1;
                }
            }
        }
        (sum, n)
    };
    let eps = 1e-6;
    let mut iterations = 0;
    let mut lambda = 1e-4;
    let (mut current, _) = cost(&t10, &poses);
    for _ in 0..20 {
        iterations += 1;
        let mut h_rr = Matrix6::<f64>::zeros();
        let mut g_r = Vector6::<f64>::zeros();
        let mut blocks = Vec::with_capacity(instants.len());
        for (i, t0) in instants.iter().zip(&poses) {
            let r = instant_residuals(cams, i, t0, &t10, target_scale);
            let m = r.len();
            let n0 = 2 * i.cam0.keypoints_px.len();
            let mut jf = DMatrix::<f64>::zeros(m, 6);
            let mut jr = DMatrix::<f64>::zeros(m, 6);
            for k in 0..6 {
                let mut d = [0.0; 6];
                d[k] = eps;
                let plus = instant_residuals(cams, i, &(increment(&d) * t0), &t10, target_scale);
                d[k] = -eps;
                let minus = instant_residuals(cams, i, &(increment(&d) * t0), &t10, target_scale);
                for row in 0..m {
                    jf[(row, k)] = (plus[row] - minus[row]) / (2.0 * eps);
                }
                d[k] = eps;
                let plus = instant_residuals(cams, i, t0, &(increment(&d) * t10), target_scale);
                d[k] = -eps;
                let minus = instant_residuals(cams, i, t0, &(increment(&d) * t10), target_scale);
                for row in n0..m {
                    jr[(row, k)] = (plus[row] - minus[row]) / (2.0 * eps);
                }
            }
            let mut h_ff = Matrix6::<f64>::zeros();
            let mut h_fr = Matrix6::<f64>::zeros();
            let mut g_f = Vector6::<f64>::zeros();
            for pair in 0..m / 2 {
                let (a, b) = (2 * pair, 2 * pair + 1);
                let w = huber_weight(r[a], r[b]);
                if w == 0.0
                    || !jf
                        .row(a)
                        .iter()
                        .chain(jf.row(b).iter())
                        .all(|v| v.is_finite())
                {
                    continue;
                }
                for row in [a, b] {
                    let f = Vector6::from_iterator(jf.row(row).iter().copied());
                    let q = Vector6::from_iterator(jr.row(row).iter().copied());
                    h_ff += w * f * f.transpose();
                    h_fr += w * f * q.transpose();
                    h_rr += w * q * q.transpose();
                    g_f += w * f * r[row];
                    g_r += w * q * r[row];
                }
            }
            blocks.push((h_ff, h_fr, g_f));
        }
        // Schur complement onto the relative pose, damped (Levenberg).
        let mut s = h_rr;
        let mut rhs = g_r;
        let mut inverses = Vec::with_capacity(blocks.len());
        for (h_ff, h_fr, g_f) in &blocks {
            let damped = h_ff + Matrix6::from_diagonal(&h_ff.diagonal()) * lambda;
            let inv = damped.try_inverse()?;
            s -= h_fr.transpose() * inv * h_fr;
            rhs -= h_fr.transpose() * inv * g_f;
            inverses.push(inv);
        }
        s += Matrix6::from_diagonal(&h_rr.diagonal()) * lambda;
        let dr = -(s.try_inverse()? * rhs);
        let new_t10 = increment(dr.as_slice()) * t10;
        let new_poses: Vec<Isometry3<f64>> = blocks
            .iter()
            .zip(&inverses)
            .zip(&poses)
            .map(|(((_, h_fr, g_f), inv), t0)| {
                let df = -(inv * (g_f + h_fr * dr));
                increment(df.as_slice()) * t0
            })
            .collect();
        let (candidate, _) = cost(&new_t10, &new_poses);
        if candidate < current {
            let converged = (current - candidate) / current < 1e-9;
            t10 = new_t10;
            poses = new_poses;
            current = candidate;
            lambda = (lambda * 0.3).max(1e-9);
            if converged {
                break;
            }
        } else {
            lambda *= 10.0;
            if lambda > 1e4 {
                break;
            }
        }
    }
    let (sum, n) = cost(&t10, &poses);
    Some(StereoRefinement {
        T_cam0_cam1: t10.inverse(),
        instants: instants.len(),
        rms_px: (sum / n.max(1) as f64).sqrt(),
        iterations,
    })
}
