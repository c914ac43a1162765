//! `rigslam-calibrate`: one command per calibration step, each writing its
//! file into one rig calibration folder (`--out DIR`, see
//! `rigslam::rig::folder`) that the daemon reads as it is, with a report
//! beside it; `check` gives the verdict on a folder.

use clap::{Parser, Subcommand};

mod camera;
mod camera_imu;
mod check;
mod export;
mod imu;
mod noise;
mod target_input;

#[derive(Parser)]
#[command(
    name = "rigslam-calibrate",
    version,
    about = "Calibrate a camera + IMU rig for rigslam"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Accelerometer scale/misalignment and bias from static orientations; gyroscope bias (and scale with rotations).
    Imu(imu::ImuArgs),
    /// Allan deviation of a static log: noise densities and random walks as a Kalibr imu.yaml.
    Noise(noise::NoiseArgs),
    /// Camera intrinsics (pinhole + radial-tangential) from chessboard images.
    Camera(camera::CameraArgs),
    /// Camera-IMU rotation, translation and time offset from target detections and IMU.
    CameraImu(camera_imu::CameraImuArgs),
    /// Whether a calibration folder's files agree (image sizes, rates,
    /// frames, time shift), in plain words; non-zero exit on a problem.
    Check(check::CheckArgs),
    /// The calibration folder in OpenVINS, Basalt or VINS-Fusion files.
    Export(export::ExportArgs),
}

/// `dir/name`, with `dir` created: every subcommand writes its file into
/// the one rig calibration folder given by `--out`.
pub(crate) fn output_file(dir: &std::path::Path, name: &str) -> anyhow::Result<std::path::PathBuf> {
    use anyhow::Context as _;
    if dir.is_file() {
        anyhow::bail!(
            "--out {}: is a file; give the calibration folder (every step writes its file there)",
            dir.display()
        );
    }
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    Ok(dir.join(name))
}

fn main() -> std::process::ExitCode {
    // The core's warnings (a recording's unreadable rows, say) reach the
    // user as the other binaries' do.
    rigslam::console::init_logging();
    let result = match Cli::parse().command {
        Command::Imu(args) => imu::run(args),
        Command::Noise(args) => noise::run(args),
        Command::Camera(args) => camera::run(args),
        Command::CameraImu(args) => camera_imu::run(args),
        Command::Check(args) => check::run(args),
        Command::Export(args) => export::run(args),
    };
    match result {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {}", rigslam::console::error_chain(&e));
            std::process::ExitCode::FAILURE
        }
    }
}
