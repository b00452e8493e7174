//! `rove operator`: the DDS side of an operator. Every decision — what to stream to which
//! vehicle, input liveness, the console's and the API's commands, active handover — is
//! [`rove_core::session::OperatorSession`]'s; this module is the loop around it: it turns DDS
//! samples, input events, commands and timers into session events, and the session's effects
//! into DDS writes, disposals, log lines and console events.
//!
//! Under systemd (see [`crate::sdnotify`]): `READY=1` once the participant and every writer
//! exist, `STATUS=` with what we drive, hold and stand by for, `WATCHDOG=1` from this loop, and
//! `STOPPING=1` when the stop begins.
//!
//! Stop (the injected shutdown future: SIGTERM or SIGINT in `rove operator`): held grants are
//! finished, every instance we drive is disposed (an explicit release, so the vehicle hands over
//! at once), and the participant leaves.

use crate::config::{InputChoice, OperatorConfig};
use crate::dds::{
    self, Discovery, Domain, KeyedControlCommand, KeyedDeviceInfo, KeyedVehicleStatus, Node,
};
use crate::runtime::{Clock, JsonLines, RateLimited, sleep_until};
use crate::sdnotify::Notifier;
use futures::StreamExt;
use rove_console::model::{DeviceKind, InputStatus as UiInput};
use rove_console::{CommandRequest, ConsoleState, Event, Identity, Stamped};
use rove_core::adapter::{InputAction, InputEvent, InputSource};
use rove_core::hierarchy::Strength;
use rove_core::msg::{Ack, DeviceId, DeviceType, RequestControl};
use rove_core::session::{
    Effect, OperatorSession, Report, SessionConfig, SessionEvent, SessionInput, Writer,
};
use rustdds::with_key::Sample;
use rustdds::{DomainParticipantStatusEvent, StatusEvented};
use std::collections::HashMap;
use std::collections::hash_map::Entry;
use std::path::PathBuf;
use std::sync::Arc;
use tracing::{info, warn};

type CommandWriter = rustdds::with_key::DataWriterCdr<KeyedControlCommand>;

/// How many times a release (dispose) is sent. Vehicles read commands best effort, so each copy
/// may be lost on its own: at 10 % packet loss one copy is lost one time in 10, three one time
/// in 1 000. A vehicle that misses all of them hands over after the command timeout instead,
/// as for a crash. A repeat costs one small datagram; the vehicle ignores a release of a source
/// it has already released.
const RELEASE_REPEATS: usize = 3;

/// Longest wait, per writer, for peers to acknowledge the final FINISH and disposals on exit.
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

/// What discovery tells the session: ControlCommand writers found (with their strength) and
/// lost, participants gone.
fn discovery_event(discovery: Discovery) -> SessionEvent {
    match discovery {
        Discovery::CommandWriter { guid, strength } => SessionEvent::WriterFound {
            writer: dds::writer_id(guid),
            strength,
        },
        Discovery::WriterLost { guid } => SessionEvent::WriterLost {
            writer: dds::writer_id(guid),
        },
        Discovery::ParticipantLost { participant } => SessionEvent::ParticipantGone { participant },
    }
}

/// The next VehicleStatus sample, or never without a reader.
async fn next_status(
    statuses: &mut Option<rustdds::with_key::DataReaderStream<KeyedVehicleStatus>>,
) -> Option<rustdds::dds::ReadResult<rustdds::with_key::DataSample<KeyedVehicleStatus>>> {
    match statuses {
        Some(stream) => stream.next().await,
        None => std::future::pending().await,
    }
}

/// What a front end that is not this process's (the browser console, `crate::web`) hands the
/// operator loop: its input, its clock, and the channels of its events and commands.
#[derive(Debug)]
pub struct Attached {
    /// The sticks.
    pub input: crate::web::WebInput,
    /// Notified when `input` has something new.
    pub wake: Arc<tokio::sync::Notify>,
    /// The clock `input`'s times are on.
    pub clock: Clock,
    /// Where the loop's events go (the front end's hub subscribes).
    pub events: tokio::sync::broadcast::Sender<Stamped>,
    /// The front end's commands.
    pub commands: tokio::sync::mpsc::Receiver<CommandRequest>,
}

/// The input the loop reads.
enum Device {
    Evdev(Box<rove_inputs::MappedSource>),
    Web(crate::web::WebInput),
}

impl Device {
    fn source(&mut self) -> &mut dyn InputSource {
        match self {
            Device::Evdev(d) => d.as_mut(),
            Device::Web(w) => w,
        }
    }

    fn next_deadline(&self) -> Option<rove_core::time::MonoTime> {
        match self {
            Device::Evdev(d) => d.next_deadline(),
            Device::Web(w) => w.next_deadline(),
        }
    }

    /// Whether the deadman is held, and the link in words, for the console.
    fn link(&self) -> (Option<bool>, String) {
        match self {
            Device::Evdev(d) => {
                let status = d.status();
                (status.deadman, status.to_string())
            }
            Device::Web(w) => w.status(),
        }
    }
}

/// The console's view of an operator before its first event: its identity, and devices offline
/// after three missed heartbeats. The host's console and API, and each web device's page, start
/// from it.
pub fn console_state(config: &OperatorConfig) -> ConsoleState {
    let identity = Identity {
        id: config.common.id,
        name: config.common.name.clone(),
        level: config.level,
        class: config.device_class,
        strength: config.strength,
    };
    ConsoleState::new(identity, config.common.heartbeat * 3)
}

/// Runs the operator role until `shutdown` completes or the console is closed; with `[web]`,
/// the browser console and its devices too.
///
/// # Errors
/// The participant, a topic, a reader or writer cannot be created, the input cannot be opened,
/// the API socket or the web console cannot be bound, or the record cannot be opened.
pub async fn run(
    config: OperatorConfig,
    options: Options,
    shutdown: impl std::future::Future<Output = ()>,
) -> anyhow::Result<()> {
    run_attached(config, options, None, shutdown).await
}

/// [`run`], or with `attached`, one web device's loop (its input and console are a browser's).
///
/// # Errors
/// As [`run`].
pub async fn run_attached(
    config: OperatorConfig,
    options: Options,
    attached: Option<Attached>,
    shutdown: impl std::future::Future<Output = ()>,
) -> anyhow::Result<()> {
    let clock = attached.as_ref().map_or_else(Clock::start, |a| a.clock);
    let host = attached.is_none();
    // systemd hears from the host's loop only: a web device starting or stopping is not the
    // service's.
    let mut notify = if host {
        Notifier::from_env()
    } else {
        Notifier::disabled()
    };
    let mut record = options
        .record
        .as_deref()
        .map(JsonLines::create)
        .transpose()?;
    let me = config.common.id;
    let node = Node::join(
        &config.common,
        DeviceType::Controller,
        options.any_certificate,
    )?;
    let domain = &node.domain;
    let mut writers = Writers {
        strength: config.strength,
        commands: HashMap::new(),
        routes: dds::Routes::default(),
        requests: domain.request_writer()?,
        failed: RateLimited::new("ControlCommand write failed"),
    };
    // The vehicles to drive from the start, and the one to ask for: their writers now, so
    // that discovery has matched them by the first command.
    for &vehicle in &config.drive {
        writers.command_writer(domain, Writer::Regular, vehicle);
    }
    if let Some(vehicle) = options.request {
        writers.prepare(domain, vehicle);
    }
    let infos = domain.device_info_reader()?;
    // The vehicles' output health for the console; optional (a secured fleet's permissions
    // may predate the topic).
    let statuses = domain
        .vehicle_status_reader()
        .map_err(|e| warn!(cause = %format!("{e:#}"), "no VehicleStatus: the console shows no output health"))
        .ok();
    let requests = domain.request_reader()?;
    let listener = domain.participant.status_listener();
    info!(
        config = %options.config_path.display(),
        device = me,
        name = %config.common.name,
        level = ?config.level,
        class = ?config.device_class,
        strength = config.strength.0,
        domain = config.common.domain_id,
        interfaces = ?config.common.interfaces,
        drive = ?config.drive,
        watchdog_keepalive_ms = notify.watchdog_period().map(|p| p.as_millis() as u64),
        "operator started"
    );

    let wake = attached.as_ref().map_or_else(
        || Arc::new(tokio::sync::Notify::new()),
        |a| Arc::clone(&a.wake),
    );
    let (input, mut device) = match &config.input {
        _ if attached.is_some() => {
            let web = attached.as_ref().map(|a| a.input.clone());
            (SessionInput::Device, web.map(Device::Web))
        }
        InputChoice::Constant(movement, mode) => (SessionInput::Constant(*movement, *mode), None),
        InputChoice::Device(input) => {
            let mut source =
                rove_inputs::open_mapped(input).map_err(|e| anyhow::anyhow!("[input]: {e}"))?;
            let waker = Arc::clone(&wake);
            source.set_waker(Arc::new(move || waker.notify_one()));
            info!(input = %source.describe(), "input opened: driving starts when its sticks are live and centred");
            (SessionInput::Device, Some(Device::Evdev(Box::new(source))))
        }
    };
    let mut session = OperatorSession::new(
        SessionConfig {
            me,
            strength: config.strength,
            handover: config.handover,
            drive: config.drive.clone(),
            input,
            heartbeat: config.common.heartbeat,
            confirm_actions: options.console,
            request: options.request,
            participant: node.participant,
            trust: config.common.trust(),
        },
        clock.now(),
    );
    if let Some(certifier) = node.certifier.clone() {
        session.certify(certifier);
    }

    // The console and the local API see the operator through events and act through commands
    // (rove-console); both are optional.
    let mirror = console_state(&config);
    let identity = mirror.identity.clone();
    let (commands_tx, own_commands) = tokio::sync::mpsc::channel::<CommandRequest>(64);
    let (events_tx, mut commands) = match attached {
        Some(a) => (a.events, a.commands),
        None => (
            tokio::sync::broadcast::channel::<Stamped>(1024).0,
            own_commands,
        ),
    };
    let (actions_tx, actions_rx) = tokio::sync::mpsc::channel::<InputAction>(64);
    let mut ui = Ui {
        tx: events_tx.clone(),
        clock,
        actions: actions_tx,
        shown_input: None,
        shown_streams: None,
        untrusted_told: std::cell::Cell::new(None),
    };
    if let Some(path) = &config.api_socket {
        let socket = rove_console::ApiSocket::bind(path)
            .map_err(|e| anyhow::anyhow!("local API socket: {e}"))?;
        info!(path = %path.display(), "local API listening");
        let hub = rove_console::Hub::start(mirror.clone(), events_tx.subscribe());
        let serve = socket.serve(hub, commands_tx.clone());
        tokio::spawn(async move {
            if let Err(e) = serve.await {
                warn!(cause = %e, "local API stopped");
            }
        });
    }
    // The browser console: its devices are operators of their own (crate::web), stopped with us.
    let (web_stop, web_stopped) = tokio::sync::oneshot::channel::<()>();
    let web = match &config.web {
        Some(web) if host => {
            let console =
                crate::web::WebConsole::bind(web, &options, events_tx.clone(), clock).await?;
            Some(tokio::spawn(console.run(async {
                let _ = web_stopped.await;
            })))
        }
        _ => None,
    };
    let terminal = options.console.then(|| {
        rove_console::run_terminal(
            mirror.clone(),
            move || clock.now(),
            events_tx.subscribe(),
            commands_tx.clone(),
            actions_rx,
        )
    });
    let terminal_on = terminal.is_some();
    let terminal = async move {
        match terminal {
            Some(t) => t.await,
            None => std::future::pending().await,
        }
    };
    tokio::pin!(terminal);
    ui.emit(Event::Identity(identity));
    let input_link = |device: Option<&Device>| match device {
        Some(d) => d.link(),
        None => (None, "constant sticks (config)".to_string()),
    };
    let mut link = input_link(device.as_ref());
    ui.show(&session, &link);

    let publish_info = || node.publish(me);
    publish_info();

    let mut infos = infos.async_sample_stream();
    let mut requests = requests.async_sample_stream();
    let mut statuses = statuses.map(|r| r.async_sample_stream());
    let mut status = listener.as_async_status_stream();
    let mut stream_timer = tokio::time::interval(config.stream_period);
    stream_timer.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    let mut heartbeat = tokio::time::interval(config.common.heartbeat);
    tokio::pin!(shutdown);
    let mut malformed = RateLimited::new("malformed DeviceInfo or RequestControl sample");
    let mut keepalive = notify.keepalive_timer();
    let mut shown = session.status_line();
    notify.ready(&shown);
    let mut selected = None;

    loop {
        let deadline = session.next_deadline().map(|d| clock.instant(d));
        let input_deadline = device
            .as_ref()
            .and_then(Device::next_deadline)
            .map(|d| clock.instant(d));
        let step =
            |session: &mut OperatorSession, event| session.step(clock.now(), clock.stamp(), event);
        let mut reply = None;
        let mut polled = false;
        // The status line only changes with what we stream to or the vehicles seen: recomputed
        // when a step did more than write samples (the hot path: sticks, keep-alives), and on
        // each heartbeat.
        let mut heartbeat_due = false;
        let effects = tokio::select! {
            _ = &mut shutdown => break,
            ended = &mut terminal, if terminal_on => {
                if let Err(e) = ended {
                    warn!(cause = %e, "console failed");
                }
                info!("console closed: stopping");
                break;
            }
            Some(req) = commands.recv() => {
                reply = Some(req.reply);
                step(&mut session, SessionEvent::Command(req.command))
            }
            _ = wake.notified(), if device.is_some() => {
                polled = true;
                poll_input(device.as_mut(), &mut session, &clock, record.as_mut())
            }
            _ = sleep_until(input_deadline), if input_deadline.is_some() => {
                polled = true;
                poll_input(device.as_mut(), &mut session, &clock, record.as_mut())
            }
            _ = stream_timer.tick() => step(&mut session, SessionEvent::StreamTick),
            _ = heartbeat.tick() => {
                heartbeat_due = true;
                publish_info();
                ui.emit(Event::Tick);
                Vec::new()
            }
            // From this loop, so that a hung loop stops the keep-alives.
            _ = keepalive.tick() => { notify.keepalive(); Vec::new() }
            sample = infos.next() => match sample {
                Some(Ok(s)) => {
                    let from = dds::sender(s.sample_info());
                    match s.into_value() {
                        Sample::Value(KeyedDeviceInfo(info)) => {
                            let seen = Event::DeviceSeen {
                                id: info.device_id,
                                name: info.name.clone(),
                                kind: if info.device_type == DeviceType::Vehicle {
                                    DeviceKind::Vehicle
                                } else {
                                    DeviceKind::Controller
                                },
                                owner: info.controller_id,
                            };
                            let (id, vehicle) = (info.device_id, info.device_type == DeviceType::Vehicle);
                            let effects = step(&mut session, SessionEvent::DeviceInfo { info, from });
                            // Shown only if believed; the session reports it otherwise.
                            if !effects.iter().any(|e| matches!(e, Effect::Report(Report::Untrusted(_)))) {
                                ui.emit(seen);
                                if vehicle {
                                    writers.routes.vehicle_seen(id, from);
                                }
                            }
                            effects
                        }
                        // Only the participant that speaks for a device can withdraw it.
                        Sample::Dispose(id) if session.speaks_for(clock.now(), id, from) => {
                            ui.emit(Event::DeviceGone { id });
                            Vec::new()
                        }
                        Sample::Dispose(_) => Vec::new(),
                    }
                }
                Some(Err(e)) => { malformed.warn(&e); Vec::new() }
                None => anyhow::bail!("DeviceInfo stream ended"),
            },
            Some(sample) = next_status(&mut statuses) => {
                if let Ok(s) = sample
                    && let Sample::Value(KeyedVehicleStatus(status)) = s.value()
                {
                    let from = dds::sender(s.sample_info());
                    // Believed only from the participant that speaks for the vehicle.
                    if session.speaks_for(clock.now(), status.vehicle_id, from) {
                        ui.emit(Event::VehicleStatus {
                            vehicle: status.vehicle_id,
                            mode: Some(status.mode),
                            failsafe: status.failsafe,
                            link: crate::status::output_text(status),
                        });
                    }
                }
                Vec::new()
            }
            sample = requests.next() => match sample {
                Some(Ok(s)) => {
                    let msg = *s.value();
                    let from = dds::sender(s.sample_info());
                    tracing::debug!(?msg.ack, msg.src_id, msg.current_controller_id, stamp = msg.timestamp.0, %from, "RequestControl");
                    step(&mut session, SessionEvent::RequestControl { msg, from })
                }
                Some(Err(e)) => { malformed.warn(&e); Vec::new() }
                None => anyhow::bail!("RequestControl stream ended"),
            },
            ev = status.next() => {
                if let Some(ev) = &ev {
                    writers.routes_learn(ev);
                }
                match ev.as_ref().and_then(Discovery::of) {
                    Some(discovery) => step(&mut session, discovery_event(discovery)),
                    None => Vec::new(),
                }
            }
            _ = sleep_until(deadline) => step(&mut session, SessionEvent::Tick),
        };
        let changed = heartbeat_due || effects.iter().any(|e| !matches!(e, Effect::Write { .. }));
        let refused = writers.carry_out(domain, effects, &clock, record.as_mut(), &ui);
        // The selected vehicle is the one buttons and the console ask for: both its writers
        // now, so that an owner who accepts at once (auto-accept) is not faster than
        // discovery (measured: made at the REQUEST, the first commands of an auto-accepted
        // grant were lost until the vehicle had matched the new writer, p50 3 → 8 ms).
        if session.selected() != selected {
            selected = session.selected();
            if let Some(vehicle) = selected {
                writers.prepare(domain, vehicle);
            }
        }
        if let Some(reply) = reply {
            if let Some(why) = &refused {
                ui.emit(Event::Notice { text: why.clone() });
            }
            // The asker may have gone; nothing to do then.
            let _ = reply.send(refused.map_or(Ok(()), Err));
        } else if let Some(why) = refused {
            warn!("button: {why}");
        }
        if polled && ui.watched() {
            link = input_link(device.as_ref());
        }
        ui.show(&session, &link);
        if changed {
            let line = session.status_line();
            if line != shown {
                notify.status(&line);
                shown = line;
            }
        }
    }

    if let Some(web) = web {
        let _ = web_stop.send(());
        if let Err(e) = web.await {
            warn!(cause = %e, "web console failed");
        }
    }
    info!("operator stopping: finishing grants and releasing vehicles");
    notify.stopping("stopping: finishing grants, releasing vehicles");
    let effects = session.stop(clock.stamp());
    writers.carry_out(domain, effects, &clock, record.as_mut(), &ui);
    node.withdraw();
    // The FINISHes and disposals above are reliable writes; leaving the domain at once would
    // drop them before every reader has them (seen: a replier never resumed). Wait, bounded,
    // for the acknowledgments. Blocking is fine here: the event loop is over.
    // Each writer is named: one that had nothing unacknowledged, or whose readers all
    // answered, is quiet; a timeout means some matched reader (maybe one that has itself left)
    // did not answer in time, and those peers fall back to the command timeout.
    let wait = SHUTDOWN_ACK_WAIT;
    let mut acked = vec![
        (
            "RequestControl (FINISH)",
            writers.requests.wait_for_acknowledgments(wait),
        ),
        ("DeviceInfo (withdrawal)", node.wait_for_withdrawal(wait)),
    ];
    for writer in writers.commands.values() {
        let result = writer.wait_for_acknowledgments(wait);
        acked.push(("ControlCommand (release)", result));
    }
    for (writer, result) in acked {
        match result {
            Ok(true) => {}
            Ok(false) => warn!(
                writer,
                wait_ms = wait.as_millis() as u64,
                "a matched reader did not acknowledge before exit; it falls back to its timeout"
            ),
            Err(e) => warn!(writer, cause = ?e, "cannot wait for acknowledgments"),
        }
    }
    Ok(())
}

/// Reads every event the input has now and steps the session with each.
fn poll_input(
    device: Option<&mut Device>,
    session: &mut OperatorSession,
    clock: &Clock,
    mut record: Option<&mut JsonLines>,
) -> Vec<Effect> {
    let Some(device) = device else {
        return Vec::new();
    };
    let device = device.source();
    let mut effects = Vec::new();
    for _ in 0..INPUT_EVENTS_PER_TURN {
        let event = match device.poll(clock.now()) {
            Ok(Some(e)) => e,
            Ok(None) => break,
            Err(e) => InputEvent::Lost {
                reason: e.to_string(),
            },
        };
        if let (InputEvent::Axes(movement), Some(record)) = (&event, record.as_deref_mut()) {
            // For `rove bench input`: when each stick value was read.
            record.write(&serde_json::json!({
                "wall_us": clock.wall_micros(), "kind": "input",
                "throttle": movement.throttle, "roll": movement.roll,
            }));
        }
        effects.extend(session.step(clock.now(), clock.stamp(), SessionEvent::Input(event)));
    }
    effects
}

/// The operator's DDS writers.
struct Writers {
    /// The regular writers' strength.
    strength: Strength,
    /// ControlCommand writers, one per session writer and route, made when first needed: for a
    /// vehicle driven, requested or to drive from the start. Bounded by what this operator
    /// drives or asks for, never by what others send.
    commands: HashMap<(Writer, dds::Route), CommandWriter>,
    routes: dds::Routes,
    requests: rustdds::no_key::DataWriterCdr<RequestControl>,
    failed: RateLimited,
}

impl Writers {
    /// The session's `writer` for `vehicle`'s route, made if needed (`None` if rustdds
    /// refuses, which is logged).
    fn command_writer(
        &mut self,
        domain: &Domain,
        writer: Writer,
        vehicle: DeviceId,
    ) -> Option<&CommandWriter> {
        let route = self.routes.route(vehicle);
        match self.commands.entry((writer, route)) {
            Entry::Occupied(e) => Some(e.into_mut()),
            Entry::Vacant(e) => {
                let strength = match writer {
                    Writer::Regular => self.strength,
                    Writer::Priority => Strength::PRIORITY,
                };
                match domain.command_writer(strength, route) {
                    Ok(w) => {
                        info!(vehicle, ?route, ?writer, "ControlCommand writer made");
                        Some(e.insert(w))
                    }
                    Err(err) => {
                        self.failed.warn(&err);
                        None
                    }
                }
            }
        }
    }

    /// Both writers for `vehicle` (regular, and priority for a grant), made ahead of need.
    fn prepare(&mut self, domain: &Domain, vehicle: DeviceId) {
        for writer in [Writer::Regular, Writer::Priority] {
            self.command_writer(domain, writer, vehicle);
        }
    }

    /// Learns routes from discovery: a ControlCommand reader found, a participant gone.
    fn routes_learn(&mut self, event: &DomainParticipantStatusEvent) {
        match event {
            DomainParticipantStatusEvent::ReaderDetected { reader }
                if reader.topic_name == rove_core::msg::topic_names::CONTROL_COMMAND =>
            {
                let participant = dds::writer_id(reader.guid).participant;
                self.routes
                    .reader_found(participant, reader.qos.partition().as_ref());
            }
            DomainParticipantStatusEvent::ParticipantLost { id, .. } => {
                self.routes
                    .participant_gone(dds::participant_id(id.as_ref()));
            }
            _ => {}
        }
    }

    /// Carries out the session's effects; returns why a command was refused, if one was.
    fn carry_out(
        &mut self,
        domain: &Domain,
        effects: Vec<Effect>,
        clock: &Clock,
        mut record: Option<&mut JsonLines>,
        ui: &Ui,
    ) -> Option<String> {
        let mut refused = None;
        for effect in effects {
            match effect {
                Effect::Write { writer, command } => {
                    let Some(w) = self.command_writer(domain, writer, command.dest_id) else {
                        continue;
                    };
                    // The source timestamp lets the vehicle tell a sample that queued up from a
                    // fresh one (rove_core::freshness).
                    let stamp = Some(rustdds::Timestamp::now());
                    if let Err(e) = w.write(KeyedControlCommand(command), stamp) {
                        self.failed.warn(&e);
                    }
                }
                Effect::Release { writer, vehicle } => {
                    // Vehicles read commands best effort (dds::Domain::command_reader): a lost
                    // dispose would leave them waiting a command timeout, so it is repeated.
                    let Some(w) = self.command_writer(domain, writer, vehicle) else {
                        continue;
                    };
                    for _ in 0..RELEASE_REPEATS {
                        if let Err(e) = w.dispose(&vehicle, None) {
                            warn!(vehicle, cause = ?e, "release (dispose) failed");
                            break;
                        }
                    }
                }
                Effect::Send(msg) => {
                    // Asking for a vehicle not selected before: both writers for it now.
                    if msg.ack == Ack::Request && msg.src_id != msg.current_controller_id {
                        self.prepare(domain, msg.dest_id);
                    }
                    if let Some(record) = record.as_deref_mut() {
                        record.write(&crate::runtime::request_json(clock, &msg));
                    }
                    if let Err(e) = self.requests.write(msg, None) {
                        warn!(cause = ?e, "cannot send RequestControl");
                    }
                }
                Effect::Report(report) => ui.report(report),
                Effect::Confirm(action) => {
                    // The console confirms what would move a vehicle, then sends the command
                    // back; a full queue drops the press (the person presses again).
                    let _ = ui.actions.try_send(action);
                }
                Effect::Refused(why) => refused = Some(why),
            }
        }
        refused
    }
}

/// The console's and the local API's view of the operator: events out, button presses to the
/// console (which asks for confirmation) when one runs.
struct Ui {
    tx: tokio::sync::broadcast::Sender<Stamped>,
    clock: Clock,
    actions: tokio::sync::mpsc::Sender<InputAction>,
    /// The last input and stream snapshots sent, so only changes go out.
    shown_input: Option<UiInput>,
    shown_streams: Option<rove_core::session::Streams>,
    /// When a message that was not believed was last logged and shown: a flood of them is
    /// told at most once per [`RateLimited::INTERVAL`].
    untrusted_told: std::cell::Cell<Option<std::time::Instant>>,
}

impl Ui {
    fn emit(&self, event: Event) {
        // No receiver (no console, no API client) is not an error.
        let _ = self.tx.send(Stamped {
            at: self.clock.now(),
            event,
        });
    }

    /// Whether anyone listens: the console and the API subscribe at start or never.
    fn watched(&self) -> bool {
        self.tx.receiver_count() > 0
    }

    /// Sends the input's and the streams' state when they changed.
    fn show(&mut self, session: &OperatorSession, link: &(Option<bool>, String)) {
        let streams = session.streams();
        if self.shown_streams.as_ref() != Some(&streams) {
            self.emit(Event::Driving {
                driving: streams.driving.clone(),
                holding: streams.holding.clone(),
                standby: streams.standby.clone(),
                paused: streams.paused.clone(),
            });
            self.shown_streams = Some(streams);
        }
        if !self.watched() {
            return;
        }
        let (movement, mode, live) = session.input();
        let input = UiInput {
            movement,
            mode,
            deadman: link.0,
            live,
            link: link.1.clone(),
        };
        if self.shown_input.as_ref() != Some(&input) {
            self.emit(Event::Input(input.clone()));
            self.shown_input = Some(input);
        }
    }

    /// Logs a session report and tells the console what it shows.
    fn report(&self, report: Report) {
        if let Report::Untrusted(_) = report {
            let last = self.untrusted_told.get();
            if last.is_some_and(|t| t.elapsed() < RateLimited::INTERVAL) {
                return;
            }
            self.untrusted_told.set(Some(std::time::Instant::now()));
        }
        let vehicle = report.vehicle();
        if report.is_warning() {
            warn!(vehicle, "{report}");
        } else {
            info!(vehicle, "{report}");
        }
        let event = match report {
            Report::Selected { vehicle } => Event::Selected { vehicle },
            Report::RequestSent { vehicle, owner } => Event::RequestSent { vehicle, owner },
            Report::Prompt {
                vehicle,
                requester,
                src_priority,
                deadline,
            } => Event::RequestIncoming {
                vehicle,
                from: requester,
                src_priority,
                deadline,
            },
            Report::PromptClosed { vehicle, outcome } => Event::PromptClosed {
                vehicle,
                outcome: outcome.into(),
            },
            Report::RequestEnded { vehicle, outcome } => Event::RequestEnded {
                vehicle,
                outcome: outcome.into(),
            },
            Report::Untrusted(suspect) => Event::Notice {
                text: format!("not believed: {suspect}"),
            },
            _ => return,
        };
        self.emit(event);
    }
}
