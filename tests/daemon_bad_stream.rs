//! Damaged input end to end.
//!
//! A recording: a run on the bundled EuRoC sequence is recorded to MCAP,
//! the recording is rewritten with its sensor messages damaged (bit flips
//! in image and IMU payloads, messages dropped, duplicated and swapped,
//! one IMU stamp thrown far ahead), and the daemon replays the damaged
//! file. It must play to the end without a panic, count what it left out
//! in its status and report, and publish only finite poses that stay near
//! the undamaged replay's.
//!
//! A dataset folder with listed images missing and a NaN IMU row:
//! `rigslam run` and the daemon each count them (report, summary line,
//! status) and name each file once in the log.

use std::collections::BTreeMap;
use std::io::BufWriter;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rigslam::daemon::config::{DaemonConfig, ReplayPace};
use rigslam::daemon::{check, Pipeline, PipelineReport};
use rigslam::publish::{PoseMessage, StatusMessage, TRACKING_STATE_TRACKING};
use rigslam::recording::schemas::ImuSampleProto;
use rigslam::relative::SensorMode;
use rigslam::shared_data;

#[path = "common/collect.rs"]
mod collect;
use collect::Collect;

struct Replayed {
    poses: Vec<PoseMessage>,
    fast: Vec<PoseMessage>,
    report: PipelineReport,
    status: StatusMessage,
}

/// Replays `config` as fast as possible to its end.
fn replay(mut config: DaemonConfig) -> Replayed {
    config.replay.as_mut().expect("replay config").pace = ReplayPace::AsFastAsPossible;
    let rig = check(&config, Path::new("(test)")).expect("valid config");
    let sink = Collect::default();
    let mut pipeline = Pipeline::start(&config, rig, Box::new(sink.clone())).expect("start");
    let deadline = Instant::now() + Duration::from_secs(180);
    while !pipeline.finished() {
        assert!(Instant::now() < deadline, "replay did not finish in 180 s");
        std::thread::sleep(Duration::from_millis(20));
    }
    let status = pipeline.status();
    let report = pipeline.stop().expect("stop");
    let poses = sink.poses.lock().expect("lock").clone();
    let fast = sink.fast.lock().expect("lock").clone();
    Replayed {
        poses,
        fast,
        report,
        status,
    }
}

/// What was done to the recording.
#[derive(Debug, Default)]
struct Damage {
    /// Sensor messages in the original.
    messages: u64,
    dropped: u64,
    duplicated: u64,
    swapped: u64,
    flipped: u64,
    /// Flipped messages that no longer decode as their schema says (or
    /// decode into an image that does not hold its pixels): each must be
    /// counted as left out.
    flipped_undecodable: BTreeMap<String, u64>,
    /// The IMU sample whose stamp was thrown ahead.
    stamp_thrown_ahead: bool,
    /// Messages damaged in any of these ways, per topic.
    damaged: BTreeMap<String, u64>,
}

fn is_sensor(topic: &str) -> bool {
    matches!(topic, "/cam0" | "/cam1" | "/imu0")
}

/// Whether a sensor message decodes into a sample or a mono8 image, by
/// the protobuf schemas alone.
fn decodes(topic: &str, data: &[u8]) -> bool {
    use prost::Message;
    if topic == "/imu0" {
        return ImuSampleProto::decode(data)
            .is_ok_and(|m| m.gyro_rad_s.len() == 3 && m.accel_m_s2.len() == 3);
    }
    foxglove::messages::RawImage::decode(data).is_ok_and(|m| {
        m.encoding == "mono8"
            && m.timestamp.is_some()
            && m.step >= m.width
            && m.data.len() as u64 >= u64::from(m.step) * u64::from(m.height)
    })
}

/// Rewrites the recording at `src` into `dst` with its sensor messages
/// damaged (seeded, the same every run); attachments and other channels
/// are copied as they are.
fn damage(src: &Path, dst: &Path, seed: u64) -> Damage {
    let bytes = std::fs::read(src).expect("read recording");
    let file = std::fs::File::create(dst).expect("create");
    let mut writer = mcap::WriteOptions::new()
        .compression(None)
        .create(BufWriter::new(file))
        .expect("writer");
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut damage = Damage::default();
    let messages: Vec<mcap::Message> = mcap::MessageStream::new(&bytes)
        .expect("stream")
        .map(|m| m.expect("message"))
        .collect();
    let mut held: Option<mcap::Message> = None;
    let mut imu_seen = 0;
    for mut m in messages {
        let topic = m.channel.topic.clone();
        if !is_sensor(&topic) {
            writer.write(&m).expect("write");
            continue;
        }
        damage.messages += 1;
        if topic == "/imu0" {
            imu_seen += 1;
            if imu_seen == 300 {
                // One stamp with bit 40 set: 18 minutes ahead.
                use prost::Message;
                let mut v = ImuSampleProto::decode(&m.data[..]).expect("an IMU sample");
                v.t_ns |= 1 << 40;
                m.data = v.encode_to_vec().into();
                damage.stamp_thrown_ahead = true;
            }
        }
        let r: f64 = rng.gen();
        if r < 0.10 {
            *damage.damaged.entry(topic.clone()).or_default() += 1;
        }
        let mut out = vec![];
        if r < 0.03 {
            damage.dropped += 1;
        } else if r < 0.06 {
            let mut data = m.data.to_vec();
            for _ in 0..rng.gen_range(1..=4) {
                let bit = rng.gen_range(0..data.len() * 8);
                data[bit / 8] ^= 1 << (bit % 8);
            }
            if !decodes(&topic, &data) {
                *damage.flipped_undecodable.entry(topic.clone()).or_default() += 1;
            }
            m.data = data.into();
            damage.flipped += 1;
            out.push(m);
        } else if r < 0.08 {
            damage.duplicated += 1;
            out.push(m.clone());
            out.push(m);
        } else if r < 0.10 && held.is_none() {
            damage.swapped += 1;
            held = Some(m);
            continue;
        } else {
            out.push(m);
        }
        for m in out {
            writer.write(&m).expect("write");
        }
        if let Some(h) = held.take() {
            writer.write(&h).expect("write");
        }
    }
    if let Some(h) = held.take() {
        writer.write(&h).expect("write");
    }
    let attachments = rigslam::recording::read_attachments(src).expect("attachments");
    for (name, data) in attachments {
        writer
            .attach(&mcap::Attachment {
                log_time: 0,
                create_time: 0,
                name,
                media_type: "application/x-yaml".into(),
                data: data.into(),
            })
            .expect("attach");
    }
    writer.finish().expect("finish");
    damage
}

fn finite(m: &PoseMessage) -> bool {
    m.position_world_m
        .iter()
        .chain(&m.orientation_world_body_xyzw)
        .chain(&m.velocity_world_m_s)
        .all(|x| x.is_finite())
}

fn record(root: &Path, dir: &Path) -> PathBuf {
    let mut config = DaemonConfig::replay(root, SensorMode::StereoInertial);
    config.recording.enabled = true;
    config.recording.dir = dir.join("rec");
    let run = replay(config);
    assert_eq!(run.report.recordings.len(), 1, "{:?}", run.report);
    run.report.recordings[0].clone()
}

#[test]
fn a_damaged_recording_plays_to_the_end_counting_what_it_left_out() {
    let Some(root) = shared_data::path_or_skip("euroc/V1_01_micro") else {
        return;
    };
    let dir = tempfile::tempdir().expect("tempdir");
    let clean_file = record(&root, dir.path());
    let clean = replay(DaemonConfig::replay(
        &clean_file,
        SensorMode::StereoInertial,
    ));
    assert_eq!(
        clean.report.frame_drops + clean.report.imu_drops,
        0,
        "the undamaged recording replays whole: {:?}",
        clean.report
    );
    let clean_frames = clean.poses.len();

    for seed in [1, 2] {
        let damaged_file = dir.path().join(format!("damaged-{seed}.mcap"));
        let d = damage(&clean_file, &damaged_file, seed);
        eprintln!("seed {seed}: {d:?}");
        assert!(d.stamp_thrown_ahead && d.flipped > 10 && d.duplicated > 5 && d.dropped > 5);
        let run = replay(DaemonConfig::replay(
            &damaged_file,
            SensorMode::StereoInertial,
        ));
        let r = &run.report;
        eprintln!(
            "seed {seed}: {} poses (undamaged {clean_frames}), report {r:?}, status camera_drops {} imu_drops {}",
            run.poses.len(),
            run.status.camera_drops,
            run.status.imu_drops
        );

        // Played to the end: a pose within the file's last half second
        // (its very last frames may be among the damaged ones).
        let last_clean = clean.poses.last().expect("poses").t_ns;
        let last = run.poses.last().map_or(i64::MIN, |m| m.t_ns);
        assert!(
            last >= last_clean - 500_000_000,
            "seed {seed}: the replay stopped at {last} ns, the file ends at {last_clean} ns"
        );

        // Counted: every message that no longer decodes, in the report
        // and the status; every duplicate refused or left unpaired.
        let undecodable_images = d.flipped_undecodable.get("/cam0").unwrap_or(&0)
            + d.flipped_undecodable.get("/cam1").unwrap_or(&0);
        let undecodable_imu = *d.flipped_undecodable.get("/imu0").unwrap_or(&0);
        assert!(
            r.frames_skipped >= undecodable_images && r.imu_skipped >= undecodable_imu,
            "seed {seed}: {d:?} {r:?}"
        );
        assert!(
            r.frame_drops + r.imu_drops >= undecodable_images + undecodable_imu + d.duplicated + 1,
            "seed {seed}: duplicates and the stamp thrown ahead are refused: {d:?} {r:?}"
        );
        // Nothing lost beyond the damage: an image message damaged costs
        // at most its stereo frame (two images), an IMU message itself
        // (the stamp thrown ahead is one more); the stream after a
        // damaged stamp is not refused.
        let damaged = |t: &str| *d.damaged.get(t).unwrap_or(&0);
        assert!(
            r.frame_drops <= 2 * (damaged("/cam0") + damaged("/cam1"))
                && r.imu_drops <= damaged("/imu0") + 1,
            "seed {seed}: more left out than was damaged: {d:?} {r:?}"
        );
        assert_eq!(
            (run.status.camera_drops, run.status.imu_drops),
            (r.frame_drops, r.imu_drops),
            "seed {seed}: the status counts what the report counts"
        );

        // Finite, and near the undamaged replay where both track.
        for m in run.poses.iter().chain(&run.fast) {
            assert!(finite(m), "seed {seed}: {m:?}");
        }
        let clean_at: BTreeMap<i64, &PoseMessage> =
            clean.poses.iter().map(|m| (m.t_ns, m)).collect();
        let mut compared = 0;
        let mut worst = 0.0f64;
        for m in &run.poses {
            let Some(c) = clean_at.get(&m.t_ns) else {
                continue;
            };
            if m.tracking_state != TRACKING_STATE_TRACKING
                || c.tracking_state != TRACKING_STATE_TRACKING
            {
                continue;
            }
            let d2: f64 = (0..3)
                .map(|k| (m.position_world_m[k] - c.position_world_m[k]).powi(2))
                .sum();
            worst = worst.max(d2.sqrt());
            compared += 1;
        }
        eprintln!(
            "seed {seed}: {compared} poses compared, worst {worst:.3} m from the undamaged replay"
        );
        assert!(
            compared * 10 >= clean_frames * 7,
            "seed {seed}: only {compared} of {clean_frames} frames tracked in both"
        );
        assert!(
            worst < 0.25,
            "seed {seed}: {worst:.3} m from the undamaged replay"
        );
    }
}

/// Copies a folder tree.
fn copy_tree(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).expect("mkdir");
    for entry in std::fs::read_dir(from).expect("read dir") {
        let entry = entry.expect("entry");
        let target = to.join(entry.file_name());
        if entry.file_type().expect("type").is_dir() {
            copy_tree(&entry.path(), &target);
        } else {
            std::fs::copy(entry.path(), &target).expect("copy");
        }
    }
}

/// The bundled sequence with two left images and one right image deleted
/// (their rows still listed) and one IMU row's values turned to NaN.
fn folder_with_holes(root: &Path, dir: &Path) -> PathBuf {
    let copy = dir.join("V1_01_holes");
    copy_tree(root, &copy);
    let listed = |cam: &str| -> Vec<String> {
        std::fs::read_to_string(copy.join(format!("mav0/{cam}/data.csv")))
            .expect("csv")
            .lines()
            .filter(|l| !l.starts_with('#'))
            .map(|l| l.split(',').nth(1).expect("file").trim().to_string())
            .collect()
    };
    let (left, right) = (listed("cam0"), listed("cam1"));
    for (cam, file) in [
        ("cam0", &left[30]),
        ("cam0", &left[60]),
        ("cam1", &right[45]),
    ] {
        std::fs::remove_file(copy.join(format!("mav0/{cam}/data/{file}"))).expect("rm");
    }
    let imu = copy.join("mav0/imu0/data.csv");
    let text = std::fs::read_to_string(&imu).expect("imu");
    let lines: Vec<String> = text
        .lines()
        .enumerate()
        .map(|(i, l)| {
            if i == 200 {
                let t = l.split(',').next().expect("stamp");
                format!("{t},nan,nan,nan,nan,nan,nan")
            } else {
                l.to_string()
            }
        })
        .collect();
    std::fs::write(&imu, lines.join("\n") + "\n").expect("write");
    copy
}

#[test]
fn missing_images_and_nan_samples_are_counted_and_named_once() {
    let Some(root) = shared_data::path_or_skip("euroc/V1_01_micro") else {
        return;
    };
    let dir = tempfile::tempdir().expect("tempdir");
    let holes = folder_with_holes(&root, dir.path());

    // rigslam run: the report's stream counts, the summary line, and one
    // warning per file.
    let report_path = dir.path().join("report.json");
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_rigslam"))
        .args(["run", "--mode", "stereo-inertial", "--dataset"])
        .arg(&holes)
        .arg("--report")
        .arg(&report_path)
        .output()
        .expect("run rigslam");
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&report_path).expect("report"))
            .expect("json");
    let stream = &report["stream"];
    assert_eq!(stream["frames_missing_image"], 2, "{stream}");
    assert_eq!(stream["frames_missing_right"], 1, "{stream}");
    assert_eq!(stream["imu_samples_nonfinite"], 1, "{stream}");
    assert_eq!(report["frames"], 93, "95 listed, 2 without their image");
    assert!(
        stdout.contains(
            "input left out: 2 listed images missing, 1 right images missing, 1 non-finite IMU samples"
        ),
        "{stdout}"
    );
    assert!(
        !stderr.contains('\x1b'),
        "colour codes in a log that is not a terminal"
    );
    let log = format!("{stdout}{stderr}");
    for file in ["cam0/data.csv", "cam1/data.csv", "imu0/data.csv"] {
        let n = log.lines().filter(|l| l.contains(file)).count();
        assert_eq!(n, 1, "{file} named {n} times in:\n{log}");
    }

    // The daemon replaying the folder: the same counts in its report and
    // status.
    let run = replay(DaemonConfig::replay(&holes, SensorMode::StereoInertial));
    let r = &run.report;
    assert_eq!((r.frames_skipped, r.imu_skipped), (3, 1), "{r:?}");
    assert_eq!((r.frame_drops, r.imu_drops), (3, 1), "{r:?}");
    assert_eq!(
        (run.status.camera_drops, run.status.imu_drops),
        (3, 1),
        "the status counts them"
    );
    assert_eq!(run.poses.len(), 93);
    for m in run.poses.iter().chain(&run.fast) {
        assert!(finite(m), "{m:?}");
    }
}
