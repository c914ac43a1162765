use super::*;

const PRIMITIVES: &[&str] = &[
    "bool", "byte", "char", "float32", "float64", "int8", "uint8", "int16", "uint16", "int32",
    "uint32", "int64", "uint64", "string", "wstring",
];

/// Every definition names each type its fields use exactly once in its
/// `MSG:` sections, and no other: what a reader that knows no ROS types
/// needs, and nothing that would make it guess.
#[test]
fn complete_definitions_hold_every_type_they_use_once() {
    for d in [&IMAGE, &IMU, &ODOMETRY, &TF_MESSAGE, &CAMERA_INFO] {
        let text = d.complete();
        let mut sections: Vec<(String, &str)> = Vec::new();
        for (i, part) in text.split(&format!("\n{SEPARATOR}\n")).enumerate() {
            if i == 0 {
                sections.push((d.short_name(), part));
                continue;
            }
            let (first, rest) = part.split_once('\n').expect("a MSG line, then fields");
            let name = first.strip_prefix("MSG: ").expect("MSG: line");
            assert!(
                !sections.iter().any(|(n, _)| n == name),
                "{}: {name} twice",
                d.name
            );
            sections.push((name.to_owned(), rest));
        }
        let mut used = vec![d.short_name()];
        for (name, fields) in &sections {
            let package = name.split('/').next().expect("pkg/Type");
            for line in fields.lines() {
                let ty = line.split_whitespace().next().expect("a type");
                let base = ty.split('[').next().expect("type");
                if PRIMITIVES.contains(&base) {
                    continue;
                }
                let full = if base.contains('/') {
                    base.to_owned()
                } else {
                    format!("{package}/{base}")
                };
                assert!(
                    sections.iter().any(|(n, _)| *n == full),
                    "{}: {name} uses {full}, which has no MSG section",
                    d.name
                );
                used.push(full);
            }
        }
        for (name, _) in &sections {
            assert!(used.contains(name), "{}: {name} is not used", d.name);
        }
    }
    assert_eq!(
        TF_MESSAGE.complete(),
        format!(
            "geometry_msgs/TransformStamped[] transforms\n{SEPARATOR}\n\
             MSG: geometry_msgs/TransformStamped\n\
             std_msgs/Header header\nstring child_frame_id\nTransform transform\n{SEPARATOR}\n\
             MSG: std_msgs/Header\nbuiltin_interfaces/Time stamp\nstring frame_id\n{SEPARATOR}\n\
             MSG: builtin_interfaces/Time\nint32 sec\nuint32 nanosec\n{SEPARATOR}\n\
             MSG: geometry_msgs/Transform\nVector3 translation\nQuaternion rotation\n{SEPARATOR}\n\
             MSG: geometry_msgs/Vector3\nfloat64 x\nfloat64 y\nfloat64 z\n{SEPARATOR}\n\
             MSG: geometry_msgs/Quaternion\nfloat64 x 0\nfloat64 y 0\nfloat64 z 0\nfloat64 w 1"
        )
    );
    assert_eq!(SEPARATOR.len(), 80);
    assert!(SEPARATOR.bytes().all(|b| b == b'='));
}

/// A transform message laid out by hand: the count, the header's stamp
/// and frame, the child frame, padding to 8, seven float64.
#[test]
fn a_tf_message_has_the_hand_computed_layout() {
    let m = TfMessage {
        transforms: vec![TransformStamped {
            header: Header::new(3_000_000_004, "map"),
            child_frame_id: "odom".into(),
            translation: [1.0, 2.0, 3.0],
            rotation_xyzw: [0.0, 0.0, 0.0, 1.0],
        }],
    };
    let bytes = m.to_cdr().expect("encode");
    let f = |v: f64| v.to_le_bytes();
    #[rustfmt::skip]
    let expected: Vec<u8> = [
        &[0x00, 0x01, 0x00, 0x00][..],
        &[1, 0, 0, 0],                    // 0: one transform
        &[3, 0, 0, 0], &[4, 0, 0, 0],     // 4: sec, 8: nanosec
        &[4, 0, 0, 0], b"map\0",          // 12: "map" with its NUL
        &[5, 0, 0, 0], b"odom\0",         // 20: "odom"
        &[0, 0, 0],                       // 29: padding to 32
        &f(1.0), &f(2.0), &f(3.0),        // 32: translation
        &f(0.0), &f(0.0), &f(0.0), &f(1.0), // 56: rotation
    ]
    .concat();
    assert_eq!(bytes, expected);
    assert_eq!(bytes.len(), 4 + 88);
}

/// An image laid out by hand: padding after the frame id and after
/// `is_bigendian`, the data's count.
#[test]
fn an_image_has_the_hand_computed_layout() {
    let m = Image {
        header: Header::new(1_500_000_000, "cam0"),
        height: 2,
        width: 3,
        encoding: "mono8".into(),
        is_bigendian: 0,
        step: 3,
        data: vec![10, 20, 30, 40, 50, 60],
    };
    let bytes = m.to_cdr().expect("encode");
    #[rustfmt::skip]
    let expected: Vec<u8> = [
        &[0x00, 0x01, 0x00, 0x00][..],
        &[1, 0, 0, 0], &500_000_000u32.to_le_bytes(), // 0: stamp
        &[5, 0, 0, 0], b"cam0\0",                     // 8: frame_id
        &[0, 0, 0],                                   // 17: padding to 20
        &[2, 0, 0, 0], &[3, 0, 0, 0],                 // 20: height, 24: width
        &[6, 0, 0, 0], b"mono8\0",                    // 28: encoding
        &[0],                                         // 38: is_bigendian
        &[0],                                         // 39: padding to 40
        &[3, 0, 0, 0],                                // 40: step
        &[6, 0, 0, 0], &[10, 20, 30, 40, 50, 60],     // 44: data
    ]
    .concat();
    assert_eq!(bytes, expected);
    assert_eq!(Image::decode(&bytes), Ok(m));
}

#[test]
fn odometry_and_camera_info_have_the_hand_computed_lengths() {
    let odometry = Odometry {
        header: Header::new(0, "odom"),
        child_frame_id: "body".into(),
        position: [1.0; 3],
        orientation_xyzw: [0.5; 4],
        pose_covariance: [0.25; 36],
        linear_velocity: [2.0; 3],
        angular_velocity: [0.0; 3],
        twist_covariance: [0.0; 36],
    };
    let bytes = odometry.to_cdr().expect("encode");
    // Header ends at 17, child frame from 20 to 29, 85 float64 from 32.
    assert_eq!(bytes.len(), 4 + 32 + 85 * 8);
    assert_eq!(&bytes[4 + 20..4 + 29], b"\x05\0\0\0body\0");
    assert_eq!(&bytes[4 + 29..4 + 32], &[0, 0, 0]);
    assert_eq!(&bytes[4 + 32..4 + 40], &1.0f64.to_le_bytes());
    assert_eq!(
        &bytes[4 + 32 + 7 * 8..4 + 32 + 8 * 8],
        &0.25f64.to_le_bytes()
    );

    let info = CameraInfo {
        header: Header::new(0, "cam0"),
        height: 480,
        width: 752,
        distortion_model: "plumb_bob".into(),
        d: vec![0.1, 0.2, 0.3, 0.4, 0.5],
        k: [1.0; 9],
        r: [2.0; 9],
        p: [3.0; 12],
        binning_x: 0,
        binning_y: 0,
        roi: RegionOfInterest {
            do_rectify: true,
            ..Default::default()
        },
    };
    let bytes = info.to_cdr().expect("encode");
    // "plumb_bob" from 28 to 42, d's count at 44 (padded), d from 48,
    // k, r, p to 328, binning and roi to 352, do_rectify at 352.
    assert_eq!(&bytes[4 + 28..4 + 32], &10u32.to_le_bytes());
    assert_eq!(&bytes[4 + 42..4 + 44], &[0, 0]);
    assert_eq!(&bytes[4 + 44..4 + 48], &5u32.to_le_bytes());
    assert_eq!(&bytes[4 + 48..4 + 56], &0.1f64.to_le_bytes());
    assert_eq!(&bytes[4 + 232..4 + 240], &3.0f64.to_le_bytes());
    assert_eq!(bytes.len(), 4 + 353);
    assert_eq!(bytes[4 + 352], 1);
}

#[test]
fn imu_messages_decode_to_what_was_encoded() {
    let m = Imu {
        header: Header::new(1_403_636_579_763_555_584, "imu"),
        orientation_xyzw: [0.0, 0.0, 0.0, 1.0],
        orientation_covariance: [-1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
        angular_velocity: [1.0 / 3.0, -1e-300, f64::MAX],
        angular_velocity_covariance: [1e-6; 9],
        linear_acceleration: [9.81, -0.0, 0.1],
        linear_acceleration_covariance: [4e-2; 9],
    };
    let bytes = m.to_cdr().expect("encode");
    // Header "imu" ends at 16: the float64 follow without padding.
    assert_eq!(bytes.len(), 4 + 16 + (4 + 9 + 3 + 9 + 3 + 9) * 8);
    let back = Imu::decode(&bytes).expect("decode");
    assert_eq!(back, m);
    assert_eq!(back.header.stamp.ns(), 1_403_636_579_763_555_584);
    assert_eq!(back.linear_acceleration[1].to_bits(), (-0.0f64).to_bits());
    // Cut short: an error naming the field.
    let e = Imu::decode(&bytes[..bytes.len() - 1]).unwrap_err();
    assert!(e.contains("linear_acceleration_covariance"), "{e}");
}

#[test]
fn times_split_exactly_and_clamp_outside_int32_seconds() {
    for t in [
        0,
        1,
        999_999_999,
        -1,
        -1_000_000_001,
        1_403_636_579_763_555_584,
    ] {
        assert_eq!(Time::from_ns(t).ns(), t, "{t}");
    }
    assert_eq!(
        Time::from_ns(-1),
        Time {
            sec: -1,
            nanosec: 999_999_999
        }
    );
    assert_eq!(Time::from_ns(i64::MAX).sec, i32::MAX);
    assert_eq!(
        Time::from_ns(i64::MIN),
        Time {
            sec: i32::MIN,
            nanosec: 0
        }
    );
}

#[test]
fn the_schema_is_the_complete_definition_in_ros2msg() {
    let schema = <Odometry as Encode>::get_schema().expect("a schema");
    assert_eq!(schema.name, "nav_msgs/msg/Odometry");
    assert_eq!(schema.encoding, "ros2msg");
    assert_eq!(&schema.data[..], ODOMETRY.complete().as_bytes());
    assert_eq!(<Odometry as Encode>::get_message_encoding(), "cdr");
}
