//! The few SO(3) maps preintegration needs: hat, exponential, logarithm and
//! the right Jacobian with its inverse (Forster et al., "On-Manifold
//! Preintegration for Real-Time Visual-Inertial Odometry", TRO 2017, eq. 1-8).
//! Perturbations are on the right: `R Exp(dphi)`.

use nalgebra::{Matrix3, Matrix3x2, Rotation3, UnitQuaternion, Vector3};

/// Below this angle the series forms are used (their error is ~angle^4).
const SMALL_ANGLE_RAD: f64 = 1e-5;

/// `[v]x`, so that `hat(a) * b = a.cross(&b)`.
#[inline]
pub fn hat(v: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::new(0.0, -v.z, v.y, v.z, 0.0, -v.x, -v.y, v.x, 0.0)
}

/// An orthonormal basis `[b1, b2]` of the plane orthogonal to the unit
/// vector `n` (the tangent plane of the sphere at `n`), with `b1 = n x a /
/// |n x a|` for a coordinate axis `a` far from `n` and `b2 = n x b1`: the
/// coordinates in which a direction (gravity, a translation's direction)
/// is perturbed.
pub fn tangent_basis(n: &Vector3<f64>) -> Matrix3x2<f64> {
    let helper = if n.x.abs() < 0.9 {
        Vector3::x()
    } else {
        Vector3::y()
    };
    let b1 = n.cross(&helper).normalize();
    let b2 = n.cross(&b1);
    Matrix3x2::from_columns(&[b1, b2])
}

/// Exp: the rotation by angle |phi| about phi/|phi| (Rodrigues).
#[inline]
pub fn exp(phi: &Vector3<f64>) -> Matrix3<f64> {
    let angle2 = phi.norm_squared();
    let k = hat(phi);
    let (a, b) = if angle2 < SMALL_ANGLE_RAD * SMALL_ANGLE_RAD {
        (1.0 - angle2 / 6.0, 0.5 - angle2 / 24.0)
    } else {
        let angle = angle2.sqrt();
        (angle.sin() / angle, (1.0 - angle.cos()) / angle2)
    };
    Matrix3::identity() + k * a + k * k * b
}

/// Log: the rotation vector of `r` (angle in [0, pi]), through the
/// quaternion so that small angles keep full precision (an arccos of the
/// trace loses half the digits near identity).
#[inline]
pub fn log(r: &Matrix3<f64>) -> Vector3<f64> {
    let q = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(*r));
    let (w, v) = if q.w < 0.0 {
        (-q.w, -q.imag())
    } else {
        (q.w, q.imag())
    };
    let n = v.norm();
    if n < 1e-12 {
        v * (2.0 / w)
    } else {
        v * (2.0 * n.atan2(w) / n)
    }
}

/// `(Exp(phi), J_r(phi))` sharing one sine, cosine and `[phi]x^2`.
#[inline]
pub fn exp_and_right_jacobian(phi: &Vector3<f64>) -> (Matrix3<f64>, Matrix3<f64>) {
    let angle2 = phi.norm_squared();
    let k = hat(phi);
    let k2 = k * k;
    let (a, b, c, d) = if angle2 < SMALL_ANGLE_RAD * SMALL_ANGLE_RAD {
        (
            1.0 - angle2 / 6.0,
            0.5 - angle2 / 24.0,
            0.5 - angle2 / 24.0,
            1.0 / 6.0 - angle2 / 120.0,
        )
    } else {
        let angle = angle2.sqrt();
        let (sin, cos) = angle.sin_cos();
        (
            sin / angle,
            (1.0 - cos) / angle2,
            (1.0 - cos) / angle2,
            (angle - sin) / (angle2 * angle),
        )
    };
    let identity = Matrix3::identity();
    (identity + k * a + k2 * b, identity - k * c + k2 * d)
}

/// Right Jacobian: `Exp(phi + d) ~ Exp(phi) Exp(J_r(phi) d)`.
#[inline]
pub fn right_jacobian(phi: &Vector3<f64>) -> Matrix3<f64> {
    let angle2 = phi.norm_squared();
    let k = hat(phi);
    let (a, b) = if angle2 < SMALL_ANGLE_RAD * SMALL_ANGLE_RAD {
        (0.5 - angle2 / 24.0, 1.0 / 6.0 - angle2 / 120.0)
    } else {
        let angle = angle2.sqrt();
        (
            (1.0 - angle.cos()) / angle2,
            (angle - angle.sin()) / (angle2 * angle),
        )
    };
    Matrix3::identity() - k * a + k * k * b
}

/// Inverse right Jacobian: `Log(Exp(phi) Exp(d)) ~ phi + J_r^-1(phi) d`.
#[inline]
pub fn right_jacobian_inverse(phi: &Vector3<f64>) -> Matrix3<f64> {
    let angle2 = phi.norm_squared();
    let k = hat(phi);
    let b = if angle2 < SMALL_ANGLE_RAD * SMALL_ANGLE_RAD {
        1.0 / 12.0 + angle2 / 720.0
    } else {
        let angle = angle2.sqrt();
        1.0 / angle2 - (1.0 + angle.cos()) / (2.0 * angle * angle.sin())
    };
    Matrix3::identity() + k * 0.5 + k * k * b
}

#[cfg(test)]
mod tests {
    use super::*;

    fn phis() -> [Vector3<f64>; 4] {
        [
            Vector3::new(0.3, -0.2, 0.5),
            Vector3::new(1e-7, 2e-7, -1e-7),
            Vector3::new(-2.0, 0.7, 1.1),
            Vector3::new(0.0, 0.0, 3.0),
        ]
    }

    #[test]
    fn exp_matches_nalgebra_and_log_inverts_it() {
        for phi in phis() {
            let ours = exp(&phi);
            let theirs = Rotation3::new(phi).into_inner();
            assert!((ours - theirs).norm() < 1e-14, "{phi}");
            assert!((log(&ours) - phi).norm() < 1e-12, "{phi}");
        }
    }

    #[test]
    fn right_jacobian_matches_finite_differences() {
        let eps = 1e-6;
        for phi in phis() {
            let jr = right_jacobian(&phi);
            assert!((jr * right_jacobian_inverse(&phi) - Matrix3::identity()).norm() < 1e-12);
            let (e, j) = exp_and_right_jacobian(&phi);
            assert!((e - exp(&phi)).norm() < 1e-15 && (j - jr).norm() < 1e-15);
            for k in 0..3 {
                let d = Vector3::ith(k, eps);
                // Exp(phi)^T Exp(phi + d) = Exp(J_r d)
                let plus = log(&(exp(&phi).transpose() * exp(&(phi + d))));
                let minus = log(&(exp(&phi).transpose() * exp(&(phi - d))));
                let column = (plus - minus) / (2.0 * eps);
                assert!((column - jr.column(k)).norm() < 1e-8, "{phi} {k}");
            }
        }
    }
}
