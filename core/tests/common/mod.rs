//! Shared helpers for the core's scenario and property tests: a vehicle rig that scripts
//! `(t_ms, event)` timelines against an arbiter.

#![allow(dead_code)]

use rove_core::MonoTime;
use rove_core::arbiter::{Arbiter, ArbiterConfig, Decision, Event, ParticipantId, WriterId};
use rove_core::hierarchy::Strength;
use rove_core::msg::{CommandType, ControlCommand, DeviceId, Mode, MovementCommand, TimeT};

/// The vehicle under test.
pub const VEHICLE: DeviceId = 1000;

/// Writer `n` of participant `n` (one writer per process, as operators have).
pub fn w(n: u32) -> WriterId {
    WriterId {
        participant: ParticipantId(u128::from(n)),
        entity: 1,
    }
}

/// A priority writer (second writer) of participant `n`.
pub fn pw(n: u32) -> WriterId {
    WriterId {
        participant: ParticipantId(u128::from(n)),
        entity: 2,
    }
}

pub fn ms(t: u64) -> MonoTime {
    MonoTime::from_millis(t)
}

pub fn movement(throttle: i16) -> MovementCommand {
    MovementCommand {
        throttle,
        ..MovementCommand::CENTRED
    }
}

pub fn command(src: DeviceId, kind: CommandType, throttle: i16) -> ControlCommand {
    ControlCommand {
        src_id: src,
        dest_id: VEHICLE,
        command_type: kind,
        movement_command: movement(throttle),
        mode: Mode::Manual,
        timestamp: TimeT::UNIX_EPOCH,
    }
}

/// An arbiter plus helpers that step it at given times.
pub struct Rig {
    pub arb: Arbiter,
}

impl Rig {
    pub fn new() -> Self {
        Rig {
            arb: Arbiter::new(VEHICLE, ArbiterConfig::default()),
        }
    }

    pub fn with(config: ArbiterConfig) -> Self {
        Rig {
            arb: Arbiter::new(VEHICLE, config),
        }
    }

    /// A movement sample from `device` via `writer` with `strength`, arriving at `t`.
    pub fn drive(
        &mut self,
        t: u64,
        writer: WriterId,
        device: DeviceId,
        strength: u16,
        throttle: i16,
    ) -> Decision {
        self.send(
            t,
            writer,
            Strength(strength),
            command(device, CommandType::Movement, throttle),
        )
    }

    pub fn send(
        &mut self,
        t: u64,
        writer: WriterId,
        strength: Strength,
        cmd: ControlCommand,
    ) -> Decision {
        self.arb.step(
            ms(t),
            Event::Sample {
                writer,
                strength,
                command: cmd,
                arrival: ms(t),
            },
        )
    }

    pub fn at(&mut self, t: u64, event: Event) -> Decision {
        self.arb.step(ms(t), event)
    }

    pub fn tick(&mut self, t: u64) -> Decision {
        self.arb.step(ms(t), Event::Tick)
    }
}
