//! `rigslam camera`: open a V4L2 or Aravis camera (or the built-in pattern
//! camera), stream for a while, and report identity, format, measured rate,
//! drops and where the timestamps come from.

use std::time::{Duration, Instant};

use anyhow::Context;
use rigslam::sensors::camera::fake::PatternCamera;
use rigslam::sensors::camera::v4l2::{open_v4l2, V4l2Config};
use rigslam::sensors::camera::v4l2_format::WireFormat;
use rigslam::sensors::camera::FrameSource;
use rigslam::sensors::{PixelFormat, NS_PER_S};

#[derive(Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Driver {
    /// Video4Linux2 (/dev/videoN): UVC webcams, FireWire/USB machine-vision cameras.
    V4l2,
    /// GigE Vision / USB3 Vision through libaravis (the default build has it; `--no-default-features` leaves it out).
    Aravis,
    /// A built-in moving pattern at --rate-hz (no hardware).
    Fake,
}

#[derive(clap::Args)]
pub struct CameraArgs {
    /// Which driver opens the device.
    #[arg(long, value_enum)]
    driver: Driver,
    /// Device: /dev/videoN or N for V4L2; for Aravis a camera id ("Vendor-Model-Serial") or a GigE camera's IP address, 0 for the first camera found.
    #[arg(long, default_value = "0")]
    device: String,
    /// How long to stream.
    #[arg(long, default_value_t = 5.0)]
    seconds: f64,
    /// Pixel format to ask for: a V4L2 FourCC (GREY, Y16, YUYV, BA81, RGGB, ...) or a GenICam name (Mono8, Mono16).
    #[arg(long)]
    format: Option<String>,
    #[arg(long)]
    width: Option<u32>,
    #[arg(long)]
    height: Option<u32>,
    /// Frame rate to ask for.
    #[arg(long)]
    rate_hz: Option<f64>,
    /// Manual exposure to set, where the camera has the control.
    #[arg(long)]
    exposure_us: Option<f64>,
    /// Print one JSON object instead of text.
    #[arg(long)]
    json: bool,
}

/// What `--json` prints (keys: frames, rate_hz, drops, width, height, format).
#[derive(serde::Serialize)]
struct Report {
    frames: u64,
    rate_hz: f64,
    drops: u64,
    corrupt: u64,
    width: u32,
    height: u32,
    format: String,
    wire_format: String,
    timestamp_source: &'static str,
    driver: &'static str,
    device: String,
    name: String,
    bus: String,
    nominal_rate_hz: Option<f64>,
    exposure_us: Option<f64>,
    seconds: f64,
}

pub fn run(args: CameraArgs) -> anyhow::Result<()> {
    anyhow::ensure!(
        args.seconds > 0.0 && args.seconds.is_finite(),
        "--seconds must be positive, got {}",
        args.seconds
    );
    let mut source = open(&args)?;
    let info = source.info().clone();
    if !args.json {
        println!(
            "{} camera {}: {} [{}], {}x{} {} (wire {}), nominal {}",
            info.driver,
            info.device,
            info.name,
            info.bus,
            info.width,
            info.height,
            format_name(info.format),
            info.wire_format,
            info.nominal_rate_hz
                .map(|hz| format!("{hz:.2} Hz"))
                .unwrap_or_else(|| "rate unknown".into()),
        );
    }
    // First frame may take a while (camera start-up); later ones a few periods.
    let mut timeout = Duration::from_secs(5);
    let started = Instant::now();
    let budget = Duration::from_secs_f64(args.seconds);
    let (mut first_t_ns, mut last_t_ns) = (None, 0i64);
    let mut frames = 0u64;
    while started.elapsed() < budget {
        let frame = source
            .next_frame(timeout)
            .with_context(|| format!("after {frames} frames"))?;
        first_t_ns.get_or_insert(frame.t_ns);
        last_t_ns = frame.t_ns;
        frames += 1;
        timeout = Duration::from_secs(2);
    }
    let stats = source.stats();
    let info = source.info();
    let span_s = first_t_ns.map_or(0.0, |t0| (last_t_ns - t0) as f64 / NS_PER_S as f64);
    let rate_hz = if frames > 1 && span_s > 0.0 {
        (frames - 1) as f64 / span_s
    } else {
        0.0
    };
    let report = Report {
        frames,
        rate_hz,
        drops: stats.drops,
        corrupt: stats.corrupt,
        width: info.width,
        height: info.height,
        format: format_name(info.format),
        wire_format: info.wire_format.clone(),
        timestamp_source: info.timestamp_source.name(),
        driver: info.driver,
        device: info.device.clone(),
        name: info.name.clone(),
        bus: info.bus.clone(),
        nominal_rate_hz: info.nominal_rate_hz,
        exposure_us: info.exposure_us,
        seconds: started.elapsed().as_secs_f64(),
    };
    if args.json {
        println!("{}", serde_json::to_string(&report)?);
    } else {
        println!(
            "{} frames in {:.2} s: {:.2} Hz by frame stamps, {} dropped, {} corrupt; timestamps: {}",
            report.frames,
            report.seconds,
            report.rate_hz,
            report.drops,
            report.corrupt,
            report.timestamp_source
        );
    }
    Ok(())
}

fn open(args: &CameraArgs) -> anyhow::Result<Box<dyn FrameSource>> {
    match args.driver {
        Driver::V4l2 => {
            let mut config = V4l2Config::new(&args.device);
            config.format = match &args.format {
                Some(name) => Some(WireFormat::parse(name).with_context(|| {
                    format!(
                        "--format {name}: not a format rigslam reads over V4L2 (it reads {})",
                        rigslam::sensors::camera::v4l2::supported_text()
                    )
                })?),
                None => None,
            };
            config.width = args.width;
            config.height = args.height;
            config.rate_hz = args.rate_hz.map(|hz| hz.round() as u32);
            config.exposure_us = args.exposure_us.map(|us| us.round() as u32);
            Ok(Box::new(open_v4l2(&config)?))
        }
        Driver::Aravis => open_aravis(args),
        Driver::Fake => Ok(Box::new(PatternCamera::new(
            args.width.unwrap_or(640),
            args.height.unwrap_or(480),
            args.rate_hz.unwrap_or(30.0),
        ))),
    }
}

#[cfg(feature = "aravis")]
fn open_aravis(args: &CameraArgs) -> anyhow::Result<Box<dyn FrameSource>> {
    use rigslam::sensors::camera::aravis::{open_aravis, AravisConfig};
    let config = AravisConfig {
        device: (args.device != "0").then(|| args.device.clone()),
        pixel_format: args.format.clone(),
        width: args.width,
        height: args.height,
        rate_hz: args.rate_hz,
        exposure_us: args.exposure_us,
        ..AravisConfig::default()
    };
    Ok(Box::new(open_aravis(&config)?))
}

#[cfg(not(feature = "aravis"))]
fn open_aravis(_args: &CameraArgs) -> anyhow::Result<Box<dyn FrameSource>> {
    anyhow::bail!(
        "this rigslam was built without Aravis; rebuild with `cargo build --release --features aravis` (needs libaravis-dev, libglib2.0-dev, libusb-1.0-0-dev)"
    )
}

fn format_name(format: PixelFormat) -> String {
    match format {
        PixelFormat::Mono8 => "mono8".into(),
        PixelFormat::Mono16 { significant_bits } => format!("mono16 ({significant_bits} bits)"),
        PixelFormat::Bayer8(p) => format!("bayer8_{}", format!("{p:?}").to_lowercase()),
        PixelFormat::Bayer16(p) => format!("bayer16_{}", format!("{p:?}").to_lowercase()),
    }
}
