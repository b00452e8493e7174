//! `rove vehicle`: DDS samples → arbiter → output adapter, with DeviceInfo publishing.
//!
//! One task, one `select!` loop: every input (command samples, disposals, discovery events,
//! RequestControl, timers) becomes an arbiter [`Event`]; every decision is carried out at once:
//! outputs handed to the output's own thread ([`OutputWorker`]: a device call that blocks never
//! stalls this loop), ownership changes to DeviceInfo (published in the same loop turn).
//! The loop sleeps until the arbiter's next deadline, so a silent owner is dropped exactly one
//! command timeout after its last sample, with no polling.
//!
//! Start: the adapter is put in its safe state before the participant joins; then systemd is
//! told `READY=1`. Stop (SIGTERM, SIGINT): systemd is told `STOPPING=1`, the arbiter's owner is
//! dropped, the adapter goes safe, DeviceInfo shows the failsafe, and the participant leaves the
//! domain cleanly.
//!
//! Under systemd (see [`crate::sdnotify`]): `STATUS=` names the owner, how many operators are
//! live and the output's health (or that it is hung), and is updated on every owner change and
//! every heartbeat; `WATCHDOG=1` keep-alives are sent by this loop itself, so a hung loop stops
//! them, and it stops them once the output has been hung past `[vehicle] output_hung_limit_ms`.
//!
//! Trust (docs/design.md §4b): every event carries the participant it came from; the arbiter
//! pins device ids to participants and believes only strengths inside the hierarchy (or the
//! `[access]` list). What it does not believe is logged (once per id and participant every
//! 5 s) and counted in `STATUS=`. The vehicle reads DeviceInfo too, so that every present
//! device's id is pinned to its participant before anyone else can claim it.
//!
//! # Layout
//! - this file: [`Options`], `Outputs`, [`run`] (start: output, then the network), the
//!   `select!` loop on injected edges (network, output, clock, notifier, shutdown), the stop.
//! - `net.rs`: the network edge (`Net`) and its DDS form: samples and discovery →
//!   arbiter events, DeviceInfo and VehicleStatus out.
//! - `intake.rs`: ControlCommand samples → arbiter events (strengths, freshness, batching).
//! - `report.rs`: VehicleStatus, the `STATUS=` line, the hung-output and not-believed watches.
//! - `hooks.rs`: the SIGUSR1 stall test hook and the output record (`--record`).
//! - `tests.rs`: the loop on a channel network and a recording output, on tokio's paused clock.
//!
//! Test hook: with the hidden `--test-stall-on-sigusr1 MS`, SIGUSR1 blocks this loop (the
//! whole thread) for MS milliseconds, the way a hung device write would, after saying so in
//! `STATUS=`. The sd_notify test uses it to see keep-alives stop. Without the option SIGUSR1
//! keeps its default action (the process ends; ExecStopPost makes the outputs safe).

mod hooks;
mod intake;
mod net;
mod report;
mod stations;
#[cfg(test)]
mod tests;

use crate::audit::Recorder;
use crate::config::VehicleConfig;
use crate::output::{OutputReport, OutputWorker, WriteLimits};
use crate::runtime::{Clock, sleep_until};
use crate::sdnotify::Notifier;
use hooks::{OutputLog, StallHook};
use net::{Dds, Net};
use report::{HungWatch, StatusWatch, Suspects, status_line};
use rove_core::MonoTime;
use rove_core::arbiter::{Arbiter, Decision, Event, Output, Owner, Setpoint};
use rove_core::audit::Why;
use rove_core::msg::DeviceId;
use std::path::PathBuf;
use std::time::Duration;
use tracing::{info, warn};

/// How `rove vehicle` was started, beyond its config.
#[derive(Debug, Clone, Default)]
pub struct Options {
    /// The config file, for the start-up line.
    pub config_path: PathBuf,
    /// Append every output to this JSON-lines file.
    pub record: Option<PathBuf>,
    /// Test hook: SIGUSR1 stalls the loop this long (see the module docs).
    pub stall_on_sigusr1: Option<Duration>,
}

/// What the vehicle loop needs of its output: the output's own thread ([`OutputWorker`]) in
/// `rove vehicle`, a recorder in the loop's tests.
pub(crate) trait Outputs {
    /// Drive with `setpoint`, decided at `now`.
    fn apply(&self, now: MonoTime, setpoint: Setpoint);
    /// Go safe.
    fn safe_state(&self);
    /// How the output is.
    fn report(&self) -> OutputReport;
    /// Tells the output what the vehicle says of itself (VehicleStatus, on change).
    fn status(&self, _status: &rove_core::msg::VehicleStatus) {}
    /// Safe state, then stop, waiting at most `wait`; `false` if the device did not return.
    fn stop(self, wait: Duration) -> bool;
}

impl Outputs for OutputWorker {
    fn apply(&self, now: MonoTime, setpoint: Setpoint) {
        OutputWorker::apply(self, now, setpoint);
    }
    fn safe_state(&self) {
        OutputWorker::safe_state(self);
    }
    fn report(&self) -> OutputReport {
        OutputWorker::report(self)
    }
    fn status(&self, status: &rove_core::msg::VehicleStatus) {
        OutputWorker::status(self, status);
    }
    fn stop(self, wait: Duration) -> bool {
        OutputWorker::stop(self, wait)
    }
}

/// The vehicle as its loop holds it: the arbiter, its edges, and what it tells.
struct Vehicle<N, O> {
    me: DeviceId,
    clock: Clock,
    net: N,
    arbiter: Arbiter,
    output: O,
    log: Option<OutputLog>,
    status: StatusWatch,
    suspects: Suspects,
    hung: HungWatch,
    notify: Notifier,
    /// The `STATUS=` line last sent.
    shown: String,
    heartbeat: Duration,
    stall: Option<Duration>,
    /// Who drove, when and why ([`crate::audit`]).
    audit: Recorder,
    /// Whether the output was down at the last look: the audit records each change.
    output_down: bool,
}

/// Runs the vehicle role on `clock` until `shutdown` completes: opens the output (which
/// writes its safe state) before joining the domain, then the loop, then the stop.
///
/// # Errors
/// The participant, a topic, a reader or writer cannot be created, the output record file
/// cannot be opened, or the SIGUSR1 test hook's handler cannot be installed.
pub async fn run(
    config: VehicleConfig,
    options: Options,
    clock: Clock,
    shutdown: impl std::future::Future<Output = ()>,
) -> anyhow::Result<()> {
    let notify = Notifier::from_env();
    let limits = WriteLimits {
        deadline: config.output_deadline,
        max_age: config.arbiter.command_timeout.get(),
    };
    // Opening writes the safe state; a transient failure is retried by the output's thread.
    let output = OutputWorker::start(config.output.clone(), clock, limits)?;
    let mut log = options
        .record
        .as_deref()
        .map(OutputLog::create)
        .transpose()?;
    if let Some(log) = log.as_mut() {
        log.record(&clock, "safe", Owner::Failsafe, None);
    }
    let net = Dds::join(&config)?;
    let audit = Recorder::open(config.common.id, net.certifier());
    info!(
        audit = ?audit.path(),
        config = %options.config_path.display(),
        device = config.common.id,
        name = %config.common.name,
        domain = config.common.domain_id,
        interfaces = ?config.common.interfaces,
        adapter = %output.report().describe,
        output_health = %output.report(),
        command_timeout_ms = config.arbiter.command_timeout.get().as_millis() as u64,
        watchdog_keepalive_ms = notify.watchdog_period().map(|p| p.as_millis() as u64),
        "vehicle started"
    );
    let stall = options.stall_on_sigusr1;
    let stations = stations::Stations::start(&config, config.output.spec().hosted())?;
    let mut vehicle = Vehicle::new(&config, stall, clock, net, output, log, notify);
    vehicle.audit = audit;
    vehicle.audit(&Owner::Failsafe, Why::Start);
    if config.access.is_open() {
        warn!(
            "no [access] in the config: this vehicle trusts every participant on its network \
             (any operator id may drive it, at any strength inside the hierarchy)"
        );
    }
    let result = vehicle.serve(shutdown).await;
    stations.stop().await;
    result
}

impl<N: Net, O: Outputs> Vehicle<N, O> {
    /// The vehicle on its edges; `output` has written its safe state (and `log` recorded it).
    fn new(
        config: &VehicleConfig,
        stall: Option<Duration>,
        clock: Clock,
        net: N,
        output: O,
        log: Option<OutputLog>,
        notify: Notifier,
    ) -> Vehicle<N, O> {
        let me = config.common.id;
        let mut arbiter = Arbiter::new(me, config.arbiter).with_access(config.access.clone());
        arbiter.pin_own(net.participant());
        if let Some(certifier) = net.certifier() {
            arbiter.certify(certifier);
        }
        Vehicle {
            me,
            clock,
            net,
            arbiter,
            output,
            log,
            status: StatusWatch::new(me, config.battery_low_pct),
            suspects: Suspects::default(),
            hung: HungWatch::new(config.output_hung_limit),
            notify,
            shown: String::new(),
            heartbeat: config.common.heartbeat,
            stall,
            audit: Recorder::none(me),
            output_down: false,
        }
    }

    /// Appends who drives now and why to the audit log.
    fn audit(&mut self, owner: &Owner, why: Why) {
        self.audit.record(self.clock.wall_micros(), owner, why);
    }

    /// The loop until `shutdown` (or the network is gone: an error), then the stop.
    async fn serve(
        mut self,
        shutdown: impl std::future::Future<Output = ()>,
    ) -> anyhow::Result<()> {
        let result = self.control_loop(shutdown).await;
        self.stop();
        result
    }

    /// The loop: until `shutdown`, or the network is gone (an error).
    async fn control_loop(
        &mut self,
        shutdown: impl std::future::Future<Output = ()>,
    ) -> anyhow::Result<()> {
        /// What woke the loop.
        enum Wake {
            Heard(anyhow::Result<Vec<Event>>),
            Heartbeat,
            Keepalive,
            Stall(Duration),
            Deadline,
            Shutdown,
        }
        self.net.publish_owner(self.arbiter.controller_id());
        let mut heartbeat = tokio::time::interval(self.heartbeat);
        tokio::pin!(shutdown);
        let mut keepalive = self.notify.keepalive_timer();
        let mut stall = StallHook::new(self.stall)?;
        // The outputs are safe (or held safe while their device is reopened), the participant
        // is up and the signal handlers are in place: ready.
        let clock = self.clock;
        // Down while it opens is not an event: the start's entry says the failsafe holds.
        self.output_down = is_down(&self.output.report());
        self.shown = status_line(&self.arbiter, &self.output.report(), clock.now());
        self.publish_status();
        self.notify.ready(&self.shown);
        loop {
            let deadline = self.arbiter.next_deadline().map(|d| clock.instant(d));
            // In this order when several are ready: what was heard before the deadline, so
            // that a loop woken late (a busy machine) takes the owner's samples waiting for it
            // before it times the owner out.
            let wake = tokio::select! {
                biased;
                () = &mut shutdown => Wake::Shutdown,
                // From this loop, so that a hung loop stops the keep-alives; and stopped while
                // the output has been hung past its limit, so that systemd restarts the unit.
                _ = keepalive.tick() => Wake::Keepalive,
                _ = heartbeat.tick() => Wake::Heartbeat,
                stall_for = stall.requested() => Wake::Stall(stall_for),
                heard = self.net.heard(&clock) => Wake::Heard(heard),
                () = sleep_until(deadline) => Wake::Deadline,
            };
            match wake {
                Wake::Shutdown => break,
                Wake::Heard(events) => self.decide_all(events?),
                Wake::Heartbeat => self.on_heartbeat(),
                Wake::Keepalive => self.on_keepalive(),
                Wake::Stall(stall_for) => {
                    warn!(
                        stall_ms = stall_for.as_millis() as u64,
                        "test hook: stalling the control loop"
                    );
                    self.notify
                        .status("control loop stalled by the SIGUSR1 test hook");
                    // Blocking on purpose: this is the hang the watchdog is there to catch.
                    std::thread::sleep(stall_for);
                    self.notify.status(&self.shown);
                }
                Wake::Deadline => self.decide(Event::Tick),
            }
        }
        Ok(())
    }

    /// VehicleStatus, if it changed.
    fn publish_status(&mut self) {
        let report = self.output.report();
        let now = self.clock.now();
        if let Some(status) = self.status.changed(&self.arbiter, &report, now) {
            self.net.publish_status(status);
            self.output.status(status);
        }
    }

    /// Every heartbeat: DeviceInfo again, VehicleStatus and `STATUS=` if they changed.
    fn on_heartbeat(&mut self) {
        self.audit.tick();
        self.net.publish_owner(self.arbiter.controller_id());
        let report = self.output.report();
        self.hung.observe(&report);
        self.audit_output(&report);
        self.publish_status();
        let line = status_line(&self.arbiter, &report, self.clock.now());
        let line = self.hung.annotate(self.suspects.annotate(line));
        if line != self.shown {
            self.notify.status(&line);
            self.shown = line;
        }
    }

    /// Records in the audit an output that went down (the vehicle is held safe: the failsafe
    /// holds it, whoever owns) or came back (the owner drives again).
    fn audit_output(&mut self, report: &crate::output::OutputReport) {
        let down = is_down(report);
        if down != self.output_down {
            self.output_down = down;
            match down {
                true => self.audit(&Owner::Failsafe, Why::OutputDown),
                false => self.audit(&self.arbiter.owner(), Why::OutputBack),
            }
        }
    }

    /// The watchdog keep-alive, unless the output has been hung past its limit.
    fn on_keepalive(&mut self) {
        if self.hung.keepalive(&self.output.report()) {
            self.notify.keepalive();
        } else if !self.shown.ends_with(HungWatch::STOPPED) {
            self.shown = self.hung.annotate(std::mem::take(&mut self.shown));
            self.notify.status(&self.shown);
        }
    }

    /// One event to the arbiter, and its decision carried out at once.
    fn decide(&mut self, event: Event) {
        self.trace(std::slice::from_ref(&event));
        let decision = self.arbiter.step(self.clock.now(), event);
        self.act(decision);
    }

    /// What one read heard: each run of command samples and releases is stepped as one batch
    /// (taken at one instant, so that the owner's sample behind a weaker one's keeps the
    /// vehicle: `Arbiter::step_batch`), anything else one by one.
    fn decide_all(&mut self, events: Vec<Event>) {
        for run in events.chunk_by(|a, b| is_command(a) && is_command(b)) {
            match run {
                [event] if !is_command(event) => self.decide(*event),
                batch => {
                    self.trace(batch);
                    for decision in self.arbiter.step_batch(self.clock.now(), batch) {
                        self.act(decision);
                    }
                }
            }
        }
    }

    /// The events, at TRACE, with the wall clock (the bench's timelines).
    fn trace(&self, events: &[Event]) {
        if tracing::enabled!(tracing::Level::TRACE) {
            let wall_us = self.clock.wall_micros();
            for event in events {
                tracing::trace!(wall_us, ?event, "event");
            }
        }
    }

    /// Acts on what the arbiter decided: outputs, DeviceInfo, the audit, `STATUS=`.
    fn act(&mut self, decision: Decision) {
        let clock = self.clock;
        let net = &self.net;
        apply_decision(
            self.me,
            &decision,
            &self.output,
            self.log.as_mut(),
            &clock,
            &|id| net.publish_owner(id),
        );
        if let Some(Output::Apply { setpoint, .. }) = decision.output {
            self.status.mode = setpoint.mode;
        }
        if let Some(suspect) = decision.suspect {
            self.suspects.report(suspect);
        }
        if let Some(change) = decision.owner_change {
            self.audit(&change.to, Why::of(change.reason));
        }
        if decision.owner_change.is_some() {
            self.publish_status();
            let line = status_line(&self.arbiter, &self.output.report(), clock.now());
            self.shown = self.hung.annotate(self.suspects.annotate(line));
            self.notify.status(&self.shown);
        }
    }

    /// The stop: outputs safe first, then tell everyone, then leave.
    fn stop(mut self) {
        info!("vehicle stopping: outputs to safe state");
        self.notify.stopping("stopping: outputs to safe state");
        if !self.output.stop(STOP_WAIT) {
            warn!(
                wait_ms = STOP_WAIT.as_millis() as u64,
                "the output did not return in time for the safe state (hung device): leaving it \
                 to `rove failsafe`"
            );
        }
        if let Some(log) = self.log.as_mut() {
            log.record(&self.clock, "safe", Owner::Failsafe, None);
        }
        self.audit
            .record(self.clock.wall_micros(), &Owner::Failsafe, Why::Stop);
        self.audit.sync();
        self.net.publish_owner(self.me);
        self.net.withdraw();
    }
}

/// A command stream's event: what one read of ControlCommand yields.
fn is_command(event: &Event) -> bool {
    matches!(event, Event::Sample { .. } | Event::Released { .. })
}

/// Whether the output's device failed (it is being reopened; a call that is only slow, hung,
/// is the watchdog's and `STATUS=`'s, not the audit's: on a busy machine it comes and goes).
fn is_down(report: &crate::output::OutputReport) -> bool {
    matches!(report.health, rove_core::adapter::Health::Down(_))
}

/// How long stopping waits for the output's safe state.
const STOP_WAIT: Duration = Duration::from_millis(500);

/// Carries out the arbiter's `decision` at once: publishes a new owner, writes the output (and
/// its log).
fn apply_decision(
    me: DeviceId,
    decision: &Decision,
    output: &impl Outputs,
    log: Option<&mut OutputLog>,
    clock: &Clock,
    publish: &impl Fn(i64),
) {
    if let Some(change) = decision.owner_change {
        info!(
            from = ?change.from.device(),
            to = ?change.to.device(),
            reason = %change.reason,
            "owner changed"
        );
        // Published in the same loop turn; the failsafe shows as the vehicle's own id.
        publish(change.to.device().unwrap_or(me));
    }
    let now = clock.now();
    match decision.output {
        Some(Output::Apply { by, setpoint, .. }) => {
            output.apply(now, setpoint);
            if let Some(log) = log {
                log.record(clock, "apply", Owner::Controller(by), Some(setpoint));
            }
        }
        Some(Output::SafeState { owner, .. }) => {
            output.safe_state();
            if let Some(log) = log {
                log.record(clock, "safe", owner, None);
            }
        }
        None => {}
    }
}
