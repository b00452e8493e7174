//! `[output]` for `adapter = "ros2"`: as written ([`Ros2Settings`]) and validated
//! ([`Ros2Config`]). Errors name keys relative to `[output]`.

use crate::msg::valid_topic;
use rove_core::config::Int;
use rove_core::error::ConfigErrors;
use rove_core::mapping::Axis;
use rove_core::msg::MovementCommand;
use std::net::Ipv4Addr;
use std::time::Duration;

rove_core::config_types! {
    /// `[output]` for a ROS 2 robot, as written.
    pub table Ros2Settings {
        domain_id: Option<Int> => "The ROS 2 graph's DDS domain (`ROS_DOMAIN_ID`; absent: 0). It \
            may differ from the hierarchy's `[network] domain_id`.",
        interfaces: Option<Vec<Ipv4Addr>> => "IPv4 addresses of the interfaces the ROS 2 side \
            may use (absent: loopback only, a ROS 2 graph on this computer).",
        topic: Option<String> => "The velocity topic (absent: `/cmd_vel`).",
        message: Option<TwistType> => "`\"TwistStamped\"` (absent; what `diff_drive_controller` \
            and Nav2 take since Jazzy) or `\"Twist\"`.",
        frame_id: Option<String> => "`header.frame_id` of a TwistStamped (absent: `base_link`).",
        rate_hz: Option<f64> => "Least publish rate while driven, Hz, so that a controller's \
            `cmd_vel_timeout` never stops a driven robot (absent: 20).",
        zero_for_ms: Option<Int> => "How long the failsafe keeps publishing a zero twist at \
            `rate_hz`, ms (absent: 1000).",
        estop_topic: Option<String> => "A `std_msgs/Bool` set true in failsafe and false when an \
            operator drives, latched (absent: `/rove/estop`; `\"\"`: none).",
        battery_topic: Option<String> => "A `sensor_msgs/BatteryState` topic whose percentage \
            feeds the vehicle's battery on every console (absent: none).",
        owner_topic: Option<String> => "A `std_msgs/String`, latched, saying who drives as JSON \
            on every change (absent: `/rove/owner`; `\"\"`: none).",
        mode_topic: Option<String> => "A `std_msgs/String`, latched, with the mode the owner \
            asks (`manual`, `assisted`, `auto`) on every change, for a robot whose controllers \
            switch on it (absent: none; the velocity is the same in every mode).",
        diagnostics: Option<bool> => "Publish the vehicle's standing, output and battery as \
            `diagnostic_msgs/DiagnosticArray` on `/diagnostics` (absent: true).",
        #[serde(default)] twist: Vec<TwistAxisSettings> => "`[[output.twist]]`: which stick \
            feeds each twist component (absent: throttle → linear.x at 0.5 m/s, roll → \
            angular.z at 1.0 rad/s reversed, stick right turning right).",
    }

    /// The velocity message type.
    pub keyword TwistType {
        #[serde(rename = "TwistStamped")] Stamped => "`geometry_msgs/msg/TwistStamped`.",
        #[serde(rename = "Twist")] Plain => "`geometry_msgs/msg/Twist`.",
    }

    /// One component of the twist.
    pub keyword Component {
        #[serde(rename = "linear.x")] LinearX => "Forward, m/s.",
        #[serde(rename = "linear.y")] LinearY => "Left, m/s.",
        #[serde(rename = "linear.z")] LinearZ => "Up, m/s.",
        #[serde(rename = "angular.x")] AngularX => "Roll rate, rad/s.",
        #[serde(rename = "angular.y")] AngularY => "Pitch rate, rad/s.",
        #[serde(rename = "angular.z")] AngularZ => "Yaw rate (positive: left), rad/s.",
    }

    /// `[[output.twist]]`: a stick axis on a twist component.
    pub table TwistAxisSettings {
        component: Option<Component> => "`\"linear.x\"` … `\"angular.z\"` (required).",
        axis: Option<Axis> => "`throttle`, `roll`, `pitch` or `yaw` (required).",
        max: Option<f64> => "The component at full stick, m/s or rad/s (required, > 0).",
        reverse: Option<bool> => "Full stick gives −max (absent: false).",
    }
}

/// One stick axis on one twist component.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TwistAxis {
    /// The component.
    pub component: Component,
    /// The stick axis.
    pub axis: Axis,
    /// m/s or rad/s at full stick, signed (negative: reversed).
    pub scale: f64,
}

/// A validated ROS 2 output.
#[derive(Debug, Clone, PartialEq)]
pub struct Ros2Config {
    /// DDS domain of the ROS 2 graph.
    pub domain_id: u16,
    /// Interfaces the ROS 2 participant may use.
    pub interfaces: Vec<Ipv4Addr>,
    /// The velocity topic (ROS name).
    pub topic: String,
    /// Its message type.
    pub message: TwistType,
    /// `header.frame_id` of a TwistStamped.
    pub frame_id: String,
    /// Least publish period while driven.
    pub period: Duration,
    /// How long the failsafe keeps publishing zero.
    pub zero_for: Duration,
    /// The e-stop topic, if any.
    pub estop_topic: Option<String>,
    /// The battery topic, if any.
    pub battery_topic: Option<String>,
    /// The who-drives topic, if any.
    pub owner_topic: Option<String>,
    /// The mode topic, if any.
    pub mode_topic: Option<String>,
    /// Whether `/diagnostics` is published.
    pub diagnostics: bool,
    /// The stick → twist map.
    pub twist: Vec<TwistAxis>,
}

impl Ros2Settings {
    /// Validates, filling every default into `self`.
    ///
    /// # Errors
    /// [`rove_core::Error::Config`] listing every invalid key.
    pub fn validate(&mut self) -> rove_core::Result<Ros2Config> {
        let mut errors = ConfigErrors::default();
        let domain = *self.domain_id.get_or_insert(0);
        // The RTPS port formula leaves room for domains 0..=232.
        let domain_id = errors.int("domain_id", domain, 0..=232, "").unwrap_or(0);
        let interfaces = (self.interfaces)
            .get_or_insert_with(|| vec![Ipv4Addr::LOCALHOST])
            .clone();
        if interfaces.is_empty() {
            errors.add("interfaces", "[]", "names at least one interface");
        }
        let topic = self.topic.get_or_insert_with(|| "/cmd_vel".into()).clone();
        check_topic(&mut errors, "topic", &topic);
        let message = *self.message.get_or_insert(TwistType::Stamped);
        let frame_id = self.frame_id.get_or_insert_with(|| "base_link".into());
        let rate = *self.rate_hz.get_or_insert(20.0);
        errors.float("rate_hz", rate, 1.0..=200.0, "must be 1..=200");
        let zero = *self.zero_for_ms.get_or_insert(1000);
        let zero_for = errors.int("zero_for_ms", zero, 0..=60_000, " ms");
        let estop = self.estop_topic.get_or_insert_with(|| "/rove/estop".into());
        if !estop.is_empty() {
            check_topic(&mut errors, "estop_topic", estop);
        }
        let owner = self.owner_topic.get_or_insert_with(|| "/rove/owner".into());
        if !owner.is_empty() {
            check_topic(&mut errors, "owner_topic", owner);
        }
        let owner_topic = Some(owner.clone()).filter(|t| !t.is_empty());
        if let Some(mode) = &self.mode_topic {
            check_topic(&mut errors, "mode_topic", mode);
        }
        let diagnostics = *self.diagnostics.get_or_insert(true);
        if let Some(battery) = &self.battery_topic {
            check_topic(&mut errors, "battery_topic", battery);
        }
        if self.twist.is_empty() {
            self.twist = default_twist();
        }
        let twist = validate_twist(&mut errors, &mut self.twist);
        errors.into_result(Ros2Config {
            domain_id,
            interfaces,
            topic,
            message,
            frame_id: frame_id.clone(),
            period: Duration::from_secs_f64(1.0 / rate.clamp(1.0, 200.0)),
            zero_for: Duration::from_millis(zero_for.unwrap_or(1000)),
            estop_topic: Some(estop.clone()).filter(|t| !t.is_empty()),
            battery_topic: self.battery_topic.clone(),
            owner_topic,
            mode_topic: self.mode_topic.clone(),
            diagnostics,
            twist,
        })
    }
}

fn check_topic(errors: &mut ConfigErrors, key: &str, topic: &str) {
    if !valid_topic(topic) {
        let rule = "must be a ROS 2 topic name: `/` then letters, digits and `_`, parts \
                    separated by `/`";
        errors.add(key, format!("{topic:?}"), rule);
    }
}

/// Throttle → linear.x at 0.5 m/s; roll (steering) → angular.z at 1.0 rad/s, reversed: stick
/// right turns right, which REP 103 calls negative.
fn default_twist() -> Vec<TwistAxisSettings> {
    let entry = |component, axis, max, reverse| TwistAxisSettings {
        component: Some(component),
        axis: Some(axis),
        max: Some(max),
        reverse: Some(reverse),
    };
    vec![
        entry(Component::LinearX, Axis::Throttle, 0.5, false),
        entry(Component::AngularZ, Axis::Roll, 1.0, true),
    ]
}

fn validate_twist(errors: &mut ConfigErrors, twist: &mut [TwistAxisSettings]) -> Vec<TwistAxis> {
    let mut seen = Vec::new();
    let mut out = Vec::new();
    for (i, entry) in twist.iter_mut().enumerate() {
        let key = |k: &str| format!("twist[{i}].{k}");
        let component = errors.required(&key("component"), &entry.component);
        let axis = errors.required(&key("axis"), &entry.axis);
        let max = errors.required(&key("max"), &entry.max);
        let reverse = *entry.reverse.get_or_insert(false);
        if let Some(max) = max {
            errors.float(&key("max"), max, f64::MIN_POSITIVE..=1000.0, "must be > 0");
        }
        if let Some(c) = component {
            if seen.contains(&c) {
                errors.add(key("component"), c.name(), "is fed twice");
            }
            seen.push(c);
        }
        if let (Some(component), Some(axis), Some(max)) = (component, axis, max) {
            let scale = if reverse { -max } else { max };
            out.push(TwistAxis {
                component,
                axis,
                scale,
            });
        }
    }
    out
}

impl Component {
    /// The component's name as written.
    pub fn name(self) -> &'static str {
        match self {
            Component::LinearX => "\"linear.x\"",
            Component::LinearY => "\"linear.y\"",
            Component::LinearZ => "\"linear.z\"",
            Component::AngularX => "\"angular.x\"",
            Component::AngularY => "\"angular.y\"",
            Component::AngularZ => "\"angular.z\"",
        }
    }
}

impl Ros2Config {
    /// The twist for `movement`: each mapped axis, as a fraction of full stick, times its
    /// scale; unmapped components are zero.
    pub fn twist_of(&self, movement: &MovementCommand) -> crate::msg::Twist {
        let mut twist = crate::msg::Twist::default();
        for map in &self.twist {
            let stick = f64::from(map.axis.of(movement)) / f64::from(rove_core::msg::AXIS_MAX);
            let value = stick.clamp(-1.0, 1.0) * map.scale;
            let slot = match map.component {
                Component::LinearX => &mut twist.linear.x,
                Component::LinearY => &mut twist.linear.y,
                Component::LinearZ => &mut twist.linear.z,
                Component::AngularX => &mut twist.angular.x,
                Component::AngularY => &mut twist.angular.y,
                Component::AngularZ => &mut twist.angular.z,
            };
            *slot = value;
        }
        twist
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn settings(text: &str) -> Ros2Settings {
        toml::from_str(text).expect("parses")
    }

    #[test]
    fn defaults_drive_a_diff_drive_robot_on_cmd_vel() {
        let mut s = settings("");
        let c = s.validate().expect("valid");
        assert_eq!(
            (c.topic.as_str(), c.message),
            ("/cmd_vel", TwistType::Stamped)
        );
        assert_eq!(c.estop_topic.as_deref(), Some("/rove/estop"));
        let full = MovementCommand {
            throttle: rove_core::msg::AXIS_MAX,
            roll: rove_core::msg::AXIS_MAX,
            ..MovementCommand::CENTRED
        };
        let t = c.twist_of(&full);
        assert_eq!((t.linear.x, t.angular.z), (0.5, -1.0));
        assert_eq!(c.twist_of(&MovementCommand::CENTRED), Default::default());
        // The defaults are written back, so the effective config shows the map.
        assert_eq!(s.twist.len(), 2);
        let again = toml::to_string(&s).expect("writes");
        assert_eq!(settings(&again).validate().expect("valid"), c);
    }

    #[test]
    fn a_holonomic_map_and_its_errors() {
        let mut s = settings(
            "message = \"Twist\"\n\
             [[twist]]\ncomponent = \"linear.y\"\naxis = \"roll\"\nmax = 0.3\n\
             [[twist]]\ncomponent = \"linear.y\"\naxis = \"yaw\"\nmax = 0\n",
        );
        let err = s.validate().expect_err("invalid").to_string();
        assert!(
            err.contains("twist[1].component = \"linear.y\": is fed twice"),
            "{err}"
        );
        assert!(err.contains("twist[1].max = 0: must be > 0"), "{err}");
        let err = settings("topic = \"cmd vel\"\nestop_topic = \"/a/\"\n")
            .validate()
            .expect_err("invalid")
            .to_string();
        assert!(err.contains("topic = \"cmd vel\""), "{err}");
        assert!(err.contains("estop_topic = \"/a/\""), "{err}");
        assert!(toml::from_str::<Ros2Settings>("warp = 1").is_err());
    }
}
