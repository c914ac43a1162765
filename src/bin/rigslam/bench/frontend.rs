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
    /// Spread KLT corners over buckets of this size, px. Off by default:
    /// the peer's goodFeaturesToTrack takes the strongest corners anywhere
    /// (10 px apart), and so does this bench unless told otherwise.
    #[arg(long)]
    bucket_px: Option<usize>,
    /// Also print the KLT time split into pyramid, detection and tracking (stderr).
    #[arg(long)]
    stages: bool,
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
    /// The same runs timed by the thread's own CPU time: on a shared,
    /// busy machine this is the steadier number to compare with the peer.
    klt_cpu_ms_per_frame: f64,
    orb_cpu_ms_per_frame: f64,
}

/// Wall and CPU seconds of one timed run.
#[derive(Clone, Copy)]
struct Timing {
    wall_s: f64,
    cpu_s: f64,
}

impl Timing {
    fn best(self, other: Timing) -> Timing {
        Timing {
            wall_s: self.wall_s.min(other.wall_s),
            cpu_s: self.cpu_s.min(other.cpu_s),
        }
    }
}

const NO_TIMING: Timing = Timing {
    wall_s: f64::INFINITY,
    cpu_s: f64::INFINITY,
};

/// CPU time this thread has run, s (Linux schedstat; 0 elsewhere).
fn thread_cpu_s() -> f64 {
    std::fs::read_to_string("/proc/thread-self/schedstat")
        .ok()
        .and_then(|s| s.split_whitespace().next()?.parse::<u64>().ok())
        .map_or(0.0, |ns| ns as f64 * 1e-9)
}

/// Starts both clocks; `stop` gives the elapsed [`Timing`].
struct Clocks {
    wall: Instant,
    cpu_s: f64,
}

impl Clocks {
    fn start() -> Self {
        Self {
            wall: Instant::now(),
            cpu_s: thread_cpu_s(),
        }
    }
    fn stop(&self) -> Timing {
        Timing {
            wall_s: self.wall.elapsed().as_secs_f64(),
            cpu_s: thread_cpu_s() - self.cpu_s,
        }
    }
}

pub fn run(args: FrontendArgs) -> anyhow::Result<()> {
    let frames = load_frames(&args.images)?;
    let repeat = args.repeat.max(1);
    let mut best_klt = NO_TIMING;
    let mut tracks = Vec::new();
    for _ in 0..repeat {
        let (timing, counts) = run_klt(&frames, args.bucket_px, args.stages)?;
        best_klt = best_klt.best(timing);
        tracks = counts;
    }
    let mut best_orb = NO_TIMING;
    let mut features = Vec::new();
    for _ in 0..repeat {
        let (timing, counts) = run_orb(&frames)?;
        best_orb = best_orb.best(timing);
        features = counts;
    }
    let pairs = (frames.len() - 1) as f64;
    let mean = |v: &[usize]| v.iter().sum::<usize>() as f64 / v.len().max(1) as f64;
    let report = FrontendReport {
        frames: frames.len(),
        klt_ms_per_frame: 1e3 * best_klt.wall_s / pairs,
        klt_tracks_mean: mean(&tracks),
        orb_ms_per_frame: 1e3 * best_orb.wall_s / frames.len() as f64,
        orb_features_mean: mean(&features),
        klt_cpu_ms_per_frame: 1e3 * best_klt.cpu_s / pairs,
        orb_cpu_ms_per_frame: 1e3 * best_orb.cpu_s / frames.len() as f64,
    };
    if args.json {
        println!("{}", serde_json::to_string(&report)?);
    } else {
        println!("{} frames from {}", report.frames, args.images.display());
        println!(
            "KLT detect+track: {:.2} ms/frame ({:.2} ms CPU), {:.1} tracks survive (of {KLT_CORNERS} detected)",
            report.klt_ms_per_frame, report.klt_cpu_ms_per_frame, report.klt_tracks_mean
        );
        println!(
            "ORB(1000):        {:.2} ms/frame ({:.2} ms CPU), {:.1} features",
            report.orb_ms_per_frame, report.orb_cpu_ms_per_frame, report.orb_features_mean
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

/// Time for the whole sequence and surviving tracks per pair.
fn run_klt(
    frames: &[Image],
    bucket_px: Option<usize>,
    print_stages: bool,
) -> anyhow::Result<(Timing, Vec<usize>)> {
    let mut prev = Pyramid::new(PyramidConfig::klt())?;
    let mut cur = Pyramid::new(PyramidConfig::klt())?;
    let mut corner_config = CornerConfig::default();
    corner_config.grid.bucket_px = bucket_px.unwrap_or(usize::MAX);
    let mut detector = CornerDetector::new(corner_config);
    let klt_config = KltConfig::default();
    let mut tracker = KltTracker::new(klt_config)?;
    let mut corners: Vec<Corner> = Vec::with_capacity(KLT_CORNERS);
    let mut points: Vec<[f32; 2]> = Vec::with_capacity(KLT_CORNERS);
    let (mut tracked, mut status) = (Vec::new(), Vec::new());
    let mut survivors = Vec::with_capacity(frames.len());
    let mut stage_s = [0f64; 3];
    let clocks = Clocks::start();
    prev.build(&frames[0])?;
    for frame in &frames[1..] {
        let t0 = Instant::now();
        cur.build(frame)?;
        let t1 = Instant::now();
        detector.detect(prev.level(0), &[], KLT_CORNERS, &mut corners);
        points.clear();
        points.extend(corners.iter().map(|c| [c.x as f32, c.y as f32]));
        let t2 = Instant::now();
        tracker.track(&prev, &cur, &points, None, &mut tracked, &mut status);
        let t3 = Instant::now();
        stage_s[0] += (t1 - t0).as_secs_f64();
        stage_s[1] += (t2 - t1).as_secs_f64();
        stage_s[2] += (t3 - t2).as_secs_f64();
        survivors.push(
            status
                .iter()
                .filter(|s| **s == TrackStatus::Tracked)
                .count(),
        );
        std::mem::swap(&mut prev, &mut cur);
    }
    let timing = clocks.stop();
    if print_stages {
        let n = (frames.len() - 1) as f64;
        eprintln!(
            "pyramid {:.2} ms, detect {:.2} ms, track {:.2} ms per frame",
            1e3 * stage_s[0] / n,
            1e3 * stage_s[1] / n,
            1e3 * stage_s[2] / n
        );
    }
    Ok((timing, survivors))
}

/// Time for the whole sequence and features per frame.
fn run_orb(frames: &[Image]) -> anyhow::Result<(Timing, Vec<usize>)> {
    let mut extractor = OrbExtractor::new(OrbConfig::default())?;
    let (mut keypoints, mut descriptors) = (Vec::new(), Vec::new());
    let mut counts = Vec::with_capacity(frames.len());
    let clocks = Clocks::start();
    for frame in frames {
        extractor.extract(frame, &mut keypoints, &mut descriptors)?;
        counts.push(keypoints.len());
    }
    Ok((clocks.stop(), counts))
}
