//! New landmarks for a keyframe: from its stereo pairs (the calibrated
//! left-right pair) or, for tracks first seen in an earlier keyframe of the
//! window, from that first view and this one once the rays meet at more
//! than `min_parallax_deg`. Both use the optimal two-view correction then
//! linear triangulation of [`crate::two_view::triangulation`], which also
//! rejects points behind either camera, too near or too far; a point must
//! also reproject within `init_max_error_px` in both views, which keeps
//! most gross outliers from becoming landmarks.

use nalgebra::{Isometry3, Vector2, Vector3};

use super::reprojection::reprojection_error;
use super::rig_camera::RigCamera;
use super::{Landmark, PendingTrack, Window};
use crate::two_view::triangulation::{triangulate, TriangulationConfig, TriangulationFailure};

/// The normalised image point (z = 1) of a pixel, if it unprojects in
/// front of the camera.
fn normalised(camera: &RigCamera, pixel: &Vector2<f64>) -> Option<Vector2<f64>> {
    let ray = camera.calibration.model.unproject(pixel)?;
    (ray.z > 1e-9).then(|| ray.xy() / ray.z)
}

/// Why two views gave no landmark.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum InitFailure {
    /// Too little parallax (or a ray that does not unproject): a later
    /// view may do.
    Degenerate,
    /// The views disagree (behind a camera, out of the depth range, or a
    /// reprojection error above the limit): one of them is likely an
    /// outlier.
    Inconsistent,
}

/// The world point seen at `pixel_a` by camera `cam_a` of a body at
/// `T_world_a` and at `pixel_b` by `cam_b` of a body at `T_world_b`, if
/// it reprojects within `max_error_px` in both.
#[allow(non_snake_case, clippy::too_many_arguments)]
pub(crate) fn triangulate_views(
    cam_a: &RigCamera,
    T_world_a: &Isometry3<f64>,
    pixel_a: &Vector2<f64>,
    cam_b: &RigCamera,
    T_world_b: &Isometry3<f64>,
    pixel_b: &Vector2<f64>,
    config: &TriangulationConfig,
    max_error_px: f64,
) -> Result<Vector3<f64>, InitFailure> {
    let xa = normalised(cam_a, pixel_a).ok_or(InitFailure::Degenerate)?;
    let xb = normalised(cam_b, pixel_b).ok_or(InitFailure::Degenerate)?;
    let T_world_ca = T_world_a * cam_a.calibration.T_body_cam;
    let T_world_cb = T_world_b * cam_b.calibration.T_body_cam;
    let T_cb_ca = T_world_cb.inverse() * T_world_ca;
    let r = T_cb_ca.rotation.to_rotation_matrix().into_inner();
    let point = match triangulate(&r, &T_cb_ca.translation.vector, &xa, &xb, config) {
        Ok(p) => p,
        Err(TriangulationFailure::LowParallax { .. } | TriangulationFailure::NonFinite) => {
            return Err(InitFailure::Degenerate)
        }
        Err(_) => return Err(InitFailure::Inconsistent),
    };
    let world = T_world_ca.transform_point(&point.point_c1.into()).coords;
    if !world.iter().all(|v| v.is_finite()) {
        return Err(InitFailure::Degenerate);
    }
    for (cam, pose, pixel) in [(cam_a, T_world_a, pixel_a), (cam_b, T_world_b, pixel_b)] {
        match reprojection_error(cam, pose, &world, pixel) {
            Some((e, depth)) if depth > 0.0 && e.norm() <= max_error_px => {}
            _ => return Err(InitFailure::Inconsistent),
        }
    }
    Ok(world)
}

impl Window {
    /// Triangulates what the newest keyframe makes possible.
    pub(super) fn initialise_landmarks(&mut self) {
        let Some(newest) = self.keyframes.back() else {
            return;
        };
        let front_seq = self.keyframes.front().map_or(0, |k| k.seq);
        let stereo_config = TriangulationConfig {
            min_parallax_rad: self.config.stereo_min_parallax_deg.to_radians(),
            min_depth: self.config.min_depth_m,
            max_depth: self.config.max_depth_m,
        };
        let motion_config = TriangulationConfig {
            min_parallax_rad: self.config.min_parallax_deg.to_radians(),
            ..stereo_config.clone()
        };
        let pose = newest.state.T_world_body;
        let max_error_px = self.config.init_max_error_px;

        if self.cameras.len() >= 2 {
            self.scratch_pairs.clear();
            self.scratch_pairs.extend(
                newest
                    .observations
                    .iter()
                    .enumerate()
                    .filter(|(_, o)| o.camera == 1)
                    .map(|(i, o)| (o.landmark, i)),
            );
            self.scratch_pairs.sort_unstable();
            for o in newest.observations.iter().filter(|o| o.camera == 0) {
                if self.landmarks.contains_key(&o.landmark) || self.rejected.contains(&o.landmark) {
                    continue;
                }
                let Ok(k) = self
                    .scratch_pairs
                    .binary_search_by_key(&o.landmark, |p| p.0)
                else {
                    continue;
                };
                let right = &newest.observations[self.scratch_pairs[k].1];
                if let Ok(p) = triangulate_views(
                    &self.cameras[0],
                    &pose,
                    &o.pixel,
                    &self.cameras[1],
                    &pose,
                    &right.pixel,
                    &stereo_config,
                    max_error_px,
                ) {
                    self.landmarks.insert(
                        o.landmark,
                        Landmark {
                            position_world_m: p,
                        },
                    );
                    self.pending.remove(&o.landmark);
                }
            }
        }

        for (i, o) in newest.observations.iter().enumerate() {
            if self.landmarks.contains_key(&o.landmark) || self.rejected.contains(&o.landmark) {
                continue;
            }
            match self.pending.get(&o.landmark).copied() {
                Some(p) if p.seq != newest.seq => {
                    let Some(first) = self
                        .keyframes
                        .get(p.seq.wrapping_sub(front_seq) as usize)
                        .filter(|k| k.seq == p.seq)
                    else {
                        self.pending.insert(
                            o.landmark,
                            PendingTrack {
                                seq: newest.seq,
                                obs_index: i,
                            },
                        );
                        continue;
                    };
                    let first_obs = &first.observations[p.obs_index];
                    match triangulate_views(
                        &self.cameras[first_obs.camera as usize],
                        &first.state.T_world_body,
                        &first_obs.pixel,
                        &self.cameras[o.camera as usize],
                        &pose,
                        &o.pixel,
                        &motion_config,
                        max_error_px,
                    ) {
                        Ok(point) => {
                            self.landmarks.insert(
                                o.landmark,
                                Landmark {
                                    position_world_m: point,
                                },
                            );
                            self.pending.remove(&o.landmark);
                        }
                        Err(InitFailure::Degenerate) => {}
                        // Start the track again from this view: the first
                        // one may be the outlier.
                        Err(InitFailure::Inconsistent) => {
                            self.pending.insert(
                                o.landmark,
                                PendingTrack {
                                    seq: newest.seq,
                                    obs_index: i,
                                },
                            );
                        }
                    }
                }
                Some(_) => {}
                None => {
                    self.pending.insert(
                        o.landmark,
                        PendingTrack {
                            seq: newest.seq,
                            obs_index: i,
                        },
                    );
                }
            }
        }
    }
}
