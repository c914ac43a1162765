//! `rigslam bench essential` (being built on its branch; replaced when it lands).

#[derive(clap::Args)]
pub struct EssentialArgs {}

pub fn run(_args: EssentialArgs) -> anyhow::Result<()> {
    anyhow::bail!("`rigslam bench essential` is not built yet")
}
