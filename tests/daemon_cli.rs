//! `rigslamd` as a process: --check-config's messages, SIGTERM in the
//! middle of a recording, SIGHUP reloading the calibration, SIGKILL and a
//! restart over the dead process's shared memory, systemd's notify
//! protocol, subscribers crashing while it publishes.
//!
//! Every test uses its own iceoryx2 root path and service prefix.

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use rigslam::publish::{IpcConfig, PoseSubscriber};
use rigslam::shared_data;

#[path = "common/daemon.rs"]
mod daemon;
use daemon::{rigslamd, Daemon};

fn euroc() -> Option<PathBuf> {
    shared_data::path_or_skip("euroc/V1_01_micro")
}

fn private_ipc(test: &str, root: &Path) -> IpcConfig {
    IpcConfig {
        service_prefix: format!("rigslamd_test_{}_{test}", std::process::id()),
        root_path: Some(root.to_path_buf()),
        group: None,
    }
}

fn replay_command(dataset: &Path, ipc: &IpcConfig) -> Command {
    let mut c = rigslamd();
    c.arg("--replay")
        .arg(dataset)
        .arg("--service-prefix")
        .arg(&ipc.service_prefix)
        .arg("--root-path")
        .arg(ipc.root_path.as_ref().expect("root path"));
    c
}

/// `dir/rig.toml`: a replay of `dataset` published under a private
/// prefix and root in `dir/iox`; `rest` goes after the `[replay]` table's
/// `dataset` key (more of its keys, then further tables).
fn write_replay_config(test: &str, dir: &Path, dataset: &Path, rest: &str) -> PathBuf {
    let ipc = private_ipc(test, &dir.join("iox"));
    let config = dir.join("rig.toml");
    std::fs::write(
        &config,
        format!(
            "[camera]\nsource = \"replay\"\n[imu]\nsource = \"replay\"\n\
             [replay]\ndataset = {:?}\n{rest}\
             [publish]\nservice_prefix = {:?}\nroot_path = {:?}\n",
            dataset.display().to_string(),
            ipc.service_prefix,
            dir.join("iox").display().to_string()
        ),
    )
    .expect("write config");
    config
}

fn check_config(text: &str, dir: &Path) -> (bool, String) {
    let path = dir.join("rig.toml");
    std::fs::write(&path, text).expect("write config");
    let out = rigslamd()
        .arg("--config")
        .arg(&path)
        .arg("--check-config")
        .output()
        .expect("run rigslamd");
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stderr).into_owned() + &String::from_utf8_lossy(&out.stdout),
    )
}

#[test]
fn check_config_names_file_key_and_why() {
    let dir = tempfile::tempdir().expect("tempdir");
    let file = dir.path().join("rig.toml");
    let file = file.display().to_string();

    let (ok, out) = check_config(
        "[camera]\nsourse = \"v4l2\"\n[imu]\nsource = \"yei\"\n",
        dir.path(),
    );
    assert!(!ok);
    assert!(out.contains(&file) && out.contains("sourse"), "{out}");

    let (ok, out) = check_config(
        "[camera]\nsource = \"v4l2\"\n[imu]\nsource = \"yei\"\nrate_hz = 5000\n\
         [calibration]\ncameras = [\"missing.yaml\"]\n[slam]\nmode = \"stereo-inertial\"\n\
         [pipeline]\nframe_queue = 0\n",
        dir.path(),
    );
    assert!(!ok);
    for key in [
        "camera.device",
        "imu.port",
        "imu.rate_hz",
        "slam.mode",
        "pipeline.frame_queue",
        "calibration.cameras[0]",
        "calibration.imu",
    ] {
        assert!(
            out.contains(&format!("{file}: {key}: ")),
            "no {key} in:\n{out}"
        );
    }
    assert!(out.contains("missing.yaml"), "{out}");

    // A publishing group that does not exist: the key, the group, the fix.
    let (ok, out) = check_config(
        "[camera]\nsource = \"v4l2\"\ndevice = \"/dev/video0\"\n[imu]\nsource = \"yei\"\n\
         port = \"/dev/ttyACM0\"\n[publish]\ngroup = \"rsl_no_such_group\"\n",
        dir.path(),
    );
    assert!(!ok);
    assert!(
        out.contains(&format!("{file}: publish.group: "))
            && out.contains("rsl_no_such_group")
            && out.contains("groupadd"),
        "{out}"
    );

    // A calibration file that lacks a field: the file and the field.
    let Some(euroc) = euroc() else {
        return;
    };
    let cam = std::fs::read_to_string(euroc.join("mav0/cam0/sensor.yaml")).expect("cam0");
    let broken: String = cam
        .lines()
        .filter(|l| !l.starts_with("intrinsics"))
        .collect::<Vec<_>>()
        .join("\n");
    std::fs::write(dir.path().join("cam0.yaml"), broken).expect("write");
    std::fs::copy(
        euroc.join("mav0/imu0/sensor.yaml"),
        dir.path().join("imu0.yaml"),
    )
    .expect("copy");
    let (ok, out) = check_config(
        "[camera]\nsource = \"v4l2\"\ndevice = \"/dev/video0\"\n[imu]\nsource = \"yei\"\nport = \"/dev/ttyACM0\"\n\
         [calibration]\ncameras = [\"cam0.yaml\"]\nimu = \"imu0.yaml\"\n[slam]\nmode = \"mono-inertial\"\n",
        dir.path(),
    );
    assert!(!ok);
    assert!(
        out.contains("calibration.cameras[0]")
            && out.contains("cam0.yaml")
            && out.contains("intrinsics"),
        "{out}"
    );
    // The same with the field back is valid.
    std::fs::write(dir.path().join("cam0.yaml"), &cam).expect("write");
    let (ok, out) = check_config(
        "[camera]\nsource = \"v4l2\"\ndevice = \"/dev/video0\"\n[imu]\nsource = \"yei\"\nport = \"/dev/ttyACM0\"\n\
         [calibration]\ncameras = [\"cam0.yaml\"]\nimu = \"imu0.yaml\"\n[slam]\nmode = \"mono-inertial\"\n",
        dir.path(),
    );
    assert!(ok, "{out}");
    // A calibration from another camera: the size asked for, and a
    // replayed folder's images, against the calibrated resolution.
    let (ok, out) = check_config(
        "[camera]\nsource = \"v4l2\"\ndevice = \"/dev/video0\"\nwidth = 640\nheight = 480\n[imu]\nsource = \"yei\"\nport = \"/dev/ttyACM0\"\n\
         [calibration]\ncameras = [\"cam0.yaml\"]\nimu = \"imu0.yaml\"\n[slam]\nmode = \"mono-inertial\"\n",
        dir.path(),
    );
    assert!(!ok);
    assert!(
        out.contains("camera.width") && out.contains("640x480") && out.contains("752x480"),
        "{out}"
    );
    let replay = |camera_file: &str| {
        format!(
            "[camera]\nsource = \"replay\"\n[imu]\nsource = \"replay\"\n[replay]\ndataset = \"{}\"\n\
             [calibration]\ncameras = [\"{camera_file}\"]\nimu = \"imu0.yaml\"\n[slam]\nmode = \"mono\"\n",
            euroc.display()
        )
    };
    let (ok, out) = check_config(&replay("cam0.yaml"), dir.path());
    assert!(ok, "the EuRoC folder matches its own calibration: {out}");
    assert!(cam.contains("resolution: [752, 480]"), "{cam}");
    std::fs::write(
        dir.path().join("small.yaml"),
        cam.replace("resolution: [752, 480]", "resolution: [640, 480]"),
    )
    .expect("write");
    let (ok, out) = check_config(&replay("small.yaml"), dir.path());
    assert!(!ok);
    assert!(
        out.contains("has 752x480 images") && out.contains("640x480 camera"),
        "{out}"
    );
}

#[test]
fn bundled_replay_config_is_valid() {
    if euroc().is_none() {
        return;
    }
    let out = rigslamd()
        .arg("--config")
        .arg(Path::new(env!("CARGO_MANIFEST_DIR")).join("systemd/replay-euroc.toml"))
        .arg("--check-config")
        .output()
        .expect("run");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

#[test]
fn sigterm_mid_recording_leaves_a_complete_recording() {
    let Some(dataset) = euroc() else {
        return;
    };
    let root = tempfile::tempdir().expect("tempdir");
    let rec = tempfile::tempdir().expect("tempdir");
    let ipc = private_ipc("sigterm", root.path());
    let mut command = replay_command(&dataset, &ipc);
    command.arg("--record").arg(rec.path());
    let mut daemon = Daemon::start(command);
    // At recorded pace the 4.7 s sequence is still running after 2 s.
    daemon.wait_for("recording to", Duration::from_secs(20));
    std::thread::sleep(Duration::from_secs(2));
    daemon.signal(libc::SIGTERM);
    let status = daemon.wait_exit(Duration::from_secs(20));
    assert!(status.success(), "{status:?}\n{}", daemon.log());
    assert!(daemon.log().contains("stop requested"), "{}", daemon.log());
    let files = rigslam::daemon::recorder::list_recordings(rec.path());
    assert_eq!(files.len(), 1, "{files:?}");
    // The summary is only there when the file was closed properly.
    let counts = rigslam::recording::channel_counts(&files[0].0).expect("complete MCAP");
    let poses = counts.get("/rigslam/pose").copied().unwrap_or(0);
    let frames = counts.get("/cam0").copied().unwrap_or(0);
    assert!(poses > 5 && poses < 95, "{counts:?}");
    assert!(frames >= poses, "{counts:?}");
    assert!(
        counts.get("/imu0").copied().unwrap_or(0) > 200,
        "{counts:?}"
    );
    let read = rigslam::recording::read_pose_channel(&files[0].0, "/rigslam/pose").expect("read");
    assert_eq!(read.len() as u64, poses);
}

#[test]
fn sighup_reloads_the_calibration_and_refuses_a_broken_one() {
    let Some(dataset) = euroc() else {
        return;
    };
    let dir = tempfile::tempdir().expect("tempdir");
    for (from, to) in [
        ("cam0", "cam0.yaml"),
        ("cam1", "cam1.yaml"),
        ("imu0", "imu0.yaml"),
    ] {
        std::fs::copy(
            dataset.join(format!("mav0/{from}/sensor.yaml")),
            dir.path().join(to),
        )
        .expect("copy calibration");
    }
    let config = write_replay_config(
        "sighup",
        dir.path(),
        &dataset,
        "[calibration]\ncameras = [\"cam0.yaml\", \"cam1.yaml\"]\nimu = \"imu0.yaml\"\n",
    );
    let report = dir.path().join("report.json");
    let mut command = rigslamd();
    command
        .arg("--config")
        .arg(&config)
        .arg("--report")
        .arg(&report);
    let mut daemon = Daemon::start(command);
    daemon.wait_for("publishing", Duration::from_secs(20));
    std::thread::sleep(Duration::from_millis(800));
    daemon.signal(libc::SIGHUP);
    daemon.wait_for("reloading the calibration", Duration::from_secs(5));
    daemon.wait_for("calibration reloaded", Duration::from_secs(5));
    // Break the IMU file: the reload is refused, the daemon goes on.
    std::fs::write(dir.path().join("imu0.yaml"), "rate_hz: -3\n").expect("write");
    daemon.signal(libc::SIGHUP);
    daemon.wait_for("reload refused", Duration::from_secs(5));
    assert!(daemon.log().contains("imu0.yaml"), "{}", daemon.log());
    // The config gone: refused too, its cause said once.
    std::fs::rename(&config, dir.path().join("moved.toml")).expect("move");
    daemon.signal(libc::SIGHUP);
    daemon.wait_for("No such file", Duration::from_secs(5));
    let log = daemon.log();
    assert_eq!(log.matches("No such file or directory").count(), 1, "{log}");
    let status = daemon.wait_exit(Duration::from_secs(30));
    assert!(status.success(), "{}", daemon.log());
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&report).expect("report")).expect("json");
    assert_eq!(report["frames"], 95, "{report}");
    assert_eq!(report["poses"], report["frames"], "{report}");
}

/// The map as a user meets it: `[map] path` in the config; the first
/// start builds a map, `systemctl reload` (SIGHUP) saves it and goes on
/// localising in it, SIGTERM saves it again; the next start localises in
/// it from the beginning and says so.
#[test]
fn the_map_is_saved_on_reload_and_stop_and_the_next_start_localises_in_it() {
    let Some(dataset) = euroc() else {
        return;
    };
    let dir = tempfile::tempdir().expect("tempdir");
    let config = write_replay_config(
        "map",
        dir.path(),
        &dataset,
        // The clip rests and then barely turns: with the default wait for
        // the accelerometer bias nothing would be mapped (`rigslam run`
        // says so: run_real.rs); this test is about saving and loading.
        "loops = 2\n[slam.absolute]\nwait_accel_bias = \"off\"\n\
         [map]\npath = \"robot.map\"\nsave_every_s = 0.2\n",
    );
    let map = dir.path().join("robot.map");
    let report = dir.path().join("report.json");
    let start = || {
        let mut command = rigslamd();
        command
            .arg("--config")
            .arg(&config)
            .arg("--report")
            .arg(&report);
        Daemon::start(command)
    };
    let mut daemon = start();
    daemon.wait_for("building a new map", Duration::from_secs(20));
    // The sequence is nearly still: the first map exists at its end, so
    // it is played twice (at recorded pace, 9.5 s) and reloaded in the
    // second pass.
    daemon.wait_for("map saved", Duration::from_secs(20));
    daemon.signal(libc::SIGHUP);
    daemon.wait_for("calibration reloaded", Duration::from_secs(10));
    let saved_on_reload = rigslam::absolute::map_file::SavedMap::read(&map);
    daemon.signal(libc::SIGTERM);
    let status = daemon.wait_exit(Duration::from_secs(30));
    assert!(status.success(), "{}", daemon.log());
    let saved_on_reload = saved_on_reload
        .unwrap_or_else(|e| panic!("no whole map after the reload: {e}\n{}", daemon.log()));
    assert!(!saved_on_reload.landmarks.is_empty(), "{}", daemon.log());
    let read = |path: &Path| -> serde_json::Value {
        serde_json::from_str(&std::fs::read_to_string(path).expect("report")).expect("json")
    };
    let first = read(&report);
    // Reloaded, the daemon localises in the map it has just saved.
    assert!(
        first["map"]
            .as_str()
            .is_some_and(|m| m.contains("localising")),
        "{first}"
    );
    assert!(first["map_saves"].as_u64() >= Some(1), "{first}");
    rigslam::absolute::map_file::SavedMap::read(&map).expect("a whole map after SIGTERM");

    let mut daemon = start();
    daemon.wait_for("localising in the saved map", Duration::from_secs(20));
    let status = daemon.wait_exit(Duration::from_secs(30));
    assert!(status.success(), "{}", daemon.log());
    let second = read(&report);
    assert_eq!(second["frames"], 190, "{second}");
    assert!(
        second["map"]
            .as_str()
            .is_some_and(|m| m.contains("localising")),
        "{second}"
    );
}

#[test]
fn sigkill_and_restart_cleans_the_dead_process_shared_memory() {
    let Some(dataset) = euroc() else {
        return;
    };
    let root = tempfile::tempdir().expect("tempdir");
    let ipc = private_ipc("sigkill", root.path());
    // No subscriber of this test's own meanwhile: a node of this process
    // would notice the dead one and clean it up before the restart can.
    let mut first = Daemon::start(replay_command(&dataset, &ipc));
    first.wait_for("ready:", Duration::from_secs(20));
    first.signal(libc::SIGKILL);
    let status = first.wait_exit(Duration::from_secs(10));
    assert!(!status.success());

    let mut second = Daemon::start(replay_command(&dataset, &ipc));
    second.wait_for("publishing", Duration::from_secs(20));
    assert!(
        second
            .log()
            .contains("removed the stale resources of 1 dead process"),
        "{}",
        second.log()
    );
    let mut poses = PoseSubscriber::pose(&ipc).expect("subscribe again");
    assert!(
        poses
            .wait_newest(Duration::from_secs(20))
            .expect("wait")
            .is_some(),
        "no pose from the restarted daemon:\n{}",
        second.log()
    );
    second.signal(libc::SIGTERM);
    assert!(
        second.wait_exit(Duration::from_secs(20)).success(),
        "{}",
        second.log()
    );
}

#[test]
fn systemd_hears_ready_status_and_watchdog_pings() {
    let Some(dataset) = euroc() else {
        return;
    };
    let dir = tempfile::tempdir().expect("tempdir");
    let socket_path = dir.path().join("notify");
    let socket = std::os::unix::net::UnixDatagram::bind(&socket_path).expect("bind");
    socket
        .set_read_timeout(Some(Duration::from_millis(200)))
        .expect("timeout");
    let ipc = private_ipc("notify", &dir.path().join("iox"));
    let mut command = replay_command(&dataset, &ipc);
    command
        .env("NOTIFY_SOCKET", &socket_path)
        .env("WATCHDOG_USEC", "2000000");
    let mut daemon = Daemon::start(command);
    let mut messages = Vec::new();
    let mut buf = [0u8; 4096];
    let deadline = Instant::now() + Duration::from_secs(30);
    while daemon.child.try_wait().expect("try_wait").is_none() && Instant::now() < deadline {
        if let Ok(n) = socket.recv(&mut buf) {
            messages.push(String::from_utf8_lossy(&buf[..n]).into_owned());
        }
    }
    assert!(
        daemon.wait_exit(Duration::from_secs(5)).success(),
        "{}",
        daemon.log()
    );
    let ready = messages
        .iter()
        .position(|m| m.contains("READY=1"))
        .unwrap_or_else(|| panic!("no READY=1 in {messages:?}"));
    assert!(
        messages[ready].contains("STATUS=camera"),
        "{}",
        messages[ready]
    );
    let pings = messages.iter().filter(|m| *m == "WATCHDOG=1").count();
    // 4.7 s of replay, pinged at least every WATCHDOG_USEC / 4.
    assert!(pings >= 8, "{pings} watchdog pings in {messages:?}");
    assert!(messages.iter().any(|m| m == "STOPPING=1"), "{messages:?}");
}

#[test]
fn subscribers_that_crash_do_not_disturb_the_publisher() {
    let Some(dataset) = euroc() else {
        return;
    };
    let dir = tempfile::tempdir().expect("tempdir");
    let ipc = private_ipc("crash", &dir.path().join("iox"));
    let report = dir.path().join("report.json");
    // A subscriber of this test, there from before the first sample to the
    // end, on its own thread (iceoryx2 ports stay on the thread that made
    // them): every fast pose, no gap, whatever the others do.
    let (ready_tx, ready_rx) = std::sync::mpsc::channel();
    let watcher = {
        let ipc = ipc.clone();
        std::thread::spawn(move || {
            let mut fast = PoseSubscriber::pose_fast(&ipc).expect("subscribe");
            ready_tx.send(()).expect("test waits");
            let mut got = Vec::new();
            // The first pose within 30 s; then quiet for 3 s: the daemon
            // has finished.
            let mut quiet = Duration::from_secs(30);
            while fast.wait(quiet).expect("wait") {
                fast.take_all(&mut got).expect("take");
                quiet = Duration::from_secs(3);
            }
            (got.len() as u64, fast.missed())
        })
    };
    ready_rx.recv().expect("watcher subscribed");
    let mut command = replay_command(&dataset, &ipc);
    command.arg("--report").arg(&report);
    let mut daemon = Daemon::start(command);
    daemon.wait_for("publishing", Duration::from_secs(20));
    // More crashes than iceoryx2's default of 8 subscribers per service:
    // the dead ones' ports must not use up the places.
    let crashes = 10;
    for i in 0..crashes {
        let mut echo = Command::new(env!("CARGO_BIN_EXE_rigslam"))
            .arg("echo")
            .arg("--service")
            .arg(format!("{}/pose_fast", ipc.service_prefix))
            .arg("--root-path")
            .arg(ipc.root_path.as_ref().expect("root path"))
            .arg("--timeout-s")
            .arg("20")
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .expect("start rigslam echo");
        // One printed pose: it is subscribed and holding samples.
        let mut line = String::new();
        BufReader::new(echo.stdout.take().expect("piped"))
            .read_line(&mut line)
            .expect("read echo");
        assert!(
            !line.is_empty(),
            "subscriber {i} printed nothing:\n{}",
            daemon.log()
        );
        echo.kill().expect("SIGKILL the subscriber");
        echo.wait().expect("reap");
    }
    assert!(
        daemon.child.try_wait().expect("try_wait").is_none(),
        "the daemon ended while its subscribers crashed:\n{}",
        daemon.log()
    );
    let status = daemon.wait_exit(Duration::from_secs(30));
    assert!(status.success(), "{}", daemon.log());
    let (received, missed) = watcher.join().expect("watcher");
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&report).expect("report")).expect("json");
    assert_eq!(report["pose_drops"], 0, "{report}");
    assert_eq!(missed, 0, "the steady subscriber missed fast poses");
    assert_eq!(
        Some(received),
        report["poses_fast"].as_u64(),
        "{report}\n{}",
        daemon.log()
    );
}

#[test]
fn a_recording_replays_with_the_shorthand() {
    let Some(dataset) = euroc() else {
        return;
    };
    let dir = tempfile::tempdir().expect("tempdir");
    let ipc = private_ipc("mcap", &dir.path().join("iox"));
    let rec = dir.path().join("rec");
    let mut record = replay_command(&dataset, &ipc);
    record
        .arg("--as-fast-as-possible")
        .arg("--record")
        .arg(&rec);
    let mut first = Daemon::start(record);
    assert!(
        first.wait_exit(Duration::from_secs(60)).success(),
        "{}",
        first.log()
    );
    let files = rigslam::daemon::recorder::list_recordings(&rec);
    assert_eq!(files.len(), 1, "{files:?}");

    // `--replay FILE.mcap`: mode and calibration from the recording.
    let report = dir.path().join("report.json");
    let mut replay = replay_command(&files[0].0, &ipc);
    replay
        .arg("--as-fast-as-possible")
        .arg("--report")
        .arg(&report);
    let mut second = Daemon::start(replay);
    assert!(
        second.wait_exit(Duration::from_secs(60)).success(),
        "{}",
        second.log()
    );
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&report).expect("report")).expect("json");
    assert_eq!(report["frames"], 95, "{report}");
    assert_eq!(report["poses"], 95, "{report}");
    assert_eq!(report["imu_samples"], 942, "{report}");
    // No colour codes where stderr is not a terminal (the journal).
    assert!(!second.log().contains('\x1b'), "{}", second.log());

    // A recording whose middle chunk is damaged (one byte of its
    // compressed data changed): the replay skips that chunk, says which
    // once, plays the rest to the end and counts it in the report.
    let bytes = std::fs::read(&files[0].0).expect("read");
    let summary = mcap::Summary::read(&bytes)
        .expect("summary")
        .expect("a closed file");
    let chunks = &summary.chunk_indexes;
    assert!(chunks.len() >= 3, "{} chunks", chunks.len());
    let middle = &chunks[chunks.len() / 2];
    let at = (middle.chunk_start_offset + middle.chunk_length / 2) as usize;
    let mut damaged = bytes.clone();
    damaged[at] ^= 0x20;
    let damaged_path = dir.path().join("damaged.mcap");
    std::fs::write(&damaged_path, &damaged).expect("write");
    let report = dir.path().join("damaged.json");
    let mut replay = replay_command(&damaged_path, &ipc);
    replay
        .arg("--as-fast-as-possible")
        .arg("--report")
        .arg(&report);
    let mut third = Daemon::start(replay);
    let status = third.wait_exit(Duration::from_secs(60));
    let log = third.log();
    assert!(status.success(), "{log}");
    let chunk = format!("chunk at byte {}", middle.chunk_start_offset);
    assert_eq!(log.matches(&chunk).count(), 1, "named once:\n{log}");
    assert!(log.contains("its messages are skipped"), "{log}");
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&report).expect("report")).expect("json");
    assert_eq!(report["replay_damaged"], 1, "{report}");
    assert_eq!(report["replay_cut"], false, "{report}");
    let frames = report["frames"].as_u64().expect("frames");
    assert!((60..95).contains(&frames), "{report}");

    // A file that is not MCAP at all: refused by name, once, with a
    // failure status.
    let junk = dir.path().join("junk.mcap");
    std::fs::write(&junk, vec![7u8; 4096]).expect("write");
    let mut replay = replay_command(&junk, &ipc);
    replay.arg("--as-fast-as-possible");
    let mut fourth = Daemon::start(replay);
    let status = fourth.wait_exit(Duration::from_secs(60));
    let log = fourth.log();
    assert!(!status.success(), "{log}");
    assert!(log.contains("not an MCAP file"), "{log}");
    assert_eq!(log.matches("junk.mcap").count(), 1, "said once:\n{log}");
}

/// A daemon that cannot start says why once and exits non-zero: the
/// cause ("No such file or directory") used to be printed a second time,
/// as the source of an error that already carried it.
#[test]
fn a_failed_start_says_its_error_once() {
    let dir = tempfile::tempdir().expect("tempdir");
    let missing = dir.path().join("missing");
    for (flag, path) in [
        ("--config", missing.join("rig.toml")),
        ("--replay", missing.join("recording.mcap")),
        ("--replay", missing.join("euroc")),
    ] {
        let out = rigslamd()
            .arg(flag)
            .arg(&path)
            .output()
            .expect("run rigslamd");
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "{flag} {}: {err}", path.display());
        assert_eq!(
            err.matches("No such file or directory").count(),
            1,
            "{flag} {}: {err}",
            path.display()
        );
        assert!(err.contains(&*path.to_string_lossy()), "{err}");
    }
}
