use super::*;
use crate::features::matching::{match_descriptors, MatchConfig};

/// Smooth aperiodic blob texture (as in the KLT tests), exact at any point.
fn texture(x: f64, y: f64) -> f64 {
    const CELL: f64 = 9.0;
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
            1.5 + 3.0 * next(),
            200.0 * (next() - 0.5),
        )
    }
    let (ci, cj) = ((x / CELL).floor() as i64, (y / CELL).floor() as i64);
    let mut v = 128.0;
    for j in cj - 2..=cj + 2 {
        for i in ci - 2..=ci + 2 {
            let (jx, jy, sigma, amplitude) = blob(i, j);
            let (dx, dy) = (x - (i as f64 * CELL + jx), y - (j as f64 * CELL + jy));
            v += amplitude * (-(dx * dx + dy * dy) / (2.0 * sigma * sigma)).exp();
        }
    }
    v
}

const SIZE: usize = 400;

/// The texture turned by `angle` about the image centre, inside a disc
/// (outside it a flat grey, so that both images show the same content).
fn rotated_image(angle_rad: f64) -> Vec<u8> {
    let c = SIZE as f64 / 2.0;
    let (s, co) = angle_rad.sin_cos();
    (0..SIZE * SIZE)
        .map(|k| {
            let (x, y) = ((k % SIZE) as f64 - c, (k / SIZE) as f64 - c);
            if x.hypot(y) > c - 2.0 {
                return 128;
            }
            // Inverse rotation finds where this pixel came from.
            let (u, v) = (co * x + s * y, -s * x + co * y);
            texture(u + c + 1000.0, v + c + 1000.0)
                .round()
                .clamp(0.0, 255.0) as u8
        })
        .collect()
}

/// Fraction and number of mutual matches that land where the rotation says.
fn rotation_matching(angle_deg: f64, config: OrbConfig, steer: bool) -> (f64, usize, f64) {
    let angle = angle_deg.to_radians();
    let mut orb = OrbExtractor::new(config).unwrap();
    if !steer {
        // Unsteered BRIEF: every keypoint uses the unrotated pattern.
        let zero = orb.patterns[0];
        orb.patterns.iter_mut().for_each(|p| *p = zero);
    }
    let (mut k0, mut d0, mut k1, mut d1) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    orb.extract_grey(SIZE, SIZE, &rotated_image(0.0), &mut k0, &mut d0)
        .unwrap();
    orb.extract_grey(SIZE, SIZE, &rotated_image(angle), &mut k1, &mut d1)
        .unwrap();
    assert!(k0.len() > 300, "{} keypoints", k0.len());
    let matches = match_descriptors(&d0, &d1, &MatchConfig::default(), None);
    let c = SIZE as f64 / 2.0;
    let (s, co) = angle.sin_cos();
    let mut correct = 0;
    let mut angle_errors = Vec::new();
    for m in &matches {
        let (a, b) = (k0[m.query as usize], k1[m.train as usize]);
        let (x, y) = (f64::from(a.x) - c, f64::from(a.y) - c);
        let (ex, ey) = (co * x - s * y + c, s * x + co * y + c);
        let tolerance = 2.0 * f64::from(config.scale).powi(i32::from(a.level.max(b.level)));
        if (f64::from(b.x) - ex).hypot(f64::from(b.y) - ey) < tolerance {
            correct += 1;
            let turn = f64::from(b.angle_rad - a.angle_rad) - angle;
            angle_errors.push(turn.sin().atan2(turn.cos()).abs().to_degrees());
        }
    }
    angle_errors.sort_by(f64::total_cmp);
    let median_angle_error = angle_errors
        .get(angle_errors.len() / 2)
        .copied()
        .unwrap_or(f64::NAN);
    (
        correct as f64 / matches.len().max(1) as f64,
        correct,
        median_angle_error,
    )
}

#[test]
fn steered_descriptors_match_across_rotations() {
    for angle_deg in [0.0, 30.0, 90.0, 135.0] {
        let (precision, correct, angle_error) =
            rotation_matching(angle_deg, OrbConfig::default(), true);
        assert!(precision > 0.9, "{angle_deg} deg: precision {precision}");
        assert!(correct > 150, "{angle_deg} deg: {correct} correct matches");
        assert!(
            angle_error < 3.0,
            "{angle_deg} deg: median orientation error {angle_error} deg"
        );
    }
}

#[test]
fn without_steering_the_same_descriptors_fail_at_large_rotations() {
    // The control for the test above: it would pass for the wrong reason if
    // unsteered BRIEF matched just as well.
    let (_, correct_steered, _) = rotation_matching(90.0, OrbConfig::default(), true);
    let (_, correct_plain, _) = rotation_matching(90.0, OrbConfig::default(), false);
    assert!(
        correct_plain * 5 < correct_steered,
        "{correct_plain} vs {correct_steered}"
    );
}

#[test]
fn the_budget_is_respected_and_keypoints_stay_inside() {
    let config = OrbConfig {
        max_features: 300,
        ..OrbConfig::default()
    };
    let mut orb = OrbExtractor::new(config).unwrap();
    let (mut k, mut d) = (Vec::new(), Vec::new());
    orb.extract_grey(SIZE, SIZE, &rotated_image(0.3), &mut k, &mut d)
        .unwrap();
    assert_eq!(k.len(), d.len());
    assert!(k.len() <= 300 && k.len() > 250, "{}", k.len());
    assert!(
        k.iter().any(|p| p.level > 0),
        "features come from several levels"
    );
    for p in &k {
        assert!(p.x >= 15.0 && p.y >= 15.0 && p.x < (SIZE - 15) as f32 && p.y < (SIZE - 15) as f32);
    }
}

#[test]
fn the_centroid_angle_points_to_the_bright_side() {
    // Brighter to the right and below: angle atan2(+, +) in image axes.
    let w = 64;
    let data: Vec<u8> = (0..w * w)
        .map(|k| (2 * (k % w) + (k / w)).min(255) as u8)
        .collect();
    let img = GreyImage::from_vec(w, w, data).unwrap();
    let r = ORIENTATION_RADIUS_PX as f64;
    let half: Vec<usize> = (0..=ORIENTATION_RADIUS_PX)
        .map(|dy| (r * r - (dy * dy) as f64).sqrt().floor() as usize)
        .collect();
    let angle = intensity_centroid_angle(&img, 32, 32, &half);
    // Symmetric disc: m10 : m01 = 2 : 1.
    assert!((f64::from(angle) - 0.5f64.atan()).abs() < 1e-3, "{angle}");
}

#[test]
fn empty_tiny_flat_and_saturated_images_give_no_features() {
    let mut orb = OrbExtractor::new(OrbConfig::default()).unwrap();
    let (mut k, mut d) = (vec![], vec![]);
    assert!(matches!(
        orb.extract_grey(0, 0, &[], &mut k, &mut d),
        Err(FeatureError::Empty { .. })
    ));
    for (w, h, v) in [(10, 10, 77), (400, 300, 0), (400, 300, 255), (37, 500, 128)] {
        orb.extract_grey(w, h, &vec![v; w * h], &mut k, &mut d)
            .unwrap();
        assert!(k.is_empty() && d.is_empty());
    }
    // A tiny image with texture has no room for the orientation disc.
    let tiny: Vec<u8> = (0..30 * 30).map(|i| (i * 37 % 251) as u8).collect();
    orb.extract_grey(30, 30, &tiny, &mut k, &mut d).unwrap();
    assert!(k.is_empty());
    assert!(OrbExtractor::new(OrbConfig {
        edge_px: 3,
        ..OrbConfig::default()
    })
    .is_err());
}

#[test]
fn vector_disc_moments_equal_the_scalar_definition_on_noise() {
    use rand::{Rng, SeedableRng};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
    let (w, h) = (90, 70);
    let pixels: Vec<u8> = (0..w * h).map(|_| rng.gen()).collect();
    let img = GreyImage::from_vec(w, h, pixels).unwrap();
    let r = ORIENTATION_RADIUS_PX as f64;
    let half: Vec<usize> = (0..=ORIENTATION_RADIUS_PX)
        .map(|dy| (r * r - (dy * dy) as f64).sqrt().floor() as usize)
        .collect();
    let edge = ORIENTATION_RADIUS_PX + 2;
    for y in edge..h - edge {
        for x in edge..w - edge {
            assert_eq!(
                centroid_moments(&img, x, y, &half),
                centroid_moments_scalar(&img, x, y, &half),
                "({x},{y})"
            );
        }
    }
    // Saturated pixels: the 16-bit sums must not overflow.
    let white = GreyImage::filled(64, 64, 255);
    assert_eq!(
        centroid_moments(&white, 32, 32, &half),
        centroid_moments_scalar(&white, 32, 32, &half)
    );
}

#[test]
fn described_points_equal_the_extractors_level_zero_descriptors() {
    let mut orb = OrbExtractor::new(OrbConfig::default()).unwrap();
    let pixels = rotated_image(0.0);
    let (mut keypoints, mut descriptors) = (Vec::new(), Vec::new());
    orb.extract_grey(SIZE, SIZE, &pixels, &mut keypoints, &mut descriptors)
        .unwrap();
    let level0: Vec<usize> = (0..keypoints.len())
        .filter(|&k| keypoints[k].level == 0)
        .collect();
    assert!(level0.len() > 50, "{} level-0 keypoints", level0.len());
    let points: Vec<[f32; 2]> = level0
        .iter()
        .map(|&k| [keypoints[k].x, keypoints[k].y])
        .collect();
    let image = GreyImage::from_vec(SIZE, SIZE, pixels).unwrap();
    let mut described = Vec::new();
    orb.describe_points(&image, &points, &mut described);
    assert_eq!(described.len(), points.len());
    for (d, &k) in described.iter().zip(&level0) {
        assert_eq!(d.as_ref(), Some(&descriptors[k]));
    }
}

#[test]
fn described_points_near_the_border_have_no_descriptor_and_a_turned_point_matches() {
    let mut orb = OrbExtractor::new(OrbConfig::default()).unwrap();
    let image = GreyImage::from_vec(SIZE, SIZE, rotated_image(0.0)).unwrap();
    let mut out = Vec::new();
    orb.describe_points(&image, &[[3.0, 200.0], [200.0, 395.0]], &mut out);
    assert_eq!(out, vec![None, None]);
    // The same scene point in an image turned by 40 degrees keeps its
    // descriptor up to a few bits; an unrelated point does not.
    let angle = 40f64.to_radians();
    let turned = GreyImage::from_vec(SIZE, SIZE, rotated_image(angle)).unwrap();
    let c = SIZE as f64 / 2.0;
    let (s, co) = angle.sin_cos();
    let mut close = 0;
    let probes: Vec<[f32; 2]> = (0..40)
        .map(|k| {
            let a = k as f64 * 0.157;
            [(c + 80.0 * a.cos()) as f32, (c + 80.0 * a.sin()) as f32]
        })
        .collect();
    for p in &probes {
        let (x, y) = (f64::from(p[0]) - c, f64::from(p[1]) - c);
        let q = [(co * x - s * y + c) as f32, (s * x + co * y + c) as f32];
        let (mut a, mut b, mut far) = (Vec::new(), Vec::new(), Vec::new());
        orb.describe_points(&image, &[*p], &mut a);
        orb.describe_points(&turned, &[q], &mut b);
        orb.describe_points(&turned, &[[q[0] + 25.0, q[1]]], &mut far);
        let (a, b, far) = (a[0].unwrap(), b[0].unwrap(), far[0].unwrap());
        let same = crate::features::matching::hamming(&a, &b);
        let other = crate::features::matching::hamming(&a, &far);
        if same + 30 < other {
            close += 1;
        }
    }
    assert!(close >= 30, "{close} of 40 points kept their descriptor");
}
