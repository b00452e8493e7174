//! Ground stations (QGroundControl, Mission Planner) that reach the autopilot through rove, as
//! mavlink-router routes a link: one thread per `[[output.gcs]]` endpoint.
//!
//! - Autopilot → stations: every frame the link's reader decodes (telemetry, parameters,
//!   mission items, COMMAND_ACKs, logs; from the autopilot and any other system on its link)
//!   goes to every station whose port can send, as received: its sequence number, sender and
//!   signature unchanged.
//! - Station → autopilot: every frame goes to the autopilot's link as received, once, except
//!   sticks: MANUAL_CONTROL and RC_CHANNELS_OVERRIDE are dropped ([`from_station`]), because the
//!   hierarchy decides who drives and rove's own control messages carry the owner's sticks.
//!   Everything else (parameters, missions, mode and arming commands) passes: docs/mavlink.md,
//!   "Sharing the autopilot with a ground station", says why.
//! - Frames of message ids the `ardupilotmega` dialect does not know are not forwarded (their
//!   CRC cannot be checked); nor is one station's traffic sent to another station.

use super::transport::{ReadOutcome, Writer, accept, classify_read, listen, open};
use super::{READ_CHUNK, RECONNECT, Shared, lock};
use crate::config::Endpoint;
use crate::frame::{Decoder, Frame, Payload};
use mavlink::dialects::ardupilotmega::MavMessage;
use std::net::{SocketAddr, TcpListener};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use tracing::{info, warn};

/// What becomes of a message a ground station sent.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Verdict {
    /// Passed to the autopilot as received.
    Forward,
    /// Sticks: dropped (rove's control messages carry the owner's).
    Sticks,
}

/// What becomes of `msg` from a ground station (pure).
pub fn from_station(msg: &Payload) -> Verdict {
    match msg {
        Payload::Mav(MavMessage::MANUAL_CONTROL(_) | MavMessage::RC_CHANNELS_OVERRIDE(_)) => {
            Verdict::Sticks
        }
        // The operator-control protocol never gets here (rove answers it, `stations.rs`); by
        // itself it is a command like any.
        _ => Verdict::Forward,
    }
}

/// A ground station's counters, as [`super::Link::stations`] reports them.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct StationStatus {
    /// Its endpoint.
    pub endpoint: String,
    /// Its port is open.
    pub connected: bool,
    /// Frames it sent that went to the autopilot.
    pub to_autopilot: u64,
    /// Frames of the autopilot's link sent to it.
    pub to_station: u64,
    /// Stick messages it sent, dropped.
    pub sticks_dropped: u64,
    /// Stick messages of a station with an `id`, taken for its operator loop.
    pub sticks_taken: u64,
}

/// A ground station's port.
pub(super) struct Port {
    endpoint: Endpoint,
    /// The station as an operator of the hierarchy, if it has an `id`.
    pub(super) station: Option<crate::config::StationConfig>,
    /// A `udpin:` port's peer: the station's last datagram's sender.
    peer: Arc<Mutex<Option<SocketAddr>>>,
    pub(super) writer: Mutex<Option<Arc<Writer>>>,
    connected: AtomicBool,
    to_autopilot: AtomicU64,
    to_station: AtomicU64,
    sticks_dropped: AtomicU64,
    /// Sticks of a station with an `id`, taken for its operator loop.
    pub(super) sticks_taken: AtomicU64,
    /// What rove as the system manager keeps for this station ([`super::stations`]).
    pub(super) manager: Mutex<super::stations::Manager>,
    /// Whether "it speaks as rove's own system id" was said.
    same_id_said: AtomicBool,
}

impl Port {
    pub(super) fn new(gcs: crate::config::GcsConfig) -> Port {
        Port {
            endpoint: gcs.endpoint,
            station: gcs.station,
            peer: Arc::default(),
            writer: Mutex::new(None),
            connected: AtomicBool::new(false),
            to_autopilot: AtomicU64::new(0),
            to_station: AtomicU64::new(0),
            sticks_dropped: AtomicU64::new(0),
            sticks_taken: AtomicU64::new(0),
            manager: Mutex::default(),
            same_id_said: AtomicBool::new(false),
        }
    }

    pub(super) fn status(&self) -> StationStatus {
        StationStatus {
            endpoint: self.endpoint.to_string(),
            connected: self.connected.load(Ordering::Relaxed),
            to_autopilot: self.to_autopilot.load(Ordering::Relaxed),
            to_station: self.to_station.load(Ordering::Relaxed),
            sticks_dropped: self.sticks_dropped.load(Ordering::Relaxed),
            sticks_taken: self.sticks_taken.load(Ordering::Relaxed),
        }
    }
}

/// Sends a frame of the autopilot's link (`raw`, as received) to every station that can take it.
/// The operator-control protocol is not passed on: toward the stations rove is the system
/// manager ([`super::stations`]), and the autopilot's answers to rove are rove's.
pub(super) fn to_stations(shared: &Shared, message: &Payload, raw: &[u8]) {
    if matches!(message, Payload::Control(_)) {
        return;
    }
    for port in &shared.ground {
        let writer = lock(&port.writer).clone();
        let Some(writer) = writer.filter(|w| w.ready()) else {
            continue;
        };
        // A TCP station that stopped reading is closed; the autopilot's reader waits at most
        // the send timeout for it.
        if write_or_close(&port.writer, &writer, raw) {
            port.to_station.fetch_add(1, Ordering::Relaxed);
        }
    }
}

/// Writes `bytes` with `writer`, the one `slot` holds. A stream a write failed on is closed and
/// leaves the slot (its reader reconnects): part of a frame may have left, so it is out of step.
/// Whether the write went out.
pub(super) fn write_or_close(
    slot: &Mutex<Option<Arc<Writer>>>,
    writer: &Writer,
    bytes: &[u8],
) -> bool {
    let written = writer.write(bytes).is_ok();
    if !written && writer.close_if_stream() {
        *lock(slot) = None;
    }
    written
}

/// The thread of the station at `shared.ground[index]`: opens its port (again after an error,
/// every [`RECONNECT`]), reads its frames and passes them on.
pub(super) fn serve(shared: &Shared, index: usize) {
    let Some(port) = shared.ground.get(index) else {
        return;
    };
    let mut logged_error: Option<String> = None;
    let mut decoder = Decoder::new();
    let mut buf = vec![0u8; READ_CHUNK];
    // A tcpin: port's listener, kept across its clients.
    let mut listener: Option<TcpListener> = None;
    while !shared.stop.load(Ordering::Relaxed) {
        let opened = match (&port.endpoint, &listener) {
            (Endpoint::TcpIn(address), None) => listen(address).map(|l| {
                listener = Some(l);
                None
            }),
            (Endpoint::TcpIn(_), Some(l)) => accept(l),
            (endpoint, _) => open(endpoint, &port.peer).map(Some),
        };
        let (mut reader, writer) = match opened {
            Ok(Some(c)) => c,
            Ok(None) => continue,
            Err(e) => {
                let why = format!("{}: {e}", port.endpoint);
                if logged_error.as_deref() != Some(why.as_str()) {
                    warn!(error = %why, "mavlink: cannot open a ground station's port; retrying every {RECONNECT:?}");
                    logged_error = Some(why);
                }
                std::thread::sleep(RECONNECT);
                continue;
            }
        };
        info!(endpoint = %port.endpoint, "mavlink: ground station port open");
        logged_error = None;
        decoder.clear();
        *lock(&port.writer) = Some(Arc::new(writer));
        port.connected.store(true, Ordering::Relaxed);
        while !shared.stop.load(Ordering::Relaxed) {
            match reader.read(&mut buf) {
                Ok((n, _)) => {
                    decoder.push(buf.get(..n).unwrap_or(&buf));
                    while let Some(frame) = decoder.next_frame() {
                        if !super::stations::from_station(shared, port, &frame) {
                            from_port(shared, port, &frame, decoder.raw());
                        }
                    }
                    super::stations::tick(shared, port);
                }
                Err(e) => match classify_read(&e) {
                    ReadOutcome::Idle => super::stations::tick(shared, port),
                    ReadOutcome::Reconnect => {
                        warn!(endpoint = %port.endpoint, error = %e, "mavlink: ground station gone; reopening its port");
                        break;
                    }
                },
            }
        }
        *lock(&port.writer) = None;
        port.connected.store(false, Ordering::Relaxed);
        if !shared.stop.load(Ordering::Relaxed) {
            std::thread::sleep(RECONNECT);
        }
    }
}

/// A station's frame (`raw`, as received): to the autopilot, unless it is sticks.
fn from_port(shared: &Shared, port: &Port, frame: &Frame, raw: &[u8]) {
    if frame.header.system_id == u32::from(shared.system_id)
        && !port.same_id_said.swap(true, Ordering::Relaxed)
    {
        warn!(
            endpoint = %port.endpoint,
            system = shared.system_id,
            "mavlink: a ground station speaks as rove's own system id: the autopilot's answers \
             cannot tell the two apart; give the station another (QGroundControl: Application \
             Settings → MAVLink → MAVLink System ID)"
        );
    }
    if from_station(&frame.message) == Verdict::Sticks {
        port.sticks_dropped.fetch_add(1, Ordering::Relaxed);
        return;
    }
    let Some(writer) = lock(&shared.writer).clone() else {
        return;
    };
    // As rove's own sends: a TCP autopilot that stopped reading is reconnected.
    if write_or_close(&shared.writer, &writer, raw) {
        port.to_autopilot.fetch_add(1, Ordering::Relaxed);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use mavlink::dialects::ardupilotmega as ap;

    #[test]
    fn sticks_are_dropped_and_everything_else_passes() {
        let manual = MavMessage::MANUAL_CONTROL(ap::MANUAL_CONTROL_DATA::default());
        let rc = MavMessage::RC_CHANNELS_OVERRIDE(ap::RC_CHANNELS_OVERRIDE_DATA::default());
        assert_eq!(from_station(&Payload::Mav(manual)), Verdict::Sticks);
        assert_eq!(from_station(&Payload::Mav(rc)), Verdict::Sticks);
        for passes in [
            MavMessage::HEARTBEAT(ap::HEARTBEAT_DATA::default()),
            MavMessage::PARAM_REQUEST_LIST(ap::PARAM_REQUEST_LIST_DATA::default()),
            MavMessage::COMMAND_LONG(ap::COMMAND_LONG_DATA::default()),
            MavMessage::MISSION_COUNT(ap::MISSION_COUNT_DATA::default()),
        ] {
            assert_eq!(from_station(&Payload::Mav(passes)), Verdict::Forward);
        }
        let request = crate::control::Message::Request {
            request: true,
            takeover: false,
            timeout_s: 10.0,
            gcs: 250,
            target: (1, 1),
        };
        assert_eq!(from_station(&Payload::Control(request)), Verdict::Forward);
    }
}
