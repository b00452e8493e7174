//! The MAVLink link: a thread that (re)connects and reads, and a sender the adapter calls on its
//! own thread (so a control message leaves in the same call that decided it).
//!
//! The transports are opened here rather than by the mavlink crate, so that the reader sees raw
//! bytes ([`crate::frame::Decoder`] resynchronises at once on bytes that are not a message) and
//! TCP gets `TCP_NODELAY` (without it the second of two back-to-back messages waited ~44 ms for
//! Nagle's algorithm). The mavlink crate still encodes and decodes every message.
//!
//! The reader thread keeps what the adapter needs in [`LinkStatus`]: whether the transport is
//! open, which autopilot we talk to (the configured target, else the first HEARTBEAT from a
//! system that is not a GCS), when it was last heard, its mode and armed state, and the
//! COMMAND_ACKs it sent us. Messages from any other system are counted and dropped; bytes that do
//! not parse are skipped. On a transport error (TCP closed, serial device gone) it reconnects
//! every [`RECONNECT`]; UDP needs no reconnect (a restarted autopilot just speaks again).
//!
//! # Layout
//! - this file: [`Link`] (start, what it knows, sending), [`LinkStatus`] and the state the
//!   reader thread shares with it.
//! - `transport.rs`: opening UDP, TCP and serial transports, and reading them
//!   ([`classify_read`]).
//! - `receive.rs`: the reader thread: (re)connect, read, decode, and what each message from
//!   our autopilot changes.

mod ground;
mod receive;
mod stations;
mod transport;

pub use ground::{StationStatus, Verdict, from_station};
pub use transport::{ReadOutcome, classify_read};

use crate::config::{Endpoint, MavlinkConfig};
use crate::frame::encode;
use crate::memory::{Keeper, Learned};
use crate::mode::AckResult;
use mavlink::dialects::ardupilotmega::MavMessage;
use mavlink::{MavHeader, MavlinkVersion};
use receive::run;
use rove_core::error::LinkError;
use std::collections::VecDeque;
use std::io;
use std::net::SocketAddr;
use std::sync::atomic::{AtomicBool, AtomicI64, AtomicU8, Ordering};
use std::sync::{Arc, Condvar, Mutex, MutexGuard, PoisonError};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};
use tracing::warn;
use transport::Writer;

/// Pause between reconnect attempts.
pub const RECONNECT: Duration = Duration::from_millis(500);
/// Read timeout, so the thread notices a stop request.
const READ_TIMEOUT: Duration = Duration::from_millis(100);
/// Send timeout of TCP and UDP (SO_SNDTIMEO; a serial port's is its 100 ms read timeout): a peer
/// that stops taking data fails the send within it instead of blocking the output, under the
/// gateway's default 50 ms output deadline.
pub const SEND_TIMEOUT: Duration = Duration::from_millis(25);
/// TCP send buffer. A control link must never hold seconds of old commands in the kernel: 8 KiB
/// (the kernel doubles the 4 KiB asked) is a few seconds of RC overrides at 25 Hz, so a peer
/// that stops reading makes sends time out soon rather than after megabytes.
const TCP_SEND_BUFFER: usize = 4096;
/// TCP connect timeout: an unreachable host must not hold the reader past a few reconnects.
const CONNECT_TIMEOUT: Duration = Duration::from_secs(2);
/// COMMAND_ACKs kept for the adapter; older ones are dropped (a flood cannot grow memory).
const ACK_QUEUE: usize = 32;
/// Bytes read at once; a UDP datagram larger than this is cut (MAVLink frames are ≤ 280 bytes).
const READ_CHUNK: usize = 2048;

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
    /// Bytes skipped because they were not a message we know (garbage, bad CRC, unknown id).
    pub garbage: u64,
    /// Times the transport was (re)opened.
    pub connects: u64,
    /// The battery, from our autopilot's last SYS_STATUS.
    pub battery: Option<Battery>,
    /// The (system, component) whose last COMMAND_ACK for a mode was ours: proof the autopilot
    /// hears us, HEARTBEAT or not.
    pub acked_by: Option<(u8, u8)>,
    /// The autopilot's system manager, if it has one (the operator-control protocol).
    pub control: crate::control::Control,
}

/// A SYS_STATUS's battery: each part `None` where the autopilot says it does not know.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Battery {
    /// Voltage, millivolts (`voltage_battery`; UINT16_MAX: unknown).
    pub mv: Option<u32>,
    /// Remaining, percent (`battery_remaining`; -1: unknown).
    pub pct: Option<u8>,
}

struct Shared {
    endpoint: Endpoint,
    target_system: Option<u8>,
    target_component: Option<u8>,
    /// Ids learned by an earlier run ([`Learned`]): used until the autopilot is heard.
    learned: Option<(u8, u8)>,
    /// A `udpin:` link's peer: the sender of the last datagram (or the learned address).
    peer: Arc<Mutex<Option<SocketAddr>>>,
    /// Keeps what is learned in the memory file (off this thread), if there is one.
    keeper: Option<Keeper>,
    writer: Mutex<Option<Arc<Writer>>>,
    status: Mutex<LinkStatus>,
    acks: Mutex<VecDeque<AckResult>>,
    /// Requests for control our autopilot's system manager forwarded to us, oldest first.
    forwarded: Mutex<VecDeque<crate::control::Message>>,
    /// Bumped when the transport opens and on every HEARTBEAT or COMMAND_ACK from our
    /// autopilot; waiters wake on `news`.
    generation: Mutex<u64>,
    news: Condvar,
    stop: AtomicBool,
    /// Our system id (a COMMAND_ACK for another system is not ours).
    system_id: u8,
    /// The ground stations routed to the autopilot ([`ground`]).
    ground: Vec<ground::Port>,
    /// The vehicle's id and its owner's, from its last VehicleStatus ([`Link::set_owner`]; 0:
    /// none yet), for CONTROL_STATUS ([`stations`]).
    vehicle: AtomicI64,
    owner: AtomicI64,
}

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(PoisonError::into_inner)
}

/// The link: owns the reader thread; sends on the caller's thread.
pub struct Link {
    shared: Arc<Shared>,
    version: MavlinkVersion,
    system_id: u8,
    component_id: u8,
    /// Every frame gets its own sequence number, so the autopilot can count losses.
    sequence: AtomicU8,
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
        Link::start_from(config, None)
    }

    /// [`Link::start`], addressing the autopilot from what an earlier run learned until it is
    /// heard: its ids, and on a `udpin:` link its address (`rove failsafe`).
    ///
    /// # Errors
    /// The thread cannot be spawned.
    pub fn start_from(
        config: &MavlinkConfig,
        learned: Option<&Learned>,
    ) -> Result<Link, LinkError> {
        let udpin = matches!(config.endpoint, Endpoint::UdpIn(_));
        let shared = Arc::new(Shared {
            endpoint: config.endpoint.clone(),
            target_system: config.target_system,
            target_component: config.target_component,
            learned: learned.map(|l| (l.system_id, l.component_id)),
            peer: Arc::new(Mutex::new(learned.and_then(|l| l.peer).filter(|_| udpin))),
            keeper: keeper(config),
            writer: Mutex::new(None),
            status: Mutex::new(LinkStatus::default()),
            acks: Mutex::new(VecDeque::new()),
            forwarded: Mutex::new(VecDeque::new()),
            generation: Mutex::new(0),
            news: Condvar::new(),
            stop: AtomicBool::new(false),
            system_id: config.system_id,
            ground: (config.gcs.iter().cloned())
                .map(ground::Port::new)
                .collect(),
            vehicle: AtomicI64::new(0),
            owner: AtomicI64::new(0),
        });
        for index in 0..shared.ground.len() {
            stations::nudge_on_news(&shared, index);
            let for_thread = Arc::clone(&shared);
            let spawned = std::thread::Builder::new()
                .name("rove-mavlink-gcs".into())
                .spawn(move || ground::serve(&for_thread, index));
            if let Err(e) = spawned {
                shared.stop.store(true, Ordering::Relaxed);
                return Err(LinkError::transient(format!(
                    "mavlink ground station thread: {e}"
                )));
            }
        }
        let for_thread = Arc::clone(&shared);
        let thread = std::thread::Builder::new()
            .name("rove-mavlink".into())
            .spawn(move || run(&for_thread))
            .map_err(|e| {
                shared.stop.store(true, Ordering::Relaxed);
                LinkError::transient(format!("mavlink reader thread: {e}"))
            })?;
        Ok(Link {
            shared,
            version: if config.mavlink_version == 1 {
                MavlinkVersion::V1
            } else {
                MavlinkVersion::V2
            },
            system_id: config.system_id,
            component_id: config.component_id,
            sequence: AtomicU8::new(0),
            thread: Some(thread),
        })
    }

    /// A snapshot of the link's state.
    pub fn status(&self) -> LinkStatus {
        lock(&self.shared.status).clone()
    }

    /// The count of transport opens, HEARTBEATs and COMMAND_ACKs from our autopilot so far;
    /// pass it to [`Link::wait_for_news`].
    pub fn generation(&self) -> u64 {
        *lock(&self.shared.generation)
    }

    /// Blocks until news newer than `seen` (an open, a HEARTBEAT, a COMMAND_ACK) or `limit`.
    pub fn wait_for_news(&self, seen: u64, limit: Duration) {
        let guard = lock(&self.shared.generation);
        let _ = self
            .shared
            .news
            .wait_timeout_while(guard, limit, |g| *g == seen);
    }

    /// The (system, component) to address, once known: the configured ids, else the
    /// autopilot's as heard, else as an earlier run learned them.
    pub fn target(&self) -> Option<(u8, u8)> {
        target(&self.shared)
    }

    /// Whether a send can leave now: the transport is open and, on a `udpin:` link, the
    /// autopilot's address is known.
    pub fn can_send(&self) -> bool {
        lock(&self.shared.writer)
            .as_deref()
            .is_some_and(Writer::ready)
    }

    /// The ground stations' ports and what passed through them.
    pub fn stations(&self) -> Vec<StationStatus> {
        self.shared
            .ground
            .iter()
            .map(ground::Port::status)
            .collect()
    }

    /// COMMAND_ACKs for MAV_CMD_DO_SET_MODE received since the last call.
    pub fn take_acks(&self) -> Vec<AckResult> {
        lock(&self.shared.acks).drain(..).collect()
    }

    /// What the link knows of the autopilot's system manager (the operator-control protocol),
    /// without a copy of the rest of its status.
    pub fn control(&self) -> crate::control::Control {
        lock(&self.shared.status).control
    }

    /// The vehicle `vehicle` is owned by `owner` now (its own id: failsafe): what rove tells its
    /// ground stations in CONTROL_STATUS.
    pub fn set_owner(&self, vehicle: i64, owner: i64) {
        self.shared.vehicle.store(vehicle, Ordering::Relaxed);
        self.shared.owner.store(owner, Ordering::Relaxed);
    }

    /// The requests for control the autopilot's system manager forwarded to rove since the last
    /// call.
    pub fn take_forwarded(&self) -> Vec<crate::control::Message> {
        lock(&self.shared.forwarded).drain(..).collect()
    }

    /// Whether the transport has never been open yet (the first connect is under way).
    pub fn first_connect_pending(&self) -> bool {
        let s = lock(&self.shared.status);
        s.connects == 0 && s.error.is_none()
    }

    /// Sends `msg` now, as one write (one datagram, one TCP segment).
    ///
    /// # Errors
    /// Transient: not connected, nobody to send to yet (udpin before the first packet), or the
    /// write failed.
    pub fn send(&self, msg: &MavMessage) -> Result<(), LinkError> {
        self.send_with(|header| encode(self.version, header, msg))
    }

    /// Sends a message the dialect does not know (id and CRC_EXTRA `id`, `payload`), as
    /// [`Link::send`] does.
    ///
    /// # Errors
    /// As [`Link::send`].
    pub fn send_raw(&self, id: (u32, u8), payload: &[u8]) -> Result<(), LinkError> {
        self.send_with(|header| crate::frame::encode_raw(self.version, header, id, payload))
    }

    fn send_with(
        &self,
        frame: impl FnOnce(MavHeader) -> Result<Vec<u8>, String>,
    ) -> Result<(), LinkError> {
        let writer = lock(&self.shared.writer).clone();
        let Some(writer) = writer else {
            let why = lock(&self.shared.status)
                .error
                .clone()
                .unwrap_or_else(|| "connecting".into());
            return Err(LinkError::transient(format!(
                "mavlink {}: not connected ({why})",
                self.shared.endpoint
            )));
        };
        let header = MavHeader {
            system_id: u32::from(self.system_id),
            component_id: self.component_id,
            sequence: self.sequence.fetch_add(1, Ordering::Relaxed),
        };
        let bytes = frame(header).map_err(|e| {
            LinkError::transient(format!(
                "mavlink {}: message not encoded: {e}",
                self.shared.endpoint
            ))
        })?;
        let written = match writer.write(&bytes) {
            Err(e) if e.kind() == io::ErrorKind::NotConnected => {
                return Err(LinkError::transient(format!(
                    "mavlink {}: no peer to send to yet (waiting for the autopilot's first \
                     packet)",
                    self.shared.endpoint
                )));
            }
            written => written,
        };
        written.map_err(|e| {
            let timed_out = matches!(
                e.kind(),
                io::ErrorKind::WouldBlock | io::ErrorKind::TimedOut
            );
            // Part of a frame may have left: the stream is out of step. Closing it makes the
            // reader reconnect.
            if timed_out && writer.close_if_stream() {
                *lock(&self.shared.writer) = None;
            }
            let why = match timed_out {
                true => format!(
                    "send timed out after {SEND_TIMEOUT:?} (the autopilot is not taking data)"
                ),
                false => format!("send failed: {e}"),
            };
            LinkError::transient(format!("mavlink {}: {why}", self.shared.endpoint))
        })
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

/// The (system, component) to address: see [`Link::target`].
fn target(shared: &Shared) -> Option<(u8, u8)> {
    let heard = lock(&shared.status)
        .autopilot
        .map(|a| (a.system_id, a.component_id));
    let (sys, comp) = match (shared.target_system, heard.or(shared.learned)) {
        (Some(sys), known) => (sys, known.map_or(1, |(_, c)| c)),
        (None, Some(known)) => known,
        (None, None) => return None,
    };
    Some((sys, shared.target_component.unwrap_or(comp)))
}

/// The memory file's keeper, which starts from what the file holds: an unchanged autopilot
/// is not written again. Without one (no runtime directory, `rove failsafe`), nothing is kept.
fn keeper(config: &MavlinkConfig) -> Option<Keeper> {
    let path = config.memory.clone()?;
    let on_disk = Learned::load(&path, &config.endpoint.to_string())
        .ok()
        .flatten();
    match Keeper::start(path, on_disk) {
        Ok(k) => Some(k),
        Err(e) => {
            warn!(error = %e, "mavlink: cannot start the memory file's writer; `rove failsafe` will wait for the autopilot");
            None
        }
    }
}

#[cfg(test)]
mod tests {
    use super::receive::handle;
    use super::*;
    use mavlink::dialects::ardupilotmega::{
        COMMAND_ACK_DATA, HEARTBEAT_DATA, MavAutopilot, MavCmd, MavModeFlag, MavResult, MavState,
        MavType,
    };

    fn header(system_id: u32, component_id: u8) -> MavHeader {
        MavHeader {
            system_id,
            component_id,
            sequence: 0,
        }
    }

    fn heartbeat() -> MavMessage {
        MavMessage::HEARTBEAT(HEARTBEAT_DATA {
            custom_mode: 4,
            mavtype: MavType::MAV_TYPE_GROUND_ROVER,
            autopilot: MavAutopilot::MAV_AUTOPILOT_ARDUPILOTMEGA,
            base_mode: MavModeFlag::empty(),
            system_status: MavState::MAV_STATE_ACTIVE,
            mavlink_version: 3,
        })
    }

    fn ack() -> MavMessage {
        MavMessage::COMMAND_ACK(COMMAND_ACK_DATA {
            command: MavCmd::MAV_CMD_DO_SET_MODE,
            result: MavResult::MAV_RESULT_ACCEPTED,
            ..COMMAND_ACK_DATA::default()
        })
    }

    /// What an earlier run learned addresses the autopilot until it is heard, but is a hint:
    /// another autopilot's HEARTBEAT still locks on, and what is heard is kept for next time.
    #[test]
    fn learned_ids_address_until_a_heartbeat_says_otherwise() {
        let dir = tempfile::tempdir().expect("temp dir");
        let memory = dir.path().join("learned");
        let mut settings: crate::MavlinkSettings =
            toml::from_str("connection = \"udpout:127.0.0.1:9\"").expect("parses");
        let mut config = settings.validate().expect("valid");
        config.memory = Some(memory.clone());
        let learned = Learned {
            endpoint: config.endpoint.to_string(),
            peer: None,
            system_id: 1,
            component_id: 1,
        };
        let link = Link::start_from(&config, Some(&learned)).expect("link");
        let shared = &link.shared;
        assert_eq!(
            link.target(),
            Some((1, 1)),
            "addressed before any HEARTBEAT"
        );
        handle(shared, header(7, 1), &ack());
        assert!(link.take_acks().is_empty(), "an ACK from another system");
        handle(shared, header(1, 1), &ack());
        assert_eq!(link.take_acks(), vec![AckResult::Accepted]);
        assert_eq!(
            link.status().acked_by,
            Some((1, 1)),
            "heard without a HEARTBEAT"
        );
        assert!(!memory.exists(), "nothing heard, nothing new to keep");
        // The autopilot on this link now is system 2: its HEARTBEAT wins over the file.
        handle(shared, header(2, 1), &heartbeat());
        assert_eq!(link.target(), Some((2, 1)));
        handle(shared, header(1, 1), &ack());
        assert!(
            link.take_acks().is_empty(),
            "the learned system is no longer ours"
        );
        let keeper = shared.keeper.as_ref().expect("a memory file is kept");
        assert!(keeper.wait_idle(Duration::from_secs(10)), "written");
        let kept = Learned::load(&memory, &config.endpoint.to_string()).expect("readable");
        assert_eq!(kept.map(|l| l.system_id), Some(2), "what is heard is kept");
    }

    #[test]
    fn without_learned_ids_nothing_is_addressed_before_a_heartbeat() {
        let mut settings: crate::MavlinkSettings =
            toml::from_str("connection = \"udpout:127.0.0.1:9\"").expect("parses");
        let config = settings.validate().expect("valid");
        let link = Link::start(&config).expect("link");
        assert_eq!(link.target(), None);
        handle(&link.shared, header(1, 1), &ack());
        assert!(
            link.take_acks().is_empty(),
            "nobody's ACK before an autopilot is known"
        );
        handle(&link.shared, header(3, 1), &heartbeat());
        assert_eq!(link.target(), Some((3, 1)));
    }

    /// The battery is our autopilot's: nobody's before it is heard, not another system's or
    /// component's; the autopilot's "unknown" values stay unknown.
    #[test]
    fn the_battery_comes_from_our_autopilots_sys_status() {
        use mavlink::dialects::ardupilotmega::SYS_STATUS_DATA;
        let mut settings: crate::MavlinkSettings =
            toml::from_str("connection = \"udpout:127.0.0.1:9\"").expect("parses");
        let config = settings.validate().expect("valid");
        let link = Link::start(&config).expect("link");
        let status = |mv: u16, pct: i8| {
            MavMessage::SYS_STATUS(SYS_STATUS_DATA {
                voltage_battery: mv,
                battery_remaining: pct,
                ..SYS_STATUS_DATA::default()
            })
        };
        let battery = || link.status().battery;
        handle(&link.shared, header(1, 1), &status(12_100, 80));
        assert_eq!(battery(), None, "before any autopilot is heard");
        handle(&link.shared, header(1, 1), &heartbeat());
        handle(&link.shared, header(1, 1), &status(12_100, 80));
        let known = Battery {
            mv: Some(12_100),
            pct: Some(80),
        };
        assert_eq!(battery(), Some(known));
        handle(&link.shared, header(2, 1), &status(9_000, 5));
        handle(&link.shared, header(1, 191), &status(9_000, 5));
        assert_eq!(battery(), Some(known), "another system's or component's");
        handle(&link.shared, header(1, 1), &status(u16::MAX, -1));
        let unknown = Battery {
            mv: None,
            pct: None,
        };
        assert_eq!(battery(), Some(unknown));
        handle(&link.shared, header(1, 1), &status(11_000, 120));
        assert_eq!(
            battery().and_then(|b| b.pct),
            None,
            "over 100 % is not a level"
        );
    }

    #[test]
    fn read_errors_are_classified() {
        let e = |k| io::Error::from(k);
        assert_eq!(
            classify_read(&e(io::ErrorKind::WouldBlock)),
            ReadOutcome::Idle
        );
        assert_eq!(
            classify_read(&e(io::ErrorKind::TimedOut)),
            ReadOutcome::Idle
        );
        assert_eq!(
            classify_read(&e(io::ErrorKind::UnexpectedEof)),
            ReadOutcome::Reconnect,
            "TCP peer closed"
        );
        assert_eq!(
            classify_read(&e(io::ErrorKind::ConnectionReset)),
            ReadOutcome::Reconnect
        );
        assert_eq!(
            classify_read(&e(io::ErrorKind::ConnectionRefused)),
            ReadOutcome::Idle,
            "udp peer not up yet"
        );
    }
}
