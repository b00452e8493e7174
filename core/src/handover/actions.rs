//! What the handover machine tells its operator role ([`Action`], with the consent [`Prompt`]
//! and how a request ended, [`Outcome`]) and why a local command was refused ([`Refusal`]).

use crate::msg::{DeviceId, RequestControl};
use crate::time::MonoTime;

/// How a request ended, as seen by one side.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Outcome {
    /// The owner accepted: the requester now drives with a priority writer.
    Accepted,
    /// The owner refused (a person, a busy replier, or one that does not own the vehicle).
    Refused,
    /// No answer in time (requester: reply timeout; replier: consent timeout → REFUSE sent).
    TimedOut,
    /// The requester withdrew (FINISH before an answer).
    Withdrawn,
}

impl Outcome {
    /// Lower-case name, as the local API spells it.
    pub fn as_str(self) -> &'static str {
        match self {
            Outcome::Accepted => "accepted",
            Outcome::Refused => "refused",
            Outcome::TimedOut => "timed_out",
            Outcome::Withdrawn => "withdrawn",
        }
    }
}

/// A request a person must decide: someone asks us for a vehicle we drive. One type for the
/// handover machine ([`Action::AskOperator`]), the session's report and the consoles.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Prompt {
    /// The vehicle.
    pub vehicle: DeviceId,
    /// Who asks.
    pub requester: DeviceId,
    /// Its priority.
    pub src_priority: i32,
    /// When the request is refused automatically (the consent timeout).
    pub deadline: MonoTime,
}

/// What the operator role must do.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Action {
    /// Publish this RequestControl sample.
    Send(RequestControl),
    /// Show the consent prompt: `requester` asks for `vehicle`; refused automatically at
    /// `deadline`.
    AskOperator(Prompt),
    /// Close the prompt for `vehicle`.
    PromptClosed {
        /// The vehicle.
        vehicle: DeviceId,
        /// How it ended.
        outcome: Outcome,
    },
    /// Our own request for `vehicle` ended.
    RequestEnded {
        /// The vehicle.
        vehicle: DeviceId,
        /// How it ended.
        outcome: Outcome,
    },
    /// Start driving `vehicle` with a priority writer (strength 65535): we hold the grant.
    StartPriorityDriving {
        /// The vehicle.
        vehicle: DeviceId,
    },
    /// Stop driving `vehicle` with the priority writer (we gave the grant back).
    StopPriorityDriving {
        /// The vehicle.
        vehicle: DeviceId,
    },
    /// Stop driving `vehicle`, without releasing: we gave it to a requester (module docs).
    /// Keep the regular stream alive with PROBE samples (standby) until [`Action::EndStandby`]
    /// or [`Action::Resume`]: the grant outranks us on the vehicle, and when it ends the vehicle
    /// falls back to us rather than to a weaker bystander.
    Yield {
        /// The vehicle.
        vehicle: DeviceId,
    },
    /// Stop the PROBE standby for `vehicle`: the holder never showed up on the vehicle, so we
    /// let the vehicle time us out; its next owner tells us the grant is void (we resume then).
    EndStandby {
        /// The vehicle.
        vehicle: DeviceId,
    },
    /// The grant on `vehicle` is over (FINISH, or seen on the vehicle): we drive it again.
    Resume {
        /// The vehicle.
        vehicle: DeviceId,
    },
}

/// Why a local command could not be carried out.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum Refusal {
    /// A request for this vehicle is already open or granted.
    #[error("a request for this vehicle is already open or granted")]
    AlreadyRequested,
    /// We own the vehicle already (or nobody does, so there is nobody to ask).
    #[error("no request needed: the owner is this operator or the vehicle's failsafe")]
    NothingToRequest,
    /// No open request or grant for this vehicle.
    #[error("no open request or grant for this vehicle")]
    NoRequest,
    /// No prompt is open for this vehicle.
    #[error("no consent prompt is open for this vehicle")]
    NoPrompt,
}
