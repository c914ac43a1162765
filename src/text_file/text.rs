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

/// Errors when a stamp is earlier than the one before; equal stamps pass
/// (see [`crate::dataset::tum::read_tum`] for why trajectories allow them).
pub fn check_not_decreasing(
    path: &Path,
    stamps: impl IntoIterator<Item = (usize, i64)>,
) -> Result<(), DatasetError> {
    let mut previous: Option<i64> = None;
    for (line_no, t_ns) in stamps {
        if let Some(p) = previous {
            if t_ns < p {
                return Err(DatasetError::malformed(
                    path,
                    line_no,
                    format!("timestamp {t_ns} ns goes back in time (previous {p} ns)"),
                ));
            }
        }
        previous = Some(t_ns);
    }
    Ok(())
}

/// EuRoC's CSVs by column count, to say what a misplaced file looks like.
const EUROC_CSV_KINDS: [(usize, &str); 4] = [
    (2, "a camera's data.csv (t, filename)"),
    (7, "an IMU csv (t, gyro xyz, accel xyz)"),
    (8, "a pose csv (t, p xyz, q wxyz)"),
    (17, "a ground-truth csv (t, p, q, v, gyro and accel biases)"),
];

/// Checks the column count of a `#` header on line 1 of a EuRoC CSV, so a
/// file given in place of another (an IMU csv as ground truth) is refused
/// at line 1 saying what was `expected`, rather than at line 2 with a bare
/// field count. Files without a header pass, and so does a `#` line
/// without a comma: free text, not a column list.
pub fn check_euroc_header(
    path: &Path,
    text: &str,
    expected_columns: &[usize],
    expected: &str,
) -> Result<(), DatasetError> {
    let Some(first) = text.lines().next() else {
        return Ok(());
    };
    let Some(header) = first.trim().strip_prefix('#') else {
        return Ok(());
    };
    if !header.contains(',') {
        return Ok(());
    }
    let columns = header.split(',').count();
    if expected_columns.contains(&columns) {
        return Ok(());
    }
    let looks_like = EUROC_CSV_KINDS
        .iter()
        .find(|(n, _)| *n == columns)
        .map_or(String::new(), |(_, kind)| format!(", as in {kind}"));
    Err(DatasetError::malformed(
        path,
        1,
        format!("header has {columns} columns{looks_like}; expected {expected}"),
    ))
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

/// Decimal seconds (`1403715274.30214`, `1.403715529112143517e+09`,
/// `-0.5`) as exact i64 nanoseconds, computed on the digits rather than
/// through f64; digits past the nanosecond are rounded half away from
/// zero. `None` for anything else (NaN, inf, words) or out of range.
pub fn parse_seconds_ns(text: &str) -> Option<i64> {
    let text = text.trim();
    let (negative, body) = match text.as_bytes().first()? {
        b'-' => (true, &text[1..]),
        b'+' => (false, &text[1..]),
        _ => (false, text),
    };
    let (mantissa, exponent) = match body.find(['e', 'E']) {
        Some(i) => (&body[..i], body[i + 1..].parse::<i32>().ok()?),
        None => (body, 0),
    };
    let (int_part, frac_part) = mantissa.split_once('.').unwrap_or((mantissa, ""));
    let all_digits = int_part
        .bytes()
        .chain(frac_part.bytes())
        .all(|b| b.is_ascii_digit());
    if !all_digits || (int_part.is_empty() && frac_part.is_empty()) {
        return None;
    }
    let digits = format!("{int_part}{frac_part}");
    let digits = digits.trim_start_matches('0');
    // value = digits * 10^shift ns
    let mut shift = i64::from(exponent) + 9 - frac_part.len() as i64;
    // Keep at most 30 significant digits: far past a nanosecond at any
    // stamp an i64 can hold.
    let kept = &digits[..digits.len().min(30)];
    shift += (digits.len() - kept.len()) as i64;
    let mantissa: i128 = if kept.is_empty() {
        0
    } else {
        kept.parse().ok()?
    };
    let ns: i128 = if shift >= 0 {
        if mantissa == 0 {
            0
        } else {
            10i128
                .checked_pow(u32::try_from(shift).ok()?)
                .and_then(|p| mantissa.checked_mul(p))?
        }
    } else if shift < -38 {
        0
    } else {
        let p = 10i128.pow((-shift) as u32);
        mantissa / p + i128::from(2 * (mantissa % p) >= p)
    };
    let ns = if negative { -ns } else { ns };
    i64::try_from(ns).ok()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn seconds_parse_exactly_to_nanoseconds() {
        let cases: [(&str, Option<i64>); 14] = [
            ("1403715274.30214", Some(1_403_715_274_302_140_000)),
            ("1.403715529112143517e+09", Some(1_403_715_529_112_143_517)),
            ("1403715273.262142976", Some(1_403_715_273_262_142_976)),
            ("0.1000000005", Some(100_000_001)),
            ("-0.5", Some(-500_000_000)),
            ("1.036e-01", Some(103_600_000)),
            ("0.000000e+00", Some(0)),
            ("5", Some(5_000_000_000)),
            (".25", Some(250_000_000)),
            ("1e-30", Some(0)),
            ("1e10", None),
            ("nan", None),
            ("1.2.3", None),
            ("", None),
        ];
        for (text, want) in cases {
            assert_eq!(parse_seconds_ns(text), want, "{text:?}");
        }
    }

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
    fn euroc_header_column_count_is_checked() {
        let p = Path::new("gt.csv");
        let check = |text: &str| check_euroc_header(p, text, &[17, 8], "17 or 8 columns");
        // No header, a matching one (with a Windows line end), free text.
        assert!(check("1,2,3\n").is_ok());
        assert!(check("").is_ok());
        assert!(check("#t,x,y,z,qw,qx,qy,qz\r\n1,0,0,0,1,0,0,0\n").is_ok());
        assert!(check("# written by a logger\n1,2\n").is_ok());
        // A header on line 2 is not line 1's: data rows report it.
        assert!(check("1,2\n#a,b\n").is_ok());
        let err = check("#timestamp [ns],w_x,w_y,w_z,a_x,a_y,a_z\n1,0,0,0,0,0,9.8\n")
            .expect_err("imu header");
        assert_eq!(
            err.to_string(),
            "gt.csv:1: header has 7 columns, as in an IMU csv (t, gyro xyz, accel xyz); \
             expected 17 or 8 columns"
        );
        let err = check("#a,b,c\n").expect_err("unknown kind");
        assert_eq!(
            err.to_string(),
            "gt.csv:1: header has 3 columns; expected 17 or 8 columns"
        );
    }

    #[test]
    fn decreasing_stamps_are_rejected() {
        let p = Path::new("t.csv");
        assert!(check_increasing(p, [(1, 5), (2, 6)]).is_ok());
        let err = check_increasing(p, [(1, 5), (2, 6), (4, 6)]).expect_err("repeat");
        assert!(err.to_string().contains("t.csv:4"), "{err}");
    }
}
