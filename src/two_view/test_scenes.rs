//! Synthetic two-view scenes for the unit tests: a random relative pose
//! and points in front of both cameras, seen exactly or with noise.

use nalgebra::{Matrix3, Rotation3, Vector2, Vector3};
use rand::Rng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

/// `[v]ₓ`, the cross-product matrix.
pub fn skew(v: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::new(0.0, -v.z, v.y, v.z, 0.0, -v.x, -v.y, v.x, 0.0)
}

/// A rotation of angle up to `max_angle_rad` about a random axis and a
/// translation of norm `baseline` in a random direction.
pub fn random_pose(
    rng: &mut ChaCha8Rng,
    max_angle_rad: f64,
    baseline: f64,
) -> (Matrix3<f64>, Vector3<f64>) {
    let axis = random_unit(rng);
    let angle = rng.gen_range(-max_angle_rad..max_angle_rad);
    let r = Rotation3::from_scaled_axis(axis * angle).into_inner();
    (r, random_unit(rng) * baseline)
}

pub fn random_unit(rng: &mut ChaCha8Rng) -> Vector3<f64> {
    loop {
        let v = Vector3::new(
            rng.gen_range(-1.0..1.0),
            rng.gen_range(-1.0..1.0),
            rng.gen_range(-1.0..1.0),
        );
        let n = v.norm();
        if n > 0.1 && n <= 1.0 {
            return v / n;
        }
    }
}

/// Points in view 1 (`points_c1`) and their normalised image coordinates
/// in both views, `x_2 = R x_1 + t`.
pub struct Scene {
    pub points_c1: Vec<Vector3<f64>>,
    /// Homogeneous normalised coordinates (z = 1).
    pub q1: Vec<Vector3<f64>>,
    pub q2: Vec<Vector3<f64>>,
}

impl Scene {
    pub fn x1(&self) -> Vec<Vector2<f64>> {
        self.q1.iter().map(|q| q.xy()).collect()
    }
    pub fn x2(&self) -> Vec<Vector2<f64>> {
        self.q2.iter().map(|q| q.xy()).collect()
    }
}

/// `n` points at depths 2-10 within a ±45° field of view of view 1 that
/// view 2 also sees within ±60°, their image coordinates perturbed by
/// Gaussian noise of `noise_sigma` (normalised units).
pub fn random_scene(
    rng: &mut ChaCha8Rng,
    r: &Matrix3<f64>,
    t: &Vector3<f64>,
    n: usize,
    noise_sigma: f64,
) -> Scene {
    let noise = Normal::new(0.0, noise_sigma.max(1e-300)).expect("positive sigma");
    let mut scene = Scene {
        points_c1: Vec::new(),
        q1: Vec::new(),
        q2: Vec::new(),
    };
    while scene.points_c1.len() < n {
        let depth = rng.gen_range(2.0..10.0);
        let p1 = Vector3::new(rng.gen_range(-1.0..1.0), rng.gen_range(-1.0..1.0), 1.0) * depth;
        let p2 = r * p1 + t;
        if p2.z < 0.5 || p2.x.abs() > 1.7 * p2.z || p2.y.abs() > 1.7 * p2.z {
            continue;
        }
        let mut q1 = p1 / p1.z;
        let mut q2 = p2 / p2.z;
        if noise_sigma > 0.0 {
            for q in [&mut q1, &mut q2] {
                q.x += noise.sample(rng);
                q.y += noise.sample(rng);
            }
        }
        scene.points_c1.push(p1);
        scene.q1.push(q1);
        scene.q2.push(q2);
    }
    scene
}

/// Angle of `a⁻¹ b` in radians.
pub fn rotation_angle(a: &Matrix3<f64>, b: &Matrix3<f64>) -> f64 {
    crate::dataset::matches_file::rotation_error_deg(a, b).to_radians()
}
