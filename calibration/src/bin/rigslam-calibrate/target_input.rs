//! Where `camera-imu` gets the target's corners from: per-frame detection
//! files another program wrote, folders of images, or a recording
//! `rigslamd` made of the target (its frames and its IMU). Images are run
//! through our AprilGrid detector; the detections are written beside the
//! calibration (`detections/camN/<t_ns>.csv`) so they can be inspected or
//! reused with `--detections`.

use std::ops::ControlFlow;
use std::path::{Path, PathBuf};

use anyhow::{bail, Context};
use rigslam::dataset::SensorEvent;
use rigslam::recording::{for_each_sensor_event, ReplayItem, SensorTopics};
use rigslam::sensors::ImuSample;
use rigslam_calibration::aprilgrid::{detect_aprilgrid, write_detection_csv, AprilGridTarget};
use rigslam_calibration::aprilgrid_detections::{read_detection_dir, TargetDetection};

/// Each camera's detections (cam0 first) and, from a recording, its IMU.
pub struct Observations {
    pub cameras: Vec<(String, Vec<TargetDetection>)>,
    pub imu: Option<Vec<ImuSample>>,
}

/// Per-frame detection files: `dir/camN/<t_ns>.csv`.
pub fn from_detections(dir: &Path) -> anyhow::Result<Observations> {
    let mut cams = camera_folders(dir)?;
    cams.sort();
    let cameras = cams
        .into_iter()
        .map(|(name, path)| Ok((name, read_detection_dir(&path)?)))
        .collect::<anyhow::Result<Vec<_>>>()?;
    Ok(Observations { cameras, imu: None })
}

fn camera_folders(dir: &Path) -> anyhow::Result<Vec<(String, PathBuf)>> {
    let mut out: Vec<(String, PathBuf)> = std::fs::read_dir(dir)
        .with_context(|| format!("reading {}", dir.display()))?
        .filter_map(|e| e.ok())
        .filter(|e| e.path().is_dir())
        .map(|e| (e.file_name().to_string_lossy().into_owned(), e.path()))
        .filter(|(n, _)| n.starts_with("cam"))
        .collect();
    out.sort();
    if out.is_empty() {
        bail!("{}: no cam0/, cam1/ ... folders", dir.display());
    }
    Ok(out)
}

fn detect(
    image: &image::GrayImage,
    t_ns: i64,
    target: &AprilGridTarget,
    save: &Path,
) -> anyhow::Result<TargetDetection> {
    let found = detect_aprilgrid(image, target);
    let detection = found.target_detection(target, t_ns);
    if !found.tags.is_empty() {
        write_detection_csv(
            &save.join(format!("{t_ns}.csv")),
            &detection,
            target,
            &found.corner_ids(),
        )?;
    }
    Ok(detection)
}

/// Images in `dir/camN/` (or EuRoC's `dir/mav0/camN/data/`) named
/// `<t_ns>.png` (or .jpg), each searched for the target.
pub fn from_images(
    dir: &Path,
    target: &AprilGridTarget,
    save: &Path,
) -> anyhow::Result<Observations> {
    let root = if dir.join("mav0").is_dir() {
        dir.join("mav0")
    } else {
        dir.to_path_buf()
    };
    let mut cameras = Vec::new();
    for (name, path) in camera_folders(&root)? {
        let images = if path.join("data").is_dir() {
            path.join("data")
        } else {
            path
        };
        let mut files: Vec<PathBuf> = std::fs::read_dir(&images)
            .with_context(|| format!("reading {}", images.display()))?
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| {
                p.extension().and_then(|e| e.to_str()).is_some_and(|e| {
                    matches!(e.to_ascii_lowercase().as_str(), "png" | "jpg" | "jpeg")
                })
            })
            .collect();
        files.sort();
        if files.is_empty() {
            bail!("{}: no PNG or JPEG images", images.display());
        }
        let out = save.join(&name);
        std::fs::create_dir_all(&out).with_context(|| format!("creating {}", out.display()))?;
        let mut detections = Vec::new();
        for file in &files {
            let t_ns: i64 = file
                .file_stem()
                .and_then(|s| s.to_str())
                .and_then(|s| s.parse().ok())
                .with_context(|| {
                    format!(
                        "{}: name images by their stamp in ns (<t_ns>.png)",
                        file.display()
                    )
                })?;
            let image = image::open(file)
                .with_context(|| format!("reading {}", file.display()))?
                .to_luma8();
            detections.push(detect(&image, t_ns, target, &out)?);
        }
        detections.sort_by_key(|d| d.t_ns);
        cameras.push((name, detections));
    }
    Ok(Observations { cameras, imu: None })
}

fn grey(image: &rigslam::sensors::Image) -> image::GrayImage {
    image::GrayImage::from_fn(image.width(), image.height(), |x, y| {
        image::Luma([image.grey8_at(x, y).unwrap_or(0)])
    })
}

/// A recording `rigslamd` made: its left (cam0) and right (cam1) frames
/// searched for the target, and its IMU samples.
pub fn from_recording(
    path: &Path,
    target: &AprilGridTarget,
    save: &Path,
) -> anyhow::Result<Observations> {
    let mut cams: Vec<(String, Vec<TargetDetection>)> = Vec::new();
    let mut imu = Vec::new();
    let mut skipped = 0u64;
    let mut failure = None;
    for_each_sensor_event(
        path,
        SensorTopics {
            stereo: true,
            imu: true,
        },
        |item| {
            match item {
                ReplayItem::Event(SensorEvent::Imu(s)) => imu.push(s),
                ReplayItem::Event(SensorEvent::Frame { t_ns, left, right }) => {
                    for (i, frame) in std::iter::once(left).chain(right).enumerate() {
                        if cams.len() <= i {
                            cams.push((format!("cam{i}"), Vec::new()));
                        }
                        let out = save.join(&cams[i].0);
                        let result = std::fs::create_dir_all(&out)
                            .map_err(anyhow::Error::from)
                            .and_then(|()| detect(&grey(&frame.image), t_ns, target, &out));
                        match result {
                            Ok(d) => cams[i].1.push(d),
                            Err(e) => {
                                failure = Some(e);
                                return ControlFlow::Break(());
                            }
                        }
                    }
                }
                ReplayItem::Skipped(_) => skipped += 1,
            }
            ControlFlow::Continue(())
        },
    )
    .with_context(|| format!("reading {}", path.display()))?;
    if let Some(e) = failure {
        return Err(e);
    }
    if skipped > 0 {
        eprintln!(
            "{}: {skipped} unreadable message(s) left out",
            path.display()
        );
    }
    if cams.is_empty() {
        bail!(
            "{}: no camera frames (/cam0) in the recording",
            path.display()
        );
    }
    Ok(Observations {
        cameras: cams,
        imu: Some(imu),
    })
}
