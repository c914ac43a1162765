//! The recordings' own message types (`rigslam.ImuSample`,
//! `rigslam.PoseEstimate`, `rigslam.Status`), encoded in protobuf like
//! Foxglove's schemas, and their schema: a `FileDescriptorSet` written out
//! field by field here, so that any protobuf reader (Foxglove, the MCAP
//! tools, Python's `mcap-protobuf-support`) decodes them without our code.
//!
//! Field numbers are part of the file format: a field is never renumbered
//! or reused; a new one takes the next free number.

use std::borrow::Cow;

use foxglove::{Encode, Schema};
use prost::Message as _;
use prost_types::field_descriptor_proto::{Label, Type};
use prost_types::{DescriptorProto, FieldDescriptorProto, FileDescriptorProto, FileDescriptorSet};

/// Schema name of IMU messages.
pub const IMU_SCHEMA_NAME: &str = "rigslam.ImuSample";
/// Schema name of pose estimates.
pub const POSE_SCHEMA_NAME: &str = "rigslam.PoseEstimate";
/// Schema name of status messages.
pub const STATUS_SCHEMA_NAME: &str = "rigslam.Status";

/// One IMU sample as the driver gave it (raw: the rig's IMU intrinsics are
/// applied in the pipeline, not here).
#[derive(Clone, PartialEq, prost::Message)]
pub struct ImuSampleProto {
    /// Sample stamp on the sensor's clock as the daemon maps it, ns.
    #[prost(int64, tag = "1")]
    pub t_ns: i64,
    /// Angular rate x, y, z, rad/s.
    #[prost(double, repeated, tag = "2")]
    pub gyro_rad_s: Vec<f64>,
    /// Specific force x, y, z, m/s^2.
    #[prost(double, repeated, tag = "3")]
    pub accel_m_s2: Vec<f64>,
}

/// One published pose with everything `rigslam/pose` carries: the
/// map-frame ("world") pose with its covariance, the odometry-frame pose
/// and the map -> odometry transform.
#[derive(Clone, PartialEq, prost::Message)]
pub struct PoseEstimateProto {
    /// Stamp of the frame the pose is for, ns (the clock the frames are stamped in).
    #[prost(int64, tag = "1")]
    pub t_ns: i64,
    /// The wire code of the tracking state (`TRACKING_STATE_*`).
    #[prost(uint32, tag = "2")]
    pub tracking_state: u32,
    /// `POSE_FLAG_*` bits.
    #[prost(uint32, tag = "3")]
    pub flags: u32,
    /// Body position in the map frame, m.
    #[prost(double, repeated, tag = "4")]
    pub position_world_m: Vec<f64>,
    /// `R_world_body` as x, y, z, w.
    #[prost(double, repeated, tag = "5")]
    pub orientation_world_body_xyzw: Vec<f64>,
    /// Body velocity in the map frame, m/s.
    #[prost(double, repeated, tag = "6")]
    pub velocity_world_m_s: Vec<f64>,
    /// 6x6 covariance of (position, rotation vector), row-major; empty
    /// when the pose has none.
    #[prost(double, repeated, tag = "7")]
    pub covariance: Vec<f64>,
    /// Body position in the odometry frame, m.
    #[prost(double, repeated, tag = "8")]
    pub position_odom_m: Vec<f64>,
    /// `R_odom_body` as x, y, z, w.
    #[prost(double, repeated, tag = "9")]
    pub orientation_odom_body_xyzw: Vec<f64>,
    /// Translation of `T_world_odom`, m.
    #[prost(double, repeated, tag = "10")]
    pub translation_world_odom_m: Vec<f64>,
    /// Rotation of `T_world_odom` as x, y, z, w.
    #[prost(double, repeated, tag = "11")]
    pub rotation_world_odom_xyzw: Vec<f64>,
}

/// The daemon's status at one instant (what `rigslam/status` publishes).
#[derive(Clone, PartialEq, prost::Message)]
pub struct StatusProto {
    /// Host time of the status, ns (`CLOCK_MONOTONIC`).
    #[prost(int64, tag = "1")]
    pub t_ns: i64,
    /// `HEALTH_*` bits.
    #[prost(uint32, tag = "2")]
    pub sensor_health: u32,
    /// The health bits in words.
    #[prost(string, tag = "3")]
    pub health: String,
    /// Camera frame rate over the last period, Hz.
    #[prost(double, tag = "4")]
    pub camera_rate_hz: f64,
    /// IMU sample rate, Hz.
    #[prost(double, tag = "5")]
    pub imu_rate_hz: f64,
    /// Pose rate, Hz.
    #[prost(double, tag = "6")]
    pub pose_rate_hz: f64,
    /// Frames lost since start.
    #[prost(uint64, tag = "7")]
    pub camera_drops: u64,
    /// IMU samples lost since start.
    #[prost(uint64, tag = "8")]
    pub imu_drops: u64,
    /// Poses not published since start.
    #[prost(uint64, tag = "9")]
    pub pose_drops: u64,
    /// Frame to pose latency, median, us.
    #[prost(double, tag = "10")]
    pub latency_p50_us: f64,
    /// Frame to pose latency, 99th percentile, us.
    #[prost(double, tag = "11")]
    pub latency_p99_us: f64,
}

/// A field of a message descriptor.
fn field(name: &str, number: i32, kind: Type, repeated: bool) -> FieldDescriptorProto {
    FieldDescriptorProto {
        name: Some(name.to_owned()),
        number: Some(number),
        label: Some(if repeated {
            Label::Repeated
        } else {
            Label::Optional
        } as i32),
        r#type: Some(kind as i32),
        json_name: Some(name.to_owned()),
        ..Default::default()
    }
}

fn message(name: &str, fields: Vec<FieldDescriptorProto>) -> DescriptorProto {
    DescriptorProto {
        name: Some(name.to_owned()),
        field: fields,
        ..Default::default()
    }
}

/// The descriptor of the three messages above, as one proto3 file.
fn file_descriptor_set() -> FileDescriptorSet {
    use Type::{Double, Int64, String as Str, Uint32, Uint64};
    let imu = message(
        "ImuSample",
        vec![
            field("t_ns", 1, Int64, false),
            field("gyro_rad_s", 2, Double, true),
            field("accel_m_s2", 3, Double, true),
        ],
    );
    let pose = message(
        "PoseEstimate",
        vec![
            field("t_ns", 1, Int64, false),
            field("tracking_state", 2, Uint32, false),
            field("flags", 3, Uint32, false),
            field("position_world_m", 4, Double, true),
            field("orientation_world_body_xyzw", 5, Double, true),
            field("velocity_world_m_s", 6, Double, true),
            field("covariance", 7, Double, true),
            field("position_odom_m", 8, Double, true),
            field("orientation_odom_body_xyzw", 9, Double, true),
            field("translation_world_odom_m", 10, Double, true),
            field("rotation_world_odom_xyzw", 11, Double, true),
        ],
    );
    let status = message(
        "Status",
        vec![
            field("t_ns", 1, Int64, false),
            field("sensor_health", 2, Uint32, false),
            field("health", 3, Str, false),
            field("camera_rate_hz", 4, Double, false),
            field("imu_rate_hz", 5, Double, false),
            field("pose_rate_hz", 6, Double, false),
            field("camera_drops", 7, Uint64, false),
            field("imu_drops", 8, Uint64, false),
            field("pose_drops", 9, Uint64, false),
            field("latency_p50_us", 10, Double, false),
            field("latency_p99_us", 11, Double, false),
        ],
    );
    FileDescriptorSet {
        file: vec![FileDescriptorProto {
            name: Some("rigslam/recording.proto".to_owned()),
            package: Some("rigslam".to_owned()),
            message_type: vec![imu, pose, status],
            syntax: Some("proto3".to_owned()),
            ..Default::default()
        }],
    }
}

/// The encoded descriptor set, built once.
static DESCRIPTOR: std::sync::LazyLock<Vec<u8>> =
    std::sync::LazyLock::new(|| file_descriptor_set().encode_to_vec());

macro_rules! rigslam_message {
    ($ty:ty, $name:expr) => {
        impl Encode for $ty {
            type Error = prost::EncodeError;

            fn get_schema() -> Option<Schema> {
                Some(Schema::new(
                    $name,
                    "protobuf",
                    Cow::<'static, [u8]>::Owned(DESCRIPTOR.clone()),
                ))
            }

            fn get_message_encoding() -> String {
                "protobuf".to_owned()
            }

            fn encode(
                &self,
                buf: &mut impl foxglove::bytes::BufMut,
            ) -> Result<(), prost::EncodeError> {
                prost::Message::encode(self, buf)
            }

            fn encoded_len(&self) -> Option<usize> {
                Some(prost::Message::encoded_len(self))
            }
        }
    };
}

rigslam_message!(ImuSampleProto, IMU_SCHEMA_NAME);
rigslam_message!(PoseEstimateProto, POSE_SCHEMA_NAME);
rigslam_message!(StatusProto, STATUS_SCHEMA_NAME);

/// A Foxglove timestamp for a stamp in ns; stamps before 1970 (or after
/// 2106) are clamped, as the schema's seconds are unsigned 32-bit.
pub fn timestamp(t_ns: i64) -> foxglove::messages::Timestamp {
    let sec = t_ns.div_euclid(1_000_000_000).clamp(0, i64::from(u32::MAX)) as u32;
    let nsec = if t_ns < 0 {
        0
    } else {
        t_ns.rem_euclid(1_000_000_000) as u32
    };
    foxglove::messages::Timestamp::new(sec, nsec)
}

/// The stamp of a Foxglove timestamp, ns.
pub fn timestamp_ns(t: &foxglove::messages::Timestamp) -> i64 {
    i64::from(t.sec()) * 1_000_000_000 + i64::from(t.nsec())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every field of each derived message has a descriptor field with its
    /// number, type and label: encoding a message whose fields are all set
    /// and walking the bytes with the descriptor finds each one.
    #[test]
    fn the_descriptor_describes_what_prost_encodes() {
        let set = file_descriptor_set();
        let file = &set.file[0];
        let find = |name: &str| {
            file.message_type
                .iter()
                .find(|m| m.name() == name)
                .unwrap_or_else(|| panic!("{name} not in the descriptor"))
        };
        let pose = PoseEstimateProto {
            t_ns: -5,
            tracking_state: 2,
            flags: 9,
            position_world_m: vec![1.0, 2.0, 3.0],
            orientation_world_body_xyzw: vec![0.0, 0.0, 0.0, 1.0],
            velocity_world_m_s: vec![0.5; 3],
            covariance: vec![0.25; 36],
            position_odom_m: vec![4.0; 3],
            orientation_odom_body_xyzw: vec![0.5; 4],
            translation_world_odom_m: vec![6.0; 3],
            rotation_world_odom_xyzw: vec![0.0, 1.0, 0.0, 0.0],
        };
        let status = StatusProto {
            t_ns: 1,
            sensor_health: 3,
            health: "ok".into(),
            camera_rate_hz: 20.0,
            imu_rate_hz: 200.0,
            pose_rate_hz: 20.0,
            camera_drops: 1,
            imu_drops: 2,
            pose_drops: 3,
            latency_p50_us: 4.0,
            latency_p99_us: 5.0,
        };
        let imu = ImuSampleProto {
            t_ns: 7,
            gyro_rad_s: vec![0.1; 3],
            accel_m_s2: vec![9.8; 3],
        };
        for (name, bytes) in [
            ("PoseEstimate", pose.encode_to_vec()),
            ("Status", status.encode_to_vec()),
            ("ImuSample", imu.encode_to_vec()),
        ] {
            let descriptor = find(name);
            let seen = wire_fields(&bytes);
            let mut expected: Vec<(i32, u8)> = descriptor
                .field
                .iter()
                .map(|f| {
                    let wire = match (f.label(), f.r#type()) {
                        // proto3 packs repeated scalars: length-delimited.
                        (Label::Repeated, _) | (_, Type::String) => 2,
                        (_, Type::Double) => 1,
                        _ => 0,
                    };
                    (f.number(), wire)
                })
                .collect();
            expected.sort_unstable();
            assert_eq!(seen, expected, "{name}");
        }
    }

    /// (field number, wire type) of each top-level field, sorted.
    fn wire_fields(mut bytes: &[u8]) -> Vec<(i32, u8)> {
        let mut out = Vec::new();
        while !bytes.is_empty() {
            let key = prost::encoding::decode_varint(&mut bytes).expect("key");
            let wire = (key & 7) as u8;
            match wire {
                0 => {
                    prost::encoding::decode_varint(&mut bytes).expect("varint");
                }
                1 => bytes = &bytes[8..],
                2 => {
                    let len = prost::encoding::decode_varint(&mut bytes).expect("len");
                    bytes = &bytes[len as usize..];
                }
                other => panic!("wire type {other}"),
            }
            out.push(((key >> 3) as i32, wire));
        }
        out.sort_unstable();
        out
    }

    #[test]
    fn timestamps_round_trip_and_clamp() {
        for t in [0, 1, 999_999_999, 1_403_636_579_763_555_584] {
            assert_eq!(timestamp_ns(&timestamp(t)), t);
        }
        assert_eq!(timestamp_ns(&timestamp(-3)), 0);
    }
}
