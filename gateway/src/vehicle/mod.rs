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
//! - this file: [`Options`], [`run`] (start, the `select!` loop, the stop), decisions carried
//!   out.
//! - `intake.rs`: ControlCommand samples → arbiter events (strengths, freshness, batching).
//! - `report.rs`: VehicleStatus, the `STATUS=` line, the hung-output and not-believed watches.
//! - `hooks.rs`: the SIGUSR1 stall test hook and the output record (`--record`).
//!
//! Test hook: with the hidden `--test-stall-on-sigusr1 MS`, SIGUSR1 blocks this loop (the
//! whole thread) for MS milliseconds, the way a hung device write would, after saying so in
//! `STATUS=`. The sd_notify test uses it to see keep-alives stop. Without the option SIGUSR1
//! keeps its default action (the process ends; ExecStopPost makes the outputs safe).

mod hooks;
mod intake;
mod report;

use crate::config::VehicleConfig;
use crate::dds::{self, Discovery, KeyedDeviceInfo, Node};
use crate::output::{OutputWorker, WriteLimits};
use crate::runtime::{Clock, RateLimited, sleep_until};
use crate::sdnotify::Notifier;
use futures::{FutureExt, StreamExt};
use hooks::{OutputLog, StallHook};
use intake::{Intake, MAX_BATCH};
use report::{HungWatch, StatusWriter, Suspects, status_line};
use rove_core::arbiter::{Arbiter, Decision, Event, Output, Owner};
use rove_core::msg::DeviceType;
use rustdds::StatusEvented;
use rustdds::with_key::Sample;
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

/// The vehicle as its loop holds it: the arbiter, the output, and what it tells.
struct Vehicle {
    me: i64,
    clock: Clock,
    node: Node,
    arbiter: Arbiter,
    output: OutputWorker,
    log: Option<OutputLog>,
    status_writer: StatusWriter,
    suspects: Suspects,
    hung: HungWatch,
    notify: Notifier,
    /// The `STATUS=` line last sent.
    shown: String,
    intake: Intake,
    malformed: RateLimited,
}

/// Runs the vehicle role on `clock` until `shutdown` completes.
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
    let mut vehicle = Vehicle::start(&config, &options, clock)?;
    let mut readers = Readers::open(&vehicle.node.domain, vehicle.me)?;
    let result = vehicle.run(&config, &options, &mut readers, shutdown).await;
    vehicle.stop();
    // Only now: deleting a reader is announced to every peer; the stop (outputs safe,
    // DeviceInfo) goes first.
    drop(readers);
    result
}

/// The vehicle's DDS readers, kept until it has stopped.
struct Readers {
    commands: rustdds::with_key::DataReaderStream<dds::KeyedControlCommand>,
    requests: rustdds::no_key::DataReaderStream<rove_core::msg::RequestControl>,
    infos: rustdds::with_key::DataReaderStream<KeyedDeviceInfo>,
}

impl Readers {
    fn open(domain: &dds::Domain, me: i64) -> anyhow::Result<Readers> {
        Ok(Readers {
            commands: domain.command_reader(me)?.async_sample_stream(),
            requests: domain.request_reader()?.async_sample_stream(),
            infos: domain.device_info_reader()?.async_sample_stream(),
        })
    }
}

impl Vehicle {
    /// Opens the output (which writes its safe state) before joining the domain.
    fn start(config: &VehicleConfig, options: &Options, clock: Clock) -> anyhow::Result<Vehicle> {
        let me = config.common.id;
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
        let node = Node::join(&config.common, DeviceType::Vehicle, false)?;
        let status_writer = StatusWriter::new(me, &node.domain);
        info!(
            config = %options.config_path.display(),
            device = me,
            name = %config.common.name,
            domain = config.common.domain_id,
            interfaces = ?config.common.interfaces,
            adapter = %output.report().describe,
            output_health = %output.report(),
            command_timeout_ms = config.arbiter.command_timeout.get().as_millis() as u64,
            watchdog_keepalive_ms = notify.watchdog_period().map(|p| p.as_millis() as u64),
            "vehicle started"
        );
        if config.access.is_open() {
            warn!(
                "no [access] in the config: this vehicle trusts every participant on its network \
                 (any operator id may drive it, at any strength inside the hierarchy)"
            );
        }
        let mut arbiter = Arbiter::new(me, config.arbiter).with_access(config.access.clone());
        arbiter.pin_own(node.participant);
        if let Some(certifier) = node.certifier.clone() {
            arbiter.certify(certifier);
        }
        Ok(Vehicle {
            me,
            clock,
            node,
            arbiter,
            output,
            log,
            status_writer,
            suspects: Suspects::default(),
            hung: HungWatch::new(config.output_hung_limit),
            notify,
            shown: String::new(),
            intake: Intake::new(me, config.arbiter.command_timeout.get()),
            malformed: RateLimited::new("malformed or unreadable RequestControl or DeviceInfo"),
        })
    }

    /// The loop: until `shutdown`, or a DDS stream ends (an error).
    async fn run(
        &mut self,
        config: &VehicleConfig,
        options: &Options,
        readers: &mut Readers,
        shutdown: impl std::future::Future<Output = ()>,
    ) -> anyhow::Result<()> {
        let Readers {
            commands,
            requests,
            infos,
        } = readers;
        let listener = self.node.domain.participant.status_listener();
        let mut status = listener.as_async_status_stream();
        self.node.publish(self.arbiter.controller_id());
        let mut heartbeat = tokio::time::interval(config.common.heartbeat);
        tokio::pin!(shutdown);
        let mut keepalive = self.notify.keepalive_timer();
        let mut stall = StallHook::new(options.stall_on_sigusr1)?;
        // Events of a batch of samples not yet given to the arbiter.
        let mut queued = std::collections::VecDeque::new();
        // The outputs are safe (or held safe while their device is reopened), the participant
        // is up and the signal handlers are in place: ready.
        let clock = self.clock;
        self.shown = status_line(&self.arbiter, &self.output.report(), clock.now());
        self.status_writer
            .update(&self.arbiter, &self.output.report());
        self.notify.ready(&self.shown);
        loop {
            let deadline = self.arbiter.next_deadline().map(|d| clock.instant(d));
            let event = tokio::select! {
                _ = &mut shutdown => break,
                sample = commands.next() => match sample {
                    Some(first) => {
                        // With what already queued behind it: only each writer's newest counts.
                        let mut batch = vec![first];
                        while batch.len() < MAX_BATCH
                            && let Some(Some(more)) = commands.next().now_or_never()
                        {
                            batch.push(more);
                        }
                        queued.extend(self.intake.events(&self.node.domain, &clock, batch));
                        queued.pop_front()
                    }
                    None => anyhow::bail!("ControlCommand stream ended"),
                },
                request = requests.next() => match request {
                    Some(Ok(sample)) => {
                        let sender = dds::sender(sample.sample_info());
                        Some(Event::from_request_control(self.me, sample.value(), sender))
                    }
                    Some(Err(e)) => { self.malformed.warn(&e); None }
                    None => anyhow::bail!("RequestControl stream ended"),
                },
                info = infos.next() => match info {
                    Some(Ok(sample)) => {
                        let sender = dds::sender(sample.sample_info());
                        match sample.into_value() {
                            Sample::Value(KeyedDeviceInfo(info)) => {
                                Some(Event::Heard { device: info.device_id, sender })
                            }
                            Sample::Dispose(_) => None,
                        }
                    }
                    Some(Err(e)) => { self.malformed.warn(&e); None }
                    None => anyhow::bail!("DeviceInfo stream ended"),
                },
                ev = status.next() => self.on_discovery(ev.as_ref().and_then(Discovery::of)),
                _ = heartbeat.tick() => { self.on_heartbeat(); None }
                // From this loop, so that a hung loop stops the keep-alives; and stopped while
                // the output has been hung past its limit, so that systemd restarts the unit.
                _ = keepalive.tick() => { self.on_keepalive(); None }
                stall_for = stall.requested() => {
                    warn!(stall_ms = stall_for.as_millis() as u64, "test hook: stalling the control loop");
                    self.notify.status("control loop stalled by the SIGUSR1 test hook");
                    // Blocking on purpose: this is the hang the watchdog is there to catch.
                    std::thread::sleep(stall_for);
                    self.notify.status(&self.shown);
                    None
                }
                _ = sleep_until(deadline) => Some(Event::Tick),
            };
            let mut next = event;
            while let Some(event) = next.take().or_else(|| queued.pop_front()) {
                self.decide(event);
            }
        }
        Ok(())
    }

    /// Discovery: strengths learnt, writers and participants gone.
    fn on_discovery(&mut self, discovery: Option<Discovery>) -> Option<Event> {
        match discovery? {
            Discovery::CommandWriter { guid, strength } => {
                self.intake.learn(guid, strength);
                None
            }
            Discovery::WriterLost { guid } => {
                self.intake.forget(guid);
                Some(Event::WriterGone {
                    writer: dds::writer_id(guid),
                })
            }
            Discovery::ParticipantLost { participant } => {
                Some(Event::ParticipantGone { participant })
            }
        }
    }

    /// Every heartbeat: DeviceInfo again, VehicleStatus and `STATUS=` if they changed.
    fn on_heartbeat(&mut self) {
        self.node.publish(self.arbiter.controller_id());
        let report = self.output.report();
        self.hung.observe(&report);
        self.status_writer.update(&self.arbiter, &report);
        let line = status_line(&self.arbiter, &report, self.clock.now());
        let line = self.hung.annotate(self.suspects.annotate(line));
        if line != self.shown {
            self.notify.status(&line);
            self.shown = line;
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
        let clock = self.clock;
        if tracing::enabled!(tracing::Level::TRACE) {
            tracing::trace!(wall_us = clock.wall_micros(), ?event, "event");
        }
        let decision = self.arbiter.step(clock.now(), event);
        let node = &self.node;
        carry_out(
            self.me,
            &decision,
            &self.output,
            self.log.as_mut(),
            &clock,
            &|id| node.publish(id),
        );
        if let Some(Output::Apply { setpoint, .. }) = decision.output {
            self.status_writer.mode = setpoint.mode;
        }
        if let Some(suspect) = decision.suspect {
            self.suspects.report(suspect);
        }
        if decision.owner_change.is_some() {
            let report = self.output.report();
            self.status_writer.update(&self.arbiter, &report);
            let line = status_line(&self.arbiter, &report, clock.now());
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
        self.node.publish(self.me);
        self.node.withdraw();
        self.status_writer.withdraw();
    }
}

/// How long stopping waits for the output's safe state.
const STOP_WAIT: Duration = Duration::from_millis(500);

fn carry_out(
    me: i64,
    decision: &Decision,
    output: &OutputWorker,
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
