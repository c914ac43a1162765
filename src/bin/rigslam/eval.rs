//! `rigslam eval` (being built on its branch; replaced when it lands).

#[derive(clap::Args)]
pub struct EvalArgs {}

pub fn run(_args: EvalArgs) -> anyhow::Result<()> {
    anyhow::bail!("`rigslam eval` is not built yet")
}
