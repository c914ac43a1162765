//! Reads a EuRoC ASL dataset. Calibration, stamps, IMU and ground truth
//! are read at once; images only when asked for.

use std::path::{Path, PathBuf};

use super::imu_csv::read_euroc_imu_csv;
use super::sensor_yaml::{read_camera_yaml, read_imu_yaml};
use super::{camera_number, GROUNDTRUTH_DIR, IMU_DIR};
use crate::dataset::error::DatasetError;
use crate::dataset::groundtruth::{read_euroc_groundtruth, GroundTruthState};
use crate::dataset::image_file::read_png;
use crate::dataset::text::{
    check_euroc_header, check_increasing, data_lines, parse_stamp_ns, read_text,
};
use crate::rig::{CameraCalibration, ImuCalibration};
use crate::sensors::{Frame, ImuSample};

/// One row of a camera's `data.csv`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ImageEntry {
    /// Exposure stamp from `data.csv`, ns (EuRoC's clock).
    pub t_ns: i64,
    /// The image file; `None` when the stamp is listed but the file is
    /// absent (EuRoC's V1_01 cam1 lists stamps whose PNGs were dropped).
    pub path: Option<PathBuf>,
    /// The image file the listing names, there or not (for messages).
    pub listed_path: PathBuf,
}

/// One camera: calibration and the stamps of its images.
#[derive(Debug, Clone)]
pub struct EurocCamera {
    /// Folder name, `camN`.
    pub name: String,
    /// N of `camN`, which becomes [`Frame::camera_index`].
    pub camera_index: u8,
    /// Intrinsics, distortion and `T_BS` (camera to body = IMU) from the camera's `sensor.yaml`.
    pub calibration: CameraCalibration,
    /// The `data.csv` rows in increasing stamp order.
    pub frames: Vec<ImageEntry>,
    /// The `data.csv` the frames came from, for error messages.
    pub csv_path: PathBuf,
}

impl EurocCamera {
    /// Decodes image `index`: `Ok(None)` when its file is absent, an
    /// `Image` error when the PNG is truncated or corrupt, a `Layout`
    /// error when `index` is past the end.
    pub fn load(&self, index: usize) -> Result<Option<Frame>, DatasetError> {
        load_listed(&self.frames, index, &self.csv_path, self.camera_index)
    }

    /// Stamps listed without an image file.
    pub fn missing_images(&self) -> usize {
        self.frames.iter().filter(|f| f.path.is_none()).count()
    }
}

/// The IMU: calibration and samples.
#[derive(Debug, Clone)]
pub struct EurocImu {
    /// Noise densities and `T_BS` from `imu0/sensor.yaml`.
    pub calibration: ImuCalibration,
    /// Finite samples in increasing time order.
    pub samples: Vec<ImuSample>,
    /// Rows with NaN or infinite values, dropped (see [`super::ImuCsv`]).
    pub dropped_nonfinite: usize,
}

/// A EuRoC ASL dataset.
#[derive(Debug, Clone)]
pub struct EurocDataset {
    /// The `mav0` folder.
    pub root: PathBuf,
    /// `camN` folders in increasing N.
    pub cameras: Vec<EurocCamera>,
    /// `imu0`, when the dataset has one.
    pub imu: Option<EurocImu>,
    /// `state_groundtruth_estimate0/data.csv`, when present.
    pub groundtruth: Option<Vec<GroundTruthState>>,
}

impl EurocDataset {
    /// Opens the folder holding `mav0/`, or `mav0` itself. Every camera
    /// folder needs `data.csv` and `sensor.yaml`; `imu0/` and the ground
    /// truth are optional, but when present must be complete and valid.
    pub fn open(path: &Path) -> Result<Self, DatasetError> {
        let root = mav0_of(path).ok_or_else(|| {
            DatasetError::layout(
                path,
                "not a EuRoC ASL dataset: expected mav0/ or camN/ and imu0/ folders",
            )
        })?;
        let mut cameras = Vec::new();
        for (number, dir) in camera_dirs(&root)? {
            cameras.push(read_camera(&dir, number)?);
        }
        let imu_dir = root.join(IMU_DIR);
        let imu = if imu_dir.is_dir() {
            let csv_path = imu_dir.join("data.csv");
            let csv = read_euroc_imu_csv(&csv_path)?;
            if let Some(line) = csv.first_nonfinite_line {
                tracing::warn!(
                    "{}: {} sample{} with NaN or infinite values left out, the first on line {line}",
                    csv_path.display(),
                    csv.dropped_nonfinite,
                    if csv.dropped_nonfinite == 1 { "" } else { "s" }
                );
            }
            Some(EurocImu {
                calibration: read_imu_yaml(&imu_dir.join("sensor.yaml"))?,
                samples: csv.samples,
                dropped_nonfinite: csv.dropped_nonfinite,
            })
        } else {
            None
        };
        let gt_csv = root.join(GROUNDTRUTH_DIR).join("data.csv");
        let groundtruth = if gt_csv.is_file() {
            Some(read_euroc_groundtruth(&gt_csv)?)
        } else {
            None
        };
        if cameras.is_empty() && imu.is_none() {
            return Err(DatasetError::layout(
                &root,
                "holds neither camN/ nor imu0/ folders",
            ));
        }
        Ok(Self {
            root,
            cameras,
            imu,
            groundtruth,
        })
    }

    /// The camera whose folder is `name`.
    pub fn camera(&self, name: &str) -> Option<&EurocCamera> {
        self.cameras.iter().find(|c| c.name == name)
    }
}

/// `path/mav0` if it exists, else `path` when it looks like a `mav0`
/// folder (named so, or holding `camN/` or `imu0/`).
pub(crate) fn mav0_of(path: &Path) -> Option<PathBuf> {
    let nested = path.join("mav0");
    if nested.is_dir() {
        return Some(nested);
    }
    let looks_like_mav0 = path.file_name().is_some_and(|n| n == "mav0")
        || path.join(IMU_DIR).is_dir()
        || path.join("cam0").join("data.csv").is_file();
    (path.is_dir() && looks_like_mav0).then(|| path.to_path_buf())
}

/// `camN` sub-folders in increasing N.
fn camera_dirs(root: &Path) -> Result<Vec<(u8, PathBuf)>, DatasetError> {
    let entries = std::fs::read_dir(root).map_err(|e| DatasetError::io(root, e))?;
    let mut dirs = Vec::new();
    for entry in entries {
        let entry = entry.map_err(|e| DatasetError::io(root, e))?;
        let name = entry.file_name();
        if let Some(number) = name.to_str().and_then(camera_number) {
            if entry.path().is_dir() {
                dirs.push((number, entry.path()));
            }
        }
    }
    dirs.sort();
    Ok(dirs)
}

fn read_camera(dir: &Path, number: u8) -> Result<EurocCamera, DatasetError> {
    let csv_path = dir.join("data.csv");
    let text = read_text(&csv_path)?;
    check_euroc_header(
        &csv_path,
        &text,
        &[2],
        "2 columns (t_ns, filename) for a camera's data.csv",
    )?;
    let image_dir = dir.join("data");
    let mut frames = Vec::new();
    let mut stamps = Vec::new();
    for (line_no, line) in data_lines(&text) {
        let fields: Vec<&str> = line.split(',').map(str::trim).collect();
        let [stamp, file_name] = fields[..] else {
            return Err(DatasetError::malformed(
                &csv_path,
                line_no,
                format!("expected 2 fields (t_ns, filename), found {}", fields.len()),
            ));
        };
        let t_ns = parse_stamp_ns(&csv_path, line_no, stamp)?;
        if file_name.is_empty() {
            return Err(DatasetError::malformed(
                &csv_path,
                line_no,
                "empty file name",
            ));
        }
        let image_path = image_dir.join(file_name);
        frames.push(ImageEntry {
            t_ns,
            path: image_path.is_file().then(|| image_path.clone()),
            listed_path: image_path,
        });
        stamps.push((line_no, t_ns));
    }
    check_increasing(&csv_path, stamps)?;
    Ok(EurocCamera {
        name: format!("cam{number}"),
        camera_index: number,
        calibration: read_camera_yaml(&dir.join("sensor.yaml"))?,
        frames,
        csv_path,
    })
}

/// Decodes entry `index` of a camera's listing (`listing` names the file
/// or folder the entries came from, for the error when `index` is past the
/// end): `Ok(None)` when the entry has no image file.
pub(crate) fn load_listed(
    frames: &[ImageEntry],
    index: usize,
    listing: &Path,
    camera_index: u8,
) -> Result<Option<Frame>, DatasetError> {
    let entry = frames.get(index).ok_or_else(|| {
        DatasetError::layout(
            listing,
            format!("frame {index} asked for, {} listed", frames.len()),
        )
    })?;
    let Some(path) = &entry.path else {
        return Ok(None);
    };
    Ok(Some(Frame {
        t_ns: entry.t_ns,
        seq: index as u64,
        camera_index,
        image: read_png(path)?,
    }))
}

#[cfg(test)]
mod tests {
    use super::super::writer::EurocWriter;
    use super::*;
    use crate::camera::{CameraModel, PinholeRadtan};
    use crate::rig::ImuNoise;
    use crate::sensors::{Image, PixelFormat};
    use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};

    fn calibration(cx: f64) -> CameraCalibration {
        CameraCalibration {
            time_shift_cam_imu_s: 0.0,
            model: CameraModel::PinholeRadtan(PinholeRadtan {
                width: 32,
                height: 24,
                fx: 458.654,
                fy: 457.296,
                cx,
                cy: 248.375,
                distortion: [-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05, 0.0],
            }),
            T_body_cam: Isometry3::from_parts(
                Translation3::new(-0.0216401454975, -0.064676986768, 0.00981073058949),
                UnitQuaternion::from_euler_angles(1.5, -0.02, 1.56),
            ),
            rate_hz: 20.0,
        }
    }

    fn image(seed: u32, sixteen_bit: bool) -> Image {
        if sixteen_bit {
            let words: Vec<u16> = (0..32 * 24)
                .map(|i| ((i * 977 + seed * 31) % 4096) as u16)
                .collect();
            Image::mono16(32, 24, 12, &words).expect("image")
        } else {
            let px: Vec<u8> = (0..32 * 24)
                .map(|i| ((i * 7 + seed * 13) % 256) as u8)
                .collect();
            Image::mono8(32, 24, px).expect("image")
        }
    }

    fn imu_samples() -> Vec<ImuSample> {
        (0..400)
            .map(|i| {
                let t = i as f64 * 0.005;
                ImuSample {
                    t_ns: 1_403_715_273_262_142_976 + i * 5_000_000,
                    gyro_rad_s: [0.1 * t.sin(), -0.02, 1.0 / (t + 1.0)],
                    accel_m_s2: [9.80665 * t.cos(), 0.13075533333333333, -3.69 + t],
                }
            })
            .collect()
    }

    fn groundtruth() -> Vec<GroundTruthState> {
        (0..40)
            .map(|i| GroundTruthState {
                t_ns: 1_403_715_273_262_142_976 + i * 50_000_000,
                T_world_body: Isometry3::from_parts(
                    Translation3::new(0.87 + 0.01 * i as f64, 2.18, 0.948),
                    UnitQuaternion::from_euler_angles(0.01 * i as f64, 0.2, -0.3),
                ),
                velocity_m_s: Vector3::new(0.2, 0.0, -0.001 * i as f64),
                gyro_bias_rad_s: Vector3::new(-0.00224703, 0.0215352, 0.0770299),
                accel_bias_m_s2: Vector3::new(-0.0180115, 0.0659796, 0.0309774),
            })
            .collect()
    }

    /// Writes a small stereo dataset; cam1 gets one 16-bit image.
    fn write_dataset(root: &Path) -> Vec<(i64, Image, Image)> {
        let mut w = EurocWriter::create(root).expect("create");
        w.write_camera("cam0", &calibration(367.215))
            .expect("cam0 yaml");
        w.write_camera("cam1", &calibration(379.999))
            .expect("cam1 yaml");
        let frames: Vec<_> = (0..6)
            .map(|i| {
                (
                    1_403_715_273_262_142_976 + i * 50_000_000,
                    image(i as u32, false),
                    image(i as u32 + 100, i == 3),
                )
            })
            .collect();
        for (t_ns, left, right) in &frames {
            w.add_image("cam0", *t_ns, left).expect("cam0 image");
            w.add_image("cam1", *t_ns, right).expect("cam1 image");
        }
        let imu = ImuCalibration {
            intrinsics: crate::rig::ImuIntrinsics::IDENTITY,
            T_body_imu: Isometry3::identity(),
            rate_hz: 200.0,
            noise: ImuNoise::EUROC_ADIS16448,
        };
        w.write_imu(&imu, &imu_samples()).expect("imu");
        w.write_groundtruth(&groundtruth()).expect("gt");
        w.finish().expect("finish");
        frames
    }

    #[test]
    fn written_dataset_reads_back_identically() {
        let dir = tempfile::tempdir().expect("temp dir");
        let frames = write_dataset(dir.path());
        for path in [dir.path().to_path_buf(), dir.path().join("mav0")] {
            let ds = EurocDataset::open(&path).expect("open");
            assert_eq!(ds.root, dir.path().join("mav0"));
            assert_eq!(ds.cameras.len(), 2);
            for (c, cx) in ds.cameras.iter().zip([367.215, 379.999]) {
                let want = calibration(cx);
                assert_eq!(c.calibration.model, want.model);
                assert_eq!(c.calibration.rate_hz, want.rate_hz);
                assert_eq!(
                    c.calibration.T_body_cam.translation,
                    want.T_body_cam.translation
                );
                assert!(
                    c.calibration
                        .T_body_cam
                        .rotation
                        .angle_to(&want.T_body_cam.rotation)
                        < 1e-15
                );
                let stamps: Vec<i64> = c.frames.iter().map(|f| f.t_ns).collect();
                let want_stamps: Vec<i64> = frames.iter().map(|f| f.0).collect();
                assert_eq!(stamps, want_stamps);
            }
            for (i, (t_ns, left, right)) in frames.iter().enumerate() {
                let l = ds.cameras[0].load(i).expect("load").expect("file present");
                let r = ds.cameras[1].load(i).expect("load").expect("file present");
                assert_eq!((l.t_ns, l.seq, l.camera_index), (*t_ns, i as u64, 0));
                assert_eq!(r.camera_index, 1);
                assert_eq!(l.image.data(), left.data());
                assert_eq!(l.image.format(), PixelFormat::Mono8);
                assert_eq!(r.image.data(), right.data());
            }
            assert_eq!(
                ds.cameras[1]
                    .load(3)
                    .expect("load")
                    .expect("present")
                    .image
                    .format(),
                PixelFormat::Mono16 {
                    significant_bits: 16
                }
            );
            let imu = ds.imu.as_ref().expect("imu");
            assert_eq!(imu.samples, imu_samples());
            assert_eq!(imu.dropped_nonfinite, 0);
            assert_eq!(imu.calibration.noise, ImuNoise::EUROC_ADIS16448);
            assert_eq!(imu.calibration.T_body_imu, Isometry3::identity());
            let gt = ds.groundtruth.as_ref().expect("ground truth");
            let want = groundtruth();
            assert_eq!(gt.len(), want.len());
            for (a, b) in gt.iter().zip(&want) {
                assert_eq!(a.t_ns, b.t_ns);
                assert_eq!(a.T_world_body.translation, b.T_world_body.translation);
                assert!(a.T_world_body.rotation.angle_to(&b.T_world_body.rotation) < 1e-15);
                assert_eq!(a.velocity_m_s, b.velocity_m_s);
            }
        }
    }

    #[test]
    fn missing_and_corrupt_images() {
        let dir = tempfile::tempdir().expect("temp dir");
        let frames = write_dataset(dir.path());
        let cam0 = dir.path().join("mav0/cam0");
        std::fs::remove_file(cam0.join(format!("data/{}.png", frames[1].0))).expect("rm");
        let png2 = cam0.join(format!("data/{}.png", frames[2].0));
        let bytes = std::fs::read(&png2).expect("read");
        std::fs::write(&png2, &bytes[..bytes.len() / 2]).expect("truncate");
        let ds = EurocDataset::open(dir.path()).expect("open");
        let cam = &ds.cameras[0];
        assert_eq!(cam.frames.len(), 6);
        assert_eq!(cam.missing_images(), 1);
        assert_eq!(cam.frames[1].path, None);
        assert!(cam.load(1).expect("absent is not an error").is_none());
        let err = cam.load(2).expect_err("truncated png");
        assert!(matches!(err, DatasetError::Image { .. }), "{err}");
        assert!(matches!(cam.load(6), Err(DatasetError::Layout { .. })));
    }

    #[test]
    fn broken_files_are_errors_naming_them() {
        let dir = tempfile::tempdir().expect("temp dir");
        let frames = write_dataset(dir.path());
        let mav0 = dir.path().join("mav0");
        let cases: Vec<(PathBuf, Vec<u8>, &str)> = vec![
            (
                mav0.join("cam0/data.csv"),
                format!("#t,f\n{},a.png\n{}\n", frames[0].0, frames[1].0).into_bytes(),
                "cam0/data.csv:3: expected 2 fields",
            ),
            (
                mav0.join("cam0/data.csv"),
                format!("{},b.png\n{},a.png\n", frames[1].0, frames[0].0).into_bytes(),
                "cam0/data.csv:2: timestamp",
            ),
            (
                mav0.join("cam0/data.csv"),
                b"abc,def.png\n".to_vec(),
                "cam0/data.csv:1: field 1",
            ),
            (
                mav0.join("cam1/sensor.yaml"),
                b"%YAML:1.0\nrate_hz: 20\n".to_vec(),
                "cam1/sensor.yaml: field `camera_model`: missing",
            ),
            (
                mav0.join("imu0/sensor.yaml"),
                b"".to_vec(),
                "imu0/sensor.yaml",
            ),
            (
                mav0.join("imu0/data.csv"),
                b"1,2,3\n".to_vec(),
                "imu0/data.csv:1: expected 7 fields",
            ),
            // Each CSV swapped for another's: refused at the header.
            (
                mav0.join("cam0/data.csv"),
                std::fs::read(mav0.join("imu0/data.csv")).expect("imu csv"),
                "cam0/data.csv:1: header has 7 columns, as in an IMU csv",
            ),
            (
                mav0.join("imu0/data.csv"),
                std::fs::read(mav0.join("cam1/data.csv")).expect("camera csv"),
                "imu0/data.csv:1: header has 2 columns, as in a camera's data.csv",
            ),
            (
                mav0.join("state_groundtruth_estimate0/data.csv"),
                std::fs::read(mav0.join("imu0/data.csv")).expect("imu csv"),
                "state_groundtruth_estimate0/data.csv:1: header has 7 columns",
            ),
            (
                mav0.join("state_groundtruth_estimate0/data.csv"),
                b"\xff\xd8\xff\xe0garbage".to_vec(),
                "state_groundtruth_estimate0/data.csv:1: not UTF-8",
            ),
        ];
        for (path, bytes, expected) in cases {
            let saved = std::fs::read(&path).expect("original");
            std::fs::write(&path, bytes).expect("corrupt");
            let err = EurocDataset::open(dir.path())
                .expect_err(expected)
                .to_string();
            assert!(err.contains(expected), "{expected}: {err}");
            std::fs::write(&path, saved).expect("restore");
        }
        std::fs::remove_file(mav0.join("cam1/sensor.yaml")).expect("rm");
        let err = EurocDataset::open(dir.path())
            .expect_err("no yaml")
            .to_string();
        assert!(err.contains("cam1/sensor.yaml"), "{err}");
        let err = EurocDataset::open(&dir.path().join("nowhere")).expect_err("absent");
        assert!(matches!(err, DatasetError::Layout { .. }), "{err}");
    }

    /// Truncations and flipped bytes in every file of a small dataset:
    /// opening and loading may fail, but must return errors, not panic.
    #[test]
    fn corrupted_files_never_panic() {
        use rand::{Rng, SeedableRng};
        let dir = tempfile::tempdir().expect("temp dir");
        write_dataset(dir.path());
        let mav0 = dir.path().join("mav0");
        let mut files = Vec::new();
        for sub in ["cam0", "cam1", "imu0", GROUNDTRUTH_DIR] {
            files.push(mav0.join(sub).join("data.csv"));
            files.push(mav0.join(sub).join("sensor.yaml"));
        }
        files.push(mav0.join("cam0/data/1403715273262142976.png"));
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let mut failures = 0;
        for file in &files {
            let original = std::fs::read(file).expect("original");
            for trial in 0..12 {
                let mut bytes = original.clone();
                if trial % 2 == 0 {
                    bytes.truncate(rng.gen_range(0..bytes.len()));
                } else {
                    for _ in 0..rng.gen_range(1..8) {
                        let i = rng.gen_range(0..bytes.len());
                        bytes[i] = rng.gen();
                    }
                }
                std::fs::write(file, &bytes).expect("corrupt");
                match EurocDataset::open(dir.path()) {
                    Ok(ds) => {
                        for cam in &ds.cameras {
                            for i in 0..cam.frames.len() {
                                failures += usize::from(cam.load(i).is_err());
                            }
                        }
                    }
                    Err(_) => failures += 1,
                }
            }
            std::fs::write(file, &original).expect("restore");
        }
        // Most corruptions must be caught (a flipped digit can still parse).
        assert!(failures > files.len() * 6, "{failures}");
        assert!(EurocDataset::open(dir.path()).is_ok());
    }
}
