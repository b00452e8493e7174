//! The MAVLink link: a thread that (re)connects and reads, and a sender the adapter calls on its
//! own thread (so a control message leaves in the same call that decided it).
//!
//! The reader thread keeps what the adapter needs in [`LinkStatus`]: whether the transport is
//! open, which autopilot we talk to (the configured target, else the first HEARTBEAT from a
//! system that is not a GCS), when it was last heard, its mode and armed state, and the
//! COMMAND_ACKs it sent us. Messages from any other system are counted and dropped; bytes that do
//! not parse are skipped. On a transport error (TCP closed, serial device gone) it reconnects
//! every [`RECONNECT`]; UDP needs no reconnect (a restarted autopilot just speaks again).

use crate::config::{Endpoint, MavlinkConfig};
use crate::mode::AckResult;
use mavlink::dialects::common::{
    MavAutopilot, MavCmd, MavMessage, MavModeFlag, MavResult, MavType,
};
use mavlink::error::{MessageReadError, MessageWriteError};
use mavlink::{
    Connectable, Connection, MavConnection, MavHeader, MavlinkVersion, SerialConfig, TcpConfig,
    TcpMode, UdpConfig, UdpMode,
};
use rove_core::error::LinkError;
use std::collections::VecDeque;
use std::io;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, MutexGuard, PoisonError};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};
use tracing::{debug, info, warn};

/// Pause between reconnect attempts.
pub const RECONNECT: Duration = Duration::from_millis(500);
/// Read timeout, so the thread notices a stop request.
const READ_TIMEOUT: Duration = Duration::from_millis(100);
/// COMMAND_ACKs kept for the adapter; older ones are dropped (a flood cannot grow memory).
const ACK_QUEUE: usize = 32;

/// The autopilot as last heard.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct AutopilotInfo {
    /// Its system id.
    pub system_id: u8,
    /// Its component id.
    pub component_id: u8,
    /// MAV_TYPE as a number.
    pub mav_type: u32,
    /// MAV_AUTOPILOT as a number.
    pub autopilot: u32,
    /// HEARTBEAT custom_mode.
    pub custom_mode: u32,
    /// MAV_MODE_FLAG_SAFETY_ARMED set.
    pub armed: bool,
}

/// What the reader thread knows.
#[derive(Debug, Clone, Default)]
pub struct LinkStatus {
    /// The transport is open.
    pub connected: bool,
    /// Why it is not (the last connect or read error).
    pub error: Option<String>,
    /// Our autopilot, once heard.
    pub autopilot: Option<AutopilotInfo>,
    /// When its last HEARTBEAT arrived.
    pub last_heartbeat: Option<Instant>,
    /// Messages dropped because they came from another system.
    pub foreign: u64,
    /// Reads that did not parse (garbage, bad CRC, unknown message).
    pub garbage: u64,
    /// Times the transport was (re)opened.
    pub connects: u64,
}

struct Shared {
    endpoint: Endpoint,
    version: MavlinkVersion,
    target_system: Option<u8>,
    target_component: Option<u8>,
    conn: Mutex<Option<Arc<Connection<MavMessage>>>>,
    status: Mutex<LinkStatus>,
    acks: Mutex<VecDeque<AckResult>>,
    stop: AtomicBool,
}

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(PoisonError::into_inner)
}

/// The link: owns the reader thread; sends on the caller's thread.
pub struct Link {
    shared: Arc<Shared>,
    header: MavHeader,
    thread: Option<JoinHandle<()>>,
}

impl std::fmt::Debug for Link {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Link")
            .field("endpoint", &self.shared.endpoint)
            .finish()
    }
}

impl Link {
    /// Starts the reader thread, which opens the transport.
    ///
    /// # Errors
    /// The thread cannot be spawned.
    pub fn start(config: &MavlinkConfig) -> Result<Link, LinkError> {
        let shared = Arc::new(Shared {
            endpoint: config.endpoint.clone(),
            version: if config.mavlink_version == 1 {
                MavlinkVersion::V1
            } else {
                MavlinkVersion::V2
            },
            target_system: config.target_system,
            target_component: config.target_component,
            conn: Mutex::new(None),
            status: Mutex::new(LinkStatus::default()),
            acks: Mutex::new(VecDeque::new()),
            stop: AtomicBool::new(false),
        });
        let for_thread = Arc::clone(&shared);
        let thread = std::thread::Builder::new()
            .name("rove-mavlink".into())
            .spawn(move || run(&for_thread))
            .map_err(|e| LinkError::transient(format!("mavlink reader thread: {e}")))?;
        Ok(Link {
            shared,
            header: MavHeader {
                system_id: u32::from(config.system_id),
                component_id: config.component_id,
                sequence: 0,
            },
            thread: Some(thread),
        })
    }

    /// A snapshot of the link's state.
    pub fn status(&self) -> LinkStatus {
        lock(&self.shared.status).clone()
    }

    /// The (system, component) to address, once known.
    pub fn target(&self) -> Option<(u8, u8)> {
        let s = lock(&self.shared.status);
        match (self.shared.target_system, s.autopilot) {
            (Some(sys), a) => Some((
                sys,
                self.shared
                    .target_component
                    .or(a.map(|a| a.component_id))
                    .unwrap_or(1),
            )),
            (None, Some(a)) => Some((
                a.system_id,
                self.shared.target_component.unwrap_or(a.component_id),
            )),
            (None, None) => None,
        }
    }

    /// COMMAND_ACKs for MAV_CMD_DO_SET_MODE received since the last call.
    pub fn take_acks(&self) -> Vec<AckResult> {
        lock(&self.shared.acks).drain(..).collect()
    }

    /// Sends `msg` now.
    ///
    /// # Errors
    /// Transient: not connected, nobody to send to yet (udpin before the first packet), or the
    /// write failed.
    pub fn send(&self, msg: &MavMessage) -> Result<(), LinkError> {
        let conn = lock(&self.shared.conn).clone();
        let Some(conn) = conn else {
            let why = lock(&self.shared.status)
                .error
                .clone()
                .unwrap_or_else(|| "connecting".into());
            return Err(LinkError::transient(format!(
                "mavlink {}: not connected ({why})",
                self.shared.endpoint
            )));
        };
        match conn.send(&self.header, msg) {
            Ok(0) => Err(LinkError::transient(format!(
                "mavlink {}: no peer to send to yet (waiting for the autopilot's first packet)",
                self.shared.endpoint
            ))),
            Ok(_) => Ok(()),
            Err(MessageWriteError::Io(e)) => Err(LinkError::transient(format!(
                "mavlink {}: send failed: {e}",
                self.shared.endpoint
            ))),
            Err(e) => Err(LinkError::transient(format!(
                "mavlink {}: message not encoded: {e}",
                self.shared.endpoint
            ))),
        }
    }
}

impl Drop for Link {
    fn drop(&mut self) {
        self.shared.stop.store(true, Ordering::Relaxed);
        // The thread wakes within READ_TIMEOUT (or RECONNECT) and exits; joining would make a
        // stopping gateway wait for that, so it is detached instead.
        drop(self.thread.take());
    }
}

fn open(shared: &Shared) -> io::Result<Connection<MavMessage>> {
    let mut conn: Connection<MavMessage> = match &shared.endpoint {
        Endpoint::UdpIn(a) => UdpConfig::new(a.clone(), UdpMode::Udpin)
            .read_timeout(READ_TIMEOUT)
            .connect()?,
        Endpoint::UdpOut(a) => UdpConfig::new(a.clone(), UdpMode::Udpout)
            .read_timeout(READ_TIMEOUT)
            .connect()?,
        Endpoint::TcpOut(a) => TcpConfig::new(a.clone(), TcpMode::TcpOut).connect()?,
        Endpoint::Serial { device, baud } => SerialConfig::new(device.clone(), *baud)
            .timeout(READ_TIMEOUT)
            .connect()?,
    };
    conn.set_protocol_version(shared.version);
    conn.set_allow_recv_any_version(true);
    Ok(conn)
}

/// How a read error is handled.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ReadOutcome {
    /// Nothing arrived in time: check for stop, read again.
    Idle,
    /// Bytes that are not a message we know: count, read again.
    Garbage,
    /// The transport is gone: reconnect.
    Reconnect,
}

/// Classifies a read error (pure, unit-tested).
pub fn classify_read(e: &MessageReadError) -> ReadOutcome {
    match e {
        MessageReadError::Io(io) => match io.kind() {
            io::ErrorKind::WouldBlock | io::ErrorKind::TimedOut | io::ErrorKind::Interrupted => {
                ReadOutcome::Idle
            }
            // UDP: an ICMP port-unreachable from a peer that is not up yet surfaces here.
            io::ErrorKind::ConnectionRefused => ReadOutcome::Idle,
            _ => ReadOutcome::Reconnect,
        },
        MessageReadError::Parse(_) => ReadOutcome::Garbage,
    }
}

fn run(shared: &Shared) {
    let mut logged_error: Option<String> = None;
    while !shared.stop.load(Ordering::Relaxed) {
        let conn = match open(shared) {
            Ok(c) => Arc::new(c),
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
        {
            let mut s = lock(&shared.status);
            s.connected = true;
            s.error = None;
            s.connects += 1;
        }
        *lock(&shared.conn) = Some(Arc::clone(&conn));
        let serial = matches!(shared.endpoint, Endpoint::Serial { .. });
        while !shared.stop.load(Ordering::Relaxed) {
            // Serial's blocking `recv` retries every error internally (a removed device would
            // spin there); `try_recv` returns them, with the port's read timeout.
            let read = if serial { conn.try_recv() } else { conn.recv() };
            match read {
                Ok((header, msg)) => handle(shared, header, &msg),
                Err(e) => match classify_read(&e) {
                    ReadOutcome::Idle => {}
                    ReadOutcome::Garbage => {
                        debug!(error = %e, "mavlink: skipped bytes that do not parse");
                        lock(&shared.status).garbage += 1;
                    }
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
        *lock(&shared.conn) = None;
        if !shared.stop.load(Ordering::Relaxed) {
            std::thread::sleep(RECONNECT);
        }
    }
}

fn handle(shared: &Shared, header: MavHeader, msg: &MavMessage) {
    let mut s = lock(&shared.status);
    let ours = match (shared.target_system, s.autopilot) {
        (Some(sys), _) => header.system_id == u32::from(sys),
        (None, Some(a)) => header.system_id == u32::from(a.system_id),
        (None, None) => true, // decided below: only an autopilot's HEARTBEAT locks on
    };
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
            if s.autopilot.is_none() {
                info!(
                    system = info.system_id,
                    component = info.component_id,
                    autopilot = ?hb.autopilot,
                    mav_type = ?hb.mavtype,
                    "mavlink: autopilot found"
                );
            }
            s.autopilot = Some(info);
            s.last_heartbeat = Some(Instant::now());
        }
        MavMessage::COMMAND_ACK(ack) if s.autopilot.is_some() || shared.target_system.is_some() => {
            if ack.command != MavCmd::MAV_CMD_DO_SET_MODE {
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
            drop(s);
            let mut acks = lock(&shared.acks);
            if acks.len() >= ACK_QUEUE {
                acks.pop_front();
            }
            acks.push_back(result);
        }
        _ => {}
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn read_errors_are_classified() {
        let io_err = |k| MessageReadError::Io(io::Error::from(k));
        assert_eq!(
            classify_read(&io_err(io::ErrorKind::WouldBlock)),
            ReadOutcome::Idle
        );
        assert_eq!(
            classify_read(&io_err(io::ErrorKind::TimedOut)),
            ReadOutcome::Idle
        );
        assert_eq!(
            classify_read(&io_err(io::ErrorKind::UnexpectedEof)),
            ReadOutcome::Reconnect,
            "TCP peer closed"
        );
        assert_eq!(
            classify_read(&io_err(io::ErrorKind::ConnectionReset)),
            ReadOutcome::Reconnect
        );
        assert_eq!(
            classify_read(&MessageReadError::Parse(
                mavlink::error::ParserError::UnknownMessage { id: 4242 }
            )),
            ReadOutcome::Garbage
        );
    }
}
