//! The per-vehicle ownership arbiter: who drives this vehicle, at every instant (docs/design.md §4).
//!
//! DDS's EXCLUSIVE ownership is not arbitrated by rustdds, so the vehicle does it here, as a pure
//! state machine: [`Arbiter::step`] takes `now` and one [`Event`] and returns a [`Decision`];
//! [`Arbiter::step_batch`] takes the samples of one read together, as one instant.
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
//!
//! # Layout
//! - this file: the source table, [`Arbiter`] and its step: re-arbitration and the output.
//! - `types.rs`: the arbiter's vocabulary: [`Event`] in, [`Decision`] out (with [`OwnerChange`],
//!   [`Output`], [`Ignored`]), [`Controller`], [`Owner`], [`Setpoint`], [`ArbiterConfig`].
//! - `record.rs`: how one event is recorded: samples, releases, departures, grants; the source
//!   table's admission and eviction.

mod record;
mod types;

pub use crate::sender::{ParticipantId, WriterId};
pub use types::{
    ArbiterConfig, Controller, Decision, Event, Ignored, Output, Owner, OwnerChange, Reason,
    Setpoint,
};

use crate::hierarchy::Strength;
use crate::msg::{DeviceId, TimeT};
use crate::time::MonoTime;
use crate::trust::{Access, Identities};
use crate::watchdog::{CommandTimeout, Watchdog};

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
        let now = self.advance(now);
        let before = self.owner;
        let mut decision = Decision::default();
        // `sampled` is the writer whose new values may need applying.
        let sampled = self.record(now, &event, &mut decision);
        self.reselect(now, before, &event, |w| sampled == Some(w), &mut decision);
        decision
    }

    /// Processes events taken together at `now` (one read of the command stream: samples and
    /// releases) as one step: every event is recorded before the owner is chosen again.
    ///
    /// Stepped one by one, a weaker controller's sample that comes first in such a batch,
    /// while the owner's last sample is a timeout old, hands it the vehicle and its values are
    /// applied; the owner's sample right behind it, taken at the same instant, takes the
    /// vehicle back: a weaker operator drove for one output although the owner was live all
    /// along. One decision per event, in order: each says what recording its event found
    /// (`ignored`, `suspect`), and the last also carries the owner change and the output, as
    /// [`Arbiter::step`] would after the whole batch. Grants are decided against the owner
    /// before the batch, so they belong in a step of their own.
    pub fn step_batch(&mut self, now: MonoTime, events: &[Event]) -> Vec<Decision> {
        let now = self.advance(now);
        let before = self.owner;
        let mut sampled = Vec::new();
        let mut decisions = Vec::with_capacity(events.len());
        for event in events {
            let mut decision = Decision::default();
            sampled.extend(self.record(now, event, &mut decision));
            decisions.push(decision);
        }
        if let (Some(last), Some(decision)) = (events.last(), decisions.last_mut()) {
            self.reselect(now, before, last, |w| sampled.contains(&w), decision);
        }
        decisions
    }

    /// `now`, or the latest `now` seen if the clock went backwards.
    fn advance(&mut self, now: MonoTime) -> MonoTime {
        let now = now.max(self.last_now);
        self.last_now = now;
        now
    }

    /// Re-arbitrates at `now` after `event` was recorded (the last of a batch), `before` owning
    /// until then; `sent_values` says whether a writer's new values were recorded.
    fn reselect(
        &mut self,
        now: MonoTime,
        before: Owner,
        event: &Event,
        sent_values: impl Fn(WriterId) -> bool,
        decision: &mut Decision,
    ) {
        let after = self.select(now);
        if after.writer() != before.writer() {
            let reason = self.reason(before, event, now);
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
            let owner_sent_values = after.writer().is_some_and(&sent_values);
            let values_lapsed = self.driving
                && self
                    .owner_source()
                    .and_then(|s| s.fresh_setpoint(now, self.config.command_timeout))
                    .is_none();
            if owner_sent_values || values_lapsed {
                decision.output = Some(self.output_for_owner());
            }
        }
    }

    /// The index of `writer`'s source, if it has one.
    fn find(&self, writer: WriterId) -> Option<usize> {
        self.sources
            .iter()
            .position(|s| s.controller.writer == writer)
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

/// True if `c` is a priority stream of the device holding `grant`.
fn is_grant_stream(c: &Controller, grant: Option<DeviceId>) -> bool {
    c.strength == Strength::PRIORITY && grant == Some(c.device)
}
