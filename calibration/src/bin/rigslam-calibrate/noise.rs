//! `rigslam-calibrate noise` (being built on its branch; replaced when it lands).

#[derive(clap::Args)]
pub struct NoiseArgs {}

pub fn run(_args: NoiseArgs) -> anyhow::Result<()> {
    anyhow::bail!("`rigslam-calibrate noise` is not built yet")
}
