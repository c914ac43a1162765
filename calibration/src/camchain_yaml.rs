//! A camera's intrinsics from a Kalibr camera chain or a `sequence.yaml`
//! (`camN:` with `intrinsics`, `distortion_coeffs`, `resolution`), and one
//! camera's camera-IMU result. The chain itself is written by
//! `rigslam::rig::kalibr`.

use std::path::Path;

use anyhow::{bail, Context};

use nalgebra::Matrix4;
use rigslam::camera::PinholeRadtan;

/// One camera of the chain.
#[derive(Debug, Clone)]
#[allow(non_snake_case)]
pub struct CamchainEntry {
    pub name: String,
    pub camera: PinholeRadtan,
    pub T_cam_imu: Matrix4<f64>,
    pub timeshift_cam_imu_s: f64,
}

/// `camN` intrinsics from a sequence.yaml / Kalibr camchain entry
/// (`intrinsics`, `distortion_coeffs`, `resolution`).
pub fn read_intrinsics(path: &Path, cam: &str) -> anyhow::Result<PinholeRadtan> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    parse_intrinsics(&text, path, cam)
}

/// `camN` intrinsics from the text of a sequence.yaml / camchain; `path`
/// names it in errors.
pub fn parse_intrinsics(text: &str, path: &Path, cam: &str) -> anyhow::Result<PinholeRadtan> {
    let yaml: serde_yaml::Value =
        serde_yaml::from_str(text).with_context(|| format!("parsing {}", path.display()))?;
    let entry = yaml
        .get(cam)
        .with_context(|| format!("{}: no `{cam}` entry", path.display()))?;
    let numbers = |key: &str| -> anyhow::Result<Vec<f64>> {
        let seq = entry
            .get(key)
            .and_then(|v| v.as_sequence())
            .with_context(|| format!("{}: `{cam}.{key}` missing or not a list", path.display()))?;
        seq.iter()
            .map(|v| {
                v.as_f64().with_context(|| {
                    format!("{}: `{cam}.{key}` holds a non-number", path.display())
                })
            })
            .collect()
    };
    let resolution = numbers("resolution")?;
    let distortion = numbers("distortion_coeffs")?;
    if resolution.len() != 2 {
        bail!(
            "{}: `{cam}.resolution` must be [width, height]",
            path.display()
        );
    }
    PinholeRadtan::from_kalibr(
        resolution[0] as u32,
        resolution[1] as u32,
        &numbers("intrinsics")?,
        &distortion,
    )
    .with_context(|| format!("{}: `{cam}` intrinsics", path.display()))
}
