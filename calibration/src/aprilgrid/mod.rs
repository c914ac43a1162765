//! AprilGrid detection: Kalibr's grid of tag36h11 tags (with black squares
//! at the tag corners) found in a greyscale image, each tag's id and four
//! subpixel corners, ready for `camera-imu` as a [`TargetDetection`] or as
//! the per-frame CSV that `aprilgrid_detections` reads.
//!
//! ```no_run
//! use std::path::Path;
//! use rigslam_calibration::aprilgrid::{detect_aprilgrid, write_detection_csv, AprilGridTarget};
//!
//! let target = AprilGridTarget::from_yaml_file(Path::new("target.yaml"))?;
//! let image = image::open("frame.png")?.to_luma8();
//! let found = detect_aprilgrid(&image, &target);
//! let t_ns = 1_403_709_395_937_837_056;
//! let detection = found.target_detection(&target, t_ns);
//! write_detection_csv(Path::new("out/1403709395937837056.csv"), &detection, &target, &found.corner_ids())?;
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```
//!
//! Steps, one file each: `threshold` (adaptive threshold; saddles
//! cleared and the mask eroded, which parts tags from the corner squares
//! they touch), `quads` (dark components that are quadrilaterals),
//! `refine` (subpixel corners: an x-junction window, then the two edges
//! through the junction as lines), `decode` (cells sampled through a
//! homography and sharpened against their neighbours, the nearest
//! tag36h11 codeword of `tag36h11` under rotation, wrong cells weighed by
//! how clearly they are wrong), `target` (the `target.yaml` and the target
//! frame), `csv` (the detection file) and `render` (a synthetic image of a
//! grid, for tests and benchmarks).
//!
//! Pixels: image coordinates with pixel centres at integers (OpenCV's and
//! Kalibr's convention), x right, y down. Target points: metres in the
//! target frame of [`target`].

mod csv;
pub mod decode;
pub mod quads;
pub mod refine;
pub mod render;
pub mod tag36h11;
pub mod target;
pub mod threshold;

pub use csv::write_detection_csv;
pub use decode::DecodedTag;
pub use target::AprilGridTarget;

use crate::aprilgrid_detections::TargetDetection;
use crate::chessboard::GreyImage;

/// Smoothing before the threshold and the corner refinement (less noise,
/// and bilinear sampling of a smooth image has no pixel-locking bias), px.
const SMOOTHING_SIGMA_PX: f64 = 0.8;
/// Pixels the erosion removed plus the half pixel from a boundary pixel's
/// centre to the boundary: what the quads are grown by.
const GROW_PX: f64 = 1.5;
/// Most data cells that may be read wrong: below half the family's
/// minimum distance of 11, so the nearest codeword is unique (the soft
/// cost in `decode` bounds how wrong they may be).
const MAX_HAMMING: u32 = 5;

/// The tags found in one image, ascending id, each id once.
#[derive(Debug, Clone, Default)]
pub struct GridDetection {
    pub tags: Vec<DecodedTag>,
}

impl GridDetection {
    /// `(tag_id, corner_idx)` of each keypoint of
    /// [`GridDetection::target_detection`], in its order.
    pub fn corner_ids(&self) -> Vec<(usize, usize)> {
        self.tags
            .iter()
            .flat_map(|t| (0..4).map(move |c| (t.id, c)))
            .collect()
    }

    /// Keypoints (px) and their target points (m), four per tag in
    /// `corner_idx` order, as the CSVs `aprilgrid_detections` reads hold
    /// them. Tags whose id is not on `target` are left out.
    pub fn target_detection(&self, target: &AprilGridTarget, t_ns: i64) -> TargetDetection {
        let mut out = TargetDetection {
            t_ns,
            keypoints_px: Vec::new(),
            target_points_m: Vec::new(),
            tag_size_m: target.tag_size_m,
        };
        for tag in &self.tags {
            for (c, px) in tag.corners_px.iter().enumerate() {
                if let Some(p) = target.corner_m(tag.id, c) {
                    out.keypoints_px.push(*px);
                    out.target_points_m.push(p);
                }
            }
        }
        out
    }
}

/// Finds the tags of `target` in `image`. Never fails: an image without
/// the grid, too small or flat gives no tags. Each tag's corners are
/// subpixel x-junctions; a tag a corner of which cannot be refined (cut by
/// the image edge, occluded) is left out rather than given a rough corner.
pub fn detect_aprilgrid(image: &image::GrayImage, target: &AprilGridTarget) -> GridDetection {
    let (w, h) = (image.width() as usize, image.height() as usize);
    if w < 2 * quads::MIN_SIDE_PX as usize
        || h < 2 * quads::MIN_SIDE_PX as usize
        || target.validate().is_err()
    {
        return GridDetection::default();
    }
    let grey = GreyImage::from_luma8(w, h, image.as_raw());
    let smoothed = grey.gaussian_blur(SMOOTHING_SIGMA_PX);
    let mask = threshold::erode(&threshold::threshold(&smoothed));
    let mut tags: Vec<DecodedTag> = Vec::new();
    for quad in quads::find_quads(&mask, GROW_PX) {
        let Some(refined) = refine::refine_quad(&smoothed, &quad, target.tag_spacing_ratio) else {
            continue;
        };
        if let Some(tag) = decode::decode_quad(&grey, &refined, target, MAX_HAMMING) {
            tags.push(tag);
        }
    }
    // One observation per id: the best read.
    tags.sort_by_key(|t| (t.id, t.hamming));
    tags.dedup_by_key(|t| t.id);
    GridDetection { tags }
}
