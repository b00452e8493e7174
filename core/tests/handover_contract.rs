//! Active handover (docs/design.md §4): REQUEST / ACCEPT / REFUSE / FINISH for requester and replier,
//! consent timeout, auto-accept policy, duplicates, out-of-order and unknown messages — and an
//! end-to-end exchange between two operators and the vehicle's arbiter over a simulated bus.

mod common;

use common::{VEHICLE, command, ms, pw, w};
use rove_core::arbiter::{Arbiter, ArbiterConfig, Event, ParticipantId, WriterId};
use rove_core::handover::{
    Action, AutoAccept, Handover, HandoverConfig, HandoverSettings, Outcome, Prompt, Refusal,
};
use rove_core::hierarchy::Strength;
use rove_core::msg::{Ack, CommandType, RequestControl, TimeT};

const A: i64 = 1; // owner, stationary laptop (220)
const B: i64 = 2; // requester, remote laptop (120)
const C: i64 = 3; // another requester
const STAMP: TimeT = TimeT(1_000);

fn config(policy: AutoAccept) -> HandoverConfig {
    HandoverConfig {
        auto_accept: policy,
        ..HandoverConfig::default()
    }
}

fn owner_a(policy: AutoAccept) -> Handover {
    Handover::new(A, Strength(220), config(policy))
}

fn requester_b() -> Handover {
    Handover::new(B, Strength(120), HandoverConfig::default())
}

fn msg(src: i64, ack: Ack, priority: i32, stamp: TimeT) -> RequestControl {
    RequestControl {
        src_id: src,
        dest_id: VEHICLE,
        current_controller_id: A,
        src_priority: priority,
        ack,
        timestamp: stamp,
    }
}

fn sent(actions: &[Action]) -> Vec<(i64, Ack)> {
    actions
        .iter()
        .filter_map(|a| match a {
            Action::Send(m) => Some((m.src_id, m.ack)),
            _ => None,
        })
        .collect()
}

// ---- Requester ----------------------------------------------------------------------------

#[test]
fn a_request_carries_the_triple_our_priority_and_is_resent_with_the_same_stamp() {
    let mut b = requester_b();
    let actions = b.request(ms(0), VEHICLE, A, STAMP).expect("request");
    assert_eq!(actions, [Action::Send(msg(B, Ack::Request, 120, STAMP))]);
    assert_eq!(b.next_deadline(), Some(ms(500)));
    assert_eq!(b.tick(ms(499)), []);
    assert_eq!(
        b.tick(ms(500)),
        [Action::Send(msg(B, Ack::Request, 120, STAMP))]
    );
    assert_eq!(b.next_deadline(), Some(ms(1000)));
}

#[test]
fn a_request_needs_someone_to_ask_and_only_one_at_a_time() {
    let mut b = requester_b();
    assert_eq!(
        b.request(ms(0), VEHICLE, B, STAMP),
        Err(Refusal::NothingToRequest)
    );
    assert_eq!(
        b.request(ms(0), VEHICLE, VEHICLE, STAMP),
        Err(Refusal::NothingToRequest)
    );
    b.request(ms(0), VEHICLE, A, STAMP).expect("first");
    assert_eq!(
        b.request(ms(1), VEHICLE, A, STAMP),
        Err(Refusal::AlreadyRequested)
    );
    assert_eq!(b.finish(VEHICLE + 1), Err(Refusal::NoRequest));
}

#[test]
fn accept_starts_priority_driving_and_duplicates_change_nothing() {
    let mut b = requester_b();
    b.request(ms(0), VEHICLE, A, STAMP).expect("request");
    let actions = b.on_message(ms(5), &msg(B, Ack::Accept, 120, STAMP));
    assert_eq!(
        actions,
        [
            Action::StartPriorityDriving { vehicle: VEHICLE },
            Action::RequestEnded {
                vehicle: VEHICLE,
                outcome: Outcome::Accepted
            },
        ]
    );
    assert!(b.holds_grant(VEHICLE));
    assert_eq!(b.on_message(ms(6), &msg(B, Ack::Accept, 120, STAMP)), []);
    assert_eq!(b.next_deadline(), None, "no resend once granted");
}

#[test]
fn refuse_ends_the_request() {
    let mut b = requester_b();
    b.request(ms(0), VEHICLE, A, STAMP).expect("request");
    assert_eq!(
        b.on_message(ms(5), &msg(B, Ack::Refuse, 120, STAMP)),
        [Action::RequestEnded {
            vehicle: VEHICLE,
            outcome: Outcome::Refused
        }]
    );
    assert!(!b.holds_grant(VEHICLE));
}

#[test]
fn an_accept_from_an_owner_we_did_not_ask_is_handed_back() {
    let mut b = requester_b();
    b.request(ms(0), VEHICLE, A, STAMP).expect("request");
    let mut from_c = msg(B, Ack::Accept, 120, STAMP);
    from_c.current_controller_id = C;
    let mut finish = msg(B, Ack::Finish, 120, STAMP);
    finish.current_controller_id = C;
    assert_eq!(b.on_message(ms(5), &from_c), [Action::Send(finish)]);
    assert!(!b.holds_grant(VEHICLE));
    // A REFUSE from C does not end our request to A either.
    from_c.ack = Ack::Refuse;
    assert_eq!(b.on_message(ms(6), &from_c), []);
    assert_eq!(
        b.request(ms(7), VEHICLE, A, STAMP),
        Err(Refusal::AlreadyRequested)
    );
}

#[test]
fn an_answer_to_an_earlier_request_is_not_taken_for_the_current_one() {
    let mut b = requester_b();
    b.request(ms(0), VEHICLE, A, STAMP).expect("first");
    b.finish(VEHICLE).expect("withdraw");
    // Same wall-clock stamp again: the machine still makes the second request's stamp later.
    let actions = b.request(ms(1), VEHICLE, A, STAMP).expect("second");
    let Action::Send(second) = actions[0] else {
        panic!("expected a REQUEST, got {actions:?}");
    };
    assert!(second.timestamp > STAMP);
    // The first request's ACCEPT arrives late: handed back, not held.
    let actions = b.on_message(ms(2), &msg(B, Ack::Accept, 120, STAMP));
    assert_eq!(sent(&actions), [(B, Ack::Finish)]);
    assert!(!b.holds_grant(VEHICLE));
}

#[test]
fn finish_gives_the_grant_back_and_stops_priority_driving() {
    let mut b = requester_b();
    b.request(ms(0), VEHICLE, A, STAMP).expect("request");
    b.on_message(ms(5), &msg(B, Ack::Accept, 120, STAMP));
    assert_eq!(
        b.finish(VEHICLE),
        Ok(vec![
            Action::Send(msg(B, Ack::Finish, 120, STAMP)),
            Action::StopPriorityDriving { vehicle: VEHICLE },
        ])
    );
    assert!(!b.holds_grant(VEHICLE));
}

#[test]
fn finish_before_an_answer_withdraws_the_request() {
    let mut b = requester_b();
    b.request(ms(0), VEHICLE, A, STAMP).expect("request");
    let actions = b.finish(VEHICLE).expect("withdraw");
    assert_eq!(
        actions[1],
        Action::RequestEnded {
            vehicle: VEHICLE,
            outcome: Outcome::Withdrawn
        }
    );
    assert_eq!(sent(&actions), [(B, Ack::Finish)]);
}

#[test]
fn no_answer_within_the_reply_timeout_gives_up_and_hands_back_any_lost_accept() {
    let mut b = requester_b();
    b.request(ms(0), VEHICLE, A, STAMP).expect("request");
    let actions = b.tick(ms(12_000));
    assert_eq!(sent(&actions), [(B, Ack::Finish)]);
    assert!(actions.contains(&Action::RequestEnded {
        vehicle: VEHICLE,
        outcome: Outcome::TimedOut
    }));
    assert_eq!(b.next_deadline(), None);
}

/// rustdds replays a writer's history to new readers: an ACCEPT older than anything we asked
/// for is not ours to hand back (found by `rove bench handover --scenario active`).
#[test]
fn an_accept_older_than_our_first_request_is_ignored() {
    let mut b = requester_b();
    assert_eq!(b.on_message(ms(0), &msg(B, Ack::Accept, 120, STAMP)), []);
    b.request(ms(1), VEHICLE, A, STAMP).expect("request");
    assert_eq!(
        b.on_message(ms(2), &msg(B, Ack::Accept, 120, TimeT(STAMP.0 - 1))),
        []
    );
    assert!(!b.holds_grant(VEHICLE));
}

#[test]
fn a_late_accept_after_giving_up_is_handed_straight_back() {
    let mut b = requester_b();
    b.request(ms(0), VEHICLE, A, STAMP).expect("request");
    b.tick(ms(12_000));
    let actions = b.on_message(ms(12_001), &msg(B, Ack::Accept, 120, STAMP));
    assert_eq!(actions, [Action::Send(msg(B, Ack::Finish, 120, STAMP))]);
    assert!(!b.holds_grant(VEHICLE));
}

// ---- Replier ------------------------------------------------------------------------------

#[test]
fn auto_accepts_a_requester_with_higher_priority_than_our_strength() {
    let mut a = owner_a(AutoAccept::HigherPriority);
    let actions = a.on_message(ms(0), &msg(B, Ack::Request, 340, STAMP));
    assert_eq!(
        actions,
        [
            Action::Send(msg(B, Ack::Accept, 340, STAMP)),
            Action::Yield { vehicle: VEHICLE },
        ]
    );
    assert!(a.has_yielded(VEHICLE));
}

#[test]
fn asks_the_operator_when_priority_is_not_higher_and_accepts_on_consent() {
    let mut a = owner_a(AutoAccept::HigherPriority);
    // Equal priority is not higher: ask.
    let actions = a.on_message(ms(0), &msg(B, Ack::Request, 220, STAMP));
    assert_eq!(
        actions,
        [Action::AskOperator(Prompt {
            vehicle: VEHICLE,
            requester: B,
            src_priority: 220,
            deadline: ms(10_000)
        })]
    );
    let actions = a.decide(ms(10), VEHICLE, true).expect("prompt open");
    assert_eq!(
        actions,
        [
            Action::Send(msg(B, Ack::Accept, 220, STAMP)),
            Action::Yield { vehicle: VEHICLE },
            Action::PromptClosed {
                vehicle: VEHICLE,
                outcome: Outcome::Accepted
            },
        ]
    );
    assert_eq!(a.decide(ms(10), VEHICLE, true), Err(Refusal::NoPrompt));
}

#[test]
fn the_operator_refusing_sends_refuse() {
    let mut a = owner_a(AutoAccept::HigherPriority);
    a.on_message(ms(0), &msg(B, Ack::Request, 120, STAMP));
    let actions = a.decide(ms(10), VEHICLE, false).expect("prompt open");
    assert_eq!(sent(&actions), [(B, Ack::Refuse)]);
    assert!(!a.has_yielded(VEHICLE));
}

#[test]
fn the_consent_timeout_refuses() {
    let mut a = owner_a(AutoAccept::Never);
    a.on_message(ms(0), &msg(B, Ack::Request, 999, STAMP));
    assert_eq!(a.next_deadline(), Some(ms(10_000)));
    assert_eq!(a.tick(ms(9_999)), []);
    let actions = a.tick(ms(10_000));
    assert_eq!(
        actions,
        [
            Action::Send(msg(B, Ack::Refuse, 999, STAMP)),
            Action::PromptClosed {
                vehicle: VEHICLE,
                outcome: Outcome::TimedOut
            },
        ]
    );
    assert_eq!(a.decide(ms(10), VEHICLE, true), Err(Refusal::NoPrompt));
}

#[test]
fn policy_always_and_never() {
    let mut a = owner_a(AutoAccept::Always);
    let actions = a.on_message(ms(0), &msg(B, Ack::Request, 1, STAMP));
    assert_eq!(sent(&actions), [(B, Ack::Accept)]);
    let mut a = owner_a(AutoAccept::Never);
    let actions = a.on_message(ms(0), &msg(B, Ack::Request, 65535, STAMP));
    assert!(matches!(actions[..], [Action::AskOperator(_)]));
}

#[test]
fn a_resent_request_does_not_prompt_twice_and_gets_the_same_answer_again() {
    let mut a = owner_a(AutoAccept::HigherPriority);
    a.on_message(ms(0), &msg(B, Ack::Request, 120, STAMP));
    assert_eq!(a.on_message(ms(500), &msg(B, Ack::Request, 120, STAMP)), []);
    a.decide(ms(10), VEHICLE, false).expect("prompt open");
    // The REFUSE was lost; B resends the same request: same answer, no new prompt.
    assert_eq!(
        a.on_message(ms(1000), &msg(B, Ack::Request, 120, STAMP)),
        [Action::Send(msg(B, Ack::Refuse, 120, STAMP))]
    );
    // A *new* request (new stamp) asks the person again.
    let actions = a.on_message(ms(2000), &msg(B, Ack::Request, 120, TimeT(2_000)));
    assert!(matches!(actions[..], [Action::AskOperator(_)]));
}

#[test]
fn a_resent_request_after_yielding_repeats_the_accept() {
    let mut a = owner_a(AutoAccept::Always);
    a.on_message(ms(0), &msg(B, Ack::Request, 120, STAMP));
    assert_eq!(
        a.on_message(ms(500), &msg(B, Ack::Request, 120, STAMP)),
        [Action::Send(msg(B, Ack::Accept, 120, STAMP))]
    );
}

#[test]
fn a_second_requester_is_refused_while_busy_or_after_yielding() {
    let mut a = owner_a(AutoAccept::Never);
    a.on_message(ms(0), &msg(B, Ack::Request, 120, STAMP));
    assert_eq!(
        sent(&a.on_message(ms(1), &msg(C, Ack::Request, 130, STAMP))),
        [(C, Ack::Refuse)]
    );
    a.decide(ms(10), VEHICLE, true).expect("prompt open");
    assert_eq!(
        sent(&a.on_message(ms(2), &msg(C, Ack::Request, 130, STAMP))),
        [(C, Ack::Refuse)]
    );
}

#[test]
fn finish_from_the_holder_lets_us_resume_and_a_stranger_cannot() {
    let mut a = owner_a(AutoAccept::Always);
    a.on_message(ms(0), &msg(B, Ack::Request, 120, STAMP));
    assert_eq!(a.on_message(ms(5), &msg(C, Ack::Finish, 130, STAMP)), []);
    assert!(a.has_yielded(VEHICLE));
    assert_eq!(
        a.on_message(ms(6), &msg(B, Ack::Finish, 120, STAMP)),
        [Action::Resume { vehicle: VEHICLE }]
    );
    assert!(!a.has_yielded(VEHICLE));
    // A duplicate FINISH changes nothing.
    assert_eq!(a.on_message(ms(7), &msg(B, Ack::Finish, 120, STAMP)), []);
}

#[test]
fn finish_while_asking_withdraws_the_prompt() {
    let mut a = owner_a(AutoAccept::Never);
    a.on_message(ms(0), &msg(B, Ack::Request, 120, STAMP));
    assert_eq!(
        a.on_message(ms(5), &msg(B, Ack::Finish, 120, STAMP)),
        [Action::PromptClosed {
            vehicle: VEHICLE,
            outcome: Outcome::Withdrawn
        }]
    );
    assert_eq!(a.next_deadline(), None);
}

#[test]
fn resume_takes_the_vehicle_back_without_a_finish() {
    let mut a = owner_a(AutoAccept::Always);
    a.on_message(ms(0), &msg(B, Ack::Request, 120, STAMP));
    assert!(a.resume(VEHICLE));
    assert!(!a.resume(VEHICLE));
}

#[test]
fn messages_not_addressed_to_us_are_ignored() {
    let mut a = owner_a(AutoAccept::Always);
    let mut other_owner = msg(B, Ack::Request, 999, STAMP);
    other_owner.current_controller_id = C;
    assert_eq!(a.on_message(ms(0), &other_owner), []);
    // Our own answers echoed back to us change nothing.
    assert_eq!(a.on_message(ms(0), &msg(B, Ack::Accept, 120, STAMP)), []);
    // A message naming us as both requester and owner is nonsense.
    let mut self_talk = msg(A, Ack::Request, 999, STAMP);
    self_talk.current_controller_id = A;
    assert_eq!(a.on_message(ms(0), &self_talk), []);
    assert!(!a.has_yielded(VEHICLE));
}

#[test]
fn a_grant_holder_is_always_asked_before_its_grant_is_passed_on() {
    // B holds a grant on the vehicle; C asks B with a priority above B's regular strength.
    let mut b = requester_b();
    b.request(ms(0), VEHICLE, A, STAMP).expect("request");
    b.on_message(ms(1), &msg(B, Ack::Accept, 120, STAMP));
    let to_b = RequestControl {
        src_id: C,
        dest_id: VEHICLE,
        current_controller_id: B,
        src_priority: 65_000,
        ack: Ack::Request,
        timestamp: STAMP,
    };
    let actions = b.on_message(ms(2), &to_b);
    assert!(matches!(
        actions[..],
        [Action::AskOperator(Prompt { requester: C, .. })]
    ));
    // On consent the grant passes on: B stops its priority stream and yields.
    let actions = b.decide(ms(10), VEHICLE, true).expect("prompt open");
    assert!(actions.contains(&Action::StopPriorityDriving { vehicle: VEHICLE }));
    assert!(actions.contains(&Action::Yield { vehicle: VEHICLE }));
    assert!(!b.holds_grant(VEHICLE));
}

#[test]
fn settings_validate_and_name_bad_keys() {
    assert_eq!(
        HandoverSettings::default().validate(),
        Ok(HandoverConfig::default())
    );
    let raw: HandoverSettings = toml::from_str(
        "auto_accept = \"never\"\nconsent_timeout_ms = 5000\nreply_timeout_ms = 4000",
    )
    .expect("parses");
    let err = raw.validate().expect_err("reply <= consent").to_string();
    assert!(
        err.starts_with("reply_timeout_ms = 4000: must be longer than consent_timeout_ms (5000)"),
        "{err}"
    );
    assert!(toml::from_str::<HandoverSettings>("auto_accept = \"sometimes\"").is_err());
    assert!(toml::from_str::<HandoverSettings>("consent_ms = 1").is_err());
}

// ---- End to end: two operators and the vehicle ------------------------------------------------

/// Delivers every Send to the other operator and to the vehicle (as its arbiter events), like the
/// RequestControl topic would, and returns the non-send actions per operator.
struct Bus {
    vehicle: Arbiter,
    ops: Vec<Handover>,
    owners: Vec<Option<i64>>,
}

impl Bus {
    fn deliver(&mut self, t: u64, from: usize, actions: Vec<Action>) -> Vec<(usize, Action)> {
        let mut queue: Vec<(usize, Action)> = actions.into_iter().map(|a| (from, a)).collect();
        let mut local = Vec::new();
        while let Some((who, action)) = queue.pop() {
            match action {
                Action::Send(m) => {
                    // Operator i speaks from participant i + 1 (its writers `w`/`pw(i + 1)`).
                    let sender = ParticipantId(who as u128 + 1);
                    self.event(t, Event::from_request_control(VEHICLE, &m, sender));
                    for i in 0..self.ops.len() {
                        if i != who {
                            let out = self.ops[i].on_message(ms(t), &m);
                            queue.extend(out.into_iter().map(|a| (i, a)));
                        }
                    }
                }
                other => local.push((who, other)),
            }
        }
        local
    }

    /// Steps the vehicle, recording every owner it changes to.
    fn event(&mut self, t: u64, event: Event) {
        let d = self.vehicle.step(ms(t), event);
        if let Some(c) = d.owner_change {
            self.owners.push(c.to.device());
        }
    }

    fn stream(&mut self, t: u64, writer: WriterId, device: i64, strength: u16) {
        self.event(
            t,
            Event::Sample {
                writer,
                strength: Strength(strength),
                command: command(device, CommandType::Movement, 1),
                arrival: ms(t),
            },
        );
    }
}

#[test]
fn end_to_end_request_accept_drive_finish_with_no_ping_pong() {
    let mut bus = Bus {
        vehicle: Arbiter::new(VEHICLE, ArbiterConfig::default()),
        ops: vec![owner_a(AutoAccept::HigherPriority), requester_b()],
        owners: Vec::new(),
    };
    let (mut a_drives, mut b_priority) = (true, false);
    for t in (0..2000).step_by(20) {
        // Operators act on their local actions.
        let mut local = Vec::new();
        if t == 100 {
            let actions = bus.ops[1]
                .request(ms(t), VEHICLE, A, STAMP)
                .expect("request");
            local.extend(bus.deliver(t, 1, actions));
        }
        if t == 300 {
            let actions = bus.ops[0]
                .decide(ms(10), VEHICLE, true)
                .expect("prompt open");
            local.extend(bus.deliver(t, 0, actions));
        }
        if t == 1000 {
            let actions = bus.ops[1].finish(VEHICLE).expect("holding");
            local.extend(bus.deliver(t, 1, actions));
        }
        for (who, action) in local {
            match (who, action) {
                // The replier stops streaming without releasing (handover module docs).
                (0, Action::Yield { .. }) => a_drives = false,
                (0, Action::Resume { .. }) => a_drives = true,
                (1, Action::StartPriorityDriving { .. }) => b_priority = true,
                (1, Action::StopPriorityDriving { .. }) => {
                    b_priority = false;
                    bus.event(t, Event::Released { writer: pw(2) });
                }
                _ => {}
            }
        }
        if a_drives {
            bus.stream(t, w(1), A, 220);
        }
        if b_priority {
            bus.stream(t, pw(2), B, 65535);
        }
        // A late, already-in-flight sample from A right after the handover wins nothing.
        if t == 320 {
            bus.stream(t, w(1), A, 220);
        }
        let expected = match t {
            0..300 => A,
            300..1000 => B,
            _ => A,
        };
        assert_eq!(bus.vehicle.controller_id(), expected, "t={t}");
    }
    // A → B directly (no failsafe gap) → (grant returned, A silent) failsafe → A: each handover
    // exactly once, and A's late sample at 320 ms did not win the vehicle back.
    assert_eq!(bus.owners, [Some(A), Some(B), None, Some(A)]);
    assert_eq!(bus.vehicle.grant_holder(), None);
}

// ---- Regressions found by tests/handover_properties.rs ----------------------------------------

/// A late FINISH from an earlier handover must not end the current one (both would drive).
#[test]
fn a_late_finish_of_an_earlier_handover_does_not_end_the_current_one() {
    let mut a = owner_a(AutoAccept::Always);
    a.on_message(ms(0), &msg(B, Ack::Request, 120, STAMP));
    a.on_message(ms(1), &msg(B, Ack::Finish, 120, STAMP));
    let second = TimeT(5_000);
    a.on_message(ms(2), &msg(B, Ack::Request, 120, second));
    assert!(a.has_yielded(VEHICLE));
    // The first handover's FINISH arrives again, late.
    assert_eq!(a.on_message(ms(3), &msg(B, Ack::Finish, 120, STAMP)), []);
    assert!(a.has_yielded(VEHICLE));
    assert_eq!(
        a.on_message(ms(4), &msg(B, Ack::Finish, 120, second)),
        [Action::Resume { vehicle: VEHICLE }]
    );
}

/// A REQUEST resent after its grant was finished (or taken back) must not re-accept it.
#[test]
fn a_resent_request_after_the_grant_ended_gets_no_answer() {
    let mut a = owner_a(AutoAccept::Always);
    a.on_message(ms(0), &msg(B, Ack::Request, 120, STAMP));
    a.on_message(ms(1), &msg(B, Ack::Finish, 120, STAMP));
    assert_eq!(a.on_message(ms(2), &msg(B, Ack::Request, 120, STAMP)), []);
    assert!(!a.has_yielded(VEHICLE));

    let mut a = owner_a(AutoAccept::Always);
    a.on_message(ms(0), &msg(B, Ack::Request, 120, STAMP));
    assert!(a.resume(VEHICLE));
    assert_eq!(a.on_message(ms(2), &msg(B, Ack::Request, 120, STAMP)), []);
    assert!(!a.has_yielded(VEHICLE));
}

/// A yielded replier learns from the vehicle that the grant is over when the FINISH never
/// arrives (seen in the benchmark: a holder quit before its FINISH was delivered).
#[test]
fn a_lost_finish_is_made_up_for_by_the_vehicle_naming_us_again() {
    let mut a = owner_a(AutoAccept::Always);
    a.on_message(ms(0), &msg(B, Ack::Request, 120, STAMP));
    assert!(a.has_yielded(VEHICLE));
    // Still ours until the holder's stream reaches the vehicle: nothing to do.
    assert_eq!(a.on_vehicle_owner(VEHICLE, A), []);
    assert_eq!(a.on_vehicle_owner(VEHICLE, B), []);
    assert!(a.has_yielded(VEHICLE));
    // The holder drove; now the vehicle names us again: the grant ended.
    assert_eq!(
        a.on_vehicle_owner(VEHICLE, A),
        [Action::Resume { vehicle: VEHICLE }]
    );
    assert!(!a.has_yielded(VEHICLE));
    // The late FINISH and a resent REQUEST of that handover change nothing.
    assert_eq!(a.on_message(ms(5), &msg(B, Ack::Finish, 120, STAMP)), []);
    assert_eq!(a.on_message(ms(6), &msg(B, Ack::Request, 120, STAMP)), []);
}

#[test]
fn a_bystander_or_the_failsafe_on_the_vehicle_ends_the_yield() {
    for other in [C, VEHICLE] {
        // Before the holder was seen: the handover broke down.
        let mut a = owner_a(AutoAccept::Always);
        a.on_message(ms(0), &msg(B, Ack::Request, 120, STAMP));
        assert_eq!(
            a.on_vehicle_owner(VEHICLE, other),
            [Action::Resume { vehicle: VEHICLE }]
        );
        // After: the holder left without FINISH.
        let mut a = owner_a(AutoAccept::Always);
        a.on_message(ms(0), &msg(B, Ack::Request, 120, STAMP));
        a.on_vehicle_owner(VEHICLE, B);
        assert_eq!(
            a.on_vehicle_owner(VEHICLE, other),
            [Action::Resume { vehicle: VEHICLE }]
        );
    }
}

#[test]
fn vehicle_owners_change_nothing_unless_we_have_yielded() {
    let mut a = owner_a(AutoAccept::Never);
    for owner in [A, B, C, VEHICLE] {
        assert_eq!(a.on_vehicle_owner(VEHICLE, owner), []);
    }
    // Asking the person is not yielding.
    a.on_message(ms(0), &msg(B, Ack::Request, 120, STAMP));
    assert_eq!(a.on_vehicle_owner(VEHICLE, C), []);
    // Another vehicle's owner says nothing about ours.
    let mut a = owner_a(AutoAccept::Always);
    a.on_message(ms(0), &msg(B, Ack::Request, 120, STAMP));
    assert_eq!(a.on_vehicle_owner(VEHICLE + 1, C), []);
    assert!(a.has_yielded(VEHICLE));
}

/// The holder never shows up on the vehicle: after two resend periods the standby stream stops
/// (so the vehicle can time us out); we stay yielded until the vehicle says otherwise.
#[test]
fn the_standby_ends_when_the_holder_never_takes_over() {
    let mut a = owner_a(AutoAccept::Always);
    a.on_message(ms(100), &msg(B, Ack::Request, 120, STAMP));
    let resend = HandoverConfig::default().resend;
    assert_eq!(a.next_deadline(), Some(ms(100) + resend * 2));
    assert_eq!(
        a.tick(ms(100) + (resend * 2 - std::time::Duration::from_nanos(1))),
        []
    );
    assert_eq!(
        a.tick(ms(100) + resend * 2),
        [Action::EndStandby { vehicle: VEHICLE }]
    );
    assert_eq!(a.next_deadline(), None);
    assert_eq!(a.tick(ms(5_000)), []);
    assert!(a.has_yielded(VEHICLE));
    assert_eq!(
        a.on_vehicle_owner(VEHICLE, VEHICLE),
        [Action::Resume { vehicle: VEHICLE }]
    );

    // Once the holder has been seen there is no standby deadline.
    let mut a = owner_a(AutoAccept::Always);
    a.on_message(ms(100), &msg(B, Ack::Request, 120, STAMP));
    a.on_vehicle_owner(VEHICLE, B);
    assert_eq!(a.next_deadline(), None);
    assert_eq!(a.tick(ms(60_000)), []);
}
