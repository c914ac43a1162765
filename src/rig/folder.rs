//! The rig calibration folder: what `rigslam-calibrate --out DIR` writes
//! and what `rigslamd` (`[calibration] folder = DIR`) and `rigslam run
//! --calibration DIR` read as it is.
//!
//! | file | written by | holds |
//! |---|---|---|
//! | `camchain.yaml` | `camera` | Kalibr chain, intrinsics only |
//! | `camchain-imucam.yaml` | `camera-imu` | Kalibr chain with `T_cam_imu`, `timeshift_cam_imu` |
//! | `imu.yaml` | `noise` | Kalibr noise densities, random walks, `update_rate` |
//! | `imu_intrinsics.yaml` | `imu` | `x_c = S x_r + b` per triad |
//!
//! The rig needs `camchain-imucam.yaml` and, for the inertial modes,
//! `imu.yaml`; `imu_intrinsics.yaml` is optional (identity without it).
//! The same names are used for a recording's calibration attachments, so
//! a recording replays with exactly the files the robot ran on.

use std::path::{Path, PathBuf};

use super::{kalibr, RigModel};
use crate::text_file::DatasetError;

/// File name of a Kalibr camera chain with intrinsics only (`rigslam-calibrate camera`); not enough
/// for a rig.
pub const CAMCHAIN_INTRINSICS: &str = "camchain.yaml";
/// File name of the Kalibr camera chain with `T_cam_imu` and `timeshift_cam_imu`
/// (`rigslam-calibrate camera-imu`).
pub const CAMCHAIN: &str = "camchain-imucam.yaml";
/// File name of the Kalibr IMU noise file (`rigslam-calibrate noise`).
pub const IMU_NOISE: &str = "imu.yaml";
/// File name of the IMU intrinsics `x_c = S x_r + b` (`rigslam-calibrate imu`); optional.
pub const IMU_INTRINSICS: &str = "imu_intrinsics.yaml";

/// The files of a folder that make a rig, in the order they are read.
pub const RIG_FILES: [&str; 3] = [CAMCHAIN, IMU_NOISE, IMU_INTRINSICS];

/// One calibration file under its canonical name (one of
/// [`RIG_FILES`], or EuRoC's per-sensor `cam0.yaml`, `cam1.yaml`,
/// `imu0.yaml`), with where it came from for the messages.
#[derive(Debug, Clone, PartialEq)]
pub struct CalibrationFile {
    /// Canonical name, e.g. `camchain-imucam.yaml`.
    pub name: String,
    /// Where the bytes were read from (a file or a recording's attachment), for the messages.
    pub origin: PathBuf,
    /// The file's contents.
    pub bytes: Vec<u8>,
}

impl CalibrationFile {
    fn text(&self) -> Result<String, DatasetError> {
        String::from_utf8(self.bytes.clone())
            .map_err(|_| DatasetError::malformed(&self.origin, 1, "not UTF-8 text"))
    }
}

/// The rig files present in `dir` (missing ones are left out; the rig
/// reader says which it needs).
pub fn read_folder(dir: &Path) -> Result<Vec<CalibrationFile>, DatasetError> {
    let meta = std::fs::metadata(dir).map_err(|e| DatasetError::io(dir, e))?;
    if !meta.is_dir() {
        return Err(DatasetError::malformed(
            dir,
            0,
            "not a folder: give the calibration folder `rigslam-calibrate --out` wrote",
        ));
    }
    let mut out = Vec::new();
    for name in RIG_FILES {
        let path = dir.join(name);
        match std::fs::read(&path) {
            Ok(bytes) => out.push(CalibrationFile {
                name: name.to_owned(),
                origin: path,
                bytes,
            }),
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
            Err(e) => return Err(DatasetError::io(path, e)),
        }
    }
    if out.is_empty() && dir.join(CAMCHAIN_INTRINSICS).exists() {
        return Err(DatasetError::io(
            dir.join(CAMCHAIN),
            std::io::Error::new(
                std::io::ErrorKind::NotFound,
                format!("only {CAMCHAIN_INTRINSICS} is there (intrinsics only): run `rigslam-calibrate camera-imu --out` on this folder"),
            ),
        ));
    }
    Ok(out)
}

/// Individually named files (`[calibration] cameras = [...]`, `imu = ...`,
/// `imu_intrinsics = ...`) under canonical names, each recognised by its
/// content: a Kalibr camera chain gives every camera (and must be the only
/// camera file), a EuRoC `sensor.yaml` one camera; an IMU file with
/// `T_BS` is EuRoC's, otherwise Kalibr's `imu.yaml`.
pub fn name_files(
    cameras: &[PathBuf],
    imu: Option<&Path>,
    imu_intrinsics: Option<&Path>,
) -> Result<Vec<CalibrationFile>, DatasetError> {
    let read = |path: &Path| std::fs::read(path).map_err(|e| DatasetError::io(path, e));
    let mut out = Vec::new();
    for (i, path) in cameras.iter().enumerate() {
        let bytes = read(path)?;
        let chain = kalibr::is_camchain(&String::from_utf8_lossy(&bytes));
        if chain && cameras.len() > 1 {
            return Err(DatasetError::malformed(
                path,
                1,
                "a Kalibr camera chain holds every camera: list it alone in `cameras`",
            ));
        }
        let name = if chain {
            CAMCHAIN.to_owned()
        } else {
            format!("cam{i}.yaml")
        };
        out.push(CalibrationFile {
            name,
            origin: path.clone(),
            bytes,
        });
    }
    if let Some(path) = imu {
        let bytes = read(path)?;
        let euroc = String::from_utf8_lossy(&bytes)
            .lines()
            .any(|l| l.trim_start().starts_with("T_BS"));
        out.push(CalibrationFile {
            name: if euroc { "imu0.yaml" } else { IMU_NOISE }.to_owned(),
            origin: path.to_path_buf(),
            bytes,
        });
    }
    if let Some(path) = imu_intrinsics {
        out.push(CalibrationFile {
            name: IMU_INTRINSICS.to_owned(),
            origin: path.to_path_buf(),
            bytes: read(path)?,
        });
    }
    Ok(out)
}

/// The rig from calibration files under their canonical names; `where_`
/// names the folder (or recording) in messages about a missing file.
/// `needs_imu`: the mode is inertial, so an IMU file must be there.
pub fn rig_from_files(
    files: &[CalibrationFile],
    where_: &Path,
    needs_imu: bool,
) -> Result<RigModel, DatasetError> {
    let find = |name: &str| files.iter().find(|f| f.name == name);
    let missing = |name: &str, hint: &str| {
        DatasetError::io(
            where_.join(name),
            std::io::Error::new(std::io::ErrorKind::NotFound, hint.to_owned()),
        )
    };
    let cameras = match find(CAMCHAIN) {
        Some(f) => kalibr::cameras_from_camchain(&f.text()?, &f.origin)?,
        None => {
            let mut cameras = Vec::new();
            while let Some(f) = find(&format!("cam{}.yaml", cameras.len())) {
                cameras.push(super::sensor_yaml::parse_camera_yaml(
                    &f.text()?,
                    &f.origin,
                )?);
            }
            if cameras.is_empty() {
                return Err(missing(
                    CAMCHAIN,
                    "no camera calibration: run `rigslam-calibrate camera` then `camera-imu` with `--out` this folder, or copy Kalibr's camchain-imucam.yaml here",
                ));
            }
            cameras
        }
    };
    let mut imu = match (find(IMU_NOISE), find("imu0.yaml")) {
        (Some(f), _) => Some(kalibr::imu_from_kalibr(&f.text()?, &f.origin)?),
        (None, Some(f)) => Some(super::sensor_yaml::parse_imu_yaml(&f.text()?, &f.origin)?),
        (None, None) if needs_imu => {
            return Err(missing(
                IMU_NOISE,
                "the inertial modes need the IMU noise: run `rigslam-calibrate noise --out` on this folder, or copy Kalibr's imu.yaml here",
            ))
        }
        (None, None) => None,
    };
    if let (Some(imu), Some(f)) = (imu.as_mut(), find(IMU_INTRINSICS)) {
        imu.intrinsics = super::imu_intrinsics_file::parse_intrinsics_yaml(&f.text()?, &f.origin)?;
    }
    Ok(RigModel { cameras, imu })
}

/// Reads the rig in `dir`.
pub fn load_folder(dir: &Path, needs_imu: bool) -> Result<RigModel, DatasetError> {
    rig_from_files(&read_folder(dir)?, dir, needs_imu)
}

pub use crate::text_file::write_atomically;

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rig::euroc::{euroc_cam0, euroc_cam1, euroc_imu0};
    use crate::rig::ImuIntrinsics;

    fn write_rig(dir: &Path, intrinsics: Option<&ImuIntrinsics>) {
        let chain = kalibr::camchain_yaml(&[euroc_cam0(), euroc_cam1()], true).expect("writes");
        write_atomically(&dir.join(CAMCHAIN), chain.as_bytes()).expect("write");
        let imu = euroc_imu0();
        let noise = kalibr::imu_yaml(&imu.noise, imu.rate_hz);
        write_atomically(&dir.join(IMU_NOISE), noise.as_bytes()).expect("write");
        if let Some(i) = intrinsics {
            let text = super::super::imu_intrinsics_file::intrinsics_yaml(i);
            write_atomically(&dir.join(IMU_INTRINSICS), text.as_bytes()).expect("write");
        }
    }

    #[test]
    fn a_folder_reads_as_the_rig_it_was_written_from() {
        let dir = tempfile::tempdir().expect("temp dir");
        let mut intrinsics = ImuIntrinsics::IDENTITY;
        intrinsics.accel_scale[(0, 0)] = 1.02;
        intrinsics.gyro_offset_rad_s.z = 0.003;
        write_rig(dir.path(), Some(&intrinsics));
        let rig = load_folder(dir.path(), true).expect("reads");
        assert_eq!(rig.cameras.len(), 2);
        let cam1 = euroc_cam1();
        let d = cam1.T_body_cam.inverse() * rig.cameras[1].T_body_cam;
        assert!(d.translation.vector.norm() < 1e-12 && d.rotation.angle() < 1e-12);
        let imu = rig.imu.expect("imu.yaml was written");
        assert_eq!(imu.noise, euroc_imu0().noise);
        assert_eq!(imu.intrinsics, intrinsics);
        // No temporary files left behind.
        let names: Vec<_> = std::fs::read_dir(dir.path())
            .expect("list")
            .map(|e| e.expect("entry").file_name().to_string_lossy().into_owned())
            .collect();
        assert!(names.iter().all(|n| !n.contains(".tmp")), "{names:?}");
    }

    #[test]
    fn what_is_missing_is_named_with_the_step_that_makes_it() {
        let dir = tempfile::tempdir().expect("temp dir");
        let e = load_folder(dir.path(), true)
            .expect_err("empty")
            .to_string();
        assert!(e.contains(CAMCHAIN) && e.contains("camera-imu"), "{e}");
        let e = load_folder(&dir.path().join("nowhere"), true)
            .expect_err("no folder")
            .to_string();
        assert!(e.contains("nowhere"), "{e}");
        let only_intrinsics = kalibr::camchain_yaml(&[euroc_cam0()], false).expect("writes");
        std::fs::write(dir.path().join(CAMCHAIN_INTRINSICS), only_intrinsics).expect("write");
        let e = load_folder(dir.path(), true)
            .expect_err("no extrinsics")
            .to_string();
        assert!(e.contains("intrinsics only"), "{e}");
        write_rig(dir.path(), None);
        std::fs::remove_file(dir.path().join(IMU_NOISE)).expect("remove");
        let e = load_folder(dir.path(), true)
            .expect_err("no noise")
            .to_string();
        assert!(e.contains(IMU_NOISE) && e.contains("noise"), "{e}");
        let rig = load_folder(dir.path(), false).expect("vision-only needs no IMU");
        assert!(rig.imu.is_none());
        let file = dir.path().join(CAMCHAIN);
        let e = load_folder(&file, true).expect_err("a file").to_string();
        assert!(e.contains("not a folder"), "{e}");
    }

    #[test]
    fn euroc_and_kalibr_files_can_be_mixed_and_each_is_recognised() {
        let dir = tempfile::tempdir().expect("temp dir");
        let d = dir.path();
        let cam0 = d.join("cam0_sensor.yaml");
        let cam1 = d.join("cam1_sensor.yaml");
        std::fs::write(
            &cam0,
            crate::rig::sensor_yaml::camera_yaml("cam0", &euroc_cam0()),
        )
        .expect("write");
        std::fs::write(
            &cam1,
            crate::rig::sensor_yaml::camera_yaml("cam1", &euroc_cam1()),
        )
        .expect("write");
        let imu = euroc_imu0();
        let kalibr_imu = d.join("kalibr_imu.yaml");
        std::fs::write(&kalibr_imu, kalibr::imu_yaml(&imu.noise, imu.rate_hz)).expect("write");
        let files = name_files(&[cam0.clone(), cam1], Some(&kalibr_imu), None).expect("named");
        let names: Vec<_> = files.iter().map(|f| f.name.as_str()).collect();
        assert_eq!(names, ["cam0.yaml", "cam1.yaml", IMU_NOISE]);
        let rig = rig_from_files(&files, d, true).expect("reads");
        let (read, written) = (&rig.cameras[1], euroc_cam1());
        assert_eq!(read.model, written.model);
        let off = read.T_body_cam.inverse() * written.T_body_cam;
        assert!(off.translation.vector.norm() < 1e-12 && off.rotation.angle() < 1e-12);
        assert_eq!(rig.imu.expect("imu").noise, imu.noise);

        let euroc_imu = d.join("imu_sensor.yaml");
        std::fs::write(&euroc_imu, crate::rig::sensor_yaml::imu_yaml(&imu)).expect("write");
        let chain = d.join("chain.yaml");
        std::fs::write(
            &chain,
            kalibr::camchain_yaml(&[euroc_cam0(), euroc_cam1()], true).expect("writes"),
        )
        .expect("write");
        let files =
            name_files(std::slice::from_ref(&chain), Some(&euroc_imu), None).expect("named");
        let names: Vec<_> = files.iter().map(|f| f.name.as_str()).collect();
        assert_eq!(names, [CAMCHAIN, "imu0.yaml"]);
        assert_eq!(
            rig_from_files(&files, d, true)
                .expect("reads")
                .cameras
                .len(),
            2
        );

        let e = name_files(&[chain, cam0], None, None)
            .expect_err("chain not alone")
            .to_string();
        assert!(e.contains("alone"), "{e}");
    }
}
