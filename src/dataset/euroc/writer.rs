//! Writes a EuRoC ASL dataset: what the simulator produces and what the
//! reader reads back.

use std::collections::BTreeMap;
use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

use super::imu_csv::write_euroc_imu_csv;
use super::sensor_yaml::{camera_yaml, groundtruth_yaml, imu_yaml};
use super::{camera_number, CAMERA_CSV_HEADER, GROUNDTRUTH_DIR, IMU_DIR};
use crate::dataset::error::DatasetError;
use crate::dataset::groundtruth::{write_euroc_groundtruth, GroundTruthState};
use crate::dataset::image_file::write_png;
use crate::rig::{CameraCalibration, ImuCalibration};
use crate::sensors::{Image, ImuSample};

/// One camera's open `data.csv`.
struct CameraStream {
    dir: PathBuf,
    csv_path: PathBuf,
    csv: BufWriter<File>,
    /// Rows written so far, to name the line of a refused stamp.
    rows: usize,
    last_t_ns: Option<i64>,
}

/// Writes `<root>/mav0/...`. Images are written as they are added; each
/// camera's `data.csv` stays open until [`EurocWriter::finish`].
pub struct EurocWriter {
    mav0: PathBuf,
    cameras: BTreeMap<String, CameraStream>,
}

impl EurocWriter {
    /// Creates `<root>/mav0/` (and `root` if needed). Files already there
    /// are overwritten as the writer reaches them.
    pub fn create(root: &Path) -> Result<Self, DatasetError> {
        let mav0 = root.join("mav0");
        std::fs::create_dir_all(&mav0).map_err(|e| DatasetError::io(&mav0, e))?;
        Ok(Self {
            mav0,
            cameras: BTreeMap::new(),
        })
    }

    /// The `mav0` folder being written.
    pub fn mav0(&self) -> &Path {
        &self.mav0
    }

    /// Writes `mav0/<name>/sensor.yaml`. `name` must be `camN`.
    pub fn write_camera(
        &mut self,
        name: &str,
        calib: &CameraCalibration,
    ) -> Result<(), DatasetError> {
        let path = self.camera_stream(name)?.dir.join("sensor.yaml");
        let yaml = camera_yaml(name, calib);
        std::fs::write(&path, yaml).map_err(|e| DatasetError::io(&path, e))
    }

    /// Writes `mav0/<name>/data/<t_ns>.png` and its `data.csv` row. Stamps
    /// must increase per camera.
    pub fn add_image(&mut self, name: &str, t_ns: i64, image: &Image) -> Result<(), DatasetError> {
        let stream = self.camera_stream(name)?;
        if let Some(last) = stream.last_t_ns {
            if t_ns <= last {
                return Err(DatasetError::malformed(
                    &stream.csv_path,
                    stream.rows + 2,
                    format!("timestamp {t_ns} ns does not increase (previous {last} ns)"),
                ));
            }
        }
        let file_name = format!("{t_ns}.png");
        let png_path = stream.dir.join("data").join(&file_name);
        write_png(&png_path, image)?;
        writeln!(stream.csv, "{t_ns},{file_name}")
            .map_err(|e| DatasetError::io(&stream.csv_path, e))?;
        stream.rows += 1;
        stream.last_t_ns = Some(t_ns);
        Ok(())
    }

    /// Writes `imu0/data.csv` and `imu0/sensor.yaml` (Kalibr noise names).
    pub fn write_imu(
        &mut self,
        calib: &ImuCalibration,
        samples: &[ImuSample],
    ) -> Result<(), DatasetError> {
        let dir = self.subdir(IMU_DIR)?;
        write_euroc_imu_csv(&dir.join("data.csv"), samples)?;
        let yaml = dir.join("sensor.yaml");
        std::fs::write(&yaml, imu_yaml(calib)).map_err(|e| DatasetError::io(&yaml, e))
    }

    /// Writes `state_groundtruth_estimate0/data.csv` and its `sensor.yaml`.
    pub fn write_groundtruth(&mut self, states: &[GroundTruthState]) -> Result<(), DatasetError> {
        let dir = self.subdir(GROUNDTRUTH_DIR)?;
        let csv = dir.join("data.csv");
        crate::dataset::text::check_increasing(
            &csv,
            states.iter().enumerate().map(|(i, s)| (i + 2, s.t_ns)),
        )?;
        write_euroc_groundtruth(&csv, states)?;
        let yaml = dir.join("sensor.yaml");
        std::fs::write(&yaml, groundtruth_yaml()).map_err(|e| DatasetError::io(&yaml, e))
    }

    /// Flushes every camera's `data.csv`.
    pub fn finish(self) -> Result<(), DatasetError> {
        for (_, mut stream) in self.cameras {
            stream
                .csv
                .flush()
                .map_err(|e| DatasetError::io(&stream.csv_path, e))?;
        }
        Ok(())
    }

    fn subdir(&self, name: &str) -> Result<PathBuf, DatasetError> {
        let dir = self.mav0.join(name);
        std::fs::create_dir_all(&dir).map_err(|e| DatasetError::io(&dir, e))?;
        Ok(dir)
    }

    /// The camera's stream, creating `<name>/data/` and `data.csv` the first time.
    fn camera_stream(&mut self, name: &str) -> Result<&mut CameraStream, DatasetError> {
        if !self.cameras.contains_key(name) {
            if camera_number(name).is_none() {
                return Err(DatasetError::layout(
                    &self.mav0,
                    format!("camera folder {name:?} must be named camN (cam0, cam1, ...)"),
                ));
            }
            let dir = self.subdir(name)?;
            let data = dir.join("data");
            std::fs::create_dir_all(&data).map_err(|e| DatasetError::io(&data, e))?;
            let csv_path = dir.join("data.csv");
            let file = File::create(&csv_path).map_err(|e| DatasetError::io(&csv_path, e))?;
            let mut csv = BufWriter::new(file);
            writeln!(csv, "{CAMERA_CSV_HEADER}").map_err(|e| DatasetError::io(&csv_path, e))?;
            self.cameras.insert(
                name.to_owned(),
                CameraStream {
                    dir,
                    csv_path,
                    csv,
                    rows: 0,
                    last_t_ns: None,
                },
            );
        }
        Ok(self.cameras.get_mut(name).expect("inserted above"))
    }
}
