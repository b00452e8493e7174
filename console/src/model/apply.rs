//! How an event folds into the console state ([`ConsoleState::apply`]): devices listed and
//! bounded, early statuses kept, requests and the log updated; and what time expires.

use super::{
    CONFIRM_TIMEOUT, ConsoleState, Device, DeviceKind, Event, IncomingRequest, LOG_CAPACITY,
    LogEntry, Logged, MAX_DEVICES, MAX_EARLY_STATUSES, MyRole, OutgoingRequest, VehicleView,
};
use rove_core::MonoTime;
use rove_core::handover::Prompt;
use rove_core::msg::DeviceId;

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
}
