//! `rove operator`: streams ControlCommand to the vehicles it drives, keeps the device list and
//! takes part in active handover as requester and replier.
//!
//! Streaming: every driven vehicle gets a sample on every input change and at least every
//! `stream_period` (keep-alive). A priority writer (strength 65535) is created at start, so its
//! discovery is done long before a grant needs it; it streams only to vehicles we hold a grant
//! for. Consent: the config's auto-accept policy decides; a request that needs a person waits
//! for the console (a later issue) and is refused at the consent timeout meanwhile.
//!
//! Stop (SIGTERM, SIGINT): held grants are finished, every instance we drive is disposed (an
//! explicit release, so the vehicle hands over at once), and the participant leaves.
//!
//! Under systemd (see [`crate::sdnotify`]): `READY=1` once the participant and every writer
//! exist, `STATUS=` with what we drive, hold and stand by for, `WATCHDOG=1` from this loop, and
//! `STOPPING=1` when the stop begins.

use crate::config::OperatorConfig;
use crate::dds::{Domain, KeyedControlCommand, KeyedDeviceInfo};
use crate::runtime::{Clock, JsonLines, RateLimited, shutdown_signal, sleep_until};
use crate::sdnotify::Notifier;
use futures::StreamExt;
use rove_core::handover::{Action, Handover};
use rove_core::hierarchy::Strength;
use rove_core::msg::{
    CommandType, ControlCommand, DeviceId, DeviceInfo, DeviceType, RequestControl,
};
use rustdds::with_key::Sample;
use std::collections::{BTreeMap, BTreeSet};
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

    let mut state = Streams {
        me,
        input: config.input,
        driving: config.drive.iter().copied().collect(),
        priority: BTreeSet::new(),
        standby: BTreeSet::new(),
        regular,
        priority_writer: priority,
        failed: RateLimited::new("ControlCommand write failed"),
    };
    let mut handover = Handover::new(me, config.strength, config.handover);
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
        let actions = tokio::select! {
            _ = &mut shutdown => break,
            _ = stream_timer.tick() => { state.send_all(&clock); Vec::new() }
            _ = heartbeat.tick() => {
                publish_info();
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
                    Some(Ok(s)) => {
                        if let Sample::Value(KeyedDeviceInfo(info)) = s.into_value()
                            && info.device_type == DeviceType::Vehicle
                        {
                            actions = handover.on_vehicle_owner(info.device_id, info.controller_id);
                            vehicles.insert(info.device_id, info);
                        }
                    }
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
            carry_out(action, &mut state, &request_writer, &clock, record.as_mut());
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
                carry_out(action, &mut state, &request_writer, &clock, record.as_mut());
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

/// What this operator streams, and its writers.
struct Streams {
    me: DeviceId,
    input: (rove_core::msg::MovementCommand, rove_core::msg::Mode),
    /// Vehicles driven with the regular writer.
    driving: BTreeSet<DeviceId>,
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

    fn send_all(&mut self, clock: &Clock) {
        let regular: Vec<_> = self.driving.iter().copied().collect();
        for v in regular {
            self.send(v, false, CommandType::Movement, clock);
        }
        let standby: Vec<_> = self.standby.iter().copied().collect();
        for v in standby {
            self.send(v, false, CommandType::Probe, clock);
        }
        let held: Vec<_> = self.priority.iter().copied().collect();
        for v in held {
            self.send(v, true, CommandType::Movement, clock);
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
            ..
        } => info!(
            vehicle,
            requester, src_priority, "control requested: consent needed (refused at timeout)"
        ),
        Action::PromptClosed { vehicle, outcome } => {
            info!(vehicle, ?outcome, "consent prompt closed")
        }
        Action::RequestEnded { vehicle, outcome } => info!(vehicle, ?outcome, "request ended"),
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
            info!(vehicle, "grant over: driving again");
            state.standby.remove(&vehicle);
            state.driving.insert(vehicle);
            state.send(vehicle, false, CommandType::Movement, clock);
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
