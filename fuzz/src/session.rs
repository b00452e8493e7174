//! Operator sessions, their active-handover machines and a vehicle's arbiter together, over a
//! lossy network, driven by fuzz bytes: sticks, deadman, lost inputs and every button, every
//! console command (for the vehicle or any id), time, graceful quits, crashes, discovery
//! events, and forged DeviceInfo and RequestControl (any stage, any fields) from a rogue.
//!
//! Three sessions (device ids 1, 2, 3 at strengths 130, 220, 340; settings from the first
//! bytes) and the arbiter of vehicle [`VEHICLE`](crate::arbiter) exchange what their effects
//! say through the shared simulated world (`rove_core::world`): ControlCommand writes and
//! releases go to the arbiter, RequestControl to the arbiter and every session, and the
//! vehicle's DeviceInfo (its owner) back to the sessions. Each delivery is lost with a
//! probability the first byte chooses, decided by a generator seeded from the input, so the
//! choices of the remaining bytes stay in place.
//!
//! Checked, besides "no panic": the arbiter's invariants after each of its steps
//! ([`crate::arbiter`]), and that the effects of one operation settle (no endless exchange).

use crate::arbiter::{VEHICLE, access, advance, check, mode, movement, request_control};
use crate::bytes::Bytes;
use rove_core::MonoTime;
use rove_core::adapter::{InputAction, InputEvent};
use rove_core::arbiter::{Arbiter, ArbiterConfig, Decision, Event, ParticipantId, WriterId};
use rove_core::handover::{AutoAccept, HandoverConfig};
use rove_core::hierarchy::Strength;
use rove_core::msg::{DeviceId, DeviceInfo, DeviceType};
use rove_core::session::{Command, SessionConfig, SessionEvent, SessionInput, Writer};
use rove_core::trust::TrustConfig;
use rove_core::world::{Halt, Observer, Operator, View, World};
use std::time::Duration;

const IDS: [DeviceId; 3] = [1, 2, 3];
const STRENGTHS: [u16; 3] = [130, 220, 340];
/// The forger's participant.
const ROGUE: ParticipantId = ParticipantId(0xbad);
/// The vehicle's participant (its DeviceInfo comes from it).
const VEHICLE_PARTICIPANT: ParticipantId = ParticipantId(0xffff);

fn participant(i: usize) -> ParticipantId {
    ParticipantId(u128::from(IDS[i].unsigned_abs()))
}

/// Runs the sessions and the arbiter on `data`.
pub fn session(data: &[u8]) {
    let mut input = Bytes::new(data);
    let mut world = world(&mut input);
    while !input.is_empty() {
        if let Err(halt) = operate(&mut world, &mut input) {
            panic!("{halt}");
        }
    }
}

/// Loses deliveries (a deterministic xorshift64* generator) and checks the arbiter's
/// invariants after each of its steps.
#[derive(Debug)]
struct Lossy {
    state: u64,
    /// Out of 256.
    rate: u64,
}

impl Observer for Lossy {
    type Error = std::convert::Infallible;

    fn lost(&mut self) -> bool {
        self.state ^= self.state >> 12;
        self.state ^= self.state << 25;
        self.state ^= self.state >> 27;
        (self.state.wrapping_mul(0x2545_F491_4F6C_DD1D) >> 56) < self.rate
    }

    fn decision(&mut self, world: View<'_>, decision: &Decision) -> Result<(), Self::Error> {
        let max_sources = ArbiterConfig::default().max_sources;
        check(world.vehicle, world.now, decision, max_sources);
        Ok(())
    }
}

type Sim = World<Lossy>;
type Step = Result<(), Halt<std::convert::Infallible>>;

fn world(input: &mut Bytes<'_>) -> Sim {
    let loss = Lossy {
        rate: [0, 0, 26, 77][input.below(4)],
        state: input.u64() | 1,
    };
    let operators = (0..3)
        .map(|i| {
            let settings = input.u8();
            let handover = HandoverConfig {
                auto_accept: [
                    AutoAccept::Never,
                    AutoAccept::HigherPriority,
                    AutoAccept::Always,
                ][usize::from(settings % 3)],
                consent_timeout: Duration::from_millis(300),
                reply_timeout: Duration::from_millis(400),
                resend: Duration::from_millis(100),
            };
            let sticks = movement(input);
            let mode = mode(input);
            let config = SessionConfig {
                me: IDS[i],
                strength: Strength(STRENGTHS[i]),
                handover,
                drive: if settings & 4 != 0 {
                    vec![VEHICLE]
                } else {
                    vec![]
                },
                input: if settings & 8 != 0 {
                    SessionInput::Constant(sticks, mode)
                } else {
                    SessionInput::Device
                },
                heartbeat: Duration::from_millis(500),
                confirm_actions: settings & 16 != 0,
                request: (settings & 32 != 0).then_some(VEHICLE),
                participant: participant(i),
                trust: TrustConfig::default(),
            };
            Operator::new(config, MonoTime::ZERO)
        })
        .collect();
    let mut vehicle = Arbiter::new(VEHICLE, ArbiterConfig::default());
    if input.bool() {
        vehicle = vehicle.with_access(access());
    }
    let mut world = World::new(vehicle, VEHICLE_PARTICIPANT, operators, loss);
    world.discover();
    world
}

/// One operation the bytes choose.
fn operate(world: &mut Sim, input: &mut Bytes<'_>) -> Step {
    let i = input.below(3);
    match input.u8() % 12 {
        0 | 1 => {
            let sticks = InputEvent::Axes(movement(input));
            world.step(i, SessionEvent::Input(sticks))
        }
        2 => {
            let event = match input.u8() % 4 {
                0 => InputEvent::Deadman(input.bool()),
                1 => InputEvent::Lost {
                    reason: "fuzz".into(),
                },
                _ => InputEvent::Action(action(input)),
            };
            world.step(i, SessionEvent::Input(event))
        }
        3 | 4 => world.step(i, SessionEvent::Command(command(input))),
        5 | 6 => {
            let now = advance(input, world.now());
            world.set_now(now);
            for j in 0..3 {
                world.step(j, SessionEvent::StreamTick)?;
                world.step(j, SessionEvent::Tick)?;
            }
            world.vehicle_step(Event::Tick)?;
            world.publish_owner()
        }
        7 => {
            let msg = request_control(input);
            world.vehicle_step(Event::from_request_control(VEHICLE, &msg, ROGUE))?;
            for j in 0..3 {
                world.step(j, SessionEvent::RequestControl { msg, from: ROGUE })?;
            }
            Ok(())
        }
        8 => {
            let from = [ROGUE, participant(0), participant(1), participant(2)][input.below(4)];
            let info = DeviceInfo {
                device_id: input.pick(&[VEHICLE, 1, 2, 3, 99]),
                name: String::new(),
                device_type: input.pick(&[DeviceType::Vehicle, DeviceType::Controller]),
                controller_id: input.pick(&[VEHICLE, 1, 2, 3, 99]),
            };
            world.step(i, SessionEvent::DeviceInfo { info, from })
        }
        9 => {
            let j = input.below(3);
            let writer = Writer::Regular.id(participant(j));
            let event = match input.u8() % 4 {
                0 => SessionEvent::WriterLost { writer },
                1 => SessionEvent::ParticipantGone {
                    participant: participant(j),
                },
                2 => SessionEvent::WriterFound {
                    writer: WriterId {
                        participant: ROGUE,
                        entity: 1,
                    },
                    strength: Strength(input.u16()),
                },
                _ => SessionEvent::WriterFound {
                    writer,
                    strength: Strength(STRENGTHS[j]),
                },
            };
            world.step(i, event)
        }
        // A graceful quit: the session's last effects go out, then it is gone.
        10 => world.quit(i),
        _ => {
            // A crash: nothing more from it; discovery reports it gone, or not.
            world.crash(i);
            if input.bool() {
                let participant = participant(i);
                world.vehicle_step(Event::ParticipantGone { participant })?;
            }
            Ok(())
        }
    }
}

fn action(input: &mut Bytes<'_>) -> InputAction {
    match input.u8() % 8 {
        0 => InputAction::Mode(mode(input)),
        1 => InputAction::RequestControl,
        2 => InputAction::Accept,
        3 => InputAction::Refuse,
        4 => InputAction::Finish,
        5 => InputAction::Release,
        6 => InputAction::NextVehicle,
        _ => InputAction::PreviousVehicle,
    }
}

fn command(input: &mut Bytes<'_>) -> Command {
    let vehicle = match input.u8() % 8 {
        0 => 2,
        1 => i64::from_le_bytes(input.u64().to_le_bytes()),
        _ => VEHICLE,
    };
    let all = input.u8().is_multiple_of(4);
    match input.u8() % 8 {
        0 => Command::Select { vehicle },
        1 => Command::Drive { vehicle },
        2 => Command::Release {
            vehicle: (!all).then_some(vehicle),
        },
        3 => Command::Request { vehicle },
        4 => Command::Accept { vehicle },
        5 => Command::Refuse { vehicle },
        6 => Command::Finish { vehicle },
        _ => Command::Mode {
            vehicle: (!all).then_some(vehicle),
            mode: mode(input),
        },
    }
}
