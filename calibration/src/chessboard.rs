//! Chessboard detection with subpixel corners, written for this crate (no
//! OpenCV): saddle points of the smoothed image (negative Hessian
//! determinant), an x-junction test on a ring around each, the gradient
//! orthogonality refinement of Förstner and Gülch ("A fast operator for
//! detection and precise location of distinct points", 1987; the same
//! equation as OpenCV's `cornerSubPix`), then a grid grown from a seed
//! corner by linear and parallelogram prediction until it holds exactly
//! `cols x rows` corners.
//!
//! Corners come out row-major in the board's frame: `cols` corners per row,
//! the first row the one nearest the top of the image, each row running
//! left to right in the image. Any other ordering that is a symmetry of the
//! grid would calibrate the same intrinsics; this one is just consistent.

use std::collections::HashMap;

use nalgebra::{Matrix2, Vector2};

/// A greyscale image as `f32` in [0, 255], row-major.
#[derive(Debug, Clone)]
pub struct GreyImage {
    pub width: usize,
    pub height: usize,
    pub pixels: Vec<f32>,
}

impl GreyImage {
    pub fn from_luma8(width: usize, height: usize, bytes: &[u8]) -> Self {
        Self {
            width,
            height,
            pixels: bytes.iter().map(|&b| f32::from(b)).collect(),
        }
    }

    #[inline]
    fn at(&self, x: usize, y: usize) -> f32 {
        self.pixels[y * self.width + x]
    }

    /// Bilinear sample; `None` outside the image.
    pub fn sample(&self, x: f64, y: f64) -> Option<f32> {
        if !(x >= 0.0 && y >= 0.0) {
            return None;
        }
        let (x0, y0) = (x.floor() as usize, y.floor() as usize);
        if x0 + 1 >= self.width || y0 + 1 >= self.height {
            return None;
        }
        let (ax, ay) = ((x - x0 as f64) as f32, (y - y0 as f64) as f32);
        let top = self.at(x0, y0) * (1.0 - ax) + self.at(x0 + 1, y0) * ax;
        let bottom = self.at(x0, y0 + 1) * (1.0 - ax) + self.at(x0 + 1, y0 + 1) * ax;
        Some(top * (1.0 - ay) + bottom * ay)
    }

    /// Separable Gaussian blur (kernel radius 3 sigma, edges clamped).
    pub fn gaussian_blur(&self, sigma: f64) -> GreyImage {
        let radius = (3.0 * sigma).ceil() as isize;
        let kernel: Vec<f32> = (-radius..=radius)
            .map(|i| (-(i * i) as f64 / (2.0 * sigma * sigma)).exp() as f32)
            .collect();
        let sum: f32 = kernel.iter().sum();
        let kernel: Vec<f32> = kernel.iter().map(|k| k / sum).collect();
        let (w, h) = (self.width as isize, self.height as isize);
        let mut horizontal = vec![0.0f32; self.pixels.len()];
        for y in 0..h {
            for x in 0..w {
                let mut acc = 0.0;
                for (k, &weight) in kernel.iter().enumerate() {
                    let xx = (x + k as isize - radius).clamp(0, w - 1);
                    acc += weight * self.pixels[(y * w + xx) as usize];
                }
                horizontal[(y * w + x) as usize] = acc;
            }
        }
        let mut out = vec![0.0f32; self.pixels.len()];
        for y in 0..h {
            for x in 0..w {
                let mut acc = 0.0;
                for (k, &weight) in kernel.iter().enumerate() {
                    let yy = (y + k as isize - radius).clamp(0, h - 1);
                    acc += weight * horizontal[(yy * w + x) as usize];
                }
                out[(y * w + x) as usize] = acc;
            }
        }
        GreyImage {
            width: self.width,
            height: self.height,
            pixels: out,
        }
    }
}

/// Settings of [`detect_chessboard`]; the defaults suit boards whose squares
/// are 15 to 100 px wide.
#[derive(Debug, Clone)]
pub struct ChessboardConfig {
    /// Smoothing before the saddle response, px.
    pub sigma_px: f64,
    /// Radius of the ring sampled by the x-junction test, px.
    pub ring_radius_px: f64,
    /// Half width of the subpixel refinement window, px.
    pub refine_half_window_px: i32,
    /// Saddle candidates weaker than this fraction of the strongest are dropped.
    pub relative_threshold: f32,
}

impl Default for ChessboardConfig {
    fn default() -> Self {
        Self {
            sigma_px: 1.5,
            ring_radius_px: 5.0,
            refine_half_window_px: 5,
            relative_threshold: 0.02,
        }
    }
}

/// A found board: `cols * rows` corners, row-major (see the module doc).
#[derive(Debug, Clone)]
pub struct ChessboardCorners {
    pub cols: usize,
    pub rows: usize,
    pub corners_px: Vec<Vector2<f64>>,
}

/// An x-junction candidate: position and the two directions of the edges
/// crossing at it (radians, in [0, pi)).
#[derive(Debug, Clone, Copy)]
struct Candidate {
    position: Vector2<f64>,
    response: f32,
    edge_angles_rad: [f64; 2],
}

/// Finds a chessboard of `cols x rows` inner corners (either orientation on
/// the sensor). `None` when no complete grid of that size is found.
pub fn detect_chessboard(
    image: &GreyImage,
    cols: usize,
    rows: usize,
    config: &ChessboardConfig,
) -> Option<ChessboardCorners> {
    let smooth = image.gaussian_blur(config.sigma_px);
    let gradient_image = image.gaussian_blur(0.7);
    let candidates = saddle_candidates(&smooth, &gradient_image, config);
    let mut order: Vec<usize> = (0..candidates.len()).collect();
    order.sort_by(|&a, &b| candidates[b].response.total_cmp(&candidates[a].response));
    for &seed in order.iter().take(60) {
        if let Some(grid) = grow_grid(&candidates, seed, cols, rows) {
            return Some(canonical_order(grid, &candidates, cols, rows));
        }
    }
    None
}

/// Saddle points of the smoothed image that pass the x-junction ring test,
/// refined to subpixel.
fn saddle_candidates(
    smooth: &GreyImage,
    gradient_image: &GreyImage,
    config: &ChessboardConfig,
) -> Vec<Candidate> {
    let (w, h) = (smooth.width, smooth.height);
    let mut response = vec![0.0f32; w * h];
    for y in 1..h - 1 {
        for x in 1..w - 1 {
            let c = smooth.at(x, y);
            let dxx = smooth.at(x + 1, y) - 2.0 * c + smooth.at(x - 1, y);
            let dyy = smooth.at(x, y + 1) - 2.0 * c + smooth.at(x, y - 1);
            let dxy = 0.25
                * (smooth.at(x + 1, y + 1) - smooth.at(x + 1, y - 1) - smooth.at(x - 1, y + 1)
                    + smooth.at(x - 1, y - 1));
            // Saddle: det(H) < 0; the response is -det(H).
            response[y * w + x] = (dxy * dxy - dxx * dyy).max(0.0);
        }
    }
    let strongest = response.iter().cloned().fold(0.0f32, f32::max);
    let threshold = strongest * config.relative_threshold;
    let margin =
        (config.ring_radius_px.ceil() as usize + 3).max(config.refine_half_window_px as usize + 2);
    let suppress = 3usize;
    let mut out = Vec::new();
    for y in margin..h.saturating_sub(margin) {
        for x in margin..w.saturating_sub(margin) {
            let r = response[y * w + x];
            if r <= threshold {
                continue;
            }
            let is_max = (y - suppress..=y + suppress).all(|yy| {
                (x - suppress..=x + suppress).all(|xx| {
                    let other = response[yy * w + xx];
                    other < r || (other == r && (yy, xx) >= (y, x))
                })
            });
            if !is_max {
                continue;
            }
            let Some(position) = refine_corner(
                gradient_image,
                Vector2::new(x as f64, y as f64),
                config.refine_half_window_px,
            ) else {
                continue;
            };
            if let Some(edge_angles_rad) =
                x_junction_edges(smooth, &position, config.ring_radius_px)
            {
                out.push(Candidate {
                    position,
                    response: r,
                    edge_angles_rad,
                });
            }
        }
    }
    out
}

/// Subpixel corner by gradient orthogonality: every pixel `p` near a corner
/// `q` either has zero gradient or lies on an edge through `q`, so
/// `g(p)^T (p - q) = 0`; least squares gives
/// `q = (sum g g^T)^-1 sum g g^T p` (Förstner and Gülch 1987), iterated with
/// the window recentred. Gaussian-weighted; `None` if it drifts away.
pub fn refine_corner(
    image: &GreyImage,
    start: Vector2<f64>,
    half_window: i32,
) -> Option<Vector2<f64>> {
    let mut q = start;
    let sigma = half_window as f64 * 0.7;
    for _ in 0..10 {
        let mut a = Matrix2::<f64>::zeros();
        let mut b = Vector2::<f64>::zeros();
        for dy in -half_window..=half_window {
            for dx in -half_window..=half_window {
                let p = Vector2::new(q.x + dx as f64, q.y + dy as f64);
                let gx = image.sample(p.x + 1.0, p.y)? - image.sample(p.x - 1.0, p.y)?;
                let gy = image.sample(p.x, p.y + 1.0)? - image.sample(p.x, p.y - 1.0)?;
                let g = Vector2::new(gx as f64 * 0.5, gy as f64 * 0.5);
                let weight = (-((dx * dx + dy * dy) as f64) / (2.0 * sigma * sigma)).exp();
                let ggt = g * g.transpose() * weight;
                a += ggt;
                b += ggt * p;
            }
        }
        let next = a.try_inverse()? * b;
        let step = (next - q).norm();
        q = next;
        if (q - start).norm() > half_window as f64 {
            return None;
        }
        if step < 1e-3 {
            break;
        }
    }
    Some(q)
}

/// The x-junction test: around a chessboard corner a ring of the image
/// alternates dark, bright, dark, bright with opposite sectors alike, so its
/// sign about the ring mean changes exactly four times, at roughly opposite
/// pairs of angles. Returns the two edge directions (mod pi).
fn x_junction_edges(image: &GreyImage, centre: &Vector2<f64>, radius: f64) -> Option<[f64; 2]> {
    const SAMPLES: usize = 48;
    let mut values = [0.0f32; SAMPLES];
    for (i, v) in values.iter_mut().enumerate() {
        let angle = i as f64 * std::f64::consts::TAU / SAMPLES as f64;
        *v = image.sample(
            centre.x + radius * angle.cos(),
            centre.y + radius * angle.sin(),
        )?;
    }
    let mean = values.iter().sum::<f32>() / SAMPLES as f32;
    let (min, max) = values
        .iter()
        .fold((f32::MAX, f32::MIN), |(lo, hi), &v| (lo.min(v), hi.max(v)));
    // Contrast check: a flat or single-edge ring is not a corner.
    if max - min < 20.0 {
        return None;
    }
    let band = 0.15 * (max - min);
    // Hysteresis sign: start from a sample clearly on one side.
    let start = values.iter().position(|v| (v - mean).abs() > band)?;
    let mut sign = values[start] > mean;
    let mut crossings = Vec::new();
    for k in 1..=SAMPLES {
        let i = (start + k) % SAMPLES;
        let v = values[i];
        let now = if v > mean + band {
            true
        } else if v < mean - band {
            false
        } else {
            continue;
        };
        if now != sign {
            // The crossing lies between the previous sample and this one;
            // find where the ring passes the mean.
            let mut j = (i + SAMPLES - 1) % SAMPLES;
            while (values[j] > mean) != sign && j != start {
                j = (j + SAMPLES - 1) % SAMPLES;
            }
            let (a, b) = (values[j], values[(j + 1) % SAMPLES]);
            let frac = if (b - a).abs() > 1e-6 {
                ((mean - a) / (b - a)).clamp(0.0, 1.0) as f64
            } else {
                0.5
            };
            crossings.push((j as f64 + frac) * std::f64::consts::TAU / SAMPLES as f64);
            sign = now;
        }
    }
    if crossings.len() != 4 {
        return None;
    }
    crossings.sort_by(f64::total_cmp);
    let pi = std::f64::consts::PI;
    let mut edges = [0.0; 2];
    for (k, edge) in edges.iter_mut().enumerate() {
        let (a, b) = (crossings[k], crossings[k + 2]);
        // Opposite crossings of one straight edge are pi apart.
        let gap = (b - a - pi).abs();
        if gap > 0.45 {
            return None;
        }
        *edge = ((a + b - pi) * 0.5).rem_euclid(pi);
    }
    Some(edges)
}

/// Angle between a direction and an edge (mod pi), in [0, pi/2].
fn angle_to_edge(direction: &Vector2<f64>, edge_rad: f64) -> f64 {
    let pi = std::f64::consts::PI;
    let d = (direction.y.atan2(direction.x) - edge_rad).rem_euclid(pi);
    d.min(pi - d)
}

/// The nearest unused candidate to `from` along an edge direction (either
/// sense), within 20 degrees.
fn nearest_along(candidates: &[Candidate], from: usize, edge_rad: f64) -> Option<usize> {
    let origin = candidates[from].position;
    candidates
        .iter()
        .enumerate()
        .filter(|&(i, _)| i != from)
        .filter(|(_, c)| angle_to_edge(&(c.position - origin), edge_rad) < 20f64.to_radians())
        .map(|(i, c)| (i, (c.position - origin).norm()))
        .filter(|&(_, d)| d > 4.0)
        .min_by(|a, b| a.1.total_cmp(&b.1))
        .map(|(i, _)| i)
}

/// Grows a grid from `seed`; `Some(map cell -> candidate)` when it is
/// complete and exactly `cols x rows` (or `rows x cols`).
fn grow_grid(
    candidates: &[Candidate],
    seed: usize,
    cols: usize,
    rows: usize,
) -> Option<HashMap<(i32, i32), usize>> {
    let [edge_u, edge_v] = candidates[seed].edge_angles_rad;
    let right = nearest_along(candidates, seed, edge_u)?;
    let down = nearest_along(candidates, seed, edge_v)?;
    let mut grid: HashMap<(i32, i32), usize> = HashMap::new();
    let mut used = vec![false; candidates.len()];
    for (cell, idx) in [((0, 0), seed), ((1, 0), right), ((0, 1), down)] {
        grid.insert(cell, idx);
        used[idx] = true;
    }
    let position = |grid: &HashMap<(i32, i32), usize>, cell: (i32, i32)| {
        grid.get(&cell).map(|&i| candidates[i].position)
    };
    let longest = cols.max(rows) as i32;
    loop {
        let mut added = false;
        let cells: Vec<(i32, i32)> = grid.keys().copied().collect();
        for (i, j) in cells {
            for (di, dj) in [(1, 0), (-1, 0), (0, 1), (0, -1)] {
                let target = (i + di, j + dj);
                if grid.contains_key(&target) {
                    continue;
                }
                let mut predictions = Vec::new();
                let mut spacing = f64::MAX;
                for (ai, aj) in [(1, 0), (-1, 0), (0, 1), (0, -1)] {
                    let a = position(&grid, (target.0 - ai, target.1 - aj));
                    let b = position(&grid, (target.0 - 2 * ai, target.1 - 2 * aj));
                    if let (Some(a), Some(b)) = (a, b) {
                        predictions.push(2.0 * a - b);
                        spacing = spacing.min((a - b).norm());
                    }
                }
                for (ai, aj, bi, bj) in [(1, 0, 0, 1), (1, 0, 0, -1), (-1, 0, 0, 1), (-1, 0, 0, -1)]
                {
                    let a = position(&grid, (target.0 - ai, target.1 - aj));
                    let b = position(&grid, (target.0 - bi, target.1 - bj));
                    let c = position(&grid, (target.0 - ai - bi, target.1 - aj - bj));
                    if let (Some(a), Some(b), Some(c)) = (a, b, c) {
                        predictions.push(a + b - c);
                        spacing = spacing.min((a - c).norm()).min((b - c).norm());
                    }
                }
                if predictions.is_empty() {
                    continue;
                }
                let predicted = predictions.iter().fold(Vector2::zeros(), |s, p| s + p)
                    / predictions.len() as f64;
                let radius = 0.35 * spacing;
                let found = candidates
                    .iter()
                    .enumerate()
                    .filter(|&(k, _)| !used[k])
                    .map(|(k, c)| (k, (c.position - predicted).norm()))
                    .filter(|&(_, d)| d < radius)
                    .min_by(|a, b| a.1.total_cmp(&b.1));
                if let Some((k, _)) = found {
                    grid.insert(target, k);
                    used[k] = true;
                    added = true;
                }
            }
        }
        let (min_i, max_i, min_j, max_j) = extents(&grid);
        // A stray point or two beyond the board (its outer border, the
        // paper's edge) may attach; more than that is not this board.
        if max_i - min_i + 1 > longest + 2 || max_j - min_j + 1 > longest + 2 {
            return None;
        }
        if !added {
            break;
        }
    }
    complete_window(&grid, candidates, cols, rows)
}

/// The `cols x rows` (or `rows x cols`) window of the grown grid that is
/// completely filled, the strongest by summed saddle response when stray
/// points beyond the board make more than one; re-indexed from (0, 0).
fn complete_window(
    grid: &HashMap<(i32, i32), usize>,
    candidates: &[Candidate],
    cols: usize,
    rows: usize,
) -> Option<HashMap<(i32, i32), usize>> {
    let (min_i, max_i, min_j, max_j) = extents(grid);
    type Window = HashMap<(i32, i32), usize>;
    let mut best: Option<(f32, Window)> = None;
    for (span_i, span_j) in [(cols as i32, rows as i32), (rows as i32, cols as i32)] {
        for i0 in min_i..=max_i - span_i + 1 {
            for j0 in min_j..=max_j - span_j + 1 {
                let mut window = HashMap::new();
                let mut strength = 0.0;
                for i in 0..span_i {
                    for j in 0..span_j {
                        if let Some(&k) = grid.get(&(i0 + i, j0 + j)) {
                            window.insert((i, j), k);
                            strength += candidates[k].response;
                        }
                    }
                }
                // A complete row or column just outside the window means the
                // board is larger than declared, not a stray point.
                let filled = |cells: Vec<(i32, i32)>| cells.iter().all(|c| grid.contains_key(c));
                let larger = filled((0..span_j).map(|j| (i0 - 1, j0 + j)).collect())
                    || filled((0..span_j).map(|j| (i0 + span_i, j0 + j)).collect())
                    || filled((0..span_i).map(|i| (i0 + i, j0 - 1)).collect())
                    || filled((0..span_i).map(|i| (i0 + i, j0 + span_j)).collect());
                let full = window.len() == cols * rows && !larger;
                if full && best.as_ref().map_or(true, |b| strength > b.0) {
                    best = Some((strength, window));
                }
            }
        }
    }
    best.map(|b| b.1)
}

fn extents(grid: &HashMap<(i32, i32), usize>) -> (i32, i32, i32, i32) {
    grid.keys().fold(
        (i32::MAX, i32::MIN, i32::MAX, i32::MIN),
        |(a, b, c, d), &(i, j)| (a.min(i), b.max(i), c.min(j), d.max(j)),
    )
}

/// Puts a complete grid into the module's order: the grid axis with `cols`
/// corners runs left to right in the image, rows top to bottom. For a square
/// board the axis nearer the image x axis is the column axis.
fn canonical_order(
    grid: HashMap<(i32, i32), usize>,
    candidates: &[Candidate],
    cols: usize,
    rows: usize,
) -> ChessboardCorners {
    let (min_i, max_i, min_j, max_j) = extents(&grid);
    let at = |i: i32, j: i32| candidates[grid[&(i, j)]].position;
    // Direction of each grid axis across the whole board.
    let axis_i = at(max_i, min_j) - at(min_i, min_j);
    let axis_j = at(min_i, max_j) - at(min_i, min_j);
    let span_i = (max_i - min_i + 1) as usize;
    // Which grid axis becomes the column (x) axis.
    let i_is_x = if cols == rows {
        axis_i.x.abs() / axis_i.norm() >= axis_j.x.abs() / axis_j.norm()
    } else {
        span_i == cols
    };
    let (x_axis, y_axis) = if i_is_x {
        (axis_i, axis_j)
    } else {
        (axis_j, axis_i)
    };
    let flip_x = x_axis.x < 0.0;
    let flip_y = y_axis.y < 0.0;
    let mut corners_px = Vec::with_capacity(cols * rows);
    for r in 0..rows as i32 {
        for c in 0..cols as i32 {
            let gx = if flip_x { cols as i32 - 1 - c } else { c };
            let gy = if flip_y { rows as i32 - 1 - r } else { r };
            let (i, j) = if i_is_x {
                (min_i + gx, min_j + gy)
            } else {
                (min_i + gy, min_j + gx)
            };
            corners_px.push(at(i, j));
        }
    }
    ChessboardCorners {
        cols,
        rows,
        corners_px,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A synthetic chessboard rendered by supersampling, with its exact
    /// inner corners under an affine map.
    fn render_board(cols: usize, rows: usize) -> (GreyImage, Vec<Vector2<f64>>) {
        let (w, h) = (320usize, 240usize);
        // Board coordinates (in squares) -> pixels: rotation 10 deg, 22 px squares.
        let (s, c) = (10f64.to_radians().sin(), 10f64.to_radians().cos());
        let scale = 22.0;
        let origin = Vector2::new(60.3, 40.7);
        let to_px = |u: f64, v: f64| origin + scale * Vector2::new(c * u - s * v, s * u + c * v);
        let to_board = |x: f64, y: f64| {
            let d = (Vector2::new(x, y) - origin) / scale;
            (c * d.x + s * d.y, -s * d.x + c * d.y)
        };
        let mut pixels = vec![0f32; w * h];
        let n = 8;
        for y in 0..h {
            for x in 0..w {
                let mut acc = 0.0;
                for sy in 0..n {
                    for sx in 0..n {
                        let (u, v) = to_board(
                            x as f64 + (sx as f64 + 0.5) / n as f64 - 0.5,
                            y as f64 + (sy as f64 + 0.5) / n as f64 - 0.5,
                        );
                        let inside =
                            u >= 0.0 && v >= 0.0 && u < (cols + 1) as f64 && v < (rows + 1) as f64;
                        let black = inside && ((u.floor() as i64 + v.floor() as i64) % 2 == 0);
                        acc += if black { 30.0 } else { 220.0 };
                    }
                }
                pixels[y * w + x] = acc / (n * n) as f32;
            }
        }
        let corners = (1..=rows)
            .flat_map(|r| (1..=cols).map(move |cc| (cc, r)))
            .map(|(cc, r)| to_px(cc as f64, r as f64))
            .collect();
        (
            GreyImage {
                width: w,
                height: h,
                pixels,
            },
            corners,
        )
    }

    #[test]
    fn finds_synthetic_board_to_subpixel_accuracy() {
        let (image, truth) = render_board(7, 5);
        let found = detect_chessboard(&image, 7, 5, &ChessboardConfig::default())
            .expect("the rendered board is found");
        assert_eq!(found.corners_px.len(), 35);
        // Same ordering as the rendering (rows top to bottom, left to right).
        let worst = found
            .corners_px
            .iter()
            .zip(&truth)
            .map(|(a, b)| (a - b).norm())
            .fold(0.0, f64::max);
        assert!(worst < 0.05, "worst corner error {worst} px");
    }

    #[test]
    fn wrong_board_size_is_not_found() {
        let (image, _) = render_board(7, 5);
        assert!(detect_chessboard(&image, 8, 5, &ChessboardConfig::default()).is_none());
    }

    #[test]
    fn a_larger_board_is_not_taken_for_a_smaller_one() {
        let (image, _) = render_board(7, 5);
        assert!(detect_chessboard(&image, 6, 5, &ChessboardConfig::default()).is_none());
        assert!(detect_chessboard(&image, 7, 4, &ChessboardConfig::default()).is_none());
    }

    #[test]
    fn blank_image_has_no_board() {
        let image = GreyImage {
            width: 100,
            height: 80,
            pixels: vec![128.0; 8000],
        };
        assert!(detect_chessboard(&image, 7, 5, &ChessboardConfig::default()).is_none());
    }
}
