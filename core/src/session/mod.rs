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
//!
//! # Roles
//!
//! What the session does with each vehicle is one role (`roles::Role`), kept in one table;
//! a vehicle it has nothing to do with has none:
//! - **Driving**: ours on the regular writer. It is driven while the input is live and
//!   *paused* while it is not: released, and driven again once the input is live. Paused is not
//!   a role of its own: input liveness is one fact for the whole session, so every vehicle we
//!   drive is paused exactly while the input is not live.
//! - **Yielded**: we gave it to a grant holder; with a flag for the standby (PROBEs on the
//!   regular writer keep us its fallback), which ends when the input goes or the holder never
//!   takes over, while the vehicle stays yielded. A yielded vehicle is never driven on the
//!   regular writer: it is driven again only by the grant's end (FINISH, or the vehicle's
//!   DeviceInfo) or a `drive` command.
//! - **Granted**: we hold a grant for it and drive it with the priority writer.
//!
//! The grant is a fact of its own, beside the regular writer's part: `Driving` and `Yielded`
//! carry a `grant` flag, and `Granted` is a grant alone. Each combination occurs:
//! - a grant for a vehicle we drive, or that is paused: we still stream to a vehicle a stronger
//!   operator has taken over, ask that owner (as its DeviceInfo names it) and are granted it;
//!   or a vehicle we yielded comes back to us while we hold a grant for it;
//! - a grant for a vehicle we yielded: we asked its holder for it back and were granted it.
//!
//! What cannot occur cannot be written: a vehicle both driven and paused, driven or paused
//! while yielded, a standby for a vehicle not yielded. A vehicle is `Yielded` exactly while the
//! handover machine has yielded it ([`Handover::has_yielded`]), and has a grant exactly while
//! the machine holds one for it ([`Handover::holds_grant`]): the machine decides both, and the
//! roles follow its actions.
//!
//! # Layout
//! - `mod.rs`: the session's events, settings and state; [`OperatorSession::step`] and
//!   [`OperatorSession::stop`].
//! - `roles.rs`: one role per vehicle (above), and the only code that changes roles.
//! - `driving.rs`: streaming, input liveness (pause and resume), and what we stream to.
//! - `commands.rs`: [`Command`]s, from the console, the local API or a button.
//! - `handover.rs`: REQUESTs we answer, and the handover machine's actions carried out.
//! - `requests.rs`: the vehicles seen (DeviceInfo) and `--request` (ask once the owner is known).
//! - `effects.rs`: what a step answers: [`Effect`]s and [`Report`]s.

mod commands;
mod driving;
mod effects;
mod handover;
mod requests;
mod roles;

pub use commands::Command;
pub use effects::{DriveReason, Effect, Report, Writer};

use crate::adapter::InputEvent;
use crate::arbiter::{ParticipantId, WriterId};
use crate::handover::{Handover, HandoverConfig};
use crate::hierarchy::Strength;
use crate::msg::{
    ControlCommand, DeviceId, DeviceInfo, Mode, MovementCommand, RequestControl, TimeT,
};
use crate::time::MonoTime;
use crate::trust::{Identities, TrustConfig};
use roles::Roles;
use std::collections::BTreeMap;
use std::time::Duration;

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
    /// What we do with each vehicle (module docs, "Roles").
    roles: Roles,
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
            roles: Roles::driving(&config.drive),
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
                self.send_probes(stamp, &mut out);
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
        let granted: Vec<DeviceId> = self.roles.granted().collect();
        for vehicle in granted {
            if let Ok(actions) = self.handover.finish(vehicle) {
                self.push_actions(stamp, actions, &mut out);
            }
        }
        // Paused vehicles were released when the input went.
        let driving = self.roles.stop_driving_all();
        let driven = if self.input_live { driving } else { Vec::new() };
        for v in driven.into_iter().chain(self.roles.end_standby_all()) {
            out.push(Effect::Release {
                writer: Writer::Regular,
                vehicle: v,
            });
        }
        // Every grant is the handover machine's, so the finishes above leave none; should one
        // be left, its stream is released all the same.
        let granted: Vec<DeviceId> = self.roles.granted().collect();
        for v in granted {
            self.roles.set_grant(v, false);
            out.push(Effect::Release {
                writer: Writer::Priority,
                vehicle: v,
            });
        }
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
