//! The exit report (`--report FILE`): the pipeline's counts and latencies
//! with the process's CPU time.

use std::path::Path;

use anyhow::Context;
use rigslam::daemon::PipelineReport;

#[derive(serde::Serialize)]
struct Report<'a> {
    #[serde(flatten)]
    pipeline: &'a PipelineReport,
    wall_s: f64,
    cpu_s: f64,
    /// CPU seconds per wall-clock second (1.0 = one core busy).
    cpu_per_wall_s: f64,
    peak_rss_mib: Option<f64>,
}

/// User + system CPU time of this process so far, s.
pub fn cpu_seconds() -> f64 {
    // SAFETY: getrusage fills the struct we pass.
    let usage = unsafe {
        let mut u: libc::rusage = std::mem::zeroed();
        libc::getrusage(libc::RUSAGE_SELF, &mut u);
        u
    };
    let s = |t: libc::timeval| t.tv_sec as f64 + t.tv_usec as f64 * 1e-6;
    s(usage.ru_utime) + s(usage.ru_stime)
}

pub fn write(
    path: &Path,
    pipeline: &PipelineReport,
    wall_s: f64,
    cpu_s: f64,
) -> anyhow::Result<()> {
    let report = Report {
        pipeline,
        wall_s,
        cpu_s,
        cpu_per_wall_s: if wall_s > 0.0 { cpu_s / wall_s } else { 0.0 },
        peak_rss_mib: rigslam::run::resident_memory_mib().1,
    };
    let text = serde_json::to_string_pretty(&report).expect("numbers and strings serialise");
    std::fs::write(path, text + "\n").with_context(|| format!("writing {}", path.display()))
}
