//! The arbiter's vocabulary: its inputs ([`Event`]), what a step decides ([`Decision`] with
//! [`OwnerChange`], [`Output`], [`Ignored`]), who drives ([`Owner`], [`Controller`]) and its
//! settings ([`ArbiterConfig`]).

use super::{ParticipantId, WriterId};
use crate::hierarchy::Strength;
use crate::msg::{Ack, ControlCommand, DeviceId, Mode, MovementCommand, RequestControl, TimeT};
use crate::time::MonoTime;
use crate::trust::{Suspect, TrustConfig};
use crate::watchdog::CommandTimeout;
use std::fmt;

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
