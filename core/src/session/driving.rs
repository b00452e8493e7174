//! Streaming and input liveness: samples on every input change and keep-alive, release and
//! pause when the input cannot be trusted, and what the session streams to.

use super::{DriveReason, Effect, OperatorSession, Out, Report, Streams, Writer};
use crate::adapter::InputEvent;
use crate::msg::{CommandType, ControlCommand, DeviceId, TimeT};
use crate::time::MonoTime;

impl OperatorSession {
    /// What we stream to now.
    pub fn streams(&self) -> Streams {
        Streams {
            driving: self.driven().collect(),
            holding: self.roles.granted().collect(),
            standby: self.roles.standing_by().collect(),
            paused: self.paused().collect(),
        }
    }

    /// Whether a [`SessionEvent::StreamTick`](super::SessionEvent::StreamTick) has anything to
    /// send: a vehicle we drive, hold a grant for, or stand by for. An operator that streams
    /// nothing need not tick.
    pub fn streams_anything(&self) -> bool {
        self.driven().next().is_some()
            || self.roles.granted().next().is_some()
            || self.roles.standing_by().next().is_some()
    }

    /// Whether we send samples to `vehicle` (regular or priority writer).
    pub fn streams_to(&self, vehicle: DeviceId) -> bool {
        (self.input_live && self.roles.is_driving(vehicle)) || self.roles.holds_grant(vehicle)
    }

    /// The `STATUS=` line, e.g. `driving 100; holding a grant for 101; 3 vehicles seen`.
    pub fn status_line(&self) -> String {
        let list = |ids: &[DeviceId]| {
            ids.iter()
                .map(DeviceId::to_string)
                .collect::<Vec<_>>()
                .join(", ")
        };
        let streams = self.streams();
        let mut parts = Vec::new();
        if !self.streams_anything() {
            parts.push("driving nothing".to_string());
        }
        if !streams.driving.is_empty() {
            parts.push(format!("driving {}", list(&streams.driving)));
        }
        if !streams.holding.is_empty() {
            parts.push(format!("holding a grant for {}", list(&streams.holding)));
        }
        if !streams.standby.is_empty() {
            parts.push(format!("standing by for {}", list(&streams.standby)));
        }
        parts.push(match self.vehicles.len() {
            1 => "1 vehicle seen".to_string(),
            n => format!("{n} vehicles seen"),
        });
        parts.join("; ")
    }

    /// The vehicles driven with the regular writer now: ours on it, while the input is live.
    fn driven(&self) -> impl Iterator<Item = DeviceId> + '_ {
        (self.roles.driving_ones()).filter(|_| self.input_live)
    }

    /// The vehicles paused: ours on the regular writer, while the input is not live.
    fn paused(&self) -> impl Iterator<Item = DeviceId> + '_ {
        (self.roles.driving_ones()).filter(|_| !self.input_live)
    }

    /// Our sample of `kind` for `vehicle`, with the current sticks and mode.
    pub(super) fn command(
        &self,
        vehicle: DeviceId,
        kind: CommandType,
        stamp: TimeT,
    ) -> ControlCommand {
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
    pub(super) fn send_driven(&self, stamp: TimeT, out: &mut Out) {
        for v in self.driven() {
            out.write(
                Writer::Regular,
                self.command(v, CommandType::Movement, stamp),
            );
        }
        for v in self.roles.granted() {
            out.write(
                Writer::Priority,
                self.command(v, CommandType::Movement, stamp),
            );
        }
    }

    /// A PROBE to every vehicle we stand by for.
    pub(super) fn send_probes(&self, stamp: TimeT, out: &mut Out) {
        for v in self.roles.standing_by() {
            out.write(Writer::Regular, self.command(v, CommandType::Probe, stamp));
        }
    }

    pub(super) fn on_input(
        &mut self,
        now: MonoTime,
        stamp: TimeT,
        event: InputEvent,
        out: &mut Out,
    ) {
        match event {
            InputEvent::Axes(movement) => {
                self.movement = movement;
                if !self.input_live {
                    // The paused vehicles are driven again.
                    self.input_live = true;
                    let vehicles = self.roles.driving_ones().collect();
                    out.report(Report::InputLive { vehicles });
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
    /// hand over at once (they stay ours, paused); grants are finished. Driving resumes on live
    /// input.
    fn stop_driving(&mut self, why: &str, stamp: TimeT, out: &mut Out) {
        if !self.input_live {
            return;
        }
        self.input_live = false;
        let regular: Vec<DeviceId> = self.roles.driving_ones().collect();
        for &v in &regular {
            out.push(Effect::Release {
                writer: Writer::Regular,
                vehicle: v,
            });
        }
        // Vehicles we stand by for: our PROBEs would make the vehicle fall back to us (and to
        // our last values) when the grant ends, but we cannot drive. Stop them and release;
        // the yield itself stands, so the grant's end still brings them back to us (paused
        // until the input is live).
        for v in self.roles.end_standby_all() {
            out.push(Effect::Release {
                writer: Writer::Regular,
                vehicle: v,
            });
        }
        out.report(Report::InputNotLive {
            reason: why.to_string(),
            vehicles: regular,
        });
        let granted: Vec<DeviceId> = self.roles.granted().collect();
        for v in granted {
            let actions = self.handover.finish(v).unwrap_or_default();
            self.push_actions(stamp, actions, out);
        }
    }

    /// Drives `vehicle` with the regular writer now, or once the input is live.
    pub(super) fn drive(
        &mut self,
        vehicle: DeviceId,
        why: DriveReason,
        stamp: TimeT,
        out: &mut Out,
    ) {
        out.report(Report::Driving { vehicle, why });
        self.drive_or_pause(vehicle, false, stamp, out);
    }

    /// Streams to `vehicle` now if the input is live, else pauses it until it is. `probing`:
    /// our standby PROBEs kept us live on the vehicle, so a pause releases it, and the vehicle
    /// hands over at once rather than after a command timeout.
    pub(super) fn drive_or_pause(
        &mut self,
        vehicle: DeviceId,
        probing: bool,
        stamp: TimeT,
        out: &mut Out,
    ) {
        self.roles.drive(vehicle);
        if self.input_live {
            out.write(
                Writer::Regular,
                self.command(vehicle, CommandType::Movement, stamp),
            );
        } else if probing {
            out.push(Effect::Release {
                writer: Writer::Regular,
                vehicle,
            });
        }
    }
}
