//! `rove-ros2`: a ROS 2 robot as a rove vehicle, by config. The vehicle publishes its owner's
//! sticks as a velocity (`geometry_msgs/TwistStamped` or `Twist` on `/cmd_vel`, what
//! `diff_drive_controller`, Nav2 and most ROS 2 robots take), a zero twist and a latched
//! e-stop (`std_msgs/Bool`) in failsafe, and reads the robot's `sensor_msgs/BatteryState`.
//!
//! The ROS 2 side is a DDS participant of its own, on its own domain and interfaces, written
//! on rove's rustdds: the few message types are serde structs in IDL order ([`msg`]), so no
//! ROS install and no second DDS stack are needed (docs/design.md, "ROS 2").
//!
//! # Layout
//! - [`msg`]: the ROS 2 message types, their DDS names, topic name rules.
//! - [`config`]: `[output]` for `adapter = "ros2"` ([`Ros2Settings`] → [`Ros2Config`]), and
//!   the stick → twist map.
//! - [`vehicle`]: [`Ros2Vehicle`], the [`rove_core::adapter::OutputAdapter`].
//! - [`Ros2`]: the adapter as the gateway offers it ([`rove_core::adapter::OutputKind`]);
//!   [`join`], [`topic`], [`reader`]: the ROS 2 participant and its endpoints, also for
//!   rove-inputs' `ros2` source (a Joy or twist topic).
//!
//! # Known limitations
//! - A ROS 2 velocity interface has no modes: the owner's mode goes out on `mode_topic` if one
//!   is configured, and the velocity is the same in every mode.
//! - The ROS 2 participant is unsecured (SROS 2 is not supported).

#![deny(missing_docs)]

pub mod config;
pub mod msg;
pub mod vehicle;

pub use config::{Ros2Config, Ros2Settings};
pub use vehicle::Ros2Vehicle;

use rove_core::MonoTime;
use rove_core::adapter::{OutputAdapter, OutputKind, OutputSpec};
use rove_core::error::LinkError;

/// Joins the ROS 2 graph on DDS domain `domain_id`, confined to `interfaces`, unsecured: the
/// participant of the output adapter and of the `ros2` input source.
///
/// # Errors
/// rustdds cannot join (no such interface, ports taken): fatal, the configuration must change.
pub fn join(
    domain_id: u16,
    interfaces: &[std::net::Ipv4Addr],
) -> Result<rustdds::DomainParticipant, LinkError> {
    rustdds::DomainParticipantBuilder::new(domain_id)
        .with_only_networks(interfaces.iter().copied())
        .same_host_loopback(true)
        .build()
        .map_err(|e| LinkError::fatal(format!("ROS 2: cannot join domain {domain_id}: {e}")))
}

/// The DDS topic of the ROS 2 topic `name`, of message type `M`.
///
/// # Errors
/// rustdds refuses it (fatal).
pub fn topic<M: msg::RosType>(
    participant: &rustdds::DomainParticipant,
    name: &str,
    qos: &rustdds::QosPolicies,
) -> Result<rustdds::Topic, LinkError> {
    let kind = rustdds::TopicKind::NoKey;
    let type_name = M::DDS_NAME.to_string();
    (participant.create_topic(msg::dds_topic(name), type_name, qos, kind))
        .map_err(|e| LinkError::fatal(format!("ROS 2: topic {name}: {e}")))
}

/// A reader of `M` on the ROS 2 topic `name`, with a subscriber of its own: the vehicle's
/// battery, the `ros2` input source's Joy or twist.
///
/// # Errors
/// rustdds refuses the topic, subscriber or reader (fatal).
pub fn reader<M: msg::RosType + serde::de::DeserializeOwned + 'static>(
    participant: &rustdds::DomainParticipant,
    name: &str,
    qos: rustdds::QosPolicies,
) -> Result<rustdds::no_key::DataReaderCdr<M>, LinkError> {
    let fatal = |what: &str, e: &dyn std::fmt::Display| {
        LinkError::fatal(format!("ROS 2: {what} {name}: {e}"))
    };
    let t = topic::<M>(participant, name, &qos)?;
    let subscriber = (participant.create_subscriber(&qos)).map_err(|e| fatal("subscriber", &e))?;
    (subscriber.create_datareader_no_key_cdr(&t, Some(qos))).map_err(|e| fatal("reader", &e))
}

/// `[output] adapter = "ros2"`.
#[derive(Debug, Clone, Copy)]
pub struct Ros2;

impl OutputKind for Ros2 {
    const NAME: &'static str = "ros2";
    const SUMMARY: &'static str = "A ROS 2 robot: velocity on cmd_vel (TwistStamped or Twist), zero and an e-stop in failsafe.";
    type Settings = Ros2Settings;

    fn validate(settings: &mut Ros2Settings) -> rove_core::Result<Box<dyn OutputSpec>> {
        Ok(Box::new(settings.validate()?))
    }
}

impl OutputSpec for Ros2Config {
    fn open(&self, now: MonoTime) -> Result<Box<dyn OutputAdapter>, LinkError> {
        Ok(Box::new(Ros2Vehicle::new(self.clone(), now)?))
    }

    /// Waits up to a second for the robot's subscribers, so that a process of its own
    /// (`rove failsafe` after the gateway died) reaches them.
    fn failsafe(&self) -> Result<String, LinkError> {
        let mut vehicle = Ros2Vehicle::new(self.clone(), MonoTime::ZERO)?;
        vehicle.failsafe_now(std::time::Duration::from_secs(1))
    }

    fn clone_spec(&self) -> Box<dyn OutputSpec> {
        Box::new(self.clone())
    }
}
