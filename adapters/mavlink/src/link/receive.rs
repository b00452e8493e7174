//! The link's reader thread: opens the transport (again after an error, every [`RECONNECT`]),
//! reads and decodes, and keeps in [`LinkStatus`] what our autopilot's
//! messages say: its HEARTBEAT, its COMMAND_ACKs for a mode, its battery; and keeps what it
//! learned in the memory file.

use super::transport::{ReadOutcome, classify_read, open};
use super::{
    ACK_QUEUE, AutopilotInfo, Battery, LinkStatus, READ_CHUNK, RECONNECT, Shared, lock, target,
};
use crate::control;
use crate::frame::{Decoder, Payload};
use crate::memory::Learned;
use crate::mode::AckResult;
use mavlink::MavHeader;
use mavlink::dialects::ardupilotmega::{
    MavAutopilot, MavCmd, MavMessage, MavModeFlag, MavResult, MavType,
};
use std::sync::Arc;
use std::sync::atomic::Ordering;
use std::time::Instant;
use tracing::{debug, info, warn};

pub(super) fn run(shared: &Shared) {
    let mut logged_error: Option<String> = None;
    let mut decoder = Decoder::new();
    let mut buf = vec![0u8; READ_CHUNK];
    while !shared.stop.load(Ordering::Relaxed) {
        let (mut reader, writer) = match open(&shared.endpoint, &shared.peer) {
            Ok(c) => c,
            Err(e) => {
                let why = format!("{}: {e}", shared.endpoint);
                if logged_error.as_deref() != Some(why.as_str()) {
                    warn!(error = %why, "mavlink: cannot open the link; retrying every {RECONNECT:?}");
                    logged_error = Some(why.clone());
                }
                let mut s = lock(&shared.status);
                s.connected = false;
                s.error = Some(e.to_string());
                drop(s);
                std::thread::sleep(RECONNECT);
                continue;
            }
        };
        info!(endpoint = %shared.endpoint, "mavlink: link open");
        logged_error = None;
        decoder.clear();
        {
            let mut s = lock(&shared.status);
            s.connected = true;
            s.error = None;
            s.connects += 1;
        }
        *lock(&shared.writer) = Some(Arc::new(writer));
        // A waiter with a configured target needs only an open transport.
        notify(shared);
        while !shared.stop.load(Ordering::Relaxed) {
            match reader.read(&mut buf) {
                Ok((n, new_peer)) => {
                    if new_peer {
                        // A udpin waiter needs the address; `rove failsafe` needs it kept.
                        notify(shared);
                        remember(shared);
                    }
                    decoder.push(buf.get(..n).unwrap_or(&buf));
                    let skipped = decoder.skipped();
                    while let Some(frame) = decoder.next_frame() {
                        super::ground::to_stations(shared, &frame.message, decoder.raw());
                        match &frame.message {
                            Payload::Mav(msg) => handle(shared, frame.header, msg),
                            Payload::Control(msg) => handle_control(shared, frame.header, *msg),
                        }
                    }
                    let more = decoder.skipped() - skipped;
                    if more > 0 {
                        debug!(
                            bytes = more,
                            "mavlink: skipped bytes that are not a message"
                        );
                        lock(&shared.status).garbage += more;
                    }
                }
                Err(e) => match classify_read(&e) {
                    ReadOutcome::Idle => {}
                    ReadOutcome::Reconnect => {
                        warn!(endpoint = %shared.endpoint, error = %e, "mavlink: link lost; reconnecting");
                        let mut s = lock(&shared.status);
                        s.connected = false;
                        s.error = Some(e.to_string());
                        break;
                    }
                },
            }
        }
        *lock(&shared.writer) = None;
        if !shared.stop.load(Ordering::Relaxed) {
            std::thread::sleep(RECONNECT);
        }
    }
}

fn notify(shared: &Shared) {
    *lock(&shared.generation) += 1;
    shared.news.notify_all();
}

/// Keeps what the link learned in the memory file, when it changed (the udpin peer, the
/// autopilot's ids); the [`Keeper`](crate::memory::Keeper) writes it on its own thread.
fn remember(shared: &Shared) {
    let Some(keeper) = &shared.keeper else {
        return;
    };
    // Whom the link addresses: a udpin link's address is worth keeping with a configured
    // target even before the first HEARTBEAT.
    let Some((system_id, component_id)) = target(shared) else {
        return;
    };
    keeper.keep(Learned {
        endpoint: shared.endpoint.to_string(),
        peer: *lock(&shared.peer),
        system_id,
        component_id,
    });
}

/// The system id our autopilot speaks as: the configured target, else the one heard, else the
/// one an earlier run learned; `None` until one of these is known.
fn expected_system(shared: &Shared, status: &LinkStatus) -> Option<u8> {
    (shared.target_system)
        .or(status.autopilot.map(|a| a.system_id))
        .or(shared.learned.map(|(sys, _)| sys))
}

pub(super) fn handle(shared: &Shared, header: MavHeader, msg: &MavMessage) {
    let mut s = lock(&shared.status);
    let expected = expected_system(shared, &s);
    // Until an autopilot is heard (and without a configured target), any autopilot's
    // HEARTBEAT locks on, even one other than an earlier run learned.
    let lock_on = shared.target_system.is_none()
        && s.autopilot.is_none()
        && matches!(msg, MavMessage::HEARTBEAT(_));
    let ours = lock_on || expected.is_none_or(|sys| header.system_id == u32::from(sys));
    if !ours {
        s.foreign += 1;
        return;
    }
    // MAVLink 2 allows system ids above 255 in principle; no autopilot we drive uses one.
    let Ok(system_id) = u8::try_from(header.system_id) else {
        s.foreign += 1;
        return;
    };
    match msg {
        MavMessage::HEARTBEAT(hb) => {
            let is_autopilot = hb.mavtype != MavType::MAV_TYPE_GCS
                && hb.autopilot != MavAutopilot::MAV_AUTOPILOT_INVALID;
            let component_ok = shared
                .target_component
                .is_none_or(|c| c == header.component_id);
            if !is_autopilot || !component_ok {
                return;
            }
            let info = AutopilotInfo {
                system_id,
                component_id: header.component_id,
                mav_type: hb.mavtype as u32,
                autopilot: hb.autopilot as u32,
                custom_mode: hb.custom_mode,
                armed: hb
                    .base_mode
                    .contains(MavModeFlag::MAV_MODE_FLAG_SAFETY_ARMED),
            };
            let known = s.autopilot.map(|a| (a.system_id, a.component_id));
            if known != Some((info.system_id, info.component_id)) {
                // Another autopilot: the last one's battery is not this one's.
                s.battery = None;
            }
            s.autopilot = Some(info);
            s.last_heartbeat = Some(Instant::now());
            drop(s);
            notify(shared);
            if known != Some((info.system_id, info.component_id)) {
                // Handed to the keeper before it is announced (written within milliseconds).
                remember(shared);
            }
            if known.is_none() {
                info!(
                    system = info.system_id,
                    component = info.component_id,
                    autopilot = ?hb.autopilot,
                    mav_type = ?hb.mavtype,
                    "mavlink: autopilot found"
                );
            }
        }
        MavMessage::COMMAND_ACK(_) if expected.is_none() => {}
        MavMessage::COMMAND_ACK(ack) => {
            // A ground station's mode command is answered to the station (MAVLink 1 acks
            // have no target: 0).
            let for_us = ack.target_system == 0 || ack.target_system == shared.system_id;
            if ack.command != MavCmd::MAV_CMD_DO_SET_MODE || !for_us {
                return;
            }
            let result = match ack.result {
                MavResult::MAV_RESULT_ACCEPTED => AckResult::Accepted,
                MavResult::MAV_RESULT_IN_PROGRESS => AckResult::InProgress,
                MavResult::MAV_RESULT_TEMPORARILY_REJECTED => AckResult::TemporarilyRejected,
                MavResult::MAV_RESULT_DENIED => AckResult::Refused("MAV_RESULT_DENIED"),
                MavResult::MAV_RESULT_UNSUPPORTED => AckResult::Refused("MAV_RESULT_UNSUPPORTED"),
                MavResult::MAV_RESULT_FAILED => AckResult::Refused("MAV_RESULT_FAILED"),
                _ => AckResult::Refused("a refusal"),
            };
            s.acked_by = Some((system_id, header.component_id));
            drop(s);
            let mut acks = lock(&shared.acks);
            if acks.len() >= ACK_QUEUE {
                acks.pop_front();
            }
            acks.push_back(result);
            drop(acks);
            notify(shared);
        }
        // The battery of the autopilot we drive (its component; before it is heard, nothing).
        MavMessage::SYS_STATUS(st)
            if s.autopilot.is_some_and(|a| {
                a.system_id == system_id && a.component_id == header.component_id
            }) =>
        {
            s.battery = Some(Battery {
                mv: (st.voltage_battery != u16::MAX).then_some(u32::from(st.voltage_battery)),
                pct: u8::try_from(st.battery_remaining)
                    .ok()
                    .filter(|p| *p <= 100),
            });
        }
        _ => {}
    }
}

/// A message of the operator-control protocol from our autopilot (docs/mavlink.md, "An
/// autopilot that manages its ground stations"): its system manager's CONTROL_STATUS, a request
/// for control it forwards to rove, or its answer to rove's own.
fn handle_control(shared: &Shared, header: MavHeader, msg: control::Message) {
    let mut s = lock(&shared.status);
    let ours = expected_system(shared, &s).is_some_and(|sys| header.system_id == u32::from(sys));
    if !ours {
        s.foreign += 1;
        return;
    }
    match msg {
        control::Message::Status { flags, gcs_main } => {
            let before = s.control.standing(shared.system_id, Instant::now());
            s.control
                .heard(header.component_id, flags, gcs_main, Instant::now());
            let after = s.control.standing(shared.system_id, Instant::now());
            drop(s);
            if before != after {
                info!(
                    ?after,
                    gcs_main, "mavlink: the autopilot's system manager says who is in control"
                );
                notify(shared);
            }
        }
        control::Message::Request { target, .. } if target.0 == shared.system_id => {
            drop(s);
            let mut forwarded = lock(&shared.forwarded);
            if forwarded.len() < ACK_QUEUE {
                forwarded.push_back(msg);
            }
            drop(forwarded);
            notify(shared);
        }
        control::Message::Ack {
            result,
            target_system,
        } if target_system == 0 || target_system == shared.system_id => {
            drop(s);
            info!(
                result,
                "mavlink: the autopilot answered rove's request for control (0 granted; 4 the \
                 station in control is asked)"
            );
        }
        _ => {}
    }
}
