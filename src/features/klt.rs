//! Pyramidal Lucas-Kanade tracking, inverse compositional (Baker &
//! Matthews, "Lucas-Kanade 20 years on", IJCV 2004, sec. 3.2) for a
//! translation warp, coarse to fine over a halving [`Pyramid`] (Bouguet,
//! "Pyramidal implementation of the Lucas Kanade feature tracker", 2000).
//!
//! Per level the template T (prev image around the feature) and its
//! gradient are sampled once and give a constant Hessian
//! H = sum grad T^T grad T; each iteration samples the current image at
//! the displaced window, e = I(x + d) - T(x), and updates
//! d <- d - H^-1 sum grad T^T e (eq. 34-35 of the paper, warp composed
//! with the inverse increment). Bilinear weights are the same for every
//! pixel of a window, so sampling is four multiply-adds per pixel over
//! contiguous rows.
//!
//! A forward-backward check (Kalal et al., "Forward-backward error",
//! ICPR 2010) tracks the result back and keeps a track only when it returns
//! within `fb_threshold_px` of where it started. An IMU rotation can
//! predict where each feature lands ([`predict_from_rotation`]) so that
//! fast turns start the search near the answer.

use nalgebra::{Matrix2, Matrix6, Rotation3, Vector2, Vector6};

/// Affine refinement iterations at most (it starts at the converged translation).
const AFFINE_ITERATIONS: usize = 5;

use crate::camera::CameraModel;
#[cfg(target_arch = "x86_64")]
use crate::features::gathered_corners::gathered_corners;
use crate::features::pyramid::{GreyImage, Pyramid};
use crate::features::FeatureError;

/// Tracking parameters.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct KltConfig {
    /// Window half-size: the window is (2h+1)^2 pixels (10 -> 21x21).
    pub half_window_px: usize,
    /// Gauss-Newton iterations per level at most.
    pub max_iterations: usize,
    /// Stop a level when the update is shorter than this, px.
    pub epsilon_px: f32,
    /// Smallest accepted eigenvalue of H / window area, (grey/px)^2.
    pub min_eigenvalue: f32,
    /// Forward-backward threshold, px; `None` disables the check.
    pub fb_threshold_px: Option<f32>,
    /// After the translation converges at level 0, refine an affine warp
    /// of the window (inverse compositional, Baker & Matthews sec. 3.2 with
    /// the affine warp of their eq. 1): removes the bias that rotation and
    /// scale change within the window leave in a translation-only fit
    /// (0.06 px mean at 1 degree of roll; < 0.01 px with it, klt tests).
    /// Off by default, as in OpenCV: it runs on the forward pass only but
    /// still doubles its cost, and on KITTI it keeps slightly fewer tracks.
    /// The relative stage's tracker can turn it on for the frame-to-frame
    /// tracks, whose per-frame bias otherwise adds up along a track
    /// (`[relative] klt_affine`).
    pub affine_refinement: bool,
    /// Largest accepted std(I(x + d) - T(x)) / std(T) over the window at
    /// level 0 after convergence (a brightness offset does not count);
    /// `None` (the default, as OpenCV) disables the check. It catches wrong
    /// matches self-consistent enough to pass the forward-backward check
    /// (ratio 0.3-1 on synthetic texture, where right ones stay below
    /// 0.02), but on real frames with perspective change and blur right
    /// tracks reach 0.5-0.8 too, so a limit there costs tracks.
    pub max_residual: Option<f32>,
}

impl Default for KltConfig {
    fn default() -> Self {
        Self {
            half_window_px: 10,
            max_iterations: 30,
            epsilon_px: 0.01,
            min_eigenvalue: 1e-2,
            fb_threshold_px: Some(1.0),
            affine_refinement: false,
            max_residual: None,
        }
    }
}

/// What happened to one feature.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TrackStatus {
    /// Converged inside the image (and passed the forward-backward check when one is set).
    Tracked,
    /// The window left the image at the finest level.
    OutOfImage,
    /// The template has too little texture (small eigenvalue of H).
    Textureless,
    /// Tracking back did not return to the start.
    ForwardBackward,
    /// The window found does not look like the template.
    LargeResidual,
    /// Non-finite input position or prediction.
    BadInput,
}

/// A tracker with its window buffers, reused for every feature and frame.
#[derive(Debug, Clone)]
pub struct KltTracker {
    config: KltConfig,
    /// Template with a one-pixel rim for the gradient, (2h+3)^2.
    template: Vec<f32>,
    grad_x: Vec<f32>,
    grad_y: Vec<f32>,
    /// Template cropped to the window, (2h+1) rows of [`padded`] (2h+1)
    /// values; the padding (and that of the gradients) stays zero.
    template_inner: Vec<f32>,
    /// One interpolated window row, padded likewise.
    row_values: Vec<f32>,
    /// Each column's offset from the window centre, `i - h`, padded
    /// likewise with the last column's: where the gathered affine rows
    /// place the padding's samples (inside the window, so they never fail
    /// the image check).
    sample_offsets: Vec<f32>,
    /// All bits set for a column of the window, zero for the padding.
    sample_lanes: Vec<f32>,
    back_points: Vec<[f32; 2]>,
    back_status: Vec<TrackStatus>,
    /// Standard deviation of I - T over the window in the last iteration
    /// divided by the template's own standard deviation.
    last_residual_ratio: f32,
    /// True while tracking forward (affine refinement runs only then).
    forward_pass: bool,
    /// Standard deviation of the current template, grey levels.
    template_spread: f32,
    /// The forward pass's residual ratio of each point of the last
    /// [`KltTracker::track`] call (NaN where no level converged).
    residual_ratios: Vec<f32>,
}

impl KltTracker {
    /// A tracker with `config`; [`FeatureError::Config`] when the window, iteration count,
    /// `epsilon_px`, `min_eigenvalue` or `fb_threshold_px` is out of range.
    pub fn new(config: KltConfig) -> Result<Self, FeatureError> {
        if config.half_window_px == 0
            || config.max_iterations == 0
            || !(config.epsilon_px > 0.0)
            || !(config.min_eigenvalue >= 0.0)
            || config.fb_threshold_px.is_some_and(|t| !(t > 0.0))
        {
            return Err(FeatureError::Config(format!(
                "invalid KLT configuration {config:?}"
            )));
        }
        let rim = 2 * config.half_window_px + 3;
        let inner = 2 * config.half_window_px + 1;
        Ok(Self {
            config,
            template: vec![0.0; rim * rim],
            grad_x: vec![0.0; inner * padded(inner)],
            grad_y: vec![0.0; inner * padded(inner)],
            template_inner: vec![0.0; inner * padded(inner)],
            row_values: vec![0.0; padded(inner)],
            sample_offsets: (0..padded(inner))
                .map(|i| i.min(inner - 1) as f32 - config.half_window_px as f32)
                .collect(),
            sample_lanes: (0..padded(inner))
                .map(|i| f32::from_bits(if i < inner { u32::MAX } else { 0 }))
                .collect(),
            back_points: Vec::new(),
            back_status: Vec::new(),
            last_residual_ratio: 0.0,
            forward_pass: true,
            template_spread: 1.0,
            residual_ratios: Vec::new(),
        })
    }

    /// The settings it was built with.
    pub fn config(&self) -> &KltConfig {
        &self.config
    }

    /// How unlike its template each point of the last [`KltTracker::track`]
    /// call ended, one value per point: std(I(x + d) - T(x)) / std(T) over
    /// the window at the last level that converged, forward pass (NaN where no
    /// level converged). What `max_residual` compares; a caller can also
    /// judge a point against the others of its call.
    pub fn residual_ratios(&self) -> &[f32] {
        &self.residual_ratios
    }

    /// Tracks `prev_points` (level-0 pixels of `prev`) into `cur`, starting
    /// from `predicted` where given (else from the same position). Writes
    /// one position and one status per input point (both cleared first);
    /// positions of lost features are their last estimate.
    pub fn track(
        &mut self,
        prev: &Pyramid,
        cur: &Pyramid,
        prev_points: &[[f32; 2]],
        predicted: Option<&[[f32; 2]]>,
        cur_points: &mut Vec<[f32; 2]>,
        status: &mut Vec<TrackStatus>,
    ) {
        self.forward_pass = true;
        self.residual_ratios.clear();
        self.track_one_way(prev, cur, prev_points, predicted, cur_points, status);
        // The way back only checks consistency to within a pixel: the
        // translation fit is enough there.
        self.forward_pass = false;
        let Some(threshold) = self.config.fb_threshold_px else {
            return;
        };
        let mut back = std::mem::take(&mut self.back_points);
        let mut back_status = std::mem::take(&mut self.back_status);
        self.track_one_way(
            cur,
            prev,
            cur_points,
            Some(prev_points),
            &mut back,
            &mut back_status,
        );
        for i in 0..prev_points.len() {
            if status[i] != TrackStatus::Tracked {
                continue;
            }
            let (dx, dy) = (
                back[i][0] - prev_points[i][0],
                back[i][1] - prev_points[i][1],
            );
            if back_status[i] != TrackStatus::Tracked || dx * dx + dy * dy > threshold * threshold {
                status[i] = TrackStatus::ForwardBackward;
            }
        }
        self.back_points = back;
        self.back_status = back_status;
    }

    /// One direction, compiled for AVX2 + FMA when the CPU has them
    /// (checked at run time; the window loops then use 8-wide vectors).
    fn track_one_way(
        &mut self,
        from: &Pyramid,
        to: &Pyramid,
        points: &[[f32; 2]],
        predicted: Option<&[[f32; 2]]>,
        out: &mut Vec<[f32; 2]>,
        status: &mut Vec<TrackStatus>,
    ) {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma")
        {
            // SAFETY: the CPU has AVX2 and FMA, checked just above.
            return unsafe { self.track_one_way_avx2(from, to, points, predicted, out, status) };
        }
        self.track_one_way_generic(from, to, points, predicted, out, status)
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    unsafe fn track_one_way_avx2(
        &mut self,
        from: &Pyramid,
        to: &Pyramid,
        points: &[[f32; 2]],
        predicted: Option<&[[f32; 2]]>,
        out: &mut Vec<[f32; 2]>,
        status: &mut Vec<TrackStatus>,
    ) {
        self.track_one_way_generic(from, to, points, predicted, out, status)
    }

    #[inline(always)]
    fn track_one_way_generic(
        &mut self,
        from: &Pyramid,
        to: &Pyramid,
        points: &[[f32; 2]],
        predicted: Option<&[[f32; 2]]>,
        out: &mut Vec<[f32; 2]>,
        status: &mut Vec<TrackStatus>,
    ) {
        out.clear();
        status.clear();
        let levels = from.levels().len().min(to.levels().len());
        let same_size = levels > 0
            && from.level(0).width == to.level(0).width
            && from.level(0).height == to.level(0).height;
        for (i, p) in points.iter().enumerate() {
            let guess = predicted.and_then(|g| g.get(i)).copied().unwrap_or(*p);
            if !same_size || !p.iter().chain(guess.iter()).all(|v| v.is_finite()) {
                out.push(guess);
                status.push(TrackStatus::BadInput);
                if self.forward_pass {
                    self.residual_ratios.push(f32::NAN);
                }
                continue;
            }
            self.last_residual_ratio = f32::NAN;
            let (q, s) = self.track_point(from, to, levels, *p, guess);
            if self.forward_pass {
                self.residual_ratios.push(self.last_residual_ratio);
            }
            out.push(q);
            status.push(s);
        }
    }

    /// One feature through the pyramid; level-0 result and status.
    #[inline(always)]
    fn track_point(
        &mut self,
        from: &Pyramid,
        to: &Pyramid,
        levels: usize,
        p: [f32; 2],
        guess: [f32; 2],
    ) -> ([f32; 2], TrackStatus) {
        let top = levels - 1;
        let top_scale = (1u32 << top) as f32;
        let mut d = [(guess[0] - p[0]) / top_scale, (guess[1] - p[1]) / top_scale];
        for level in (0..levels).rev() {
            let scale = (1u32 << level) as f32;
            let pl = [p[0] / scale, p[1] / scale];
            let finest = level == 0;
            match self.track_level(from.level(level), to.level(level), pl, d) {
                LevelResult::Converged(dl) => d = dl,
                LevelResult::OutOfImage(dl) if !finest => d = dl,
                LevelResult::Textureless if !finest => {}
                LevelResult::OutOfImage(dl) => {
                    return ([p[0] + dl[0], p[1] + dl[1]], TrackStatus::OutOfImage)
                }
                LevelResult::Textureless => {
                    return ([p[0] + d[0], p[1] + d[1]], TrackStatus::Textureless)
                }
            }
            if !finest {
                d = [2.0 * d[0], 2.0 * d[1]];
            }
        }
        if self.forward_pass && self.config.affine_refinement {
            if let Some(t) = self.refine_affine(to.level(0), p, d) {
                d = t;
            }
        }
        if self
            .config
            .max_residual
            .is_some_and(|r| !(self.last_residual_ratio <= r))
        {
            return ([p[0] + d[0], p[1] + d[1]], TrackStatus::LargeResidual);
        }
        ([p[0] + d[0], p[1] + d[1]], TrackStatus::Tracked)
    }

    /// Affine inverse-compositional refinement at level 0, starting from
    /// the translation `d`; the template and its gradient are those
    /// `track_level` left for level 0. Returns the refined translation of
    /// the window centre, or `None` (keep `d`) when the window leaves the
    /// image or the fit is ill-conditioned.
    #[inline(always)]
    fn refine_affine(&mut self, to: &GreyImage, p: [f32; 2], d: [f32; 2]) -> Option<[f32; 2]> {
        let h = self.config.half_window_px as isize;
        let n = self.config.half_window_px * 2 + 1;
        // Steepest-descent images for p = (a11-1, a21, a12, a22-1, tx, ty):
        // grad T * dW/dp = [gx u, gy u, gx v, gy v, gx, gy].
        // H = sum sd sd^T: every entry is a moment sum g_a g_b u^i v^j
        // (i + j <= 2) of one of the three gradient products; per row (v
        // fixed) the sums over u need only 1, u, u^2.
        let np = padded(n);
        // m[g][q]: g in (xx, xy, yy), q in (1, u, v, uu, uv, vv).
        let mut m = [[0f64; 6]; 3];
        for j in 0..n {
            let v = (j as isize - h) as f32;
            let mut row = [[0f32; 3]; 3]; // [g][1, u, uu]
            for i in 0..n {
                let k = j * np + i;
                let (gx, gy) = (self.grad_x[k], self.grad_y[k]);
                let u = (i as isize - h) as f32;
                for (g, value) in [gx * gx, gx * gy, gy * gy].into_iter().enumerate() {
                    row[g][0] += value;
                    row[g][1] += value * u;
                    row[g][2] += value * u * u;
                }
            }
            let v = f64::from(v);
            for g in 0..3 {
                let [s0, s1, s2] = row[g].map(f64::from);
                m[g][0] += s0;
                m[g][1] += s1;
                m[g][2] += s0 * v;
                m[g][3] += s2;
                m[g][4] += s1 * v;
                m[g][5] += s0 * v * v;
            }
        }
        let (xx, xy, yy) = (m[0], m[1], m[2]);
        let (one, u, v, uu, uv, vv) = (0, 1, 2, 3, 4, 5);
        // sd = [gx u, gy u, gx v, gy v, gx, gy].
        #[rustfmt::skip]
        let hessian = Matrix6::<f64>::new(
            xx[uu], xy[uu], xx[uv], xy[uv], xx[u], xy[u],
            xy[uu], yy[uu], xy[uv], yy[uv], xy[u], yy[u],
            xx[uv], xy[uv], xx[vv], xy[vv], xx[v], xy[v],
            xy[uv], yy[uv], xy[vv], yy[vv], xy[v], yy[v],
            xx[u],  xy[u],  xx[v],  xy[v],  xx[one], xy[one],
            xy[u],  yy[u],  xy[v],  yy[v],  xy[one], yy[one],
        );
        let inverse: Matrix6<f32> = hessian.try_inverse()?.cast();
        // Current warp x' = p + A x + t, x relative to the feature.
        let mut a = Matrix2::<f32>::identity();
        let mut t = Vector2::new(d[0], d[1]);
        for _ in 0..AFFINE_ITERATIONS {
            let (b, residual) = self.affine_residual_products(to, p, &a, &t)?;
            self.last_residual_ratio = residual / self.template_spread;
            let step = inverse * b;
            // Compose with the inverse increment: W <- W o W(dp)^-1.
            let a_step = Matrix2::new(1.0 + step[0], step[2], step[1], 1.0 + step[3]);
            let a_step_inv = a_step.try_inverse()?;
            let t_step = Vector2::new(step[4], step[5]);
            t -= a * a_step_inv * t_step;
            a *= a_step_inv;
            if !(t.iter().all(|v| v.is_finite())) {
                return None;
            }
            if t_step.norm_squared() < self.config.epsilon_px * self.config.epsilon_px
                && step.fixed_rows::<4>(0).amax() < 1e-4
            {
                break;
            }
        }
        // A wildly distorted window means the fit went astray.
        if (a - Matrix2::identity()).amax() > 0.5 {
            return None;
        }
        Some([t[0], t[1]])
    }

    /// sum of SD^T e over the window warped by (A, t) about `p`. Each row
    /// is sampled first, eight samples at a time with gathers where the
    /// CPU has AVX2 ([`Self::sample_affine_row_avx2`]), then summed one
    /// sample after the other: the same numbers whichever way it was
    /// sampled.
    #[inline(always)]
    fn affine_residual_products(
        &mut self,
        image: &GreyImage,
        p: [f32; 2],
        a: &Matrix2<f32>,
        t: &Vector2<f32>,
    ) -> Option<(Vector6<f32>, f32)> {
        #[cfg(target_arch = "x86_64")]
        let gathers = std::arch::is_x86_feature_detected!("avx2")
            && std::arch::is_x86_feature_detected!("fma");
        #[cfg(not(target_arch = "x86_64"))]
        let gathers = false;
        self.affine_residual_products_with(image, p, a, t, gathers)
    }

    /// [`Self::affine_residual_products`], the rows gathered or not.
    #[inline(always)]
    fn affine_residual_products_with(
        &mut self,
        image: &GreyImage,
        p: [f32; 2],
        a: &Matrix2<f32>,
        t: &Vector2<f32>,
        gathers: bool,
    ) -> Option<(Vector6<f32>, f32)> {
        let h = self.config.half_window_px as f32;
        let n = self.config.half_window_px * 2 + 1;
        let np = padded(n);
        let mut acc = [0f32; 6];
        let (mut e_sum, mut e2_sum) = (0f32, 0f32);
        for j in 0..n {
            let v = j as f32 - h;
            let mut sampled = None;
            #[cfg(target_arch = "x86_64")]
            if gathers {
                // SAFETY: `gathers` is set only when the CPU has AVX2 and FMA.
                sampled = unsafe { self.sample_affine_row_avx2(image, p, a, t, v) };
            }
            let inside = match sampled {
                Some(inside) => inside,
                None => self.sample_affine_row(image, p, a, t, v),
            };
            if !inside {
                return None;
            }
            for i in 0..n {
                let u = i as f32 - h;
                let k = j * np + i;
                let e = self.row_values[i] - self.template_inner[k];
                e_sum += e;
                e2_sum += e * e;
                let (ex, ey) = (e * self.grad_x[k], e * self.grad_y[k]);
                acc[0] += ex * u;
                acc[1] += ey * u;
                acc[2] += ex * v;
                acc[3] += ey * v;
                acc[4] += ex;
                acc[5] += ey;
            }
        }
        Some((Vector6::from(acc), spread(e_sum, e2_sum, (n * n) as f32)))
    }

    /// Row `v` of the window warped by (A, t) about `p` into
    /// `row_values`, one bilinear sample at a time; false when a sample
    /// leaves the image.
    #[inline(always)]
    fn sample_affine_row(
        &mut self,
        image: &GreyImage,
        p: [f32; 2],
        a: &Matrix2<f32>,
        t: &Vector2<f32>,
        v: f32,
    ) -> bool {
        let h = self.config.half_window_px as f32;
        let n = self.config.half_window_px * 2 + 1;
        let (w, hh) = (image.width as f32, image.height as f32);
        let stride = image.width;
        let data = &image.data;
        for (i, value) in self.row_values[..n].iter_mut().enumerate() {
            let u = i as f32 - h;
            // Each sample placed and checked on its own: checking only
            // the window's corners let a sample on an edge between two
            // of them round past the last pixel.
            let x = p[0] + a[(0, 0)] * u + a[(0, 1)] * v + t[0];
            let y = p[1] + a[(1, 0)] * u + a[(1, 1)] * v + t[1];
            if !(x >= 0.0 && y >= 0.0 && x < w - 1.0 && y < hh - 1.0) {
                return false;
            }
            // 0 <= x < w - 1: truncation is floor, and ix + 1 is in the row.
            let (ix, iy) = (x as usize, y as usize);
            let (ax, ay) = (x - ix as f32, y - iy as f32);
            let o = iy * stride + ix;
            *value = (1.0 - ay) * ((1.0 - ax) * f32::from(data[o]) + ax * f32::from(data[o + 1]))
                + ay * ((1.0 - ax) * f32::from(data[o + stride])
                    + ax * f32::from(data[o + stride + 1]));
        }
        true
    }

    /// [`Self::sample_affine_row`] eight samples at a time: places, image
    /// check and weights in vectors, the four grey levels around each
    /// sample by two gathers ([`gathered_corners`]), every sample computed
    /// as the scalar code computes it (the same bits). `None` when a
    /// gather would read past the image's last bytes (the caller samples
    /// the row one by one); the padding's lanes are left at zero.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    unsafe fn sample_affine_row_avx2(
        &mut self,
        image: &GreyImage,
        p: [f32; 2],
        a: &Matrix2<f32>,
        t: &Vector2<f32>,
        v: f32,
    ) -> Option<bool> {
        use std::arch::x86_64::*;
        let n = self.config.half_window_px * 2 + 1;
        let np = padded(n);
        let stride = image.width;
        let (x_end, y_end) = (
            _mm256_set1_ps(image.width as f32 - 1.0),
            _mm256_set1_ps(image.height as f32 - 1.0),
        );
        let zero = _mm256_setzero_ps();
        let one = _mm256_set1_ps(1.0);
        // x = p + a00 u + a01 v + t, added in the scalar code's order.
        let (x0, xv, xt) = (
            _mm256_set1_ps(p[0]),
            _mm256_set1_ps(a[(0, 1)] * v),
            _mm256_set1_ps(t[0]),
        );
        let (y0, yv, yt) = (
            _mm256_set1_ps(p[1]),
            _mm256_set1_ps(a[(1, 1)] * v),
            _mm256_set1_ps(t[1]),
        );
        let (a00, a10) = (_mm256_set1_ps(a[(0, 0)]), _mm256_set1_ps(a[(1, 0)]));
        for c in (0..np).step_by(LANES) {
            // The padding's lanes repeat the row's last sample (inside
            // whenever the row is).
            let u = _mm256_loadu_ps(self.sample_offsets[c..c + LANES].as_ptr());
            let x = _mm256_add_ps(
                _mm256_add_ps(_mm256_add_ps(x0, _mm256_mul_ps(a00, u)), xv),
                xt,
            );
            let y = _mm256_add_ps(
                _mm256_add_ps(_mm256_add_ps(y0, _mm256_mul_ps(a10, u)), yv),
                yt,
            );
            let inside = _mm256_and_ps(
                _mm256_and_ps(
                    _mm256_cmp_ps::<_CMP_GE_OQ>(x, zero),
                    _mm256_cmp_ps::<_CMP_GE_OQ>(y, zero),
                ),
                _mm256_and_ps(
                    _mm256_cmp_ps::<_CMP_LT_OQ>(x, x_end),
                    _mm256_cmp_ps::<_CMP_LT_OQ>(y, y_end),
                ),
            );
            if _mm256_movemask_ps(inside) != 0xff {
                return Some(false);
            }
            // 0 <= x < w - 1: truncation is floor.
            let (ix, iy) = (_mm256_cvttps_epi32(x), _mm256_cvttps_epi32(y));
            let ax = _mm256_sub_ps(x, _mm256_cvtepi32_ps(ix));
            let ay = _mm256_sub_ps(y, _mm256_cvtepi32_ps(iy));
            let offsets =
                _mm256_add_epi32(_mm256_mullo_epi32(iy, _mm256_set1_epi32(stride as i32)), ix);
            // SAFETY: AVX2 is on; the offsets are of pixels inside the image.
            let [d0, d1, d2, d3] = unsafe { gathered_corners(&image.data, stride, offsets) }?;
            let (bx, by) = (_mm256_sub_ps(one, ax), _mm256_sub_ps(one, ay));
            let top = _mm256_add_ps(_mm256_mul_ps(bx, d0), _mm256_mul_ps(ax, d1));
            let bottom = _mm256_add_ps(_mm256_mul_ps(bx, d2), _mm256_mul_ps(ax, d3));
            let value = _mm256_add_ps(_mm256_mul_ps(by, top), _mm256_mul_ps(ay, bottom));
            let value = _mm256_and_ps(
                value,
                _mm256_loadu_ps(self.sample_lanes[c..c + LANES].as_ptr()),
            );
            _mm256_storeu_ps(self.row_values[c..c + LANES].as_mut_ptr(), value);
        }
        Some(true)
    }

    /// Gauss-Newton at one level from displacement `d`.
    #[inline(always)]
    fn track_level(
        &mut self,
        from: &GreyImage,
        to: &GreyImage,
        p: [f32; 2],
        mut d: [f32; 2],
    ) -> LevelResult {
        let h = self.config.half_window_px;
        let rim = 2 * h + 3;
        let n = 2 * h + 1;
        // Template with rim: top-left at p - (h + 1).
        let t0 = [p[0] - (h + 1) as f32, p[1] - (h + 1) as f32];
        if !sample_window(from, t0, rim, &mut self.template) {
            return LevelResult::OutOfImage(d);
        }
        let np = padded(n);
        for y in 0..n {
            let above = &self.template[y * rim + 1..y * rim + 1 + n];
            let row = &self.template[(y + 1) * rim..(y + 2) * rim];
            let below = &self.template[(y + 2) * rim + 1..(y + 2) * rim + 1 + n];
            let gx = &mut self.grad_x[y * np..y * np + n];
            let gy = &mut self.grad_y[y * np..y * np + n];
            let ti = &mut self.template_inner[y * np..y * np + n];
            for x in 0..n {
                gx[x] = 0.5 * (row[x + 2] - row[x]);
                gy[x] = 0.5 * (below[x] - above[x]);
                ti[x] = row[x + 1];
            }
        }
        // Sums in lane-wise accumulators over the zero-padded rows, so that
        // they run as vectors (a single float accumulator would be a chain
        // of dependent adds, longer than a tracking iteration).
        let mut sums = [[0f32; LANES]; 5];
        for k in (0..n * np).step_by(LANES) {
            for l in 0..LANES {
                let (ix, iy, t) = (
                    self.grad_x[k + l],
                    self.grad_y[k + l],
                    self.template_inner[k + l],
                );
                sums[0][l] += ix * ix;
                sums[1][l] += ix * iy;
                sums[2][l] += iy * iy;
                sums[3][l] += t;
                sums[4][l] += t * t;
            }
        }
        let [hxx, hxy, hyy, t_sum, t2_sum] = sums.map(|a| a.iter().sum::<f32>());
        let area = (n * n) as f32;
        self.template_spread = spread(t_sum, t2_sum, area).max(1e-3);
        let (a, b, c) = (hxx / area, hxy / area, hyy / area);
        let min_eig = 0.5 * (a + c) - (0.25 * (a - c) * (a - c) + b * b).sqrt();
        let det = hxx * hyy - hxy * hxy;
        if !(min_eig >= self.config.min_eigenvalue) || !(det > 0.0) {
            return LevelResult::Textureless;
        }
        let inv = [hyy / det, -hxy / det, hxx / det];
        let eps2 = self.config.epsilon_px * self.config.epsilon_px;
        for _ in 0..self.config.max_iterations {
            let w0 = [p[0] + d[0] - h as f32, p[1] + d[1] - h as f32];
            let Some((bx, by, e_sum, e2_sum)) = residual_gradient_products(
                to,
                w0,
                n,
                &self.template_inner,
                &self.grad_x,
                &self.grad_y,
                &mut self.row_values,
            ) else {
                return LevelResult::OutOfImage(d);
            };
            self.last_residual_ratio = spread(e_sum, e2_sum, area) / self.template_spread;
            let step = [inv[0] * bx + inv[1] * by, inv[1] * bx + inv[2] * by];
            d = [d[0] - step[0], d[1] - step[1]];
            if step[0] * step[0] + step[1] * step[1] < eps2 {
                break;
            }
        }
        LevelResult::Converged(d)
    }
}

/// Standard deviation from a sum and a sum of squares over `n` samples.
#[inline]
fn spread(sum: f32, sum2: f32, n: f32) -> f32 {
    let mean = sum / n;
    (sum2 / n - mean * mean).max(0.0).sqrt()
}

enum LevelResult {
    Converged([f32; 2]),
    OutOfImage([f32; 2]),
    Textureless,
}

/// Bilinear samples of the `size` x `size` window whose top-left sample is
/// at (x0, y0); false when it needs a pixel outside the image.
#[inline(always)]
fn sample_window(image: &GreyImage, origin: [f32; 2], size: usize, out: &mut [f32]) -> bool {
    let Some((ix, iy, w)) = bilinear_setup(image, origin, size) else {
        return false;
    };
    for y in 0..size {
        let r0 = &image.row(iy + y)[ix..ix + size + 1];
        let r1 = &image.row(iy + y + 1)[ix..ix + size + 1];
        let o = &mut out[y * size..(y + 1) * size];
        for x in 0..size {
            o[x] = w[0] * f32::from(r0[x])
                + w[1] * f32::from(r0[x + 1])
                + w[2] * f32::from(r1[x])
                + w[3] * f32::from(r1[x + 1]);
        }
    }
    true
}

/// sums over the window of grad T * e, e and e^2 for e = I(x) - T(x), I
/// sampled bilinearly with top-left at `origin`; `None` outside the image.
#[inline(always)]
fn residual_gradient_products(
    image: &GreyImage,
    origin: [f32; 2],
    n: usize,
    template: &[f32],
    grad_x: &[f32],
    grad_y: &[f32],
    row_values: &mut [f32],
) -> Option<(f32, f32, f32, f32)> {
    let (ix, iy, w) = bilinear_setup(image, origin, n)?;
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma") {
        // SAFETY: the CPU has AVX2 and FMA, checked just above.
        let sums = unsafe {
            residual_gradient_products_avx2(image, ix, iy, w, n, template, grad_x, grad_y)
        };
        if sums.is_some() {
            return sums;
        }
    }
    let np = padded(n);
    // Lane-wise accumulators over padded rows: the compiler keeps them in
    // vector registers (float sums are not reassociated otherwise).
    let mut sx = [0f32; LANES];
    let mut sy = [0f32; LANES];
    let mut se = [0f32; LANES];
    let mut se2 = [0f32; LANES];
    for y in 0..n {
        let r0 = &image.row(iy + y)[ix..ix + n + 1];
        let r1 = &image.row(iy + y + 1)[ix..ix + n + 1];
        for (x, v) in row_values[..n].iter_mut().enumerate() {
            *v = w[0] * f32::from(r0[x])
                + w[1] * f32::from(r0[x + 1])
                + w[2] * f32::from(r1[x])
                + w[3] * f32::from(r1[x + 1]);
        }
        let t = &template[y * np..(y + 1) * np];
        let gx = &grad_x[y * np..(y + 1) * np];
        let gy = &grad_y[y * np..(y + 1) * np];
        for c in 0..np / LANES {
            for l in 0..LANES {
                let k = c * LANES + l;
                let e = row_values[k] - t[k];
                sx[l] += e * gx[k];
                sy[l] += e * gy[k];
                se[l] += e;
                se2[l] += e * e;
            }
        }
    }
    let sum = |a: [f32; LANES]| a.iter().sum::<f32>();
    Some((sum(sx), sum(sy), sum(se), sum(se2)))
}

/// [`residual_gradient_products`] in explicit AVX2 + FMA vectors (the
/// compiler left the lane-wise loop scalar): per 8 pixels of a row, four
/// u8 loads widened to f32 and blended, e = I - T, then four fused
/// multiply-adds; lanes past the window width are masked out of e. Window
/// top-left pixel (ix, iy), bilinear weights `w`. `None` when the 8-byte
/// loads of the last row would read past the image buffer (the caller
/// then takes the scalar path).
///
/// # Safety
/// The CPU must have AVX2 and FMA.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
#[allow(clippy::too_many_arguments)]
unsafe fn residual_gradient_products_avx2(
    image: &GreyImage,
    ix: usize,
    iy: usize,
    w: [f32; 4],
    n: usize,
    template: &[f32],
    grad_x: &[f32],
    grad_y: &[f32],
) -> Option<(f32, f32, f32, f32)> {
    use std::arch::x86_64::*;
    let np = padded(n);
    let stride = image.width;
    // Loads reach byte np + 1 of a row (LANES bytes from offset np - LANES + 1).
    if (iy + n) * stride + ix + np + 1 > image.data.len() || template.len() < n * np {
        return None;
    }
    assert!(grad_x.len() >= n * np && grad_y.len() >= n * np);
    let weights = w.map(|v| _mm256_set1_ps(v));
    let lane = _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7);
    let last_chunk = np - LANES;
    let tail_mask = _mm256_castsi256_ps(_mm256_cmpgt_epi32(
        _mm256_set1_epi32((n - last_chunk) as i32),
        lane,
    ));
    let (mut sx, mut sy) = (_mm256_setzero_ps(), _mm256_setzero_ps());
    let (mut se, mut se2) = (_mm256_setzero_ps(), _mm256_setzero_ps());
    for y in 0..n {
        let r0 = image.data.as_ptr().add((iy + y) * stride + ix);
        let r1 = r0.add(stride);
        for x in (0..np).step_by(LANES) {
            let value = _mm256_fmadd_ps(
                weights[0],
                widen8(r0.add(x)),
                _mm256_fmadd_ps(
                    weights[1],
                    widen8(r0.add(x + 1)),
                    _mm256_fmadd_ps(
                        weights[2],
                        widen8(r1.add(x)),
                        _mm256_mul_ps(weights[3], widen8(r1.add(x + 1))),
                    ),
                ),
            );
            let k = y * np + x;
            let mut e = _mm256_sub_ps(value, _mm256_loadu_ps(template.as_ptr().add(k)));
            if x == last_chunk {
                e = _mm256_and_ps(e, tail_mask);
            }
            sx = _mm256_fmadd_ps(e, _mm256_loadu_ps(grad_x.as_ptr().add(k)), sx);
            sy = _mm256_fmadd_ps(e, _mm256_loadu_ps(grad_y.as_ptr().add(k)), sy);
            se = _mm256_add_ps(se, e);
            se2 = _mm256_fmadd_ps(e, e, se2);
        }
    }
    Some((hsum8(sx), hsum8(sy), hsum8(se), hsum8(se2)))
}

/// Eight u8 at `p` as eight f32.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
unsafe fn widen8(p: *const u8) -> std::arch::x86_64::__m256 {
    use std::arch::x86_64::*;
    _mm256_cvtepi32_ps(_mm256_cvtepu8_epi32(_mm_loadl_epi64(p as *const __m128i)))
}

/// Sum of the eight lanes.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
unsafe fn hsum8(v: std::arch::x86_64::__m256) -> f32 {
    use std::arch::x86_64::*;
    let s = _mm_add_ps(_mm256_castps256_ps128(v), _mm256_extractf128_ps(v, 1));
    let s = _mm_add_ps(s, _mm_movehl_ps(s, s));
    let s = _mm_add_ss(s, _mm_shuffle_ps(s, s, 1));
    _mm_cvtss_f32(s)
}

/// Vector lanes of the window loops.
const LANES: usize = 8;

/// Window row length rounded up to whole [`LANES`].
#[inline]
fn padded(n: usize) -> usize {
    n.div_ceil(LANES) * LANES
}

/// Integer top-left pixel and the four bilinear weights for a window of
/// `size` samples starting at `origin`, or `None` when it leaves the image.
#[inline]
fn bilinear_setup(
    image: &GreyImage,
    origin: [f32; 2],
    size: usize,
) -> Option<(usize, usize, [f32; 4])> {
    let (fx0, fy0) = (origin[0].floor(), origin[1].floor());
    if !(fx0 >= 0.0 && fy0 >= 0.0) {
        return None;
    }
    let (ix, iy) = (fx0 as usize, fy0 as usize);
    if ix + size >= image.width || iy + size >= image.height {
        return None;
    }
    let (ax, ay) = (origin[0] - fx0, origin[1] - fy0);
    Some((
        ix,
        iy,
        [
            (1.0 - ax) * (1.0 - ay),
            ax * (1.0 - ay),
            (1.0 - ax) * ay,
            ax * ay,
        ],
    ))
}

/// Where features seen at `prev_points` (pixels of the previous frame)
/// appear after the camera turned by `R_cam_prev_cam_cur` (maps current
/// camera coordinates into the previous camera's), assuming the scene is
/// far compared with the translation: unproject, rotate into the current
/// camera, project. A point whose ray cannot be (un)projected keeps its
/// previous position.
#[allow(non_snake_case)]
pub fn predict_from_rotation(
    camera: &CameraModel,
    R_cam_prev_cam_cur: &Rotation3<f64>,
    prev_points: &[[f32; 2]],
    predicted: &mut Vec<[f32; 2]>,
) {
    predicted.clear();
    let R_cur_prev = R_cam_prev_cam_cur.inverse();
    predicted.extend(prev_points.iter().map(|p| {
        let px = Vector2::new(f64::from(p[0]), f64::from(p[1]));
        camera
            .unproject(&px)
            .and_then(|ray_prev| camera.project(&(R_cur_prev * ray_prev)))
            .filter(|q| q.x.is_finite() && q.y.is_finite())
            .map_or(*p, |q| [q.x as f32, q.y as f32])
    }));
}

#[cfg(test)]
mod tests;
