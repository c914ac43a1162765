//! Saved maps: the landmarks of a solved edge map with
//! their covariance and descriptor, written at the end of a run
//! (`rigslam run --absolute --save-map FILE`) and loaded to localise in
//! (`--load-map FILE`, [`super::localise`]).
//!
//! Text, one landmark per line after a header line:
//!
//! ```text
//! # rigslam map v1 landmarks N
//! id x y z c00 c01 c02 c11 c12 c22 descriptor
//! ```
//!
//! Positions in the map's world frame, m; the covariance's upper triangle,
//! m²; the descriptor as 64 hex digits (256 bits, word 0 first, each word
//! big-endian) or `-` when the landmark has none. The covariance is the
//! landmark's given its neighbours in the map (the inverse of its diagonal
//! block of A): the local precision a robot localising against nearby
//! landmarks relies on, not the drift from the map's reference.

use std::fmt::Write as _;
use std::io::{BufRead, BufReader, Write};
use std::path::{Path, PathBuf};

use nalgebra::{Matrix3, Vector3};

use crate::features::orb::Descriptor;

const HEADER: &str = "# rigslam map v1 landmarks";

/// Landmarks reserved for up front at most, whatever the header announces.
const PREALLOCATED_LANDMARKS: usize = 4096;

/// One landmark of a saved map.
#[derive(Clone, Debug, PartialEq)]
pub struct MapLandmark {
    /// Landmark id in the map.
    pub id: u32,
    /// Position in the map's world frame, m.
    pub position_m: Vector3<f64>,
    /// Covariance of the position given its neighbours in the map, m^2.
    pub covariance_m2: Matrix3<f64>,
    /// ORB descriptor for recognition, when the landmark has one.
    pub descriptor: Option<Descriptor>,
}

/// A saved map.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SavedMap {
    /// The landmarks, in file order.
    pub landmarks: Vec<MapLandmark>,
}

#[derive(Debug, thiserror::Error)]
/// Why a map file could not be written or read.
pub enum MapFileError {
    #[error("{path}: {source}")]
    /// The file could not be created, written or read.
    Io {
        /// The file.
        path: PathBuf,
        /// The I/O error.
        source: std::io::Error,
    },
    #[error("{path}:{line}: {message}")]
    /// A line does not parse (or the header is wrong).
    Parse {
        /// The file.
        path: PathBuf,
        /// 1-based line number.
        line: usize,
        /// What is wrong with it.
        message: String,
    },
}

fn hex(d: &Descriptor) -> String {
    let mut s = String::with_capacity(64);
    for word in d {
        let _ = write!(s, "{word:016x}");
    }
    s
}

fn parse_hex(text: &str) -> Option<Descriptor> {
    if text.len() != 64 || !text.is_ascii() {
        return None;
    }
    let mut d = [0u64; 4];
    for (k, word) in d.iter_mut().enumerate() {
        *word = u64::from_str_radix(&text[16 * k..16 * (k + 1)], 16).ok()?;
    }
    Some(d)
}

impl SavedMap {
    /// Writes the map to `path` in the text format above (creating or truncating the file).
    pub fn write(&self, path: &Path) -> Result<(), MapFileError> {
        let io = |source| MapFileError::Io {
            path: path.to_path_buf(),
            source,
        };
        let file = std::fs::File::create(path).map_err(io)?;
        let mut out = std::io::BufWriter::new(file);
        writeln!(out, "{HEADER} {}", self.landmarks.len()).map_err(io)?;
        writeln!(
            out,
            "# id x y z c00 c01 c02 c11 c12 c22 descriptor (m, m^2, 64 hex digits or -)"
        )
        .map_err(io)?;
        for l in &self.landmarks {
            let (p, c) = (&l.position_m, &l.covariance_m2);
            // `{:e}` of an f64 round-trips exactly.
            writeln!(
                out,
                "{} {:e} {:e} {:e} {:e} {:e} {:e} {:e} {:e} {:e} {}",
                l.id,
                p.x,
                p.y,
                p.z,
                c[(0, 0)],
                c[(0, 1)],
                c[(0, 2)],
                c[(1, 1)],
                c[(1, 2)],
                c[(2, 2)],
                l.descriptor.as_ref().map_or_else(|| "-".to_string(), hex)
            )
            .map_err(io)?;
        }
        out.flush().map_err(io)
    }

    /// Reads a map written by [`Self::write`].
    pub fn read(path: &Path) -> Result<Self, MapFileError> {
        let file = std::fs::File::open(path).map_err(|source| MapFileError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        Self::read_from(BufReader::new(file), path)
    }

    /// Reads a map from `reader`; `path` names it in errors.
    pub fn read_from(reader: impl BufRead, path: &Path) -> Result<Self, MapFileError> {
        let parse = |line: usize, message: String| MapFileError::Parse {
            path: path.to_path_buf(),
            line,
            message,
        };
        let mut lines = reader.lines().enumerate();
        let (_, first) = lines
            .next()
            .ok_or_else(|| parse(1, "empty file: not a rigslam map".into()))?;
        let first = first.map_err(|source| MapFileError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        let expected: usize = first
            .strip_prefix(HEADER)
            .and_then(|n| n.trim().parse().ok())
            .ok_or_else(|| parse(1, format!("expected `{HEADER} N`, found `{first}`")))?;
        // The count is the file's word, checked against the lines at the
        // end: reserve for what a file of any size plausibly holds, not
        // for whatever the header says (2^60 would abort the process).
        let mut landmarks = Vec::with_capacity(expected.min(PREALLOCATED_LANDMARKS));
        let mut seen = std::collections::HashSet::new();
        for (index, text) in lines {
            let number = index + 1;
            let text = text.map_err(|source| MapFileError::Io {
                path: path.to_path_buf(),
                source,
            })?;
            let text = text.trim();
            if text.is_empty() || text.starts_with('#') {
                continue;
            }
            let fields: Vec<&str> = text.split_whitespace().collect();
            if fields.len() != 11 {
                return Err(parse(
                    number,
                    format!(
                        "{} fields, expected 11 (id, 3 position, 6 covariance, descriptor)",
                        fields.len()
                    ),
                ));
            }
            let id: u32 = fields[0].parse().map_err(|_| {
                parse(
                    number,
                    format!("landmark id `{}` is not a number", fields[0]),
                )
            })?;
            if !seen.insert(id) {
                return Err(parse(number, format!("landmark {id} appears twice")));
            }
            let mut v = [0.0f64; 9];
            for (k, slot) in v.iter_mut().enumerate() {
                *slot = fields[k + 1]
                    .parse::<f64>()
                    .ok()
                    .filter(|x| x.is_finite())
                    .ok_or_else(|| {
                        parse(
                            number,
                            format!("field {} `{}` is not a finite number", k + 2, fields[k + 1]),
                        )
                    })?;
            }
            let covariance_m2 = Matrix3::new(v[3], v[4], v[5], v[4], v[6], v[7], v[5], v[7], v[8]);
            if covariance_m2.cholesky().is_none() {
                return Err(parse(
                    number,
                    format!("the covariance of landmark {id} is not positive definite"),
                ));
            }
            let descriptor = match fields[10] {
                "-" => None,
                text => Some(parse_hex(text).ok_or_else(|| {
                    parse(
                        number,
                        format!("descriptor `{text}` is not 64 hex digits or -"),
                    )
                })?),
            };
            landmarks.push(MapLandmark {
                id,
                position_m: Vector3::new(v[0], v[1], v[2]),
                covariance_m2,
                descriptor,
            });
        }
        if landmarks.len() != expected {
            return Err(parse(
                1,
                format!(
                    "the header announces {expected} landmarks, the file holds {} (truncated?)",
                    landmarks.len()
                ),
            ));
        }
        Ok(Self { landmarks })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample() -> SavedMap {
        SavedMap {
            landmarks: vec![
                MapLandmark {
                    id: 0,
                    position_m: Vector3::new(1.0 / 3.0, -2.5e-7, 1e5),
                    covariance_m2: Matrix3::new(2.0, 0.1, 0.0, 0.1, 1.0, -0.2, 0.0, -0.2, 0.5)
                        * 1e-4,
                    descriptor: Some([u64::MAX, 0, 0x0123_4567_89ab_cdef, 42]),
                },
                MapLandmark {
                    id: 7,
                    position_m: Vector3::new(0.1, 0.2, 0.3),
                    covariance_m2: Matrix3::identity() * 0.01,
                    descriptor: None,
                },
            ],
        }
    }

    #[test]
    fn a_map_round_trips_exactly() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("map.txt");
        let map = sample();
        map.write(&path).expect("write");
        assert_eq!(SavedMap::read(&path).expect("read"), map);
    }

    #[test]
    fn bad_files_say_which_line_and_why() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("map.txt");
        sample().write(&path).expect("write");
        let good = std::fs::read_to_string(&path).expect("read");
        let lines: Vec<&str> = good.lines().collect();
        let with_line = |index: usize, replacement: &str| {
            let mut l = lines.clone();
            l[index] = replacement;
            l.join("\n")
        };
        let with_line3 = |replacement: &str| with_line(2, replacement);
        let duplicate = lines[3].replacen("7 ", "0 ", 1);
        let cases = [
            (String::new(), ":1:", "empty"),
            ("hello\n".to_string(), ":1:", "expected"),
            (lines[..3].join("\n"), ":1:", "truncated"),
            (with_line3("0 1 2 3"), ":3:", "4 fields"),
            (with_line3("0 1 2 nan 1 0 0 1 0 1 -"), ":3:", "not a finite"),
            (
                with_line3("0 1 2 3 1 0 0 -1 0 1 -"),
                ":3:",
                "not positive definite",
            ),
            (with_line3("0 1 2 3 1 0 0 1 0 1 abc"), ":3:", "64 hex"),
            (with_line3("x 1 2 3 1 0 0 1 0 1 -"), ":3:", "not a number"),
            (with_line(3, &duplicate), ":4:", "twice"),
        ];
        for (text, line, why) in cases {
            std::fs::write(&path, &text).expect("write");
            let err = SavedMap::read(&path).unwrap_err().to_string();
            assert!(err.contains(line) && err.contains(why), "{text:?}: {err}");
        }
        let missing = SavedMap::read(&dir.path().join("none.txt")).unwrap_err();
        assert!(missing.to_string().contains("none.txt"), "{missing}");
    }

    /// Found by fuzzing: a header announcing 2^60 (or any count from
    /// 2^24) landmarks made the reader reserve room for 2^24 of them,
    /// 2.4 GB, before reading a line. The error stays; the allocation is
    /// caught by `tests/fuzz_corpus.rs` on `corpus/map_file/huge_count.txt`.
    #[test]
    fn a_huge_landmark_count_is_an_error_not_an_allocation() {
        for count in ["1152921504606846976", "16777216", "18446744073709551615"] {
            let text = format!("{HEADER} {count}\n0 1 2 3 1 0 0 1 0 1 -\n");
            let err = SavedMap::read_from(text.as_bytes(), Path::new("huge.map"))
                .unwrap_err()
                .to_string();
            assert!(
                err.starts_with("huge.map:1:") && err.contains("the file holds 1"),
                "{err}"
            );
        }
    }
}
