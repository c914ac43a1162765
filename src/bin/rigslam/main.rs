//! `rigslam`: the command-line front of the SLAM core.

use clap::{Parser, Subcommand};

mod bench;
mod demo;
mod eval;
mod map;
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
    /// Score an estimated trajectory against ground truth (ATE, RPE, scale, final drift).
    Eval(eval::EvalArgs),
    /// Solve, generate and compare edge-map problems (the absolute stage's map, A L = B).
    Map(map::MapArgs),
    /// Render a synthetic EuRoC-layout dataset (images, IMU, ground truth, calibration).
    Simulate(simulate::SimulateArgs),
}

fn main() -> anyhow::Result<()> {
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| "info".into()),
        )
        .with_writer(std::io::stderr)
        .init();
    match Cli::parse().command {
        Command::Bench(args) => bench::run(args),
        Command::Demo(args) => demo::run(args),
        Command::Eval(args) => eval::run(args),
        Command::Map(args) => map::run(args),
        Command::Simulate(args) => simulate::run(args),
    }
}
