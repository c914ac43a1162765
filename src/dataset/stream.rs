//! A recorded sequence as the sensors would have delivered it: IMU samples
//! and (stereo) frames merged into one time-ordered stream, images decoded
//! one at a time as the stream reaches them. `rigslam run` and the
//! daemon's replay source read datasets through this.

use crate::sensors::{Frame, ImuSample};

use super::detect::Dataset;
use super::error::DatasetError;
use super::euroc::{EurocCamera, ImageEntry};

/// One thing a rig delivers.
#[derive(Debug, Clone)]
pub enum SensorEvent {
    /// One IMU sample (stamp in the dataset's clock, ns).
    Imu(ImuSample),
    /// An exposure: the left image and, when stereo was asked for and the
    /// right image exists, the right one with the same stamp.
    Frame {
        /// Exposure stamp in the dataset's clock, ns.
        t_ns: i64,
        /// The cam0 (left) image, or the only one.
        left: Frame,
        /// The cam1 (right) image with the same stamp, when stereo was asked for and it exists.
        right: Option<Frame>,
    },
}

/// What the stream left out, for the run report.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
pub struct StreamCounts {
    /// Frames delivered so far.
    pub frames: u64,
    /// IMU samples delivered so far.
    pub imu_samples: u64,
    /// Listed left stamps whose image file is absent.
    pub frames_missing_image: u64,
    /// Stereo frames whose right image is absent (sent as left only).
    pub frames_missing_right: u64,
    /// IMU rows with NaN or infinite values, left out when the dataset
    /// was read (the whole file's, whatever part is streamed).
    pub imu_samples_nonfinite: u64,
}

impl StreamCounts {
    /// Whether any input was left out.
    pub fn any_skipped(&self) -> bool {
        self.frames_missing_image + self.frames_missing_right + self.imu_samples_nonfinite > 0
    }
}

/// Decodes listed image `index` of a camera.
type LoadFrame<'a> = Box<dyn Fn(usize) -> Result<Option<Frame>, DatasetError> + 'a>;

/// Merges a dataset's frames and IMU samples in time order. Before each
/// frame it delivers every IMU sample up to the frame's stamp and the first
/// one after it, so that the interval ending at the frame can be
/// integrated right away.
pub struct SensorStream<'a> {
    left: &'a [ImageEntry],
    load_left: LoadFrame<'a>,
    right: Option<&'a EurocCamera>,
    imu: &'a [ImuSample],
    next_frame: usize,
    next_imu: usize,
    /// Index into `right.frames` where the search for the next stamp starts.
    right_cursor: usize,
    /// Stop after this many frames.
    max_frames: usize,
    /// See [`StreamOptions::imu_lead_ns`] (never negative).
    imu_lead_ns: i64,
    counts: StreamCounts,
}

/// How to read a dataset.
#[derive(Debug, Clone, Copy)]
pub struct StreamOptions {
    /// Deliver cam1 with cam0 (EuRoC only).
    pub stereo: bool,
    /// Deliver the IMU samples.
    pub imu: bool,
    /// Skip frames before this stamp (and IMU samples before the first
    /// delivered frame's previous 2 s, as a live IMU would have run before the camera).
    pub start_ns: Option<i64>,
    /// Stop after this many frames (all when `None`).
    pub max_frames: Option<usize>,
    /// Deliver the IMU up to this long past each frame's stamp (and one
    /// sample more) before the frame, ns. A camera whose clock runs behind
    /// the IMU's (a positive `timeshift_cam_imu`) took its image at the
    /// stamp plus the shift on the IMU clock, and the estimator
    /// preintegrates up to that instant: the rig's
    /// [`crate::rig::RigModel::frame_shift_ns`] (0 or less: one sample
    /// past the stamp).
    pub imu_lead_ns: i64,
}

impl<'a> SensorStream<'a> {
    /// The stream of `dataset`; errors when it lacks what `options` ask for.
    pub fn new(dataset: &'a Dataset, options: StreamOptions) -> Result<Self, DatasetError> {
        let (left, load_left, right, imu): (
            &'a [ImageEntry],
            LoadFrame<'a>,
            Option<&'a EurocCamera>,
            &'a [ImuSample],
        ) = match dataset {
            Dataset::Euroc(d) => {
                let cam0 = d
                    .cameras
                    .first()
                    .ok_or_else(|| DatasetError::layout(&d.root, "has no camera folder (cam0/)"))?;
                let right = if options.stereo {
                    Some(d.cameras.get(1).ok_or_else(|| {
                        DatasetError::layout(
                            &d.root,
                            "has no cam1/: a stereo mode needs both cameras",
                        )
                    })?)
                } else {
                    None
                };
                let imu: &[ImuSample] = if options.imu {
                    &d.imu
                        .as_ref()
                        .ok_or_else(|| {
                            DatasetError::layout(
                                &d.root,
                                "has no imu0/: an inertial mode needs the IMU",
                            )
                        })?
                        .samples
                } else {
                    &[]
                };
                // Frames listed without their image are skipped (left) or
                // sent as left only (right), and counted; say so once, here.
                warn_missing(cam0, options.start_ns, "their frames are skipped");
                if let Some(cam1) = right {
                    warn_missing(
                        cam1,
                        options.start_ns,
                        "those frames go out as left images only",
                    );
                }
                (&cam0.frames, Box::new(move |i| cam0.load(i)), right, imu)
            }
            Dataset::Kitti(k) => {
                if options.stereo || options.imu {
                    return Err(DatasetError::layout(
                        &k.root,
                        "is a KITTI odometry sequence: mono images only (use --mode mono)",
                    ));
                }
                (&k.frames, Box::new(move |i| k.load(i)), None, &[])
            }
        };
        let imu_samples_nonfinite = match dataset {
            Dataset::Euroc(d) if options.imu => {
                d.imu.as_ref().map_or(0, |i| i.dropped_nonfinite as u64)
            }
            _ => 0,
        };
        let next_frame = options
            .start_ns
            .map_or(0, |t| left.partition_point(|e| e.t_ns < t));
        let first_frame_ns = left.get(next_frame).map_or(i64::MAX, |e| e.t_ns);
        // Saturating: a listing may start at any stamp, i64::MIN included.
        let imu_from_ns = first_frame_ns.saturating_sub(2_000_000_000);
        let next_imu = imu.partition_point(|s| s.t_ns < imu_from_ns);
        Ok(Self {
            left,
            load_left,
            right,
            imu,
            next_frame,
            next_imu,
            right_cursor: 0,
            max_frames: options.max_frames.unwrap_or(usize::MAX),
            imu_lead_ns: options.imu_lead_ns.max(0),
            counts: StreamCounts {
                imu_samples_nonfinite,
                ..StreamCounts::default()
            },
        })
    }

    /// Frames the stream will deliver at most (listed left stamps).
    pub fn frames_listed(&self) -> usize {
        (self.left.len() - self.next_frame.min(self.left.len())).min(self.max_frames)
    }

    /// What the stream delivered and left out so far.
    pub fn counts(&self) -> StreamCounts {
        self.counts
    }

    fn right_for(&mut self, t_ns: i64) -> Result<Option<Frame>, DatasetError> {
        let Some(cam) = self.right else {
            return Ok(None);
        };
        let start = self.right_cursor.min(cam.frames.len());
        let offset = cam.frames[start..].partition_point(|e| e.t_ns < t_ns);
        let index = start + offset;
        self.right_cursor = index;
        match cam.frames.get(index) {
            Some(e) if e.t_ns == t_ns => cam.load(index),
            _ => Ok(None),
        }
    }
}

/// Warns once that `camera`'s listing (from `start_ns` on) names image
/// files that are absent: how many, and the first; returns how many.
fn warn_missing(camera: &EurocCamera, start_ns: Option<i64>, consequence: &str) -> usize {
    let mut missing = camera
        .frames
        .iter()
        .filter(|e| e.path.is_none() && start_ns.map_or(true, |t| e.t_ns >= t));
    let Some(first) = missing.next() else {
        return 0;
    };
    let n = 1 + missing.count();
    tracing::warn!(
        "{}: {n} listed image{} missing, the first {} (t = {} ns); {consequence}",
        camera.csv_path.display(),
        if n == 1 { " is" } else { "s are" },
        first.listed_path.display(),
        first.t_ns
    );
    n
}

impl Iterator for SensorStream<'_> {
    type Item = Result<SensorEvent, DatasetError>;

    fn next(&mut self) -> Option<Self::Item> {
        loop {
            let frame_ns = if (self.counts.frames as usize) < self.max_frames {
                self.left.get(self.next_frame).map(|e| e.t_ns)
            } else {
                None
            };
            // IMU up to the frame (on the IMU clock) and one past it (or
            // the rest when the frames are exhausted and the run is not
            // capped).
            if let Some(sample) = self.imu.get(self.next_imu) {
                let previous_ns = self
                    .next_imu
                    .checked_sub(1)
                    .and_then(|i| self.imu.get(i))
                    .map(|s| s.t_ns);
                let wanted = match frame_ns.map(|f| f.saturating_add(self.imu_lead_ns)) {
                    Some(f) => sample.t_ns <= f || previous_ns.map_or(true, |p| p <= f),
                    None => false,
                };
                if wanted {
                    self.next_imu += 1;
                    self.counts.imu_samples += 1;
                    return Some(Ok(SensorEvent::Imu(*sample)));
                }
            }
            let t_ns = frame_ns?;
            let index = self.next_frame;
            self.next_frame += 1;
            let left = match (self.load_left)(index) {
                Ok(Some(frame)) => frame,
                Ok(None) => {
                    self.counts.frames_missing_image += 1;
                    continue;
                }
                Err(e) => return Some(Err(e)),
            };
            let right = match self.right_for(t_ns) {
                Ok(r) => r,
                Err(e) => return Some(Err(e)),
            };
            if self.right.is_some() && right.is_none() {
                self.counts.frames_missing_right += 1;
            }
            self.counts.frames += 1;
            return Some(Ok(SensorEvent::Frame { t_ns, left, right }));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::shared_data;

    #[test]
    fn euroc_stream_is_time_ordered_with_one_sample_past_each_frame() {
        let Some(root) = shared_data::path_or_skip("euroc/V1_01_micro") else {
            return;
        };
        let dataset = crate::dataset::open_dataset(&root).expect("open V1_01_micro");
        let stream = SensorStream::new(
            &dataset,
            StreamOptions {
                stereo: true,
                imu: true,
                start_ns: None,
                max_frames: Some(20),
                imu_lead_ns: 0,
            },
        )
        .expect("stream");
        let mut last_imu_ns = i64::MIN;
        let mut last_frame_ns = i64::MIN;
        let mut frames = 0;
        let mut stereo = 0;
        for event in stream {
            match event.expect("event") {
                SensorEvent::Imu(s) => {
                    assert!(s.t_ns > last_imu_ns);
                    last_imu_ns = s.t_ns;
                }
                SensorEvent::Frame { t_ns, right, .. } => {
                    assert!(t_ns > last_frame_ns);
                    // The sample after the frame has arrived already.
                    assert!(last_imu_ns > t_ns, "{last_imu_ns} <= {t_ns}");
                    assert!(last_imu_ns - t_ns <= 5_000_000 + 1_000);
                    last_frame_ns = t_ns;
                    frames += 1;
                    if let Some(r) = right {
                        assert_eq!(r.t_ns, t_ns);
                        assert_eq!(r.camera_index, 1);
                        stereo += 1;
                    }
                }
            }
        }
        assert_eq!(frames, 20);
        assert!(stereo >= 19, "{stereo}");
    }

    /// An in-memory EuRoC dataset: cameras listing (stamp, image file)
    /// with no file there, and IMU samples at the given stamps.
    fn dataset(cameras: &[&[(i64, &str)]], imu: &[i64]) -> Dataset {
        use crate::camera::{CameraModel, PinholeRadtan};
        use crate::dataset::euroc::{EurocDataset, EurocImu};
        use crate::rig::{CameraCalibration, ImuCalibration, ImuNoise};
        use nalgebra::Isometry3;

        let camera = |i: usize, listing: &[(i64, &str)]| EurocCamera {
            name: format!("cam{i}"),
            camera_index: i as u8,
            calibration: CameraCalibration {
                time_shift_cam_imu_s: 0.0,
                model: CameraModel::PinholeRadtan(
                    PinholeRadtan::new(8, 6, [10.0, 10.0, 4.0, 3.0], [0.0; 5]).expect("camera"),
                ),
                T_body_cam: Isometry3::identity(),
                rate_hz: 20.0,
            },
            frames: listing
                .iter()
                .map(|&(t_ns, file)| ImageEntry {
                    t_ns,
                    path: None,
                    listed_path: format!("mav0/cam{i}/data/{file}").into(),
                })
                .collect(),
            csv_path: format!("mav0/cam{i}/data.csv").into(),
        };
        Dataset::Euroc(EurocDataset {
            root: "mav0".into(),
            cameras: cameras
                .iter()
                .enumerate()
                .map(|(i, l)| camera(i, l))
                .collect(),
            imu: Some(EurocImu {
                calibration: ImuCalibration {
                    intrinsics: crate::rig::ImuIntrinsics::IDENTITY,
                    T_body_imu: Isometry3::identity(),
                    rate_hz: 200.0,
                    noise: ImuNoise {
                        gyroscope_noise_density: 1e-4,
                        gyroscope_random_walk: 1e-5,
                        accelerometer_noise_density: 1e-3,
                        accelerometer_random_walk: 1e-4,
                    },
                },
                samples: imu
                    .iter()
                    .map(|&t_ns| ImuSample {
                        t_ns,
                        gyro_rad_s: [0.0; 3],
                        accel_m_s2: [0.0, 0.0, 9.8],
                    })
                    .collect(),
                dropped_nonfinite: 0,
            }),
            groundtruth: None,
        })
    }

    /// Found by fuzzing: a listing starting at i64::MIN overflowed the
    /// stream's 2 s look-back for IMU samples (a panic with overflow
    /// checks; without, every sample was skipped).
    #[test]
    fn a_listing_may_start_at_any_stamp() {
        let dataset = dataset(&[&[(i64::MIN, "0.png")]], &[i64::MIN, 0]);
        let options = StreamOptions {
            stereo: false,
            imu: true,
            start_ns: None,
            max_frames: None,
            imu_lead_ns: 0,
        };
        let stream = SensorStream::new(&dataset, options).expect("stream");
        let imu = stream
            .filter(|e| matches!(e, Ok(SensorEvent::Imu(_))))
            .count();
        // The sample at the frame's stamp and the one after it.
        assert_eq!(imu, 2);
    }

    /// A camera behind the IMU clock: the samples up to the frame's
    /// stamp plus the lead, and one past it, come before the frame; with
    /// no lead, one past the stamp. The IMU stamps are not on the
    /// frame's (2.775 ms off).
    #[test]
    fn the_imu_reaches_past_a_late_cameras_instant() {
        let imu: Vec<i64> = (0..40).map(|k| 2_775_000 + 5_000_000 * k).collect();
        let delivered = |lead_ns: i64| -> Vec<i64> {
            let dataset = dataset(&[&[(100_000_000, "0.png")]], &imu);
            let options = StreamOptions {
                stereo: false,
                imu: true,
                start_ns: None,
                max_frames: None,
                imu_lead_ns: lead_ns,
            };
            SensorStream::new(&dataset, options)
                .expect("stream")
                .filter_map(|e| match e {
                    Ok(SensorEvent::Imu(s)) => Some(s.t_ns),
                    _ => None,
                })
                .collect()
        };
        let plain = delivered(0);
        assert_eq!(plain.last(), Some(&102_775_000));
        assert_eq!(plain.len(), 21);
        // 7 ms behind: up to 107 ms and one past, 107.775 ms.
        let late = delivered(7_000_000);
        assert_eq!(late.last(), Some(&107_775_000));
        assert_eq!(late.len(), 22);
        // A camera ahead of the IMU (negative shift) needs nothing more.
        assert_eq!(delivered(-7_000_000), plain);
    }

    /// Writes what a `tracing` subscriber prints into a shared buffer.
    #[derive(Clone, Default)]
    struct Captured(std::sync::Arc<std::sync::Mutex<Vec<u8>>>);

    impl std::io::Write for Captured {
        fn write(&mut self, bytes: &[u8]) -> std::io::Result<usize> {
            self.0.lock().expect("log buffer").extend_from_slice(bytes);
            Ok(bytes.len())
        }
        fn flush(&mut self) -> std::io::Result<()> {
            Ok(())
        }
    }

    /// A listed image whose file is missing used to be skipped without a
    /// word (only counted): now each camera says once how many, naming
    /// the first.
    #[test]
    fn missing_images_are_counted_and_named_once() {
        let dataset = dataset(
            &[
                &[(1000, "1000.png"), (2000, "2000.png"), (3000, "3000.png")],
                &[(2000, "2000.png")],
            ],
            &[],
        );
        let options = StreamOptions {
            stereo: true,
            imu: false,
            start_ns: Some(2000),
            max_frames: None,
            imu_lead_ns: 0,
        };
        let captured = Captured::default();
        let writer = captured.clone();
        let subscriber = tracing_subscriber::fmt()
            .with_writer(move || writer.clone())
            .with_ansi(false)
            .finish();
        let counts = tracing::subscriber::with_default(subscriber, || {
            let mut stream = SensorStream::new(&dataset, options).expect("stream");
            assert_eq!(stream.by_ref().count(), 0);
            stream.counts()
        });
        assert_eq!(counts.frames_missing_image, 2);
        let log = String::from_utf8(captured.0.lock().expect("log").clone()).expect("text");
        let lines: Vec<&str> = log.lines().collect();
        assert_eq!(lines.len(), 2, "{log}");
        assert!(
            lines[0].contains(
                "mav0/cam0/data.csv: 2 listed images are missing, the first \
                 mav0/cam0/data/2000.png (t = 2000 ns); their frames are skipped"
            ),
            "{log}"
        );
        assert!(
            lines[1].contains("mav0/cam1/data.csv: 1 listed image is missing"),
            "{log}"
        );
    }

    #[test]
    fn kitti_refuses_stereo_and_imu() {
        let Some(root) = shared_data::path_or_skip("kitti/seq_a") else {
            return;
        };
        let dataset = crate::dataset::open_dataset(&root).expect("open seq_a");
        let err = SensorStream::new(
            &dataset,
            StreamOptions {
                stereo: false,
                imu: true,
                start_ns: None,
                max_frames: None,
                imu_lead_ns: 0,
            },
        )
        .err()
        .expect("refused");
        assert!(err.to_string().contains("mono"), "{err}");
        let stream = SensorStream::new(
            &dataset,
            StreamOptions {
                stereo: false,
                imu: false,
                start_ns: None,
                max_frames: None,
                imu_lead_ns: 0,
            },
        )
        .expect("mono stream");
        assert_eq!(stream.count(), 51);
    }
}
