//! KITTI odometry sequences: `image_0/` (or `image_l/`; `image_2/` for
//! the left colour camera) with `NNNNNN.png`, `calib.txt` with the
//! rectified 3x4 projection matrices, optional `poses.txt` (camera-to-world
//! 3x4 rows, one per frame) and `times.txt` (seconds, one per frame).
//! Without `times.txt`, frame i is at i/10 s: KITTI records at 10 Hz.
//! The body frame is the left camera, so `T_body_cam` is the identity.

use std::path::{Path, PathBuf};

use nalgebra::{Isometry3, Matrix3};

use super::error::DatasetError;
use super::euroc::reader::load_listed;
use super::euroc::sensor_yaml::rigid_from_parts;
use super::euroc::ImageEntry;
use super::image_file::png_dimensions;
use super::text::{check_increasing, data_lines, parse_fields, read_text};
use super::tum::seconds_to_ns;
use crate::camera::{CameraModel, PinholeRadtan};
use crate::rig::CameraCalibration;
use crate::sensors::Frame;
use crate::trajectory::{StampedPose, Trajectory};

/// KITTI's frame period without `times.txt`, ns.
pub const KITTI_FRAME_PERIOD_NS: i64 = 100_000_000;

/// KITTI's 3x4 poses print 7 significant digits: their rotations are
/// orthonormal to about 1e-6; allow some margin.
const POSE_ROTATION_TOLERANCE: f64 = 1e-4;

/// Image folders we read, with the projection matrix each one uses.
const IMAGE_DIRS: [(&str, &str); 3] = [("image_0", "P0"), ("image_l", "P0"), ("image_2", "P2")];

/// One mono KITTI odometry sequence.
#[derive(Debug, Clone)]
pub struct KittiSequence {
    /// The sequence folder (holding `image_0/`, `times.txt`, `calib.txt`).
    pub root: PathBuf,
    /// The folder images come from.
    pub image_dir: PathBuf,
    /// fx, fy, cx, cy from calib.txt, no distortion (images are rectified).
    pub camera: CameraCalibration,
    /// The images in file-name order, stamped from `times.txt` (or at 10 Hz without it).
    pub frames: Vec<ImageEntry>,
    /// `poses.txt`, stamped like the frames; pose of the left camera (= body).
    pub groundtruth: Option<Trajectory>,
}

impl KittiSequence {
    /// Opens the KITTI odometry sequence in `path`: the first image folder found (`image_0`,
    /// `image_l`, `image_2`) with its projection matrix from `calib.txt`, the stamps from
    /// `times.txt` (frame i at i/10 s without it) and `poses.txt` when present. Errors name the
    /// file that is missing or malformed.
    pub fn open(path: &Path) -> Result<Self, DatasetError> {
        let (image_dir, projection) = IMAGE_DIRS
            .iter()
            .map(|(dir, p)| (path.join(dir), *p))
            .find(|(dir, _)| dir.is_dir())
            .ok_or_else(|| {
                DatasetError::layout(
                    path,
                    "not a KITTI odometry sequence: no image_0/, image_l/ or image_2/ folder",
                )
            })?;
        let files = png_files(&image_dir)?;
        let Some(first) = files.first() else {
            return Err(DatasetError::layout(&image_dir, "holds no .png images"));
        };
        let (width, height) = png_dimensions(first)?;

        let times_path = path.join("times.txt");
        let stamps_ns = if times_path.is_file() {
            let stamps = read_times(&times_path)?;
            if stamps.len() != files.len() {
                return Err(DatasetError::layout(
                    &times_path,
                    format!(
                        "lists {} stamps for {} images in {}",
                        stamps.len(),
                        files.len(),
                        image_dir.display()
                    ),
                ));
            }
            stamps
        } else {
            (0..files.len() as i64)
                .map(|i| i * KITTI_FRAME_PERIOD_NS)
                .collect()
        };
        let rate_hz = match (stamps_ns.first(), stamps_ns.last()) {
            (Some(&a), Some(&b)) if b > a => {
                (stamps_ns.len() - 1) as f64 / ((b as f64 - a as f64) * 1e-9)
            }
            _ => 1e9 / KITTI_FRAME_PERIOD_NS as f64,
        };

        let calib_path = path.join("calib.txt");
        let p = read_projection(&calib_path, projection)?;
        let camera = CameraCalibration {
            time_shift_cam_imu_s: 0.0,
            model: CameraModel::PinholeRadtan(PinholeRadtan {
                width,
                height,
                fx: p[0],
                fy: p[5],
                cx: p[2],
                cy: p[6],
                distortion: [0.0; 5],
            }),
            T_body_cam: Isometry3::identity(),
            rate_hz,
        };

        let poses_path = path.join("poses.txt");
        let groundtruth = if poses_path.is_file() {
            Some(read_kitti_poses_stamped(&poses_path, &stamps_ns)?)
        } else {
            None
        };

        Ok(Self {
            root: path.to_path_buf(),
            image_dir,
            camera,
            frames: stamps_ns
                .into_iter()
                .zip(files)
                .map(|(t_ns, p)| ImageEntry {
                    t_ns,
                    path: Some(p.clone()),
                    listed_path: p,
                })
                .collect(),
            groundtruth,
        })
    }

    /// Decodes frame `index` (camera index 0). `Ok(None)` never happens
    /// for KITTI (every frame is a file) but keeps the EuRoC signature.
    pub fn load(&self, index: usize) -> Result<Option<Frame>, DatasetError> {
        load_listed(&self.frames, index, &self.image_dir, 0)
    }
}

/// Reads a KITTI `poses.txt`, stamped from `times.txt` beside it or, when
/// there is none, at i/10 s.
pub fn read_kitti_poses(path: &Path) -> Result<Trajectory, DatasetError> {
    let times = path.with_file_name("times.txt");
    if times.is_file() {
        read_kitti_poses_stamped(path, &read_times(&times)?)
    } else {
        let text = read_text(path)?;
        let n = data_lines(&text).count() as i64;
        let stamps: Vec<i64> = (0..n).map(|i| i * KITTI_FRAME_PERIOD_NS).collect();
        read_kitti_poses_stamped(path, &stamps)
    }
}

/// Reads a KITTI `poses.txt` giving pose i the stamp `stamps_ns[i]`.
#[allow(non_snake_case)]
pub fn read_kitti_poses_stamped(
    path: &Path,
    stamps_ns: &[i64],
) -> Result<Trajectory, DatasetError> {
    parse_kitti_poses_stamped(&read_text(path)?, path, stamps_ns)
}

/// Parses the text of a KITTI `poses.txt`; `path` names it in errors.
#[allow(non_snake_case)]
pub fn parse_kitti_poses_stamped(
    text: &str,
    path: &Path,
    stamps_ns: &[i64],
) -> Result<Trajectory, DatasetError> {
    let mut poses = Vec::new();
    for (line_no, line) in data_lines(text) {
        let m: [f64; 12] = parse_fields(path, line_no, line, ' ')?;
        let Some(&t_ns) = stamps_ns.get(poses.len()) else {
            return Err(DatasetError::malformed(
                path,
                line_no,
                format!("more poses than the {} stamps", stamps_ns.len()),
            ));
        };
        if !m.iter().all(|v| v.is_finite()) {
            return Err(DatasetError::malformed(path, line_no, "non-finite value"));
        }
        let r = Matrix3::new(m[0], m[1], m[2], m[4], m[5], m[6], m[8], m[9], m[10]);
        let T_world_cam = rigid_from_parts(&r, m[3], m[7], m[11], POSE_ROTATION_TOLERANCE)
            .map_err(|e| DatasetError::malformed(path, line_no, e))?;
        poses.push(StampedPose {
            t_ns,
            T_world_body: T_world_cam,
        });
    }
    Ok(Trajectory::new(poses))
}

/// `times.txt`: one stamp in seconds per line, increasing.
fn read_times(path: &Path) -> Result<Vec<i64>, DatasetError> {
    parse_times(&read_text(path)?, path)
}

/// Parses the text of a `times.txt`; `path` names it in errors.
pub fn parse_times(text: &str, path: &Path) -> Result<Vec<i64>, DatasetError> {
    let mut stamps = Vec::new();
    let mut lines = Vec::new();
    for (line_no, line) in data_lines(text) {
        let [_t_s]: [f64; 1] = parse_fields(path, line_no, line, ' ')?;
        stamps.push(seconds_to_ns(path, line_no, line)?);
        lines.push(line_no);
    }
    check_increasing(path, lines.into_iter().zip(stamps.iter().copied()))?;
    Ok(stamps)
}

/// The 3x4 projection matrix `name` (row-major) from `calib.txt`. Lines are
/// `P0: 12 numbers`; lines without a `NAME:` prefix are named P0, P1, ...
/// in order, as some copies of the files strip the names.
fn read_projection(path: &Path, name: &str) -> Result<[f64; 12], DatasetError> {
    parse_projection(&read_text(path)?, path, name)
}

/// The 3x4 projection matrix `name` from the text of a `calib.txt`;
/// `path` names it in errors.
pub fn parse_projection(text: &str, path: &Path, name: &str) -> Result<[f64; 12], DatasetError> {
    let mut bare = 0;
    for (line_no, line) in data_lines(text) {
        let (key, values) = match line.split_once(':') {
            Some((k, v)) => (k.trim().to_owned(), v),
            None => {
                bare += 1;
                (format!("P{}", bare - 1), line)
            }
        };
        if key != name {
            continue;
        }
        let p: [f64; 12] = parse_fields(path, line_no, values, ' ')?;
        let focal_ok = p[0].is_finite() && p[0] > 0.0 && p[5].is_finite() && p[5] > 0.0;
        if !focal_ok || !p[2].is_finite() || !p[6].is_finite() {
            return Err(DatasetError::malformed(
                path,
                line_no,
                format!("{name}: focal lengths must be positive and centre finite"),
            ));
        }
        return Ok(p);
    }
    Err(DatasetError::bad_field(path, name, "missing"))
}

/// `.png` files of a folder in name order (KITTI's zero-padded indices).
fn png_files(dir: &Path) -> Result<Vec<PathBuf>, DatasetError> {
    let mut files = Vec::new();
    for entry in std::fs::read_dir(dir).map_err(|e| DatasetError::io(dir, e))? {
        let path = entry.map_err(|e| DatasetError::io(dir, e))?.path();
        let is_png = path
            .extension()
            .is_some_and(|e| e.eq_ignore_ascii_case("png"));
        if is_png && path.is_file() {
            files.push(path);
        }
    }
    files.sort();
    Ok(files)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dataset::image_file::write_png;
    use crate::sensors::Image;

    const P0: &str = "7.070912000000e+02 0.000000000000e+00 6.018873000000e+02 0.000000000000e+00 0.000000000000e+00 7.070912000000e+02 1.831104000000e+02 0.000000000000e+00 0.000000000000e+00 0.000000000000e+00 1.000000000000e+00 0.000000000000e+00";

    fn sequence(dir: &Path, frames: usize) {
        std::fs::create_dir_all(dir.join("image_0")).expect("mkdir");
        for i in 0..frames {
            let img = Image::mono8(8, 4, vec![i as u8; 32]).expect("image");
            write_png(&dir.join(format!("image_0/{i:06}.png")), &img).expect("png");
        }
        std::fs::write(dir.join("calib.txt"), format!("P0: {P0}\nP1: {P0}\n")).expect("calib");
    }

    #[test]
    fn reads_named_calib_times_and_poses() {
        let dir = tempfile::tempdir().expect("temp dir");
        sequence(dir.path(), 3);
        std::fs::write(
            dir.path().join("times.txt"),
            "0.000000e+00\n1.036e-01\n2.07e-01\n",
        )
        .expect("times");
        std::fs::write(
            dir.path().join("poses.txt"),
            "1 0 0 0 0 1 0 0 0 0 1 0\n0 -1 0 1.5 1 0 0 2 0 0 1 -3\n",
        )
        .expect("poses");
        let seq = KittiSequence::open(dir.path()).expect("open");
        #[allow(irrefutable_let_patterns)] // more models are coming
        let CameraModel::PinholeRadtan(c) = &seq.camera.model
        else {
            panic!("expected a pinhole-radtan camera");
        };
        assert_eq!(
            [c.fx, c.fy, c.cx, c.cy],
            [707.0912, 707.0912, 601.8873, 183.1104]
        );
        assert_eq!((c.width, c.height), (8, 4));
        let stamps: Vec<i64> = seq.frames.iter().map(|f| f.t_ns).collect();
        assert_eq!(stamps, [0, 103_600_000, 207_000_000]);
        let gt = seq.groundtruth.as_ref().expect("poses");
        assert_eq!(gt.len(), 2);
        assert_eq!(gt.poses[1].t_ns, 103_600_000);
        // Row-major 3x4: a quarter turn about z and translation (1.5, 2, -3).
        let p = gt.poses[1].T_world_body * nalgebra::Point3::new(1.0, 0.0, 0.0);
        assert!((p.coords - nalgebra::Vector3::new(1.5, 3.0, -3.0)).norm() < 1e-15);
        let frame = seq.load(2).expect("load").expect("present");
        assert_eq!(frame.image.grey8_at(0, 0), Some(2));
        assert!(seq.load(3).is_err());
    }

    #[test]
    fn broken_sequences_are_errors() {
        let dir = tempfile::tempdir().expect("temp dir");
        sequence(dir.path(), 2);
        let root = dir.path();
        // Too many stamps.
        std::fs::write(root.join("times.txt"), "0\n0.1\n0.2\n").expect("w");
        let err = KittiSequence::open(root).expect_err("count").to_string();
        assert!(err.contains("lists 3 stamps for 2 images"), "{err}");
        std::fs::write(root.join("times.txt"), "0\n-0.1\n").expect("w");
        let err = KittiSequence::open(root).expect_err("order").to_string();
        assert!(err.contains("times.txt:2: timestamp"), "{err}");
        std::fs::remove_file(root.join("times.txt")).expect("rm");
        // A pose row cut short, a non-rotation, more poses than frames.
        for (poses, expected) in [
            (
                "1 0 0 0 0 1 0 0 0 0 1 0\n1 0 0 0 0 1",
                "poses.txt:2: expected 12 fields",
            ),
            ("2 0 0 0 0 1 0 0 0 0 1 0\n", "poses.txt:1: rotation part"),
            (
                "1 0 0 0 0 1 0 0 0 0 1 0\n1 0 0 0 0 1 0 0 0 0 1 0\n1 0 0 0 0 1 0 0 0 0 1 0\n",
                "poses.txt:3: more poses",
            ),
        ] {
            std::fs::write(root.join("poses.txt"), poses).expect("w");
            let err = KittiSequence::open(root).expect_err(expected).to_string();
            assert!(err.contains(expected), "{expected}: {err}");
        }
        std::fs::remove_file(root.join("poses.txt")).expect("rm");
        // calib.txt without P0, with a short P0, with a zero focal length.
        for (calib, expected) in [
            ("P1: 1 0 0 0 0 1 0 0 0 0 1 0\n", "field `P0`: missing"),
            ("P0: 1 0 0 0 0 1 0\n", "calib.txt:1: expected 12 fields"),
            ("P0: 0 0 0 0 0 1 0 0 0 0 1 0\n", "calib.txt:1: P0: focal"),
        ] {
            std::fs::write(root.join("calib.txt"), calib).expect("w");
            let err = KittiSequence::open(root).expect_err(expected).to_string();
            assert!(err.contains(expected), "{expected}: {err}");
        }
        // A truncated first image: its header cannot be read.
        std::fs::write(root.join("calib.txt"), format!("{P0}\n")).expect("w");
        std::fs::write(root.join("image_0/000000.png"), [0x89, b'P', b'N']).expect("w");
        let err = KittiSequence::open(root).expect_err("png");
        assert!(matches!(err, DatasetError::Image { .. }), "{err}");
    }
}
