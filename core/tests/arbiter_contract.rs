//! The ownership contract of docs/design.md §4, one named test per rule, as `(t_ms, event)` timelines
//! against manual time. The twist_mux black-box cases (`test/system_blackbox.py`: empty, basic,
//! priorities, fallback after timeout, locks) are ported at the end as deterministic tests.

mod common;

use common::*;
use rove_core::arbiter::{
    Arbiter, ArbiterConfig, Controller, Decision, Event, Ignored, Output, Owner, OwnerChange,
    ParticipantId, Reason, Setpoint, WriterId,
};
use rove_core::hierarchy::{DeviceClass, Hierarchy, Level, Strength};
use rove_core::msg::{CommandType, Mode, TimeT};
use rove_core::trust::{Access, Certified, Distrust, Grant, Suspect};

/// The stamp of the handovers in these tests.
const S: TimeT = TimeT(7);
use rove_core::watchdog::CommandTimeout;

const OP_A: i64 = 1; // stationary laptop
const OP_B: i64 = 2; // mobile phone
const OP_C: i64 = 3;

/// The participant each operator speaks from: its writers' (`w(n)`, `pw(n)`).
fn by(device: i64) -> ParticipantId {
    ParticipantId(u128::try_from(device).expect("a test operator id"))
}

fn ctl(writer: rove_core::arbiter::WriterId, device: i64, strength: u16) -> Controller {
    Controller {
        writer,
        device,
        strength: Strength(strength),
    }
}

fn applied(d: &Decision) -> Option<(i64, i16)> {
    match d.output? {
        Output::Apply { by, setpoint, .. } => Some((by.device, setpoint.movement.throttle)),
        Output::SafeState { .. } => None,
    }
}

fn change(d: &Decision) -> Option<(Option<i64>, Option<i64>, Reason)> {
    d.owner_change
        .map(|c| (c.from.device(), c.to.device(), c.reason))
}

// ---- Rule 3 / start: the failsafe owns when nobody is live -------------------------------------

#[test]
fn failsafe_owns_at_start_and_controller_id_is_the_vehicle() {
    let rig = Rig::new();
    assert_eq!(rig.arb.owner(), Owner::Failsafe);
    assert_eq!(rig.arb.controller_id(), VEHICLE);
    assert_eq!(rig.arb.next_deadline(), None);
}

#[test]
fn lone_controller_drives_and_its_sample_is_applied_at_once() {
    let mut rig = Rig::new();
    let d = rig.drive(0, w(1), OP_A, 220, 500);
    assert_eq!(
        d.owner_change,
        Some(OwnerChange {
            from: Owner::Failsafe,
            to: Owner::Controller(ctl(w(1), OP_A, 220)),
            reason: Reason::Joined,
        })
    );
    assert!(d.left_failsafe());
    assert_eq!(applied(&d), Some((OP_A, 500)));
    assert_eq!(rig.arb.controller_id(), OP_A);
    // Every following sample of the owner is applied, with provenance and rising sequence.
    let d2 = rig.drive(20, w(1), OP_A, 220, 600);
    assert_eq!(d2.owner_change, None);
    match (d.output, d2.output) {
        (Some(Output::Apply { seq: s1, .. }), Some(Output::Apply { seq: s2, by, .. })) => {
            assert!(s2 > s1);
            assert_eq!(by, ctl(w(1), OP_A, 220));
        }
        other => panic!("expected two applies, got {other:?}"),
    }
}

// ---- Rule 2: highest live strength; ties keep the incumbent; else lowest device id ----------

#[test]
fn stronger_controller_joining_preempts() {
    let mut rig = Rig::new();
    rig.drive(0, w(1), OP_A, 220, 100);
    let d = rig.drive(10, w(2), OP_B, 340, 200);
    assert_eq!(
        change(&d),
        Some((Some(OP_A), Some(OP_B), Reason::Preempted))
    );
    assert_eq!(applied(&d), Some((OP_B, 200)));
    // The preempted controller keeps streaming but is not applied.
    let d = rig.drive(20, w(1), OP_A, 220, 101);
    assert_eq!(d, Decision::default());
}

#[test]
fn weaker_controller_joining_does_not_take_over() {
    let mut rig = Rig::new();
    rig.drive(0, w(2), OP_B, 340, 100);
    let d = rig.drive(10, w(1), OP_A, 220, 200);
    assert_eq!(d, Decision::default());
    assert_eq!(rig.arb.controller_id(), OP_B);
}

#[test]
fn equal_strength_never_steals_from_the_incumbent() {
    let mut rig = Rig::new();
    // B has the higher id but came first: it keeps control against A at equal strength.
    rig.drive(0, w(2), OP_B, 220, 100);
    for t in (10..300).step_by(10) {
        let d = rig.drive(t, w(1), OP_A, 220, 5);
        assert_eq!(d.owner_change, None, "stolen at t={t}");
        rig.drive(t, w(2), OP_B, 220, 100);
    }
    assert_eq!(rig.arb.controller_id(), OP_B);
}

#[test]
fn with_no_incumbent_the_lowest_device_id_wins_a_tie() {
    let mut rig = Rig::new();
    // A strong owner keeps C (id 3) and A (id 1), equal strength, waiting; C streams last.
    rig.drive(0, w(9), 9, 340, 0);
    rig.drive(5, w(3), OP_C, 220, 3);
    rig.drive(6, w(1), OP_A, 220, 1);
    rig.drive(7, w(3), OP_C, 220, 3);
    let d = rig.at(8, Event::Released { writer: w(9) });
    assert_eq!(change(&d), Some((Some(9), Some(OP_A), Reason::Released)));
    assert_eq!(applied(&d), Some((OP_A, 1)));
}

#[test]
fn two_writers_of_one_participant_claiming_one_device_id_tie_break_on_writer_id() {
    let mut rig = Rig::new();
    let writer = |entity| WriterId {
        participant: ParticipantId(5),
        entity,
    };
    rig.drive(0, w(9), 9, 340, 0);
    rig.drive(1, writer(7), OP_A, 220, 5);
    rig.drive(2, writer(4), OP_A, 220, 4);
    let d = rig.at(3, Event::WriterGone { writer: w(9) });
    assert_eq!(
        d.owner_change.map(|c| c.to),
        Some(Owner::Controller(ctl(writer(4), OP_A, 220)))
    );
}

// ---- Trust: ids pinned to participants, strengths inside the hierarchy ------------------------

#[test]
fn a_device_id_speaking_from_another_participant_is_ignored_and_reported() {
    let mut rig = Rig::new();
    rig.drive(0, w(1), OP_A, 220, 1);
    // Participant 6 streams as OP_A, stronger: nothing changes, and it is named.
    let d = rig.drive(1, w(6), OP_A, 340, 66);
    assert_eq!(d.ignored, Some(Ignored::Untrusted));
    assert_eq!(
        d.suspect,
        Some(Suspect {
            device: OP_A,
            sender: ParticipantId(6),
            why: Distrust::IdOfAnotherParticipant {
                owner: ParticipantId(1)
            },
        })
    );
    assert_eq!((d.owner_change, d.output), (None, None));
    // Nor can it consent in OP_A's name, or end a grant in the holder's name.
    let d = rig.at(
        2,
        Event::GrantAccepted {
            holder: OP_C,
            granted_by: OP_A,
            stamp: S,
            sender: ParticipantId(6),
        },
    );
    assert_eq!(d.ignored, Some(Ignored::Untrusted));
    assert_eq!(rig.arb.grant_holder(), None);
    // Once OP_A's participant has left (and the grace period passed), the id is free again.
    rig.at(
        3,
        Event::ParticipantGone {
            participant: ParticipantId(1),
        },
    );
    let d = rig.drive(600, w(6), OP_A, 340, 66);
    assert_eq!(d.ignored, None);
    assert_eq!(rig.arb.controller_id(), OP_A);
}

#[test]
fn a_finish_in_the_holders_name_from_another_participant_does_not_end_the_grant() {
    let mut rig = granted_rig();
    let d = rig.at(
        10,
        Event::GrantFinished {
            holder: OP_B,
            stamp: S,
            sender: ParticipantId(1),
        },
    );
    assert_eq!(d.ignored, Some(Ignored::Untrusted));
    assert_eq!(rig.arb.grant_holder(), Some(OP_B));
}

#[test]
fn strengths_the_hierarchy_cannot_give_are_ignored_and_an_access_list_limits_ids() {
    let mut rig = Rig::new();
    for strength in [1, 150, 350, 65534] {
        let d = rig.drive(0, w(1), OP_A, strength, 1);
        assert_eq!(
            d.suspect.map(|s| s.why),
            Some(Distrust::StrengthOutsideHierarchy(Strength(strength)))
        );
        assert_eq!(rig.arb.owner(), Owner::Failsafe);
    }
    let access = Access::listed(
        Hierarchy::STANDARD,
        &[Grant {
            id: OP_A,
            level: Level::Stationary,
            device_class: DeviceClass::Laptop,
        }],
    );
    let mut rig = Rig {
        arb: Arbiter::new(VEHICLE, ArbiterConfig::default()).with_access(access),
    };
    let d = rig.drive(0, w(2), OP_B, 340, 2);
    assert_eq!(d.suspect.map(|s| s.why), Some(Distrust::NotAllowed));
    let d = rig.drive(1, w(1), OP_A, 240, 1);
    assert_eq!(
        d.suspect.map(|s| s.why),
        Some(Distrust::AboveAccess {
            claimed: Strength(240),
            max: Strength(229)
        })
    );
    rig.drive(2, w(1), OP_A, 220, 1);
    assert_eq!(rig.arb.controller_id(), OP_A);
    // A grant to an id outside the list is not taken.
    let d = rig.at(
        3,
        Event::GrantAccepted {
            holder: OP_B,
            granted_by: OP_A,
            stamp: S,
            sender: by(OP_A),
        },
    );
    assert_eq!(d.suspect.map(|s| s.why), Some(Distrust::NotAllowed));
    assert_eq!(rig.arb.grant_holder(), None);
}

/// Under DDS Security, another site's operator (its bridge's proxy certificate, docs/remote.md)
/// drives only up to the level that certificate allows, whatever its writer claims.
#[test]
fn a_proxy_certificate_bounds_the_level_its_operator_may_claim() {
    let mut rig = Rig::new();
    rig.arb
        .certify(std::sync::Arc::new(|device, _| match device {
            OP_A => Certified::Proxy(Level::Remote),
            _ => Certified::Device,
        }));
    let d = rig.drive(0, w(1), OP_A, 340, 1);
    assert_eq!(
        d.suspect.map(|s| s.why),
        Some(Distrust::AboveSite {
            claimed: Strength(340),
            level: Level::Remote
        })
    );
    assert_eq!(rig.arb.owner(), Owner::Failsafe);
    rig.drive(1, w(1), OP_A, 140, 1);
    assert_eq!(rig.arb.controller_id(), OP_A, "at its level it drives");
    rig.drive(2, w(2), OP_B, 340, 2);
    assert_eq!(rig.arb.controller_id(), OP_B, "a local phone preempts it");
}

// ---- Liveness: release, departure, timeout -----------------------------------------------

#[test]
fn owner_releasing_hands_over_at_once_without_waiting_for_a_timeout() {
    let mut rig = Rig::new();
    rig.drive(0, w(1), OP_A, 220, 1);
    rig.drive(1, w(2), OP_B, 340, 2);
    let d = rig.at(2, Event::Released { writer: w(2) });
    assert_eq!(change(&d), Some((Some(OP_B), Some(OP_A), Reason::Released)));
    assert_eq!(applied(&d), Some((OP_A, 1)), "A's latest fresh sample");
}

#[test]
fn owner_writer_or_participant_leaving_hands_over() {
    let mut rig = Rig::new();
    rig.drive(0, w(1), OP_A, 220, 1);
    rig.drive(1, w(2), OP_B, 340, 2);
    let d = rig.at(2, Event::WriterGone { writer: w(2) });
    assert_eq!(change(&d), Some((Some(OP_B), Some(OP_A), Reason::Left)));

    let d = rig.at(
        3,
        Event::ParticipantGone {
            participant: ParticipantId(1),
        },
    );
    assert_eq!(change(&d), Some((Some(OP_A), None, Reason::Left)));
    assert!(d.entered_failsafe());
    assert!(matches!(
        d.output,
        Some(Output::SafeState {
            owner: Owner::Failsafe,
            ..
        })
    ));
}

#[test]
fn silent_owner_times_out_to_the_next_strongest_live_controller() {
    let mut rig = Rig::new();
    rig.drive(0, w(2), OP_B, 340, 2);
    for t in (0..=80).step_by(20) {
        rig.drive(t, w(1), OP_A, 220, 1);
    }
    // B's last sample arrived at 0: it is live until (not at) 100 ms; A until 180 ms.
    assert_eq!(rig.tick(99).owner_change, None);
    let d = rig.tick(100);
    assert_eq!(change(&d), Some((Some(OP_B), Some(OP_A), Reason::TimedOut)));
    assert_eq!(applied(&d), Some((OP_A, 1)));
}

#[test]
fn everyone_silent_enters_failsafe_exactly_at_the_timeout() {
    let mut rig = Rig::new();
    rig.drive(0, w(1), OP_A, 220, 1);
    rig.drive(30, w(1), OP_A, 220, 1);
    assert_eq!(rig.arb.next_deadline(), Some(ms(130)));
    assert_eq!(rig.tick(129).owner_change, None);
    let d = rig.tick(130);
    assert!(d.entered_failsafe());
    assert_eq!(change(&d), Some((Some(OP_A), None, Reason::TimedOut)));
    assert!(matches!(
        d.output,
        Some(Output::SafeState {
            owner: Owner::Failsafe,
            ..
        })
    ));
    assert_eq!(rig.arb.controller_id(), VEHICLE);
    assert_eq!(rig.arb.next_deadline(), None);
}

#[test]
fn a_lapsed_owner_is_replaced_on_any_event_not_only_on_tick() {
    let mut rig = Rig::new();
    rig.drive(0, w(2), OP_B, 340, 2);
    // No tick at 100 ms; A's sample at 150 ms finds B expired.
    let d = rig.drive(150, w(1), OP_A, 220, 1);
    assert_eq!(change(&d), Some((Some(OP_B), Some(OP_A), Reason::TimedOut)));
}

#[test]
fn a_released_controller_that_streams_again_is_live_again() {
    let mut rig = Rig::new();
    rig.drive(0, w(1), OP_A, 220, 1);
    rig.at(1, Event::Released { writer: w(1) });
    assert_eq!(rig.arb.owner(), Owner::Failsafe);
    let d = rig.drive(2, w(1), OP_A, 220, 7);
    assert_eq!(change(&d), Some((None, Some(OP_A), Reason::Joined)));
    assert_eq!(applied(&d), Some((OP_A, 7)));
}

#[test]
fn command_timeout_is_configurable() {
    let config = ArbiterConfig {
        command_timeout: CommandTimeout::from_millis("t", 250).expect("valid"),
        ..ArbiterConfig::default()
    };
    let mut rig = Rig::with(config);
    rig.drive(0, w(1), OP_A, 220, 1);
    assert_eq!(rig.tick(249).owner_change, None);
    assert!(rig.tick(250).entered_failsafe());
}

// ---- Batches: samples taken together are one instant --------------------------------------

fn sample_at(t: u64, writer: WriterId, device: i64, strength: u16, throttle: i16) -> Event {
    Event::Sample {
        writer,
        strength: Strength(strength),
        command: command(device, CommandType::Movement, throttle),
        arrival: ms(t),
    }
}

/// The owner's stream is a timeout old when one read takes a weaker operator's sample and then
/// the owner's: stepped one by one, the weaker drives for one output (the fleet bench's start
/// and handover incidents); as one batch, the owner keeps the vehicle.
#[test]
fn a_batch_taken_together_keeps_a_late_owner_whose_sample_is_in_it() {
    let late = |rig: &mut Rig| {
        rig.drive(0, w(2), OP_B, 340, 2);
        rig.drive(0, w(1), OP_A, 220, 1);
    };
    let batch = [
        sample_at(150, w(1), OP_A, 220, 11),
        sample_at(150, w(2), OP_B, 340, 12),
    ];

    let mut one_by_one = Rig::new();
    late(&mut one_by_one);
    let d = one_by_one.at(150, batch[0]);
    assert_eq!(change(&d), Some((Some(OP_B), Some(OP_A), Reason::TimedOut)));
    assert_eq!(applied(&d), Some((OP_A, 11)), "the weaker drove");

    let mut rig = Rig::new();
    late(&mut rig);
    let ds = rig.arb.step_batch(ms(150), &batch);
    assert_eq!(ds.len(), 2);
    assert!(ds.iter().all(|d| d.owner_change.is_none()), "{ds:?}");
    assert_eq!(applied(&ds[0]), None);
    assert_eq!(applied(&ds[1]), Some((OP_B, 12)), "the owner's new values");
    assert_eq!(rig.arb.controller_id(), OP_B);
}

/// A batch decides once, at its end, as the last of its events would; each event's own
/// verdict stays with its decision.
#[test]
fn a_batch_hands_over_once_and_reports_each_sample() {
    let mut rig = Rig::new();
    rig.drive(0, w(1), OP_A, 220, 1);
    let batch = [
        sample_at(150, w(3), OP_C, 110, 3),
        sample_at(150, w(2), OP_A, 340, 9), // OP_A's id from participant 2: not believed
        sample_at(150, w(1), OP_A, 220, 4),
        Event::Released { writer: w(1) },
    ];
    let ds = rig.arb.step_batch(ms(150), &batch);
    assert_eq!(ds.len(), 4);
    assert_eq!(ds[1].ignored, Some(Ignored::Untrusted));
    assert!(ds[1].suspect.is_some());
    assert!(
        ds[..3]
            .iter()
            .all(|d| d.owner_change.is_none() && d.output.is_none())
    );
    assert_eq!(
        change(&ds[3]),
        Some((Some(OP_A), Some(OP_C), Reason::Released))
    );
    assert_eq!(applied(&ds[3]), Some((OP_C, 3)));
    assert!(
        rig.arb.step_batch(ms(151), &[]).is_empty(),
        "nothing to decide"
    );
    assert_eq!(rig.arb.controller_id(), OP_C);
}

// ---- Freshness: stale and reordered samples are never applied -----------------------------

#[test]
fn a_stale_sample_is_never_applied_nor_counts_as_live() {
    let mut rig = Rig::new();
    let cmd = command(OP_A, CommandType::Movement, 9);
    let d = rig.arb.step(
        ms(500),
        Event::Sample {
            writer: w(1),
            strength: Strength(220),
            command: cmd,
            arrival: ms(400),
        },
    );
    assert_eq!(d.ignored, Some(Ignored::Stale));
    assert_eq!(d.output, None);
    assert_eq!(rig.arb.owner(), Owner::Failsafe);
}

#[test]
fn a_sample_older_than_one_already_processed_is_out_of_order() {
    let mut rig = Rig::new();
    rig.drive(50, w(1), OP_A, 220, 1);
    let d = rig.arb.step(
        ms(60),
        Event::Sample {
            writer: w(1),
            strength: Strength(220),
            command: command(OP_A, CommandType::Movement, 2),
            arrival: ms(40),
        },
    );
    assert_eq!(d.ignored, Some(Ignored::OutOfOrder));
    assert_eq!(d.output, None);
}

#[test]
fn a_sample_sent_before_a_release_cannot_revive_the_writer() {
    let mut rig = Rig::new();
    rig.drive(10, w(1), OP_A, 220, 1);
    rig.at(20, Event::Released { writer: w(1) });
    let d = rig.arb.step(
        ms(21),
        Event::Sample {
            writer: w(1),
            strength: Strength(220),
            command: command(OP_A, CommandType::Movement, 2),
            arrival: ms(15),
        },
    );
    assert_eq!(d.ignored, Some(Ignored::OutOfOrder));
    assert_eq!(rig.arb.owner(), Owner::Failsafe);
}

#[test]
fn a_new_owners_latest_sample_is_applied_and_never_an_older_one() {
    let mut rig = Rig::new();
    rig.drive(0, w(2), OP_B, 340, 0);
    rig.drive(10, w(1), OP_A, 220, 1);
    rig.drive(20, w(1), OP_A, 220, 2);
    rig.drive(30, w(1), OP_A, 220, 3);
    let d = rig.at(31, Event::Released { writer: w(2) });
    assert_eq!(applied(&d), Some((OP_A, 3)));
}

// ---- Sample kinds -------------------------------------------------------------------------

#[test]
fn probes_keep_a_controller_live_but_apply_nothing() {
    let mut rig = Rig::new();
    let d = rig.send(0, w(1), Strength(220), command(OP_A, CommandType::Probe, 0));
    assert_eq!(change(&d), Some((None, Some(OP_A), Reason::Joined)));
    // Owner with no values yet: outputs stay safe.
    assert!(matches!(
        d.output,
        Some(Output::SafeState {
            owner: Owner::Controller(_),
            ..
        })
    ));
    for t in (50..=400).step_by(50) {
        let d = rig.send(t, w(1), Strength(220), command(OP_A, CommandType::Probe, 0));
        assert_eq!(d, Decision::default(), "t={t}");
    }
    assert_eq!(rig.arb.controller_id(), OP_A);
}

#[test]
fn a_mode_command_changes_mode_and_keeps_the_last_movement() {
    let mut rig = Rig::new();
    rig.drive(0, w(1), OP_A, 220, 42);
    let mut cmd = command(OP_A, CommandType::Mode, 0);
    cmd.mode = Mode::Auto;
    let d = rig.send(10, w(1), Strength(220), cmd);
    let Some(Output::Apply { setpoint, .. }) = d.output else {
        panic!("expected apply, got {d:?}");
    };
    assert_eq!(
        setpoint,
        Setpoint {
            movement: movement(42),
            mode: Mode::Auto
        }
    );
}

// ---- Malformed or misaddressed input changes nothing ---------------------------------------

#[test]
fn samples_for_other_vehicles_from_this_vehicle_or_at_failsafe_strength_change_nothing() {
    let mut rig = Rig::new();
    let mut other = command(OP_A, CommandType::Movement, 1);
    other.dest_id = VEHICLE + 1;
    assert_eq!(
        rig.send(0, w(1), Strength(220), other).ignored,
        Some(Ignored::NotForThisVehicle)
    );
    let spoof = command(VEHICLE, CommandType::Movement, 1);
    assert_eq!(
        rig.send(0, w(1), Strength(220), spoof).ignored,
        Some(Ignored::FromThisVehicle)
    );
    assert_eq!(
        rig.drive(0, w(1), OP_A, 0, 1).ignored,
        Some(Ignored::FailsafeStrength)
    );
    assert_eq!(rig.arb.owner(), Owner::Failsafe);
    assert_eq!(rig.arb.sources(ms(0)).count(), 0);
}

#[test]
fn a_writer_switching_device_id_is_ignored() {
    let mut rig = Rig::new();
    rig.drive(0, w(1), OP_A, 220, 1);
    let d = rig.drive(10, w(1), OP_B, 220, 2);
    assert_eq!(d.ignored, Some(Ignored::SourceMismatch));
    assert_eq!(d.output, None);
}

#[test]
fn unknown_writers_and_participants_leaving_change_nothing() {
    let mut rig = Rig::new();
    rig.drive(0, w(1), OP_A, 220, 1);
    for event in [
        Event::Released { writer: w(7) },
        Event::WriterGone { writer: w(7) },
        Event::ParticipantGone {
            participant: ParticipantId(7),
        },
    ] {
        let d = rig.at(1, event);
        assert_eq!(d.ignored, Some(Ignored::UnknownSource));
        assert_eq!(d.owner_change, None);
    }
}

#[test]
fn time_going_backwards_never_revives_a_stream() {
    let mut rig = Rig::new();
    rig.drive(0, w(1), OP_A, 220, 1);
    assert!(rig.tick(200).entered_failsafe());
    // A caller passing an earlier `now` does not bring A back.
    let d = rig.tick(50);
    assert_eq!(d.owner_change, None);
    assert_eq!(rig.arb.owner(), Owner::Failsafe);
}

#[test]
fn the_source_table_is_bounded_and_a_flood_cannot_displace_the_owner() {
    let mut rig = Rig::with(ArbiterConfig {
        max_sources: 4,
        ..ArbiterConfig::default()
    });
    rig.drive(0, w(1), OP_A, 220, 1);
    for n in 2..=4 {
        rig.drive(1, w(n), i64::from(n), 110, 0);
    }
    let d = rig.drive(2, w(5), 5, 340, 0);
    assert_eq!(d.ignored, Some(Ignored::TooManySources));
    assert_eq!(rig.arb.controller_id(), OP_A);
    // Once the flood is silent its entries make room.
    rig.drive(150, w(1), OP_A, 220, 1);
    let d = rig.drive(151, w(5), 5, 340, 0);
    assert_eq!(change(&d), Some((Some(OP_A), Some(5), Reason::Preempted)));
}

/// Writer `entity` of participant `participant`.
fn pw_of(participant: u32, entity: u32) -> rove_core::arbiter::WriterId {
    rove_core::arbiter::WriterId {
        participant: ParticipantId(u128::from(participant)),
        entity,
    }
}

#[test]
fn one_participant_cannot_fill_the_source_table() {
    let mut rig = Rig::new();
    rig.drive(0, w(1), OP_A, 220, 1);
    // Participant 9 streams as twenty devices: it gets its share of eight.
    let mut refused = 0;
    for n in 0..20u32 {
        let d = rig.drive(1, pw_of(9, n + 1), 100 + i64::from(n), 110, 0);
        if d.ignored == Some(Ignored::ParticipantQuota) {
            refused += 1;
        }
    }
    assert_eq!(refused, 12);
    assert_eq!(rig.arb.sources(ms(1)).count(), 9);
    // Everyone else still gets in: a stronger operator takes over.
    let d = rig.drive(2, w(2), OP_B, 340, 2);
    assert_eq!(
        change(&d),
        Some((Some(OP_A), Some(OP_B), Reason::Preempted))
    );
    // Once its streams are silent, the participant's new ones replace them.
    rig.drive(150, w(2), OP_B, 340, 2);
    let d = rig.drive(151, pw_of(9, 50), 150, 110, 0);
    assert_eq!(d.ignored, None);
}

#[test]
fn a_grant_holder_gets_room_in_a_table_full_of_live_strangers() {
    let mut rig = Rig::with(ArbiterConfig {
        max_sources: 4,
        ..ArbiterConfig::default()
    });
    rig.drive(0, w(1), OP_A, 220, 1);
    for n in 20..23u32 {
        rig.drive(1, w(n), i64::from(n), 110, 0);
    }
    let d = rig.drive(2, w(2), OP_B, 120, 2);
    assert_eq!(d.ignored, Some(Ignored::TooManySources));
    rig.at(
        3,
        Event::GrantAccepted {
            holder: OP_B,
            granted_by: OP_A,
            stamp: S,
            sender: by(OP_A),
        },
    );
    // The strangers are still live; the granted operator's priority stream gets in anyway.
    for n in 20..23u32 {
        rig.drive(4, w(n), i64::from(n), 110, 0);
    }
    let d = rig.drive(5, pw(2), OP_B, 65535, 22);
    assert_eq!(change(&d), Some((Some(OP_A), Some(OP_B), Reason::Granted)));
    assert_eq!(applied(&d), Some((OP_B, 22)));
    assert_eq!(rig.arb.sources(ms(5)).count(), 4);
}

#[test]
fn a_strength_update_is_taken_from_the_next_sample() {
    let mut rig = Rig::new();
    rig.drive(0, w(1), OP_A, 220, 1);
    rig.drive(1, w(2), OP_B, 210, 2);
    let d = rig.drive(2, w(2), OP_B, 230, 3);
    assert_eq!(
        change(&d),
        Some((Some(OP_A), Some(OP_B), Reason::Preempted))
    );
}

// ---- Rule 1: the priority grant -------------------------------------------------------------

/// A drives (stationary 220), B (remote 120) holds a priority writer.
fn granted_rig() -> Rig {
    let mut rig = Rig::new();
    rig.drive(0, w(1), OP_A, 220, 1);
    rig.drive(0, w(2), OP_B, 120, 2);
    let d = rig.at(
        5,
        Event::GrantAccepted {
            holder: OP_B,
            granted_by: OP_A,
            stamp: S,
            sender: by(OP_A),
        },
    );
    assert_eq!(d.ignored, None);
    assert_eq!(
        d.owner_change, None,
        "holder not streaming with priority yet"
    );
    let d = rig.drive(6, pw(2), OP_B, 65535, 22);
    assert_eq!(change(&d), Some((Some(OP_A), Some(OP_B), Reason::Granted)));
    assert_eq!(applied(&d), Some((OP_B, 22)));
    rig
}

#[test]
fn the_grant_holder_drives_while_its_priority_stream_is_live() {
    let mut rig = granted_rig();
    assert_eq!(rig.arb.grant_holder(), Some(OP_B));
    // Even a mobile phone (340) joining does not take over from the grant holder.
    let d = rig.drive(10, w(3), OP_C, 340, 3);
    assert_eq!(d.owner_change, None);
    assert_eq!(rig.arb.controller_id(), OP_B);
}

#[test]
fn a_priority_stream_without_a_grant_never_drives() {
    let mut rig = Rig::new();
    rig.drive(0, w(1), OP_A, 220, 1);
    let d = rig.drive(1, pw(2), OP_B, 65535, 2);
    assert_eq!(d.ignored, Some(Ignored::PriorityWithoutGrant));
    assert_eq!(d.owner_change, None);
    assert_eq!(d.output, None);
    // Not even when nobody else is live.
    rig.at(2, Event::Released { writer: w(1) });
    assert_eq!(rig.arb.owner(), Owner::Failsafe);
}

#[test]
fn a_grant_seen_after_the_holder_started_streaming_takes_effect_at_once() {
    let mut rig = Rig::new();
    rig.drive(0, w(1), OP_A, 220, 1);
    rig.drive(1, pw(2), OP_B, 65535, 22); // B heard the ACCEPT before the vehicle did
    let d = rig.at(
        2,
        Event::GrantAccepted {
            holder: OP_B,
            granted_by: OP_A,
            stamp: S,
            sender: by(OP_A),
        },
    );
    assert_eq!(change(&d), Some((Some(OP_A), Some(OP_B), Reason::Granted)));
    assert_eq!(applied(&d), Some((OP_B, 22)));
}

#[test]
fn finish_returns_control_to_the_strongest_live_controller() {
    let mut rig = granted_rig();
    rig.drive(10, w(1), OP_A, 220, 1);
    let d = rig.at(
        11,
        Event::GrantFinished {
            holder: OP_B,
            stamp: S,
            sender: by(OP_B),
        },
    );
    assert_eq!(
        change(&d),
        Some((Some(OP_B), Some(OP_A), Reason::GrantReturned))
    );
    assert_eq!(applied(&d), Some((OP_A, 1)));
    assert_eq!(rig.arb.grant_holder(), None);
}

/// The yielded owner stands by with PROBEs: at FINISH the vehicle returns to it, not to a
/// weaker bystander that happens to be streaming, and holds the safe state until its first
/// movement sample (PROBE keeps ownership, not motion).
#[test]
fn finish_returns_control_to_a_standing_by_owner_before_a_bystander() {
    let mut rig = granted_rig();
    for t in (20..200).step_by(20) {
        rig.send(t, w(1), Strength(220), command(OP_A, CommandType::Probe, 0));
        rig.drive(t, w(3), OP_C, 110, 3);
        let d = rig.drive(t, pw(2), OP_B, 65535, 22);
        assert_eq!(applied(&d), Some((OP_B, 22)));
    }
    let d = rig.at(
        201,
        Event::GrantFinished {
            holder: OP_B,
            stamp: S,
            sender: by(OP_B),
        },
    );
    assert_eq!(
        change(&d),
        Some((Some(OP_B), Some(OP_A), Reason::GrantReturned))
    );
    assert!(matches!(d.output, Some(Output::SafeState { .. })));
    let d = rig.drive(202, w(1), OP_A, 220, 7);
    assert_eq!(applied(&d), Some((OP_A, 7)));
    assert_eq!(rig.arb.controller_id(), OP_A);
}

#[test]
fn a_late_sample_from_a_previous_holder_cannot_win_control_back() {
    let mut rig = granted_rig();
    // The grant moves on from B to C (B, the owner, consents).
    rig.drive(10, pw(3), OP_C, 65535, 33);
    let d = rig.at(
        11,
        Event::GrantAccepted {
            holder: OP_C,
            granted_by: OP_B,
            stamp: S,
            sender: by(OP_B),
        },
    );
    assert_eq!(change(&d), Some((Some(OP_B), Some(OP_C), Reason::Granted)));
    // B's priority writer was still in flight: its samples do nothing.
    for t in 12..40 {
        let d = rig.drive(t, pw(2), OP_B, 65535, 22);
        assert_eq!(d.owner_change, None, "ping-pong at t={t}");
        assert_eq!(d.ignored, Some(Ignored::PriorityWithoutGrant));
        rig.drive(t, pw(3), OP_C, 65535, 33);
    }
    assert_eq!(rig.arb.controller_id(), OP_C);
}

/// rustdds replays a RequestControl writer's history to a newly matched reader, so a requester
/// may hand back an old ACCEPT with a FINISH of that old handover: it must not end the current
/// grant (found by `rove bench handover --scenario active`).
#[test]
fn a_finish_of_an_earlier_handover_does_not_end_the_current_grant() {
    let mut rig = granted_rig();
    let d = rig.at(
        10,
        Event::GrantFinished {
            holder: OP_B,
            stamp: TimeT(S.0 - 1),
            sender: by(OP_B),
        },
    );
    assert_eq!(d.ignored, Some(Ignored::NotGrantHolder));
    assert_eq!(rig.arb.grant_holder(), Some(OP_B));
    // A later stamp (a foreign peer stamping at send time) does end it.
    let d = rig.at(
        11,
        Event::GrantFinished {
            holder: OP_B,
            stamp: TimeT(S.0 + 1),
            sender: by(OP_B),
        },
    );
    assert_eq!(d.ignored, None);
    assert_eq!(rig.arb.grant_holder(), None);
}

#[test]
fn a_finish_from_a_non_holder_is_ignored() {
    let mut rig = granted_rig();
    let d = rig.at(
        10,
        Event::GrantFinished {
            holder: OP_A,
            stamp: S,
            sender: by(OP_A),
        },
    );
    assert_eq!(d.ignored, Some(Ignored::NotGrantHolder));
    assert_eq!(rig.arb.grant_holder(), Some(OP_B));
}

#[test]
fn a_grant_holder_that_stops_its_priority_stream_gives_the_grant_up() {
    let mut rig = granted_rig();
    rig.drive(10, w(1), OP_A, 220, 1);
    let d = rig.at(11, Event::Released { writer: pw(2) });
    assert_eq!(change(&d), Some((Some(OP_B), Some(OP_A), Reason::Released)));
    assert_eq!(rig.arb.grant_holder(), None);

    let mut rig = granted_rig();
    rig.drive(10, w(1), OP_A, 220, 1);
    rig.at(
        11,
        Event::ParticipantGone {
            participant: ParticipantId(2),
        },
    );
    assert_eq!(rig.arb.grant_holder(), None);
    assert_eq!(rig.arb.controller_id(), OP_A);
}

#[test]
fn a_silent_grant_holder_falls_back_to_rule_two_and_wins_again_when_back() {
    let mut rig = granted_rig();
    for t in (20..=200).step_by(20) {
        rig.drive(t, w(1), OP_A, 220, 1);
    }
    assert_eq!(rig.arb.controller_id(), OP_A, "B silent since 6 ms");
    let d = rig.drive(201, pw(2), OP_B, 65535, 22);
    assert_eq!(change(&d), Some((Some(OP_A), Some(OP_B), Reason::Granted)));
}

#[test]
fn consent_from_a_device_that_does_not_own_the_vehicle_is_ignored() {
    let mut rig = Rig::new();
    rig.drive(0, w(1), OP_A, 220, 1);
    for (holder, granted_by, why) in [
        (OP_B, OP_C, Ignored::ConsentNotFromOwner),
        (OP_A, OP_A, Ignored::InvalidGrant),
        (VEHICLE, OP_A, Ignored::InvalidGrant),
    ] {
        let d = rig.at(
            1,
            Event::GrantAccepted {
                holder,
                granted_by,
                stamp: S,
                sender: by(granted_by),
            },
        );
        assert_eq!(d.ignored, Some(why));
    }
    assert_eq!(rig.arb.grant_holder(), None);
}

#[test]
fn consent_of_an_owner_that_just_released_counts_for_one_timeout() {
    // The replier's release may overtake its ACCEPT: they travel on different topics.
    let mut rig = Rig::new();
    rig.drive(0, w(1), OP_A, 220, 1);
    rig.drive(0, pw(2), OP_B, 65535, 22);
    rig.at(10, Event::Released { writer: w(1) });
    let d = rig.at(
        11,
        Event::GrantAccepted {
            holder: OP_B,
            granted_by: OP_A,
            stamp: S,
            sender: by(OP_A),
        },
    );
    assert_eq!(change(&d), Some((None, Some(OP_B), Reason::Granted)));

    // After one timeout the stepped-down owner's consent is stale.
    let mut rig = Rig::new();
    rig.drive(0, w(1), OP_A, 220, 1);
    rig.at(10, Event::Released { writer: w(1) });
    let d = rig.at(
        110,
        Event::GrantAccepted {
            holder: OP_B,
            granted_by: OP_A,
            stamp: S,
            sender: by(OP_A),
        },
    );
    assert_eq!(d.ignored, Some(Ignored::ConsentNotFromOwner));
}

#[test]
fn consent_of_a_preempted_owner_does_not_count() {
    let mut rig = Rig::new();
    rig.drive(0, w(1), OP_A, 220, 1);
    rig.drive(1, w(3), OP_C, 340, 3); // C preempts A
    let d = rig.at(
        2,
        Event::GrantAccepted {
            holder: OP_B,
            granted_by: OP_A,
            stamp: S,
            sender: by(OP_A),
        },
    );
    assert_eq!(d.ignored, Some(Ignored::ConsentNotFromOwner));
}

// ---- Status ----------------------------------------------------------------------------------

#[test]
fn source_status_reports_liveness_eligibility_and_age() {
    let mut rig = granted_rig();
    rig.drive(50, pw(3), OP_C, 65535, 0);
    let mut rows: Vec<_> = rig.arb.sources(ms(60)).collect();
    rows.sort_by_key(|s| s.controller.writer);
    let summary: Vec<_> = rows
        .iter()
        .map(|s| {
            (
                s.controller.device,
                s.controller.strength.0,
                s.live,
                s.eligible,
                s.age,
            )
        })
        .collect();
    use std::time::Duration as D;
    assert_eq!(
        summary,
        [
            (OP_A, 220, true, true, Some(D::from_millis(60))),
            (OP_B, 120, true, true, Some(D::from_millis(60))),
            (OP_B, 65535, true, true, Some(D::from_millis(54))),
            (OP_C, 65535, true, false, Some(D::from_millis(10))),
        ]
    );
}

// ---- twist_mux black-box cases (test/system_blackbox.py), ported ----------------------------

/// `test_empty`: no input → the output is the safe state, and stays so on ticks.
#[test]
fn twist_mux_empty() {
    let mut rig = Rig::new();
    for t in (0..1000).step_by(100) {
        assert_eq!(rig.tick(t), Decision::default());
    }
    assert_eq!(rig.arb.owner(), Owner::Failsafe);
}

/// `test_basic`: one source's command reaches the output.
#[test]
fn twist_mux_basic() {
    let mut rig = Rig::new();
    let d = rig.drive(0, w(1), OP_A, 110, 1234);
    assert_eq!(applied(&d), Some((OP_A, 1234)));
}

/// `test_priorities`: the higher-priority source wins while both publish.
#[test]
fn twist_mux_priorities() {
    let mut rig = Rig::new();
    for t in (0..500).step_by(20) {
        rig.drive(t, w(1), OP_A, 110, 1);
        let d = rig.drive(t, w(2), OP_B, 340, 2);
        assert_eq!(rig.arb.controller_id(), OP_B);
        assert_eq!(applied(&d), Some((OP_B, 2)));
    }
}

/// `test_fallback`: the high-priority source stops; after its timeout the lower one drives —
/// and, unlike twist_mux, the handover is decided on the tick, not on the next message.
#[test]
fn twist_mux_fallback_after_timeout() {
    let mut rig = Rig::new();
    rig.drive(0, w(2), OP_B, 340, 2);
    rig.drive(90, w(1), OP_A, 110, 1);
    let d = rig.tick(100);
    assert_eq!(change(&d), Some((Some(OP_B), Some(OP_A), Reason::TimedOut)));
    assert_eq!(applied(&d), Some((OP_A, 1)));
}

/// twist_mux locks: a lock masks lower priorities while its publisher is live, and engages
/// (blocks output) when the publisher goes silent. Our analogue is the priority grant: it masks
/// every other controller while its stream is live; when the holder goes silent, nothing it sent
/// keeps driving — the next live controller or the failsafe takes over after the timeout.
#[test]
fn twist_mux_locks_as_grants() {
    let mut rig = granted_rig();
    let d = rig.drive(20, w(3), OP_C, 340, 3);
    assert_eq!(d.output, None, "masked by the grant");
    let d = rig.tick(106);
    assert_eq!(change(&d), Some((Some(OP_B), Some(OP_C), Reason::TimedOut)));
    assert!(rig.tick(120).entered_failsafe());
    assert_eq!(
        rig.arb.sources(ms(120)).filter(|s| s.live).count(),
        0,
        "nothing live"
    );
}

// ---- DeviceInfo.controller_id ------------------------------------------------------------------

/// Every change of owner is visible in `controller_id` in the same step that decided it, so the
/// vehicle publishes it within one event-loop turn; the failsafe shows as the vehicle's own id.
#[test]
fn controller_id_follows_every_owner_change_in_the_same_step() {
    let mut rig = Rig::new();
    let timeline: [(u64, Event); 4] = [
        (0, Event::Tick),
        (1, Event::Released { writer: w(2) }),
        (
            2,
            Event::ParticipantGone {
                participant: ParticipantId(1),
            },
        ),
        (3, Event::Tick),
    ];
    rig.drive(0, w(1), OP_A, 220, 1);
    assert_eq!(rig.arb.controller_id(), OP_A);
    rig.drive(0, w(2), OP_B, 340, 2);
    assert_eq!(rig.arb.controller_id(), OP_B);
    for (t, event) in timeline {
        let d = rig.at(t, event);
        let expected = rig.arb.owner().device().unwrap_or(VEHICLE);
        assert_eq!(rig.arb.controller_id(), expected);
        if let Some(c) = d.owner_change {
            assert_eq!(c.to.device().unwrap_or(VEHICLE), rig.arb.controller_id());
        }
    }
    assert_eq!(rig.arb.controller_id(), VEHICLE);
}
