//! Corners to track: FAST-9 candidates re-scored by Shi-Tomasi, then
//! spread over the image by the grid and kept away from features already
//! tracked. The front half of a KLT front end; [`KltTracker`] is the back.
//!
//! [`KltTracker`]: crate::features::KltTracker

use crate::features::fast::{detect_fast9, Corner, FastScratch};
use crate::features::grid::{GridConfig, GridSelector};
use crate::features::pyramid::GreyImage;
use crate::features::score::shi_tomasi_score;

/// Detection parameters.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CornerConfig {
    /// FAST threshold, grey levels.
    pub fast_threshold: u8,
    /// Used instead when the first pass finds fewer candidates than the
    /// budget (dark or blurred frames).
    pub fallback_fast_threshold: u8,
    /// Shi-Tomasi window half-size (2 -> 5x5).
    pub score_half_window_px: usize,
    /// Corners closer than this to an edge are not reported (a KLT window
    /// must fit around them).
    pub border_px: usize,
    /// Bucketing of the corners over the image and the minimum distance to existing features.
    pub grid: GridConfig,
}

impl Default for CornerConfig {
    fn default() -> Self {
        Self {
            fast_threshold: 20,
            fallback_fast_threshold: 8,
            score_half_window_px: 2,
            border_px: 12,
            grid: GridConfig::default(),
        }
    }
}

/// A corner detector with its buffers.
#[derive(Debug, Clone)]
pub struct CornerDetector {
    config: CornerConfig,
    fast: FastScratch,
    candidates: Vec<Corner>,
    grid: GridSelector,
}

impl CornerDetector {
    /// A detector with `config` and empty scratch buffers.
    pub fn new(config: CornerConfig) -> Self {
        Self {
            config,
            fast: FastScratch::default(),
            candidates: Vec::new(),
            grid: GridSelector::new(config.grid),
        }
    }

    /// The settings it was built with.
    pub fn config(&self) -> &CornerConfig {
        &self.config
    }

    /// Up to `budget` new corners of `image` (best Shi-Tomasi score first
    /// within the grid's rounds) into `out`, none within the grid's
    /// `min_distance_px` of `tracked`.
    pub fn detect(
        &mut self,
        image: &GreyImage,
        tracked: &[[f32; 2]],
        budget: usize,
        out: &mut Vec<Corner>,
    ) {
        out.clear();
        if budget == 0 {
            return;
        }
        let c = self.config;
        detect_fast9(
            image,
            c.fast_threshold,
            c.border_px,
            &mut self.fast,
            &mut self.candidates,
        );
        if self.candidates.len() < budget && c.fallback_fast_threshold < c.fast_threshold {
            detect_fast9(
                image,
                c.fallback_fast_threshold,
                c.border_px,
                &mut self.fast,
                &mut self.candidates,
            );
        }
        let r = c.score_half_window_px;
        self.candidates.retain_mut(|corner| {
            corner.score = shi_tomasi_score(image, corner.x as usize, corner.y as usize, r);
            corner.score > 0.0
        });
        self.grid.select(
            image.width,
            image.height,
            &mut self.candidates,
            tracked,
            budget,
            out,
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Bright squares on a dark background: 4 corners each.
    fn squares(w: usize, h: usize, step: usize) -> GreyImage {
        let data = (0..h)
            .flat_map(|y| (0..w).map(move |x| (x, y)))
            .map(|(x, y)| {
                let inside = (x % step) >= step / 4
                    && (x % step) < 3 * step / 4
                    && (y % step) >= step / 4
                    && (y % step) < 3 * step / 4;
                if inside {
                    220
                } else {
                    30
                }
            })
            .collect();
        GreyImage::from_vec(w, h, data).unwrap()
    }

    #[test]
    fn corners_sit_on_square_corners_and_respect_budget_border_and_mask() {
        let img = squares(200, 160, 40);
        let mut detector = CornerDetector::new(CornerConfig::default());
        let mut out = Vec::new();
        detector.detect(&img, &[], 1000, &mut out);
        assert!(out.len() >= 20, "{} corners", out.len());
        for c in &out {
            // Square corners are at 10 and 30 (mod 40); FAST fires within
            // a circle radius of them.
            let near = |v: u32| (7..=13).contains(&(v % 40)) || (27..=33).contains(&(v % 40));
            assert!(near(c.x) && near(c.y), "{c:?}");
            assert!(c.x >= 12 && c.y >= 12 && c.x < 188 && c.y < 148);
        }
        detector.detect(&img, &[], 5, &mut out);
        assert_eq!(out.len(), 5);
        let tracked = [[50.0, 50.0]];
        detector.detect(&img, &tracked, 1000, &mut out);
        assert!(out
            .iter()
            .all(|c| (c.x as f32 - 50.0).hypot(c.y as f32 - 50.0) >= 10.0));
    }

    #[test]
    fn flat_saturated_and_tiny_images_give_no_corners() {
        let mut detector = CornerDetector::new(CornerConfig::default());
        let mut out = Vec::new();
        for img in [
            GreyImage::filled(100, 100, 0),
            GreyImage::filled(100, 100, 255),
            GreyImage::filled(20, 20, 7),
            squares(8, 8, 4),
        ] {
            detector.detect(&img, &[], 100, &mut out);
            assert!(out.is_empty());
        }
    }
}
