//! Unit tests of the operator session: one behaviour each, effects compared in full.

use super::*;
// Named here since the session's code moved into submodules (`super::*` no longer brings them).
use crate::adapter::InputAction;
use crate::arbiter::Event as ArbiterEvent;
use crate::handover::{AutoAccept, Outcome, Prompt};
use crate::msg::{Ack, CommandType, DeviceType};
use crate::trust::Suspect;

const ME: DeviceId = 11;
const OTHER: DeviceId = 12;
const V: DeviceId = 100;
const W: DeviceId = 101;

fn ms(t: u64) -> MonoTime {
    MonoTime::from_millis(t)
}

fn stamp(t: u64) -> TimeT {
    TimeT(1_000_000 + t)
}

fn sticks(throttle: i16) -> MovementCommand {
    MovementCommand {
        throttle,
        ..MovementCommand::CENTRED
    }
}

fn config(input: SessionInput) -> SessionConfig {
    SessionConfig {
        me: ME,
        strength: Strength(220),
        handover: HandoverConfig::default(),
        drive: vec![V],
        input,
        heartbeat: Duration::from_millis(500),
        confirm_actions: false,
        request: None,
        participant: participant(ME),
        trust: crate::trust::TrustConfig::default(),
    }
}

/// Each device's own participant in these tests.
fn participant(id: DeviceId) -> ParticipantId {
    ParticipantId(0x1000 + id as u128)
}

/// A RequestControl sample as it arrives from its sender's own participant.
fn rc(msg: RequestControl) -> SessionEvent {
    SessionEvent::RequestControl {
        msg,
        from: participant(msg.sender_id()),
    }
}

fn constant() -> OperatorSession {
    OperatorSession::new(
        config(SessionInput::Constant(sticks(100), Mode::Manual)),
        ms(0),
    )
}

fn device() -> OperatorSession {
    OperatorSession::new(config(SessionInput::Device), ms(0))
}

fn vehicle(id: DeviceId, owner: DeviceId) -> SessionEvent {
    SessionEvent::DeviceInfo {
        info: DeviceInfo {
            device_id: id,
            name: format!("v{id}"),
            device_type: DeviceType::Vehicle,
            controller_id: owner,
        },
        from: participant(id),
    }
}

fn sample(
    vehicle: DeviceId,
    kind: CommandType,
    throttle: i16,
    mode: Mode,
    t: u64,
) -> ControlCommand {
    ControlCommand {
        src_id: ME,
        dest_id: vehicle,
        command_type: kind,
        movement_command: sticks(throttle),
        mode,
        timestamp: stamp(t),
    }
}

fn writes(effects: &[Effect]) -> Vec<(Writer, ControlCommand)> {
    effects
        .iter()
        .filter_map(|e| match e {
            Effect::Write { writer, command } => Some((*writer, *command)),
            _ => None,
        })
        .collect()
}

fn releases(effects: &[Effect]) -> Vec<(Writer, DeviceId)> {
    effects
        .iter()
        .filter_map(|e| match e {
            Effect::Release { writer, vehicle } => Some((*writer, *vehicle)),
            _ => None,
        })
        .collect()
}

fn sent(effects: &[Effect]) -> Vec<RequestControl> {
    effects
        .iter()
        .filter_map(|e| match e {
            Effect::Send(m) => Some(*m),
            _ => None,
        })
        .collect()
}

fn refused(effects: &[Effect]) -> Option<&str> {
    effects.iter().find_map(|e| match e {
        Effect::Refused(why) => Some(why.as_str()),
        _ => None,
    })
}

fn step(s: &mut OperatorSession, t: u64, event: SessionEvent) -> Vec<Effect> {
    s.step(ms(t), stamp(t), event)
}

fn request_from(requester: DeviceId, priority: i32, t: u64) -> SessionEvent {
    rc(RequestControl {
        src_id: requester,
        dest_id: V,
        current_controller_id: ME,
        src_priority: priority,
        ack: Ack::Request,
        timestamp: stamp(t),
    })
}

/// `requester`'s regular writer is discovered at `priority`, then its REQUEST for `V` arrives
/// at `t`.
fn request(s: &mut OperatorSession, requester: DeviceId, priority: i32, t: u64) -> Vec<Effect> {
    let writer = Writer::Regular.id(participant(requester));
    let strength = Strength(u16::try_from(priority).expect("an operator strength"));
    step(s, t, SessionEvent::WriterFound { writer, strength });
    step(s, t, request_from(requester, priority, t))
}

/// Requests vehicle `W` from OTHER at `t` and receives its ACCEPT: we then hold the grant.
/// Returns the effects of the ACCEPT.
fn hold_grant(s: &mut OperatorSession, t: u64) -> Vec<Effect> {
    step(s, t, vehicle(W, OTHER));
    let out = step(
        s,
        t + 1,
        SessionEvent::Command(Command::Request { vehicle: W }),
    );
    let accept = RequestControl {
        ack: Ack::Accept,
        ..sent(&out)[0]
    };
    step(s, t + 2, rc(accept))
}

#[test]
fn constant_sticks_stream_to_the_configured_vehicles_on_every_keepalive() {
    let mut s = constant();
    let out = step(&mut s, 20, SessionEvent::StreamTick);
    assert_eq!(
        out,
        vec![Effect::Write {
            writer: Writer::Regular,
            command: sample(V, CommandType::Movement, 100, Mode::Manual, 20),
        }]
    );
    assert_eq!(s.status_line(), "driving 100; 0 vehicles seen");
}

#[test]
fn a_device_drives_only_once_it_reports_sticks_and_sends_each_change_at_once() {
    let mut s = device();
    assert!(step(&mut s, 20, SessionEvent::StreamTick).is_empty());
    assert_eq!(s.streams().paused, vec![V]);
    let out = step(&mut s, 25, SessionEvent::Input(InputEvent::Axes(sticks(5))));
    assert_eq!(
        out,
        vec![
            Effect::Report(Report::InputLive { vehicles: vec![V] }),
            Effect::Write {
                writer: Writer::Regular,
                command: sample(V, CommandType::Movement, 5, Mode::Manual, 25),
            },
        ]
    );
    let out = step(&mut s, 26, SessionEvent::Input(InputEvent::Axes(sticks(6))));
    assert_eq!(
        writes(&out),
        vec![(
            Writer::Regular,
            sample(V, CommandType::Movement, 6, Mode::Manual, 26)
        )]
    );
}

#[test]
fn a_lost_device_or_released_deadman_releases_everything_and_resumes_on_live_sticks() {
    for lost in [
        InputEvent::Lost {
            reason: "unplugged".into(),
        },
        InputEvent::Deadman(false),
    ] {
        let mut s = device();
        step(&mut s, 1, SessionEvent::Input(InputEvent::Axes(sticks(5))));
        let out = step(&mut s, 2, SessionEvent::Input(lost.clone()));
        assert_eq!(releases(&out), vec![(Writer::Regular, V)], "{lost:?}");
        assert!(writes(&out).is_empty());
        assert!(step(&mut s, 20, SessionEvent::StreamTick).is_empty());
        // A second loss releases nothing more.
        assert!(step(&mut s, 21, SessionEvent::Input(lost)).is_empty());
        let out = step(&mut s, 30, SessionEvent::Input(InputEvent::Axes(sticks(0))));
        assert_eq!(
            writes(&out),
            vec![(
                Writer::Regular,
                sample(V, CommandType::Movement, 0, Mode::Manual, 30)
            )]
        );
    }
}

#[test]
fn drive_is_refused_for_an_unseen_or_owned_vehicle_and_done_for_a_free_one() {
    let mut s = constant();
    let out = step(
        &mut s,
        1,
        SessionEvent::Command(Command::Drive { vehicle: W }),
    );
    assert_eq!(refused(&out), Some("vehicle 101 has not been seen"));
    step(&mut s, 2, vehicle(W, OTHER));
    let out = step(
        &mut s,
        3,
        SessionEvent::Command(Command::Drive { vehicle: W }),
    );
    assert_eq!(
        refused(&out),
        Some("vehicle 101 is driven by 12: request control instead")
    );
    assert!(!s.streams_to(W));
    step(&mut s, 4, vehicle(W, W));
    let out = step(
        &mut s,
        5,
        SessionEvent::Command(Command::Drive { vehicle: W }),
    );
    assert_eq!(refused(&out), None);
    assert_eq!(
        writes(&out),
        vec![(
            Writer::Regular,
            sample(W, CommandType::Movement, 100, Mode::Manual, 5)
        )]
    );
    assert_eq!(s.selected(), Some(W));
}

#[test]
fn request_asks_the_owner_and_drives_a_free_vehicle_instead() {
    let mut s = constant();
    step(&mut s, 1, vehicle(W, OTHER));
    let out = step(
        &mut s,
        2,
        SessionEvent::Command(Command::Request { vehicle: W }),
    );
    let msgs = sent(&out);
    assert_eq!(msgs.len(), 1);
    assert_eq!(
        (
            msgs[0].ack,
            msgs[0].src_id,
            msgs[0].dest_id,
            msgs[0].current_controller_id
        ),
        (Ack::Request, ME, W, OTHER)
    );
    assert!(out.contains(&Effect::Report(Report::RequestSent {
        vehicle: W,
        owner: OTHER
    })));
    // A second request while one is open is refused.
    let out = step(
        &mut s,
        3,
        SessionEvent::Command(Command::Request { vehicle: W }),
    );
    assert!(refused(&out).is_some_and(|w| w.starts_with("cannot request 101")));

    let mut s = constant();
    step(&mut s, 1, vehicle(W, W));
    let out = step(
        &mut s,
        2,
        SessionEvent::Command(Command::Request { vehicle: W }),
    );
    assert!(sent(&out).is_empty());
    assert!(s.streams_to(W));
}

#[test]
fn a_stronger_requester_is_auto_accepted_and_we_stand_by_with_probes() {
    let mut s = constant();
    step(&mut s, 1, vehicle(V, ME));
    let out = request(&mut s, OTHER, 340, 2);
    let msgs = sent(&out);
    assert_eq!(msgs.len(), 1);
    assert_eq!((msgs[0].ack, msgs[0].src_id), (Ack::Accept, OTHER));
    assert!(out.contains(&Effect::Report(Report::Yielded { vehicle: V })));
    // Standing by: PROBEs only, never a MOVEMENT.
    let out = step(&mut s, 20, SessionEvent::StreamTick);
    assert_eq!(
        writes(&out),
        vec![(
            Writer::Regular,
            sample(V, CommandType::Probe, 100, Mode::Manual, 20)
        )]
    );
    assert_eq!(s.status_line(), "standing by for 100; 1 vehicle seen");
    // The holder's FINISH: we drive again at once.
    let finish = rc(RequestControl {
        ack: Ack::Finish,
        ..msgs[0]
    });
    let out = step(&mut s, 30, finish);
    assert!(out.contains(&Effect::Report(Report::Resumed {
        vehicle: V,
        live: true
    })));
    assert_eq!(
        writes(&out),
        vec![(
            Writer::Regular,
            sample(V, CommandType::Movement, 100, Mode::Manual, 30)
        )]
    );
}

#[test]
fn a_weaker_requester_prompts_and_the_person_decides() {
    let mut s = constant();
    step(&mut s, 1, vehicle(V, ME));
    let out = request(&mut s, OTHER, 130, 2);
    assert!(sent(&out).is_empty());
    assert!(matches!(
        out.as_slice(),
        [Effect::Report(Report::Prompt(Prompt {
            vehicle: V,
            requester: OTHER,
            src_priority: 130,
            ..
        }))]
    ));
    // The accept button acts on the open prompt.
    let out = step(
        &mut s,
        3,
        SessionEvent::Input(InputEvent::Action(InputAction::Accept)),
    );
    assert_eq!(sent(&out).first().map(|m| m.ack), Some(Ack::Accept));
    assert!(out.contains(&Effect::Report(Report::PromptClosed {
        vehicle: V,
        outcome: Outcome::Accepted
    })));
    // Nothing left to answer.
    let out = step(
        &mut s,
        4,
        SessionEvent::Command(Command::Refuse { vehicle: V }),
    );
    assert!(refused(&out).is_some());
}

#[test]
fn with_a_console_buttons_go_to_it_for_confirmation() {
    let mut c = config(SessionInput::Device);
    c.confirm_actions = true;
    let mut s = OperatorSession::new(c, ms(0));
    let out = step(
        &mut s,
        1,
        SessionEvent::Input(InputEvent::Action(InputAction::Release)),
    );
    assert_eq!(out, vec![Effect::Confirm(InputAction::Release)]);
}

#[test]
fn a_grant_is_driven_with_the_priority_writer_and_finished_when_the_input_is_lost() {
    let mut s = device();
    step(&mut s, 1, SessionEvent::Input(InputEvent::Axes(sticks(7))));
    let out = hold_grant(&mut s, 2);
    assert_eq!(
        writes(&out),
        vec![(
            Writer::Priority,
            sample(W, CommandType::Movement, 7, Mode::Manual, 4)
        )]
    );
    let out = step(&mut s, 20, SessionEvent::StreamTick);
    assert!(writes(&out).contains(&(
        Writer::Priority,
        sample(W, CommandType::Movement, 7, Mode::Manual, 20)
    )));
    let out = step(
        &mut s,
        21,
        SessionEvent::Input(InputEvent::Lost {
            reason: "gone".into(),
        }),
    );
    assert_eq!(
        sent(&out)
            .iter()
            .map(|m| (m.ack, m.dest_id))
            .collect::<Vec<_>>(),
        vec![(Ack::Finish, W)]
    );
    assert_eq!(
        releases(&out),
        vec![(Writer::Regular, V), (Writer::Priority, W)]
    );
    assert!(!s.streams_to(W) && !s.streams_to(V));
}

/// A grant that arrives while the input is not live (the request went out, then the joystick
/// was unplugged) is given back at once: nothing moves on the priority writer with the sticks
/// the device last reported.
#[test]
fn a_grant_accepted_after_the_input_was_lost_is_finished_not_driven() {
    let mut s = device();
    step(&mut s, 1, SessionEvent::Input(InputEvent::Axes(sticks(7))));
    step(&mut s, 2, vehicle(W, OTHER));
    let out = step(
        &mut s,
        3,
        SessionEvent::Command(Command::Request { vehicle: W }),
    );
    let request = sent(&out)[0];
    let lost = InputEvent::Lost {
        reason: "gone".into(),
    };
    step(&mut s, 4, SessionEvent::Input(lost));
    let accept = RequestControl {
        ack: Ack::Accept,
        ..request
    };
    let out = step(&mut s, 5, rc(accept));
    assert_eq!(writes(&out), vec![], "nothing driven without live input");
    assert_eq!(
        sent(&out)
            .iter()
            .map(|m| (m.ack, m.dest_id))
            .collect::<Vec<_>>(),
        vec![(Ack::Finish, W)]
    );
    assert!(!s.streams_to(W));
    let out = step(&mut s, 20, SessionEvent::StreamTick);
    assert_eq!(writes(&out), vec![]);
}

#[test]
fn mode_changes_go_out_at_once_and_stay() {
    let mut s = constant();
    let out = step(
        &mut s,
        1,
        SessionEvent::Command(Command::Mode {
            vehicle: None,
            mode: Mode::Auto,
        }),
    );
    assert_eq!(
        writes(&out),
        vec![(
            Writer::Regular,
            sample(V, CommandType::Movement, 100, Mode::Auto, 1)
        )]
    );
    assert_eq!(s.input().1, Mode::Auto);
}

#[test]
fn release_all_stops_every_stream_and_finishes_grants() {
    let mut s = constant();
    hold_grant(&mut s, 1);
    let out = step(
        &mut s,
        4,
        SessionEvent::Command(Command::Release { vehicle: None }),
    );
    assert_eq!(sent(&out).first().map(|m| m.ack), Some(Ack::Finish));
    assert_eq!(
        releases(&out),
        vec![(Writer::Regular, V), (Writer::Priority, W)]
    );
    assert!(step(&mut s, 20, SessionEvent::StreamTick).is_empty());
}

#[test]
fn stop_finishes_grants_then_releases_every_instance() {
    let mut s = constant();
    hold_grant(&mut s, 1);
    let out = s.stop(stamp(5));
    let kinds: Vec<&str> = out
        .iter()
        .filter_map(|e| match e {
            Effect::Send(_) => Some("send"),
            Effect::Release { .. } => Some("release"),
            _ => None,
        })
        .collect();
    assert_eq!(kinds, vec!["send", "release", "release"]);
    assert_eq!(sent(&out)[0].ack, Ack::Finish);
    assert!(step(&mut s, 20, SessionEvent::StreamTick).is_empty());
}

#[test]
fn request_when_seen_waits_for_live_info_then_asks_or_drives_a_free_vehicle() {
    let mut c = config(SessionInput::Constant(sticks(1), Mode::Manual));
    c.drive = vec![];
    c.request = Some(W);
    // Owned by another: asked once the DeviceInfo is live (a heartbeat after start).
    let mut s = OperatorSession::new(c.clone(), ms(0));
    assert!(sent(&step(&mut s, 100, vehicle(W, OTHER))).is_empty());
    let out = step(&mut s, 600, vehicle(W, OTHER));
    assert_eq!(sent(&out).first().map(|m| m.ack), Some(Ack::Request));
    assert!(sent(&step(&mut s, 1100, vehicle(W, OTHER))).is_empty());
    // Ownerless: free only after two heartbeats, and a heartbeat after it was first seen.
    let mut s = OperatorSession::new(c.clone(), ms(0));
    assert!(step(&mut s, 600, vehicle(W, W)).is_empty());
    assert!(step(&mut s, 1000, vehicle(W, W)).is_empty());
    assert!(!s.streams_to(W));
    let out = step(&mut s, 1100, vehicle(W, W));
    assert!(s.streams_to(W));
    assert!(out.contains(&Effect::Report(Report::Driving {
        vehicle: W,
        why: DriveReason::Free
    })));
    // Discovery was slow (as under DDS Security): the history burst arrives late with an old
    // "free" sample; the live heartbeat that follows names the owner, and it is asked.
    let mut s = OperatorSession::new(c.clone(), ms(0));
    assert!(step(&mut s, 1200, vehicle(W, W)).is_empty());
    assert!(!s.streams_to(W));
    let out = step(&mut s, 1700, vehicle(W, OTHER));
    assert_eq!(sent(&out).first().map(|m| m.ack), Some(Ack::Request));
    assert!(!s.streams_to(W));
    // Names us without our stream: an old sample; wait.
    let mut s = OperatorSession::new(c, ms(0));
    step(&mut s, 600, vehicle(W, ME));
    assert!(!s.streams_to(W));
    let out = step(&mut s, 1100, vehicle(W, OTHER));
    assert_eq!(sent(&out).first().map(|m| m.ack), Some(Ack::Request));
}

/// An unchanged DeviceInfo is published only every few seconds (presence is the participant's),
/// so the `--request` decision falls due on a Tick at its deadline, not at the next sample.
#[test]
fn request_when_seen_decides_at_its_deadline_without_another_sample() {
    let mut c = config(SessionInput::Constant(sticks(1), Mode::Manual));
    c.drive = vec![];
    c.request = Some(W);
    // Owned by another: asked a heartbeat after the first sample.
    let mut s = OperatorSession::new(c.clone(), ms(0));
    assert!(sent(&step(&mut s, 100, vehicle(W, OTHER))).is_empty());
    assert_eq!(s.next_deadline(), Some(ms(600)));
    let out = s.step(ms(600), stamp(600), SessionEvent::Tick);
    assert_eq!(sent(&out).first().map(|m| m.ack), Some(Ack::Request));
    // Ownerless: driven when it counts as free, a heartbeat after it was first seen.
    let mut s = OperatorSession::new(c.clone(), ms(0));
    assert!(step(&mut s, 600, vehicle(W, W)).is_empty());
    assert_eq!(s.next_deadline(), Some(ms(1100)));
    s.step(ms(1100), stamp(1100), SessionEvent::Tick);
    assert!(s.streams_to(W));
    assert_eq!(s.next_deadline(), None, "decided: nothing left to wait for");
    // Names us without our stream: an old sample; no deadline, it waits for a fresher one.
    let mut s = OperatorSession::new(c.clone(), ms(0));
    step(&mut s, 600, vehicle(W, ME));
    assert_eq!(s.next_deadline(), None);
    // The vehicle's participant left before the decision (its pin lapsed after the grace):
    // nothing is decided on its last sample, and nothing waits for a deadline.
    let mut s = OperatorSession::new(c, ms(0));
    step(&mut s, 100, vehicle(W, OTHER));
    let gone = SessionEvent::ParticipantGone {
        participant: participant(W),
    };
    step(&mut s, 200, gone);
    let out = s.step(ms(1000), stamp(1000), SessionEvent::Tick);
    assert!(sent(&out).is_empty(), "asked a vehicle that left: {out:?}");
    assert_eq!(s.next_deadline(), None);
}

#[test]
fn a_stream_tick_has_work_only_while_something_is_driven_held_or_stood_by_for() {
    let mut c = config(SessionInput::Constant(sticks(1), Mode::Manual));
    c.drive = vec![];
    let mut s = OperatorSession::new(c, ms(0));
    assert!(!s.streams_anything());
    assert!(step(&mut s, 1, SessionEvent::StreamTick).is_empty());
    step(&mut s, 2, vehicle(W, W));
    step(
        &mut s,
        3,
        SessionEvent::Command(Command::Drive { vehicle: W }),
    );
    assert!(s.streams_to(W) && s.streams_anything());
    assert!(!step(&mut s, 4, SessionEvent::StreamTick).is_empty());
    let release = Command::Release { vehicle: Some(W) };
    step(&mut s, 5, SessionEvent::Command(release));
    assert!(!s.streams_anything());
}

#[test]
fn buttons_cycle_the_selected_vehicle_through_those_seen() {
    let mut s = constant();
    step(&mut s, 1, vehicle(V, V));
    step(&mut s, 1, vehicle(W, W));
    let next = SessionEvent::Input(InputEvent::Action(InputAction::NextVehicle));
    let prev = SessionEvent::Input(InputEvent::Action(InputAction::PreviousVehicle));
    assert_eq!(s.selected(), Some(V));
    step(&mut s, 2, next.clone());
    assert_eq!(s.selected(), Some(W));
    step(&mut s, 3, next);
    assert_eq!(s.selected(), Some(V));
    let out = step(&mut s, 4, prev);
    assert_eq!(s.selected(), Some(W));
    assert_eq!(
        out,
        vec![Effect::Report(Report::Selected { vehicle: Some(W) })]
    );
}

#[test]
fn auto_accept_never_always_asks() {
    let mut c = config(SessionInput::Constant(sticks(1), Mode::Manual));
    c.handover.auto_accept = AutoAccept::Never;
    let mut s = OperatorSession::new(c, ms(0));
    step(&mut s, 1, vehicle(V, ME));
    let out = request(&mut s, OTHER, 65_000, 2);
    assert!(sent(&out).is_empty());
    // Refused at the consent timeout.
    let deadline = s.next_deadline().expect("a consent deadline");
    let out = s.step(deadline, stamp(20_000), SessionEvent::Tick);
    assert_eq!(sent(&out).first().map(|m| m.ack), Some(Ack::Refuse));
}

#[test]
fn status_line_says_what_we_drive_hold_and_stand_by_for() {
    let mut s = device();
    assert_eq!(s.status_line(), "driving nothing; 0 vehicles seen");
    step(&mut s, 1, SessionEvent::Input(InputEvent::Axes(sticks(1))));
    step(&mut s, 2, vehicle(V, ME));
    assert_eq!(s.status_line(), "driving 100; 1 vehicle seen");
    request(&mut s, OTHER, 340, 3);
    hold_grant(&mut s, 4);
    assert_eq!(
        s.status_line(),
        "holding a grant for 101; standing by for 100; 2 vehicles seen"
    );
}

#[test]
fn driving_a_yielded_vehicle_that_is_still_ours_takes_it_back_from_standby() {
    let mut s = constant();
    step(&mut s, 1, vehicle(V, ME));
    request(&mut s, OTHER, 340, 2);
    assert!(s.handover().has_yielded(V));
    // The holder never shows up on the vehicle; the person drives it again.
    let out = step(
        &mut s,
        3,
        SessionEvent::Command(Command::Drive { vehicle: V }),
    );
    assert_eq!(refused(&out), None);
    assert!(!s.handover().has_yielded(V));
    assert_eq!(
        writes(&step(&mut s, 20, SessionEvent::StreamTick)),
        vec![(
            Writer::Regular,
            sample(V, CommandType::Movement, 100, Mode::Manual, 20)
        )],
        "MOVEMENT only, no standby PROBE"
    );
}

#[test]
fn losing_the_input_while_standing_by_stops_the_probes_and_releases() {
    let mut s = device();
    step(&mut s, 1, SessionEvent::Input(InputEvent::Axes(sticks(1))));
    step(&mut s, 2, vehicle(V, ME));
    request(&mut s, OTHER, 340, 3);
    assert_eq!(s.streams().standby, vec![V]);
    let out = step(&mut s, 4, SessionEvent::Input(InputEvent::Deadman(false)));
    assert_eq!(releases(&out), vec![(Writer::Regular, V)]);
    assert!(step(&mut s, 20, SessionEvent::StreamTick).is_empty());
    // The yield stands: the grant's end brings the vehicle back, paused until live input.
    assert!(s.handover().has_yielded(V));
}

#[test]
fn yielding_without_live_input_releases_instead_of_standing_by() {
    let mut s = device();
    step(&mut s, 1, vehicle(V, ME));
    let out = request(&mut s, OTHER, 340, 2);
    assert_eq!(sent(&out).first().map(|m| m.ack), Some(Ack::Accept));
    assert_eq!(releases(&out), vec![(Writer::Regular, V)]);
    assert!(writes(&out).is_empty());
    assert!(s.streams().standby.is_empty());
}

#[test]
fn direct_delivery_maps_writes_releases_and_grants_for_this_vehicle_only() {
    let p = ParticipantId(7);
    let write = Effect::Write {
        writer: Writer::Priority,
        command: sample(V, CommandType::Movement, 1, Mode::Manual, 1),
    };
    assert!(matches!(
        write.arbiter_event(V, p, Strength(220), ms(1)),
        Some(ArbiterEvent::Sample { writer, strength: Strength::PRIORITY, .. })
            if writer == Writer::Priority.id(p)
    ));
    let release = |vehicle| Effect::Release {
        writer: Writer::Regular,
        vehicle,
    };
    assert_eq!(
        release(V).arbiter_event(V, p, Strength(220), ms(1)),
        Some(ArbiterEvent::Released {
            writer: Writer::Regular.id(p)
        })
    );
    assert_eq!(release(W).arbiter_event(V, p, Strength(220), ms(1)), None);
    let finish = RequestControl {
        src_id: ME,
        dest_id: V,
        current_controller_id: OTHER,
        src_priority: 220,
        ack: Ack::Finish,
        timestamp: stamp(1),
    };
    assert!(matches!(
        Effect::Send(finish).arbiter_event(V, p, Strength(220), ms(1)),
        Some(ArbiterEvent::GrantFinished { holder: ME, .. })
    ));
    assert_eq!(
        Effect::Refused("no".into()).arbiter_event(V, p, Strength(220), ms(1)),
        None
    );
}

#[test]
fn a_priority_that_discovery_does_not_confirm_is_put_to_a_person() {
    let mut s = constant();
    step(&mut s, 1, vehicle(V, ME));
    // OTHER's writer announces 130, its REQUEST claims 340.
    let writer = Writer::Regular.id(participant(OTHER));
    step(
        &mut s,
        2,
        SessionEvent::WriterFound {
            writer,
            strength: Strength(130),
        },
    );
    let out = step(&mut s, 2, request_from(OTHER, 340, 2));
    assert!(sent(&out).is_empty(), "not auto-accepted: {out:?}");
    assert!(matches!(
        out[..],
        [Effect::Report(Report::Prompt(Prompt {
            requester: OTHER,
            ..
        }))]
    ));
    assert!(s.streams_to(V));
}

#[test]
fn a_request_for_a_vehicle_we_do_not_drive_or_that_names_another_owner_is_not_answered() {
    let mut s = constant();
    // W is not driven by us (only V is).
    step(&mut s, 1, vehicle(W, ME));
    let forged = RequestControl {
        dest_id: W,
        ..match request_from(OTHER, 340, 2) {
            SessionEvent::RequestControl { msg, .. } => msg,
            _ => unreachable!(),
        }
    };
    let writer = Writer::Regular.id(participant(OTHER));
    step(
        &mut s,
        2,
        SessionEvent::WriterFound {
            writer,
            strength: Strength(340),
        },
    );
    let out = step(&mut s, 2, rc(forged));
    assert_eq!(
        out,
        vec![Effect::Report(Report::RequestIgnored {
            vehicle: W,
            requester: OTHER
        })]
    );
    // V is driven by us, but its DeviceInfo names someone else: not ours to give.
    step(&mut s, 3, vehicle(V, 13));
    let out = request(&mut s, OTHER, 340, 4);
    assert_eq!(
        out,
        vec![Effect::Report(Report::RequestIgnored {
            vehicle: V,
            requester: OTHER
        })]
    );
    // A later FINISH cannot make us resume what we never yielded.
    let finish = RequestControl {
        ack: Ack::Finish,
        ..forged
    };
    let out = step(&mut s, 5, rc(finish));
    assert!(out.is_empty(), "{out:?}");
    assert!(!s.streams_to(W));
}

#[test]
fn messages_claiming_an_id_pinned_to_another_participant_are_reported_and_ignored() {
    let mut s = constant();
    step(&mut s, 1, vehicle(V, ME));
    let rogue = ParticipantId(0xbad);
    // A DeviceInfo for V from the rogue, naming another owner: not believed.
    let forged = SessionEvent::DeviceInfo {
        info: DeviceInfo {
            controller_id: 99,
            ..s.vehicles()[&V].clone()
        },
        from: rogue,
    };
    let out = step(&mut s, 2, forged);
    assert_eq!(
        out,
        vec![Effect::Report(Report::Untrusted(Suspect {
            device: V,
            sender: rogue,
            why: crate::trust::Distrust::IdOfAnotherParticipant {
                owner: participant(V)
            },
        }))]
    );
    assert_eq!(s.vehicles()[&V].controller_id, ME);
    // A REQUEST in OTHER's name from the rogue, once OTHER has spoken: not believed.
    request(&mut s, OTHER, 340, 3);
    let SessionEvent::RequestControl { msg, .. } = request_from(OTHER, 340, 4) else {
        unreachable!()
    };
    let out = step(
        &mut s,
        4,
        SessionEvent::RequestControl {
            msg: RequestControl {
                ack: Ack::Finish,
                ..msg
            },
            from: rogue,
        },
    );
    assert!(
        matches!(
            out[..],
            [Effect::Report(Report::Untrusted(Suspect {
                device: OTHER,
                ..
            }))]
        ),
        "{out:?}"
    );
    assert_eq!(
        s.streams().standby,
        vec![V],
        "the forged FINISH did not end the yield"
    );
    // Our own id cannot be taken either.
    let out = step(
        &mut s,
        5,
        SessionEvent::RequestControl {
            msg: RequestControl { src_id: ME, ..msg },
            from: rogue,
        },
    );
    assert!(matches!(
        out[..],
        [Effect::Report(Report::Untrusted(Suspect {
            device: ME,
            ..
        }))]
    ));
}

#[test]
fn a_prompt_answered_after_the_vehicle_is_no_longer_ours_refuses() {
    let mut s = constant();
    step(&mut s, 1, vehicle(V, ME));
    // A person must decide (the priority is unconfirmed)…
    let out = step(&mut s, 2, request_from(OTHER, 340, 2));
    assert!(matches!(out[..], [Effect::Report(Report::Prompt(_))]));
    // …but meanwhile the vehicle went to someone else: accepting would hand out a grant the
    // vehicle never honours.
    step(&mut s, 3, vehicle(V, 13));
    let out = step(
        &mut s,
        4,
        SessionEvent::Command(Command::Accept { vehicle: V }),
    );
    assert_eq!(
        sent(&out).iter().map(|m| m.ack).collect::<Vec<_>>(),
        vec![Ack::Refuse]
    );
    assert!(refused(&out).is_some_and(|why| why.contains("no longer ours")));
    assert!(!s.handover().has_yielded(V));
}

#[test]
fn the_vehicle_table_stays_bounded_under_invented_vehicles_and_keeps_ours() {
    let mut s = constant();
    step(&mut s, 0, vehicle(V, V));
    // Three waves of more invented vehicles than the table holds, each after the last wave's
    // pins lapsed (3 s): the table never outgrows its bound, forgets the lapsed strangers for
    // the newcomers, and keeps the vehicle we drive, whose pin lapsed too.
    for wave in 0..3 {
        let t = 10_000 * wave + 1;
        let first = 10_000 * (wave as DeviceId + 1);
        for id in first..first + MAX_VEHICLES as DeviceId + 100 {
            step(&mut s, t, vehicle(id, id));
        }
        assert!(s.vehicles().len() <= MAX_VEHICLES, "wave {wave}");
        assert!(
            s.vehicles().contains_key(&V),
            "wave {wave}: our vehicle forgotten"
        );
        assert!(
            s.vehicles().contains_key(&first),
            "wave {wave}: no room made"
        );
    }
}

#[test]
fn a_flood_of_requests_grows_no_handover_table_beyond_the_vehicles_we_answer_for() {
    let mut s = constant();
    step(&mut s, 0, vehicle(V, ME));
    // 5 000 requesters each ask for V (ours, named us) and for a vehicle of their own
    // invention: only V may be answered, and each table is keyed by vehicle.
    for n in 0..5_000 {
        let requester = 20_000 + n;
        let t = 1 + n as u64;
        step(&mut s, t, request_from(requester, 120, t));
        let elsewhere = RequestControl {
            src_id: requester,
            dest_id: 50_000 + n,
            current_controller_id: ME,
            src_priority: 120,
            ack: Ack::Request,
            timestamp: stamp(t),
        };
        step(&mut s, t, rc(elsewhere));
        assert!(
            s.handover().table_len() <= 2,
            "after {n}: {}",
            s.handover().table_len()
        );
    }
}
