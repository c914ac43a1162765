//! Zhang's closed-form intrinsics from plane homographies (Z. Zhang, "A
//! flexible new technique for camera calibration", PAMI 2000, section 3.1
//! and appendix B), with zero skew imposed, and each view's pose from its
//! homography (section 3.1, eq. 3.1 there).

use nalgebra::{DMatrix, Matrix3, Rotation3, Vector3};

/// `v_ij` of Zhang's eq. 8 from columns `i`, `j` of `H`.
fn v_ij(h: &Matrix3<f64>, i: usize, j: usize) -> [f64; 6] {
    let (hi, hj) = (h.column(i), h.column(j));
    [
        hi[0] * hj[0],
        hi[0] * hj[1] + hi[1] * hj[0],
        hi[1] * hj[1],
        hi[2] * hj[0] + hi[0] * hj[2],
        hi[2] * hj[1] + hi[1] * hj[2],
        hi[2] * hj[2],
    ]
}

/// `[fx, fy, cx, cy]` from at least two homographies (three without the
/// zero-skew row; it is added here). `None` when the views do not
/// constrain the camera (e.g. all boards parallel to the sensor).
pub fn intrinsics_from_homographies(homographies: &[Matrix3<f64>]) -> Option<[f64; 4]> {
    if homographies.len() < 2 {
        return None;
    }
    // Scale each homography so the rows have comparable magnitude.
    let mut v = DMatrix::<f64>::zeros(2 * homographies.len() + 1, 6);
    for (k, h) in homographies.iter().enumerate() {
        let h = h / h.norm();
        let v12 = v_ij(&h, 0, 1);
        let v11 = v_ij(&h, 0, 0);
        let v22 = v_ij(&h, 1, 1);
        for c in 0..6 {
            v[(2 * k, c)] = v12[c];
            v[(2 * k + 1, c)] = v11[c] - v22[c];
        }
    }
    // Zero skew: B12 = 0 (weighted as one more view's row).
    v[(2 * homographies.len(), 1)] = 1.0;
    let eig = (v.transpose() * &v).symmetric_eigen();
    let b = eig.eigenvectors.column(eig.eigenvalues.imin()).into_owned();
    let (b11, b12, b22, b13, b23, b33) = (b[0], b[1], b[2], b[3], b[4], b[5]);
    // Appendix B.
    let denom = b11 * b22 - b12 * b12;
    let cy = (b12 * b13 - b11 * b23) / denom;
    let lambda = b33 - (b13 * b13 + cy * (b12 * b13 - b11 * b23)) / b11;
    let fx2 = lambda / b11;
    let fy2 = lambda * b11 / denom;
    if !(fx2 > 0.0 && fy2 > 0.0) {
        return None;
    }
    let (fx, fy) = (fx2.sqrt(), fy2.sqrt());
    let skew = -b12 * fx * fx * fy / lambda;
    let cx = skew * cy / fy - b13 * fx * fx / lambda;
    Some([fx, fy, cx, cy])
}

/// `(R_cam_board, t_cam_board)` from a homography and the intrinsics,
/// with the rotation projected onto SO(3) and the board in front.
pub fn pose_from_homography(h: &Matrix3<f64>, pinhole: [f64; 4]) -> (Matrix3<f64>, Vector3<f64>) {
    let [fx, fy, cx, cy] = pinhole;
    let k_inv = Matrix3::new(
        1.0 / fx,
        0.0,
        -cx / fx,
        0.0,
        1.0 / fy,
        -cy / fy,
        0.0,
        0.0,
        1.0,
    );
    let m = k_inv * h;
    let mut scale = 1.0 / m.column(0).norm();
    if (m.column(2) * scale).z < 0.0 {
        scale = -scale;
    }
    let r1 = m.column(0) * scale;
    let r2 = m.column(1) * scale;
    let t = m.column(2) * scale;
    let r3 = r1.cross(&r2);
    let q = Matrix3::from_columns(&[r1, r2, r3]);
    // Nearest rotation (Zhang appendix C) via SVD.
    let svd = q.svd(true, true);
    let (u, v_t) = (svd.u.expect("requested"), svd.v_t.expect("requested"));
    let mut r = u * v_t;
    if r.determinant() < 0.0 {
        r = -r;
    }
    (Rotation3::from_matrix_unchecked(r).into_inner(), t)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::homography::homography_dlt;
    use nalgebra::Vector2;

    #[test]
    fn recovers_intrinsics_and_poses_of_synthetic_views() {
        let pinhole = [520.0, 515.0, 322.0, 241.0];
        let k = Matrix3::new(520.0, 0.0, 322.0, 0.0, 515.0, 241.0, 0.0, 0.0, 1.0);
        let plane: Vec<Vector2<f64>> = (0..54)
            .map(|i| Vector2::new((i % 9) as f64 * 0.025, (i / 9) as f64 * 0.025))
            .collect();
        let views = [
            (Vector3::new(0.3, -0.2, 0.1), Vector3::new(-0.1, -0.05, 0.5)),
            (
                Vector3::new(-0.25, 0.3, -0.2),
                Vector3::new(-0.08, -0.1, 0.45),
            ),
            (Vector3::new(0.1, 0.4, 0.3), Vector3::new(-0.12, -0.02, 0.6)),
        ];
        let mut hs = Vec::new();
        for (rv, t) in &views {
            let r = Rotation3::from_scaled_axis(*rv).into_inner();
            let img: Vec<Vector2<f64>> = plane
                .iter()
                .map(|p| {
                    let q = k * (r * Vector3::new(p.x, p.y, 0.0) + t);
                    Vector2::new(q.x / q.z, q.y / q.z)
                })
                .collect();
            hs.push(homography_dlt(&plane, &img).expect("well-posed"));
        }
        let est = intrinsics_from_homographies(&hs).expect("three general views");
        for (e, t) in est.iter().zip(pinhole) {
            assert!((e - t).abs() < 1e-6 * t, "{est:?} vs {pinhole:?}");
        }
        let (r, t) = pose_from_homography(&hs[1], est);
        let r_true = Rotation3::from_scaled_axis(views[1].0).into_inner();
        assert!((r - r_true).norm() < 1e-8);
        assert!((t - views[1].1).norm() < 1e-8);
    }
}
