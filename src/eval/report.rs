//! One evaluation from two trajectories to the numbers `rigslam eval`
//! prints: association, alignment, ATE, RPE, scale error, final drift.

use nalgebra::{Isometry3, Vector3};

use super::align::{align, umeyama, Alignment, Sim3};
use super::associate::{associate, MatchedPoses};
use super::error::EvalError;
use super::metrics::{
    ate_errors_m, final_drift_pct, path_length_m, rpe_over_distance, rpe_per_frame, ErrorStats,
    RpeOverDistance,
};
use crate::trajectory::Trajectory;

/// How to evaluate.
#[derive(Debug, Clone, Copy)]
pub struct EvalOptions {
    /// How the estimate is fitted to the ground truth before the errors are taken \[se3\].
    pub alignment: Alignment,
    /// Largest time difference of an associated pair, ns (evo's default 10 ms).
    pub max_dt_ns: i64,
    /// Added to the estimate's stamps before association, ns.
    pub t_offset_ns: i64,
    /// Scale the estimate by the ratio of path lengths before computing the
    /// final drift (monocular runs; the paper's configuration 1).
    pub scale_by_path: bool,
    /// Travelled distance of the RPE pairs, m.
    pub rpe_delta_m: f64,
    /// Accepted deviation from `rpe_delta_m`, m.
    pub rpe_tol_m: f64,
}

impl Default for EvalOptions {
    fn default() -> Self {
        Self {
            alignment: Alignment::Se3,
            max_dt_ns: 10_000_000,
            t_offset_ns: 0,
            scale_by_path: false,
            rpe_delta_m: 1.0,
            rpe_tol_m: 0.1,
        }
    }
}

/// The numbers of one evaluation, as `rigslam eval --json` prints them.
/// Keys are snake_case with units; `null` where a number is undefined
/// (e.g. no pose pair ~1 m apart on a short trajectory).
#[derive(Debug, Clone, serde::Serialize)]
pub struct EvalReport {
    /// The alignment applied.
    pub align: Alignment,
    /// Estimated poses paired with a ground-truth pose.
    pub matched_poses: usize,
    /// Poses in the estimate.
    pub estimate_poses: usize,
    /// Poses in the ground truth.
    pub ground_truth_poses: usize,
    /// Largest time difference allowed in a pair, ms.
    pub max_dt_ms: f64,
    /// Offset added to the estimate's stamps before association, s.
    pub t_offset_s: f64,
    /// Time spanned by the matched poses, s.
    pub duration_s: f64,
    /// True path length between the first and last matched stamps, over all
    /// ground-truth poses in between, m.
    pub path_length_m: f64,
    /// Absolute trajectory error (position, after alignment): root mean square, m.
    pub ate_rmse_m: f64,
    /// ATE mean, m.
    pub ate_mean_m: f64,
    /// ATE median, m.
    pub ate_median_m: f64,
    /// ATE largest, m.
    pub ate_max_m: f64,
    /// ATE smallest, m.
    pub ate_min_m: f64,
    /// ATE population standard deviation, m.
    pub ate_std_m: f64,
    /// Mean over pose pairs ~1 m of true path apart of relative translation
    /// error / true path length between them, m/m.
    pub rpe_trans_m_per_m: Option<f64>,
    /// Same pairs: relative rotation error / path length, deg/m.
    pub rpe_rot_deg_per_m: Option<f64>,
    /// Pose pairs the two RPE-over-distance figures above average.
    pub rpe_pairs_1m: usize,
    /// Mean relative translation error of consecutive matched poses, m.
    pub rpe_trans_m_per_frame: Option<f64>,
    /// Mean relative rotation error of consecutive matched poses, deg.
    pub rpe_rot_deg_per_frame: Option<f64>,
    /// `|1 - s|` with s the scale of the Sim(3) Umeyama fit of the estimate
    /// to the truth, whatever `align` is: 0.02 means the estimate's
    /// distances are 2 % off. `null` when the positions do not fix a Sim(3).
    pub scale_error: Option<f64>,
    /// The Sim(3) fit's scale s itself (truth units per estimate unit).
    pub sim3_scale: Option<f64>,
    /// The paper's eq. 72: |final estimated - final true position| / true
    /// path length, %, with the estimate anchored at its first pose.
    pub final_drift_pct: Option<f64>,
    /// Whether the estimate was scaled by the ratio of path lengths for the final drift (monocular
    /// runs).
    pub scale_by_path: bool,
    /// Scale of the applied alignment (1 except for sim3).
    pub align_scale: f64,
}

/// Everything computed on the way, for plots and tests.
#[allow(non_snake_case)]
#[derive(Debug, Clone)]
pub struct Evaluation {
    /// The numbers `rigslam eval` prints.
    pub report: EvalReport,
    /// The estimate-ground truth pairs.
    pub matched: MatchedPoses,
    /// The transformation fitted, estimate world to ground-truth world.
    pub alignment: Sim3,
    /// The matched estimated poses after alignment.
    pub T_world_est_aligned: Vec<Isometry3<f64>>,
    /// ATE of each matched pair (position error after alignment), m.
    pub ate_errors_m: Vec<f64>,
    /// The RPE pairs about `rpe_delta_m` of true path apart, with their errors.
    pub rpe_1m: RpeOverDistance,
}

/// Associates, aligns and scores `estimate` against `ground_truth`.
#[allow(non_snake_case)]
pub fn evaluate(
    estimate: &Trajectory,
    ground_truth: &Trajectory,
    options: &EvalOptions,
) -> Result<Evaluation, EvalError> {
    let matched = associate(
        estimate,
        ground_truth,
        options.max_dt_ns,
        options.t_offset_ns,
    )?;
    let est_positions: Vec<Vector3<f64>> = matched
        .T_world_est
        .iter()
        .map(|t| t.translation.vector)
        .collect();
    let gt_positions: Vec<Vector3<f64>> = matched
        .T_world_gt
        .iter()
        .map(|t| t.translation.vector)
        .collect();

    let alignment = align(options.alignment, &est_positions, &gt_positions)?;
    let T_world_est_aligned: Vec<Isometry3<f64>> = matched
        .T_world_est
        .iter()
        .map(|t| alignment.transform_pose(t))
        .collect();

    let ate_errors_m = ate_errors_m(&T_world_est_aligned, &matched.T_world_gt);
    let ate = ErrorStats::of(&ate_errors_m).expect("association returns at least one pair");
    let (frame_trans_m, frame_rot_deg) = rpe_per_frame(&T_world_est_aligned, &matched.T_world_gt);
    let mean = |v: &[f64]| ErrorStats::of(v).map(|s| s.mean);
    let rpe_1m = rpe_over_distance(
        &T_world_est_aligned,
        &matched.T_world_gt,
        options.rpe_delta_m,
        options.rpe_tol_m,
    );

    let sim3_scale = umeyama(&est_positions, &gt_positions, true)
        .ok()
        .map(|s| s.scale);

    let first_gt = matched.gt_index[0];
    let last_gt = *matched.gt_index.last().expect("non-empty");
    let true_path: Vec<Vector3<f64>> = ground_truth.poses[first_gt..=last_gt]
        .iter()
        .map(|p| p.position())
        .collect();
    let true_path_m = path_length_m(&true_path);
    // Both lengths over the matched poses, so that sampling shortens them alike.
    let path_scale = if options.scale_by_path {
        let est_len = path_length_m(&est_positions);
        let gt_len = path_length_m(&gt_positions);
        if est_len > 0.0 {
            gt_len / est_len
        } else {
            f64::NAN
        }
    } else {
        1.0
    };
    let final_drift_pct = final_drift_pct(
        &matched.T_world_est,
        &matched.T_world_gt,
        true_path_m,
        path_scale,
    )
    .filter(|d| d.is_finite());

    let report = EvalReport {
        align: options.alignment,
        matched_poses: matched.len(),
        estimate_poses: estimate.len(),
        ground_truth_poses: ground_truth.len(),
        max_dt_ms: options.max_dt_ns as f64 * 1e-6,
        t_offset_s: options.t_offset_ns as f64 * 1e-9,
        duration_s: (matched.t_ns[matched.len() - 1] - matched.t_ns[0]) as f64 * 1e-9,
        path_length_m: true_path_m,
        ate_rmse_m: ate.rmse,
        ate_mean_m: ate.mean,
        ate_median_m: ate.median,
        ate_max_m: ate.max,
        ate_min_m: ate.min,
        ate_std_m: ate.std,
        rpe_trans_m_per_m: rpe_1m.mean_trans_m_per_m(),
        rpe_rot_deg_per_m: rpe_1m.mean_rot_deg_per_m(),
        rpe_pairs_1m: rpe_1m.pairs.len(),
        rpe_trans_m_per_frame: mean(&frame_trans_m),
        rpe_rot_deg_per_frame: mean(&frame_rot_deg),
        scale_error: sim3_scale.map(|s| (1.0 - s).abs()),
        sim3_scale,
        final_drift_pct,
        scale_by_path: options.scale_by_path,
        align_scale: alignment.scale,
    };
    Ok(Evaluation {
        report,
        matched,
        alignment,
        T_world_est_aligned,
        ate_errors_m,
        rpe_1m,
    })
}

impl EvalReport {
    /// A short aligned table for people.
    pub fn to_table(&self) -> String {
        let opt = |v: Option<f64>, unit: &str| match v {
            Some(v) => format!("{v:.6} {unit}").trim_end().to_string(),
            None => "n/a".to_string(),
        };
        let rows: Vec<(&str, String)> = vec![
            (
                "matched poses",
                format!(
                    "{} of {} estimated, {} true (max dt {} ms)",
                    self.matched_poses,
                    self.estimate_poses,
                    self.ground_truth_poses,
                    self.max_dt_ms
                ),
            ),
            (
                "alignment",
                format!("{} (scale {:.6})", self.align.name(), self.align_scale),
            ),
            ("duration", format!("{:.3} s", self.duration_s)),
            ("true path length", format!("{:.3} m", self.path_length_m)),
            ("ATE rmse", format!("{:.6} m", self.ate_rmse_m)),
            ("ATE mean", format!("{:.6} m", self.ate_mean_m)),
            ("ATE median", format!("{:.6} m", self.ate_median_m)),
            ("ATE max", format!("{:.6} m", self.ate_max_m)),
            (
                "RPE per 1 m",
                format!(
                    "{}, {}  ({} pairs)",
                    opt(self.rpe_trans_m_per_m, "m/m"),
                    opt(self.rpe_rot_deg_per_m, "deg/m"),
                    self.rpe_pairs_1m
                ),
            ),
            (
                "RPE per frame",
                format!(
                    "{}, {}",
                    opt(self.rpe_trans_m_per_frame, "m"),
                    opt(self.rpe_rot_deg_per_frame, "deg")
                ),
            ),
            (
                "scale error",
                format!(
                    "{}  (sim3 scale {})",
                    opt(self.scale_error.map(|e| 100.0 * e), "%"),
                    opt(self.sim3_scale, "")
                ),
            ),
            (
                "final drift (eq. 72)",
                format!(
                    "{}{}",
                    opt(self.final_drift_pct, "% of path"),
                    if self.scale_by_path {
                        "  (scaled by path)"
                    } else {
                        ""
                    }
                ),
            ),
        ];
        let width = rows.iter().map(|(k, _)| k.len()).max().unwrap_or(0);
        rows.iter()
            .map(|(k, v)| format!("{k:<width$}  {}\n", v.trim_end()))
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::trajectory::StampedPose;
    use nalgebra::{Rotation3, UnitQuaternion};

    /// A figure-eight at 1 m/s sampled at 20 Hz with gentle yaw.
    fn figure_eight(n: usize, dt_ns: i64) -> Trajectory {
        Trajectory::new(
            (0..n)
                .map(|k| {
                    let s = k as f64 * 0.05;
                    StampedPose::new(
                        1_000_000_000 + k as i64 * dt_ns,
                        Vector3::new(3.0 * s.sin(), 2.0 * (2.0 * s).sin(), 0.2 * s.cos()),
                        UnitQuaternion::from_euler_angles(0.05 * s.sin(), 0.0, s),
                    )
                })
                .collect(),
        )
    }

    #[test]
    fn a_moved_scaled_copy_scores_zero_after_sim3() {
        let gt = figure_eight(300, 50_000_000);
        let motion = Sim3 {
            rotation: Rotation3::from_euler_angles(0.1, 0.2, -1.0),
            translation: Vector3::new(4.0, -1.0, 2.0),
            scale: 0.5,
        };
        let est = Trajectory::new(
            gt.poses
                .iter()
                .map(|p| StampedPose {
                    t_ns: p.t_ns + 3_000_000, // 3 ms late: still associated
                    T_world_body: motion.transform_pose(&p.T_world_body),
                })
                .collect(),
        );
        let options = EvalOptions {
            alignment: Alignment::Sim3,
            ..EvalOptions::default()
        };
        let ev = evaluate(&est, &gt, &options).expect("evaluates");
        let r = &ev.report;
        assert_eq!(r.matched_poses, 300);
        assert!(r.ate_rmse_m < 1e-9 && r.ate_max_m < 1e-9, "{r:?}");
        assert!((r.align_scale - 2.0).abs() < 1e-9);
        assert!((r.scale_error.expect("fit") - 1.0).abs() < 1e-9);
        assert!(r.rpe_trans_m_per_frame.expect("pairs") < 1e-9);
        assert!(r.rpe_trans_m_per_m.expect("pairs") < 1e-9);
        assert!(r.rpe_pairs_1m > 200);
        // Unscaled, the anchored half-size estimate ends far off; scaled by
        // path lengths, exactly on the truth.
        assert!(r.final_drift_pct.expect("drift") > 1.0);
        let scaled = EvalOptions {
            scale_by_path: true,
            ..options
        };
        let r = evaluate(&est, &gt, &scaled).expect("evaluates").report;
        assert!(r.final_drift_pct.expect("drift") < 1e-9, "{r:?}");
    }

    #[test]
    fn se3_leaves_a_scale_error_visible() {
        let gt = figure_eight(300, 50_000_000);
        let est = Trajectory::new(
            gt.poses
                .iter()
                .map(|p| StampedPose::new(p.t_ns, 1.1 * p.position(), p.orientation()))
                .collect(),
        );
        let ev = evaluate(&est, &gt, &EvalOptions::default()).expect("evaluates");
        let r = ev.report.clone();
        assert!((r.scale_error.expect("fit") - (1.0 - 1.0 / 1.1)).abs() < 1e-9);
        assert!(r.ate_rmse_m > 0.05);
        // Every displacement is 10 % long: the relative error of a pair is
        // 0.1 of its chord, and RPE divides by the (longer) path between.
        let expected: f64 = ev
            .rpe_1m
            .pairs
            .iter()
            .zip(&ev.rpe_1m.distances_m)
            .map(|(&(i, j), d)| 0.1 * (gt.poses[j].position() - gt.poses[i].position()).norm() / d)
            .sum::<f64>()
            / ev.rpe_1m.pairs.len() as f64;
        assert!((0.09..0.1).contains(&expected));
        assert!((r.rpe_trans_m_per_m.expect("pairs") - expected).abs() < 1e-9);
        let json = serde_json::to_value(&r).expect("serialises");
        assert_eq!(json["align"], "se3");
        for key in [
            "ate_rmse_m",
            "ate_mean_m",
            "ate_median_m",
            "ate_max_m",
            "rpe_trans_m_per_m",
            "scale_error",
            "final_drift_pct",
            "matched_poses",
        ] {
            assert!(json.get(key).is_some(), "missing {key}");
        }
        let table = r.to_table();
        assert!(
            table.contains("ATE rmse") && table.contains(" m\n"),
            "{table}"
        );
    }
}
