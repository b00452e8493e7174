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
//! Test hook: with the hidden `--test-stall-on-sigusr1 MS`, SIGUSR1 blocks this loop (the
//! whole thread) for MS milliseconds, the way a hung device write would, after saying so in
//! `STATUS=`. The sd_notify test uses it to see keep-alives stop. Without the option SIGUSR1
//! keeps its default action (the process ends; ExecStopPost makes the outputs safe).

use crate::config::VehicleConfig;
use crate::dds::{self, Discovery, Domain, KeyedControlCommand, KeyedDeviceInfo, Node};
use crate::output::{OutputReport, OutputWorker, WriteLimits};
use crate::runtime::{Clock, JsonLines, RateLimited, sleep_until};
use crate::sdnotify::Notifier;
use futures::{FutureExt, StreamExt};
use rove_core::arbiter::{Arbiter, Decision, Event, Output, Owner, ParticipantId};
use rove_core::freshness::Freshness;
use rove_core::msg::{DeviceType, VehicleStatus};
use rove_core::trust::Suspect;
use rustdds::StatusEvented;
use rustdds::with_key::Sample;
use std::collections::HashMap;
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
    let me = config.common.id;
    let mut notify = Notifier::from_env();
    let record = options.record;
    let limits = WriteLimits {
        deadline: config.output_deadline,
        max_age: config.arbiter.command_timeout.get(),
    };
    // Opening writes the safe state; a transient failure is retried by the output's thread.
    let output = OutputWorker::start(config.output.clone(), clock, limits)?;
    let mut hung = HungWatch::new(config.output_hung_limit);
    let mut log = match &record {
        Some(path) => Some(OutputLog::create(path)?),
        None => None,
    };
    if let Some(log) = log.as_mut() {
        log.record(&clock, "safe", Owner::Failsafe, None);
    }

    let node = Node::join(&config.common, DeviceType::Vehicle, false)?;
    let domain = &node.domain;
    let mut status_writer = StatusWriter::new(me, domain);
    let commands = domain.command_reader(config.common.id)?;
    let requests = domain.request_reader()?;
    let infos = domain.device_info_reader()?;
    let listener = domain.participant.status_listener();
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
    let mut suspects = Suspects::default();
    let publish = |controller_id| node.publish(controller_id);
    publish(arbiter.controller_id());

    let mut commands = commands.async_sample_stream();
    let mut requests = requests.async_sample_stream();
    let mut infos = infos.async_sample_stream();
    let mut status = listener.as_async_status_stream();
    let mut heartbeat = tokio::time::interval(config.common.heartbeat);
    tokio::pin!(shutdown);
    let mut keepalive = notify.keepalive_timer();
    let mut stall = StallHook::new(options.stall_on_sigusr1)?;
    let mut malformed = RateLimited::new("malformed or unreadable RequestControl or DeviceInfo");
    let mut intake = Intake::new(me, config.arbiter.command_timeout.get());
    // Events of a batch of samples not yet given to the arbiter.
    let mut queued = std::collections::VecDeque::new();
    // The outputs are safe (or held safe while their device is reopened), the participant is
    // up and the signal handlers are in place: ready.
    let mut shown = status_line(&arbiter, &output.report(), clock.now());
    status_writer.update(&arbiter, &output.report());
    notify.ready(&shown);

    loop {
        let deadline = arbiter.next_deadline().map(|d| clock.instant(d));
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
                    queued.extend(intake.events(domain, &clock, batch));
                    queued.pop_front()
                }
                None => anyhow::bail!("ControlCommand stream ended"),
            },
            request = requests.next() => match request {
                Some(Ok(sample)) => {
                    let sender = dds::sender(sample.sample_info());
                    Some(Event::from_request_control(me, sample.value(), sender))
                }
                Some(Err(e)) => { malformed.warn(&e); None }
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
                Some(Err(e)) => { malformed.warn(&e); None }
                None => anyhow::bail!("DeviceInfo stream ended"),
            },
            ev = status.next() => match ev.as_ref().and_then(Discovery::of) {
                Some(Discovery::CommandWriter { guid, strength }) => {
                    intake.learn(guid, strength);
                    None
                }
                Some(Discovery::WriterLost { guid }) => {
                    intake.forget(guid);
                    Some(Event::WriterGone { writer: dds::writer_id(guid) })
                }
                Some(Discovery::ParticipantLost { participant }) => {
                    Some(Event::ParticipantGone { participant })
                }
                None => None,
            },
            _ = heartbeat.tick() => {
                publish(arbiter.controller_id());
                let report = output.report();
                hung.observe(&report);
                status_writer.update(&arbiter, &report);
                let line = hung.annotate(suspects.annotate(status_line(&arbiter, &report, clock.now())));
                if line != shown {
                    notify.status(&line);
                    shown = line;
                }
                None
            }
            // From this loop, so that a hung loop stops the keep-alives; and stopped while the
            // output has been hung past its limit, so that systemd restarts the unit.
            _ = keepalive.tick() => {
                if hung.keepalive(&output.report()) {
                    notify.keepalive();
                } else if !shown.ends_with(HungWatch::STOPPED) {
                    shown = hung.annotate(shown);
                    notify.status(&shown);
                }
                None
            }
            stall_for = stall.requested() => {
                warn!(stall_ms = stall_for.as_millis() as u64, "test hook: stalling the control loop");
                notify.status("control loop stalled by the SIGUSR1 test hook");
                // Blocking on purpose: this is the hang the watchdog is there to catch.
                std::thread::sleep(stall_for);
                notify.status(&shown);
                None
            }
            _ = sleep_until(deadline) => Some(Event::Tick),
        };
        let mut next = event;
        while let Some(event) = next.take().or_else(|| queued.pop_front()) {
            if tracing::enabled!(tracing::Level::TRACE) {
                tracing::trace!(wall_us = clock.wall_micros(), ?event, "event");
            }
            let now = clock.now();
            let decision = arbiter.step(now, event);
            carry_out(me, &decision, &output, log.as_mut(), &clock, &publish);
            if let Some(Output::Apply { setpoint, .. }) = decision.output {
                status_writer.mode = setpoint.mode;
            }
            if let Some(suspect) = decision.suspect {
                suspects.report(suspect);
            }
            if decision.owner_change.is_some() {
                let report = output.report();
                status_writer.update(&arbiter, &report);
                let line = status_line(&arbiter, &report, clock.now());
                shown = hung.annotate(suspects.annotate(line));
                notify.status(&shown);
            }
        }
    }

    // Shutdown: outputs safe first, then tell everyone, then leave.
    info!("vehicle stopping: outputs to safe state");
    notify.stopping("stopping: outputs to safe state");
    if !output.stop(STOP_WAIT) {
        warn!(
            wait_ms = STOP_WAIT.as_millis() as u64,
            "the output did not return in time for the safe state (hung device): leaving it to \
             `rove failsafe`"
        );
    }
    if let Some(log) = log.as_mut() {
        log.record(&clock, "safe", Owner::Failsafe, None);
    }
    publish(me);
    node.withdraw();
    status_writer.withdraw();
    Ok(())
}

/// The vehicle's VehicleStatus: published when it changes (checked on every owner change and
/// every heartbeat), withdrawn on stop. Without a writer (a secured fleet whose permissions
/// predate the topic) the vehicle runs on and says so once.
struct StatusWriter {
    me: i64,
    writer: Option<rustdds::with_key::DataWriterCdr<dds::KeyedVehicleStatus>>,
    /// The mode last applied.
    mode: rove_core::msg::Mode,
    last: Option<VehicleStatus>,
}

impl StatusWriter {
    fn new(me: i64, domain: &Domain) -> StatusWriter {
        let writer = domain
            .vehicle_status_writer()
            .map_err(|e| warn!(cause = %format!("{e:#}"), "no VehicleStatus: operators will not see the output's health"))
            .ok();
        StatusWriter {
            me,
            writer,
            mode: rove_core::msg::Mode::Manual,
            last: None,
        }
    }

    fn update(&mut self, arbiter: &Arbiter, report: &OutputReport) {
        let status = vehicle_status(self.me, arbiter, self.mode, report);
        if self.last.as_ref() == Some(&status) {
            return;
        }
        if let Some(writer) = &self.writer
            && let Err(e) = writer.write(dds::KeyedVehicleStatus(status.clone()), None)
        {
            warn!(cause = ?e, "cannot publish VehicleStatus");
        }
        self.last = Some(status);
    }

    fn withdraw(&self) {
        if let Some(writer) = &self.writer
            && let Err(e) = writer.dispose(&self.me, None)
        {
            warn!(cause = ?e, "cannot withdraw VehicleStatus");
        }
    }
}

/// What VehicleStatus says: the owner, the mode last applied, whether the outputs are safe
/// (the failsafe owns them, the output is down, or the adapter holds them safe itself: an
/// autopilot that refused the owner's mode; issue 30), and the output's health.
fn vehicle_status(
    me: i64,
    arbiter: &Arbiter,
    mode: rove_core::msg::Mode,
    report: &OutputReport,
) -> VehicleStatus {
    use rove_core::adapter::Health;
    use rove_core::msg::OutputState;
    let output = match (&report.hung, &report.health) {
        (Some(_), _) => OutputState::Hung,
        (None, Health::Ok) => OutputState::Ok,
        (None, Health::Degraded(_)) => OutputState::Degraded,
        (None, Health::Down(_)) => OutputState::Down,
    };
    VehicleStatus {
        vehicle_id: me,
        controller_id: arbiter.controller_id(),
        mode,
        failsafe: arbiter.owner() == Owner::Failsafe
            || output == OutputState::Down
            || report.held_safe,
        output,
        // Whole durations only, so that a hung call's growing age does not count as a change.
        detail: match report.hung {
            Some(hung) => format!("a device call has not returned for {} s", hung.as_secs()),
            None => report.to_string(),
        },
    }
}

/// The `STATUS=` line: who drives, how many operators are live, and the output's health.
/// E.g. `driven by 11 (2 operators live); output ok` or
/// `failsafe (no operator live); output down: …`.
fn status_line(arbiter: &Arbiter, output: &OutputReport, now: rove_core::MonoTime) -> String {
    // Devices, not streams: an operator holding a grant may have two live writers.
    let live = arbiter
        .sources(now)
        .filter(|s| s.live)
        .map(|s| s.controller.device)
        .collect::<std::collections::BTreeSet<_>>()
        .len();
    let operators = match live {
        0 => "no operator live".to_string(),
        1 => "1 operator live".to_string(),
        n => format!("{n} operators live"),
    };
    let owner = match arbiter.owner().device() {
        Some(id) => format!("driven by {id}"),
        None => "failsafe".to_string(),
    };
    format!("{owner} ({operators}); output {output}")
}

/// Command writers whose delivery baselines are remembered (rove_core::freshness).
const MAX_WRITERS: usize = 1024;

/// Most ControlCommand samples taken in one turn of the loop.
const MAX_BATCH: usize = 256;

/// ControlCommand samples into arbiter events: each writer's strength (from discovery), and
/// which samples are fresh. Of a batch taken at once, a writer's Movement sample supersedes its
/// earlier ones (a control stream needs the newest command, not every one), and a sample that
/// queued up longer than the command timeout (`rove_core::freshness`) is dropped and counted.
struct Intake {
    me: i64,
    strengths: HashMap<rustdds::GUID, rove_core::hierarchy::Strength>,
    freshness: Freshness,
    stale: RateLimited,
    stale_total: u64,
    unknown_strength: RateLimited,
    malformed: RateLimited,
}

impl Intake {
    fn new(me: i64, command_timeout: Duration) -> Intake {
        Intake {
            me,
            strengths: HashMap::new(),
            freshness: Freshness::new(command_timeout, MAX_WRITERS),
            stale: RateLimited::new(
                "stale ControlCommand sample (it queued up longer than the command timeout)",
            ),
            stale_total: 0,
            unknown_strength: RateLimited::new(
                "ControlCommand from a writer whose ownership strength is unknown",
            ),
            malformed: RateLimited::new("malformed or unreadable ControlCommand sample"),
        }
    }

    /// Remembers a writer's strength; beyond [`MAX_WRITERS`] writers it is looked up in
    /// discovery each time instead (a flood of writers cannot grow the table).
    fn learn(&mut self, writer: rustdds::GUID, strength: rove_core::hierarchy::Strength) {
        if self.strengths.len() < MAX_WRITERS || self.strengths.contains_key(&writer) {
            self.strengths.insert(writer, strength);
        }
    }

    fn forget(&mut self, writer: rustdds::GUID) {
        self.strengths.remove(&writer);
        self.freshness.forget(dds::writer_id(writer));
    }

    /// The events of a batch of samples, in order.
    fn events(
        &mut self,
        domain: &Domain,
        clock: &crate::runtime::Clock,
        batch: Vec<rustdds::dds::ReadResult<rustdds::with_key::DataSample<KeyedControlCommand>>>,
    ) -> Vec<Event> {
        let samples: Vec<_> = (batch.into_iter())
            .filter_map(|r| r.map_err(|e| self.malformed.warn(&e)).ok())
            .collect();
        // A Movement sample carries the whole setpoint: it supersedes every earlier sample of
        // its writer (a Probe or a Mode change does not).
        let superseded = |i: usize, writer: rustdds::GUID| {
            samples[i + 1..].iter().any(|later| {
                later.sample_info().writer_guid() == writer
                    && matches!(later.value(), Sample::Value(c)
                        if c.0.command_type == rove_core::msg::CommandType::Movement)
            })
        };
        let mut events = Vec::new();
        for (i, sample) in samples.iter().enumerate() {
            let guid = sample.sample_info().writer_guid();
            let writer = dds::writer_id(guid);
            let sent = sample
                .sample_info()
                .source_timestamp()
                .map(dds::timestamp_nanos);
            match sample.value() {
                Sample::Value(_) if superseded(i, guid) => {}
                Sample::Value(cmd) => {
                    if let Some(late) = self.freshness.judge(writer, sent, clock.now()) {
                        self.stale_total += 1;
                        let total = self.stale_total;
                        self.stale.warn(&format_args!(
                            "from {writer}, {late:?} late; {total} in all"
                        ));
                        continue;
                    }
                    let strength = match self.strengths.get(&guid) {
                        Some(s) => Some(*s),
                        None => {
                            let s = domain.discovered_strength(guid);
                            if let Some(s) = s {
                                self.learn(guid, s);
                            }
                            s
                        }
                    };
                    match strength {
                        Some(strength) => events.push(Event::Sample {
                            writer,
                            strength,
                            command: cmd.0,
                            arrival: clock.now(),
                        }),
                        None => self.unknown_strength.warn(&writer),
                    }
                }
                Sample::Dispose(key) if *key == self.me => events.push(Event::Released { writer }),
                Sample::Dispose(_) => {}
            }
        }
        events
    }
}

/// How long stopping waits for the output's safe state.
const STOP_WAIT: Duration = Duration::from_millis(500);

/// Watches the output's thread for a device call that does not return: logs when one hangs and
/// when it returns, and stops the watchdog keep-alives once it has been hung for `limit`.
#[derive(Debug)]
struct HungWatch {
    limit: Duration,
    hung: bool,
    stopped: bool,
}

impl HungWatch {
    /// The end of `STATUS=` while the keep-alives are stopped.
    const STOPPED: &str = "; watchdog keep-alives stopped";

    fn new(limit: Duration) -> HungWatch {
        HungWatch {
            limit,
            hung: false,
            stopped: false,
        }
    }

    fn observe(&mut self, report: &OutputReport) {
        match (report.hung, self.hung) {
            (Some(hung), false) => warn!(
                hung_ms = hung.as_millis() as u64,
                output = %report.describe,
                "output hung: a device call has not returned; the vehicle goes on deciding, the \
                 outputs change when it returns"
            ),
            (None, true) => info!(output = %report.health, "output call returned"),
            _ => {}
        }
        self.hung = report.hung.is_some();
    }

    /// Whether the watchdog keep-alive may be sent now.
    fn keepalive(&mut self, report: &OutputReport) -> bool {
        self.observe(report);
        let over = report.hung.is_some_and(|h| h > self.limit);
        if over && !self.stopped {
            warn!(
                limit_ms = self.limit.as_millis() as u64,
                "output hung longer than [vehicle] output_hung_limit_ms: watchdog keep-alives \
                 stopped, so that systemd restarts the unit"
            );
        }
        self.stopped = over;
        !over
    }

    fn annotate(&self, line: String) -> String {
        match self.stopped && !line.ends_with(Self::STOPPED) {
            true => line + Self::STOPPED,
            false => line,
        }
    }
}

/// Messages the arbiter did not believe: the first from each participant is logged at once,
/// then at most one per [`RateLimited::INTERVAL`](crate::runtime::RateLimited::INTERVAL) (a
/// rogue inventing ids cannot flood the journal); all are counted.
#[derive(Debug, Default)]
struct Suspects {
    logged: HashMap<ParticipantId, std::time::Instant>,
    total: u64,
    last: Option<Suspect>,
}

impl Suspects {
    /// Participants remembered for rate limiting; beyond it the table starts afresh.
    const MAX_PARTICIPANTS: usize = 256;

    fn report(&mut self, suspect: Suspect) {
        self.total += 1;
        self.last = Some(suspect);
        let key = suspect.sender;
        let interval = crate::runtime::RateLimited::INTERVAL;
        if self
            .logged
            .get(&key)
            .is_some_and(|t| t.elapsed() < interval)
        {
            return;
        }
        if self.logged.len() >= Self::MAX_PARTICIPANTS {
            self.logged.clear();
        }
        self.logged.insert(key, std::time::Instant::now());
        warn!(
            device = suspect.device,
            participant = %suspect.sender,
            total = self.total,
            "not believed: {suspect}"
        );
    }

    /// `line` with the count and the last one, once there is one.
    fn annotate(&self, line: String) -> String {
        match &self.last {
            Some(last) => format!(
                "{line}; {} untrusted messages ignored (last: device {} from participant {})",
                self.total, last.device, last.sender
            ),
            None => line,
        }
    }
}

/// The SIGUSR1 stall test hook, when enabled.
struct StallHook(Option<(tokio::signal::unix::Signal, Duration)>);

impl StallHook {
    fn new(stall: Option<Duration>) -> anyhow::Result<StallHook> {
        use tokio::signal::unix::{SignalKind, signal};
        Ok(StallHook(match stall {
            Some(d) => Some((signal(SignalKind::user_defined1())?, d)),
            None => None,
        }))
    }

    /// Resolves with the stall length on SIGUSR1; never when the hook is off.
    async fn requested(&mut self) -> Duration {
        match &mut self.0 {
            Some((signal, stall)) => match signal.recv().await {
                Some(()) => *stall,
                None => std::future::pending().await,
            },
            None => std::future::pending().await,
        }
    }
}

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

/// The sim adapter's record as JSON lines, one per output, for tests and benchmarks:
/// `{"wall_us":…,"mono_us":…,"action":"apply"|"safe","owner":id|null,"throttle":…,…}`.
struct OutputLog(JsonLines);

impl OutputLog {
    fn create(path: &std::path::Path) -> anyhow::Result<OutputLog> {
        JsonLines::create(path).map(OutputLog)
    }

    fn record(
        &mut self,
        clock: &Clock,
        action: &str,
        owner: Owner,
        setpoint: Option<rove_core::arbiter::Setpoint>,
    ) {
        let mut line = serde_json::json!({
            "wall_us": clock.wall_micros(),
            "mono_us": clock.now().as_nanos() / 1_000,
            "action": action,
            "owner": owner.device(),
        });
        if let Some(sp) = setpoint {
            line["throttle"] = sp.movement.throttle.into();
            line["roll"] = sp.movement.roll.into();
            line["pitch"] = sp.movement.pitch.into();
            line["yaw"] = sp.movement.yaw.into();
            line["mode"] = (sp.mode as u32).into();
        }
        self.0.write(&line);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rove_core::MonoTime;
    use rove_core::arbiter::{ArbiterConfig, ParticipantId, WriterId};
    use rove_core::hierarchy::Strength;
    use rove_core::msg::{CommandType, ControlCommand, Mode, MovementCommand, TimeT};

    fn sample(writer: WriterId, device: i64, strength: u16, at: MonoTime) -> Event {
        Event::Sample {
            writer,
            strength: Strength(strength),
            command: ControlCommand {
                src_id: device,
                dest_id: 100,
                command_type: CommandType::Movement,
                movement_command: MovementCommand::default(),
                mode: Mode::Manual,
                timestamp: TimeT(0),
            },
            arrival: at,
        }
    }

    #[test]
    fn status_line_names_the_owner_counts_live_devices_and_shows_output_health() {
        let mut output = OutputReport {
            describe: "sim".into(),
            health: rove_core::adapter::Health::Ok,
            detail: None,
            hung: None,
            stale: 0,
            held_safe: false,
        };
        let mut arbiter = Arbiter::new(100, ArbiterConfig::default());
        let t = MonoTime::ZERO;
        assert_eq!(
            status_line(&arbiter, &output, t),
            "failsafe (no operator live); output ok"
        );
        let writer = |p: u128, e: u32| WriterId {
            participant: ParticipantId(p),
            entity: e,
        };
        // Device 11 streams on two writers (regular and priority): one operator.
        arbiter.step(t, sample(writer(1, 1), 11, 220, t));
        arbiter.step(t, sample(writer(1, 2), 11, 65535, t));
        arbiter.step(t, sample(writer(2, 1), 12, 110, t));
        assert_eq!(
            status_line(&arbiter, &output, t),
            "driven by 11 (2 operators live); output ok"
        );
        // One command timeout later nobody is live.
        let later = t + std::time::Duration::from_secs(1);
        arbiter.step(later, Event::Tick);
        assert_eq!(
            status_line(&arbiter, &output, later),
            "failsafe (no operator live); output ok"
        );
        // A device call that does not return.
        output.hung = Some(Duration::from_millis(1250));
        assert_eq!(
            status_line(&arbiter, &output, later),
            "failsafe (no operator live); output hung: a device call has not returned for 1.2s"
        );
    }

    /// Issue 30: an autopilot that refused the owner's mode, with the adapter holding the
    /// outputs safe, is reported as failsafe while the owner still owns the vehicle.
    #[test]
    fn status_says_failsafe_while_the_adapter_holds_the_outputs_safe() {
        let mut arbiter = Arbiter::new(100, ArbiterConfig::default());
        let t = MonoTime::ZERO;
        let writer = WriterId {
            participant: ParticipantId(1),
            entity: 1,
        };
        arbiter.step(t, sample(writer, 11, 220, t));
        let mut report = OutputReport {
            describe: "mavlink".into(),
            health: rove_core::adapter::Health::Degraded("AUTO refused".into()),
            detail: None,
            hung: None,
            stale: 0,
            held_safe: false,
        };
        let driving = vehicle_status(100, &arbiter, rove_core::msg::Mode::Auto, &report);
        assert_eq!((driving.controller_id, driving.failsafe), (11, false));
        report.held_safe = true;
        let held = vehicle_status(100, &arbiter, rove_core::msg::Mode::Auto, &report);
        assert_eq!((held.controller_id, held.failsafe), (11, true));
    }

    #[test]
    fn keepalives_stop_only_once_the_output_is_hung_past_its_limit() {
        let mut watch = HungWatch::new(Duration::from_secs(2));
        let report = |hung_ms: Option<u64>| OutputReport {
            describe: "pwm".into(),
            health: rove_core::adapter::Health::Ok,
            detail: None,
            hung: hung_ms.map(Duration::from_millis),
            stale: 0,
            held_safe: false,
        };
        assert!(watch.keepalive(&report(None)));
        assert!(watch.keepalive(&report(Some(60))));
        assert!(watch.keepalive(&report(Some(2000))));
        assert_eq!(watch.annotate("x".into()), "x");
        assert!(!watch.keepalive(&report(Some(2001))));
        assert_eq!(
            watch.annotate("x".into()),
            "x; watchdog keep-alives stopped"
        );
        assert_eq!(
            watch.annotate(watch.annotate("x".into())),
            "x; watchdog keep-alives stopped"
        );
        // The call returned: keep-alives again.
        assert!(watch.keepalive(&report(None)));
        assert_eq!(watch.annotate("x".into()), "x");
    }
}
