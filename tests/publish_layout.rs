//! The C header `include/rigslam/pose_message.h` and the Rust messages
//! describe the same bytes: every size, alignment and offset the header
//! asserts is read out of the header and checked against the Rust types,
//! every Rust field must be asserted there, and a C program built against
//! the header reads bytes written by Rust.

use std::collections::BTreeMap;
use std::mem::{align_of, offset_of, size_of};
use std::path::Path;
use std::process::Command;

use rigslam::publish::{
    PoseMessage, QueueFill, StatusMessage, POSE_FLAG_COVARIANCE_VALID, POSE_FLAG_IMU_PROPAGATED,
    POSE_FLAG_MAP_CORRECTED, POSE_FLAG_VELOCITY_VALID, POSE_LAYOUT_VERSION, STATUS_LAYOUT_VERSION,
    TRACKING_STATE_LOST, TRACKING_STATE_TRACKING,
};

const HEADER: &str = concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/include/rigslam/pose_message.h"
);

/// What the header asserts: (C type, "sizeof" | "alignof" | field) -> number.
fn header_asserts() -> BTreeMap<(String, String), usize> {
    let text = std::fs::read_to_string(HEADER).expect("the header exists");
    let mut asserts = BTreeMap::new();
    for (index, line) in text.lines().enumerate() {
        let Some(body) = line.trim().strip_prefix("RIGSLAM_STATIC_ASSERT(") else {
            continue;
        };
        let line_no = index + 1;
        // The message is the last argument; offsetof has a comma of its own.
        let (expr, _) = body
            .rsplit_once(", \"")
            .unwrap_or_else(|| panic!("{HEADER}:{line_no}: no message in {line:?}"));
        let (lhs, rhs) = expr
            .split_once("==")
            .unwrap_or_else(|| panic!("{HEADER}:{line_no}: no == in {line:?}"));
        let value: usize = rhs
            .trim()
            .parse()
            .unwrap_or_else(|e| panic!("{HEADER}:{line_no}: {rhs:?}: {e}"));
        let lhs = lhs.trim();
        let inner = |prefix: &str| {
            lhs.strip_prefix(prefix)
                .and_then(|r| r.strip_suffix(')'))
                .map(str::trim)
        };
        let key = if let Some(ty) = inner("sizeof(") {
            (ty.to_string(), "sizeof".to_string())
        } else if let Some(ty) = inner("RIGSLAM_ALIGNOF(") {
            (ty.to_string(), "alignof".to_string())
        } else if let Some(args) = inner("offsetof(") {
            let (ty, field) = args
                .split_once(',')
                .unwrap_or_else(|| panic!("{HEADER}:{line_no}: offsetof needs two arguments"));
            (ty.trim().to_string(), field.trim().to_string())
        } else {
            panic!("{HEADER}:{line_no}: unknown assert {lhs:?}");
        };
        assert!(
            asserts.insert(key.clone(), value).is_none(),
            "{HEADER}:{line_no}: {key:?} asserted twice"
        );
    }
    asserts
}

/// (field, offset, field size).
type Field = (&'static str, usize, usize);

/// Rust's layout, per C type name: size, alignment and every field.
fn rust_layout() -> Vec<(&'static str, usize, usize, Vec<Field>)> {
    macro_rules! fields {
        ($ty:ty, $($field:ident),* $(,)?) => {{
            let value: $ty = unsafe { std::mem::zeroed() };
            vec![$((stringify!($field), offset_of!($ty, $field), std::mem::size_of_val(&value.$field))),*]
        }};
    }
    vec![
        (
            "rigslam_pose_message_t",
            size_of::<PoseMessage>(),
            align_of::<PoseMessage>(),
            fields!(
                PoseMessage,
                layout_version,
                tracking_state,
                flags,
                reserved,
                t_ns,
                published_t_ns,
                sequence,
                position_world_m,
                orientation_world_body_xyzw,
                velocity_world_m_s,
                covariance,
                position_odom_m,
                orientation_odom_body_xyzw,
                translation_world_odom_m,
                rotation_world_odom_xyzw,
            ),
        ),
        (
            "rigslam_queue_fill_t",
            size_of::<QueueFill>(),
            align_of::<QueueFill>(),
            fields!(QueueFill, name, len, capacity),
        ),
        (
            "rigslam_status_message_t",
            size_of::<StatusMessage>(),
            align_of::<StatusMessage>(),
            fields!(
                StatusMessage,
                layout_version,
                sensor_health,
                queue_count,
                reserved,
                t_ns,
                published_t_ns,
                sequence,
                camera_rate_hz,
                imu_rate_hz,
                pose_rate_hz,
                camera_drops,
                imu_drops,
                pose_drops,
                latency_p50_us,
                latency_p99_us,
                queues,
                imu_noise_scale_gyro,
                imu_noise_scale_accel,
                pixel_noise_scale,
                camera_imu_rotation_deg,
                camera_imu_translation_m,
                camera_imu_time_offset_s,
            ),
        ),
    ]
}

#[test]
fn header_and_rust_types_agree_on_every_size_and_offset() {
    let mut asserts = header_asserts();
    for (c_type, size, align, fields) in rust_layout() {
        let mut take = |what: &str| {
            asserts
                .remove(&(c_type.to_string(), what.to_string()))
                .unwrap_or_else(|| panic!("the header does not assert {what} of {c_type}"))
        };
        assert_eq!(take("sizeof"), size, "sizeof({c_type})");
        assert_eq!(take("alignof"), align, "alignof({c_type})");
        for &(field, offset, _) in &fields {
            assert_eq!(take(field), offset, "offsetof({c_type}, {field})");
        }
        // No padding and no field missing from the list above: the fields
        // tile the struct exactly.
        let mut end = 0;
        for &(field, offset, field_size) in &fields {
            assert_eq!(
                offset, end,
                "{c_type}.{field} does not follow its predecessor"
            );
            end = offset + field_size;
        }
        assert_eq!(end, size, "{c_type} has padding or an unlisted field");
    }
    assert!(
        asserts.is_empty(),
        "the header asserts what Rust does not have: {asserts:?}"
    );
}

#[test]
fn header_constants_match_rust() {
    let text = std::fs::read_to_string(HEADER).expect("the header exists");
    let define = |name: &str| -> String {
        text.lines()
            .find_map(|l| l.strip_prefix(&format!("#define {name} ")))
            .unwrap_or_else(|| panic!("{name} is not defined in the header"))
            .split("/*")
            .next()
            .expect("split yields one part")
            .trim()
            .to_string()
    };
    assert_eq!(
        define("RIGSLAM_POSE_LAYOUT_VERSION"),
        format!("{POSE_LAYOUT_VERSION}u")
    );
    assert_eq!(
        define("RIGSLAM_STATUS_LAYOUT_VERSION"),
        format!("{STATUS_LAYOUT_VERSION}u")
    );
    for (name, bit) in [
        (
            "RIGSLAM_POSE_FLAG_COVARIANCE_VALID",
            POSE_FLAG_COVARIANCE_VALID,
        ),
        ("RIGSLAM_POSE_FLAG_VELOCITY_VALID", POSE_FLAG_VELOCITY_VALID),
        ("RIGSLAM_POSE_FLAG_IMU_PROPAGATED", POSE_FLAG_IMU_PROPAGATED),
        ("RIGSLAM_POSE_FLAG_MAP_CORRECTED", POSE_FLAG_MAP_CORRECTED),
    ] {
        assert_eq!(
            define(name),
            format!("(1u << {})", bit.trailing_zeros()),
            "{name}"
        );
    }
    assert_eq!(
        define("RIGSLAM_TRACKING_STATE_TRACKING"),
        format!("{TRACKING_STATE_TRACKING}u")
    );
    assert_eq!(
        define("RIGSLAM_TRACKING_STATE_LOST"),
        format!("{TRACKING_STATE_LOST}u")
    );
    assert_eq!(
        define("RIGSLAM_POSE_TYPE_NAME"),
        format!("{:?}", unsafe {
            <PoseMessage as iceoryx2::prelude::ZeroCopySend>::type_name()
        })
    );
    assert_eq!(
        define("RIGSLAM_STATUS_TYPE_NAME"),
        format!("{:?}", unsafe {
            <StatusMessage as iceoryx2::prelude::ZeroCopySend>::type_name()
        })
    );
}

/// Values chosen so that C's `%.9g` and Rust's `{}` print them alike.
fn pose(i: u32) -> PoseMessage {
    let f = f64::from(i);
    let mut covariance = [0.0; 36];
    covariance[0] = 0.25 * f;
    covariance[6 * 3 + 3] = 0.0625;
    covariance[6 * 2 + 4] = -0.5 - f;
    PoseMessage {
        layout_version: POSE_LAYOUT_VERSION,
        tracking_state: if i == 1 {
            TRACKING_STATE_LOST
        } else {
            TRACKING_STATE_TRACKING
        },
        flags: match i {
            2 => POSE_FLAG_IMU_PROPAGATED,
            3 => POSE_FLAG_COVARIANCE_VALID | POSE_FLAG_MAP_CORRECTED,
            _ => POSE_FLAG_COVARIANCE_VALID,
        },
        reserved: 0,
        t_ns: 1_700_000_000_123_456_789 + i64::from(i),
        published_t_ns: 5,
        sequence: 40 + u64::from(i),
        position_world_m: [1.5 + f, -2.25, 1000.0 * f],
        orientation_world_body_xyzw: [0.5, -0.5, 0.5, 0.5],
        velocity_world_m_s: [0.125, -f, 7.75],
        covariance,
        position_odom_m: [1.0 + f, -2.0, 999.5 * f],
        orientation_odom_body_xyzw: [0.5, -0.5, 0.5, 0.5],
        translation_world_odom_m: [0.5, -0.25, 0.5 * f],
        rotation_world_odom_xyzw: [0.0, 0.0, 0.0, 1.0],
    }
}

fn expected_line(m: &PoseMessage) -> String {
    let state = if m.tracking_state == TRACKING_STATE_LOST {
        "lost"
    } else {
        "tracking"
    };
    let [px, py, pz] = m.position_world_m;
    let [qx, qy, qz, qw] = m.orientation_world_body_xyzw;
    let [vx, vy, vz] = m.velocity_world_m_s;
    let mut line = format!(
        "seq={} t_ns={} state={state} p={px},{py},{pz} q_xyzw={qx},{qy},{qz},{qw} v={vx},{vy},{vz}",
        m.sequence, m.t_ns
    );
    if m.flags & POSE_FLAG_COVARIANCE_VALID != 0 {
        line += &format!(
            " var_x={} var_rx={} cov_z_ry={}",
            m.covariance[0], m.covariance[21], m.covariance[16]
        );
    } else {
        line += " cov=unknown";
    }
    if m.flags & POSE_FLAG_MAP_CORRECTED != 0 {
        let [ox, oy, oz] = m.position_odom_m;
        let [tx, ty, tz] = m.translation_world_odom_m;
        line += &format!(" odom_p={ox},{oy},{oz} world_odom_t={tx},{ty},{tz}");
    }
    if m.flags & POSE_FLAG_IMU_PROPAGATED != 0 {
        line += " imu_propagated";
    }
    line
}

#[test]
fn the_c_example_reads_what_rust_writes() {
    if Command::new("gcc").arg("--version").output().is_err() {
        assert!(std::env::var_os("CI").is_none(), "gcc is missing on CI");
        eprintln!("skipped: no gcc");
        return;
    }
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let dir = tempfile::tempdir().expect("temp dir");
    let exe = dir.path().join("echo_pose");
    let build = Command::new("gcc")
        .args(["-std=c11", "-Wall", "-Wextra", "-Werror", "-I"])
        .arg(root.join("include"))
        .arg(root.join("examples/c/echo_pose.c"))
        .arg("-o")
        .arg(&exe)
        .output()
        .expect("run gcc");
    assert!(
        build.status.success(),
        "gcc failed:\n{}",
        String::from_utf8_lossy(&build.stderr)
    );
    let messages: Vec<PoseMessage> = (0..4).map(pose).collect();
    let records = dir.path().join("poses.bin");
    let bytes: Vec<u8> = messages
        .iter()
        .flat_map(|m| m.as_bytes().to_vec())
        .collect();
    std::fs::write(&records, &bytes).expect("write records");
    let run = Command::new(&exe)
        .arg(&records)
        .output()
        .expect("run echo_pose");
    assert!(
        run.status.success(),
        "echo_pose failed: {}",
        String::from_utf8_lossy(&run.stderr)
    );
    let stdout = String::from_utf8(run.stdout).expect("UTF-8");
    let expected: Vec<String> = messages.iter().map(expected_line).collect();
    assert_eq!(stdout.lines().collect::<Vec<_>>(), expected);

    // A record of another layout version is refused, not misread.
    let mut other = pose(0);
    other.layout_version = POSE_LAYOUT_VERSION + 1;
    std::fs::write(&records, other.as_bytes()).expect("write record");
    let run = Command::new(&exe)
        .arg(&records)
        .output()
        .expect("run echo_pose");
    assert!(!run.status.success());
    assert!(String::from_utf8_lossy(&run.stderr).contains("layout version"));
}
