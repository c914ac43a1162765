//! IMU preintegration on real data: against GTSAM's recorded
//! output, and against EuRoC ground truth.
//!
//! `fixtures/gtsam/v1_01_preintegration.txt` is GTSAM 4.3.0's
//! PreintegratedImuMeasurements on 200 V1_01 intervals, made by
//! `bench/peers/gtsam_preintegration.sh` (provenance in
//! `fixtures/gtsam/README.md`). Run with `--nocapture` to see the tables.

use std::path::{Path, PathBuf};

use nalgebra::{Matrix3, SMatrix, UnitQuaternion, Vector3};
use rigslam::dataset::{read_euroc_groundtruth, read_euroc_imu_csv, GroundTruthState};
use rigslam::imu::so3::{exp, log, right_jacobian};
use rigslam::imu::{
    ImuBiases, ImuIntrinsics, ImuStream, IntegrationScheme, IntervalConfig, NavState,
    Preintegrator, GRAVITY_M_S2,
};
use rigslam::rig::ImuNoise;

type Matrix9 = SMatrix<f64, 9, 9>;

/// A file under the shared data folder; `None` (skip) when missing unless
/// `CI` is set, where a missing folder or file fails the test.
fn shared(relative: &str) -> Option<PathBuf> {
    let path = rigslam::shared_data::shared_data_dir()?.join(relative);
    assert!(
        path.exists() || std::env::var_os("CI").is_none(),
        "{} is missing and CI is set",
        path.display()
    );
    path.exists().then_some(path)
}

/// One row of the GTSAM fixture.
struct GtsamInterval {
    t_start_ns: i64,
    t_end_ns: i64,
    steps: usize,
    /// GTSAM's tangent-space preintegrated vector: theta, dp, dv.
    theta: Vector3<f64>,
    dp: Vector3<f64>,
    dv: Vector3<f64>,
    /// Over (theta, dp, dv).
    cov: Matrix9,
}

fn read_fixture() -> Vec<GtsamInterval> {
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/fixtures/gtsam/v1_01_preintegration.txt"
    );
    let text = std::fs::read_to_string(path).expect("fixture is in the repository");
    text.lines()
        .filter(|l| !l.starts_with('#'))
        .map(|l| {
            let f: Vec<&str> = l.split_whitespace().collect();
            assert_eq!(f.len(), 3 + 9 + 45, "fixture row: {l}");
            let x: Vec<f64> = f[3..].iter().map(|v| v.parse().expect("number")).collect();
            let mut cov = Matrix9::zeros();
            let mut n = 9;
            for r in 0..9 {
                for c in r..9 {
                    cov[(r, c)] = x[n];
                    cov[(c, r)] = x[n];
                    n += 1;
                }
            }
            GtsamInterval {
                t_start_ns: f[0].parse().expect("stamp"),
                t_end_ns: f[1].parse().expect("stamp"),
                steps: f[2].parse().expect("count"),
                theta: Vector3::new(x[0], x[1], x[2]),
                dp: Vector3::new(x[3], x[4], x[5]),
                dv: Vector3::new(x[6], x[7], x[8]),
                cov,
            }
        })
        .collect()
}

/// GTSAM's covariance over (theta, dp, dv) in ours over (dphi, dv, dp):
/// `Exp(theta + d) = Exp(theta) Exp(J_r(theta) d)`, so `dphi = J_r dtheta`.
fn gtsam_covariance_in_our_order(g: &GtsamInterval) -> Matrix9 {
    let mut t = Matrix9::zeros();
    t.fixed_view_mut::<3, 3>(0, 0)
        .copy_from(&right_jacobian(&g.theta));
    t.fixed_view_mut::<3, 3>(3, 6)
        .copy_from(&Matrix3::identity());
    t.fixed_view_mut::<3, 3>(6, 3)
        .copy_from(&Matrix3::identity());
    t * g.cov * t.transpose()
}

#[test]
fn euler_matches_gtsam_on_v1_01() {
    let (Some(imu_csv), Some(gt_csv)) = (
        shared("euroc/V1_01_micro/mav0/imu0/data.csv"),
        shared("euroc/ground_truth/V1_01_gt_camrate.csv"),
    ) else {
        return;
    };
    let imu = read_euroc_imu_csv(&imu_csv).expect("V1_01 IMU");
    let gt = read_euroc_groundtruth(&gt_csv).expect("V1_01 ground truth");
    let stream = ImuStream::from_samples(ImuIntrinsics::IDENTITY, &imu.samples);
    let fixture = read_fixture();
    assert_eq!(fixture.len(), 200);
    let mut integrator = Preintegrator::new(IntegrationScheme::Euler, ImuNoise::EUROC_ADIS16448);
    let (mut worst_r, mut worst_v, mut worst_p, mut worst_cov) = (0f64, 0f64, 0f64, 0f64);
    let mut worst_diag = 0f64;
    for g in &fixture {
        let start = gt
            .iter()
            .find(|s| s.t_ns == g.t_start_ns)
            .expect("fixture stamps are ground-truth stamps");
        let interval = stream
            .interval(g.t_start_ns, g.t_end_ns, &IntervalConfig::default())
            .expect("covered");
        assert!(interval.report.reliable);
        let pre = integrator
            .integrate_interval(&interval, &ImuBiases::from(start))
            .expect("integrable");
        assert_eq!(pre.steps, g.steps);
        worst_r = worst_r.max(log(&(exp(&g.theta).transpose() * pre.delta_R)).norm());
        worst_v = worst_v.max((pre.delta_v_m_s - g.dv).norm());
        worst_p = worst_p.max((pre.delta_p_m - g.dp).norm());
        let theirs = gtsam_covariance_in_our_order(g);
        for r in 0..9 {
            worst_diag = worst_diag.max((pre.covariance[(r, r)] / theirs[(r, r)] - 1.0).abs());
            for c in 0..9 {
                let scale = (theirs[(r, r)] * theirs[(c, c)]).sqrt();
                worst_cov = worst_cov.max((pre.covariance[(r, c)] - theirs[(r, c)]).abs() / scale);
            }
        }
    }
    println!(
        "GTSAM agreement over {} V1_01 intervals: rotation {worst_r:.3e} rad, velocity \
         {worst_v:.3e} m/s, position {worst_p:.3e} m; covariance diagonal {:.3e} relative, \
         any entry {:.3e} of sqrt(S_ii S_jj)",
        fixture.len(),
        worst_diag,
        worst_cov
    );
    assert!(worst_r < 1e-6, "rotation {worst_r}");
    assert!(worst_v < 1e-6, "velocity {worst_v}");
    assert!(worst_p < 1e-6, "position {worst_p}");
    assert!(worst_diag < 0.01, "covariance diagonal {worst_diag}");
    assert!(worst_cov < 0.01, "covariance {worst_cov}");
}

/// Median and 90th percentile.
fn stats(mut v: Vec<f64>) -> (f64, f64) {
    v.sort_by(f64::total_cmp);
    let at = |q: f64| v[((v.len() - 1) as f64 * q).round() as usize];
    (at(0.5), at(0.9))
}

struct Errors {
    rotation_deg: Vec<f64>,
    velocity_m_s: Vec<f64>,
    position_m: Vec<f64>,
}

/// Predicts every next ground-truth state from the true one with the
/// ground-truth biases; errors per scheme.
fn predict_ground_truth(
    name: &str,
    imu_csv: &Path,
    states: &[GroundTruthState],
) -> Vec<(IntegrationScheme, Errors)> {
    let imu = read_euroc_imu_csv(imu_csv).expect("IMU csv");
    let stream = ImuStream::from_samples(ImuIntrinsics::IDENTITY, &imu.samples);
    let gravity = Vector3::new(0.0, 0.0, -GRAVITY_M_S2);
    let mut out = Vec::new();
    let mut unreliable = 0;
    for scheme in IntegrationScheme::ALL {
        let mut integrator = Preintegrator::new(scheme, ImuNoise::EUROC_ADIS16448);
        let mut e = Errors {
            rotation_deg: Vec::new(),
            velocity_m_s: Vec::new(),
            position_m: Vec::new(),
        };
        unreliable = 0;
        for pair in states.windows(2) {
            let (a, b) = (&pair[0], &pair[1]);
            let Ok(interval) = stream.interval(a.t_ns, b.t_ns, &IntervalConfig::default()) else {
                continue;
            };
            if !interval.report.reliable {
                unreliable += 1;
            }
            let pre = integrator
                .integrate_interval(&interval, &ImuBiases::from(a))
                .expect("integrable");
            let start = NavState {
                t_ns: a.t_ns,
                R_world_body: a.T_world_body.rotation,
                position_world_m: a.T_world_body.translation.vector,
                velocity_world_m_s: a.velocity_m_s,
            };
            let end = pre.predict(&start, &ImuBiases::from(a), &gravity);
            let truth: UnitQuaternion<f64> = b.T_world_body.rotation;
            e.rotation_deg
                .push(end.R_world_body.angle_to(&truth).to_degrees());
            e.velocity_m_s
                .push((end.velocity_world_m_s - b.velocity_m_s).norm());
            e.position_m
                .push((end.position_world_m - b.T_world_body.translation.vector).norm());
        }
        out.push((scheme, e));
    }
    println!(
        "{name}: {} intervals ({unreliable} unreliable)",
        out[0].1.rotation_deg.len()
    );
    println!("| scheme | rot median (deg) | rot p90 (deg) | vel median (m/s) | vel p90 (m/s) | pos median (mm) | pos p90 (mm) |");
    for (scheme, e) in &out {
        let (rm, r9) = stats(e.rotation_deg.clone());
        let (vm, v9) = stats(e.velocity_m_s.clone());
        let (pm, p9) = stats(e.position_m.clone());
        println!(
            "| {} | {rm:.5} | {r9:.5} | {vm:.5} | {v9:.5} | {:.3} | {:.3} |",
            scheme.name(),
            pm * 1e3,
            p9 * 1e3
        );
    }
    out
}

#[test]
fn predicts_ground_truth_of_v1_01_and_v1_02() {
    let (Some(imu1), Some(gt1), Some(imu2), Some(gt2)) = (
        shared("euroc/V1_01_micro/mav0/imu0/data.csv"),
        shared("euroc/ground_truth/V1_01_gt_camrate.csv"),
        shared("euroc/ground_truth/V1_02_imu0.csv"),
        shared("euroc/ground_truth/V1_02_groundtruth.csv"),
    ) else {
        return;
    };
    let v1_01 = read_euroc_groundtruth(&gt1).expect("V1_01 ground truth");
    // V1_02's ground truth is at 200 Hz: every 10th state is a 20 Hz stream.
    let v1_02: Vec<_> = read_euroc_groundtruth(&gt2)
        .expect("V1_02 ground truth")
        .into_iter()
        .step_by(10)
        .collect();
    for (name, imu, states) in [("V1_01", &imu1, &v1_01), ("V1_02", &imu2, &v1_02)] {
        let results = predict_ground_truth(name, imu, states);
        for (scheme, e) in &results {
            assert!(e.rotation_deg.len() > 1000, "{name} {scheme:?}");
            let (rm, _) = stats(e.rotation_deg.clone());
            let (vm, _) = stats(e.velocity_m_s.clone());
            // Over 50 ms with the true biases, a working integration is
            // within the ground truth's own noise: far below the motion per
            // interval (EuRoC rotates ~1 deg and changes speed ~0.05 m/s per
            // frame); a sign or frame error gives errors of that size.
            assert!(
                rm < 0.1 && vm < 0.02,
                "{name} {scheme:?}: {rm} deg, {vm} m/s"
            );
        }
    }
}
