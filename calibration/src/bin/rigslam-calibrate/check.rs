//! `rigslam-calibrate check DIR`: whether a rig calibration folder's files
//! agree with each other (and with a recording of the rig, when given), in
//! plain words; exits non-zero when the daemon would refuse the folder or
//! run wrong with it.

use std::path::PathBuf;

use anyhow::{bail, Context};
use rigslam::dataset::{open_dataset, Dataset};
use rigslam_calibration::folder_check::{check_folder, Observed};

#[derive(clap::Args)]
pub struct CheckArgs {
    /// The calibration folder (what `--out` of the other steps wrote).
    dir: PathBuf,
    /// A recording of this rig, a EuRoC-layout folder (holding mav0/) or
    /// a rigslamd MCAP file: its image sizes and IMU rate are held against
    /// the files.
    #[arg(long)]
    dataset: Option<PathBuf>,
}

/// Image sizes and IMU rate of a rigslamd recording: both cameras' sizes
/// from a stereo recording, cam0's from a mono one.
fn observed_in_recording(path: &std::path::Path) -> anyhow::Result<Observed> {
    let stereo = observed_with(path, true)?;
    if stereo.image_sizes.is_empty() {
        return observed_with(path, false);
    }
    Ok(stereo)
}

fn observed_with(path: &std::path::Path, stereo: bool) -> anyhow::Result<Observed> {
    use std::ops::ControlFlow;
    let mut sizes: Vec<(u32, u32)> = Vec::new();
    let mut stamps = Vec::new();
    rigslam::recording::for_each_sensor_event(
        path,
        rigslam::recording::SensorTopics { stereo, imu: true },
        |item| {
            match item {
                rigslam::recording::ReplayItem::Event(rigslam::dataset::SensorEvent::Imu(s)) => {
                    stamps.push(s.t_ns)
                }
                rigslam::recording::ReplayItem::Event(rigslam::dataset::SensorEvent::Frame {
                    left,
                    right,
                    ..
                }) if sizes.is_empty() => {
                    sizes = std::iter::once(left)
                        .chain(right)
                        .map(|f| (f.image.width(), f.image.height()))
                        .collect();
                }
                _ => {}
            }
            // The rate needs a few seconds of samples, not the whole file.
            if stamps.len() > 2000 && !sizes.is_empty() {
                ControlFlow::Break(())
            } else {
                ControlFlow::Continue(())
            }
        },
    )?;
    Ok(Observed {
        image_sizes: sizes,
        imu_rate_hz: median_rate(&stamps),
    })
}

fn median_rate(stamps: &[i64]) -> Option<f64> {
    let mut dts: Vec<i64> = stamps.windows(2).map(|w| w[1] - w[0]).collect();
    dts.sort_unstable();
    dts.get(dts.len() / 2)
        .filter(|dt| **dt > 0)
        .map(|dt| 1e9 / *dt as f64)
}

fn observed(path: &std::path::Path) -> anyhow::Result<Observed> {
    if rigslam::recording::is_mcap(path) {
        return observed_in_recording(path);
    }
    let Dataset::Euroc(d) = open_dataset(path)? else {
        bail!(
            "{}: give a EuRoC-layout recording (mav0/ with camN/ and imu0/)",
            path.display()
        );
    };
    let mut image_sizes = Vec::new();
    for cam in &d.cameras {
        let first = cam
            .frames
            .iter()
            .find_map(|f| f.path.clone())
            .with_context(|| format!("{}: no images", cam.csv_path.display()))?;
        image_sizes.push(rigslam::dataset::image_file::png_dimensions(&first)?);
    }
    let imu_rate_hz = d.imu.as_ref().and_then(|imu| {
        let mut dts: Vec<i64> = imu
            .samples
            .windows(2)
            .map(|w| w[1].t_ns - w[0].t_ns)
            .collect();
        dts.sort_unstable();
        dts.get(dts.len() / 2)
            .filter(|dt| **dt > 0)
            .map(|dt| 1e9 / *dt as f64)
    });
    Ok(Observed {
        image_sizes,
        imu_rate_hz,
    })
}

pub fn run(args: CheckArgs) -> anyhow::Result<()> {
    let seen = match &args.dataset {
        Some(p) => Some(observed(p).with_context(|| format!("reading {}", p.display()))?),
        None => None,
    };
    let findings = check_folder(&args.dir, seen.as_ref());
    for f in &findings {
        println!("{f}");
    }
    let problems = findings.iter().filter(|f| f.is_problem()).count();
    if problems > 0 {
        bail!(
            "{}: {problems} problem(s); the daemon would refuse this calibration or run wrong with it",
            args.dir.display()
        );
    }
    println!("{}: the files agree", args.dir.display());
    Ok(())
}
