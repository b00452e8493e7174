//! One simulated world: operator sessions and one vehicle's arbiter joined by direct, in-order
//! delivery, on a virtual clock. The network of the in-process demo, the session property test
//! and the session fuzz target.
//!
//! What travels, as over DDS (docs/design.md §2):
//! - an operator's ControlCommand writes and releases reach the arbiter;
//! - its RequestControl reaches the arbiter and every running session, its own included (a
//!   DDS reader hears its own participant's writers);
//! - the vehicle's DeviceInfo (naming its owner) reaches every running session whenever the
//!   owner changes, and on [`World::publish_owner`] (its heartbeat);
//! - an operator's DeviceInfo reaches the arbiter (as [`Event::Heard`]) and the other sessions on
//!   [`World::announce`].
//!
//! An [`Observer`] sees every effect before it is delivered and every decision of the arbiter,
//! and may lose any delivery: the demo prints and drives its outputs from it, the tests check
//! their properties in it, the fuzz target loses messages through it. The effects of one call
//! are delivered to quiescence; an exchange that does not settle within [`BUDGET`] deliveries is
//! reported as [`Halt::Unsettled`] rather than run for ever.

use crate::arbiter::{Arbiter, Decision, Event, ParticipantId};
use crate::hierarchy::Strength;
use crate::msg::{DeviceId, DeviceInfo, DeviceType, TimeT};
use crate::session::{Effect, OperatorSession, SessionConfig, SessionEvent, Writer};
use crate::time::MonoTime;
use std::collections::VecDeque;
use std::fmt;
use std::time::Duration;

/// Deliveries one call may cause before the exchange counts as endless.
pub const BUDGET: u32 = 10_000;

/// One operator of the world: the session `rove operator` runs, and what the network knows of
/// it.
#[derive(Debug)]
pub struct Operator {
    /// Its decisions.
    pub session: OperatorSession,
    /// Its own device id.
    pub id: DeviceId,
    /// Its regular writer's strength.
    pub strength: Strength,
    /// The participant its messages come from.
    pub participant: ParticipantId,
    /// Since when it takes no events (quit, crashed, or not started); `None` while it runs.
    pub out_since: Option<MonoTime>,
}

impl Operator {
    /// A running operator with `config`, started at `now`.
    pub fn new(config: SessionConfig, now: MonoTime) -> Operator {
        let (id, strength, participant) = (config.me, config.strength, config.participant);
        Operator {
            session: OperatorSession::new(config, now),
            id,
            strength,
            participant,
            out_since: None,
        }
    }

    /// The same operator, not started yet ([`World::start`] starts it).
    pub fn not_started(mut self) -> Operator {
        self.out_since = Some(MonoTime::ZERO);
        self
    }

    /// It runs: it takes events.
    pub fn runs(&self) -> bool {
        self.out_since.is_none()
    }
}

/// What an observer may look at.
#[derive(Debug, Clone, Copy)]
pub struct View<'a> {
    /// The world's time.
    pub now: MonoTime,
    /// The operators, in the order given.
    pub operators: &'a [Operator],
    /// The vehicle's arbiter.
    pub vehicle: &'a Arbiter,
}

/// Watches the world, and decides which deliveries are lost.
pub trait Observer {
    /// What stops the world (a property that does not hold, an output that failed).
    type Error;

    /// Whether the next delivery is lost. Never, by default.
    fn lost(&mut self) -> bool {
        false
    }

    /// Operator `from` produced `effect`; called before it is delivered.
    ///
    /// # Errors
    /// Whatever the observer finds wrong; the world stops.
    fn effect(&mut self, world: View<'_>, from: usize, effect: &Effect) -> Result<(), Self::Error> {
        let _ = (world, from, effect);
        Ok(())
    }

    /// The arbiter decided `decision`; called after each of its steps.
    ///
    /// # Errors
    /// Whatever the observer finds wrong; the world stops.
    fn decision(&mut self, world: View<'_>, decision: &Decision) -> Result<(), Self::Error> {
        let _ = (world, decision);
        Ok(())
    }
}

/// Why the world stopped.
#[derive(Debug)]
pub enum Halt<E> {
    /// One call's effects did not settle within [`BUDGET`] deliveries.
    Unsettled {
        /// The operator whose effect was next.
        from: usize,
        /// That effect.
        effect: String,
    },
    /// The observer stopped it.
    Observer(E),
}

impl<E: fmt::Display> fmt::Display for Halt<E> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Halt::Unsettled { from, effect } => {
                write!(f, "effects never settle: {effect} from operator {from}")
            }
            Halt::Observer(e) => e.fmt(f),
        }
    }
}

impl<E: fmt::Debug + fmt::Display> std::error::Error for Halt<E> {}

/// One pending delivery.
enum Delivery {
    /// Operator `.0`'s effect.
    Effect(usize, Effect),
    /// The vehicle's DeviceInfo to operator `.0`.
    Owner(usize, DeviceInfo),
}

/// The operators and the vehicle, and the clock.
#[derive(Debug)]
pub struct World<O> {
    now: MonoTime,
    vehicle: Arbiter,
    vehicle_participant: ParticipantId,
    operators: Vec<Operator>,
    observer: O,
}

impl<O: Observer> World<O> {
    /// A world at time zero. `vehicle` is the arbiter (its own participant pinned to
    /// `vehicle_participant`, which the vehicle's DeviceInfo comes from).
    pub fn new(
        mut vehicle: Arbiter,
        vehicle_participant: ParticipantId,
        operators: Vec<Operator>,
        observer: O,
    ) -> World<O> {
        vehicle.pin_own(vehicle_participant);
        World {
            now: MonoTime::ZERO,
            vehicle,
            vehicle_participant,
            operators,
            observer,
        }
    }

    /// The world's time.
    pub fn now(&self) -> MonoTime {
        self.now
    }

    /// Moves the clock to `now` (never backwards). Nothing is stepped: ticks are the caller's.
    pub fn set_now(&mut self, now: MonoTime) {
        self.now = self.now.max(now);
    }

    /// Moves the clock on by `by`.
    pub fn advance(&mut self, by: Duration) {
        self.now = self.now + by;
    }

    /// The wall-clock stamp put on what is sent now: one second after the Unix epoch plus the
    /// world's time, so stamps grow with it.
    pub fn stamp(&self) -> TimeT {
        TimeT::from_unix(Duration::from_secs(1) + self.now.saturating_since(MonoTime::ZERO))
    }

    /// What the observer sees.
    pub fn view(&self) -> View<'_> {
        View {
            now: self.now,
            operators: &self.operators,
            vehicle: &self.vehicle,
        }
    }

    /// The operators, in the order given.
    pub fn operators(&self) -> &[Operator] {
        &self.operators
    }

    /// Operator `i`'s session.
    ///
    /// # Panics
    /// `i` is not an operator's index.
    pub fn session(&self, i: usize) -> &OperatorSession {
        &self.operators[i].session
    }

    /// The vehicle's arbiter.
    pub fn vehicle(&self) -> &Arbiter {
        &self.vehicle
    }

    /// The observer.
    pub fn observer(&self) -> &O {
        &self.observer
    }

    /// The observer, to change.
    pub fn observer_mut(&mut self) -> &mut O {
        &mut self.observer
    }

    /// Ends the world, keeping what the observer gathered.
    pub fn into_observer(self) -> O {
        self.observer
    }

    /// Whether operator `i` runs.
    pub fn runs(&self, i: usize) -> bool {
        self.operators.get(i).is_some_and(Operator::runs)
    }

    /// Every operator learns every other one's regular writer and strength (discovery).
    pub fn discover(&mut self) {
        let writers: Vec<_> = self
            .operators
            .iter()
            .map(|o| (o.participant, o.strength))
            .collect();
        let (now, stamp) = (self.now, self.stamp());
        for (i, op) in self.operators.iter_mut().enumerate() {
            for (j, &(participant, strength)) in writers.iter().enumerate() {
                if i != j {
                    let writer = Writer::Regular.id(participant);
                    let _ =
                        op.session
                            .step(now, stamp, SessionEvent::WriterFound { writer, strength });
                }
            }
        }
    }

    /// Steps operator `i` with `event` (if it runs) and delivers what follows.
    ///
    /// # Errors
    /// The observer stopped the world, or the effects did not settle.
    pub fn step(&mut self, i: usize, event: SessionEvent) -> Result<(), Halt<O::Error>> {
        if !self.runs(i) {
            return Ok(());
        }
        let (now, stamp) = (self.now, self.stamp());
        let effects = self.operators[i].session.step(now, stamp, event);
        self.deliver(effects.into_iter().map(|e| Delivery::Effect(i, e)))
    }

    /// Steps the vehicle's arbiter with `event`; an owner change is published to the sessions.
    /// Returns the decision.
    ///
    /// # Errors
    /// The observer stopped the world, or the effects did not settle.
    pub fn vehicle_step(&mut self, event: Event) -> Result<Decision, Halt<O::Error>> {
        let mut queue = VecDeque::new();
        let decision = self.arbiter_step(event, &mut queue)?;
        self.settle(queue)?;
        Ok(decision)
    }

    /// Starts operator `i` (again).
    pub fn start(&mut self, i: usize) {
        if let Some(op) = self.operators.get_mut(i) {
            op.out_since = None;
        }
    }

    /// Operator `i` quits gracefully: it takes no more events, its last effects (FINISH,
    /// releases) go out, then its participant leaves.
    ///
    /// # Errors
    /// The observer stopped the world, or the effects did not settle.
    pub fn quit(&mut self, i: usize) -> Result<(), Halt<O::Error>> {
        if !self.runs(i) {
            return Ok(());
        }
        let stamp = self.stamp();
        let op = &mut self.operators[i];
        op.out_since = Some(self.now);
        let effects = op.session.stop(stamp);
        let participant = op.participant;
        self.deliver(effects.into_iter().map(|e| Delivery::Effect(i, e)))?;
        self.vehicle_step(Event::ParticipantGone { participant })?;
        Ok(())
    }

    /// Operator `i` crashes: nothing more from it, no release.
    pub fn crash(&mut self, i: usize) {
        if self.runs(i)
            && let Some(op) = self.operators.get_mut(i)
        {
            op.out_since = Some(self.now);
        }
    }

    /// The vehicle's DeviceInfo (naming its owner) to every running session, as its heartbeat
    /// sends it.
    ///
    /// # Errors
    /// The observer stopped the world, or the effects did not settle.
    pub fn publish_owner(&mut self) -> Result<(), Halt<O::Error>> {
        let queue = self.owner_info();
        self.settle(queue)
    }

    /// Operator `i`'s DeviceInfo, to the vehicle (which pins its id) and the other running
    /// sessions, as its heartbeat sends it. Returns the vehicle's decision (`None` if `i` does
    /// not run).
    ///
    /// # Errors
    /// The observer stopped the world, or the effects did not settle.
    pub fn announce(&mut self, i: usize) -> Result<Option<Decision>, Halt<O::Error>> {
        if !self.runs(i) {
            return Ok(None);
        }
        let (device, sender) = (self.operators[i].id, self.operators[i].participant);
        let decision = self.vehicle_step(Event::Heard { device, sender })?;
        let info = DeviceInfo {
            device_id: device,
            name: format!("op{device}"),
            device_type: DeviceType::Controller,
            controller_id: device,
        };
        for j in (0..self.operators.len()).filter(|&j| j != i) {
            let from = sender;
            self.step(
                j,
                SessionEvent::DeviceInfo {
                    info: info.clone(),
                    from,
                },
            )?;
        }
        Ok(Some(decision))
    }

    /// The vehicle's DeviceInfo deliveries to every running operator.
    fn owner_info(&self) -> VecDeque<Delivery> {
        let info = DeviceInfo {
            device_id: self.vehicle.vehicle(),
            name: "vehicle".into(),
            device_type: DeviceType::Vehicle,
            controller_id: self.vehicle.controller_id(),
        };
        (0..self.operators.len())
            .filter(|&j| self.runs(j))
            .map(|j| Delivery::Owner(j, info.clone()))
            .collect()
    }

    fn deliver(
        &mut self,
        deliveries: impl IntoIterator<Item = Delivery>,
    ) -> Result<(), Halt<O::Error>> {
        self.settle(deliveries.into_iter().collect())
    }

    /// One arbiter step: the observer sees the decision; an owner change queues the vehicle's
    /// DeviceInfo.
    fn arbiter_step(
        &mut self,
        event: Event,
        queue: &mut VecDeque<Delivery>,
    ) -> Result<Decision, Halt<O::Error>> {
        let decision = self.vehicle.step(self.now, event);
        let view = View {
            now: self.now,
            operators: &self.operators,
            vehicle: &self.vehicle,
        };
        self.observer
            .decision(view, &decision)
            .map_err(Halt::Observer)?;
        if decision.owner_change.is_some() {
            queue.extend(self.owner_info());
        }
        Ok(decision)
    }

    /// Delivers `queue` and everything that follows, in order, to quiescence.
    fn settle(&mut self, mut queue: VecDeque<Delivery>) -> Result<(), Halt<O::Error>> {
        let mut budget = BUDGET;
        let vehicle = self.vehicle.vehicle();
        while let Some(delivery) = queue.pop_front() {
            if budget == 0 {
                return Err(match delivery {
                    Delivery::Effect(from, effect) => Halt::Unsettled {
                        from,
                        effect: format!("{effect:?}"),
                    },
                    Delivery::Owner(to, info) => Halt::Unsettled {
                        from: to,
                        effect: format!("the vehicle's {info:?}"),
                    },
                });
            }
            budget -= 1;
            match delivery {
                Delivery::Owner(j, info) => {
                    if !self.runs(j) || self.observer.lost() {
                        continue;
                    }
                    let (now, stamp) = (self.now, self.stamp());
                    let from = self.vehicle_participant;
                    let effects = self.operators[j].session.step(
                        now,
                        stamp,
                        SessionEvent::DeviceInfo { info, from },
                    );
                    queue.extend(effects.into_iter().map(|e| Delivery::Effect(j, e)));
                }
                Delivery::Effect(i, effect) => {
                    let view = View {
                        now: self.now,
                        operators: &self.operators,
                        vehicle: &self.vehicle,
                    };
                    self.observer
                        .effect(view, i, &effect)
                        .map_err(Halt::Observer)?;
                    let op = &self.operators[i];
                    let event =
                        effect.arbiter_event(vehicle, op.participant, op.strength, self.now);
                    if let Some(event) = event
                        && !self.observer.lost()
                    {
                        self.arbiter_step(event, &mut queue)?;
                    }
                    if let Effect::Send(msg) = effect {
                        let from = self.operators[i].participant;
                        for j in 0..self.operators.len() {
                            if !self.runs(j) || self.observer.lost() {
                                continue;
                            }
                            let (now, stamp) = (self.now, self.stamp());
                            let event = SessionEvent::RequestControl { msg, from };
                            let more = self.operators[j].session.step(now, stamp, event);
                            queue.extend(more.into_iter().map(|e| Delivery::Effect(j, e)));
                        }
                    }
                }
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::adapter::InputEvent;
    use crate::arbiter::{ArbiterConfig, Owner};
    use crate::handover::HandoverConfig;
    use crate::msg::MovementCommand;
    use crate::session::SessionInput;
    use crate::trust::TrustConfig;

    const V: DeviceId = 100;

    fn operator(id: DeviceId, strength: u16) -> Operator {
        Operator::new(
            SessionConfig {
                me: id,
                strength: Strength(strength),
                handover: HandoverConfig::default(),
                drive: vec![V],
                input: SessionInput::Device,
                heartbeat: Duration::from_millis(500),
                confirm_actions: false,
                request: None,
                participant: ParticipantId(u128::from(id.unsigned_abs())),
                trust: TrustConfig::default(),
            },
            MonoTime::ZERO,
        )
    }

    /// Counts the arbiter's owner changes; loses every delivery while `deaf`.
    #[derive(Default)]
    struct Count {
        changes: usize,
        deaf: bool,
    }

    impl Observer for Count {
        type Error = String;
        fn lost(&mut self) -> bool {
            self.deaf
        }
        fn decision(&mut self, _: View<'_>, d: &Decision) -> Result<(), String> {
            self.changes += usize::from(d.owner_change.is_some());
            Ok(())
        }
    }

    fn world(observer: Count) -> World<Count> {
        let arbiter = Arbiter::new(V, ArbiterConfig::default());
        let ops = vec![operator(1, 220), operator(2, 340).not_started()];
        World::new(arbiter, ParticipantId(0xffff), ops, observer)
    }

    fn sticks(w: &mut World<Count>, i: usize) {
        let axes = InputEvent::Axes(MovementCommand::CENTRED);
        w.step(i, SessionEvent::Input(axes)).expect("settles");
    }

    #[test]
    fn the_stronger_operator_takes_over_and_its_quit_hands_back() {
        let mut w = world(Count::default());
        sticks(&mut w, 0);
        assert_eq!(w.vehicle().owner().device(), Some(1));
        sticks(&mut w, 1);
        assert_eq!(w.vehicle().owner().device(), Some(1), "not started");
        w.start(1);
        sticks(&mut w, 1);
        assert_eq!(w.vehicle().owner().device(), Some(2));
        // The owner change reached the sessions at once.
        assert_eq!(w.session(0).vehicles()[&V].controller_id, 2);
        w.quit(1).expect("settles");
        assert!(!w.runs(1));
        assert_eq!(w.vehicle().owner().device(), Some(1));
        assert_eq!(w.observer().changes, 3);
    }

    #[test]
    fn a_crash_is_timed_out_and_lost_deliveries_reach_nobody() {
        let mut w = world(Count::default());
        sticks(&mut w, 0);
        w.crash(0);
        w.advance(Duration::from_millis(150));
        w.vehicle_step(Event::Tick).expect("settles");
        assert_eq!(w.vehicle().owner(), Owner::Failsafe);

        let mut w = world(Count {
            deaf: true,
            ..Count::default()
        });
        sticks(&mut w, 0);
        assert_eq!(w.vehicle().owner(), Owner::Failsafe);
        assert_eq!(w.observer().changes, 0);
    }

    #[test]
    fn stamps_grow_with_the_clock() {
        let mut w = world(Count::default());
        let before = w.stamp();
        w.advance(Duration::from_millis(1));
        assert!(w.stamp() > before);
        w.set_now(MonoTime::ZERO);
        assert_eq!(w.now(), MonoTime::from_millis(1), "never backwards");
    }
}
