//! Recordings in ROS 2's terms (`[recording] format = "ros2"`): MCAP
//! with the `ros2` profile, message definitions in `ros2msg`, messages
//! in CDR, the layout `ros2 bag play` reads.
//!
//! The topics: `/cam0/image_raw` and `/cam1/image_raw`
//! (`sensor_msgs/msg/Image`, mono8), `/imu0` (`sensor_msgs/msg/Imu`),
//! `/rigslam/odom` (`nav_msgs/msg/Odometry`), `/tf` (`map -> odom ->
//! body` with each pose), `/tf_static` (`body -> cam0, cam1, imu`, once
//! per file) and `/cam0/camera_info`, `/cam1/camera_info`
//! (`sensor_msgs/msg/CameraInfo`, with every image under its stamp, as
//! camera drivers publish it). [`convert`] says what
//! each field holds; [`cdr`] writes the bytes; [`messages`] has the
//! types and their definitions.
//!
//! Each channel says how its publisher offered it
//! (`offered_qos_profiles`, what `ros2 bag play` publishes with):
//! reliable, volatile, except `/tf_static`, written once per file, which
//! is transient-local so that a node
//! started later still gets them (tf2 listens to `/tf_static` that way and
//! hears no volatile publisher). The profiles are in rosbag2's older
//! numeric YAML form, the one Humble's rosbag2 reads; later ones read it
//! in files of bag format 8 and before, and a `rosbag2` metadata record
//! with an empty `serialized_metadata` is what makes
//! rosbag2_storage_mcap's `read_metadata` take a file as such. This
//! follows rosbag2's source; it was not run against rosbag2.

use std::collections::BTreeMap;

pub mod cdr;
pub mod convert;
pub mod messages;

/// Topic of camera `index`'s images.
pub fn image_topic(index: usize) -> String {
    format!("/cam{index}/image_raw")
}

/// Topic of camera `index`'s calibration.
pub fn camera_info_topic(index: usize) -> String {
    format!("/cam{index}/camera_info")
}

/// Topic of the IMU samples.
pub const IMU_TOPIC: &str = "/imu0";
/// Topic of the poses as odometry.
pub const ODOM_TOPIC: &str = "/rigslam/odom";
/// Topic of the transforms that move.
pub const TF_TOPIC: &str = "/tf";
/// Topic of the transforms that do not.
pub const TF_STATIC_TOPIC: &str = "/tf_static";

/// Channel metadata key rosbag2 reads a topic's offered QoS from.
pub const QOS_KEY: &str = "offered_qos_profiles";

/// The channel metadata of a topic: its publisher's QoS, keep-last
/// reliable, transient-local when `latched` (a message written once that
/// later subscribers must still get) else volatile. Deadline, lifespan
/// and lease duration are left unspecified (0), liveliness automatic.
pub fn channel_metadata(latched: bool) -> BTreeMap<String, String> {
    // rmw's enums: history 1 keep-last; reliability 1 reliable;
    // durability 1 transient-local, 2 volatile; liveliness 1 automatic.
    let (depth, durability) = if latched { (1, 1) } else { (10, 2) };
    let profile = format!(
        "- history: 1\n  depth: {depth}\n  reliability: 1\n  durability: {durability}\n  \
         deadline:\n    sec: 0\n    nsec: 0\n  lifespan:\n    sec: 0\n    nsec: 0\n  \
         liveliness: 1\n  liveliness_lease_duration:\n    sec: 0\n    nsec: 0\n  \
         avoid_ros_namespace_conventions: false"
    );
    BTreeMap::from([(QOS_KEY.to_owned(), profile)])
}

/// Name of the metadata record rosbag2 reads.
pub const BAG_METADATA_NAME: &str = "rosbag2";

/// The `rosbag2` metadata record: an empty `serialized_metadata`, so that
/// rosbag2 reads the QoS profiles in their numeric form (see the module
/// documentation).
pub fn bag_metadata() -> BTreeMap<String, String> {
    BTreeMap::from([("serialized_metadata".to_owned(), String::new())])
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The profile as rosbag2 (Humble's `qos.cpp`, and later ones for
    /// bags of version 8 and before) reads it: a YAML list of one map
    /// with these keys, numbers for the policies, sec and nsec for the
    /// durations.
    #[test]
    fn the_qos_profile_has_every_key_rosbag2_reads() {
        for (latched, depth, durability) in [(true, 1, 1), (false, 10, 2)] {
            let text = &channel_metadata(latched)[QOS_KEY];
            let yaml: serde_yaml::Value = serde_yaml::from_str(text).expect("YAML");
            let list = yaml.as_sequence().expect("a list");
            assert_eq!(list.len(), 1, "{text}");
            let profile = list[0].as_mapping().expect("a map");
            let number = |key: &str| profile[key].as_u64().unwrap_or_else(|| panic!("{key}"));
            assert_eq!(number("history"), 1);
            assert_eq!(number("depth"), depth);
            assert_eq!(number("reliability"), 1);
            assert_eq!(number("durability"), durability);
            assert_eq!(number("liveliness"), 1);
            for key in ["deadline", "lifespan", "liveliness_lease_duration"] {
                let d = profile[key].as_mapping().expect(key);
                assert_eq!(d["sec"].as_u64(), Some(0), "{key}");
                assert_eq!(d["nsec"].as_u64(), Some(0), "{key}");
            }
            assert_eq!(
                profile["avoid_ros_namespace_conventions"].as_bool(),
                Some(false)
            );
            assert_eq!(profile.len(), 9, "{text}");
        }
    }

    #[test]
    fn topics_are_named_as_ros_drivers_name_them() {
        assert_eq!(image_topic(1), "/cam1/image_raw");
        assert_eq!(camera_info_topic(0), "/cam0/camera_info");
    }
}
