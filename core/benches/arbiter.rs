//! Per-sample cost of the ownership arbiter with 32 live writers.
//!
//! Each iteration steps one ControlCommand sample through the arbiter, cycling through 32
//! writers of mixed strengths and advancing the clock by 625 µs per sample (32 writers × 50 Hz,
//! the operators' default keep-alive rate), so liveness, ties and the owner's applies are all
//! exercised as in a busy fleet. Run: `cargo bench -p rove-core --bench arbiter`.

use criterion::{Criterion, black_box, criterion_group, criterion_main};
use rove_core::MonoTime;
use rove_core::arbiter::{Arbiter, ArbiterConfig, Event, ParticipantId, WriterId};
use rove_core::hierarchy::Strength;
use rove_core::msg::{CommandType, ControlCommand, Mode, MovementCommand, TimeT};
use std::time::Duration;

const VEHICLE: i64 = 1000;
const WRITERS: u32 = 32;

fn writer(n: u32) -> WriterId {
    WriterId {
        participant: ParticipantId(u128::from(n)),
        entity: 1,
    }
}

fn sample(n: u32, arrival: MonoTime) -> Event {
    Event::Sample {
        writer: writer(n),
        // Mixed strengths with ties: 8 distinct values 110..=320, four writers each.
        strength: Strength(110 + 30 * (n % 8) as u16),
        command: ControlCommand {
            src_id: i64::from(n) + 1,
            dest_id: VEHICLE,
            command_type: CommandType::Movement,
            movement_command: MovementCommand {
                throttle: n as i16,
                ..MovementCommand::CENTRED
            },
            mode: Mode::Manual,
            timestamp: TimeT::UNIX_EPOCH,
        },
        arrival,
    }
}

fn per_sample(c: &mut Criterion) {
    let period = Duration::from_micros(625);
    c.bench_function("arbiter step, 32 live writers, one sample", |b| {
        let mut arb = Arbiter::new(VEHICLE, ArbiterConfig::default());
        let mut now = MonoTime::ZERO;
        for n in 0..WRITERS {
            arb.step(now, sample(n, now));
        }
        let mut n = 0;
        b.iter(|| {
            now = now + period;
            n = (n + 1) % WRITERS;
            black_box(arb.step(now, black_box(sample(n, now))))
        });
    });
    c.bench_function("arbiter step, 32 live writers, tick", |b| {
        let mut arb = Arbiter::new(VEHICLE, ArbiterConfig::default());
        for n in 0..WRITERS {
            arb.step(MonoTime::ZERO, sample(n, MonoTime::ZERO));
        }
        let now = MonoTime::from_millis(50);
        b.iter(|| black_box(arb.step(now, Event::Tick)));
    });
}

criterion_group!(benches, per_sample);
criterion_main!(benches);
