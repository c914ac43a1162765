//! Line-oriented text parsing shared by the CSV and whitespace readers.

use std::path::Path;
use std::str::FromStr;

use super::error::DatasetError;

/// Non-empty, non-comment lines with their 1-based line numbers. A
/// trailing `\r` (files written on Windows) is dropped.
pub fn data_lines(text: &str) -> impl Iterator<Item = (usize, &str)> {
    text.lines().enumerate().filter_map(|(i, l)| {
        let l = l.trim_end_matches('\r').trim();
        (!l.is_empty() && !l.starts_with('#') && !l.starts_with('%')).then_some((i + 1, l))
    })
}

/// Splits `line` on `sep` (whitespace runs when `sep` is ' ') into exactly
/// N numbers.
pub fn parse_fields<T: FromStr + Copy + Default, const N: usize>(
    path: &Path,
    line_no: usize,
    line: &str,
    sep: char,
) -> Result<[T; N], DatasetError> {
    let mut out = [T::default(); N];
    let parts: Vec<&str> = if sep == ' ' {
        line.split_whitespace().collect()
    } else {
        line.split(sep).map(str::trim).collect()
    };
    if parts.len() != N {
        return Err(DatasetError::malformed(
            path,
            line_no,
            format!("expected {N} fields, found {}", parts.len()),
        ));
    }
    for (i, (slot, part)) in out.iter_mut().zip(&parts).enumerate() {
        *slot = part.parse().map_err(|_| {
            DatasetError::malformed(
                path,
                line_no,
                format!("field {} is not a number: {part:?}", i + 1),
            )
        })?;
    }
    Ok(out)
}

/// Splits a row whose first field is an integer nanosecond stamp followed
/// by N numbers (EuRoC's `t_ns,v1,...,vN`).
pub fn parse_stamped_row<const N: usize>(
    path: &Path,
    line_no: usize,
    line: &str,
    sep: char,
) -> Result<(i64, [f64; N]), DatasetError> {
    let parts: Vec<&str> = if sep == ' ' {
        line.split_whitespace().collect()
    } else {
        line.split(sep).map(str::trim).collect()
    };
    if parts.len() != N + 1 {
        return Err(DatasetError::malformed(
            path,
            line_no,
            format!("expected {} fields, found {}", N + 1, parts.len()),
        ));
    }
    let t_ns = parse_stamp_ns(path, line_no, parts[0])?;
    let mut values = [0.0; N];
    for (i, (slot, part)) in values.iter_mut().zip(&parts[1..]).enumerate() {
        *slot = part.parse().map_err(|_| {
            DatasetError::malformed(
                path,
                line_no,
                format!("field {} is not a number: {part:?}", i + 2),
            )
        })?;
    }
    Ok((t_ns, values))
}

/// An integer nanosecond stamp, the first field of every EuRoC row.
pub fn parse_stamp_ns(path: &Path, line_no: usize, field: &str) -> Result<i64, DatasetError> {
    field.parse().map_err(|_| {
        DatasetError::malformed(
            path,
            line_no,
            format!("field 1 is not an integer nanosecond timestamp: {field:?}"),
        )
    })
}

/// Errors unless each stamp is later than the one before; `stamps` pairs a
/// stamp with its 1-based line.
pub fn check_increasing(
    path: &Path,
    stamps: impl IntoIterator<Item = (usize, i64)>,
) -> Result<(), DatasetError> {
    let mut previous: Option<i64> = None;
    for (line_no, t_ns) in stamps {
        if let Some(p) = previous {
            if t_ns <= p {
                return Err(DatasetError::malformed(
                    path,
                    line_no,
                    format!("timestamp {t_ns} ns does not increase (previous {p} ns)"),
                ));
            }
        }
        previous = Some(t_ns);
    }
    Ok(())
}

/// Reads a whole text file, naming it in the error.
pub fn read_text(path: &Path) -> Result<String, DatasetError> {
    let bytes = std::fs::read(path).map_err(|e| DatasetError::io(path, e))?;
    String::from_utf8(bytes).map_err(|e| {
        let line = 1 + e.as_bytes()[..e.utf8_error().valid_up_to()]
            .iter()
            .filter(|&&b| b == b'\n')
            .count();
        DatasetError::malformed(path, line, "not UTF-8 text")
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stamped_row_names_bad_fields() {
        let p = Path::new("x.csv");
        let (t, v) = parse_stamped_row::<2>(p, 1, "12, 1.5,-2", ',').expect("valid row");
        assert_eq!((t, v), (12, [1.5, -2.0]));
        let err = parse_stamped_row::<2>(p, 7, "12,1.5", ',').expect_err("short");
        assert!(err
            .to_string()
            .contains("x.csv:7: expected 3 fields, found 2"));
        let err = parse_stamped_row::<2>(p, 3, "1.2e3,1,2", ',').expect_err("float stamp");
        assert!(err.to_string().contains("x.csv:3: field 1"), "{err}");
        let err = parse_stamped_row::<2>(p, 4, "5,1,zz", ',').expect_err("word");
        assert!(err.to_string().contains("field 3 is not a number"), "{err}");
    }

    #[test]
    fn non_utf8_names_the_line() {
        let dir = tempfile::tempdir().expect("temp dir");
        let path = dir.path().join("bin.csv");
        std::fs::write(&path, b"1,2\n3,4\n\xff\xfe\x00garbage").expect("write");
        let err = read_text(&path).expect_err("garbage");
        assert!(err.to_string().contains("bin.csv:3: not UTF-8"), "{err}");
    }

    #[test]
    fn decreasing_stamps_are_rejected() {
        let p = Path::new("t.csv");
        assert!(check_increasing(p, [(1, 5), (2, 6)]).is_ok());
        let err = check_increasing(p, [(1, 5), (2, 6), (4, 6)]).expect_err("repeat");
        assert!(err.to_string().contains("t.csv:4"), "{err}");
    }
}
