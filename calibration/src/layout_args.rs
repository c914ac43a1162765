//! The command-line flags that describe a non-EuRoC IMU CSV, shared by
//! `rigslam-calibrate imu` and `noise`.

use crate::imu_log::{AccelUnit, GyroUnit, ImuLogLayout};

#[derive(Debug, Clone, clap::Args)]
pub struct LayoutArgs {
    /// Column roles, comma separated: t_ns, t_s, gx, gy, gz, ax, ay, az, skip.
    /// Default: EuRoC's imu0 layout (t_ns,gx,gy,gz,ax,ay,az).
    #[arg(long, value_name = "LIST")]
    pub columns: Option<String>,
    /// Gyroscope unit in the file.
    #[arg(long, value_parser = ["rad/s", "deg/s"], default_value = "rad/s")]
    pub gyro_unit: String,
    /// Accelerometer unit in the file (g = 9.80665 m/s^2).
    #[arg(long, value_parser = ["m/s^2", "g"], default_value = "m/s^2")]
    pub accel_unit: String,
    /// Sample rate, needed when the file has no time column.
    #[arg(long)]
    pub rate_hz: Option<f64>,
    /// The file has no header line.
    #[arg(long)]
    pub no_header: bool,
}

impl LayoutArgs {
    pub fn layout(&self) -> Result<ImuLogLayout, String> {
        let mut layout = ImuLogLayout::euroc();
        if let Some(list) = &self.columns {
            layout.columns = ImuLogLayout::parse_columns(list)?;
        }
        layout.gyro_unit = if self.gyro_unit == "deg/s" {
            GyroUnit::DegPerS
        } else {
            GyroUnit::RadPerS
        };
        layout.accel_unit = if self.accel_unit == "g" {
            AccelUnit::G
        } else {
            AccelUnit::MPerS2
        };
        layout.rate_hz = self.rate_hz;
        if let Some(r) = self.rate_hz {
            if !(r.is_finite() && r > 0.0) {
                return Err(format!("--rate-hz must be positive, got {r}"));
            }
        }
        layout.header = !self.no_header;
        Ok(layout)
    }
}
