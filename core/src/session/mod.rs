//! The operator's session: every decision `rove operator` makes, with no I/O.
//!
//! Like the [`Arbiter`](crate::arbiter::Arbiter) on the vehicle, the session is a state machine
//! stepped with `now` and one [`SessionEvent`] — an input event, a DeviceInfo or RequestControl
//! sample, a command from the console, the local API or a button, a keep-alive tick, a timer —
//! and it answers with [`Effect`]s: ControlCommand samples to write or instances to release
//! (dispose), RequestControl samples to send, reports for the log and the console. The gateway's
//! operator loop only moves events in and effects out, and the in-process demo drives the same
//! session.
//!
//! What the session decides:
//! - **Streaming.** Every driven vehicle gets a sample on every input change
//!   ([`SessionEvent::Input`] with new sticks) and on every [`SessionEvent::StreamTick`]
//!   (keep-alive). Vehicles held by a grant get theirs on the priority writer; vehicles yielded
//!   to a grant holder get PROBEs on the regular writer (standby).
//! - **Input liveness.** Constant sticks drive the configured vehicles from the start. A device
//!   drives only while it is live: a lost device or a released deadman releases every vehicle
//!   explicitly and finishes every grant, so the hierarchy hands over at once; driving resumes on
//!   the device's next stick report (the input layer holds that back until the sticks are
//!   centred, so nothing jumps).
//! - **Active handover** through [`Handover`]: requests, consent (auto-accept policy, or a
//!   person through [`Command::Accept`] / [`Command::Refuse`]), grants and FINISH.
//! - **Request when seen** (`rove operator --request V`): the request goes out once the
//!   vehicle's owner is known from a live DeviceInfo; a vehicle that still looks ownerless two
//!   heartbeats after start is free and simply driven.
//! - **Stop**: [`OperatorSession::stop`] finishes held grants and releases every instance.
//! - **Trust** (docs/design.md §4b): every DeviceInfo and RequestControl comes with its sender's
//!   participant, and counts only if that participant is the one pinned for the id it claims
//!   ([`Identities`]); others are reported ([`Report::Untrusted`]). A REQUEST is answered only
//!   for a vehicle we drive and whose DeviceInfo names us; auto-accept believes `src_priority`
//!   only when a ControlCommand writer of the requester's participant has that strength; a
//!   FINISH or a DeviceInfo resumes only a vehicle we yielded.

use crate::adapter::{InputAction, InputEvent};
use crate::arbiter::{Event as ArbiterEvent, ParticipantId, WriterId};
use crate::handover::{Action, Handover, HandoverConfig, Outcome, Prompt};
use crate::hierarchy::Strength;
use crate::msg::{
    CommandType, ControlCommand, DeviceId, DeviceInfo, DeviceType, Mode, MovementCommand,
    RequestControl, TimeT,
};
use crate::time::MonoTime;
use crate::trust::{Identities, Suspect, TrustConfig};
use std::collections::{BTreeMap, BTreeSet};
use std::fmt;
use std::time::Duration;

/// What a front end (the console's keys, joystick buttons, an API client) asks the operator to
/// do: the single path by which a person changes what the operator does.
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
    /// The command's name as the local API spells it (`"drive"`, `"release"`, …).
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

/// Where the operator's sticks come from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SessionInput {
    /// Fixed sticks and mode from the config: always live.
    Constant(MovementCommand, Mode),
    /// A device or a recording: live once it reports sticks, until it is lost or its deadman
    /// is let go.
    Device,
}

/// The session's settings, from the operator's config and command line.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SessionConfig {
    /// Our device id.
    pub me: DeviceId,
    /// Our regular writer's strength (the hierarchy's).
    pub strength: Strength,
    /// Active handover timing and policy.
    pub handover: HandoverConfig,
    /// The vehicles to drive from the start (`drive` in the config).
    pub drive: Vec<DeviceId>,
    /// The input.
    pub input: SessionInput,
    /// The DeviceInfo heartbeat period. A late joiner's first DeviceInfo may be an old sample
    /// (DDS replays writer history on match), so the request-when-seen logic trusts only what
    /// arrives a heartbeat after start, and calls a vehicle free only after two.
    pub heartbeat: Duration,
    /// Buttons go to a console, which confirms them and sends the command back, instead of
    /// acting at once.
    pub confirm_actions: bool,
    /// Ask this vehicle's owner for control as soon as the owner is known (`--request`).
    pub request: Option<DeviceId>,
    /// Our own participant: our id is pinned to it.
    pub participant: ParticipantId,
    /// How long other devices' ids stay pinned to their participants.
    pub trust: TrustConfig,
}

/// An event the session acts on.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum SessionEvent {
    /// Something the input device reported.
    Input(InputEvent),
    /// A DeviceInfo sample (any device), from participant `from`.
    DeviceInfo {
        /// The sample.
        info: DeviceInfo,
        /// Its sender.
        from: ParticipantId,
    },
    /// A RequestControl sample, from participant `from`.
    RequestControl {
        /// The sample.
        msg: RequestControl,
        /// Its sender.
        from: ParticipantId,
    },
    /// Discovery found a ControlCommand writer (`strength` is its ownership strength).
    WriterFound {
        /// The writer.
        writer: WriterId,
        /// Its strength.
        strength: Strength,
    },
    /// A ControlCommand writer left.
    WriterLost {
        /// The writer.
        writer: WriterId,
    },
    /// A participant left the domain.
    ParticipantGone {
        /// The participant.
        participant: ParticipantId,
    },
    /// A command from the console, the local API or a confirmed button.
    Command(Command),
    /// The keep-alive period passed: stream to everything we drive or stand by for.
    StreamTick,
    /// Time passed: the handover's resends and timeouts ([`OperatorSession::next_deadline`]).
    Tick,
}

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

/// What the operator streams to, as the console shows it ("you drive").
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Streams {
    /// Driven with the regular writer.
    pub driving: Vec<DeviceId>,
    /// Driven with the priority writer (grants held).
    pub holding: Vec<DeviceId>,
    /// Yielded to a grant holder (PROBEs on the regular writer).
    pub standby: Vec<DeviceId>,
    /// Waiting for live input.
    pub paused: Vec<DeviceId>,
}

/// One operator's session. See the module docs.
#[derive(Debug, Clone)]
pub struct OperatorSession {
    me: DeviceId,
    handover: Handover,
    confirm_actions: bool,
    movement: MovementCommand,
    mode: Mode,
    /// The input may drive (constant input: always; a device: live and deadman held).
    input_live: bool,
    /// Vehicles driven with the regular writer.
    driving: BTreeSet<DeviceId>,
    /// Vehicles released while the input is not live; driven again when it is.
    paused: BTreeSet<DeviceId>,
    /// Vehicles driven with the priority writer (grants held).
    priority: BTreeSet<DeviceId>,
    /// Vehicles yielded to a grant holder: PROBEs on the regular writer keep us the vehicle's
    /// fallback, so it returns to us (not to a bystander) when the grant ends.
    standby: BTreeSet<DeviceId>,
    /// The vehicle that buttons act on.
    selected: Option<DeviceId>,
    /// The vehicle whose control request waits for our answer.
    prompt: Option<DeviceId>,
    /// The last DeviceInfo of every vehicle seen.
    vehicles: BTreeMap<DeviceId, DeviceInfo>,
    /// `--request`: the vehicle, and when it counts as free if it still looks ownerless.
    pending_request: Option<(DeviceId, MonoTime)>,
    /// DeviceInfo arriving before this may be history replay: no request decided on it.
    ask_after: MonoTime,
    /// When the `--request` vehicle's first DeviceInfo arrived: a joiner may get the writer's
    /// history (older owners) in one burst, late when discovery is slow (DDS Security's
    /// handshake takes over a second), so the decision waits one heartbeat more, for a live
    /// sample.
    request_seen: Option<MonoTime>,
    heartbeat: Duration,
    /// Device ids pinned to participants.
    identities: Identities,
    /// Strengths of the ControlCommand writers discovery found, to check a REQUEST's
    /// `src_priority` against (bounded: see [`MAX_WRITERS`]).
    writers: BTreeMap<WriterId, Strength>,
    /// Vehicles we yielded to a grant holder: the only ones a FINISH or DeviceInfo may resume.
    yielded: BTreeSet<DeviceId>,
}

/// Most ControlCommand writers remembered for checking priorities: a flood of writers beyond
/// it is not remembered, so their REQUESTs are never auto-accepted.
pub const MAX_WRITERS: usize = 1024;

/// Most vehicles whose DeviceInfo is remembered. A fleet has tens; beyond this, a new vehicle
/// takes the place of one whose id is no longer pinned to a live participant and that we
/// have nothing to do with, or, with none such, is not remembered (a flood of invented
/// vehicle ids cannot grow the table).
pub const MAX_VEHICLES: usize = 1024;

impl OperatorSession {
    /// A session starting at `now`.
    pub fn new(config: SessionConfig, now: MonoTime) -> Self {
        let configured: BTreeSet<DeviceId> = config.drive.iter().copied().collect();
        let (movement, mode, live) = match config.input {
            SessionInput::Constant(movement, mode) => (movement, mode, true),
            SessionInput::Device => (MovementCommand::CENTRED, Mode::Manual, false),
        };
        OperatorSession {
            me: config.me,
            handover: Handover::new(config.me, config.strength, config.handover),
            confirm_actions: config.confirm_actions,
            movement,
            mode,
            input_live: live,
            driving: if live {
                configured.clone()
            } else {
                BTreeSet::new()
            },
            paused: if live { BTreeSet::new() } else { configured },
            priority: BTreeSet::new(),
            standby: BTreeSet::new(),
            selected: config.drive.first().copied(),
            prompt: None,
            vehicles: BTreeMap::new(),
            pending_request: config.request.map(|v| (v, now + config.heartbeat * 2)),
            ask_after: now + config.heartbeat,
            request_seen: None,
            heartbeat: config.heartbeat,
            identities: {
                let mut ids = Identities::new(config.trust);
                ids.pin_own(config.me, config.participant);
                ids
            },
            writers: BTreeMap::new(),
            yielded: BTreeSet::new(),
        }
    }

    /// Steps the session with `event` at `now`; `stamp` is the wall-clock time put on samples
    /// sent in this step.
    pub fn step(&mut self, now: MonoTime, stamp: TimeT, event: SessionEvent) -> Vec<Effect> {
        let mut out = Out::default();
        match event {
            SessionEvent::Input(input) => self.on_input(now, stamp, input, &mut out),
            SessionEvent::DeviceInfo { info, from } => {
                match self.identities.check(now, info.device_id, from) {
                    Ok(()) => self.on_device_info(now, stamp, info, &mut out),
                    Err(suspect) => out.report(Report::Untrusted(suspect)),
                }
            }
            SessionEvent::RequestControl { msg, from } => {
                match self.identities.check(now, msg.sender_id(), from) {
                    Ok(()) => self.on_request_control(now, stamp, &msg, &mut out),
                    Err(suspect) => out.report(Report::Untrusted(suspect)),
                }
            }
            SessionEvent::WriterFound { writer, strength } => {
                if self.writers.len() < MAX_WRITERS || self.writers.contains_key(&writer) {
                    self.writers.insert(writer, strength);
                }
            }
            SessionEvent::WriterLost { writer } => {
                self.writers.remove(&writer);
            }
            SessionEvent::ParticipantGone { participant } => {
                self.identities.participant_gone(now, participant);
                self.writers.retain(|w, _| w.participant != participant);
            }
            SessionEvent::Command(command) => self.on_command(now, stamp, command, &mut out),
            SessionEvent::StreamTick => {
                self.send_driven(stamp, &mut out);
                for &v in &self.standby {
                    out.write(Writer::Regular, self.command(v, CommandType::Probe, stamp));
                }
            }
            SessionEvent::Tick => {
                let actions = self.handover.tick(now);
                self.push_actions(stamp, actions, &mut out);
                self.consider_request(now, stamp, &mut out);
            }
        }
        out.0
    }

    /// Stops: finishes every held grant, then releases every instance we write. The session
    /// drives nothing afterwards (until commanded again).
    pub fn stop(&mut self, stamp: TimeT) -> Vec<Effect> {
        let mut out = Out::default();
        for vehicle in self.priority.clone() {
            if let Ok(actions) = self.handover.finish(vehicle) {
                self.push_actions(stamp, actions, &mut out);
            }
        }
        for v in std::mem::take(&mut self.driving)
            .into_iter()
            .chain(std::mem::take(&mut self.standby))
        {
            out.push(Effect::Release {
                writer: Writer::Regular,
                vehicle: v,
            });
        }
        for v in std::mem::take(&mut self.priority) {
            out.push(Effect::Release {
                writer: Writer::Priority,
                vehicle: v,
            });
        }
        self.paused.clear();
        out.0
    }

    /// When [`SessionEvent::Tick`] next has work (a handover resend or timeout, the `--request`
    /// decision).
    pub fn next_deadline(&self) -> Option<MonoTime> {
        let deadlines = [self.handover.next_deadline(), self.request_deadline()];
        deadlines.into_iter().flatten().min()
    }

    /// The sticks and mode we send, and whether the input is live.
    pub fn input(&self) -> (MovementCommand, Mode, bool) {
        (self.movement, self.mode, self.input_live)
    }

    /// What we stream to now.
    pub fn streams(&self) -> Streams {
        let list = |s: &BTreeSet<DeviceId>| s.iter().copied().collect();
        Streams {
            driving: list(&self.driving),
            holding: list(&self.priority),
            standby: list(&self.standby),
            paused: list(&self.paused),
        }
    }

    /// Whether a [`SessionEvent::StreamTick`] has anything to send: a vehicle we drive, hold a
    /// grant for, or stand by for. An operator that streams nothing need not tick.
    pub fn streams_anything(&self) -> bool {
        !(self.driving.is_empty() && self.priority.is_empty() && self.standby.is_empty())
    }

    /// Whether we send samples to `vehicle` (regular or priority writer).
    pub fn streams_to(&self, vehicle: DeviceId) -> bool {
        self.driving.contains(&vehicle) || self.priority.contains(&vehicle)
    }

    /// The vehicles seen, with their last DeviceInfo.
    pub fn vehicles(&self) -> &BTreeMap<DeviceId, DeviceInfo> {
        &self.vehicles
    }

    /// The vehicle that buttons act on.
    pub fn selected(&self) -> Option<DeviceId> {
        self.selected
    }

    /// Under DDS Security: a participant may speak for an id only if `certifier` says so.
    pub fn certify(&mut self, certifier: crate::trust::Certifier) {
        self.identities.certify(certifier);
    }

    /// Whether `participant` may speak for `device` at `now` (its pin, or no pin): a
    /// DeviceInfo disposal from anyone else is not believed.
    pub fn speaks_for(&self, now: MonoTime, device: DeviceId, participant: ParticipantId) -> bool {
        self.identities
            .owner(now, device)
            .is_none_or(|p| p == participant)
    }

    /// The devices `participant` speaks for at `now` (their ids pinned to it): what leaves the
    /// device lists when it leaves the domain.
    pub fn devices_of(&self, now: MonoTime, participant: ParticipantId) -> Vec<DeviceId> {
        self.identities.ids_of(now, participant)
    }

    /// The handover state (for tests and status).
    pub fn handover(&self) -> &Handover {
        &self.handover
    }

    /// The `STATUS=` line, e.g. `driving 100; holding a grant for 101; 3 vehicles seen`.
    pub fn status_line(&self) -> String {
        let list = |set: &BTreeSet<DeviceId>| {
            set.iter()
                .map(DeviceId::to_string)
                .collect::<Vec<_>>()
                .join(", ")
        };
        let mut parts = Vec::new();
        if self.driving.is_empty() && self.priority.is_empty() && self.standby.is_empty() {
            parts.push("driving nothing".to_string());
        }
        if !self.driving.is_empty() {
            parts.push(format!("driving {}", list(&self.driving)));
        }
        if !self.priority.is_empty() {
            parts.push(format!("holding a grant for {}", list(&self.priority)));
        }
        if !self.standby.is_empty() {
            parts.push(format!("standing by for {}", list(&self.standby)));
        }
        parts.push(match self.vehicles.len() {
            1 => "1 vehicle seen".to_string(),
            n => format!("{n} vehicles seen"),
        });
        parts.join("; ")
    }

    fn command(&self, vehicle: DeviceId, kind: CommandType, stamp: TimeT) -> ControlCommand {
        ControlCommand {
            src_id: self.me,
            dest_id: vehicle,
            command_type: kind,
            movement_command: self.movement,
            mode: self.mode,
            timestamp: stamp,
        }
    }

    /// A fresh sample to every vehicle we drive (not the standby PROBEs).
    fn send_driven(&self, stamp: TimeT, out: &mut Out) {
        for &v in &self.driving {
            out.write(
                Writer::Regular,
                self.command(v, CommandType::Movement, stamp),
            );
        }
        for &v in &self.priority {
            out.write(
                Writer::Priority,
                self.command(v, CommandType::Movement, stamp),
            );
        }
    }

    fn on_input(&mut self, now: MonoTime, stamp: TimeT, event: InputEvent, out: &mut Out) {
        match event {
            InputEvent::Axes(movement) => {
                self.movement = movement;
                if !self.input_live {
                    self.input_live = true;
                    let resumed: Vec<DeviceId> =
                        std::mem::take(&mut self.paused).into_iter().collect();
                    self.driving.extend(resumed.iter().copied());
                    out.report(Report::InputLive { vehicles: resumed });
                }
                // Event-driven: the change leaves now, not on the next keep-alive tick.
                self.send_driven(stamp, out);
            }
            InputEvent::Deadman(true) => {}
            InputEvent::Deadman(false) => self.stop_driving("deadman released", stamp, out),
            InputEvent::Lost { reason } => self.stop_driving(&reason, stamp, out),
            InputEvent::Action(action) if self.confirm_actions => {
                out.push(Effect::Confirm(action));
            }
            InputEvent::Action(action) => {
                if let Some(command) = self.action_to_command(action, out) {
                    self.on_command(now, stamp, command, out);
                }
            }
        }
    }

    /// The input cannot be trusted: release everything we drive, explicitly, so the vehicles
    /// hand over at once; grants are finished. Driving resumes on live input.
    fn stop_driving(&mut self, why: &str, stamp: TimeT, out: &mut Out) {
        if !self.input_live {
            return;
        }
        self.input_live = false;
        let regular: Vec<DeviceId> = std::mem::take(&mut self.driving).into_iter().collect();
        for &v in &regular {
            out.push(Effect::Release {
                writer: Writer::Regular,
                vehicle: v,
            });
        }
        self.paused.extend(regular.iter().copied());
        // Vehicles we stand by for: our PROBEs would make the vehicle fall back to us (and to
        // our last values) when the grant ends, but we cannot drive. Stop them and release;
        // the yield itself stands, so the grant's end still brings them back to us (paused
        // until the input is live).
        for v in std::mem::take(&mut self.standby) {
            out.push(Effect::Release {
                writer: Writer::Regular,
                vehicle: v,
            });
        }
        out.report(Report::InputNotLive {
            reason: why.to_string(),
            vehicles: regular,
        });
        for v in self.priority.clone() {
            let actions = self.handover.finish(v).unwrap_or_default();
            self.push_actions(stamp, actions, out);
        }
    }

    /// A button or key without the console: the command it means for the selected vehicle.
    fn action_to_command(&mut self, action: InputAction, out: &mut Out) -> Option<Command> {
        let selected = self.selected;
        match action {
            InputAction::Mode(mode) => Some(Command::Mode {
                vehicle: None,
                mode,
            }),
            InputAction::NextVehicle | InputAction::PreviousVehicle => {
                let ids: Vec<DeviceId> = self.vehicles.keys().copied().collect();
                let at = selected.and_then(|s| ids.iter().position(|&v| v == s));
                let next = match (action, at) {
                    (_, None) => ids.first().copied(),
                    (InputAction::NextVehicle, Some(i)) => ids.get((i + 1) % ids.len()).copied(),
                    (_, Some(i)) => ids.get((i + ids.len() - 1) % ids.len()).copied(),
                };
                self.selected = next;
                out.report(Report::Selected { vehicle: next });
                None
            }
            InputAction::RequestControl => selected.map(|vehicle| Command::Request { vehicle }),
            InputAction::Accept => self.prompt.map(|vehicle| Command::Accept { vehicle }),
            InputAction::Refuse => self.prompt.map(|vehicle| Command::Refuse { vehicle }),
            InputAction::Finish => {
                let held = selected.filter(|s| self.priority.contains(s)).or(self
                    .priority
                    .iter()
                    .next()
                    .copied());
                held.map(|vehicle| Command::Finish { vehicle })
            }
            InputAction::Release => Some(Command::Release { vehicle: selected }),
        }
    }

    fn on_command(&mut self, now: MonoTime, stamp: TimeT, command: Command, out: &mut Out) {
        let owner_of = |s: &Self, v: DeviceId| s.vehicles.get(&v).map(|i| i.controller_id);
        match command {
            Command::Select { vehicle } => {
                self.selected = Some(vehicle);
                out.report(Report::Selected {
                    vehicle: Some(vehicle),
                });
            }
            Command::Mode { mode, .. } => {
                self.mode = mode;
                out.report(Report::ModeSelected { mode });
                self.send_driven(stamp, out);
            }
            Command::Drive { vehicle } => {
                if self.streams_to(vehicle) {
                    return;
                }
                match owner_of(self, vehicle) {
                    None => out.refuse(format!("vehicle {vehicle} has not been seen")),
                    Some(owner) if owner != vehicle && owner != self.me => out.refuse(format!(
                        "vehicle {vehicle} is driven by {owner}: request control instead"
                    )),
                    Some(_) => {
                        // Still ours after we yielded it (the holder never took over): the
                        // person takes it back, so the standby ends and a late FINISH is moot.
                        self.yielded.remove(&vehicle);
                        let probing =
                            self.handover.resume(vehicle) && self.standby.remove(&vehicle);
                        self.selected = Some(vehicle);
                        out.report(Report::Driving {
                            vehicle,
                            why: DriveReason::Commanded,
                        });
                        self.drive_or_pause(vehicle, probing, stamp, out);
                    }
                }
            }
            Command::Release { vehicle } => {
                let targets: Vec<DeviceId> = match vehicle {
                    Some(v) => vec![v],
                    None => self
                        .driving
                        .iter()
                        .chain(&self.paused)
                        .chain(&self.priority)
                        .copied()
                        .collect(),
                };
                for v in targets {
                    out.report(Report::Released { vehicle: v });
                    self.paused.remove(&v);
                    if self.driving.remove(&v) {
                        out.push(Effect::Release {
                            writer: Writer::Regular,
                            vehicle: v,
                        });
                    }
                    if self.priority.contains(&v) {
                        let actions = self.handover.finish(v).unwrap_or_default();
                        self.push_actions(stamp, actions, out);
                    }
                }
            }
            Command::Request { vehicle } => match owner_of(self, vehicle) {
                None => out.refuse(format!("vehicle {vehicle} has not been seen")),
                Some(owner) if owner == vehicle || owner == self.me => {
                    self.on_command(now, stamp, Command::Drive { vehicle }, out);
                }
                Some(owner) => match self.handover.request(now, vehicle, owner, stamp) {
                    Ok(actions) => {
                        out.report(Report::RequestSent { vehicle, owner });
                        self.push_actions(stamp, actions, out);
                    }
                    Err(e) => out.refuse(format!("cannot request {vehicle}: {e}")),
                },
            },
            Command::Accept { vehicle } | Command::Refuse { vehicle } => {
                // Only what we still own can be given: a prompt answered after we released
                // the vehicle (or lost it) is refused, or the requester would hold a grant the
                // vehicle never honours.
                let ours = owner_of(self, vehicle) == Some(self.me);
                let wanted = matches!(command, Command::Accept { .. });
                match self.handover.decide(now, vehicle, wanted && ours) {
                    Ok(actions) => {
                        self.push_actions(stamp, actions, out);
                        if wanted && !ours {
                            out.refuse(format!(
                                "vehicle {vehicle} is no longer ours to give: the request was \
                                 refused"
                            ));
                        }
                    }
                    Err(e) => out.refuse(format!("no answer taken for {vehicle}: {e}")),
                }
            }
            Command::Finish { vehicle } => match self.handover.finish(vehicle) {
                Ok(actions) => self.push_actions(stamp, actions, out),
                Err(e) => out.refuse(format!("cannot finish {vehicle}: {e}")),
            },
        }
    }

    /// Drives `vehicle` with the regular writer now, or once the input is live.
    fn drive(&mut self, vehicle: DeviceId, why: DriveReason, stamp: TimeT, out: &mut Out) {
        out.report(Report::Driving { vehicle, why });
        self.drive_or_pause(vehicle, false, stamp, out);
    }

    /// Streams to `vehicle` now if the input is live, else pauses it until it is. `probing`:
    /// our standby PROBEs kept us live on the vehicle, so a pause releases it, and the vehicle
    /// hands over at once rather than after a command timeout.
    fn drive_or_pause(&mut self, vehicle: DeviceId, probing: bool, stamp: TimeT, out: &mut Out) {
        if self.input_live {
            self.driving.insert(vehicle);
            out.write(
                Writer::Regular,
                self.command(vehicle, CommandType::Movement, stamp),
            );
        } else {
            self.paused.insert(vehicle);
            if probing {
                out.push(Effect::Release {
                    writer: Writer::Regular,
                    vehicle,
                });
            }
        }
    }

    /// A believed RequestControl: REQUESTs to us are answered only for a vehicle we drive and
    /// whose DeviceInfo names us (or while we answer that vehicle's request already), and a
    /// REQUEST's priority counts for auto-accept only if discovery agrees with it.
    fn on_request_control(
        &mut self,
        now: MonoTime,
        stamp: TimeT,
        msg: &RequestControl,
        out: &mut Out,
    ) {
        let to_us = msg.current_controller_id == self.me && msg.src_id != self.me;
        if to_us && msg.ack == crate::msg::Ack::Request {
            let vehicle = msg.dest_id;
            let drives = self.streams_to(vehicle) || self.paused.contains(&vehicle);
            let names_us =
                (self.vehicles.get(&vehicle)).is_some_and(|i| i.controller_id == self.me);
            if !(self.handover.is_replying(vehicle) || drives && names_us) {
                out.report(Report::RequestIgnored {
                    vehicle,
                    requester: msg.src_id,
                });
                return;
            }
        }
        let verified = (self.identities.owner(now, msg.src_id)).is_some_and(|p| {
            (self.writers.iter())
                .any(|(w, s)| w.participant == p && i32::from(s.0) == msg.src_priority)
        });
        let actions = self.handover.on_message_checked(now, msg, verified);
        self.push_actions(stamp, actions, out);
    }

    /// Whether the vehicle table may hold `vehicle` (see [`MAX_VEHICLES`]), making room if it
    /// must by forgetting vehicles that are neither pinned to a live participant nor ours in
    /// any way (driven, paused, standing by, held, yielded, selected, prompted or requested).
    fn has_room_for_vehicle(&mut self, now: MonoTime, vehicle: DeviceId) -> bool {
        if self.vehicles.len() < MAX_VEHICLES || self.vehicles.contains_key(&vehicle) {
            return true;
        }
        let ours = |v: &DeviceId| {
            [
                &self.driving,
                &self.paused,
                &self.priority,
                &self.standby,
                &self.yielded,
            ]
            .iter()
            .any(|set| set.contains(v))
                || self.selected == Some(*v)
                || self.prompt == Some(*v)
                || self.pending_request.is_some_and(|(r, _)| r == *v)
        };
        let gone: Vec<DeviceId> = (self.vehicles.keys())
            .filter(|v| !ours(v) && self.identities.owner(now, **v).is_none())
            .copied()
            .collect();
        for v in gone {
            self.vehicles.remove(&v);
        }
        self.vehicles.len() < MAX_VEHICLES
    }

    fn on_device_info(&mut self, now: MonoTime, stamp: TimeT, info: DeviceInfo, out: &mut Out) {
        if info.device_type == DeviceType::Vehicle {
            // A yielded vehicle's published owner can show that its grant is over.
            let actions = self
                .handover
                .on_vehicle_owner(info.device_id, info.controller_id);
            if self.has_room_for_vehicle(now, info.device_id) {
                self.vehicles.insert(info.device_id, info);
            }
            self.push_actions(stamp, actions, out);
        }
        self.consider_request(now, stamp, out);
    }

    /// When the `--request` decision may next be made without a new DeviceInfo: a heartbeat
    /// after start and after the vehicle's first sample, and for a vehicle that looks free, when
    /// it counts as free. `None` when it waits for a sample (or there is none to make).
    fn request_deadline(&self) -> Option<MonoTime> {
        let (wanted, free_after) = self.pending_request?;
        let v = self.vehicles.get(&wanted)?;
        let decide = self.ask_after.max(self.request_seen? + self.heartbeat);
        if v.controller_id == wanted {
            Some(decide.max(free_after))
        } else if v.controller_id == self.me {
            None // waits for a fresher sample (see `consider_request`)
        } else {
            Some(decide)
        }
    }

    /// `--request`: ask once the vehicle and its owner are known from a live sample, on a
    /// DeviceInfo or at [`Self::request_deadline`]. An unchanged DeviceInfo is published only
    /// every few seconds, so the decision is not left to the next sample.
    fn consider_request(&mut self, now: MonoTime, stamp: TimeT, out: &mut Out) {
        let Some((wanted, free_after)) = self.pending_request else {
            return;
        };
        let Some(v) = self.vehicles.get(&wanted) else {
            return;
        };
        if self.identities.owner(now, wanted).is_none() {
            // Its participant left since: wait for a live sample (no deadline until then).
            self.request_seen = None;
            return;
        }
        let first_seen = *self.request_seen.get_or_insert(now);
        if now < self.ask_after || now < first_seen + self.heartbeat {
            return;
        }
        let (vehicle, owner) = (v.device_id, v.controller_id);
        if owner == self.me {
            // Names us: true only if we stream to it; otherwise it is an older sample (a
            // previous process with our id), so wait for a fresher one.
            if self.streams_to(vehicle) {
                self.pending_request = None;
                out.report(Report::Driving {
                    vehicle,
                    why: DriveReason::AlreadyOurs,
                });
            }
        } else if owner == vehicle {
            // Looks free, but may be an old sample until two heartbeats have passed.
            if now >= free_after {
                self.pending_request = None;
                self.drive(vehicle, DriveReason::Free, stamp, out);
            }
        } else {
            self.pending_request = None;
            match self.handover.request(now, vehicle, owner, stamp) {
                Ok(actions) => {
                    out.report(Report::RequestSent { vehicle, owner });
                    self.push_actions(stamp, actions, out);
                }
                Err(e) => out.report(Report::RequestFailed {
                    vehicle,
                    owner,
                    reason: e.to_string(),
                }),
            }
        }
    }

    /// The handover machine's `actions` as this turn's effects (and prompts) in `out`.
    fn push_actions(&mut self, stamp: TimeT, actions: Vec<Action>, out: &mut Out) {
        for action in actions {
            match action {
                Action::Send(msg) => out.push(Effect::Send(msg)),
                Action::AskOperator(prompt) => {
                    self.prompt = Some(prompt.vehicle);
                    out.report(Report::Prompt(prompt));
                }
                Action::PromptClosed { vehicle, outcome } => {
                    if self.prompt == Some(vehicle) {
                        self.prompt = None;
                    }
                    out.report(Report::PromptClosed { vehicle, outcome });
                }
                Action::RequestEnded { vehicle, outcome } => {
                    out.report(Report::RequestEnded { vehicle, outcome });
                }
                Action::StartPriorityDriving { vehicle } => {
                    self.priority.insert(vehicle);
                    out.report(Report::GrantStarted { vehicle });
                    out.write(
                        Writer::Priority,
                        self.command(vehicle, CommandType::Movement, stamp),
                    );
                }
                Action::StopPriorityDriving { vehicle } => {
                    self.priority.remove(&vehicle);
                    out.report(Report::GrantEnded { vehicle });
                    out.push(Effect::Release {
                        writer: Writer::Priority,
                        vehicle,
                    });
                }
                Action::Yield { vehicle } => {
                    self.yielded.insert(vehicle);
                    self.driving.remove(&vehicle);
                    self.paused.remove(&vehicle);
                    out.report(Report::Yielded { vehicle });
                    if self.input_live {
                        self.standby.insert(vehicle);
                        out.write(
                            Writer::Regular,
                            self.command(vehicle, CommandType::Probe, stamp),
                        );
                    } else {
                        // No standby without live input: the vehicle must not fall back to
                        // us when the grant ends (see `stop_driving`).
                        out.push(Effect::Release {
                            writer: Writer::Regular,
                            vehicle,
                        });
                    }
                }
                Action::EndStandby { vehicle } => {
                    self.standby.remove(&vehicle);
                    out.report(Report::StandbyEnded { vehicle });
                }
                Action::Resume { vehicle } => {
                    // Only a vehicle we yielded: never a role we did not hold.
                    if !self.yielded.remove(&vehicle) {
                        continue;
                    }
                    self.standby.remove(&vehicle);
                    let live = self.input_live;
                    out.report(Report::Resumed { vehicle, live });
                    self.drive_or_pause(vehicle, true, stamp, out);
                }
            }
        }
    }
}

/// The effects of one step, in order.
#[derive(Default)]
struct Out(Vec<Effect>);

impl Out {
    fn push(&mut self, effect: Effect) {
        self.0.push(effect);
    }

    fn write(&mut self, writer: Writer, command: ControlCommand) {
        self.0.push(Effect::Write { writer, command });
    }

    fn report(&mut self, report: Report) {
        self.0.push(Effect::Report(report));
    }

    fn refuse(&mut self, why: String) {
        self.0.push(Effect::Refused(why));
    }
}

#[cfg(test)]
mod tests;
