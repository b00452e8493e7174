//! The console's view model: what one operator knows about itself, the devices and the
//! handovers it takes part in, updated by [`Event`]s and stepped with an injected `now`.
//!
//! The operator role emits events (device samples, its own streams, handover actions, input
//! changes); [`ConsoleState::apply`] folds them into a state that the view draws and the key
//! handling reads. Nothing here reads a clock or does I/O; the state is `Clone`, so the API
//! server keeps its own mirror of it to greet late clients with a snapshot.
//!
//! # Layout
//! - this file: [`ConsoleState`], its bounds, what it answers (labels, the prompt shown first)
//!   and its snapshot as events.
//! - `event.rs`: what the operator role reports: [`Event`], [`Stamped`].
//! - `parts.rs`: what the state is made of: [`Identity`], [`Device`], [`VehicleView`],
//!   [`MyRole`], [`InputStatus`], log lines, requests, confirmations.
//! - `apply.rs`: how an event folds into the state ([`ConsoleState::apply`]), and what time
//!   expires.

mod apply;
mod event;
mod parts;

pub use event::{Event, Stamped};
pub use parts::{
    Confirmation, Device, DeviceKind, Identity, IncomingRequest, InputStatus, LogEntry, Logged,
    MyRole, OutgoingRequest, VehicleView,
};

use rove_core::MonoTime;
use rove_core::handover::Prompt;
use rove_core::msg::DeviceId;
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

/// How a handover ended: the core's, as the API and the views spell it.
pub use rove_core::handover::Outcome;

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
    use rove_core::hierarchy::{DeviceClass, Level, Strength};
    use rove_core::msg::{Mode, OutputState, VehicleHealth};

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
