//! Property tests of the arbiter over random event sequences (≥ 10 000 cases).
//!
//! A small shadow model, written independently of the arbiter and in a plainer style, tracks
//! what the contract needs: which samples count, who is live, who holds the grant. After every
//! step the invariants of docs/design.md §4 are checked against it:
//!
//! - at most one owner, and `controller_id` always names it;
//! - the owner is the strongest eligible live controller (the grant holder's priority stream
//!   counting as 65535), or the failsafe when nobody is live;
//! - no owner change without a cause: an owner that is still eligible and strongest is never
//!   replaced, so equal strength never steals; "preempted" means strictly stronger;
//! - with no incumbent, ties go to the lowest (device id, writer id);
//! - the failsafe takes over no later than the timeout after the last live sample, and
//!   `next_deadline` names exactly that instant;
//! - only the owner's own latest, fresh sample is ever applied;
//! - the same event sequence gives the same decisions;
//! - trust (docs/design.md §4b): a device id is pinned to the first participant heard speaking
//!   for it; samples, consent and FINISH claiming an id pinned to another participant, and
//!   strengths outside the hierarchy, change nothing; whoever owns speaks from the participant
//!   its id is pinned to.

mod common;

use common::{VEHICLE, command, ms, pw, w};
use proptest::prelude::*;
use rove_core::MonoTime;
use rove_core::arbiter::{
    Arbiter, ArbiterConfig, Decision, Event, Ignored, Output, Owner, ParticipantId, Reason,
    Setpoint, WriterId,
};
use rove_core::hierarchy::{DeviceClass, Hierarchy, Level, Strength};
use rove_core::msg::{CommandType, DeviceId, MovementCommand, TimeT};
use std::collections::BTreeMap;
use std::time::Duration;

const TIMEOUT: Duration = Duration::from_millis(100);

/// Pins lapse this long after their participant last spoke, or left (the defaults).
const HOLD: Duration = Duration::from_secs(3);
const GRACE: Duration = Duration::from_millis(500);

/// The writers in play: (writer, device, strength). Equal strengths (220) and a device id on
/// two participants' writers (device 1 on participants 1 and 5, device 2 on 2 and 6) make ties
/// and spoofing attempts common; participant 7 streams at a strength the hierarchy cannot give.
fn cast() -> Vec<(WriterId, DeviceId, u16)> {
    vec![
        (w(1), 1, 220),
        (w(2), 2, 220),
        (w(3), 3, 340),
        (w(4), 4, 110),
        (w(5), 1, 220),
        (pw(1), 1, 65535),
        (pw(2), 2, 65535),
        (pw(3), 3, 65535),
        (w(6), 2, 230),
        (pw(6), 2, 65535),
        (w(7), 4, 65534),
    ]
}

/// One generated step: time advance plus an event template.
#[derive(Debug, Clone)]
enum Gen {
    Sample {
        who: usize,
        kind: u8,
        throttle: i16,
        lag_ms: u64,
        elsewhere: bool,
    },
    Release(usize),
    WriterGone(usize),
    ParticipantGone(u32),
    /// `granted_by: None` = whoever owns the vehicle when the event is played; `sender: None`
    /// = the participant `granted_by` is pinned to.
    Accept {
        holder: DeviceId,
        granted_by: Option<DeviceId>,
        stamp: u64,
        sender: Option<u32>,
    },
    /// (holder, stamp, sender: `None` = the holder's pinned participant)
    Finish(DeviceId, u64, Option<u32>),
    /// A participant speaks as a device (DeviceInfo, REQUEST…).
    Heard(DeviceId, u32),
    Tick,
}

fn gen_event() -> impl Strategy<Value = Gen> {
    let n = cast().len();
    prop_oneof![
        8 => (0..n, 0u8..10, any::<i16>(), prop_oneof![6 => Just(0u64), 1 => 1u64..250], prop::bool::weighted(0.03))
            .prop_map(|(who, kind, throttle, lag_ms, elsewhere)| Gen::Sample { who, kind, throttle, lag_ms, elsewhere }),
        1 => (0..n).prop_map(Gen::Release),
        1 => (0..n).prop_map(Gen::WriterGone),
        1 => (1u32..=5).prop_map(Gen::ParticipantGone),
        1 => (prop::sample::select(vec![1, 2, 3, VEHICLE]), prop::option::weighted(0.4, 1i64..=4), 0u64..4, prop::option::weighted(0.3, 1u32..=8))
            .prop_map(|(holder, granted_by, stamp, sender)| Gen::Accept { holder, granted_by, stamp, sender }),
        1 => (1i64..=4, 0u64..4, prop::option::weighted(0.3, 1u32..=8)).prop_map(|(holder, stamp, sender)| Gen::Finish(holder, stamp, sender)),
        1 => (prop::sample::select(vec![1, 2, 3, 4, VEHICLE]), 1u32..=8).prop_map(|(d, p)| Gen::Heard(d, p)),
        3 => Just(Gen::Tick),
    ]
}

fn scenario() -> impl Strategy<Value = Vec<(u64, Gen)>> {
    prop::collection::vec((0u64..60, gen_event()), 1..60)
}

/// Turns the generated steps into concrete `(now, event)` pairs, resolving "the current owner"
/// against a live arbiter as it goes; returns the pairs and the decisions.
fn play(steps: &[(u64, Gen)]) -> (Vec<(MonoTime, Event)>, Vec<Decision>) {
    let cast = cast();
    let mut arb = Arbiter::new(VEHICLE, ArbiterConfig::default());
    arb.pin_own(ParticipantId(1000));
    let mut now = 0;
    let mut played = Vec::new();
    let participant = |p: u32| ParticipantId(u128::from(p));
    let mut decisions = Vec::new();
    for (dt, g) in steps {
        now += dt;
        let event = match g {
            Gen::Sample {
                who,
                kind,
                throttle,
                lag_ms,
                elsewhere,
            } => {
                let (writer, device, strength) = cast[*who];
                let kind = match kind {
                    0 => CommandType::Probe,
                    1 => CommandType::Mode,
                    _ => CommandType::Movement,
                };
                let mut cmd = command(device, kind, *throttle);
                if *elsewhere {
                    cmd.dest_id = VEHICLE + 1;
                }
                Event::Sample {
                    writer,
                    strength: Strength(strength),
                    command: cmd,
                    arrival: ms(now.saturating_sub(*lag_ms)),
                }
            }
            Gen::Release(i) => Event::Released { writer: cast[*i].0 },
            Gen::WriterGone(i) => Event::WriterGone { writer: cast[*i].0 },
            Gen::ParticipantGone(p) => Event::ParticipantGone {
                participant: ParticipantId(u128::from(*p)),
            },
            Gen::Accept {
                holder,
                granted_by,
                stamp,
                sender,
            } => {
                let granted_by = granted_by.unwrap_or(arb.controller_id());
                let pinned = arb.pinned(ms(now), granted_by);
                Event::GrantAccepted {
                    holder: *holder,
                    granted_by,
                    stamp: TimeT(*stamp),
                    sender: sender.map(participant).or(pinned).unwrap_or(participant(8)),
                }
            }
            Gen::Finish(holder, stamp, sender) => {
                let pinned = arb.pinned(ms(now), *holder);
                Event::GrantFinished {
                    holder: *holder,
                    stamp: TimeT(*stamp),
                    sender: sender.map(participant).or(pinned).unwrap_or(participant(8)),
                }
            }
            Gen::Heard(device, p) => Event::Heard {
                device: *device,
                sender: participant(*p),
            },
            Gen::Tick => Event::Tick,
        };
        decisions.push(arb.step(ms(now), event));
        played.push((ms(now), event));
    }
    (played, decisions)
}

/// What the contract needs to know about one writer, kept independently of the arbiter.
#[derive(Debug, Clone, Default)]
struct Shadow {
    device: DeviceId,
    strength: u16,
    last: Option<MonoTime>,
    high_water: MonoTime,
    /// Latest values and their arrival.
    setpoint: Option<(MonoTime, Setpoint)>,
}

#[derive(Debug, Default)]
struct Model {
    /// device → (participant, pinned until).
    pins: BTreeMap<DeviceId, (ParticipantId, MonoTime)>,
    writers: BTreeMap<WriterId, Shadow>,
    grant: Option<DeviceId>,
    grant_stamp: TimeT,
    /// (device, until): owners recently seen, whose ACCEPT may still be honoured.
    recent_owners: Vec<(DeviceId, MonoTime)>,
}

impl Model {
    fn new() -> Self {
        let mut model = Model::default();
        model
            .pins
            .insert(VEHICLE, (ParticipantId(1000), MonoTime::MAX));
        model
    }

    /// Whether `p` may speak as `device` at `now`; pins or refreshes if so.
    fn claim(&mut self, now: MonoTime, device: DeviceId, p: ParticipantId) -> bool {
        match self.pins.get(&device) {
            Some((owner, until)) if *owner != p && now < *until => false,
            Some((owner, until)) if *owner == p => {
                let until = (*until).max(now + HOLD);
                self.pins.insert(device, (p, until));
                true
            }
            _ => {
                self.pins.insert(device, (p, now + HOLD));
                true
            }
        }
    }

    fn pinned(&self, now: MonoTime, device: DeviceId) -> Option<ParticipantId> {
        self.pins
            .get(&device)
            .filter(|(_, until)| now < *until)
            .map(|(p, _)| *p)
    }

    fn live(&self, s: &Shadow, now: MonoTime) -> bool {
        s.last.is_some_and(|t| now < t + TIMEOUT)
    }

    fn fresh(&self, s: &Shadow, now: MonoTime) -> Option<Setpoint> {
        s.setpoint
            .filter(|(t, _)| now < *t + TIMEOUT)
            .map(|(_, sp)| sp)
    }

    fn effective(&self, s: &Shadow, now: MonoTime) -> Option<u16> {
        if !self.live(s, now) {
            return None;
        }
        match s.strength {
            65535 if self.grant == Some(s.device) => Some(65535),
            65535 => None,
            v => Some(v),
        }
    }

    /// Eligible writers with the top effective strength, and that strength.
    fn top(&self, now: MonoTime) -> (Vec<(DeviceId, WriterId)>, Option<u16>) {
        let best = self
            .writers
            .values()
            .filter_map(|s| self.effective(s, now))
            .max();
        let top = self
            .writers
            .iter()
            .filter(|(_, s)| best.is_some() && self.effective(s, now) == best)
            .map(|(w, s)| (s.device, *w))
            .collect();
        (top, best)
    }

    fn drop_holder_grant(&mut self, removed: &Shadow) {
        if removed.strength == 65535 && self.grant == Some(removed.device) {
            self.grant = None;
        }
    }

    /// Applies an event; returns whether a sample was accepted.
    fn apply(&mut self, now: MonoTime, event: &Event, grant_taken: bool) -> bool {
        match *event {
            Event::Sample {
                writer,
                strength,
                command,
                arrival,
            } => {
                let arrival = arrival.min(now);
                let in_hierarchy = strength == Strength::PRIORITY
                    || Hierarchy::STANDARD.rank_of(strength).is_some();
                if command.dest_id != VEHICLE
                    || strength.0 == 0
                    || !in_hierarchy
                    || !self.claim(now, command.src_id, writer.participant)
                    || now.saturating_since(arrival) >= TIMEOUT
                {
                    return false;
                }
                let s = self.writers.entry(writer).or_insert_with(|| Shadow {
                    device: command.src_id,
                    strength: strength.0,
                    ..Shadow::default()
                });
                if arrival < s.high_water {
                    return false;
                }
                s.high_water = arrival;
                s.last = Some(s.last.map_or(arrival, |l| l.max(arrival)));
                let kept = s
                    .setpoint
                    .filter(|(t, _)| arrival < *t + TIMEOUT)
                    .map_or(MovementCommand::CENTRED, |(_, p)| p.movement);
                match command.command_type {
                    CommandType::Probe => {}
                    CommandType::Movement => {
                        s.setpoint = Some((
                            arrival,
                            Setpoint {
                                movement: command.movement_command,
                                mode: command.mode,
                            },
                        ))
                    }
                    CommandType::Mode => {
                        s.setpoint = Some((
                            arrival,
                            Setpoint {
                                movement: kept,
                                mode: command.mode,
                            },
                        ))
                    }
                }
                true
            }
            Event::Released { writer } => {
                if let Some(s) = self.writers.get_mut(&writer) {
                    s.last = None;
                    s.high_water = s.high_water.max(now);
                    let s = s.clone();
                    self.drop_holder_grant(&s);
                }
                false
            }
            Event::WriterGone { writer } => {
                if let Some(s) = self.writers.remove(&writer) {
                    self.drop_holder_grant(&s);
                }
                false
            }
            Event::ParticipantGone { participant } => {
                for (p, until) in self.pins.values_mut() {
                    if *p == participant {
                        *until = (*until).min(now + GRACE);
                    }
                }
                let gone: Vec<_> = self
                    .writers
                    .keys()
                    .filter(|w| w.participant == participant)
                    .copied()
                    .collect();
                for w in gone {
                    if let Some(s) = self.writers.remove(&w) {
                        self.drop_holder_grant(&s);
                    }
                }
                false
            }
            Event::GrantAccepted {
                holder,
                stamp,
                granted_by,
                sender,
            } => {
                let believed = self.claim(now, granted_by, sender);
                assert!(
                    believed || !grant_taken,
                    "a grant on consent from a stranger"
                );
                if grant_taken {
                    self.grant = Some(holder);
                    self.grant_stamp = stamp;
                }
                false
            }
            Event::GrantFinished {
                holder,
                stamp,
                sender,
            } => {
                if self.claim(now, holder, sender)
                    && self.grant == Some(holder)
                    && stamp >= self.grant_stamp
                {
                    self.grant = None;
                }
                false
            }
            Event::Heard { device, sender } => {
                self.claim(now, device, sender);
                false
            }
            Event::Tick => false,
        }
    }
}

fn check(played: &[(MonoTime, Event)], decisions: &[Decision]) -> Result<(), TestCaseError> {
    let mut model = Model::new();
    let mut arb = Arbiter::new(VEHICLE, ArbiterConfig::default());
    arb.pin_own(ParticipantId(1000));
    let mut last_output_seq = 0;
    let mut driving = false;
    for (i, ((now, event), d)) in played.iter().zip(decisions).enumerate() {
        let now = *now;
        let before = arb.owner();
        let grant_before = arb.grant_holder();
        let replay = arb.step(now, *event);
        // Determinism: a second arbiter fed the same sequence decides the same.
        prop_assert_eq!(&replay, d, "step {} diverged on replay", i);
        let after = arb.owner();

        // Grant bookkeeping: ACCEPTs are honoured only from the owner or a recent owner.
        let grant_taken = matches!(event, Event::GrantAccepted { .. }) && d.ignored.is_none();
        if let Event::GrantAccepted {
            holder, granted_by, ..
        } = event
            && grant_taken
        {
            prop_assert_eq!(arb.grant_holder(), Some(*holder));
            let consent_ok = before.device() == Some(*granted_by)
                || model
                    .recent_owners
                    .iter()
                    .any(|(dev, until)| dev == granted_by && now < *until);
            prop_assert!(consent_ok, "grant without owner consent at step {}", i);
        }
        let accepted = model.apply(now, event, grant_taken);
        prop_assert_eq!(arb.grant_holder(), model.grant, "grant at step {}", i);
        if let Event::Sample { .. } = event {
            let arbiter_took_it = matches!(d.ignored, None | Some(Ignored::PriorityWithoutGrant));
            prop_assert_eq!(arbiter_took_it, accepted, "sample acceptance at step {}", i);
        }

        // Trust: whoever owns speaks from the participant its id is pinned to, and a message
        // not believed says who sent it and which id it claimed.
        if let Owner::Controller(c) = after {
            prop_assert_eq!(
                model.pinned(now, c.device),
                Some(c.writer.participant),
                "owner {:?} speaks for an id pinned elsewhere at step {}",
                c,
                i
            );
        }
        prop_assert_eq!(d.suspect.is_some(), d.ignored == Some(Ignored::Untrusted));

        // At most one owner, consistently reported.
        match d.owner_change {
            Some(c) => {
                prop_assert_eq!(c.from, before);
                prop_assert_eq!(c.to, after);
                prop_assert_ne!(c.from.writer(), c.to.writer());
            }
            None => prop_assert_eq!(before.writer(), after.writer()),
        }
        prop_assert_eq!(arb.controller_id(), after.device().unwrap_or(VEHICLE));

        // The owner is the strongest eligible live controller, else the failsafe.
        let (top, best) = model.top(now);
        match after {
            Owner::Failsafe => prop_assert!(top.is_empty(), "failsafe while {:?} live", top),
            Owner::Controller(c) => {
                prop_assert!(
                    top.iter().any(|(_, w)| *w == c.writer),
                    "owner {:?} not among strongest {:?} at step {}",
                    c,
                    top,
                    i
                );
                prop_assert_eq!(Some(c.strength.0), best);
            }
        }
        // No change without a cause; equal strength never steals.
        if let Some(prev) = before.writer()
            && top.iter().any(|(_, w)| *w == prev)
        {
            prop_assert_eq!(
                after.writer(),
                Some(prev),
                "incumbent replaced at step {}",
                i
            );
        }
        // With no incumbent among the strongest, the lowest (device, writer) wins.
        if d.owner_change.is_some() && !top.is_empty() {
            let lowest = top.iter().min().map(|(_, w)| *w);
            prop_assert_eq!(after.writer(), lowest);
        }
        if let Some(c) = d.owner_change {
            if c.reason == Reason::Preempted
                && let (Owner::Controller(from), Owner::Controller(to)) = (c.from, c.to)
            {
                prop_assert!(
                    to.strength > from.strength,
                    "preempted by a non-stronger one"
                );
            }
            if let Owner::Controller(from) = c.from {
                model.recent_owners.push((from.device, now + TIMEOUT));
            }
        }
        if let Owner::Controller(c) = after {
            model.recent_owners.push((c.device, now + TIMEOUT));
        }

        // Outputs: only the owner's latest fresh values; something on every owner change, when
        // the owner sends values, and when the values driving the vehicle go stale; else nothing.
        let owner_shadow = after.writer().and_then(|w| model.writers.get(&w));
        let owner_fresh = owner_shadow.and_then(|s| model.fresh(s, now));
        let owner_sent_values = matches!(event, Event::Sample { writer, command, .. }
            if accepted && Some(*writer) == after.writer() && command.command_type != CommandType::Probe);
        let values_lapsed = driving && d.owner_change.is_none() && owner_fresh.is_none();
        match d.output {
            Some(Output::Apply { by, setpoint, seq }) => {
                prop_assert!(seq > last_output_seq);
                last_output_seq = seq;
                prop_assert_eq!(Some(by.writer), after.writer());
                prop_assert_eq!(
                    owner_fresh,
                    Some(setpoint),
                    "not the latest fresh values at step {}",
                    i
                );
                driving = true;
            }
            Some(Output::SafeState { owner, seq }) => {
                prop_assert!(seq > last_output_seq);
                last_output_seq = seq;
                prop_assert_eq!(owner, after);
                prop_assert_eq!(
                    owner_fresh,
                    None,
                    "safe state despite fresh values at step {}",
                    i
                );
                driving = false;
            }
            None => prop_assert!(
                d.owner_change.is_none() && !owner_sent_values && !values_lapsed,
                "missing output at step {}",
                i
            ),
        }

        // The next deadline is exactly the earliest expiry of a live stream or of the values
        // driving the vehicle: the gateway's tick at that instant is all timing needs.
        let value_expiry = owner_shadow
            .filter(|_| driving)
            .and_then(|s| s.setpoint)
            .map(|(t, _)| t + TIMEOUT);
        let expected_deadline = model
            .writers
            .values()
            .filter(|s| model.live(s, now))
            .filter_map(|s| s.last.map(|t| t + TIMEOUT))
            .chain(value_expiry)
            .filter(|t| *t > now)
            .min();
        prop_assert_eq!(
            arb.next_deadline(),
            expected_deadline,
            "deadline at step {}",
            i
        );
        let _ = grant_before;
    }
    Ok(())
}

/// One read of the command stream: samples and releases taken at one instant.
fn batch() -> impl Strategy<Value = Vec<Gen>> {
    let n = cast().len();
    let sample = (0..n, 0u8..10, any::<i16>(), prop::bool::weighted(0.03)).prop_map(
        |(who, kind, throttle, elsewhere)| Gen::Sample {
            who,
            kind,
            throttle,
            lag_ms: 0,
            elsewhere,
        },
    );
    prop::collection::vec(
        prop_oneof![6 => sample, 1 => (0..n).prop_map(Gen::Release)],
        1..8,
    )
}

/// A history, then a batch `gap_ms` after its last step, stepped at once and one by one from
/// the same state: each event's verdict is the same; the batch decides once, at its end, for
/// the strongest eligible stream, keeping an owner that is among them; and only that owner's
/// values are applied.
fn check_batch(steps: &[(u64, Gen)], gap_ms: u64, batch: &[Gen]) -> Result<(), TestCaseError> {
    let mut all = steps.to_vec();
    all.extend(
        batch
            .iter()
            .enumerate()
            .map(|(i, g)| (if i == 0 { gap_ms } else { 0 }, g.clone())),
    );
    let (played, _) = play(&all);
    let (history, taken) = played.split_at(steps.len());
    let mut arb = Arbiter::new(VEHICLE, ArbiterConfig::default());
    arb.pin_own(ParticipantId(1000));
    for (now, event) in history {
        arb.step(*now, *event);
    }
    let now = taken[0].0;
    let events: Vec<Event> = taken.iter().map(|(_, e)| *e).collect();
    let before = arb.owner();
    let mut one_by_one = arb.clone();
    let singles: Vec<Decision> = events.iter().map(|e| one_by_one.step(now, *e)).collect();
    let decisions = arb.step_batch(now, &events);

    prop_assert_eq!(decisions.len(), events.len());
    for (d, single) in decisions.iter().zip(&singles) {
        prop_assert_eq!(d.ignored, single.ignored);
        prop_assert_eq!(d.suspect, single.suspect);
    }
    let (last, earlier) = decisions.split_last().expect("a batch of one or more");
    prop_assert!(
        earlier
            .iter()
            .all(|d| d.owner_change.is_none() && d.output.is_none())
    );
    let after = arb.owner();
    match last.owner_change {
        Some(c) => prop_assert_eq!((c.from, c.to), (before, after)),
        None => prop_assert_eq!(before.writer(), after.writer()),
    }
    let eligible: Vec<_> = arb
        .sources(now)
        .filter(|s| s.eligible)
        .map(|s| s.controller)
        .collect();
    let best = eligible.iter().map(|c| c.strength).max();
    prop_assert_eq!(after.writer().is_some(), best.is_some());
    if let Owner::Controller(c) = after {
        prop_assert_eq!(Some(c.strength), best);
    }
    let strength_of = |o: Owner| match o {
        Owner::Controller(c) => Some(c.strength),
        Owner::Failsafe => None,
    };
    prop_assert_eq!(
        strength_of(after),
        strength_of(one_by_one.owner()),
        "same strength as one by one"
    );
    if let Owner::Controller(b) = before
        && eligible
            .iter()
            .any(|c| c.writer == b.writer && Some(c.strength) == best)
    {
        prop_assert_eq!(
            after.writer(),
            Some(b.writer),
            "the owner keeps the vehicle"
        );
    }
    if let Some(Output::Apply { by, .. }) = last.output {
        prop_assert_eq!(Some(by.writer), after.writer());
    }
    Ok(())
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 10_000, ..ProptestConfig::default() })]

    #[test]
    fn a_batch_decides_once_for_the_strongest(
        steps in scenario(),
        gap_ms in prop_oneof![Just(0u64), 1u64..250],
        batch in batch(),
    ) {
        check_batch(&steps, gap_ms, &batch)?;
    }

    #[test]
    fn arbiter_keeps_the_ownership_contract(steps in scenario()) {
        let (played, decisions) = play(&steps);
        check(&played, &decisions)?;
    }

    /// With nobody else live, the failsafe owns no later than one timeout after the owner's
    /// last sample, given a tick at that instant (the gateway ticks at `next_deadline`).
    #[test]
    fn failsafe_no_later_than_timeout_after_last_sample(
        gaps in prop::collection::vec(0u64..99, 1..40),
        level in 0usize..3,
        class in 0usize..4,
        offset in 0u8..=9,
    ) {
        let strength = Hierarchy::STANDARD
            .strength(Level::ALL[level], DeviceClass::ALL[class], offset)
            .expect("valid offset")
            .0;
        let mut arb = Arbiter::new(VEHICLE, ArbiterConfig::default());
        let mut now = ms(0);
        for gap in gaps {
            now = now + Duration::from_millis(gap);
            arb.step(now, Event::Sample {
                writer: w(1), strength: Strength(strength),
                command: command(1, CommandType::Movement, 1), arrival: now,
            });
            prop_assert_eq!(arb.controller_id(), 1);
        }
        let deadline = arb.next_deadline();
        prop_assert_eq!(deadline, Some(now + TIMEOUT));
        let d = arb.step(now + TIMEOUT, Event::Tick);
        prop_assert!(d.entered_failsafe());
        let safe = matches!(d.output, Some(Output::SafeState { owner: Owner::Failsafe, .. }));
        prop_assert!(safe, "expected the failsafe's safe state, got {:?}", d.output);
    }
}
