//! Active handover in the session: which REQUESTs are answered, and what the handover
//! machine's actions mean for our streams (prompts, grants, yield and standby, resumption).

use super::{Effect, OperatorSession, Out, Report, Writer};
use crate::handover::Action;
use crate::msg::{Ack, CommandType, RequestControl, TimeT};
use crate::time::MonoTime;

impl OperatorSession {
    /// A believed RequestControl: REQUESTs to us are answered only for a vehicle we drive and
    /// whose DeviceInfo names us (or while we answer that vehicle's request already), and a
    /// REQUEST's priority counts for auto-accept only if discovery agrees with it.
    pub(super) fn on_request_control(
        &mut self,
        now: MonoTime,
        stamp: TimeT,
        msg: &RequestControl,
        out: &mut Out,
    ) {
        let to_us = msg.current_controller_id == self.me && msg.src_id != self.me;
        if to_us && msg.ack == Ack::Request {
            let vehicle = msg.dest_id;
            let drives = self.roles.is_driving(vehicle) || self.roles.holds_grant(vehicle);
            let names_us =
                (self.vehicles.get(&vehicle)).is_some_and(|i| i.controller_id == self.me);
            if !(self.handover.is_replying(vehicle) || drives && names_us) {
                out.report(Report::RequestIgnored {
                    vehicle,
                    requester: msg.src_id,
                });
                return;
            }
        }
        let verified = (self.identities.owner(now, msg.src_id)).is_some_and(|p| {
            (self.writers.iter())
                .any(|(w, s)| w.participant == p && i32::from(s.0) == msg.src_priority)
        });
        let actions = self.handover.on_message_checked(now, msg, verified);
        self.push_actions(stamp, actions, out);
    }

    /// The handover machine's `actions` as this turn's effects (and prompts) in `out`.
    pub(super) fn push_actions(&mut self, stamp: TimeT, actions: Vec<Action>, out: &mut Out) {
        for action in actions {
            match action {
                Action::Send(msg) => out.push(Effect::Send(msg)),
                Action::AskOperator(prompt) => {
                    self.prompt = Some(prompt.vehicle);
                    out.report(Report::Prompt(prompt));
                }
                Action::PromptClosed { vehicle, outcome } => {
                    if self.prompt == Some(vehicle) {
                        self.prompt = None;
                    }
                    out.report(Report::PromptClosed { vehicle, outcome });
                }
                Action::RequestEnded { vehicle, outcome } => {
                    out.report(Report::RequestEnded { vehicle, outcome });
                }
                Action::StartPriorityDriving { vehicle } => {
                    self.roles.set_grant(vehicle, true);
                    out.report(Report::GrantStarted { vehicle });
                    if self.input_live {
                        out.write(
                            Writer::Priority,
                            self.command(vehicle, CommandType::Movement, stamp),
                        );
                    } else {
                        // The input was lost after the request went out: give the grant back
                        // at once, as a lost input does with the grants it holds, rather than
                        // drive the vehicle with the sticks the device last reported.
                        let finish = self.handover.finish(vehicle).unwrap_or_default();
                        self.push_actions(stamp, finish, out);
                    }
                }
                Action::StopPriorityDriving { vehicle } => {
                    self.roles.set_grant(vehicle, false);
                    out.report(Report::GrantEnded { vehicle });
                    out.push(Effect::Release {
                        writer: Writer::Priority,
                        vehicle,
                    });
                }
                Action::Yield { vehicle } => {
                    self.roles.yield_to_holder(vehicle, self.input_live);
                    out.report(Report::Yielded { vehicle });
                    if self.input_live {
                        out.write(
                            Writer::Regular,
                            self.command(vehicle, CommandType::Probe, stamp),
                        );
                    } else {
                        // No standby without live input: the vehicle must not fall back to
                        // us when the grant ends (see `stop_driving`).
                        out.push(Effect::Release {
                            writer: Writer::Regular,
                            vehicle,
                        });
                    }
                }
                Action::EndStandby { vehicle } => {
                    self.roles.end_standby(vehicle);
                    out.report(Report::StandbyEnded { vehicle });
                }
                Action::Resume { vehicle } => {
                    // Only a vehicle we yielded: never a role we did not hold.
                    if self.roles.end_yield(vehicle).is_none() {
                        continue;
                    }
                    let live = self.input_live;
                    out.report(Report::Resumed { vehicle, live });
                    self.drive_or_pause(vehicle, true, stamp, out);
                }
            }
        }
    }
}
