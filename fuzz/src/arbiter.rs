//! Event sequences against the vehicle's [`Arbiter`], structure-aware: every few bytes are one
//! time step and one event (a sample, a release, a departure, a grant, a FINISH, a claim of an
//! id, a tick) from one of a small cast of writers and participants, so that the fuzzer meets
//! the same streams again and builds up ownership, grants and pins.
//!
//! The first bytes choose the arbiter's settings: a small source table and per-participant
//! quota (so eviction and quotas are reached), and optionally an `[access]` list.
//!
//! Checked after every step, besides "no panic":
//! - the owner is the failsafe or a source the arbiter lists as live;
//! - `controller_id` names the owner's device, or the vehicle itself for the failsafe;
//! - an output applies values only from the owner, and an owner change ends at the owner;
//! - the source table never holds more than `max_sources`.

use crate::bytes::Bytes;
use rove_core::MonoTime;
use rove_core::arbiter::{
    Arbiter, ArbiterConfig, Decision, Event, Output, Owner, ParticipantId, WriterId,
};
use rove_core::hierarchy::{DeviceClass, Hierarchy, Level, Strength};
use rove_core::msg::{
    CommandType, ControlCommand, DeviceId, Mode, MovementCommand, RequestControl, TimeT,
};
use rove_core::trust::{Access, Grant};
use std::time::Duration;

/// The vehicle's id.
pub(crate) const VEHICLE: DeviceId = 1000;

/// Device ids in play: four operators, the vehicle itself, and a stranger.
const DEVICES: [DeviceId; 6] = [1, 2, 3, 4, VEHICLE, -7];

/// Strengths in play: the failsafe's, the hierarchy's, the top operator strength, the
/// priority writer's, and one no hierarchy gives.
const STRENGTHS: [u16; 8] = [0, 110, 130, 220, 340, 349, 65534, 65535];

/// Feeds `data` to an arbiter as a sequence of events, checking its invariants at each step.
pub fn arbiter(data: &[u8]) {
    let mut input = Bytes::new(data);
    let config = ArbiterConfig {
        max_sources: 2 + input.below(15),
        per_participant: 1 + input.below(8),
        ..ArbiterConfig::default()
    };
    let mut arb = Arbiter::new(VEHICLE, config);
    if input.bool() {
        arb = arb.with_access(access());
    }
    arb.pin_own(ParticipantId(0xffff));
    let mut now = MonoTime::ZERO;
    while !input.is_empty() {
        now = advance(&mut input, now);
        let event = event(&mut input, now, &arb);
        let decision = arb.step(now, event);
        check(&arb, now, &decision, config.max_sources);
    }
}

/// The access list operators 1 to 3 are granted by (4 and the stranger are not listed).
pub(crate) fn access() -> Access {
    let grant = Grant::new;
    Access::listed(
        Hierarchy::STANDARD,
        &[
            grant(1, Level::Remote, DeviceClass::Tablet),
            grant(2, Level::Stationary, DeviceClass::Laptop),
            grant(3, Level::Mobile, DeviceClass::Phone),
        ],
    )
}

/// The next instant: mostly small steps around the 100 ms timeout, sometimes a long silence,
/// sometimes none.
pub(crate) fn advance(input: &mut Bytes<'_>, now: MonoTime) -> MonoTime {
    let step = match input.u8() % 8 {
        0 => Duration::ZERO,
        1 => Duration::from_millis(u64::from(input.u32())),
        2 => Duration::from_nanos(input.u64()),
        _ => Duration::from_millis(u64::from(input.u8())),
    };
    now + step
}

fn participant(input: &mut Bytes<'_>) -> ParticipantId {
    ParticipantId(u128::from(input.u8() % 6))
}

fn writer(input: &mut Bytes<'_>) -> WriterId {
    let b = input.u8();
    WriterId {
        participant: ParticipantId(u128::from(b % 6)),
        entity: u32::from(b / 6 % 3),
    }
}

fn device(input: &mut Bytes<'_>) -> DeviceId {
    match input.u8() {
        0xff => i64::from_le_bytes(input.u64().to_le_bytes()),
        b => DEVICES[usize::from(b) % DEVICES.len()],
    }
}

fn stamp(input: &mut Bytes<'_>) -> TimeT {
    match input.u8() % 4 {
        0 => TimeT(input.u64()),
        n => TimeT(u64::from(n)),
    }
}

pub(crate) fn mode(input: &mut Bytes<'_>) -> Mode {
    input.pick(&[Mode::Manual, Mode::Assisted, Mode::Auto])
}

pub(crate) fn movement(input: &mut Bytes<'_>) -> MovementCommand {
    MovementCommand {
        throttle: input.i16(),
        roll: input.i16(),
        pitch: input.i16(),
        yaw: input.i16(),
    }
}

/// A RequestControl with fields from the cast (any stage, any stamp).
pub(crate) fn request_control(input: &mut Bytes<'_>) -> RequestControl {
    RequestControl {
        src_id: device(input),
        dest_id: if input.u8() < 224 {
            VEHICLE
        } else {
            device(input)
        },
        current_controller_id: device(input),
        src_priority: input.pick(&[0, 130, 220, 340, 400, i32::MAX, -1]),
        ack: input.pick(&[
            rove_core::msg::Ack::Request,
            rove_core::msg::Ack::Accept,
            rove_core::msg::Ack::Refuse,
            rove_core::msg::Ack::Finish,
        ]),
        timestamp: stamp(input),
    }
}

fn event(input: &mut Bytes<'_>, now: MonoTime, arb: &Arbiter) -> Event {
    match input.u8() % 10 {
        0..=3 => {
            let command = ControlCommand {
                src_id: device(input),
                dest_id: if input.u8() < 240 {
                    VEHICLE
                } else {
                    device(input)
                },
                command_type: input.pick(&[
                    CommandType::Probe,
                    CommandType::Movement,
                    CommandType::Movement,
                    CommandType::Mode,
                ]),
                movement_command: movement(input),
                mode: mode(input),
                timestamp: stamp(input),
            };
            let lag = match input.u8() % 8 {
                0 => Duration::from_millis(u64::from(input.u16())),
                _ => Duration::ZERO,
            };
            let arrival = MonoTime::from_nanos(
                now.as_nanos()
                    .saturating_sub(u64::try_from(lag.as_nanos()).unwrap_or(u64::MAX)),
            );
            Event::Sample {
                writer: writer(input),
                strength: Strength(input.pick(&STRENGTHS)),
                command,
                arrival,
            }
        }
        4 => Event::Released {
            writer: writer(input),
        },
        5 => Event::WriterGone {
            writer: writer(input),
        },
        6 => Event::ParticipantGone {
            participant: participant(input),
        },
        7 => {
            // Usually from the participant the consenting owner is pinned to, so that grants
            // are actually reached; sometimes from anyone.
            let msg = request_control(input);
            let claimed = match msg.ack {
                rove_core::msg::Ack::Accept => msg.current_controller_id,
                _ => msg.src_id,
            };
            let sender = match arb.pinned(now, claimed) {
                Some(p) if input.u8() < 200 => p,
                _ => participant(input),
            };
            let msg = if input.u8() < 128 && msg.ack == rove_core::msg::Ack::Accept {
                RequestControl {
                    current_controller_id: arb.controller_id(),
                    ..msg
                }
            } else {
                msg
            };
            Event::from_request_control(VEHICLE, &msg, sender)
        }
        8 => Event::Heard {
            device: device(input),
            sender: participant(input),
        },
        _ => Event::Tick,
    }
}

/// The invariants that hold after every step.
pub(crate) fn check(arb: &Arbiter, now: MonoTime, decision: &Decision, max_sources: usize) {
    let owner = arb.owner();
    let sources: Vec<_> = arb.sources(now).collect();
    assert!(
        sources.len() <= max_sources,
        "{} sources, at most {max_sources}",
        sources.len()
    );
    match owner {
        Owner::Failsafe => assert_eq!(arb.controller_id(), arb.vehicle()),
        Owner::Controller(c) => {
            assert_eq!(arb.controller_id(), c.device);
            let source = sources.iter().find(|s| s.controller.writer == c.writer);
            assert!(
                source.is_some_and(|s| s.live),
                "owner {c:?} is not a live source at {now}: {sources:?} ({decision:?})"
            );
        }
    }
    if let Some(Output::Apply { by, .. }) = decision.output {
        assert_eq!(
            owner,
            Owner::Controller(by),
            "applied values of a non-owner"
        );
    }
    if let Some(change) = decision.owner_change {
        assert_eq!(change.to, owner);
        assert_ne!(change.from, change.to);
    }
}
