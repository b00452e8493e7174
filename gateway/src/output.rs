//! The vehicle's output adapter as the gateway runs it: opened from `[output]`, kept in the safe
//! state while its device fails, retried, and reopened if it could not be opened at start.
//!
//! Policy: a failing output never stops the gateway. A write that fails puts the
//! outputs in the safe state (as far as the device still takes writes) and holds them there for
//! [`RETRY`]; then commands are applied again, which retries the device (the PWM backends redo a
//! channel's set-up on the next write). A device that cannot be opened at start for a transient
//! reason (a sysfs channel the kernel has not exported yet) is reopened every [`RETRY`]; a fatal
//! reason (permission denied, a channel that does not exist) ends the start with the error.

use crate::config::OutputConfig;
use rove_core::MonoTime;
use rove_core::adapter::{Health, OutputAdapter};
use rove_core::arbiter::Setpoint;
use rove_core::error::{Disposition, LinkError};
use rove_core::sim::SimOutput;
use std::time::Duration;
use tracing::{info, warn};

/// How long outputs stay safe after a failed write, and the reopen interval.
pub const RETRY: Duration = Duration::from_millis(250);

/// Opens the adapter `config` describes; it writes its safe state before returning.
///
/// # Errors
/// The device cannot be opened or the safe state cannot be written.
pub fn open(config: &OutputConfig, now: MonoTime) -> Result<Box<dyn OutputAdapter>, LinkError> {
    Ok(match config {
        OutputConfig::Sim => {
            let mut sim = SimOutput::default();
            sim.safe_state(now)?;
            Box::new(sim)
        }
        OutputConfig::Pwm(c) | OutputConfig::Eyedrive(c) => {
            let backend = rove_pwm::open_backend(c)?;
            Box::new(rove_pwm::PwmVehicle::new(c.clone(), backend, now)?)
        }
        OutputConfig::Naza(c) => {
            let backend = rove_pwm::open_backend(&c.pwm)?;
            Box::new(rove_naza::NazaVehicle::new(c.clone(), backend, now)?)
        }
        OutputConfig::Mavlink(c) => {
            Box::new(rove_mavlink::MavlinkVehicle::new((**c).clone(), now)?)
        }
        OutputConfig::Can(c) => {
            let bus = rove_can::open_bus(c)?;
            Box::new(rove_can::CanVehicle::new((**c).clone(), bus, now)?)
        }
    })
}

/// The output adapter with the gateway's failure policy around it.
pub struct ManagedOutput {
    config: OutputConfig,
    adapter: Option<Box<dyn OutputAdapter>>,
    /// While set: outputs held safe (or the device reopened) until then.
    hold_until: Option<MonoTime>,
    /// When the adapter's keep-alive is next due.
    next_keepalive: Option<MonoTime>,
    last_error: Option<String>,
}

impl std::fmt::Debug for ManagedOutput {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ManagedOutput")
            .field("adapter", &self.describe())
            .field("hold_until", &self.hold_until)
            .field("last_error", &self.last_error)
            .finish()
    }
}

impl ManagedOutput {
    /// Opens the output; a transient failure leaves it closed, to be reopened.
    ///
    /// # Errors
    /// A fatal failure to open (wrong path, no permission): the configuration must change.
    pub fn open(config: OutputConfig, now: MonoTime) -> Result<ManagedOutput, LinkError> {
        let mut managed = ManagedOutput {
            config,
            adapter: None,
            hold_until: None,
            next_keepalive: None,
            last_error: None,
        };
        match open(&managed.config, now) {
            Ok(adapter) => managed.adapter = Some(adapter),
            Err(e) if e.disposition == Disposition::Fatal => return Err(e),
            Err(e) => managed.failed(now, &e),
        }
        Ok(managed)
    }

    /// The adapter's description, or what is being opened.
    pub fn describe(&self) -> String {
        match &self.adapter {
            Some(a) => a.describe(),
            None => format!("{:?} (not open yet)", kind(&self.config)),
        }
    }

    /// The link's health.
    pub fn health(&self) -> Health {
        match (&self.adapter, &self.last_error) {
            (Some(a), None) => a.health(),
            (_, Some(e)) => Health::Down(e.clone()),
            (None, None) => Health::Down("not open".into()),
        }
    }

    /// What the device reports about itself (an autopilot's mode and armed state).
    pub fn detail(&self) -> Option<String> {
        self.adapter.as_ref().and_then(|a| a.detail())
    }

    /// Whether the adapter holds the outputs safe by its own decision (see
    /// [`rove_core::adapter::OutputAdapter::held_safe`]).
    pub fn held_safe(&self) -> bool {
        self.adapter.as_ref().is_some_and(|a| a.held_safe())
    }

    /// When [`ManagedOutput::tick`] has work: the end of a hold, or the adapter's keep-alive.
    pub fn next_deadline(&self) -> Option<MonoTime> {
        let keepalive = self.adapter.as_ref().and(self.next_keepalive);
        match (self.hold_until, keepalive) {
            (Some(h), Some(k)) => Some(h.min(k)),
            (h, k) => h.or(k),
        }
    }

    /// Drives `setpoint`, unless the outputs are held safe after a failure.
    pub fn apply(&mut self, now: MonoTime, setpoint: &Setpoint) {
        if self.holding(now) {
            return;
        }
        let Some(adapter) = self.adapter.as_mut() else {
            return;
        };
        match adapter.apply(now, setpoint) {
            Ok(()) => {
                // The command was the retry and it worked: the hold is over. Left set, the next
                // tick would end it by putting the adapter, already driving, in its safe state
                // (seen against ArduPilot: a start-up hold ending in the same turn as the first command made
                // the MAVLink adapter release and command HOLD).
                self.hold_until = None;
                self.recovered();
            }
            Err(e) => {
                self.failed(now, &e);
                self.safe_state(now);
            }
        }
    }

    /// Puts the outputs in the safe state (also while holding).
    pub fn safe_state(&mut self, now: MonoTime) {
        let Some(adapter) = self.adapter.as_mut() else {
            return;
        };
        match adapter.safe_state(now) {
            Ok(()) => self.recovered_if_healthy(),
            Err(e) => self.failed(now, &e),
        }
    }

    /// Periodic work: reopen a closed output, end a hold, run the adapter's keep-alive.
    pub fn tick(&mut self, now: MonoTime) {
        if self.adapter.is_none() && !self.holding(now) {
            match open(&self.config, now) {
                Ok(adapter) => {
                    info!(output = %adapter.describe(), "output opened");
                    self.adapter = Some(adapter);
                    self.recovered();
                }
                Err(e) => self.failed(now, &e),
            }
        }
        if self.hold_until.is_some_and(|h| now >= h) {
            self.hold_until = None;
            // Still safe until the next command; that command is the retry.
            self.safe_state(now);
        }
        let due = self.next_keepalive.is_none_or(|k| now >= k);
        if let Some(adapter) = self.adapter.as_mut()
            && let Some(period) = adapter.keepalive_period()
            && due
        {
            self.next_keepalive = Some(now + period);
            match adapter.keepalive(now) {
                Ok(()) => self.recovered_if_healthy(),
                Err(e) => self.failed(now, &e),
            }
        }
    }

    fn holding(&self, now: MonoTime) -> bool {
        self.hold_until.is_some_and(|h| now < h)
    }

    fn failed(&mut self, now: MonoTime, e: &LinkError) {
        if e.disposition == Disposition::Silent {
            return;
        }
        if self.last_error.as_deref() != Some(e.detail.as_str()) {
            warn!(error = %e.detail, disposition = ?e.disposition, "output failed: outputs held safe, retrying");
        }
        self.last_error = Some(e.detail.clone());
        self.hold_until = Some(now + RETRY);
    }

    /// A keep-alive or safe-state write worked: the device is back if it says so (a CAN bus
    /// that left bus-off while nobody drives would otherwise show its old error until the
    /// next command).
    fn recovered_if_healthy(&mut self) {
        if self
            .adapter
            .as_ref()
            .is_some_and(|a| a.health() == Health::Ok)
        {
            self.recovered();
        }
    }

    fn recovered(&mut self) {
        if let Some(e) = self.last_error.take() {
            info!(previous_error = %e, "output working again");
        }
    }
}

/// How long a device call may take before the output counts as hung, and how old a command
/// may be when the device is free to take it (`[vehicle] output_deadline_ms`, and the command
/// timeout).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct WriteLimits {
    /// A device call (apply, safe state, keep-alive, reopen) running longer is a hung output.
    pub deadline: Duration,
    /// An apply older than this when the device is free again is not written: the arbiter has
    /// decided something newer by then, or will within this time.
    pub max_age: Duration,
}

/// What the control loop knows of the output, for `STATUS=` and logs.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct OutputReport {
    /// The adapter's description.
    pub describe: String,
    /// Its health as of its last call that returned.
    pub health: Health,
    /// What the device says of itself (an autopilot's mode).
    pub detail: Option<String>,
    /// How long the call in progress has run, once past [`WriteLimits::deadline`].
    pub hung: Option<Duration>,
    /// Applies not written because they were older than [`WriteLimits::max_age`] when the
    /// device was free again.
    pub stale: u64,
    /// The adapter holds the outputs safe by its own decision (an autopilot refused a mode).
    pub held_safe: bool,
}

impl std::fmt::Display for OutputReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match (&self.hung, &self.detail) {
            (Some(hung), _) => write!(f, "hung: a device call has not returned for {hung:.1?}"),
            (None, Some(detail)) => write!(f, "{} ({detail})", self.health),
            (None, None) => write!(f, "{}", self.health),
        }
    }
}

/// A command for the output thread, with the time it was decided.
#[derive(Debug, Clone, Copy)]
enum Command {
    Apply(MonoTime, Setpoint),
    Safe,
}

#[derive(Debug)]
struct WorkerState {
    /// The newest command the thread has not taken yet; a newer one replaces it.
    pending: Option<Command>,
    /// When the thread entered the device call in progress, if it is in one.
    busy_since: Option<MonoTime>,
    stale: u64,
    describe: String,
    health: Health,
    detail: Option<String>,
    held_safe: bool,
    stop: bool,
    done: bool,
}

#[derive(Debug)]
struct WorkerShared {
    state: std::sync::Mutex<WorkerState>,
    /// Wakes the thread (a command, a stop) and the stopping loop (done).
    wake: std::sync::Condvar,
}

impl WorkerShared {
    fn lock(&self) -> std::sync::MutexGuard<'_, WorkerState> {
        // The state stays consistent under a panic in the device call (nothing is left half
        // written while holding the lock), so a poisoned lock is used as it is.
        crate::runtime::lock(&self.state)
    }

    fn publish(&self, output: &ManagedOutput) {
        let mut state = self.lock();
        state.describe = output.describe();
        state.health = output.health();
        state.detail = output.detail();
        state.held_safe = output.held_safe();
    }
}

/// The output on a thread of its own, so that a device call that blocks (a sysfs write, a TCP
/// send to a peer that stopped reading) never stalls the control loop: the loop hands over the
/// newest command without waiting, a slow device never has a queue of old ones, and a call
/// that runs past its deadline shows as a hung output in [`OutputWorker::report`].
#[derive(Debug)]
pub struct OutputWorker {
    shared: std::sync::Arc<WorkerShared>,
    clock: crate::runtime::Clock,
    limits: WriteLimits,
}

impl OutputWorker {
    /// Opens the output described by `config` on a thread of its own, which then runs its
    /// retries and keep-alives. (Adapters need not be `Send`: each lives on the thread that
    /// opened it.)
    ///
    /// # Errors
    /// The thread cannot be started, or [`ManagedOutput::open`] failed.
    pub fn start(
        config: OutputConfig,
        clock: crate::runtime::Clock,
        limits: WriteLimits,
    ) -> anyhow::Result<OutputWorker> {
        let name = kind(&config);
        Self::start_with(clock, limits, name, move |now| {
            ManagedOutput::open(config, now)
        })
    }

    /// [`OutputWorker::start`] with the output made by `open` on the thread.
    fn start_with(
        clock: crate::runtime::Clock,
        limits: WriteLimits,
        name: &str,
        open: impl FnOnce(MonoTime) -> Result<ManagedOutput, LinkError> + Send + 'static,
    ) -> anyhow::Result<OutputWorker> {
        let shared = std::sync::Arc::new(WorkerShared {
            state: std::sync::Mutex::new(WorkerState {
                pending: None,
                busy_since: None,
                stale: 0,
                describe: format!("{name:?} (opening)"),
                health: Health::Down("opening".into()),
                detail: None,
                held_safe: false,
                stop: false,
                done: false,
            }),
            wake: std::sync::Condvar::new(),
        });
        let thread_shared = std::sync::Arc::clone(&shared);
        let (opened, result) = std::sync::mpsc::channel();
        std::thread::Builder::new()
            .name("rove-output".into())
            .spawn(move || {
                // Opening writes the safe state; a transient failure is retried from `work`.
                match open(clock.now()) {
                    Ok(mut output) => {
                        output.tick(clock.now());
                        thread_shared.publish(&output);
                        let _ = opened.send(Ok(()));
                        work(output, &thread_shared, clock, limits.max_age);
                    }
                    Err(e) => {
                        let _ = opened.send(Err(e.detail));
                    }
                }
            })?;
        match result.recv() {
            Ok(Ok(())) => Ok(OutputWorker {
                shared,
                clock,
                limits,
            }),
            Ok(Err(detail)) => Err(anyhow::anyhow!("output adapter: {detail}")),
            Err(_) => Err(anyhow::anyhow!(
                "output adapter: its thread ended while opening"
            )),
        }
    }

    /// Drives `setpoint` (decided at `now`) as soon as the device is free, unless a newer
    /// command comes first.
    pub fn apply(&self, now: MonoTime, setpoint: Setpoint) {
        self.hand_over(Command::Apply(now, setpoint));
    }

    /// Puts the outputs in the safe state as soon as the device is free.
    pub fn safe_state(&self) {
        self.hand_over(Command::Safe);
    }

    fn hand_over(&self, command: Command) {
        self.shared.lock().pending = Some(command);
        self.shared.wake.notify_all();
    }

    /// The output as the thread last saw it, and whether a device call is hung.
    pub fn report(&self) -> OutputReport {
        let now = self.clock.now();
        let state = self.shared.lock();
        let running = state.busy_since.map(|since| now.saturating_since(since));
        OutputReport {
            describe: state.describe.clone(),
            health: state.health.clone(),
            detail: state.detail.clone(),
            hung: running.filter(|r| *r > self.limits.deadline),
            stale: state.stale,
            held_safe: state.held_safe,
        }
    }

    /// Puts the outputs in the safe state and stops the thread, waiting at most `wait` for the
    /// device. `false` if the device did not return in time (the thread is left blocked; the
    /// process may still exit, and systemd's `rove failsafe` tries again).
    pub fn stop(self, wait: Duration) -> bool {
        let mut state = self.shared.lock();
        state.pending = Some(Command::Safe);
        state.stop = true;
        self.shared.wake.notify_all();
        let (state, _) = (self.shared.wake)
            .wait_timeout_while(state, wait, |s| !s.done)
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        state.done
    }
}

/// The output thread: takes the newest command, or wakes for the output's own deadline (end
/// of a hold, a keep-alive, a reopen), and publishes how the output is after each round.
fn work(
    mut output: ManagedOutput,
    shared: &WorkerShared,
    clock: crate::runtime::Clock,
    max_age: Duration,
) {
    let mut state = shared.lock();
    loop {
        while state.pending.is_none() && !state.stop {
            let now = clock.now();
            state = match output.next_deadline() {
                Some(due) if due <= now => break,
                Some(due) => (shared.wake)
                    .wait_timeout(state, due.saturating_since(now))
                    .map(|(s, _)| s)
                    .unwrap_or_else(|e| e.into_inner().0),
                None => (shared.wake)
                    .wait(state)
                    .unwrap_or_else(std::sync::PoisonError::into_inner),
            };
        }
        let (command, stop) = (state.pending.take(), state.stop);
        let now = clock.now();
        let command = match command {
            Some(Command::Apply(at, _)) if now.saturating_since(at) > max_age => {
                state.stale += 1;
                None
            }
            command => command,
        };
        state.busy_since = Some(now);
        drop(state);
        match command {
            Some(Command::Apply(_, setpoint)) => output.apply(now, &setpoint),
            Some(Command::Safe) => output.safe_state(now),
            None => {}
        }
        output.tick(clock.now());
        shared.publish(&output);
        state = shared.lock();
        state.busy_since = None;
        if stop && state.pending.is_none() {
            // Closed before saying done: an adapter's drop finishes its stop (MAVLink waits
            // for the autopilot to confirm the safe mode before it closes the link).
            drop(state);
            drop(output);
            let mut state = shared.lock();
            state.done = true;
            shared.wake.notify_all();
            return;
        }
    }
}

/// The adapter's name as `[output] adapter` spells it.
pub(crate) fn kind(config: &OutputConfig) -> &'static str {
    match config {
        OutputConfig::Sim => "sim",
        OutputConfig::Pwm(_) => "pwm",
        OutputConfig::Eyedrive(_) => "eyedrive",
        OutputConfig::Naza(_) => "naza",
        OutputConfig::Mavlink(_) => "mavlink",
        OutputConfig::Can(_) => "can",
    }
}

/// Gives a MAVLink output the file where its link keeps what it learns about the autopilot
/// (its address and ids), in the [`crate::runtime::runtime_dir`]: `rove failsafe` for the same
/// vehicle reads it and addresses the autopilot at once. Other outputs need nothing.
pub fn keep_learned(config: &mut OutputConfig, vehicle_id: i64) {
    if let OutputConfig::Mavlink(c) = config {
        c.memory = crate::runtime::runtime_dir()
            .map(|dir| dir.join(format!("vehicle-{vehicle_id}-mavlink")));
    }
}

/// `rove failsafe`: opens the configured outputs (which writes their safe state), writes it once
/// more, and closes them (the adapters write it again on drop). For systemd's `ExecStopPost`.
///
/// # Errors
/// The outputs cannot be opened or written.
pub fn failsafe(config: &OutputConfig) -> Result<String, LinkError> {
    if let OutputConfig::Mavlink(c) = config {
        // An autopilot must be found first, and its safe mode confirmed.
        return rove_mavlink::failsafe(c);
    }
    let now = MonoTime::ZERO;
    let mut adapter = open(config, now)?;
    adapter.safe_state(now)?;
    Ok(adapter.describe())
}

#[cfg(test)]
mod tests {
    use super::*;
    use rove_core::msg::{Mode, MovementCommand};
    use std::sync::{Arc, Mutex};

    /// Records its calls; the first keep-alive fails (a link still connecting).
    #[derive(Debug)]
    struct Flaky(Arc<Mutex<Vec<&'static str>>>);

    impl OutputAdapter for Flaky {
        fn describe(&self) -> String {
            "flaky".into()
        }
        fn apply(&mut self, _: MonoTime, _: &Setpoint) -> Result<(), LinkError> {
            self.0
                .lock()
                .map_err(|_| LinkError::fatal("poisoned"))?
                .push("apply");
            Ok(())
        }
        fn safe_state(&mut self, _: MonoTime) -> Result<(), LinkError> {
            self.0
                .lock()
                .map_err(|_| LinkError::fatal("poisoned"))?
                .push("safe");
            Ok(())
        }
        fn keepalive_period(&self) -> Option<Duration> {
            Some(Duration::from_secs(10))
        }
        fn keepalive(&mut self, _: MonoTime) -> Result<(), LinkError> {
            let mut calls = self.0.lock().map_err(|_| LinkError::fatal("poisoned"))?;
            calls.push("keepalive");
            if calls.len() == 1 {
                return Err(LinkError::transient("not connected (connecting)"));
            }
            Ok(())
        }
        fn health(&self) -> Health {
            Health::Ok
        }
    }

    /// Records the throttle of every apply (and `i16::MIN` for a safe state); every call waits
    /// while the gate is shut, as a blocked device write would.
    #[derive(Debug)]
    struct Gated {
        calls: Arc<Mutex<Vec<i16>>>,
        gate: Arc<(Mutex<bool>, std::sync::Condvar)>,
    }

    impl Gated {
        fn pass(&self, throttle: i16) -> Result<(), LinkError> {
            let (shut, opened) = &*self.gate;
            let guard = shut.lock().map_err(|_| LinkError::fatal("poisoned"))?;
            let _open = opened
                .wait_while(guard, |shut| *shut)
                .map_err(|_| LinkError::fatal("poisoned"))?;
            self.calls
                .lock()
                .map_err(|_| LinkError::fatal("poisoned"))?
                .push(throttle);
            Ok(())
        }
    }

    impl OutputAdapter for Gated {
        fn describe(&self) -> String {
            "gated".into()
        }
        fn apply(&mut self, _: MonoTime, setpoint: &Setpoint) -> Result<(), LinkError> {
            self.pass(setpoint.movement.throttle)
        }
        fn safe_state(&mut self, _: MonoTime) -> Result<(), LinkError> {
            self.pass(i16::MIN)
        }
        fn health(&self) -> Health {
            Health::Ok
        }
    }

    /// An output thread over a [`Gated`] adapter: deadline 20 ms, max age 1 s.
    fn gated_worker(
        clock: crate::runtime::Clock,
        calls: &Arc<Mutex<Vec<i16>>>,
        gate: &Arc<(Mutex<bool>, std::sync::Condvar)>,
    ) -> OutputWorker {
        let adapter = Gated {
            calls: Arc::clone(calls),
            gate: Arc::clone(gate),
        };
        let limits = WriteLimits {
            deadline: Duration::from_millis(20),
            max_age: Duration::from_secs(1),
        };
        OutputWorker::start_with(clock, limits, "gated", move |_| {
            Ok(ManagedOutput {
                config: OutputConfig::Sim,
                adapter: Some(Box::new(adapter)),
                hold_until: None,
                next_keepalive: None,
                last_error: None,
            })
        })
        .expect("worker")
    }

    fn throttle(t: i16) -> Setpoint {
        Setpoint {
            movement: MovementCommand {
                throttle: t,
                ..MovementCommand::CENTRED
            },
            mode: Mode::Manual,
        }
    }

    fn shut(gate: &(Mutex<bool>, std::sync::Condvar), value: bool) {
        *gate.0.lock().expect("gate") = value;
        gate.1.notify_all();
    }

    #[test]
    fn a_blocked_device_call_never_blocks_the_loop_and_only_the_newest_command_follows() {
        let calls = Arc::new(Mutex::new(Vec::new()));
        let gate = Arc::new((Mutex::new(false), std::sync::Condvar::new()));
        // A clock already 10 s old, so that a command decided at 0 is stale.
        let clock =
            crate::runtime::Clock::since(std::time::Instant::now() - Duration::from_secs(10));
        let worker = gated_worker(clock, &calls, &gate);
        let recorded = || calls.lock().expect("calls").clone();
        worker.apply(clock.now(), throttle(1));
        rove_testkit::eventually("the first apply", || match recorded()[..] {
            [1] => Ok(()),
            ref other => Err(format!("{other:?}")),
        });
        assert_eq!(worker.report().hung, None);

        // The device blocks: the call is reported hung once past the deadline, and handing
        // over commands meanwhile does not wait for it.
        shut(&gate, true);
        worker.apply(clock.now(), throttle(2));
        rove_testkit::eventually("the call reported hung", || {
            worker.report().hung.ok_or("not hung yet")
        });
        for t in 3..=50 {
            worker.apply(clock.now(), throttle(t));
        }
        shut(&gate, false);
        // Only the newest of the commands that queued up is written.
        rove_testkit::eventually("the newest command", || match recorded()[..] {
            [1, 2, 50] => Ok(()),
            ref other => Err(format!("{other:?}")),
        });
        rove_testkit::eventually("hung no more", || match worker.report().hung {
            None => Ok(()),
            Some(h) => Err(format!("{h:?}")),
        });

        // A command older than max_age when the device is free is not written; a safe state
        // always is.
        worker.apply(MonoTime::ZERO, throttle(99));
        rove_testkit::eventually("99 skipped", || match worker.report().stale {
            1 => Ok(()),
            n => Err(format!("{n} stale")),
        });
        worker.safe_state();
        rove_testkit::eventually("the safe state", || match recorded()[..] {
            [1, 2, 50, i16::MIN] => Ok(()),
            ref other => Err(format!("{other:?}")),
        });
        shut(&gate, true);
        worker.apply(clock.now(), throttle(7));
        rove_testkit::eventually("7 taken", || worker.report().hung.ok_or("not taken yet"));
        worker.apply(MonoTime::ZERO, throttle(98));
        shut(&gate, false);
        rove_testkit::eventually("98 skipped", || match worker.report().stale {
            2 => Ok(()),
            n => Err(format!("{n} stale")),
        });
        worker.apply(clock.now(), throttle(8));
        rove_testkit::eventually("the fresh ones", || match recorded()[..] {
            [1, 2, 50, i16::MIN, 7, 8] => Ok(()),
            ref other => Err(format!("{other:?}")),
        });
        assert!(
            worker.stop(Duration::from_secs(10)),
            "a free device stops at once"
        );
        assert_eq!(
            recorded().last(),
            Some(&i16::MIN),
            "stopping writes the safe state"
        );
    }

    #[test]
    fn stopping_gives_up_on_a_device_that_does_not_return() {
        let gate = Arc::new((Mutex::new(true), std::sync::Condvar::new()));
        let clock = crate::runtime::Clock::start();
        let worker = gated_worker(clock, &Arc::new(Mutex::new(Vec::new())), &gate);
        worker.apply(clock.now(), throttle(5));
        rove_testkit::eventually("hung", || worker.report().hung.ok_or("not hung yet"));
        assert!(!worker.stop(Duration::from_millis(50)));
        shut(&gate, false);
    }

    /// Regression (against ArduPilot SITL): a hold that ends in the same loop turn as the first command must not put the
    /// adapter, already driving, in its safe state.
    #[test]
    fn r20_a_successful_apply_ends_the_hold() {
        let calls = Arc::new(Mutex::new(Vec::new()));
        let mut out = ManagedOutput {
            config: OutputConfig::Sim,
            adapter: Some(Box::new(Flaky(Arc::clone(&calls)))),
            hold_until: None,
            next_keepalive: None,
            last_error: None,
        };
        let t0 = MonoTime::ZERO;
        out.tick(t0); // the keep-alive fails: held safe for RETRY
        assert_eq!(out.next_deadline(), Some(t0 + RETRY));
        let sp = Setpoint {
            movement: MovementCommand::CENTRED,
            mode: Mode::Manual,
        };
        out.apply(t0 + RETRY / 2, &sp);
        // The first command arrives as the hold ends, before the loop's tick for its end.
        let end = t0 + RETRY;
        out.apply(end, &sp);
        out.tick(end);
        let calls = calls.lock().map(|c| c.clone()).unwrap_or_default();
        assert_eq!(
            calls,
            ["keepalive", "apply"],
            "held while holding, then driving with no safe state after it"
        );
        assert_eq!(out.health(), Health::Ok);
    }
}
