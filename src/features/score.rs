//! Corner strength from the structure tensor M = sum over a window of
//! [Ix^2 IxIy; IxIy Iy^2] with central-difference gradients:
//! Shi & Tomasi's min eigenvalue ("Good features to track", CVPR 1994) and
//! Harris & Stephens' det(M) - k trace(M)^2 (Alvey Vision Conf. 1988).
//! Evaluated only at candidate pixels, never over the whole image.

use crate::features::pyramid::GreyImage;

/// Structure tensor (sxx, sxy, syy) over the (2r+1)^2 window centred at
/// (x, y), averaged per pixel, gradients in grey levels per pixel. `None`
/// when the window plus one pixel for the gradient leaves the image.
#[inline]
pub fn structure_tensor(
    image: &GreyImage,
    x: usize,
    y: usize,
    r: usize,
) -> Option<(f32, f32, f32)> {
    let (w, h) = (image.width, image.height);
    if x < r + 1 || y < r + 1 || x + r + 1 >= w || y + r + 1 >= h {
        return None;
    }
    let (mut sxx, mut sxy, mut syy) = (0i32, 0i32, 0i32);
    for yy in y - r..=y + r {
        let up = image.row(yy - 1);
        let row = image.row(yy);
        let down = image.row(yy + 1);
        for xx in x - r..=x + r {
            // Twice the central difference, kept in integers.
            let gx = i32::from(row[xx + 1]) - i32::from(row[xx - 1]);
            let gy = i32::from(down[xx]) - i32::from(up[xx]);
            sxx += gx * gx;
            sxy += gx * gy;
            syy += gy * gy;
        }
    }
    let n = ((2 * r + 1) * (2 * r + 1)) as f32 * 4.0;
    Some((sxx as f32 / n, sxy as f32 / n, syy as f32 / n))
}

/// Smaller eigenvalue of the structure tensor (Shi-Tomasi); 0 outside.
#[inline]
pub fn shi_tomasi_score(image: &GreyImage, x: usize, y: usize, r: usize) -> f32 {
    structure_tensor(image, x, y, r).map_or(0.0, |(a, b, c)| {
        let half_trace = 0.5 * (a + c);
        let d = (0.25 * (a - c) * (a - c) + b * b).sqrt();
        (half_trace - d).max(0.0)
    })
}

/// Harris response det(M) - k trace(M)^2; 0 outside.
#[inline]
pub fn harris_score(image: &GreyImage, x: usize, y: usize, r: usize, k: f32) -> f32 {
    structure_tensor(image, x, y, r).map_or(0.0, |(a, b, c)| a * c - b * b - k * (a + c) * (a + c))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn image_from(w: usize, h: usize, f: impl Fn(usize, usize) -> u8) -> GreyImage {
        let data = (0..h)
            .flat_map(|y| (0..w).map(move |x| (x, y)))
            .map(|(x, y)| f(x, y))
            .collect();
        GreyImage::from_vec(w, h, data).unwrap()
    }

    #[test]
    fn a_ramp_has_one_eigenvalue_equal_to_its_squared_slope_and_the_other_zero() {
        // I = 3x: Ix = 3, Iy = 0 -> M = [9 0; 0 0].
        let img = image_from(40, 40, |x, _| (3 * x) as u8);
        let (a, b, c) = structure_tensor(&img, 20, 20, 3).unwrap();
        assert_eq!((a, b, c), (9.0, 0.0, 0.0));
        assert_eq!(shi_tomasi_score(&img, 20, 20, 3), 0.0);
        assert!(
            harris_score(&img, 20, 20, 3, 0.04) < 0.0,
            "an edge has negative Harris response"
        );
    }

    #[test]
    fn a_corner_scores_higher_than_an_edge_and_a_flat_patch() {
        let img = image_from(40, 40, |x, y| if x >= 20 && y >= 20 { 200 } else { 20 });
        let corner = shi_tomasi_score(&img, 20, 20, 3);
        let edge = shi_tomasi_score(&img, 20, 30, 3);
        let flat = shi_tomasi_score(&img, 8, 8, 3);
        assert!(corner > 100.0, "corner {corner}");
        assert_eq!(edge, 0.0);
        assert_eq!(flat, 0.0);
        assert!(harris_score(&img, 20, 20, 3, 0.04) > harris_score(&img, 20, 30, 3, 0.04));
    }

    #[test]
    fn the_eigenvalue_matches_the_closed_form_of_a_rotated_tensor() {
        // I = 2x + y: M = [4 2; 2 1] (rank one) -> min eigenvalue 0, max 5.
        let img = image_from(30, 30, |x, y| (2 * x + y) as u8);
        let (a, b, c) = structure_tensor(&img, 15, 15, 2).unwrap();
        assert_eq!((a, b, c), (4.0, 2.0, 1.0));
        assert!(shi_tomasi_score(&img, 15, 15, 2).abs() < 1e-5);
    }

    #[test]
    fn windows_off_the_image_score_zero() {
        let img = image_from(10, 10, |x, y| (x * y) as u8);
        assert_eq!(shi_tomasi_score(&img, 1, 5, 3), 0.0);
        assert_eq!(harris_score(&img, 5, 9, 3, 0.04), 0.0);
    }
}
