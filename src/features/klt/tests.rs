use super::*;
use crate::camera::PinholeRadtan;
use crate::features::pyramid::PyramidConfig;

/// A smooth, aperiodic texture that can be evaluated exactly at any real
/// position: Gaussian blobs (sigma 2.5-5 px, amplitude +-60) on a jittered
/// 8 px grid, each pixel summing the blobs within 3 cells.
fn texture(x: f64, y: f64) -> f64 {
    const CELL: f64 = 8.0;
    // Cheap deterministic hash of a cell -> (jitter x, jitter y, sigma, amplitude).
    fn blob(i: i64, j: i64) -> (f64, f64, f64, f64) {
        let mut z = (i as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
            ^ (j as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F);
        let mut next = || {
            z ^= z >> 29;
            z = z.wrapping_mul(0xBF58_476D_1CE4_E5B9);
            z ^= z >> 32;
            (z >> 11) as f64 / (1u64 << 53) as f64
        };
        (
            next() * CELL,
            next() * CELL,
            2.5 + 2.5 * next(),
            120.0 * (next() - 0.5),
        )
    }
    let (ci, cj) = ((x / CELL).floor() as i64, (y / CELL).floor() as i64);
    let mut v = 128.0;
    for j in cj - 3..=cj + 3 {
        for i in ci - 3..=ci + 3 {
            let (jx, jy, sigma, amplitude) = blob(i, j);
            let (dx, dy) = (x - (i as f64 * CELL + jx), y - (j as f64 * CELL + jy));
            v += amplitude * (-(dx * dx + dy * dy) / (2.0 * sigma * sigma)).exp();
        }
    }
    v
}

fn render(w: usize, h: usize, f: impl Fn(f64, f64) -> f64) -> Pyramid {
    let data: Vec<u8> = (0..h)
        .flat_map(|y| (0..w).map(move |x| (x, y)))
        .map(|(x, y)| f(x as f64, y as f64).round().clamp(0.0, 255.0) as u8)
        .collect();
    let mut pyramid = Pyramid::new(PyramidConfig::klt()).unwrap();
    pyramid.build_from_grey(w, h, &data).unwrap();
    pyramid
}

fn grid_points(w: usize, h: usize, margin: usize, step: usize) -> Vec<[f32; 2]> {
    let mut points = Vec::new();
    for y in (margin..h - margin).step_by(step) {
        for x in (margin..w - margin).step_by(step) {
            points.push([x as f32 + 0.25, y as f32 + 0.5]);
        }
    }
    points
}

/// Tracks `points` and returns the errors against `truth` of the tracked ones,
/// asserting that (nearly) all were tracked.
fn tracking_errors(
    prev: &Pyramid,
    cur: &Pyramid,
    points: &[[f32; 2]],
    predicted: Option<&[[f32; 2]]>,
    truth: impl Fn([f32; 2]) -> [f64; 2],
) -> Vec<f64> {
    tracking_errors_with(KltConfig::default(), prev, cur, points, predicted, truth)
}

fn tracking_errors_with(
    config: KltConfig,
    prev: &Pyramid,
    cur: &Pyramid,
    points: &[[f32; 2]],
    predicted: Option<&[[f32; 2]]>,
    truth: impl Fn([f32; 2]) -> [f64; 2],
) -> Vec<f64> {
    let mut tracker = KltTracker::new(config).unwrap();
    let (mut out, mut status) = (Vec::new(), Vec::new());
    tracker.track(prev, cur, points, predicted, &mut out, &mut status);
    let errors: Vec<f64> = points
        .iter()
        .zip(&out)
        .zip(&status)
        .filter(|(_, s)| **s == TrackStatus::Tracked)
        .map(|((p, q), _)| {
            let t = truth(*p);
            ((f64::from(q[0]) - t[0]).powi(2) + (f64::from(q[1]) - t[1]).powi(2)).sqrt()
        })
        .collect();
    assert!(
        errors.len() * 100 >= points.len() * 95,
        "only {} of {} tracked: {:?}",
        errors.len(),
        points.len(),
        status
            .iter()
            .filter(|s| **s != TrackStatus::Tracked)
            .collect::<Vec<_>>()
    );
    errors
}

/// Uniform numbers in [0, 1) from a xorshift generator seeded with `seed`.
fn uniform(seed: u64) -> impl FnMut() -> f32 {
    let mut z = seed;
    move || {
        z ^= z << 13;
        z ^= z >> 7;
        z ^= z << 17;
        (z >> 40) as f32 / (1u64 << 24) as f32
    }
}

fn mean(v: &[f64]) -> f64 {
    v.iter().sum::<f64>() / v.len() as f64
}

#[test]
fn subpixel_shifts_are_recovered_to_within_five_hundredths_of_a_pixel() {
    let (w, h) = (320, 240);
    let prev = render(w, h, texture);
    let points = grid_points(w, h, 40, 20);
    for (tx, ty) in [(0.3, -0.45), (2.71, 1.18), (-7.6, 4.35), (8.6, -6.3)] {
        let cur = render(w, h, |x, y| texture(x - tx, y - ty));
        let errors = tracking_errors(&prev, &cur, &points, None, |p| {
            [f64::from(p[0]) + tx, f64::from(p[1]) + ty]
        });
        let worst = errors.iter().cloned().fold(0.0, f64::max);
        assert!(
            mean(&errors) < 0.05,
            "shift ({tx},{ty}): mean error {}",
            mean(&errors)
        );
        assert!(worst < 0.1, "shift ({tx},{ty}): worst error {worst}");
    }
}

#[test]
fn shifts_beyond_the_pyramid_reach_are_rejected_not_misplaced() {
    // 22 px is more than a 3-level pyramid with a 21x21 window reliably
    // captures on this texture: some features converge to wrong places,
    // and the forward-backward and residual checks must catch them.
    let (w, h) = (320, 240);
    let (tx, ty) = (18.2, -11.7);
    let prev = render(w, h, texture);
    let cur = render(w, h, |x, y| texture(x - tx, y - ty));
    let points = grid_points(w, h, 40, 20);
    for checks in [false, true] {
        let config = if checks {
            KltConfig {
                max_residual: Some(0.25),
                ..KltConfig::default()
            }
        } else {
            KltConfig {
                fb_threshold_px: None,
                max_residual: None,
                ..KltConfig::default()
            }
        };
        let mut tracker = KltTracker::new(config).unwrap();
        let (mut out, mut status) = (Vec::new(), Vec::new());
        tracker.track(&prev, &cur, &points, None, &mut out, &mut status);
        let (mut right, mut wrong) = (0, 0);
        for ((p, q), s) in points.iter().zip(&out).zip(&status) {
            if *s == TrackStatus::Tracked {
                let e = (f64::from(q[0] - p[0]) - tx).hypot(f64::from(q[1] - p[1]) - ty);
                if e < 0.1 {
                    right += 1
                } else {
                    wrong += 1
                }
            }
        }
        assert!(right * 2 > points.len(), "checks {checks}: {right} right");
        if checks {
            assert_eq!(wrong, 0);
        } else {
            assert!(wrong > 0, "the case must be hard enough to fool plain KLT");
        }
    }
}

#[test]
fn small_rotations_are_tracked_to_within_five_hundredths_of_a_pixel_with_affine_refinement() {
    let affine = KltConfig {
        affine_refinement: true,
        ..KltConfig::default()
    };
    let (w, h) = (320, 240);
    let (cx, cy) = (160.0, 120.0);
    let prev = render(w, h, texture);
    let points = grid_points(w, h, 40, 20);
    for angle_deg in [1.0f64, -3.0] {
        let (s, c) = angle_deg.to_radians().sin_cos();
        // cur(x) = prev(R^-1 (x - c) + c): content turns by +angle.
        let cur = render(w, h, |x, y| {
            let (dx, dy) = (x - cx, y - cy);
            texture(cx + c * dx + s * dy, cy - s * dx + c * dy)
        });
        let truth = |p: [f32; 2]| {
            let (dx, dy) = (f64::from(p[0]) - cx, f64::from(p[1]) - cy);
            [cx + c * dx - s * dy, cy + s * dx + c * dy]
        };
        let errors = tracking_errors_with(affine, &prev, &cur, &points, None, truth);
        assert!(
            mean(&errors) < 0.05,
            "{angle_deg} deg: mean error {}",
            mean(&errors)
        );
        // The translation-only default is biased by the turn within the
        // window; this is what the refinement is for.
        let plain = tracking_errors(&prev, &cur, &points, None, truth);
        assert!(mean(&plain) > mean(&errors), "{angle_deg} deg");
    }
}

fn pinhole(w: u32, h: u32) -> CameraModel {
    CameraModel::PinholeRadtan(
        PinholeRadtan::new(w, h, [300.0, 300.0, 160.0, 120.0], [0.0; 5]).unwrap(),
    )
}

#[test]
#[allow(non_snake_case)]
fn predicted_positions_map_back_onto_the_previous_pixels() {
    let camera = pinhole(320, 240);
    let R_cam_prev_cam_cur = Rotation3::from_euler_angles(0.02, -0.15, 0.05);
    let points = grid_points(320, 240, 30, 40);
    let mut predicted = Vec::new();
    predict_from_rotation(&camera, &R_cam_prev_cam_cur, &points, &mut predicted);
    assert_eq!(predicted.len(), points.len());
    for (p, q) in points.iter().zip(&predicted) {
        let ray_cur = camera
            .unproject(&Vector2::new(f64::from(q[0]), f64::from(q[1])))
            .unwrap();
        let back = camera.project(&(R_cam_prev_cam_cur * ray_cur)).unwrap();
        assert!((back.x - f64::from(p[0])).abs() < 1e-3 && (back.y - f64::from(p[1])).abs() < 1e-3);
        assert!(
            (q[0] - p[0]).abs() > 20.0,
            "the rotation must move features a lot"
        );
    }
}

#[test]
#[allow(non_snake_case)]
fn an_imu_rotation_prediction_rescues_a_fast_turn() {
    let (w, h) = (320usize, 240usize);
    let camera = pinhole(w as u32, h as u32);
    // A 12 degree yaw: features move ~64 px, beyond a 3-level pyramid's reach.
    let R_cam_prev_cam_cur = Rotation3::from_euler_angles(0.0, 12f64.to_radians(), 0.0);
    let prev = render(w, h, texture);
    let cur = render(w, h, |x, y| {
        let ray_cur = camera.unproject(&Vector2::new(x, y)).unwrap();
        let u = camera.project(&(R_cam_prev_cam_cur * ray_cur)).unwrap();
        texture(u.x, u.y)
    });
    let points: Vec<[f32; 2]> = grid_points(w, h, 30, 15)
        .into_iter()
        .filter(|p| p[0] > 110.0) // those that stay in view
        .collect();
    let truth = |p: [f32; 2]| {
        let ray_prev = camera
            .unproject(&Vector2::new(f64::from(p[0]), f64::from(p[1])))
            .unwrap();
        let q = camera
            .project(&(R_cam_prev_cam_cur.inverse() * ray_prev))
            .unwrap();
        [q.x, q.y]
    };
    let mut predicted = Vec::new();
    predict_from_rotation(&camera, &R_cam_prev_cam_cur, &points, &mut predicted);
    // A 12 degree yaw through a 300 px lens shears the windows: the
    // affine refinement is needed for the subpixel bar.
    let affine = KltConfig {
        affine_refinement: true,
        ..KltConfig::default()
    };
    let errors = tracking_errors_with(affine, &prev, &cur, &points, Some(&predicted), truth);
    assert!(
        mean(&errors) < 0.05,
        "with prediction: mean error {}",
        mean(&errors)
    );

    let mut tracker = KltTracker::new(KltConfig::default()).unwrap();
    let (mut out, mut status) = (Vec::new(), Vec::new());
    tracker.track(&prev, &cur, &points, None, &mut out, &mut status);
    let right = points
        .iter()
        .zip(&out)
        .zip(&status)
        .filter(|((p, q), s)| {
            let t = truth(**p);
            **s == TrackStatus::Tracked
                && ((f64::from(q[0]) - t[0]).abs() + (f64::from(q[1]) - t[1]).abs()) < 0.5
        })
        .count();
    assert!(
        right * 2 < points.len(),
        "without prediction {right} of {} right",
        points.len()
    );
}

#[test]
fn forward_backward_rejects_features_that_cannot_be_found() {
    let (w, h) = (200, 160);
    let prev = render(w, h, texture);
    // The right half of the next image shows something else entirely.
    let cur = render(w, h, |x, y| {
        if x < 100.0 {
            texture(x, y)
        } else {
            texture(y * 1.7 + 300.0, x * 0.6)
        }
    });
    let points = grid_points(w, h, 30, 10);
    let mut tracker = KltTracker::new(KltConfig::default()).unwrap();
    let (mut out, mut status) = (Vec::new(), Vec::new());
    tracker.track(&prev, &cur, &points, None, &mut out, &mut status);
    let ok = |lo: f32, hi: f32| {
        points
            .iter()
            .zip(&status)
            .filter(|(p, s)| p[0] >= lo && p[0] < hi && **s == TrackStatus::Tracked)
            .count() as f64
            / points.iter().filter(|p| p[0] >= lo && p[0] < hi).count() as f64
    };
    assert!(
        ok(0.0, 80.0) > 0.95,
        "unchanged part kept {}",
        ok(0.0, 80.0)
    );
    assert!(
        ok(120.0, 200.0) < 0.2,
        "replaced part kept {}",
        ok(120.0, 200.0)
    );
}

#[test]
fn flat_saturated_tiny_and_mismatched_images_lose_every_feature_without_panicking() {
    let points = [[10.0f32, 10.0], [30.0, 20.0], [f32::NAN, 3.0], [-50.0, 1e9]];
    let mut tracker = KltTracker::new(KltConfig::default()).unwrap();
    let (mut out, mut status) = (Vec::new(), Vec::new());
    let flat = render(64, 48, |_, _| 0.0);
    let saturated = render(64, 48, |_, _| 255.0);
    let tiny = render(3, 2, texture);
    let textured = render(64, 48, texture);
    for (a, b) in [
        (&flat, &flat),
        (&saturated, &saturated),
        (&tiny, &tiny),
        (&textured, &tiny),
    ] {
        tracker.track(a, b, &points, None, &mut out, &mut status);
        assert_eq!(status.len(), points.len());
        assert!(
            status.iter().all(|s| *s != TrackStatus::Tracked),
            "{status:?}"
        );
    }
    assert_eq!(status[2], TrackStatus::BadInput);
    tracker.track(&textured, &textured, &[], None, &mut out, &mut status);
    assert!(out.is_empty() && status.is_empty());
    assert!(KltTracker::new(KltConfig {
        half_window_px: 0,
        ..KltConfig::default()
    })
    .is_err());
}

#[test]
fn a_window_over_two_layers_that_move_apart_ends_with_a_large_residual_ratio() {
    // Left of x = 160 the texture moves by 2.3 px, right of it by 8.3 px
    // (two surfaces at different depths); a window across the seam cannot
    // be aligned by one shift.
    let (w, h) = (320, 240);
    let prev = render(w, h, texture);
    let cur = render(w, h, |x, y| {
        if x < 162.3 {
            texture(x - 2.3, y)
        } else {
            texture(x - 8.3, y)
        }
    });
    let points: Vec<[f32; 2]> = (0..9)
        .flat_map(|row| {
            [
                [80.0, 40.0 + 20.0 * row as f32],
                [158.0, 40.0 + 20.0 * row as f32],
            ]
        })
        .collect();
    let mut tracker = KltTracker::new(KltConfig::default()).unwrap();
    let (mut out, mut status) = (Vec::new(), Vec::new());
    tracker.track(&prev, &cur, &points, None, &mut out, &mut status);
    let ratios = tracker.residual_ratios();
    assert_eq!(ratios.len(), points.len());
    // Away from the seam the windows align (measured 0.011-0.022); on it
    // they end 0.30-0.66, more than four times the largest of the others
    // (the tracker's stereo check compares with four times the median).
    let away = (0..points.len()).filter(|i| points[*i][0] == 80.0);
    let largest_away = away.map(|i| ratios[i]).fold(0.0f32, f32::max);
    assert!(largest_away < 0.05, "{ratios:?}");
    for i in (0..points.len()).filter(|i| points[*i][0] == 158.0) {
        assert!(ratios[i] > 4.0 * largest_away, "seam point {i}: {ratios:?}");
    }
    // Another call starts a new list.
    tracker.track(&prev, &cur, &points[..3], None, &mut out, &mut status);
    assert_eq!(tracker.residual_ratios().len(), 3);
}

#[test]
fn an_affine_window_ending_on_the_image_edge_is_refused_not_read_past() {
    // The window's corners are checked against the image before sampling;
    // a sample on the window's edge between two corners, computed as a
    // running sum, could round past the last row and read beyond the
    // image (a panic on a rendered sequence). Windows are placed with a
    // corner a rounding error inside the bottom or right edge, turned and
    // scaled: every one must be sampled in bounds or refused.
    let (w, h) = (64usize, 48usize);
    let pyramid = render(w, h, texture);
    let image = pyramid.level(0);
    let mut tracker = KltTracker::new(KltConfig {
        affine_refinement: true,
        ..KltConfig::default()
    })
    .unwrap();
    let half = tracker.config().half_window_px as f32;
    let mut next = uniform(0x2545_F491_4F6C_DD1D);
    let (mut sampled, mut refused) = (0, 0);
    for k in 0..20_000 {
        let a = Matrix2::new(
            0.8 + 0.4 * next(),
            0.3 * (next() - 0.5),
            0.3 * (next() - 0.5),
            0.8 + 0.4 * next(),
        );
        // The corner (u, v) = (h, h) or (-h, h) or (h, -h) a hair inside.
        let corner = match k % 3 {
            0 => Vector2::new(half, half),
            1 => Vector2::new(-half, half),
            _ => Vector2::new(half, -half),
        };
        let hair = 1e-4 * next();
        let target = match k % 3 {
            0 => Vector2::new(w as f32 - 1.0 - hair, h as f32 - 1.0 - hair),
            1 => Vector2::new(20.0 + 10.0 * next(), h as f32 - 1.0 - hair),
            _ => Vector2::new(w as f32 - 1.0 - hair, 20.0 + 10.0 * next()),
        };
        let p = [30.0f32, 24.0];
        let t = target - Vector2::new(p[0], p[1]) - a * corner;
        match tracker.affine_residual_products(image, p, &a, &t) {
            Some((b, _)) => {
                assert!(b.iter().all(|v| v.is_finite()));
                sampled += 1;
            }
            None => refused += 1,
        }
    }
    println!("{sampled} windows sampled, {refused} refused");
    assert!(
        sampled > 0 && refused > 0,
        "{sampled} sampled, {refused} refused"
    );
}

#[cfg(target_arch = "x86_64")]
#[test]
fn gathered_affine_sums_are_the_scalar_ones_to_the_bit() {
    // Rows sampled eight at a time with gathers against one sample at a
    // time: the same samples, the same sums to the bit, the same
    // refusals at the image's edge (windows near every border, the last
    // bytes included, where the gathers hand the row back).
    if !(std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma"))
    {
        return;
    }
    let (w, h) = (96usize, 72usize);
    let pyramid = render(w, h, texture);
    let image = pyramid.level(0);
    let mut tracker = KltTracker::new(KltConfig {
        affine_refinement: true,
        ..KltConfig::default()
    })
    .unwrap();
    let n = 2 * tracker.config().half_window_px + 1;
    let np = padded(n);
    let mut next = uniform(0x9E37_79B9_7F4A_7C15);
    // A template and gradients of any values (the padding stays zero).
    for j in 0..n {
        for i in 0..n {
            tracker.template_inner[j * np + i] = 255.0 * next();
            tracker.grad_x[j * np + i] = 40.0 * (next() - 0.5);
            tracker.grad_y[j * np + i] = 40.0 * (next() - 0.5);
        }
    }
    let (mut compared, mut refused) = (0, 0);
    let half = tracker.config().half_window_px as f32;
    for k in 0..5000 {
        let a = Matrix2::new(
            0.8 + 0.4 * next(),
            0.3 * (next() - 0.5),
            0.3 * (next() - 0.5),
            0.8 + 0.4 * next(),
        );
        let p = [w as f32 * next(), h as f32 * next()];
        let t = if k % 4 == 0 {
            // The window's bottom-right corner a hair inside the last pixel.
            let target = Vector2::new(
                w as f32 - 1.0 - 1e-4 * next(),
                h as f32 - 1.0 - 1e-4 * next(),
            );
            target - Vector2::new(p[0], p[1]) - a * Vector2::new(half, half)
        } else {
            Vector2::new(4.0 * (next() - 0.5), 4.0 * (next() - 0.5))
        };
        let scalar = tracker.affine_residual_products_with(image, p, &a, &t, false);
        let gathered = tracker.affine_residual_products_with(image, p, &a, &t, true);
        match (scalar, gathered) {
            (None, None) => refused += 1,
            (Some((bs, rs)), Some((bg, rg))) => {
                let bits = |b: &Vector6<f32>| b.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
                assert_eq!(bits(&bs), bits(&bg), "sums {bs:?} against {bg:?}");
                assert_eq!(rs.to_bits(), rg.to_bits(), "spread {rs} against {rg}");
                compared += 1;
            }
            (s, g) => panic!("scalar {s:?}, gathered {g:?} at p {p:?}, a {a:?}, t {t:?}"),
        }
    }
    assert!(
        compared > 500 && refused > 100,
        "{compared} compared, {refused} refused"
    );
}
