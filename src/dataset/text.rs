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
