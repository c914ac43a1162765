//! A whole synthetic sequence: motion, room sized to contain it, IMU, and
//! the EuRoC ASL dataset written through [`crate::dataset::EurocWriter`].

use std::path::{Path, PathBuf};
use std::time::Instant;

use nalgebra::Vector3;

use super::imu_synth::{synthesize, ImuSynthConfig};
use super::interpolated::InterpolatedMotion;
use super::motion::{BuiltinMotion, Motion, MotionError, SplineMotion};
use super::progress::RenderProgress;
use super::render::{RenderOptions, Renderer};
use super::scene::{Aabb, Scene, SceneConfig};
use super::texture::hash3;
use crate::dataset::{
    read_euroc_groundtruth, read_euroc_imu_csv, read_trajectory_any, DatasetError, EurocWriter,
    GroundTruthState,
};
use crate::imu::ImuBiases;
use crate::imu::{accel_agreement, gyro_agreement};
use crate::rig::euroc::{euroc_cam0, euroc_cam1, euroc_imu0};
use crate::rig::{CameraCalibration, ImuNoise};
use crate::sensors::{Image, ImuSample};
use crate::trajectory::Trajectory;

/// Where the IMU samples come from.
#[derive(Debug, Clone, PartialEq)]
pub enum ImuSource {
    /// Synthesised from the motion, with noise and bias random walk.
    Synthetic,
    /// Copied from a real EuRoC `imu0/data.csv`-style log over the
    /// trajectory's span; the trajectory must be that log's ground truth.
    Real(PathBuf),
}

/// How the spline follows a recorded trajectory.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SplineConfig {
    /// Through the trajectory at every knot ([`SplineMotion::fit_through`])
    /// or with control poses on it, smoothing it ([`SplineMotion::fit`]).
    pub through_samples: bool,
    /// Time between knots, s.
    pub knot_spacing_s: f64,
}

impl SplineConfig {
    /// For a real IMU log the images must move as that IMU measured, so
    /// the spline passes through the ground truth every 10 ms. On V1_02
    /// it then agrees with the IMU's 50 ms increments as closely as the
    /// ground truth does (rotation 0.006-0.007 deg median, against 0.05-
    /// 0.07 deg for control poses on the ground truth every 50 ms;
    /// `tests/simulate_real_imu.rs`). Its accelerations carry the ground
    /// truth's 200 Hz content, which does not matter here: nothing is
    /// synthesised from them.
    pub const REAL_IMU: Self = Self {
        through_samples: true,
        knot_spacing_s: 0.01,
    };
    /// A synthetic IMU differentiates the spline twice, so it smooths:
    /// control poses on the ground truth every 50 ms (on V1_02 the ideal
    /// specific force changes by 0.04 m/s^2 RMS between 200 Hz samples,
    /// against 1.2 m/s^2 for the spline through it every 10 ms).
    pub const SYNTHETIC_IMU: Self = Self {
        through_samples: false,
        knot_spacing_s: 0.05,
    };

    /// The spline settings for `imu`: [`Self::SYNTHETIC_IMU`] or [`Self::REAL_IMU`].
    pub fn for_imu(imu: &ImuSource) -> Self {
        match imu {
            ImuSource::Synthetic => Self::SYNTHETIC_IMU,
            ImuSource::Real(_) => Self::REAL_IMU,
        }
    }

    /// The spline through or along `trajectory`.
    pub fn fit(&self, trajectory: &Trajectory) -> Result<SplineMotion, MotionError> {
        if self.through_samples {
            SplineMotion::fit_through(trajectory, self.knot_spacing_s)
        } else {
            SplineMotion::fit(trajectory, self.knot_spacing_s)
        }
    }
}

/// Everything `simulate` needs; [`Default`] is EuRoC's rig on the built-in motion.
#[derive(Debug, Clone, PartialEq)]
pub struct SimConfig {
    /// Ground truth to follow (EuRoC csv, TUM, ...); `None` for the built-in motion.
    pub trajectory: Option<PathBuf>,
    /// Length of the sequence; `None` = 30 s built-in or the whole file.
    pub duration_s: Option<f64>,
    /// Where the IMU samples come from.
    pub imu: ImuSource,
    /// Render cam1 as well (a stereo sequence).
    pub stereo: bool,
    /// Seed of the scene and the IMU noise; the same seed gives the same sequence.
    pub seed: u64,
    /// Camera frame rate, Hz.
    pub camera_rate_hz: f64,
    /// IMU rate of synthetic samples, Hz.
    pub imu_rate_hz: f64,
    /// Left camera: intrinsics, distortion and pose on the body.
    pub cam0: CameraCalibration,
    /// Right camera, used when `stereo`.
    pub cam1: CameraCalibration,
    /// Synthetic IMU noise; `None` gives ideal measurements (biases stay at
    /// their initial values).
    pub imu_noise: Option<ImuNoise>,
    /// Biases of the synthetic IMU at the first sample.
    pub initial_biases: ImuBiases,
    /// Rendering options (pixel noise, vignetting).
    pub render: RenderOptions,
    /// Boxes placed in the room.
    pub box_count: usize,
    /// Base texel edge of the textures, m.
    pub texel_m: f32,
    /// How a trajectory file becomes a spline; `None` chooses by the IMU
    /// source ([`SplineConfig::for_imu`]).
    pub spline: Option<SplineConfig>,
    /// Follow a recorded trajectory without a spline: the poses
    /// interpolated at each stamp ([`super::interpolated`]); real IMU only.
    pub interpolate_poses: bool,
    /// With a real IMU log, write into `imu0/sensor.yaml` the noise the
    /// log shows against the rendered motion when it is above the
    /// datasheet's (true), or the datasheet's alone, as a user on a robot
    /// would have it (false).
    pub declare_measured_noise: bool,
    /// Progress bar on stderr (shown only when it is a terminal).
    pub show_progress: bool,
}

/// Built-in motion starts here (1 s), so no stamp is 0.
pub const BUILTIN_START_NS: i64 = 1_000_000_000;
/// Built-in sequence length when none is given, s.
pub const BUILTIN_DURATION_S: f64 = 30.0;

impl Default for SimConfig {
    fn default() -> Self {
        Self {
            trajectory: None,
            duration_s: None,
            imu: ImuSource::Synthetic,
            stereo: false,
            seed: 0,
            camera_rate_hz: 20.0,
            imu_rate_hz: 200.0,
            cam0: euroc_cam0(),
            cam1: euroc_cam1(),
            imu_noise: Some(ImuNoise::EUROC_ADIS16448),
            initial_biases: ImuSynthConfig::default().initial_biases,
            render: RenderOptions::default(),
            box_count: 12,
            texel_m: 0.005,
            spline: None,
            interpolate_poses: false,
            declare_measured_noise: true,
            show_progress: true,
        }
    }
}

/// What was written and how fast.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct SimReport {
    /// Camera stamps (stereo pairs count once).
    pub frames: usize,
    /// Images written (frames times cameras).
    pub images: usize,
    /// IMU samples written.
    pub imu_samples: usize,
    /// Sequence length, s.
    pub duration_s: f64,
    /// Length of the path the body travels, m.
    pub path_length_m: f64,
    /// Size of the room along x, y, z, m.
    pub room_size_m: [f64; 3],
    /// Boxes placed (fewer than asked when they do not fit).
    pub boxes: usize,
    /// Scene generation (textures) plus ray tables, s.
    pub setup_s: f64,
    /// Ray casting only, s.
    pub render_s: f64,
    /// Images per second of ray casting alone, wall clock (one thread).
    pub render_fps: f64,
    /// Images per second of ray casting per CPU-second of the rendering
    /// thread (Linux schedstat): the speed on one unloaded core.
    pub render_cpu_fps: Option<f64>,
    /// PNG encoding and file writing of the images, s.
    pub write_s: f64,
    /// Images per second including PNG encoding and writing.
    pub render_write_fps: f64,
    /// Total wall time, s.
    pub total_s: f64,
    /// With a real IMU log: its accelerometer noise density measured
    /// against the rendered motion ([`accel_agreement`], 0.25 s windows),
    /// m/s^2/sqrt(Hz); written to `imu0/sensor.yaml` when above the
    /// datasheet's.
    pub imu_accel_noise_measured: Option<f64>,
    /// The same for its gyroscope ([`gyro_agreement`]), rad/s/sqrt(Hz).
    pub imu_gyro_noise_measured: Option<f64>,
}

/// Windows over which a real IMU log is compared with the motion: the
/// span of one inertial term, keyframe to keyframe (0.2 s on average on
/// V1_02, at most 0.5 s). The log's error is not white (V1_02: 0.020
/// m/s^2/sqrt(Hz) over 0.25 s windows, 0.026 over 0.5 s, 0.032 over 1 s),
/// so one density fits one time scale; at 1 s windows the mono-inertial
/// alignment of a start in flight waits 4.6 s instead of 1.6 s for its
/// scale.
const REAL_IMU_AGREEMENT_WINDOW_S: f64 = 0.25;

#[derive(Debug, thiserror::Error)]
/// Why a sequence could not be simulated.
pub enum SimError {
    #[error(transparent)]
    /// A trajectory or IMU log could not be read, or the dataset could not be written.
    Dataset(#[from] DatasetError),
    #[error("{path}: cannot follow this trajectory: {source}")]
    /// The trajectory cannot be turned into a spline.
    Motion {
        /// The trajectory file.
        path: PathBuf,
        #[source]
        /// Why.
        source: MotionError,
    },
    #[error("{path}: no IMU samples inside the trajectory's span [{start_ns}, {end_ns}] ns")]
    /// The real IMU log has no sample inside the trajectory's span.
    NoImuInSpan {
        /// The IMU log.
        path: PathBuf,
        /// Start of the trajectory's span, ns.
        start_ns: i64,
        /// End of the trajectory's span, ns.
        end_ns: i64,
    },
    #[error("invalid configuration: {0}")]
    /// The settings contradict each other or are out of range (the message says which).
    Config(String),
}

fn check_config(config: &SimConfig) -> Result<(), SimError> {
    let positive = |name: &str, v: f64| {
        if v.is_finite() && v > 0.0 {
            Ok(())
        } else {
            Err(SimError::Config(format!(
                "{name} must be positive and finite, got {v}"
            )))
        }
    };
    if let Some(d) = config.duration_s {
        positive("duration_s", d)?;
    }
    positive("camera_rate_hz", config.camera_rate_hz)?;
    positive("imu_rate_hz", config.imu_rate_hz)?;
    positive("texel_m", config.texel_m as f64)?;
    if let Some(spline) = &config.spline {
        positive("spline.knot_spacing_s", spline.knot_spacing_s)?;
    }
    if config.box_count > super::render::MAX_BOXES {
        return Err(SimError::Config(format!(
            "box_count must be at most {}, got {}",
            super::render::MAX_BOXES,
            config.box_count
        )));
    }
    if config.interpolate_poses && !matches!(config.imu, ImuSource::Real(_)) {
        return Err(SimError::Config(
            "interpolated poses have no usable acceleration: they need a real IMU log (--imu real:FILE)".into(),
        ));
    }
    if config.interpolate_poses && config.spline.is_some() {
        return Err(SimError::Config(
            "interpolated poses and a spline are two ways to follow the trajectory: choose one"
                .into(),
        ));
    }
    if matches!(config.imu, ImuSource::Real(_)) && config.trajectory.is_none() {
        return Err(SimError::Config(
            "a real IMU log needs its own ground-truth trajectory (--trajectory)".into(),
        ));
    }
    Ok(())
}

/// The motion to follow, clipped to the requested duration.
fn build_motion(config: &SimConfig) -> Result<(Motion, i64, i64), SimError> {
    let motion = match &config.trajectory {
        None => Motion::Builtin(BuiltinMotion::standard(
            BUILTIN_START_NS,
            config.duration_s.unwrap_or(BUILTIN_DURATION_S),
        )),
        Some(path) => {
            let trajectory = read_trajectory_any(path)?;
            if config.interpolate_poses {
                let motion = InterpolatedMotion::new(&trajectory).map_err(|e| {
                    SimError::Config(format!("{}: cannot interpolate: {e}", path.display()))
                })?;
                return finish_motion(config, Motion::Interpolated(motion));
            }
            let spline = config
                .spline
                .unwrap_or_else(|| SplineConfig::for_imu(&config.imu));
            Motion::Spline(spline.fit(&trajectory).map_err(|source| SimError::Motion {
                path: path.clone(),
                source,
            })?)
        }
    };
    finish_motion(config, motion)
}

/// The motion with its span clipped to the requested duration.
fn finish_motion(config: &SimConfig, motion: Motion) -> Result<(Motion, i64, i64), SimError> {
    let start_ns = motion.start_ns();
    let end_ns = match config.duration_s {
        Some(d) => (start_ns + (d * 1e9).round() as i64).min(motion.end_ns()),
        None => motion.end_ns(),
    };
    Ok((motion, start_ns, end_ns))
}

/// A room around everything the cameras pass through: the trajectory's
/// bounding box plus 2 m sideways, 1 m below and 1.2 m above, at least
/// 6 x 6 x 3 m; boxes keep 0.5 m away from the trajectory.
fn room_around(
    motion: &Motion,
    start_ns: i64,
    end_ns: i64,
    cams: &[&CameraCalibration],
) -> (Aabb, Aabb) {
    let mut lo = Vector3::repeat(f64::INFINITY);
    let mut hi = Vector3::repeat(f64::NEG_INFINITY);
    let step_ns = 10_000_000;
    let mut t = start_ns;
    while t <= end_ns + step_ns {
        let pose = motion.state(t.min(end_ns)).T_world_body;
        for p in std::iter::once(pose.translation.vector).chain(
            cams.iter()
                .map(|c| (pose * c.T_body_cam).translation.vector),
        ) {
            lo = lo.inf(&p);
            hi = hi.sup(&p);
        }
        t += step_ns;
    }
    let mut room_lo = lo - Vector3::new(2.0, 2.0, 1.0);
    let mut room_hi = hi + Vector3::new(2.0, 2.0, 1.2);
    for (a, min_size) in [6.0, 6.0, 3.0].into_iter().enumerate() {
        let grow = (min_size - (room_hi[a] - room_lo[a])).max(0.0) / 2.0;
        room_lo[a] -= grow;
        room_hi[a] += grow;
    }
    let f = |v: Vector3<f64>| [v.x as f32, v.y as f32, v.z as f32];
    let keep = Aabb::new(f(lo), f(hi)).expanded(0.5);
    (Aabb::new(f(room_lo), f(room_hi)), keep)
}

/// IMU samples and the true bias at each.
fn imu_stream(
    config: &SimConfig,
    motion: &Motion,
    start_ns: i64,
    end_ns: i64,
) -> Result<(Vec<ImuSample>, Vec<ImuBiases>), SimError> {
    match &config.imu {
        ImuSource::Synthetic => {
            let imu = synthesize(
                motion,
                start_ns,
                end_ns,
                &ImuSynthConfig {
                    rate_hz: config.imu_rate_hz,
                    noise: config.imu_noise,
                    initial_biases: config.initial_biases,
                    seed: hash3(config.seed, 0x1A1, 0xB1A5),
                },
            );
            Ok((imu.samples, imu.biases))
        }
        ImuSource::Real(path) => {
            let samples: Vec<ImuSample> = read_euroc_imu_csv(path)?
                .samples
                .into_iter()
                .filter(|s| (start_ns..=end_ns).contains(&s.t_ns))
                .collect();
            if samples.is_empty() {
                return Err(SimError::NoImuInSpan {
                    path: path.clone(),
                    start_ns,
                    end_ns,
                });
            }
            // Biases from the ground truth when it carries them (EuRoC csv),
            // at the nearest earlier ground-truth stamp; zero otherwise.
            let gt_path = config.trajectory.as_ref().expect("checked in check_config");
            let gt = match read_euroc_groundtruth(gt_path) {
                Ok(gt) => gt,
                Err(e) => {
                    tracing::warn!(
                        "{}: no biases in the ground truth ({e}); recording zero biases",
                        gt_path.display()
                    );
                    Vec::new()
                }
            };
            let biases = samples
                .iter()
                .map(|s| {
                    let k = gt.partition_point(|g| g.t_ns <= s.t_ns);
                    gt.get(k.saturating_sub(1))
                        .map_or(ImuBiases::default(), ImuBiases::from)
                })
                .collect();
            Ok((samples, biases))
        }
    }
}

/// The file beside `mav0/` that holds the rendered scene's surfaces.
pub const SCENE_FILE: &str = "scene.json";

/// Writes `scene`'s surfaces to [`SCENE_FILE`] under `out`, atomically.
fn write_scene_geometry(scene: &Scene, out: &Path) -> Result<(), SimError> {
    let path = out.join(SCENE_FILE);
    let mut text = serde_json::to_string_pretty(&scene.geometry())
        .map_err(|e| DatasetError::io(&path, std::io::Error::other(e)))?;
    text.push('\n');
    crate::text_file::write_atomically(&path, text.as_bytes())
        .map_err(|e| DatasetError::io(&path, e))?;
    Ok(())
}

/// CPU time of the calling thread, s, from `/proc/thread-self/schedstat`
/// (its first field is ns on CPU); `None` where that file does not exist.
fn thread_cpu_s() -> Option<f64> {
    let text = std::fs::read_to_string("/proc/thread-self/schedstat").ok()?;
    let ns: u64 = text.split_whitespace().next()?.parse().ok()?;
    Some(ns as f64 * 1e-9)
}

/// Renders and writes the dataset `config` describes under `out` (which
/// then holds `mav0/`).
pub fn simulate(config: &SimConfig, out: &Path) -> Result<SimReport, SimError> {
    let started = Instant::now();
    check_config(config)?;
    let (motion, start_ns, end_ns) = build_motion(config)?;
    let mut cams = vec![&config.cam0];
    if config.stereo {
        cams.push(&config.cam1);
    }
    let (room, keep_clear) = room_around(&motion, start_ns, end_ns, &cams);
    let scene = Scene::generate(&SceneConfig {
        seed: config.seed,
        room,
        keep_clear,
        box_count: config.box_count,
        texel_m: config.texel_m,
    });
    let renderers: Vec<Renderer> = cams
        .iter()
        .map(|c| Renderer::new(&c.model, config.render))
        .collect();
    let setup_s = started.elapsed().as_secs_f64();

    let mut writer = EurocWriter::create(out)?;
    for (k, cam) in cams.iter().enumerate() {
        let mut calib = (*cam).clone();
        calib.rate_hz = config.camera_rate_hz;
        writer.write_camera(&format!("cam{k}"), &calib)?;
    }

    let period_ns = (1e9 / config.camera_rate_hz).round() as i64;
    let frames = ((end_ns - start_ns) / period_ns + 1) as usize;
    let progress = RenderProgress::new(frames, config.show_progress);
    let (width, height) = (renderers[0].width(), renderers[0].height());
    let mut buffer = vec![0u8; width * height];
    let (mut render_s, mut write_s) = (0.0, 0.0);
    let mut render_cpu_s = Some(0.0);
    for frame in 0..frames {
        let t_ns = start_ns + frame as i64 * period_ns;
        let pose = motion.state(t_ns).T_world_body;
        for (k, (cam, renderer)) in cams.iter().zip(&renderers).enumerate() {
            if buffer.len() != renderer.width() * renderer.height() {
                buffer.resize(renderer.width() * renderer.height(), 0);
            }
            let cpu0 = thread_cpu_s();
            let t0 = Instant::now();
            let noise_seed = hash3(frame as u64, k as u64, config.seed);
            renderer.render_into(&scene, &(pose * cam.T_body_cam), noise_seed, &mut buffer);
            let t1 = Instant::now();
            render_cpu_s = match (render_cpu_s, cpu0, thread_cpu_s()) {
                (Some(total), Some(a), Some(b)) => Some(total + (b - a)),
                _ => None,
            };
            let image = Image::mono8(
                renderer.width() as u32,
                renderer.height() as u32,
                buffer.clone(),
            )
            .expect("buffer matches the renderer's size");
            writer.add_image(&format!("cam{k}"), t_ns, &image)?;
            render_s += (t1 - t0).as_secs_f64();
            write_s += t1.elapsed().as_secs_f64();
        }
        progress.frame_done();
    }
    progress.finish();

    let (samples, biases) = imu_stream(config, &motion, start_ns, end_ns)?;
    let mut imu_calib = euroc_imu0();
    imu_calib.rate_hz = config.imu_rate_hz;
    if let Some(noise) = config.imu_noise {
        imu_calib.noise = noise;
    }
    let groundtruth: Vec<GroundTruthState> = samples
        .iter()
        .zip(&biases)
        .map(|(s, b)| {
            let state = motion.state(s.t_ns);
            GroundTruthState {
                t_ns: s.t_ns,
                T_world_body: state.T_world_body,
                velocity_m_s: state.velocity_world_m_s,
                gyro_bias_rad_s: b.gyro_rad_s,
                accel_bias_m_s2: b.accel_m_s2,
            }
        })
        .collect();
    let path_length_m: f64 = groundtruth
        .windows(2)
        .map(|w| {
            (w[1].T_world_body.translation.vector - w[0].T_world_body.translation.vector).norm()
        })
        .sum();
    // A real log disagrees with the rendered motion far more than its
    // datasheet noise says (V1_02: 0.02 against 0.002 m/s^2/sqrt(Hz),
    // see `imu::agreement`); the estimator reads the noise from this
    // file, so it must describe the log as it is.
    let real = matches!(config.imu, ImuSource::Real(_));
    let window_s = REAL_IMU_AGREEMENT_WINDOW_S;
    let imu_accel_noise_measured = real
        .then(|| accel_agreement(&groundtruth, &samples, window_s))
        .flatten()
        .map(|a| a.noise_density_m_s2_sqrt_hz);
    let imu_gyro_noise_measured = real
        .then(|| gyro_agreement(&groundtruth, &samples, window_s))
        .flatten()
        .map(|a| a.noise_density_rad_s_sqrt_hz);
    let noise = &mut imu_calib.noise;
    let declared = config.declare_measured_noise;
    if let Some(density) = imu_accel_noise_measured.filter(|_| declared) {
        noise.accelerometer_noise_density = noise.accelerometer_noise_density.max(density);
    }
    if let Some(density) = imu_gyro_noise_measured.filter(|_| declared) {
        noise.gyroscope_noise_density = noise.gyroscope_noise_density.max(density);
    }
    writer.write_imu(&imu_calib, &samples)?;
    writer.write_groundtruth(&groundtruth)?;
    writer.finish()?;
    write_scene_geometry(&scene, out)?;

    let images = frames * cams.len();
    let size = |a: usize| (room.max_m[a] - room.min_m[a]) as f64;
    Ok(SimReport {
        frames,
        images,
        imu_samples: samples.len(),
        duration_s: (end_ns - start_ns) as f64 * 1e-9,
        path_length_m,
        room_size_m: [size(0), size(1), size(2)],
        boxes: scene.boxes.len(),
        setup_s,
        render_s,
        render_fps: images as f64 / render_s.max(1e-12),
        render_cpu_fps: render_cpu_s.map(|s| images as f64 / s.max(1e-12)),
        write_s,
        render_write_fps: images as f64 / (render_s + write_s).max(1e-12),
        total_s: started.elapsed().as_secs_f64(),
        imu_accel_noise_measured,
        imu_gyro_noise_measured,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dataset::EurocDataset;

    use crate::shared_data::shared_data_dir as data_dir;

    fn quick(seed: u64, duration_s: f64, stereo: bool) -> SimConfig {
        SimConfig {
            duration_s: Some(duration_s),
            stereo,
            seed,
            show_progress: false,
            // Coarser texels keep scene generation quick in tests.
            texel_m: 0.01,
            ..SimConfig::default()
        }
    }

    /// Every file under `dir` with its bytes, sorted by path.
    fn files(dir: &Path) -> Vec<(PathBuf, Vec<u8>)> {
        let mut out = Vec::new();
        let mut stack = vec![dir.to_path_buf()];
        while let Some(d) = stack.pop() {
            for entry in std::fs::read_dir(&d).unwrap() {
                let p = entry.unwrap().path();
                if p.is_dir() {
                    stack.push(p);
                } else {
                    let bytes = std::fs::read(&p).unwrap();
                    out.push((p.strip_prefix(dir).unwrap().to_path_buf(), bytes));
                }
            }
        }
        out.sort();
        out
    }

    #[test]
    fn dataset_reads_back_through_the_euroc_reader() {
        let dir = tempfile::tempdir().unwrap();
        let config = quick(3, 2.0, true);
        let report = simulate(&config, dir.path()).unwrap();
        assert_eq!(report.frames, 41);
        assert_eq!(report.images, 82);
        assert_eq!(report.imu_samples, 401);
        let ds = EurocDataset::open(dir.path()).unwrap();
        assert_eq!(ds.cameras.len(), 2);
        for cam in &ds.cameras {
            assert_eq!(cam.frames.len(), 41);
            assert_eq!(cam.missing_images(), 0);
            let frame = cam.load(40).unwrap().expect("image present");
            assert_eq!((frame.image.width(), frame.image.height()), (752, 480));
            assert_eq!(frame.t_ns, BUILTIN_START_NS + 2_000_000_000);
        }
        assert_eq!(ds.cameras[0].calibration.model, config.cam0.model);
        let t_err = (ds.cameras[1].calibration.T_body_cam.translation.vector
            - config.cam1.T_body_cam.translation.vector)
            .norm();
        assert!(t_err < 1e-9);
        let imu = ds.imu.expect("imu0 written");
        assert_eq!(imu.samples.len(), 401);
        assert_eq!(imu.calibration.noise, ImuNoise::EUROC_ADIS16448);
        let gt = ds.groundtruth.expect("ground truth written");
        assert_eq!(gt.len(), 401);
        // The scene's surfaces, in the ground truth's frame: the rig flies
        // inside the room and at least the keep-clear margin from every box.
        let text = std::fs::read_to_string(dir.path().join(SCENE_FILE)).unwrap();
        let geometry: crate::simulate::scene::SceneGeometry = serde_json::from_str(&text).unwrap();
        assert_eq!(geometry.boxes.len(), report.boxes);
        for a in 0..3 {
            let size = (geometry.room.max_m[a] - geometry.room.min_m[a]) as f64;
            assert!((size - report.room_size_m[a]).abs() < 1e-6);
        }
        for g in &gt {
            let p = g.T_world_body.translation.vector;
            let p = [p.x as f32, p.y as f32, p.z as f32];
            assert!(geometry.room.contains(p), "{p:?} outside the room");
            for b in &geometry.boxes {
                assert!(!b.expanded(0.4).contains(p), "{p:?} within 0.4 m of {b:?}");
            }
        }
        // Ground truth is the motion the images were rendered along.
        let motion = Motion::Builtin(BuiltinMotion::standard(BUILTIN_START_NS, 2.0));
        for g in gt.iter().step_by(37) {
            let truth = motion.state(g.t_ns);
            assert!(
                (g.T_world_body.translation.vector - truth.T_world_body.translation.vector).norm()
                    < 1e-6
            );
            assert!(
                g.T_world_body
                    .rotation
                    .angle_to(&truth.T_world_body.rotation)
                    < 1e-6
            );
            assert!((g.velocity_m_s - truth.velocity_world_m_s).norm() < 1e-6);
        }
        assert!((gt[0].gyro_bias_rad_s - config.initial_biases.gyro_rad_s).norm() < 1e-9);
        // The biases walk.
        assert!(gt[400].accel_bias_m_s2 != gt[0].accel_bias_m_s2);
    }

    #[test]
    fn same_seed_gives_identical_files_other_seed_differs() {
        let dirs: Vec<_> = (0..3).map(|_| tempfile::tempdir().unwrap()).collect();
        for (dir, seed) in dirs.iter().zip([7, 7, 8]) {
            simulate(&quick(seed, 0.5, false), dir.path()).unwrap();
        }
        let [a, b, c] = [0, 1, 2].map(|k| files(dirs[k].path()));
        assert!(a.len() > 10);
        assert!(a == b, "same seed, different bytes");
        let imu = |f: &[(PathBuf, Vec<u8>)]| {
            f.iter()
                .find(|(p, _)| p.ends_with("imu0/data.csv"))
                .expect("imu csv")
                .1
                .clone()
        };
        assert_ne!(imu(&a), imu(&c));
        let pngs_equal = a
            .iter()
            .zip(&c)
            .filter(|((p, x), (_, y))| p.extension().is_some_and(|e| e == "png") && x == y)
            .count();
        assert_eq!(pngs_equal, 0, "a different seed must change every image");
    }

    #[test]
    fn real_imu_noise_is_written_as_measured_against_the_motion() {
        let Some(data) = data_dir() else { return };
        let dir = tempfile::tempdir().unwrap();
        let config = SimConfig {
            trajectory: Some(data.join("euroc/ground_truth/V1_02_groundtruth.csv")),
            imu: ImuSource::Real(data.join("euroc/ground_truth/V1_02_imu0.csv")),
            ..quick(1, 3.0, false)
        };
        let report = simulate(&config, dir.path()).unwrap();
        let measured = report.imu_accel_noise_measured.expect("2 whole windows");
        // V1_02's first seconds: far above the datasheet's 0.002.
        assert!(measured > 0.005, "{measured}");
        let ds = EurocDataset::open(dir.path()).unwrap();
        let noise = ds.imu.unwrap().calibration.noise;
        assert_eq!(noise.accelerometer_noise_density, measured);
        let gyro = report.imu_gyro_noise_measured.expect("2 whole windows");
        // Above the datasheet's 0.00017 rad/s/sqrt(Hz) too.
        assert!(
            gyro > ImuNoise::EUROC_ADIS16448.gyroscope_noise_density,
            "{gyro}"
        );
        assert_eq!(noise.gyroscope_noise_density, gyro);
        // A synthetic IMU keeps the noise it was made with.
        let other = tempfile::tempdir().unwrap();
        let synthetic = simulate(&quick(1, 3.0, false), other.path()).unwrap();
        assert_eq!(synthetic.imu_accel_noise_measured, None);
        assert_eq!(synthetic.imu_gyro_noise_measured, None);
    }

    #[test]
    fn real_imu_is_copied_with_ground_truth_biases() {
        let Some(data) = data_dir() else { return };
        let gt_path = data.join("euroc/ground_truth/V1_02_groundtruth.csv");
        let imu_path = data.join("euroc/ground_truth/V1_02_imu0.csv");
        let dir = tempfile::tempdir().unwrap();
        let config = SimConfig {
            trajectory: Some(gt_path.clone()),
            imu: ImuSource::Real(imu_path.clone()),
            ..quick(1, 1.0, false)
        };
        let report = simulate(&config, dir.path()).unwrap();
        assert_eq!(report.frames, 21);
        let ds = EurocDataset::open(dir.path()).unwrap();
        let written = ds.imu.unwrap().samples;
        let real = read_euroc_imu_csv(&imu_path).unwrap().samples;
        let first = real
            .iter()
            .position(|s| s.t_ns == written[0].t_ns)
            .expect("a real stamp");
        assert_eq!(&real[first..first + written.len()], &written[..]);
        assert!((195..=201).contains(&written.len()), "{}", written.len());
        let truth = read_euroc_groundtruth(&gt_path).unwrap();
        let gt = ds.groundtruth.unwrap();
        for g in gt.iter().step_by(50) {
            let k = truth.partition_point(|s| s.t_ns <= g.t_ns) - 1;
            assert_eq!(g.gyro_bias_rad_s, truth[k].gyro_bias_rad_s);
            // The spline follows the recorded positions to within a few mm.
            let near = truth[k].T_world_body.translation.vector;
            assert!((g.T_world_body.translation.vector - near).norm() < 0.01);
        }
    }

    /// V1_02's ground truth and IMU, when the shared data is there.
    fn v1_02() -> Option<(PathBuf, PathBuf)> {
        let data = data_dir()?;
        Some((
            data.join("euroc/ground_truth/V1_02_groundtruth.csv"),
            data.join("euroc/ground_truth/V1_02_imu0.csv"),
        ))
    }

    #[test]
    fn with_a_real_imu_the_frames_are_rendered_at_the_recorded_poses() {
        // The real IMU measured the recorded motion, so every camera pose
        // must be a recorded pose, not a smoothed one (the smoothing fit at
        // 0.05 s is up to 3.4 mm off on V1_02).
        let Some((gt_path, imu_path)) = v1_02() else {
            return;
        };
        let config = SimConfig {
            trajectory: Some(gt_path.clone()),
            imu: ImuSource::Real(imu_path),
            ..quick(0, 1.0, false)
        };
        let (motion, start_ns, end_ns) = build_motion(&config).unwrap();
        let truth = read_euroc_groundtruth(&gt_path).unwrap();
        let period_ns = (1e9 / config.camera_rate_hz).round() as i64;
        let (mut worst_p, mut worst_r, mut frames) = (0.0f64, 0.0f64, 0);
        let mut t_ns = start_ns;
        while t_ns <= motion.end_ns() {
            // The ground truth's stamps wobble by tens of ns around a 5 ms
            // grid; the nearest row is the recorded pose at this stamp.
            let k = truth.partition_point(|g| g.t_ns < t_ns);
            let g = [k.saturating_sub(1), k.min(truth.len() - 1)]
                .into_iter()
                .min_by_key(|&i| (truth[i].t_ns - t_ns).abs())
                .unwrap();
            assert!((truth[g].t_ns - t_ns).abs() < 1_000, "a stamp off the grid");
            let (a, b) = (motion.state(t_ns).T_world_body, truth[g].T_world_body);
            worst_p = worst_p.max((a.translation.vector - b.translation.vector).norm());
            worst_r = worst_r.max(a.rotation.angle_to(&b.rotation));
            frames += 1;
            t_ns += period_ns;
        }
        assert!(frames > 1600, "{frames} frames");
        assert!(end_ns - start_ns == 1_000_000_000);
        // A 1 us stamp difference at 2 m/s and 3 rad/s is 2e-6 m, 3e-6 rad.
        assert!(worst_p < 1e-5, "position {worst_p} m off the recording");
        assert!(worst_r < 1e-5, "rotation {worst_r} rad off the recording");
    }

    #[test]
    fn a_synthetic_imu_on_a_recorded_trajectory_stays_smooth() {
        // A synthetic IMU is the spline's second derivative; a spline that
        // followed the ground truth's 200 Hz wobble would make it rough
        // (1.2 m/s^2 RMS from one sample to the next for the spline through
        // V1_02 every 10 ms, against 0.04 for the smoothing one).
        let Some((gt_path, imu_path)) = v1_02() else {
            return;
        };
        let rms_step = |config: &SimConfig| {
            let (motion, start_ns, end_ns) = build_motion(config).unwrap();
            let synthetic = SimConfig {
                imu: ImuSource::Synthetic,
                imu_noise: None,
                ..config.clone()
            };
            let (samples, _) = imu_stream(&synthetic, &motion, start_ns, end_ns).unwrap();
            let sum: f64 = samples
                .windows(2)
                .map(|w| {
                    (Vector3::from(w[1].accel_m_s2) - Vector3::from(w[0].accel_m_s2)).norm_squared()
                })
                .sum();
            (sum / (samples.len() - 1) as f64).sqrt()
        };
        let synthetic = SimConfig {
            trajectory: Some(gt_path.clone()),
            ..quick(0, 1.0, false)
        };
        let smooth = rms_step(&SimConfig {
            duration_s: None,
            ..synthetic.clone()
        });
        assert!(smooth < 0.1, "synthetic IMU steps {smooth} m/s^2 RMS");
        // The test tells the fits apart: the real-IMU spline would be rough.
        let real_spline = rms_step(&SimConfig {
            duration_s: None,
            imu: ImuSource::Real(imu_path),
            ..synthetic
        });
        assert!(real_spline > 5.0 * smooth, "{real_spline} vs {smooth}");
    }

    #[test]
    fn bad_configuration_is_a_typed_error() {
        let dir = tempfile::tempdir().unwrap();
        let real_without_gt = SimConfig {
            imu: ImuSource::Real(PathBuf::from("imu.csv")),
            ..quick(0, 1.0, false)
        };
        assert!(matches!(
            simulate(&real_without_gt, dir.path()),
            Err(SimError::Config(_))
        ));
        assert!(matches!(
            simulate(&quick(0, -1.0, false), dir.path()),
            Err(SimError::Config(_))
        ));
        let missing = SimConfig {
            trajectory: Some(dir.path().join("nope.csv")),
            ..quick(0, 1.0, false)
        };
        assert!(matches!(
            simulate(&missing, dir.path()),
            Err(SimError::Dataset(_))
        ));
    }
}
