//! The output on a thread of its own ([`OutputWorker`]), and what the control loop knows of it
//! ([`OutputReport`]).

use super::ManagedOutput;
use crate::config::OutputConfig;
use rove_core::MonoTime;
use rove_core::adapter::Health;
use rove_core::arbiter::Setpoint;
use rove_core::error::LinkError;
use std::time::Duration;

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
    /// What the device says of the vehicle (battery, autopilot), as of its last call.
    pub telemetry: rove_core::adapter::Telemetry,
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
    /// The newest VehicleStatus the adapter has not been told yet (apart from `pending`, so
    /// that a status never replaces a command).
    status: Option<rove_core::msg::VehicleStatus>,
    /// When the thread entered the device call in progress, if it is in one.
    busy_since: Option<MonoTime>,
    stale: u64,
    describe: String,
    health: Health,
    detail: Option<String>,
    held_safe: bool,
    telemetry: rove_core::adapter::Telemetry,
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
        state.telemetry = output.telemetry();
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
        let name = config.adapter();
        Self::start_with(clock, limits, name, move |now| {
            ManagedOutput::open(config, now)
        })
    }

    /// [`OutputWorker::start`] with the output made by `open` on the thread.
    pub(super) fn start_with(
        clock: crate::runtime::Clock,
        limits: WriteLimits,
        name: &str,
        open: impl FnOnce(MonoTime) -> Result<ManagedOutput, LinkError> + Send + 'static,
    ) -> anyhow::Result<OutputWorker> {
        let shared = std::sync::Arc::new(WorkerShared {
            state: std::sync::Mutex::new(WorkerState {
                pending: None,
                status: None,
                busy_since: None,
                stale: 0,
                describe: format!("{name:?} (opening)"),
                health: Health::Down("opening".into()),
                detail: None,
                held_safe: false,
                telemetry: Default::default(),
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

    /// Tells the adapter what the vehicle says of itself, as soon as the device is free.
    pub fn status(&self, status: &rove_core::msg::VehicleStatus) {
        self.shared.lock().status = Some(status.clone());
        self.shared.wake.notify_all();
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
            telemetry: state.telemetry.clone(),
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
        while state.pending.is_none() && state.status.is_none() && !state.stop {
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
        let (command, status, stop) = (state.pending.take(), state.status.take(), state.stop);
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
        if let Some(status) = status {
            output.status(now, &status);
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
