//! `rigslam bench essential`: five-point MSAC relative pose over every
//! image pair of a matches file, timed single-threaded, scored against the
//! true relative rotations when a ground-truth file is given.

use std::collections::HashMap;
use std::path::PathBuf;
use std::time::Instant;

use anyhow::Context;
use rigslam::dataset::matches_file::{
    normalise, read_matches, read_relative_motions, rotation_error_deg,
};
use rigslam::two_view::{estimate_relative_pose, RelativePoseConfig};

#[derive(clap::Args)]
pub struct EssentialArgs {
    /// Correspondences: `# K fx fy cx cy: ...` header, then `k n x1 y1 x2 y2 ...` per pair.
    #[arg(long)]
    matches: PathBuf,
    /// True relative motions: `k r00 .. r22 tx ty tz` per pair.
    #[arg(long)]
    gt: Option<PathBuf>,
    /// Inlier threshold in pixels (Sampson error).
    #[arg(long, default_value_t = 1.0)]
    threshold_px: f64,
    /// Times each pair is solved (the timing is the mean).
    #[arg(long, default_value_t = 5)]
    repeats: usize,
    /// Print one JSON object instead of a table.
    #[arg(long)]
    json: bool,
}

/// `q`-quantile by linear interpolation (as numpy's default).
fn quantile(sorted: &[f64], q: f64) -> f64 {
    let pos = q * (sorted.len() - 1) as f64;
    let (lo, hi) = (pos.floor() as usize, pos.ceil() as usize);
    sorted[lo] + (sorted[hi] - sorted[lo]) * (pos - lo as f64)
}

pub fn run(args: EssentialArgs) -> anyhow::Result<()> {
    anyhow::ensure!(args.repeats > 0, "--repeats must be at least 1");
    let file = read_matches(&args.matches)?;
    let camera = file.camera(&args.matches)?;
    let gt = match &args.gt {
        Some(path) => Some(
            read_relative_motions(path)?
                .into_iter()
                .map(|m| (m.k, m))
                .collect::<HashMap<_, _>>(),
        ),
        None => None,
    };
    let config = RelativePoseConfig::for_pixels(args.threshold_px, file.pinhole[0]);
    let normalised: Vec<_> = file.pairs.iter().map(|p| normalise(&camera, p)).collect();

    let mut errors_deg = Vec::new();
    let mut failures = 0;
    let mut elapsed_s = 0.0;
    let mut inliers_total = 0;
    for (pair, (x1, x2)) in file.pairs.iter().zip(&normalised) {
        let start = Instant::now();
        let mut result = None;
        for _ in 0..args.repeats {
            result = Some(estimate_relative_pose(x1, x2, &config));
        }
        elapsed_s += start.elapsed().as_secs_f64();
        let result = result.expect("repeats >= 1");
        let pose = match result {
            Ok(pose) => pose,
            Err(e) => {
                failures += 1;
                tracing::warn!("pair {}: {e}", pair.k);
                if gt.as_ref().is_some_and(|g| g.contains_key(&pair.k)) {
                    errors_deg.push(180.0);
                }
                continue;
            }
        };
        inliers_total += pose.inlier_count;
        if let Some(truth) = gt.as_ref().and_then(|g| g.get(&pair.k)) {
            errors_deg.push(rotation_error_deg(
                &truth.rotation_c2_c1,
                pose.rotation_c2_c1.matrix(),
            ));
        }
    }
    let pairs = file.pairs.len();
    anyhow::ensure!(pairs > 0, "{}: no image pairs", args.matches.display());
    let ms_per_pair = 1e3 * elapsed_s / (pairs * args.repeats) as f64;
    errors_deg.sort_by(f64::total_cmp);
    let (median, p90) = if errors_deg.is_empty() {
        (None, None)
    } else {
        (
            Some(quantile(&errors_deg, 0.5)),
            Some(quantile(&errors_deg, 0.9)),
        )
    };
    if args.json {
        let mut out = serde_json::json!({
            "pairs": pairs,
            "ms_per_pair": ms_per_pair,
            "failures": failures,
            "inliers_mean": inliers_total as f64 / pairs as f64,
            "threshold_px": args.threshold_px,
        });
        if let (Some(m), Some(p)) = (median, p90) {
            out["rot_err_median_deg"] = m.into();
            out["rot_err_p90_deg"] = p.into();
        }
        println!(
            "{}",
            serde_json::to_string(&out).context("serialising the report")?
        );
    } else {
        println!("pairs            {pairs}");
        println!("ms per pair      {ms_per_pair:.3}");
        println!("failures         {failures}");
        println!(
            "inliers (mean)   {:.1}",
            inliers_total as f64 / pairs as f64
        );
        if let (Some(m), Some(p)) = (median, p90) {
            println!("rotation error   median {m:.4} deg, p90 {p:.4} deg");
        }
    }
    Ok(())
}
