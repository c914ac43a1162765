//! Procedural, seeded, world-anchored surface textures with mipmaps.
//!
//! Each planar surface of the scene owns one texture covering it at a fixed
//! texel size in metres, so a point of the world looks the same from every
//! view. The base level is multi-octave value noise plus random shapes
//! (rotated rectangles, discs, thick line segments) drawn with analytic
//! coverage; shapes give corners a tracker holds on to, noise gives
//! texture between them. Nothing repeats: every octave lattice value and
//! every shape comes from a hash of the surface's own seed. Lower levels
//! are 2x2 box filters, and the renderer samples them trilinearly by the
//! pixel footprint, which band-limits the image (Williams 1983, "Pyramidal
//! parametrics").

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// One mip level: grey texels, row-major.
#[derive(Debug, Clone)]
struct Level {
    width: usize,
    height: usize,
    texels: Vec<u8>,
}

/// A mipmapped grey texture over a rectangle of a plane.
#[derive(Debug, Clone)]
pub struct Texture {
    levels: Vec<Level>,
    /// Edge of one base-level texel, m.
    texel_m: f32,
    inv_texel_m: f32,
}

/// Octaves of value noise: (wavelength m, amplitude in grey levels).
const NOISE_OCTAVES: [(f32, f32); 5] = [
    (0.7, 38.0),
    (0.28, 30.0),
    (0.11, 24.0),
    (0.045, 18.0),
    (0.018, 10.0),
];
/// Shapes per square metre of surface.
const SHAPES_PER_M2: f32 = 70.0;
/// Size range of shapes (half extent), m; drawn log-uniformly.
const SHAPE_HALF_SIZE_M: (f32, f32) = (0.008, 0.12);

impl Texture {
    /// A texture of one grey level everywhere (test scenes, flat colours).
    pub fn flat(grey: u8) -> Self {
        Self {
            levels: vec![Level {
                width: 1,
                height: 1,
                texels: vec![grey],
            }],
            texel_m: 1.0,
            inv_texel_m: 1.0,
        }
    }

    /// Generates a texture covering `width_m` x `height_m` from `seed`.
    pub fn generate(width_m: f32, height_m: f32, texel_m: f32, seed: u64) -> Self {
        let width = (width_m / texel_m).ceil().max(1.0) as usize + 1;
        let height = (height_m / texel_m).ceil().max(1.0) as usize + 1;
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut values = vec![0f32; width * height];
        let octave_seeds: Vec<u64> = NOISE_OCTAVES.iter().map(|_| rng.gen()).collect();
        // Surfaces differ in mean brightness and contrast so that they are
        // told apart, but all keep enough contrast for corners.
        let mean = rng.gen_range(95.0..160.0f32);
        let contrast = rng.gen_range(0.8..1.2f32);
        for y in 0..height {
            let v_m = (y as f32 + 0.5) * texel_m;
            for x in 0..width {
                let u_m = (x as f32 + 0.5) * texel_m;
                let mut value = mean;
                for (&(wavelength_m, amplitude), &s) in NOISE_OCTAVES.iter().zip(&octave_seeds) {
                    let n = value_noise(u_m / wavelength_m, v_m / wavelength_m, s);
                    value += contrast * amplitude * (2.0 * n - 1.0);
                }
                values[y * width + x] = value;
            }
        }
        let shape_count = (width_m * height_m * SHAPES_PER_M2).round() as usize;
        for _ in 0..shape_count {
            let shape = Shape::random(&mut rng, width_m, height_m);
            shape.paint(&mut values, width, height, texel_m);
        }
        let base = Level {
            width,
            height,
            texels: values
                .iter()
                .map(|v| v.round().clamp(0.0, 255.0) as u8)
                .collect(),
        };
        let mut levels = vec![base];
        while let Some(next) = levels.last().and_then(downsample) {
            levels.push(next);
        }
        Self {
            levels,
            texel_m,
            inv_texel_m: 1.0 / texel_m,
        }
    }

    /// Number of mip levels.
    pub fn level_count(&self) -> usize {
        self.levels.len()
    }

    /// Grey value at plane coordinates (`u_m`, `v_m`) relative to the
    /// texture's corner, for a pixel footprint of `footprint_m`: trilinear
    /// between the two mip levels bracketing the footprint.
    #[inline]
    pub fn sample(&self, u_m: f32, v_m: f32, footprint_m: f32) -> f32 {
        let lod = fast_log2(footprint_m * self.inv_texel_m);
        let max_level = (self.levels.len() - 1) as f32;
        if lod <= 0.0 {
            return self.bilinear(0, u_m, v_m);
        }
        if lod >= max_level {
            return self.bilinear(self.levels.len() - 1, u_m, v_m);
        }
        let l0 = lod as usize;
        let frac = lod - l0 as f32;
        let a = self.bilinear(l0, u_m, v_m);
        let b = self.bilinear(l0 + 1, u_m, v_m);
        a + (b - a) * frac
    }

    #[inline]
    fn bilinear(&self, level: usize, u_m: f32, v_m: f32) -> f32 {
        let l = &self.levels[level];
        let scale = self.inv_texel_m / (1u32 << level) as f32;
        let x = (u_m * scale - 0.5).clamp(0.0, (l.width - 1) as f32);
        let y = (v_m * scale - 0.5).clamp(0.0, (l.height - 1) as f32);
        let x0 = x as usize;
        let y0 = y as usize;
        let x1 = (x0 + 1).min(l.width - 1);
        let y1 = (y0 + 1).min(l.height - 1);
        let fx = x - x0 as f32;
        let fy = y - y0 as f32;
        let row0 = y0 * l.width;
        let row1 = y1 * l.width;
        let t = &l.texels;
        let top = t[row0 + x0] as f32 + (t[row0 + x1] as f32 - t[row0 + x0] as f32) * fx;
        let bottom = t[row1 + x0] as f32 + (t[row1 + x1] as f32 - t[row1 + x0] as f32) * fx;
        top + (bottom - top) * fy
    }

    /// Edge of one base-level texel, m.
    pub fn texel_m(&self) -> f32 {
        self.texel_m
    }
}

/// The next mip level by 2x2 box filtering; `None` once a side is 1.
fn downsample(level: &Level) -> Option<Level> {
    if level.width <= 1 || level.height <= 1 {
        return None;
    }
    let width = level.width.div_ceil(2);
    let height = level.height.div_ceil(2);
    let mut texels = vec![0u8; width * height];
    for y in 0..height {
        let ya = (2 * y).min(level.height - 1);
        let yb = (2 * y + 1).min(level.height - 1);
        for x in 0..width {
            let xa = (2 * x).min(level.width - 1);
            let xb = (2 * x + 1).min(level.width - 1);
            let sum = level.texels[ya * level.width + xa] as u32
                + level.texels[ya * level.width + xb] as u32
                + level.texels[yb * level.width + xa] as u32
                + level.texels[yb * level.width + xb] as u32;
            texels[y * width + x] = ((sum + 2) / 4) as u8;
        }
    }
    Some(Level {
        width,
        height,
        texels,
    })
}

/// A shape painted onto the base level with analytic coverage.
enum Shape {
    /// Rotated rectangle: centre, half extents, angle.
    Rect {
        centre: [f32; 2],
        half: [f32; 2],
        cos_sin: [f32; 2],
        grey: f32,
    },
    Disc {
        centre: [f32; 2],
        radius: f32,
        grey: f32,
    },
    /// Thick segment from `a` to `b`.
    Line {
        a: [f32; 2],
        b: [f32; 2],
        half_width: f32,
        grey: f32,
    },
}

impl Shape {
    fn random(rng: &mut ChaCha8Rng, width_m: f32, height_m: f32) -> Self {
        let centre = [rng.gen_range(0.0..width_m), rng.gen_range(0.0..height_m)];
        let (lo, hi) = SHAPE_HALF_SIZE_M;
        let size = lo * (hi / lo).powf(rng.gen::<f32>());
        // Dark or bright, rarely mid-grey: strong edges.
        let grey = if rng.gen_bool(0.5) {
            rng.gen_range(0.0..70.0)
        } else {
            rng.gen_range(185.0..255.0)
        };
        match rng.gen_range(0..10) {
            0..=4 => {
                let angle = rng.gen_range(0.0..std::f32::consts::PI);
                Shape::Rect {
                    centre,
                    half: [size, size * rng.gen_range(0.3..1.0f32)],
                    cos_sin: [angle.cos(), angle.sin()],
                    grey,
                }
            }
            5..=7 => Shape::Disc {
                centre,
                radius: size * 0.7,
                grey,
            },
            _ => {
                let angle = rng.gen_range(0.0..std::f32::consts::TAU);
                let length = size * 3.0;
                Shape::Line {
                    a: centre,
                    b: [
                        centre[0] + length * angle.cos(),
                        centre[1] + length * angle.sin(),
                    ],
                    half_width: (size * 0.08).max(0.003),
                    grey,
                }
            }
        }
    }

    /// Signed distance from a plane point to the shape's outline (negative inside), m.
    fn signed_distance(&self, p: [f32; 2]) -> f32 {
        match *self {
            Shape::Rect {
                centre,
                half,
                cos_sin: [c, s],
                ..
            } => {
                let dx = p[0] - centre[0];
                let dy = p[1] - centre[1];
                let lx = (c * dx + s * dy).abs() - half[0];
                let ly = (-s * dx + c * dy).abs() - half[1];
                let outside = (lx.max(0.0).powi(2) + ly.max(0.0).powi(2)).sqrt();
                outside + lx.max(ly).min(0.0)
            }
            Shape::Disc { centre, radius, .. } => {
                ((p[0] - centre[0]).powi(2) + (p[1] - centre[1]).powi(2)).sqrt() - radius
            }
            Shape::Line {
                a, b, half_width, ..
            } => {
                let ab = [b[0] - a[0], b[1] - a[1]];
                let ap = [p[0] - a[0], p[1] - a[1]];
                let len2 = ab[0] * ab[0] + ab[1] * ab[1];
                let t = ((ap[0] * ab[0] + ap[1] * ab[1]) / len2).clamp(0.0, 1.0);
                let d = [ap[0] - t * ab[0], ap[1] - t * ab[1]];
                (d[0] * d[0] + d[1] * d[1]).sqrt() - half_width
            }
        }
    }

    /// Bounding box (min, max) in metres.
    fn bounds(&self) -> ([f32; 2], [f32; 2]) {
        match *self {
            Shape::Rect { centre, half, .. } => {
                let r = (half[0] * half[0] + half[1] * half[1]).sqrt();
                (
                    [centre[0] - r, centre[1] - r],
                    [centre[0] + r, centre[1] + r],
                )
            }
            Shape::Disc { centre, radius, .. } => (
                [centre[0] - radius, centre[1] - radius],
                [centre[0] + radius, centre[1] + radius],
            ),
            Shape::Line {
                a, b, half_width, ..
            } => (
                [a[0].min(b[0]) - half_width, a[1].min(b[1]) - half_width],
                [a[0].max(b[0]) + half_width, a[1].max(b[1]) + half_width],
            ),
        }
    }

    fn grey(&self) -> f32 {
        match *self {
            Shape::Rect { grey, .. } | Shape::Disc { grey, .. } | Shape::Line { grey, .. } => grey,
        }
    }

    /// Blends the shape over `values` with coverage from the signed distance
    /// (a one-texel ramp across the outline: anti-aliased edges).
    fn paint(&self, values: &mut [f32], width: usize, height: usize, texel_m: f32) {
        let (lo, hi) = self.bounds();
        let x0 = ((lo[0] / texel_m).floor() as isize - 1).max(0) as usize;
        let y0 = ((lo[1] / texel_m).floor() as isize - 1).max(0) as usize;
        let x1 = (((hi[0] / texel_m).ceil() as isize + 1).max(0) as usize).min(width);
        let y1 = (((hi[1] / texel_m).ceil() as isize + 1).max(0) as usize).min(height);
        let grey = self.grey();
        for y in y0..y1 {
            for x in x0..x1 {
                let p = [(x as f32 + 0.5) * texel_m, (y as f32 + 0.5) * texel_m];
                let coverage = (0.5 - self.signed_distance(p) / texel_m).clamp(0.0, 1.0);
                if coverage > 0.0 {
                    let v = &mut values[y * width + x];
                    *v += (grey - *v) * coverage;
                }
            }
        }
    }
}

/// A 64-bit mix (splitmix64 finaliser) of a lattice point and a seed.
#[inline]
pub(crate) fn hash3(a: u64, b: u64, seed: u64) -> u64 {
    let mut z =
        seed ^ a.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ b.wrapping_mul(0xC2B2_AE3D_27D4_EB4F);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

#[inline]
fn lattice(ix: i64, iy: i64, seed: u64) -> f32 {
    (hash3(ix as u64, iy as u64, seed) >> 40) as f32 * (1.0 / (1u64 << 24) as f32)
}

/// Value noise in [0, 1): lattice values blended with a quintic fade
/// (Perlin 2002, "Improving noise"), so it is C2 and band-limited to about
/// one cycle per lattice cell.
fn value_noise(x: f32, y: f32, seed: u64) -> f32 {
    let fx = x.floor();
    let fy = y.floor();
    let ix = fx as i64;
    let iy = fy as i64;
    let tx = x - fx;
    let ty = y - fy;
    let sx = tx * tx * tx * (tx * (tx * 6.0 - 15.0) + 10.0);
    let sy = ty * ty * ty * (ty * (ty * 6.0 - 15.0) + 10.0);
    let a = lattice(ix, iy, seed);
    let b = lattice(ix + 1, iy, seed);
    let c = lattice(ix, iy + 1, seed);
    let d = lattice(ix + 1, iy + 1, seed);
    let top = a + (b - a) * sx;
    let bottom = c + (d - c) * sx;
    top + (bottom - top) * sy
}

/// log2 from the float's exponent and a quadratic on its mantissa; exact at
/// powers of two, continuous and monotonic, within 0.01 of `f32::log2`.
/// Used only to pick mip levels.
#[inline]
pub(crate) fn fast_log2(x: f32) -> f32 {
    if x <= 0.0 {
        return f32::NEG_INFINITY;
    }
    let bits = x.to_bits();
    let exponent = ((bits >> 23) & 0xff) as i32 - 127;
    let m = f32::from_bits((bits & 0x007f_ffff) | 0x3f80_0000) - 1.0;
    exponent as f32 + m * (1.3466 - 0.3466 * m)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fast_log2_tracks_log2() {
        for i in 1..2000 {
            let x = i as f32 * 0.0137;
            assert!((fast_log2(x) - x.log2()).abs() < 0.01, "x = {x}");
        }
    }

    #[test]
    fn same_seed_same_texture_other_seed_differs() {
        let a = Texture::generate(0.5, 0.4, 0.005, 7);
        let b = Texture::generate(0.5, 0.4, 0.005, 7);
        let c = Texture::generate(0.5, 0.4, 0.005, 8);
        assert_eq!(a.levels[0].texels, b.levels[0].texels);
        assert_ne!(a.levels[0].texels, c.levels[0].texels);
    }

    #[test]
    fn mip_levels_preserve_mean() {
        let t = Texture::generate(1.0, 1.0, 0.005, 3);
        let mean =
            |l: &Level| l.texels.iter().map(|&v| v as f64).sum::<f64>() / l.texels.len() as f64;
        let m0 = mean(&t.levels[0]);
        let m3 = mean(&t.levels[3]);
        assert!((m0 - m3).abs() < 2.0, "{m0} vs {m3}");
        assert!(t.level_count() >= 7);
    }
}
