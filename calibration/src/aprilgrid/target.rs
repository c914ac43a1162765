//! The AprilGrid target as Kalibr describes it in `target.yaml`, and the
//! positions of its tag corners in the target frame.
//!
//! Target frame (metres): origin at the outer corner of tag 0's black
//! border, x along a row of tags, y up the columns, z out of the plane
//! (right-handed), the same convention as the detection CSVs Kalibr and yac
//! write. Tag `i` is in column `i % tag_cols` and row `i / tag_cols`; its
//! corners, for `corner_idx` 0..3, are its `(0,0)`, `(s,0)`, `(s,s)` and
//! `(0,s)` corners shifted by the tag pitch `s (1 + spacing)` per column
//! and row, `s` the tag size.

use std::path::Path;

use nalgebra::Vector3;
use rigslam::dataset::DatasetError;
use serde::Deserialize;

/// A Kalibr AprilGrid: `tag_rows x tag_cols` tag36h11 tags with black
/// squares at every tag corner.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AprilGridTarget {
    pub tag_rows: usize,
    pub tag_cols: usize,
    /// Edge of a tag's black square (border included), m.
    pub tag_size_m: f64,
    /// Gap between neighbouring tags as a fraction of `tag_size_m`; also
    /// the edge of the corner squares.
    pub tag_spacing_ratio: f64,
}

/// `target.yaml` as Kalibr writes it (`tagRows`, ...) or with the snake case
/// keys some tools use (`tag_rows`, ...); either spelling is accepted.
#[derive(Debug, Deserialize)]
struct TargetFile {
    #[serde(alias = "targetType")]
    target_type: String,
    #[serde(alias = "tagRows")]
    tag_rows: Option<usize>,
    #[serde(alias = "tagCols")]
    tag_cols: Option<usize>,
    #[serde(alias = "tagSize")]
    tag_size: Option<f64>,
    #[serde(alias = "tagSpacing")]
    tag_spacing: Option<f64>,
}

impl AprilGridTarget {
    /// Reads a Kalibr `target.yaml`; errors name the file and the key.
    pub fn from_yaml_file(path: &Path) -> Result<Self, DatasetError> {
        let text = std::fs::read_to_string(path).map_err(|e| DatasetError::io(path, e))?;
        Self::from_yaml_str(&text, path)
    }

    /// Parses the text of a `target.yaml`; `path` names it in errors.
    pub fn from_yaml_str(text: &str, path: &Path) -> Result<Self, DatasetError> {
        let file: TargetFile = serde_yaml::from_str(text).map_err(|e| {
            let line = e.location().map_or(0, |l| l.line());
            DatasetError::malformed(path, line, format!("not a Kalibr target file: {e}"))
        })?;
        let bad = |field: &str, message: &str| DatasetError::BadField {
            path: path.to_path_buf(),
            field: field.to_string(),
            message: message.to_string(),
        };
        if file.target_type != "aprilgrid" {
            return Err(bad(
                "target_type",
                &format!(
                    "{:?} is not supported here, only 'aprilgrid'",
                    file.target_type
                ),
            ));
        }
        let missing = |field: &str| {
            bad(field, "missing (Kalibr spells it tagRows/tagCols/tagSize/tagSpacing; tag_rows/... also accepted)")
        };
        let target = Self {
            tag_rows: file.tag_rows.ok_or_else(|| missing("tag_rows"))?,
            tag_cols: file.tag_cols.ok_or_else(|| missing("tag_cols"))?,
            tag_size_m: file.tag_size.ok_or_else(|| missing("tag_size"))?,
            tag_spacing_ratio: file.tag_spacing.ok_or_else(|| missing("tag_spacing"))?,
        };
        target
            .validate()
            .map_err(|(field, message)| bad(field, &message))?;
        Ok(target)
    }

    /// Checks the numbers make a printable grid whose ids fit in tag36h11.
    pub fn validate(&self) -> Result<(), (&'static str, String)> {
        if self.tag_rows == 0 || self.tag_cols == 0 {
            return Err(("tag_rows", "rows and columns must be at least 1".into()));
        }
        if self.tag_count() > super::tag36h11::CODES.len() {
            return Err((
                "tag_rows",
                format!(
                    "{} tags, tag36h11 has only {}",
                    self.tag_count(),
                    super::tag36h11::CODES.len()
                ),
            ));
        }
        if !(self.tag_size_m.is_finite() && self.tag_size_m > 0.0) {
            return Err((
                "tag_size",
                format!("{} is not a positive length in metres", self.tag_size_m),
            ));
        }
        if !(self.tag_spacing_ratio.is_finite()
            && self.tag_spacing_ratio > 0.0
            && self.tag_spacing_ratio < 2.0)
        {
            return Err((
                "tag_spacing",
                format!(
                    "{} is not a ratio of gap to tag size in (0, 2)",
                    self.tag_spacing_ratio
                ),
            ));
        }
        Ok(())
    }

    /// Tags on the grid.
    pub fn tag_count(&self) -> usize {
        self.tag_rows * self.tag_cols
    }

    /// Distance between neighbouring tags' origins, m.
    pub fn pitch_m(&self) -> f64 {
        self.tag_size_m * (1.0 + self.tag_spacing_ratio)
    }

    /// Corner `corner_idx` (0..3) of tag `tag_id` in the target frame, m
    /// (module doc). `None` for a tag not on this grid or a corner above 3.
    pub fn corner_m(&self, tag_id: usize, corner_idx: usize) -> Option<Vector3<f64>> {
        if tag_id >= self.tag_count() || corner_idx > 3 {
            return None;
        }
        let (col, row) = (
            (tag_id % self.tag_cols) as f64,
            (tag_id / self.tag_cols) as f64,
        );
        let s = self.tag_size_m;
        let (dx, dy) = [(0.0, 0.0), (s, 0.0), (s, s), (0.0, s)][corner_idx];
        Some(Vector3::new(
            col * self.pitch_m() + dx,
            row * self.pitch_m() + dy,
            0.0,
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn both_spellings_read_and_corners_follow_the_csv_convention() {
        let p = Path::new("target.yaml");
        let kalibr =
            "target_type: 'aprilgrid'\ntagCols: 6\ntagRows: 5\ntagSize: 0.088\ntagSpacing: 0.3\n";
        let snake =
            "target_type: aprilgrid\ntag_cols: 6\ntag_rows: 5\ntag_size: 0.088\ntag_spacing: 0.3\n";
        let a = AprilGridTarget::from_yaml_str(kalibr, p).expect("Kalibr spelling");
        let b = AprilGridTarget::from_yaml_str(snake, p).expect("snake case");
        assert_eq!(a, b);
        assert_eq!((a.tag_rows, a.tag_cols), (5, 6));
        // Tag 7 is column 1, row 1; its corner 2 is (s,s) from its origin.
        let c = a.corner_m(7, 2).expect("on the grid");
        let pitch = 0.088 * 1.3;
        assert!((c - Vector3::new(pitch + 0.088, pitch + 0.088, 0.0)).norm() < 1e-12);
        assert!(a.corner_m(30, 0).is_none());
        assert!(a.corner_m(0, 4).is_none());
    }

    #[test]
    fn wrong_type_missing_keys_and_nonsense_name_the_file_and_key() {
        let p = Path::new("/calib/target.yaml");
        let cases = [
            (
                "target_type: checkerboard\ntargetRows: 6\ntargetCols: 7\n",
                "target_type",
            ),
            (
                "target_type: aprilgrid\ntagCols: 6\ntagSize: 0.088\ntagSpacing: 0.3\n",
                "tag_rows",
            ),
            (
                "target_type: aprilgrid\ntagCols: 6\ntagRows: 6\ntagSize: -1\ntagSpacing: 0.3\n",
                "tag_size",
            ),
            ("tagCols: 6\n", "target_type"),
            ("target_type: aprilgrid\ntagCols: six\n", "tag"),
            ("[1, 2", "not a Kalibr target file"),
        ];
        for (text, expected) in cases {
            let message = AprilGridTarget::from_yaml_str(text, p)
                .expect_err(text)
                .to_string();
            assert!(message.contains("/calib/target.yaml"), "{message}");
            assert!(message.contains(expected), "{text:?}: {message}");
        }
    }
}
