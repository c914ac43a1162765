//! Poses for the daemon's group and nobody else, across real users: the
//! daemon (`rigslamd` replaying EuRoC) runs as user A of group G; B in G
//! receives every pose and fast pose with `rigslam echo`; C outside G is
//! refused with a message that names G and `usermod -aG`; B cannot get a
//! publisher nor write the payload; a name taken by B before the daemon
//! starts stops the daemon with a message instead of a silent takeover.
//! Once with a strict umask and the root directly in a temp folder, once
//! with the systemd unit's settings (UMask=0022, a RuntimeDirectory of
//! A:G mode 0750 holding the root).
//!
//! Creating users needs root: the tests skip with a reason otherwise (CI
//! runs them as root). Users and the group are removed at the end, also
//! when a test fails.

use std::ffi::CString;
use std::os::unix::fs::{MetadataExt, PermissionsExt};
use std::os::unix::process::CommandExt;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use rigslam::shared_data;

#[path = "common/daemon.rs"]
mod daemon;
use daemon::collect;

// ---------------------------------------------------------------- accounts

/// A user as the kernel sees it: ids and supplementary groups.
#[derive(Debug, Clone)]
struct Identity {
    name: String,
    uid: u32,
    gid: u32,
    groups: Vec<u32>,
}

fn id_of(name: &str, flag: &str) -> Vec<u32> {
    let out = Command::new("id")
        .arg(flag)
        .arg(name)
        .output()
        .expect("run id");
    assert!(out.status.success(), "id {flag} {name}: {out:?}");
    String::from_utf8_lossy(&out.stdout)
        .split_whitespace()
        .map(|n| n.parse().expect("numeric id"))
        .collect()
}

fn id_of_opt(name: &str) -> Option<u32> {
    let out = Command::new("id").arg("-u").arg(name).output().ok()?;
    String::from_utf8_lossy(&out.stdout).trim().parse().ok()
}

impl Identity {
    fn of(name: &str) -> Self {
        Identity {
            name: name.to_string(),
            uid: id_of(name, "-u")[0],
            gid: id_of(name, "-g")[0],
            groups: id_of(name, "-G"),
        }
    }
}

fn run(program: &str, args: &[&str]) {
    let out = Command::new(program).args(args).output().expect(program);
    assert!(
        out.status.success(),
        "{program} {args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
}

/// A group G and users A (primary group G), B (in G), C (not), D (in G
/// until the test takes it out); all removed on drop.
struct Accounts {
    group: String,
    users: Vec<String>,
}

impl Accounts {
    fn create(tag: &str) -> Accounts {
        let pid = std::process::id();
        let name = |role: &str| format!("rsl_t_{role}_{pid}{tag}");
        let mut accounts = Accounts {
            group: name("g"),
            users: Vec::new(),
        };
        run("groupadd", &[&accounts.group]);
        for role in ["a", "b", "c", "d"] {
            let user = name(role);
            let mut args = vec!["-M", "-N", "-s", "/usr/sbin/nologin"];
            if role == "a" {
                args.extend(["-g", &accounts.group]);
            } else if role != "c" {
                args.extend(["-G", &accounts.group]);
            }
            args.push(&user);
            run("useradd", &args);
            accounts.users.push(user);
        }
        accounts
    }

    fn user(&self, role: usize) -> Identity {
        Identity::of(&self.users[role])
    }
}

impl Drop for Accounts {
    fn drop(&mut self) {
        // What the test users' processes left in /dev/shm (a killed
        // process, or a reader that may not remove the daemon's files).
        let uids: Vec<u32> = self.users.iter().filter_map(|u| id_of_opt(u)).collect();
        if let Ok(entries) = std::fs::read_dir("/dev/shm") {
            for entry in entries.flatten() {
                if entry.metadata().is_ok_and(|m| uids.contains(&m.uid())) {
                    let _ = std::fs::remove_file(entry.path());
                }
            }
        }
        for user in &self.users {
            let _ = Command::new("userdel").arg(user).output();
        }
        let _ = Command::new("groupdel").arg(&self.group).output();
    }
}

fn is_root() -> bool {
    // SAFETY: no arguments.
    unsafe { libc::geteuid() == 0 }
}

fn euroc() -> Option<PathBuf> {
    shared_data::path_or_skip("euroc/V1_01_micro")
}

/// `command` run as `who` (groups, gid, uid dropped in the child before
/// exec) with `umask`.
fn as_user(mut command: Command, who: &Identity, umask: u32) -> Command {
    let groups: Vec<libc::gid_t> = who.groups.clone();
    let (uid, gid) = (who.uid, who.gid);
    // SAFETY: only async-signal-safe system calls between fork and exec.
    unsafe {
        command.pre_exec(move || {
            if libc::setgroups(groups.len(), groups.as_ptr()) != 0
                || libc::setgid(gid) != 0
                || libc::setuid(uid) != 0
            {
                return Err(std::io::Error::last_os_error());
            }
            libc::umask(umask);
            Ok(())
        });
    }
    command.env("RUST_LOG", "info").env_remove("NOTIFY_SOCKET");
    command
}

fn chown(path: &Path, uid: u32, gid: u32) {
    let c = CString::new(path.as_os_str().as_encoded_bytes()).expect("path");
    // SAFETY: valid C string.
    assert_eq!(
        unsafe { libc::chown(c.as_ptr(), uid, gid) },
        0,
        "chown {path:?}"
    );
}

fn chmod(path: &Path, mode: u32) {
    std::fs::set_permissions(path, std::fs::Permissions::from_mode(mode)).expect("chmod");
}

// --------------------------------------------------------------- processes

/// A process whose stderr (and stdout) is collected as it comes.
struct Watched {
    child: Child,
    stdout: Arc<Mutex<String>>,
    stderr: Arc<Mutex<String>>,
}

impl Watched {
    fn start(mut command: Command) -> Watched {
        let mut child = command
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .expect("start process");
        let stdout = collect(child.stdout.take().expect("stdout"));
        let stderr = collect(child.stderr.take().expect("stderr"));
        Watched {
            child,
            stdout,
            stderr,
        }
    }

    fn stderr(&self) -> String {
        self.stderr.lock().expect("lock").clone()
    }

    fn wait_for(&self, text: &str, within: Duration) {
        let end = Instant::now() + within;
        while !self.stderr().contains(text) {
            assert!(
                Instant::now() < end,
                "no {text:?} within {within:?}; stderr:\n{}",
                self.stderr()
            );
            std::thread::sleep(Duration::from_millis(50));
        }
    }

    /// Waits for the exit; (success, stdout, stderr).
    fn finish(mut self, within: Duration) -> (bool, String, String) {
        let end = Instant::now() + within;
        let status = loop {
            if let Some(status) = self.child.try_wait().expect("try_wait") {
                break status;
            }
            if Instant::now() > end {
                let _ = self.child.kill();
                let _ = self.child.wait();
                panic!("still running after {within:?}; stderr:\n{}", self.stderr());
            }
            std::thread::sleep(Duration::from_millis(50));
        };
        // The reader threads end at EOF, right after the exit.
        std::thread::sleep(Duration::from_millis(200));
        let stdout = self.stdout.lock().expect("lock").clone();
        (status.success(), stdout, self.stderr())
    }
}

impl Drop for Watched {
    fn drop(&mut self) {
        if let Ok(None) = self.child.try_wait() {
            let _ = self.child.kill();
            let _ = self.child.wait();
        }
    }
}

fn wait_file(path: &Path, within: Duration, who: &Watched) {
    let end = Instant::now() + within;
    while !path.exists() {
        assert!(
            Instant::now() < end,
            "{path:?} not there within {within:?}; stderr:\n{}",
            who.stderr()
        );
        std::thread::sleep(Duration::from_millis(20));
    }
}

fn echo(service: &str, root: &Path, ready: &Path, quiet_s: f64) -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_rigslam"));
    c.arg("echo")
        .arg("--service")
        .arg(service)
        .arg("--root-path")
        .arg(root)
        .arg("--json")
        .arg("--timeout-s")
        .arg(quiet_s.to_string())
        .arg("--ready-file")
        .arg(ready);
    c
}

fn daemon_command(dataset: &Path, prefix: &str, root: &Path, report: &Path) -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_rigslamd"));
    c.arg("--replay")
        .arg(dataset)
        .arg("--service-prefix")
        .arg(prefix)
        .arg("--root-path")
        .arg(root)
        .arg("--report")
        .arg(report);
    c
}

/// The files of `uid` in /dev/shm with bits for others, or payload
/// segments (`*.data`) writable by the group.
fn files_open_to_others(uid: u32) -> Vec<String> {
    let mut open = Vec::new();
    for entry in std::fs::read_dir("/dev/shm").expect("/dev/shm").flatten() {
        let name = entry.file_name().to_string_lossy().into_owned();
        let Ok(m) = entry.metadata() else { continue };
        if m.uid() != uid || name.ends_with(".global_mgmt") {
            continue;
        }
        let mode = m.mode() & 0o777;
        if mode & 0o007 != 0 || name.ends_with(".data") && mode != 0o640 {
            open.push(format!("{name} {mode:o}"));
        }
    }
    open
}

fn json_number(json: &str, key: &str) -> u64 {
    let value: serde_json::Value =
        serde_json::from_str(json.trim()).unwrap_or_else(|e| panic!("not JSON ({e}): {json}"));
    value[key]
        .as_u64()
        .unwrap_or_else(|| panic!("no {key} in {json}"))
}

// ------------------------------------------------------ the child's side

/// What B tries in order to publish; run in a child as B (this test
/// binary again, `--exact attempts_to_publish --ignored`, told what to do
/// by the environment). Prints one line per attempt: `<what>: refused:
/// <why>` or `<what>: ALLOWED`.
#[test]
#[ignore = "run as another user by the access tests"]
fn attempts_to_publish() {
    use iceoryx2::prelude::*;
    use rigslam::publish::{IpcConfig, PoseMessage, PosePublisher};

    let (Ok(root), Ok(prefix)) = (std::env::var("RSL_ROOT"), std::env::var("RSL_PREFIX")) else {
        return;
    };
    let service = format!("{prefix}/pose");
    let mut config = iceoryx2::config::Config::default();
    let mut root_text = root.clone();
    root_text.push('/');
    config
        .global
        .set_root_path(&iceoryx2::prelude::Path::new(root_text.as_bytes()).expect("root"));
    let node = NodeBuilder::new()
        .config(&config)
        .signal_handling_mode(SignalHandlingMode::Disabled)
        .create::<ipc_threadsafe::Service>()
        .expect("B may create a node: it is in the group");
    let pubsub = node
        .service_builder(&ServiceName::new(&service).expect("name"))
        .publish_subscribe::<PoseMessage>()
        .open()
        .expect("B may open the service");
    match pubsub.publisher_builder().create() {
        Ok(_) => println!("iceoryx2 publisher: ALLOWED"),
        Err(e) => println!("iceoryx2 publisher: refused: {e:?}"),
    }
    let event = node
        .service_builder(&ServiceName::new(&service).expect("name"))
        .event()
        .open()
        .expect("B may open the event service");
    match event.notifier_builder().create() {
        Ok(_) => println!("iceoryx2 notifier: ALLOWED"),
        Err(e) => println!("iceoryx2 notifier: refused: {e:?}"),
    }
    let ipc = IpcConfig {
        service_prefix: prefix.clone(),
        root_path: Some(root.clone().into()),
        group: None,
    };
    match PosePublisher::open(&ipc) {
        Ok(_) => println!("rigslam publisher: ALLOWED"),
        Err(e) => println!("rigslam publisher: refused: {e}"),
    }
    // Writing into the daemon's payload segments directly.
    let mut segments = 0;
    for entry in std::fs::read_dir("/dev/shm").expect("/dev/shm").flatten() {
        let name = entry.file_name().to_string_lossy().into_owned();
        if !(name.starts_with("iox2_") && name.ends_with(".data")) {
            continue;
        }
        let owner = entry.metadata().map(|m| m.uid()).unwrap_or(0);
        if owner
            != std::env::var("RSL_DAEMON_UID")
                .ok()
                .and_then(|u| u.parse().ok())
                .unwrap_or(u32::MAX)
        {
            continue;
        }
        segments += 1;
        match std::fs::OpenOptions::new().write(true).open(entry.path()) {
            Ok(_) => println!("payload segment {name} for writing: ALLOWED"),
            Err(e) => println!("payload segment {name} for writing: refused: {e}"),
        }
    }
    println!("payload segments of the daemon: {segments}");
}

fn attempt_to_publish(b: &Identity, root: &Path, prefix: &str, daemon_uid: u32) -> String {
    let mut c = Command::new(std::env::current_exe().expect("test binary"));
    c.args([
        "--exact",
        "attempts_to_publish",
        "--ignored",
        "--nocapture",
        "--test-threads=1",
    ])
    .env("RSL_ROOT", root)
    .env("RSL_PREFIX", prefix)
    .env("RSL_DAEMON_UID", daemon_uid.to_string());
    let out: Output = as_user(c, b, 0o022)
        .output()
        .expect("run the attempts as B");
    let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
    assert!(
        out.status.success(),
        "the attempts failed to run:\n{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    stdout
}

/// examples/c/echo_pose.c built into the site; `None` without gcc.
fn c_example(site: &Site) -> Option<PathBuf> {
    if Command::new("gcc").arg("--version").output().is_err() {
        assert!(std::env::var_os("CI").is_none(), "gcc is missing on CI");
        eprintln!("no gcc: the C example's check is skipped");
        return None;
    }
    let repo = Path::new(env!("CARGO_MANIFEST_DIR"));
    let exe = site.flags.parent().expect("site").join("echo_pose");
    let build = Command::new("gcc")
        .args(["-std=c11", "-Wall", "-Wextra", "-Werror", "-I"])
        .arg(repo.join("include"))
        .arg(repo.join("examples/c/echo_pose.c"))
        .arg("-o")
        .arg(&exe)
        .output()
        .expect("run gcc");
    assert!(
        build.status.success(),
        "gcc: {}",
        String::from_utf8_lossy(&build.stderr)
    );
    chmod(&exe, 0o755);
    Some(exe)
}

// ---------------------------------------------------------------- scenario

/// Where the processes meet: a folder every test user can enter.
struct Site {
    _tmp: tempfile::TempDir,
    /// iceoryx2's root (publish.root_path).
    root: PathBuf,
    /// Ready files, world-writable.
    flags: PathBuf,
    /// The daemon's report.
    report: PathBuf,
}

fn site(a: &Identity, unit_settings: bool) -> Site {
    let tmp = tempfile::Builder::new()
        .prefix("rigslam-access")
        .tempdir_in("/tmp")
        .expect("temp dir");
    chmod(tmp.path(), 0o755);
    let flags = tmp.path().join("flags");
    std::fs::create_dir(&flags).expect("flags");
    chmod(&flags, 0o1777);
    let out = tmp.path().join("out");
    std::fs::create_dir(&out).expect("out");
    chown(&out, a.uid, a.gid);
    let root = if unit_settings {
        // RuntimeDirectory=rigslam with RuntimeDirectoryMode=0750: systemd
        // creates it for User= and Group= before the daemon starts.
        let run = tmp.path().join("run");
        std::fs::create_dir(&run).expect("run dir");
        chown(&run, a.uid, a.gid);
        chmod(&run, 0o750);
        run.join("iceoryx2")
    } else {
        // A folder of A's, as a home directory would be.
        let own = tmp.path().join("a");
        std::fs::create_dir(&own).expect("A's folder");
        chown(&own, a.uid, a.gid);
        chmod(&own, 0o755);
        own.join("iox")
    };
    Site {
        root,
        flags,
        report: out.join("report.json"),
        _tmp: tmp,
    }
}

fn group_access(unit_settings: bool) {
    if !is_root() {
        eprintln!("skipped: creating users and a group needs root (CI runs this as root)");
        return;
    }
    let Some(dataset) = euroc() else { return };
    let tag = if unit_settings { "u" } else { "p" };
    let accounts = Accounts::create(tag);
    let (a, b, c, d) = (
        accounts.user(0),
        accounts.user(1),
        accounts.user(2),
        accounts.user(3),
    );
    let group = accounts.group.clone();
    // The unit's UMask=0022; otherwise a strict one, to show it does not matter.
    let umask = if unit_settings { 0o022 } else { 0o077 };
    let site = site(&a, unit_settings);
    let prefix = format!("rsl_access_{}_{tag}", std::process::id());
    let pose = format!("{prefix}/pose");
    let pose_fast = format!("{prefix}/pose_fast");

    // A's own readers first: as the daemon's user they create the services
    // (and the root), so that B can subscribe before the first pose.
    let mut holders = Vec::new();
    for service in [&pose, &pose_fast] {
        let ready = site.flags.join(format!("a_{}", service.replace('/', "_")));
        // Done before B's readers (15 s): a reader of the group is the
        // last user of the services, which it may not remove.
        let w = Watched::start(as_user(echo(service, &site.root, &ready, 10.0), &a, umask));
        wait_file(&ready, Duration::from_secs(20), &w);
        holders.push(w);
    }

    // B (in G) subscribes to both pose streams.
    let mut readers = Vec::new();
    for (who, service) in [(&b, &pose), (&b, &pose_fast), (&d, &pose)] {
        let ready = site
            .flags
            .join(format!("{}_{}", who.name, service.replace('/', "_")));
        let w = Watched::start(as_user(echo(service, &site.root, &ready, 15.0), who, umask));
        wait_file(&ready, Duration::from_secs(20), &w);
        readers.push(w);
    }
    // D leaves the group while subscribed.
    run("gpasswd", &["-d", &d.name, &group]);

    let daemon = Watched::start(as_user(
        daemon_command(&dataset, &prefix, &site.root, &site.report),
        &a,
        umask,
    ));
    daemon.wait_for("publishing", Duration::from_secs(60));
    daemon.wait_for("group", Duration::from_secs(1));

    // C (not in G) is refused, and told which group and how to join.
    let ready_c = site.flags.join("c");
    let (ok, _, stderr) =
        Watched::start(as_user(echo(&pose, &site.root, &ready_c, 2.0), &c, umask))
            .finish(Duration::from_secs(30));
    assert!(!ok, "C is outside the group but subscribed:\n{stderr}");
    assert!(!ready_c.exists(), "C got as far as subscribing");
    assert!(stderr.contains("permission denied"), "{stderr}");
    assert!(!stderr.contains("InternalError"), "{stderr}");
    assert!(stderr.contains(&format!("group {group}")), "{stderr}");
    assert!(
        stderr.contains(&format!("usermod -aG {group} {}", c.name)),
        "{stderr}"
    );

    // A root that does not exist under a folder C may not write: said so.
    if !unit_settings {
        let elsewhere = site.root.with_file_name("not_yet");
        let ready = site.flags.join("c_elsewhere");
        let (ok, _, stderr) =
            Watched::start(as_user(echo(&pose, &elsewhere, &ready, 2.0), &c, umask))
                .finish(Duration::from_secs(30));
        assert!(!ok && stderr.contains("cannot create"), "{stderr}");
        assert!(stderr.contains("is not writable by"), "{stderr}");
        assert!(!stderr.contains("InternalError"), "{stderr}");
    }

    // The C example says the same for a C reader, and lets B in.
    if let Some(exe) = c_example(&site) {
        let check = |who: &Identity| {
            let mut c = Command::new(&exe);
            c.arg("--check-access").arg(&site.root);
            as_user(c, who, umask).output().expect("run echo_pose")
        };
        let out = check(&c);
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "C: {stderr}");
        assert!(
            stderr.contains(&format!("usermod -aG {group} {}", c.name)),
            "C: {stderr}"
        );
        let out = check(&b);
        assert!(
            out.status.success(),
            "B: {}",
            String::from_utf8_lossy(&out.stderr)
        );
    }

    // D, out of the group now, is refused a new subscription.
    let ready_d = site.flags.join("d_again");
    let (ok, _, stderr) = Watched::start(as_user(
        echo(&pose, &site.root, &ready_d, 2.0),
        &Identity::of(&d.name),
        umask,
    ))
    .finish(Duration::from_secs(30));
    assert!(
        !ok && stderr.contains(&format!("group {group}")),
        "{stderr}"
    );

    // B cannot publish: iceoryx2 gives the one publisher and the one
    // notifier to the daemon, rigslam's publisher refuses another user's
    // root, and the payload segments are read-only for the group.
    let attempts = attempt_to_publish(&b, &site.root, &prefix, a.uid);
    assert!(
        attempts.contains("iceoryx2 publisher: refused"),
        "{attempts}"
    );
    assert!(
        attempts.contains("iceoryx2 notifier: refused"),
        "{attempts}"
    );
    assert!(
        attempts.contains("rigslam publisher: refused"),
        "{attempts}"
    );
    assert!(
        attempts.contains(&format!("belongs to user {}", a.name)),
        "{attempts}"
    );
    assert!(!attempts.contains("ALLOWED"), "{attempts}");
    assert!(
        !attempts.contains("payload segments of the daemon: 0"),
        "{attempts}"
    );

    // The files: root A:G 0770, nothing of the daemon's open to others,
    // its payload segments 0640.
    let meta = std::fs::metadata(&site.root).expect("root");
    assert_eq!(
        (meta.uid(), meta.gid(), meta.mode() & 0o7777),
        (a.uid, a.gid, 0o770)
    );
    // New connection segments are narrowed within a status period.
    let end = Instant::now() + Duration::from_secs(5);
    loop {
        let open = files_open_to_others(a.uid);
        if open.is_empty() {
            break;
        }
        assert!(
            Instant::now() < end,
            "the daemon's user's files open too wide: {open:?}"
        );
        std::thread::sleep(Duration::from_millis(200));
    }

    let (ok, _, log) = daemon.finish(Duration::from_secs(120));
    assert!(ok, "rigslamd failed:\n{log}");
    assert!(!log.contains("cannot be connected"), "{log}");
    let report = std::fs::read_to_string(&site.report).expect("daemon report");
    let poses = json_number(&report, "poses");
    let poses_fast = json_number(&report, "poses_fast");
    assert!(poses > 10 && poses_fast > poses, "{report}");

    for (w, expected, who) in readers
        .into_iter()
        .zip([poses, poses_fast, poses])
        .zip(["B pose", "B pose_fast", "D pose"])
        .map(|((w, e), who)| (w, e, who))
    {
        let (ok, stdout, stderr) = w.finish(Duration::from_secs(60));
        assert!(ok, "{who}: {stderr}");
        assert_eq!(
            json_number(&stdout, "received"),
            expected,
            "{who}: {stdout}"
        );
        assert_eq!(json_number(&stdout, "missed"), 0, "{who}: {stdout}");
        if who == "D pose" {
            assert!(stderr.contains("no longer in group"), "{who}: {stderr}");
        }
    }
    for (w, expected) in holders.into_iter().zip([poses, poses_fast]) {
        let (ok, stdout, stderr) = w.finish(Duration::from_secs(60));
        assert!(ok, "A's reader: {stderr}");
        assert_eq!(json_number(&stdout, "received"), expected, "{stdout}");
    }

    // The readers of the group left last and could not remove the daemon's
    // service files: the next start of the daemon still publishes.
    let again = Watched::start(as_user(
        daemon_command(&dataset, &prefix, &site.root, &site.report),
        &a,
        umask,
    ));
    again.wait_for("publishing", Duration::from_secs(60));
    // SAFETY: signalling our own child.
    unsafe { libc::kill(again.child.id() as libc::pid_t, libc::SIGTERM) };
    let (ok, _, log) = again.finish(Duration::from_secs(60));
    assert!(ok, "the second start failed:\n{log}");
    assert!(log.contains("left marked for destruction"), "{log}");
}

#[test]
fn group_members_read_every_pose_others_are_refused() {
    group_access(false);
}

#[test]
fn the_same_under_the_units_umask_and_runtime_directory() {
    group_access(true);
}

/// B takes the service names before the daemon starts: the daemon stops
/// with a message naming the file and B, it does not publish into B's
/// service.
#[test]
fn a_name_taken_before_the_daemon_starts_stops_it_with_a_message() {
    if !is_root() {
        eprintln!("skipped: creating users and a group needs root (CI runs this as root)");
        return;
    }
    let Some(dataset) = euroc() else { return };
    let accounts = Accounts::create("s");
    let (a, b) = (accounts.user(0), accounts.user(1));
    let site = site(&a, false);
    // The root as an earlier run of the daemon left it.
    std::fs::create_dir(&site.root).expect("root");
    chown(&site.root, a.uid, a.gid);
    chmod(&site.root, 0o770);
    let prefix = format!("rsl_access_{}_s", std::process::id());
    let ready = site.flags.join("b");
    let squatter = Watched::start(as_user(
        echo(&format!("{prefix}/pose"), &site.root, &ready, 30.0),
        &b,
        0o022,
    ));
    wait_file(&ready, Duration::from_secs(20), &squatter);
    let (ok, _, log) = Watched::start(as_user(
        daemon_command(&dataset, &prefix, &site.root, &site.report),
        &a,
        0o022,
    ))
    .finish(Duration::from_secs(60));
    assert!(!ok, "the daemon published into B's service:\n{log}");
    assert!(
        log.contains(&format!("belongs to user {}", b.name)),
        "{log}"
    );
    assert!(log.contains("services"), "{log}");
    drop(squatter);
}
