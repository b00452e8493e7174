//! `rove operator`: the DDS side of an operator. Every decision — what to stream to which
//! vehicle, input liveness, the console's and the API's commands, active handover — is
//! [`rove_core::session::OperatorSession`]'s; this module is the loop around it: it turns DDS
//! samples, input events, commands and timers into session events, and the session's effects
//! into DDS writes, disposals, log lines and front-end events.
//!
//! The loop's edges are injected: the network (`net::Net`; in `rove operator` the DDS node,
//! readers and writers, `net::Dds`), and [`Edges`]: its clock, its sticks, the channel its
//! events go out on and the one its commands come in on, systemd's notifier, and the shutdown
//! future. Who is on the other side — the terminal console, the local API and the browser
//! console of `rove operator` ([`crate::host`]), or one browser's device ([`crate::web`]) — is
//! not this module's business: it imports neither. Its tests run it on a channel network in
//! virtual time.
//!
//! Under systemd (see [`crate::sdnotify`]): `READY=1` once the participant and every writer
//! exist, `STATUS=` with what we drive, hold and stand by for, `WATCHDOG=1` from this loop, and
//! `STOPPING=1` when the stop begins.
//!
//! Stop (the injected shutdown future: SIGTERM or SIGINT in `rove operator`): held grants are
//! finished, every instance we drive is disposed (an explicit release, so the vehicle hands over
//! at once), and the participant leaves.
//!
//! # Layout
//! - this file: [`Options`], [`Edges`], [`run`] (set-up, the `select!` loop, the stop), the
//!   session's effects carried out.
//! - `net.rs`: the network edge (`Net`, what was heard and from whom) and its DDS form.
//! - `samples.rs`: what was heard → session events and front-end events.
//! - `writers.rs`: the DDS writers (a ControlCommand writer per session writer and route).
//! - `ui.rs`: what the front ends are told, only when it changed.
//! - `tests.rs`: the loop on a channel network, on tokio's paused clock.

mod net;
mod samples;
mod spawned;
#[cfg(test)]
mod tests;
mod ui;
mod writers;

use crate::config::{InputChoice, OperatorConfig};
use crate::runtime::{Clock, JsonLines, sleep_until};
use crate::sdnotify::Notifier;
use net::{Dds, Net};
use rove_console::{CommandRequest, ConsoleState, Event, Identity, Stamped};
use rove_core::adapter::{InputAction, InputEvent, InputSource};
use rove_core::msg::DeviceId;
use rove_core::session::{Effect, OperatorSession, SessionConfig, SessionEvent, SessionInput};
use std::path::PathBuf;
use std::sync::Arc;
use tracing::{info, warn};
use ui::Ui;

pub use spawned::{STOP_BOUND, Spawned};

/// Longest wait for peers to acknowledge the final FINISHes and releases on exit (one deadline
/// for all writers).
/// Loopback acknowledges in about a millisecond; 300 ms covers a loaded radio link without
/// holding up a systemd stop noticeably. If it runs out, peers fall back to the command timeout.
const SHUTDOWN_ACK_WAIT: std::time::Duration = std::time::Duration::from_millis(300);

/// Most input events taken in one turn of the loop, so a chattering device cannot keep the loop
/// from DDS samples and timers; the rest are taken on the next turn.
const INPUT_EVENTS_PER_TURN: usize = 256;

/// How `rove operator` was started, beyond its config.
#[derive(Debug, Clone, Default)]
pub struct Options {
    /// The config file, for the start-up line.
    pub config_path: PathBuf,
    /// Ask this vehicle's owner for control as soon as the vehicle is seen.
    pub request: Option<DeviceId>,
    /// Append every RequestControl sent, and every stick value read, as JSON lines (for the
    /// benchmarks).
    pub record: Option<PathBuf>,
    /// Run the console on this terminal.
    pub console: bool,
    /// Test hook: run with another device's certificate (`[security]`), to see the others
    /// refuse what it sends in this device's name.
    pub any_certificate: bool,
}

/// Sticks the loop reads: an evdev device under its mapping, or a browser's.
pub trait Sticks: InputSource + Send {
    /// Whether the deadman is held, and the link in words, for the front ends.
    fn link(&self) -> (Option<bool>, String);
}

impl Sticks for rove_inputs::MappedSource {
    fn link(&self) -> (Option<bool>, String) {
        let status = self.status();
        (status.deadman, status.to_string())
    }
}

/// The loop's edges: everything it reads or tells that is not DDS.
#[derive(Debug)]
pub struct Edges {
    /// The clock every time in the loop is on (the sticks' too).
    pub clock: Clock,
    /// The sticks; `None`: the config's constant sticks (`[input] source = "constant"`).
    pub sticks: Option<Box<dyn Sticks>>,
    /// Notified when the sticks have something new.
    pub wake: Arc<tokio::sync::Notify>,
    /// Where the loop's events go (front ends subscribe).
    pub events: tokio::sync::broadcast::Sender<Stamped>,
    /// The front ends' commands.
    pub commands: tokio::sync::mpsc::Receiver<CommandRequest>,
    /// Presses to confirm, when a console asks the person first (`None`: nobody asks).
    pub confirm: Option<tokio::sync::mpsc::Sender<InputAction>>,
    /// systemd (disabled for a browser's device: its start and stop are not the service's).
    pub notify: Notifier,
}

impl std::fmt::Debug for dyn Sticks {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.describe())
    }
}

impl Edges {
    /// Edges with no front end yet: a fresh clock, `sticks`, and channels nobody listens to.
    /// Returns the sender of the command channel too.
    pub fn new(
        sticks: Option<Box<dyn Sticks>>,
        wake: Arc<tokio::sync::Notify>,
        notify: Notifier,
    ) -> (Edges, tokio::sync::mpsc::Sender<CommandRequest>) {
        let (commands_tx, commands) = tokio::sync::mpsc::channel(64);
        let edges = Edges {
            clock: Clock::start(),
            sticks,
            wake,
            events: tokio::sync::broadcast::channel(1024).0,
            commands,
            confirm: None,
            notify,
        };
        (edges, commands_tx)
    }
}

/// Opens the sticks `[input]` names (`None` for constant sticks), waking `wake` on news.
///
/// # Errors
/// The device cannot be opened.
pub fn open_sticks(
    config: &OperatorConfig,
    wake: &Arc<tokio::sync::Notify>,
) -> anyhow::Result<Option<Box<dyn Sticks>>> {
    let InputChoice::Device(input) = &config.input else {
        return Ok(None);
    };
    let mut source =
        rove_inputs::open_mapped(input).map_err(|e| anyhow::anyhow!("[input]: {e}"))?;
    let waker = Arc::clone(wake);
    source.set_waker(Arc::new(move || waker.notify_one()));
    info!(input = %source.describe(), "input opened: driving starts when its sticks are live and centred");
    Ok(Some(Box::new(source)))
}

/// The front ends' view of an operator before its first event: its identity, and devices
/// offline when their participant leaves (events) or, as a backstop, three DeviceInfo refreshes
/// after they were last heard. The host's console and API, and each web device's page, start
/// from it.
pub fn console_state(config: &OperatorConfig) -> ConsoleState {
    let identity = Identity {
        id: config.common.id,
        name: config.common.name.clone(),
        level: config.level,
        class: config.device_class,
        strength: config.strength,
    };
    ConsoleState::new(identity, crate::dds::OFFLINE_AFTER)
}

/// The operator as the loop holds it.
struct Role<N> {
    config: OperatorConfig,
    net: N,
    session: OperatorSession,
    ui: Ui,
    edges: Edges,
    record: Option<JsonLines>,
}

/// Runs the operator role with `edges` until `shutdown` completes, then finishes its grants,
/// releases its vehicles and leaves.
///
/// # Errors
/// The participant, a topic, a reader or writer cannot be created, or the record cannot be
/// opened.
pub async fn run(
    config: OperatorConfig,
    options: Options,
    edges: Edges,
    shutdown: impl std::future::Future<Output = ()>,
) -> anyhow::Result<()> {
    let record = options
        .record
        .as_deref()
        .map(JsonLines::create)
        .transpose()?;
    let net = Dds::join(&config, options.request, options.any_certificate)?;
    info!(
        config = %options.config_path.display(),
        device = config.common.id,
        name = %config.common.name,
        level = ?config.level,
        class = ?config.device_class,
        strength = config.strength.0,
        domain = config.common.domain_id,
        interfaces = ?config.common.interfaces,
        drive = ?config.drive,
        watchdog_keepalive_ms = edges.notify.watchdog_period().map(|p| p.as_millis() as u64),
        "operator started"
    );
    Role::new(config, options.request, edges, net, record)?
        .serve(shutdown)
        .await
}

impl<N: Net> Role<N> {
    /// The session on its edges.
    fn new(
        config: OperatorConfig,
        request: Option<DeviceId>,
        edges: Edges,
        net: N,
        record: Option<JsonLines>,
    ) -> anyhow::Result<Role<N>> {
        let input = match (&edges.sticks, &config.input) {
            (Some(_), _) => SessionInput::Device,
            (None, InputChoice::Constant(movement, mode)) => {
                SessionInput::Constant(*movement, *mode)
            }
            (None, InputChoice::Device(_)) => {
                anyhow::bail!("[input] names a device, and none was opened")
            }
        };
        let clock = edges.clock;
        let mut session = OperatorSession::new(
            SessionConfig {
                me: config.common.id,
                strength: config.strength,
                handover: config.handover,
                drive: config.drive.clone(),
                input,
                heartbeat: config.common.heartbeat,
                confirm_actions: edges.confirm.is_some(),
                request,
                participant: net.participant(),
                trust: config.common.trust(),
            },
            clock.now(),
        );
        if let Some(certifier) = net.certifier() {
            session.certify(certifier);
        }
        let ui = Ui {
            tx: edges.events.clone(),
            clock,
            actions: edges.confirm.clone(),
            shown_input: None,
            shown_streams: None,
            untrusted_told: std::cell::Cell::new(None),
        };
        Ok(Role {
            config,
            net,
            session,
            ui,
            edges,
            record,
        })
    }

    /// The loop until `shutdown` (or the network is gone: an error), then the leave.
    async fn serve(
        mut self,
        shutdown: impl std::future::Future<Output = ()>,
    ) -> anyhow::Result<()> {
        let result = self.control_loop(shutdown).await;
        self.leave();
        result
    }

    /// The sticks' link for the front ends.
    fn link(&self) -> (Option<bool>, String) {
        match &self.edges.sticks {
            Some(sticks) => sticks.link(),
            None => (None, "constant sticks (config)".to_string()),
        }
    }

    fn step(&mut self, event: SessionEvent) -> Vec<Effect> {
        let clock = self.edges.clock;
        self.session.step(clock.now(), clock.stamp(), event)
    }

    /// The loop: until `shutdown`, or the network is gone (an error).
    async fn control_loop(
        &mut self,
        shutdown: impl std::future::Future<Output = ()>,
    ) -> anyhow::Result<()> {
        let clock = self.edges.clock;
        let mut stream_timer = tokio::time::interval(self.config.stream_period);
        stream_timer.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
        let mut heartbeat = tokio::time::interval(self.config.common.heartbeat);
        let mut keepalive = self.edges.notify.keepalive_timer();
        tokio::pin!(shutdown);
        self.ui
            .emit(Event::Identity(console_state(&self.config).identity));
        let mut link = self.link();
        self.ui.show(&self.session, &link);
        self.net.announce();
        let mut shown = self.session.status_line();
        self.edges.notify.ready(&shown);
        let mut selected = None;
        loop {
            let deadline = self.session.next_deadline().map(|d| clock.instant(d));
            let input_deadline = (self.edges.sticks.as_ref())
                .and_then(|s| s.next_deadline())
                .map(|d| clock.instant(d));
            let news = Arc::clone(&self.edges.wake);
            let mut reply = None;
            let mut polled = false;
            // The status line only changes with what we stream to or the vehicles seen:
            // recomputed when a step did more than write samples (the hot path: sticks,
            // keep-alives), and on each heartbeat.
            let mut heartbeat_due = false;
            // An operator that streams nothing does not wake 50 times a second for it.
            let streaming = self.session.streams_anything();
            let wake = tokio::select! {
                () = &mut shutdown => break,
                Some(req) = self.edges.commands.recv() => Wake::Command(req),
                () = news.notified(), if self.edges.sticks.is_some() => Wake::Sticks,
                () = sleep_until(input_deadline), if input_deadline.is_some() => Wake::Sticks,
                _ = stream_timer.tick(), if streaming => Wake::Stream,
                _ = heartbeat.tick() => Wake::Heartbeat,
                // From this loop, so that a hung loop stops the keep-alives.
                _ = keepalive.tick() => Wake::Keepalive,
                heard = self.net.heard() => Wake::Heard(heard?),
                () = sleep_until(deadline) => Wake::Deadline,
            };
            let effects = match wake {
                Wake::Command(req) => {
                    reply = Some(req.reply);
                    self.step(SessionEvent::Command(req.command))
                }
                Wake::Sticks => {
                    polled = true;
                    self.poll_sticks()
                }
                Wake::Stream => self.step(SessionEvent::StreamTick),
                Wake::Heartbeat => {
                    heartbeat_due = true;
                    self.net.announce();
                    self.ui.emit(Event::Tick);
                    Vec::new()
                }
                Wake::Keepalive => {
                    self.edges.notify.keepalive();
                    Vec::new()
                }
                Wake::Heard(heard) => self.on_heard(heard),
                Wake::Deadline => self.step(SessionEvent::Tick),
            };
            let changed =
                heartbeat_due || effects.iter().any(|e| !matches!(e, Effect::Write { .. }));
            self.finish_turn(effects, reply, &mut selected);
            if polled && self.ui.watched() {
                link = self.link();
            }
            self.ui.show(&self.session, &link);
            if changed {
                let line = self.session.status_line();
                if line != shown {
                    self.edges.notify.status(&line);
                    shown = line;
                }
            }
        }
        Ok(())
    }

    /// Carries out a turn's effects and answers the command that caused them, if one did.
    fn finish_turn(
        &mut self,
        effects: Vec<Effect>,
        reply: Option<tokio::sync::oneshot::Sender<Result<(), String>>>,
        selected: &mut Option<DeviceId>,
    ) {
        let refused = self.apply(effects);
        // The selected vehicle is the one buttons and the console ask for: both its writers
        // now, so that an owner who accepts at once (auto-accept) is not faster than discovery
        // (measured: made at the REQUEST, the first commands of an auto-accepted grant were
        // lost until the vehicle had matched the new writer, p50 3 → 8 ms).
        if self.session.selected() != *selected {
            *selected = self.session.selected();
            if let Some(vehicle) = *selected {
                self.net.prepare(vehicle);
            }
        }
        if let Some(reply) = reply {
            if let Some(why) = &refused {
                self.ui.emit(Event::Notice { text: why.clone() });
            }
            // The asker may have gone; nothing to do then.
            let _ = reply.send(refused.map_or(Ok(()), Err));
        } else if let Some(why) = refused {
            warn!("button: {why}");
        }
    }

    /// The session's effects: on the network, to the front ends; returns why a command was
    /// refused, if one was.
    fn apply(&mut self, effects: Vec<Effect>) -> Option<String> {
        let mut refused = None;
        for effect in effects {
            match effect {
                Effect::Write { writer, command } => self.net.write(writer, command),
                Effect::Release { writer, vehicle } => self.net.release(writer, vehicle),
                Effect::Send(msg) => {
                    if let Some(record) = self.record.as_mut() {
                        record.write(&crate::runtime::request_json(&self.edges.clock, &msg));
                    }
                    self.net.send(msg);
                }
                Effect::Report(report) => self.ui.report(report),
                Effect::Confirm(action) => {
                    // The console confirms what would move a vehicle, then sends the command
                    // back; a full queue drops the press (the person presses again).
                    if let Some(actions) = &self.ui.actions {
                        let _ = actions.try_send(action);
                    }
                }
                Effect::Refused(why) => refused = Some(why),
            }
        }
        refused
    }

    /// Reads every event the sticks have now and steps the session with each.
    fn poll_sticks(&mut self) -> Vec<Effect> {
        let clock = self.edges.clock;
        let Some(sticks) = self.edges.sticks.as_mut() else {
            return Vec::new();
        };
        let mut effects = Vec::new();
        for _ in 0..INPUT_EVENTS_PER_TURN {
            let event = match sticks.poll(clock.now()) {
                Ok(Some(e)) => e,
                Ok(None) => break,
                Err(e) => InputEvent::Lost {
                    reason: e.to_string(),
                },
            };
            if let (InputEvent::Axes(movement), Some(record)) = (&event, self.record.as_mut()) {
                // For `rove bench input`: when each stick value was read.
                record.write(&serde_json::json!({
                    "wall_us": clock.wall_micros(), "kind": "input",
                    "throttle": movement.throttle, "roll": movement.roll,
                }));
            }
            effects.extend(self.session.step(
                clock.now(),
                clock.stamp(),
                SessionEvent::Input(event),
            ));
        }
        effects
    }

    /// The stop: held grants finished, driven vehicles released, DeviceInfo withdrawn, and a
    /// bounded wait for the peers to acknowledge the FINISHes and releases.
    fn leave(mut self) {
        info!("operator stopping: finishing grants and releasing vehicles");
        self.edges
            .notify
            .stopping("stopping: finishing grants, releasing vehicles");
        let effects = self.session.stop(self.edges.clock.stamp());
        self.apply(effects);
        self.net.leave(SHUTDOWN_ACK_WAIT);
    }
}

/// What woke the operator loop.
enum Wake {
    Command(CommandRequest),
    Sticks,
    Stream,
    Heartbeat,
    Keepalive,
    Heard(net::Heard),
    Deadline,
}
