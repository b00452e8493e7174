//! [`Command`]: the one interface through which the console's keys, joystick buttons and API
//! clients ask the operator role to act.

use rove_core::msg::{DeviceId, Mode};
use tokio::sync::oneshot;

/// What a front end asks the operator to do. The operator carries it out (or refuses it) and
/// answers with a [`CommandResult`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Command {
    /// Make `vehicle` the one that buttons act on. Moves nothing.
    Select {
        /// The vehicle.
        vehicle: DeviceId,
    },
    /// Start driving `vehicle` (it must be free: its failsafe or this operator owns it).
    Drive {
        /// The vehicle.
        vehicle: DeviceId,
    },
    /// Stop driving (explicit release; a held grant is finished). `None`: every vehicle.
    Release {
        /// The vehicle, or `None` for all.
        vehicle: Option<DeviceId>,
    },
    /// Ask the owner of `vehicle` for control (REQUEST).
    Request {
        /// The vehicle.
        vehicle: DeviceId,
    },
    /// Accept the open request for `vehicle` (ACCEPT): the requester drives it.
    Accept {
        /// The vehicle.
        vehicle: DeviceId,
    },
    /// Refuse the open request for `vehicle` (REFUSE).
    Refuse {
        /// The vehicle.
        vehicle: DeviceId,
    },
    /// Give back the grant held for `vehicle` (FINISH).
    Finish {
        /// The vehicle.
        vehicle: DeviceId,
    },
    /// Send `mode`. `None`: to every vehicle this operator drives (the operator has one mode).
    Mode {
        /// The vehicle, or `None` for all driven ones.
        vehicle: Option<DeviceId>,
        /// The mode.
        mode: Mode,
    },
}

impl Command {
    /// The command's name as the API spells it (`"drive"`, `"release"`, …).
    pub fn name(&self) -> &'static str {
        match self {
            Command::Select { .. } => "select",
            Command::Drive { .. } => "drive",
            Command::Release { .. } => "release",
            Command::Request { .. } => "request",
            Command::Accept { .. } => "accept",
            Command::Refuse { .. } => "refuse",
            Command::Finish { .. } => "finish",
            Command::Mode { .. } => "mode",
        }
    }
}

/// The operator's answer to a command: done, or why not (shown to the person, sent to the
/// API client as `{"error": …}`).
pub type CommandResult = Result<(), String>;

/// Where a command came from, for the operator's log.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Source {
    /// The terminal console (keys or joystick buttons).
    Console,
    /// An API client; the number counts connections since the server started.
    Api(u64),
}

/// A command on its way to the operator, with the channel for its answer.
#[derive(Debug)]
pub struct CommandRequest {
    /// What to do.
    pub command: Command,
    /// Who asked.
    pub source: Source,
    /// Send exactly one answer here. Dropping it unanswered tells the asker
    /// "operator gone".
    pub reply: oneshot::Sender<CommandResult>,
}
