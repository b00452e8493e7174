//! rove as the system manager toward its ground stations (the GCS operator-control protocol,
//! docs/mavlink.md, "A ground station in the hierarchy"): a station with an `id` is an operator
//! of the hierarchy, whose MANUAL_CONTROL and requests for control go to its operator loop
//! ([`crate::station::Feed`]) instead of the autopilot; every station gets rove's CONTROL_STATUS
//! (who drives, in MAVLink's words) and its requests answered. Toward the autopilot rove is a
//! ground station like any (`vehicle/manager.rs`).

use super::ground::Port;
use super::{Shared, lock, target};
use crate::control::{self, Message};
use crate::frame::{Frame, Payload, encode_raw};
use mavlink::dialects::ardupilotmega::MavMessage;
use mavlink::{MavHeader, MavlinkVersion};
use rove_core::adapter::HostedEvent;
use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};
use tracing::info;

/// MAV_COMP_ID_ONBOARD_COMPUTER: the component rove speaks as toward the stations, in the
/// autopilot's system (the protocol's system manager is a component of the vehicle).
pub const MANAGER_COMPONENT: u8 = 191;
/// How often CONTROL_STATUS goes out besides on every change (the protocol's nominal 1 Hz).
pub const STATUS_PERIOD: Duration = Duration::from_secs(1);

/// What a station's port thread keeps between its reads.
#[derive(Debug, Default)]
pub(super) struct Manager {
    /// The `gcs_main` last sent, and when.
    sent: Option<(u8, Instant)>,
    /// Who asked for control last (system, component), to be answered.
    requester: Option<(u8, u8)>,
    /// Sequence numbers of rove's frames to this station.
    sequence: u8,
}

/// Takes a station's frame for its operator loop, or answers it; `true` when it is not to go to
/// the autopilot. Sticks go to the loop of a station with an `id` (any other's are dropped by
/// the router); a request for control is the hierarchy's, whoever sends it.
pub(super) fn from_station(shared: &Shared, port: &Port, frame: &Frame) -> bool {
    let sender = u8::try_from(frame.header.system_id).ok();
    let station = port
        .station
        .as_ref()
        .filter(|s| Some(s.system_id) == sender);
    match (&frame.message, station) {
        (Payload::Mav(MavMessage::MANUAL_CONTROL(mc)), Some(s)) => {
            let sticks = crate::station::sticks(mc.x, mc.y, mc.z, mc.r);
            s.feed.heard(HostedEvent::Sticks(sticks));
            port.sticks_taken.fetch_add(1, Ordering::Relaxed);
            true
        }
        (Payload::Mav(MavMessage::HEARTBEAT(_)), Some(s)) => {
            s.feed.heard(HostedEvent::Alive(Instant::now()));
            false
        }
        (Payload::Control(Message::Request { request, .. }), _) => {
            lock(&port.manager).requester = sender.map(|sys| (sys, frame.header.component_id));
            match station {
                Some(s) => {
                    let event = if *request {
                        HostedEvent::Request
                    } else {
                        HostedEvent::Release
                    };
                    info!(
                        station = s.id,
                        request, "mavlink: a ground station asks for control, or gives it back"
                    );
                    s.feed.heard(event);
                }
                // Not an operator of the hierarchy (no `id`): it cannot drive, and has nothing
                // to give back.
                None => answer(shared, port, &mut lock(&port.manager), !*request),
            }
            true
        }
        (Payload::Control(_), _) => true,
        _ => false,
    }
}

/// Between reads: sends the hierarchy's answers to the station's requests and CONTROL_STATUS
/// (on a change of who drives, and every [`STATUS_PERIOD`]).
pub(super) fn tick(shared: &Shared, port: &Port) {
    let manager = &mut *lock(&port.manager);
    if let Some(s) = &port.station {
        for granted in s.feed.take_answers() {
            answer(shared, port, manager, granted);
        }
    }
    let gcs_main = gcs_main(shared);
    // Takeover is allowed when the hierarchy lets a request pass without asking anyone: nobody
    // drives. While an operator drives, its own auto-accept decides, which the vehicle cannot
    // promise for it.
    let flags = match gcs_main {
        0 => control::FLAG_SYSTEM_MANAGER | control::FLAG_TAKEOVER_ALLOWED,
        _ => control::FLAG_SYSTEM_MANAGER,
    };
    let due = manager
        .sent
        .is_none_or(|(sent, at)| sent != gcs_main || at.elapsed() >= STATUS_PERIOD);
    if due
        && send(
            shared,
            port,
            manager,
            (control::CONTROL_STATUS, control::CONTROL_STATUS_CRC_EXTRA),
            &[flags, gcs_main],
        )
    {
        manager.sent = Some((gcs_main, Instant::now()));
    }
}

/// Makes the station's feed tick its port at once when the hierarchy answers or control changes
/// hands, instead of at the port's next read (up to its read timeout, 100 ms, later). Weak: the
/// feed outlives nothing it points to.
pub(super) fn nudge_on_news(shared: &std::sync::Arc<Shared>, index: usize) {
    let Some(station) = shared.ground.get(index).and_then(|p| p.station.as_ref()) else {
        return;
    };
    let weak = std::sync::Arc::downgrade(shared);
    station.feed.set_nudge(Box::new(move || {
        if let Some(shared) = weak.upgrade()
            && let Some(port) = shared.ground.get(index)
        {
            tick(&shared, port);
        }
    }));
}

/// Who drives, in MAVLink's words: the system id of the station that owns the vehicle, rove's
/// own while another operator does, 0 in failsafe.
fn gcs_main(shared: &Shared) -> u8 {
    let (vehicle, owner) = (
        shared.vehicle.load(Ordering::Relaxed),
        shared.owner.load(Ordering::Relaxed),
    );
    let stations = || (shared.ground.iter()).filter_map(|p| p.station.as_ref());
    if let Some(s) = stations().find(|s| s.feed.holding()) {
        return s.system_id;
    }
    if owner == 0 || owner == vehicle {
        return 0;
    }
    stations()
        .find(|s| s.id == owner)
        .map_or(shared.system_id, |s| s.system_id)
}

/// A COMMAND_ACK of MAV_CMD_REQUEST_OPERATOR_CONTROL to the last requester.
fn answer(shared: &Shared, port: &Port, manager: &mut Manager, granted: bool) {
    let Some(requester) = manager.requester else {
        return;
    };
    let result = if granted {
        control::RESULT_ACCEPTED
    } else {
        control::RESULT_FAILED
    };
    send(
        shared,
        port,
        manager,
        control::COMMAND_ACK,
        &control::ack_payload(result, requester),
    );
}

/// Sends rove's own message to the station, as the manager component of the autopilot's system.
fn send(
    shared: &Shared,
    port: &Port,
    manager: &mut Manager,
    id: (u32, u8),
    payload: &[u8],
) -> bool {
    let Some(writer) = lock(&port.writer).clone().filter(|w| w.ready()) else {
        return false;
    };
    let system = target(shared).map_or(1, |(sys, _)| sys);
    let header = MavHeader {
        system_id: u32::from(system),
        component_id: MANAGER_COMPONENT,
        sequence: manager.sequence,
    };
    manager.sequence = manager.sequence.wrapping_add(1);
    encode_raw(MavlinkVersion::V2, header, id, payload)
        .is_ok_and(|bytes| super::ground::write_or_close(&port.writer, &writer, &bytes))
}
