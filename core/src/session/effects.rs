//! What one step answers: [`Effect`]s for the operator loop, among them [`Report`]s for the
//! log and the console.

use crate::adapter::InputAction;
use crate::arbiter::{Event as ArbiterEvent, ParticipantId, WriterId};
use crate::handover::{Outcome, Prompt};
use crate::hierarchy::Strength;
use crate::msg::{ControlCommand, DeviceId, Mode, RequestControl};
use crate::time::MonoTime;
use crate::trust::Suspect;
use std::fmt;

/// Which of the operator's two ControlCommand writers.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Writer {
    /// The regular writer, at the hierarchy's strength.
    Regular,
    /// The priority writer (strength 65535), for vehicles we hold a grant for.
    Priority,
}

impl Writer {
    /// The stream's identity when the session's effects go straight to an arbiter, as in the
    /// in-process demo and the tests: writer 1 (regular) or 2 (priority) of `participant`.
    /// Over DDS the binding derives writer ids from GUIDs instead.
    pub fn id(self, participant: ParticipantId) -> WriterId {
        WriterId {
            participant,
            entity: match self {
                Writer::Regular => 1,
                Writer::Priority => 2,
            },
        }
    }
}

/// What the operator loop must do.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Effect {
    /// Write this ControlCommand sample with `writer`.
    Write {
        /// Which writer.
        writer: Writer,
        /// The sample.
        command: ControlCommand,
    },
    /// Release `vehicle`'s instance on `writer` (dispose): the vehicle hands over at once.
    Release {
        /// Which writer.
        writer: Writer,
        /// The vehicle (the instance key).
        vehicle: DeviceId,
    },
    /// Publish this RequestControl sample.
    Send(RequestControl),
    /// Tell the log and the console.
    Report(Report),
    /// A button was pressed while a console runs: the console confirms it and sends the
    /// command back.
    Confirm(InputAction),
    /// The command in this step was not carried out, and why (for the person or API client).
    Refused(String),
}

impl Effect {
    /// What this effect, delivered straight to `vehicle`'s arbiter at `arrival`, means to it:
    /// a sample or a release of one of `participant`'s writers (the regular one at
    /// `strength`, the priority one at [`Strength::PRIORITY`]), or a grant event for a
    /// RequestControl ([`ArbiterEvent::from_request_control`]). For the in-process demo and
    /// the tests; the operator loop carries effects out over DDS instead.
    pub fn arbiter_event(
        &self,
        vehicle: DeviceId,
        participant: ParticipantId,
        strength: Strength,
        arrival: MonoTime,
    ) -> Option<ArbiterEvent> {
        match self {
            Effect::Write { writer, command } => Some(ArbiterEvent::Sample {
                writer: writer.id(participant),
                strength: match writer {
                    Writer::Regular => strength,
                    Writer::Priority => Strength::PRIORITY,
                },
                command: *command,
                arrival,
            }),
            // A release is per instance: another vehicle's means nothing here.
            Effect::Release { writer, vehicle: v } if *v == vehicle => {
                Some(ArbiterEvent::Released {
                    writer: writer.id(participant),
                })
            }
            Effect::Send(msg) => Some(ArbiterEvent::from_request_control(
                vehicle,
                msg,
                participant,
            )),
            Effect::Release { .. }
            | Effect::Report(_)
            | Effect::Confirm(_)
            | Effect::Refused(_) => None,
        }
    }
}

/// Something worth telling the operator's log and console.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Report {
    /// The input became live: the paused vehicles are driven again.
    InputLive {
        /// Vehicles driven again.
        vehicles: Vec<DeviceId>,
    },
    /// The input cannot be trusted (lost, deadman let go): everything driven was released.
    InputNotLive {
        /// Why.
        reason: String,
        /// Vehicles released (driven again when the input is live).
        vehicles: Vec<DeviceId>,
    },
    /// Buttons now act on this vehicle.
    Selected {
        /// The vehicle, if any.
        vehicle: Option<DeviceId>,
    },
    /// The operator's mode changed.
    ModeSelected {
        /// The mode.
        mode: Mode,
    },
    /// We drive this vehicle now (a free vehicle, on a command or on `--request`).
    Driving {
        /// The vehicle.
        vehicle: DeviceId,
        /// Why.
        why: DriveReason,
    },
    /// The operator released this vehicle.
    Released {
        /// The vehicle.
        vehicle: DeviceId,
    },
    /// A REQUEST went out to `owner` for `vehicle`.
    RequestSent {
        /// The vehicle.
        vehicle: DeviceId,
        /// Its owner.
        owner: DeviceId,
    },
    /// A request could not be made.
    RequestFailed {
        /// The vehicle.
        vehicle: DeviceId,
        /// Its owner.
        owner: DeviceId,
        /// Why.
        reason: String,
    },
    /// Someone asks us for a vehicle we own and a person must decide.
    Prompt(Prompt),
    /// The consent prompt for `vehicle` closed.
    PromptClosed {
        /// The vehicle.
        vehicle: DeviceId,
        /// How.
        outcome: Outcome,
    },
    /// A message was not believed (its id belongs to another participant): a spoofing attempt
    /// or a misconfigured duplicate id.
    Untrusted(Suspect),
    /// A REQUEST for a vehicle we do not drive (or whose DeviceInfo does not name us) got no
    /// answer: only the owner answers.
    RequestIgnored {
        /// The vehicle.
        vehicle: DeviceId,
        /// Who asked.
        requester: DeviceId,
    },
    /// Our own request for `vehicle` ended.
    RequestEnded {
        /// The vehicle.
        vehicle: DeviceId,
        /// How.
        outcome: Outcome,
    },
    /// We hold a grant for `vehicle` and drive it with the priority writer.
    GrantStarted {
        /// The vehicle.
        vehicle: DeviceId,
    },
    /// We gave the grant for `vehicle` back.
    GrantEnded {
        /// The vehicle.
        vehicle: DeviceId,
    },
    /// We yielded `vehicle` to a grant holder and stand by (PROBEs).
    Yielded {
        /// The vehicle.
        vehicle: DeviceId,
    },
    /// The grant holder never took over: the standby stops.
    StandbyEnded {
        /// The vehicle.
        vehicle: DeviceId,
    },
    /// The grant on `vehicle` is over: we drive it again (at once if the input is live).
    Resumed {
        /// The vehicle.
        vehicle: DeviceId,
        /// The input is live, so samples go out now.
        live: bool,
    },
}

/// Why the session started driving a vehicle.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DriveReason {
    /// A `drive` command for a free vehicle.
    Commanded,
    /// `--request` found the vehicle free.
    Free,
    /// `--request` found we already drive it.
    AlreadyOurs,
}

impl Report {
    /// Whether the log shows it as a warning.
    pub fn is_warning(&self) -> bool {
        matches!(
            self,
            Report::InputNotLive { .. } | Report::RequestFailed { .. } | Report::Untrusted(_)
        )
    }

    /// The vehicle it concerns, if one.
    pub fn vehicle(&self) -> Option<DeviceId> {
        match self {
            Report::InputLive { .. }
            | Report::InputNotLive { .. }
            | Report::ModeSelected { .. }
            | Report::Untrusted(_) => None,
            Report::RequestIgnored { vehicle, .. } => Some(*vehicle),
            Report::Selected { vehicle } => *vehicle,
            Report::Driving { vehicle, .. }
            | Report::Released { vehicle }
            | Report::RequestSent { vehicle, .. }
            | Report::RequestFailed { vehicle, .. }
            | Report::Prompt(Prompt { vehicle, .. })
            | Report::PromptClosed { vehicle, .. }
            | Report::RequestEnded { vehicle, .. }
            | Report::GrantStarted { vehicle }
            | Report::GrantEnded { vehicle }
            | Report::Yielded { vehicle }
            | Report::StandbyEnded { vehicle }
            | Report::Resumed { vehicle, .. } => Some(*vehicle),
        }
    }
}

impl fmt::Display for Report {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Report::InputLive { vehicles } => write!(f, "input live: driving {vehicles:?}"),
            Report::InputNotLive { reason, vehicles } => write!(
                f,
                "input not live: releasing control of {vehicles:?} ({reason}) until it is live"
            ),
            Report::Selected { vehicle: Some(v) } => write!(f, "vehicle {v} selected"),
            Report::Selected { vehicle: None } => write!(f, "no vehicle selected"),
            Report::ModeSelected { mode } => write!(f, "mode {mode:?} selected"),
            Report::Driving { vehicle, why } => match why {
                DriveReason::Commanded => write!(f, "driving vehicle {vehicle}"),
                DriveReason::Free => {
                    write!(
                        f,
                        "vehicle {vehicle} is free: driving it, no request needed"
                    )
                }
                DriveReason::AlreadyOurs => {
                    write!(f, "already driving vehicle {vehicle}: no request needed")
                }
            },
            Report::Released { vehicle } => write!(f, "vehicle {vehicle} released by the operator"),
            Report::RequestSent { vehicle, owner } => {
                write!(f, "requesting control of vehicle {vehicle} from {owner}")
            }
            Report::RequestFailed {
                vehicle,
                owner,
                reason,
            } => write!(f, "cannot request vehicle {vehicle} from {owner}: {reason}"),
            Report::Prompt(Prompt {
                vehicle,
                requester,
                src_priority,
                ..
            }) => write!(
                f,
                "{requester} (priority {src_priority}) requests vehicle {vehicle}: consent needed \
                 (accept / refuse; refused at the timeout)"
            ),
            Report::PromptClosed { vehicle, outcome } => {
                write!(
                    f,
                    "consent prompt for vehicle {vehicle} closed: {outcome:?}"
                )
            }
            Report::Untrusted(suspect) => write!(f, "not believed: {suspect}"),
            Report::RequestIgnored { vehicle, requester } => write!(
                f,
                "{requester} requests vehicle {vehicle}, which we do not drive: not answered"
            ),
            Report::RequestEnded { vehicle, outcome } => {
                write!(f, "request ended: {outcome:?} (vehicle {vehicle})")
            }
            Report::GrantStarted { vehicle } => write!(
                f,
                "grant for vehicle {vehicle} received: driving with the priority writer"
            ),
            Report::GrantEnded { vehicle } => write!(f, "grant for vehicle {vehicle} given back"),
            Report::Yielded { vehicle } => write!(
                f,
                "yielding vehicle {vehicle} to the grant holder (standing by)"
            ),
            Report::StandbyEnded { vehicle } => write!(
                f,
                "grant holder never took over vehicle {vehicle}: standby ends"
            ),
            Report::Resumed {
                vehicle,
                live: true,
            } => write!(f, "grant on vehicle {vehicle} over: driving again"),
            Report::Resumed {
                vehicle,
                live: false,
            } => write!(
                f,
                "grant on vehicle {vehicle} over: driving again once the input is live"
            ),
        }
    }
}
