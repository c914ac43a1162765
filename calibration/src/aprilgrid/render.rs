//! Synthetic AprilGrid images with known corners, for tests and benchmarks:
//! the grid as Kalibr prints it (tags drawn from the tag36h11 codewords,
//! black squares at every tag corner, a white margin one tag wide), seen
//! through any map from image pixels to the target plane, antialiased by
//! supersampling each pixel.

use nalgebra::Vector2;

use super::tag36h11;
use super::target::AprilGridTarget;
use crate::chessboard::GreyImage;

/// Grey levels of the print and what is around the board.
#[derive(Debug, Clone, Copy)]
pub struct Shades {
    pub black: f32,
    pub white: f32,
    pub background: f32,
}

impl Default for Shades {
    fn default() -> Self {
        Self {
            black: 25.0,
            white: 215.0,
            background: 90.0,
        }
    }
}

/// What the print looks like at target point `(x, y)` (m, target frame):
/// `Some(true)` white, `Some(false)` black, `None` off the board.
pub fn is_white(target: &AprilGridTarget, x: f64, y: f64) -> Option<bool> {
    let s = target.tag_size_m;
    let gap = s * target.tag_spacing_ratio;
    let pitch = target.pitch_m();
    let (cols, rows) = (target.tag_cols as f64, target.tag_rows as f64);
    let on_board = |v: f64, n: f64| v >= -gap - s && v <= n * pitch + s;
    if !on_board(x, cols) || !on_board(y, rows) {
        return None;
    }
    // Corner squares: [c pitch - gap, c pitch] for c in 0..=n, both axes.
    let in_square_band = |v: f64, n: f64| {
        let f = (v + gap) / pitch;
        let c = f.floor();
        (0.0..=n).contains(&c) && (f - c) * pitch < gap
    };
    if in_square_band(x, cols) && in_square_band(y, rows) {
        return Some(false);
    }
    let (col, row) = ((x / pitch).floor(), (y / pitch).floor());
    let (lx, ly) = (x - col * pitch, y - row * pitch);
    if !(0.0..cols).contains(&col) || !(0.0..rows).contains(&row) || lx >= s || ly >= s {
        return Some(true);
    }
    let cell = s / 10.0;
    let u = (lx / cell).floor() as usize;
    let v = ((s - ly) / cell).floor() as usize; // cells counted from the tag's top (+y) edge
    if !(2..8).contains(&u) || !(2..8).contains(&v) {
        return Some(false);
    }
    let id = row as usize * target.tag_cols + col as usize;
    Some(tag36h11::cell_is_white(id, v - 2, u - 2).unwrap_or(false))
}

/// Renders a `width x height` image: `pixel_to_target` maps an image point
/// (px, pixel centres at integers) to the target point seen there (m), or
/// `None` where the ray misses the plane. Each pixel is the mean of
/// `supersample x supersample` evenly spread samples.
pub fn render_aprilgrid(
    target: &AprilGridTarget,
    width: usize,
    height: usize,
    supersample: usize,
    shades: Shades,
    pixel_to_target: impl Fn(Vector2<f64>) -> Option<Vector2<f64>>,
) -> GreyImage {
    let n = supersample.max(1);
    let mut pixels = vec![0.0f32; width * height];
    for y in 0..height {
        for x in 0..width {
            let mut sum = 0.0f32;
            for sy in 0..n {
                for sx in 0..n {
                    let p = Vector2::new(
                        x as f64 - 0.5 + (sx as f64 + 0.5) / n as f64,
                        y as f64 - 0.5 + (sy as f64 + 0.5) / n as f64,
                    );
                    sum += match pixel_to_target(p).and_then(|t| is_white(target, t.x, t.y)) {
                        Some(true) => shades.white,
                        Some(false) => shades.black,
                        None => shades.background,
                    };
                }
            }
            pixels[y * width + x] = sum / (n * n) as f32;
        }
    }
    GreyImage {
        width,
        height,
        pixels,
    }
}

/// Rounds to 8 bits, clamping to 0..255.
pub fn to_gray8(image: &GreyImage) -> image::GrayImage {
    let bytes = image
        .pixels
        .iter()
        .map(|v| v.round().clamp(0.0, 255.0) as u8)
        .collect();
    image::GrayImage::from_raw(image.width as u32, image.height as u32, bytes)
        .unwrap_or_else(|| image::GrayImage::new(0, 0))
}
