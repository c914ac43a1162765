//! `rigslam-calibrate export --to openvins|basalt|vins`: the rig's
//! calibration folder in the files other estimators read, so one
//! calibration serves every system a team compares.
//!
//! Each writer builds the target's layout from serde types; the layouts
//! follow the projects' public example configurations (the key sets and
//! shapes are checked against fixtures made from those examples, see
//! `fixtures/calibration_export/PROVENANCE.md`). What a format cannot carry
//! is said in the returned notes, never dropped silently.

use std::path::{Path, PathBuf};

use rigslam::rig::RigModel;

pub mod basalt;
pub mod opencv_yaml;
pub mod openvins;
pub mod vins;

/// The systems `export` writes for.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum ExportTarget {
    /// OpenVINS: `kalibr_imucam_chain.yaml` and `kalibr_imu_chain.yaml`.
    Openvins,
    /// Basalt: `calibration.json`.
    Basalt,
    /// VINS-Fusion: `vins_config.yaml` with `cam0.yaml` (and `cam1.yaml`).
    Vins,
}

/// One file of an export.
#[derive(Debug, Clone, PartialEq)]
pub struct ExportFile {
    pub name: String,
    pub text: String,
}

/// What an export made: its files and what the format could not carry.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Export {
    pub files: Vec<ExportFile>,
    pub notes: Vec<String>,
}

/// Why a rig cannot be exported.
#[derive(Debug, thiserror::Error)]
pub enum ExportError {
    #[error("the rig has no IMU calibration (imu.yaml): every target is visual-inertial")]
    NoImu,
    #[error("{0}")]
    Camera(String),
    #[error("writing {path}: {source}")]
    Write {
        path: PathBuf,
        source: std::io::Error,
    },
}

/// The rig in `target`'s files.
pub fn export(rig: &RigModel, target: ExportTarget) -> Result<Export, ExportError> {
    let imu = rig.imu.as_ref().ok_or(ExportError::NoImu)?;
    for (i, c) in rig.cameras.iter().enumerate() {
        if let rigslam::camera::CameraModel::PinholeEquidistant(_) = c.model {
            if target == ExportTarget::Vins {
                return Err(ExportError::Camera(format!(
                    "cam{i} is equidistant (fisheye); this export writes VINS-Fusion's PINHOLE model only"
                )));
            }
        }
    }
    match target {
        ExportTarget::Openvins => openvins::export(&rig.cameras, imu),
        ExportTarget::Basalt => basalt::export(&rig.cameras, imu),
        ExportTarget::Vins => vins::export(&rig.cameras, imu),
    }
}

/// Writes every file of `export` into `dir` (atomically, each).
pub fn write_export(export: &Export, dir: &Path) -> Result<Vec<PathBuf>, ExportError> {
    std::fs::create_dir_all(dir).map_err(|source| ExportError::Write {
        path: dir.to_path_buf(),
        source,
    })?;
    export
        .files
        .iter()
        .map(|f| {
            let path = dir.join(&f.name);
            rigslam::rig::folder::write_atomically(&path, f.text.as_bytes())
                .map(|()| path.clone())
                .map_err(|source| ExportError::Write { path, source })
        })
        .collect()
}

/// Rows of a 4x4 homogeneous matrix.
pub(crate) fn rows4(t: &nalgebra::Isometry3<f64>) -> [[f64; 4]; 4] {
    let m = t.to_homogeneous();
    [0, 1, 2, 3].map(|r| [m[(r, 0)], m[(r, 1)], m[(r, 2)], m[(r, 3)]])
}

/// Radial-tangential k1, k2, p1, p2 of a camera, or why it has no such form.
pub(crate) fn radtan4(
    camera: &rigslam::rig::CameraCalibration,
    index: usize,
) -> Result<[f64; 4], ExportError> {
    let c = camera.model.distortion_coefficients();
    match camera.model {
        rigslam::camera::CameraModel::PinholeRadtan(_) => {
            if c.get(4).is_some_and(|k3| *k3 != 0.0) {
                return Err(ExportError::Camera(format!(
                    "cam{index} has k3 = {}: the target's radtan has four coefficients; calibrate with k3 held at 0",
                    c[4]
                )));
            }
            Ok([c[0], c[1], c[2], c[3]])
        }
        rigslam::camera::CameraModel::PinholeEquidistant(_) => Err(ExportError::Camera(format!(
            "cam{index} is equidistant, not radtan"
        ))),
    }
}
