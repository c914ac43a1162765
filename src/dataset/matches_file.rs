//! Text files of image-pair correspondences and of true relative motions,
//! the inputs of `rigslam bench essential`.
//!
//! Matches (e.g. `kitti/seq_a_matches.txt` in [`crate::shared_data`]): lines starting
//! with `#` are comments, one of them `# K fx fy cx cy: <4 numbers>`; then
//! per image pair `k n` followed by `n` quadruples `x1 y1 x2 y2` in pixels
//! (frame k to k+1), either on the same line or one quadruple per line.
//!
//! Relative ground truth (`seq_a_gt_rel.txt`): `k r00 .. r22 tx ty tz`,
//! `x_{k+1} = R x_k + t`.

use std::path::Path;

use nalgebra::{Matrix3, Vector2, Vector3};

use crate::camera::{CameraModel, PinholeRadtan};
use crate::text_file::text::data_lines;
use crate::text_file::DatasetError;

/// The correspondences of one image pair, in pixels.
#[derive(Debug, Clone, PartialEq)]
pub struct PixelMatches {
    /// Index of the first frame; the pair is (k, k+1).
    pub k: usize,
    /// Pixel positions in frame k.
    pub px1: Vec<Vector2<f64>>,
    /// Pixel positions of the same points in frame k+1.
    pub px2: Vec<Vector2<f64>>,
}

#[derive(Debug, Clone, PartialEq)]
/// A correspondence file: the camera and the matches of each image pair.
pub struct MatchesFile {
    /// `fx fy cx cy` in pixels.
    pub pinhole: [f64; 4],
    /// The image pairs in file order.
    pub pairs: Vec<PixelMatches>,
}

impl MatchesFile {
    /// A distortion-free camera from the header's intrinsics, rejecting
    /// non-finite or non-positive values with the header's line named.
    pub fn camera(&self, path: &Path) -> Result<CameraModel, DatasetError> {
        let [_, _, cx, cy] = self.pinhole;
        // The file does not give the image size; twice the principal point
        // is only used as a nominal size.
        let width = (2.0 * cx).ceil().clamp(1.0, 1e6) as u32;
        let height = (2.0 * cy).ceil().clamp(1.0, 1e6) as u32;
        PinholeRadtan::new(width.max(1), height.max(1), self.pinhole, [0.0; 5])
            .map(CameraModel::PinholeRadtan)
            .map_err(|e| DatasetError::bad_field(path, "# K fx fy cx cy", e.to_string()))
    }
}

fn parse_number(path: &Path, line_no: usize, token: &str, what: &str) -> Result<f64, DatasetError> {
    token.parse::<f64>().map_err(|_| {
        DatasetError::malformed(path, line_no, format!("{what} is not a number: {token:?}"))
    })
}

fn parse_count(
    path: &Path,
    line_no: usize,
    token: &str,
    what: &str,
) -> Result<usize, DatasetError> {
    token.parse::<usize>().map_err(|_| {
        DatasetError::malformed(
            path,
            line_no,
            format!("{what} is not a non-negative integer: {token:?}"),
        )
    })
}

/// Reads a matches file (format in the module documentation).
pub fn read_matches(path: &Path) -> Result<MatchesFile, DatasetError> {
    let text = std::fs::read_to_string(path).map_err(|e| DatasetError::io(path, e))?;
    parse_matches(path, &text)
}

/// Parses the text of a matches file; `path` only names it in errors.
pub fn parse_matches(path: &Path, text: &str) -> Result<MatchesFile, DatasetError> {
    let mut pinhole = None;
    for (i, line) in text.lines().enumerate() {
        if let Some(rest) = line.trim().strip_prefix('#') {
            if let Some(values) = rest.trim().strip_prefix("K fx fy cx cy:") {
                let tokens: Vec<&str> = values.split_whitespace().collect();
                if tokens.len() != 4 {
                    return Err(DatasetError::malformed(
                        path,
                        i + 1,
                        format!("`# K fx fy cx cy:` needs 4 numbers, found {}", tokens.len()),
                    ));
                }
                let mut k = [0.0; 4];
                for (slot, (token, name)) in k
                    .iter_mut()
                    .zip(tokens.iter().zip(["fx", "fy", "cx", "cy"]))
                {
                    *slot = parse_number(path, i + 1, token, name)?;
                }
                pinhole = Some(k);
            }
        }
    }
    let pinhole = pinhole.ok_or_else(|| {
        DatasetError::bad_field(
            path,
            "# K fx fy cx cy",
            "header line with the intrinsics is missing",
        )
    })?;

    let mut pairs = Vec::new();
    let mut lines = data_lines(text).peekable();
    while let Some((line_no, line)) = lines.next() {
        let tokens: Vec<&str> = line.split_whitespace().collect();
        if tokens.len() < 2 {
            return Err(DatasetError::malformed(
                path,
                line_no,
                "expected `k n` to start an image pair",
            ));
        }
        let k = parse_count(path, line_no, tokens[0], "frame index k")?;
        let n = parse_count(path, line_no, tokens[1], "match count n")?;
        // `n` is the file's word: reserve for no more matches than the
        // text can hold (one takes at least 8 bytes), whatever it says.
        let mut px1 = Vec::with_capacity(n.min(text.len() / 8));
        let mut px2 = Vec::with_capacity(n.min(text.len() / 8));
        let mut push = |line_no: usize, quad: &[&str]| -> Result<(), DatasetError> {
            let v: Vec<f64> = quad
                .iter()
                .zip(["x1", "y1", "x2", "y2"])
                .map(|(t, name)| parse_number(path, line_no, t, name))
                .collect::<Result<_, _>>()?;
            px1.push(Vector2::new(v[0], v[1]));
            px2.push(Vector2::new(v[2], v[3]));
            Ok(())
        };
        if tokens.len() == 2 {
            // One quadruple per following line.
            for j in 0..n {
                let Some((qline_no, qline)) = lines.next() else {
                    return Err(DatasetError::malformed(
                        path,
                        line_no,
                        format!("pair {k} announces {n} matches but the file ends after {j}"),
                    ));
                };
                let quad: Vec<&str> = qline.split_whitespace().collect();
                if quad.len() != 4 {
                    return Err(DatasetError::malformed(
                        path,
                        qline_no,
                        format!(
                            "expected a quadruple `x1 y1 x2 y2`, found {} fields",
                            quad.len()
                        ),
                    ));
                }
                push(qline_no, &quad)?;
            }
        } else {
            // In u128: `4 n` of a huge count must not overflow.
            let numbers = 4 * n as u128;
            if (tokens.len() - 2) as u128 != numbers {
                return Err(DatasetError::malformed(
                    path,
                    line_no,
                    format!(
                        "pair {k} announces {n} matches ({numbers} numbers) but the line has {} after `k n`",
                        tokens.len() - 2
                    ),
                ));
            }
            for quad in tokens[2..].chunks(4) {
                push(line_no, quad)?;
            }
        }
        pairs.push(PixelMatches { k, px1, px2 });
    }
    Ok(MatchesFile { pinhole, pairs })
}

/// One true relative motion `x_{k+1} = R x_k + t`.
#[derive(Debug, Clone, PartialEq)]
pub struct RelativeMotion {
    /// Index of the first frame; the motion is from frame k to k+1.
    pub k: usize,
    /// `R`: rotation from camera k's frame to camera k+1's.
    pub rotation_c2_c1: Matrix3<f64>,
    /// `t`: translation of `x_{k+1} = R x_k + t`, in the file's unit.
    pub t_c2_c1: Vector3<f64>,
}

/// Reads a relative ground-truth file (format in the module documentation).
pub fn read_relative_motions(path: &Path) -> Result<Vec<RelativeMotion>, DatasetError> {
    let text = std::fs::read_to_string(path).map_err(|e| DatasetError::io(path, e))?;
    parse_relative_motions(path, &text)
}

/// Parses the text of a relative ground-truth file; `path` only names it
/// in errors.
pub fn parse_relative_motions(
    path: &Path,
    text: &str,
) -> Result<Vec<RelativeMotion>, DatasetError> {
    let mut out = Vec::new();
    for (line_no, line) in data_lines(text) {
        let tokens: Vec<&str> = line.split_whitespace().collect();
        if tokens.len() != 13 {
            return Err(DatasetError::malformed(
                path,
                line_no,
                format!(
                    "expected 13 fields `k r00 .. r22 tx ty tz`, found {}",
                    tokens.len()
                ),
            ));
        }
        let k = parse_count(path, line_no, tokens[0], "frame index k")?;
        let mut v = [0.0; 12];
        for (j, slot) in v.iter_mut().enumerate() {
            *slot = parse_number(path, line_no, tokens[j + 1], &format!("field {}", j + 2))?;
        }
        out.push(RelativeMotion {
            k,
            rotation_c2_c1: Matrix3::new(v[0], v[1], v[2], v[3], v[4], v[5], v[6], v[7], v[8]),
            t_c2_c1: Vector3::new(v[9], v[10], v[11]),
        });
    }
    Ok(out)
}

/// Pixel correspondences to normalised image coordinates through
/// `camera`, dropping pairs a camera cannot unproject.
pub fn normalise(
    camera: &CameraModel,
    pair: &PixelMatches,
) -> (Vec<Vector2<f64>>, Vec<Vector2<f64>>) {
    pair.px1
        .iter()
        .zip(&pair.px2)
        .filter_map(|(a, b)| {
            let ra = camera.unproject(a)?;
            let rb = camera.unproject(b)?;
            Some((ra.xy() / ra.z, rb.xy() / rb.z))
        })
        .unzip()
}

/// Angle of `a⁻¹ b` in degrees, as `atan2(sin θ, cos θ)` from the
/// antisymmetric part and the trace (accurate for tiny angles, where
/// `acos` of the trace alone is not).
pub fn rotation_error_deg(a: &Matrix3<f64>, b: &Matrix3<f64>) -> f64 {
    let d = a.transpose() * b;
    let sin = 0.5
        * Vector3::new(
            d[(2, 1)] - d[(1, 2)],
            d[(0, 2)] - d[(2, 0)],
            d[(1, 0)] - d[(0, 1)],
        )
        .norm();
    let cos = 0.5 * (d.trace() - 1.0);
    sin.atan2(cos).to_degrees()
}

#[cfg(test)]
mod tests {
    use super::*;

    const HEADER: &str = "# comment\n# K fx fy cx cy: 700 700 600 180\n";

    #[test]
    fn parses_both_layouts() {
        let one_line = format!("{HEADER}0 2 1 2 3 4 5 6 7 8\n");
        let per_line = format!("{HEADER}0 2\n1 2 3 4\n5 6 7 8\n");
        let a = parse_matches(Path::new("m.txt"), &one_line).unwrap();
        let b = parse_matches(Path::new("m.txt"), &per_line).unwrap();
        assert_eq!(a, b);
        assert_eq!(a.pinhole, [700.0, 700.0, 600.0, 180.0]);
        assert_eq!(a.pairs[0].px2[1], Vector2::new(7.0, 8.0));
    }

    #[test]
    fn errors_name_the_line() {
        let short = format!("{HEADER}0 2 1 2 3 4 5 6 7\n");
        let e = parse_matches(Path::new("m.txt"), &short)
            .unwrap_err()
            .to_string();
        assert!(e.starts_with("m.txt:3:"), "{e}");
        let word = format!("{HEADER}0 1\n1 2 x 4\n");
        let e = parse_matches(Path::new("m.txt"), &word)
            .unwrap_err()
            .to_string();
        assert!(e.starts_with("m.txt:4:") && e.contains("x2"), "{e}");
        let truncated = format!("{HEADER}0 3\n1 2 3 4\n");
        let e = parse_matches(Path::new("m.txt"), &truncated)
            .unwrap_err()
            .to_string();
        assert!(e.starts_with("m.txt:3:"), "{e}");
        let e = parse_matches(Path::new("m.txt"), "0 1 1 2 3 4\n")
            .unwrap_err()
            .to_string();
        assert!(e.contains("K fx fy cx cy"), "{e}");
    }

    /// Found by reading, confirmed on the fuzz target: a huge match count
    /// reserved room for it (a capacity-overflow panic at 2^60) and
    /// overflowed `2 + 4 n` when the matches were on its line.
    #[test]
    fn a_huge_match_count_is_an_error() {
        for (text, at) in [
            (
                format!("{HEADER}0 1152921504606846976\n1 2 3 4\n"),
                "m.txt:3:",
            ),
            (
                format!("{HEADER}0 4611686018427387904 1 2 3 4\n"),
                "m.txt:3:",
            ),
            (
                format!("{HEADER}0 18446744073709551615 1 2 3 4\n"),
                "m.txt:3:",
            ),
        ] {
            let e = parse_matches(Path::new("m.txt"), &text)
                .unwrap_err()
                .to_string();
            assert!(e.starts_with(at) && e.contains("announces"), "{e}");
        }
    }

    #[test]
    fn nan_intrinsics_are_refused() {
        let text = "# K fx fy cx cy: nan 700 600 180\n0 1 1 2 3 4\n";
        let file = parse_matches(Path::new("m.txt"), text).unwrap();
        let e = file.camera(Path::new("m.txt")).unwrap_err().to_string();
        assert!(e.contains("fx") && e.contains("not a finite number"), "{e}");
    }
}
