//! [`Ros2Vehicle`]: the ROS 2 robot as an [`OutputAdapter`]. It joins the ROS 2 graph as a DDS
//! participant of its own (rustdds, unsecured, on `[output] domain_id` and `interfaces`),
//! publishes the velocity while driven and a zero twist plus the e-stop in failsafe, and reads
//! the robot's battery.

use crate::config::{Ros2Config, TwistType};
use crate::msg::{
    BatteryState, Bool, DiagnosticArray, DiagnosticStatus, Header, KeyValue, RosString, RosType,
    Time, Twist, TwistStamped,
};
use rove_core::MonoTime;
use rove_core::adapter::{Health, OutputAdapter, Telemetry};
use rove_core::arbiter::Setpoint;
use rove_core::error::LinkError;
use rove_core::msg::{OutputState, VehicleStatus};
use rustdds::no_key::{DataReaderCdr, DataWriterCdr};
use rustdds::policy::{Durability, History, Reliability};
use rustdds::{DomainParticipant, Publisher, QosPolicies, QosPolicyBuilder};
use serde::Serialize;
use std::time::Duration;

/// How long a reliable write may wait for a full history: a velocity superseded 50 ms later
/// is not worth waiting for.
const MAX_BLOCKING: rustdds::Duration = rustdds::Duration::from_millis(5);

/// rclcpp's and rclpy's default QoS, which their subscribers ask for: reliable, volatile,
/// keep last. A reliable writer also serves best-effort readers.
fn velocity_qos() -> QosPolicies {
    QosPolicyBuilder::new()
        .reliability(Reliability::Reliable {
            max_blocking_time: MAX_BLOCKING,
        })
        .durability(Durability::Volatile)
        .history(History::KeepLast { depth: 10 })
        .build()
}

/// A latched topic (ROS 2's "transient local"): a subscriber that joins late gets the last
/// value.
fn latched_qos() -> QosPolicies {
    QosPolicyBuilder::new()
        .reliability(Reliability::Reliable {
            max_blocking_time: MAX_BLOCKING,
        })
        .durability(Durability::TransientLocal)
        .history(History::KeepLast { depth: 1 })
        .build()
}

/// A battery reader matches reliable and best-effort (sensor-data) publishers alike.
fn battery_qos() -> QosPolicies {
    QosPolicyBuilder::new()
        .reliability(Reliability::BestEffort)
        .durability(Durability::Volatile)
        .history(History::KeepLast { depth: 1 })
        .build()
}

enum VelocityWriter {
    Stamped(DataWriterCdr<TwistStamped>),
    Plain(DataWriterCdr<Twist>),
}

impl VelocityWriter {
    /// The writer's next status event, if one is waiting.
    fn status(&self) -> Option<rustdds::dds::statusevents::DataWriterStatus> {
        use rustdds::StatusEvented;
        match self {
            VelocityWriter::Stamped(w) => w.try_recv_status(),
            VelocityWriter::Plain(w) => w.try_recv_status(),
        }
    }

    /// Whether every matched reader acknowledged what was written, within `wait`.
    fn acknowledged(&self, wait: Duration) -> bool {
        let acked = match self {
            VelocityWriter::Stamped(w) => w.wait_for_acknowledgments(wait),
            VelocityWriter::Plain(w) => w.wait_for_acknowledgments(wait),
        };
        acked.unwrap_or(false)
    }
}

/// A latched topic's writer that writes a value only when it differs from the last one written
/// (the e-stop, who drives, the mode).
struct Latched<M: Serialize> {
    writer: DataWriterCdr<M>,
    shown: Option<M>,
}

impl<M: Serialize + PartialEq + Clone> Latched<M> {
    /// Writes `value` unless it is the value last written.
    fn show(&mut self, value: M) -> Result<(), String> {
        if self.shown.as_ref() == Some(&value) {
            return Ok(());
        }
        (self.writer.write(value.clone(), None)).map_err(|e| e.to_string())?;
        self.shown = Some(value);
        Ok(())
    }
}

/// A writer of `M` on the ROS 2 topic `name`.
fn writer<M: RosType + Serialize>(
    participant: &DomainParticipant,
    publisher: &Publisher,
    name: &str,
    qos: QosPolicies,
) -> Result<DataWriterCdr<M>, LinkError> {
    let t = crate::topic::<M>(participant, name, &qos)?;
    (publisher.create_datawriter_no_key_cdr(&t, Some(qos)))
        .map_err(|e| fatal(&format!("writer {name}"), e))
}

/// A [`Latched`] writer of `M` on `name`, if the config names a topic.
fn latched<M: RosType + Serialize>(
    participant: &DomainParticipant,
    publisher: &Publisher,
    name: Option<&str>,
) -> Result<Option<Latched<M>>, LinkError> {
    name.map(|name| {
        let writer = writer(participant, publisher, name, latched_qos())?;
        Ok(Latched {
            writer,
            shown: None,
        })
    })
    .transpose()
}

/// Where the output stands.
#[derive(Debug, Clone, Copy, PartialEq)]
enum State {
    /// Driven: `twist` is republished at least every period.
    Driving(Twist),
    /// Failsafe: zero is republished until then.
    Safe { zero_until: MonoTime },
}

/// The ROS 2 robot.
pub struct Ros2Vehicle {
    config: Ros2Config,
    velocity: VelocityWriter,
    estop: Option<Latched<Bool>>,
    owner: Option<Latched<RosString>>,
    mode: Option<Latched<RosString>>,
    diagnostics: Option<DataWriterCdr<DiagnosticArray>>,
    battery: Option<DataReaderCdr<BatteryState>>,
    state: State,
    last_publish: Option<MonoTime>,
    battery_pct: Option<u8>,
    error: Option<String>,
    // Dropped last: its writers above go first.
    _participant: DomainParticipant,
}

impl std::fmt::Debug for Ros2Vehicle {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Ros2Vehicle")
            .field("config", &self.config)
            .field("state", &self.state)
            .field("estop", &self.estop.as_ref().and_then(|e| e.shown))
            .finish_non_exhaustive()
    }
}

fn fatal(what: &str, e: impl std::fmt::Display) -> LinkError {
    LinkError::fatal(format!("ROS 2: {what}: {e}"))
}

impl Ros2Vehicle {
    /// Joins the ROS 2 graph and puts the robot in the safe state (zero twist, e-stop set).
    ///
    /// # Errors
    /// rustdds cannot join the domain (no such interface, ports taken) or create an endpoint
    /// (fatal: the configuration must change).
    pub fn new(config: Ros2Config, now: MonoTime) -> Result<Ros2Vehicle, LinkError> {
        let participant = crate::join(config.domain_id, &config.interfaces)?;
        let default = QosPolicyBuilder::new().build();
        let publisher =
            (participant.create_publisher(&default)).map_err(|e| fatal("publisher", e))?;
        let (p, name) = (&participant, config.topic.as_str());
        let velocity = match config.message {
            TwistType::Stamped => {
                VelocityWriter::Stamped(writer(p, &publisher, name, velocity_qos())?)
            }
            TwistType::Plain => VelocityWriter::Plain(writer(p, &publisher, name, velocity_qos())?),
        };
        let estop = latched(p, &publisher, config.estop_topic.as_deref())?;
        let owner = latched(p, &publisher, config.owner_topic.as_deref())?;
        let mode = latched(p, &publisher, config.mode_topic.as_deref())?;
        let diagnostics = (config.diagnostics)
            .then(|| writer(p, &publisher, "/diagnostics", velocity_qos()))
            .transpose()?;
        let battery = (config.battery_topic.as_deref())
            .map(|name| crate::reader(p, name, battery_qos()))
            .transpose()?;
        let mut vehicle = Ros2Vehicle {
            config,
            velocity,
            estop,
            owner,
            mode,
            diagnostics,
            battery,
            state: State::Safe { zero_until: now },
            last_publish: None,
            battery_pct: None,
            error: None,
            _participant: participant,
        };
        vehicle.safe_state(now)?;
        Ok(vehicle)
    }

    fn publish(&mut self, now: MonoTime, twist: Twist) -> Result<(), LinkError> {
        let written = match &self.velocity {
            VelocityWriter::Stamped(w) => {
                let header = Header {
                    stamp: Time::now(),
                    frame_id: self.config.frame_id.clone(),
                };
                w.write(TwistStamped { header, twist }, None)
                    .map_err(|e| e.to_string())
            }
            VelocityWriter::Plain(w) => w.write(twist, None).map_err(|e| e.to_string()),
        };
        self.last_publish = Some(now);
        self.checked(written)
    }

    /// The e-stop, when it changes.
    fn show_estop(&mut self, on: bool) -> Result<(), LinkError> {
        match self.estop.as_mut() {
            Some(estop) => {
                let written = estop.show(Bool { data: on });
                self.checked(written)
            }
            None => Ok(()),
        }
    }

    /// The owner's mode on the mode topic, when it changes.
    fn show_mode(&mut self, mode: rove_core::msg::Mode) -> Result<(), LinkError> {
        match self.mode.as_mut() {
            Some(topic) => {
                let data = format!("{mode:?}").to_lowercase();
                let written = topic.show(RosString { data });
                self.checked(written)
            }
            None => Ok(()),
        }
    }

    /// A write's outcome: a failed write is transient (the gateway holds the output safe and
    /// retries); the error shows in the health until a write works.
    fn checked(&mut self, written: Result<(), String>) -> Result<(), LinkError> {
        match written {
            Ok(()) => {
                self.error = None;
                Ok(())
            }
            Err(e) => {
                let e = format!("ROS 2 write: {e}");
                self.error = Some(e.clone());
                Err(LinkError::transient(e))
            }
        }
    }

    /// `rove failsafe` from a process of its own: a participant that just joined has no
    /// subscriber yet, so this waits up to `patience` for the velocity topic's subscribers
    /// (discovery), publishes zero and the e-stop, and waits for them to acknowledge both.
    ///
    /// # Errors
    /// A write fails.
    pub fn failsafe_now(&mut self, patience: Duration) -> Result<String, LinkError> {
        use rustdds::dds::statusevents::DataWriterStatus;
        let start = std::time::Instant::now();
        let mut matched = 0;
        // A one-shot command, not a loop of the gateway: polling discovery is enough here.
        loop {
            match self.velocity.status() {
                Some(DataWriterStatus::PublicationMatched { current, .. }) => {
                    matched = current.count();
                }
                Some(_) => {}
                None if matched > 0 || start.elapsed() >= patience => break,
                None => std::thread::sleep(Duration::from_millis(20)),
            }
        }
        self.safe_state(MonoTime::ZERO)?;
        let wait = Duration::from_millis(500);
        let acked = self.velocity.acknowledged(wait);
        if let Some(estop) = &self.estop {
            let _ = estop.writer.wait_for_acknowledgments(wait);
        }
        Ok(match (matched, acked) {
            (0, _) => format!(
                "{}: zero twist and e-stop published, but no subscriber of {} was found within {} ms",
                self.describe(),
                self.config.topic,
                patience.as_millis()
            ),
            (n, true) => format!(
                "{}: zero twist and e-stop acknowledged by {n} subscriber(s)",
                self.describe()
            ),
            (n, _) => format!(
                "{}: zero twist and e-stop sent to {n} subscriber(s), not all acknowledged",
                self.describe()
            ),
        })
    }

    /// Takes whatever the battery topic brought; the newest percentage wins.
    fn read_battery(&mut self) {
        let Some(reader) = self.battery.as_mut() else {
            return;
        };
        // Bounded: a flood is read at most this much per call, the rest next time.
        for _ in 0..64 {
            match reader.take_next_sample() {
                Ok(Some(sample)) => {
                    let p = sample.into_value().percentage;
                    if p.is_finite() {
                        self.battery_pct = Some((p.clamp(0.0, 1.0) * 100.0).round() as u8);
                    }
                }
                Ok(None) | Err(_) => break,
            }
        }
    }
}

impl OutputAdapter for Ros2Vehicle {
    fn describe(&self) -> String {
        let kind = match self.config.message {
            TwistType::Stamped => TwistStamped::ROS_NAME,
            TwistType::Plain => Twist::ROS_NAME,
        };
        format!(
            "ROS 2 {} ({kind}) on domain {}, e-stop {}",
            self.config.topic,
            self.config.domain_id,
            self.config.estop_topic.as_deref().unwrap_or("none")
        )
    }

    fn apply(&mut self, now: MonoTime, setpoint: &Setpoint) -> Result<(), LinkError> {
        let twist = self.config.twist_of(&setpoint.movement);
        self.state = State::Driving(twist);
        self.show_estop(false)?;
        self.show_mode(setpoint.mode)?;
        self.publish(now, twist)
    }

    fn safe_state(&mut self, now: MonoTime) -> Result<(), LinkError> {
        self.state = State::Safe {
            zero_until: now + self.config.zero_for,
        };
        // Zero first: it stops the robot even where nothing listens to the e-stop.
        let zero = self.publish(now, Twist::default());
        self.show_estop(true)?;
        zero
    }

    fn keepalive_period(&self) -> Option<Duration> {
        Some(self.config.period)
    }

    /// Republishes the driven twist when no command did within the period (a controller's
    /// `cmd_vel_timeout` must not stop a driven robot), and zero for `zero_for_ms` after a
    /// failsafe; reads the battery.
    fn keepalive(&mut self, now: MonoTime) -> Result<(), LinkError> {
        self.read_battery();
        let due = self
            .last_publish
            .is_none_or(|t| now.saturating_since(t) >= self.config.period);
        match self.state {
            State::Driving(twist) if due => self.publish(now, twist),
            State::Safe { zero_until } if due && now < zero_until => {
                self.publish(now, Twist::default())
            }
            _ => Ok(()),
        }
    }

    /// Who drives, on the latched owner topic when it changes, and the vehicle's standing on
    /// `/diagnostics`.
    fn status(&mut self, _now: MonoTime, status: &VehicleStatus) -> Result<(), LinkError> {
        if let Some(owner) = self.owner.as_mut() {
            let data = owner_text(status);
            (owner.show(RosString { data }))
                .map_err(|e| LinkError::transient(format!("ROS 2 owner: {e}")))?;
        }
        if let Some(writer) = &self.diagnostics {
            let array = DiagnosticArray {
                header: Header {
                    stamp: Time::now(),
                    frame_id: String::new(),
                },
                status: vec![diagnostic(status)],
            };
            writer
                .write(array, None)
                .map_err(|e| LinkError::transient(format!("ROS 2 /diagnostics: {e}")))?;
        }
        Ok(())
    }

    fn health(&self) -> Health {
        match &self.error {
            None => Health::Ok,
            Some(e) => Health::Down(e.clone()),
        }
    }

    fn telemetry(&self) -> Telemetry {
        Telemetry {
            battery_pct: self.battery_pct,
            ..Telemetry::default()
        }
    }
}

impl Drop for Ros2Vehicle {
    /// Zero twist and the e-stop, however the adapter goes (the gateway stopping, unwinding).
    fn drop(&mut self) {
        let _ = self.safe_state(MonoTime::ZERO);
    }
}

/// Who drives, as the owner topic says it: `{"vehicle":100,"owner":11,"failsafe":false}`, the
/// owner `null` while the vehicle's failsafe owns it.
pub fn owner_text(status: &VehicleStatus) -> String {
    let owner = match status.controller_id == status.vehicle_id {
        true => "null".to_string(),
        false => status.controller_id.to_string(),
    };
    format!(
        "{{\"vehicle\":{},\"owner\":{owner},\"failsafe\":{}}}",
        status.vehicle_id, status.failsafe
    )
}

/// The vehicle's standing as one `/diagnostics` status: ERROR when the output is down or hung,
/// WARN in failsafe or on a low battery, else OK.
pub fn diagnostic(status: &VehicleStatus) -> DiagnosticStatus {
    let driven = status.controller_id != status.vehicle_id && !status.failsafe;
    let level = match status.output {
        OutputState::Down | OutputState::Hung => 2,
        _ if !driven || status.health.battery_low || status.output == OutputState::Degraded => 1,
        _ => 0,
    };
    let standing = match driven {
        true => format!("driven by {}", status.controller_id),
        false => "failsafe".to_string(),
    };
    let kv = |key: &str, value: String| KeyValue {
        key: key.into(),
        value,
    };
    let battery = status.health.battery_pct;
    DiagnosticStatus {
        level,
        name: format!("rove: vehicle {}", status.vehicle_id),
        message: format!("{standing}; output {:?}", status.output).to_lowercase(),
        hardware_id: format!("rove-{}", status.vehicle_id),
        values: vec![
            kv("owner", status.controller_id.to_string()),
            kv("failsafe", status.failsafe.to_string()),
            kv("output", format!("{:?}", status.output).to_lowercase()),
            kv("mode", format!("{:?}", status.mode).to_lowercase()),
            kv(
                "battery_pct",
                if battery < 0 {
                    "unknown".into()
                } else {
                    battery.to_string()
                },
            ),
            kv("battery_low", status.health.battery_low.to_string()),
            kv("detail", status.detail.clone()),
        ],
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rove_core::msg::{Mode, VehicleHealth};

    fn status(owner: i64, failsafe: bool, output: OutputState, low: bool) -> VehicleStatus {
        VehicleStatus {
            vehicle_id: 100,
            controller_id: owner,
            mode: Mode::Manual,
            failsafe,
            output,
            detail: String::new(),
            health: VehicleHealth {
                battery_pct: 20,
                battery_low: low,
                ..VehicleHealth::default()
            },
        }
    }

    #[test]
    fn the_owner_text_names_the_operator_or_the_failsafe() {
        let driven = status(11, false, OutputState::Ok, false);
        assert_eq!(
            owner_text(&driven),
            r#"{"vehicle":100,"owner":11,"failsafe":false}"#
        );
        let safe = status(100, true, OutputState::Ok, false);
        assert_eq!(
            owner_text(&safe),
            r#"{"vehicle":100,"owner":null,"failsafe":true}"#
        );
    }

    #[test]
    fn diagnostics_levels_follow_the_standing_and_the_output() {
        let level = |s: &VehicleStatus| diagnostic(s).level;
        assert_eq!(level(&status(11, false, OutputState::Ok, false)), 0);
        assert_eq!(level(&status(100, true, OutputState::Ok, false)), 1);
        assert_eq!(level(&status(11, false, OutputState::Ok, true)), 1);
        assert_eq!(level(&status(11, false, OutputState::Degraded, false)), 1);
        assert_eq!(level(&status(11, false, OutputState::Down, false)), 2);
        assert_eq!(level(&status(100, true, OutputState::Hung, false)), 2);
        let d = diagnostic(&status(11, false, OutputState::Ok, false));
        assert_eq!(d.message, "driven by 11; output ok");
        assert!(d.values.contains(&KeyValue {
            key: "battery_pct".into(),
            value: "20".into()
        }));
    }
}
