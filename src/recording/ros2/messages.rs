//! The ROS 2 messages a ROS 2 recording holds, their CDR encoding and
//! their `ros2msg` definitions.
//!
//! Each message's schema is its complete definition as rosbag2 stores
//! it: the message's own `.msg` text first, then every message type it
//! uses, directly or not, once each, each after a line of 80 `=` and a
//! `MSG: pkg/Type` line. The field lists are those of ROS 2 (Humble to
//! Rolling; comments left out). [`Image`] and [`Imu`] also decode, for
//! the replay.

use std::borrow::Cow;

use foxglove::{Encode, Schema};

use super::cdr::{CdrError, CdrReader, CdrWriter};

/// One message type's definition and the types it uses.
#[derive(Debug)]
pub struct Definition {
    /// The type's name, `pkg/msg/Type`.
    pub name: &'static str,
    /// Its `.msg` text: one field (or constant) per line.
    pub text: &'static str,
    /// The message types its fields have.
    pub uses: &'static [&'static Definition],
}

/// The line rosbag2 puts before each dependency's definition.
pub const SEPARATOR: &str =
    "================================================================================";

impl Definition {
    /// `pkg/Type`, the name a `MSG:` line gives.
    pub fn short_name(&self) -> String {
        match self.name.split('/').collect::<Vec<_>>()[..] {
            [pkg, "msg", ty] => format!("{pkg}/{ty}"),
            _ => self.name.to_owned(),
        }
    }

    /// The complete definition: this type's text, then each type it
    /// uses (depth first, each once) after its separator and `MSG:` line.
    pub fn complete(&self) -> String {
        let mut order: Vec<&Definition> = Vec::new();
        fn visit<'d>(d: &'d Definition, order: &mut Vec<&'d Definition>) {
            for &used in d.uses {
                if !order.iter().any(|o| std::ptr::eq(*o, used)) {
                    order.push(used);
                    visit(used, order);
                }
            }
        }
        visit(self, &mut order);
        let mut out = self.text.to_owned();
        for d in order {
            out.push('\n');
            out.push_str(SEPARATOR);
            out.push_str("\nMSG: ");
            out.push_str(&d.short_name());
            out.push('\n');
            out.push_str(d.text);
        }
        out
    }
}

/// `builtin_interfaces/msg/Time`.
pub static TIME: Definition = Definition {
    name: "builtin_interfaces/msg/Time",
    text: "int32 sec\nuint32 nanosec",
    uses: &[],
};
/// `std_msgs/msg/Header`.
pub static HEADER: Definition = Definition {
    name: "std_msgs/msg/Header",
    text: "builtin_interfaces/Time stamp\nstring frame_id",
    uses: &[&TIME],
};
/// `geometry_msgs/msg/Vector3`.
pub static VECTOR3: Definition = Definition {
    name: "geometry_msgs/msg/Vector3",
    text: "float64 x\nfloat64 y\nfloat64 z",
    uses: &[],
};
/// `geometry_msgs/msg/Point`.
pub static POINT: Definition = Definition {
    name: "geometry_msgs/msg/Point",
    text: "float64 x\nfloat64 y\nfloat64 z",
    uses: &[],
};
/// `geometry_msgs/msg/Quaternion`.
pub static QUATERNION: Definition = Definition {
    name: "geometry_msgs/msg/Quaternion",
    text: "float64 x 0\nfloat64 y 0\nfloat64 z 0\nfloat64 w 1",
    uses: &[],
};
/// `geometry_msgs/msg/Pose`.
pub static POSE: Definition = Definition {
    name: "geometry_msgs/msg/Pose",
    text: "Point position\nQuaternion orientation",
    uses: &[&POINT, &QUATERNION],
};
/// `geometry_msgs/msg/PoseWithCovariance`.
pub static POSE_WITH_COVARIANCE: Definition = Definition {
    name: "geometry_msgs/msg/PoseWithCovariance",
    text: "Pose pose\nfloat64[36] covariance",
    uses: &[&POSE],
};
/// `geometry_msgs/msg/Twist`.
pub static TWIST: Definition = Definition {
    name: "geometry_msgs/msg/Twist",
    text: "Vector3 linear\nVector3 angular",
    uses: &[&VECTOR3],
};
/// `geometry_msgs/msg/TwistWithCovariance`.
pub static TWIST_WITH_COVARIANCE: Definition = Definition {
    name: "geometry_msgs/msg/TwistWithCovariance",
    text: "Twist twist\nfloat64[36] covariance",
    uses: &[&TWIST],
};
/// `geometry_msgs/msg/Transform`.
pub static TRANSFORM: Definition = Definition {
    name: "geometry_msgs/msg/Transform",
    text: "Vector3 translation\nQuaternion rotation",
    uses: &[&VECTOR3, &QUATERNION],
};
/// `geometry_msgs/msg/TransformStamped`.
pub static TRANSFORM_STAMPED: Definition = Definition {
    name: "geometry_msgs/msg/TransformStamped",
    text: "std_msgs/Header header\nstring child_frame_id\nTransform transform",
    uses: &[&HEADER, &TRANSFORM],
};
/// `sensor_msgs/msg/RegionOfInterest`.
pub static REGION_OF_INTEREST: Definition = Definition {
    name: "sensor_msgs/msg/RegionOfInterest",
    text: "uint32 x_offset\nuint32 y_offset\nuint32 height\nuint32 width\nbool do_rectify",
    uses: &[],
};
/// `sensor_msgs/msg/Image`.
pub static IMAGE: Definition = Definition {
    name: "sensor_msgs/msg/Image",
    text: "std_msgs/Header header\nuint32 height\nuint32 width\nstring encoding\n\
           uint8 is_bigendian\nuint32 step\nuint8[] data",
    uses: &[&HEADER],
};
/// `sensor_msgs/msg/Imu`.
pub static IMU: Definition = Definition {
    name: "sensor_msgs/msg/Imu",
    text: "std_msgs/Header header\n\
           geometry_msgs/Quaternion orientation\nfloat64[9] orientation_covariance\n\
           geometry_msgs/Vector3 angular_velocity\nfloat64[9] angular_velocity_covariance\n\
           geometry_msgs/Vector3 linear_acceleration\nfloat64[9] linear_acceleration_covariance",
    uses: &[&HEADER, &QUATERNION, &VECTOR3],
};
/// `sensor_msgs/msg/CameraInfo`.
pub static CAMERA_INFO: Definition = Definition {
    name: "sensor_msgs/msg/CameraInfo",
    text: "std_msgs/Header header\nuint32 height\nuint32 width\nstring distortion_model\n\
           float64[] d\nfloat64[9] k\nfloat64[9] r\nfloat64[12] p\n\
           uint32 binning_x\nuint32 binning_y\nRegionOfInterest roi",
    uses: &[&HEADER, &REGION_OF_INTEREST],
};
/// `nav_msgs/msg/Odometry`.
pub static ODOMETRY: Definition = Definition {
    name: "nav_msgs/msg/Odometry",
    text: "std_msgs/Header header\nstring child_frame_id\n\
           geometry_msgs/PoseWithCovariance pose\ngeometry_msgs/TwistWithCovariance twist",
    uses: &[&HEADER, &POSE_WITH_COVARIANCE, &TWIST_WITH_COVARIANCE],
};
/// `tf2_msgs/msg/TFMessage`.
pub static TF_MESSAGE: Definition = Definition {
    name: "tf2_msgs/msg/TFMessage",
    text: "geometry_msgs/TransformStamped[] transforms",
    uses: &[&TRANSFORM_STAMPED],
};

/// A message that writes itself as CDR.
pub trait Ros2Message {
    /// Its type's definition.
    fn definition() -> &'static Definition;

    /// Its fields, in order, after the header `w` already holds.
    fn write(&self, w: &mut CdrWriter) -> Result<(), CdrError>;

    /// The whole message: encapsulation header and fields.
    fn to_cdr(&self) -> Result<Vec<u8>, CdrError> {
        let mut w = CdrWriter::new();
        self.write(&mut w)?;
        Ok(w.into_bytes())
    }
}

/// `builtin_interfaces/Time`: seconds and nanoseconds (0 to 999999999)
/// since the clock's zero.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Time {
    /// Whole seconds (negative before the clock's zero).
    pub sec: i32,
    /// Nanoseconds to add, 0 to 999 999 999.
    pub nanosec: u32,
}

impl Time {
    /// A stamp in ns: exact from -2^31 s to 2^31 s (1901 to 2038 on the
    /// epoch), clamped to those ends outside.
    pub fn from_ns(t_ns: i64) -> Self {
        let sec = t_ns.div_euclid(1_000_000_000);
        if sec < i64::from(i32::MIN) {
            return Self {
                sec: i32::MIN,
                nanosec: 0,
            };
        }
        if sec > i64::from(i32::MAX) {
            return Self {
                sec: i32::MAX,
                nanosec: 999_999_999,
            };
        }
        Self {
            sec: sec as i32,
            nanosec: t_ns.rem_euclid(1_000_000_000) as u32,
        }
    }

    /// The stamp in ns.
    pub fn ns(&self) -> i64 {
        i64::from(self.sec) * 1_000_000_000 + i64::from(self.nanosec)
    }

    fn write(&self, w: &mut CdrWriter) {
        w.i32(self.sec);
        w.u32(self.nanosec);
    }

    fn read(r: &mut CdrReader<'_>) -> Result<Self, String> {
        Ok(Self {
            sec: r.i32("header.stamp.sec")?,
            nanosec: r.u32("header.stamp.nanosec")?,
        })
    }
}

/// `std_msgs/Header`: when and in which frame.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Header {
    /// When the data was taken.
    pub stamp: Time,
    /// The frame the data is in.
    pub frame_id: String,
}

impl Header {
    /// A header stamped `t_ns` in `frame_id`.
    pub fn new(t_ns: i64, frame_id: &str) -> Self {
        Self {
            stamp: Time::from_ns(t_ns),
            frame_id: frame_id.to_owned(),
        }
    }

    fn write(&self, w: &mut CdrWriter) -> Result<(), CdrError> {
        self.stamp.write(w);
        w.string(&self.frame_id)
    }

    fn read(r: &mut CdrReader<'_>) -> Result<Self, String> {
        Ok(Self {
            stamp: Time::read(r)?,
            frame_id: r.string("header.frame_id")?,
        })
    }
}

/// `sensor_msgs/Image`.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Image {
    /// Exposure stamp and camera frame.
    pub header: Header,
    /// Rows.
    pub height: u32,
    /// Columns.
    pub width: u32,
    /// Pixel encoding (`mono8`).
    pub encoding: String,
    /// 1 when multi-byte pixels are big-endian.
    pub is_bigendian: u8,
    /// Bytes per row.
    pub step: u32,
    /// `step * height` bytes.
    pub data: Vec<u8>,
}

impl Ros2Message for Image {
    fn definition() -> &'static Definition {
        &IMAGE
    }

    fn write(&self, w: &mut CdrWriter) -> Result<(), CdrError> {
        self.header.write(w)?;
        w.u32(self.height);
        w.u32(self.width);
        w.string(&self.encoding)?;
        w.u8(self.is_bigendian);
        w.u32(self.step);
        w.u8_sequence(&self.data)
    }
}

impl Image {
    /// An image from its CDR bytes.
    pub fn decode(bytes: &[u8]) -> Result<Self, String> {
        let mut r = CdrReader::new(bytes)?;
        Ok(Self {
            header: Header::read(&mut r)?,
            height: r.u32("height")?,
            width: r.u32("width")?,
            encoding: r.string("encoding")?,
            is_bigendian: r.u8("is_bigendian")?,
            step: r.u32("step")?,
            data: r.u8_sequence("data")?.to_vec(),
        })
    }
}

/// `sensor_msgs/Imu`. Covariances are row-major 3x3 about x, y, z; a
/// first element of -1 says the quantity is not measured.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Imu {
    /// Sample stamp and IMU frame.
    pub header: Header,
    /// Orientation x, y, z, w.
    pub orientation_xyzw: [f64; 4],
    /// Its covariance.
    pub orientation_covariance: [f64; 9],
    /// Angular rate, rad/s.
    pub angular_velocity: [f64; 3],
    /// Its covariance, rad^2/s^2.
    pub angular_velocity_covariance: [f64; 9],
    /// Specific force, m/s^2.
    pub linear_acceleration: [f64; 3],
    /// Its covariance, m^2/s^4.
    pub linear_acceleration_covariance: [f64; 9],
}

impl Ros2Message for Imu {
    fn definition() -> &'static Definition {
        &IMU
    }

    fn write(&self, w: &mut CdrWriter) -> Result<(), CdrError> {
        self.header.write(w)?;
        w.f64_array(&self.orientation_xyzw);
        w.f64_array(&self.orientation_covariance);
        w.f64_array(&self.angular_velocity);
        w.f64_array(&self.angular_velocity_covariance);
        w.f64_array(&self.linear_acceleration);
        w.f64_array(&self.linear_acceleration_covariance);
        Ok(())
    }
}

impl Imu {
    /// An IMU message from its CDR bytes.
    pub fn decode(bytes: &[u8]) -> Result<Self, String> {
        let mut r = CdrReader::new(bytes)?;
        Ok(Self {
            header: Header::read(&mut r)?,
            orientation_xyzw: r.f64_array("orientation")?,
            orientation_covariance: r.f64_array("orientation_covariance")?,
            angular_velocity: r.f64_array("angular_velocity")?,
            angular_velocity_covariance: r.f64_array("angular_velocity_covariance")?,
            linear_acceleration: r.f64_array("linear_acceleration")?,
            linear_acceleration_covariance: r.f64_array("linear_acceleration_covariance")?,
        })
    }
}

/// `nav_msgs/Odometry`: the child frame's pose in the header's frame,
/// and its velocity in the child frame. Covariances are row-major 6x6
/// over (x, y, z, rotation about x, y, z).
#[derive(Debug, Clone, PartialEq)]
pub struct Odometry {
    /// Stamp and the frame of the pose (`odom`).
    pub header: Header,
    /// The frame whose pose this is, and the frame of the twist (`body`).
    pub child_frame_id: String,
    /// Position, m.
    pub position: [f64; 3],
    /// Orientation x, y, z, w.
    pub orientation_xyzw: [f64; 4],
    /// The pose's covariance.
    pub pose_covariance: [f64; 36],
    /// Linear velocity in the child frame, m/s.
    pub linear_velocity: [f64; 3],
    /// Angular velocity in the child frame, rad/s.
    pub angular_velocity: [f64; 3],
    /// The twist's covariance.
    pub twist_covariance: [f64; 36],
}

impl Ros2Message for Odometry {
    fn definition() -> &'static Definition {
        &ODOMETRY
    }

    fn write(&self, w: &mut CdrWriter) -> Result<(), CdrError> {
        self.header.write(w)?;
        w.string(&self.child_frame_id)?;
        w.f64_array(&self.position);
        w.f64_array(&self.orientation_xyzw);
        w.f64_array(&self.pose_covariance);
        w.f64_array(&self.linear_velocity);
        w.f64_array(&self.angular_velocity);
        w.f64_array(&self.twist_covariance);
        Ok(())
    }
}

/// `geometry_msgs/TransformStamped`: maps `child_frame_id` coordinates
/// into the header's frame.
#[derive(Debug, Clone, PartialEq)]
pub struct TransformStamped {
    /// Stamp and the parent frame.
    pub header: Header,
    /// The child frame.
    pub child_frame_id: String,
    /// The child's origin in the parent frame, m.
    pub translation: [f64; 3],
    /// The child's orientation x, y, z, w.
    pub rotation_xyzw: [f64; 4],
}

impl TransformStamped {
    fn write(&self, w: &mut CdrWriter) -> Result<(), CdrError> {
        self.header.write(w)?;
        w.string(&self.child_frame_id)?;
        w.f64_array(&self.translation);
        w.f64_array(&self.rotation_xyzw);
        Ok(())
    }
}

/// `tf2_msgs/TFMessage`: the messages of `/tf` and `/tf_static`.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct TfMessage {
    /// The transforms.
    pub transforms: Vec<TransformStamped>,
}

impl Ros2Message for TfMessage {
    fn definition() -> &'static Definition {
        &TF_MESSAGE
    }

    fn write(&self, w: &mut CdrWriter) -> Result<(), CdrError> {
        w.sequence_len("transforms", self.transforms.len())?;
        for t in &self.transforms {
            t.write(w)?;
        }
        Ok(())
    }
}

/// `sensor_msgs/RegionOfInterest`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct RegionOfInterest {
    /// Left column.
    pub x_offset: u32,
    /// Top row.
    pub y_offset: u32,
    /// Rows (0: the whole image).
    pub height: u32,
    /// Columns (0: the whole image).
    pub width: u32,
    /// Whether the region is to be rectified.
    pub do_rectify: bool,
}

/// `sensor_msgs/CameraInfo`: a camera's calibration in ROS's terms.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct CameraInfo {
    /// Stamp and camera frame.
    pub header: Header,
    /// Rows.
    pub height: u32,
    /// Columns.
    pub width: u32,
    /// `plumb_bob` (k1, k2, p1, p2, k3) or `equidistant` (k1..k4).
    pub distortion_model: String,
    /// The distortion coefficients.
    pub d: Vec<f64>,
    /// Intrinsics, row-major 3x3.
    pub k: [f64; 9],
    /// Rectifying rotation, row-major 3x3.
    pub r: [f64; 9],
    /// Projection, row-major 3x4.
    pub p: [f64; 12],
    /// Horizontal binning (0 or 1: none).
    pub binning_x: u32,
    /// Vertical binning.
    pub binning_y: u32,
    /// Region of interest (zero: the whole image).
    pub roi: RegionOfInterest,
}

impl Ros2Message for CameraInfo {
    fn definition() -> &'static Definition {
        &CAMERA_INFO
    }

    fn write(&self, w: &mut CdrWriter) -> Result<(), CdrError> {
        self.header.write(w)?;
        w.u32(self.height);
        w.u32(self.width);
        w.string(&self.distortion_model)?;
        w.f64_sequence(&self.d)?;
        w.f64_array(&self.k);
        w.f64_array(&self.r);
        w.f64_array(&self.p);
        w.u32(self.binning_x);
        w.u32(self.binning_y);
        w.u32(self.roi.x_offset);
        w.u32(self.roi.y_offset);
        w.u32(self.roi.height);
        w.u32(self.roi.width);
        w.bool(self.roi.do_rectify);
        Ok(())
    }
}

/// Schema encoding of ROS 2 message definitions.
pub const SCHEMA_ENCODING: &str = "ros2msg";
/// Message encoding of ROS 2 messages.
pub const MESSAGE_ENCODING: &str = "cdr";

macro_rules! ros2_encode {
    ($($ty:ty),*) => {$(
        impl Encode for $ty {
            type Error = CdrError;

            fn get_schema() -> Option<Schema> {
                let d = <$ty as Ros2Message>::definition();
                Some(Schema::new(
                    d.name,
                    SCHEMA_ENCODING,
                    Cow::<'static, [u8]>::Owned(d.complete().into_bytes()),
                ))
            }

            fn get_message_encoding() -> String {
                MESSAGE_ENCODING.to_owned()
            }

            fn encode(&self, buf: &mut impl foxglove::bytes::BufMut) -> Result<(), CdrError> {
                buf.put_slice(&self.to_cdr()?);
                Ok(())
            }
        }
    )*};
}

ros2_encode!(Image, Imu, Odometry, TfMessage, CameraInfo);

#[cfg(test)]
mod tests;
