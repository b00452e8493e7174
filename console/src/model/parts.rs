//! What the console state is made of: who we are ([`Identity`]), the devices and what is known
//! of each vehicle ([`Device`], [`VehicleView`]), our role with each ([`MyRole`]), the input
//! ([`InputStatus`]), log lines, open requests and the confirmation prompt.

use rove_core::MonoTime;
use rove_core::hierarchy::{DeviceClass, Level, Strength};
use rove_core::msg::{DeviceId, DeviceType, Mode, MovementCommand, OutputState, VehicleHealth};

/// Who this operator is (from its config).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Identity {
    /// Device id.
    pub id: DeviceId,
    /// Name.
    pub name: String,
    /// Hierarchy level.
    pub level: Level,
    /// Device class.
    pub class: DeviceClass,
    /// Ownership strength of its regular writer.
    pub strength: Strength,
}

/// Vehicle or controller.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum DeviceKind {
    /// Runs `rove vehicle`.
    Vehicle,
    /// Runs `rove operator`.
    Controller,
}

impl DeviceKind {
    /// `"vehicle"` or `"controller"`, as `rove status` and the API spell it.
    pub fn as_str(self) -> &'static str {
        match self {
            DeviceKind::Vehicle => "vehicle",
            DeviceKind::Controller => "controller",
        }
    }
}

impl From<DeviceType> for DeviceKind {
    fn from(t: DeviceType) -> Self {
        match t {
            DeviceType::Vehicle => DeviceKind::Vehicle,
            DeviceType::Controller => DeviceKind::Controller,
        }
    }
}

/// What this operator does with a vehicle (the operator's own streams).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum MyRole {
    /// Driving it with the regular writer.
    Driving,
    /// Driving it with the priority writer: we hold a grant.
    Holding,
    /// Yielded to a grant holder; keep-alive PROBEs keep us its fallback.
    Standby,
    /// Would drive it, but the input is not live (deadman released, device lost).
    Paused,
}

/// The input device as the operator sees it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct InputStatus {
    /// Latest stick values (mapped).
    pub movement: MovementCommand,
    /// The mode this operator sends.
    pub mode: Mode,
    /// Deadman held (`Some(true)`), let go (`Some(false)`), or no deadman configured (`None`).
    pub deadman: Option<bool>,
    /// The input may drive (constant input: always; a device: live and deadman held).
    pub live: bool,
    /// The device and its state, e.g. `"evdev /dev/input/event3: ok"` or why it was lost.
    pub link: String,
}

impl Default for InputStatus {
    fn default() -> Self {
        InputStatus {
            movement: MovementCommand::CENTRED,
            mode: Mode::Manual,
            deadman: None,
            live: false,
            link: "no input yet".into(),
        }
    }
}

/// A device in the list.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Device {
    /// Device id.
    pub id: DeviceId,
    /// Name.
    pub name: String,
    /// Vehicle or controller.
    pub kind: DeviceKind,
    /// Announced within [`ConsoleState::offline_after`](super::ConsoleState::offline_after)
    /// and not withdrawn.
    pub online: bool,
    /// When its last DeviceInfo arrived.
    pub last_seen: MonoTime,
    /// Vehicles only: owner, mode, failsafe, link.
    pub vehicle: Option<VehicleView>,
}

/// What is known about a vehicle.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct VehicleView {
    /// Its published owner (`controller_id`); its own id = failsafe.
    pub owner: DeviceId,
    /// Mode, if a status report gave one.
    pub mode: Option<Mode>,
    /// A status report says its outputs are in the safe state (believed for `status_owner`'s
    /// time only: [`crate::standing::standing`]).
    pub failsafe: bool,
    /// Output-link health, if a status report gave it.
    pub link: Option<String>,
    /// The owner the last status report was published under: its `failsafe` describes that
    /// owner's time (DeviceInfo and VehicleStatus are two topics and arrive in either order).
    pub status_owner: Option<DeviceId>,
    /// The output's state, if a status report gave it.
    pub output: Option<OutputState>,
    /// What its device says of the vehicle (unknown until a status report says).
    pub health: VehicleHealth,
}

impl VehicleView {
    /// A vehicle whose DeviceInfo names `owner`, before any status report.
    pub fn new(owner: DeviceId) -> VehicleView {
        VehicleView {
            owner,
            mode: None,
            failsafe: false,
            link: None,
            status_owner: None,
            output: None,
            health: VehicleHealth::UNKNOWN,
        }
    }
}

/// One log line: an ownership change or a notice.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LogEntry {
    /// When it was logged.
    pub at: MonoTime,
    /// What.
    pub what: Logged,
}

/// The content of a [`LogEntry`].
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Logged {
    /// The owner of `vehicle` changed.
    Owner {
        /// The vehicle.
        vehicle: DeviceId,
        /// Previous owner.
        from: DeviceId,
        /// New owner.
        to: DeviceId,
        /// Why.
        reason: String,
    },
    /// Anything else worth a line (requests, refusals, notices).
    Note(String),
}

/// A request for one of our vehicles, waiting for our answer.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct IncomingRequest {
    /// The vehicle.
    pub vehicle: DeviceId,
    /// The requester.
    pub from: DeviceId,
    /// Its priority.
    pub src_priority: i32,
    /// When it is refused automatically.
    pub deadline: MonoTime,
    /// When the prompt opened (accept is ignored for [`crate::keys::ACCEPT_GUARD`] after).
    pub opened: MonoTime,
}

/// Our own request for a vehicle, waiting for the owner's answer.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct OutgoingRequest {
    /// The owner asked.
    pub owner: DeviceId,
    /// When we asked.
    pub since: MonoTime,
}

/// A command that waits for the operator to confirm it on screen.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Confirmation {
    /// What runs on "yes".
    pub command: crate::Command,
    /// The question, naming the target, e.g. `"Drive rover-1 (100)?"`.
    pub question: String,
    /// When it opened; it closes by itself after [`CONFIRM_TIMEOUT`](super::CONFIRM_TIMEOUT).
    pub opened: MonoTime,
}
