//! `imu0/data.csv`: `t[ns], gyro xyz [rad/s], accel xyz [m/s^2]`.

use std::io::Write;
use std::path::Path;

use crate::dataset::error::DatasetError;
use crate::dataset::text::{
    check_euroc_header, check_increasing, data_lines, parse_stamped_row, read_text,
};
use crate::sensors::ImuSample;

/// EuRoC's IMU column header.
pub const IMU_CSV_HEADER: &str = "#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],\
w_RS_S_z [rad s^-1],a_RS_S_x [m s^-2],a_RS_S_y [m s^-2],a_RS_S_z [m s^-2]";

/// The samples of an IMU CSV.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ImuCsv {
    /// Finite samples in increasing time order.
    pub samples: Vec<ImuSample>,
    /// Rows whose values were NaN or infinite. They are dropped here, and
    /// counted, rather than failing the file: a logger writes NaN when a
    /// reading is missing, and one bad packet should not lose a dataset.
    /// Their stamps still had to increase.
    pub dropped_nonfinite: usize,
    /// The line of the first such row (1-based).
    pub first_nonfinite_line: Option<usize>,
}

/// Reads an IMU CSV. Rows with the wrong field count or non-numbers are
/// errors naming the line; stamps must increase. A `#` header, when
/// there is one, must have 7 columns.
pub fn read_euroc_imu_csv(path: &Path) -> Result<ImuCsv, DatasetError> {
    parse_euroc_imu_csv(&read_text(path)?, path)
}

/// Parses the text of an IMU CSV; `path` names it in errors.
pub fn parse_euroc_imu_csv(text: &str, path: &Path) -> Result<ImuCsv, DatasetError> {
    check_euroc_header(
        path,
        text,
        &[7],
        "7 columns (t_ns, gyro xyz, accel xyz) for an IMU csv",
    )?;
    let mut out = ImuCsv::default();
    let mut stamps = Vec::new();
    for (line_no, line) in data_lines(text) {
        let (t_ns, f) = parse_stamped_row::<6>(path, line_no, line, ',')?;
        stamps.push((line_no, t_ns));
        let sample = ImuSample {
            t_ns,
            gyro_rad_s: [f[0], f[1], f[2]],
            accel_m_s2: [f[3], f[4], f[5]],
        };
        if sample.is_finite() {
            out.samples.push(sample);
        } else {
            out.dropped_nonfinite += 1;
            out.first_nonfinite_line.get_or_insert(line_no);
        }
    }
    check_increasing(path, stamps)?;
    Ok(out)
}

/// Writes an IMU CSV with numbers in their shortest exact form. Stamps
/// must increase; the error names the line the offending row would have.
pub fn write_euroc_imu_csv(path: &Path, samples: &[ImuSample]) -> Result<(), DatasetError> {
    check_increasing(
        path,
        samples.iter().enumerate().map(|(i, s)| (i + 2, s.t_ns)),
    )?;
    let file = std::fs::File::create(path).map_err(|e| DatasetError::io(path, e))?;
    let mut out = std::io::BufWriter::new(file);
    let io = |e| DatasetError::io(path, e);
    writeln!(out, "{IMU_CSV_HEADER}").map_err(io)?;
    for s in samples {
        let [gx, gy, gz] = s.gyro_rad_s;
        let [ax, ay, az] = s.accel_m_s2;
        writeln!(out, "{},{gx},{gy},{gz},{ax},{ay},{az}", s.t_ns).map_err(io)?;
    }
    out.flush().map_err(io)
}

#[cfg(test)]
mod tests {
    use super::*;

    const GOOD: &str = "#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1],a_RS_S_x [m s^-2],a_RS_S_y [m s^-2],a_RS_S_z [m s^-2]
1403715273262142976,-0.0020943951023931952,0.017453292519943295,0.07749261878854824,9.0874956666666655,0.13075533333333333,-3.6938381666666662
1403715273267142912,-0.0013962634015954637,0.019547687622336492,0.07819075048934597,9.0793234583333327,0.122583125,-3.6938381666666662
1403715273272142848,-0.0013962634015954637,0.019547687622336492,0.07819075048934597,9.0793234583333327,0.122583125,-3.6938381666666662
";

    fn write(dir: &Path, text: &[u8]) -> std::path::PathBuf {
        let path = dir.join("data.csv");
        std::fs::write(&path, text).expect("write");
        path
    }

    #[test]
    fn reads_euroc_rows_exactly() {
        let dir = tempfile::tempdir().expect("temp dir");
        let csv = read_euroc_imu_csv(&write(dir.path(), GOOD.as_bytes())).expect("valid");
        assert_eq!(csv.samples.len(), 3);
        assert_eq!(csv.dropped_nonfinite, 0);
        assert_eq!(csv.samples[1].t_ns, 1403715273267142912);
        assert_eq!(csv.samples[0].gyro_rad_s[1], 0.017453292519943295);
        assert_eq!(
            csv.samples[0].accel_m_s2[2],
            "-3.6938381666666662".parse::<f64>().expect("number")
        );
    }

    #[test]
    fn round_trip_is_bit_exact() {
        let dir = tempfile::tempdir().expect("temp dir");
        let samples: Vec<ImuSample> = (0..50)
            .map(|i| ImuSample {
                t_ns: 1_000_000_000 + i * 5_000_000,
                gyro_rad_s: [
                    0.1 / (i as f64 + 3.0),
                    -1e-7 * i as f64,
                    std::f64::consts::PI,
                ],
                accel_m_s2: [9.81, 1.0 / 3.0, -(i as f64).sqrt()],
            })
            .collect();
        let path = dir.path().join("imu.csv");
        write_euroc_imu_csv(&path, &samples).expect("write");
        assert_eq!(read_euroc_imu_csv(&path).expect("read").samples, samples);
    }

    #[test]
    fn nan_rows_are_dropped_and_counted() {
        let dir = tempfile::tempdir().expect("temp dir");
        let text = GOOD.replacen("0.017453292519943295", "NaN", 1).replacen(
            "9.0793234583333327",
            "inf",
            1,
        );
        let csv = read_euroc_imu_csv(&write(dir.path(), text.as_bytes())).expect("valid");
        assert_eq!(csv.dropped_nonfinite, 2);
        assert_eq!(csv.samples.len(), 1);
        assert_eq!(csv.samples[0].t_ns, 1403715273272142848);
    }

    #[test]
    fn malformed_rows_name_file_and_line() {
        let dir = tempfile::tempdir().expect("temp dir");
        // Truncated mid-row.
        let path = write(dir.path(), &GOOD.as_bytes()[..GOOD.len() - 60]);
        let err = read_euroc_imu_csv(&path).expect_err("truncated");
        assert!(
            err.to_string()
                .contains("data.csv:4: expected 7 fields, found 4"),
            "{err}"
        );
        // A word where a number belongs.
        let path = write(
            dir.path(),
            GOOD.replacen("0.122583125", "0.12x", 1).as_bytes(),
        );
        let err = read_euroc_imu_csv(&path).expect_err("word");
        assert!(
            err.to_string()
                .contains("data.csv:3: field 6 is not a number"),
            "{err}"
        );
        // A header without '#'.
        let path = write(dir.path(), &GOOD.as_bytes()[1..]);
        let err = read_euroc_imu_csv(&path).expect_err("header");
        assert!(err.to_string().contains("data.csv:1: field 1"), "{err}");
        // Repeated stamp.
        let lines: Vec<&str> = GOOD.lines().collect();
        let text = format!("{}\n{}\n{}\n", lines[0], lines[1], lines[1]);
        let err = read_euroc_imu_csv(&write(dir.path(), text.as_bytes())).expect_err("repeat");
        assert!(err.to_string().contains("data.csv:3: timestamp"), "{err}");
        // Garbage bytes.
        let path = write(dir.path(), &[0x00, 0x9f, 0x92, 0x96, b',', 0xff]);
        assert!(read_euroc_imu_csv(&path).is_err());
        // Empty file: no samples.
        let path = write(dir.path(), b"");
        assert_eq!(read_euroc_imu_csv(&path).expect("empty"), ImuCsv::default());
        // Writer refuses stamps going backwards.
        let s = |t_ns| ImuSample {
            t_ns,
            gyro_rad_s: [0.0; 3],
            accel_m_s2: [0.0; 3],
        };
        let err = write_euroc_imu_csv(&dir.path().join("w.csv"), &[s(2), s(1)]).expect_err("order");
        assert!(err.to_string().contains("w.csv:3"), "{err}");
    }
}
