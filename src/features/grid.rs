//! Spreading features over the image: candidates compete inside buckets of
//! a regular grid (each bucket takes its best first, then its second best,
//! ...) so that texture-rich regions cannot take the whole budget, and a
//! mask keeps new features at least `min_distance_px` from each other and
//! from features that are already being tracked.

use crate::features::fast::Corner;

/// Bucketing and masking parameters.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GridConfig {
    /// Side of a bucket, px.
    pub bucket_px: usize,
    /// Minimum distance of a new feature to any other, px (0 = no mask).
    pub min_distance_px: f32,
}

impl Default for GridConfig {
    fn default() -> Self {
        Self {
            bucket_px: 48,
            min_distance_px: 10.0,
        }
    }
}

/// Points a mask cell can hold; cells are `min_distance_px` wide, and at
/// most 4 points pairwise that far apart fit in one, so a full cell only
/// happens with crowded tracked points and then counts as blocked.
const CELL_CAPACITY: usize = 4;

/// Grid selection with buffers reused between frames.
#[derive(Debug, Clone, Default)]
pub struct GridSelector {
    config: GridConfig,
    bucket_counts: Vec<u16>,
    /// (rank in bucket, candidate index), sorted.
    order: Vec<(u16, u32)>,
    mask_cells: Vec<[[f32; 2]; CELL_CAPACITY]>,
    mask_fill: Vec<u8>,
    mask_cols: usize,
    mask_rows: usize,
    mask_cell_px: f32,
}

impl GridSelector {
    /// A selector with `config` and empty buffers.
    pub fn new(config: GridConfig) -> Self {
        Self {
            config,
            ..Self::default()
        }
    }

    /// The settings it was built with.
    pub fn config(&self) -> &GridConfig {
        &self.config
    }

    /// Picks up to `budget` of `candidates` (reordered here, best score
    /// first) for a `width` x `height` image into `out` (cleared first),
    /// spread over buckets and away from `tracked` (positions in the same
    /// pixel grid) by the mask.
    pub fn select(
        &mut self,
        width: usize,
        height: usize,
        candidates: &mut [Corner],
        tracked: &[[f32; 2]],
        budget: usize,
        out: &mut Vec<Corner>,
    ) {
        out.clear();
        if width == 0 || height == 0 || budget == 0 || candidates.is_empty() {
            return;
        }
        candidates.sort_unstable_by(|a, b| b.score.total_cmp(&a.score));
        let bucket = self.config.bucket_px.max(1);
        let (bx, by) = (width.div_ceil(bucket), height.div_ceil(bucket));
        self.bucket_counts.clear();
        self.bucket_counts.resize(bx * by, 0);
        // Rank of each candidate within its bucket (0 = the bucket's best);
        // taking candidates by (rank, score) gives every bucket its best
        // before any bucket its second, and so on.
        self.order.clear();
        for (i, c) in candidates.iter().enumerate() {
            let b = (c.y as usize / bucket).min(by - 1) * bx + (c.x as usize / bucket).min(bx - 1);
            let rank = self.bucket_counts[b];
            self.bucket_counts[b] = rank.saturating_add(1);
            self.order.push((rank, i as u32));
        }
        self.order.sort_unstable();
        self.reset_mask(width, height);
        for p in tracked {
            self.mask_insert(*p);
        }
        for k in 0..self.order.len() {
            if out.len() == budget {
                return;
            }
            let c = candidates[self.order[k].1 as usize];
            let p = [c.x as f32, c.y as f32];
            if self.mask_blocks(p) {
                continue;
            }
            self.mask_insert(p);
            out.push(c);
        }
    }

    fn reset_mask(&mut self, width: usize, height: usize) {
        let d = self.config.min_distance_px;
        if d <= 0.0 {
            self.mask_cols = 0;
            self.mask_rows = 0;
            return;
        }
        let cell = d.ceil() as usize;
        self.mask_cell_px = cell as f32;
        self.mask_cols = width.div_ceil(cell) + 1;
        self.mask_rows = height.div_ceil(cell) + 1;
        self.mask_fill.clear();
        self.mask_fill.resize(self.mask_cols * self.mask_rows, 0);
        self.mask_cells
            .resize(self.mask_cols * self.mask_rows, [[0.0; 2]; CELL_CAPACITY]);
    }

    fn mask_cell(&self, p: [f32; 2]) -> Option<(usize, usize)> {
        if self.mask_cols == 0 || !(p[0] >= 0.0 && p[1] >= 0.0) {
            return None;
        }
        let cell = self.mask_cell_px;
        let (cx, cy) = ((p[0] / cell) as usize, (p[1] / cell) as usize);
        (cx < self.mask_cols && cy < self.mask_rows).then_some((cx, cy))
    }

    fn mask_insert(&mut self, p: [f32; 2]) {
        if let Some((cx, cy)) = self.mask_cell(p) {
            let i = cy * self.mask_cols + cx;
            let n = self.mask_fill[i] as usize;
            if n < CELL_CAPACITY {
                self.mask_cells[i][n] = p;
            }
            self.mask_fill[i] = (n + 1).min(u8::MAX as usize) as u8;
        }
    }

    fn mask_blocks(&self, p: [f32; 2]) -> bool {
        let Some((cx, cy)) = self.mask_cell(p) else {
            return false;
        };
        let d2 = self.config.min_distance_px * self.config.min_distance_px;
        for y in cy.saturating_sub(1)..(cy + 2).min(self.mask_rows) {
            for x in cx.saturating_sub(1)..(cx + 2).min(self.mask_cols) {
                let i = y * self.mask_cols + x;
                let n = self.mask_fill[i] as usize;
                if n > CELL_CAPACITY {
                    return true;
                }
                for q in &self.mask_cells[i][..n] {
                    let (dx, dy) = (q[0] - p[0], q[1] - p[1]);
                    if dx * dx + dy * dy < d2 {
                        return true;
                    }
                }
            }
        }
        false
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn corner(x: u32, y: u32, score: f32) -> Corner {
        Corner { x, y, score }
    }

    #[test]
    fn buckets_share_the_budget_before_any_takes_a_second() {
        // 40 strong corners in the left bucket, 2 weak ones in the right.
        let mut candidates: Vec<Corner> = (0..40)
            .map(|i| corner(2 + (i % 8) * 5, 2 + (i / 8) * 5, 100.0 + i as f32))
            .collect();
        candidates.push(corner(70, 10, 1.0));
        candidates.push(corner(90, 30, 2.0));
        let mut grid = GridSelector::new(GridConfig {
            bucket_px: 50,
            min_distance_px: 0.0,
        });
        let mut out = Vec::new();
        grid.select(100, 50, &mut candidates, &[], 4, &mut out);
        assert_eq!(out.len(), 4);
        let right = out.iter().filter(|c| c.x >= 50).count();
        assert_eq!(right, 2, "{out:?}");
        assert_eq!(out[0].score, 139.0, "the best overall comes first");
    }

    #[test]
    fn the_mask_keeps_new_features_away_from_tracked_ones_and_each_other() {
        let mut candidates: Vec<Corner> = (0..100)
            .map(|i| corner((i % 10) * 3 + 1, (i / 10) * 3 + 1, i as f32))
            .collect();
        let tracked = [[5.0, 5.0]];
        let mut grid = GridSelector::new(GridConfig {
            bucket_px: 16,
            min_distance_px: 8.0,
        });
        let mut out = Vec::new();
        grid.select(32, 32, &mut candidates, &tracked, 100, &mut out);
        assert!(!out.is_empty());
        for (i, a) in out.iter().enumerate() {
            let pa = [a.x as f32, a.y as f32];
            let dt = ((pa[0] - 5.0).powi(2) + (pa[1] - 5.0).powi(2)).sqrt();
            assert!(dt >= 8.0, "{a:?} is {dt} px from the tracked feature");
            for b in &out[i + 1..] {
                let d =
                    ((a.x as f32 - b.x as f32).powi(2) + (a.y as f32 - b.y as f32).powi(2)).sqrt();
                assert!(d >= 8.0, "{a:?} and {b:?} are {d} px apart");
            }
        }
    }

    #[test]
    fn nothing_in_nothing_out() {
        let mut grid = GridSelector::new(GridConfig::default());
        let mut out = vec![corner(0, 0, 0.0)];
        grid.select(0, 0, &mut [], &[], 10, &mut out);
        assert!(out.is_empty());
        grid.select(
            10,
            10,
            &mut [corner(1, 1, 1.0)],
            &[[f32::NAN, 0.0]],
            0,
            &mut out,
        );
        assert!(out.is_empty());
    }
}
