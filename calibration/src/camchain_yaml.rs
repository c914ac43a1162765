//! `camchain-imucam.yaml` in Kalibr's layout: per camera `T_cam_imu` (4x4,
//! maps IMU coordinates into the camera), `timeshift_cam_imu`
//! (`t_imu = t_cam + shift`, s), intrinsics, distortion and resolution.

use std::fmt::Write as _;
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

/// The YAML text.
pub fn camchain_text(entries: &[CamchainEntry]) -> String {
    let mut s = String::new();
    for e in entries {
        let c = &e.camera;
        let [k1, k2, p1, p2, k3] = c.distortion;
        let _ = writeln!(s, "{}:", e.name);
        let _ = writeln!(s, "  T_cam_imu:");
        for r in 0..4 {
            let row: Vec<String> = (0..4)
                .map(|k| format!("{:.12}", e.T_cam_imu[(r, k)]))
                .collect();
            let _ = writeln!(s, "  - [{}]", row.join(", "));
        }
        let _ = writeln!(s, "  camera_model: pinhole");
        let _ = writeln!(s, "  distortion_model: radtan");
        if k3 == 0.0 {
            let _ = writeln!(s, "  distortion_coeffs: [{k1}, {k2}, {p1}, {p2}]");
        } else {
            let _ = writeln!(s, "  distortion_coeffs: [{k1}, {k2}, {p1}, {p2}, {k3}]");
        }
        let _ = writeln!(s, "  intrinsics: [{}, {}, {}, {}]", c.fx, c.fy, c.cx, c.cy);
        let _ = writeln!(s, "  resolution: [{}, {}]", c.width, c.height);
        let _ = writeln!(s, "  timeshift_cam_imu: {:.9}", e.timeshift_cam_imu_s);
    }
    s
}

pub fn write_camchain(path: &Path, entries: &[CamchainEntry]) -> std::io::Result<()> {
    std::fs::write(path, camchain_text(entries))
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trips_through_serde_yaml() {
        let mut t = Matrix4::identity();
        t[(0, 3)] = 0.065;
        t[(1, 0)] = 0.01;
        let entry = CamchainEntry {
            name: "cam0".into(),
            camera: PinholeRadtan::new(
                752,
                480,
                [458.6, 457.3, 367.2, 248.4],
                [-0.28, 0.07, 0.0002, 0.00002, 0.0],
            )
            .expect("valid"),
            T_cam_imu: t,
            timeshift_cam_imu_s: -0.00025,
        };
        let text = camchain_text(&[entry]);
        let yaml: serde_yaml::Value = serde_yaml::from_str(&text).expect("valid YAML");
        let cam = &yaml["cam0"];
        assert_eq!(cam["T_cam_imu"][0][3].as_f64(), Some(0.065));
        assert_eq!(cam["T_cam_imu"][1][0].as_f64(), Some(0.01));
        assert_eq!(cam["timeshift_cam_imu"].as_f64(), Some(-0.00025));
        assert_eq!(
            cam["distortion_coeffs"].as_sequence().map(|s| s.len()),
            Some(4)
        );
        assert_eq!(cam["intrinsics"][0].as_f64(), Some(458.6));
    }
}
