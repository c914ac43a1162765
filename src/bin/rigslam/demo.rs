//! `rigslam demo`: the README's first command. Renders a synthetic EuRoC
//! sequence, reads it back through the dataset reader, runs the pipeline
//! that exists today on it and scores the result with the evaluation, then
//! does the same on a real recording when ../shared/data is beside the
//! repository. Every number printed is measured; nothing is faked.
//!
//! The pipeline today is inertial dead reckoning (RK4 strapdown) from the
//! first ground-truth state with the biases held at their first true
//! values: the inertial half of the relative stage. The vision stages
//! (front end, window, edge map) join as their issues land.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{bail, Context};
use nalgebra::Vector3;
use serde::Serialize;

use rigslam::dataset::{
    groundtruth_trajectory, read_euroc_groundtruth, read_euroc_imu_csv, write_tum, EurocDataset,
    GroundTruthState,
};
use rigslam::eval::{evaluate, Alignment, EvalOptions, EvalReport};
use rigslam::imu::{integrate, ImuBiases, NavState};
use rigslam::sensors::ImuSample;
use rigslam::simulate::{simulate, SimConfig, SimReport};
use rigslam::trajectory::{StampedPose, Trajectory};

#[derive(clap::Args)]
pub struct DemoArgs {
    /// Folder for the generated dataset, the estimate and the plots.
    #[arg(long, default_value = "out/demo")]
    out: PathBuf,
    /// Length of the generated sequence, s.
    #[arg(long, default_value_t = 10.0)]
    duration_s: f64,
    /// Seed of the scene, textures and IMU noise.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Render the right camera too.
    #[arg(long)]
    stereo: bool,
    /// Real recording to run on as well (EuRoC imu0 csv + ground-truth csv);
    /// skipped when missing.
    #[arg(long, default_value = "../shared/data/euroc/ground_truth")]
    real_data: PathBuf,
    /// Seconds of the real recording to dead-reckon (from 5 s after its start).
    #[arg(long, default_value_t = 10.0)]
    real_duration_s: f64,
    /// Print one JSON object instead of the human summary.
    #[arg(long)]
    json: bool,
}

#[derive(Serialize)]
struct StageTimes {
    simulate_s: f64,
    read_back_s: f64,
    images_read: usize,
    read_ms_per_image: f64,
    dead_reckoning_ms: f64,
    eval_ms: f64,
}

#[derive(Serialize)]
struct DemoReport {
    pipeline: &'static str,
    dataset: PathBuf,
    simulation: SimReport,
    synthetic: EvalReport,
    times: StageTimes,
    real: Option<RealReport>,
}

#[derive(Serialize)]
struct RealReport {
    sequence: &'static str,
    duration_s: f64,
    imu_samples: usize,
    dead_reckoning_ms: f64,
    eval: EvalReport,
}

pub fn run(args: DemoArgs) -> anyhow::Result<()> {
    if !(args.duration_s.is_finite() && args.duration_s >= 1.0) {
        bail!("--duration-s must be at least 1 s, got {}", args.duration_s);
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
        stereo: args.stereo,
        show_progress: !args.json,
        ..SimConfig::default()
    };
    let started = Instant::now();
    let simulation = simulate(&config, &dataset_dir).context("simulating the demo sequence")?;
    let simulate_s = started.elapsed().as_secs_f64();

    // Read everything back through the same reader a recorded sequence uses.
    let started = Instant::now();
    let dataset =
        EurocDataset::open(&dataset_dir).context("reading the generated sequence back")?;
    let mut images_read = 0;
    for camera in &dataset.cameras {
        for index in 0..camera.frames.len() {
            if camera.load(index)?.is_some() {
                images_read += 1;
            }
        }
    }
    let read_back_s = started.elapsed().as_secs_f64();
    if images_read != simulation.images {
        bail!(
            "wrote {} images but read back {images_read}",
            simulation.images
        );
    }
    let imu = dataset
        .imu
        .as_ref()
        .context("the generated sequence has no imu0")?;
    let groundtruth = dataset
        .groundtruth
        .as_ref()
        .context("the generated sequence has no ground truth")?;

    let started = Instant::now();
    let estimate = dead_reckon(groundtruth, &imu.samples)?;
    let dead_reckoning_ms = started.elapsed().as_secs_f64() * 1e3;
    write_tum(&args.out.join("estimate.tum"), &estimate)?;

    let started = Instant::now();
    let options = EvalOptions {
        alignment: Alignment::None,
        ..EvalOptions::default()
    };
    let synthetic = evaluate(&estimate, &groundtruth_trajectory(groundtruth), &options)?;
    let eval_ms = started.elapsed().as_secs_f64() * 1e3;
    let plot = args.out.join("synthetic.png");
    rigslam::eval::plot::write_plot(&plot, &synthetic)?;

    let real = match real_recording(&args.real_data) {
        Some((imu_csv, gt_csv)) => Some(run_real(
            &imu_csv,
            &gt_csv,
            args.real_duration_s,
            &args.out,
        )?),
        None => {
            if !args.json {
                eprintln!(
                    "(no real recording at {}: skipping that part)",
                    args.real_data.display()
                );
            }
            None
        }
    };

    let report = DemoReport {
        pipeline: "inertial dead reckoning (RK4 strapdown from the first true state, biases held at their first true values)",
        dataset: dataset_dir,
        simulation,
        synthetic: synthetic.report,
        times: StageTimes {
            simulate_s,
            read_back_s,
            images_read,
            read_ms_per_image: read_back_s * 1e3 / images_read.max(1) as f64,
            dead_reckoning_ms,
            eval_ms,
        },
        real,
    };
    if args.json {
        println!("{}", serde_json::to_string(&report)?);
    } else {
        print_summary(&report, &args.out);
    }
    Ok(())
}

fn print_summary(r: &DemoReport, out: &Path) {
    let s = &r.simulation;
    println!("rigslam demo: pipeline = {}", r.pipeline);
    println!(
        "  simulate   {} frames x {} camera(s) of 752x480, {} IMU samples, {:.1} m path in a {:.1}x{:.1}x{:.1} m room",
        s.frames,
        s.images / s.frames.max(1),
        s.imu_samples,
        s.path_length_m,
        s.room_size_m[0],
        s.room_size_m[1],
        s.room_size_m[2]
    );
    println!(
        "             render {:.1} frames/s on one thread (ray casting only), {:.1} frames/s with PNG writing; {:.2} s total",
        s.render_fps, s.render_write_fps, r.times.simulate_s
    );
    println!(
        "  read back  {} images through the EuRoC reader, {:.2} ms/image",
        r.times.images_read, r.times.read_ms_per_image
    );
    let e = &r.synthetic;
    println!(
        "  synthetic  dead reckoning {:.1} ms for {:.1} s: ATE rmse {:.3} m, max {:.3} m, final drift {} of {:.1} m ({} poses, no alignment)",
        r.times.dead_reckoning_ms,
        e.duration_s,
        e.ate_rmse_m,
        e.ate_max_m,
        e.final_drift_pct.map_or("n/a".to_string(), |d| format!("{d:.2} %")),
        e.path_length_m,
        e.matched_poses
    );
    if let Some(real) = &r.real {
        let e = &real.eval;
        println!(
            "  real       {} ({} IMU samples, {:.1} s) dead reckoning {:.1} ms: ATE rmse {:.3} m, max {:.3} m, final drift {} of {:.1} m",
            real.sequence,
            real.imu_samples,
            real.duration_s,
            real.dead_reckoning_ms,
            e.ate_rmse_m,
            e.ate_max_m,
            e.final_drift_pct.map_or("n/a".to_string(), |d| format!("{d:.2} %")),
            e.path_length_m
        );
    }
    println!(
        "  wrote {} (dataset), {} and {}",
        r.dataset.display(),
        out.join("estimate.tum").display(),
        out.join("synthetic.png").display()
    );
}

/// The real V1_02 IMU and its ground truth, when ../shared/data is there.
fn real_recording(dir: &Path) -> Option<(PathBuf, PathBuf)> {
    let imu = dir.join("V1_02_imu0.csv");
    let gt = dir.join("V1_02_groundtruth.csv");
    (imu.is_file() && gt.is_file()).then_some((imu, gt))
}

fn run_real(
    imu_csv: &Path,
    gt_csv: &Path,
    duration_s: f64,
    out: &Path,
) -> anyhow::Result<RealReport> {
    let imu = read_euroc_imu_csv(imu_csv)?;
    let groundtruth = read_euroc_groundtruth(gt_csv)?;
    let Some(first) = groundtruth.first() else {
        bail!("{}: no ground truth", gt_csv.display())
    };
    // Skip the first 5 s (the vehicle idles on the ground) and keep `duration_s`.
    let start_ns = first.t_ns + 5_000_000_000;
    let end_ns = start_ns + (duration_s * 1e9) as i64;
    let window: Vec<GroundTruthState> = groundtruth
        .iter()
        .filter(|s| s.t_ns >= start_ns && s.t_ns <= end_ns)
        .cloned()
        .collect();
    if window.len() < 2 {
        bail!(
            "{}: no ground truth between {start_ns} and {end_ns} ns",
            gt_csv.display()
        );
    }
    let samples: Vec<ImuSample> = imu
        .samples
        .iter()
        .filter(|s| s.t_ns >= start_ns - 10_000_000 && s.t_ns <= end_ns + 10_000_000)
        .copied()
        .collect();
    let started = Instant::now();
    let estimate = dead_reckon(&window, &samples)?;
    let dead_reckoning_ms = started.elapsed().as_secs_f64() * 1e3;
    write_tum(&out.join("real_v1_02_estimate.tum"), &estimate)?;
    let options = EvalOptions {
        alignment: Alignment::None,
        ..EvalOptions::default()
    };
    let evaluation = evaluate(&estimate, &groundtruth_trajectory(&window), &options)?;
    rigslam::eval::plot::write_plot(&out.join("real_v1_02.png"), &evaluation)?;
    Ok(RealReport {
        sequence: "EuRoC V1_02_medium (real ADIS16448 IMU, Vicon ground truth)",
        duration_s: (window[window.len() - 1].t_ns - window[0].t_ns) as f64 * 1e-9,
        imu_samples: samples.len(),
        dead_reckoning_ms,
        eval: evaluation.report,
    })
}

/// Integrates the IMU from the first ground-truth state and returns the
/// estimated body pose at every later ground-truth stamp.
fn dead_reckon(
    groundtruth: &[GroundTruthState],
    samples: &[ImuSample],
) -> anyhow::Result<Trajectory> {
    let first = groundtruth.first().context("empty ground truth")?;
    let last = groundtruth.last().context("empty ground truth")?;
    // Start exactly at the first true state: interpolate a sample there.
    let after = samples.partition_point(|s| s.t_ns <= first.t_ns);
    if after == 0 || after >= samples.len() {
        bail!(
            "the IMU does not cover the first ground-truth stamp {} ns",
            first.t_ns
        );
    }
    let mut run = vec![interpolate_sample(
        &samples[after - 1],
        &samples[after],
        first.t_ns,
    )];
    run.extend(
        samples[after..]
            .iter()
            .take_while(|s| s.t_ns <= last.t_ns + 10_000_000)
            .copied(),
    );

    let initial = NavState {
        t_ns: first.t_ns,
        R_world_body: first.T_world_body.rotation,
        position_world_m: first.T_world_body.translation.vector,
        velocity_world_m_s: first.velocity_m_s,
    };
    let biases = ImuBiases {
        gyro_rad_s: first.gyro_bias_rad_s,
        accel_m_s2: first.accel_bias_m_s2,
    };
    let states = integrate(&initial, &run, &biases)?;

    let mut poses = Vec::with_capacity(groundtruth.len());
    for gt in groundtruth {
        let i = states.partition_point(|s| s.t_ns < gt.t_ns);
        if i >= states.len() {
            break;
        }
        let pose = if states[i].t_ns == gt.t_ns || i == 0 {
            nav_pose(&states[i], gt.t_ns)
        } else {
            let (a, b) = (&states[i - 1], &states[i]);
            let w = (gt.t_ns - a.t_ns) as f64 / (b.t_ns - a.t_ns) as f64;
            let position: Vector3<f64> = a.position_world_m.lerp(&b.position_world_m, w);
            StampedPose::new(gt.t_ns, position, a.R_world_body.slerp(&b.R_world_body, w))
        };
        poses.push(pose);
    }
    Ok(Trajectory::new(poses))
}

fn nav_pose(state: &NavState, t_ns: i64) -> StampedPose {
    StampedPose::new(t_ns, state.position_world_m, state.R_world_body)
}

fn interpolate_sample(a: &ImuSample, b: &ImuSample, t_ns: i64) -> ImuSample {
    let w = (t_ns - a.t_ns) as f64 / (b.t_ns - a.t_ns) as f64;
    let mix = |x: [f64; 3], y: [f64; 3]| [0, 1, 2].map(|k| x[k] + w * (y[k] - x[k]));
    ImuSample {
        t_ns,
        gyro_rad_s: mix(a.gyro_rad_s, b.gyro_rad_s),
        accel_m_s2: mix(a.accel_m_s2, b.accel_m_s2),
    }
}
