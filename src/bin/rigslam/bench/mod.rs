//! `rigslam bench`: speed and quality of one stage on real data, printed
//! for people or as one JSON object (`--json`).

mod essential;
mod frontend;

#[derive(clap::Args)]
pub struct BenchArgs {
    #[command(subcommand)]
    command: BenchCommand,
}

#[derive(clap::Subcommand)]
enum BenchCommand {
    /// Feature detection + KLT tracking and ORB extraction over a folder of frames.
    Frontend(frontend::FrontendArgs),
    /// Five-point RANSAC relative pose over a file of correspondences.
    Essential(essential::EssentialArgs),
}

pub fn run(args: BenchArgs) -> anyhow::Result<()> {
    match args.command {
        BenchCommand::Frontend(a) => frontend::run(a),
        BenchCommand::Essential(a) => essential::run(a),
    }
}
