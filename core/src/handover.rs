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

use crate::error::{ConfigError, ConfigErrors, Result};
use crate::hierarchy::Strength;
use crate::msg::{Ack, DeviceId, RequestControl, TimeT};
use crate::time::MonoTime;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::time::Duration;

/// When the owner's operator gives control without asking a person.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum AutoAccept {
    /// Always ask the operator.
    Never,
    /// Accept at once when the requester's priority exceeds our strength; else ask.
    #[default]
    HigherPriority,
    /// Always accept (unattended stations).
    Always,
}

/// `[handover]` as written in TOML; absent keys take defaults.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HandoverSettings {
    /// Auto-accept policy.
    pub auto_accept: Option<AutoAccept>,
    /// How long a person has to answer a request before it is refused.
    pub consent_timeout_ms: Option<crate::config::Int>,
    /// How long a requester waits for an answer before giving up.
    pub reply_timeout_ms: Option<crate::config::Int>,
    /// How often an unanswered REQUEST is sent again.
    pub resend_ms: Option<crate::config::Int>,
}

/// Validated handover settings.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct HandoverConfig {
    /// Auto-accept policy.
    pub auto_accept: AutoAccept,
    /// Default 10 s: long enough to read a prompt and decide, short enough that a requester
    /// whose operator is away is not left waiting.
    pub consent_timeout: Duration,
    /// Default 12 s: the consent timeout plus margin for the REFUSE to arrive, so a requester
    /// normally hears the refusal rather than timing out on its own.
    pub reply_timeout: Duration,
    /// Default 500 ms: RequestControl has default QoS (possibly best-effort), so a lost REQUEST
    /// is repeated well inside a person's patience; more often only adds traffic.
    pub resend: Duration,
}

impl Default for HandoverConfig {
    fn default() -> Self {
        HandoverConfig {
            auto_accept: AutoAccept::HigherPriority,
            consent_timeout: Duration::from_secs(10),
            reply_timeout: Duration::from_secs(12),
            resend: Duration::from_millis(500),
        }
    }
}

impl HandoverSettings {
    /// Validates, filling defaults. Keys are named relative to the `[handover]` table.
    ///
    /// # Errors
    /// [`crate::Error::Config`] for a zero duration, a consent timeout over 10 minutes, a reply
    /// timeout not longer than the consent timeout, or a resend period not shorter than the reply
    /// timeout.
    pub fn validate(&self) -> Result<HandoverConfig> {
        let d = HandoverConfig::default();
        let mut errors = ConfigErrors::default();
        // Read wide (the config integer policy): a negative value is reported with its key, and
        // the default stands in so that the checks below do not repeat it.
        let mut ms = |key: &str, v: Option<crate::config::Int>, default: Duration| {
            let v = v.map(|v| errors.int(key, v, 0..=crate::config::Int::MAX, " ms"));
            v.flatten().map_or(default, Duration::from_millis)
        };
        let config = HandoverConfig {
            auto_accept: self.auto_accept.unwrap_or(d.auto_accept),
            consent_timeout: ms(
                "consent_timeout_ms",
                self.consent_timeout_ms,
                d.consent_timeout,
            ),
            reply_timeout: ms("reply_timeout_ms", self.reply_timeout_ms, d.reply_timeout),
            resend: ms("resend_ms", self.resend_ms, d.resend),
        };
        let show = |d: Duration| d.as_millis();
        if config.consent_timeout.is_zero() || config.consent_timeout > Duration::from_secs(600) {
            errors.push(ConfigError::new(
                "consent_timeout_ms",
                show(config.consent_timeout),
                "must be 1..=600000",
            ));
        }
        if config.reply_timeout <= config.consent_timeout {
            errors.push(ConfigError::new(
                "reply_timeout_ms",
                show(config.reply_timeout),
                format!(
                    "must be longer than consent_timeout_ms ({}) so the requester hears the \
                     refusal instead of timing out",
                    show(config.consent_timeout)
                ),
            ));
        }
        if config.resend.is_zero() || config.resend >= config.reply_timeout {
            errors.push(ConfigError::new(
                "resend_ms",
                show(config.resend),
                format!(
                    "must be at least 1 and shorter than reply_timeout_ms ({})",
                    show(config.reply_timeout)
                ),
            ));
        }
        errors.into_result(config)
    }
}

/// How a request ended, as seen by one side.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Outcome {
    /// The owner accepted: the requester now drives with a priority writer.
    Accepted,
    /// The owner refused (a person, a busy replier, or one that does not own the vehicle).
    Refused,
    /// No answer in time (requester: reply timeout; replier: consent timeout → REFUSE sent).
    TimedOut,
    /// The requester withdrew (FINISH before an answer).
    Withdrawn,
}

impl Outcome {
    /// Lower-case name, as the local API spells it.
    pub fn as_str(self) -> &'static str {
        match self {
            Outcome::Accepted => "accepted",
            Outcome::Refused => "refused",
            Outcome::TimedOut => "timed_out",
            Outcome::Withdrawn => "withdrawn",
        }
    }
}

/// A request a person must decide: someone asks us for a vehicle we drive. One type for the
/// handover machine ([`Action::AskOperator`]), the session's report and the consoles.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Prompt {
    /// The vehicle.
    pub vehicle: DeviceId,
    /// Who asks.
    pub requester: DeviceId,
    /// Its priority.
    pub src_priority: i32,
    /// When the request is refused automatically (the consent timeout).
    pub deadline: MonoTime,
}

/// What the operator role must do.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Action {
    /// Publish this RequestControl sample.
    Send(RequestControl),
    /// Show the consent prompt: `requester` asks for `vehicle`; refused automatically at
    /// `deadline`.
    AskOperator(Prompt),
    /// Close the prompt for `vehicle`.
    PromptClosed {
        /// The vehicle.
        vehicle: DeviceId,
        /// How it ended.
        outcome: Outcome,
    },
    /// Our own request for `vehicle` ended.
    RequestEnded {
        /// The vehicle.
        vehicle: DeviceId,
        /// How it ended.
        outcome: Outcome,
    },
    /// Start driving `vehicle` with a priority writer (strength 65535): we hold the grant.
    StartPriorityDriving {
        /// The vehicle.
        vehicle: DeviceId,
    },
    /// Stop driving `vehicle` with the priority writer (we gave the grant back).
    StopPriorityDriving {
        /// The vehicle.
        vehicle: DeviceId,
    },
    /// Stop driving `vehicle`, without releasing: we gave it to a requester (module docs).
    /// Keep the regular stream alive with PROBE samples (standby) until [`Action::EndStandby`]
    /// or [`Action::Resume`]: the grant outranks us on the vehicle, and when it ends the vehicle
    /// falls back to us rather than to a weaker bystander.
    Yield {
        /// The vehicle.
        vehicle: DeviceId,
    },
    /// Stop the PROBE standby for `vehicle`: the holder never showed up on the vehicle, so we
    /// let the vehicle time us out; its next owner tells us the grant is void (we resume then).
    EndStandby {
        /// The vehicle.
        vehicle: DeviceId,
    },
    /// The grant on `vehicle` is over (FINISH, or seen on the vehicle): we drive it again.
    Resume {
        /// The vehicle.
        vehicle: DeviceId,
    },
}

/// Why a local command could not be carried out.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum Refusal {
    /// A request for this vehicle is already open or granted.
    #[error("a request for this vehicle is already open or granted")]
    AlreadyRequested,
    /// We own the vehicle already (or nobody does, so there is nobody to ask).
    #[error("no request needed: the owner is this operator or the vehicle's failsafe")]
    NothingToRequest,
    /// No open request or grant for this vehicle.
    #[error("no open request or grant for this vehicle")]
    NoRequest,
    /// No prompt is open for this vehicle.
    #[error("no consent prompt is open for this vehicle")]
    NoPrompt,
}

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

    fn as_requester(&mut self, msg: &RequestControl) -> Vec<Action> {
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

    fn as_replier(
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

    fn close_answer(&mut self, vehicle: DeviceId) {
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
    fn answer(
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
    fn as_requester_send(
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
