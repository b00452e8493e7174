//! The traits the gateway drives: output adapters on vehicles, input sources on operators.
//!
//! Both are synchronous and non-blocking by contract; an implementation whose device API blocks
//! (a serial port, an evdev read) runs it on its own thread and exposes the latest state here.
//! Errors are [`LinkError`]s, already classified, so the caller's policy is uniform: a transient
//! failure puts the vehicle in failsafe and is retried, a fatal one is reported and not retried.

use crate::arbiter::Setpoint;
use crate::error::LinkError;
use crate::msg::{Mode, MovementCommand};
use crate::time::MonoTime;
use std::fmt;
use std::path::PathBuf;
use std::time::Duration;

/// Health of an output link or input device, for status displays.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub enum Health {
    /// Working.
    #[default]
    Ok,
    /// Working with problems (retries, dropped frames); the text says which.
    Degraded(String),
    /// Not working; the text says why. The vehicle is in failsafe while an output is down.
    Down(String),
}

impl fmt::Display for Health {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Health::Ok => f.write_str("ok"),
            Health::Degraded(why) => write!(f, "degraded: {why}"),
            Health::Down(why) => write!(f, "down: {why}"),
        }
    }
}

/// What an output adapter crate exports so that the gateway offers it with one line of its
/// list (docs/design.md, "Adding an output adapter"): the name `[output] adapter` spells, the
/// adapter's other `[output]` keys, and how they validate into an [`OutputSpec`]. The gateway
/// knows nothing else of an adapter.
pub trait OutputKind {
    /// `[output] adapter = "NAME"`.
    const NAME: &'static str;
    /// One line for the reference of adapters (`rove check-config --adapters`).
    const SUMMARY: &'static str;
    /// The adapter's `[output]` keys as written; unknown keys are rejected by serde, and the
    /// effective config is these settings written back.
    type Settings: serde::Serialize
        + serde::de::DeserializeOwned
        + fmt::Debug
        + Clone
        + Send
        + Sync
        + 'static;
    /// Checks `settings`, filling every default in place (so the effective config shows it).
    ///
    /// # Errors
    /// [`crate::Error::Config`] listing every invalid key, named as `output.<key>`.
    fn validate(settings: &mut Self::Settings) -> crate::Result<Box<dyn OutputSpec>>;
}

/// A validated `[output]`: everything the gateway does with an adapter it otherwise knows
/// nothing about.
pub trait OutputSpec: fmt::Debug + Send + Sync {
    /// Opens the device; the adapter writes its safe state before returning.
    ///
    /// # Errors
    /// The device cannot be opened (a [`crate::error::Disposition::Fatal`] error ends the
    /// start: the configuration must change), or the safe state cannot be written.
    fn open(&self, now: MonoTime) -> Result<Box<dyn OutputAdapter>, LinkError>;

    /// `rove failsafe` (systemd's `ExecStopPost`): opens the device, which writes the safe
    /// state, writes it once more and closes it (adapters write it again on drop). Returns
    /// what was made safe. An adapter whose device must be found or answer first overrides it.
    ///
    /// # Errors
    /// The device cannot be opened or written.
    fn failsafe(&self) -> Result<String, LinkError> {
        let mut adapter = self.open(MonoTime::ZERO)?;
        adapter.safe_state(MonoTime::ZERO)?;
        Ok(adapter.describe())
    }

    /// What the adapter needs of the computer, for `rove doctor`.
    fn needs(&self) -> Vec<Need> {
        Vec::new()
    }

    /// Gives an adapter that asks for [`Need::Memory`] the file to keep it in.
    fn remember_in(&mut self, _file: PathBuf) {}

    /// A copy (a vehicle's config is cloned into its output thread).
    fn clone_spec(&self) -> Box<dyn OutputSpec>;

    /// The operators the adapter hosts (a MAVLink vehicle's ground stations), each with the
    /// handle it shares with the adapter; a copy of the spec shares the same handles.
    fn hosted(&self) -> Vec<HostedOperator> {
        Vec::new()
    }
}

/// An operator an output adapter hosts: a ground station on a MAVLink link (docs/design.md,
/// "Ground stations"). The gateway runs an operator loop for it in the vehicle's process, a
/// participant of its own, as it does for a web console's device.
#[derive(Debug, Clone)]
pub struct HostedOperator {
    /// Its device id.
    pub id: crate::msg::DeviceId,
    /// Its name.
    pub name: String,
    /// Its level in the hierarchy.
    pub level: crate::hierarchy::Level,
    /// Its device class.
    pub class: crate::hierarchy::DeviceClass,
    /// Its DDS Security files (a secured fleet), as `[security]` names them.
    pub security: Option<PathBuf>,
    /// What it does, and where the hierarchy's answers go.
    pub link: std::sync::Arc<dyn HostedLink>,
}

/// What a hosted operator did, as its adapter heard it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum HostedEvent {
    /// Its sticks (taken as of when its loop takes them: it does so as they come).
    Sticks(MovementCommand),
    /// It said it is there (a MAVLink HEARTBEAT).
    Alive(std::time::Instant),
    /// It asks for control of the vehicle.
    Request,
    /// It gives control back.
    Release,
}

/// The handle a hosted operator's loop and its adapter share (both sides may run on threads of
/// their own).
pub trait HostedLink: Send + Sync + fmt::Debug {
    /// One line for the log.
    fn describe(&self) -> String;
    /// What it did since the last call, oldest first (bounded: a loop that stops taking loses
    /// the oldest sticks first).
    fn take(&self) -> Vec<HostedEvent>;
    /// Calls `waker` whenever something arrives.
    fn set_waker(&self, waker: std::sync::Arc<dyn Fn() + Send + Sync>);
    /// The hierarchy's answer to its last request: it may drive (`true`) or not.
    fn answered(&self, granted: bool);
    /// Whether it holds control now (a grant, or it drives the vehicle).
    fn holds(&self, control: bool);
}

impl Clone for Box<dyn OutputSpec> {
    fn clone(&self) -> Self {
        self.clone_spec()
    }
}

/// Something of the computer an output needs: `rove doctor` checks each.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Need {
    /// A Raspberry Pi's GPIO and PWM registers (rppal): a Pi and `/dev/gpiochip*`.
    RaspberryPi,
    /// A channel of the kernel's PWM class, `root/pwmchip<chip>/pwm<channel>`.
    PwmChannel {
        /// The channel's name in the config.
        name: String,
        /// The class directory (`/sys/class/pwm`, or a test tree).
        root: PathBuf,
        /// The chip number.
        chip: u32,
        /// The channel on the chip.
        channel: u32,
    },
    /// A serial port (`/dev/ttyACM0`).
    Serial(String),
    /// A CAN network interface (`can0`).
    Can(String),
    /// A file in the runtime directory where the adapter keeps what it learns of its device,
    /// so that `rove failsafe` reaches the device at once ([`OutputSpec::remember_in`]).
    Memory,
}

/// A vehicle's output: turns setpoints into actuator signals.
///
/// Implementations also drive the safe state from `Drop`, so that a gateway that unwinds or
/// returns early never leaves servos driving.
pub trait OutputAdapter {
    /// A one-line description for the start-up log (kind and device).
    fn describe(&self) -> String;

    /// Drives the actuators with `setpoint`.
    ///
    /// # Errors
    /// A classified [`LinkError`] naming the device when the write failed.
    fn apply(&mut self, now: MonoTime, setpoint: &Setpoint) -> Result<(), LinkError>;

    /// Puts the actuators in their safe state: UGV stopped, multirotor hovering, autopilot
    /// overrides released. Bypasses any slew limit.
    ///
    /// # Errors
    /// A classified [`LinkError`] naming the device when the write failed.
    fn safe_state(&mut self, now: MonoTime) -> Result<(), LinkError>;

    /// How often [`OutputAdapter::keepalive`] must run while driving, for devices that time
    /// out a held value (autopilot RC overrides, CAN servos). `None`: the device holds its value.
    fn keepalive_period(&self) -> Option<Duration> {
        None
    }

    /// Re-sends the last output (see [`OutputAdapter::keepalive_period`]).
    ///
    /// # Errors
    /// As [`OutputAdapter::apply`].
    fn keepalive(&mut self, _now: MonoTime) -> Result<(), LinkError> {
        Ok(())
    }

    /// Current health of the link.
    fn health(&self) -> Health;

    /// What the device reports about itself, for status lines (an autopilot's mode and armed
    /// state); `None` when there is nothing beyond [`OutputAdapter::health`].
    fn detail(&self) -> Option<String> {
        None
    }

    /// Whether the adapter holds the outputs in their safe state by its own decision while the
    /// arbiter has an owner: an autopilot refused the operator's mode and the adapter stopped
    /// (MAVLink `on_mode_refused = "hold"`). Status then says failsafe, as the outputs are.
    fn held_safe(&self) -> bool {
        false
    }

    /// What the vehicle says of itself, on every change of its VehicleStatus (owner,
    /// failsafe, output state, battery): an adapter whose device has a world of its own to
    /// tell (ROS 2's who-drives topic and `/diagnostics`) shows it there. An error here is
    /// reported, never a reason to hold the outputs safe.
    ///
    /// # Errors
    /// The device did not take it.
    fn status(
        &mut self,
        _now: MonoTime,
        _status: &crate::msg::VehicleStatus,
    ) -> Result<(), LinkError> {
        Ok(())
    }

    /// What the device reports about the vehicle (an autopilot's battery, mode, armed state and
    /// how long ago it was heard); the default knows nothing.
    fn telemetry(&self) -> Telemetry {
        Telemetry::default()
    }
}

/// What an output's device says about the vehicle, each part `None` when it cannot tell.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct Telemetry {
    /// Battery voltage, millivolts.
    pub battery_mv: Option<u32>,
    /// Battery remaining, percent (0–100).
    pub battery_pct: Option<u8>,
    /// The autopilot's mode, by name.
    pub autopilot_mode: Option<String>,
    /// The autopilot says it is armed.
    pub armed: Option<bool>,
    /// How long ago the autopilot was last heard.
    pub link_age: Option<Duration>,
}

/// Operator actions bound to buttons or keys.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum InputAction {
    /// Switch the driven vehicle's mode.
    Mode(Mode),
    /// Ask the selected vehicle's owner for control (REQUEST).
    RequestControl,
    /// Accept an incoming request.
    Accept,
    /// Refuse an incoming request.
    Refuse,
    /// Give a grant back (FINISH).
    Finish,
    /// Stop driving the selected vehicle (explicit release).
    Release,
    /// Select the next vehicle.
    NextVehicle,
    /// Select the previous vehicle.
    PreviousVehicle,
}

/// Something an input source reports.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum InputEvent {
    /// New stick values (already mapped: deadzone, expo, invert applied).
    Axes(MovementCommand),
    /// The deadman control was pressed (`true`) or let go (`false`).
    Deadman(bool),
    /// An action button or key.
    Action(InputAction),
    /// The device is gone or its state can no longer be trusted (unplugged, SYN_DROPPED, silent):
    /// the operator must stop driving and release at once.
    Lost {
        /// Why, naming the device.
        reason: String,
    },
}

/// An operator's input device.
pub trait InputSource {
    /// A one-line description for the start-up log.
    fn describe(&self) -> String;

    /// The next event due at or before `now`, if any; never blocks.
    ///
    /// # Errors
    /// A classified [`LinkError`] when the device failed.
    fn poll(&mut self, now: MonoTime) -> Result<Option<InputEvent>, LinkError>;

    /// When the source next has an event without outside input (scripts, key ramps), so the
    /// caller can sleep until then.
    fn next_deadline(&self) -> Option<MonoTime> {
        None
    }
}
