//! `rigslam`: the command-line front of the SLAM core.

use clap::{Parser, Subcommand};

mod bench;
mod camera;
mod demo;
mod echo;
mod eval;
mod imu;
mod map;
mod run;
mod simulate;

#[derive(Parser)]
#[command(
    name = "rigslam",
    version,
    about = "Visual-inertial SLAM for camera + IMU rigs"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Measure one stage (front end, essential matrix) on real data.
    Bench(bench::BenchArgs),
    /// Run the main job on a generated sequence: simulate, read back, estimate, score (the README's first command).
    Demo(demo::DemoArgs),
    /// Read a V4L2 or Aravis camera: identity, format, rate, drops; optionally record.
    Camera(camera::CameraArgs),
    /// Subscribe to a published stream (rigslam/pose, pose_fast, status): print samples, rate, latency.
    Echo(echo::EchoArgs),
    /// Score an estimated trajectory against ground truth (ATE, RPE, scale, final drift).
    Eval(eval::EvalArgs),
    /// Solve, generate and compare edge-map problems (the absolute stage's map, A L = B).
    Map(map::MapArgs),
    /// Read a YEI 3-Space IMU: identity, rate, jitter, error counters; optionally record.
    Imu(imu::ImuArgs),
    /// Run the relative stage on a recorded sequence (EuRoC or KITTI): trajectory, timings, accuracy.
    Run(run::RunArgs),
    /// Render a synthetic EuRoC-layout dataset (images, IMU, ground truth, calibration).
    Simulate(simulate::SimulateArgs),
}

/// Errors are printed as one chain of causes (`error: reading X: X:12: ...`),
/// never as a debug dump with a backtrace: the user needs the file and the
/// line, not our stack.
fn main() -> std::process::ExitCode {
    match run() {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {}", rigslam::console::error_chain(&e));
            std::process::ExitCode::FAILURE
        }
    }
}

fn run() -> anyhow::Result<()> {
    rigslam::console::init_logging();
    match Cli::parse().command {
        Command::Bench(args) => bench::run(args),
        Command::Camera(args) => camera::run(args),
        Command::Demo(args) => demo::run(args),
        Command::Echo(args) => echo::run(args),
        Command::Eval(args) => eval::run(args),
        Command::Imu(args) => imu::run(args),
        Command::Map(args) => map::run(args),
        Command::Simulate(args) => simulate::run(args),
        Command::Run(args) => run::run(args),
    }
}
