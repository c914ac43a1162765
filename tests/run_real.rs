//! `rigslam run` end to end on the real recordings in ../shared/data:
//! EuRoC V1_01 at rest (static start, drift) and KITTI seq_a (mono, the
//! paper's configuration 1), plus the report's contract keys.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

#[path = "common/time_shift.rs"]
mod time_shift;
use time_shift::with_time_shift;

fn shared(relative: &str) -> Option<PathBuf> {
    rigslam::shared_data::path_or_skip(relative)
}

/// `rigslam run --quiet` with more arguments to come.
fn rigslam_run() -> Command {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_rigslam"));
    cmd.args(["run", "--quiet"]);
    cmd
}

/// `rigslam run` of both stages in stereo-inertial on `root`, the report
/// as JSON on stdout.
fn two_stages_json(root: &Path) -> Command {
    let mut cmd = rigslam_run();
    cmd.args([
        "--json",
        "--absolute",
        "--mode",
        "stereo-inertial",
        "--dataset",
    ])
    .arg(root);
    cmd
}

/// Runs `cmd`, which must succeed; its output.
fn succeeds(cmd: &mut Command) -> Output {
    let out = cmd.output().expect("run rigslam");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    out
}

/// Runs `cmd`, which must fail; what it printed on stderr.
fn fails(cmd: &mut Command) -> String {
    let out = cmd.output().expect("run rigslam");
    assert!(!out.status.success());
    String::from_utf8_lossy(&out.stderr).into_owned()
}

/// The poses of a TUM file.
fn read_poses(path: &Path) -> Vec<[f64; 8]> {
    std::fs::read_to_string(path)
        .expect("trajectory")
        .lines()
        .filter(|l| !l.starts_with('#') && !l.trim().is_empty())
        .map(|l| {
            let v: Vec<f64> = l
                .split_whitespace()
                .map(|x| x.parse().expect("number"))
                .collect();
            v.try_into().expect("8 fields")
        })
        .collect()
}

fn run(dataset: &Path, mode: &str, dir: &Path) -> (serde_json::Value, Vec<[f64; 8]>) {
    let tum = dir.join(format!("{mode}.tum"));
    let report = dir.join(format!("{mode}.json"));
    let out = succeeds(
        rigslam_run()
            .args(["--mode", mode, "--dataset"])
            .arg(dataset)
            .arg("--trajectory")
            .arg(&tum)
            .arg("--report")
            .arg(&report),
    );
    let summary = String::from_utf8_lossy(&out.stdout);
    assert!(
        summary.contains(mode) && summary.contains("ms/frame"),
        "{summary}"
    );
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&report).expect("report")).expect("json");
    (report, read_poses(&tum))
}

fn largest_displacement_m(poses: &[[f64; 8]]) -> f64 {
    let p0 = &poses[0];
    poses
        .iter()
        .map(|p| ((p[1] - p0[1]).powi(2) + (p[2] - p0[2]).powi(2) + (p[3] - p0[3]).powi(2)).sqrt())
        .fold(0.0, f64::max)
}

#[test]
fn euroc_at_rest_initialises_from_the_static_start_and_stays_within_a_centimetre() {
    let Some(root) = shared("euroc/V1_01_micro") else {
        return;
    };
    let dir = tempfile::tempdir().expect("tempdir");
    for mode in ["stereo-inertial", "mono-inertial"] {
        let (report, poses) = run(&root, mode, dir.path());
        // The IMU starts with the camera: the detector needs 0.4 s of it.
        let init = report["initialized_at_s"].as_f64().expect("initialised");
        assert!(init <= 0.5, "{mode}: initialised at {init} s");
        assert!(report["counters"]["static_frames"].as_u64().expect("count") > 0);
        assert_eq!(report["lost_count"], 0, "{mode}");
        assert!(poses.len() >= 85, "{mode}: {} poses", poses.len());
        assert!(poses.iter().all(|p| p.iter().all(|v| v.is_finite())));
        // The vehicle moved 2 mm in these 4.7 s (ground truth).
        let moved = largest_displacement_m(&poses);
        assert!(moved < 0.01, "{mode}: drifted {moved} m at rest");
        // Metric modes check their covariance against the truth.
        assert!(
            report["nees"]["poses"].as_u64().is_some_and(|n| n > 0),
            "{mode}: {}",
            report["nees"]
        );
        // Without a second stage there is no map-frame position to score.
        assert!(
            report["map_nees"].is_null(),
            "{mode}: {}",
            report["map_nees"]
        );
    }
}

/// `--landmarks` writes what the relative stage hands the absolute stage:
/// one row per landmark and tracked frame, body-frame positions in front
/// of the cameras and covariances that are symmetric positive definite.
#[test]
fn landmarks_are_written_per_frame() {
    let Some(root) = shared("euroc/V1_01_micro") else {
        return;
    };
    let dir = tempfile::tempdir().expect("tempdir");
    let csv = dir.path().join("lm.csv");
    let trajectory = dir.path().join("t.csv");
    succeeds(
        rigslam_run()
            .args(["--mode", "stereo-inertial", "--dataset"])
            .arg(&root)
            .arg("--landmarks")
            .arg(&csv)
            .arg("--trajectory")
            .arg(&trajectory),
    );
    let text = std::fs::read_to_string(&csv).expect("written");
    let mut lines = text.lines();
    assert_eq!(
        lines.next(),
        Some("t_ns,id,x,y,z,c00,c01,c02,c11,c12,c22,keyframes")
    );
    let stamps: std::collections::HashSet<i64> = std::fs::read_to_string(&trajectory)
        .expect("trajectory")
        .lines()
        .filter(|l| !l.starts_with('#'))
        .filter_map(|l| l.split(',').next()?.parse().ok())
        .collect();
    let mut rows = 0;
    let mut frames = std::collections::HashSet::new();
    for line in lines {
        let v: Vec<f64> = line
            .split(',')
            .map(|f| f.parse().expect("number"))
            .collect();
        assert_eq!(v.len(), 12, "{line}");
        let t_ns: i64 = line
            .split(',')
            .next()
            .and_then(|f| f.parse().ok())
            .expect("stamp");
        assert!(
            stamps.contains(&t_ns),
            "{t_ns} is not a frame of the trajectory"
        );
        frames.insert(t_ns);
        let (x, y, z) = (v[2], v[3], v[4]);
        assert!(x.is_finite() && y.is_finite() && z.is_finite(), "{line}");
        assert!((x * x + y * y + z * z).sqrt() < 100.0, "{line}");
        let c = nalgebra::Matrix3::new(v[5], v[6], v[7], v[6], v[8], v[9], v[7], v[9], v[10]);
        assert!(
            c.cholesky().is_some(),
            "covariance not positive definite: {line}"
        );
        assert!(
            v[11] >= 1.0,
            "a window estimate rests on a keyframe: {line}"
        );
        rows += 1;
    }
    // At rest few frames hand landmarks on (8 of these 95).
    assert!(frames.len() >= 5, "{} frames with landmarks", frames.len());
    assert!(
        rows >= 20 * frames.len(),
        "{rows} rows over {} frames",
        frames.len()
    );
    let err = fails(
        rigslam_run()
            .args(["--mode", "stereo", "--max-frames", "2", "--dataset"])
            .arg(&root)
            .arg("--landmarks")
            .arg(dir.path().join("missing/lm.csv")),
    );
    assert!(err.contains("landmarks file"), "{err}");
}

/// A camera whose clock runs 7 ms behind the IMU's (Kalibr's
/// `timeshift_cam_imu: 0.007`, as a calibration of a real rig may say):
/// every frame is preintegrated up to its instant on the IMU clock, 7 ms
/// after its stamp. The reader used to hand over a frame with the IMU up
/// to its stamp and one sample (5 ms) past, so each frame's interval was
/// short of samples and the inertial modes ran without the IMU after
/// their start, silently.
#[test]
fn a_camera_behind_the_imu_clock_still_gets_its_imu() {
    let Some(root) = shared("euroc/V1_01_micro") else {
        return;
    };
    let dir = tempfile::tempdir().expect("tempdir");
    let copy = with_time_shift(&root, dir.path(), 0.007);
    for mode in ["stereo-inertial", "mono-inertial"] {
        let (report, poses) = run(&copy, mode, dir.path());
        assert!(report["initialized_at_s"].as_f64().is_some(), "{mode}");
        assert!(poses.len() >= 85, "{mode}: {} poses", poses.len());
        assert_eq!(
            report["counters"]["frames_without_imu"], 0,
            "{mode}: {}",
            report["counters"]
        );
    }
    // Had any frame gone without the IMU, the summary says so: here the
    // IMU stops 1 s before the camera.
    let dropped = tempfile::tempdir().expect("tempdir");
    let imu = std::fs::read_to_string(root.join("mav0/imu0/data.csv")).expect("imu csv");
    let frames = std::fs::read_to_string(root.join("mav0/cam0/data.csv")).expect("cam0 csv");
    let stamp = |l: &str| l.split(',').next().and_then(|t| t.parse::<i64>().ok());
    let last_frame_ns = frames.lines().filter_map(stamp).max().expect("frames");
    let kept: Vec<&str> = imu
        .lines()
        .filter(|l| stamp(l).map_or(true, |t| t <= last_frame_ns - 1_000_000_000))
        .collect();
    let gap = dropped.path().join("gap");
    std::fs::create_dir_all(gap.join("mav0/imu0")).expect("mkdir");
    std::fs::write(gap.join("mav0/imu0/data.csv"), kept.join("\n") + "\n").expect("write");
    std::fs::copy(
        root.join("mav0/imu0/sensor.yaml"),
        gap.join("mav0/imu0/sensor.yaml"),
    )
    .expect("copy");
    for link in ["mav0/cam0", "mav0/cam1", "mav0/state_groundtruth_estimate0"] {
        std::os::unix::fs::symlink(root.join(link), gap.join(link)).expect("link");
    }
    let out = succeeds(
        rigslam_run()
            .args(["--mode", "stereo-inertial", "--dataset"])
            .arg(&gap),
    );
    let summary = String::from_utf8_lossy(&out.stdout);
    assert!(
        summary.contains("frames without the IMU (it did not reach their instant"),
        "{summary}"
    );
}

#[test]
fn run_report_has_the_contract_keys() {
    let Some(root) = shared("euroc/V1_01_micro") else {
        return;
    };
    let dir = tempfile::tempdir().expect("tempdir");
    let (report, _) = run(&root, "stereo", dir.path());
    for key in [
        "frames",
        "wall_s",
        "mean_ms_per_frame",
        "p99_ms_per_frame",
        "stages",
        "mode",
        "initialized_at_s",
        "lost_count",
    ] {
        assert!(report.get(key).is_some(), "missing {key}: {report}");
    }
    assert_eq!(report["frames"], 95);
    assert_eq!(report["mode"], "stereo");
    for stage in ["track", "pose", "window"] {
        let s = &report["stages"][stage];
        let (mean, p50, p99) = (
            s["mean_ms"].as_f64().expect("mean"),
            s["p50_ms"].as_f64().expect("p50"),
            s["p99_ms"].as_f64().expect("p99"),
        );
        assert!(mean > 0.0 && p50 <= p99, "{stage}: {s}");
    }
    // Stereo from the first frame: metric at once.
    assert_eq!(report["initialized_at_s"].as_f64(), Some(0.0));
}

#[test]
fn kitti_mono_meets_the_papers_configuration_1_bar() {
    let Some(root) = shared("kitti/seq_a") else {
        return;
    };
    let dir = tempfile::tempdir().expect("tempdir");
    let (report, poses) = run(&root, "mono", dir.path());
    assert!(poses.len() >= 45, "{} poses of 51 frames", poses.len());
    let eval = &report["eval"];
    assert_eq!(eval["align"], "sim3");
    assert_eq!(eval["scale_by_path"], true);
    // The paper's eq. 72 with the scale from the path length: <= 2 %.
    let drift = eval["final_drift_pct"].as_f64().expect("final drift");
    assert!(drift <= 2.0, "final drift {drift} %");
    let ate = eval["ate_rmse_m"].as_f64().expect("ate");
    assert!(ate < 0.5, "ATE {ate} m");
    // Without metric scale there is no covariance to check against metric
    // truth: no NEES (it printed 1.6e9 per dof before).
    assert!(report["nees"].is_null(), "mono NEES: {}", report["nees"]);
}

#[test]
fn bad_requests_say_what_is_wrong() {
    let Some(root) = shared("kitti/seq_a") else {
        return;
    };
    let err = fails(
        rigslam_run()
            .args(["--mode", "stereo-inertial", "--dataset"])
            .arg(&root),
    );
    assert!(err.contains("needs 2 camera"), "{err}");
    let err = fails(rigslam_run().args(["--dataset", "/nonexistent/rigslam"]));
    assert!(err.contains("/nonexistent/rigslam"), "{err}");
    let dir = tempfile::tempdir().expect("tempdir");
    let config = dir.path().join("bad.toml");
    std::fs::write(&config, "[relative]\nwindow_free = 0\n").expect("write");
    let err = fails(
        rigslam_run()
            .arg("--dataset")
            .arg(&root)
            .arg("--config")
            .arg(&config),
    );
    assert!(err.contains("window_free"), "{err}");
}

#[test]
fn the_ekf_baseline_runs_the_inertial_modes_and_refuses_the_others() {
    let Some(root) = shared("euroc/V1_01_micro") else {
        return;
    };
    let dir = tempfile::tempdir().expect("tempdir");
    let tum = dir.path().join("ekf.tum");
    let out = succeeds(
        rigslam_run()
            .args([
                "--json",
                "--estimator",
                "ekf",
                "--mode",
                "stereo-inertial",
                "--dataset",
            ])
            .arg(&root)
            .arg("--trajectory")
            .arg(&tum),
    );
    let report: serde_json::Value = serde_json::from_slice(&out.stdout).expect("json");
    assert_eq!(report["estimator"], "ekf");
    assert!(report["initialized_at_s"].as_f64().expect("initialised") <= 0.5);
    let poses = read_poses(&tum);
    assert!(poses.len() >= 85);
    let moved = largest_displacement_m(&poses);
    assert!(
        moved < 0.02,
        "the EKF drifted {moved} m at rest with stereo"
    );
    let err = fails(
        rigslam_run()
            .args(["--estimator", "ekf", "--mode", "stereo", "--dataset"])
            .arg(&root),
    );
    assert!(err.contains("propagates with the IMU"), "{err}");
}

/// A settings file that lets the second stage map the clip: V1_01_micro
/// rests and then barely turns, so the relative stage never knows its
/// accelerometer bias to the default wait's 0.02 m/s^2 and the map would
/// never start (`a_clip_that_never_turns_is_not_mapped_and_says_why`).
fn no_bias_wait(dir: &Path) -> PathBuf {
    let path = dir.join("no_wait.toml");
    std::fs::write(&path, "[absolute]\nwait_accel_bias = \"off\"\n").expect("write");
    path
}

#[test]
fn a_clip_that_never_turns_is_not_mapped_and_says_why() {
    let Some(root) = shared("euroc/V1_01_micro") else {
        return;
    };
    let dir = tempfile::tempdir().expect("tempdir");
    let out = rigslam_run()
        .args(["--absolute", "--mode", "stereo-inertial", "--dataset"])
        .arg(&root)
        .arg("--save-map")
        .arg(dir.path().join("v101.map"))
        .output()
        .expect("run rigslam");
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("no map to save")
            && err.contains("wait_accel_bias = \"off\"")
            && err.contains("turn the rig"),
        "{err}"
    );
    assert!(!dir.path().join("v101.map").exists());
    assert!(err.contains("wait_accel_bias_max_s"), "{err}");

    // With the wait limited to a fifth of a second (on this clip it
    // covers the last nine frames with landmarks) the same clip is mapped, the
    // report counts the wait that ran out, and the log says what it did.
    let limited = dir.path().join("limited.toml");
    std::fs::write(&limited, "[absolute]\nwait_accel_bias_max_s = 0.2\n").expect("write");
    let out = two_stages_json(&root)
        .arg("--save-map")
        .arg(dir.path().join("v101.map"))
        .arg("--config")
        .arg(&limited)
        .output()
        .expect("run rigslam");
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    assert!(dir.path().join("v101.map").exists());
    let report: serde_json::Value = serde_json::from_slice(&out.stdout).expect("json");
    assert_eq!(report["second_stage_bias_waits_given_up"], 1, "{report}");
    assert!(
        err.contains("the accelerometer bias is still not known"),
        "{err}"
    );
}

#[test]
fn absolute_writes_both_trajectories_and_scores_both() {
    let Some(root) = shared("euroc/V1_01_micro") else {
        return;
    };
    let dir = tempfile::tempdir().expect("tempdir");
    let (corrected, relative) = (dir.path().join("abs.tum"), dir.path().join("rel.tum"));
    let out = succeeds(
        two_stages_json(&root)
            .arg("--trajectory")
            .arg(&corrected)
            .arg("--trajectory-relative")
            .arg(&relative)
            .arg("--config")
            .arg(no_bias_wait(dir.path())),
    );
    let report: serde_json::Value = serde_json::from_slice(&out.stdout).expect("json");
    assert_eq!(report["absolute"]["frames"], 95);
    assert!(report["absolute"]["solves"].as_u64().expect("solves") > 0);
    assert!(
        report["stages"]["absolute"]["count"]
            .as_u64()
            .expect("count")
            == 95
    );
    assert_eq!(read_poses(&corrected).len(), read_poses(&relative).len());
    // At rest both stay put.
    for key in ["eval", "eval_relative"] {
        let ate = report[key]["ate_rmse_m"].as_f64().expect("ate");
        assert!(ate < 0.01, "{key}: ATE {ate} m");
    }
    // The map-frame covariance is scored on the poses the filter published
    // (at rest the relative stage hands over landmarks on few frames, and
    // the filter starts with the first).
    let map_nees = &report["map_nees"];
    let scored = map_nees["positions"].as_u64().expect("map NEES positions");
    assert!(scored >= 1 && scored <= 95, "{map_nees}");
    let mean = map_nees["mean_per_dof"].as_f64().expect("mean");
    assert!(mean.is_finite() && mean > 0.0, "{map_nees}");
}

#[test]
fn a_saved_map_is_localised_in_again() {
    let Some(root) = shared("euroc/V1_01_micro") else {
        return;
    };
    let dir = tempfile::tempdir().expect("tempdir");
    let map = dir.path().join("v101.map");
    succeeds(
        rigslam_run()
            .args(["--absolute", "--mode", "stereo-inertial", "--dataset"])
            .arg(&root)
            .arg("--save-map")
            .arg(&map)
            .arg("--config")
            .arg(no_bias_wait(dir.path())),
    );
    let text = std::fs::read_to_string(&map).expect("map written");
    let header = text.lines().next().expect("header");
    let count: usize = header
        .strip_prefix("# rigslam map v3 landmarks ")
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| panic!("header {header}"));
    assert!(count > 50, "{count} landmarks");
    let rows = text.lines().filter(|l| !l.starts_with('#')).count();
    assert_eq!(rows, count);
    assert!(
        text.lines()
            .last()
            .is_some_and(|l| l.starts_with("# crc32 ")),
        "the map ends with its checksum"
    );
    // The stereo-inertial run publishes its attitude covariance: every
    // landmark keeps what its mapping frame's attitude error put in it
    // (21 numbers after the descriptor), for a later run localising in it.
    for row in text.lines().filter(|l| !l.starts_with('#')) {
        assert_eq!(row.split_whitespace().count(), 32, "{row}");
    }
    let localised = dir.path().join("loc.tum");
    let out = succeeds(
        rigslam_run()
            .args(["--json", "--mode", "stereo-inertial", "--dataset"])
            .arg(&root)
            .arg("--load-map")
            .arg(&map)
            .arg("--trajectory")
            .arg(&localised)
            .arg("--config")
            .arg(no_bias_wait(dir.path())),
    );
    let report: serde_json::Value = serde_json::from_slice(&out.stdout).expect("json");
    let stats = &report["localise"];
    assert_eq!(stats["relocalisations"], 1, "{stats}");
    // At rest the relative stage holds its pose without handing over
    // landmarks; the first frame that has them (when it starts tracking
    // them again) must be enough to localise.
    let frames = stats["localised_frames"].as_u64().expect("frames");
    assert!(frames >= 3, "{stats}");
    assert_eq!(stats["corrections"].as_u64(), Some(frames), "{stats}");
    // Every localised pose that went out is in the trajectory. A keyframe's
    // pose goes out before the second stage takes it, so when the
    // relocalisation happens on a keyframe that frame went out unplaced:
    // at most one localised frame per relocalisation is not published.
    let published = read_poses(&localised).len() as u64;
    assert!(
        published <= frames && published + 1 >= frames,
        "{published} poses published, {stats}"
    );
    // The same still scene: the map's frame is the first run's world
    // frame, so the localised poses stay where that run put the robot.
    let ate = report["eval"]["ate_rmse_m"].as_f64().expect("ate");
    assert!(ate < 0.01, "ATE {ate} m");
    // The localiser's covariance is scored on its localised poses.
    let scored = report["map_nees"]["positions"].as_u64().expect("map NEES");
    assert!(scored >= 1 && scored <= frames, "{}", report["map_nees"]);
}

#[test]
fn map_options_that_cannot_work_say_why() {
    let Some(root) = shared("euroc/V1_01_micro") else {
        return;
    };
    let dir = tempfile::tempdir().expect("tempdir");
    let err = fails(
        rigslam_run()
            .arg("--dataset")
            .arg(&root)
            .arg("--save-map")
            .arg(dir.path().join("m.map")),
    );
    assert!(err.contains("--absolute"), "{err}");
    let bad = dir.path().join("bad.map");
    std::fs::write(
        &bad,
        "# rigslam map v1 landmarks 1\n0 1 2 3 nan 0 0 1 0 1 -\n",
    )
    .expect("write");
    let err = fails(
        rigslam_run()
            .arg("--dataset")
            .arg(&root)
            .arg("--load-map")
            .arg(&bad),
    );
    assert!(err.contains("bad.map:2"), "{err}");
}

/// `--trajectory` writes the format its extension names (`.txt` TUM,
/// `.csv` EuRoC, `.kitti` KITTI) and `--trajectory-format` overrides the
/// extension; each file holds the same poses as the TUM one.
#[test]
fn the_trajectory_format_follows_the_extension_or_the_flag() {
    let Some(root) = shared("euroc/V1_01_micro") else {
        return;
    };
    let dir = tempfile::tempdir().expect("tempdir");
    let write = |name: &str, format: Option<&str>| -> PathBuf {
        let path = dir.path().join(name);
        let mut cmd = rigslam_run();
        cmd.args(["--mode", "stereo", "--max-frames", "10", "--dataset"])
            .arg(&root)
            .arg("--trajectory")
            .arg(&path);
        if let Some(format) = format {
            cmd.args(["--trajectory-format", format]);
        }
        succeeds(&mut cmd);
        path
    };
    let close = |a: f64, b: f64| (a - b).abs() < 1e-6;
    let tum = read_poses(&write("poses.txt", None));
    assert_eq!(tum.len(), 10);

    let euroc = std::fs::read_to_string(write("poses.csv", None)).expect("written");
    let mut lines = euroc.lines();
    assert_eq!(
        lines.next(),
        Some("#timestamp [ns],p_RS_R_x [m],p_RS_R_y [m],p_RS_R_z [m],q_RS_w [],q_RS_x [],q_RS_y [],q_RS_z []")
    );
    let rows: Vec<&str> = lines.collect();
    assert_eq!(rows.len(), tum.len(), "{euroc}");
    for (row, p) in rows.iter().zip(&tum) {
        let fields: Vec<&str> = row.split(',').collect();
        assert_eq!(fields.len(), 8, "{row}");
        let t_ns: i64 = fields[0].parse().expect("integer nanoseconds");
        let v: Vec<f64> = fields[1..]
            .iter()
            .map(|x| x.parse().expect("number"))
            .collect();
        // TUM: t x y z qx qy qz qw; EuRoC: x y z qw qx qy qz.
        let tum_as_euroc = [p[1], p[2], p[3], p[7], p[4], p[5], p[6]];
        assert!(close(t_ns as f64 * 1e-9, p[0]), "{row} vs {p:?}");
        assert!(
            v.iter().zip(tum_as_euroc).all(|(&a, b)| close(a, b)),
            "{row} vs {p:?}"
        );
    }

    let kitti_lines_match_tum = |path: PathBuf| {
        let text = std::fs::read_to_string(&path).expect("written");
        let lines: Vec<&str> = text.lines().collect();
        assert_eq!(lines.len(), tum.len(), "{}: {text}", path.display());
        for (line, p) in lines.iter().zip(&tum) {
            let v: Vec<f64> = line
                .split_whitespace()
                .map(|x| x.parse().expect("number"))
                .collect();
            assert_eq!(v.len(), 12, "{line}");
            let q = nalgebra::UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(
                p[7], p[4], p[5], p[6],
            ));
            let r = q.to_rotation_matrix();
            for row in 0..3 {
                for col in 0..3 {
                    assert!(close(v[4 * row + col], r[(row, col)]), "{line} vs {p:?}");
                }
                assert!(close(v[4 * row + 3], p[1 + row]), "{line} vs {p:?}");
            }
        }
    };
    kitti_lines_match_tum(write("poses.kitti", None));
    // The flag wins over the extension.
    kitti_lines_match_tum(write("forced.csv", Some("kitti")));
}

/// A pseudo-terminal: (the side we read, the side the child writes to).
fn pseudo_terminal() -> (std::fs::File, std::os::fd::OwnedFd) {
    use std::os::fd::FromRawFd;
    let (mut reader, mut terminal) = (-1, -1);
    // SAFETY: two valid out-pointers; no name, terminal settings or size.
    let r = unsafe {
        libc::openpty(
            &mut reader,
            &mut terminal,
            std::ptr::null_mut(),
            std::ptr::null(),
            std::ptr::null(),
        )
    };
    assert_eq!(r, 0, "openpty: {}", std::io::Error::last_os_error());
    // SAFETY: openpty opened both and nothing else owns them.
    unsafe {
        (
            std::fs::File::from_raw_fd(reader),
            std::os::fd::OwnedFd::from_raw_fd(terminal),
        )
    }
}

/// The log carries colour codes on a terminal only, and not there either
/// with NO_COLOR set (an empty NO_COLOR counts as unset); in a pipe, as
/// under systemd, never. (V1_01_micro lacks some right images, which
/// `rigslam run` warns about.)
#[test]
fn the_log_is_in_colour_only_on_a_terminal_without_no_color() {
    use std::io::Read;
    let Some(root) = shared("euroc/V1_01_micro") else {
        return;
    };
    let log = |terminal: bool, no_color: Option<&str>| -> String {
        let mut cmd = rigslam_run();
        cmd.args(["--mode", "stereo", "--max-frames", "2", "--dataset"])
            .arg(&root)
            .env_remove("NO_COLOR")
            .env_remove("RUST_LOG");
        if let Some(v) = no_color {
            cmd.env("NO_COLOR", v);
        }
        if !terminal {
            return String::from_utf8_lossy(&succeeds(&mut cmd).stderr).into_owned();
        }
        let (mut reader, stderr) = pseudo_terminal();
        cmd.stdout(std::process::Stdio::null()).stderr(stderr);
        let mut child = cmd.spawn().expect("run rigslam");
        // Our copy of the terminal's end goes, so reading ends with the child.
        drop(cmd);
        let mut text = Vec::new();
        let mut buf = [0u8; 4096];
        // Linux says EIO, not end of file, once no one holds the other end.
        while let Ok(n @ 1..) = reader.read(&mut buf) {
            text.extend_from_slice(&buf[..n]);
        }
        assert!(child.wait().expect("wait").success());
        String::from_utf8_lossy(&text).into_owned()
    };
    for (terminal, no_color, coloured) in [
        (true, None, true),
        (true, Some(""), true),
        (true, Some("1"), false),
        (false, None, false),
    ] {
        let text = log(terminal, no_color);
        let case = format!("terminal {terminal}, NO_COLOR={no_color:?}");
        assert!(text.contains("WARN"), "{case}: {text:?}");
        assert_eq!(text.contains("\x1b["), coloured, "{case}: {text:?}");
    }
}

/// A command that fails says its error once, on stderr, and exits
/// non-zero (anyhow's `{:#}` would repeat a cause the error already
/// carries).
#[test]
fn a_missing_input_is_said_once() {
    let dir = tempfile::tempdir().expect("tempdir");
    let missing = dir.path().join("missing");
    let mut run = rigslam_run();
    run.arg("--dataset").arg(missing.join("euroc"));
    let mut eval = Command::new(env!("CARGO_BIN_EXE_rigslam"));
    eval.args(["eval", "--estimate"])
        .arg(missing.join("estimate.tum"))
        .arg("--groundtruth")
        .arg(missing.join("groundtruth.csv"));
    for mut cmd in [run, eval] {
        let err = fails(&mut cmd);
        assert_eq!(err.matches("No such file or directory").count(), 1, "{err}");
        assert!(err.contains(&*missing.to_string_lossy()), "{err}");
    }
}
