//! Vehicles seen and `--request`: DeviceInfo samples (a bounded table of vehicles), and asking
//! the `--request` vehicle's owner once it is known from a live sample.

use super::{DriveReason, MAX_VEHICLES, OperatorSession, Out, Report};
use crate::msg::{DeviceId, DeviceInfo, DeviceType, TimeT};
use crate::time::MonoTime;

impl OperatorSession {
    /// Whether the vehicle table may hold `vehicle` (see [`MAX_VEHICLES`]), making room if it
    /// must by forgetting vehicles that are neither pinned to a live participant nor ours in
    /// any way (driven, paused, standing by, held, yielded, selected, prompted or requested).
    fn has_room_for_vehicle(&mut self, now: MonoTime, vehicle: DeviceId) -> bool {
        if self.vehicles.len() < MAX_VEHICLES || self.vehicles.contains_key(&vehicle) {
            return true;
        }
        let ours = |v: &DeviceId| {
            self.roles.has(*v)
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

    pub(super) fn on_device_info(
        &mut self,
        now: MonoTime,
        stamp: TimeT,
        info: DeviceInfo,
        out: &mut Out,
    ) {
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
    pub(super) fn request_deadline(&self) -> Option<MonoTime> {
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
    pub(super) fn consider_request(&mut self, now: MonoTime, stamp: TimeT, out: &mut Out) {
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
}
