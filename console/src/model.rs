//! The console's view model: what one operator knows about itself, the devices and the
//! handovers it takes part in, updated by [`Event`]s and stepped with an injected `now`.
//!
//! The operator role emits events (device samples, its own streams, handover actions, input
//! changes); [`ConsoleState::apply`] folds them into a state that the view draws and the key
//! handling reads. Nothing here reads a clock or does I/O; the state is `Clone`, so the API
//! server keeps its own mirror of it to greet late clients with a snapshot.

use rove_core::MonoTime;
use rove_core::handover::Prompt;
use rove_core::hierarchy::{DeviceClass, Level, Strength};
use rove_core::msg::{DeviceId, DeviceType, Mode, MovementCommand, OutputState, VehicleHealth};
use std::collections::{BTreeMap, VecDeque};
use std::time::Duration;

/// Most log entries kept: a few hours of handovers at a busy station, and a bound on memory
/// for an operator that runs for weeks. Older entries are dropped first.
pub const LOG_CAPACITY: usize = 200;

/// Most devices the console remembers. A fleet has tens; beyond this a new device takes the
/// place of the one offline longest (never the selected one or one we stream to), or, with
/// none offline, is not shown: a flood of invented ids cannot grow the table.
pub const MAX_DEVICES: usize = 1024;

/// Most statuses kept of vehicles not seen yet (a status can arrive before the vehicle's
/// DeviceInfo: the topics are matched and repaired apart). Beyond it, one of an unseen vehicle
/// is dropped: a flood of invented ids cannot grow the table.
pub const MAX_EARLY_STATUSES: usize = 64;

/// How long a confirmation prompt stays open: long enough to read it, short enough that a
/// forgotten prompt cannot be confirmed by a stray key much later, when the situation on
/// screen has changed.
pub const CONFIRM_TIMEOUT: Duration = Duration::from_secs(10);

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

/// How a handover ended: the core's, as the API and the views spell it.
pub use rove_core::handover::Outcome;

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

/// Something the operator role reports to the console and to API clients.
///
/// Each maps to one thing `rove operator` already knows: a DeviceInfo sample or disposal, a
/// change of its own streams, a handover [`rove_core::handover::Action`], an input event.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Event {
    /// Who we are (send once at start).
    Identity(Identity),
    /// A DeviceInfo sample: the device is present; for a vehicle, `owner` is its
    /// `controller_id` (the vehicle's own id when its failsafe owns it).
    DeviceSeen {
        /// Device id.
        id: DeviceId,
        /// Name.
        name: String,
        /// Vehicle or controller.
        kind: DeviceKind,
        /// `controller_id` of the sample.
        owner: DeviceId,
    },
    /// The device withdrew (its DeviceInfo was disposed): shown offline.
    DeviceGone {
        /// Device id.
        id: DeviceId,
    },
    /// What a vehicle reports beyond its owner (from a status topic, when there is one).
    VehicleStatus {
        /// The vehicle.
        vehicle: DeviceId,
        /// The owner this status was published under (VehicleStatus's `controller_id`).
        owner: DeviceId,
        /// Its current mode, if known.
        mode: Option<Mode>,
        /// Its outputs are in the safe state.
        failsafe: bool,
        /// Output-link health, e.g. `"ok"` or `"down: /dev/ttyACM0 gone"`.
        link: String,
        /// The output's state.
        output: OutputState,
        /// What its device says of the vehicle (battery, autopilot).
        health: VehicleHealth,
    },
    /// The owner of a vehicle changed, with the reason the operator knows.
    OwnerChanged {
        /// The vehicle.
        vehicle: DeviceId,
        /// Previous owner (the vehicle's id = failsafe).
        from: DeviceId,
        /// New owner.
        to: DeviceId,
        /// Why, e.g. `"grant accepted"`, `"released"`, `"reported by the vehicle"`.
        reason: String,
    },
    /// What this operator streams to now (a full snapshot; vehicles not listed: nothing).
    Driving {
        /// Driven with the regular writer.
        driving: Vec<DeviceId>,
        /// Driven with the priority writer (grants held).
        holding: Vec<DeviceId>,
        /// Yielded to a grant holder.
        standby: Vec<DeviceId>,
        /// Waiting for live input.
        paused: Vec<DeviceId>,
    },
    /// Someone asks us for a vehicle we own ([`rove_core::handover::Action::AskOperator`]).
    RequestIncoming(Prompt),
    /// The consent prompt for `vehicle` closed ([`rove_core::handover::Action::PromptClosed`]).
    PromptClosed {
        /// The vehicle.
        vehicle: DeviceId,
        /// How.
        outcome: Outcome,
    },
    /// We asked `owner` for `vehicle` (a REQUEST went out).
    RequestSent {
        /// The vehicle.
        vehicle: DeviceId,
        /// The owner asked.
        owner: DeviceId,
    },
    /// Our own request ended ([`rove_core::handover::Action::RequestEnded`]).
    RequestEnded {
        /// The vehicle.
        vehicle: DeviceId,
        /// How.
        outcome: Outcome,
    },
    /// The input's state changed (sticks, mode, deadman, link).
    Input(InputStatus),
    /// The vehicle that buttons and keys act on.
    Selected {
        /// `None`: nothing selected.
        vehicle: Option<DeviceId>,
    },
    /// A line for the log (a refused command, a warning).
    Notice {
        /// The text.
        text: String,
    },
    /// Time passed: devices go offline, prompts count down. Not sent to API clients.
    Tick,
}

/// An event with the time it happened: what the operator broadcasts.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Stamped {
    /// When (the operator's monotonic clock).
    pub at: MonoTime,
    /// What.
    pub event: Event,
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
    /// Announced within [`ConsoleState::offline_after`] and not withdrawn.
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
    /// When it opened; it closes by itself after [`CONFIRM_TIMEOUT`].
    pub opened: MonoTime,
}

/// Everything the console shows.
#[derive(Debug, Clone)]
pub struct ConsoleState {
    /// Who we are.
    pub identity: Identity,
    /// A device not announced for this long is shown offline (a backstop: the operator sends
    /// [`Event::DeviceGone`] when a device's participant leaves; three DeviceInfo refreshes, as
    /// `rove status` does).
    pub offline_after: Duration,
    /// Every device seen, by id (vehicles and controllers, including ourselves).
    pub devices: BTreeMap<DeviceId, Device>,
    /// What we do with each vehicle we stream to.
    pub mine: BTreeMap<DeviceId, MyRole>,
    /// The vehicle keys act on.
    pub selected: Option<DeviceId>,
    /// The input device.
    pub input: InputStatus,
    /// Ownership changes and notices, oldest first, at most [`LOG_CAPACITY`].
    pub log: VecDeque<LogEntry>,
    /// Requests waiting for our answer, by vehicle.
    pub incoming: BTreeMap<DeviceId, IncomingRequest>,
    /// Our requests waiting for an answer, by vehicle.
    pub outgoing: BTreeMap<DeviceId, OutgoingRequest>,
    /// The open confirmation prompt.
    pub confirm: Option<Confirmation>,
    /// The operator asked to quit (the terminal loop ends).
    pub quit: bool,
    /// The latest `now` applied.
    pub now: MonoTime,
    /// The last status of each vehicle whose DeviceInfo has not come yet, applied when it
    /// does. A vehicle publishes its status only when it changes, so one dropped here would be
    /// missing until the next change (seen: a console that never showed a vehicle's status).
    pub early_status: BTreeMap<DeviceId, Event>,
}

impl ConsoleState {
    /// Whether the device table may hold `id` at `now` (see [`MAX_DEVICES`]), making room if
    /// it must.
    fn has_room_for(&mut self, id: DeviceId, now: MonoTime) -> bool {
        if self.devices.len() < MAX_DEVICES || self.devices.contains_key(&id) {
            return true;
        }
        let offline = |d: &&Device| {
            (!d.online || now.saturating_since(d.last_seen) >= self.offline_after)
                && self.selected != Some(d.id)
                && !self.mine.contains_key(&d.id)
        };
        let oldest = (self.devices.values().filter(offline))
            .min_by_key(|d| d.last_seen)
            .map(|d| d.id);
        oldest.is_some_and(|old| self.devices.remove(&old).is_some())
    }

    /// An empty console for `identity`.
    pub fn new(identity: Identity, offline_after: Duration) -> Self {
        ConsoleState {
            identity,
            offline_after,
            devices: BTreeMap::new(),
            mine: BTreeMap::new(),
            selected: None,
            input: InputStatus::default(),
            log: VecDeque::new(),
            incoming: BTreeMap::new(),
            outgoing: BTreeMap::new(),
            confirm: None,
            quit: false,
            now: MonoTime::ZERO,
            early_status: BTreeMap::new(),
        }
    }

    /// Folds `event`, which happened at `now`, into the state.
    pub fn apply(&mut self, now: MonoTime, event: Event) {
        self.now = self.now.max(now);
        let Some(event) = self.unless_early_status(event) else {
            return;
        };
        match event {
            Event::Identity(identity) => self.identity = identity,
            Event::DeviceSeen { id, .. } if !self.has_room_for(id, now) => {}
            Event::DeviceSeen {
                id,
                name,
                kind,
                owner,
            } => self.device_seen(now, id, name, kind, owner),
            Event::DeviceGone { id } => {
                if let Some(d) = self.devices.get_mut(&id) {
                    d.online = false;
                }
            }
            Event::VehicleStatus {
                vehicle,
                owner,
                mode,
                failsafe,
                link,
                output,
                health,
            } => {
                if let Some(v) = self
                    .devices
                    .get_mut(&vehicle)
                    .and_then(|d| d.vehicle.as_mut())
                {
                    v.mode = mode;
                    v.failsafe = failsafe;
                    v.link = Some(link);
                    v.status_owner = Some(owner);
                    v.output = Some(output);
                    v.health = health;
                }
            }
            Event::OwnerChanged {
                vehicle,
                from,
                to,
                reason,
            } => {
                if let Some(v) = self
                    .devices
                    .get_mut(&vehicle)
                    .and_then(|d| d.vehicle.as_mut())
                {
                    v.owner = to;
                }
                self.log_owner(now, vehicle, from, to, reason);
            }
            Event::Driving {
                driving,
                holding,
                standby,
                paused,
            } => {
                self.mine.clear();
                for (ids, role) in [
                    (paused, MyRole::Paused),
                    (standby, MyRole::Standby),
                    (driving, MyRole::Driving),
                    (holding, MyRole::Holding),
                ] {
                    for id in ids {
                        self.mine.insert(id, role);
                    }
                }
            }
            Event::RequestIncoming(Prompt {
                vehicle,
                requester: from,
                src_priority,
                deadline,
            }) => self.request_incoming(now, vehicle, from, src_priority, deadline),
            Event::PromptClosed { vehicle, outcome } => {
                if let Some(req) = self.incoming.remove(&vehicle) {
                    let text = format!(
                        "request from {} for {}: {}",
                        self.label(req.from),
                        self.label(vehicle),
                        outcome.as_str().replace('_', " ")
                    );
                    self.note(now, text);
                }
            }
            Event::RequestSent { vehicle, owner } => {
                self.outgoing
                    .insert(vehicle, OutgoingRequest { owner, since: now });
                let text = format!(
                    "you asked {} for {}",
                    self.label(owner),
                    self.label(vehicle)
                );
                self.note(now, text);
            }
            Event::RequestEnded { vehicle, outcome } => {
                self.outgoing.remove(&vehicle);
                let text = format!(
                    "your request for {}: {}",
                    self.label(vehicle),
                    outcome.as_str().replace('_', " ")
                );
                self.note(now, text);
            }
            Event::Input(input) => self.input = input,
            Event::Selected { vehicle } => self.selected = vehicle,
            Event::Notice { text } => self.note(now, text),
            Event::Tick => {}
        }
        self.expire(now);
    }

    /// A device's DeviceInfo: listed (or updated), its owner change logged.
    /// A VehicleStatus of a vehicle not seen yet is kept for when it is (`early_status`);
    /// any other event is handed back.
    fn unless_early_status(&mut self, event: Event) -> Option<Event> {
        let Event::VehicleStatus { vehicle, .. } = event else {
            return Some(event);
        };
        if (self.devices.get(&vehicle)).is_some_and(|d| d.vehicle.is_some()) {
            return Some(event);
        }
        if self.early_status.contains_key(&vehicle) || self.early_status.len() < MAX_EARLY_STATUSES
        {
            self.early_status.insert(vehicle, event);
        }
        None
    }

    fn device_seen(
        &mut self,
        now: MonoTime,
        id: DeviceId,
        name: String,
        kind: DeviceKind,
        owner: DeviceId,
    ) {
        let previous = self
            .devices
            .get(&id)
            .and_then(|d| d.vehicle.as_ref())
            .map(|v| v.owner);
        if let Some(from) = previous.filter(|&from| from != owner) {
            self.log_owner(now, id, from, owner, "reported by the vehicle".into());
        }
        let device = self.devices.entry(id).or_insert_with(|| Device {
            id,
            name: name.clone(),
            kind,
            online: true,
            last_seen: now,
            vehicle: None,
        });
        device.name = name;
        device.kind = kind;
        device.online = true;
        device.last_seen = now;
        device.vehicle = match (kind, device.vehicle.take()) {
            (DeviceKind::Controller, _) => None,
            (DeviceKind::Vehicle, Some(v)) => Some(VehicleView { owner, ..v }),
            (DeviceKind::Vehicle, None) => Some(VehicleView::new(owner)),
        };
        if self.selected.is_none() && kind == DeviceKind::Vehicle {
            self.selected = Some(id);
        }
        if kind == DeviceKind::Vehicle
            && let Some(status) = self.early_status.remove(&id)
        {
            self.apply(now, status);
        }
    }

    /// Another operator asks for a vehicle we hold: the question, shown.
    fn request_incoming(
        &mut self,
        now: MonoTime,
        vehicle: DeviceId,
        from: DeviceId,
        src_priority: i32,
        deadline: MonoTime,
    ) {
        // A question about another vehicle now covers the screen: a "yes" meant for the
        // hidden confirmation must not land on it, nor the other way round.
        self.confirm = None;
        self.incoming.insert(
            vehicle,
            IncomingRequest {
                vehicle,
                from,
                src_priority,
                deadline,
                opened: now,
            },
        );
        let text = format!("{} asks for {}", self.label(from), self.label(vehicle));
        self.note(now, text);
    }

    /// Time-driven changes: devices go offline, stale confirmations close.
    fn expire(&mut self, now: MonoTime) {
        for d in self.devices.values_mut() {
            if now.saturating_since(d.last_seen) >= self.offline_after {
                d.online = false;
            }
        }
        if self
            .confirm
            .as_ref()
            .is_some_and(|c| now.saturating_since(c.opened) >= CONFIRM_TIMEOUT)
        {
            self.confirm = None;
        }
    }

    fn log_owner(
        &mut self,
        at: MonoTime,
        vehicle: DeviceId,
        from: DeviceId,
        to: DeviceId,
        reason: String,
    ) {
        self.push_log(LogEntry {
            at,
            what: Logged::Owner {
                vehicle,
                from,
                to,
                reason,
            },
        });
    }

    fn note(&mut self, at: MonoTime, text: String) {
        self.push_log(LogEntry {
            at,
            what: Logged::Note(text),
        });
    }

    fn push_log(&mut self, entry: LogEntry) {
        while self.log.len() >= LOG_CAPACITY {
            self.log.pop_front();
        }
        self.log.push_back(entry);
    }

    /// `"name (id)"` for a known device, `"you (id)"` for ourselves, else the bare id.
    pub fn label(&self, id: DeviceId) -> String {
        if id == self.identity.id {
            return format!("you ({id})");
        }
        match self.devices.get(&id) {
            Some(d) => format!("{} ({id})", d.name),
            None => id.to_string(),
        }
    }

    /// Who drives a vehicle, as a short label: `"failsafe"` when it owns itself.
    pub fn owner_label(&self, vehicle: DeviceId, owner: DeviceId) -> String {
        if owner == vehicle {
            "failsafe".into()
        } else {
            self.label(owner)
        }
    }

    /// Vehicles in list order (by id), for selection.
    pub fn vehicles(&self) -> impl Iterator<Item = &Device> {
        self.devices
            .values()
            .filter(|d| d.kind == DeviceKind::Vehicle)
    }

    /// The open consent prompt shown first: the one with the earliest deadline.
    pub fn prompt(&self) -> Option<&IncomingRequest> {
        self.incoming.values().min_by_key(|r| r.deadline)
    }

    /// A snapshot of the state as events, so that a client that connects late sees the same
    /// state as one that was there from the start (minus the log). Device events carry their
    /// device's last-seen time; the rest the latest `now`.
    pub fn snapshot(&self) -> Vec<Stamped> {
        let now = self.now;
        let at_now = |event| Stamped { at: now, event };
        let mut events = vec![at_now(Event::Identity(self.identity.clone()))];
        for d in self.devices.values() {
            events.push(Stamped {
                at: d.last_seen,
                event: Event::DeviceSeen {
                    id: d.id,
                    name: d.name.clone(),
                    kind: d.kind,
                    owner: d.vehicle.as_ref().map_or(d.id, |v| v.owner),
                },
            });
            if let Some(v) = &d.vehicle
                && let (Some(link), Some(output)) = (&v.link, v.output)
            {
                events.push(at_now(Event::VehicleStatus {
                    vehicle: d.id,
                    owner: v.status_owner.unwrap_or(v.owner),
                    mode: v.mode,
                    failsafe: v.failsafe,
                    link: link.clone(),
                    output,
                    health: v.health.clone(),
                }));
            }
            if !d.online {
                events.push(at_now(Event::DeviceGone { id: d.id }));
            }
        }
        let role = |r: MyRole| -> Vec<DeviceId> {
            self.mine
                .iter()
                .filter(|(_, m)| **m == r)
                .map(|(id, _)| *id)
                .collect()
        };
        events.push(at_now(Event::Driving {
            driving: role(MyRole::Driving),
            holding: role(MyRole::Holding),
            standby: role(MyRole::Standby),
            paused: role(MyRole::Paused),
        }));
        events.push(at_now(Event::Input(self.input.clone())));
        events.push(at_now(Event::Selected {
            vehicle: self.selected,
        }));
        for req in self.incoming.values() {
            events.push(Stamped {
                at: req.opened,
                event: Event::RequestIncoming(Prompt {
                    vehicle: req.vehicle,
                    requester: req.from,
                    src_priority: req.src_priority,
                    deadline: req.deadline,
                }),
            });
        }
        for (&vehicle, req) in &self.outgoing {
            events.push(Stamped {
                at: req.since,
                event: Event::RequestSent {
                    vehicle,
                    owner: req.owner,
                },
            });
        }
        events
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    pub(crate) fn me() -> Identity {
        Identity {
            id: 1,
            name: "laptop-1".into(),
            level: Level::Mobile,
            class: DeviceClass::Laptop,
            strength: Strength(320),
        }
    }

    pub(crate) fn ms(t: u64) -> MonoTime {
        MonoTime::from_millis(t)
    }

    pub(crate) fn seen(id: DeviceId, name: &str, kind: DeviceKind, owner: DeviceId) -> Event {
        Event::DeviceSeen {
            id,
            name: name.into(),
            kind,
            owner,
        }
    }

    #[test]
    fn the_device_table_stays_bounded_and_makes_room_only_from_offline_devices() {
        let mut s = ConsoleState::new(me(), Duration::from_secs(3));
        s.apply(ms(0), seen(100, "rover-1", DeviceKind::Vehicle, 100));
        let flood = |s: &mut ConsoleState, t: u64, first: DeviceId| {
            for id in first..first + MAX_DEVICES as DeviceId {
                s.apply(ms(t), seen(id, "x", DeviceKind::Controller, id));
            }
        };
        // All online: the table fills and the rest are not remembered.
        flood(&mut s, 10, 10_000);
        assert_eq!(s.devices.len(), MAX_DEVICES);
        assert!(
            !s.devices
                .contains_key(&(10_000 + MAX_DEVICES as DeviceId - 1))
        );
        // Once they are offline, newcomers take their places; the selected vehicle stays.
        flood(&mut s, 5_000, 20_000);
        assert_eq!(s.devices.len(), MAX_DEVICES);
        assert!(
            s.devices
                .contains_key(&(20_000 + MAX_DEVICES as DeviceId - 2))
        );
        assert!(
            s.devices.contains_key(&100),
            "the selected vehicle was forgotten"
        );
    }

    #[test]
    fn devices_go_offline_after_silence_and_on_withdrawal() {
        let mut s = ConsoleState::new(me(), Duration::from_secs(3));
        s.apply(ms(0), seen(100, "rover-1", DeviceKind::Vehicle, 100));
        s.apply(ms(0), seen(2, "tablet-2", DeviceKind::Controller, 2));
        assert!(s.devices[&100].online);
        s.apply(ms(2_999), Event::Tick);
        assert!(s.devices[&100].online);
        s.apply(ms(3_000), Event::Tick);
        assert!(!s.devices[&100].online);
        s.apply(ms(3_100), seen(100, "rover-1", DeviceKind::Vehicle, 100));
        assert!(s.devices[&100].online);
        s.apply(ms(3_200), Event::DeviceGone { id: 100 });
        assert!(!s.devices[&100].online);
        assert_eq!(s.selected, Some(100), "the first vehicle seen is selected");
    }

    #[test]
    fn owner_changes_are_logged_once_with_their_reason() {
        let mut s = ConsoleState::new(me(), Duration::from_secs(3));
        s.apply(ms(0), seen(100, "rover-1", DeviceKind::Vehicle, 100));
        s.apply(
            ms(10),
            Event::OwnerChanged {
                vehicle: 100,
                from: 100,
                to: 1,
                reason: "you started driving".into(),
            },
        );
        // The vehicle then confirms: no second entry.
        s.apply(ms(20), seen(100, "rover-1", DeviceKind::Vehicle, 1));
        // A change only the vehicle tells us about is logged as such.
        s.apply(ms(30), seen(100, "rover-1", DeviceKind::Vehicle, 7));
        let owners: Vec<_> = s
            .log
            .iter()
            .filter_map(|e| match &e.what {
                Logged::Owner {
                    from, to, reason, ..
                } => Some((*from, *to, reason.as_str())),
                Logged::Note(_) => None,
            })
            .collect();
        assert_eq!(
            owners,
            [
                (100, 1, "you started driving"),
                (1, 7, "reported by the vehicle")
            ]
        );
        assert!(s.standing(100).is_some_and(|st| !st.is_safe()));
    }

    #[test]
    fn log_is_bounded() {
        let mut s = ConsoleState::new(me(), Duration::from_secs(3));
        for i in 0..(LOG_CAPACITY as u64 + 50) {
            s.apply(
                ms(i),
                Event::Notice {
                    text: i.to_string(),
                },
            );
        }
        assert_eq!(s.log.len(), LOG_CAPACITY);
        assert_eq!(s.log.front().map(|e| e.at), Some(ms(50)));
    }

    #[test]
    fn an_incoming_request_closes_a_pending_confirmation() {
        let mut s = ConsoleState::new(me(), Duration::from_secs(3));
        s.confirm = Some(Confirmation {
            command: crate::Command::Drive { vehicle: 100 },
            question: "Drive?".into(),
            opened: ms(0),
        });
        s.apply(
            ms(5),
            Event::RequestIncoming(Prompt {
                vehicle: 101,
                requester: 2,
                src_priority: 330,
                deadline: ms(10_005),
            }),
        );
        assert_eq!(s.confirm, None);
        assert_eq!(s.prompt().map(|r| r.from), Some(2));
        s.apply(
            ms(6),
            Event::PromptClosed {
                vehicle: 101,
                outcome: Outcome::Refused,
            },
        );
        assert_eq!(s.prompt(), None);
    }

    #[test]
    fn a_status_that_comes_before_its_vehicle_is_shown_once_the_vehicle_is_seen() {
        let mut s = ConsoleState::new(me(), Duration::from_secs(3));
        let status_of = |vehicle: DeviceId, link: &str| Event::VehicleStatus {
            vehicle,
            owner: 7,
            mode: Some(Mode::Manual),
            failsafe: false,
            link: link.into(),
            output: OutputState::Ok,
            health: VehicleHealth::UNKNOWN,
        };
        let status = |link: &str| status_of(100, link);
        s.apply(ms(0), status("first"));
        s.apply(ms(1), status("ok"));
        assert!(
            !s.devices.contains_key(&100),
            "not shown before its DeviceInfo"
        );
        s.apply(ms(2), seen(100, "rover-1", DeviceKind::Vehicle, 7));
        let v = s.devices[&100].vehicle.clone().expect("a vehicle");
        assert_eq!(v.link.as_deref(), Some("ok"), "the latest early status");
        assert!(s.early_status.is_empty());
        let replayed = s
            .snapshot()
            .into_iter()
            .any(|e| matches!(e.event, Event::VehicleStatus { ref link, .. } if link == "ok"));
        assert!(replayed, "a late API client gets it in the snapshot");
        // Invented vehicles cannot grow the table.
        for id in 1000..1000 + 2 * MAX_EARLY_STATUSES as DeviceId {
            s.apply(ms(3), status_of(id, "x"));
        }
        assert_eq!(s.early_status.len(), MAX_EARLY_STATUSES);
    }

    #[test]
    fn snapshot_replays_to_the_same_state() {
        let mut s = ConsoleState::new(me(), Duration::from_secs(3));
        s.apply(ms(0), seen(100, "rover-1", DeviceKind::Vehicle, 7));
        s.apply(ms(0), seen(101, "rover-2", DeviceKind::Vehicle, 1));
        s.apply(
            ms(0),
            Event::Driving {
                driving: vec![101],
                holding: vec![],
                standby: vec![],
                paused: vec![],
            },
        );
        s.apply(
            ms(1),
            Event::RequestIncoming(Prompt {
                vehicle: 101,
                requester: 2,
                src_priority: 330,
                deadline: ms(10_000),
            }),
        );
        let mut copy = ConsoleState::new(me(), Duration::from_secs(3));
        for e in s.snapshot() {
            copy.apply(e.at, e.event);
        }
        assert_eq!(copy.devices, s.devices);
        assert_eq!(copy.mine, s.mine);
        assert_eq!(copy.incoming, s.incoming);
        assert_eq!(copy.selected, s.selected);
    }
}
