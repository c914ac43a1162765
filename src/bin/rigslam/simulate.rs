//! `rigslam simulate` (being built on its branch; replaced when it lands).

#[derive(clap::Args)]
pub struct SimulateArgs {}

pub fn run(_args: SimulateArgs) -> anyhow::Result<()> {
    anyhow::bail!("`rigslam simulate` is not built yet")
}
