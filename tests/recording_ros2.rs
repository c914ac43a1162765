//! Recordings in ROS 2's format (`[recording] format = "ros2"`) as a ROS
//! tool reads them, and as `rigslamd` replays them.
//!
//! The bundled EuRoC sequence goes through the daemon's pipeline with
//! the recorder on. Python's `mcap-ros2-support`, which decodes CDR from
//! the `ros2msg` definitions in the file and nothing else, must find the
//! values that went in: every IMU sample exactly, every image's pixels
//! (CRC-32), every published pose as odometry and as `/tf`, the rig's
//! static transforms and camera intrinsics; it encodes each message again
//! and must get the file's bytes. `tests/readers/check_ros2.py` is the
//! Python side; it needs `RIGSLAM_PYTHON` (`scripts/test` makes one in
//! `target/py`), and that part skips without it, except with `CI` set.
//!
//! The same recording then replays through the pipeline to the live
//! run's poses bit for bit, its IMU samples and pixels equal to the
//! dataset's.

use std::ops::ControlFlow;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use nalgebra::{Matrix3, Matrix6, Quaternion, UnitQuaternion, Vector3};
use rigslam::daemon::config::{DaemonConfig, ReplayPace};
use rigslam::daemon::{check, Pipeline};
use rigslam::dataset::{open_dataset, SensorEvent, SensorStream, StreamOptions};
use rigslam::publish::{PoseMessage, POSE_FLAG_COVARIANCE_VALID, POSE_FLAG_VELOCITY_VALID};
use rigslam::recording::{for_each_sensor_event, Format, ReplayItem, SensorTopics};
use rigslam::relative::{RigModel, SensorMode};
use rigslam::sensors::ImuSample;
use rigslam::shared_data;
use serde_json::Value;

#[path = "common/collect.rs"]
mod collect;
use collect::Collect;

#[path = "common/python.rs"]
mod python_env;

/// A Python that imports the MCAP reader and its ROS 2 decoder, or
/// `None` (skip) outside CI.
fn python() -> Option<PathBuf> {
    python_env::python_with(
        "mcap, mcap_ros2, zstandard, lz4",
        "mcap mcap-ros2-support zstandard lz4",
    )
}

/// What `check_ros2.py` found in `file`.
fn python_reads(python: &Path, file: &Path) -> Value {
    python_env::script_json(python, "check_ros2.py", file)
}

fn f64s(v: &Value) -> Vec<f64> {
    v.as_array()
        .unwrap_or_else(|| panic!("not an array: {v}"))
        .iter()
        .map(|x| x.as_f64().unwrap_or_else(|| panic!("not a number: {x}")))
        .collect()
}

fn unix_now_ns() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .expect("after 1970")
        .as_nanos() as u64
}

fn bits(m: &PoseMessage) -> Vec<u64> {
    let mut v = vec![m.t_ns as u64, m.tracking_state as u64, m.flags as u64];
    v.extend(m.position_world_m.iter().map(|x| x.to_bits()));
    v.extend(m.orientation_world_body_xyzw.iter().map(|x| x.to_bits()));
    v.extend(m.velocity_world_m_s.iter().map(|x| x.to_bits()));
    v.extend(m.position_odom_m.iter().map(|x| x.to_bits()));
    v
}

/// Runs a replay config as fast as possible to its end: every pose, the
/// recordings it made.
fn run(mut config: DaemonConfig) -> (Vec<PoseMessage>, Vec<PathBuf>) {
    config.replay.as_mut().expect("replay config").pace = ReplayPace::AsFastAsPossible;
    let rig = check(&config, Path::new("(test)")).expect("valid config");
    let sink = Collect::default();
    let pipeline = Pipeline::start(&config, rig, Box::new(sink.clone())).expect("start");
    let deadline = Instant::now() + Duration::from_secs(300);
    while !pipeline.finished() {
        assert!(Instant::now() < deadline, "replay did not finish in 300 s");
        std::thread::sleep(Duration::from_millis(20));
    }
    let report = pipeline.stop().expect("stop");
    assert_eq!(report.frame_drops + report.imu_drops, 0, "{report:?}");
    assert_eq!(report.recording_drops, 0, "{report:?}");
    let poses = sink.poses.lock().expect("lock").clone();
    assert_eq!(poses.len() as u64, report.frames, "{report:?}");
    (poses, report.recordings)
}

/// The 8-bit rows of an image without their padding.
fn rows(image: &rigslam::sensors::Image) -> Vec<u8> {
    let (w, stride) = (image.width() as usize, image.stride_bytes());
    (0..image.height() as usize)
        .flat_map(|y| image.data()[y * stride..y * stride + w].iter().copied())
        .collect()
}

/// Every IMU sample and stereo frame of the sequence, as the dataset has them.
fn dataset_events(root: &Path) -> (Vec<ImuSample>, Vec<(i64, Vec<u8>, Vec<u8>)>) {
    let dataset = open_dataset(root).expect("dataset");
    let stream = SensorStream::new(
        &dataset,
        StreamOptions {
            stereo: true,
            imu: true,
            start_ns: None,
            max_frames: None,
            imu_lead_ns: 0,
        },
    )
    .expect("stream");
    let (mut imu, mut frames) = (Vec::new(), Vec::new());
    for event in stream {
        match event.expect("event") {
            SensorEvent::Imu(s) => imu.push(s),
            SensorEvent::Frame { t_ns, left, right } => {
                frames.push((t_ns, rows(&left.image), rows(&right.expect("stereo").image)))
            }
        }
    }
    (imu, frames)
}

fn quaternion(q: [f64; 4]) -> UnitQuaternion<f64> {
    UnitQuaternion::from_quaternion(Quaternion::new(q[3], q[0], q[1], q[2]))
}

/// Stamp fields (sec, nanosec) as ns.
fn stamp_ns(v: &[Value]) -> i64 {
    v[0].as_i64().expect("sec") * 1_000_000_000 + v[1].as_i64().expect("nanosec")
}

fn close(a: &[f64], b: &[f64], scale: f64, what: &str) {
    assert_eq!(a.len(), b.len(), "{what}");
    for (x, y) in a.iter().zip(b) {
        assert!(
            (x - y).abs() <= 1e-12 * scale.max(1.0),
            "{what}: {a:?} vs {b:?}"
        );
    }
}

#[test]
fn a_ros2_recording_reads_in_ros_tools_and_replays_bit_for_bit() {
    let Some(root) = shared_data::path_or_skip("euroc/V1_01_micro") else {
        return;
    };
    let dir = tempfile::tempdir().expect("tempdir");
    let mut config = DaemonConfig::replay(&root, SensorMode::StereoInertial);
    config.recording.enabled = true;
    config.recording.dir = dir.path().join("rec");
    config.recording.format = Format::Ros2;
    let rig = check(&config, Path::new("(test)")).expect("valid config");
    let before = unix_now_ns();
    let (live, recordings) = run(config);
    let after = unix_now_ns();
    assert_eq!(recordings.len(), 1, "{recordings:?}");
    let file = &recordings[0];
    let (imu, frames) = dataset_events(&root);
    assert!(live.len() > 50 && frames.len() == live.len());

    if let Some(python) = python() {
        let py = python_reads(&python, file);
        check_what_python_decoded(&py, &rig, &imu, &frames, &live, (before, after));
    }

    // rigslam's own replay reads the ROS 2 streams back as they went in.
    let (mut replay_imu, mut replay_frames) = (Vec::new(), Vec::new());
    let end = for_each_sensor_event(
        file,
        SensorTopics {
            stereo: true,
            imu: true,
        },
        |item| {
            match item {
                ReplayItem::Event(SensorEvent::Imu(s)) => replay_imu.push(s),
                ReplayItem::Event(SensorEvent::Frame { t_ns, left, right }) => replay_frames
                    .push((t_ns, rows(&left.image), rows(&right.expect("stereo").image))),
                ReplayItem::Skipped(s) => panic!("{s}"),
            }
            ControlFlow::Continue(())
        },
    )
    .expect("replay");
    assert!(end.file.is_whole(), "{end:?}");
    assert_eq!(replay_imu.len(), imu.len());
    for (a, b) in replay_imu.iter().zip(&imu) {
        assert_eq!(a.t_ns, b.t_ns);
        assert_eq!(
            a.gyro_rad_s.map(f64::to_bits),
            b.gyro_rad_s.map(f64::to_bits)
        );
        assert_eq!(
            a.accel_m_s2.map(f64::to_bits),
            b.accel_m_s2.map(f64::to_bits)
        );
    }
    assert!(replay_frames == frames, "the replayed pixels differ");

    // And through the pipeline, with the rig the file carries: the live
    // run's poses to the bit.
    let (replayed, _) = run(DaemonConfig::replay(file, SensorMode::StereoInertial));
    assert_eq!(replayed.len(), live.len());
    for (i, (x, y)) in replayed.iter().zip(&live).enumerate() {
        assert_eq!(bits(x), bits(y), "pose {i} differs from the live run's");
    }
}

fn check_what_python_decoded(
    py: &Value,
    rig: &RigModel,
    imu: &[ImuSample],
    frames: &[(i64, Vec<u8>, Vec<u8>)],
    live: &[PoseMessage],
    (before, after): (u64, u64),
) {
    // The file: profile, schemas, encodings, QoS, the rosbag2 record.
    assert_eq!(py["profile"], "ros2");
    let schemas = py["schemas"].as_object().expect("schemas");
    assert_eq!(schemas.len(), 5, "{schemas:?}");
    assert!(schemas.values().all(|e| e == "ros2msg"), "{schemas:?}");
    let expected_channels = [
        ("/imu0", "sensor_msgs/msg/Imu", false),
        ("/cam0/image_raw", "sensor_msgs/msg/Image", false),
        ("/cam1/image_raw", "sensor_msgs/msg/Image", false),
        ("/rigslam/odom", "nav_msgs/msg/Odometry", false),
        ("/tf", "tf2_msgs/msg/TFMessage", false),
        ("/tf_static", "tf2_msgs/msg/TFMessage", true),
        ("/cam0/camera_info", "sensor_msgs/msg/CameraInfo", false),
        ("/cam1/camera_info", "sensor_msgs/msg/CameraInfo", false),
    ];
    let channels = py["channels"].as_object().expect("channels");
    assert_eq!(channels.len(), expected_channels.len(), "{channels:?}");
    for (topic, schema, latched) in expected_channels {
        let c = &channels[topic];
        assert_eq!(c["schema"], schema, "{topic}");
        assert_eq!(c["message_encoding"], "cdr", "{topic}");
        let qos = c["metadata"]["offered_qos_profiles"]
            .as_str()
            .unwrap_or_else(|| panic!("{topic}: no QoS"));
        let durability = if latched { 1 } else { 2 };
        assert!(
            qos.contains(&format!("\n  durability: {durability}\n")),
            "{topic}: {qos}"
        );
    }
    assert_eq!(
        py["metadata"]["rosbag2"],
        serde_json::json!({"serialized_metadata": ""})
    );
    assert!(py["metadata"]["rigslam.clock"]["unix_ns"].is_string());
    for name in ["calibration/cam0.yaml", "calibration/imu0.yaml"] {
        assert!(
            py["attachments"]
                .as_array()
                .expect("names")
                .iter()
                .any(|n| n == name),
            "{name}"
        );
    }
    // Every message decoded, in both passes, and encoded again to the
    // file's bytes by the package's own CDR writer.
    let total: u64 = py["messages"]
        .as_object()
        .expect("counts")
        .values()
        .map(|n| n.as_u64().expect("count"))
        .sum();
    assert_eq!(py["statistics_messages"], total);
    assert_eq!(py["streamed_messages"], total);
    assert_eq!(
        py["reencoded_differ"],
        serde_json::json!({}),
        "the package encodes these messages otherwise"
    );
    for (topic, times) in py["log_times"].as_object().expect("topics") {
        for t in times.as_array().expect("times") {
            let t = t.as_u64().expect("ns");
            assert!(
                (before..=after).contains(&t),
                "{topic}: log time {t} outside the run"
            );
        }
    }

    // IMU: every sample exact, no orientation, the rig's noise.
    let noise = rig.imu.as_ref().expect("an IMU");
    let gyro_var = noise.noise.gyroscope_noise_density.powi(2) * noise.rate_hz;
    let accel_var = noise.noise.accelerometer_noise_density.powi(2) * noise.rate_hz;
    let values = py["values"]["/imu0"].as_array().expect("imu");
    assert_eq!(values.len(), imu.len());
    for (v, s) in values.iter().zip(imu) {
        let v = v.as_array().expect("fields");
        assert_eq!(stamp_ns(v), s.t_ns);
        assert_eq!(v[2], "imu");
        assert_eq!(f64s(&Value::Array(v[3..7].to_vec())), [0.0, 0.0, 0.0, 1.0]);
        assert_eq!(f64s(&v[7])[0], -1.0, "orientation unknown");
        assert_eq!(f64s(&Value::Array(v[8..11].to_vec())), s.gyro_rad_s);
        assert_eq!(f64s(&Value::Array(v[12..15].to_vec())), s.accel_m_s2);
        for (index, variance) in [(11, gyro_var), (15, accel_var)] {
            let c = f64s(&v[index]);
            let diagonal = [variance, 0.0, 0.0, 0.0, variance, 0.0, 0.0, 0.0, variance];
            close(&c, &diagonal, variance * 1e4, "IMU covariance");
        }
    }

    // Images: stamps, sizes, every pixel.
    for (side, topic) in ["/cam0/image_raw", "/cam1/image_raw"].iter().enumerate() {
        let values = py["values"][*topic].as_array().expect("images");
        assert_eq!(values.len(), frames.len(), "{topic}");
        for (v, (t_ns, left, right)) in values.iter().zip(frames) {
            let v = v.as_array().expect("fields");
            let pixels = if side == 0 { left } else { right };
            assert_eq!(stamp_ns(v), *t_ns);
            assert_eq!(v[2], format!("cam{side}"));
            let width = rig.cameras[side].model.width();
            let height = rig.cameras[side].model.height();
            assert_eq!(
                (v[3].as_u64(), v[4].as_u64()),
                (Some(height.into()), Some(width.into()))
            );
            assert_eq!(v[5], "mono8");
            assert_eq!(v[6], 0);
            assert_eq!(v[7], width);
            assert_eq!(v[8], pixels.len());
            assert_eq!(v[9], crc32fast::hash(pixels), "{topic} at {t_ns}");
        }
    }

    // Odometry: the published odometry-frame pose exactly, its
    // covariance turned into the odometry frame's axes, the velocity in
    // the body frame.
    let values = py["values"]["/rigslam/odom"].as_array().expect("odometry");
    assert_eq!(values.len(), live.len());
    let mut with_covariance = 0;
    for (v, p) in values.iter().zip(live) {
        let v = v.as_array().expect("fields");
        assert_eq!(stamp_ns(v), p.t_ns);
        assert_eq!((&v[2], &v[3]), (&Value::from("odom"), &Value::from("body")));
        assert_eq!(f64s(&Value::Array(v[4..7].to_vec())), p.position_odom_m);
        assert_eq!(
            f64s(&Value::Array(v[7..11].to_vec())),
            p.orientation_odom_body_xyzw
        );
        let covariance = f64s(&v[11]);
        if p.flags & POSE_FLAG_COVARIANCE_VALID != 0 {
            with_covariance += 1;
            let r: Matrix3<f64> = quaternion(p.rotation_world_odom_xyzw)
                .to_rotation_matrix()
                .matrix()
                .transpose();
            let mut turn = Matrix6::zeros();
            turn.fixed_view_mut::<3, 3>(0, 0).copy_from(&r);
            turn.fixed_view_mut::<3, 3>(3, 3).copy_from(&r);
            let odom = turn * Matrix6::from_row_slice(&p.covariance) * turn.transpose();
            let expected: Vec<f64> = (0..36).map(|i| odom[(i / 6, i % 6)]).collect();
            let scale = p.covariance.iter().fold(0.0f64, |m, c| m.max(c.abs()));
            close(&covariance, &expected, scale, "pose covariance");
        } else {
            assert_eq!(covariance, [0.0; 36]);
        }
        let velocity = f64s(&Value::Array(v[12..15].to_vec()));
        if p.flags & POSE_FLAG_VELOCITY_VALID != 0 {
            let body = quaternion(p.orientation_world_body_xyzw).inverse()
                * Vector3::from(p.velocity_world_m_s);
            close(&velocity, body.as_slice(), 1.0, "body velocity");
        } else {
            assert_eq!(velocity, [0.0; 3]);
        }
        assert_eq!(f64s(&Value::Array(v[15..18].to_vec())), [0.0; 3]);
        assert_eq!(f64s(&v[18]), [0.0; 36]);
    }
    assert!(
        with_covariance >= 5,
        "{with_covariance} poses with a covariance"
    );

    // /tf: map -> odom -> body with every pose, exactly as published.
    let tf = py["values"]["/tf"].as_array().expect("tf");
    assert_eq!(tf.len(), live.len());
    for (t, p) in tf.iter().zip(live) {
        let t = t.as_array().expect("transforms");
        assert_eq!(t.len(), 2);
        for (transform, parent, child, translation, rotation) in [
            (
                &t[0],
                "map",
                "odom",
                p.translation_world_odom_m,
                p.rotation_world_odom_xyzw,
            ),
            (
                &t[1],
                "odom",
                "body",
                p.position_odom_m,
                p.orientation_odom_body_xyzw,
            ),
        ] {
            let v = transform.as_array().expect("fields");
            assert_eq!(stamp_ns(v), p.t_ns);
            assert_eq!((&v[2], &v[3]), (&Value::from(parent), &Value::from(child)));
            assert_eq!(f64s(&Value::Array(v[4..7].to_vec())), translation);
            assert_eq!(f64s(&Value::Array(v[7..11].to_vec())), rotation);
        }
    }

    // /tf_static once: where the cameras and the IMU sit on the body.
    let statics = py["values"]["/tf_static"].as_array().expect("tf_static");
    assert_eq!(statics.len(), 1);
    let statics = statics[0].as_array().expect("transforms");
    let mut expected = vec![
        ("cam0", rig.cameras[0].T_body_cam),
        ("cam1", rig.cameras[1].T_body_cam),
    ];
    expected.push(("imu", rig.imu.as_ref().expect("IMU").T_body_imu));
    assert_eq!(statics.len(), expected.len());
    for (v, (child, pose)) in statics.iter().zip(&expected) {
        let v = v.as_array().expect("fields");
        assert_eq!((&v[2], &v[3]), (&Value::from("body"), &Value::from(*child)));
        let t = pose.translation.vector;
        let q = pose.rotation.coords;
        assert_eq!(f64s(&Value::Array(v[4..7].to_vec())), [t.x, t.y, t.z]);
        assert_eq!(f64s(&Value::Array(v[7..11].to_vec())), [q.x, q.y, q.z, q.w]);
    }

    // A camera info with every image, under its stamp (image_proc pairs
    // them by stamp): the rig's intrinsics.
    for (i, camera) in rig.cameras.iter().enumerate() {
        let values = py["values"][format!("/cam{i}/camera_info")]
            .as_array()
            .expect("camera info");
        let images = py["values"][format!("/cam{i}/image_raw")]
            .as_array()
            .expect("images");
        assert_eq!(values.len(), images.len(), "cam{i}");
        for (info, image) in values.iter().zip(images) {
            assert_eq!((&info[0], &info[1]), (&image[0], &image[1]), "cam{i}");
        }
        let v = values[0].as_array().expect("fields");
        let [fx, fy, cx, cy] = camera.model.pinhole();
        assert_eq!(v[2], format!("cam{i}"));
        assert_eq!(v[3], camera.model.height());
        assert_eq!(v[4], camera.model.width());
        assert_eq!(v[5], "plumb_bob");
        assert_eq!(f64s(&v[6]), camera.model.distortion_coefficients());
        assert_eq!(f64s(&v[7]), [fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0]);
        assert_eq!(
            f64s(&v[9]),
            [fx, 0.0, cx, 0.0, 0.0, fy, cy, 0.0, 0.0, 0.0, 1.0, 0.0]
        );
    }
}
