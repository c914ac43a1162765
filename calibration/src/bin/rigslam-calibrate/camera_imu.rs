//! `rigslam-calibrate camera-imu` (being built on its branch; replaced when it lands).

#[derive(clap::Args)]
pub struct CameraImuArgs {}

pub fn run(_args: CameraImuArgs) -> anyhow::Result<()> {
    anyhow::bail!("`rigslam-calibrate camera-imu` is not built yet")
}
