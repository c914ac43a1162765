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

#[cfg(target_arch = "x86_64")]
use crate::features::gathered_corners::gathered_corners;
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
/// Each sample's offset from the patch's centre along x, px ...
const OFFSET_U: [f64; SAMPLES] = offsets(0);
/// ... and along y.
const OFFSET_V: [f64; SAMPLES] = offsets(1);

/// The samples' offsets from the centre along x (`axis` 0) or y (1).
const fn offsets(axis: usize) -> [f64; SAMPLES] {
    let mut out = [0.0; SAMPLES];
    let mut k = 0;
    while k < SAMPLES {
        let index = if axis == 0 {
            k % PATCH_SIDE
        } else {
            k / PATCH_SIDE
        };
        out[k] = index as f64 - PATCH_HALF as f64;
        k += 1;
    }
    out
}

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

impl FirstPatch {
    /// The patch centred on `centre` (None when it does not fit in the
    /// image or has no texture to align).
    pub fn capture(image: &GreyImage, centre: [f32; 2]) -> Option<Self> {
        let mut samples = Vec::with_capacity(SAMPLES);
        let mut gradient_x = Vec::with_capacity(SAMPLES);
        let mut gradient_y = Vec::with_capacity(SAMPLES);
        let mut normal = SMatrix::<f64, 8, 8>::zeros();
        let mut gathered = [[0.0f32; SAMPLES]; 3];
        let mut from = 0;
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") && patch_fits(image, centre) {
            // SAFETY: the CPU has AVX2 (checked just above) and every
            // sample with its gradient's neighbours lies inside the image.
            from = unsafe { patch_samples_avx2(image, centre, &mut gathered) };
        }
        for k in 0..SAMPLES {
            let (u, v) = (OFFSET_U[k], OFFSET_V[k]);
            let (p, gx, gy) = if k < from {
                (gathered[0][k], gathered[1][k], gathered[2][k])
            } else {
                let (x, y) = (centre[0] + u as f32, centre[1] + v as f32);
                let p = bilinear(image, x, y)?;
                let gx = bilinear(image, x + 0.5, y)? - bilinear(image, x - 0.5, y)?;
                let gy = bilinear(image, x, y + 0.5)? - bilinear(image, x, y - 0.5)?;
                (p, gx, gy)
            };
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
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma")
        {
            // SAFETY: the CPU has AVX2 and FMA, checked just above.
            return unsafe { self.align_avx2(image, start) };
        }
        self.align_generic(image, start, false)
    }

    /// [`Self::align`] compiled for AVX2 + FMA, sampling with gathers.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    unsafe fn align_avx2(&mut self, image: &GreyImage, start: [f32; 2]) -> Option<[f32; 2]> {
        self.align_generic(image, start, true)
    }

    /// The alignment; `gathers`: sample the warped patch eight at a time
    /// ([`warped_samples_avx2`], only when the CPU has AVX2).
    #[inline(always)]
    fn align_generic(
        &mut self,
        image: &GreyImage,
        start: [f32; 2],
        gathers: bool,
    ) -> Option<[f32; 2]> {
        let mut a = self.warp;
        let mut t = [f64::from(start[0]), f64::from(start[1])];
        let (mut gain, mut offset_b) = (1.0f64, 0.0f64);
        let mut rms = f64::INFINITY;
        let mut converged = false;
        let half = PATCH_HALF as f64;
        let mut values = [0.0f32; SAMPLES];
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
            // The warped samples first, eight at a time with gathers
            // where the CPU has AVX2 (the same bits as one by one).
            let mut from = 0;
            #[cfg(target_arch = "x86_64")]
            if gathers {
                // SAFETY: `gathers` is set only when the CPU has AVX2.
                from = unsafe { warped_samples_avx2(image, t, &a, &mut values) };
            }
            for (k, value) in values.iter_mut().enumerate().skip(from) {
                let (u, v) = (OFFSET_U[k], OFFSET_V[k]);
                let x = (t[0] + a[0] * u + a[1] * v) as f32;
                let y = (t[1] + a[2] * u + a[3] * v) as f32;
                *value = bilinear_inside(image, x, y);
            }
            // Summed one sample after the other, whichever way sampled.
            let mut sums = [0.0f64; 8];
            let mut squares = 0.0;
            for (k, &value) in values.iter().enumerate() {
                let (u, v) = (OFFSET_U[k], OFFSET_V[k]);
                let value = f64::from(value);
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

/// The patch's samples warped by `(t, a)`, eight at a time, each as
/// [`bilinear_inside`] computes it (places in f64, rounded to f32, the cell
/// clamped to the last inside). Returns how many it wrote, from the first:
/// it stops before the last few samples (fewer than eight) and before
/// eight whose reads would pass the image's last bytes; the caller
/// samples the rest. The patch's corners must lie inside the image.
///
/// # Safety
/// The CPU must have AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn warped_samples_avx2(
    image: &GreyImage,
    t: [f64; 2],
    a: &[f64; 4],
    values: &mut [f32; SAMPLES],
) -> usize {
    use std::arch::x86_64::*;
    let place = |origin: f64, along_u: f64, along_v: f64, k: usize| {
        // origin + along_u u + along_v v in f64, as the scalar path, for
        // samples k..k + 8, rounded to f32.
        let half = |k: usize| {
            let u = _mm256_loadu_pd(OFFSET_U[k..k + 4].as_ptr());
            let v = _mm256_loadu_pd(OFFSET_V[k..k + 4].as_ptr());
            let sum = _mm256_add_pd(
                _mm256_add_pd(
                    _mm256_set1_pd(origin),
                    _mm256_mul_pd(_mm256_set1_pd(along_u), u),
                ),
                _mm256_mul_pd(_mm256_set1_pd(along_v), v),
            );
            _mm256_cvtpd_ps(sum)
        };
        _mm256_set_m128(half(k + 4), half(k))
    };
    let last_x = _mm256_set1_epi32(image.width as i32 - 2);
    let last_y = _mm256_set1_epi32(image.height as i32 - 2);
    let stride = _mm256_set1_epi32(image.width as i32);
    let mut done = 0;
    while done + 8 <= SAMPLES {
        let x = place(t[0], a[0], a[1], done);
        let y = place(t[1], a[2], a[3], done);
        let ix = _mm256_min_epi32(_mm256_cvttps_epi32(x), last_x);
        let iy = _mm256_min_epi32(_mm256_cvttps_epi32(y), last_y);
        let fx = _mm256_sub_ps(x, _mm256_cvtepi32_ps(ix));
        let fy = _mm256_sub_ps(y, _mm256_cvtepi32_ps(iy));
        let offsets = _mm256_add_epi32(_mm256_mullo_epi32(iy, stride), ix);
        // SAFETY: AVX2 is on; the offsets are of pixels inside the image.
        let Some([d0, d1, d2, d3]) =
            (unsafe { gathered_corners(&image.data, image.width, offsets) })
        else {
            break;
        };
        let top = _mm256_add_ps(d0, _mm256_mul_ps(_mm256_sub_ps(d1, d0), fx));
        let bottom = _mm256_add_ps(d2, _mm256_mul_ps(_mm256_sub_ps(d3, d2), fx));
        let value = _mm256_add_ps(top, _mm256_mul_ps(_mm256_sub_ps(bottom, top), fy));
        _mm256_storeu_ps(values[done..done + 8].as_mut_ptr(), value);
        done += 8;
    }
    done
}

/// Whether every sample of the patch centred on `centre`, with the
/// neighbours its gradient takes half a pixel either side, has its
/// bilinear cell inside the image (what [`bilinear`] checks, computed for
/// the outermost samples: the places grow with the offsets, and so does
/// their rounding).
fn patch_fits(image: &GreyImage, centre: [f32; 2]) -> bool {
    let half = PATCH_HALF as f32;
    let cell = |c: f32, size: usize| {
        let (low, high) = ((c - half) - 0.5, (c + half) + 0.5);
        low >= 0.0 && (high.floor() as usize) + 1 < size
    };
    cell(centre[0], image.width) && cell(centre[1], image.height)
}

/// The patch centred on `centre` eight samples at a time: its grey levels
/// and its gradients (the bilinear samples half a pixel either side), each
/// as [`bilinear`] computes it. Returns how many it wrote, from the first
/// (it stops before the last few and before eight whose reads would pass
/// the image's last bytes; the caller samples the rest).
///
/// # Safety
/// The CPU must have AVX2, and [`patch_fits`] must hold.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn patch_samples_avx2(
    image: &GreyImage,
    centre: [f32; 2],
    out: &mut [[f32; SAMPLES]; 3],
) -> usize {
    use std::arch::x86_64::*;
    let stride = _mm256_set1_epi32(image.width as i32);
    let one = _mm256_set1_ps(1.0);
    // `bilinear` at (x, y): the cell's floor, its fractions, the four
    // levels around it, weighed as the scalar code weighs them; None when
    // a gather would pass the image's last bytes.
    let sample = |x: __m256, y: __m256| {
        let (fx0, fy0) = (_mm256_floor_ps(x), _mm256_floor_ps(y));
        let (ix, iy) = (_mm256_cvttps_epi32(fx0), _mm256_cvttps_epi32(fy0));
        let fx = _mm256_sub_ps(x, _mm256_cvtepi32_ps(ix));
        let fy = _mm256_sub_ps(y, _mm256_cvtepi32_ps(iy));
        let offsets = _mm256_add_epi32(_mm256_mullo_epi32(iy, stride), ix);
        // SAFETY: AVX2 is on; the offsets are of cells inside the image.
        let [d0, d1, d2, d3] = unsafe { gathered_corners(&image.data, image.width, offsets) }?;
        let (gx, gy) = (_mm256_sub_ps(one, fx), _mm256_sub_ps(one, fy));
        let top = _mm256_add_ps(_mm256_mul_ps(d0, gx), _mm256_mul_ps(d1, fx));
        let bottom = _mm256_add_ps(_mm256_mul_ps(d2, gx), _mm256_mul_ps(d3, fx));
        Some(_mm256_add_ps(
            _mm256_mul_ps(top, gy),
            _mm256_mul_ps(bottom, fy),
        ))
    };
    let half_px = _mm256_set1_ps(0.5);
    let mut done = 0;
    while done + 8 <= SAMPLES {
        let offset = |table: &[f64; SAMPLES]| {
            let mut lanes = [0f32; 8];
            for (lane, &o) in lanes.iter_mut().zip(&table[done..done + 8]) {
                *lane = o as f32;
            }
            _mm256_loadu_ps(lanes.as_ptr())
        };
        let x = _mm256_add_ps(_mm256_set1_ps(centre[0]), offset(&OFFSET_U));
        let y = _mm256_add_ps(_mm256_set1_ps(centre[1]), offset(&OFFSET_V));
        let values = (|| {
            let p = sample(x, y)?;
            let right = sample(_mm256_add_ps(x, half_px), y)?;
            let left = sample(_mm256_sub_ps(x, half_px), y)?;
            let below = sample(x, _mm256_add_ps(y, half_px))?;
            let above = sample(x, _mm256_sub_ps(y, half_px))?;
            Some((p, _mm256_sub_ps(right, left), _mm256_sub_ps(below, above)))
        })();
        let Some((p, gx, gy)) = values else {
            break;
        };
        _mm256_storeu_ps(out[0][done..done + 8].as_mut_ptr(), p);
        _mm256_storeu_ps(out[1][done..done + 8].as_mut_ptr(), gx);
        _mm256_storeu_ps(out[2][done..done + 8].as_mut_ptr(), gy);
        done += 8;
    }
    done
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

    /// Uniform numbers in [0, 1) from a xorshift generator seeded with `seed`.
    fn uniform(seed: u64) -> impl FnMut() -> f64 {
        let mut z = seed;
        move || {
            z ^= z << 13;
            z ^= z >> 7;
            z ^= z << 17;
            (z >> 11) as f64 / (1u64 << 53) as f64
        }
    }

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

    #[cfg(target_arch = "x86_64")]
    #[test]
    fn the_gathered_samples_are_the_scalar_ones_to_the_bit() {
        if !std::arch::is_x86_feature_detected!("avx2") {
            return;
        }
        let image = render([70.0, 60.0], [1.0, 0.0, 0.0, 1.0], 1.0, 0.0);
        let mut next = uniform(0x2545_F491_4F6C_DD1D);
        let half = PATCH_HALF as f64;
        let (mut gathered, mut short) = (0usize, 0usize);
        for k in 0..2000 {
            let a = [
                0.8 + 0.4 * next(),
                0.1 * (next() - 0.5),
                0.1 * (next() - 0.5),
                0.8 + 0.4 * next(),
            ];
            // Centres anywhere the warped patch's corners stay inside;
            // one in four with its bottom-right corner a hair inside the
            // image's last pixel.
            let reach = (a[0].abs() + a[1].abs()).max(a[2].abs() + a[3].abs()) * half;
            let (w, h) = (image.width as f64 - 1.0, image.height as f64 - 1.0);
            let t = if k % 4 == 0 {
                [
                    w - 1e-9 - (a[0] + a[1]) * half,
                    h - 1e-9 - (a[2] + a[3]) * half,
                ]
            } else {
                [
                    reach + (w - 2.0 * reach - 1e-9) * next(),
                    reach + (h - 2.0 * reach - 1e-9) * next(),
                ]
            };
            let mut values = [f32::NAN; SAMPLES];
            // SAFETY: AVX2 checked above.
            let done = unsafe { warped_samples_avx2(&image, t, &a, &mut values) };
            assert!(SAMPLES - done < 8 || done % 8 == 0);
            for (k, value) in values.iter().enumerate().take(done) {
                let (u, v) = (OFFSET_U[k], OFFSET_V[k]);
                let x = (t[0] + a[0] * u + a[1] * v) as f32;
                let y = (t[1] + a[2] * u + a[3] * v) as f32;
                assert_eq!(
                    value.to_bits(),
                    bilinear_inside(&image, x, y).to_bits(),
                    "sample {k}"
                );
            }
            gathered += done;
            short += usize::from(SAMPLES - done >= 8);
        }
        // Most patches are gathered whole; some end near the image's last
        // bytes, where the gathers stop early.
        assert!(
            gathered > 2000 * (SAMPLES - 8) * 9 / 10,
            "{gathered} samples gathered"
        );
        assert!(short > 0, "no patch reached the image's end");
    }

    #[cfg(target_arch = "x86_64")]
    #[test]
    fn a_gathered_capture_is_the_scalar_one_to_the_bit() {
        if !std::arch::is_x86_feature_detected!("avx2") {
            return;
        }
        let image = render([70.0, 60.0], [1.0, 0.0, 0.0, 1.0], 1.0, 0.0);
        let mut draw = uniform(0x9E37_79B9_7F4A_7C15);
        let mut next = || draw() as f32;
        let (w, h) = (image.width as f32, image.height as f32);
        let (mut fits, mut short) = (0, 0);
        for k in 0..3000 {
            // Anywhere, the borders included (a third of the centres
            // within two pixels of the right or bottom edge's limit).
            let centre = match k % 3 {
                0 => [w * next(), h * next()],
                1 => [w - 11.5 - 2.0 * next(), h * next()],
                _ => [w * next(), h - 11.5 - 2.0 * next()],
            };
            if !patch_fits(&image, centre) {
                // The scalar capture refuses it too.
                let scalar_refuses = (0..SAMPLES).any(|k| {
                    let (x, y) = (
                        centre[0] + OFFSET_U[k] as f32,
                        centre[1] + OFFSET_V[k] as f32,
                    );
                    [
                        (x, y),
                        (x + 0.5, y),
                        (x - 0.5, y),
                        (x, y + 0.5),
                        (x, y - 0.5),
                    ]
                    .iter()
                    .any(|&(x, y)| bilinear(&image, x, y).is_none())
                });
                assert!(
                    scalar_refuses,
                    "centre {centre:?} refused but every sample is inside"
                );
                continue;
            }
            let mut out = [[f32::NAN; SAMPLES]; 3];
            // SAFETY: AVX2 checked above, the patch fits.
            let done = unsafe { patch_samples_avx2(&image, centre, &mut out) };
            for k in 0..done {
                let (x, y) = (
                    centre[0] + OFFSET_U[k] as f32,
                    centre[1] + OFFSET_V[k] as f32,
                );
                let at = |x: f32, y: f32| bilinear(&image, x, y).expect("inside");
                assert_eq!(out[0][k].to_bits(), at(x, y).to_bits(), "sample {k}");
                let gx = at(x + 0.5, y) - at(x - 0.5, y);
                let gy = at(x, y + 0.5) - at(x, y - 0.5);
                assert_eq!(out[1][k].to_bits(), gx.to_bits(), "x gradient {k}");
                assert_eq!(out[2][k].to_bits(), gy.to_bits(), "y gradient {k}");
            }
            fits += 1;
            short += usize::from(SAMPLES - done >= 8);
        }
        assert!(
            fits > 500 && short > 0,
            "{fits} patches fit, {short} stopped early"
        );
    }
}
