//! The daemon's pipeline on the bundled EuRoC sequence, in-process: a
//! replay as fast as possible gives the same poses bit for bit twice;
//! frames stopping for 2 s while the IMU goes on give IMU-only poses for a
//! bounded time, then "lost", then tracking again; stamps jumping back are
//! refused and stamps jumping forward are flagged and tracked through; a
//! run recorded to MCAP replays to the same poses bit for bit; a hung
//! stage is reported stuck (what stops the systemd watchdog pings).

use std::collections::VecDeque;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use rigslam::absolute::settings::ModeSwitch;
use rigslam::daemon::config::{DaemonConfig, ReplayPace};
use rigslam::daemon::health::Health;
use rigslam::daemon::queue::{BoundedQueue, WhenFull};
use rigslam::daemon::slam_stage::{run_stage, StageInputs, StageSettings};
use rigslam::daemon::{check, Doorbell, FrameItem, Pipeline, PoseSink};
use rigslam::dataset::{open_dataset, SensorEvent, SensorStream, StreamOptions};
use rigslam::publish::{PoseMessage, TRACKING_STATE_LOST, TRACKING_STATE_TRACKING};
use rigslam::relative::{RelativeOutput, SensorMode};
use rigslam::sensors::ImuSample;
use rigslam::shared_data;

#[path = "common/collect.rs"]
mod collect;
use collect::Collect;
#[path = "common/time_shift.rs"]
mod time_shift;
use time_shift::with_time_shift;

fn bits(m: &PoseMessage) -> Vec<u64> {
    let mut v = vec![m.t_ns as u64, m.tracking_state as u64, m.flags as u64];
    v.extend(m.position_world_m.iter().map(|x| x.to_bits()));
    v.extend(m.orientation_world_body_xyzw.iter().map(|x| x.to_bits()));
    v.extend(m.velocity_world_m_s.iter().map(|x| x.to_bits()));
    v
}

fn stage_settings() -> StageSettings {
    StageSettings {
        mode: SensorMode::StereoInertial,
        estimator: rigslam::relative::EstimatorKind::Window,
        slam: Default::default(),
        map: Default::default(),
        imu_wait: Duration::from_millis(50),
        imu_stall_ns: 100_000_000,
        max_pending_imu: 4096,
        live: false,
    }
}

/// The SLAM stage on its thread, fed by the test instead of a source.
struct StageUnderTest {
    frames: Arc<BoundedQueue<FrameItem>>,
    imu: Arc<BoundedQueue<ImuSample>>,
    doorbell: Arc<Doorbell>,
    health: Arc<Health>,
    sink: Collect,
    thread: std::thread::JoinHandle<Result<(), rigslam::slam_pipeline::PipelineError>>,
}

impl StageUnderTest {
    fn start(dataset: &rigslam::dataset::Dataset) -> StageUnderTest {
        let rig = rigslam::run::dataset_run::rig_of(dataset);
        let frames = Arc::new(BoundedQueue::new("frames", 2, WhenFull::Wait));
        let imu = Arc::new(BoundedQueue::new("imu", 64, WhenFull::Wait));
        let doorbell = Arc::new(Doorbell::default());
        let health = Arc::new(Health::new());
        let inputs = StageInputs {
            frames: frames.clone(),
            imu: imu.clone(),
            doorbell: doorbell.clone(),
            health: health.clone(),
            reload: Arc::new(Mutex::new(None)),
        };
        let sink = Collect::default();
        let thread = {
            let sink = sink.clone();
            std::thread::spawn(move || run_stage(stage_settings(), rig, inputs, Box::new(sink)))
        };
        StageUnderTest {
            frames,
            imu,
            doorbell,
            health,
            sink,
            thread,
        }
    }

    /// Hands `events` over in order, as a source would, closes the queues
    /// and waits for the stage to drain them and end.
    fn feed_and_finish(self, events: impl IntoIterator<Item = SensorEvent>) -> Arc<Health> {
        for e in events {
            match e {
                SensorEvent::Imu(s) => {
                    self.imu.push(s);
                }
                SensorEvent::Frame { t_ns, left, right } => {
                    self.frames.push(FrameItem {
                        t_ns,
                        left,
                        right,
                        arrival_ns: rigslam::sensors::yei::device::host_monotonic_ns(),
                    });
                }
            }
            self.doorbell.ring();
        }
        self.frames.close();
        self.imu.close();
        self.doorbell.ring();
        self.thread
            .join()
            .expect("stage thread")
            .expect("stage ends without an error");
        self.health
    }
}

/// Every event of one pass over the sequence, stereo with the IMU.
fn sensor_events(dataset: &rigslam::dataset::Dataset) -> Vec<SensorEvent> {
    SensorStream::new(
        dataset,
        StreamOptions {
            stereo: true,
            imu: true,
            start_ns: None,
            max_frames: None,
            imu_lead_ns: 0,
        },
    )
    .expect("stream")
    .map(|e| e.expect("event"))
    .collect()
}

fn t_of(e: &SensorEvent) -> i64 {
    match e {
        SensorEvent::Imu(s) => s.t_ns,
        SensorEvent::Frame { t_ns, .. } => *t_ns,
    }
}

fn replay_once(dataset: &std::path::Path) -> Vec<PoseMessage> {
    let config = DaemonConfig::replay(dataset, SensorMode::StereoInertial);
    run_replay(config).0
}

/// Runs a replay config as fast as possible to its end; every pose and
/// the report.
fn run_replay(config: DaemonConfig) -> (Vec<PoseMessage>, rigslam::daemon::PipelineReport) {
    run_replay_losing(config, 0)
}

/// [`run_replay`] of input that loses at most `lost` frames and samples.
fn run_replay_losing(
    mut config: DaemonConfig,
    lost: u64,
) -> (Vec<PoseMessage>, rigslam::daemon::PipelineReport) {
    config.replay.as_mut().expect("replay config").pace = ReplayPace::AsFastAsPossible;
    // A tiny frame queue: the replay has to wait for the stage all the
    // time, which is where a race would show.
    config.pipeline.frame_queue = 1;
    config.pipeline.imu_queue = 16;
    let rig = check(&config, std::path::Path::new("(test)")).expect("valid config");
    let sink = Collect::default();
    let pipeline = Pipeline::start(&config, rig, Box::new(sink.clone())).expect("start");
    let deadline = Instant::now() + Duration::from_secs(120);
    while !pipeline.finished() {
        assert!(Instant::now() < deadline, "replay did not finish in 120 s");
        std::thread::sleep(Duration::from_millis(20));
    }
    let report = pipeline.stop().expect("stop");
    assert!(report.frame_drops + report.imu_drops <= lost, "{report:?}");
    let poses = sink.poses.lock().expect("lock").clone();
    assert_eq!(poses.len() as u64, report.frames, "{report:?}");
    (poses, report)
}

#[test]
fn replay_as_fast_as_possible_repeats_bit_for_bit() {
    let Some(dataset) = shared_data::path_or_skip("euroc/V1_01_micro") else {
        return;
    };
    let a = replay_once(&dataset);
    let b = replay_once(&dataset);
    assert_eq!(a.len(), 95);
    let tracking = a
        .iter()
        .filter(|m| m.tracking_state == TRACKING_STATE_TRACKING)
        .count();
    assert!(tracking > 50, "only {tracking} of 95 frames tracked");
    for (i, (x, y)) in a.iter().zip(&b).enumerate() {
        assert_eq!(bits(x), bits(y), "pose {i} differs: {x:?} vs {y:?}");
    }
    // Tracked poses carry the odometry's covariance once the window runs
    // (at rest before the first motion the pose is the origin itself):
    // every one from then on, symmetric, not negative on the diagonal,
    // growing with the way travelled.
    let tracked: Vec<&PoseMessage> = a
        .iter()
        .filter(|m| m.tracking_state == TRACKING_STATE_TRACKING)
        .collect();
    let first = tracked
        .iter()
        .position(|m| m.covariance_matrix().is_some())
        .expect("a tracked pose with a covariance");
    let covariances: Vec<_> = tracked[first..]
        .iter()
        .map(|m| m.covariance_matrix())
        .collect::<Option<_>>()
        .expect("every tracked pose after the first with a covariance has one");
    assert!(
        covariances.len() >= 5,
        "{} with a covariance",
        covariances.len()
    );
    for c in &covariances {
        assert!((c - c.transpose()).amax() < 1e-12 * c.amax(), "{c}");
        assert!(
            (0..6).all(|i| c[(i, i)] >= 0.0 && c[(i, i)].is_finite()),
            "{c}"
        );
    }
    let position_variance = |c: &nalgebra::Matrix6<f64>| c.fixed_view::<3, 3>(0, 0).trace();
    let (first, last) = (&covariances[0], &covariances[covariances.len() - 1]);
    assert!(
        position_variance(last) > position_variance(first),
        "first {first}, last {last}"
    );
}

#[test]
fn camera_gap_gives_bounded_imu_only_poses_then_lost_then_recovery() {
    let Some(root) = shared_data::path_or_skip("euroc/V1_01_micro") else {
        return;
    };
    let dataset = open_dataset(&root).expect("open");
    let imu_only_max_s = stage_settings().slam.relative.imu_only_max_s;
    let stage = StageUnderTest::start(&dataset);
    let sink = stage.sink.clone();
    // Two passes of the sequence back to back (the second shifted in
    // time), with the frames of 2 s in the middle of the first missing.
    let mut events: VecDeque<SensorEvent> = VecDeque::new();
    let one_pass = sensor_events(&dataset);
    let span = t_of(one_pass.last().expect("events")) - t_of(&one_pass[0]) + 5_000_000;
    for pass in 0..2 {
        for mut e in one_pass.iter().cloned() {
            let shift = pass * span;
            match &mut e {
                SensorEvent::Imu(s) => s.t_ns += shift,
                SensorEvent::Frame { t_ns, .. } => *t_ns += shift,
            }
            events.push_back(e);
        }
    }
    let first_frame = events
        .iter()
        .find_map(|e| match e {
            SensorEvent::Frame { t_ns, .. } => Some(*t_ns),
            _ => None,
        })
        .expect("a frame");
    let gap = (first_frame + 1_500_000_000, first_frame + 3_500_000_000);
    // The second pass starts with 2 s of IMU only (the stream's lead-in),
    // also a gap; the assertions below look at the first one.
    events.retain(|e| match e {
        SensorEvent::Frame { t_ns, .. } => *t_ns < gap.0 || *t_ns >= gap.1,
        SensorEvent::Imu(_) => true,
    });
    stage.feed_and_finish(events);

    let poses = sink.poses.lock().expect("lock").clone();
    let fast = sink.fast.lock().expect("lock").clone();
    let last_before = poses
        .iter()
        .rfind(|m| m.t_ns < gap.0)
        .expect("poses before the gap");
    assert_eq!(last_before.tracking_state, TRACKING_STATE_TRACKING);
    let bound_ns = (imu_only_max_s * 1e9) as i64;
    let in_gap: Vec<&PoseMessage> = fast
        .iter()
        .filter(|m| m.t_ns > last_before.t_ns && m.t_ns < gap.1)
        .collect();
    assert!(in_gap.len() > 300, "{} IMU poses in the gap", in_gap.len());
    // A fast pose is carried from the newest frame the stage has
    // finished; fed as fast as possible, the IMU runs ahead of the frames
    // by up to the frame queue (2 frames) and the frame in work, so the
    // state may turn "lost" up to that much earlier than the bound.
    let lead_ns = 200_000_000;
    for m in &in_gap {
        let since = m.t_ns - last_before.t_ns;
        let expected = if since <= bound_ns - lead_ns {
            TRACKING_STATE_TRACKING
        } else if since > bound_ns {
            TRACKING_STATE_LOST
        } else {
            m.tracking_state
        };
        assert_eq!(
            m.tracking_state,
            expected,
            "{} ms after the last frame",
            since / 1_000_000
        );
        // Bounded: the vehicle stands still, the IMU-only pose may not
        // run away while it is trusted.
        if m.tracking_state == TRACKING_STATE_TRACKING {
            let d: f64 = (0..3)
                .map(|i| (m.position_world_m[i] - last_before.position_world_m[i]).powi(2))
                .sum::<f64>()
                .sqrt();
            assert!(
                d < 0.5,
                "IMU-only pose moved {d} m in {} ms",
                since / 1_000_000
            );
        }
    }
    let recovered = poses
        .iter()
        .find(|m| m.t_ns >= gap.1 && m.tracking_state == TRACKING_STATE_TRACKING);
    assert!(
        recovered.is_some(),
        "no tracking pose after the frames came back"
    );
}

#[test]
fn timestamps_jumping_are_refused_backwards_flagged_and_survived() {
    let Some(root) = shared_data::path_or_skip("euroc/V1_01_micro") else {
        return;
    };
    let dataset = open_dataset(&root).expect("open");
    let stage = StageUnderTest::start(&dataset);
    let sink = stage.sink.clone();
    let all = sensor_events(&dataset);
    let frame_stamps: Vec<i64> = all
        .iter()
        .filter_map(|e| match e {
            SensorEvent::Frame { t_ns, .. } => Some(*t_ns),
            _ => None,
        })
        .collect();
    // After frame 40: a frame and an IMU sample from 1 s back (a clock
    // stepped back, or a driver resending), then every stamp from frame
    // 50 on 3 s later (a clock stepped forward: both streams jump).
    let back_after = frame_stamps[40];
    let forward_from = frame_stamps[50];
    let jump_ns = 3_000_000_000;
    let mut events = Vec::new();
    let mut stale_frame = None;
    let mut stale_imu = None;
    for e in all {
        let t = t_of(&e);
        // EuRoC's IMU and camera share stamps: the frame itself is meant.
        let is_frame = matches!(e, SensorEvent::Frame { .. });
        match &e {
            SensorEvent::Frame { t_ns, .. } if *t_ns == frame_stamps[20] => {
                stale_frame = Some(e.clone())
            }
            SensorEvent::Imu(s) if stale_imu.is_none() && s.t_ns > frame_stamps[20] => {
                stale_imu = Some(e.clone())
            }
            _ => {}
        }
        let mut e = e;
        if t >= forward_from {
            match &mut e {
                SensorEvent::Imu(s) => s.t_ns += jump_ns,
                SensorEvent::Frame { t_ns, .. } => *t_ns += jump_ns,
            }
        }
        events.push(e);
        if is_frame && t == back_after {
            events.push(stale_imu.clone().expect("an IMU sample after frame 20"));
            events.push(stale_frame.clone().expect("frame 20"));
        }
    }
    let health = stage.feed_and_finish(events);

    use std::sync::atomic::Ordering::Relaxed;
    assert_eq!(health.frames_rejected.load(Relaxed), 1, "the stale frame");
    assert_eq!(health.imu_rejected.load(Relaxed), 1, "the stale IMU sample");
    // Back: one frame, one sample; forward: once on each stream.
    assert_eq!(health.timestamp_jumps.load(Relaxed), 4);
    let rules = rigslam::daemon::health::HealthRules {
        camera_stall_ns: 1_000_000_000,
        imu_stall_ns: 1_000_000_000,
        stuck_ns: 60_000_000_000,
        uses_imu: true,
    };
    let status = health.status(
        &rules,
        &mut rigslam::daemon::health::RateBase::default(),
        &[],
        (0, 0),
    );
    assert_ne!(
        status.sensor_health & rigslam::publish::HEALTH_TIMESTAMP_JUMP,
        0,
        "the status says the stamps jumped"
    );

    let poses = sink.poses.lock().expect("lock").clone();
    let fast = sink.fast.lock().expect("lock").clone();
    assert_eq!(
        poses.len(),
        frame_stamps.len(),
        "one pose per accepted frame"
    );
    for stream in [&poses, &fast] {
        for w in stream.windows(2) {
            assert!(w[1].t_ns > w[0].t_ns, "published stamps go back: {w:?}");
        }
        for m in stream.iter() {
            if m.tracking_state == TRACKING_STATE_TRACKING {
                assert!(m.position_world_m.iter().all(|x| x.is_finite()), "{m:?}");
            }
        }
    }
    let before = poses
        .iter()
        .rfind(|m| m.t_ns < forward_from)
        .expect("poses before the jump");
    assert_eq!(before.tracking_state, TRACKING_STATE_TRACKING);
    let after: Vec<&PoseMessage> = poses.iter().filter(|m| m.t_ns >= forward_from).collect();
    assert!(
        after
            .iter()
            .any(|m| m.tracking_state == TRACKING_STATE_TRACKING),
        "no tracking after the stamps jumped forward: {:?}",
        after.iter().map(|m| m.tracking_state).collect::<Vec<_>>()
    );
}

/// `rigslam run`'s path (the library call behind it) and the daemon's
/// replay as fast as possible, with the same settings, give the same poses
/// bit for bit: with the relative stage alone, and with both stages (the
/// daemon's `rigslam/pose` then carries the corrected position); and with
/// a camera clock 7 ms behind the IMU's, where both must hand each frame
/// the IMU up to its instant on the IMU clock (the daemon handed it the
/// samples up to its stamp only, and ran without the IMU).
#[test]
fn rigslam_run_and_the_daemon_give_the_same_poses_with_one_or_both_stages() {
    use rigslam::run::dataset_run::{run_dataset, DatasetRun};
    let Some(micro) = shared_data::path_or_skip("euroc/V1_01_micro") else {
        return;
    };
    let work = tempfile::tempdir().expect("tempdir");
    let shifted = with_time_shift(&micro, work.path(), 0.007);
    let mut corrections_seen = 0;
    for (dataset, both_stages) in [(&micro, false), (&micro, true), (&shifted, false)] {
        let mut config = DaemonConfig::replay(dataset, SensorMode::StereoInertial);
        config.slam.absolute.enabled = both_stages;
        // The clip rests and then barely turns: with the default wait for
        // the accelerometer bias the map would never start, and the
        // corrections are what is compared here.
        config.slam.absolute.wait_accel_bias = ModeSwitch::Off;
        let run = DatasetRun {
            mode: Some(SensorMode::StereoInertial),
            settings: config.slam.settings(),
            ..DatasetRun::default()
        };
        let result = run_dataset(dataset, &run, |_, _| {}).expect("rigslam run's path");
        assert_eq!(
            result.report.counters.get("frames_without_imu"),
            Some(&0),
            "{}",
            dataset.display()
        );
        let (poses, _) = run_replay(config);
        let tracked: Vec<&PoseMessage> = poses
            .iter()
            .filter(|m| m.tracking_state == TRACKING_STATE_TRACKING)
            .collect();
        let ran = &result.outcome.trajectory.poses;
        assert!(ran.len() > 50, "{} poses", ran.len());
        assert_eq!(tracked.len(), ran.len(), "both stages: {both_stages}");
        for (i, (m, p)) in tracked.iter().zip(ran).enumerate() {
            let q = p.T_world_body.rotation.coords;
            let expected: Vec<u64> = [p.t_ns as u64]
                .into_iter()
                .chain(
                    p.T_world_body
                        .translation
                        .vector
                        .iter()
                        .map(|v| v.to_bits()),
                )
                .chain([q.x, q.y, q.z, q.w].iter().map(|v| v.to_bits()))
                .collect();
            let published: Vec<u64> = [m.t_ns as u64]
                .into_iter()
                .chain(m.position_world_m.iter().map(|v| v.to_bits()))
                .chain(m.orientation_world_body_xyzw.iter().map(|v| v.to_bits()))
                .collect();
            assert_eq!(published, expected, "pose {i}, both stages: {both_stages}");
        }
        // The odometry frame (REP-105 `odom`): the relative stage's poses,
        // never moved by a correction; with one stage it is the world.
        let relative = match &result.trajectory_relative {
            Some(t) => &t.poses,
            None => ran,
        };
        for (i, (m, p)) in tracked.iter().zip(relative).enumerate() {
            let q = p.T_world_body.rotation.coords;
            let odom: Vec<u64> = m
                .position_odom_m
                .iter()
                .chain(&m.orientation_odom_body_xyzw)
                .map(|v| v.to_bits())
                .collect();
            let expected: Vec<u64> = p
                .T_world_body
                .translation
                .vector
                .iter()
                .chain([q.x, q.y, q.z, q.w].iter())
                .map(|v| v.to_bits())
                .collect();
            assert_eq!(
                odom, expected,
                "odometry pose {i}, both stages: {both_stages}"
            );
            assert_eq!(
                m.flags & rigslam::publish::POSE_FLAG_MAP_CORRECTED != 0,
                both_stages,
                "pose {i}"
            );
            let composed = m.T_world_odom() * m.T_odom_body();
            let world = m.T_world_body();
            assert!(
                (composed.translation.vector - world.translation.vector).norm() < 1e-9
                    && composed.rotation.angle_to(&world.rotation) < 1e-9,
                "pose {i}: T_world_odom T_odom_body is not T_world_body"
            );
        }
        if both_stages {
            // The absolute stage really ran in both: its positions are not
            // the relative stage's.
            corrections_seen = ran
                .iter()
                .zip(relative)
                .filter(|(a, b)| a.T_world_body.translation != b.T_world_body.translation)
                .count();
            let stats = result.report.absolute.as_ref().expect("absolute stats");
            assert!(stats.solves > 0, "{stats:?}");
        }
    }
    assert!(corrections_seen >= 5, "{corrections_seen} corrected poses");
}

/// `[map] path`: the first run builds a map and saves it (periodically
/// and at the end); the next run starts from it and localises in it, its
/// poses in the same frame as the first run's; a file that is not a whole
/// map is set aside under a new name, untouched, and a new map is built.
#[test]
fn the_map_outlives_the_daemon_and_a_broken_one_is_set_aside() {
    use rigslam::absolute::map_file::SavedMap;
    use rigslam::publish::POSE_FLAG_MAP_CORRECTED;
    let Some(dataset) = shared_data::path_or_skip("euroc/V1_01_micro") else {
        return;
    };
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("robot.map");
    let run = |path: &std::path::Path| {
        let mut config = DaemonConfig::replay(&dataset, SensorMode::StereoInertial);
        config.map.path = Some(path.to_path_buf());
        config.map.save_every_s = 1.0;
        // As above: with the default wait nothing would be mapped.
        config.slam.absolute.wait_accel_bias = ModeSwitch::Off;
        run_replay(config)
    };
    let in_map = |poses: &[PoseMessage]| -> Vec<PoseMessage> {
        poses
            .iter()
            .filter(|m| m.flags & POSE_FLAG_MAP_CORRECTED != 0)
            .copied()
            .collect()
    };

    let (built, report) = run(&path);
    let words = report.map.clone().expect("map words");
    assert!(words.contains("building"), "{words}");
    assert!(
        report.map_saves >= 2,
        "periodic and final saves: {report:?}"
    );
    let map = SavedMap::read(&path).expect("a whole map");
    assert!(
        map.landmarks.len() > 20,
        "{} landmarks",
        map.landmarks.len()
    );
    let built = in_map(&built);
    assert!(
        built.len() > 30,
        "{} poses from the absolute stage",
        built.len()
    );

    let (again, report) = run(&path);
    let words = report.map.clone().expect("map words");
    assert!(words.contains("localising"), "{words}");
    let localised = in_map(&again);
    // The sequence is nearly still: the relative stage hands landmarks
    // over in its last frames only (as `rigslam run --load-map` sees).
    assert!(
        localised.len() >= 3,
        "{} of {} poses localised in the saved map",
        localised.len(),
        again.len()
    );
    // The same frames placed in the same map: the two runs agree.
    let mut gaps: Vec<f64> = localised
        .iter()
        .filter_map(|m| {
            let b = built.iter().find(|b| b.t_ns == m.t_ns)?;
            Some((m.T_world_body().translation.vector - b.T_world_body().translation.vector).norm())
        })
        .collect();
    assert!(gaps.len() >= 3, "{} frames in both", gaps.len());
    gaps.sort_by(f64::total_cmp);
    let median = gaps[gaps.len() / 2];
    assert!(median < 0.02, "median gap {median:.3} m between the runs");
    // Localising does not change the map.
    assert_eq!(SavedMap::read(&path).expect("still whole"), map);

    // A damaged map and the remains of a save cut short.
    std::fs::write(&path, "# rigslam map v2 landmarks 3\n0 1 2\n").expect("damage");
    let stale = dir.path().join(".robot.map.tmp999-0");
    std::fs::write(&stale, "half a map").expect("stale temporary");
    let (_, report) = run(&path);
    assert!(report.map.expect("map words").contains("building"));
    let aside = dir.path().join("robot.map.unusable-1");
    assert_eq!(
        std::fs::read_to_string(&aside).expect("the damaged map kept"),
        "# rigslam map v2 landmarks 3\n0 1 2\n"
    );
    assert!(
        SavedMap::read(&path)
            .expect("a new whole map")
            .landmarks
            .len()
            > 20
    );
    assert!(!stale.exists(), "the stale temporary is removed");
}

#[test]
fn a_recording_replays_to_the_poses_of_the_run_that_made_it() {
    let Some(root) = shared_data::path_or_skip("euroc/V1_01_micro") else {
        return;
    };
    let dir = tempfile::tempdir().expect("tempdir");
    // The run that records: the EuRoC folder through the pipeline.
    let mut config = DaemonConfig::replay(&root, SensorMode::StereoInertial);
    config.recording.enabled = true;
    config.recording.dir = dir.path().join("rec");
    let (live, report) = run_replay(config);
    assert_eq!(report.recording_drops, 0, "{report:?}");
    assert_eq!(report.recordings.len(), 1, "{report:?}");
    let mcap = report.recordings[0].clone();
    let recorded = rigslam::recording::read_pose_channel(&mcap, "/rigslam/pose").expect("poses");
    assert_eq!(recorded.len(), live.len());

    // The recording through the same pipeline, twice, with the rig's
    // calibration files named in the config.
    let replay_config = || {
        let mut config = DaemonConfig::replay(&mcap, SensorMode::StereoInertial);
        let cal = |f: &str| root.join(format!("mav0/{f}/sensor.yaml"));
        config.calibration = Some(rigslam::daemon::config::CalibrationConfig {
            cameras: vec![cal("cam0"), cal("cam1")],
            imu: Some(cal("imu0")),
            folder: None,
            imu_intrinsics: None,
        });
        config
    };
    let (a, _) = run_replay(replay_config());
    let (b, _) = run_replay(replay_config());
    assert_eq!(a.len(), live.len(), "one pose per recorded frame");
    let tracking = a
        .iter()
        .filter(|m| m.tracking_state == TRACKING_STATE_TRACKING)
        .count();
    assert!(
        tracking > 50,
        "only {tracking} of {} frames tracked",
        a.len()
    );
    for (i, ((x, y), z)) in a.iter().zip(&b).zip(&live).enumerate() {
        assert_eq!(bits(x), bits(y), "replay pose {i} differs between replays");
        assert_eq!(
            bits(x),
            bits(z),
            "replay pose {i} differs from the live run's"
        );
        assert_eq!(x.position_world_m, recorded[i].position_world_m, "pose {i}");
    }

    // Without [calibration]: the rig recorded in the file's attachments,
    // the same to the bit.
    let (c, _) = run_replay(DaemonConfig::replay(&mcap, SensorMode::StereoInertial));
    for (i, (x, y)) in a.iter().zip(&c).enumerate() {
        assert_eq!(bits(x), bits(y), "pose {i} differs with the recorded rig");
    }
    let attached = rigslam::recording::rig_of_recording(&mcap)
        .expect("read")
        .expect("a calibration");
    assert_eq!(attached.cameras.len(), 2);
    assert!(attached.imu.is_some());

    // A recording without a calibration: --check-config's words.
    let bare_mcap = dir.path().join("bare.mcap");
    let mut bare =
        rigslam::recording::McapRecorder::create(&bare_mcap, rigslam::recording::Compression::Zstd)
            .expect("create");
    bare.add_image_channel("/cam0").expect("channel");
    bare.finish().expect("close");
    let problems = check(
        &DaemonConfig::replay(&bare_mcap, SensorMode::StereoInertial),
        std::path::Path::new("rig.toml"),
    )
    .expect_err("no calibration");
    let text: Vec<String> = problems.iter().map(|p| p.to_string()).collect();
    assert!(
        text.iter()
            .any(|t| t.contains("calibration") && t.contains("bare.mcap")),
        "{text:?}"
    );
    // A recording cut off mid-write (no summary, the last chunk partial):
    // what it holds replays, to the same poses as the whole file's.
    let cut = dir.path().join("cut.mcap");
    let bytes = std::fs::read(&mcap).expect("read");
    std::fs::write(&cut, &bytes[..bytes.len() / 2]).expect("write");
    let mut config = replay_config();
    config.replay.as_mut().expect("replay").dataset = cut.clone();
    check(&config, std::path::Path::new("rig.toml")).expect("a cut file replays");
    // The half of a stereo pair the cut left alone is dropped.
    let (d, report) = run_replay_losing(config, 1);
    assert!(!report.source_failed, "{report:?}");
    assert!(
        d.len() > a.len() / 4 && d.len() < a.len(),
        "{} of {} poses from half the file",
        d.len(),
        a.len()
    );
    // The last frame may miss the IMU samples after it.
    for (i, (x, y)) in d.iter().zip(&a).take(d.len() - 1).enumerate() {
        assert_eq!(bits(x), bits(y), "pose {i} of the cut file differs");
    }
    // A file that is not a recording at all is refused by name.
    let junk = dir.path().join("junk.mcap");
    std::fs::write(&junk, b"not an MCAP file").expect("write");
    let mut config = replay_config();
    config.replay.as_mut().expect("replay").dataset = junk;
    let problems = check(&config, std::path::Path::new("rig.toml")).expect_err("junk file");
    // Said once, though several checks read the file.
    assert_eq!(problems.len(), 1, "{problems:?}");
    assert!(
        problems
            .iter()
            .any(|p| p.key == "replay.dataset" && p.to_string().contains("junk.mcap")),
        "{problems:?}"
    );
}

/// Blocks the stage in its first `pose()` until released: a hung stage.
#[derive(Clone)]
struct Hang {
    release: Arc<(Mutex<bool>, std::sync::Condvar)>,
}

impl PoseSink for Hang {
    fn pose(&mut self, _: &PoseMessage, _: &RelativeOutput) -> bool {
        let (lock, released) = &*self.release;
        let mut done = lock.lock().expect("lock");
        while !*done {
            done = released.wait(done).expect("wait");
        }
        true
    }
    fn pose_fast(&mut self, _: &PoseMessage) -> bool {
        true
    }
}

#[test]
fn a_hung_stage_is_reported_stuck_until_it_moves_again() {
    let Some(root) = shared_data::path_or_skip("euroc/V1_01_micro") else {
        return;
    };
    let mut config = DaemonConfig::replay(&root, SensorMode::StereoInertial);
    config.pipeline.stuck_after_s = 0.5;
    let rig = check(&config, std::path::Path::new("(test)")).expect("valid config");
    let hang = Hang {
        release: Arc::new((Mutex::new(false), std::sync::Condvar::new())),
    };
    let mut pipeline = Pipeline::start(&config, rig, Box::new(hang.clone())).expect("start");
    let deadline = Instant::now() + Duration::from_secs(20);
    while !pipeline.stuck() {
        assert!(Instant::now() < deadline, "the hung stage was not noticed");
        std::thread::sleep(Duration::from_millis(50));
    }
    let status = pipeline.status();
    assert_ne!(
        status.sensor_health & rigslam::publish::HEALTH_STAGE_STUCK,
        0,
        "status says stuck"
    );
    assert!(!rigslam::daemon::health::is_healthy(&status, true));
    // Meanwhile the replay keeps offering frames: a full queue drops
    // nothing in a replay (it waits), so none are lost either.
    {
        let (lock, released) = &*hang.release;
        *lock.lock().expect("lock") = true;
        released.notify_all();
    }
    let deadline = Instant::now() + Duration::from_secs(5);
    while pipeline.stuck() {
        assert!(Instant::now() < deadline, "still stuck after the release");
        std::thread::sleep(Duration::from_millis(20));
    }
    let report = pipeline.stop().expect("stop");
    assert_eq!(report.frame_drops, 0, "{report:?}");
    assert_eq!(report.poses, report.frames, "{report:?}");
}
