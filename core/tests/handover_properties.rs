//! Property tests of active handover over a lossy, duplicating, reordering network.
//!
//! One owner's operator (A) and one requester (B) exchange RequestControl samples through a bag
//! of in-flight messages: any message may be delivered in any order, delivered more than once,
//! or lost, while B requests and finishes, A's person answers, and time passes. Safety, after
//! every step: B never holds a grant for the vehicle unless A has yielded it (both never drive
//! at once); an ACCEPT is only ever sent by an A that has just yielded; a consent prompt never
//! outlives its timeout.

mod common;

use common::{VEHICLE, ms};
use proptest::prelude::*;
use rove_core::MonoTime;
use rove_core::handover::{Action, AutoAccept, Handover, HandoverConfig};
use rove_core::hierarchy::Strength;
use rove_core::msg::{Ack, RequestControl, TimeT};

const A: i64 = 1;
const B: i64 = 2;

#[derive(Debug, Clone)]
enum Op {
    /// Deliver in-flight message `k` (mod count); keep a copy to deliver again if `dup`.
    Deliver {
        k: usize,
        dup: bool,
    },
    Lose(usize),
    Request,
    Finish,
    Decide(bool),
    Advance(u64),
}

fn op() -> impl Strategy<Value = Op> {
    prop_oneof![
        6 => (any::<usize>(), prop::bool::weighted(0.2)).prop_map(|(k, dup)| Op::Deliver { k, dup }),
        1 => any::<usize>().prop_map(Op::Lose),
        2 => Just(Op::Request),
        1 => Just(Op::Finish),
        1 => any::<bool>().prop_map(Op::Decide),
        2 => prop_oneof![0u64..600, 9_000u64..13_000].prop_map(Op::Advance),
    ]
}

fn policy() -> impl Strategy<Value = AutoAccept> {
    prop::sample::select(vec![
        AutoAccept::Never,
        AutoAccept::HigherPriority,
        AutoAccept::Always,
    ])
}

struct Net {
    a: Handover,
    b: Handover,
    /// In flight: (to A?, message).
    bag: Vec<(bool, RequestControl)>,
    now: MonoTime,
}

impl Net {
    /// Queues what `from_a`'s actions send and checks that an ACCEPT leaves A yielded.
    fn post(&mut self, from_a: bool, actions: Vec<Action>) -> Result<(), TestCaseError> {
        for action in actions {
            if let Action::Send(m) = action {
                if from_a && m.ack == Ack::Accept {
                    prop_assert!(self.a.has_yielded(VEHICLE), "ACCEPT sent while A drives");
                }
                self.bag.push((!from_a, m));
            }
        }
        Ok(())
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 10_000, ..ProptestConfig::default() })]

    #[test]
    fn never_both_drive_whatever_the_network_does(
        a_policy in policy(),
        b_strength in 100u16..400,
        ops in prop::collection::vec(op(), 1..80),
    ) {
        let config = |auto_accept| HandoverConfig { auto_accept, ..HandoverConfig::default() };
        let mut net = Net {
            a: Handover::new(A, Strength(220), config(a_policy)),
            b: Handover::new(B, Strength(b_strength), config(AutoAccept::Never)),
            bag: Vec::new(),
            now: ms(0),
        };
        for op in ops {
            match op {
                Op::Deliver { k, dup } if !net.bag.is_empty() => {
                    let i = k % net.bag.len();
                    let (to_a, m) = if dup { net.bag[i] } else { net.bag.swap_remove(i) };
                    let now = net.now;
                    if to_a {
                        let out = net.a.on_message(now, &m);
                        net.post(true, out)?;
                    } else {
                        let out = net.b.on_message(now, &m);
                        net.post(false, out)?;
                    }
                }
                Op::Deliver { .. } => {}
                Op::Lose(k) if !net.bag.is_empty() => {
                    let i = k % net.bag.len();
                    net.bag.swap_remove(i);
                }
                Op::Lose(_) => {}
                Op::Request => {
                    // Each request gets a fresh stamp, as a wall clock would give.
                    let stamp = TimeT(net.now.as_nanos() / 100 + 1);
                    if let Ok(out) = net.b.request(net.now, VEHICLE, A, stamp) {
                        net.post(false, out)?;
                    }
                }
                Op::Finish => {
                    if let Ok(out) = net.b.finish(VEHICLE) {
                        net.post(false, out)?;
                    }
                }
                Op::Decide(accept) => {
                    if let Ok(out) = net.a.decide(net.now, VEHICLE, accept) {
                        net.post(true, out)?;
                    }
                }
                Op::Advance(dt) => {
                    net.now = net.now + std::time::Duration::from_millis(dt + 1);
                    let now = net.now;
                    let out = net.a.tick(now);
                    net.post(true, out)?;
                    let out = net.b.tick(now);
                    net.post(false, out)?;
                    if let Some(d) = net.a.next_deadline() {
                        prop_assert!(d > now, "prompt outlived its timeout");
                    }
                }
            }
            prop_assert!(
                !net.b.holds_grant(VEHICLE) || net.a.has_yielded(VEHICLE),
                "B holds a grant while A still drives"
            );
        }
    }
}
