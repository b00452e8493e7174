//! [`Command`]: the one interface through which the console's keys, joystick buttons and API
//! clients ask the operator role to act.

use tokio::sync::oneshot;

pub use rove_core::session::Command;

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
    /// A browser paired through `[web]`, speaking for this device id.
    Web(rove_core::msg::DeviceId),
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
