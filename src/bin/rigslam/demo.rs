//! `rigslam demo`: the README's first command. Renders a synthetic EuRoC
//! sequence (stereo images, IMU with EuRoC's noise, ground truth), plays
//! it through the daemon live (`rigslamd --replay` at the recorded pace,
//! `rigslam echo` printing the poses it publishes, those poses scored
//! against the ground truth), runs the relative stage on it in the stereo-inertial and mono-inertial
//! modes exactly as `rigslam run` does, and scores both; then, when
//! ../shared/data is beside the repository, does the same on real
//! recordings: EuRoC V1_01 at rest (static start, drift) and KITTI seq_a
//! (mono). Every number printed is measured on this run.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{bail, Context};
use serde::Serialize;

use rigslam::dataset::write_tum;
use rigslam::plot::evaluation::write_plot;
use rigslam::relative::SensorMode;
use rigslam::run::dataset_run::{run_dataset, summary_line, DatasetRun};
use rigslam::run::RunReport;
use rigslam::simulate::{simulate, SimConfig, SimReport};

#[derive(clap::Args)]
pub struct DemoArgs {
    /// Folder for the generated dataset, the estimates and the plots.
    #[arg(long, default_value = "out/demo")]
    out: PathBuf,
    /// Length of the generated sequence, s.
    #[arg(long, default_value_t = 20.0)]
    duration_s: f64,
    /// Seed of the scene, textures and IMU noise.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// The real recordings (../shared/data); skipped when missing.
    #[arg(long, default_value = "../shared/data")]
    real_data: PathBuf,
    /// Print one JSON object instead of the human summary.
    #[arg(long)]
    json: bool,
    /// Skip the live part (rigslamd replaying the sequence, `rigslam echo`
    /// printing its poses).
    #[arg(long)]
    no_daemon: bool,
}

/// The live part: the daemon's poses as a subscriber received them.
#[derive(Serialize)]
struct LiveReport {
    frames: u64,
    poses_received: u64,
    poses_missed: u64,
    /// Frame arrival to `rigslam/pose` published, in the daemon.
    frame_to_pose_p50_ms: f64,
    frame_to_pose_p99_ms: f64,
    /// `rigslam/pose` send to the subscriber's receive.
    transport_p50_us: f64,
    transport_p99_us: f64,
    cpu_per_wall_s: f64,
    /// The map-frame poses (both stages) against the ground truth.
    eval: Option<rigslam::eval::EvalReport>,
    /// The odometry-frame poses of the same messages (the relative stage
    /// alone, which a map correction never moves).
    eval_odom: Option<rigslam::eval::EvalReport>,
}

#[derive(Serialize)]
struct DemoReport {
    dataset: PathBuf,
    simulation: SimReport,
    simulate_s: f64,
    live: Option<LiveReport>,
    runs: Vec<RunReport>,
}

pub fn run(args: DemoArgs) -> anyhow::Result<()> {
    if !(args.duration_s.is_finite() && args.duration_s >= 3.0) {
        bail!("--duration-s must be at least 3 s, got {}", args.duration_s);
    }
    let dataset_dir = args.out.join("sequence");
    if dataset_dir.exists() {
        std::fs::remove_dir_all(&dataset_dir)
            .with_context(|| format!("cannot clear {}", dataset_dir.display()))?;
    }
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("cannot create {}", args.out.display()))?;
    let config = SimConfig {
        duration_s: Some(args.duration_s),
        seed: args.seed,
        stereo: true,
        show_progress: !args.json,
        ..SimConfig::default()
    };
    let started = Instant::now();
    let simulation = simulate(&config, &dataset_dir).context("simulating the demo sequence")?;
    let simulate_s = started.elapsed().as_secs_f64();
    if !args.json {
        println!(
            "rigslam demo: rendered {} stereo frames ({:.0} s, {:.1} m path) with EuRoC's calibration and IMU noise in {:.1} s",
            simulation.frames, simulation.duration_s, simulation.path_length_m, simulate_s
        );
    }

    let live = if args.no_daemon {
        None
    } else {
        let live = live_daemon(&dataset_dir, &args.out, args.json)
            .context("the live part (rigslamd + rigslam echo); --no-daemon skips it")?;
        if !args.json {
            println!("  live: {}", live_line(&live));
        }
        Some(live)
    };

    let mut jobs: Vec<(String, PathBuf, SensorMode)> = vec![
        (
            "synthetic".into(),
            dataset_dir.clone(),
            SensorMode::StereoInertial,
        ),
        (
            "synthetic".into(),
            dataset_dir.clone(),
            SensorMode::MonoInertial,
        ),
    ];
    let euroc = args.real_data.join("euroc/V1_01_micro");
    let kitti = args.real_data.join("kitti/seq_a");
    if euroc.is_dir() {
        jobs.push((
            "real EuRoC V1_01, at rest".into(),
            euroc,
            SensorMode::StereoInertial,
        ));
    }
    if kitti.is_dir() {
        jobs.push(("real KITTI seq_a".into(), kitti, SensorMode::Mono));
    }
    if jobs.len() == 2 && !args.json {
        println!(
            "({} is missing: the real recordings are skipped)",
            args.real_data.display()
        );
    }
    let mut runs = Vec::new();
    for (label, dir, mode) in jobs {
        let run = DatasetRun {
            mode: Some(mode),
            ..DatasetRun::default()
        };
        let result = run_dataset(&dir, &run, |_, _| {})
            .with_context(|| format!("running {mode} on {}", dir.display()))?;
        let stem = format!(
            "{}_{}",
            label.split_whitespace().next().unwrap_or("run"),
            mode
        );
        write_tum(
            &args.out.join(format!("{stem}.tum")),
            &result.outcome.trajectory,
        )?;
        if let Some(e) = &result.evaluation {
            write_plot(&args.out.join(format!("{stem}.png")), e)?;
        }
        if !args.json {
            println!("  {label}: {}", summary_line(&result.report));
        }
        runs.push(result.report);
    }
    let report = DemoReport {
        dataset: dataset_dir,
        simulation,
        simulate_s,
        live,
        runs,
    };
    if args.json {
        println!("{}", serde_json::to_string(&report)?);
    } else {
        print_footer(&args.out);
    }
    Ok(())
}

fn print_footer(out: &Path) {
    println!(
        "trajectories (TUM) and plots in {}; `rigslam run --help` runs any EuRoC or KITTI folder",
        out.display()
    );
}

/// Replays `dataset` through `rigslamd` at its recorded pace (stereo with
/// the IMU) on a private iceoryx2 root under `out`, with `rigslam echo`
/// subscribed to its poses (every 10th printed unless `quiet`), then
/// scores the poses echo received against the ground truth.
fn live_daemon(dataset: &Path, out: &Path, quiet: bool) -> anyhow::Result<LiveReport> {
    use std::process::{Command, Stdio};
    let me = std::env::current_exe().context("finding the rigslam binary")?;
    let rigslamd = me.with_file_name("rigslamd");
    if !rigslamd.is_file() {
        bail!(
            "{} is missing: build it (cargo build --release --bin rigslamd)",
            rigslamd.display()
        );
    }
    let out = out
        .canonicalize()
        .with_context(|| format!("cannot resolve {}", out.display()))?;
    let root = out.join("iceoryx2");
    std::fs::create_dir_all(&root).with_context(|| format!("cannot create {}", root.display()))?;
    let prefix = format!("rigslam_demo_{}", std::process::id());
    let tum = out.join("live_stereo-inertial.tum");
    let tum_odom = out.join("live_stereo-inertial_odom.tum");
    let report_path = out.join("live_rigslamd.json");
    let echo_path = out.join("live_echo.json");
    let log_path = out.join("live_rigslamd.log");
    let frames = match rigslam::dataset::open_dataset(dataset)? {
        rigslam::dataset::Dataset::Euroc(d) => d.cameras.first().map_or(0, |c| c.frames.len()),
        _ => bail!("{} is not a EuRoC folder", dataset.display()),
    };
    if !quiet {
        println!(
            "rigslamd --replay {} (recorded pace, {frames} frames) publishing on {prefix}/pose; rigslam echo (every 10th pose):",
            dataset.display()
        );
    }
    // The subscriber first, so that it sees the first pose: the daemon
    // starts once echo says it is subscribed.
    let ready_path = out.join("live_echo.ready");
    let _ = std::fs::remove_file(&ready_path);
    let mut echo = Command::new(&me)
        .arg("echo")
        .args(["--service", &format!("{prefix}/pose")])
        .args(["--count", &frames.to_string(), "--timeout-s", "10"])
        .args(["--every", "10", "--tum"])
        .arg(&tum)
        .arg("--tum-odom")
        .arg(&tum_odom)
        .arg("--report")
        .arg(&echo_path)
        .arg("--ready-file")
        .arg(&ready_path)
        .arg("--root-path")
        .arg(&root)
        .stdout(if quiet {
            Stdio::null()
        } else {
            Stdio::inherit()
        })
        .spawn()
        .context("starting rigslam echo")?;
    let waiting = std::time::Instant::now();
    while !ready_path.exists() {
        if let Some(status) = echo.try_wait().context("waiting for rigslam echo")? {
            bail!("rigslam echo stopped before subscribing ({status})");
        }
        if waiting.elapsed() > std::time::Duration::from_secs(30) {
            let _ = echo.kill();
            let _ = echo.wait();
            bail!("rigslam echo did not subscribe within 30 s");
        }
        std::thread::sleep(std::time::Duration::from_millis(10));
    }
    let log = std::fs::File::create(&log_path)
        .with_context(|| format!("cannot create {}", log_path.display()))?;
    let daemon = Command::new(&rigslamd)
        .arg("--replay")
        .arg(dataset)
        .args(["--mode", "stereo-inertial", "--service-prefix", &prefix])
        .arg("--root-path")
        .arg(&root)
        .arg("--report")
        .arg(&report_path)
        .stdout(Stdio::null())
        .stderr(log)
        .status();
    let daemon = match daemon {
        Ok(status) => status,
        Err(e) => {
            let _ = echo.kill();
            let _ = echo.wait();
            return Err(e).context("running rigslamd");
        }
    };
    if !daemon.success() {
        let _ = echo.kill();
        let _ = echo.wait();
        bail!(
            "rigslamd failed ({daemon}); its log: {}",
            log_path.display()
        );
    }
    let echoed = echo.wait().context("waiting for rigslam echo")?;
    if !echoed.success() {
        bail!("rigslam echo failed ({echoed})");
    }
    let read_json = |path: &Path| -> anyhow::Result<serde_json::Value> {
        let text =
            std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
        serde_json::from_str(&text).with_context(|| format!("parsing {}", path.display()))
    };
    let report = read_json(&report_path)?;
    let echoed = read_json(&echo_path)?;
    let number = |v: &serde_json::Value, key: &str| v[key].as_f64().unwrap_or(f64::NAN);
    let ground_truth = match rigslam::dataset::open_dataset(dataset)? {
        rigslam::dataset::Dataset::Euroc(d) => d
            .groundtruth
            .as_deref()
            .map(rigslam::dataset::groundtruth_trajectory),
        _ => None,
    };
    let score = |path: &Path| -> anyhow::Result<Option<rigslam::eval::EvalReport>> {
        let estimate = rigslam::dataset::read_tum(path)?;
        Ok(match &ground_truth {
            Some(gt) if estimate.len() >= 3 => Some(
                rigslam::eval::evaluate(
                    &estimate,
                    gt,
                    &rigslam::eval::EvalOptions {
                        alignment: rigslam::eval::Alignment::Se3,
                        ..Default::default()
                    },
                )?
                .report,
            ),
            _ => None,
        })
    };
    let eval = score(&tum)?;
    let eval_odom = score(&tum_odom)?;
    Ok(LiveReport {
        frames: report["frames"].as_u64().unwrap_or(0),
        poses_received: echoed["received"].as_u64().unwrap_or(0),
        poses_missed: echoed["missed"].as_u64().unwrap_or(0),
        frame_to_pose_p50_ms: number(&report, "latency_p50_us") * 1e-3,
        frame_to_pose_p99_ms: number(&report, "latency_p99_us") * 1e-3,
        transport_p50_us: number(&echoed, "transport_latency_p50_us"),
        transport_p99_us: number(&echoed, "transport_latency_p99_us"),
        cpu_per_wall_s: number(&report, "cpu_per_wall_s"),
        eval,
        eval_odom,
    })
}

/// One line on the live part, e.g. `rigslamd replay, stereo-inertial: 401
/// frames, 401 poses received by rigslam echo (0 missed); frame to pose
/// ...; ATE (se3) map frame 0.009 m, odometry frame 0.011 m over 380
/// tracked poses, final drift ...`.
fn live_line(r: &LiveReport) -> String {
    let mut line = format!(
        "rigslamd replay, stereo-inertial: {} frames, {} poses received by rigslam echo ({} missed); frame to pose p50 {:.1} ms p99 {:.1} ms, publish to receive p50 {:.0} us p99 {:.0} us; daemon CPU {:.2} s per s",
        r.frames,
        r.poses_received,
        r.poses_missed,
        r.frame_to_pose_p50_ms,
        r.frame_to_pose_p99_ms,
        r.transport_p50_us,
        r.transport_p99_us,
        r.cpu_per_wall_s
    );
    if let Some(e) = &r.eval {
        let odom = r
            .eval_odom
            .as_ref()
            .map(|o| format!(", odometry frame {:.3} m", o.ate_rmse_m))
            .unwrap_or_default();
        line += &format!(
            "; ATE ({}) map frame {:.3} m{odom} over {} tracked poses",
            e.align.name(),
            e.ate_rmse_m,
            e.matched_poses
        );
        if let Some(d) = e.final_drift_pct {
            line += &format!(", final drift {d:.2} % of {:.1} m", e.path_length_m);
        }
    }
    line
}
