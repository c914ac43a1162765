//! `rigslam-calibrate export --to openvins|basalt|vins DIR --out OUT`: the
//! calibration folder in another estimator's files, with what the format
//! cannot carry printed.

use std::path::PathBuf;

use anyhow::Context;
use rigslam_calibration::export::{export, write_export, ExportTarget};

#[derive(clap::Args)]
pub struct ExportArgs {
    /// The calibration folder (camchain-imucam.yaml, imu.yaml,
    /// imu_intrinsics.yaml).
    dir: PathBuf,
    /// The system to write for.
    #[arg(long, value_enum)]
    to: ExportTarget,
    /// Folder for the exported files (created if need be).
    #[arg(long, value_name = "DIR")]
    out: PathBuf,
}

pub fn run(args: ExportArgs) -> anyhow::Result<()> {
    let rig = rigslam::rig::folder::load_folder(&args.dir, true)
        .with_context(|| format!("reading the calibration folder {}", args.dir.display()))?;
    let made = export(&rig, args.to)?;
    for path in write_export(&made, &args.out)? {
        println!("wrote {}", path.display());
    }
    for note in &made.notes {
        println!("note: {note}");
    }
    Ok(())
}
