//! `[input] source = "ros2"`: its keys, checked (the source itself is `crate::ros2`).

use super::*;

impl InputSettings {
    /// `source = "ros2"`: the topic, domain and interfaces; the device and recording keys do
    /// not apply.
    pub(super) fn validate_ros2(&mut self, errors: &mut ConfigErrors) -> SourceConfig {
        let only_others = "does not apply to source = \"ros2\"";
        let path =
            |p: &Option<PathBuf>| p.as_ref().map(|p| format!("{:?}", p.display().to_string()));
        errors.not_for("device", path(&self.device), only_others);
        errors.not_for(
            "name",
            self.name.as_ref().map(|n| format!("{n:?}")),
            only_others,
        );
        errors.not_for("grab", self.grab, only_others);
        errors.not_for("reopen_interval_ms", self.reopen_interval_ms, only_others);
        errors.not_for("file", path(&self.file), only_others);
        let message = *self.message.get_or_insert(Ros2Message::Joy);
        let default_topic = match message {
            Ros2Message::Joy => "/joy",
            Ros2Message::Twist | Ros2Message::TwistStamped => "/cmd_vel",
        };
        let topic = self
            .topic
            .get_or_insert_with(|| default_topic.into())
            .clone();
        let max_linear = *self.max_linear.get_or_insert(0.5);
        errors.float(
            "max_linear",
            max_linear,
            0.001..=100.0,
            "must be 0.001..=100 m/s",
        );
        let max_angular = *self.max_angular.get_or_insert(1.0);
        errors.float(
            "max_angular",
            max_angular,
            0.001..=100.0,
            "must be 0.001..=100 rad/s",
        );
        let valid = rove_ros2::msg::valid_topic(&topic);
        if !valid {
            let rule = "must be a ROS 2 topic name: `/` then letters, digits and `_`, parts \
                        separated by `/`";
            errors.add("topic", format!("{topic:?}"), rule);
        }
        let domain = *self.domain_id.get_or_insert(0);
        let domain_id = errors.int("domain_id", domain, 0..=232, "").unwrap_or(0);
        let interfaces = (self.interfaces)
            .get_or_insert_with(|| vec![std::net::Ipv4Addr::LOCALHOST])
            .clone();
        if interfaces.is_empty() {
            errors.add("interfaces", "[]", "names at least one interface");
        }
        // The joy node repeats its last message (autorepeat_rate, 20 Hz by default): silence
        // means the node or its link is gone.
        self.silence_timeout_ms
            .get_or_insert(DEFAULT_ROS2_SILENCE_MS);
        SourceConfig::Ros2 {
            topic,
            message,
            max_linear,
            max_angular,
            domain_id,
            interfaces,
        }
    }
}

/// `silence_timeout_ms` of a `ros2` source when absent: ten periods of the joy node's default
/// 20 Hz autorepeat.
pub const DEFAULT_ROS2_SILENCE_MS: Int = 500;
