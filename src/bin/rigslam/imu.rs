//! `rigslam imu` (being built on its branch; replaced when it lands).

#[derive(clap::Args)]
pub struct ImuArgs {}

pub fn run(_args: ImuArgs) -> anyhow::Result<()> {
    anyhow::bail!("`rigslam imu` is not built yet")
}
