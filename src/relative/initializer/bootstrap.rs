//! The vision-only start of the mono modes: two views far enough apart,
//! their relative pose, the first translation set to unit length (the
//! paper's initialisation: "the first translation = 1"), and the inliers
//! triangulated into landmarks in the first camera's frame; then PnP
//! places the frames between (or after) against those landmarks.
//!
//! The chain reuses [`crate::two_view`]: five-point MSAC with cheirality
//! and refinement ([`estimate_relative_pose`]), optimal two-view correction
//! then linear triangulation with parallax and depth checks
//! ([`triangulate`]), P3P MSAC ([`estimate_absolute_pose`]).
//!
//! Refusals. Pure rotation (the relative-pose estimator finds no
//! observable translation), too little parallax (median rotation-
//! compensated parallax of the inliers below `min_parallax_px`: depth
//! would be mostly noise), too few correspondences, inliers or landmarks.
//! Each refusal says which and by how much, so that the caller waits for
//! a later frame.

use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector2, Vector3};

use crate::camera::CameraModel;
use crate::relative::types::{LandmarkId, TrackedFrame};
use crate::two_view::{
    estimate_absolute_pose, estimate_relative_pose, triangulate, AbsolutePoseConfig,
    RelativePoseConfig, TriangulationConfig, TwoViewError,
};

/// Settings of [`bootstrap_two_view`].
#[derive(Debug, Clone, PartialEq)]
pub struct BootstrapConfig {
    /// Which camera's observations to use (0 = left or only).
    pub camera_index: u8,
    /// Fewest landmarks seen in both frames.
    pub min_correspondences: usize,
    /// MSAC inlier threshold (Sampson error), pixels.
    pub ransac_threshold_px: f64,
    /// Smallest median rotation-compensated parallax of the inliers.
    pub min_parallax_px: f64,
    /// Fewest MSAC inliers.
    pub min_inliers: usize,
    /// Smallest fraction of the correspondences that must be inliers.
    pub min_inlier_ratio: f64,
    /// Fewest landmarks that must survive triangulation.
    pub min_landmarks: usize,
    /// Per-point checks; depths in units of the (unit) first translation.
    pub triangulation: TriangulationConfig,
    /// Seed of the MSAC sampler; the same seed and input give the same result.
    pub seed: u64,
}

impl Default for BootstrapConfig {
    fn default() -> Self {
        Self {
            camera_index: 0,
            min_correspondences: 40,
            ransac_threshold_px: 1.0,
            min_parallax_px: 20.0,
            min_inliers: 30,
            min_inlier_ratio: 0.5,
            min_landmarks: 25,
            triangulation: TriangulationConfig {
                min_parallax_rad: 0.5_f64.to_radians(),
                min_depth: 1e-3,
                max_depth: 500.0,
            },
            seed: 0,
        }
    }
}

/// Why two frames do not start the map.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum BootstrapRefusal {
    #[error("{found} landmarks seen in both frames, need {needed}")]
    /// Too few landmarks are seen in both frames.
    TooFewCorrespondences {
        /// Landmarks seen in both.
        found: usize,
        /// Landmarks needed.
        needed: usize,
    },
    #[error("pure rotation: translation not observable (median parallax {median_parallax_px} px)")]
    /// The camera only rotated between the frames: the translation is not observable.
    PureRotation {
        /// Median rotation-compensated parallax of the inliers, px.
        median_parallax_px: f64,
    },
    #[error("median parallax {median_parallax_px} px, need {needed_px}")]
    /// The inliers' parallax is below the minimum.
    TooLittleParallax {
        /// Median rotation-compensated parallax of the inliers, px.
        median_parallax_px: f64,
        /// The minimum, px.
        needed_px: f64,
    },
    #[error("{inliers} of {correspondences} correspondences are inliers, need {needed}")]
    /// Too few correspondences are MSAC inliers (in number or in share).
    TooFewInliers {
        /// Inliers.
        inliers: usize,
        /// Correspondences.
        correspondences: usize,
        /// Inliers needed.
        needed: usize,
    },
    #[error("{found} landmarks triangulated, need {needed}")]
    /// Too few landmarks survive triangulation.
    TooFewLandmarks {
        /// Landmarks triangulated.
        found: usize,
        /// Landmarks needed.
        needed: usize,
    },
    #[error("the camera model has no usable focal length")]
    /// The camera model has no usable focal length to convert the pixel thresholds.
    BadCamera,
    #[error(transparent)]
    /// The two-view estimation failed (too few or bad correspondences, no consensus).
    Geometry(#[from] TwoViewError),
}

/// A landmark in the first camera's frame, in units of the first
/// translation.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Landmark {
    /// The landmark's track id.
    pub id: LandmarkId,
    /// Position in the first camera's frame, in units of the first translation.
    pub position_c0: Vector3<f64>,
}

/// The two-view start.
#[allow(non_snake_case)]
#[derive(Debug, Clone, PartialEq)]
pub struct Bootstrap {
    /// Stamp of the first frame, ns.
    pub t_first_ns: i64,
    /// Stamp of the second frame, ns.
    pub t_second_ns: i64,
    /// Maps the second camera's coordinates into the first's; the
    /// translation has unit length.
    pub T_c0_c1: Isometry3<f64>,
    /// Sorted by id.
    pub landmarks: Vec<Landmark>,
    /// Landmarks seen in both frames.
    pub correspondences: usize,
    /// MSAC inliers among them.
    pub inlier_count: usize,
    /// Median rotation-compensated parallax of the inliers, px.
    pub median_parallax_px: f64,
}

/// Normalised image coordinates (z = 1) of a pixel.
fn normalised(camera: &CameraModel, px: &Vector2<f64>) -> Option<Vector2<f64>> {
    let ray = camera.unproject(px)?;
    let x = Vector2::new(ray.x / ray.z, ray.y / ray.z);
    x.iter().all(|v| v.is_finite()).then_some(x)
}

fn focal_px(camera: &CameraModel) -> Option<f64> {
    let [fx, fy, _, _] = camera.pinhole();
    let f = 0.5 * (fx + fy);
    (f > 0.0 && f.is_finite()).then_some(f)
}

/// Starts the map from `first` and `second` (observations of
/// `config.camera_index`, matched by landmark id), or says why not.
pub fn bootstrap_two_view(
    first: &TrackedFrame,
    second: &TrackedFrame,
    camera: &CameraModel,
    config: &BootstrapConfig,
) -> Result<Bootstrap, BootstrapRefusal> {
    let focal = focal_px(camera).ok_or(BootstrapRefusal::BadCamera)?;
    let mut seen: Vec<(LandmarkId, Vector2<f64>)> = first
        .in_camera(config.camera_index)
        .filter_map(|o| normalised(camera, &o.pixel).map(|x| (o.landmark, x)))
        .collect();
    seen.sort_by_key(|e| e.0);
    seen.dedup_by_key(|e| e.0);
    let mut ids = Vec::new();
    let (mut x1, mut x2) = (Vec::new(), Vec::new());
    for o in second.in_camera(config.camera_index) {
        let Ok(k) = seen.binary_search_by_key(&o.landmark, |e| e.0) else {
            continue;
        };
        if ids.contains(&o.landmark) {
            continue;
        }
        if let Some(x) = normalised(camera, &o.pixel) {
            ids.push(o.landmark);
            x1.push(seen[k].1);
            x2.push(x);
        }
    }
    let needed = config.min_correspondences.max(5);
    if ids.len() < needed {
        return Err(BootstrapRefusal::TooFewCorrespondences {
            found: ids.len(),
            needed,
        });
    }
    let ransac = RelativePoseConfig {
        seed: config.seed,
        min_inliers: config.min_inliers,
        ..RelativePoseConfig::for_pixels(config.ransac_threshold_px, focal)
    };
    let pose = estimate_relative_pose(&x1, &x2, &ransac)?;
    let median_parallax_px = pose.median_parallax_rad * focal;
    let Some(t_dir) = pose.translation_dir_c2_c1 else {
        return Err(BootstrapRefusal::PureRotation { median_parallax_px });
    };
    if !(median_parallax_px >= config.min_parallax_px) {
        return Err(BootstrapRefusal::TooLittleParallax {
            median_parallax_px,
            needed_px: config.min_parallax_px,
        });
    }
    let needed_inliers = config
        .min_inliers
        .max((config.min_inlier_ratio * ids.len() as f64).ceil() as usize);
    if pose.inlier_count < needed_inliers {
        return Err(BootstrapRefusal::TooFewInliers {
            inliers: pose.inlier_count,
            correspondences: ids.len(),
            needed: needed_inliers,
        });
    }
    // The first translation has unit length.
    let r = pose.rotation_c2_c1.into_inner();
    let t = t_dir.into_inner();
    let mut landmarks: Vec<Landmark> = ids
        .iter()
        .enumerate()
        .filter(|(k, _)| pose.inliers[*k])
        .filter_map(|(k, id)| {
            triangulate(&r, &t, &x1[k], &x2[k], &config.triangulation)
                .ok()
                .map(|p| Landmark {
                    id: *id,
                    position_c0: p.point_c1,
                })
        })
        .collect();
    if landmarks.len() < config.min_landmarks {
        return Err(BootstrapRefusal::TooFewLandmarks {
            found: landmarks.len(),
            needed: config.min_landmarks,
        });
    }
    landmarks.sort_by_key(|l| l.id);
    let rotation_c0_c1 = UnitQuaternion::from_rotation_matrix(&pose.rotation_c2_c1.inverse());
    let t_c0_c1 = Isometry3::from_parts(Translation3::from(-(rotation_c0_c1 * t)), rotation_c0_c1);
    Ok(Bootstrap {
        t_first_ns: first.t_ns,
        t_second_ns: second.t_ns,
        T_c0_c1: t_c0_c1,
        landmarks,
        correspondences: ids.len(),
        inlier_count: pose.inlier_count,
        median_parallax_px,
    })
}

/// Settings of [`pnp_frame`].
#[derive(Debug, Clone, PartialEq)]
pub struct PnpConfig {
    /// Which camera's observations to use (0 = left or only).
    pub camera_index: u8,
    /// Reprojection inlier threshold, pixels.
    pub threshold_px: f64,
    /// Fewest inliers for the pose to be accepted.
    pub min_inliers: usize,
    /// Seed of the RANSAC sampler; the same seed and input give the same result.
    pub seed: u64,
}

impl Default for PnpConfig {
    fn default() -> Self {
        Self {
            camera_index: 0,
            threshold_px: 2.0,
            min_inliers: 12,
            seed: 0,
        }
    }
}

/// A frame placed against the bootstrap landmarks.
#[allow(non_snake_case)]
#[derive(Debug, Clone, PartialEq)]
pub struct PnpFrame {
    /// Frame stamp, ns.
    pub t_ns: i64,
    /// Maps this camera's coordinates into the first camera's frame, in
    /// the landmarks' units.
    pub T_c0_cam: Isometry3<f64>,
    /// Bootstrap landmarks seen in the frame.
    pub correspondences: usize,
    /// RANSAC inliers among them.
    pub inlier_count: usize,
}

/// The pose of `frame` from the `landmarks` it sees (sorted by id, as
/// [`Bootstrap::landmarks`]), by P3P MSAC and refinement.
pub fn pnp_frame(
    frame: &TrackedFrame,
    landmarks: &[Landmark],
    camera: &CameraModel,
    config: &PnpConfig,
) -> Result<PnpFrame, BootstrapRefusal> {
    let focal = focal_px(camera).ok_or(BootstrapRefusal::BadCamera)?;
    let (mut points, mut x) = (Vec::new(), Vec::new());
    for o in frame.in_camera(config.camera_index) {
        let Ok(k) = landmarks.binary_search_by_key(&o.landmark, |l| l.id) else {
            continue;
        };
        if let Some(n) = normalised(camera, &o.pixel) {
            points.push(landmarks[k].position_c0);
            x.push(n);
        }
    }
    let needed = config.min_inliers.max(4);
    if points.len() < needed {
        return Err(BootstrapRefusal::TooFewCorrespondences {
            found: points.len(),
            needed,
        });
    }
    let absolute = AbsolutePoseConfig {
        min_inliers: needed,
        seed: config.seed,
        ..AbsolutePoseConfig::for_pixels(config.threshold_px, focal)
    };
    let pose = estimate_absolute_pose(&points, &x, &absolute)?;
    Ok(PnpFrame {
        t_ns: frame.t_ns,
        T_c0_cam: pose.T_cam_world.inverse(),
        correspondences: points.len(),
        inlier_count: pose.inlier_count,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::relative::types::Observation;
    use crate::rig::euroc::euroc_cam0;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;
    use rand_distr::{Distribution, Normal};

    /// Points in front of the first camera, seen through the real EuRoC
    /// cam0 model from camera poses `T_c0_ck`.
    struct Scene {
        points_c0: Vec<Vector3<f64>>,
        camera: CameraModel,
    }

    fn scene(seed: u64) -> Scene {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let points_c0 = (0..250)
            .map(|_| {
                Vector3::new(
                    rng.gen_range(-4.0..4.0),
                    rng.gen_range(-2.5..2.5),
                    rng.gen_range(4.0..10.0),
                )
            })
            .collect();
        Scene {
            points_c0,
            camera: euroc_cam0().model,
        }
    }

    /// Observations of the points visible from `t_c0_cam`, with pixel
    /// noise and a fraction of outliers moved by 20-60 px.
    fn frame(
        scene: &Scene,
        t_c0_cam: &Isometry3<f64>,
        t_ns: i64,
        noise_px: f64,
        outliers: f64,
        rng: &mut ChaCha8Rng,
    ) -> (TrackedFrame, Vec<LandmarkId>) {
        let normal = Normal::new(0.0, noise_px.max(1e-300)).expect("valid sigma");
        let mut observations = Vec::new();
        let mut outlier_ids = Vec::new();
        for (k, p) in scene.points_c0.iter().enumerate() {
            let p_cam = t_c0_cam.inverse_transform_point(&(*p).into()).coords;
            let Some(mut px) = scene.camera.project(&p_cam) else {
                continue;
            };
            if !(px.x > 0.0 && px.y > 0.0 && px.x < 752.0 && px.y < 480.0) {
                continue;
            }
            if noise_px > 0.0 {
                px += Vector2::new(normal.sample(rng), normal.sample(rng));
            }
            if rng.gen::<f64>() < outliers {
                let angle: f64 = rng.gen_range(0.0..std::f64::consts::TAU);
                px += Vector2::new(angle.cos(), angle.sin()) * rng.gen_range(20.0..60.0);
                outlier_ids.push(k as LandmarkId);
            }
            observations.push(Observation {
                landmark: k as LandmarkId,
                camera_index: 0,
                pixel: px,
            });
        }
        (
            TrackedFrame {
                t_ns,
                observations,
                is_keyframe: true,
            },
            outlier_ids,
        )
    }

    fn pose(translation: Vector3<f64>, rotation: Vector3<f64>) -> Isometry3<f64> {
        Isometry3::from_parts(
            Translation3::from(translation),
            UnitQuaternion::from_scaled_axis(rotation),
        )
    }

    #[test]
    fn noise_free_bootstrap_is_exact_up_to_unit_translation() {
        let s = scene(1);
        let mut rng = ChaCha8Rng::seed_from_u64(2);
        let t_c0_c1 = pose(
            Vector3::new(0.6, 0.1, 0.15),
            Vector3::new(0.02, -0.05, 0.01),
        );
        let (f0, _) = frame(&s, &Isometry3::identity(), 0, 0.0, 0.0, &mut rng);
        let (f1, _) = frame(&s, &t_c0_c1, 1, 0.0, 0.0, &mut rng);
        let b = bootstrap_two_view(&f0, &f1, &s.camera, &BootstrapConfig::default())
            .expect("enough parallax");
        let baseline = t_c0_c1.translation.vector.norm();
        assert!((b.T_c0_c1.translation.vector.norm() - 1.0).abs() < 1e-12);
        let t_err = (b.T_c0_c1.translation.vector - t_c0_c1.translation.vector / baseline).norm();
        assert!(t_err < 1e-6, "translation direction off by {t_err}");
        let r_err = (b.T_c0_c1.rotation.inverse() * t_c0_c1.rotation).angle();
        assert!(r_err < 1e-7, "rotation off by {r_err}");
        assert!(b.landmarks.len() > 150, "{}", b.landmarks.len());
        assert!(b.landmarks.windows(2).all(|w| w[0].id < w[1].id));
        for l in &b.landmarks {
            let truth = s.points_c0[l.id as usize] / baseline;
            let err = (l.position_c0 - truth).norm() / truth.norm();
            assert!(err < 1e-5, "landmark {}: relative error {err}", l.id);
        }
        assert!(b.median_parallax_px > 20.0);
    }

    #[test]
    fn noisy_bootstrap_rejects_outliers_and_pnp_places_the_frame_between() {
        let s = scene(3);
        let mut rng = ChaCha8Rng::seed_from_u64(4);
        let t_c0_c2 = pose(
            Vector3::new(0.7, -0.1, 0.2),
            Vector3::new(-0.03, 0.08, 0.02),
        );
        let t_c0_c1 = pose(
            Vector3::new(0.35, -0.05, 0.1),
            Vector3::new(-0.01, 0.04, 0.01),
        );
        let (f0, out0) = frame(&s, &Isometry3::identity(), 0, 0.5, 0.1, &mut rng);
        let (f2, out2) = frame(&s, &t_c0_c2, 2, 0.5, 0.1, &mut rng);
        let b = bootstrap_two_view(&f0, &f2, &s.camera, &BootstrapConfig::default())
            .expect("enough parallax");
        let baseline = t_c0_c2.translation.vector.norm();
        let dir_err = b
            .T_c0_c1
            .translation
            .vector
            .angle(&t_c0_c2.translation.vector)
            .to_degrees();
        assert!(dir_err < 3.0, "translation direction off by {dir_err} deg");
        let r_err = (b.T_c0_c1.rotation.inverse() * t_c0_c2.rotation)
            .angle()
            .to_degrees();
        assert!(r_err < 0.3, "rotation off by {r_err} deg");
        let outliers_kept = b
            .landmarks
            .iter()
            .filter(|l| out0.contains(&l.id) || out2.contains(&l.id))
            .count();
        assert!(outliers_kept <= 2, "{outliers_kept} outliers triangulated");
        let mut errors: Vec<f64> = b
            .landmarks
            .iter()
            .map(|l| {
                let truth = s.points_c0[l.id as usize] / baseline;
                (l.position_c0 - truth).norm() / truth.norm()
            })
            .collect();
        errors.sort_by(f64::total_cmp);
        let median = errors[errors.len() / 2];
        assert!(median < 0.05, "median landmark error {median}");

        // The frame between, from the landmarks.
        let (f1, _) = frame(&s, &t_c0_c1, 1, 0.5, 0.1, &mut rng);
        let p = pnp_frame(&f1, &b.landmarks, &s.camera, &PnpConfig::default()).expect("placed");
        let expected = t_c0_c1.translation.vector / baseline;
        let err = (p.T_c0_cam.translation.vector - expected).norm();
        assert!(
            err < 0.05,
            "PnP position off by {err} (units of the first translation)"
        );
        let r_err = (p.T_c0_cam.rotation.inverse() * t_c0_c1.rotation)
            .angle()
            .to_degrees();
        assert!(r_err < 0.5, "PnP rotation off by {r_err} deg");
        assert!(p.inlier_count > 100);
    }

    #[test]
    fn pure_rotation_and_small_parallax_are_refused() {
        let s = scene(5);
        let mut rng = ChaCha8Rng::seed_from_u64(6);
        let config = BootstrapConfig::default();
        let (f0, _) = frame(&s, &Isometry3::identity(), 0, 0.3, 0.0, &mut rng);
        let turned = pose(Vector3::zeros(), Vector3::new(0.05, 0.1, -0.03));
        let (f1, _) = frame(&s, &turned, 1, 0.3, 0.0, &mut rng);
        let r = bootstrap_two_view(&f0, &f1, &s.camera, &config);
        assert!(
            matches!(
                r,
                Err(BootstrapRefusal::PureRotation { .. })
                    | Err(BootstrapRefusal::TooLittleParallax { .. })
            ),
            "{r:?}"
        );
        // 5 cm at 4-10 m: about 3 px of parallax, with a large rotation.
        let nudged = pose(Vector3::new(0.05, 0.0, 0.0), Vector3::new(0.05, 0.1, -0.03));
        let (f2, _) = frame(&s, &nudged, 2, 0.3, 0.0, &mut rng);
        let r = bootstrap_two_view(&f0, &f2, &s.camera, &config);
        assert!(
            matches!(
                r,
                Err(BootstrapRefusal::PureRotation { .. })
                    | Err(BootstrapRefusal::TooLittleParallax { .. })
            ),
            "{r:?}"
        );
        // Too few shared landmarks.
        let few = TrackedFrame {
            t_ns: 3,
            observations: f2.observations[..10].to_vec(),
            is_keyframe: true,
        };
        assert!(matches!(
            bootstrap_two_view(&f0, &few, &s.camera, &config),
            Err(BootstrapRefusal::TooFewCorrespondences { found: 10, .. })
        ));
        // Non-finite pixels are dropped, not propagated.
        let mut broken = f2.clone();
        for o in &mut broken.observations {
            o.pixel.x = f64::NAN;
        }
        assert!(matches!(
            bootstrap_two_view(&f0, &broken, &s.camera, &config),
            Err(BootstrapRefusal::TooFewCorrespondences { found: 0, .. })
        ));
        assert!(pnp_frame(&broken, &[], &s.camera, &PnpConfig::default()).is_err());
    }
}
