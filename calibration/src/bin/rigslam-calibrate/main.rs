//! `rigslam-calibrate`: one command per calibration step, each writing the
//! YAML the daemon reads and a report beside it.

use clap::{Parser, Subcommand};

mod camera;
mod camera_imu;
mod imu;
mod noise;

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
}

fn main() -> std::process::ExitCode {
    let result = match Cli::parse().command {
        Command::Imu(args) => imu::run(args),
        Command::Noise(args) => noise::run(args),
        Command::Camera(args) => camera::run(args),
        Command::CameraImu(args) => camera_imu::run(args),
    };
    match result {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            std::process::ExitCode::FAILURE
        }
    }
}
