//! Recording the raw streams and the poses to MCAP, on a thread of its
//! own: the sensor and SLAM threads hand records over a bounded channel
//! without waiting (a full channel drops the record and counts it), the
//! recorder writes `rigslam-<n>.mcap` files, starts a new one at
//! `rotate_mib`, deletes the oldest to stay within `budget_mib`, and
//! closes the current file properly when the daemon stops (its summary
//! and index written, so it opens in Foxglove and replays).

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::mpsc::{self, Receiver, SyncSender, TrySendError};
use std::sync::Arc;
use std::thread::JoinHandle;

use crate::recording::{ChannelId, McapRecorder, RecordedPose, RecordingError};
use crate::sensors::yei::device::host_monotonic_ns;
use crate::sensors::ImuSample;

use super::config::RecordingConfig;
use super::slam_stage::FrameItem;

/// Records in flight before new ones are dropped.
const CHANNEL_BOUND: usize = 4096;

enum Record {
    Imu(ImuSample, i64),
    Frame(FrameItem, i64),
    Pose(RecordedPose, i64),
}

/// The producers' end; cheap to clone.
#[derive(Clone)]
pub struct RecordSender {
    tx: SyncSender<Record>,
    dropped: Arc<AtomicU64>,
}

impl RecordSender {
    fn send(&self, record: Record) {
        if let Err(TrySendError::Full(_)) = self.tx.try_send(record) {
            self.dropped.fetch_add(1, Ordering::Relaxed);
        }
    }

    /// Hands an IMU sample to the recorder, stamped with the host's `CLOCK_MONOTONIC` now; dropped
    /// and counted if the channel is full.
    pub fn imu(&self, sample: &ImuSample) {
        self.send(Record::Imu(*sample, host_monotonic_ns()));
    }

    /// Hands a frame to the recorder, stamped with the host's `CLOCK_MONOTONIC` now; dropped and
    /// counted if the channel is full.
    pub fn frame(&self, frame: &FrameItem) {
        self.send(Record::Frame(frame.clone(), host_monotonic_ns()));
    }

    /// Hands a published pose to the recorder, stamped with the host's `CLOCK_MONOTONIC` now;
    /// dropped and counted if the channel is full.
    pub fn pose(&self, pose: RecordedPose) {
        self.send(Record::Pose(pose, host_monotonic_ns()));
    }

    /// Records dropped because the recorder was behind.
    pub fn dropped(&self) -> u64 {
        self.dropped.load(Ordering::Relaxed)
    }
}

/// The recorder's thread; it returns the files it closed.
pub type RecorderThread = JoinHandle<Result<Vec<PathBuf>, RecordingError>>;

/// Starts the recorder thread. It ends, closing its file, when every
/// [`RecordSender`] is dropped.
///
/// `attachments` (name, bytes) go into every file, so that each one
/// replays on its own (the rig's calibration).
pub fn spawn_recorder(
    config: RecordingConfig,
    attachments: crate::recording::Attachments,
) -> Result<(RecordSender, RecorderThread), RecordingError> {
    std::fs::create_dir_all(&config.dir).map_err(|source| RecordingError::Create {
        path: config.dir.clone(),
        source,
    })?;
    let (tx, rx) = mpsc::sync_channel(CHANNEL_BOUND);
    let handle = std::thread::Builder::new()
        .name("recorder".into())
        .spawn(move || record_loop(&config, &attachments, rx))
        .map_err(|source| RecordingError::Create {
            path: PathBuf::from("(recorder thread)"),
            source,
        })?;
    Ok((
        RecordSender {
            tx,
            dropped: Arc::new(AtomicU64::new(0)),
        },
        handle,
    ))
}

struct OpenFile {
    recorder: McapRecorder,
    imu: ChannelId,
    cam0: ChannelId,
    cam1: ChannelId,
    pose: ChannelId,
}

fn open_file(dir: &Path, attachments: &[(String, Vec<u8>)]) -> Result<OpenFile, RecordingError> {
    // Wall-clock-free name: the next free number, so files sort by age.
    let next = list_recordings(dir)
        .iter()
        .filter_map(|(p, _)| number_of(p))
        .max()
        .map_or(0, |n| n + 1);
    let path = dir.join(format!("rigslam-{next:06}.mcap"));
    let mut recorder = McapRecorder::create(&path)?;
    let imu = recorder.add_imu_channel("/imu0", &Default::default())?;
    let cam0 = recorder.add_image_channel("/cam0")?;
    let cam1 = recorder.add_image_channel("/cam1")?;
    let pose = recorder.add_pose_channel("/rigslam/pose")?;
    for (name, data) in attachments {
        recorder.attach(name, "application/x-yaml", data)?;
    }
    tracing::info!("recording to {}", path.display());
    Ok(OpenFile {
        recorder,
        imu,
        cam0,
        cam1,
        pose,
    })
}

fn number_of(path: &Path) -> Option<u64> {
    path.file_stem()?
        .to_str()?
        .strip_prefix("rigslam-")?
        .parse()
        .ok()
}

/// The recordings in `dir`, oldest first, with their sizes.
pub fn list_recordings(dir: &Path) -> Vec<(PathBuf, u64)> {
    let mut files: Vec<(PathBuf, u64)> = std::fs::read_dir(dir)
        .into_iter()
        .flatten()
        .flatten()
        .map(|e| e.path())
        .filter(|p| number_of(p).is_some() && p.extension().is_some_and(|x| x == "mcap"))
        .map(|p| {
            let size = std::fs::metadata(&p).map_or(0, |m| m.len());
            (p, size)
        })
        .collect();
    files.sort_by_key(|(p, _)| number_of(p));
    files
}

/// Deletes the oldest closed recordings until the total (with `reserve`
/// bytes for the file being written) fits `budget` bytes.
fn enforce_budget(dir: &Path, budget: u64, reserve: u64) {
    let files = list_recordings(dir);
    let mut total: u64 = files.iter().map(|(_, s)| s).sum::<u64>() + reserve;
    for (path, size) in files {
        if total <= budget {
            break;
        }
        match std::fs::remove_file(&path) {
            Ok(()) => {
                tracing::info!("recording budget: deleted {}", path.display());
                total = total.saturating_sub(size);
            }
            Err(e) => tracing::warn!("recording budget: cannot delete {}: {e}", path.display()),
        }
    }
}

fn record_loop(
    config: &RecordingConfig,
    attachments: &[(String, Vec<u8>)],
    rx: Receiver<Record>,
) -> Result<Vec<PathBuf>, RecordingError> {
    let rotate = config.rotate_mib.max(1) << 20;
    let budget = config.budget_mib << 20;
    enforce_budget(&config.dir, budget, rotate);
    let mut file = open_file(&config.dir, attachments)?;
    let mut closed = Vec::new();
    for record in rx {
        match record {
            Record::Imu(s, receipt) => file.recorder.write_imu(file.imu, &s, receipt)?,
            Record::Frame(f, receipt) => {
                file.recorder
                    .write_image(file.cam0, f.t_ns, &f.left.image, "cam0", receipt)?;
                if let Some(r) = &f.right {
                    file.recorder
                        .write_image(file.cam1, f.t_ns, &r.image, "cam1", receipt)?;
                }
            }
            Record::Pose(p, receipt) => file.recorder.write_pose(file.pose, &p, receipt)?,
        }
        if file.recorder.message_bytes() >= rotate {
            let next = open_file(&config.dir, attachments)?;
            let done = std::mem::replace(&mut file, next);
            closed.push(done.recorder.finish()?);
            enforce_budget(&config.dir, budget, rotate);
        }
    }
    closed.push(file.recorder.finish()?);
    Ok(closed)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sensors::Frame;

    fn frame(t_ns: i64) -> FrameItem {
        // 512x512 noise: ~350 KB of base64 JSON per image, as a camera's.
        let pixels: Vec<u8> = (0..512u32 * 512)
            .map(|i| (i.wrapping_mul(2_654_435_761) >> 24) as u8)
            .collect();
        let image = rigslam_drivers::Image::mono8(512, 512, pixels).expect("image");
        let f = |camera_index| Frame {
            t_ns,
            seq: 0,
            camera_index,
            image: image.clone(),
        };
        FrameItem {
            t_ns,
            left: f(0),
            right: Some(f(1)),
            arrival_ns: 0,
        }
    }

    #[test]
    fn files_rotate_stay_within_the_budget_and_close_complete() {
        let dir = tempfile::tempdir().expect("tempdir");
        let config = RecordingConfig {
            enabled: true,
            dir: dir.path().to_path_buf(),
            budget_mib: 3,
            rotate_mib: 1,
        };
        let (tx, handle) = spawn_recorder(config, vec![]).expect("recorder");
        for i in 0..12 {
            tx.frame(&frame(i * 50_000_000));
            tx.imu(&ImuSample {
                t_ns: i * 50_000_000,
                gyro_rad_s: [0.0; 3],
                accel_m_s2: [0.0, 0.0, 9.81],
            });
        }
        assert_eq!(tx.dropped(), 0);
        drop(tx);
        let written = handle.join().expect("recorder thread").expect("recording");
        // 12 frames of ~0.7 MB in 1 MiB files.
        assert!(written.len() >= 6, "{written:?}");
        let left = list_recordings(dir.path());
        let total: u64 = left.iter().map(|(_, s)| s).sum();
        // The budget counts a whole file ahead for the one being written;
        // a file ends at the first message past rotate_mib.
        assert!(total <= (3 + 1) << 20, "{total} bytes in {left:?}");
        assert!(left.len() < written.len(), "nothing was deleted: {left:?}");
        // The newest survive, each complete (its summary written).
        let newest: Vec<&PathBuf> = written.iter().rev().take(left.len()).collect();
        for (path, _) in &left {
            assert!(newest.contains(&path), "{path:?} is not among the newest");
            crate::recording::channel_counts(path).expect("a complete file");
        }
    }
}
