//! `rove operator`: streams ControlCommand to the vehicles it drives, keeps the device list and
//! takes part in active handover as requester and replier.
//!
//! Streaming: every driven vehicle gets a sample on every input change and at least every
//! `stream_period` (keep-alive). A priority writer (strength 65535) is created at start, so its
//! discovery is done long before a grant needs it; it streams only to vehicles we hold a grant
//! for. Consent: the config's auto-accept policy decides; a request that needs a person waits
//! for the console (a later issue) and is refused at the consent timeout meanwhile.
//!
//! Input (`[input]`): constant sticks drive the configured vehicles from the start. A device or
//! recording (rove-inputs) drives only while it is live: every stick change is sent at once
//! (not on the next keep-alive tick); when the device is lost (unplugged, SYN_DROPPED, silent) or
//! the deadman is let go, every vehicle we drive is released explicitly (disposed, grants
//! finished), so the hierarchy hands over at once, and driving resumes on the device's next
//! stick report, which rove-inputs holds back until the sticks are centred. Buttons: mode,
//! request (drive a free vehicle, or ask its owner), accept / refuse the open prompt, finish a
//! grant, release, select the next / previous vehicle.
//!
//! Stop (SIGTERM, SIGINT): held grants are finished, every instance we drive is disposed (an
//! explicit release, so the vehicle hands over at once), and the participant leaves.
//!
//! Under systemd (see [`crate::sdnotify`]): `READY=1` once the participant and every writer
//! exist, `STATUS=` with what we drive, hold and stand by for, `WATCHDOG=1` from this loop, and
//! `STOPPING=1` when the stop begins.

use crate::config::{InputChoice, OperatorConfig};
use crate::dds::{Domain, KeyedControlCommand, KeyedDeviceInfo};
use crate::runtime::{Clock, JsonLines, RateLimited, shutdown_signal, sleep_until};
use crate::sdnotify::Notifier;
use futures::StreamExt;
use rove_console::model::{DeviceKind, InputStatus as UiInput};
use rove_console::{Command as UiCommand, CommandRequest, ConsoleState, Event, Identity, Stamped};
use rove_core::adapter::{InputAction, InputEvent, InputSource};
use rove_core::handover::{Action, Handover};
use rove_core::hierarchy::Strength;
use rove_core::msg::{
    CommandType, ControlCommand, DeviceId, DeviceInfo, DeviceType, RequestControl,
};
use rustdds::with_key::Sample;
use std::collections::{BTreeMap, BTreeSet};
use std::sync::Arc;
use tracing::{info, warn};

type CommandWriter = rustdds::with_key::DataWriterCdr<KeyedControlCommand>;

/// Longest wait, per writer, for peers to acknowledge the final FINISH and disposals on exit.
/// Loopback acknowledges in about a millisecond; 300 ms covers a loaded radio link without
/// holding up a systemd stop noticeably. If it runs out, peers fall back to the command timeout.
const SHUTDOWN_ACK_WAIT: std::time::Duration = std::time::Duration::from_millis(300);

/// Runs the operator role until SIGTERM/SIGINT. `config_path` is named in the start-up line.
/// `request`: ask this vehicle's owner for control as soon as the vehicle is seen. `record`:
/// append every RequestControl this operator sends, with its send time, as JSON lines (the
/// instant an ACCEPT leaves, for the benchmark).
///
/// # Errors
/// The participant, a topic, a reader or writer cannot be created, or the record cannot be
/// opened.
pub async fn run(
    config: OperatorConfig,
    config_path: &std::path::Path,
    request: Option<DeviceId>,
    record: Option<&std::path::Path>,
    console: bool,
) -> anyhow::Result<()> {
    let clock = Clock::start();
    let mut notify = Notifier::from_env();
    let mut record = record.map(JsonLines::create).transpose()?;
    let me = config.common.id;
    let domain = Domain::join(config.common.domain_id, &config.common.interfaces)?;
    let regular = domain.command_writer(config.strength)?;
    let priority = domain.command_writer(Strength::PRIORITY)?;
    let request_writer = domain.request_writer()?;
    let info_writer = domain.device_info_writer()?;
    let infos = domain.device_info_reader()?;
    let requests = domain.request_reader()?;
    info!(
        config = %config_path.display(),
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

    let wake = Arc::new(tokio::sync::Notify::new());
    let (input, mut device) = match &config.input {
        InputChoice::Constant(movement, mode) => ((*movement, *mode), None),
        InputChoice::Device(input) => {
            let mut source =
                rove_inputs::open_mapped(input).map_err(|e| anyhow::anyhow!("[input]: {e}"))?;
            let waker = Arc::clone(&wake);
            source.set_waker(Arc::new(move || waker.notify_one()));
            info!(input = %source.describe(), "input opened: driving starts when its sticks are live and centred");
            (
                (
                    rove_core::msg::MovementCommand::CENTRED,
                    rove_core::msg::Mode::Manual,
                ),
                Some(source),
            )
        }
    };
    let configured: BTreeSet<DeviceId> = config.drive.iter().copied().collect();
    let mut state = Streams {
        me,
        input,
        input_live: device.is_none(),
        input_status: match &device {
            Some(d) => {
                let status = d.status();
                (status.deadman, status.to_string())
            }
            None => (None, "constant sticks (config)".to_string()),
        },
        driving: if device.is_none() {
            configured.clone()
        } else {
            BTreeSet::new()
        },
        paused: if device.is_none() {
            BTreeSet::new()
        } else {
            configured
        },
        priority: BTreeSet::new(),
        standby: BTreeSet::new(),
        selected: config.drive.first().copied(),
        prompt: None,
        regular,
        priority_writer: priority,
        failed: RateLimited::new("ControlCommand write failed"),
    };
    let mut handover = Handover::new(me, config.strength, config.handover);

    // The console and the local API see the operator through events and act through commands
    // (rove-console); both are optional.
    let identity = Identity {
        id: me,
        name: config.common.name.clone(),
        level: config.level,
        class: config.device_class,
        strength: config.strength,
    };
    let mirror = ConsoleState::new(identity.clone(), config.common.heartbeat * 3);
    let (events_tx, _) = tokio::sync::broadcast::channel::<Stamped>(1024);
    let (commands_tx, mut commands) = tokio::sync::mpsc::channel::<CommandRequest>(64);
    let (actions_tx, actions_rx) = tokio::sync::mpsc::channel::<InputAction>(64);
    let ui = Ui {
        tx: events_tx.clone(),
        clock,
        console,
        actions: actions_tx,
    };
    if let Some(path) = &config.api_socket {
        let socket = rove_console::ApiSocket::bind(path)
            .map_err(|e| anyhow::anyhow!("local API socket: {e}"))?;
        info!(path = %path.display(), "local API listening");
        let serve = socket.serve(mirror.clone(), events_tx.subscribe(), commands_tx.clone());
        tokio::spawn(async move {
            if let Err(e) = serve.await {
                warn!(cause = %e, "local API stopped");
            }
        });
    }
    let terminal = console.then(|| {
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
    ui.input(&state);
    let mut shown_driving = state.driving_event();
    ui.emit(shown_driving.clone());
    let mut vehicles: BTreeMap<DeviceId, DeviceInfo> = BTreeMap::new();
    // A request waits until the vehicle's owner is known. A vehicle that still looks ownerless
    // after two heartbeats is free: we drive it instead (the first DeviceInfo a late joiner
    // gets may be an older sample that still shows the failsafe).
    let mut request = request.map(|v| (v, clock.now() + config.common.heartbeat * 2));
    // rustdds replays a writer's history when it matches a new reader, so the first DeviceInfo
    // may name a past owner. Ask only on a sample that arrives a heartbeat after start: the
    // replay comes at match time, live samples at every heartbeat.
    let ask_after = clock.now() + config.common.heartbeat;
    let my_info = DeviceInfo {
        device_id: me,
        name: config.common.name.clone(),
        device_type: DeviceType::Controller,
        controller_id: me,
    };
    let publish_info = || {
        if let Err(e) = info_writer.write(KeyedDeviceInfo(my_info.clone()), None) {
            warn!(cause = ?e, "cannot publish DeviceInfo");
        }
    };
    publish_info();

    let mut infos = infos.async_sample_stream();
    let mut requests = requests.async_sample_stream();
    let mut stream_timer = tokio::time::interval(config.stream_period);
    stream_timer.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    let mut heartbeat = tokio::time::interval(config.common.heartbeat);
    let shutdown = shutdown_signal()?;
    tokio::pin!(shutdown);
    let mut malformed = RateLimited::new("malformed DeviceInfo or RequestControl sample");
    let mut keepalive = notify.keepalive_timer();
    let mut shown = state.status_line(vehicles.len());
    notify.ready(&shown);

    loop {
        let deadline = handover.next_deadline().map(|d| clock.instant(d));
        let input_deadline = device
            .as_ref()
            .and_then(InputSource::next_deadline)
            .map(|d| clock.instant(d));
        let actions = tokio::select! {
            _ = &mut shutdown => break,
            ended = &mut terminal, if terminal_on => {
                if let Err(e) = ended {
                    warn!(cause = %e, "console failed");
                }
                info!("console closed: stopping");
                break;
            }
            Some(req) = commands.recv() => {
                let (result, actions) = on_command(req.command, &mut state, &mut handover, &vehicles, &clock, &ui);
                if let Err(why) = &result {
                    ui.emit(Event::Notice { text: why.clone() });
                }
                let _ = req.reply.send(result);
                actions
            }
            _ = wake.notified(), if device.is_some() => {
                poll_input(device.as_mut(), &mut state, &mut handover, &vehicles, &clock, record.as_mut(), &ui)
            }
            _ = sleep_until(input_deadline), if input_deadline.is_some() => {
                poll_input(device.as_mut(), &mut state, &mut handover, &vehicles, &clock, record.as_mut(), &ui)
            }
            _ = stream_timer.tick() => { state.send_all(&clock); Vec::new() }
            _ = heartbeat.tick() => {
                publish_info();
                ui.emit(Event::Tick);
                let line = state.status_line(vehicles.len());
                if line != shown {
                    notify.status(&line);
                    shown = line;
                }
                Vec::new()
            }
            // From this loop, so that a hung loop stops the keep-alives.
            _ = keepalive.tick() => { notify.keepalive(); Vec::new() }
            sample = infos.next() => {
                // A yielded vehicle's published owner can show that its grant is over.
                let mut actions = Vec::new();
                match sample {
                    Some(Ok(s)) => match s.into_value() {
                        Sample::Value(KeyedDeviceInfo(info)) => {
                            ui.emit(Event::DeviceSeen {
                                id: info.device_id,
                                name: info.name.clone(),
                                kind: if info.device_type == DeviceType::Vehicle {
                                    DeviceKind::Vehicle
                                } else {
                                    DeviceKind::Controller
                                },
                                owner: info.controller_id,
                            });
                            if info.device_type == DeviceType::Vehicle {
                                actions = handover.on_vehicle_owner(info.device_id, info.controller_id);
                                vehicles.insert(info.device_id, info);
                            }
                        }
                        Sample::Dispose(id) => {
                            ui.emit(Event::DeviceGone { id });
                        }
                    },
                    Some(Err(e)) => malformed.warn(&e),
                    None => anyhow::bail!("DeviceInfo stream ended"),
                }
                // Ask once the vehicle and its owner are known.
                let info_is_live = clock.now() >= ask_after;
                match request
                    .filter(|_| info_is_live)
                    .and_then(|(v, free_after)| Some((vehicles.get(&v)?, free_after)))
                {
                    // Names us: true only if we stream to it; otherwise it is an older
                    // sample (a previous process with our id), so wait for a fresher one.
                    Some((v, _)) if v.controller_id == me && state.streams_to(v.device_id) => {
                        info!(vehicle = v.device_id, "already driving it: no request needed");
                        request = None;
                    }
                    Some((v, _)) if v.controller_id == me => {}
                    Some((v, free_after))
                        if v.controller_id == v.device_id && clock.now() >= free_after =>
                    {
                        info!(vehicle = v.device_id, "vehicle is free: driving it, no request needed");
                        state.driving.insert(v.device_id);
                        request = None;
                    }
                    // Looks free, but may be an old sample: wait for the next heartbeat.
                    Some((v, _)) if v.controller_id == v.device_id => {}
                    Some((v, _)) => {
                        let (vehicle, owner) = (v.device_id, v.controller_id);
                        request = None;
                        match handover.request(clock.now(), vehicle, owner, clock.stamp()) {
                            Ok(more) => {
                                info!(vehicle, owner, "requesting control");
                                ui.emit(Event::RequestSent { vehicle, owner });
                                actions.extend(more);
                            }
                            Err(e) => warn!(vehicle, owner, cause = %e, "cannot request control"),
                        }
                    }
                    None => {}
                }
                actions
            }
            sample = requests.next() => match sample {
                Some(Ok(s)) => {
                    let rc = s.value();
                    tracing::debug!(?rc.ack, rc.src_id, rc.current_controller_id, stamp = rc.timestamp.0, "RequestControl");
                    handover.on_message(clock.now(), rc)
                }
                Some(Err(e)) => { malformed.warn(&e); Vec::new() }
                None => anyhow::bail!("RequestControl stream ended"),
            },
            _ = sleep_until(deadline) => handover.tick(clock.now()),
        };
        let changed = !actions.is_empty();
        for action in actions {
            carry_out(
                action,
                &mut state,
                &request_writer,
                &clock,
                record.as_mut(),
                &ui,
            );
        }
        let driving = state.driving_event();
        if driving != shown_driving {
            ui.emit(driving.clone());
            shown_driving = driving;
        }
        if changed {
            let line = state.status_line(vehicles.len());
            if line != shown {
                notify.status(&line);
                shown = line;
            }
        }
    }

    info!("operator stopping: finishing grants and releasing vehicles");
    notify.stopping("stopping: finishing grants, releasing vehicles");
    let held: Vec<DeviceId> = state.priority.iter().copied().collect();
    for vehicle in held {
        if let Ok(actions) = handover.finish(vehicle) {
            for action in actions {
                carry_out(
                    action,
                    &mut state,
                    &request_writer,
                    &clock,
                    record.as_mut(),
                    &ui,
                );
            }
        }
    }
    state.release_all();
    // Leave the device lists at once rather than after missed heartbeats.
    if let Err(e) = info_writer.dispose(&me, None) {
        warn!(cause = ?e, "cannot withdraw DeviceInfo");
    }
    // The FINISHes and disposals above are reliable writes; leaving the domain at once would
    // drop them before every reader has them (seen: a replier never resumed). Wait, bounded,
    // for the acknowledgments. Blocking is fine here: the event loop is over.
    let wait = SHUTDOWN_ACK_WAIT;
    let acked = [
        request_writer.wait_for_acknowledgments(wait),
        state.regular.wait_for_acknowledgments(wait),
        state.priority_writer.wait_for_acknowledgments(wait),
        info_writer.wait_for_acknowledgments(wait),
    ];
    if !acked.iter().all(|r| matches!(r, Ok(true))) {
        warn!("not every peer acknowledged the release before exit");
    }
    Ok(())
}

/// The console's and the local API's view of the operator: events out, button presses to the
/// console (which asks for confirmation) when one runs.
struct Ui {
    tx: tokio::sync::broadcast::Sender<Stamped>,
    clock: Clock,
    console: bool,
    actions: tokio::sync::mpsc::Sender<InputAction>,
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

    fn input(&self, state: &Streams) {
        if !self.watched() {
            return;
        }
        self.emit(Event::Input(UiInput {
            movement: state.input.0,
            mode: state.input.1,
            deadman: state.input_status.0,
            live: state.input_live,
            link: state.input_status.1.clone(),
        }));
    }
}

/// Reads every event the input has now and acts on it; returns the handover's actions.
fn poll_input(
    device: Option<&mut rove_inputs::MappedSource>,
    state: &mut Streams,
    handover: &mut Handover,
    vehicles: &BTreeMap<DeviceId, DeviceInfo>,
    clock: &Clock,
    mut record: Option<&mut JsonLines>,
    ui: &Ui,
) -> Vec<Action> {
    let Some(device) = device else {
        return Vec::new();
    };
    let mut actions = Vec::new();
    let mut moved = false;
    let mut seen = false;
    // Bounded: a source cannot keep this loop from the rest of the operator.
    for _ in 0..256 {
        let event = match device.poll(clock.now()) {
            Ok(Some(e)) => e,
            Ok(None) => break,
            Err(e) => InputEvent::Lost {
                reason: e.to_string(),
            },
        };
        seen = true;
        match event {
            InputEvent::Axes(movement) => {
                if let Some(record) = record.as_deref_mut() {
                    // For `rove bench input`: when each stick value was read.
                    record.write(&serde_json::json!({
                        "wall_us": clock.wall_micros(), "kind": "input",
                        "throttle": movement.throttle, "roll": movement.roll,
                    }));
                }
                state.input.0 = movement;
                if !state.input_live {
                    state.input_live = true;
                    let resumed: Vec<DeviceId> =
                        std::mem::take(&mut state.paused).into_iter().collect();
                    info!(vehicles = ?resumed, "input live: driving");
                    state.driving.extend(resumed);
                }
                moved = true;
            }
            InputEvent::Deadman(true) => {}
            InputEvent::Deadman(false) => {
                actions.extend(state.stop_driving(handover, "deadman released"));
            }
            InputEvent::Lost { reason } => {
                actions.extend(state.stop_driving(handover, &reason));
            }
            InputEvent::Action(action) if ui.console => {
                // The console confirms what would move a vehicle, then sends the command back.
                let _ = ui.actions.try_send(action);
            }
            InputEvent::Action(action) => {
                if let Some(command) = action_to_command(action, state, vehicles, ui) {
                    let (result, more) = on_command(command, state, handover, vehicles, clock, ui);
                    if let Err(why) = result {
                        warn!(?action, "{why}");
                    }
                    actions.extend(more);
                }
            }
        }
    }
    if moved {
        // Event-driven: the change leaves now, not on the next keep-alive tick.
        state.send_driven(clock);
    }
    if seen && ui.watched() {
        let status = device.status();
        state.input_status = (status.deadman, status.to_string());
        ui.input(state);
    }
    actions
}

/// A button or key without the console: the command it means for the selected vehicle.
fn action_to_command(
    action: InputAction,
    state: &mut Streams,
    vehicles: &BTreeMap<DeviceId, DeviceInfo>,
    ui: &Ui,
) -> Option<UiCommand> {
    let selected = state.selected;
    match action {
        InputAction::Mode(mode) => Some(UiCommand::Mode {
            vehicle: None,
            mode,
        }),
        InputAction::NextVehicle | InputAction::PreviousVehicle => {
            let ids: Vec<DeviceId> = vehicles.keys().copied().collect();
            let at = selected.and_then(|s| ids.iter().position(|&v| v == s));
            let next = match (action, at) {
                (_, None) => ids.first().copied(),
                (InputAction::NextVehicle, Some(i)) => ids.get((i + 1) % ids.len()).copied(),
                (_, Some(i)) => ids.get((i + ids.len() - 1) % ids.len()).copied(),
            };
            state.selected = next;
            info!(vehicle = ?next, "vehicle selected");
            ui.emit(Event::Selected { vehicle: next });
            None
        }
        InputAction::RequestControl => selected.map(|vehicle| UiCommand::Request { vehicle }),
        InputAction::Accept => state.prompt.map(|vehicle| UiCommand::Accept { vehicle }),
        InputAction::Refuse => state.prompt.map(|vehicle| UiCommand::Refuse { vehicle }),
        InputAction::Finish => {
            let held = selected.filter(|s| state.priority.contains(s)).or(state
                .priority
                .iter()
                .next()
                .copied());
            held.map(|vehicle| UiCommand::Finish { vehicle })
        }
        InputAction::Release => Some(UiCommand::Release { vehicle: selected }),
    }
}

/// A command from the console, the local API or (headless) a button: the single path by which
/// a person changes what this operator does.
fn on_command(
    command: UiCommand,
    state: &mut Streams,
    handover: &mut Handover,
    vehicles: &BTreeMap<DeviceId, DeviceInfo>,
    clock: &Clock,
    ui: &Ui,
) -> (Result<(), String>, Vec<Action>) {
    let now = clock.now();
    let owner_of = |v: DeviceId| vehicles.get(&v).map(|i| i.controller_id);
    match command {
        UiCommand::Select { vehicle } => {
            state.selected = Some(vehicle);
            ui.emit(Event::Selected {
                vehicle: Some(vehicle),
            });
            (Ok(()), Vec::new())
        }
        UiCommand::Mode { mode, .. } => {
            info!(?mode, "mode selected");
            state.input.1 = mode;
            state.send_driven(clock);
            ui.input(state);
            (Ok(()), Vec::new())
        }
        UiCommand::Drive { vehicle } => {
            if state.streams_to(vehicle) {
                return (Ok(()), Vec::new());
            }
            match owner_of(vehicle) {
                None => (
                    Err(format!("vehicle {vehicle} has not been seen")),
                    Vec::new(),
                ),
                Some(owner) if owner != vehicle && owner != state.me => (
                    Err(format!(
                        "vehicle {vehicle} is driven by {owner}: request control instead"
                    )),
                    Vec::new(),
                ),
                Some(_) => {
                    info!(vehicle, "driving it");
                    state.selected = Some(vehicle);
                    if state.input_live {
                        state.driving.insert(vehicle);
                        state.send(vehicle, false, CommandType::Movement, clock);
                    } else {
                        state.paused.insert(vehicle);
                    }
                    (Ok(()), Vec::new())
                }
            }
        }
        UiCommand::Release { vehicle } => {
            let targets: Vec<DeviceId> = match vehicle {
                Some(v) => vec![v],
                None => state
                    .driving
                    .iter()
                    .chain(&state.paused)
                    .chain(&state.priority)
                    .copied()
                    .collect(),
            };
            let mut actions = Vec::new();
            for v in targets {
                info!(vehicle = v, "released by the operator");
                state.paused.remove(&v);
                if state.driving.remove(&v) {
                    state.release(v, false);
                }
                if state.priority.contains(&v) {
                    actions.extend(handover.finish(v).unwrap_or_default());
                }
            }
            (Ok(()), actions)
        }
        UiCommand::Request { vehicle } => match owner_of(vehicle) {
            None => (
                Err(format!("vehicle {vehicle} has not been seen")),
                Vec::new(),
            ),
            Some(owner) if owner == vehicle || owner == state.me => on_command(
                UiCommand::Drive { vehicle },
                state,
                handover,
                vehicles,
                clock,
                ui,
            ),
            Some(owner) => match handover.request(now, vehicle, owner, clock.stamp()) {
                Ok(actions) => {
                    info!(vehicle, owner, "requesting control");
                    ui.emit(Event::RequestSent { vehicle, owner });
                    (Ok(()), actions)
                }
                Err(e) => (Err(format!("cannot request {vehicle}: {e}")), Vec::new()),
            },
        },
        UiCommand::Accept { vehicle } | UiCommand::Refuse { vehicle } => {
            let accept = matches!(command, UiCommand::Accept { .. });
            match handover.decide(now, vehicle, accept) {
                Ok(actions) => (Ok(()), actions),
                Err(e) => (
                    Err(format!("no answer taken for {vehicle}: {e}")),
                    Vec::new(),
                ),
            }
        }
        UiCommand::Finish { vehicle } => match handover.finish(vehicle) {
            Ok(actions) => (Ok(()), actions),
            Err(e) => (Err(format!("cannot finish {vehicle}: {e}")), Vec::new()),
        },
    }
}

/// What this operator streams, and its writers.
struct Streams {
    me: DeviceId,
    input: (rove_core::msg::MovementCommand, rove_core::msg::Mode),
    /// The input may drive (constant input: always; a device: live and deadman held).
    input_live: bool,
    /// The deadman (`None`: none configured) and the input's one-line state, for the console.
    input_status: (Option<bool>, String),
    /// Vehicles driven with the regular writer.
    driving: BTreeSet<DeviceId>,
    /// Vehicles released while the input is not live; driven again when it is.
    paused: BTreeSet<DeviceId>,
    /// The vehicle that buttons act on.
    selected: Option<DeviceId>,
    /// The vehicle whose control request waits for our answer.
    prompt: Option<DeviceId>,
    /// Vehicles driven with the priority writer (grants held).
    priority: BTreeSet<DeviceId>,
    /// Vehicles yielded to a grant holder: PROBEs on the regular writer keep us the vehicle's
    /// fallback, so it returns to us (not to a bystander) when the grant ends.
    standby: BTreeSet<DeviceId>,
    regular: CommandWriter,
    priority_writer: CommandWriter,
    failed: RateLimited,
}

impl Streams {
    fn command(&self, vehicle: DeviceId, kind: CommandType, clock: &Clock) -> KeyedControlCommand {
        KeyedControlCommand(ControlCommand {
            src_id: self.me,
            dest_id: vehicle,
            command_type: kind,
            movement_command: self.input.0,
            mode: self.input.1,
            timestamp: clock.stamp(),
        })
    }

    /// The `STATUS=` line for what we stream now.
    fn status_line(&self, vehicles_seen: usize) -> String {
        status_line(&self.driving, &self.priority, &self.standby, vehicles_seen)
    }

    fn streams_to(&self, vehicle: DeviceId) -> bool {
        self.driving.contains(&vehicle) || self.priority.contains(&vehicle)
    }

    fn send(&mut self, vehicle: DeviceId, priority: bool, kind: CommandType, clock: &Clock) {
        let sample = self.command(vehicle, kind, clock);
        let writer = if priority {
            &self.priority_writer
        } else {
            &self.regular
        };
        if let Err(e) = writer.write(sample, None) {
            self.failed.warn(&e);
        }
    }

    /// What the console shows as "you drive".
    fn driving_event(&self) -> Event {
        Event::Driving {
            driving: self.driving.iter().copied().collect(),
            holding: self.priority.iter().copied().collect(),
            standby: self.standby.iter().copied().collect(),
            paused: self.paused.iter().copied().collect(),
        }
    }

    /// A fresh sample to every vehicle we drive (not the standby PROBEs).
    fn send_driven(&mut self, clock: &Clock) {
        let regular: Vec<_> = self.driving.iter().copied().collect();
        for v in regular {
            self.send(v, false, CommandType::Movement, clock);
        }
        let held: Vec<_> = self.priority.iter().copied().collect();
        for v in held {
            self.send(v, true, CommandType::Movement, clock);
        }
    }

    /// The input cannot be trusted: release everything we drive, explicitly, so the vehicles
    /// hand over at once; grants are finished. Driving resumes on live input.
    fn stop_driving(&mut self, handover: &mut Handover, why: &str) -> Vec<Action> {
        if !self.input_live {
            return Vec::new();
        }
        self.input_live = false;
        let regular: Vec<DeviceId> = std::mem::take(&mut self.driving).into_iter().collect();
        warn!(reason = why, vehicles = ?regular, "input not live: releasing control");
        for &v in &regular {
            self.release(v, false);
        }
        self.paused.extend(regular);
        let mut actions = Vec::new();
        let held: Vec<DeviceId> = self.priority.iter().copied().collect();
        for v in held {
            actions.extend(handover.finish(v).unwrap_or_default());
        }
        actions
    }

    /// The keep-alive: every driven vehicle, and PROBEs to those we stand by for.
    fn send_all(&mut self, clock: &Clock) {
        self.send_driven(clock);
        let standby: Vec<_> = self.standby.iter().copied().collect();
        for v in standby {
            self.send(v, false, CommandType::Probe, clock);
        }
    }

    fn release(&mut self, vehicle: DeviceId, priority: bool) {
        let writer = if priority {
            &self.priority_writer
        } else {
            &self.regular
        };
        if let Err(e) = writer.dispose(&vehicle, None) {
            warn!(vehicle, cause = ?e, "release (dispose) failed");
        }
    }

    fn release_all(&mut self) {
        let mut regular = std::mem::take(&mut self.driving);
        regular.append(&mut self.standby);
        for v in regular {
            self.release(v, false);
        }
        let held: Vec<_> = std::mem::take(&mut self.priority).into_iter().collect();
        for v in held {
            self.release(v, true);
        }
    }
}

/// The `STATUS=` line, e.g. `driving 100; holding a grant for 101; 3 vehicles seen`.
fn status_line(
    driving: &BTreeSet<DeviceId>,
    priority: &BTreeSet<DeviceId>,
    standby: &BTreeSet<DeviceId>,
    vehicles_seen: usize,
) -> String {
    let list = |set: &BTreeSet<DeviceId>| {
        set.iter()
            .map(DeviceId::to_string)
            .collect::<Vec<_>>()
            .join(", ")
    };
    let mut parts = Vec::new();
    if driving.is_empty() && priority.is_empty() && standby.is_empty() {
        parts.push("driving nothing".to_string());
    }
    if !driving.is_empty() {
        parts.push(format!("driving {}", list(driving)));
    }
    if !priority.is_empty() {
        parts.push(format!("holding a grant for {}", list(priority)));
    }
    if !standby.is_empty() {
        parts.push(format!("standing by for {}", list(standby)));
    }
    parts.push(match vehicles_seen {
        1 => "1 vehicle seen".to_string(),
        n => format!("{n} vehicles seen"),
    });
    parts.join("; ")
}

fn carry_out(
    action: Action,
    state: &mut Streams,
    requests: &rustdds::no_key::DataWriterCdr<RequestControl>,
    clock: &Clock,
    record: Option<&mut JsonLines>,
    ui: &Ui,
) {
    match action {
        Action::Send(msg) => {
            if let Some(record) = record {
                record.write(&crate::runtime::request_json(clock, &msg));
            }
            if let Err(e) = requests.write(msg, None) {
                warn!(cause = ?e, "cannot send RequestControl");
            }
        }
        Action::AskOperator {
            vehicle,
            requester,
            src_priority,
            deadline,
        } => {
            state.prompt = Some(vehicle);
            ui.emit(Event::RequestIncoming {
                vehicle,
                from: requester,
                src_priority,
                deadline,
            });
            info!(
                vehicle,
                requester,
                src_priority,
                "control requested: consent needed (accept / refuse button; refused at timeout)"
            )
        }
        Action::PromptClosed { vehicle, outcome } => {
            if state.prompt == Some(vehicle) {
                state.prompt = None;
            }
            ui.emit(Event::PromptClosed {
                vehicle,
                outcome: outcome.into(),
            });
            info!(vehicle, ?outcome, "consent prompt closed")
        }
        Action::RequestEnded { vehicle, outcome } => {
            ui.emit(Event::RequestEnded {
                vehicle,
                outcome: outcome.into(),
            });
            info!(vehicle, ?outcome, "request ended")
        }
        Action::StartPriorityDriving { vehicle } => {
            info!(vehicle, "grant received: driving with the priority writer");
            state.priority.insert(vehicle);
            state.send(vehicle, true, CommandType::Movement, clock);
        }
        Action::StopPriorityDriving { vehicle } => {
            info!(vehicle, "grant given back");
            state.priority.remove(&vehicle);
            state.release(vehicle, true);
        }
        Action::Yield { vehicle } => {
            info!(vehicle, "yielding to the grant holder (standing by)");
            state.driving.remove(&vehicle);
            state.standby.insert(vehicle);
            state.send(vehicle, false, CommandType::Probe, clock);
        }
        Action::EndStandby { vehicle } => {
            info!(vehicle, "grant holder never took over: standby ends");
            state.standby.remove(&vehicle);
        }
        Action::Resume { vehicle } => {
            state.standby.remove(&vehicle);
            if state.input_live {
                info!(vehicle, "grant over: driving again");
                state.driving.insert(vehicle);
                state.send(vehicle, false, CommandType::Movement, clock);
            } else {
                info!(vehicle, "grant over: driving again once the input is live");
                state.paused.insert(vehicle);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn set(ids: &[DeviceId]) -> BTreeSet<DeviceId> {
        ids.iter().copied().collect()
    }

    #[test]
    fn status_line_says_what_we_drive_hold_and_stand_by_for() {
        let none = set(&[]);
        assert_eq!(
            status_line(&none, &none, &none, 0),
            "driving nothing; 0 vehicles seen"
        );
        assert_eq!(
            status_line(&set(&[100, 102]), &none, &none, 1),
            "driving 100, 102; 1 vehicle seen"
        );
        assert_eq!(
            status_line(&set(&[100]), &set(&[101]), &set(&[103]), 3),
            "driving 100; holding a grant for 101; standing by for 103; 3 vehicles seen"
        );
    }
}
