//! The per-vehicle ownership arbiter: who drives this vehicle, at every instant (docs/design.md §4).
//!
//! DDS's EXCLUSIVE ownership is not arbitrated by rustdds, so the vehicle does it here, as a pure
//! state machine: [`Arbiter::step`] takes `now` and one [`Event`] and returns a [`Decision`].
//! It reads no clock and does no I/O; the same event sequence always yields the same decisions.
//!
//! # The contract
//! The owner is, at every step's `now`:
//! 1. the holder of the most recent accepted priority grant, if its priority stream is live; else
//! 2. the live controller with the highest strength; on equal strength the incumbent keeps
//!    control, and with no incumbent the lowest `device_id` (then the lowest writer id) wins; else
//! 3. the onboard failsafe.
//!
//! *Live* means: its last command sample for this vehicle arrived less than `command_timeout`
//! ago and it has not released since (explicit release, writer or participant gone).
//! A priority-strength (65535) stream only counts while its device holds the grant, so a late
//! sample from a previous holder can never win control back (no ping-pong).
//!
//! # Outputs
//! Each decision may carry an [`OwnerChange`] (from, to, reason), an [`Output`] for the adapter
//! (apply this setpoint, or go to the safe state) and, for events that changed nothing, why they
//! were [`Ignored`]. Every output carries its provenance: the controller it came from and a
//! sequence number. When a new owner takes over, its latest values (MOVEMENT or MODE) are applied
//! at once if they arrived within `command_timeout`. Older values are never applied: the output
//! goes to the safe state instead — also when an owner keeps its stream alive with PROBE
//! keep-alives only, once its last values are a timeout old. A live owner therefore keeps
//! ownership on PROBEs, but cannot keep the vehicle moving on them.
//!
//! # Timing
//! Liveness expires lazily at any step, and [`Event::Tick`] exists so that expiry is acted on
//! with no other traffic. [`Arbiter::next_deadline`] tells the caller when the next tick can
//! change anything, so the gateway sleeps until exactly then instead of polling.

use crate::hierarchy::Strength;
use crate::msg::{
    Ack, CommandType, ControlCommand, DeviceId, Mode, MovementCommand, RequestControl, TimeT,
};
use crate::time::MonoTime;
use crate::trust::{Access, Distrust, Identities, Suspect, TrustConfig};
use crate::watchdog::{CommandTimeout, Watchdog};
use std::fmt;

pub use crate::sender::{ParticipantId, WriterId};

/// A controller as the arbiter knows it: a writer, the device it speaks for, its strength.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Controller {
    /// The stream.
    pub writer: WriterId,
    /// The `src_id` it sends as.
    pub device: DeviceId,
    /// Its ownership strength.
    pub strength: Strength,
}

/// Who drives the vehicle.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Owner {
    /// The onboard failsafe (strength 0): outputs are in the adapter's safe state.
    Failsafe,
    /// A remote controller.
    Controller(Controller),
}

impl Owner {
    /// The owning writer, if a controller owns.
    pub fn writer(&self) -> Option<WriterId> {
        match self {
            Owner::Failsafe => None,
            Owner::Controller(c) => Some(c.writer),
        }
    }

    /// The owning device, if a controller owns.
    pub fn device(&self) -> Option<DeviceId> {
        match self {
            Owner::Failsafe => None,
            Owner::Controller(c) => Some(c.device),
        }
    }
}

/// The arbiter's inputs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Event {
    /// A ControlCommand sample arrived from `writer` (strength from discovery) at `arrival`,
    /// measured on the vehicle's clock. `arrival` later than `now` is taken as `now`.
    Sample {
        /// The writer that sent it.
        writer: WriterId,
        /// The writer's ownership strength.
        strength: Strength,
        /// The sample.
        command: ControlCommand,
        /// When it arrived.
        arrival: MonoTime,
    },
    /// The writer explicitly stopped driving this vehicle (unregister/dispose, or a release).
    Released {
        /// The writer.
        writer: WriterId,
    },
    /// The writer left (discovery lost it).
    WriterGone {
        /// The writer.
        writer: WriterId,
    },
    /// A whole participant left (discovery or presence heartbeat lost it): all its writers go.
    ParticipantGone {
        /// The participant.
        participant: ParticipantId,
    },
    /// A RequestControl ACCEPT for this vehicle was observed: `granted_by` (the owner asked)
    /// gives the vehicle to `holder`. It counts only if `sender` is the participant
    /// `granted_by` is pinned to.
    GrantAccepted {
        /// The requester, who will drive with a priority writer.
        holder: DeviceId,
        /// The owner who consented (`current_controller_id` of the ACCEPT).
        granted_by: DeviceId,
        /// The handover's stamp (the REQUEST's, echoed by rove peers).
        stamp: TimeT,
        /// The participant the ACCEPT came from.
        sender: ParticipantId,
    },
    /// A RequestControl FINISH for this vehicle: `holder` gives its grant back. It counts only
    /// if `sender` is the participant `holder` is pinned to.
    GrantFinished {
        /// The grant holder.
        holder: DeviceId,
        /// The stamp of the handover it finishes: a FINISH stamped earlier than the current
        /// grant belongs to an earlier handover (a replay, or a stale ACCEPT handed back) and
        /// does not end the current grant.
        stamp: TimeT,
        /// The participant the FINISH came from.
        sender: ParticipantId,
    },
    /// `sender` spoke as `device` (a DeviceInfo, or a RequestControl that is no grant event
    /// here): pins the id at first sight, or reports the claim if the id is another's.
    Heard {
        /// The id claimed.
        device: DeviceId,
        /// The participant the message came from.
        sender: ParticipantId,
    },
    /// Time passed: expire silent streams.
    Tick,
}

impl Event {
    /// What a RequestControl sample from `sender` means to `vehicle`'s arbiter: an ACCEPT is a
    /// grant, a FINISH ends one; a REQUEST, a REFUSE or a sample for another vehicle only
    /// shows who speaks for its sender's id ([`Event::Heard`]).
    pub fn from_request_control(
        vehicle: DeviceId,
        msg: &RequestControl,
        sender: ParticipantId,
    ) -> Event {
        match msg.ack {
            Ack::Accept if msg.dest_id == vehicle => Event::GrantAccepted {
                holder: msg.src_id,
                granted_by: msg.current_controller_id,
                stamp: msg.timestamp,
                sender,
            },
            Ack::Finish if msg.dest_id == vehicle => Event::GrantFinished {
                holder: msg.src_id,
                stamp: msg.timestamp,
                sender,
            },
            _ => Event::Heard {
                device: msg.sender_id(),
                sender,
            },
        }
    }
}

/// Why the owner changed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Reason {
    /// A controller became live while the failsafe owned.
    Joined,
    /// A stronger live controller took over from a live owner.
    Preempted,
    /// The owner released explicitly.
    Released,
    /// The owner's writer or participant left.
    Left,
    /// The owner was silent for `command_timeout`.
    TimedOut,
    /// The holder of an accepted priority grant took over (when the grant was seen, or when its
    /// priority stream started).
    Granted,
    /// The grant was given back (FINISH); the strongest live controller took over.
    GrantReturned,
}

impl fmt::Display for Reason {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Reason::Joined => "joined",
            Reason::Preempted => "preempted",
            Reason::Released => "released",
            Reason::Left => "left",
            Reason::TimedOut => "timed out",
            Reason::Granted => "granted",
            Reason::GrantReturned => "grant returned",
        })
    }
}

/// An ownership transition.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct OwnerChange {
    /// Previous owner.
    pub from: Owner,
    /// New owner.
    pub to: Owner,
    /// Why.
    pub reason: Reason,
}

/// What the adapter turns into actuator signals.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Setpoint {
    /// Stick values.
    pub movement: MovementCommand,
    /// Requested mode.
    pub mode: Mode,
}

/// What the output adapter must do now.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Output {
    /// Drive with `setpoint`, sent by `by`.
    Apply {
        /// Provenance: the owning controller.
        by: Controller,
        /// The values.
        setpoint: Setpoint,
        /// Output sequence number (counts every output of this arbiter).
        seq: u64,
    },
    /// Go to the safe state: the failsafe owns, or the owner has no fresh values (it has sent
    /// only keep-alives for a timeout, or nothing but keep-alives yet).
    SafeState {
        /// Who owns while the outputs are safe.
        owner: Owner,
        /// Output sequence number.
        seq: u64,
    },
}

/// Why an event changed nothing.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Ignored {
    /// The sample's `dest_id` is another vehicle.
    NotForThisVehicle,
    /// The sample claims this vehicle's own id as its source.
    FromThisVehicle,
    /// Strength 0 is the onboard failsafe's; no remote writer may use it.
    FailsafeStrength,
    /// The writer sent as a different `src_id` before; one stream speaks for one device.
    SourceMismatch,
    /// Arrived earlier than a sample or release already processed from the same writer.
    OutOfOrder,
    /// Arrived `command_timeout` or more before `now`.
    Stale,
    /// A priority-strength sample from a device that holds no grant: recorded (so that the
    /// holder can take over the instant its grant is seen) but it does not drive.
    PriorityWithoutGrant,
    /// The source table is full (see [`ArbiterConfig::max_sources`]).
    TooManySources,
    /// The sender's participant already has its share of the source table (see
    /// [`ArbiterConfig::per_participant`]).
    ParticipantQuota,
    /// A release or departure of a writer or participant the arbiter does not know.
    UnknownSource,
    /// An ACCEPT from a device that neither owns the vehicle nor just stepped down.
    ConsentNotFromOwner,
    /// An ACCEPT naming this vehicle, or the consenting owner itself, as the holder.
    InvalidGrant,
    /// A FINISH that does not name the current grant: another device, or an earlier handover's
    /// stamp.
    NotGrantHolder,
    /// The message was not believed: see [`Decision::suspect`].
    Untrusted,
}

/// Everything one step decided. `Default` is "nothing happened".
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Decision {
    /// Set when the owner changed.
    pub owner_change: Option<OwnerChange>,
    /// Set when the adapter must act.
    pub output: Option<Output>,
    /// Set when the event was dropped or did not count (diagnostics).
    pub ignored: Option<Ignored>,
    /// Set when the event was not believed (a claimed id of another participant, a strength
    /// outside the hierarchy or the access list): to be reported, naming id and participant.
    pub suspect: Option<Suspect>,
}

impl Decision {
    /// The failsafe took over in this step.
    pub fn entered_failsafe(&self) -> bool {
        self.owner_change
            .is_some_and(|c| c.to == Owner::Failsafe && c.from != Owner::Failsafe)
    }

    /// A controller took over from the failsafe in this step.
    pub fn left_failsafe(&self) -> bool {
        self.owner_change
            .is_some_and(|c| c.from == Owner::Failsafe && c.to != Owner::Failsafe)
    }
}

/// Validated arbiter settings.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ArbiterConfig {
    /// Silence after which a stream is no longer live.
    pub command_timeout: CommandTimeout,
    /// Most sources tracked at once. Bounds memory against a flood of writers: when the table is
    /// full, silent sources are forgotten to make room; if all are live, the new one is ignored.
    /// Sources are otherwise kept until their writer or participant leaves. 256 is far above any
    /// real fleet (the handover benchmarks use ≤ 32).
    pub max_sources: usize,
    /// Most sources one participant may hold, so that one flooding participant cannot fill
    /// the table. An operator has a regular and a priority writer per vehicle; 8 leaves room
    /// for a gateway that speaks for several devices. A participant's silent sources make room
    /// for its new ones. (The grant holder gets room in a full table at the expense of the
    /// weakest live stream that neither owns nor holds the grant.)
    pub per_participant: usize,
    /// How long device ids stay pinned to their participants.
    pub trust: TrustConfig,
}

impl Default for ArbiterConfig {
    fn default() -> Self {
        ArbiterConfig {
            command_timeout: CommandTimeout::DEFAULT,
            max_sources: 256,
            per_participant: 8,
            trust: TrustConfig::default(),
        }
    }
}

/// Why a source stopped being live by event (rather than by time).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Presence {
    Streaming,
    Released,
}

/// One command stream for this vehicle.
#[derive(Debug, Clone)]
struct Source {
    controller: Controller,
    watchdog: Watchdog,
    presence: Presence,
    /// Latest arrival or release processed: older samples are out of order.
    high_water: MonoTime,
    /// Latest movement/mode values and when they arrived; `None` while it has only sent
    /// keep-alives. Values are fresh for one command timeout, like the stream itself.
    setpoint: Option<(MonoTime, Setpoint)>,
}

impl Source {
    fn is_live(&self, now: MonoTime) -> bool {
        self.presence == Presence::Streaming && self.watchdog.is_live(now)
    }

    fn fresh_setpoint(&self, now: MonoTime, timeout: CommandTimeout) -> Option<Setpoint> {
        self.setpoint
            .filter(|(at, _)| now < *at + timeout.get())
            .map(|(_, sp)| sp)
    }
}

/// A device that stepped down without being preempted, whose consent (ACCEPT) still counts
/// for one command timeout: its release may overtake its ACCEPT on the wire, since they travel
/// on different topics.
#[derive(Debug, Clone, Copy)]
struct SteppedDown {
    device: DeviceId,
    until: MonoTime,
}

/// Snapshot of one source, for status and diagnostics.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SourceStatus {
    /// The stream.
    pub controller: Controller,
    /// Sent within the timeout and not released.
    pub live: bool,
    /// Live and allowed to own (a priority stream needs the grant).
    pub eligible: bool,
    /// Time since its last sample, if it sent one.
    pub age: Option<std::time::Duration>,
}

/// The ownership arbiter of one vehicle. See the [module docs](self) for the contract.
#[derive(Debug, Clone)]
pub struct Arbiter {
    vehicle: DeviceId,
    config: ArbiterConfig,
    access: Access,
    identities: Identities,
    sources: Vec<Source>,
    owner: Owner,
    grant: Option<DeviceId>,
    /// Stamp of the current grant's ACCEPT.
    grant_stamp: TimeT,
    stepped_down: Option<SteppedDown>,
    /// True while the last output was `Apply`: the owner's values are driving the vehicle and
    /// must be withdrawn (safe state) the moment they go stale.
    driving: bool,
    last_now: MonoTime,
    seq: u64,
}

impl Arbiter {
    /// An arbiter for vehicle `vehicle`, starting with the failsafe owning.
    pub fn new(vehicle: DeviceId, config: ArbiterConfig) -> Self {
        Arbiter {
            vehicle,
            config,
            access: Access::default(),
            identities: Identities::new(config.trust),
            sources: Vec::new(),
            owner: Owner::Failsafe,
            grant: None,
            grant_stamp: TimeT(0),
            stepped_down: None,
            driving: false,
            last_now: MonoTime::ZERO,
            seq: 0,
        }
    }

    /// Believes only the strengths and ids `access` allows (default: any id, at any strength
    /// the standard hierarchy gives).
    pub fn with_access(mut self, access: Access) -> Self {
        self.access = access;
        self
    }

    /// Pins the vehicle's own id to its own participant: nobody else can speak as the vehicle.
    pub fn pin_own(&mut self, participant: ParticipantId) {
        self.identities.pin_own(self.vehicle, participant);
    }

    /// Under DDS Security: a participant may speak for an id only if `certifier` says so.
    pub fn certify(&mut self, certifier: crate::trust::Certifier) {
        self.identities.certify(certifier);
    }

    /// The participant `device` is pinned to at `now`, if any.
    pub fn pinned(&self, now: MonoTime, device: DeviceId) -> Option<ParticipantId> {
        self.identities.owner(now, device)
    }

    /// The current owner.
    pub fn owner(&self) -> Owner {
        self.owner
    }

    /// The value for `DeviceInfo.controller_id`: the owner's device id, or the vehicle's own id
    /// while the failsafe owns.
    pub fn controller_id(&self) -> DeviceId {
        self.owner.device().unwrap_or(self.vehicle)
    }

    /// The device holding the most recent accepted priority grant, if any.
    pub fn grant_holder(&self) -> Option<DeviceId> {
        self.grant
    }

    /// The vehicle this arbiter decides for.
    pub fn vehicle(&self) -> DeviceId {
        self.vehicle
    }

    /// The earliest instant at which a [`Event::Tick`] can change something (a live stream's
    /// timeout, or the owner's values going stale), or `None` when nothing can.
    pub fn next_deadline(&self) -> Option<MonoTime> {
        let timeout = self.config.command_timeout.get();
        let streams = self
            .sources
            .iter()
            .filter(|s| s.presence == Presence::Streaming)
            .filter_map(|s| s.watchdog.deadline());
        let values = self
            .owner_source()
            .filter(|_| self.driving)
            .and_then(|s| s.setpoint)
            .map(|(at, _)| at + timeout);
        streams.chain(values).filter(|d| *d > self.last_now).min()
    }

    /// The sources known at `now`, for status displays.
    pub fn sources(&self, now: MonoTime) -> impl Iterator<Item = SourceStatus> + '_ {
        self.sources.iter().map(move |s| SourceStatus {
            controller: s.controller,
            live: s.is_live(now),
            eligible: self.is_eligible(s, now),
            age: s.watchdog.last_kick().map(|t| now.saturating_since(t)),
        })
    }

    /// Processes one event at `now` and says what follows from it.
    ///
    /// `now` must not go backwards; if it does, the latest `now` seen is used instead, so a
    /// misbehaving clock can delay a timeout but never revive a stream.
    pub fn step(&mut self, now: MonoTime, event: Event) -> Decision {
        let now = now.max(self.last_now);
        self.last_now = now;
        let before = self.owner;
        let mut decision = Decision::default();

        // 1. Record the event. `sampled` is the writer whose new values may need applying.
        let sampled = self.record(now, &event, &mut decision);

        // 2. Re-arbitrate.
        let after = self.select(now);
        if after.writer() != before.writer() {
            let reason = self.reason(before, &event, now);
            if let Owner::Controller(c) = before {
                let stepped_down =
                    matches!(reason, Reason::Released | Reason::Left | Reason::TimedOut);
                self.stepped_down = stepped_down.then_some(SteppedDown {
                    device: c.device,
                    until: now + self.config.command_timeout.get(),
                });
            }
            self.owner = after;
            decision.owner_change = Some(OwnerChange {
                from: before,
                to: after,
                reason,
            });
            decision.output = Some(self.output_for_owner());
        } else {
            // Same writer; its strength may have been updated.
            self.owner = after;
            let owner_sent_values = sampled.is_some() && sampled == after.writer();
            let values_lapsed = self.driving
                && self
                    .owner_source()
                    .and_then(|s| s.fresh_setpoint(now, self.config.command_timeout))
                    .is_none();
            if owner_sent_values || values_lapsed {
                decision.output = Some(self.output_for_owner());
            }
        }

        decision
    }

    /// Records `event`; returns the writer whose new values may need applying.
    fn record(
        &mut self,
        now: MonoTime,
        event: &Event,
        decision: &mut Decision,
    ) -> Option<WriterId> {
        let mut sampled = None;
        match *event {
            Event::Sample {
                writer,
                strength,
                command,
                arrival,
            } => match self.record_sample(now, writer, strength, &command, arrival.min(now)) {
                Ok(is_values) => {
                    if is_values {
                        sampled = Some(writer);
                    }
                    if strength == Strength::PRIORITY && self.grant != Some(command.src_id) {
                        decision.ignored = Some(Ignored::PriorityWithoutGrant);
                    }
                }
                Err(Rejected::Ignored(why)) => decision.ignored = Some(why),
                Err(Rejected::Suspect(suspect)) => decision.distrust(suspect),
            },
            Event::Released { writer } => match self.find(writer) {
                Some(i) => {
                    let s = &mut self.sources[i];
                    s.presence = Presence::Released;
                    s.watchdog.clear();
                    s.high_water = s.high_water.max(now);
                    if is_grant_stream(&s.controller, self.grant) {
                        // A holder that stops its priority stream is done with the grant.
                        self.grant = None;
                    }
                }
                None => decision.ignored = Some(Ignored::UnknownSource),
            },
            Event::WriterGone { writer } => {
                if !self.remove_where(|c| c.writer == writer) {
                    decision.ignored = Some(Ignored::UnknownSource);
                }
            }
            Event::ParticipantGone { participant } => {
                self.identities.participant_gone(now, participant);
                if !self.remove_where(|c| c.writer.participant == participant) {
                    decision.ignored = Some(Ignored::UnknownSource);
                }
            }
            Event::GrantAccepted {
                holder,
                granted_by,
                stamp,
                sender,
            } => {
                let trusted = (self.identities.check(now, granted_by, sender)).and_then(|()| {
                    self.access.allows(holder).map_err(|why| Suspect {
                        device: holder,
                        sender,
                        why,
                    })
                });
                match trusted {
                    Err(suspect) => decision.distrust(suspect),
                    Ok(()) => match self.accept_grant(now, holder, granted_by) {
                        Err(why) => decision.ignored = Some(why),
                        Ok(()) => self.grant_stamp = stamp,
                    },
                }
            }
            Event::GrantFinished {
                holder,
                stamp,
                sender,
            } => {
                // `>=`: rove echoes the grant's stamp; a foreign peer stamping its FINISH at
                // send time is later still.
                if let Err(suspect) = self.identities.check(now, holder, sender) {
                    decision.distrust(suspect);
                } else if self.grant == Some(holder) && stamp >= self.grant_stamp {
                    self.grant = None;
                } else {
                    decision.ignored = Some(Ignored::NotGrantHolder);
                }
            }
            Event::Heard { device, sender } => {
                if let Err(suspect) = self.identities.check(now, device, sender) {
                    decision.distrust(suspect);
                }
            }
            Event::Tick => {}
        }
        sampled
    }

    /// Records a sample. `Ok(true)` if it carried values (movement or mode), `Ok(false)` for a
    /// keep-alive.
    fn record_sample(
        &mut self,
        now: MonoTime,
        writer: WriterId,
        strength: Strength,
        command: &ControlCommand,
        arrival: MonoTime,
    ) -> Result<bool, Rejected> {
        if command.dest_id != self.vehicle {
            return Err(Ignored::NotForThisVehicle.into());
        }
        if command.src_id == self.vehicle {
            return Err(Ignored::FromThisVehicle.into());
        }
        if strength == Strength::FAILSAFE {
            return Err(Ignored::FailsafeStrength.into());
        }
        let suspect = |why| Suspect {
            device: command.src_id,
            sender: writer.participant,
            why,
        };
        (self.access)
            .check_strength(command.src_id, strength)
            .map_err(suspect)?;
        let level = (self.identities)
            .claim_level(now, command.src_id, writer.participant)
            .map_err(suspect)?;
        if let Some(level) = level
            && !self.access.within_level(strength, level)
        {
            return Err(suspect(Distrust::AboveSite {
                claimed: strength,
                level,
            })
            .into());
        }
        if now.saturating_since(arrival) >= self.config.command_timeout.get() {
            return Err(Ignored::Stale.into());
        }
        let index = match self.find(writer) {
            Some(i) => i,
            None => self.insert(now, writer, command.src_id, strength)?,
        };
        let source = &mut self.sources[index];
        if source.controller.device != command.src_id {
            return Err(Ignored::SourceMismatch.into());
        }
        if arrival < source.high_water {
            return Err(Ignored::OutOfOrder.into());
        }
        source.high_water = arrival;
        source.controller.strength = strength;
        source.presence = Presence::Streaming;
        source.watchdog.kick(arrival);
        let timeout = self.config.command_timeout;
        let values = match command.command_type {
            CommandType::Probe => return Ok(false),
            CommandType::Movement => Setpoint {
                movement: command.movement_command,
                mode: command.mode,
            },
            // A mode change keeps the current stick values, if they are still fresh.
            CommandType::Mode => Setpoint {
                movement: source
                    .fresh_setpoint(arrival, timeout)
                    .map_or(MovementCommand::CENTRED, |s| s.movement),
                mode: command.mode,
            },
        };
        source.setpoint = Some((arrival, values));
        Ok(true)
    }

    fn insert(
        &mut self,
        now: MonoTime,
        writer: WriterId,
        device: DeviceId,
        strength: Strength,
    ) -> Result<usize, Ignored> {
        let owner = self.owner.writer();
        let grant = self.grant;
        // Never evicted: the owner's stream, the grant holder's, and live ones (but below).
        let keep = |s: &Source| {
            s.is_live(now)
                || Some(s.controller.writer) == owner
                || is_grant_stream(&s.controller, grant)
        };
        let participant = writer.participant;
        let theirs = |s: &Source| s.controller.writer.participant == participant;
        if self.sources.iter().filter(|s| theirs(s)).count() >= self.config.per_participant {
            self.sources.retain(|s| !theirs(s) || keep(s));
            if self.sources.iter().filter(|s| theirs(s)).count() >= self.config.per_participant {
                return Err(Ignored::ParticipantQuota);
            }
        }
        if self.sources.len() >= self.config.max_sources {
            // Make room by forgetting silent streams. Only here, under a flood of writers, does
            // the arbiter forget a stream that has not left: a later release of a forgotten
            // stream is then unknown. The owner and the grant holder's streams are never evicted.
            self.sources.retain(keep);
        }
        if self.sources.len() >= self.config.max_sources {
            // The grant holder still gets in, in place of the weakest live stream that neither
            // owns nor holds the grant (a flood must not keep a granted operator out).
            let weakest = (self.sources.iter().enumerate())
                .filter(|(_, s)| Some(s.controller.writer) != owner)
                .filter(|(_, s)| !is_grant_stream(&s.controller, grant))
                .min_by_key(|(_, s)| s.controller.strength)
                .map(|(i, _)| i);
            match weakest {
                Some(i) if grant == Some(device) => {
                    self.sources.remove(i);
                }
                _ => return Err(Ignored::TooManySources),
            }
        }
        self.sources.push(Source {
            controller: Controller {
                writer,
                device,
                strength,
            },
            watchdog: Watchdog::new(self.config.command_timeout),
            presence: Presence::Streaming,
            high_water: MonoTime::ZERO,
            setpoint: None,
        });
        Ok(self.sources.len() - 1)
    }

    fn accept_grant(
        &mut self,
        now: MonoTime,
        holder: DeviceId,
        granted_by: DeviceId,
    ) -> Result<(), Ignored> {
        if holder == self.vehicle || holder == granted_by {
            return Err(Ignored::InvalidGrant);
        }
        let owner_consents = self.owner.device() == Some(granted_by);
        let just_stepped_down = self
            .stepped_down
            .is_some_and(|s| s.device == granted_by && now < s.until);
        if !(owner_consents || just_stepped_down) {
            return Err(Ignored::ConsentNotFromOwner);
        }
        self.grant = Some(holder);
        Ok(())
    }

    fn find(&self, writer: WriterId) -> Option<usize> {
        self.sources
            .iter()
            .position(|s| s.controller.writer == writer)
    }

    /// Removes matching sources; true if any was removed. A grant holder whose priority stream
    /// leaves is done with the grant.
    fn remove_where(&mut self, matches: impl Fn(&Controller) -> bool) -> bool {
        let before = self.sources.len();
        let grant = self.grant;
        let mut holder_left = false;
        self.sources.retain(|s| {
            let gone = matches(&s.controller);
            if gone && is_grant_stream(&s.controller, grant) {
                holder_left = true;
            }
            !gone
        });
        if holder_left {
            self.grant = None;
        }
        self.sources.len() != before
    }

    fn is_eligible(&self, s: &Source, now: MonoTime) -> bool {
        s.is_live(now)
            && (s.controller.strength.is_operator() || is_grant_stream(&s.controller, self.grant))
    }

    /// Applies the contract: strongest eligible source; the incumbent keeps ties; otherwise the
    /// lowest (device, writer) wins.
    fn select(&self, now: MonoTime) -> Owner {
        let incumbent = self.owner.writer();
        let rank = |s: &Source| {
            let c = &s.controller;
            // Larger is better: strength, then incumbency, then lower ids.
            (
                c.strength,
                Some(c.writer) == incumbent,
                std::cmp::Reverse((c.device, c.writer)),
            )
        };
        self.sources
            .iter()
            .filter(|s| self.is_eligible(s, now))
            .max_by_key(|s| rank(s))
            .map_or(Owner::Failsafe, |s| Owner::Controller(s.controller))
    }

    /// Why `before` lost (or the failsafe gave up) ownership in this step.
    fn reason(&self, before: Owner, event: &Event, now: MonoTime) -> Reason {
        if let Owner::Controller(c) = before {
            match self.find(c.writer).map(|i| &self.sources[i]) {
                None => return Reason::Left,
                Some(s) if s.presence == Presence::Released => return Reason::Released,
                Some(s) if !s.watchdog.is_live(now) => return Reason::TimedOut,
                Some(_) => {}
            }
        }
        let after_is_grant = match self.select(now) {
            Owner::Controller(c) => is_grant_stream(&c, self.grant),
            Owner::Failsafe => false,
        };
        match event {
            Event::GrantAccepted { .. } => Reason::Granted,
            _ if after_is_grant => Reason::Granted,
            Event::GrantFinished { .. } => Reason::GrantReturned,
            _ if before == Owner::Failsafe => Reason::Joined,
            _ => Reason::Preempted,
        }
    }

    fn owner_source(&self) -> Option<&Source> {
        self.owner
            .writer()
            .and_then(|w| self.find(w))
            .map(|i| &self.sources[i])
    }

    /// The output for the current owner: its fresh values, or the safe state when the failsafe
    /// owns or the owner has no fresh values (only keep-alives lately).
    fn output_for_owner(&mut self) -> Output {
        self.seq += 1;
        let seq = self.seq;
        let now = self.last_now;
        let timeout = self.config.command_timeout;
        let values = match self.owner {
            Owner::Failsafe => None,
            Owner::Controller(c) => self
                .owner_source()
                .and_then(|s| s.fresh_setpoint(now, timeout))
                .map(|setpoint| (c, setpoint)),
        };
        self.driving = values.is_some();
        match values {
            Some((by, setpoint)) => Output::Apply { by, setpoint, seq },
            None => Output::SafeState {
                owner: self.owner,
                seq,
            },
        }
    }
}

/// Why a sample was not recorded.
enum Rejected {
    Ignored(Ignored),
    Suspect(Suspect),
}

impl From<Ignored> for Rejected {
    fn from(why: Ignored) -> Self {
        Rejected::Ignored(why)
    }
}

impl From<Suspect> for Rejected {
    fn from(suspect: Suspect) -> Self {
        Rejected::Suspect(suspect)
    }
}

impl Decision {
    fn distrust(&mut self, suspect: Suspect) {
        self.ignored = Some(Ignored::Untrusted);
        self.suspect = Some(suspect);
    }
}

/// True if `c` is a priority stream of the device holding `grant`.
fn is_grant_stream(c: &Controller, grant: Option<DeviceId>) -> bool {
    c.strength == Strength::PRIORITY && grant == Some(c.device)
}
