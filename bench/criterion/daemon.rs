//! The daemon on a replay, measured from outside as its users see it:
//!
//! - frame arrival to `rigslam/pose` published, p50 and p99 (the daemon's
//!   own exit report; target p99 under 20 ms at 20 Hz);
//! - publish to subscriber receive on `rigslam/pose` and
//!   `rigslam/pose_fast`, p50 and p99 (a `rigslam echo --json` child per
//!   service, blocked on the paired event service; target p99 under 100 us);
//! - `pose_fast` at the full IMU rate with no gaps: the echo child's
//!   sequence gaps (`missed`), its count against the daemon's IMU samples;
//! - CPU seconds of the daemon per real-time second (`/proc/PID/stat`);
//! - resident memory sampled every few seconds; with `--minutes M` the
//!   sequence is looped for M minutes (the soak: memory must stay flat).
//!
//! `cargo bench -p rigslam --bench daemon -- [--dataset DIR] [--minutes M]
//! [--mode MODE] [--relative-only] [--map] [--cpu N] [--tum-dir DIR]
//! [--daemon PATH] [--absolute-set KEY=VALUE] [--relative-set KEY=VALUE]`
//! (default: `../shared/data/euroc/V1_01_micro` played once at recorded
//! pace, both stages as the daemon runs them by default).
//! `--relative-only` sets `[slam.absolute] enabled = false` (`--absolute-set KEY=VALUE`
//! sets any other key of that table, `--relative-set KEY=VALUE` one of
//! `[slam.relative]`, e.g. `track_first_patch=false`); `--map` gives the daemon a map file
//! saved every 60 s of sensor time, and the map's size at each save
//! (landmarks, unknowns of the last solve, from the daemon's log) is
//! reported over time; `--cpu N` pins the daemon and its threads to core N
//! (a small robot computer); `--tum-dir` keeps the subscriber's map-frame
//! and odometry-frame trajectories (`pose.tum`, `pose_odom.tum`) for
//! `rigslam eval`; `--daemon` runs another build of rigslamd (an older
//! commit's, to compare two in the same run). Prints one JSON object. Not a criterion bench: the quantities
//! are distributions of a paced, multi-process run. Never run by CI; the
//! 30-minute soak is `-- --minutes 30`.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

struct Args {
    dataset: PathBuf,
    minutes: Option<f64>,
    mode: Option<String>,
    relative_only: bool,
    map: bool,
    cpu: Option<usize>,
    tum_dir: Option<PathBuf>,
    daemon: Option<PathBuf>,
    /// `KEY = VALUE` lines for `[slam.absolute]`.
    absolute_settings: Vec<String>,
    /// `KEY = VALUE` lines for `[slam.relative]`.
    relative_settings: Vec<String>,
}

/// The `KEY = VALUE` line of a `FLAG KEY=VALUE` argument.
fn setting_line(it: &mut impl Iterator<Item = String>, flag: &str) -> String {
    let kv = it.next().unwrap_or_else(|| panic!("{flag} KEY=VALUE"));
    let (k, v) = kv
        .split_once('=')
        .unwrap_or_else(|| panic!("{flag} KEY=VALUE, not {kv:?}"));
    format!("{} = {}", k.trim(), v.trim())
}

fn args() -> Args {
    let mut a = Args {
        dataset: PathBuf::from(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../shared/data/euroc/V1_01_micro"
        )),
        minutes: None,
        mode: None,
        relative_only: false,
        map: false,
        cpu: None,
        tum_dir: None,
        daemon: None,
        absolute_settings: Vec::new(),
        relative_settings: Vec::new(),
    };
    let mut it = std::env::args().skip(1);
    while let Some(arg) = it.next() {
        match arg.as_str() {
            "--dataset" => a.dataset = it.next().expect("--dataset DIR").into(),
            "--minutes" => {
                a.minutes = Some(
                    it.next()
                        .and_then(|m| m.parse().ok())
                        .expect("--minutes M (a number)"),
                )
            }
            "--mode" => a.mode = Some(it.next().expect("--mode MODE")),
            "--relative-only" => a.relative_only = true,
            "--map" => a.map = true,
            "--cpu" => {
                a.cpu = Some(
                    it.next()
                        .and_then(|c| c.parse().ok())
                        .expect("--cpu N (a core number)"),
                )
            }
            "--tum-dir" => a.tum_dir = Some(it.next().expect("--tum-dir DIR").into()),
            // Another build of rigslamd (an older commit's) for a
            // comparison in the same run.
            "--daemon" => a.daemon = Some(it.next().expect("--daemon PATH").into()),
            // A setting of the absolute stage, e.g. `solve_every_frames=10`.
            "--absolute-set" => a.absolute_settings.push(setting_line(&mut it, &arg)),
            // A setting of the relative stage, e.g. `track_first_patch=false`.
            "--relative-set" => a.relative_settings.push(setting_line(&mut it, &arg)),
            // cargo bench passes --bench.
            _ => {}
        }
    }
    a
}

/// The span of the sequence, s (first to last IMU or frame stamp).
fn sequence_s(dataset: &Path) -> f64 {
    let d = rigslam::dataset::open_dataset(dataset).expect("a EuRoC dataset");
    let stream = rigslam::dataset::SensorStream::new(
        &d,
        rigslam::dataset::StreamOptions {
            stereo: false,
            imu: true,
            start_ns: None,
            max_frames: None,
            imu_lead_ns: 0,
        },
    )
    .expect("stream");
    let stamps: Vec<i64> = stream
        .map(|e| match e.expect("event") {
            rigslam::dataset::SensorEvent::Imu(s) => s.t_ns,
            rigslam::dataset::SensorEvent::Frame { t_ns, .. } => t_ns,
        })
        .collect();
    (stamps.last().expect("events") - stamps[0]) as f64 * 1e-9
}

/// A `rigslam echo --json` child on `service`, with `extra` arguments.
fn echo(service: &str, root: &Path, extra: &[std::ffi::OsString]) -> Child {
    Command::new(env!("CARGO_BIN_EXE_rigslam"))
        .args(["echo", "--service", service, "--json", "--timeout-s", "5"])
        .arg("--root-path")
        .arg(root)
        .args(extra)
        .stdout(Stdio::piped())
        .spawn()
        .expect("start rigslam echo")
}

/// The map's size at each save, from the daemon's log lines
/// `map saved: L landmarks to PATH (U unknowns in the last solve)`:
/// (seconds since the first line, landmarks, unknowns).
fn map_saves(log: &str) -> Vec<serde_json::Value> {
    let stamp = |line: &str| -> Option<f64> {
        // RFC 3339 UTC stamp at the start of the line: seconds of the day.
        let t = line.split_whitespace().next()?;
        let time = t.split('T').nth(1)?.trim_end_matches('Z');
        let mut parts = time.split(':');
        let h: f64 = parts.next()?.parse().ok()?;
        let m: f64 = parts.next()?.parse().ok()?;
        let s: f64 = parts.next()?.parse().ok()?;
        Some(h * 3600.0 + m * 60.0 + s)
    };
    let first = log.lines().find_map(stamp);
    log.lines()
        .filter_map(|line| {
            let rest = line.split("map saved: ").nth(1)?;
            let landmarks: u64 = rest.split_whitespace().next()?.parse().ok()?;
            let unknowns: u64 = rest
                .rsplit('(')
                .next()?
                .split_whitespace()
                .next()?
                .parse()
                .ok()?;
            let mut t = stamp(line)? - first?;
            if t < 0.0 {
                t += 86_400.0;
            }
            Some(serde_json::json!({"t_s": t, "landmarks": landmarks, "unknowns": unknowns}))
        })
        .collect()
}

/// Restricts the process about to run to core `cpu` (its threads inherit it).
fn pin_to(command: &mut Command, cpu: usize) {
    use std::os::unix::process::CommandExt;
    // SAFETY: sched_setaffinity on the child itself between fork and
    // exec; the set is a plain value built before the fork.
    unsafe {
        let mut set: libc::cpu_set_t = std::mem::zeroed();
        libc::CPU_SET(cpu, &mut set);
        command.pre_exec(move || {
            if libc::sched_setaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), &set) != 0 {
                return Err(std::io::Error::last_os_error());
            }
            Ok(())
        });
    }
}

/// utime + stime of a process, s.
fn cpu_s(pid: u32) -> Option<f64> {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).ok()?;
    // Fields after the command name, which is in parentheses.
    let rest = &stat[stat.rfind(')')? + 2..];
    let f: Vec<&str> = rest.split_whitespace().collect();
    // SAFETY: sysconf has no preconditions.
    let ticks = unsafe { libc::sysconf(libc::_SC_CLK_TCK) } as f64;
    Some((f[11].parse::<f64>().ok()? + f[12].parse::<f64>().ok()?) / ticks)
}

fn rss_mib(pid: u32) -> Option<f64> {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).ok()?;
    let kib: f64 = status
        .lines()
        .find(|l| l.starts_with("VmRSS:"))?
        .split_whitespace()
        .nth(1)?
        .parse()
        .ok()?;
    Some(kib / 1024.0)
}

fn main() {
    let a = args();
    let dataset = a.dataset.canonicalize().unwrap_or_else(|e| {
        panic!("dataset {}: {e}", a.dataset.display());
    });
    let span_s = sequence_s(&dataset);
    let loops = a
        .minutes
        .map_or(1, |m| ((m * 60.0 / span_s).ceil() as u32).max(1));
    let dir = tempfile::tempdir().expect("temp dir");
    let root = dir.path().join("iox");
    let prefix = format!("rigslam_bench_daemon_{}", std::process::id());
    let config = dir.path().join("rig.toml");
    let mode = a
        .mode
        .as_ref()
        .map(|m| format!("[slam]\nmode = {m:?}\n"))
        .unwrap_or_default();
    let mut absolute_lines = a.absolute_settings.clone();
    if a.relative_only {
        absolute_lines.push("enabled = false".into());
    }
    let absolute = if absolute_lines.is_empty() {
        String::new()
    } else {
        format!("[slam.absolute]\n{}\n", absolute_lines.join("\n"))
    };
    let relative = if a.relative_settings.is_empty() {
        String::new()
    } else {
        format!("[slam.relative]\n{}\n", a.relative_settings.join("\n"))
    };
    let map_path = dir.path().join("map.txt");
    let map = if a.map {
        format!(
            "[map]\npath = {:?}\nsave_every_s = 60.0\n",
            map_path.display().to_string()
        )
    } else {
        String::new()
    };
    std::fs::write(
        &config,
        format!(
            "[camera]\nsource = \"replay\"\n[imu]\nsource = \"replay\"\n\
             [replay]\ndataset = {:?}\nloops = {loops}\n{mode}{relative}{absolute}\
             [publish]\nservice_prefix = {prefix:?}\nroot_path = {:?}\n{map}",
            dataset.display().to_string(),
            root.display().to_string()
        ),
    )
    .expect("write config");
    std::fs::create_dir_all(&root).expect("iceoryx2 root");
    let report_path = dir.path().join("report.json");

    // Subscribers first, so that they see the first sample.
    let tum_args: Vec<std::ffi::OsString> = match &a.tum_dir {
        Some(d) => {
            std::fs::create_dir_all(d).expect("--tum-dir");
            vec![
                "--tum".into(),
                d.join("pose.tum").into(),
                "--tum-odom".into(),
                d.join("pose_odom.tum").into(),
            ]
        }
        None => Vec::new(),
    };
    let pose = echo(&format!("{prefix}/pose"), &root, &tum_args);
    let fast = echo(&format!("{prefix}/pose_fast"), &root, &[]);
    std::thread::sleep(Duration::from_millis(500));
    let log_path = dir.path().join("rigslamd.log");
    let log = std::fs::File::create(&log_path).expect("daemon log");
    let mut command = Command::new(
        a.daemon
            .clone()
            .unwrap_or_else(|| PathBuf::from(env!("CARGO_BIN_EXE_rigslamd"))),
    );
    command
        .arg("--config")
        .arg(&config)
        .arg("--report")
        .arg(&report_path)
        .env("RUST_LOG", if a.map { "info" } else { "warn" })
        .stdout(Stdio::null())
        .stderr(log);
    if let Some(cpu) = a.cpu {
        pin_to(&mut command, cpu);
    }
    let mut daemon = command.spawn().expect("start rigslamd");
    let pid = daemon.id();
    let started = Instant::now();
    let sample_every = if loops > 1 {
        Duration::from_secs(10)
    } else {
        Duration::from_secs(1)
    };
    let mut memory = Vec::new();
    let mut last_cpu = (0.0, 0.0);
    let mut next = started;
    loop {
        if let Some(status) = daemon.try_wait().expect("poll rigslamd") {
            if !status.success() {
                let log = std::fs::read_to_string(&log_path).unwrap_or_default();
                let tail: Vec<&str> = log.lines().rev().take(20).collect();
                panic!(
                    "rigslamd failed: {status:?}; its last log lines:\n{}",
                    tail.into_iter().rev().collect::<Vec<_>>().join("\n")
                );
            }
            break;
        }
        if Instant::now() >= next {
            next += sample_every;
            let t = started.elapsed().as_secs_f64();
            if let (Some(rss), Some(cpu)) = (rss_mib(pid), cpu_s(pid)) {
                memory.push(serde_json::json!({"t_s": t, "rss_mib": rss, "cpu_s": cpu}));
                last_cpu = (t, cpu);
                if loops > 1 {
                    eprint!("\r{:.0} s: RSS {rss:.1} MiB, CPU {cpu:.1} s   ", t);
                    let _ = std::io::stderr().flush();
                }
            }
        }
        std::thread::sleep(Duration::from_millis(100));
    }
    let wall_s = started.elapsed().as_secs_f64();
    let echo_report = |c: Child| -> serde_json::Value {
        let out = c.wait_with_output().expect("echo output");
        assert!(out.status.success(), "rigslam echo failed");
        serde_json::from_slice(&out.stdout).expect("echo prints one JSON object")
    };
    let pose = echo_report(pose);
    let fast = echo_report(fast);
    let daemon_report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&report_path).expect("report"))
            .expect("report JSON");

    let rss: Vec<f64> = memory
        .iter()
        .filter_map(|m| m["rss_mib"].as_f64())
        .collect();
    // Flatness: the first sample after a minute (warm-up done) against the last.
    let warm = memory
        .iter()
        .find(|m| m["t_s"].as_f64().unwrap_or(0.0) >= 60.0)
        .and_then(|m| m["rss_mib"].as_f64());
    let saves = map_saves(&std::fs::read_to_string(&log_path).unwrap_or_default());
    let out = serde_json::json!({
        "dataset": dataset,
        "absolute": !a.relative_only,
        "cpu": a.cpu,
        "sequence_s": span_s,
        "loops": loops,
        "wall_s": wall_s,
        "frames": daemon_report["frames"],
        "imu_samples": daemon_report["imu_samples"],
        "poses": daemon_report["poses"],
        "poses_fast": daemon_report["poses_fast"],
        "drops": [daemon_report["frame_drops"], daemon_report["imu_drops"], daemon_report["pose_drops"]],
        "frame_to_pose_p50_us": daemon_report["latency_p50_us"],
        "frame_to_pose_p99_us": daemon_report["latency_p99_us"],
        "frame_to_pose_max_us": daemon_report["latency_max_us"],
        "pose_received": pose["received"],
        "pose_missed": pose["missed"],
        "pose_rate_hz": pose["rate_hz"],
        "pose_transport_p50_us": pose["transport_latency_p50_us"],
        "pose_transport_p99_us": pose["transport_latency_p99_us"],
        "pose_fast_received": fast["received"],
        "pose_fast_missed": fast["missed"],
        "pose_fast_rate_hz": fast["rate_hz"],
        "pose_fast_transport_p50_us": fast["transport_latency_p50_us"],
        "pose_fast_transport_p99_us": fast["transport_latency_p99_us"],
        "cpu_s": daemon_report["cpu_s"],
        "cpu_per_wall_s": daemon_report["cpu_per_wall_s"],
        "cpu_per_wall_s_sampled": if last_cpu.0 > 0.0 { last_cpu.1 / last_cpu.0 } else { 0.0 },
        "peak_rss_mib": daemon_report["peak_rss_mib"],
        "rss_first_mib": rss.first(),
        "rss_after_1_min_mib": warm,
        "rss_last_mib": rss.last(),
        "rss_max_mib": rss.iter().cloned().fold(f64::NAN, f64::max),
        "memory": if loops > 1 { serde_json::Value::Array(memory) } else { serde_json::Value::Null },
        "map": daemon_report["map"],
        "map_saves": saves,
    });
    if loops > 1 {
        eprintln!();
    }
    println!("{out}");
}
