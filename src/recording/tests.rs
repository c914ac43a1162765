use super::*;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

#[test]
fn imu_samples_replay_bit_for_bit_with_every_compression() {
    for compression in [Compression::None, Compression::Zstd, Compression::Lz4] {
        imu_samples_replay_bit_for_bit(compression);
    }
}

fn imu_samples_replay_bit_for_bit(compression: Compression) {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("imu.mcap");
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    let samples: Vec<ImuSample> = (0..500)
        .map(|k| ImuSample {
            t_ns: 1_000_000_000 + k * 2_500_000,
            // Arbitrary doubles, including ones with 17 significant digits.
            gyro_rad_s: [
                rng.gen::<f64>() - 0.5,
                rng.gen_range(-1e-9..1e-9),
                1.0 / 3.0,
            ],
            accel_m_s2: [
                rng.gen_range(-50.0..50.0),
                9.806_65 * 0.1,
                -rng.gen::<f64>() * 1e3,
            ],
        })
        .collect();
    let mut rec = McapRecorder::create(&path, compression).expect("create");
    let meta = BTreeMap::from([("serial".to_string(), "12345678".to_string())]);
    let imu = rec.add_imu_channel("/imu0", &meta).expect("channel");
    let other = rec
        .add_imu_channel("/imu1", &BTreeMap::new())
        .expect("channel");
    for s in &samples {
        rec.write_imu(imu, s, s.t_ns + 1000).expect("write");
    }
    rec.write_imu(other, &samples[0], 0).expect("write");
    rec.finish().expect("finish");
    let back = read_imu_channel(&path, "/imu0").expect("read");
    assert_eq!(back.len(), samples.len());
    for (a, b) in back.iter().zip(&samples) {
        assert_eq!(a.t_ns, b.t_ns);
        for i in 0..3 {
            assert_eq!(a.gyro_rad_s[i].to_bits(), b.gyro_rad_s[i].to_bits());
            assert_eq!(a.accel_m_s2[i].to_bits(), b.accel_m_s2[i].to_bits());
        }
    }
    assert_eq!(read_imu_channel(&path, "/imu1").expect("read").len(), 1);
    let err = read_imu_channel(&path, "/cam0").unwrap_err();
    assert!(err.to_string().contains("no channel /cam0"), "{err}");
}

/// A stereo recording of `frames` 256x256 image pairs at 20 Hz with IMU
/// samples between, poses and the calibration attached: a chunk (1 MiB
/// uncompressed) per 8 frames.
fn stereo_recording(path: &Path, compression: Compression, frames: i64, clock: ClockMapping) {
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let mut rec = McapRecorder::create_with(
        path,
        compression,
        writer::DEFAULT_ZSTD_LEVEL,
        clock,
        Format::Foxglove,
    )
    .expect("create");
    rec.attach("calibration/cam0.yaml", "application/x-yaml", b"cam0")
        .expect("attach");
    let imu = rec.add_imu_channel("/imu0", &BTreeMap::new()).expect("imu");
    let cam0 = rec.add_image_channel("/cam0").expect("cam0");
    let cam1 = rec.add_image_channel("/cam1").expect("cam1");
    let pose = rec.add_pose_channel("/rigslam/pose").expect("pose");
    for k in 0..frames {
        let t = 1_000_000_000 + k * 50_000_000;
        for i in 0..10 {
            let s = ImuSample {
                t_ns: t + i * 5_000_000,
                gyro_rad_s: [rng.gen(), rng.gen(), rng.gen()],
                accel_m_s2: [rng.gen(), rng.gen(), 9.81],
            };
            rec.write_imu(imu, &s, s.t_ns + 1_000).expect("imu");
        }
        // A gradient with noise: compressible, as a camera's images are.
        let pixels: Vec<u8> = (0..256 * 256u32)
            .map(|i| ((i % 256 + i / 256) / 2) as u8 ^ rng.gen_range(0..8u8))
            .collect();
        let image = rigslam_drivers::Image::mono8(256, 256, pixels).expect("image");
        rec.write_image(cam0, t, &image, "cam0", t + 2_000)
            .expect("cam0");
        rec.write_image(cam1, t, &image, "cam1", t + 2_000)
            .expect("cam1");
        let mut p =
            RecordedPose::map_only(t, 1, [k as f64, 0.5, -1.0], [0.0, 0.0, 0.0, 1.0], [0.1; 3]);
        p.covariance = [k as f64 * 1e-3; 36];
        p.position_odom_m = [k as f64, 0.25, -1.5];
        p.flags = 8;
        rec.write_pose(pose, &p, t + 3_000).expect("pose");
    }
    rec.finish().expect("finish");
}

/// Every message of a complete file through the walk: (topic, sequence, log time, data).
fn all_messages(bytes: &[u8]) -> (Vec<(String, u32, u64, Vec<u8>)>, WalkReport) {
    let mut out = Vec::new();
    let report = reader::walk(bytes, Path::new("t.mcap"), |item| {
        if let reader::Item::Message(m) = item {
            out.push((
                m.channel.topic.clone(),
                m.sequence,
                m.log_time,
                m.data.to_vec(),
            ));
        }
        std::ops::ControlFlow::Continue(())
    })
    .expect("an MCAP file");
    (out, report)
}

const CLOCK: ClockMapping = ClockMapping {
    monotonic_ns: 500_000_000,
    unix_ns: 1_790_000_000_000_000_000,
};

#[test]
fn log_times_are_on_the_epoch_and_the_mapping_is_in_the_file() {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("r.mcap");
    stereo_recording(&path, Compression::Zstd, 3, CLOCK);
    let bytes = std::fs::read(&path).expect("bytes");
    let (messages, report) = all_messages(&bytes);
    assert!(report.is_whole(), "{report:?}");
    let first_imu = messages.iter().find(|m| m.0 == "/imu0").expect("imu");
    // Receipt 1e9 + 1000 ns on the monotonic clock.
    assert_eq!(
        first_imu.2,
        1_790_000_000_000_000_000 + 1_000_001_000 - 500_000_000
    );
    // The mapping, as the crate's summary reader finds it.
    let summary = mcap::Summary::read(&bytes)
        .expect("summary")
        .expect("closed");
    let index = summary
        .metadata_indexes
        .iter()
        .find(|i| i.name == writer::CLOCK_METADATA)
        .expect("clock metadata");
    let meta = mcap::read::metadata(&bytes, index).expect("metadata");
    assert_eq!(meta.metadata["monotonic_ns"], "500000000");
    assert_eq!(meta.metadata["unix_ns"], "1790000000000000000");
    // The message keeps the sensor's stamp.
    let poses = read_pose_channel_in(&bytes, &path, "/rigslam/pose").expect("poses");
    assert_eq!(poses[1].t_ns, 1_050_000_000);
}

#[test]
fn chunks_are_compressed_as_asked_and_poses_keep_both_frames() {
    let dir = tempfile::tempdir().expect("tempdir");
    let mut sizes = Vec::new();
    for (compression, name) in [
        (Compression::None, ""),
        (Compression::Zstd, "zstd"),
        (Compression::Lz4, "lz4"),
    ] {
        let path = dir.path().join(format!("r{name}.mcap"));
        stereo_recording(&path, compression, 12, CLOCK);
        let bytes = std::fs::read(&path).expect("bytes");
        let summary = mcap::Summary::read(&bytes)
            .expect("summary")
            .expect("closed");
        assert!(summary.chunk_indexes.len() >= 2, "{name}: one chunk");
        for chunk in &summary.chunk_indexes {
            assert_eq!(chunk.compression, name);
        }
        let poses = read_pose_channel_in(&bytes, &path, "/rigslam/pose").expect("poses");
        assert_eq!(poses.len(), 12);
        assert_eq!(poses[5].position_odom_m, [5.0, 0.25, -1.5]);
        assert_eq!(poses[5].covariance, [5e-3; 36]);
        assert_eq!(poses[5].flags, 8);
        sizes.push(bytes.len());
    }
    assert!(sizes[1] < sizes[0] * 3 / 4, "zstd: {sizes:?}");
    // lz4 finds repeats only: camera noise leaves it little (the bench
    // page has the numbers on real images).
    assert!(sizes[2] <= sizes[0], "lz4: {sizes:?}");
}

/// Offsets and message counts of a closed file's chunks, from the crate's
/// summary and message indexes (not from our reader).
fn chunk_layout(bytes: &[u8]) -> Vec<(u64, u64, usize)> {
    let summary = mcap::Summary::read(bytes)
        .expect("summary")
        .expect("closed");
    summary
        .chunk_indexes
        .iter()
        .map(|c| {
            let indexes = summary
                .read_message_indexes(bytes, c)
                .expect("message indexes");
            let count = indexes.values().map(Vec::len).sum();
            (
                c.chunk_start_offset,
                c.chunk_start_offset + c.chunk_length,
                count,
            )
        })
        .collect()
}

#[test]
fn a_file_cut_short_gives_every_message_of_its_complete_chunks() {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("r.mcap");
    stereo_recording(&path, Compression::Zstd, 24, CLOCK);
    let whole = std::fs::read(&path).expect("bytes");
    let layout = chunk_layout(&whole);
    let (all, _) = all_messages(&whole);
    for cut in [
        whole.len() / 3,
        whole.len() / 2,
        whole.len() * 9 / 10,
        layout[2].1 as usize,
    ] {
        let bytes = &whole[..cut];
        let expected: usize = layout
            .iter()
            .filter(|c| c.1 as usize <= cut)
            .map(|c| c.2)
            .sum();
        let (got, report) = all_messages(bytes);
        assert_eq!(got.len(), expected, "cut at {cut}");
        assert_eq!(got[..], all[..expected], "cut at {cut}");
        let FileEnd::Cut { at, .. } = &report.end else {
            panic!("cut at {cut}: {:?}", report.end);
        };
        assert!(*at as usize <= cut, "{at} > {cut}");
        // The replay plays them, and the attachments are found without a summary.
        let end = for_each_sensor_event_in(
            bytes,
            &path,
            SensorTopics {
                stereo: true,
                imu: true,
            },
            |_| std::ops::ControlFlow::Continue(()),
        )
        .expect("replay");
        assert_eq!(end.file, report);
        let attachments = read_attachments_in(bytes, &path).expect("attachments");
        assert_eq!(attachments["calibration/cam0.yaml"], b"cam0");
    }
}

#[test]
fn a_damaged_chunk_is_skipped_and_named_and_the_rest_is_read() {
    for compression in [Compression::None, Compression::Zstd, Compression::Lz4] {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("r.mcap");
        stereo_recording(&path, compression, 24, CLOCK);
        let mut bytes = std::fs::read(&path).expect("bytes");
        let layout = chunk_layout(&bytes);
        let (all, _) = all_messages(&bytes);
        // A byte in the middle of the second chunk's data.
        let (start, end, lost) = layout[1];
        let at = ((start + end) / 2) as usize;
        bytes[at] ^= 0x5a;
        let (got, report) = all_messages(&bytes);
        assert_eq!(got.len(), all.len() - lost, "{compression:?}");
        let before = layout[0].2;
        assert_eq!(got[..before], all[..before]);
        assert_eq!(got[before..], all[before + lost..]);
        assert_eq!(report.end, FileEnd::Complete);
        assert_eq!(report.skipped.len(), 1, "{compression:?}: {report:?}");
        let skipped = &report.skipped[0].reason;
        assert!(
            skipped.contains(&format!("chunk at byte {start}")),
            "{skipped}"
        );
        // Reading a whole channel says the file is damaged, naming where.
        let e = read_pose_channel_in(&bytes, &path, "/rigslam/pose").unwrap_err();
        assert!(
            e.to_string().contains(&format!("chunk at byte {start}")),
            "{e}"
        );
    }
}

#[test]
fn a_chunk_in_a_compression_the_specification_does_not_name_is_skipped() {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("r.mcap");
    stereo_recording(&path, Compression::Lz4, 24, CLOCK);
    let mut bytes = std::fs::read(&path).expect("bytes");
    let layout = chunk_layout(&bytes);
    // The chunk header: opcode, length, 3 u64, crc u32, then the string.
    let name_at = layout[0].0 as usize + 9 + 8 * 3 + 4 + 4;
    assert_eq!(&bytes[name_at..name_at + 3], b"lz4");
    bytes[name_at..name_at + 3].copy_from_slice(b"lzo");
    let (got, report) = all_messages(&bytes);
    // The first chunk declared the channels: the summary's copies of them
    // let the rest be read.
    let (all, _) = all_messages(&std::fs::read(&path).expect("bytes"));
    assert_eq!(got[..], all[layout[0].2..]);
    assert_eq!(report.skipped.len(), 1);
    assert!(
        report.skipped[0].reason.contains("\"lzo\""),
        "{:?}",
        report.skipped
    );
}

#[test]
fn a_repair_rewrites_what_a_cut_file_holds_as_a_closed_file() {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("rigslam-000007.mcap");
    stereo_recording(&path, Compression::Zstd, 24, CLOCK);
    let whole = std::fs::read(&path).expect("bytes");
    let cut = &whole[..whole.len() * 2 / 3];
    std::fs::write(&path, cut).expect("cut");
    // Not closed: no summary to count from.
    assert!(channel_counts(&path).is_err());
    let target = repair::repaired_name(&path);
    assert_eq!(target, dir.path().join("rigslam-000007.repaired.mcap"));
    let done = repair::repair(&path, &target).expect("repair");
    assert_eq!(
        std::fs::read(&path).expect("original"),
        cut,
        "the original was touched"
    );
    let (recovered, _) = all_messages(cut);
    let repaired = std::fs::read(&target).expect("repaired");
    let (rewritten, report) = all_messages(&repaired);
    assert!(report.is_whole(), "{report:?}");
    assert_eq!(rewritten, recovered);
    let counts = channel_counts(&target).expect("a closed file");
    assert_eq!(counts.values().sum::<u64>(), recovered.len() as u64);
    assert_eq!(done.messages.values().sum::<u64>(), recovered.len() as u64);
    assert_eq!(counts["/cam0"], done.messages["/cam0"]);
    assert!(matches!(done.source.end, FileEnd::Cut { .. }));
    assert_eq!(
        read_attachments(&target).expect("attachments")["calibration/cam0.yaml"],
        b"cam0"
    );
    // The clock mapping comes along.
    let summary = mcap::Summary::read(&repaired)
        .expect("summary")
        .expect("closed");
    assert!(summary
        .metadata_indexes
        .iter()
        .any(|m| m.name == writer::CLOCK_METADATA));
    // Never over the file it reads.
    let e = repair::repair(&path, &path).unwrap_err();
    assert!(e.to_string().contains("never writes over"), "{e}");
}

#[test]
fn recordings_in_the_earlier_json_layout_still_replay() {
    let path = Path::new(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/tests/fuzz/corpus/mcap_recording/stereo_imu_calibration.mcap"
    ));
    let bytes = std::fs::read(path).expect("the JSON seed recording");
    let mut imu = Vec::new();
    let mut frames = Vec::new();
    let end = for_each_sensor_event_in(
        &bytes,
        path,
        SensorTopics {
            stereo: true,
            imu: true,
        },
        |item| {
            match item {
                ReplayItem::Event(crate::dataset::SensorEvent::Imu(s)) => imu.push(s),
                ReplayItem::Event(crate::dataset::SensorEvent::Frame { t_ns, left, right }) => {
                    frames.push((t_ns, left.image.width(), right.is_some()))
                }
                ReplayItem::Skipped(s) => panic!("{s}"),
            }
            std::ops::ControlFlow::Continue(())
        },
    )
    .expect("replay");
    assert!(end.file.is_whole());
    // What the seed generator wrote: 4 samples, a stereo pair every other one.
    assert_eq!(imu.len(), 4);
    assert_eq!(imu[3].accel_m_s2, [0.1, 9.81, -0.6000000000000001]);
    assert_eq!(
        frames,
        vec![(1_000_000_000, 4, true), (1_010_000_000, 4, true)]
    );
    let poses = read_pose_channel_in(&bytes, path, "/pose").expect("poses");
    assert_eq!(poses.len(), 2);
    assert_eq!(poses[1].position_world_m, [0.1, 0.2, 0.3]);
    assert_eq!(poses[1].position_odom_m, poses[1].position_world_m);
}

/// The profile in a file's header record.
fn profile_of(bytes: &[u8]) -> String {
    match mcap::read::LinearReader::new(bytes)
        .expect("an MCAP file")
        .next()
    {
        Some(Ok(mcap::records::Record::Header(h))) => h.profile,
        other => panic!("no header first: {other:?}"),
    }
}

/// A ROS 2 recording: the `ros2` profile, the `rosbag2` record, ROS
/// types in `ros2msg` and CDR on every channel, and the sensor streams
/// replay bit for bit (IMU values and stamps, pixels), including the
/// stereo half without its partner, named by its ROS topic.
#[test]
fn ros2_recordings_replay_bit_for_bit() {
    use ros2::messages::{Image, Imu};
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("ros2.mcap");
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let mut rec = McapRecorder::create_with(
        &path,
        Compression::Zstd,
        writer::DEFAULT_ZSTD_LEVEL,
        CLOCK,
        Format::Ros2,
    )
    .expect("create");
    let meta = ros2::channel_metadata(false);
    let imu = rec.add_channel::<Imu>(ros2::IMU_TOPIC, &meta).expect("imu");
    let cams = [0, 1].map(|i| {
        rec.add_channel::<Image>(&ros2::image_topic(i), &meta)
            .expect("camera")
    });
    let mut samples = Vec::new();
    let mut images = Vec::new();
    for k in 0..12i64 {
        let t = 1_403_636_579_763_555_584 + k * 50_000_000;
        for i in 0..10 {
            let s = ImuSample {
                t_ns: t + i * 5_000_000 + 7,
                gyro_rad_s: [
                    rng.gen::<f64>() - 0.5,
                    rng.gen_range(-1e-9..1e-9),
                    1.0 / 3.0,
                ],
                accel_m_s2: [rng.gen_range(-50.0..50.0), -0.0, 9.81],
            };
            rec.write(imu, &ros2::convert::imu(&s, Some([1e-4, 1e-2])), s.t_ns)
                .expect("imu");
            samples.push(s);
        }
        let pixels: Vec<u8> = (0..64 * 48).map(|_| rng.gen()).collect();
        let image = rigslam_drivers::Image::mono8(64, 48, pixels).expect("image");
        for (i, cam) in cams.iter().enumerate() {
            // Frame 4 lost its right image.
            if k == 4 && i == 1 {
                continue;
            }
            let name = format!("cam{i}");
            rec.write(*cam, &ros2::convert::image(t, &image, &name), t)
                .expect("image");
        }
        images.push((t, image));
    }
    rec.finish().expect("finish");
    let bytes = std::fs::read(&path).expect("bytes");

    assert_eq!(profile_of(&bytes), "ros2");
    let summary = mcap::Summary::read(&bytes)
        .expect("summary")
        .expect("closed");
    let bag = summary
        .metadata_indexes
        .iter()
        .find(|i| i.name == ros2::BAG_METADATA_NAME)
        .expect("the rosbag2 record");
    let bag = mcap::read::metadata(&bytes, bag).expect("metadata");
    assert_eq!(bag.metadata, ros2::bag_metadata());
    let mut channels = Vec::new();
    reader::walk(&bytes, &path, |item| {
        if let reader::Item::Channel(c) = item {
            channels.push(c.clone());
        }
        std::ops::ControlFlow::Continue(())
    })
    .expect("walk");
    assert_eq!(channels.len(), 3);
    for c in &channels {
        assert_eq!(
            (c.message_encoding.as_str(), c.schema_encoding.as_str()),
            ("cdr", "ros2msg")
        );
        assert_eq!(c.metadata, meta, "{}", c.topic);
    }
    assert_eq!(channels[0].schema_name, "sensor_msgs/msg/Imu");
    assert_eq!(channels[1].schema_name, "sensor_msgs/msg/Image");

    let mut replayed = Vec::new();
    let mut frames = Vec::new();
    let mut skipped = Vec::new();
    let end = for_each_sensor_event_in(
        &bytes,
        &path,
        SensorTopics {
            stereo: true,
            imu: true,
        },
        |item| {
            match item {
                ReplayItem::Event(crate::dataset::SensorEvent::Imu(s)) => replayed.push(s),
                ReplayItem::Event(crate::dataset::SensorEvent::Frame { t_ns, left, right }) => {
                    frames.push((t_ns, left, right.expect("stereo")))
                }
                ReplayItem::Skipped(s) => skipped.push(s.to_string()),
            }
            std::ops::ControlFlow::Continue(())
        },
    )
    .expect("replay");
    assert!(end.file.is_whole(), "{end:?}");
    assert_eq!(replayed.len(), samples.len());
    for (a, b) in replayed.iter().zip(&samples) {
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
    assert_eq!(
        read_imu_channel_in(&bytes, &path, "/imu0").expect("imu channel"),
        samples
    );
    assert_eq!(frames.len(), images.len() - 1);
    let paired = images.iter().enumerate().filter(|(k, _)| *k != 4);
    for ((t, left, right), (_, (t_image, image))) in frames.iter().zip(paired) {
        assert_eq!(t, t_image);
        assert_eq!((left.camera_index, right.camera_index), (0, 1));
        assert_eq!(left.image.data(), image.data(), "left pixels at {t}");
        assert_eq!(right.image.data(), image.data(), "right pixels at {t}");
        assert_eq!(left.image.width(), 64);
    }
    assert_eq!(skipped.len(), 1, "{skipped:?}");
    assert!(
        skipped[0].contains("/cam0/image_raw") && skipped[0].contains("message 5"),
        "{skipped:?}"
    );

    // A repair of the file cut short keeps the profile and the records.
    let cut = dir.path().join("cut.mcap");
    std::fs::write(&cut, &bytes[..bytes.len() * 2 / 3]).expect("write");
    let repaired = dir.path().join("repaired.mcap");
    repair::repair(&cut, &repaired).expect("repair");
    let repaired = std::fs::read(&repaired).expect("repaired");
    assert_eq!(profile_of(&repaired), "ros2");
    let summary = mcap::Summary::read(&repaired)
        .expect("summary")
        .expect("closed");
    assert!(summary
        .metadata_indexes
        .iter()
        .any(|i| i.name == ros2::BAG_METADATA_NAME));
    // The profile of a foxglove file stays empty.
    let plain = dir.path().join("plain.mcap");
    stereo_recording(&plain, Compression::None, 1, CLOCK);
    let again = dir.path().join("plain.repaired.mcap");
    repair::repair(&plain, &again).expect("repair");
    assert_eq!(profile_of(&std::fs::read(&again).expect("read")), "");

    // A ROS message of another type on /imu0 is refused, naming both.
    let other = dir.path().join("other.mcap");
    let mut rec = McapRecorder::create_with(&other, Compression::None, 0, CLOCK, Format::Ros2)
        .expect("create");
    let tf = rec
        .add_channel::<ros2::messages::TfMessage>("/imu0", &meta)
        .expect("channel");
    rec.write(tf, &ros2::messages::TfMessage::default(), 0)
        .expect("write");
    rec.finish().expect("finish");
    let e = read_imu_channel(&other, "/imu0").unwrap_err().to_string();
    assert!(
        e.contains("tf2_msgs/msg/TFMessage") && e.contains("sensor_msgs/msg/Imu"),
        "{e}"
    );
}

#[test]
fn messages_in_a_schema_rigslam_does_not_know_are_skipped_by_name() {
    // A file another tool wrote: /imu0 in CBOR, /cam0 without a schema.
    let mut bytes = std::io::Cursor::new(Vec::new());
    let mut w = mcap::WriteOptions::new()
        .compression(None)
        .create(&mut bytes)
        .expect("writer");
    let schema = w
        .add_schema("other.Imu", "cbor-schema", b"{}")
        .expect("schema");
    let imu = w
        .add_channel(schema, "/imu0", "cbor", &BTreeMap::new())
        .expect("channel");
    let cam = w
        .add_channel(0, "/cam0", "raw", &BTreeMap::new())
        .expect("channel");
    for (channel, sequence) in [(imu, 1), (cam, 1), (imu, 2)] {
        let header = mcap::records::MessageHeader {
            channel_id: channel,
            sequence,
            log_time: u64::from(sequence),
            publish_time: u64::from(sequence),
        };
        w.write_to_known_channel(&header, b"\xa1\x01\x02")
            .expect("write");
    }
    w.finish().expect("finish");
    drop(w);
    let bytes = bytes.into_inner();
    let mut skipped = Vec::new();
    let end = for_each_sensor_event_in(
        &bytes,
        Path::new("other.mcap"),
        SensorTopics {
            stereo: false,
            imu: true,
        },
        |item| {
            match item {
                ReplayItem::Skipped(s) => skipped.push(s.to_string()),
                ReplayItem::Event(e) => panic!("{e:?} from an unknown schema"),
            }
            std::ops::ControlFlow::Continue(())
        },
    )
    .expect("the file itself reads");
    assert_eq!(end.events, 0);
    assert_eq!(skipped.len(), 3, "{skipped:?}");
    assert!(
        skipped[0].contains("other.mcap") && skipped[0].contains("\"cbor\""),
        "{skipped:?}"
    );
    assert!(
        skipped[1].contains("/cam0") && skipped[1].contains("\"raw\""),
        "{skipped:?}"
    );
}
