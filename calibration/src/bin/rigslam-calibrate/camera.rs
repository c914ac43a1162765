//! `rigslam-calibrate camera` (being built on its branch; replaced when it lands).

#[derive(clap::Args)]
pub struct CameraArgs {}

pub fn run(_args: CameraArgs) -> anyhow::Result<()> {
    anyhow::bail!("`rigslam-calibrate camera` is not built yet")
}
