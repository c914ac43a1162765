//! Publishing over iceoryx2 between threads: order and content, event
//! wake-up, newest-sample semantics when the subscriber lags.
//!
//! Every test uses its own service prefix and iceoryx2 root path, so the
//! tests run in parallel without meeting each other's services.

use std::sync::mpsc;
use std::thread;
use std::time::{Duration, Instant};

use nalgebra::{Isometry3, Matrix6, Translation3, UnitQuaternion, Vector3};
use rigslam::imu::ImuBiases;
use rigslam::publish::{
    IpcConfig, PoseMessage, PosePublisher, PoseSubscriber, QueueFill, StatusMessage,
    StatusSubscriber, Subscription, HEALTH_IMU_STREAMING, POSE_FLAG_COVARIANCE_VALID,
};
use rigslam::relative::types::{RelativeOutput, TrackingState};

/// A config no other test shares; the TempDir must outlive the ports.
fn private_config(test: &str) -> (IpcConfig, tempfile::TempDir) {
    let root = tempfile::tempdir().expect("temp dir for the iceoryx2 root");
    let config = IpcConfig {
        service_prefix: format!("rigslam_test_{}_{test}", std::process::id()),
        root_path: Some(root.path().to_path_buf()),
        group: None,
    };
    (config, root)
}

/// Message i of a test stream: every field depends on i, so a swapped,
/// repeated or corrupted sample is seen.
fn message(i: u64) -> PoseMessage {
    let f = i as f64;
    let output = RelativeOutput {
        t_ns: 1_000_000 * i as i64 + 17,
        state: if i % 3 == 0 {
            TrackingState::Tracking
        } else {
            TrackingState::Lost
        },
        T_world_body: Isometry3::from_parts(
            Translation3::new(f, -2.0 * f, 0.5 + f),
            UnitQuaternion::from_euler_angles(0.01 * f, -0.02 * f, 0.03 * f),
        ),
        velocity_world_m_s: Vector3::new(0.1 * f, 0.2, -f),
        biases: ImuBiases::default(),
        delta_translation_world_m: Vector3::zeros(),
        landmarks: Vec::new(),
        pose_covariance: None,
    };
    let covariance = Matrix6::from_fn(|r, c| f + (6 * r + c) as f64);
    PoseMessage::from_relative(&output, Some(&covariance))
}

/// The received sample equals what was sent apart from the two fields the
/// publisher sets.
fn assert_same_content(got: &PoseMessage, sent: &PoseMessage) {
    let mut expected = *sent;
    expected.sequence = got.sequence;
    expected.published_t_ns = got.published_t_ns;
    assert_eq!(got, &expected);
}

#[test]
fn every_pose_arrives_in_order_with_its_content_across_threads() {
    const N: u64 = 100; // below the subscriber's buffer: nothing may be lost
    let (config, _root) = private_config("order");
    let mut subscriber =
        PoseSubscriber::open_service(&config, &format!("{}/pose", config.service_prefix), 128)
            .expect("subscriber");
    let publisher_config = config.clone();
    let publisher = thread::spawn(move || {
        let mut publisher = PosePublisher::open(&publisher_config).expect("publisher");
        for i in 0..N {
            assert_eq!(publisher.publish(&message(i)).expect("publish"), i);
        }
        // Keep the publisher (and its samples) alive until the test ends.
        publisher
    });
    let mut received = Vec::new();
    while (received.len() as u64) < N {
        assert!(
            subscriber.wait(Duration::from_secs(30)).expect("wait"),
            "no sample within 30 s after {} of {N}",
            received.len()
        );
        subscriber.take_all(&mut received).expect("take");
    }
    let _publisher = publisher.join().expect("publisher thread");
    assert_eq!(received.len() as u64, N);
    for (i, got) in received.iter().enumerate() {
        assert_eq!(got.sequence, i as u64);
        assert!(got.published_t_ns > 0);
        assert_same_content(got, &message(i as u64));
        assert_eq!(
            got.flags & POSE_FLAG_COVARIANCE_VALID,
            POSE_FLAG_COVARIANCE_VALID
        );
    }
    assert_eq!(subscriber.missed(), 0);
}

#[test]
fn a_blocked_subscriber_wakes_on_the_event() {
    const WAKE_TIMEOUT: Duration = Duration::from_secs(30);
    let (config, _root) = private_config("wake");
    let (ready_tx, ready_rx) = mpsc::channel();
    let subscriber_config = config.clone();
    let subscriber = thread::spawn(move || {
        let mut subscriber = PoseSubscriber::pose(&subscriber_config).expect("subscriber");
        // Nothing published yet: the wait must time out, not return early.
        assert!(!subscriber.wait(Duration::from_millis(20)).expect("wait"));
        ready_tx.send(()).expect("main thread listens");
        // Blocks in the kernel until the publisher's notification; only a
        // missing notification lets it reach its timeout (after which it
        // would still find the sample, hence the check on how it ended).
        let started = Instant::now();
        let woke = subscriber.wait(WAKE_TIMEOUT).expect("wait");
        let waited = started.elapsed();
        let newest = subscriber.take_newest().expect("take");
        // The sample is taken: the next wait has nothing to return for.
        let again = subscriber.wait(Duration::from_millis(20)).expect("wait");
        (woke, waited, newest, again)
    });
    let mut publisher = PosePublisher::open(&config).expect("publisher");
    ready_rx.recv().expect("subscriber is ready");
    // Give the subscriber time to enter its wait, so that the sample finds
    // it blocked (setup, not a measurement: any delay gives the same
    // outcome when the notification works).
    thread::sleep(Duration::from_millis(100));
    publisher.publish(&message(7)).expect("publish");
    let (woke, waited, newest, again) = subscriber.join().expect("subscriber thread");
    assert!(woke, "no sample after the wait");
    assert!(
        waited < WAKE_TIMEOUT,
        "the subscriber ran into its timeout instead of waking on the event"
    );
    let newest = newest.expect("a sample after the wake-up");
    assert_same_content(&newest, &message(7));
    assert!(!again, "wait returned true with no sample waiting");
}

#[test]
fn a_lagging_subscriber_gets_the_newest_pose_and_counts_the_gap() {
    const BUFFER: usize = 4;
    let (config, _root) = private_config("lag");
    let mut subscriber = Subscription::<PoseMessage>::open_service(
        &config,
        &format!("{}/pose_fast", config.service_prefix),
        BUFFER,
    )
    .expect("subscriber");
    let mut publisher = PosePublisher::open(&config).expect("publisher");
    publisher.publish_fast(&message(0)).expect("publish");
    let first = subscriber
        .wait_newest(Duration::from_secs(30))
        .expect("wait")
        .expect("first sample");
    assert_eq!(first.sequence, 0);
    // 50 more while the subscriber does not read: its buffer keeps only
    // the last BUFFER of them.
    for i in 1..=50 {
        publisher.publish_fast(&message(i)).expect("publish");
    }
    let mut waiting = Vec::new();
    subscriber.take_all(&mut waiting).expect("take");
    let sequences: Vec<u64> = waiting.iter().map(|m| m.sequence).collect();
    assert_eq!(sequences, vec![47, 48, 49, 50]);
    assert_same_content(waiting.last().expect("four samples"), &message(50));
    assert_eq!(subscriber.missed(), 46, "samples 1..=46 were overwritten");

    for i in 51..=60 {
        publisher.publish_fast(&message(i)).expect("publish");
    }
    let newest = subscriber
        .wait_newest(Duration::from_secs(30))
        .expect("wait")
        .expect("newest sample");
    assert_eq!(newest.sequence, 60);
    assert_same_content(&newest, &message(60));
    assert_eq!(subscriber.take_newest().expect("take"), None);
}

#[test]
fn streams_are_separate_and_status_round_trips() {
    let (config, _root) = private_config("status");
    let mut status_sub = StatusSubscriber::status(&config).expect("status subscriber");
    let mut pose_sub = PoseSubscriber::pose(&config).expect("pose subscriber");
    let mut publisher = PosePublisher::open(&config).expect("publisher");
    let mut status = StatusMessage {
        sensor_health: HEALTH_IMU_STREAMING,
        t_ns: 99,
        camera_rate_hz: 20.0,
        imu_rate_hz: 400.0,
        imu_drops: 3,
        latency_p99_us: 1234.5,
        imu_noise_scale_gyro: 4.5,
        imu_noise_scale_accel: 7.25,
        pixel_noise_scale: 0.375,
        camera_imu_rotation_deg: 0.25,
        camera_imu_translation_m: 0.004,
        camera_imu_time_offset_s: -0.002,
        ..StatusMessage::default()
    };
    status.set_queues(&[
        QueueFill::new("frontend", 2, 4),
        QueueFill::new("window", 0, 2),
    ]);
    publisher.publish_status(&status).expect("publish status");
    publisher.publish_fast(&message(1)).expect("publish fast");
    let got = status_sub
        .wait_newest(Duration::from_secs(30))
        .expect("wait")
        .expect("status sample");
    let mut expected = status;
    expected.published_t_ns = got.published_t_ns;
    assert_eq!(got, expected);
    assert_eq!(got.queues_in_use()[0].name_str(), "frontend");
    // pose_fast went to its own service, not to pose.
    assert!(!pose_sub.wait(Duration::from_millis(20)).expect("wait"));
}
