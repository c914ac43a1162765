//! The stand-alone edge-map text format of `rigslam map solve`.
//!
//! ```text
//! # landmarks N edges M reference R
//! i j ex ey ez s00 s01 s02 s11 s12 s22
//! ```
//! One edge per line: `e = L_j - L_i` in metres (world frame) and its
//! information matrix `S = Σ^-1` as the upper triangle. A line may instead
//! give all nine entries of S row by row (14 fields); S must then be
//! symmetric. Blank lines and further `#` lines are ignored. The solution is
//! written one landmark per line, `id x y z`.

use std::fmt::Write as _;
use std::io::Write as _;
use std::path::{Path, PathBuf};

use nalgebra::{Matrix3, Vector3};

use super::problem::{MapEdge, MapProblem};
use super::EdgeMapError;

/// Relative asymmetry `|S - S^T| / |S|` accepted in a full 9-entry matrix.
const SYMMETRY_TOL: f64 = 1e-9;

/// Reads an edges file.
pub fn read_edges_file(path: &Path) -> Result<MapProblem, EdgeMapError> {
    let text = std::fs::read_to_string(path).map_err(|source| EdgeMapError::Io {
        path: path.to_owned(),
        source,
    })?;
    parse_edges(&text, path)
}

/// Parses the text of an edges file; `path` only names it in errors.
pub fn parse_edges(text: &str, path: &Path) -> Result<MapProblem, EdgeMapError> {
    let err = |line: usize, message: String| EdgeMapError::Line {
        path: path.to_owned(),
        line,
        message,
    };
    let mut lines = text.lines().enumerate().map(|(k, l)| (k + 1, l));
    let (header_line, header) = lines
        .by_ref()
        .find(|(_, l)| !l.trim().is_empty())
        .ok_or_else(|| {
            err(
                1,
                "empty file: expected `# landmarks N edges M reference R`".into(),
            )
        })?;
    let (landmarks, edge_count, reference) =
        parse_header(header).map_err(|m| err(header_line, m))?;
    // The count is the header's word, checked against the lines at the
    // end; reserve for no more than the text can hold (an edge takes at
    // least 22 bytes), not for whatever the header says.
    let mut edges = Vec::with_capacity(edge_count.min(text.len() / 22));
    for (line, content) in lines {
        let content = content.trim();
        if content.is_empty() || content.starts_with('#') {
            continue;
        }
        edges.push(parse_edge(content, landmarks).map_err(|m| err(line, m))?);
    }
    if edges.len() != edge_count {
        return Err(err(
            header_line,
            format!(
                "header announces {edge_count} edges, the file has {}",
                edges.len()
            ),
        ));
    }
    Ok(MapProblem {
        landmark_count: landmarks,
        reference,
        edges,
    })
}

fn parse_header(header: &str) -> Result<(u32, usize, u32), String> {
    let expected = "expected `# landmarks N edges M reference R`";
    let rest = header
        .trim()
        .strip_prefix('#')
        .ok_or_else(|| format!("{expected}, got `{header}`"))?;
    let fields: Vec<&str> = rest.split_whitespace().collect();
    let value = |key: &str| -> Result<Option<&str>, String> {
        match fields.iter().position(|f| *f == key) {
            None => Ok(None),
            Some(k) => fields
                .get(k + 1)
                .copied()
                .map(Some)
                .ok_or_else(|| format!("`{key}` without a value; {expected}")),
        }
    };
    let landmarks: u32 = value("landmarks")?
        .ok_or_else(|| format!("no landmark count; {expected}"))?
        .parse()
        .map_err(|e| format!("landmark count: {e}"))?;
    let edges: usize = value("edges")?
        .ok_or_else(|| format!("no edge count; {expected}"))?
        .parse()
        .map_err(|e| format!("edge count: {e}"))?;
    let reference: u32 = value("reference")?
        .ok_or_else(|| format!("missing reference landmark; {expected}"))?
        .parse()
        .map_err(|e| format!("reference: {e}"))?;
    if reference >= landmarks {
        return Err(format!(
            "reference landmark {reference} does not exist (landmarks are 0..{landmarks})"
        ));
    }
    Ok((landmarks, edges, reference))
}

fn parse_edge(content: &str, landmarks: u32) -> Result<MapEdge, String> {
    let fields: Vec<&str> = content.split_whitespace().collect();
    if fields.len() != 11 && fields.len() != 14 {
        return Err(format!(
            "expected 11 fields `i j ex ey ez s00 s01 s02 s11 s12 s22` (or 14 with the full S), got {}",
            fields.len()
        ));
    }
    let id = |k: usize| -> Result<u32, String> {
        let id: u32 = fields[k]
            .parse()
            .map_err(|_| format!("landmark id `{}` is not a non-negative integer", fields[k]))?;
        if id >= landmarks {
            return Err(format!(
                "unknown landmark id {id} (landmarks are 0..{landmarks})"
            ));
        }
        Ok(id)
    };
    let (i, j) = (id(0)?, id(1)?);
    if i == j {
        return Err(format!("edge from landmark {i} to itself"));
    }
    let mut numbers = Vec::with_capacity(fields.len() - 2);
    for (k, f) in fields[2..].iter().enumerate() {
        let v: f64 = f
            .parse()
            .map_err(|_| format!("field {} `{f}` is not a number", k + 3))?;
        if !v.is_finite() {
            return Err(format!(
                "field {} is {f}: every value must be finite",
                k + 3
            ));
        }
        numbers.push(v);
    }
    let y_m = Vector3::new(numbers[0], numbers[1], numbers[2]);
    let s = &numbers[3..];
    let info = if s.len() == 6 {
        Matrix3::new(s[0], s[1], s[2], s[1], s[3], s[4], s[2], s[4], s[5])
    } else {
        let m = Matrix3::from_row_slice(s);
        let asymmetry = (m - m.transpose()).norm();
        if asymmetry > SYMMETRY_TOL * m.norm() {
            return Err(format!(
                "information matrix is not symmetric (|S - S^T| = {asymmetry:e}, |S| = {:e})",
                m.norm()
            ));
        }
        0.5 * (m + m.transpose())
    };
    if info.cholesky().is_none() {
        let eigen = info.symmetric_eigenvalues();
        return Err(format!(
            "information matrix is not positive definite (eigenvalues {:e}, {:e}, {:e})",
            eigen[0], eigen[1], eigen[2]
        ));
    }
    Ok(MapEdge { i, j, y_m, info })
}

/// Writes a problem in the edges format (upper-triangle form), values in
/// shortest round-trip notation so that reading it back is exact.
pub fn write_edges_file(path: &Path, problem: &MapProblem) -> Result<(), EdgeMapError> {
    let mut text = String::with_capacity(problem.edges.len() * 200 + 64);
    writeln!(
        text,
        "# landmarks {} edges {} reference {}",
        problem.landmark_count,
        problem.edges.len(),
        problem.reference
    )
    .expect("writing to a String cannot fail");
    for e in &problem.edges {
        let s = &e.info;
        writeln!(
            text,
            "{} {} {} {} {} {} {} {} {} {} {}",
            e.i,
            e.j,
            e.y_m.x,
            e.y_m.y,
            e.y_m.z,
            s[(0, 0)],
            s[(0, 1)],
            s[(0, 2)],
            s[(1, 1)],
            s[(1, 2)],
            s[(2, 2)]
        )
        .expect("writing to a String cannot fail");
    }
    write_text(path, &text)
}

/// Writes landmark positions, one line `id x y z` per landmark.
pub fn write_positions(path: &Path, positions: &[Vector3<f64>]) -> Result<(), EdgeMapError> {
    let mut text = String::with_capacity(positions.len() * 64);
    for (id, p) in positions.iter().enumerate() {
        writeln!(text, "{id} {} {} {}", p.x, p.y, p.z).expect("writing to a String cannot fail");
    }
    write_text(path, &text)
}

/// Reads positions written by [`write_positions`] (or the CHOLMOD peer).
pub fn read_positions(path: &Path) -> Result<Vec<Vector3<f64>>, EdgeMapError> {
    let text = std::fs::read_to_string(path).map_err(|source| EdgeMapError::Io {
        path: path.to_owned(),
        source,
    })?;
    parse_positions(&text, path)
}

/// Parses the text of a positions file; `path` only names it in errors.
pub fn parse_positions(text: &str, path: &Path) -> Result<Vec<Vector3<f64>>, EdgeMapError> {
    let mut positions = Vec::new();
    for (k, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let err = |message: String| EdgeMapError::Line {
            path: path.to_owned(),
            line: k + 1,
            message,
        };
        let f: Vec<&str> = line.split_whitespace().collect();
        if f.len() != 4 {
            return Err(err(format!("expected `id x y z`, got {} fields", f.len())));
        }
        let id: usize = f[0]
            .parse()
            .map_err(|_| err(format!("bad id `{}`", f[0])))?;
        if id != positions.len() {
            return Err(err(format!("expected id {}, got {id}", positions.len())));
        }
        let mut v = [0.0; 3];
        for a in 0..3 {
            v[a] = f[a + 1]
                .parse()
                .map_err(|_| err(format!("bad number `{}`", f[a + 1])))?;
        }
        positions.push(Vector3::from(v));
    }
    Ok(positions)
}

fn write_text(path: &Path, text: &str) -> Result<(), EdgeMapError> {
    let io = |source| EdgeMapError::Io {
        path: PathBuf::from(path),
        source,
    };
    let mut file = std::io::BufWriter::new(std::fs::File::create(path).map_err(io)?);
    file.write_all(text.as_bytes()).map_err(io)?;
    file.flush().map_err(io)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(text: &str) -> Result<MapProblem, EdgeMapError> {
        parse_edges(text, Path::new("t.edges"))
    }

    fn line_error(text: &str) -> (usize, String) {
        match parse(text) {
            Err(EdgeMapError::Line { line, message, .. }) => (line, message),
            other => panic!("expected a line error, got {other:?}"),
        }
    }

    const GOOD: &str =
        "# landmarks 3 edges 2 reference 0\n0 1 1 0 0 1 0 0 1 0 1\n1 2 0 1 0 2 0.5 0 2 0 2\n";

    /// Found by fuzzing: a header announcing 2^26 or more edges made the
    /// reader reserve 2^26 of them, 6.4 GB (an abort), before reading a
    /// line. The allocation is caught by `tests/fuzz_corpus.rs` on
    /// `corpus/edges_file/huge_count.edges`; the error stays.
    #[test]
    fn a_huge_edge_count_is_an_error_not_an_allocation() {
        let (line, m) = line_error(
            "# landmarks 3 edges 1152921504606846976 reference 0\n0 1 1 0 0 1 0 0 1 0 1\n",
        );
        assert_eq!(line, 1);
        assert!(
            m.contains("header announces 1152921504606846976 edges, the file has 1"),
            "{m}"
        );
    }

    #[test]
    fn reads_a_good_file() {
        let p = parse(GOOD).unwrap();
        assert_eq!((p.landmark_count, p.reference, p.edges.len()), (3, 0, 2));
        assert_eq!(p.edges[1].info[(1, 0)], 0.5);
        assert_eq!(p.edges[1].y_m, Vector3::new(0.0, 1.0, 0.0));
    }

    #[test]
    fn names_the_line_of_bad_edges() {
        let (line, m) = line_error("# landmarks 3 edges 1 reference 0\n0 7 1 0 0 1 0 0 1 0 1\n");
        assert_eq!(line, 2);
        assert!(m.contains("unknown landmark id 7"), "{m}");
        let (line, m) = line_error(
            "# landmarks 3 edges 2 reference 0\n0 1 1 0 0 1 0 0 1 0 1\n\n1 2 NaN 0 0 1 0 0 1 0 1\n",
        );
        assert_eq!(line, 4);
        assert!(m.contains("finite"), "{m}");
        let (line, m) = line_error("# landmarks 3 edges 1 reference 0\n0 1 1 0 0 1 2 0 1 0 1\n");
        assert_eq!(line, 2);
        assert!(m.contains("not positive definite"), "{m}");
        let (_, m) =
            line_error("# landmarks 3 edges 1 reference 0\n0 1 1 0 0 1 0.5 0 0 1 0 0 0 1\n");
        assert!(m.contains("not symmetric"), "{m}");
        let (_, m) = line_error("# landmarks 3 edges 1 reference 0\n0 1 1 0 0 1 0 0 1 0\n");
        assert!(m.contains("expected 11 fields"), "{m}");
        let (_, m) = line_error("# landmarks 3 edges 1 reference 0\n1 1 1 0 0 1 0 0 1 0 1\n");
        assert!(m.contains("itself"), "{m}");
    }

    #[test]
    fn rejects_missing_or_unknown_reference_and_wrong_counts() {
        let (line, m) = line_error("# landmarks 3 edges 1\n0 1 1 0 0 1 0 0 1 0 1\n");
        assert_eq!(line, 1);
        assert!(m.contains("missing reference"), "{m}");
        let (_, m) = line_error("# landmarks 3 edges 1 reference 3\n0 1 1 0 0 1 0 0 1 0 1\n");
        assert!(m.contains("reference landmark 3 does not exist"), "{m}");
        let (_, m) = line_error("# landmarks 3 edges 5 reference 0\n0 1 1 0 0 1 0 0 1 0 1\n");
        assert!(m.contains("announces 5 edges"), "{m}");
    }

    #[test]
    fn write_then_read_is_exact() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("p.edges");
        let mut p = parse(GOOD).unwrap();
        p.edges[0].y_m = Vector3::new(0.1, -1.0 / 3.0, 1e-17);
        write_edges_file(&path, &p).unwrap();
        let q = read_edges_file(&path).unwrap();
        assert_eq!(p.edges, q.edges);
        let positions = vec![
            Vector3::new(0.0, 0.0, 0.0),
            Vector3::new(1.0 / 3.0, 2.0, -7.5e-9),
        ];
        let out = dir.path().join("p.txt");
        write_positions(&out, &positions).unwrap();
        assert_eq!(read_positions(&out).unwrap(), positions);
    }
}
