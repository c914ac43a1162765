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
