//! Each track's first patch, aligned into a keyframe to take back the
//! error the track gathered on its way.
//!
//! KLT follows a feature from frame to frame, so each frame's small error
//! (a few hundredths of a pixel) stays in the track: on the renderings a
//! track is 0.04 px from its surface point after one frame and 0.17-0.20
//! px after 64, and its error repeats from keyframe to keyframe (lag-1
//! correlation 0.72-0.78 over a whole track), which the window counts as
//! independent measurements (docs/results/track-error-2026-12-07.md).
//! The patch the track started from does not drift: aligned into a later
//! image by an affine warp with a gain and an offset, started at the
//! tracked position, it lands 0.04-0.05 px from the truth at every age.
//!
//! Model: `I(t + A x) = g P(x) + b` over the `PATCH_SIDE`² samples `x`
//! of the first patch `P` (offsets from its centre), solved for the
//! centre `t`, the warp `A`, the gain `g` and the offset `b` by inverse
//! compositional Gauss-Newton: each step is solved in the patch's own
//! frame (`g P(x + dA x + dt) + b` against the image sampled through the
//! current warp) and the current warp is composed with the step's
//! inverse. The patch's gradients and its normal matrix are computed
//! once, when it is captured; the gain enters the step's geometric
//! columns as a scale (`D H D` with `D = diag(g, .., g, 1, 1)`), so an
//! iteration costs one image sample and eight products per pixel. The
//! alignment is refused when it does not converge, leaves the image,
//! turns degenerate (`det A` outside [0.6, 1.6], gain outside [0.5, 2])
//! or leaves a residual over a quarter of the patch's own contrast: the
//! view has changed too much, and the track starts a new first patch
//! where it is.

use nalgebra::{SMatrix, SVector};

use crate::features::GreyImage;

/// Half the side of the patch, px.
pub const PATCH_HALF: usize = 10;
/// Side of the patch, px (21).
pub const PATCH_SIDE: usize = 2 * PATCH_HALF + 1;
const SAMPLES: usize = PATCH_SIDE * PATCH_SIDE;
const MAX_ITERATIONS: usize = 30;
/// Converged when the centre moves less than this, px ...
const CENTRE_STEP_PX: f64 = 1e-3;
/// ... and the warp's entries less than this.
const WARP_STEP: f64 = 1e-4;
/// Largest residual RMS against the patch's own standard deviation.
const MAX_RESIDUAL_SHARE: f64 = 0.25;

/// A track's first patch, what its alignment needs of it, and the warp
/// it was last aligned with.
#[derive(Debug, Clone)]
pub struct FirstPatch {
    samples: Vec<f32>,
    /// The patch's gradients along x and y at each sample.
    gradient_x: Vec<f32>,
    gradient_y: Vec<f32>,
    /// Inverse of the normal matrix at gain 1 (columns: the warp's four
    /// entries, the centre's two, gain, offset).
    normal_inverse: SMatrix<f64, 8, 8>,
    contrast: f64,
    /// Row-major 2x2 warp of the last alignment.
    warp: [f64; 4],
}

/// Offset of sample `k` from the patch's centre, px.
fn offset(k: usize) -> (f64, f64) {
    (
        (k % PATCH_SIDE) as f64 - PATCH_HALF as f64,
        (k / PATCH_SIDE) as f64 - PATCH_HALF as f64,
    )
}

impl FirstPatch {
    /// The patch centred on `centre` (None when it does not fit in the
    /// image or has no texture to align).
    pub fn capture(image: &GreyImage, centre: [f32; 2]) -> Option<Self> {
        let mut samples = Vec::with_capacity(SAMPLES);
        let mut gradient_x = Vec::with_capacity(SAMPLES);
        let mut gradient_y = Vec::with_capacity(SAMPLES);
        let mut normal = SMatrix::<f64, 8, 8>::zeros();
        for k in 0..SAMPLES {
            let (u, v) = offset(k);
            let (x, y) = (centre[0] + u as f32, centre[1] + v as f32);
            let p = bilinear(image, x, y)?;
            let gx = bilinear(image, x + 0.5, y)? - bilinear(image, x - 0.5, y)?;
            let gy = bilinear(image, x, y + 0.5)? - bilinear(image, x, y - 0.5)?;
            let (dx, dy) = (f64::from(gx), f64::from(gy));
            let row = SVector::<f64, 8>::from([
                dx * u,
                dx * v,
                dy * u,
                dy * v,
                dx,
                dy,
                f64::from(p),
                1.0,
            ]);
            normal += row * row.transpose();
            samples.push(p);
            gradient_x.push(gx);
            gradient_y.push(gy);
        }
        let n = SAMPLES as f64;
        let mean = samples.iter().map(|&s| f64::from(s)).sum::<f64>() / n;
        let contrast = (samples
            .iter()
            .map(|&s| (f64::from(s) - mean).powi(2))
            .sum::<f64>()
            / n)
            .sqrt();
        let normal_inverse = normal.cholesky()?.inverse();
        Some(Self {
            samples,
            gradient_x,
            gradient_y,
            normal_inverse,
            contrast,
            warp: [1.0, 0.0, 0.0, 1.0],
        })
    }

    /// Where the patch lies in `image`, searched from `start` with the
    /// warp of the last alignment; None when refused (module docs). The
    /// warp is kept for the next alignment only when this one succeeds.
    pub fn align(&mut self, image: &GreyImage, start: [f32; 2]) -> Option<[f32; 2]> {
        let mut a = self.warp;
        let mut t = [f64::from(start[0]), f64::from(start[1])];
        let (mut gain, mut offset_b) = (1.0f64, 0.0f64);
        let mut rms = f64::INFINITY;
        let mut converged = false;
        let half = PATCH_HALF as f64;
        for _ in 0..MAX_ITERATIONS {
            // An affine warp of the square lies inside the image when its
            // four corners do.
            let inside = [(-half, -half), (half, -half), (-half, half), (half, half)]
                .iter()
                .all(|&(u, v)| {
                    let x = t[0] + a[0] * u + a[1] * v;
                    let y = t[1] + a[2] * u + a[3] * v;
                    x >= 0.0
                        && y >= 0.0
                        && x + 1.0 < image.width as f64
                        && y + 1.0 < image.height as f64
                });
            if !inside {
                return None;
            }
            let mut sums = [0.0f64; 8];
            let mut squares = 0.0;
            for k in 0..SAMPLES {
                let (u, v) = offset(k);
                let x = (t[0] + a[0] * u + a[1] * v) as f32;
                let y = (t[1] + a[2] * u + a[3] * v) as f32;
                let value = f64::from(bilinear_inside(image, x, y));
                let p = f64::from(self.samples[k]);
                let e = value - (gain * p + offset_b);
                let (ex, ey) = (
                    f64::from(self.gradient_x[k]) * e,
                    f64::from(self.gradient_y[k]) * e,
                );
                sums[0] += ex * u;
                sums[1] += ex * v;
                sums[2] += ey * u;
                sums[3] += ey * v;
                sums[4] += ex;
                sums[5] += ey;
                sums[6] += p * e;
                sums[7] += e;
                squares += e * e;
            }
            rms = (squares / SAMPLES as f64).sqrt();
            // The step of `J d = e` with `J = J0 D`: `d = D^-1 H0^-1 J0' e`.
            let mut step = self.normal_inverse * SVector::<f64, 8>::from(sums);
            for entry in step.iter_mut().take(6) {
                *entry /= gain;
            }
            // Compose with the step's inverse: A' = A (I + dA)^-1,
            // t' = t - A' dt.
            let m = [1.0 + step[0], step[1], step[2], 1.0 + step[3]];
            let det_m = m[0] * m[3] - m[1] * m[2];
            if det_m.abs() < 1e-6 {
                return None;
            }
            let m_inv = [m[3] / det_m, -m[1] / det_m, -m[2] / det_m, m[0] / det_m];
            a = [
                a[0] * m_inv[0] + a[1] * m_inv[2],
                a[0] * m_inv[1] + a[1] * m_inv[3],
                a[2] * m_inv[0] + a[3] * m_inv[2],
                a[2] * m_inv[1] + a[3] * m_inv[3],
            ];
            let moved = [
                a[0] * step[4] + a[1] * step[5],
                a[2] * step[4] + a[3] * step[5],
            ];
            t[0] -= moved[0];
            t[1] -= moved[1];
            gain += step[6];
            offset_b += step[7];
            if moved[0].hypot(moved[1]) < CENTRE_STEP_PX
                && step.fixed_rows::<4>(0).norm() < WARP_STEP
            {
                converged = true;
                break;
            }
        }
        let det = a[0] * a[3] - a[1] * a[2];
        let accepted = converged
            && (0.6..=1.6).contains(&det)
            && (0.5..=2.0).contains(&gain)
            && rms <= MAX_RESIDUAL_SHARE * self.contrast
            && t.iter().all(|v| v.is_finite());
        if !accepted {
            return None;
        }
        self.warp = a;
        Some([t[0] as f32, t[1] as f32])
    }
}

/// Bilinear sample at a point known to lie inside the image (its pixel
/// and the next row and column exist). The caller checks the patch's
/// corners in f64; a sample rounded to f32 may land on the last column
/// or row, so the cell is clamped to the last one inside (the sample is
/// then its far corner, fraction 1: the same value).
#[inline]
fn bilinear_inside(image: &GreyImage, x: f32, y: f32) -> f32 {
    let ix = (x as usize).min(image.width - 2);
    let iy = (y as usize).min(image.height - 2);
    let (fx, fy) = (x - ix as f32, y - iy as f32);
    let w = image.width;
    let d = &image.data[iy * w + ix..];
    let at = |k: usize| f32::from(d[k]);
    let top = at(0) + (at(1) - at(0)) * fx;
    let bottom = at(w) + (at(w + 1) - at(w)) * fx;
    top + (bottom - top) * fy
}

/// Bilinear sample at `(x, y)` (pixel centres at integer coordinates, as
/// the KLT windows); None outside the image.
fn bilinear(image: &GreyImage, x: f32, y: f32) -> Option<f32> {
    if !(x >= 0.0 && y >= 0.0) {
        return None;
    }
    let (ix, iy) = (x.floor() as usize, y.floor() as usize);
    if ix + 1 >= image.width || iy + 1 >= image.height {
        return None;
    }
    let (fx, fy) = (x - ix as f32, y - iy as f32);
    let w = image.width;
    let d = &image.data;
    let at = |k: usize| f32::from(d[k]);
    let top = at(iy * w + ix) * (1.0 - fx) + at(iy * w + ix + 1) * fx;
    let bottom = at((iy + 1) * w + ix) * (1.0 - fx) + at((iy + 1) * w + ix + 1) * fx;
    Some(top * (1.0 - fy) + bottom * fy)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A smooth texture with corners at every scale: `f(x, y)`.
    fn texture(x: f64, y: f64) -> f64 {
        128.0
            + 50.0 * (0.31 * x + 0.17 * y).sin() * (0.23 * y - 0.11 * x).cos()
            + 30.0 * (0.07 * x * 1.3 + 0.05 * y).sin()
            + 20.0 * (0.41 * y).cos() * (0.37 * x).sin()
    }

    /// `image(q) = gain * f(A^-1 (q - c)) + offset`: the texture moved so
    /// that its point at the origin lies at `c`, warped by `A`.
    fn render(c: [f64; 2], a: [f64; 4], gain: f64, offset: f64) -> GreyImage {
        let (w, h) = (160, 120);
        let det = a[0] * a[3] - a[1] * a[2];
        let inv = [a[3] / det, -a[1] / det, -a[2] / det, a[0] / det];
        let mut data = Vec::with_capacity(w * h);
        for y in 0..h {
            for x in 0..w {
                let (dx, dy) = (x as f64 - c[0], y as f64 - c[1]);
                let (u, v) = (inv[0] * dx + inv[1] * dy, inv[2] * dx + inv[3] * dy);
                data.push((gain * texture(u, v) + offset).round().clamp(0.0, 255.0) as u8);
            }
        }
        GreyImage::from_vec(w, h, data).expect("size")
    }

    #[test]
    fn a_warped_brighter_view_is_found_to_two_hundredths_of_a_pixel() {
        let first = render([70.0, 60.0], [1.0, 0.0, 0.0, 1.0], 1.0, 0.0);
        let mut patch = FirstPatch::capture(&first, [70.0, 60.0]).expect("inside");
        // Turned by 6 degrees, 5 % larger, brighter, and moved.
        let (c, s) = (
            6f64.to_radians().cos() * 1.05,
            6f64.to_radians().sin() * 1.05,
        );
        let truth = [83.37, 52.81];
        let later = render(truth, [c, -s, s, c], 1.15, -12.0);
        let found = patch.align(&later, [83.0, 53.3]).expect("aligned");
        let error = (f64::from(found[0]) - truth[0]).hypot(f64::from(found[1]) - truth[1]);
        // What is left is bilinear interpolation of a grey-level image
        // turned under the patch (0.014 px here).
        assert!(error < 0.02, "found {found:?}, truth {truth:?}: {error} px");
    }

    #[test]
    fn a_view_that_is_not_the_patch_is_refused() {
        let first = render([70.0, 60.0], [1.0, 0.0, 0.0, 1.0], 1.0, 0.0);
        let mut patch = FirstPatch::capture(&first, [70.0, 60.0]).expect("inside");
        // Another part of the texture.
        let other = render([20.0, 20.0], [1.0, 0.0, 0.0, 1.0], 1.0, 0.0);
        assert_eq!(patch.align(&other, [70.0, 60.0]), None);
        // A flat image has nothing to align.
        let flat = GreyImage::filled(160, 120, 90);
        assert_eq!(patch.align(&flat, [70.0, 60.0]), None);
    }

    #[test]
    fn a_patch_at_the_border_is_not_captured_and_not_searched_outside() {
        let image = render([70.0, 60.0], [1.0, 0.0, 0.0, 1.0], 1.0, 0.0);
        assert!(FirstPatch::capture(&image, [5.0, 60.0]).is_none());
        assert!(FirstPatch::capture(&image, [f32::NAN, 60.0]).is_none());
        let mut patch = FirstPatch::capture(&image, [70.0, 60.0]).expect("inside");
        assert_eq!(patch.align(&image, [155.0, 60.0]), None);
    }

    #[test]
    fn a_patch_whose_corner_rounds_onto_the_last_row_is_sampled_inside() {
        // The corners pass the check in f64 (just inside the last row);
        // the bottom row of samples rounds onto it in f32.
        let image = render([70.0, 60.0], [1.0, 0.0, 0.0, 1.0], 1.0, 0.0);
        let mut patch = FirstPatch::capture(&image, [70.0, 60.0]).expect("inside");
        patch.warp = [1.0, 0.0, 0.0, 1.0 - 1e-9];
        let last_centre = (image.height - 1 - PATCH_HALF) as f32;
        // Any answer will do; reading past the image would panic.
        let _ = patch.align(&image, [70.0, last_centre]);
    }
}
