//! `rigslam bench frontend --images DIR [--json]`: speed and yield of the
//! image front end on real frames, with the protocol of the OpenCV peer
//! (`bench/peers/opencv_frontend.py`) so that the two can be compared:
//!
//! - KLT: for every consecutive pair (k-1, k), detect 200 corners on k-1
//!   and track them into k with the forward-backward check; the timed work
//!   is pyramid building, detection and both tracking directions (each
//!   frame's pyramid is built once and used for both of its pairs, as a
//!   tracker does).
//! - ORB: extract up to 1000 oriented FAST + rotated BRIEF features per frame.
//!
//! PNG decoding happens before any clock starts.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::Context;
use rigslam::dataset::read_png;
use rigslam::features::{
    Corner, CornerConfig, CornerDetector, KltConfig, KltTracker, OrbConfig, OrbExtractor, Pyramid,
    PyramidConfig, TrackStatus,
};
use rigslam::sensors::Image;

/// Corners detected per frame for KLT, as the peer's goodFeaturesToTrack(200).
const KLT_CORNERS: usize = 200;

#[derive(clap::Args)]
pub struct FrontendArgs {
    /// A folder of PNG frames, or a EuRoC camN folder (frames in its data/).
    #[arg(long)]
    images: PathBuf,
    /// Passes over the frames; the fastest counts (less noise on a busy machine).
    #[arg(long, default_value_t = 1)]
    repeat: usize,
    /// Print one JSON object instead of text.
    #[arg(long)]
    json: bool,
}

#[derive(serde::Serialize)]
struct FrontendReport {
    frames: usize,
    klt_ms_per_frame: f64,
    klt_tracks_mean: f64,
    orb_ms_per_frame: f64,
    orb_features_mean: f64,
}

pub fn run(args: FrontendArgs) -> anyhow::Result<()> {
    let frames = load_frames(&args.images)?;
    let repeat = args.repeat.max(1);
    let mut best_klt_s = f64::INFINITY;
    let mut tracks = Vec::new();
    for _ in 0..repeat {
        let (seconds, counts) = run_klt(&frames)?;
        best_klt_s = best_klt_s.min(seconds);
        tracks = counts;
    }
    let mut best_orb_s = f64::INFINITY;
    let mut features = Vec::new();
    for _ in 0..repeat {
        let (seconds, counts) = run_orb(&frames)?;
        best_orb_s = best_orb_s.min(seconds);
        features = counts;
    }
    let mean = |v: &[usize]| v.iter().sum::<usize>() as f64 / v.len().max(1) as f64;
    let report = FrontendReport {
        frames: frames.len(),
        klt_ms_per_frame: 1e3 * best_klt_s / (frames.len() - 1) as f64,
        klt_tracks_mean: mean(&tracks),
        orb_ms_per_frame: 1e3 * best_orb_s / frames.len() as f64,
        orb_features_mean: mean(&features),
    };
    if args.json {
        println!("{}", serde_json::to_string(&report)?);
    } else {
        println!("{} frames from {}", report.frames, args.images.display());
        println!(
            "KLT detect+track: {:.2} ms/frame, {:.1} tracks survive (of {KLT_CORNERS} detected)",
            report.klt_ms_per_frame, report.klt_tracks_mean
        );
        println!(
            "ORB(1000):        {:.2} ms/frame, {:.1} features",
            report.orb_ms_per_frame, report.orb_features_mean
        );
    }
    Ok(())
}

/// Decodes the folder's PNGs in name order (EuRoC and KITTI names sort by time).
fn load_frames(dir: &Path) -> anyhow::Result<Vec<Image>> {
    let folder = if dir.join("data").is_dir() {
        dir.join("data")
    } else {
        dir.to_path_buf()
    };
    let mut paths: Vec<PathBuf> = std::fs::read_dir(&folder)
        .with_context(|| format!("reading {}", folder.display()))?
        .filter_map(|entry| entry.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|e| e.eq_ignore_ascii_case("png")))
        .collect();
    paths.sort();
    if paths.len() < 2 {
        anyhow::bail!(
            "{}: need at least 2 PNG frames, found {}",
            folder.display(),
            paths.len()
        );
    }
    paths
        .iter()
        .map(|p| read_png(p).map_err(anyhow::Error::from))
        .collect()
}

/// Seconds for the whole sequence and surviving tracks per pair.
fn run_klt(frames: &[Image]) -> anyhow::Result<(f64, Vec<usize>)> {
    let mut prev = Pyramid::new(PyramidConfig::klt())?;
    let mut cur = Pyramid::new(PyramidConfig::klt())?;
    let mut corner_config = CornerConfig::default();
    if let Some(v) = std::env::var("RIGSLAM_BUCKET")
        .ok()
        .and_then(|v| v.parse().ok())
    {
        corner_config.grid.bucket_px = v;
    }
    let mut detector = CornerDetector::new(corner_config);
    let mut klt_config = KltConfig::default();
    if let Ok(v) = std::env::var("RIGSLAM_KLT_RESIDUAL") {
        klt_config.max_residual = v.parse().ok();
    }
    if std::env::var_os("RIGSLAM_KLT_NO_AFFINE").is_some() {
        klt_config.affine_refinement = false;
    }
    let mut tracker = KltTracker::new(klt_config)?;
    let mut corners: Vec<Corner> = Vec::with_capacity(KLT_CORNERS);
    let mut points: Vec<[f32; 2]> = Vec::with_capacity(KLT_CORNERS);
    let (mut tracked, mut status) = (Vec::new(), Vec::new());
    let mut survivors = Vec::with_capacity(frames.len());
    let start = Instant::now();
    prev.build(&frames[0])?;
    for frame in &frames[1..] {
        cur.build(frame)?;
        detector.detect(prev.level(0), &[], KLT_CORNERS, &mut corners);
        points.clear();
        points.extend(corners.iter().map(|c| [c.x as f32, c.y as f32]));
        tracker.track(&prev, &cur, &points, None, &mut tracked, &mut status);
        survivors.push(
            status
                .iter()
                .filter(|s| **s == TrackStatus::Tracked)
                .count(),
        );
        if std::env::var_os("RIGSLAM_DEBUG_KLT").is_some() {
            let count = |k: TrackStatus| status.iter().filter(|s| **s == k).count();
            eprintln!(
                "tracked {} out {} textureless {} fb {} residual {}",
                count(TrackStatus::Tracked),
                count(TrackStatus::OutOfImage),
                count(TrackStatus::Textureless),
                count(TrackStatus::ForwardBackward),
                count(TrackStatus::LargeResidual)
            );
        }
        std::mem::swap(&mut prev, &mut cur);
    }
    Ok((start.elapsed().as_secs_f64(), survivors))
}

/// Seconds for the whole sequence and features per frame.
fn run_orb(frames: &[Image]) -> anyhow::Result<(f64, Vec<usize>)> {
    let mut extractor = OrbExtractor::new(OrbConfig::default())?;
    let (mut keypoints, mut descriptors) = (Vec::new(), Vec::new());
    let mut counts = Vec::with_capacity(frames.len());
    let start = Instant::now();
    for frame in frames {
        extractor.extract(frame, &mut keypoints, &mut descriptors)?;
        counts.push(keypoints.len());
    }
    Ok((start.elapsed().as_secs_f64(), counts))
}
