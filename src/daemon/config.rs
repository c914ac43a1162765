//! `rigslamd`'s configuration file (`/etc/rigslam/rig.toml`): where the
//! frames and IMU samples come from, the rig's calibration, the SLAM mode
//! and settings, publishing, recording and the pipeline's bounds.
//!
//! Every table refuses unknown keys, so a typo is an error instead of a
//! silently kept default. [`DaemonConfig::load`] parses; [`check`] then
//! validates the values and opens every calibration file the config
//! names, collecting every problem (file, key, why) instead of stopping
//! at the first: `rigslamd --check-config` prints them all.

use std::path::{Path, PathBuf};

use crate::absolute::settings::AbsoluteSettings;
use crate::publish::IpcConfig;
use crate::relative::{EstimatorKind, RelativeConfig, RigModel, SensorMode};
use crate::slam_config::SlamSettings;

/// The whole file.
#[derive(Debug, Clone, PartialEq, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DaemonConfig {
    /// `[camera]`: where frames come from.
    pub camera: CameraConfig,
    /// `[imu]`: where IMU samples come from.
    pub imu: ImuConfig,
    /// Needed for live sensors; a EuRoC replay reads the dataset's own
    /// `sensor.yaml` files when this table is absent.
    #[serde(default)]
    pub calibration: Option<CalibrationConfig>,
    /// Needed when the camera or the IMU is `replay`.
    #[serde(default)]
    pub replay: Option<ReplayConfig>,
    #[serde(default)]
    /// `[slam]`: sensor mode, estimator and the settings of both stages.
    pub slam: SlamConfig,
    #[serde(default)]
    /// `[publish]`: the iceoryx2 services the poses and status go out on.
    pub publish: IpcConfig,
    #[serde(default)]
    /// `[recording]`: raw streams and poses to MCAP files (off by default).
    pub recording: RecordingConfig,
    #[serde(default)]
    /// `[pipeline]`: queue bounds and the health rules.
    pub pipeline: PipelineConfig,
    #[serde(default)]
    /// `[map]`: the map on disk that outlives the process (off by default).
    pub map: MapConfig,
    #[serde(default)]
    /// `[viewer]`: the live view for Foxglove (off by default).
    pub viewer: ViewerConfig,
}

/// `[viewer]`: a Foxglove WebSocket server inside the daemon with the
/// recording's channels, live.
#[derive(Debug, Clone, PartialEq, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ViewerConfig {
    /// Serve at all [false].
    pub enabled: bool,
    /// Address and port to listen on ["127.0.0.1:8765"]: loopback, so
    /// that only this machine (or an SSH tunnel) sees the robot's cameras.
    pub listen: String,
}

impl Default for ViewerConfig {
    fn default() -> Self {
        Self {
            enabled: false,
            listen: "127.0.0.1:8765".to_owned(),
        }
    }
}

impl ViewerConfig {
    /// The address to listen on, or why `listen` is not one.
    pub fn address(&self) -> Result<std::net::SocketAddr, String> {
        self.listen.parse().map_err(|_| {
            format!(
                "{:?} is not an address and port, e.g. \"127.0.0.1:8765\"",
                self.listen
            )
        })
    }
}

/// `[map]`: where the absolute stage's map is kept between runs.
#[derive(Debug, Clone, PartialEq, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct MapConfig {
    /// The map file (e.g. `/var/lib/rigslam/map.txt`; a relative path is
    /// taken from the config file's folder). When it holds a map at start
    /// the robot localises in it; otherwise the absolute stage builds one
    /// and saves it here. Unset: no map on disk.
    pub path: Option<PathBuf>,
    /// Save the map being built this often, s of sensor time (it is also
    /// saved on SIGTERM and on reload).
    pub save_every_s: f64,
}

impl Default for MapConfig {
    fn default() -> Self {
        Self {
            path: None,
            save_every_s: 60.0,
        }
    }
}

/// `[camera]`: where frames come from.
#[derive(Debug, Clone, PartialEq, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraConfig {
    /// Driver that delivers the frames.
    pub source: CameraSource,
    /// v4l2: `/dev/videoN`, `N` or a udev symlink (`/dev/rigslam-camera`);
    /// aravis: the camera id ("Vendor-Model-Serial") or IP, absent for
    /// the first camera found. Unused for replay.
    #[serde(default)]
    pub device: Option<String>,
    /// Requested frame rate, Hz (the device's setting when absent).
    #[serde(default)]
    pub rate_hz: Option<f64>,
    /// Requested size, px (the device's setting when absent).
    #[serde(default)]
    pub width: Option<u32>,
    #[serde(default)]
    /// Requested height, px (the device's setting when absent).
    pub height: Option<u32>,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
/// Where the daemon's frames come from (`source` in `[camera]`).
pub enum CameraSource {
    /// A V4L2 camera (`/dev/videoN`), mmap streaming.
    V4l2,
    /// A GigE/USB3 Vision camera through libaravis (the `aravis` feature).
    Aravis,
    /// The frames of the `[replay]` dataset or recording.
    Replay,
    /// A moving test pattern on the host clock (no hardware): bring-up
    /// of the IMU side, and the fault tests. Nothing to track in it.
    Pattern,
}

/// `[imu]`: where IMU samples come from.
#[derive(Debug, Clone, PartialEq, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ImuConfig {
    /// Driver that delivers the samples.
    pub source: ImuSource,
    /// yei: the serial device (`/dev/rigslam-imu` from the udev rule).
    #[serde(default)]
    pub port: Option<String>,
    #[serde(default = "default_baud")]
    /// Serial baud rate of the YEI port \[115200\].
    pub baud: u32,
    /// Streaming rate asked of the YEI, Hz.
    #[serde(default = "default_imu_rate_hz")]
    pub rate_hz: f64,
}

fn default_baud() -> u32 {
    115_200
}

fn default_imu_rate_hz() -> f64 {
    200.0
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
/// Where the daemon's IMU samples come from (`source` in `[imu]`).
pub enum ImuSource {
    /// A YEI 3-Space sensor on a serial port (`port`, `baud`, `rate_hz`).
    Yei,
    /// The IMU samples of the `[replay]` dataset or recording.
    Replay,
}

/// `[calibration]`: the rig's calibration, either the folder
/// `rigslam-calibrate --out` writes (`folder = "..."`, see
/// [`crate::rig::folder`]) or the files one by one: Kalibr's
/// `camchain-imucam.yaml` and `imu.yaml`, or EuRoC `sensor.yaml` files
/// (`T_BS` maps the sensor into the body = IMU frame), and optionally the
/// IMU intrinsics `imu_intrinsics.yaml`.
#[derive(Debug, Clone, PartialEq, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CalibrationConfig {
    /// The calibration folder (instead of the files below).
    #[serde(default)]
    pub folder: Option<PathBuf>,
    /// cam0 (left) first, then cam1 (right) for the stereo modes; or one
    /// Kalibr camera chain holding both.
    #[serde(default)]
    pub cameras: Vec<PathBuf>,
    /// The IMU's noise: Kalibr `imu.yaml` or EuRoC `sensor.yaml`
    /// (inertial modes).
    #[serde(default)]
    pub imu: Option<PathBuf>,
    /// The IMU's scale, misalignment and offset (`rigslam-calibrate imu`);
    /// identity when absent.
    #[serde(default)]
    pub imu_intrinsics: Option<PathBuf>,
}

impl CalibrationConfig {
    /// The files this table names, under their canonical names.
    pub fn files(
        &self,
    ) -> Result<Vec<crate::rig::folder::CalibrationFile>, crate::dataset::DatasetError> {
        match &self.folder {
            Some(dir) => crate::rig::folder::read_folder(dir),
            None => crate::rig::folder::name_files(
                &self.cameras,
                self.imu.as_deref(),
                self.imu_intrinsics.as_deref(),
            ),
        }
    }

    /// Where missing files are looked for, for the messages.
    pub fn origin(&self) -> PathBuf {
        self.folder.clone().unwrap_or_else(|| {
            self.cameras
                .first()
                .and_then(|p| p.parent())
                .map(Path::to_path_buf)
                .unwrap_or_default()
        })
    }
}

/// `[replay]`: a recorded sequence fed through the live pipeline.
#[derive(Debug, Clone, PartialEq, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ReplayConfig {
    /// A EuRoC ASL folder (the one holding `mav0/`, or `mav0` itself), or
    /// an MCAP recording rigslamd made (`*.mcap`; the rig's calibration
    /// comes from its attachments unless `[calibration]` names files).
    pub dataset: PathBuf,
    #[serde(default)]
    /// How fast the replay goes (as recorded by default).
    pub pace: ReplayPace,
    /// Stop after this many frames (all when absent).
    #[serde(default)]
    pub max_frames: Option<usize>,
    /// Play the sequence this many times back to back (a long-run soak
    /// from a short recording); the stamps of each loop continue after
    /// the previous one.
    #[serde(default = "one")]
    pub loops: u32,
}

fn one() -> u32 {
    1
}

/// How fast a replay goes.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum ReplayPace {
    /// Samples handed over when their stamps are due, as live.
    #[default]
    Recorded,
    /// As fast as the SLAM stage takes them (the replay then waits for
    /// the stage instead of dropping: nothing is lost, poses repeat bit
    /// for bit).
    AsFastAsPossible,
}

/// `[slam]`: the mode, the estimator and each stage's table.
#[derive(Debug, Clone, PartialEq, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SlamConfig {
    /// `mono`, `mono-inertial`, `stereo`, `stereo-inertial`.
    pub mode: SensorMode,
    /// `window` (the paper's method) or `ekf` (the baseline).
    pub estimator: EstimatorKind,
    /// `[slam.relative]`: the keys of `[relative]` in `rigslam run --config`.
    pub relative: RelativeConfig,
    /// `[slam.absolute]`: the keys of `[absolute]` in `rigslam run
    /// --config`. The absolute stage runs after the relative one and
    /// `rigslam/pose` carries its corrected pose unless `enabled = false`:
    /// on by default here, where a robot runs for hours and revisits its
    /// places (`rigslam run` runs it with `--absolute`).
    #[serde(deserialize_with = "absolute_on_unless_disabled")]
    pub absolute: AbsoluteSettings,
}

/// `[slam.absolute]` with `enabled = true` when the table does not say.
fn absolute_on_unless_disabled<'de, D>(d: D) -> Result<AbsoluteSettings, D::Error>
where
    D: serde::Deserializer<'de>,
{
    use serde::Deserialize;
    let mut table = toml::Table::deserialize(d)?;
    table.entry("enabled").or_insert(toml::Value::Boolean(true));
    toml::Value::Table(table)
        .try_into()
        .map_err(serde::de::Error::custom)
}

/// The daemon's absolute stage settings when `[slam.absolute]` is absent.
fn absolute_on() -> AbsoluteSettings {
    AbsoluteSettings {
        enabled: true,
        ..AbsoluteSettings::default()
    }
}

impl SlamConfig {
    /// Both stages' tables, as `rigslam run --config` reads them.
    pub fn settings(&self) -> SlamSettings {
        SlamSettings {
            relative: self.relative.clone(),
            absolute: self.absolute.clone(),
        }
    }
}

impl Default for SlamConfig {
    fn default() -> Self {
        Self {
            mode: SensorMode::StereoInertial,
            estimator: EstimatorKind::Window,
            relative: RelativeConfig::default(),
            absolute: absolute_on(),
        }
    }
}

/// `[recording]`: raw sensor streams and poses to MCAP.
#[derive(Debug, Clone, PartialEq, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RecordingConfig {
    /// Record at all [false].
    pub enabled: bool,
    /// Where the `rigslam-<t>.mcap` files go.
    pub dir: PathBuf,
    /// Total size the recordings may take; the oldest files are deleted
    /// to stay under it, MiB.
    pub budget_mib: u64,
    /// A file is closed and a new one started at this size, MiB.
    pub rotate_mib: u64,
    /// How chunks are compressed: `"zstd"` (smallest files), `"lz4"`
    /// (less CPU) or `"none"` [zstd].
    pub compression: crate::recording::Compression,
    /// zstd's level, 1 (fastest) to 19 \[1\]; lz4's acceleration.
    pub compression_level: u32,
    /// Which messages the files hold: `"foxglove"` (protobuf, every
    /// stream; Foxglove, the MCAP tools) or `"ros2"` (ROS 2 messages in
    /// CDR for `ros2 bag play`; see [`crate::recording::ros2`])
    /// \[foxglove\]. `rigslamd --replay` plays both.
    #[serde(deserialize_with = "recording_format")]
    pub format: crate::recording::Format,
}

/// `recording.format`, refused with the key's name and the choices.
fn recording_format<'de, D: serde::Deserializer<'de>>(
    d: D,
) -> Result<crate::recording::Format, D::Error> {
    let name = <String as serde::Deserialize>::deserialize(d)?;
    name.parse()
        .map_err(|why| serde::de::Error::custom(format!("recording.format: {why}")))
}

impl Default for RecordingConfig {
    fn default() -> Self {
        Self {
            enabled: false,
            dir: PathBuf::from("/var/lib/rigslam/recordings"),
            budget_mib: 4096,
            rotate_mib: 256,
            compression: crate::recording::Compression::Zstd,
            compression_level: crate::recording::writer::DEFAULT_ZSTD_LEVEL,
            format: crate::recording::Format::Foxglove,
        }
    }
}

/// `[pipeline]`: queue bounds and the health rules.
#[derive(Debug, Clone, PartialEq, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PipelineConfig {
    /// Frames waiting for the SLAM stage; when full the oldest is dropped.
    pub frame_queue: usize,
    /// IMU samples waiting for the SLAM stage; when full the oldest is dropped.
    pub imu_queue: usize,
    /// A stage that has work and makes no progress for this long is stuck:
    /// status says so, the log says so, the systemd watchdog is no longer
    /// pinged (so systemd restarts the daemon), s.
    pub stuck_after_s: f64,
    /// Period of `rigslam/status` (and of systemd's STATUS= line), s.
    pub status_period_s: f64,
    /// No frame for this long: the camera counts as stalled, s.
    pub camera_stall_s: f64,
    /// No IMU sample for this long: the IMU counts as gone, s.
    pub imu_stall_s: f64,
}

impl Default for PipelineConfig {
    fn default() -> Self {
        Self {
            frame_queue: 4,
            imu_queue: 4096,
            stuck_after_s: 5.0,
            status_period_s: 1.0,
            camera_stall_s: 0.5,
            imu_stall_s: 0.1,
        }
    }
}

/// Why the config cannot be used. `Problems` lists every one found.
#[derive(Debug, thiserror::Error)]
pub enum DaemonConfigError {
    #[error("cannot read {path}: {source}")]
    /// The config file cannot be read.
    Read {
        /// The file.
        path: PathBuf,
        /// The I/O error.
        source: std::io::Error,
    },
    #[error("{path}: {message}")]
    /// The file is not valid TOML, or does not match the tables and keys this struct expects.
    Parse {
        /// The file.
        path: PathBuf,
        /// The parser's message, with the position in the file.
        message: String,
    },
    #[error("{}", .0.iter().map(|p| p.to_string()).collect::<Vec<_>>().join("\n"))]
    /// The file parsed, but settings are missing, out of range or inconsistent (every problem
    /// found, one per line in the message).
    Problems(Vec<Problem>),
}

/// One thing wrong: the file, the key (dotted, `camera.device`) and why.
#[derive(Debug, Clone, PartialEq)]
pub struct Problem {
    /// The config file the problem is in.
    pub file: PathBuf,
    /// The dotted key, e.g. `camera.device`.
    pub key: String,
    /// Why the value cannot be used.
    pub why: String,
}

impl std::fmt::Display for Problem {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}: {}: {}", self.file.display(), self.key, self.why)
    }
}

impl DaemonConfig {
    /// Parses the file (syntax, types, unknown keys); relative paths in it
    /// are taken relative to the file's folder.
    pub fn load(path: &Path) -> Result<DaemonConfig, DaemonConfigError> {
        let text = std::fs::read_to_string(path).map_err(|source| DaemonConfigError::Read {
            path: path.to_path_buf(),
            source,
        })?;
        let mut config = Self::parse(&text).map_err(|message| DaemonConfigError::Parse {
            path: path.to_path_buf(),
            message,
        })?;
        let base = path.parent().unwrap_or(Path::new("."));
        config.resolve_paths(base);
        Ok(config)
    }

    /// Parses TOML text; the error carries toml's line, column and key.
    pub fn parse(text: &str) -> Result<DaemonConfig, String> {
        toml::from_str(text).map_err(|e| e.to_string())
    }

    /// The config `rigslamd --replay DATASET [--mode M]` stands for.
    pub fn replay(dataset: &Path, mode: SensorMode) -> DaemonConfig {
        DaemonConfig {
            camera: CameraConfig {
                source: CameraSource::Replay,
                device: None,
                rate_hz: None,
                width: None,
                height: None,
            },
            imu: ImuConfig {
                source: ImuSource::Replay,
                port: None,
                baud: default_baud(),
                rate_hz: default_imu_rate_hz(),
            },
            calibration: None,
            replay: Some(ReplayConfig {
                dataset: dataset.to_path_buf(),
                pace: ReplayPace::Recorded,
                max_frames: None,
                loops: 1,
            }),
            slam: SlamConfig {
                mode,
                ..SlamConfig::default()
            },
            publish: IpcConfig::default(),
            recording: RecordingConfig::default(),
            viewer: ViewerConfig::default(),
            pipeline: PipelineConfig::default(),
            map: MapConfig::default(),
        }
    }

    fn resolve_paths(&mut self, base: &Path) {
        let fix = |p: &mut PathBuf| {
            if p.is_relative() {
                *p = base.join(&*p);
            }
        };
        if let Some(c) = self.calibration.as_mut() {
            c.cameras.iter_mut().for_each(fix);
            for p in [&mut c.imu, &mut c.imu_intrinsics, &mut c.folder]
                .into_iter()
                .flatten()
            {
                fix(p);
            }
        }
        if let Some(r) = self.replay.as_mut() {
            fix(&mut r.dataset);
        }
        fix(&mut self.recording.dir);
        if let Some(p) = self.map.path.as_mut() {
            fix(p);
        }
    }

    /// The bytes of the rig's calibration files as a recording carries
    /// them (see [`crate::recording::calibration_attachment_name`]): the
    /// files `[calibration]` names, else a EuRoC replay's own
    /// `sensor.yaml` files, else a replayed recording's attachments;
    /// `None` when there are no such files (a KITTI replay).
    pub fn calibration_files(&self) -> Result<Option<crate::recording::Attachments>, String> {
        let mode = self.slam.mode;
        let cameras = if mode.uses_stereo() { 2 } else { 1 };
        let read = |path: &Path| {
            std::fs::read(path).map_err(|e| format!("cannot read {}: {e}", path.display()))
        };
        let name = crate::recording::calibration_attachment_name;
        if let Some(c) = &self.calibration {
            let files = c.files().map_err(|e| e.to_string())?;
            return Ok(Some(
                files
                    .into_iter()
                    .filter(|f| !f.name.starts_with("cam1") || cameras > 1)
                    .map(|f| (name(&f.name), f.bytes))
                    .collect(),
            ));
        }
        let Some(replay) = self.replay.as_ref().filter(|_| self.replays()) else {
            return Ok(None);
        };
        if crate::recording::is_mcap(&replay.dataset) {
            let attachments =
                crate::recording::read_attachments(&replay.dataset).map_err(|e| e.to_string())?;
            let prefix = name("");
            let out: Vec<_> = attachments
                .into_iter()
                .filter(|(n, _)| n.starts_with(&prefix))
                .collect();
            return Ok((!out.is_empty()).then_some(out));
        }
        match crate::dataset::open_dataset(&replay.dataset).map_err(|e| e.to_string())? {
            crate::dataset::Dataset::Euroc(d) => {
                let mut out = Vec::new();
                for (i, camera) in d.cameras.iter().take(cameras).enumerate() {
                    let yaml = camera.csv_path.with_file_name("sensor.yaml");
                    out.push((name(&format!("cam{i}.yaml")), read(&yaml)?));
                }
                if mode.uses_imu() {
                    out.push((name("imu0.yaml"), read(&d.root.join("imu0/sensor.yaml"))?));
                }
                Ok(Some(out))
            }
            crate::dataset::Dataset::Kitti(_) => Ok(None),
        }
    }

    /// Whether either sensor replays a recording.
    pub fn replays(&self) -> bool {
        self.camera.source == CameraSource::Replay || self.imu.source == ImuSource::Replay
    }
}

/// Validates every value and reads the calibration the config names;
/// returns the rig on success, every problem found otherwise. `file` is
/// the config's path, for the messages.
pub fn check(config: &DaemonConfig, file: &Path) -> Result<RigModel, Vec<Problem>> {
    let mut problems: Vec<Problem> = Vec::new();
    // Several checks read the same file; its problem is said once.
    let mut bad = |key: &str, why: String| {
        if !problems.iter().any(|p| p.key == key && p.why == why) {
            problems.push(Problem {
                file: file.to_path_buf(),
                key: key.to_string(),
                why,
            })
        }
    };
    let mode = config.slam.mode;
    if config.camera.source == CameraSource::V4l2 && config.camera.device.is_none() {
        bad(
            "camera.device",
            "missing: source = \"v4l2\" needs the device (/dev/videoN or a udev symlink)".into(),
        );
    }
    match config.camera.source {
        CameraSource::V4l2 | CameraSource::Aravis | CameraSource::Pattern if mode.uses_stereo() => bad(
            "slam.mode",
            format!(
                "{mode} needs a stereo pair; a live {} camera delivers one image per frame here (use mono or mono-inertial)",
                match config.camera.source {
                    CameraSource::V4l2 => "v4l2",
                    CameraSource::Aravis => "aravis",
                    _ => "pattern",
                }
            ),
        ),
        _ => {}
    }
    if let Some(rate) = config.camera.rate_hz {
        if !(rate.is_finite() && rate > 0.0 && rate <= 1000.0) {
            bad(
                "camera.rate_hz",
                format!("{rate} is out of range: 0 to 1000 Hz"),
            );
        }
    }
    if config.imu.source == ImuSource::Yei {
        if config.imu.port.is_none() {
            bad(
                "imu.port",
                "missing: source = \"yei\" needs the serial device (e.g. /dev/rigslam-imu)".into(),
            );
        }
        if !(config.imu.rate_hz.is_finite() && (1.0..=1000.0).contains(&config.imu.rate_hz)) {
            bad(
                "imu.rate_hz",
                format!("{} is out of range: 1 to 1000 Hz", config.imu.rate_hz),
            );
        }
    }
    if config.imu.source == ImuSource::Replay && config.camera.source != CameraSource::Replay
        || config.camera.source == CameraSource::Replay && config.imu.source != ImuSource::Replay
    {
        bad(
            "imu.source",
            "camera and IMU must both replay or both be live (a replay has its own clock)".into(),
        );
    }
    if let Err(e) = config.slam.relative.validate() {
        bad("slam.relative", e.to_string());
    }
    if let Err(e) = config
        .slam
        .absolute
        .to_config()
        .and(config.slam.absolute.to_localise_config())
    {
        bad("slam", crate::relative::ConfigError::from(e).to_string());
    }
    if !(config.map.save_every_s.is_finite() && config.map.save_every_s > 0.0) {
        bad(
            "map.save_every_s",
            format!("{} (a time > 0 s)", config.map.save_every_s),
        );
    }
    if let Some(path) = &config.map.path {
        let dir = path.parent().filter(|d| !d.as_os_str().is_empty());
        if path.file_name().is_none() || path.is_dir() {
            bad("map.path", format!("{}: not a file name", path.display()));
        } else if let Some(dir) = dir.filter(|d| !d.is_dir()) {
            bad(
                "map.path",
                format!(
                    "{}: the folder {} does not exist",
                    path.display(),
                    dir.display()
                ),
            );
        }
    }
    let p = &config.pipeline;
    for (key, value, ok, allowed) in [
        (
            "pipeline.frame_queue",
            p.frame_queue as f64,
            (1..=256).contains(&p.frame_queue),
            "1 to 256",
        ),
        (
            "pipeline.imu_queue",
            p.imu_queue as f64,
            (16..=1 << 20).contains(&p.imu_queue),
            "16 to 1048576",
        ),
        (
            "pipeline.stuck_after_s",
            p.stuck_after_s,
            p.stuck_after_s.is_finite() && p.stuck_after_s >= 0.5,
            "at least 0.5 s",
        ),
        (
            "pipeline.status_period_s",
            p.status_period_s,
            p.status_period_s.is_finite() && (0.05..=60.0).contains(&p.status_period_s),
            "0.05 to 60 s",
        ),
        (
            "pipeline.camera_stall_s",
            p.camera_stall_s,
            p.camera_stall_s.is_finite() && p.camera_stall_s > 0.0,
            "a positive number of s",
        ),
        (
            "pipeline.imu_stall_s",
            p.imu_stall_s,
            p.imu_stall_s.is_finite() && p.imu_stall_s > 0.0,
            "a positive number of s",
        ),
    ] {
        if !ok {
            bad(key, format!("{value} is out of range: {allowed}"));
        }
    }
    let r = &config.recording;
    if r.enabled {
        if r.rotate_mib == 0 || r.budget_mib < r.rotate_mib {
            bad(
                "recording.rotate_mib",
                format!(
                    "{} MiB: must be at least 1 and at most recording.budget_mib ({} MiB)",
                    r.rotate_mib, r.budget_mib
                ),
            );
        }
        if r.compression == crate::recording::Compression::Zstd
            && !(1..=19).contains(&r.compression_level)
        {
            bad(
                "recording.compression_level",
                format!(
                    "{}: zstd's levels go from 1 (fastest) to 19 (smallest)",
                    r.compression_level
                ),
            );
        }
        if r.dir.exists() && !r.dir.is_dir() {
            bad(
                "recording.dir",
                format!("{} is not a folder", r.dir.display()),
            );
        }
    }
    if config.viewer.enabled {
        if let Err(why) = config.viewer.address() {
            bad("viewer.listen", why);
        }
    }
    if let Some(root) = &config.publish.root_path {
        if !root.is_absolute() {
            bad(
                "publish.root_path",
                format!("{} must be an absolute path", root.display()),
            );
        }
    }
    if config.publish.group.is_some() {
        // The group must exist and hold the daemon's user (a typo would
        // otherwise lock every reader out); the message names the fix.
        if let Err(crate::publish::IpcError::Group { reason, .. }) =
            crate::publish::publishing_group(&config.publish)
        {
            bad(
                "publish.group",
                format!(
                    "{:?}: {reason}",
                    config.publish.group.as_deref().unwrap_or("")
                ),
            );
        }
    }
    if config.publish.service_prefix.is_empty() || config.publish.service_prefix.ends_with('/') {
        bad(
            "publish.service_prefix",
            format!(
                "{:?}: must be non-empty and not end in '/'",
                config.publish.service_prefix
            ),
        );
    }

    if config.replay.as_ref().is_some_and(|r| r.loops == 0) {
        bad("replay.loops", "0: must be at least 1".into());
    }
    let replays_mcap = config.replays()
        && config
            .replay
            .as_ref()
            .is_some_and(|r| crate::recording::is_mcap(&r.dataset));
    let rig = match (&config.calibration, &config.replay) {
        (Some(c), _) => rig_from_files(c, mode, &mut bad),
        (None, Some(replay)) if replays_mcap => {
            match crate::recording::rig_of_recording(&replay.dataset) {
                Ok(Some(rig)) => Some(rig),
                Ok(None) => {
                    bad(
                        "calibration",
                        format!(
                            "missing: {} carries no calibration; name the rig's files in [calibration] cameras = [...], imu = ...",
                            replay.dataset.display()
                        ),
                    );
                    None
                }
                Err(e) => {
                    bad("replay.dataset", e.to_string());
                    None
                }
            }
        }
        (None, Some(replay)) if config.replays() => {
            match crate::dataset::open_dataset(&replay.dataset) {
                Ok(dataset) => Some(crate::run::dataset_run::rig_of(&dataset)),
                Err(e) => {
                    bad("replay.dataset", e.to_string());
                    None
                }
            }
        }
        _ => {
            bad(
                "calibration",
                "missing: live sensors need [calibration] cameras = [...] (and imu = ... for the inertial modes)".into(),
            );
            None
        }
    };
    if config.replays() && config.replay.is_none() {
        bad(
            "replay",
            "missing: a replay source needs [replay] dataset = \"...\"".into(),
        );
    } else if let (Some(replay), true) = (&config.replay, replays_mcap) {
        check_recording(&replay.dataset, mode, &mut bad);
    } else if let (Some(replay), true, Some(_)) =
        (&config.replay, config.replays(), &config.calibration)
    {
        if let Err(e) = crate::dataset::open_dataset(&replay.dataset) {
            bad("replay.dataset", e.to_string());
        }
    }
    if let Some(rig) = &rig {
        if let Err(e) = rig.check(mode) {
            bad("slam.mode", e.to_string());
        }
        check_resolution(config, rig, &mut bad);
    }
    match (rig, problems.is_empty()) {
        (Some(rig), true) => Ok(rig),
        _ => Err(problems),
    }
}

/// A calibration made for another camera or another resolution: the size
/// the live camera is asked for, or a replayed EuRoC folder's images,
/// against camera 0's calibrated resolution.
fn check_resolution(config: &DaemonConfig, rig: &RigModel, bad: &mut impl FnMut(&str, String)) {
    let Some(cam0) = rig.cameras.first() else {
        return;
    };
    let calibrated = (cam0.model.width(), cam0.model.height());
    let from = if config.calibration.is_some() {
        "the [calibration] files"
    } else {
        "the replayed recording's calibration"
    };
    if let (Some(w), Some(h)) = (config.camera.width, config.camera.height) {
        if config.camera.source != CameraSource::Replay && (w, h) != calibrated {
            bad(
                "camera.width",
                format!(
                    "{w}x{h} asked for, but {from} describe a {}x{} camera: calibrate at the resolution the robot runs, or ask for that one",
                    calibrated.0, calibrated.1
                ),
            );
        }
    }
    let Some(replay) = config.replay.as_ref().filter(|_| config.replays()) else {
        return;
    };
    if crate::recording::is_mcap(&replay.dataset) {
        return;
    }
    if let Ok(crate::dataset::Dataset::Euroc(d)) = crate::dataset::open_dataset(&replay.dataset) {
        let first = d
            .cameras
            .first()
            .and_then(|c| c.frames.iter().find_map(|f| f.path.clone()));
        if let Some(Ok(size)) = first.map(|p| crate::dataset::image_file::png_dimensions(&p)) {
            if size != calibrated {
                bad(
                    "calibration",
                    format!(
                        "{} has {}x{} images but {from} describe a {}x{} camera: a calibration from another camera",
                        replay.dataset.display(),
                        size.0,
                        size.1,
                        calibrated.0,
                        calibrated.1
                    ),
                );
            }
        }
    }
}

/// An MCAP recording to replay, holding the streams `mode` needs: counted
/// from its summary, or, for a file that was never closed, from what it
/// holds (the replay plays that and says where the file ends).
fn check_recording(path: &Path, mode: SensorMode, bad: &mut impl FnMut(&str, String)) {
    let counts = match crate::recording::channel_counts(path) {
        Ok(c) => c,
        Err(_) => match crate::recording::message_counts(path) {
            Ok((counts, _)) => counts,
            Err(e) => return bad("replay.dataset", e.to_string()),
        },
    };
    // Each stream under either of its names (rigslam's, ROS 2's).
    let [cam0, cam1] = crate::recording::CAMERA_TOPICS;
    let mut needed = vec![cam0.to_vec()];
    if mode.uses_stereo() {
        needed.push(cam1.to_vec());
    }
    if mode.uses_imu() {
        needed.push(vec!["/imu0"]);
    }
    for topics in needed {
        let messages: u64 = topics.iter().filter_map(|t| counts.get(*t)).sum();
        if messages == 0 {
            bad(
                "replay.dataset",
                format!(
                    "{}: no {} messages, which mode {mode} needs",
                    path.display(),
                    topics.join(" or ")
                ),
            );
        }
    }
}

/// The rig from `[calibration]`'s files; every unreadable file becomes a
/// problem naming the file and the field the reader objected to.
pub fn rig_from_files(
    calibration: &CalibrationConfig,
    mode: SensorMode,
    bad: &mut impl FnMut(&str, String),
) -> Option<RigModel> {
    let key = if calibration.folder.is_some() {
        "calibration.folder"
    } else {
        "calibration"
    };
    match (&calibration.folder, calibration.cameras.is_empty()) {
        (Some(_), false) => {
            bad(
                "calibration",
                "give either folder = \"...\" or the files (cameras = [...], imu = ...), not both"
                    .into(),
            );
            return None;
        }
        (None, true) => {
            bad(
                "calibration.cameras",
                "empty: give folder = \"...\" (what rigslam-calibrate --out wrote), or list cam0's file (and cam1's for stereo, or one Kalibr camchain)".into(),
            );
            return None;
        }
        _ => {}
    }
    if calibration.folder.is_none() {
        // Every file that cannot be opened is its own problem.
        let mut ok = true;
        let keyed = calibration
            .cameras
            .iter()
            .enumerate()
            .map(|(i, p)| (format!("calibration.cameras[{i}]"), p))
            .chain(
                calibration
                    .imu
                    .iter()
                    .map(|p| ("calibration.imu".to_owned(), p)),
            )
            .chain(
                calibration
                    .imu_intrinsics
                    .iter()
                    .map(|p| ("calibration.imu_intrinsics".to_owned(), p)),
            );
        for (key, path) in keyed {
            if let Err(e) = std::fs::File::open(path) {
                bad(&key, crate::dataset::DatasetError::io(path, e).to_string());
                ok = false;
            }
        }
        if mode.uses_imu() && calibration.imu.is_none() {
            bad(
                "calibration.imu",
                format!("missing: mode {mode} needs the IMU's noise (Kalibr imu.yaml or EuRoC sensor.yaml)"),
            );
            ok = false;
        }
        if !ok {
            return None;
        }
    }
    let rig = calibration.files().and_then(|files| {
        crate::rig::folder::rig_from_files(&files, &calibration.origin(), mode.uses_imu())
    });
    match rig {
        Ok(rig) => Some(rig),
        Err(e) => {
            // Name the key whose file the reader objected to.
            let named = |p: &Path| e.path() == p;
            let key = calibration
                .cameras
                .iter()
                .position(|p| named(p))
                .map(|i| format!("calibration.cameras[{i}]"))
                .or_else(|| {
                    [
                        ("calibration.imu", &calibration.imu),
                        ("calibration.imu_intrinsics", &calibration.imu_intrinsics),
                    ]
                    .into_iter()
                    .find(|(_, p)| p.as_deref().is_some_and(named))
                    .map(|(k, _)| k.to_owned())
                })
                .unwrap_or_else(|| key.to_owned());
            bad(&key, e.to_string());
            None
        }
    }
}

/// Reads the calibration again (SIGHUP): the rig, or every problem.
pub fn reload_rig(config: &DaemonConfig, file: &Path) -> Result<RigModel, Vec<Problem>> {
    check(config, file)
}

#[cfg(test)]
mod tests {
    use super::*;

    const LIVE: &str = "[camera]\nsource = \"pattern\"\n[imu]\nsource = \"yei\"\n";

    #[test]
    fn the_recording_format_is_foxglove_unless_set_to_ros2() {
        let config = DaemonConfig::parse(LIVE).expect("valid");
        assert_eq!(config.recording.format, crate::recording::Format::Foxglove);
        let config =
            DaemonConfig::parse(&format!("{LIVE}[recording]\nformat = \"ros2\"\n")).expect("valid");
        assert_eq!(config.recording.format, crate::recording::Format::Ros2);
    }

    /// An unknown format names the key, the value and the choices.
    #[test]
    fn an_unknown_recording_format_is_refused_by_key() {
        let e = DaemonConfig::parse(&format!("{LIVE}[recording]\nformat = \"ros1\"\n"))
            .expect_err("not a format");
        assert!(
            e.contains("format = \"ros1\"")
                && e.contains("recording.format")
                && e.contains("foxglove")
                && e.contains("ros2"),
            "{e}"
        );
    }

    /// Both stages run unless `[slam.absolute] enabled = false`, also when
    /// the table sets other keys; its keys are still checked.
    #[test]
    fn the_absolute_stage_is_on_unless_disabled() {
        let config = DaemonConfig::parse(LIVE).expect("valid");
        assert!(config.slam.absolute.enabled);
        let config =
            DaemonConfig::parse(&format!("{LIVE}[slam]\nmode = \"stereo\"\n")).expect("valid");
        assert!(config.slam.absolute.enabled);
        let config = DaemonConfig::parse(&format!(
            "{LIVE}[slam.absolute]\norientation_sigma_rad_per_sqrt_s = 0.0001\n"
        ))
        .expect("valid");
        assert!(config.slam.absolute.enabled);
        assert_eq!(
            config.slam.absolute.orientation_sigma_rad_per_sqrt_s,
            0.0001
        );
        let config = DaemonConfig::parse(&format!("{LIVE}[slam.absolute]\nenabled = false\n"))
            .expect("valid");
        assert!(!config.slam.absolute.enabled);
        let e = DaemonConfig::parse(&format!("{LIVE}[slam.absolute]\nenable = false\n"))
            .expect_err("not a key");
        assert!(e.contains("enable"), "{e}");
    }
}
