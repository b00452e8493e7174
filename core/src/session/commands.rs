//! Commands: what a person asks for (console, local API, buttons), and how the session
//! carries it out.

use super::{DriveReason, Effect, OperatorSession, Out, Report, Writer};
use crate::adapter::InputAction;
use crate::msg::{DeviceId, Mode, TimeT};
use crate::time::MonoTime;

/// What a front end (the console's keys, joystick buttons, an API client) asks the operator to
/// do: the single path by which a person changes what the operator does.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Command {
    /// Make `vehicle` the one that buttons act on. Moves nothing.
    Select {
        /// The vehicle.
        vehicle: DeviceId,
    },
    /// Start driving `vehicle` (it must be free: its failsafe or this operator owns it).
    Drive {
        /// The vehicle.
        vehicle: DeviceId,
    },
    /// Stop driving (explicit release; a held grant is finished). `None`: every vehicle.
    Release {
        /// The vehicle, or `None` for all.
        vehicle: Option<DeviceId>,
    },
    /// Ask the owner of `vehicle` for control (REQUEST).
    Request {
        /// The vehicle.
        vehicle: DeviceId,
    },
    /// Accept the open request for `vehicle` (ACCEPT): the requester drives it.
    Accept {
        /// The vehicle.
        vehicle: DeviceId,
    },
    /// Refuse the open request for `vehicle` (REFUSE).
    Refuse {
        /// The vehicle.
        vehicle: DeviceId,
    },
    /// Give back the grant held for `vehicle` (FINISH).
    Finish {
        /// The vehicle.
        vehicle: DeviceId,
    },
    /// Send `mode`. `None`: to every vehicle this operator drives (the operator has one mode).
    Mode {
        /// The vehicle, or `None` for all driven ones.
        vehicle: Option<DeviceId>,
        /// The mode.
        mode: Mode,
    },
}

impl Command {
    /// The command's name as the local API spells it (`"drive"`, `"release"`, …).
    pub fn name(&self) -> &'static str {
        match self {
            Command::Select { .. } => "select",
            Command::Drive { .. } => "drive",
            Command::Release { .. } => "release",
            Command::Request { .. } => "request",
            Command::Accept { .. } => "accept",
            Command::Refuse { .. } => "refuse",
            Command::Finish { .. } => "finish",
            Command::Mode { .. } => "mode",
        }
    }
}

impl OperatorSession {
    /// A button or key without the console: the command it means for the selected vehicle.
    pub(super) fn action_to_command(
        &mut self,
        action: InputAction,
        out: &mut Out,
    ) -> Option<Command> {
        let selected = self.selected;
        match action {
            InputAction::Mode(mode) => Some(Command::Mode {
                vehicle: None,
                mode,
            }),
            InputAction::NextVehicle | InputAction::PreviousVehicle => {
                let ids: Vec<DeviceId> = self.vehicles.keys().copied().collect();
                let at = selected.and_then(|s| ids.iter().position(|&v| v == s));
                let next = match (action, at) {
                    (_, None) => ids.first().copied(),
                    (InputAction::NextVehicle, Some(i)) => ids.get((i + 1) % ids.len()).copied(),
                    (_, Some(i)) => ids.get((i + ids.len() - 1) % ids.len()).copied(),
                };
                self.selected = next;
                out.report(Report::Selected { vehicle: next });
                None
            }
            InputAction::RequestControl => selected.map(|vehicle| Command::Request { vehicle }),
            InputAction::Accept => self.prompt.map(|vehicle| Command::Accept { vehicle }),
            InputAction::Refuse => self.prompt.map(|vehicle| Command::Refuse { vehicle }),
            InputAction::Finish => {
                let held = (selected.filter(|&s| self.roles.holds_grant(s)))
                    .or_else(|| self.roles.granted().next());
                held.map(|vehicle| Command::Finish { vehicle })
            }
            InputAction::Release => Some(Command::Release { vehicle: selected }),
        }
    }

    pub(super) fn on_command(
        &mut self,
        now: MonoTime,
        stamp: TimeT,
        command: Command,
        out: &mut Out,
    ) {
        match command {
            Command::Select { vehicle } => {
                self.selected = Some(vehicle);
                out.report(Report::Selected {
                    vehicle: Some(vehicle),
                });
            }
            Command::Mode { mode, .. } => {
                self.mode = mode;
                out.report(Report::ModeSelected { mode });
                self.send_driven(stamp, out);
            }
            Command::Drive { vehicle } => self.command_drive(vehicle, stamp, out),
            Command::Release { vehicle } => self.command_release(vehicle, stamp, out),
            Command::Request { vehicle } => match self.owner_of(vehicle) {
                None => out.refuse(format!("vehicle {vehicle} has not been seen")),
                Some(owner) if owner == vehicle || owner == self.me => {
                    self.command_drive(vehicle, stamp, out);
                }
                Some(owner) => match self.handover.request(now, vehicle, owner, stamp) {
                    Ok(actions) => {
                        out.report(Report::RequestSent { vehicle, owner });
                        self.push_actions(stamp, actions, out);
                    }
                    Err(e) => out.refuse(format!("cannot request {vehicle}: {e}")),
                },
            },
            Command::Accept { vehicle } | Command::Refuse { vehicle } => {
                // Only what we still own can be given: a prompt answered after we released
                // the vehicle (or lost it) is refused, or the requester would hold a grant the
                // vehicle never honours.
                let ours = self.owner_of(vehicle) == Some(self.me);
                let wanted = matches!(command, Command::Accept { .. });
                match self.handover.decide(now, vehicle, wanted && ours) {
                    Ok(actions) => {
                        self.push_actions(stamp, actions, out);
                        if wanted && !ours {
                            out.refuse(format!(
                                "vehicle {vehicle} is no longer ours to give: the request was \
                                 refused"
                            ));
                        }
                    }
                    Err(e) => out.refuse(format!("no answer taken for {vehicle}: {e}")),
                }
            }
            Command::Finish { vehicle } => match self.handover.finish(vehicle) {
                Ok(actions) => self.push_actions(stamp, actions, out),
                Err(e) => out.refuse(format!("cannot finish {vehicle}: {e}")),
            },
        }
    }

    /// The owner `vehicle`'s last DeviceInfo names, if it has been seen.
    fn owner_of(&self, vehicle: DeviceId) -> Option<DeviceId> {
        self.vehicles.get(&vehicle).map(|i| i.controller_id)
    }

    /// `drive`: a free vehicle (its failsafe or we own it) is driven; one we drive already
    /// stays as it is.
    fn command_drive(&mut self, vehicle: DeviceId, stamp: TimeT, out: &mut Out) {
        if self.streams_to(vehicle) {
            return;
        }
        match self.owner_of(vehicle) {
            None => out.refuse(format!("vehicle {vehicle} has not been seen")),
            Some(owner) if owner != vehicle && owner != self.me => out.refuse(format!(
                "vehicle {vehicle} is driven by {owner}: request control instead"
            )),
            Some(_) => {
                // Still ours after we yielded it (the holder never took over): the person
                // takes it back, so the standby ends and a late FINISH is moot.
                let standby = self.roles.end_yield(vehicle);
                let probing = self.handover.resume(vehicle) && standby == Some(true);
                self.selected = Some(vehicle);
                out.report(Report::Driving {
                    vehicle,
                    why: DriveReason::Commanded,
                });
                self.drive_or_pause(vehicle, probing, stamp, out);
            }
        }
    }

    /// `release`: `vehicle` (`None`: every vehicle we drive, paused or hold a grant for) is no
    /// longer driven, explicitly, and a grant held for it is finished. A yielded vehicle stays
    /// yielded.
    fn command_release(&mut self, vehicle: Option<DeviceId>, stamp: TimeT, out: &mut Out) {
        let targets: Vec<DeviceId> = match vehicle {
            Some(v) => vec![v],
            None => (self.roles.driving_ones())
                .chain(self.roles.granted())
                .collect(),
        };
        for v in targets {
            out.report(Report::Released { vehicle: v });
            // A paused vehicle was released when the input went: nothing to release again.
            if self.roles.stop_driving(v) && self.input_live {
                out.push(Effect::Release {
                    writer: Writer::Regular,
                    vehicle: v,
                });
            }
            if self.roles.holds_grant(v) {
                let actions = self.handover.finish(v).unwrap_or_default();
                self.push_actions(stamp, actions, out);
            }
        }
    }
}
