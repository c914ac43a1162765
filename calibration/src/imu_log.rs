//! Reading IMU logs in the layouts calibration sessions come in: EuRoC's
//! `imu0/data.csv` (the default, read by the core's reader) or any CSV
//! whose column roles and units are given ([`ImuLogLayout`]), plain or
//! gzip-compressed (`.gz`). Everything is converted to SI at this edge.

use std::io::Read;
use std::path::Path;

use rigslam::dataset::text::data_lines;
use rigslam::dataset::{read_euroc_imu_csv, DatasetError};
use rigslam::sensors::ImuSample;

/// Standard gravity, for logs whose accelerometer unit is g.
pub const STANDARD_GRAVITY_M_S2: f64 = 9.80665;

/// What one CSV column holds.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Column {
    /// Integer nanoseconds.
    TimeNs,
    /// Seconds (float).
    TimeS,
    GyroX,
    GyroY,
    GyroZ,
    AccelX,
    AccelY,
    AccelZ,
    /// Ignored (a sample counter, a temperature ...).
    Skip,
}

impl Column {
    fn parse(name: &str) -> Option<Column> {
        Some(match name.trim() {
            "t_ns" => Column::TimeNs,
            "t_s" => Column::TimeS,
            "gx" => Column::GyroX,
            "gy" => Column::GyroY,
            "gz" => Column::GyroZ,
            "ax" => Column::AccelX,
            "ay" => Column::AccelY,
            "az" => Column::AccelZ,
            "skip" | "-" => Column::Skip,
            _ => return None,
        })
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum GyroUnit {
    RadPerS,
    DegPerS,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum AccelUnit {
    MPerS2,
    /// Multiples of standard gravity (9.80665 m/s^2).
    G,
}

/// How to read a CSV that is not in EuRoC's layout.
#[derive(Debug, Clone, PartialEq)]
pub struct ImuLogLayout {
    pub columns: Vec<Column>,
    pub gyro_unit: GyroUnit,
    pub accel_unit: AccelUnit,
    /// Needed when no time column is given; otherwise estimated from the stamps.
    pub rate_hz: Option<f64>,
    /// The first line is a header (skipped).
    pub header: bool,
}

impl ImuLogLayout {
    /// EuRoC's `t_ns, gyro xyz (rad/s), accel xyz (m/s^2)`.
    pub fn euroc() -> Self {
        Self {
            columns: Self::parse_columns("t_ns,gx,gy,gz,ax,ay,az").expect("valid constant"),
            gyro_unit: GyroUnit::RadPerS,
            accel_unit: AccelUnit::MPerS2,
            rate_hz: None,
            header: true,
        }
    }

    /// Parses a comma list of `t_ns t_s gx gy gz ax ay az skip`.
    pub fn parse_columns(list: &str) -> Result<Vec<Column>, String> {
        let columns: Vec<Column> = list
            .split(',')
            .map(|name| {
                Column::parse(name).ok_or_else(|| {
                    format!("unknown column role {name:?} (use t_ns, t_s, gx, gy, gz, ax, ay, az, skip)")
                })
            })
            .collect::<Result<_, _>>()?;
        for needed in [
            Column::GyroX,
            Column::GyroY,
            Column::GyroZ,
            Column::AccelX,
            Column::AccelY,
            Column::AccelZ,
        ] {
            if columns.iter().filter(|&&c| c == needed).count() != 1 {
                return Err(format!(
                    "the columns must name {needed:?} exactly once: {list:?}"
                ));
            }
        }
        if columns
            .iter()
            .filter(|c| matches!(c, Column::TimeNs | Column::TimeS))
            .count()
            > 1
        {
            return Err(format!("at most one time column: {list:?}"));
        }
        Ok(columns)
    }

    fn has_time(&self) -> bool {
        self.columns
            .iter()
            .any(|c| matches!(c, Column::TimeNs | Column::TimeS))
    }
}

/// A log in SI units with its (nominal) sample rate.
#[derive(Debug, Clone)]
pub struct ImuLog {
    pub samples: Vec<ImuSample>,
    pub rate_hz: f64,
}

/// Reads `path` in `layout`; EuRoC's layout goes through the core's reader.
pub fn read_imu_log(path: &Path, layout: &ImuLogLayout) -> Result<ImuLog, DatasetError> {
    let gz = path.extension().is_some_and(|e| e == "gz");
    if *layout == ImuLogLayout::euroc() && !gz {
        let csv = read_euroc_imu_csv(path)?;
        let rate_hz = estimate_rate_hz(path, &csv.samples)?;
        return Ok(ImuLog {
            samples: csv.samples,
            rate_hz,
        });
    }
    if !layout.has_time() && layout.rate_hz.is_none() {
        return Err(DatasetError::Layout {
            path: path.to_path_buf(),
            message: "the columns have no time (t_ns or t_s): give the sample rate with --rate-hz"
                .into(),
        });
    }
    let text = read_maybe_gz(path, gz)?;
    let gyro_factor = match layout.gyro_unit {
        GyroUnit::RadPerS => 1.0,
        GyroUnit::DegPerS => std::f64::consts::PI / 180.0,
    };
    let accel_factor = match layout.accel_unit {
        AccelUnit::MPerS2 => 1.0,
        AccelUnit::G => STANDARD_GRAVITY_M_S2,
    };
    let mut samples = Vec::with_capacity(text.len() / 40);
    let mut lines = data_lines(&text);
    if layout.header {
        lines.next();
    }
    for (line_no, line) in lines {
        let mut sample = ImuSample {
            t_ns: 0,
            gyro_rad_s: [0.0; 3],
            accel_m_s2: [0.0; 3],
        };
        let mut fields = 0;
        for (i, part) in line.split(',').enumerate() {
            fields += 1;
            let Some(&role) = layout.columns.get(i) else {
                continue;
            };
            if role == Column::Skip {
                continue;
            }
            let part = part.trim();
            if role == Column::TimeNs {
                sample.t_ns = part.parse().map_err(|_| {
                    DatasetError::malformed(
                        path,
                        line_no,
                        format!("field {} (t_ns) is not an integer: {part:?}", i + 1),
                    )
                })?;
                continue;
            }
            let value: f64 = part.parse().map_err(|_| {
                DatasetError::malformed(
                    path,
                    line_no,
                    format!("field {} ({role:?}) is not a number: {part:?}", i + 1),
                )
            })?;
            if !value.is_finite() {
                return Err(DatasetError::malformed(
                    path,
                    line_no,
                    format!("field {} ({role:?}) is not finite: {part:?}", i + 1),
                ));
            }
            match role {
                Column::TimeS => sample.t_ns = (value * 1e9).round() as i64,
                Column::GyroX => sample.gyro_rad_s[0] = value * gyro_factor,
                Column::GyroY => sample.gyro_rad_s[1] = value * gyro_factor,
                Column::GyroZ => sample.gyro_rad_s[2] = value * gyro_factor,
                Column::AccelX => sample.accel_m_s2[0] = value * accel_factor,
                Column::AccelY => sample.accel_m_s2[1] = value * accel_factor,
                Column::AccelZ => sample.accel_m_s2[2] = value * accel_factor,
                Column::TimeNs | Column::Skip => {}
            }
        }
        if fields != layout.columns.len() {
            return Err(DatasetError::malformed(
                path,
                line_no,
                format!(
                    "expected {} fields (--columns), found {fields}: is this the right file and layout?",
                    layout.columns.len()
                ),
            ));
        }
        if !layout.has_time() {
            let rate_hz = layout.rate_hz.expect("checked above");
            sample.t_ns = (samples.len() as f64 * 1e9 / rate_hz).round() as i64;
        } else if let Some(last) = samples.last() {
            let last: &ImuSample = last;
            if sample.t_ns <= last.t_ns {
                return Err(DatasetError::malformed(
                    path,
                    line_no,
                    format!(
                        "time goes backwards or repeats ({} ns after {} ns)",
                        sample.t_ns, last.t_ns
                    ),
                ));
            }
        }
        samples.push(sample);
    }
    let rate_hz = match layout.rate_hz {
        Some(r) => r,
        None => estimate_rate_hz(path, &samples)?,
    };
    Ok(ImuLog { samples, rate_hz })
}

fn read_maybe_gz(path: &Path, gz: bool) -> Result<String, DatasetError> {
    let file = std::fs::File::open(path).map_err(|e| DatasetError::io(path, e))?;
    let mut text = String::new();
    let result = if gz {
        flate2::read::GzDecoder::new(std::io::BufReader::new(file)).read_to_string(&mut text)
    } else {
        std::io::BufReader::new(file).read_to_string(&mut text)
    };
    result.map_err(|e| DatasetError::io(path, e))?;
    Ok(text)
}

/// The rate from the median spacing of the stamps.
fn estimate_rate_hz(path: &Path, samples: &[ImuSample]) -> Result<f64, DatasetError> {
    if samples.len() < 2 {
        return Err(DatasetError::Layout {
            path: path.to_path_buf(),
            message: format!("only {} IMU sample(s): is this an IMU log?", samples.len()),
        });
    }
    let mut dt_ns: Vec<i64> = samples.windows(2).map(|w| w[1].t_ns - w[0].t_ns).collect();
    let mid = dt_ns.len() / 2;
    let median = *dt_ns.select_nth_unstable(mid).1;
    if median <= 0 {
        return Err(DatasetError::Layout {
            path: path.to_path_buf(),
            message: "the time stamps do not increase".into(),
        });
    }
    Ok(1e9 / median as f64)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::Write;

    fn write(dir: &Path, name: &str, text: &str) -> std::path::PathBuf {
        let p = dir.join(name);
        std::fs::write(&p, text).expect("temp dir is writable");
        p
    }

    #[test]
    fn converts_degrees_and_g_and_counts_time_from_the_rate() {
        let dir = tempfile::tempdir().expect("temp dir");
        let p = write(
            dir.path(),
            "a.csv",
            "gx,gy,gz,ax,ay,az\n180,0,-90,1,0,-0.5\n0,0,0,0,0,1\n",
        );
        let layout = ImuLogLayout {
            columns: ImuLogLayout::parse_columns("gx,gy,gz,ax,ay,az").expect("valid"),
            gyro_unit: GyroUnit::DegPerS,
            accel_unit: AccelUnit::G,
            rate_hz: Some(100.0),
            header: true,
        };
        let log = read_imu_log(&p, &layout).expect("valid log");
        assert_eq!(log.samples.len(), 2);
        assert!((log.samples[0].gyro_rad_s[0] - std::f64::consts::PI).abs() < 1e-15);
        assert!((log.samples[0].gyro_rad_s[2] + std::f64::consts::FRAC_PI_2).abs() < 1e-15);
        assert!((log.samples[0].accel_m_s2[2] + 0.5 * 9.80665).abs() < 1e-12);
        assert_eq!(log.samples[1].t_ns, 10_000_000);
        assert_eq!(log.rate_hz, 100.0);
    }

    #[test]
    fn reads_gzip_and_reorders_columns() {
        let dir = tempfile::tempdir().expect("temp dir");
        let p = dir.path().join("b.csv.gz");
        let mut enc = flate2::write::GzEncoder::new(
            std::fs::File::create(&p).expect("temp dir is writable"),
            flate2::Compression::fast(),
        );
        enc.write_all(b"t_s,ax,ay,az,skip,gx,gy,gz\n0.0,1,2,3,99,4,5,6\n0.5,1,2,3,99,4,5,6\n")
            .expect("write");
        enc.finish().expect("finish");
        let layout = ImuLogLayout {
            columns: ImuLogLayout::parse_columns("t_s,ax,ay,az,skip,gx,gy,gz").expect("valid"),
            gyro_unit: GyroUnit::RadPerS,
            accel_unit: AccelUnit::MPerS2,
            rate_hz: None,
            header: true,
        };
        let log = read_imu_log(&p, &layout).expect("valid log");
        assert_eq!(log.samples[1].t_ns, 500_000_000);
        assert_eq!(log.samples[0].accel_m_s2, [1.0, 2.0, 3.0]);
        assert_eq!(log.samples[0].gyro_rad_s, [4.0, 5.0, 6.0]);
        assert_eq!(log.rate_hz, 2.0);
    }

    #[test]
    fn garbled_rows_name_the_line() {
        let dir = tempfile::tempdir().expect("temp dir");
        let layout = ImuLogLayout {
            columns: ImuLogLayout::parse_columns("gx,gy,gz,ax,ay,az").expect("valid"),
            gyro_unit: GyroUnit::RadPerS,
            accel_unit: AccelUnit::MPerS2,
            rate_hz: Some(10.0),
            header: true,
        };
        let p = write(dir.path(), "c.csv", "h\n1,2,3,4,5,6\n1,2,x,4,5,6\n");
        let e = read_imu_log(&p, &layout).expect_err("garbled").to_string();
        assert!(e.contains("c.csv:3") && e.contains("not a number"), "{e}");
        let p = write(dir.path(), "d.csv", "h\n1,2,3,4,5,6\n1,2,3,4,5\n");
        let e = read_imu_log(&p, &layout)
            .expect_err("short row")
            .to_string();
        assert!(
            e.contains("d.csv:3") && e.contains("expected 6 fields"),
            "{e}"
        );
        let no_rate = ImuLogLayout {
            rate_hz: None,
            ..layout
        };
        let e = read_imu_log(&p, &no_rate).expect_err("no time").to_string();
        assert!(e.contains("--rate-hz"), "{e}");
        assert!(ImuLogLayout::parse_columns("gx,gy,gz,ax,ay").is_err());
        assert!(ImuLogLayout::parse_columns("gx,gy,gz,ax,ay,az,foo").is_err());
    }
}
