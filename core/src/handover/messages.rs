//! The handover's messages: what a received RequestControl does to the requester's and the
//! replier's state, the answer we give, and the RequestControl samples we send.

use super::{Action, Answer, AutoAccept, Handover, Outcome, Prompt, Replying, Requesting};
use crate::hierarchy::Strength;
use crate::msg::{Ack, DeviceId, RequestControl, TimeT};
use crate::time::MonoTime;

impl Handover {
    pub(super) fn as_requester(&mut self, msg: &RequestControl) -> Vec<Action> {
        let vehicle = msg.dest_id;
        let state = self.requests.get(&vehicle).copied();
        let hand_back = || {
            vec![self.as_requester_send(
                vehicle,
                msg.current_controller_id,
                Ack::Finish,
                msg.timestamp,
            )]
        };
        match (msg.ack, state) {
            (Ack::Accept, Some(Requesting::Waiting { owner, stamp, .. }))
                if owner == msg.current_controller_id && answers(msg.timestamp, stamp) =>
            {
                self.requests
                    .insert(vehicle, Requesting::Holding { owner, stamp });
                vec![
                    Action::StartPriorityDriving { vehicle },
                    Action::RequestEnded {
                        vehicle,
                        outcome: Outcome::Accepted,
                    },
                ]
            }
            (Ack::Refuse, Some(Requesting::Waiting { owner, stamp, .. }))
                if owner == msg.current_controller_id && answers(msg.timestamp, stamp) =>
            {
                self.requests.remove(&vehicle);
                vec![Action::RequestEnded {
                    vehicle,
                    outcome: Outcome::Refused,
                }]
            }
            // An ACCEPT nobody here is waiting for (we gave up, finished, or it answers an
            // earlier request): give it straight back so the vehicle does not keep a grant for
            // a stream that will never come. While we hold a grant, an ACCEPT is a duplicate or
            // stale and is left alone: handing it back would end our current grant.
            (Ack::Accept, None | Some(Requesting::Waiting { .. }))
                if self.first_stamp.is_some_and(|first| msg.timestamp >= first) =>
            {
                hand_back()
            }
            // REFUSE after giving up, answers from an owner we did not ask, and REQUEST/FINISH
            // echoes change nothing.
            _ => Vec::new(),
        }
    }

    pub(super) fn as_replier(
        &mut self,
        now: MonoTime,
        msg: &RequestControl,
        priority_verified: bool,
    ) -> Vec<Action> {
        let vehicle = msg.dest_id;
        let requester = msg.src_id;
        let state = self.replies.get(&vehicle).copied();
        match msg.ack {
            Ack::Request => match state {
                // A resend of the request being asked about: the prompt is already up.
                Some(Replying::Asking {
                    requester: r,
                    stamp,
                    ..
                }) if r == requester && stamp == msg.timestamp => Vec::new(),
                // Yielded to this requester: repeat the ACCEPT (ours may have been lost).
                Some(Replying::Yielded {
                    requester: r,
                    stamp,
                    ..
                }) if r == requester => {
                    vec![self.as_replier_send(
                        vehicle,
                        requester,
                        Ack::Accept,
                        stamp,
                        msg.src_priority,
                    )]
                }
                // Busy with another request, or yielded to someone else: not ours to give.
                Some(_) => vec![self.as_replier_send(
                    vehicle,
                    requester,
                    Ack::Refuse,
                    msg.timestamp,
                    msg.src_priority,
                )],
                None => {
                    if let Some((r, stamp, answer)) = self.answered.get(&vehicle).copied()
                        && r == requester
                        && stamp == msg.timestamp
                    {
                        // A resend of a request already answered: the same refusal again; an
                        // accepted one is over (FINISH seen or we resumed), so it gets nothing.
                        return match answer {
                            Answer::Refused => vec![self.as_replier_send(
                                vehicle,
                                requester,
                                Ack::Refuse,
                                stamp,
                                msg.src_priority,
                            )],
                            Answer::Accepted | Answer::Closed => Vec::new(),
                        };
                    }
                    if self.auto_accepts(vehicle, msg.src_priority, priority_verified) {
                        return self.answer(
                            now,
                            vehicle,
                            requester,
                            msg.timestamp,
                            msg.src_priority,
                            true,
                        );
                    }
                    let deadline = now + self.config.consent_timeout;
                    self.replies.insert(
                        vehicle,
                        Replying::Asking {
                            requester,
                            stamp: msg.timestamp,
                            src_priority: msg.src_priority,
                            deadline,
                        },
                    );
                    vec![Action::AskOperator(Prompt {
                        vehicle,
                        requester,
                        src_priority: msg.src_priority,
                        deadline,
                    })]
                }
            },
            // A FINISH ends the handover it names (requester and stamp): a late FINISH of an
            // earlier handover must not end the current one.
            Ack::Finish => match state {
                Some(Replying::Yielded {
                    requester: r,
                    stamp,
                    ..
                }) if r == requester && answers(msg.timestamp, stamp) => {
                    self.replies.remove(&vehicle);
                    self.close_answer(vehicle);
                    vec![Action::Resume { vehicle }]
                }
                Some(Replying::Asking {
                    requester: r,
                    stamp,
                    ..
                }) if r == requester && answers(msg.timestamp, stamp) => {
                    self.replies.remove(&vehicle);
                    vec![Action::PromptClosed {
                        vehicle,
                        outcome: Outcome::Withdrawn,
                    }]
                }
                _ => Vec::new(),
            },
            // ACCEPT/REFUSE naming us as owner are our own answers echoed back.
            Ack::Accept | Ack::Refuse => Vec::new(),
        }
    }

    pub(super) fn close_answer(&mut self, vehicle: DeviceId) {
        if let Some(entry) = self.answered.get_mut(&vehicle) {
            entry.2 = Answer::Closed;
        }
    }

    /// Our priority as a requester: the strength of our regular writers.
    fn priority(&self) -> i32 {
        i32::from(self.strength.0)
    }

    fn auto_accepts(&self, vehicle: DeviceId, src_priority: i32, verified: bool) -> bool {
        let ours = if self.holds_grant(vehicle) {
            Strength::PRIORITY
        } else {
            self.strength
        };
        match self.config.auto_accept {
            AutoAccept::Never => false,
            AutoAccept::Always => true,
            AutoAccept::HigherPriority => verified && src_priority > i32::from(ours.0),
        }
    }

    /// Sends our answer and records it; on ACCEPT we yield the vehicle.
    pub(super) fn answer(
        &mut self,
        now: MonoTime,
        vehicle: DeviceId,
        requester: DeviceId,
        stamp: TimeT,
        src_priority: i32,
        accept: bool,
    ) -> Vec<Action> {
        let (ack, answer) = if accept {
            (Ack::Accept, Answer::Accepted)
        } else {
            (Ack::Refuse, Answer::Refused)
        };
        self.answered.insert(vehicle, (requester, stamp, answer));
        let mut actions = vec![self.as_replier_send(vehicle, requester, ack, stamp, src_priority)];
        if accept {
            // A live holder starts within a millisecond; one lost ACCEPT is repeated at the
            // next REQUEST resend. Two resend periods cover that; then the standby ends.
            let start_by = now + self.config.resend * 2;
            self.replies.insert(
                vehicle,
                Replying::Yielded {
                    requester,
                    stamp,
                    holder_seen: false,
                    start_by,
                    standby: true,
                },
            );
            // A grant we held on this vehicle passes on with it.
            if self.requests.remove(&vehicle).is_some() {
                actions.push(Action::StopPriorityDriving { vehicle });
            }
            actions.push(Action::Yield { vehicle });
        } else {
            self.replies.remove(&vehicle);
        }
        actions
    }

    /// A message of ours as requester: we ask `owner` for `vehicle`.
    pub(super) fn as_requester_send(
        &self,
        vehicle: DeviceId,
        owner: DeviceId,
        ack: Ack,
        stamp: TimeT,
    ) -> Action {
        Action::Send(RequestControl {
            src_id: self.me,
            dest_id: vehicle,
            current_controller_id: owner,
            src_priority: self.priority(),
            ack,
            timestamp: stamp,
        })
    }

    /// A message of ours as replier (the owner asked), echoing the request's stamp and priority.
    fn as_replier_send(
        &self,
        vehicle: DeviceId,
        requester: DeviceId,
        ack: Ack,
        stamp: TimeT,
        src_priority: i32,
    ) -> Action {
        Action::Send(RequestControl {
            src_id: requester,
            dest_id: vehicle,
            current_controller_id: self.me,
            src_priority,
            ack,
            timestamp: stamp,
        })
    }
}

/// True if a message stamped `msg` can belong to the handover whose REQUEST was stamped
/// `request`. rove echoes the request's stamp on every message of a handover, so for rove peers
/// this is equality; a foreign peer may stamp with its own send time, which is later unless its
/// clock is behind ours. A message of an *earlier* handover carries an earlier stamp and is
/// rejected either way.
fn answers(msg: TimeT, request: TimeT) -> bool {
    msg >= request
}
