//! The visual front end of the relative stage (paper Figure 8): images in,
//! [`TrackedFrame`]s of landmark observations with ids that persist while
//! a feature is tracked.
//!
//! Per frame: the left pyramid is built into reused buffers; last frame's
//! features are followed by pyramidal KLT (forward-backward checked),
//! starting where the gyroscope's rotation puts them; five-point MSAC
//! between the two frames removes tracks that disagree with one rigid
//! motion (skipped when the image barely moves, where the essential
//! matrix says nothing); new FAST/Shi-Tomasi corners fill the image up to
//! the target count, bucketed and kept away from existing tracks; in
//! stereo each left feature is found in the right image by KLT and kept
//! when it lies on its epipolar line of the calibrated pair.
//!
//! Keyframe policy (the suggestion in [`TrackedFrame::is_keyframe`]):
//! - the rotation-compensated median parallax against the last keyframe
//!   exceeds `keyframe_parallax_px`: enough baseline to triangulate new
//!   points well (10-20 px at EuRoC's 458 px focal length is 1.3-2.5 deg);
//! - fewer than `keyframe_min_tracked` of the last keyframe's features are
//!   still tracked: the window must see the new ones before the old die;
//! - `keyframe_max_interval_s` has passed: bounds the IMU intervals (and
//!   their linearisation error) and keeps the window spanning a bounded
//!   time when the rig hovers or rests.
//!
//! Rotation alone gives no baseline, which is why the parallax is taken
//! after removing the predicted rotation.

use std::collections::HashMap;

use nalgebra::{Matrix3, Rotation3, Vector2, Vector3};

use crate::camera::CameraModel;
use crate::features::orb::{Descriptor, OrbConfig, OrbExtractor};
use crate::features::{
    predict_from_rotation, Corner, CornerConfig, CornerDetector, GridConfig, KltConfig, KltTracker,
    Pyramid, PyramidConfig, TrackStatus,
};
use crate::rig::CameraCalibration;
use crate::two_view::{estimate_relative_pose, RelativePoseConfig};

use self::first_patch::FirstPatch;
use super::estimator::FrameInput;
use super::types::{LandmarkId, Observation, TrackedFrame};

/// Farthest a track is moved to where its first patch aligned, px: more
/// is a different place of the texture, not the track's drift.
const MAX_FIRST_PATCH_MOVE_PX: f32 = 1.0;

/// Settings of the tracker (defaults in brackets).
#[derive(Debug, Clone, PartialEq)]
pub struct TrackerConfig {
    /// Features kept in the left image \[150\].
    pub target_features: usize,
    /// Side of a detection bucket, px \[48\].
    pub bucket_px: usize,
    /// Smallest distance of a new feature to any tracked one, px \[15\].
    pub min_distance_px: f32,
    /// Half side of the KLT window, px [7: 15x15].
    pub klt_half_window_px: usize,
    /// Refine an affine warp of each window after its shift converges
    /// when following features from frame to frame \[false\]
    /// ([`KltConfig::affine_refinement`]): a shift alone leaves a bias of
    /// a few hundredths of a pixel per frame under turning and scaling,
    /// which a track adds up. Not used for the stereo match, made afresh
    /// every frame.
    pub klt_affine: bool,
    /// At each keyframe, align every track's first patch into the image
    /// from where KLT followed it, and move the track there
    /// ([`first_patch`]) \[false\].
    pub first_patch: bool,
    /// Pyramid levels including the image \[3\].
    pub pyramid_levels: usize,
    /// Forward-backward agreement, px [1.0].
    pub fb_threshold_px: f32,
    /// MSAC threshold on the Sampson error, px [1.0].
    pub ransac_threshold_px: f64,
    /// Median image motion below which MSAC is skipped, px [1.0].
    pub ransac_min_flow_px: f64,
    /// Keyframe when the rotation-compensated median parallax against the
    /// last keyframe exceeds this, px \[15\].
    pub keyframe_parallax_px: f64,
    /// Keyframe when fewer than this share of the last keyframe's features
    /// are still tracked [0.6].
    pub keyframe_min_tracked: f64,
    /// Keyframe at least this often, s [0.5].
    pub keyframe_max_interval_s: f64,
    /// Largest distance of a right feature from its epipolar line, px [1.5].
    pub stereo_epipolar_px: f64,
    /// Depth assumed for a right-image search without history, m \[4\].
    pub stereo_prior_depth_m: f64,
    /// A stereo match is refused when its window's residual (the KLT's
    /// residual ratio, [`crate::features::KltTracker::residual_ratios`])
    /// is more than this many times the median of the frame's stereo
    /// matches \[4\]; `None` keeps every match. A left window across an
    /// occlusion boundary holds two surfaces at different depths, which
    /// the right image shows shifted by different disparities: no shift
    /// aligns it, and the match lands between them, pixels from either
    /// surface. Judged against the frame's own matches because the
    /// residual of right ones differs between cameras (noise, exposure):
    /// median 0.25 on EuRoC's real pair, 0.08 on rendered pairs.
    pub stereo_residual_vs_median: Option<f32>,
}

impl Default for TrackerConfig {
    fn default() -> Self {
        Self {
            target_features: 150,
            bucket_px: 48,
            min_distance_px: 15.0,
            klt_half_window_px: 7,
            klt_affine: false,
            first_patch: false,
            pyramid_levels: 3,
            fb_threshold_px: 1.0,
            ransac_threshold_px: 1.0,
            ransac_min_flow_px: 1.0,
            keyframe_parallax_px: 15.0,
            keyframe_min_tracked: 0.6,
            keyframe_max_interval_s: 0.5,
            stereo_epipolar_px: 1.5,
            stereo_prior_depth_m: 4.0,
            stereo_residual_vs_median: Some(4.0),
        }
    }
}

/// What went wrong with a frame or the setup.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum TrackerError {
    #[error("tracker setting `{key}` = {value}: {allowed}")]
    /// A setting is out of range.
    InvalidConfig {
        /// The setting's key.
        key: &'static str,
        /// Its value, as written.
        value: String,
        /// The allowed range.
        allowed: &'static str,
    },
    #[error("stereo tracking needs two cameras, got {0}")]
    /// A stereo mode was asked for with fewer than two cameras (the field is how many).
    NeedsTwoCameras(usize),
    #[error("no camera given")]
    /// The rig has no camera.
    NoCamera,
    #[error("camera {camera}: image {got_w}x{got_h} px, the calibration says {want_w}x{want_h}")]
    /// An image's size differs from its camera's calibration.
    ImageSize {
        /// The camera (0 left, 1 right).
        camera: u8,
        /// Width of the image, px.
        got_w: u32,
        /// Height of the image, px.
        got_h: u32,
        /// Width the calibration says, px.
        want_w: u32,
        /// Height the calibration says, px.
        want_h: u32,
    },
    #[error("frame at {t_ns} ns does not come after the previous one at {previous_ns} ns")]
    /// A frame's stamp is not after the previous frame's.
    TimeNotIncreasing {
        /// The frame's stamp, ns.
        t_ns: i64,
        /// The previous frame's stamp, ns.
        previous_ns: i64,
    },
    #[error("image: {0}")]
    /// An image could not enter the front end (not grey, buffer too short) or a pyramid setting is
    /// invalid; the field is the reason.
    Image(String),
}

/// Counters since the tracker was made.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
pub struct TrackerStats {
    /// Frames processed.
    pub frames: u64,
    /// Feature tracks carried into a new frame by KLT (summed over frames).
    pub tracked: u64,
    /// Tracks KLT lost (left the image, did not converge, failed the forward-backward check).
    pub lost_klt: u64,
    /// Tracks MSAC rejected as outliers of the frame-to-frame motion.
    pub rejected_ransac: u64,
    /// New corners detected to refill the image.
    pub detected: u64,
    /// Left features found in the right image (summed over frames).
    pub stereo_matched: u64,
    /// Left features not found in the right image, or off the epipolar
    /// line, or refused for their residual (those also counted in
    /// `stereo_refused_residual`).
    pub stereo_rejected: u64,
    /// Stereo matches refused because their window's residual was far
    /// above the frame's median ([`TrackerConfig::stereo_residual_vs_median`]).
    pub stereo_refused_residual: u64,
    /// Times every track was dropped after lost tracking.
    pub resets: u64,
    /// Tracks moved to where their first patch aligned (`first_patch`).
    pub first_patch_aligned: u64,
    /// Tracks whose first patch was refused and started again.
    pub first_patch_restarted: u64,
}

/// The front end. Buffers are owned and reused frame to frame.
pub struct Tracker {
    config: TrackerConfig,
    cameras: Vec<CameraCalibration>,
    stereo: bool,
    /// Essential matrix of the stereo pair on normalised coordinates:
    /// `x1^T E x0 = 0`.
    stereo_essential: Matrix3<f64>,
    r_c1_c0: Matrix3<f64>,
    t_c1_c0: Vector3<f64>,
    prev: Pyramid,
    cur: Pyramid,
    right: Pyramid,
    klt: KltTracker,
    /// Left to right: a larger window, the two cameras see one patch
    /// with different gains and perspective.
    stereo_klt: KltTracker,
    detector: CornerDetector,
    /// Features of the previous frame.
    ids: Vec<LandmarkId>,
    /// Descriptor of each track at its birth, aligned with `ids` (which
    /// stay in ascending order: new ids are appended, removals compact).
    descriptors: Vec<Option<Descriptor>>,
    describer: OrbExtractor,
    points: Vec<[f32; 2]>,
    /// First patch of each track, aligned with `ids` (`first_patch` on;
    /// None where it did not fit in the image).
    first_patches: Vec<Option<FirstPatch>>,
    /// Right-image positions of the previous frame, by id.
    right_points: HashMap<LandmarkId, [f32; 2]>,
    next_id: LandmarkId,
    last_t_ns: Option<i64>,
    /// The last keyframe: its features and the camera rotation since.
    keyframe_points: HashMap<LandmarkId, [f32; 2]>,
    keyframe_t_ns: Option<i64>,
    rotation_since_keyframe: Rotation3<f64>,
    scratch_predicted: Vec<[f32; 2]>,
    scratch_tracked: Vec<[f32; 2]>,
    scratch_status: Vec<TrackStatus>,
    scratch_corners: Vec<Corner>,
    /// Per-frame working lists, kept so that tracking allocates nothing
    /// once they have grown.
    scratch: Scratch,
    stats: TrackerStats,
}

#[derive(Default)]
struct Scratch {
    kept_prev: Vec<[f32; 2]>,
    flows: Vec<f64>,
    x1: Vec<Vector2<f64>>,
    x2: Vec<Vector2<f64>>,
    usable: Vec<usize>,
    keep: Vec<bool>,
    matched: Vec<Option<[f32; 2]>>,
    pending: Vec<usize>,
    still: Vec<usize>,
    sub_points: Vec<[f32; 2]>,
    /// Residual ratio of each matched left feature, and the scratch their median is found in.
    ratios: Vec<f32>,
    sorted_ratios: Vec<f32>,
    described: Vec<Option<Descriptor>>,
}

impl Tracker {
    /// `cameras[0]` is the left camera, `cameras[1]` the right one
    /// (stereo only).
    pub fn new(
        config: TrackerConfig,
        cameras: &[CameraCalibration],
        stereo: bool,
    ) -> Result<Self, TrackerError> {
        let bad = |key, value: String, allowed| TrackerError::InvalidConfig {
            key,
            value,
            allowed,
        };
        if !(10..=5000).contains(&config.target_features) {
            return Err(bad(
                "target_features",
                config.target_features.to_string(),
                "10 to 5000",
            ));
        }
        if !(1..=8).contains(&config.pyramid_levels) {
            return Err(bad(
                "pyramid_levels",
                config.pyramid_levels.to_string(),
                "1 to 8",
            ));
        }
        for (key, v) in [
            ("ransac_threshold_px", config.ransac_threshold_px),
            ("keyframe_parallax_px", config.keyframe_parallax_px),
            ("keyframe_max_interval_s", config.keyframe_max_interval_s),
            ("stereo_epipolar_px", config.stereo_epipolar_px),
            ("stereo_prior_depth_m", config.stereo_prior_depth_m),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Err(bad(key, v.to_string(), "a positive number"));
            }
        }
        if let Some(k) = config.stereo_residual_vs_median {
            if !(k.is_finite() && k >= 1.0) {
                return Err(bad(
                    "stereo_residual_vs_median",
                    k.to_string(),
                    "a number of at least 1 (times the median), or none",
                ));
            }
        }
        if !(0.0..=1.0).contains(&config.keyframe_min_tracked) {
            return Err(bad(
                "keyframe_min_tracked",
                config.keyframe_min_tracked.to_string(),
                "0 to 1",
            ));
        }
        if cameras.is_empty() {
            return Err(TrackerError::NoCamera);
        }
        if stereo && cameras.len() < 2 {
            return Err(TrackerError::NeedsTwoCameras(cameras.len()));
        }
        for (i, c) in cameras.iter().enumerate() {
            let [fx, fy, _, _] = c.model.pinhole();
            if !(fx.is_finite() && fy.is_finite() && fx > 0.0 && fy > 0.0) {
                return Err(bad(
                    if i == 0 {
                        "camera 0 focal length"
                    } else {
                        "camera 1 focal length"
                    },
                    format!("{fx}, {fy}"),
                    "finite and positive",
                ));
            }
        }
        let pyramid = PyramidConfig {
            levels: config.pyramid_levels,
            ..PyramidConfig::klt()
        };
        let make_pyramid = || Pyramid::new(pyramid).map_err(|e| TrackerError::Image(e.to_string()));
        let klt = KltTracker::new(KltConfig {
            half_window_px: config.klt_half_window_px,
            fb_threshold_px: Some(config.fb_threshold_px),
            affine_refinement: config.klt_affine,
            ..KltConfig::default()
        })
        .map_err(|e| bad("klt", e.to_string(), "a valid KLT configuration"))?;
        let stereo_klt = KltTracker::new(KltConfig {
            half_window_px: config.klt_half_window_px,
            fb_threshold_px: Some(2.0 * config.fb_threshold_px),
            max_iterations: 15,
            ..KltConfig::default()
        })
        .map_err(|e| bad("klt", e.to_string(), "a valid KLT configuration"))?;
        let detector = CornerDetector::new(CornerConfig {
            grid: GridConfig {
                bucket_px: config.bucket_px,
                min_distance_px: config.min_distance_px,
            },
            ..CornerConfig::default()
        });
        // Right camera in the left one: T_c0_c1 = T_b_c0^-1 T_b_c1.
        let (r, t, e) = if stereo {
            #[allow(non_snake_case)]
            let T_c1_c0 = cameras[1].T_body_cam.inverse() * cameras[0].T_body_cam;
            let r = T_c1_c0.rotation.to_rotation_matrix().into_inner();
            let t = T_c1_c0.translation.vector;
            (r, t, crate::imu::so3::hat(&t) * r)
        } else {
            (Matrix3::identity(), Vector3::zeros(), Matrix3::zeros())
        };
        Ok(Self {
            stereo,
            cameras: cameras.to_vec(),
            stereo_essential: e,
            r_c1_c0: r,
            t_c1_c0: t,
            prev: make_pyramid()?,
            cur: make_pyramid()?,
            right: make_pyramid()?,
            klt,
            stereo_klt,
            detector,
            ids: Vec::new(),
            descriptors: Vec::new(),
            describer: OrbExtractor::new(OrbConfig::default())
                .map_err(|e| TrackerError::Image(e.to_string()))?,
            points: Vec::new(),
            first_patches: Vec::new(),
            right_points: HashMap::new(),
            next_id: 0,
            last_t_ns: None,
            keyframe_points: HashMap::new(),
            keyframe_t_ns: None,
            rotation_since_keyframe: Rotation3::identity(),
            scratch_predicted: Vec::new(),
            scratch_tracked: Vec::new(),
            scratch_status: Vec::new(),
            scratch_corners: Vec::new(),
            scratch: Scratch::default(),
            stats: TrackerStats::default(),
            config,
        })
    }

    /// The settings it was built with.
    pub fn config(&self) -> &TrackerConfig {
        &self.config
    }

    /// The counters since it was made.
    pub fn stats(&self) -> TrackerStats {
        self.stats
    }

    /// Features being tracked now.
    pub fn feature_count(&self) -> usize {
        self.points.len()
    }

    /// The birth descriptor of a live track.
    pub fn descriptor(&self, id: LandmarkId) -> Option<Descriptor> {
        let k = self.ids.binary_search(&id).ok()?;
        self.descriptors[k]
    }

    /// Drops every track (after lost tracking); ids are never reused.
    pub fn reset(&mut self) {
        self.stats.resets += 1;
        self.ids.clear();
        self.descriptors.clear();
        self.points.clear();
        self.first_patches.clear();
        self.right_points.clear();
        self.keyframe_points.clear();
        self.keyframe_t_ns = None;
        self.rotation_since_keyframe = Rotation3::identity();
        self.last_t_ns = None;
    }

    /// The frame just returned became a keyframe: parallax and track
    /// survival are measured against it from now on.
    pub fn mark_keyframe(&mut self, t_ns: i64) {
        self.keyframe_points.clear();
        self.keyframe_points
            .extend(self.ids.iter().copied().zip(self.points.iter().copied()));
        self.keyframe_t_ns = Some(t_ns);
        self.rotation_since_keyframe = Rotation3::identity();
    }

    fn check_size(&self, camera: u8, image: &crate::sensors::Image) -> Result<(), TrackerError> {
        let model = &self.cameras[camera as usize].model;
        if image.width() != model.width() || image.height() != model.height() {
            return Err(TrackerError::ImageSize {
                camera,
                got_w: image.width(),
                got_h: image.height(),
                want_w: model.width(),
                want_h: model.height(),
            });
        }
        Ok(())
    }

    /// Tracks `frame`. `R_camprev_camcur` is the rotation of the current
    /// left camera in the previous one (e.g. from the gyroscope).
    #[allow(non_snake_case)]
    pub fn track(
        &mut self,
        frame: &FrameInput<'_>,
        R_camprev_camcur: Option<&Rotation3<f64>>,
    ) -> Result<TrackedFrame, TrackerError> {
        if let Some(previous_ns) = self.last_t_ns {
            if frame.t_ns <= previous_ns {
                return Err(TrackerError::TimeNotIncreasing {
                    t_ns: frame.t_ns,
                    previous_ns,
                });
            }
        }
        self.check_size(0, frame.left)?;
        let right = match (self.stereo, frame.right) {
            (true, Some(r)) => {
                self.check_size(1, r)?;
                Some(r)
            }
            _ => None,
        };
        std::mem::swap(&mut self.prev, &mut self.cur);
        self.cur
            .build(frame.left)
            .map_err(|e| TrackerError::Image(e.to_string()))?;
        self.stats.frames += 1;
        let had_previous = self.last_t_ns.is_some();
        self.last_t_ns = Some(frame.t_ns);

        if had_previous && !self.points.is_empty() {
            self.follow(R_camprev_camcur);
        } else {
            self.ids.clear();
            self.descriptors.clear();
            self.points.clear();
            self.first_patches.clear();
        }
        if let Some(r) = R_camprev_camcur.filter(|_| had_previous) {
            self.rotation_since_keyframe *= *r;
        }
        if self.config.first_patch && had_previous && self.keyframe_wanted(frame.t_ns) {
            self.align_first_patches();
        }
        self.detect_new();

        let mut observations: Vec<Observation> = self
            .ids
            .iter()
            .zip(&self.points)
            .map(|(&id, p)| Observation {
                landmark: id,
                camera_index: 0,
                pixel: Vector2::new(f64::from(p[0]), f64::from(p[1])),
            })
            .collect();
        if let Some(right) = right {
            self.right
                .build(right)
                .map_err(|e| TrackerError::Image(e.to_string()))?;
            self.match_right(&mut observations);
        } else {
            self.right_points.clear();
        }
        let is_keyframe = self.keyframe_wanted(frame.t_ns);
        Ok(TrackedFrame {
            t_ns: frame.t_ns,
            observations,
            is_keyframe,
        })
    }

    /// KLT from the previous frame, then MSAC on the survivors.
    #[allow(non_snake_case)]
    fn follow(&mut self, R_camprev_camcur: Option<&Rotation3<f64>>) {
        let camera = &self.cameras[0].model;
        let predicted = match R_camprev_camcur {
            Some(r) => {
                predict_from_rotation(camera, r, &self.points, &mut self.scratch_predicted);
                Some(self.scratch_predicted.as_slice())
            }
            None => None,
        };
        self.klt.track(
            &self.prev,
            &self.cur,
            &self.points,
            predicted,
            &mut self.scratch_tracked,
            &mut self.scratch_status,
        );
        let mut kept_prev = std::mem::take(&mut self.scratch.kept_prev);
        kept_prev.clear();
        let mut write = 0;
        for i in 0..self.points.len() {
            if self.scratch_status[i] == TrackStatus::Tracked {
                kept_prev.push(self.points[i]);
                self.ids[write] = self.ids[i];
                self.descriptors[write] = self.descriptors[i];
                self.points[write] = self.scratch_tracked[i];
                self.first_patches.swap(write, i);
                write += 1;
            } else {
                self.stats.lost_klt += 1;
            }
        }
        self.ids.truncate(write);
        self.descriptors.truncate(write);
        self.points.truncate(write);
        self.first_patches.truncate(write);
        self.stats.tracked += write as u64;
        self.reject_outliers(&kept_prev);
        self.scratch.kept_prev = kept_prev;
    }

    /// Five-point MSAC between the previous and the current positions.
    fn reject_outliers(&mut self, prev_points: &[[f32; 2]]) {
        let n = self.points.len();
        if n < 8 {
            return;
        }
        let flows = &mut self.scratch.flows;
        flows.clear();
        flows.extend(
            prev_points
                .iter()
                .zip(&self.points)
                .map(|(a, b)| f64::from((a[0] - b[0]).hypot(a[1] - b[1]))),
        );
        let mid = n / 2;
        flows.select_nth_unstable_by(mid, f64::total_cmp);
        if flows[mid] < self.config.ransac_min_flow_px {
            return;
        }
        let camera = &self.cameras[0].model;
        let Scratch {
            x1,
            x2,
            usable,
            keep,
            ..
        } = &mut self.scratch;
        x1.clear();
        x2.clear();
        usable.clear();
        for (i, (a, b)) in prev_points.iter().zip(&self.points).enumerate() {
            if let (Some(p), Some(q)) = (normalised(camera, a), normalised(camera, b)) {
                x1.push(p);
                x2.push(q);
                usable.push(i);
            }
        }
        if usable.len() < 8 {
            return;
        }
        let [fx, fy, _, _] = camera.pinhole();
        let config =
            RelativePoseConfig::for_pixels(self.config.ransac_threshold_px, 0.5 * (fx + fy));
        let Ok(pose) = estimate_relative_pose(x1, x2, &config) else {
            return;
        };
        keep.clear();
        keep.resize(n, false);
        for (k, &i) in usable.iter().enumerate() {
            keep[i] = pose.inliers[k];
        }
        let mut write = 0;
        for (i, &kept) in keep.iter().enumerate() {
            if kept {
                self.ids[write] = self.ids[i];
                self.descriptors[write] = self.descriptors[i];
                self.points[write] = self.points[i];
                self.first_patches.swap(write, i);
                write += 1;
            } else {
                self.stats.rejected_ransac += 1;
            }
        }
        self.ids.truncate(write);
        self.descriptors.truncate(write);
        self.points.truncate(write);
        self.first_patches.truncate(write);
    }

    /// Each track to where its first patch aligns, when it aligns within
    /// a pixel of where KLT followed it; a track whose patch is refused
    /// starts a new one where it is ([`first_patch`]).
    fn align_first_patches(&mut self) {
        let image = self.cur.level(0);
        for (point, patch) in self.points.iter_mut().zip(self.first_patches.iter_mut()) {
            let aligned = patch.as_mut().and_then(|p| p.align(image, *point));
            match aligned {
                Some(q) if (q[0] - point[0]).hypot(q[1] - point[1]) < MAX_FIRST_PATCH_MOVE_PX => {
                    *point = q;
                    self.stats.first_patch_aligned += 1;
                }
                _ => {
                    *patch = FirstPatch::capture(image, *point);
                    self.stats.first_patch_restarted += 1;
                }
            }
        }
    }

    /// New corners up to the target count, away from the tracked ones.
    fn detect_new(&mut self) {
        let budget = self
            .config
            .target_features
            .saturating_sub(self.points.len());
        // Refill only when a fifth is missing: detection costs as much as
        // tracking, and a few features more or less change nothing.
        if budget < self.config.target_features / 5 && !self.points.is_empty() {
            return;
        }
        self.detector.detect(
            self.cur.level(0),
            &self.points,
            budget,
            &mut self.scratch_corners,
        );
        let born = self.points.len();
        for c in &self.scratch_corners {
            self.ids.push(self.next_id);
            self.next_id += 1;
            self.points.push([c.x as f32, c.y as f32]);
            self.first_patches.push(
                self.config
                    .first_patch
                    .then(|| FirstPatch::capture(self.cur.level(0), [c.x as f32, c.y as f32]))
                    .flatten(),
            );
        }
        let mut described = std::mem::take(&mut self.scratch.described);
        self.describer
            .describe_points(self.cur.level(0), &self.points[born..], &mut described);
        self.descriptors.extend(described.drain(..));
        self.scratch.described = described;
        self.stats.detected += self.scratch_corners.len() as u64;
    }

    /// Finds each left feature in the right image: KLT from the left
    /// pyramid, starting at last frame's match or at the prior depth, then
    /// (for the ones that failed) at a third and at three times that
    /// depth; a match must lie on its epipolar line, in front of both
    /// cameras.
    fn match_right(&mut self, observations: &mut Vec<Observation>) {
        let n = self.points.len();
        let mut scratch = std::mem::take(&mut self.scratch);
        let Scratch {
            matched,
            pending,
            still,
            sub_points,
            ratios,
            sorted_ratios,
            ..
        } = &mut scratch;
        matched.clear();
        matched.resize(n, None);
        ratios.clear();
        ratios.resize(n, f32::NAN);
        pending.clear();
        pending.extend(0..n);
        let depths = [
            self.config.stereo_prior_depth_m,
            self.config.stereo_prior_depth_m / 3.0,
            self.config.stereo_prior_depth_m * 3.0,
        ];
        for (pass, depth_m) in depths.into_iter().enumerate() {
            if pending.is_empty() {
                break;
            }
            sub_points.clear();
            self.scratch_predicted.clear();
            for &i in pending.iter() {
                let p = self.points[i];
                let history = if pass == 0 {
                    self.right_points.get(&self.ids[i]).copied()
                } else {
                    None
                };
                let guess = history.or_else(|| self.right_guess(&p, depth_m));
                sub_points.push(p);
                self.scratch_predicted.push(guess.unwrap_or(p));
            }
            self.stereo_klt.track(
                &self.cur,
                &self.right,
                sub_points,
                Some(&self.scratch_predicted),
                &mut self.scratch_tracked,
                &mut self.scratch_status,
            );
            still.clear();
            for (k, &i) in pending.iter().enumerate() {
                let q = self.scratch_tracked[k];
                if self.scratch_status[k] == TrackStatus::Tracked
                    && self.on_epipolar_line(&self.points[i], &q)
                {
                    matched[i] = Some(q);
                    ratios[i] = self
                        .stereo_klt
                        .residual_ratios()
                        .get(k)
                        .copied()
                        .unwrap_or(f32::NAN);
                } else {
                    still.push(i);
                }
            }
            std::mem::swap(pending, still);
        }
        if let Some(k) = self.config.stereo_residual_vs_median {
            self.stats.stereo_refused_residual +=
                refuse_far_above_median(matched, ratios, sorted_ratios, k);
        }
        self.right_points.clear();
        for (i, q) in matched.iter().enumerate() {
            match *q {
                Some(q) => {
                    self.stats.stereo_matched += 1;
                    self.right_points.insert(self.ids[i], q);
                    observations.push(Observation {
                        landmark: self.ids[i],
                        camera_index: 1,
                        pixel: Vector2::new(f64::from(q[0]), f64::from(q[1])),
                    });
                }
                None => self.stats.stereo_rejected += 1,
            }
        }
        self.scratch = scratch;
    }

    /// Where a left pixel lands in the right image at `depth_m`.
    fn right_guess(&self, p: &[f32; 2], depth_m: f64) -> Option<[f32; 2]> {
        let ray = self.cameras[0]
            .model
            .unproject(&Vector2::new(f64::from(p[0]), f64::from(p[1])))?;
        let point = ray.normalize() * depth_m;
        let q = self.cameras[1]
            .model
            .project(&(self.r_c1_c0 * point + self.t_c1_c0))?;
        (q.x.is_finite() && q.y.is_finite()).then_some([q.x as f32, q.y as f32])
    }

    /// The stereo check: Sampson distance to the epipolar line of the
    /// calibrated pair, and both depths positive.
    fn on_epipolar_line(&self, p: &[f32; 2], q: &[f32; 2]) -> bool {
        let right = &self.cameras[1].model;
        let (Some(x0), Some(x1)) = (normalised(&self.cameras[0].model, p), normalised(right, q))
        else {
            return false;
        };
        let [fx, fy, _, _] = right.pinhole();
        let sampson = crate::two_view::essential::sampson_error(&self.stereo_essential, &x0, &x1);
        let h0 = Vector3::new(x0.x, x0.y, 1.0);
        let h1 = Vector3::new(x1.x, x1.y, 1.0);
        sampson.abs() * 0.5 * (fx + fy) <= self.config.stereo_epipolar_px
            && positive_depth(&self.r_c1_c0, &self.t_c1_c0, &h0, &h1)
    }

    /// The keyframe policy of the module documentation.
    fn keyframe_wanted(&self, t_ns: i64) -> bool {
        let Some(kf_ns) = self.keyframe_t_ns else {
            return true;
        };
        if (t_ns - kf_ns) as f64 * 1e-9 >= self.config.keyframe_max_interval_s {
            return true;
        }
        if self.keyframe_points.is_empty() {
            return !self.points.is_empty();
        }
        let camera = &self.cameras[0].model;
        let r_cur_kf = self.rotation_since_keyframe.inverse();
        let mut parallax = Vec::with_capacity(self.points.len());
        for (id, p) in self.ids.iter().zip(&self.points) {
            let Some(k) = self.keyframe_points.get(id) else {
                continue;
            };
            let kx = Vector2::new(f64::from(k[0]), f64::from(k[1]));
            let rotated = camera
                .unproject(&kx)
                .and_then(|ray| camera.project(&(r_cur_kf * ray)))
                .unwrap_or(kx);
            parallax.push((Vector2::new(f64::from(p[0]), f64::from(p[1])) - rotated).norm());
        }
        let tracked_share = parallax.len() as f64 / self.keyframe_points.len() as f64;
        if tracked_share < self.config.keyframe_min_tracked {
            return true;
        }
        if parallax.is_empty() {
            return false;
        }
        let mid = parallax.len() / 2;
        parallax.select_nth_unstable_by(mid, f64::total_cmp);
        parallax[mid] > self.config.keyframe_parallax_px
    }
}

/// Fewer stereo matches than this in a frame: no median is trusted and
/// every match is kept.
const MIN_MATCHES_FOR_MEDIAN: usize = 20;

/// Drops the matches whose residual ratio is more than `k` times the
/// median of the frame's matches (a match with no ratio counts as far
/// above). Returns how many were dropped.
fn refuse_far_above_median(
    matched: &mut [Option<[f32; 2]>],
    ratios: &[f32],
    sorted: &mut Vec<f32>,
    k: f32,
) -> u64 {
    sorted.clear();
    sorted.extend(
        matched
            .iter()
            .zip(ratios)
            .filter(|(m, r)| m.is_some() && r.is_finite())
            .map(|(_, r)| *r),
    );
    if sorted.len() < MIN_MATCHES_FOR_MEDIAN {
        return 0;
    }
    let mid = sorted.len() / 2;
    let limit = k * *sorted.select_nth_unstable_by(mid, f32::total_cmp).1;
    let mut dropped = 0;
    for (m, r) in matched.iter_mut().zip(ratios) {
        if m.is_some() && !(*r <= limit) {
            *m = None;
            dropped += 1;
        }
    }
    dropped
}

/// `x/z, y/z` of the pixel's ray; `None` when it cannot be unprojected or
/// points backwards.
fn normalised(camera: &CameraModel, px: &[f32; 2]) -> Option<Vector2<f64>> {
    let ray = camera.unproject(&Vector2::new(f64::from(px[0]), f64::from(px[1])))?;
    if !(ray.z > 1e-6) {
        return None;
    }
    let x = Vector2::new(ray.x / ray.z, ray.y / ray.z);
    x.iter().all(|v| v.is_finite()).then_some(x)
}

/// Whether the rays `h0` (left) and `h1` (right) meet in front of both
/// cameras (midpoint depths positive); parallel rays count as far.
#[allow(non_snake_case)]
fn positive_depth(
    R_c1_c0: &Matrix3<f64>,
    t_c1_c0: &Vector3<f64>,
    h0: &Vector3<f64>,
    h1: &Vector3<f64>,
) -> bool {
    // Solve d1 h1 = d0 R h0 + t for (d0, d1) in least squares.
    let a = R_c1_c0 * h0;
    let b = -h1;
    let ata = a.dot(&a);
    let atb = a.dot(&b);
    let btb = b.dot(&b);
    let det = ata * btb - atb * atb;
    if det.abs() < 1e-12 {
        return true;
    }
    let rhs_a = -a.dot(t_c1_c0);
    let rhs_b = -b.dot(t_c1_c0);
    let d0 = (btb * rhs_a - atb * rhs_b) / det;
    let d1 = (ata * rhs_b - atb * rhs_a) / det;
    d0 > 0.0 && d1 > 0.0
}

pub mod first_patch;

#[cfg(test)]
mod tests;
