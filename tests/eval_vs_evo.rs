//! `rigslam::eval` against evo, the usual reference for trajectory metrics.
//!
//! The constants are evo 1.38.1's output on the V1_02 sample estimate of the
//! shared data; bench/peers/evo_reference.sh reproduces them and
//! fixtures/evo/README.md records when, how and what evo printed.

use std::path::PathBuf;

use rigslam::dataset::read_trajectory_any;
use rigslam::eval::metrics::{rpe_over_distance, rpe_per_frame, ErrorStats};
use rigslam::eval::{evaluate, Alignment, EvalOptions};
use rigslam::trajectory::Trajectory;

/// evo statistics of one run, m or deg.
struct EvoStats {
    pairs: usize,
    rmse: f64,
    mean: f64,
    median: f64,
    max: f64,
    min: f64,
}

/// `evo_ape euroc V1_02_groundtruth.csv V1_02_estimate_sample.tum -a`
const EVO_APE_SE3: EvoStats = EvoStats {
    pairs: 798,
    rmse: 0.09172711520685745,
    mean: 0.08152162194619841,
    median: 0.07791194901949514,
    max: 0.2558167338139711,
    min: 0.0026199870973829826,
};
/// Same with `-as`.
const EVO_APE_SIM3: EvoStats = EvoStats {
    pairs: 798,
    rmse: 0.08384138804295287,
    mean: 0.07484108478263368,
    median: 0.07194517866622556,
    max: 0.2266517923827704,
    min: 0.007000290579423439,
};
/// `evo_rpe ... --delta 1 --delta_unit f` (translation part, m).
const EVO_RPE_FRAME_TRANS: EvoStats = EvoStats {
    pairs: 797,
    rmse: 0.015076710159641328,
    mean: 0.006106922465380456,
    median: 0.004183939336058311,
    max: 0.21740892442745757,
    min: 0.00011469502653262393,
};
/// `evo_rpe ... --delta 1 --delta_unit f -r angle_deg` (deg).
const EVO_RPE_FRAME_ROT: EvoStats = EvoStats {
    pairs: 797,
    rmse: 0.3576155948859286,
    mean: 0.08987560074843899,
    median: 0.03303003251207459,
    max: 4.939154960254689,
    min: 0.003067746632941551,
};
/// `evo_rpe ... --delta 1 --delta_unit m --all_pairs --delta_tol 0.1
/// --pairs_from_reference` (m): pairs ~1 m apart along the ground truth.
const EVO_RPE_1M_TRANS: EvoStats = EvoStats {
    pairs: 758,
    rmse: 0.05500201228030606,
    mean: 0.04423778215396704,
    median: 0.03484464432615077,
    max: 0.2537360387336064,
    min: 0.002556939815783902,
};

/// Scale of evo's Sim(3) alignment (`-as`), the cube root of det(sR) of
/// its saved `alignment_transformation_sim3.npy`.
const EVO_SIM3_SCALE: f64 = 0.9796982521745784;

/// `evo_ape ... --align_origin`: the last error, m. evo's origin alignment
/// applies T_gt0 * T_est0^-1 to the estimate, the anchoring of eq. 72.
const EVO_ORIGIN_FINAL_ERROR_M: f64 = 0.2001771250018032;
/// evo's `path_length` of the ground truth cut to the first and last
/// matched stamps, m.
const EVO_TRUE_PATH_M: f64 = 75.72612630965092;

/// The contract: ATE statistics within 1e-4 m of evo.
const ATE_TOL_M: f64 = 1e-4;

/// `../shared/data/euroc/ground_truth`; `None` (skip) when missing, unless
/// `CI` is set: there a missing folder fails the test.
fn shared_ground_truth_dir() -> Option<PathBuf> {
    Some(rigslam::shared_data::shared_data_dir()?.join("euroc/ground_truth"))
}

fn load() -> Option<(Trajectory, Trajectory)> {
    let dir = shared_ground_truth_dir()?;
    let estimate =
        read_trajectory_any(&dir.join("V1_02_estimate_sample.tum")).expect("estimate reads");
    let truth = read_trajectory_any(&dir.join("V1_02_groundtruth.csv")).expect("truth reads");
    Some((estimate, truth))
}

fn assert_close(name: &str, ours: f64, evo: f64, tol: f64) {
    assert!(
        (ours - evo).abs() <= tol,
        "{name}: ours {ours:.12} evo {evo:.12} (diff {:.3e} > {tol:e})",
        (ours - evo).abs()
    );
}

fn check_stats(what: &str, ours: &ErrorStats, evo: &EvoStats, tol: f64) {
    eprintln!(
        "{what}: n {} rmse {:.17} mean {:.17} median {:.17} max {:.17} min {:.17}",
        ours.count, ours.rmse, ours.mean, ours.median, ours.max, ours.min
    );
    assert_eq!(ours.count, evo.pairs, "{what}: pair count");
    assert_close(&format!("{what} rmse"), ours.rmse, evo.rmse, tol);
    assert_close(&format!("{what} mean"), ours.mean, evo.mean, tol);
    assert_close(&format!("{what} median"), ours.median, evo.median, tol);
    assert_close(&format!("{what} max"), ours.max, evo.max, tol);
    assert_close(&format!("{what} min"), ours.min, evo.min, tol);
}

fn ate(alignment: Alignment, evo: &EvoStats) {
    let Some((estimate, truth)) = load() else {
        return;
    };
    let options = EvalOptions {
        alignment,
        ..EvalOptions::default()
    };
    let ev = evaluate(&estimate, &truth, &options).expect("evaluates");
    assert_eq!(ev.report.matched_poses, evo.pairs);
    let stats = ErrorStats::of(&ev.ate_errors_m).expect("pairs");
    check_stats(alignment.name(), &stats, evo, ATE_TOL_M);
    assert_close("report rmse", ev.report.ate_rmse_m, evo.rmse, ATE_TOL_M);
    // Same Umeyama fit, same numbers: the scale agrees to rounding.
    let scale = ev.report.sim3_scale.expect("well posed");
    assert_close("sim3 scale", scale, EVO_SIM3_SCALE, 1e-9);
    assert_close(
        "scale error",
        ev.report.scale_error.expect("well posed"),
        1.0 - EVO_SIM3_SCALE,
        1e-9,
    );
}

#[test]
fn ate_se3_agrees_with_evo() {
    ate(Alignment::Se3, &EVO_APE_SE3);
}

#[test]
fn ate_sim3_agrees_with_evo() {
    ate(Alignment::Sim3, &EVO_APE_SIM3);
}

/// RPE does not depend on a rigid alignment, so it is compared unaligned,
/// as evo ran it. 1e-6 m and 1e-4 deg: the pose arithmetic is the same,
/// only the rounding of stamps and quaternions read from text differs.
#[test]
fn rpe_agrees_with_evo() {
    let Some((estimate, truth)) = load() else {
        return;
    };
    let options = EvalOptions {
        alignment: Alignment::None,
        ..EvalOptions::default()
    };
    let ev = evaluate(&estimate, &truth, &options).expect("evaluates");
    let m = &ev.matched;
    let (trans_m, rot_deg) = rpe_per_frame(&m.T_world_est, &m.T_world_gt);
    check_stats(
        "rpe frame trans",
        &ErrorStats::of(&trans_m).expect("pairs"),
        &EVO_RPE_FRAME_TRANS,
        1e-6,
    );
    check_stats(
        "rpe frame rot",
        &ErrorStats::of(&rot_deg).expect("pairs"),
        &EVO_RPE_FRAME_ROT,
        1e-4,
    );
    let one_m = rpe_over_distance(&m.T_world_est, &m.T_world_gt, 1.0, 0.1);
    check_stats(
        "rpe 1 m trans",
        &ErrorStats::of(&one_m.trans_errors_m).expect("pairs"),
        &EVO_RPE_1M_TRANS,
        1e-6,
    );
    assert_close(
        "report rpe per frame",
        ev.report.rpe_trans_m_per_frame.expect("pairs"),
        EVO_RPE_FRAME_TRANS.mean,
        1e-6,
    );
}

/// The paper's final drift (eq. 72) from evo's pieces: its origin-aligned
/// final error over its path length.
#[test]
fn final_drift_agrees_with_evo_origin_alignment() {
    let Some((estimate, truth)) = load() else {
        return;
    };
    let r = evaluate(&estimate, &truth, &EvalOptions::default())
        .expect("evaluates")
        .report;
    assert_close("true path", r.path_length_m, EVO_TRUE_PATH_M, 1e-9);
    let expected_pct = 100.0 * EVO_ORIGIN_FINAL_ERROR_M / EVO_TRUE_PATH_M;
    assert_close(
        "final drift",
        r.final_drift_pct.expect("defined"),
        expected_pct,
        1e-9,
    );
}

/// `rigslam eval --json` prints exactly one JSON object with the contract's
/// keys; the table names its units. Hermetic: a synthetic pair of files.
#[test]
fn cli_prints_one_json_object() {
    use std::fmt::Write as _;
    let dir = tempfile::tempdir().expect("temp dir");
    let (mut gt, mut est) = (String::new(), String::new());
    for k in 0..400 {
        let s = k as f64 * 0.02;
        let (x, y) = (2.0 * s.cos(), 2.0 * s.sin());
        writeln!(gt, "{:.9} {x} {y} 0 0 0 0 1", 100.0 + k as f64 * 0.05).expect("fmt");
        // 5 % too large and 2 ms late: still associated, visibly scaled.
        writeln!(
            est,
            "{:.9} {} {} 0 0 0 0 1",
            100.002 + k as f64 * 0.05,
            1.05 * x,
            1.05 * y
        )
        .expect("fmt");
    }
    let gt_path = dir.path().join("gt.tum");
    let est_path = dir.path().join("est.tum");
    std::fs::write(&gt_path, gt).expect("write");
    std::fs::write(&est_path, est).expect("write");
    let run = |extra: &[&str]| {
        let out = std::process::Command::new(env!("CARGO_BIN_EXE_rigslam"))
            .args(["eval", "--estimate"])
            .arg(&est_path)
            .arg("--groundtruth")
            .arg(&gt_path)
            .args(extra)
            .output()
            .expect("rigslam runs");
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        String::from_utf8(out.stdout).expect("utf-8")
    };
    let plot = dir.path().join("p.svg");
    let stdout = run(&[
        "--json",
        "--align",
        "sim3",
        "--plot",
        plot.to_str().expect("utf-8 path"),
    ]);
    let json: serde_json::Value = serde_json::from_str(stdout.trim()).expect("one JSON object");
    assert_eq!(stdout.trim().lines().count(), 1);
    for key in [
        "ate_rmse_m",
        "ate_mean_m",
        "ate_median_m",
        "ate_max_m",
        "rpe_trans_m_per_m",
        "scale_error",
        "final_drift_pct",
        "align",
        "matched_poses",
    ] {
        assert!(json.get(key).is_some(), "missing {key} in {stdout}");
    }
    assert_eq!(json["align"], "sim3");
    assert_eq!(json["matched_poses"], 400);
    let scale_error = json["scale_error"].as_f64().expect("number");
    assert!(
        (scale_error - (1.0 - 1.0 / 1.05)).abs() < 1e-9,
        "{scale_error}"
    );
    assert!(json["ate_rmse_m"].as_f64().expect("number") < 1e-9);
    assert!(plot.metadata().expect("plot written").len() > 1000);

    let table = run(&[]);
    assert!(
        table.contains("ATE rmse") && table.contains(" m\n"),
        "{table}"
    );

    // Stamps in ns where seconds were expected: no match, both ranges shown.
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_rigslam"))
        .args(["eval", "--estimate"])
        .arg(&est_path)
        .arg("--groundtruth")
        .arg(&gt_path)
        .args(["--t-offset-s", "1000"])
        .output()
        .expect("rigslam runs");
    assert!(!out.status.success());
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains("estimate spans") && stderr.contains("ground truth spans"),
        "{stderr}"
    );
}
