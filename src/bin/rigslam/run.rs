//! `rigslam run`: a recorded sequence through the relative stage; the
//! trajectory (TUM, EuRoC csv or KITTI poses), a one-line summary, and a
//! report with per-stage timings and, when the dataset has ground truth,
//! the accuracy.

use std::path::PathBuf;

use anyhow::Context;
use indicatif::{ProgressBar, ProgressStyle};
use rigslam::absolute::map_file::SavedMap;
use rigslam::dataset::{read_trajectory_any, write_trajectory, TrajectoryFormat};
use rigslam::eval::Alignment;
use rigslam::plot::evaluation::write_plot;
use rigslam::relative::{EstimatorKind, SensorMode};
use rigslam::run::dataset_run::{run_dataset, summary_line, DatasetRun};
use rigslam::run::RunOptions;
use rigslam::slam_config::SlamSettings;

#[derive(clap::Args)]
pub struct RunArgs {
    /// The sequence: a EuRoC ASL folder (holding mav0/, or mav0 itself) or
    /// a KITTI odometry folder (image_0/ or image_l/ with calib.txt).
    #[arg(long, required_unless_present = "print_config")]
    dataset: Option<PathBuf>,
    /// Sensors to use: mono, mono-inertial, stereo, stereo-inertial.
    /// Default: stereo-inertial when the dataset has cam1 and imu0,
    /// mono-inertial with cam0 and imu0 only, mono for KITTI.
    #[arg(long)]
    mode: Option<SensorMode>,
    /// The relative-stage estimator: `window` (the paper's windowed
    /// optimisation) or `ekf` (the paper's EKF baseline).
    #[arg(long, value_enum, default_value_t = EstimatorKind::Window)]
    estimator: EstimatorKind,
    /// Write the body trajectory here; with --absolute, the corrected one.
    /// The format follows the extension unless --trajectory-format says:
    /// `.csv` EuRoC (t[ns],px,py,pz,qw,qx,qy,qz under EuRoC's ground-truth
    /// header); `.kitti` KITTI poses (the 3x4 [R|t] row-major, 12 numbers
    /// a line, no stamps); `.tum`, `.txt` or anything else TUM (t[s] tx ty
    /// tz qx qy qz qw).
    #[arg(long)]
    trajectory: Option<PathBuf>,
    /// The format of --trajectory and --trajectory-relative, whatever
    /// their extension.
    #[arg(long, value_enum)]
    trajectory_format: Option<TrajectoryFormat>,
    /// Also run the absolute stage (the linear edge map and the Kalman
    /// position filter) on the relative stage's output (as `[absolute]
    /// enabled = true` in --config does).
    #[arg(long)]
    absolute: bool,
    /// With --absolute or --load-map: write the relative stage's own
    /// trajectory here.
    #[arg(long)]
    trajectory_relative: Option<PathBuf>,
    /// With the absolute stage: save the final map here (text: one
    /// landmark per line, position, covariance and descriptor) to localise
    /// in later.
    #[arg(long)]
    save_map: Option<PathBuf>,
    /// Localise in a map saved by --save-map instead of building one. The
    /// trajectory is then in the map's frame, from the first frame the map
    /// was recognised (relocalisation by descriptor matching + RANSAC).
    #[arg(long, conflicts_with = "absolute")]
    load_map: Option<PathBuf>,
    /// The rig's calibration folder (what `rigslam-calibrate --out`
    /// writes: camchain-imucam.yaml, imu.yaml, imu_intrinsics.yaml)
    /// instead of the dataset's own sensor.yaml files.
    #[arg(long, value_name = "DIR")]
    calibration: Option<PathBuf>,
    /// Settings (TOML): a `[relative]` table for the relative stage and an
    /// `[absolute]` one for the absolute stage; every key has a default
    /// (`rigslam run --print-config` prints them all).
    #[arg(long)]
    config: Option<PathBuf>,
    /// Print the default settings of both stages as TOML and exit.
    #[arg(long)]
    print_config: bool,
    /// Write the JSON report (timings per stage, counts, accuracy) here.
    #[arg(long)]
    report: Option<PathBuf>,
    /// Print the report as one JSON object on stdout instead of the summary.
    #[arg(long)]
    json: bool,
    /// Pace the frames by their stamps instead of running as fast as possible.
    #[arg(long)]
    realtime: bool,
    /// Start at this time into the sequence, s.
    #[arg(long, default_value_t = 0.0)]
    start_s: f64,
    /// Stop after this many frames.
    #[arg(long)]
    max_frames: Option<usize>,
    /// Ground truth to score against (default: the dataset's own, if any).
    #[arg(long)]
    groundtruth: Option<PathBuf>,
    /// Alignment for the accuracy: default se3 for metric modes, sim3 for mono.
    #[arg(long, value_enum)]
    align: Option<Alignment>,
    /// Draw the aligned trajectory and its error (.png or .svg).
    #[arg(long)]
    plot: Option<PathBuf>,
    /// No progress bar.
    #[arg(long)]
    quiet: bool,
    /// Write every frame's output state here (CSV: t_ns, state, position,
    /// quaternion xyzw, velocity, gyro bias, accel bias): to compare the
    /// estimated biases and velocity with the ground truth's.
    #[arg(long)]
    states: Option<PathBuf>,
    /// Write every tracked frame's landmarks from the relative stage, what
    /// the absolute stage builds its map from (CSV: t_ns, landmark id, position in the
    /// frame's body frame, m, its covariance c00 c01 c02 c11 c12 c22, m^2,
    /// and the number of window keyframes the estimate rests on, 0 when
    /// the estimator keeps no window): to study the map offline.
    #[arg(long)]
    landmarks: Option<PathBuf>,
}

/// The `--landmarks` CSV, written as the frames come.
struct LandmarksCsv {
    path: PathBuf,
    out: std::io::BufWriter<std::fs::File>,
    error: Option<std::io::Error>,
}

impl LandmarksCsv {
    const HEADER: &'static str = "t_ns,id,x,y,z,c00,c01,c02,c11,c12,c22,keyframes\n";

    fn create(path: &std::path::Path) -> anyhow::Result<Self> {
        use std::io::Write;
        let file = std::fs::File::create(path)
            .with_context(|| format!("creating the landmarks file {}", path.display()))?;
        let mut out = std::io::BufWriter::new(file);
        out.write_all(Self::HEADER.as_bytes())
            .with_context(|| format!("writing {}", path.display()))?;
        Ok(Self {
            path: path.to_path_buf(),
            out,
            error: None,
        })
    }

    /// Appends a frame's landmarks; the first write error is kept for
    /// [`Self::finish`] and later frames are skipped.
    fn frame(&mut self, output: &rigslam::relative::RelativeOutput) {
        use std::io::Write;
        if self.error.is_some() {
            return;
        }
        for l in &output.landmarks {
            let p = l.position_body_m;
            let c = l.covariance_body_m2;
            let keyframes = l.support.map_or(0, |s| s.keyframes);
            if let Err(e) = writeln!(
                self.out,
                "{},{},{},{},{},{},{},{},{},{},{},{}",
                output.t_ns,
                l.id,
                p.x,
                p.y,
                p.z,
                c[(0, 0)],
                c[(0, 1)],
                c[(0, 2)],
                c[(1, 1)],
                c[(1, 2)],
                c[(2, 2)],
                keyframes
            ) {
                self.error = Some(e);
                return;
            }
        }
    }

    fn finish(mut self) -> anyhow::Result<()> {
        use std::io::Write;
        let flushed = match self.error.take() {
            Some(e) => Err(e),
            None => self.out.flush(),
        };
        flushed.with_context(|| format!("writing the landmarks file {}", self.path.display()))
    }
}

pub fn run(args: RunArgs) -> anyhow::Result<()> {
    if args.print_config {
        print!("{}", SlamSettings::default().to_toml()?);
        return Ok(());
    }
    let Some(dataset) = args.dataset.clone() else {
        anyhow::bail!("--dataset is required (the sequence to run)");
    };
    let mut settings = match &args.config {
        Some(path) => SlamSettings::from_toml_file(path)?,
        None => SlamSettings::default(),
    };
    settings.absolute.enabled |= args.absolute;
    if args.trajectory_relative.is_some() && !settings.absolute.enabled && args.load_map.is_none() {
        anyhow::bail!("--trajectory-relative needs --absolute or --load-map (otherwise --trajectory is the relative trajectory)");
    }
    let load_map = match &args.load_map {
        Some(path) => Some(std::sync::Arc::new(
            SavedMap::read(path).with_context(|| format!("loading the map {}", path.display()))?,
        )),
        None => None,
    };
    let rig = match &args.calibration {
        // Whether the mode needs the IMU is known once the dataset is open;
        // a folder without imu.yaml is refused there by the rig check.
        Some(dir) => Some(
            rigslam::rig::folder::load_folder(dir, false)
                .with_context(|| format!("reading the calibration folder {}", dir.display()))?,
        ),
        None => None,
    };
    let groundtruth = match &args.groundtruth {
        Some(path) => Some(
            read_trajectory_any(path)
                .with_context(|| format!("reading the ground truth {}", path.display()))?,
        ),
        None => None,
    };
    let bar = if args.quiet || args.json {
        ProgressBar::hidden()
    } else {
        let bar = ProgressBar::new(0);
        bar.set_style(
            ProgressStyle::with_template(
                "{spinner} {elapsed_precise} [{bar:30}] {pos}/{len} frames {per_sec} {msg}",
            )
            .expect("valid template")
            .progress_chars("=> "),
        );
        bar
    };
    let run = DatasetRun {
        mode: args.mode,
        estimator: args.estimator,
        settings,
        options: RunOptions {
            realtime: args.realtime,
        },
        start_s: args.start_s,
        max_frames: args.max_frames,
        groundtruth,
        align: args.align,
        save_map: args.save_map.clone(),
        load_map,
        rig,
    };
    let mut landmarks_csv = match &args.landmarks {
        Some(path) => Some(LandmarksCsv::create(path)?),
        None => None,
    };
    let mut states_csv = String::new();
    if args.states.is_some() {
        states_csv.push_str("t_ns,state,px,py,pz,qx,qy,qz,qw,vx,vy,vz,bgx,bgy,bgz,bax,bay,baz\n");
    }
    let result = run_dataset(&dataset, &run, |output, listed| {
        if let Some(csv) = landmarks_csv.as_mut() {
            csv.frame(output);
        }
        if args.states.is_some() {
            let p = output.T_world_body.translation.vector;
            let q = output.T_world_body.rotation.coords;
            let v = output.velocity_world_m_s;
            let (bg, ba) = (output.biases.gyro_rad_s, output.biases.accel_m_s2);
            let state = format!("{:?}", output.state).to_lowercase();
            states_csv.push_str(&format!(
                "{},{state},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{}\n",
                output.t_ns,
                p.x,
                p.y,
                p.z,
                q.x,
                q.y,
                q.z,
                q.w,
                v.x,
                v.y,
                v.z,
                bg.x,
                bg.y,
                bg.z,
                ba.x,
                ba.y,
                ba.z
            ));
        }
        bar.set_length(listed as u64);
        bar.inc(1);
        bar.set_message(format!("{:?}", output.state).to_lowercase());
    })
    .with_context(|| format!("running on {}", dataset.display()))?;
    bar.finish_and_clear();

    if let Some(path) = &args.trajectory {
        if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
        }
        let format = args
            .trajectory_format
            .unwrap_or_else(|| TrajectoryFormat::of_path(path));
        write_trajectory(path, &result.outcome.trajectory, format)?;
    }
    if let Some(csv) = landmarks_csv {
        csv.finish()?;
    }
    if let Some(path) = &args.states {
        std::fs::write(path, &states_csv)
            .with_context(|| format!("writing the states {}", path.display()))?;
    }
    if let (Some(path), Some(relative)) = (&args.trajectory_relative, &result.trajectory_relative) {
        let format = args
            .trajectory_format
            .unwrap_or_else(|| TrajectoryFormat::of_path(path));
        write_trajectory(path, relative, format)?;
    }
    if let Some(path) = &args.plot {
        match &result.evaluation {
            Some(e) => write_plot(path, e)?,
            None => tracing::warn!("no plot: no ground truth to compare with"),
        }
    }
    if let Some(path) = &args.report {
        let text = serde_json::to_string_pretty(&result.report).expect("report serialises");
        std::fs::write(path, text + "\n")
            .with_context(|| format!("writing the report {}", path.display()))?;
    }
    if args.json {
        println!(
            "{}",
            serde_json::to_string(&result.report).expect("report serialises")
        );
    } else {
        println!("{}", summary_line(&result.report));
    }
    Ok(())
}
