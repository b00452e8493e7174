//! Operator sessions, their active-handover machines and a vehicle's arbiter together, over a
//! lossy network, driven by fuzz bytes: sticks, deadman, lost inputs and every button, every
//! console command (for the vehicle or any id), time, graceful quits, crashes, discovery
//! events, and forged DeviceInfo and RequestControl (any stage, any fields) from a rogue.
//!
//! Three sessions (device ids 1, 2, 3 at strengths 130, 220, 340; settings from the first
//! bytes) and the arbiter of vehicle [`VEHICLE`](crate::arbiter) exchange what their effects
//! say: ControlCommand writes and releases go to the arbiter, RequestControl to the arbiter and
//! the other sessions, and the vehicle's DeviceInfo (its owner) back to the sessions. Each
//! delivery is lost with a probability the first byte chooses, decided by a generator seeded
//! from the input, so the choices of the remaining bytes stay in place.
//!
//! Checked, besides "no panic": the arbiter's invariants after each of its steps
//! ([`crate::arbiter`]), and that the effects of one operation settle (no endless exchange).

use crate::arbiter::{VEHICLE, access, advance, check, mode, movement, request_control};
use crate::bytes::Bytes;
use rove_core::MonoTime;
use rove_core::adapter::{InputAction, InputEvent};
use rove_core::arbiter::{Arbiter, ArbiterConfig, Event, ParticipantId, WriterId};
use rove_core::handover::{AutoAccept, HandoverConfig};
use rove_core::hierarchy::Strength;
use rove_core::msg::{DeviceId, DeviceInfo, DeviceType, TimeT};
use rove_core::session::{
    Command, Effect, OperatorSession, SessionConfig, SessionEvent, SessionInput, Writer,
};
use rove_core::trust::TrustConfig;
use std::collections::VecDeque;
use std::time::Duration;

const IDS: [DeviceId; 3] = [1, 2, 3];
const STRENGTHS: [u16; 3] = [130, 220, 340];
/// The forger's participant.
const ROGUE: ParticipantId = ParticipantId(0xbad);
/// The vehicle's participant (its DeviceInfo comes from it).
const VEHICLE_PARTICIPANT: ParticipantId = ParticipantId(0xffff);
/// Deliveries one operation may cause before the exchange counts as endless.
const BUDGET: u32 = 10_000;

fn participant(i: usize) -> ParticipantId {
    ParticipantId(u128::from(IDS[i].unsigned_abs()))
}

/// Runs the sessions and the arbiter on `data`.
pub fn session(data: &[u8]) {
    let mut input = Bytes::new(data);
    let mut world = World::new(&mut input);
    while !input.is_empty() {
        world.operate(&mut input);
    }
}

/// A deterministic generator (xorshift64*) for losses.
#[derive(Debug)]
struct Loss {
    state: u64,
    /// Out of 256.
    rate: u64,
}

impl Loss {
    fn lost(&mut self) -> bool {
        self.state ^= self.state >> 12;
        self.state ^= self.state << 25;
        self.state ^= self.state >> 27;
        (self.state.wrapping_mul(0x2545_F491_4F6C_DD1D) >> 56) < self.rate
    }
}

struct World {
    now: MonoTime,
    sessions: Vec<OperatorSession>,
    gone: [bool; 3],
    vehicle: Arbiter,
    loss: Loss,
}

impl World {
    fn new(input: &mut Bytes<'_>) -> World {
        let loss = Loss {
            rate: [0, 0, 26, 77][input.below(4)],
            state: input.u64() | 1,
        };
        let now = MonoTime::ZERO;
        let mut sessions: Vec<OperatorSession> = (0..3)
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
                OperatorSession::new(
                    SessionConfig {
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
                    },
                    now,
                )
            })
            .collect();
        for (i, session) in sessions.iter_mut().enumerate() {
            for j in (0..3).filter(|&j| j != i) {
                let found = SessionEvent::WriterFound {
                    writer: Writer::Regular.id(participant(j)),
                    strength: Strength(STRENGTHS[j]),
                };
                session.step(now, TimeT(0), found);
            }
        }
        let mut vehicle = Arbiter::new(VEHICLE, ArbiterConfig::default());
        if input.bool() {
            vehicle = vehicle.with_access(access());
        }
        vehicle.pin_own(VEHICLE_PARTICIPANT);
        World {
            now,
            sessions,
            gone: [false; 3],
            vehicle,
            loss,
        }
    }

    fn stamp(&self) -> TimeT {
        TimeT(1_000_000 + self.now.as_nanos() / 100)
    }

    fn operate(&mut self, input: &mut Bytes<'_>) {
        let i = input.below(3);
        let mut budget = BUDGET;
        match input.u8() % 12 {
            0 | 1 => {
                let sticks = InputEvent::Axes(movement(input));
                self.step(i, SessionEvent::Input(sticks), &mut budget);
            }
            2 => {
                let event = match input.u8() % 4 {
                    0 => InputEvent::Deadman(input.bool()),
                    1 => InputEvent::Lost {
                        reason: "fuzz".into(),
                    },
                    _ => InputEvent::Action(action(input)),
                };
                self.step(i, SessionEvent::Input(event), &mut budget);
            }
            3 | 4 => {
                let command = command(input);
                self.step(i, SessionEvent::Command(command), &mut budget);
            }
            5 | 6 => {
                self.now = advance(input, self.now);
                for j in 0..3 {
                    self.step(j, SessionEvent::StreamTick, &mut budget);
                    self.step(j, SessionEvent::Tick, &mut budget);
                }
                self.vehicle_step(Event::Tick);
                self.vehicle_info(&mut budget);
            }
            7 => {
                let msg = request_control(input);
                let event = Event::from_request_control(VEHICLE, &msg, ROGUE);
                self.vehicle_step(event);
                for j in 0..3 {
                    let event = SessionEvent::RequestControl { msg, from: ROGUE };
                    self.step(j, event, &mut budget);
                }
            }
            8 => {
                let from = [ROGUE, participant(0), participant(1), participant(2)][input.below(4)];
                let info = DeviceInfo {
                    device_id: input.pick(&[VEHICLE, 1, 2, 3, 99]),
                    name: String::new(),
                    device_type: input.pick(&[DeviceType::Vehicle, DeviceType::Controller]),
                    controller_id: input.pick(&[VEHICLE, 1, 2, 3, 99]),
                };
                self.step(i, SessionEvent::DeviceInfo { info, from }, &mut budget);
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
                self.step(i, event, &mut budget);
            }
            10 => {
                // A graceful quit: the session's last effects go out, then it is gone.
                if !self.gone[i] {
                    let stamp = self.stamp();
                    let effects = self.sessions[i].stop(stamp);
                    self.deliver(i, effects, &mut budget);
                    self.gone[i] = true;
                }
            }
            _ => {
                // A crash: nothing more from it; discovery reports it gone, or not.
                self.gone[i] = true;
                if input.bool() {
                    self.vehicle_step(Event::ParticipantGone {
                        participant: participant(i),
                    });
                }
            }
        }
    }

    fn vehicle_step(&mut self, event: Event) {
        let decision = self.vehicle.step(self.now, event);
        check(
            &self.vehicle,
            self.now,
            &decision,
            ArbiterConfig::default().max_sources,
        );
    }

    /// The vehicle's DeviceInfo (naming its owner) to every running session.
    fn vehicle_info(&mut self, budget: &mut u32) {
        let info = DeviceInfo {
            device_id: VEHICLE,
            name: "vehicle".into(),
            device_type: DeviceType::Vehicle,
            controller_id: self.vehicle.controller_id(),
        };
        for j in 0..3 {
            if !self.loss.lost() {
                let event = SessionEvent::DeviceInfo {
                    info: info.clone(),
                    from: VEHICLE_PARTICIPANT,
                };
                self.step(j, event, budget);
            }
        }
    }

    /// Steps session `i` (if it runs) and delivers what follows.
    fn step(&mut self, i: usize, event: SessionEvent, budget: &mut u32) {
        if self.gone[i] {
            return;
        }
        let (now, stamp) = (self.now, self.stamp());
        let effects = self.sessions[i].step(now, stamp, event);
        self.deliver(i, effects, budget);
    }

    fn deliver(&mut self, from: usize, effects: Vec<Effect>, budget: &mut u32) {
        let mut queue: VecDeque<(usize, Effect)> = effects.into_iter().map(|e| (from, e)).collect();
        while let Some((i, effect)) = queue.pop_front() {
            *budget = budget
                .checked_sub(1)
                .unwrap_or_else(|| panic!("effects never settle: {effect:?} from {i}"));
            let strength = Strength(STRENGTHS[i]);
            if let Some(event) = effect.arbiter_event(VEHICLE, participant(i), strength, self.now)
                && !self.loss.lost()
            {
                self.vehicle_step(event);
            }
            if let Effect::Send(msg) = effect {
                for j in (0..3).filter(|&j| j != i && !self.gone[j]) {
                    if self.loss.lost() {
                        continue;
                    }
                    let (now, stamp) = (self.now, self.stamp());
                    let event = SessionEvent::RequestControl {
                        msg,
                        from: participant(i),
                    };
                    let more = self.sessions[j].step(now, stamp, event);
                    queue.extend(more.into_iter().map(|e| (j, e)));
                }
            }
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
    let all = input.u8() % 4 == 0;
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
