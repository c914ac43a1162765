//! Plane-to-image homography by the normalised direct linear transform
//! (Hartley and Zisserman, "Multiple View Geometry", 2nd ed., alg. 4.2).

use nalgebra::{DMatrix, Matrix3, Vector2, Vector3};

/// Similarity that moves the points' centroid to the origin and their mean
/// distance to sqrt(2) (H&Z section 4.4.4).
fn normalising_transform(points: &[Vector2<f64>]) -> Matrix3<f64> {
    let n = points.len() as f64;
    let centroid = points.iter().fold(Vector2::zeros(), |s, p| s + p) / n;
    let mean_distance = points.iter().map(|p| (p - centroid).norm()).sum::<f64>() / n;
    let s = std::f64::consts::SQRT_2 / mean_distance.max(1e-12);
    Matrix3::new(
        s,
        0.0,
        -s * centroid.x,
        0.0,
        s,
        -s * centroid.y,
        0.0,
        0.0,
        1.0,
    )
}

/// `H` with `image ~ H [plane; 1]`, scaled so `H[(2,2)] = 1`. `None` for
/// fewer than 4 points or a degenerate configuration.
pub fn homography_dlt(plane: &[Vector2<f64>], image: &[Vector2<f64>]) -> Option<Matrix3<f64>> {
    if plane.len() != image.len() || plane.len() < 4 {
        return None;
    }
    let t_plane = normalising_transform(plane);
    let t_image = normalising_transform(image);
    let mut a = DMatrix::<f64>::zeros(2 * plane.len(), 9);
    for (k, (p, q)) in plane.iter().zip(image).enumerate() {
        let x = t_plane * Vector3::new(p.x, p.y, 1.0);
        let u = t_image * Vector3::new(q.x, q.y, 1.0);
        let (u, v) = (u.x / u.z, u.y / u.z);
        for c in 0..3 {
            a[(2 * k, c)] = -x[c];
            a[(2 * k, 6 + c)] = u * x[c];
            a[(2 * k + 1, 3 + c)] = -x[c];
            a[(2 * k + 1, 6 + c)] = v * x[c];
        }
    }
    let svd = (a.transpose() * &a).symmetric_eigen();
    let smallest = svd.eigenvalues.imin();
    let h = svd.eigenvectors.column(smallest);
    let h_normalised = Matrix3::from_row_slice(h.as_slice());
    let h = t_image.try_inverse()? * h_normalised * t_plane;
    (h[(2, 2)].abs() > 1e-15).then(|| h / h[(2, 2)])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn recovers_a_known_homography() {
        let truth = Matrix3::new(420.0, 15.0, 300.0, -8.0, 410.0, 220.0, 0.1, -0.05, 1.0);
        let plane: Vec<Vector2<f64>> = (0..20)
            .map(|k| Vector2::new((k % 5) as f64 * 0.1, (k / 5) as f64 * 0.1))
            .collect();
        let image: Vec<Vector2<f64>> = plane
            .iter()
            .map(|p| {
                let q = truth * Vector3::new(p.x, p.y, 1.0);
                Vector2::new(q.x / q.z, q.y / q.z)
            })
            .collect();
        let h = homography_dlt(&plane, &image).expect("well-posed");
        assert!((h - truth).norm() / truth.norm() < 1e-9, "{h} vs {truth}");
    }

    #[test]
    fn too_few_points_is_none() {
        let p = vec![Vector2::new(0.0, 0.0); 3];
        assert!(homography_dlt(&p, &p).is_none());
    }
}
