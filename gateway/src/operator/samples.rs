//! What the operator heard → session events, and what the front ends are shown of it. Who sent
//! a message is the participant it came from ([`Heard`] carries it), never a payload field;
//! what the session does not believe is not shown.

use super::Role;
use super::net::{Heard, Net};
use rove_console::Event;
use rove_console::model::DeviceKind;
use rove_core::arbiter::ParticipantId;
use rove_core::msg::{DeviceInfo, DeviceType, VehicleStatus};
use rove_core::session::{Effect, Report, SessionEvent};

impl<N: Net> Role<N> {
    /// One thing heard, to the session and the front ends.
    pub(super) fn on_heard(&mut self, heard: Heard) -> Vec<Effect> {
        match heard {
            Heard::Info { info, from } => self.on_device_info(info, from),
            Heard::InfoGone { id, from } => {
                // A withdrawal counts only from the participant that speaks for the device.
                let now = self.edges.clock.now();
                if self.session.speaks_for(now, id, from) {
                    self.ui.emit(Event::DeviceGone { id });
                }
                Vec::new()
            }
            Heard::Request { msg, from } => self.step(SessionEvent::RequestControl { msg, from }),
            Heard::Status { status, from } => {
                self.on_vehicle_status(&status, from);
                Vec::new()
            }
            Heard::Discovery(event) => {
                // A participant that left (quit, crashed, lost its link: its SPDP lease ran
                // out) takes the devices it spoke for off the lists at once.
                if let SessionEvent::ParticipantGone { participant } = event {
                    let now = self.edges.clock.now();
                    for id in self.session.devices_of(now, participant) {
                        self.ui.emit(Event::DeviceGone { id });
                    }
                }
                self.step(event)
            }
            Heard::Nothing => Vec::new(),
        }
    }

    /// A DeviceInfo: the session learns the device; the front ends see it if believed.
    fn on_device_info(&mut self, info: DeviceInfo, from: ParticipantId) -> Vec<Effect> {
        let vehicle = info.device_type == DeviceType::Vehicle;
        let seen = Event::DeviceSeen {
            id: info.device_id,
            name: info.name.clone(),
            kind: if vehicle {
                DeviceKind::Vehicle
            } else {
                DeviceKind::Controller
            },
            owner: info.controller_id,
        };
        let id = info.device_id;
        let effects = self.step(SessionEvent::DeviceInfo { info, from });
        // Shown only if believed; the session reports it otherwise.
        let untrusted = (effects.iter()).any(|e| matches!(e, Effect::Report(Report::Untrusted(_))));
        if !untrusted {
            self.ui.emit(seen);
            if vehicle {
                self.net.vehicle_seen(id, from);
            }
        }
        effects
    }

    /// A VehicleStatus: shown if it comes from the participant that speaks for the vehicle.
    fn on_vehicle_status(&mut self, status: &VehicleStatus, from: ParticipantId) {
        let now = self.edges.clock.now();
        if self.session.speaks_for(now, status.vehicle_id, from) {
            self.ui.emit(Event::VehicleStatus {
                vehicle: status.vehicle_id,
                owner: status.controller_id,
                mode: Some(status.mode),
                failsafe: status.failsafe,
                link: crate::status::output_text(status),
                output: status.output,
                health: status.health.clone(),
            });
        }
    }
}
