//! `rigslam bench frontend` (being built on its branch; replaced when it lands).

#[derive(clap::Args)]
pub struct FrontendArgs {}

pub fn run(_args: FrontendArgs) -> anyhow::Result<()> {
    anyhow::bail!("`rigslam bench frontend` is not built yet")
}
