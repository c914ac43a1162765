//! Saved maps: the landmarks of a solved edge map with
//! their covariance and descriptor, written at the end of a run
//! (`rigslam run --absolute --save-map FILE`) and loaded to localise in
//! (`--load-map FILE`, [`super::localise`]).
//!
//! Text, one landmark per line between a header line and a checksum line:
//!
//! ```text
//! # rigslam map v3 landmarks N
//! id x y z c00 c01 c02 c11 c12 c22 descriptor attitude
//! # crc32 1a2b3c4d
//! ```
//!
//! The CRC-32 (IEEE) covers every byte before its line, so a file cut
//! short or damaged on disk is refused rather than half read; files are
//! written atomically ([`crate::text_file::write_atomically`]), so a save
//! interrupted by a crash or power loss leaves the previous map. Maps of
//! the first version (no checksum line) are still read.
//!
//! Positions in the map's world frame, m; the covariance's upper triangle,
//! m²; the descriptor as 64 hex digits (256 bits, word 0 first, each word
//! big-endian) or `-` when the landmark has none. The covariance is the
//! landmark's given its neighbours in the map (the inverse of its diagonal
//! block of A): the local precision a robot localising against nearby
//! landmarks relies on, not the drift from the map's reference. The
//! attitude is what the mapping run's attitude error put in the landmark
//! ([`super::mapping_attitude`]): 21 numbers, the upper triangle of
//! `Σ Q_j` (rad²), the nine entries of `Σ [p_j]× Q_j` row by row (m rad²)
//! and the upper triangle of `Σ [p_j]× Q_j [p_j]×ᵀ` (m² rad²), positions
//! from the landmark; or `-` when the run published no attitude
//! covariance. Maps of the second version (no attitude field) are read
//! without it.

use std::fmt::Write as _;
use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};

use nalgebra::{Matrix3, Vector3};

use super::mapping_attitude::AttitudeMoments;
use crate::features::orb::Descriptor;

const HEADER: &str = "# rigslam map v3 landmarks";
/// The header of maps written before the attitude field.
const HEADER_V2: &str = "# rigslam map v2 landmarks";
/// The header of maps written before the checksum.
const HEADER_V1: &str = "# rigslam map v1 landmarks";
/// The start of the last line of a map: the checksum of what precedes it.
const CHECKSUM: &str = "# crc32 ";

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
    /// What the mapping run's attitude error put in the landmark, its
    /// positions from the landmark (None when the run published no
    /// attitude covariance, or the map predates it).
    pub attitude: Option<AttitudeMoments>,
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

/// Numbers of a landmark's attitude field.
const ATTITUDE_FIELDS: usize = 21;

/// The attitude field's numbers: the upper triangle of the steps, the
/// first moment row by row, the upper triangle of the second.
fn attitude_fields(a: &AttitudeMoments) -> [f64; ATTITUDE_FIELDS] {
    let (s, f, m) = (&a.steps_rad2, &a.first_m_rad2, &a.second_m2_rad2);
    [
        s[(0, 0)],
        s[(0, 1)],
        s[(0, 2)],
        s[(1, 1)],
        s[(1, 2)],
        s[(2, 2)],
        f[(0, 0)],
        f[(0, 1)],
        f[(0, 2)],
        f[(1, 0)],
        f[(1, 1)],
        f[(1, 2)],
        f[(2, 0)],
        f[(2, 1)],
        f[(2, 2)],
        m[(0, 0)],
        m[(0, 1)],
        m[(0, 2)],
        m[(1, 1)],
        m[(1, 2)],
        m[(2, 2)],
    ]
}

fn attitude_from_fields(v: &[f64; ATTITUDE_FIELDS]) -> AttitudeMoments {
    let symmetric = |u: &[f64]| Matrix3::new(u[0], u[1], u[2], u[1], u[3], u[4], u[2], u[4], u[5]);
    AttitudeMoments {
        steps_rad2: symmetric(&v[0..6]),
        first_m_rad2: Matrix3::from_row_slice(&v[6..15]),
        second_m2_rad2: symmetric(&v[15..21]),
    }
}

impl SavedMap {
    /// Writes the map to `path` in the text format above, atomically:
    /// a reader (or the next start after a crash) finds the old file or
    /// the new one, whole.
    pub fn write(&self, path: &Path) -> Result<(), MapFileError> {
        crate::text_file::write_atomically(path, self.to_text().as_bytes()).map_err(|source| {
            MapFileError::Io {
                path: path.to_path_buf(),
                source,
            }
        })
    }

    /// The file's text, checksum line included.
    pub fn to_text(&self) -> String {
        let mut out = String::with_capacity(160 * self.landmarks.len() + 128);
        let _ = writeln!(out, "{HEADER} {}", self.landmarks.len());
        let _ = writeln!(
            out,
            "# id x y z c00 c01 c02 c11 c12 c22 descriptor attitude (m, m^2, 64 hex digits or -, 21 numbers or -)"
        );
        for l in &self.landmarks {
            let (p, c) = (&l.position_m, &l.covariance_m2);
            // `{:e}` of an f64 round-trips exactly.
            let _ = write!(
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
            );
            match &l.attitude {
                None => out.push_str(" -"),
                Some(a) => {
                    for v in attitude_fields(a) {
                        let _ = write!(out, " {v:e}");
                    }
                }
            }
            out.push('\n');
        }
        let crc = crc32fast::hash(out.as_bytes());
        let _ = writeln!(out, "{CHECKSUM}{crc:08x}");
        out
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
        let io = |source| MapFileError::Io {
            path: path.to_path_buf(),
            source,
        };
        let mut reader = reader;
        let mut crc = crc32fast::Hasher::new();
        let mut raw = String::new();
        // One line with its end as it is in the file (for the checksum).
        let mut next_line = |raw: &mut String| -> Result<bool, MapFileError> {
            raw.clear();
            Ok(reader.read_line(raw).map_err(io)? > 0)
        };
        if !next_line(&mut raw)? {
            return Err(parse(1, "empty file: not a rigslam map".into()));
        }
        crc.update(raw.as_bytes());
        let first = raw.trim_end();
        let (expected, version): (usize, u8) = match first
            .strip_prefix(HEADER)
            .map(|n| (n, 3))
            .or_else(|| first.strip_prefix(HEADER_V2).map(|n| (n, 2)))
            .or_else(|| first.strip_prefix(HEADER_V1).map(|n| (n, 1)))
            .and_then(|(n, version)| Some((n.trim().parse().ok()?, version)))
        {
            Some(header) => header,
            None => {
                let shown: String = first.chars().take(80).collect();
                return Err(parse(
                    1,
                    format!("not a rigslam map: expected `{HEADER} N`, found `{shown}`"),
                ));
            }
        };
        // The count is the file's word, checked against the lines at the
        // end: reserve for what a file of any size plausibly holds, not
        // for whatever the header says (2^60 would abort the process).
        let mut landmarks = Vec::with_capacity(expected.min(PREALLOCATED_LANDMARKS));
        let mut seen = std::collections::HashSet::new();
        let mut stated_crc = None;
        let mut number = 1;
        while next_line(&mut raw)? {
            number += 1;
            let text = raw.trim();
            if let Some(hex) = text.strip_prefix(CHECKSUM.trim_end()) {
                stated_crc = Some((number, hex.trim().to_string()));
                if next_line(&mut raw)? && !raw.trim().is_empty() {
                    return Err(parse(number + 1, "text after the checksum line".into()));
                }
                break;
            }
            crc.update(raw.as_bytes());
            if text.is_empty() || text.starts_with('#') {
                continue;
            }
            let fields: Vec<&str> = text.split_whitespace().collect();
            let expected_fields: &[usize] = if version >= 3 {
                &[12, 11 + ATTITUDE_FIELDS]
            } else {
                &[11]
            };
            if !expected_fields.contains(&fields.len()) {
                let what = if version >= 3 {
                    "12 or 32 (id, 3 position, 6 covariance, descriptor, attitude: - or 21)"
                } else {
                    "11 (id, 3 position, 6 covariance, descriptor)"
                };
                return Err(parse(
                    number,
                    format!("{} fields, expected {what}", fields.len()),
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
            // Fields `first..first + out.len()` (0-based) as finite numbers.
            let finite = |first: usize, out: &mut [f64]| {
                for (k, slot) in out.iter_mut().enumerate() {
                    let text = fields[first + k];
                    *slot = text
                        .parse::<f64>()
                        .ok()
                        .filter(|x| x.is_finite())
                        .ok_or_else(|| {
                            parse(
                                number,
                                format!("field {} `{text}` is not a finite number", first + k + 1),
                            )
                        })?;
                }
                Ok(())
            };
            let mut v = [0.0f64; 9];
            finite(1, &mut v)?;
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
            let attitude = match &fields[11..] {
                [] | ["-"] => None,
                numbers if numbers.len() == ATTITUDE_FIELDS => {
                    let mut a = [0.0f64; ATTITUDE_FIELDS];
                    finite(11, &mut a)?;
                    let moments = attitude_from_fields(&a);
                    if !moments.is_usable() {
                        return Err(parse(
                            number,
                            format!("the attitude sums of landmark {id} are not covariances"),
                        ));
                    }
                    Some(moments)
                }
                other => {
                    return Err(parse(
                        number,
                        format!(
                            "attitude field `{}` is not - or 21 numbers",
                            other.join(" ")
                        ),
                    ))
                }
            };
            landmarks.push(MapLandmark {
                id,
                position_m: Vector3::new(v[0], v[1], v[2]),
                covariance_m2,
                descriptor,
                attitude,
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
        if version >= 2 {
            let computed = format!("{:08x}", crc.finalize());
            match stated_crc {
                None => {
                    return Err(parse(
                        number,
                        "no checksum line at the end (truncated?)".into(),
                    ))
                }
                Some((line, stated)) if stated != computed => {
                    return Err(parse(
                        line,
                        format!(
                            "checksum {stated} does not match the contents ({computed}): the file is damaged"
                        ),
                    ))
                }
                Some(_) => {}
            }
        }
        Ok(Self { landmarks })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The sums of two attitude steps taken at two places.
    fn two_steps() -> AttitudeMoments {
        let steps = [
            (
                Matrix3::new(3.0, 0.2, 0.1, 0.2, 2.0, -0.3, 0.1, -0.3, 9.0) * 1e-7,
                Vector3::new(1.0 / 3.0, -2.0, 0.5),
            ),
            (
                Matrix3::from_diagonal(&Vector3::new(1e-8, 2e-8, 4e-6)),
                Vector3::new(4.0, 1.0, -0.25),
            ),
        ];
        let mut sums = AttitudeMoments::default();
        for (q, p) in steps {
            let x = p.cross_matrix();
            sums.steps_rad2 += q;
            sums.first_m_rad2 += x * q;
            sums.second_m2_rad2 += x * q * x.transpose();
        }
        // The file holds the upper triangle: exactly symmetric, as read.
        sums.second_m2_rad2 = (sums.second_m2_rad2 + sums.second_m2_rad2.transpose()) * 0.5;
        assert!(sums.is_usable());
        sums
    }

    fn sample() -> SavedMap {
        SavedMap {
            landmarks: vec![
                MapLandmark {
                    id: 0,
                    position_m: Vector3::new(1.0 / 3.0, -2.5e-7, 1e5),
                    covariance_m2: Matrix3::new(2.0, 0.1, 0.0, 0.1, 1.0, -0.2, 0.0, -0.2, 0.5)
                        * 1e-4,
                    descriptor: Some([u64::MAX, 0, 0x0123_4567_89ab_cdef, 42]),
                    attitude: Some(two_steps()),
                },
                MapLandmark {
                    id: 7,
                    position_m: Vector3::new(0.1, 0.2, 0.3),
                    covariance_m2: Matrix3::identity() * 0.01,
                    descriptor: None,
                    attitude: None,
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

    /// A version 3 line of landmark 0 whose attitude field starts with
    /// `first` (the rest a valid diagonal).
    fn attitude_line(first: &str) -> String {
        let mut fields = vec!["0"; 21];
        fields[0] = first;
        for k in [3, 5, 15, 18, 20] {
            fields[k] = "1e-6";
        }
        format!("0 1 2 3 1 0 0 1 0 1 - {}", fields.join(" "))
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
            (
                with_line3("0 1 2 nan 1 0 0 1 0 1 - -"),
                ":3:",
                "not a finite",
            ),
            (
                with_line3("0 1 2 3 1 0 0 -1 0 1 - -"),
                ":3:",
                "not positive definite",
            ),
            (with_line3("0 1 2 3 1 0 0 1 0 1 abc -"), ":3:", "64 hex"),
            (with_line3("x 1 2 3 1 0 0 1 0 1 - -"), ":3:", "not a number"),
            (with_line(3, &duplicate), ":4:", "twice"),
            (
                with_line3("0 1 2 3 1 0 0 1 0 1 - 1 2"),
                ":3:",
                "13 fields, expected 12 or 32",
            ),
            (with_line3(&attitude_line("nan")), ":3:", "field 12 `nan`"),
            (
                with_line3(&attitude_line("-1")),
                ":3:",
                "attitude sums of landmark 0 are not covariances",
            ),
            (
                // A first moment no steps can give with these two sums.
                with_line3(&attitude_line("1e-6").replacen(
                    " 0 0 0 0 0 0 0 0 0 1e-6",
                    " 5 0 0 0 0 0 0 0 0 1e-6",
                    1,
                )),
                ":3:",
                "attitude sums of landmark 0 are not covariances",
            ),
            (
                with_line3(&format!("0 1 2 3 1 0 0 1 0 1 - {}", ["0"; 20].join(" "))),
                ":3:",
                "31 fields",
            ),
            (
                with_line3("0 1 2 3 1 0 0 1 0 1 - x"),
                ":3:",
                "not - or 21 numbers",
            ),
        ];
        for (text, line, why) in cases {
            std::fs::write(&path, &text).expect("write");
            let err = SavedMap::read(&path).unwrap_err().to_string();
            assert!(err.contains(line) && err.contains(why), "{text:?}: {err}");
        }
        let missing = SavedMap::read(&dir.path().join("none.txt")).unwrap_err();
        assert!(missing.to_string().contains("none.txt"), "{missing}");
    }

    #[test]
    fn damage_and_truncation_are_caught_by_the_checksum() {
        let text = sample().to_text();
        let read = |t: &str| SavedMap::read_from(t.as_bytes(), Path::new("m.map"));
        assert_eq!(read(&text).expect("whole"), sample());
        // One digit changed: every line still parses, the sum does not.
        let damaged = text.replacen("1e-1 2e-1", "1e-1 3e-1", 1);
        assert_ne!(damaged, text);
        let e = read(&damaged).unwrap_err().to_string();
        assert!(e.contains("checksum") && e.contains("damaged"), "{e}");
        // Cut before the checksum line.
        let cut = &text[..text.rfind("# crc32").expect("checksum line")];
        let e = read(cut).unwrap_err().to_string();
        assert!(e.contains("no checksum line"), "{e}");
        // Cut inside the checksum line.
        let e = read(&text[..text.len() - 3]).unwrap_err().to_string();
        assert!(e.contains("checksum"), "{e}");
        let e = read(&format!("{text}0 1 2 3 1 0 0 1 0 1 -\n"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("after the checksum"), "{e}");
        // Somebody else's file.
        let e = read("%YAML 1.2\ncam0:\n").unwrap_err().to_string();
        assert!(
            e.contains("not a rigslam map") && e.contains("%YAML"),
            "{e}"
        );
        // Maps of the earlier versions (no attitude field; the first
        // without a checksum) are still read, without the attitude.
        let without_attitude = SavedMap {
            landmarks: sample()
                .landmarks
                .into_iter()
                .map(|l| MapLandmark {
                    attitude: None,
                    ..l
                })
                .collect(),
        };
        let old_lines: Vec<String> = without_attitude
            .to_text()
            .lines()
            .filter(|l| !l.starts_with("# crc32"))
            .map(|l| l.strip_suffix(" -").unwrap_or(l).to_string())
            .collect();
        let v1: String = old_lines
            .iter()
            .map(|l| format!("{}\n", l.replace(HEADER, HEADER_V1)))
            .collect();
        assert_eq!(read(&v1).expect("v1"), without_attitude);
        let mut v2: String = old_lines
            .iter()
            .map(|l| format!("{}\n", l.replace(HEADER, HEADER_V2)))
            .collect();
        let crc = crc32fast::hash(v2.as_bytes());
        v2.push_str(&format!("{CHECKSUM}{crc:08x}\n"));
        assert_eq!(read(&v2).expect("v2"), without_attitude);
        // A version 2 line with an attitude field is not version 2.
        let e = read(&text.replace(HEADER, HEADER_V2))
            .unwrap_err()
            .to_string();
        assert!(e.contains("expected 11"), "{e}");
    }

    /// A map of `n` landmarks whose every number depends on `seed`.
    fn big(n: u32, seed: f64) -> SavedMap {
        SavedMap {
            landmarks: (0..n)
                .map(|id| MapLandmark {
                    id,
                    position_m: Vector3::new(seed, f64::from(id), -seed * f64::from(id)),
                    covariance_m2: Matrix3::identity() * (1e-4 + 1e-9 * f64::from(id)),
                    descriptor: Some([u64::from(id), seed.to_bits(), 7, 9]),
                    attitude: None,
                })
                .collect(),
        }
    }

    const CHILD_ENV: &str = "RIGSLAM_MAP_WRITER_CHILD";

    /// Landmarks of the maps the child saves (about 6 MB each).
    const LARGE: u32 = 40_000;

    /// Not a test of its own: the process the test below kills. It saves
    /// two large maps in turn to the path in RIGSLAM_MAP_WRITER_CHILD
    /// until it is killed.
    #[test]
    #[ignore = "run by saving_a_map_survives_being_killed_mid_write"]
    fn map_writer_child() {
        let Some(path) = std::env::var_os(CHILD_ENV) else {
            return;
        };
        let maps = [big(LARGE, 1.0), big(LARGE, 2.0)];
        for k in 0.. {
            maps[k % 2].write(Path::new(&path)).expect("save");
        }
    }

    /// The map is saved while the robot runs, so a save may be cut by
    /// SIGKILL or power loss: the file must then hold a whole map (the one
    /// before or the one being saved), never a part. A process that saves
    /// maps in a loop is killed at several moments, and the file is read.
    #[test]
    fn saving_a_map_survives_being_killed_mid_write() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("robot.map");
        let first = big(10, 0.0);
        first.write(&path).expect("first save");
        let candidates = [first, big(LARGE, 1.0), big(LARGE, 2.0)];
        // Kills spread over several save cycles: with a plain (truncate,
        // then write) save about one kill in ten lands inside a write.
        for delay_ms in (0..30).map(|k| 40 + 23 * k) {
            let mut child = std::process::Command::new(std::env::current_exe().expect("exe"))
                .args([
                    "--ignored",
                    "--exact",
                    "absolute::map_file::tests::map_writer_child",
                ])
                .env(CHILD_ENV, &path)
                .stdout(std::process::Stdio::null())
                .stderr(std::process::Stdio::null())
                .spawn()
                .expect("spawn the writer");
            std::thread::sleep(std::time::Duration::from_millis(delay_ms));
            child.kill().expect("SIGKILL");
            let _ = child.wait();
            let read = SavedMap::read(&path)
                .unwrap_or_else(|e| panic!("killed after {delay_ms} ms, the map is broken: {e}"));
            assert!(
                candidates.contains(&read),
                "killed after {delay_ms} ms: a map that was never saved"
            );
        }
    }

    /// Found by fuzzing: a header announcing 2^60 (or any count from
    /// 2^24) landmarks made the reader reserve room for 2^24 of them,
    /// 2.4 GB, before reading a line. The error stays; the allocation is
    /// caught by `tests/fuzz_corpus.rs` on `corpus/map_file/huge_count.txt`.
    #[test]
    fn a_huge_landmark_count_is_an_error_not_an_allocation() {
        for count in ["1152921504606846976", "16777216", "18446744073709551615"] {
            let text = format!("{HEADER} {count}\n0 1 2 3 1 0 0 1 0 1 - -\n");
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
