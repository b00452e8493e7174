//! The ROS 2 messages rove speaks, as their DDS types: field for field in IDL order, so that
//! rustdds's CDR (XCDR1, little endian) is what rmw_fastrtps and rmw_cyclonedds write. A ROS 2
//! topic `/name` is the DDS topic `rt/name`; a type `pkg/msg/Name` is `pkg::msg::dds_::Name_`.

use serde::{Deserialize, Serialize};

/// `builtin_interfaces/msg/Time`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct Time {
    /// Seconds since the epoch.
    pub sec: i32,
    /// Nanoseconds within the second.
    pub nanosec: u32,
}

impl Time {
    /// The wall clock now (ROS time without a simulated clock).
    pub fn now() -> Time {
        let since = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .unwrap_or_default();
        Time {
            sec: i32::try_from(since.as_secs()).unwrap_or(i32::MAX),
            nanosec: since.subsec_nanos(),
        }
    }
}

/// `std_msgs/msg/Header`.
#[derive(Debug, Clone, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct Header {
    /// When.
    pub stamp: Time,
    /// The frame the data is in.
    pub frame_id: String,
}

/// `geometry_msgs/msg/Vector3`.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct Vector3 {
    /// x.
    pub x: f64,
    /// y.
    pub y: f64,
    /// z.
    pub z: f64,
}

/// `geometry_msgs/msg/Twist`: m/s and rad/s (REP 103: x forward, y left, z up; a positive
/// `angular.z` turns left).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct Twist {
    /// Linear velocity, m/s.
    pub linear: Vector3,
    /// Angular velocity, rad/s.
    pub angular: Vector3,
}

/// `geometry_msgs/msg/TwistStamped`.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct TwistStamped {
    /// Stamp and frame.
    pub header: Header,
    /// The twist.
    pub twist: Twist,
}

/// `std_msgs/msg/Bool`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct Bool {
    /// The value.
    pub data: bool,
}

/// `std_msgs/msg/String`.
#[derive(Debug, Clone, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct RosString {
    /// The text.
    pub data: String,
}

/// `sensor_msgs/msg/BatteryState`.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct BatteryState {
    /// Stamp and frame.
    pub header: Header,
    /// Volts (NaN: unknown).
    pub voltage: f32,
    /// °C (NaN: unknown).
    pub temperature: f32,
    /// Amperes, negative when discharging (NaN: unknown).
    pub current: f32,
    /// Ah (NaN: unknown).
    pub charge: f32,
    /// Ah (NaN: unknown).
    pub capacity: f32,
    /// Ah (NaN: unknown).
    pub design_capacity: f32,
    /// Charge, 0 to 1 (NaN: unknown).
    pub percentage: f32,
    /// `POWER_SUPPLY_STATUS_*`.
    pub power_supply_status: u8,
    /// `POWER_SUPPLY_HEALTH_*`.
    pub power_supply_health: u8,
    /// `POWER_SUPPLY_TECHNOLOGY_*`.
    pub power_supply_technology: u8,
    /// Whether a battery is there.
    pub present: bool,
    /// Volts per cell.
    pub cell_voltage: Vec<f32>,
    /// °C per cell.
    pub cell_temperature: Vec<f32>,
    /// Where the battery is.
    pub location: String,
    /// Its serial number.
    pub serial_number: String,
}

/// `sensor_msgs/msg/Joy`, what the standard `joy` node publishes.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct Joy {
    /// Stamp and frame.
    pub header: Header,
    /// Axes, −1 to 1.
    pub axes: Vec<f32>,
    /// Buttons, 0 or 1.
    pub buttons: Vec<i32>,
}

/// `diagnostic_msgs/msg/KeyValue`.
#[derive(Debug, Clone, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct KeyValue {
    /// The key.
    pub key: String,
    /// The value, as text.
    pub value: String,
}

/// `diagnostic_msgs/msg/DiagnosticStatus`.
#[derive(Debug, Clone, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct DiagnosticStatus {
    /// 0 OK, 1 WARN, 2 ERROR, 3 STALE (an octet).
    pub level: u8,
    /// What is described.
    pub name: String,
    /// Its state in words.
    pub message: String,
    /// Which hardware.
    pub hardware_id: String,
    /// Details.
    pub values: Vec<KeyValue>,
}

/// `diagnostic_msgs/msg/DiagnosticArray`, what `/diagnostics` carries.
#[derive(Debug, Clone, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct DiagnosticArray {
    /// Stamp.
    pub header: Header,
    /// One status per thing described.
    pub status: Vec<DiagnosticStatus>,
}

/// A ROS 2 message type: its ROS name and its DDS type name.
pub trait RosType {
    /// `pkg/msg/Name`, as `ros2 topic list -t` shows it.
    const ROS_NAME: &'static str;
    /// `pkg::msg::dds_::Name_`, what DDS discovery matches.
    const DDS_NAME: &'static str;
}

macro_rules! ros_types {
    ($($ty:ty => $pkg:literal, $name:literal;)*) => {$(
        impl RosType for $ty {
            const ROS_NAME: &'static str = concat!($pkg, "/msg/", $name);
            const DDS_NAME: &'static str = concat!($pkg, "::msg::dds_::", $name, "_");
        }
    )*};
}

ros_types! {
    Twist => "geometry_msgs", "Twist";
    TwistStamped => "geometry_msgs", "TwistStamped";
    Bool => "std_msgs", "Bool";
    RosString => "std_msgs", "String";
    BatteryState => "sensor_msgs", "BatteryState";
    DiagnosticArray => "diagnostic_msgs", "DiagnosticArray";
    Joy => "sensor_msgs", "Joy";
}

/// The DDS topic of the ROS 2 topic `name` (`/cmd_vel` → `rt/cmd_vel`).
pub fn dds_topic(name: &str) -> String {
    format!("rt{name}")
}

/// Whether `name` is a fully qualified ROS 2 topic name: `/` then tokens of letters, digits
/// and `_` separated by single `/`, no token starting with a digit, no trailing `/`.
pub fn valid_topic(name: &str) -> bool {
    let Some(rest) = name.strip_prefix('/') else {
        return false;
    };
    !rest.is_empty()
        && rest.split('/').all(|token| {
            !token.is_empty()
                && !token.starts_with(|c: char| c.is_ascii_digit())
                && token.chars().all(|c| c.is_ascii_alphanumeric() || c == '_')
        })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn type_and_topic_names_are_what_ros_2_matches() {
        assert_eq!(
            TwistStamped::DDS_NAME,
            "geometry_msgs::msg::dds_::TwistStamped_"
        );
        assert_eq!(TwistStamped::ROS_NAME, "geometry_msgs/msg/TwistStamped");
        assert_eq!(Bool::DDS_NAME, "std_msgs::msg::dds_::Bool_");
        assert_eq!(dds_topic("/cmd_vel"), "rt/cmd_vel");
    }

    #[test]
    fn topic_names_follow_the_ros_2_rules() {
        for good in ["/cmd_vel", "/robot1/cmd_vel", "/rove/estop", "/a_1"] {
            assert!(valid_topic(good), "{good}");
        }
        for bad in [
            "cmd_vel",
            "/",
            "/cmd_vel/",
            "//x",
            "/1x",
            "/a b",
            "/a-b",
            "",
        ] {
            assert!(!valid_topic(bad), "{bad}");
        }
    }
}
