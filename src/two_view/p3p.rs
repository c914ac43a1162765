//! Perspective-three-point: the camera poses that see three known points
//! along three given rays, after Grunert (1841) as reviewed by Haralick,
//! Lee, Ottenberg & Nölle, "Review and analysis of solutions of the three
//! point perspective pose estimation problem", IJCV 13(3), 1994.
//!
//! With unit rays `f_i`, unknown depths `s_i` and the triangle's sides
//! `a = |X2 − X3|`, `b = |X1 − X3|`, `c = |X1 − X2|`, the law of cosines
//! gives three quadrics in the depths. Writing `s2 = u s1`, `s3 = v s1`
//! and eliminating `s1` leaves two equations in `(u, v)`; one of them is
//! linear in `u` once the other supplies `u²`, and substituting back gives
//! a quartic in `v` (built here by polynomial arithmetic, not by a table of
//! coefficients). Each real root with positive depths gives the points in
//! the camera frame, and the pose follows from the two triangles.

use nalgebra::{Matrix3, Vector3};

use super::polynomial::{self, MAX_DEGREE};

/// A pose `X_cam = R X_world + t`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CameraPose {
    /// `R`: rotation from world to camera coordinates.
    pub rotation_cam_world: Matrix3<f64>,
    /// `t`: the world origin in camera coordinates.
    pub t_cam_world: Vector3<f64>,
}

/// Up to four poses.
#[derive(Debug, Clone, Copy)]
pub struct P3pSolutions {
    poses: [CameraPose; 4],
    len: usize,
}

impl P3pSolutions {
    /// The poses found (0 to 4).
    pub fn as_slice(&self) -> &[CameraPose] {
        &self.poses[..self.len]
    }
}

/// Orthonormal frame of a triangle: first axis along `p1 → p2`, third
/// normal to the triangle. `None` for a degenerate (collinear) triangle.
fn triangle_frame(p: &[Vector3<f64>; 3]) -> Option<Matrix3<f64>> {
    let e1 = (p[1] - p[0]).try_normalize(1e-12)?;
    let e3 = e1.cross(&(p[2] - p[0])).try_normalize(1e-12)?;
    let e2 = e3.cross(&e1);
    Some(Matrix3::from_columns(&[e1, e2, e3]))
}

/// Newton steps on the three law-of-cosines equations in the depths.
fn polish_depths(s: &mut Vector3<f64>, cos: &[f64; 3], sq: &[f64; 3]) {
    let [ca, cb, cg] = *cos;
    let [a2, b2, c2] = *sq;
    for _ in 0..3 {
        let (s1, s2, s3) = (s.x, s.y, s.z);
        let f = Vector3::new(
            s2 * s2 + s3 * s3 - 2.0 * s2 * s3 * ca - a2,
            s1 * s1 + s3 * s3 - 2.0 * s1 * s3 * cb - b2,
            s1 * s1 + s2 * s2 - 2.0 * s1 * s2 * cg - c2,
        );
        let j = Matrix3::new(
            0.0,
            2.0 * (s2 - s3 * ca),
            2.0 * (s3 - s2 * ca),
            2.0 * (s1 - s3 * cb),
            0.0,
            2.0 * (s3 - s1 * cb),
            2.0 * (s1 - s2 * cg),
            2.0 * (s2 - s1 * cg),
            0.0,
        );
        match j.lu().solve(&f) {
            Some(step) if step.iter().all(|v| v.is_finite()) => *s -= step,
            _ => return,
        }
    }
}

/// All poses (at most four) that put `points_world[i]` on the ray
/// `bearings[i]` (any positive multiple) in front of the camera. Empty for
/// collinear or coincident points, parallel rays or non-finite input.
pub fn p3p(bearings: &[Vector3<f64>; 3], points_world: &[Vector3<f64>; 3]) -> P3pSolutions {
    let mut out = P3pSolutions {
        poses: [CameraPose {
            rotation_cam_world: Matrix3::identity(),
            t_cam_world: Vector3::zeros(),
        }; 4],
        len: 0,
    };
    let finite = bearings
        .iter()
        .chain(points_world)
        .all(|v| v.iter().all(|x| x.is_finite()));
    if !finite {
        return out;
    }
    let Some(frame_world) = triangle_frame(points_world) else {
        return out;
    };
    let f: [Vector3<f64>; 3] = match [0, 1, 2].map(|i| bearings[i].try_normalize(1e-300)) {
        [Some(a), Some(b), Some(c)] => [a, b, c],
        _ => return out,
    };
    let a2 = (points_world[1] - points_world[2]).norm_squared();
    let b2 = (points_world[0] - points_world[2]).norm_squared();
    let c2 = (points_world[0] - points_world[1]).norm_squared();
    let (ca, cb, cg) = (f[1].dot(&f[2]), f[0].dot(&f[2]), f[0].dot(&f[1]));

    // u = N(v) / D(v) and the quartic
    // b² (D² + N² − 2 cγ N D) − c² (1 + v² − 2 cβ v) D² = 0.
    let q = [1.0, -2.0 * cb, 1.0];
    let n = [
        (a2 - c2) * q[0] + b2,
        (a2 - c2) * q[1],
        (a2 - c2) * q[2] - b2,
    ];
    let d = [2.0 * b2 * cg, -2.0 * b2 * ca];
    let mut dd = [0.0; 3];
    let mut nn = [0.0; 5];
    let mut nd = [0.0; 4];
    let mut qdd = [0.0; 5];
    polynomial::multiply(&d, 1, &d, 1, &mut dd);
    polynomial::multiply(&n, 2, &n, 2, &mut nn);
    polynomial::multiply(&n, 2, &d, 1, &mut nd);
    polynomial::multiply(&q, 2, &dd, 2, &mut qdd);
    let mut quartic = [0.0; MAX_DEGREE + 1];
    for i in 0..5 {
        let dd_i = if i < 3 { dd[i] } else { 0.0 };
        let nd_i = if i < 4 { nd[i] } else { 0.0 };
        quartic[i] = b2 * (dd_i + nn[i] - 2.0 * cg * nd_i) - c2 * qdd[i];
    }

    for &v in polynomial::real_roots(&quartic).as_slice() {
        let denominator = d[0] + d[1] * v;
        if v <= 0.0 || denominator.abs() < 1e-12 * b2 {
            continue;
        }
        let u = (n[0] + n[1] * v + n[2] * v * v) / denominator;
        let k = 1.0 + v * v - 2.0 * v * cb;
        if u <= 0.0 || k <= 0.0 {
            continue;
        }
        let s1 = (b2 / k).sqrt();
        let mut s = Vector3::new(s1, u * s1, v * s1);
        polish_depths(&mut s, &[ca, cb, cg], &[a2, b2, c2]);
        if !s.iter().all(|x| x.is_finite() && *x > 0.0) {
            continue;
        }
        let points_cam = [f[0] * s.x, f[1] * s.y, f[2] * s.z];
        let Some(frame_cam) = triangle_frame(&points_cam) else {
            continue;
        };
        let r = frame_cam * frame_world.transpose();
        let t = points_cam[0] - r * points_world[0];
        if out.len < 4 {
            out.poses[out.len] = CameraPose {
                rotation_cam_world: r,
                t_cam_world: t,
            };
            out.len += 1;
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::two_view::test_scenes::{random_pose, random_unit, rotation_angle};
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    #[test]
    fn recovers_the_true_pose_among_its_solutions() {
        let mut rng = ChaCha8Rng::seed_from_u64(17);
        let mut found = 0;
        let trials = 500;
        for trial in 0..trials {
            let (r, _) = random_pose(&mut rng, std::f64::consts::PI, 1.0);
            let t = random_unit(&mut rng) * rng.gen_range(0.0..5.0);
            // Points in front of the camera, expressed in the world.
            let points_cam: [Vector3<f64>; 3] = std::array::from_fn(|_| {
                Vector3::new(rng.gen_range(-1.0..1.0), rng.gen_range(-1.0..1.0), 1.0)
                    * rng.gen_range(1.0..10.0)
            });
            let points_world = points_cam.map(|p| r.transpose() * (p - t));
            let solutions = p3p(&points_cam, &points_world);
            for pose in solutions.as_slice() {
                // Every solution puts every point on its ray.
                for (pc, pw) in points_cam.iter().zip(&points_world) {
                    let seen = pose.rotation_cam_world * pw + pose.t_cam_world;
                    assert!(seen.z > 0.0);
                    let ray_err = seen.normalize().cross(&pc.normalize()).norm();
                    assert!(ray_err < 1e-8, "trial {trial}: ray error {ray_err:e}");
                }
            }
            if solutions.as_slice().iter().any(|p| {
                rotation_angle(&r, &p.rotation_cam_world) < 1e-8
                    && (p.t_cam_world - t).norm() < 1e-8
            }) {
                found += 1;
            }
        }
        // Near-degenerate draws (rays almost on the danger cylinder) may
        // lose the true root; they are rare.
        assert!(
            found >= trials * 99 / 100,
            "true pose found in {found} of {trials}"
        );
    }

    #[test]
    fn degenerate_input_gives_no_solution() {
        let f = [
            Vector3::new(0.0, 0.0, 1.0),
            Vector3::new(0.1, 0.0, 1.0),
            Vector3::new(0.0, 0.1, 1.0),
        ];
        let collinear = [
            Vector3::zeros(),
            Vector3::new(1.0, 0.0, 0.0),
            Vector3::new(2.0, 0.0, 0.0),
        ];
        assert!(p3p(&f, &collinear).as_slice().is_empty());
        let mut nan = f;
        nan[1].y = f64::NAN;
        let world = [
            Vector3::zeros(),
            Vector3::new(1.0, 0.0, 0.0),
            Vector3::new(0.0, 1.0, 0.0),
        ];
        assert!(p3p(&nan, &world).as_slice().is_empty());
    }
}
