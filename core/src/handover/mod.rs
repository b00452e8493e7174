//! Active handover (docs/design.md §4): one operator's REQUEST / ACCEPT / REFUSE / FINISH state
//! machines, as requester and as replier, for every vehicle it deals with.
//!
//! All messages of one handover carry the same `(src_id, dest_id, current_controller_id)` triple:
//! the requester, the vehicle, the owner asked. An operator acts on a message only where it is
//! `src_id` (as requester: ACCEPT / REFUSE) or `current_controller_id` (as replier: REQUEST /
//! FINISH); everything else is ignored, as are unknown vehicles and requesters.
//!
//! ```text
//! requester                                   replier (the owner's operator)
//! request() ── REQUEST (resent every 500 ms) ─▶ auto-accept? ─ yes ─▶ ACCEPT, StopDriving
//!                                              └ no ─▶ AskOperator … decide() / consent timeout
//! ◀──────────── ACCEPT ─── StartDriving(priority)         (timeout → REFUSE)
//! finish() ──── FINISH ─── StopDriving ──────▶ ResumeDriving
//! ```
//!
//! Loss and duplication: the requester resends its REQUEST with the original time stamp, so
//! the replier recognises a resend and repeats its answer rather than asking again. Every message
//! of a handover carries its REQUEST's stamp; an answer or FINISH with an earlier stamp belongs
//! to an earlier handover and is not taken for the current one (see `answers`). A late ACCEPT
//! for a request the requester has given up is handed back at once with FINISH, so nobody holds a
//! grant it does not use. A FINISH from a requester still waiting withdraws its request.
//!
//! Auto-accept compares the requester's `src_priority` with the replier's own strength on that
//! vehicle (65535 while it holds a grant there, so a grant is never taken away without asking).
//!
//! On [`Action::Yield`] the replier stops driving but does **not** release: it keeps its stream
//! alive with PROBE samples (standby), so it stays the vehicle's owner until the grant holder's
//! priority stream takes over, and the vehicle comes straight back to it when the grant ends.
//! Releasing, or going silent, would hand the vehicle to failsafe or to a weaker bystander for
//! the moment between the ACCEPT and the holder's first sample, and again between the FINISH and
//! our resumption (measured: a bystander drove for ~1 ms at every FINISH).
//!
//! A FINISH can be lost for good (the holder crashed, or quit before its last samples were
//! acknowledged). The replier therefore also watches the vehicle's published owner
//! ([`Handover::on_vehicle_owner`]): after the vehicle has named the holder, any other owner means
//! the grant is over, and we resume. If the holder never shows up on the vehicle within two
//! resend periods, the standby ends ([`Action::EndStandby`]) so the vehicle times us out; its next
//! owner (a bystander, or its failsafe) then tells us the same.
//!
//! # Layout
//! - this file: [`Handover`], its per-vehicle states, and its entry points: local commands,
//!   received messages, the vehicle's published owner, [`Handover::tick`].
//! - `config.rs`: `[handover]` ([`HandoverSettings`]) and its validated form ([`HandoverConfig`],
//!   [`AutoAccept`]).
//! - `actions.rs`: what the machine tells its operator role: [`Action`], [`Prompt`],
//!   [`Outcome`], [`Refusal`].
//! - `messages.rs`: what a received RequestControl does, as requester and as replier; our
//!   answers and the RequestControl samples we send.

mod actions;
mod config;
mod messages;

pub use actions::{Action, Outcome, Prompt, Refusal};
pub use config::{AutoAccept, HandoverConfig, HandoverSettings};

use crate::hierarchy::Strength;
use crate::msg::{Ack, DeviceId, RequestControl, TimeT};
use crate::time::MonoTime;
use std::collections::BTreeMap;

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Requesting {
    /// REQUEST sent; waiting for an answer.
    Waiting {
        owner: DeviceId,
        stamp: TimeT,
        give_up_at: MonoTime,
        resend_at: MonoTime,
    },
    /// ACCEPT received; we drive with a priority writer until we FINISH.
    Holding { owner: DeviceId, stamp: TimeT },
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Replying {
    /// The person is being asked.
    Asking {
        requester: DeviceId,
        stamp: TimeT,
        src_priority: i32,
        deadline: MonoTime,
    },
    /// We accepted and stopped driving (the gateway keeps our stream alive with PROBEs, so the
    /// vehicle returns to us, not to a bystander, when the grant ends); waiting for FINISH, or
    /// for the vehicle to show that the grant is over.
    Yielded {
        requester: DeviceId,
        stamp: TimeT,
        /// The vehicle has named the holder as its controller since we yielded.
        holder_seen: bool,
        /// If the vehicle has not named the holder by then, the holder never started: stop
        /// the standby stream, so the vehicle drops us and we see the grant is void.
        start_by: MonoTime,
        /// Our PROBE keep-alive stream is on.
        standby: bool,
    },
}

/// One operator's active-handover state, as requester and as replier, for all vehicles.
#[derive(Debug, Clone)]
pub struct Handover {
    me: DeviceId,
    strength: Strength,
    config: HandoverConfig,
    requests: BTreeMap<DeviceId, Requesting>,
    replies: BTreeMap<DeviceId, Replying>,
    /// The last request answered per vehicle, so that a resent REQUEST (same requester and
    /// stamp) gets the same answer, or none once that handover is over.
    answered: BTreeMap<DeviceId, (DeviceId, TimeT, Answer)>,
    /// Stamp of our latest request: each new request gets a strictly later one, so that its
    /// messages can never be mistaken for an earlier handover's, even with a coarse clock.
    last_stamp: TimeT,
    /// Stamp of our first request, if any: an ACCEPT stamped earlier answers nobody here (a
    /// history replay, e.g. of a previous process with our id) and is ignored, not handed back.
    first_stamp: Option<TimeT>,
}

/// What became of a request this operator answered.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Answer {
    Refused,
    /// Accepted; the grant is still out (we are yielded).
    Accepted,
    /// Accepted and since finished (or we resumed): a resend must not re-open it.
    Closed,
}

impl Handover {
    /// The handover state of operator `me` whose regular writers have `strength`.
    pub fn new(me: DeviceId, strength: Strength, config: HandoverConfig) -> Self {
        Handover {
            me,
            strength,
            config,
            requests: BTreeMap::new(),
            replies: BTreeMap::new(),
            answered: BTreeMap::new(),
            last_stamp: TimeT(0),
            first_stamp: None,
        }
    }

    /// The earliest instant a [`Handover::tick`] has work (a resend or a timeout).
    pub fn next_deadline(&self) -> Option<MonoTime> {
        let req = self.requests.values().filter_map(|r| match r {
            Requesting::Waiting {
                give_up_at,
                resend_at,
                ..
            } => Some((*give_up_at).min(*resend_at)),
            Requesting::Holding { .. } => None,
        });
        let rep = self.replies.values().filter_map(|r| match r {
            Replying::Asking { deadline, .. } => Some(*deadline),
            Replying::Yielded {
                holder_seen: false,
                standby: true,
                start_by,
                ..
            } => Some(*start_by),
            Replying::Yielded { .. } => None,
        });
        req.chain(rep).min()
    }

    /// True while we hold a grant for `vehicle`.
    pub fn holds_grant(&self, vehicle: DeviceId) -> bool {
        matches!(
            self.requests.get(&vehicle),
            Some(Requesting::Holding { .. })
        )
    }

    /// True while we have yielded `vehicle` to a grant holder and must not drive it.
    pub fn has_yielded(&self, vehicle: DeviceId) -> bool {
        matches!(self.replies.get(&vehicle), Some(Replying::Yielded { .. }))
    }

    /// Asks `owner` (the vehicle's current `controller_id`) for `vehicle`. `stamp` is the
    /// wall-clock time stamp to put on the REQUEST and its resends; if it is not later than our
    /// previous request's, the next later value is used instead.
    ///
    /// # Errors
    /// [`Refusal::AlreadyRequested`] if a request is open or granted; [`Refusal::NothingToRequest`]
    /// if `owner` is us or the vehicle itself (its failsafe: just drive).
    pub fn request(
        &mut self,
        now: MonoTime,
        vehicle: DeviceId,
        owner: DeviceId,
        stamp: TimeT,
    ) -> Result<Vec<Action>, Refusal> {
        if self.requests.contains_key(&vehicle) {
            return Err(Refusal::AlreadyRequested);
        }
        if owner == self.me || owner == vehicle {
            return Err(Refusal::NothingToRequest);
        }
        let stamp = stamp.max(TimeT(self.last_stamp.0.saturating_add(1)));
        self.last_stamp = stamp;
        self.first_stamp.get_or_insert(stamp);
        self.requests.insert(
            vehicle,
            Requesting::Waiting {
                owner,
                stamp,
                give_up_at: now + self.config.reply_timeout,
                resend_at: now + self.config.resend,
            },
        );
        Ok(vec![self.as_requester_send(
            vehicle,
            owner,
            Ack::Request,
            stamp,
        )])
    }

    /// Gives a held grant back (FINISH), or withdraws an open request.
    ///
    /// # Errors
    /// [`Refusal::NoRequest`] if there is neither.
    pub fn finish(&mut self, vehicle: DeviceId) -> Result<Vec<Action>, Refusal> {
        let state = self.requests.remove(&vehicle).ok_or(Refusal::NoRequest)?;
        let (owner, stamp, ended) = match state {
            Requesting::Holding { owner, stamp } => {
                (owner, stamp, Action::StopPriorityDriving { vehicle })
            }
            Requesting::Waiting { owner, stamp, .. } => (
                owner,
                stamp,
                Action::RequestEnded {
                    vehicle,
                    outcome: Outcome::Withdrawn,
                },
            ),
        };
        Ok(vec![
            self.as_requester_send(vehicle, owner, Ack::Finish, stamp),
            ended,
        ])
    }

    /// The person answered the consent prompt for `vehicle`.
    ///
    /// # Errors
    /// [`Refusal::NoPrompt`] if no prompt is open for `vehicle` (it timed out or was withdrawn).
    pub fn decide(
        &mut self,
        now: MonoTime,
        vehicle: DeviceId,
        accept: bool,
    ) -> Result<Vec<Action>, Refusal> {
        let Some(Replying::Asking {
            requester,
            stamp,
            src_priority,
            ..
        }) = self.replies.get(&vehicle).copied()
        else {
            return Err(Refusal::NoPrompt);
        };
        let outcome = if accept {
            Outcome::Accepted
        } else {
            Outcome::Refused
        };
        let mut actions = self.answer(now, vehicle, requester, stamp, src_priority, accept);
        actions.push(Action::PromptClosed { vehicle, outcome });
        Ok(actions)
    }

    /// We take `vehicle` back after yielding it (the holder vanished without FINISH). The caller
    /// starts driving again; a late FINISH is then ignored.
    pub fn resume(&mut self, vehicle: DeviceId) -> bool {
        if self.has_yielded(vehicle) {
            self.replies.remove(&vehicle);
            self.close_answer(vehicle);
            true
        } else {
            false
        }
    }

    /// Acts on the vehicle's published owner (`DeviceInfo.controller_id`). While we have yielded
    /// `vehicle`, this is how we learn that the grant is over when its FINISH never reaches us
    /// (lost, or the holder crashed): once the vehicle has named the holder, any other owner —
    /// us again, a bystander, its own failsafe — means the grant ended; before that, any owner
    /// but us or the holder means the handover broke down. Either way we resume.
    pub fn on_vehicle_owner(&mut self, vehicle: DeviceId, controller_id: DeviceId) -> Vec<Action> {
        let Some(Replying::Yielded {
            requester,
            holder_seen,
            ..
        }) = self.replies.get_mut(&vehicle)
        else {
            return Vec::new();
        };
        if controller_id == *requester {
            *holder_seen = true;
            return Vec::new();
        }
        if controller_id == self.me && !*holder_seen {
            // Still ours: the holder's stream has not reached the vehicle yet.
            return Vec::new();
        }
        self.resume(vehicle);
        vec![Action::Resume { vehicle }]
    }

    /// Acts on a RequestControl sample whose `src_priority` is taken as true (see
    /// [`Handover::on_message_checked`]).
    pub fn on_message(&mut self, now: MonoTime, msg: &RequestControl) -> Vec<Action> {
        self.on_message_checked(now, msg, true)
    }

    /// Acts on a RequestControl sample. `priority_verified`: a REQUEST's `src_priority` agrees
    /// with what discovery says of the requester's writers. An unverified priority is never
    /// auto-accepted by [`AutoAccept::HigherPriority`]: a person is asked instead.
    pub fn on_message_checked(
        &mut self,
        now: MonoTime,
        msg: &RequestControl,
        priority_verified: bool,
    ) -> Vec<Action> {
        if msg.src_id == self.me && msg.current_controller_id != self.me {
            self.as_requester(msg)
        } else if msg.current_controller_id == self.me && msg.src_id != self.me {
            self.as_replier(now, msg, priority_verified)
        } else {
            Vec::new()
        }
    }

    /// Entries in the request, reply and answer tables, all keyed by vehicle.
    #[cfg(test)]
    pub(crate) fn table_len(&self) -> usize {
        self.requests.len() + self.replies.len() + self.answered.len()
    }

    /// True while a request for `vehicle` is being answered here (asking a person, or yielded
    /// to its requester): resends of it are answered even if we no longer look like the owner.
    pub fn is_replying(&self, vehicle: DeviceId) -> bool {
        self.replies.contains_key(&vehicle)
    }

    /// Resends and timeouts due at `now`.
    pub fn tick(&mut self, now: MonoTime) -> Vec<Action> {
        let mut actions = Vec::new();
        // (vehicle, owner, stamp, give up?)
        let mut due = Vec::new();
        for (vehicle, state) in &mut self.requests {
            if let Requesting::Waiting {
                owner,
                stamp,
                give_up_at,
                resend_at,
            } = state
            {
                if now >= *give_up_at {
                    due.push((*vehicle, *owner, *stamp, true));
                } else if now >= *resend_at {
                    *resend_at = now + self.config.resend;
                    due.push((*vehicle, *owner, *stamp, false));
                }
            }
        }
        for (vehicle, owner, stamp, give_up) in due {
            if give_up {
                // Give up, and hand back any ACCEPT that got lost on its way to us: the vehicle
                // may hold a grant for us that nobody would use.
                self.requests.remove(&vehicle);
                actions.push(self.as_requester_send(vehicle, owner, Ack::Finish, stamp));
                actions.push(Action::RequestEnded {
                    vehicle,
                    outcome: Outcome::TimedOut,
                });
            } else {
                actions.push(self.as_requester_send(vehicle, owner, Ack::Request, stamp));
            }
        }
        let expired: Vec<(DeviceId, DeviceId, TimeT, i32)> = self
            .replies
            .iter()
            .filter_map(|(v, r)| match r {
                Replying::Asking {
                    requester,
                    stamp,
                    src_priority,
                    deadline,
                } if now >= *deadline => Some((*v, *requester, *stamp, *src_priority)),
                _ => None,
            })
            .collect();
        for (vehicle, requester, stamp, src_priority) in expired {
            actions.extend(self.answer(now, vehicle, requester, stamp, src_priority, false));
            actions.push(Action::PromptClosed {
                vehicle,
                outcome: Outcome::TimedOut,
            });
        }
        for (vehicle, r) in &mut self.replies {
            if let Replying::Yielded {
                holder_seen: false,
                standby: standby @ true,
                start_by,
                ..
            } = r
                && now >= *start_by
            {
                *standby = false;
                actions.push(Action::EndStandby { vehicle: *vehicle });
            }
        }
        actions
    }
}
