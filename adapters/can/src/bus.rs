//! The CAN bus as the vehicle sees it: frames ([`CanFrameData`]), the [`CanBus`] trait, the pure
//! error classification ([`classify_errno`]) and the in-memory [`FakeBus`] the tests drive.
//!
//! The trait is synchronous and never blocks, like [`rove_core::adapter::OutputAdapter`]: the
//! SocketCAN implementation uses a non-blocking socket, so a full transmit queue is an error
//! (reported, and the vehicle goes to failsafe) instead of a stalled gateway.

use crate::error::FrameError;
use rove_core::MonoTime;
use rove_core::error::{Disposition, LinkError};
use std::fmt;
use std::sync::{Arc, Mutex, MutexGuard};

/// Largest standard (11-bit) identifier.
pub const STANDARD_ID_MAX: u32 = 0x7FF;

/// Largest extended (29-bit) identifier.
pub const EXTENDED_ID_MAX: u32 = 0x1FFF_FFFF;

/// Data bytes of a classic CAN frame.
pub const CLASSIC_MAX_LEN: usize = 8;

/// Data bytes of the longest CAN FD frame.
pub const FD_MAX_LEN: usize = 64;

/// The data lengths a CAN FD frame can have above 8 bytes (the DLC codes 9..=15).
pub const FD_LENGTHS: [usize; 7] = [12, 16, 20, 24, 32, 48, 64];

/// A CAN identifier, standard (11-bit) or extended (29-bit).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum CanId {
    /// An 11-bit identifier.
    Standard(u16),
    /// A 29-bit identifier.
    Extended(u32),
}

impl CanId {
    /// A standard or extended identifier.
    ///
    /// # Errors
    /// [`FrameError::IdOutOfRange`] if `id` does not fit 11 (standard) or 29 (extended) bits.
    pub fn new(id: u32, extended: bool) -> Result<CanId, FrameError> {
        match (extended, u16::try_from(id)) {
            (false, Ok(short)) if id <= STANDARD_ID_MAX => Ok(CanId::Standard(short)),
            (true, _) if id <= EXTENDED_ID_MAX => Ok(CanId::Extended(id)),
            _ => Err(FrameError::IdOutOfRange { id, extended }),
        }
    }

    /// The identifier's value.
    pub fn raw(self) -> u32 {
        match self {
            CanId::Standard(id) => u32::from(id),
            CanId::Extended(id) => id,
        }
    }

    /// Whether it is a 29-bit identifier.
    pub fn is_extended(self) -> bool {
        matches!(self, CanId::Extended(_))
    }
}

impl fmt::Display for CanId {
    /// `0x123` for a standard identifier (3 hex digits), `0x1003F264` for an extended one (8).
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            CanId::Standard(id) => write!(f, "0x{id:03X}"),
            CanId::Extended(id) => write!(f, "0x{id:08X}"),
        }
    }
}

/// One data frame to send: an identifier and 0..=8 (classic) or up to 64 (CAN FD) bytes.
///
/// Frames longer than 8 bytes are CAN FD frames; shorter ones are classic frames, also on an FD
/// interface (every FD controller sends classic frames too).
#[derive(Clone, Copy, PartialEq, Eq, Hash)]
pub struct CanFrameData {
    id: CanId,
    len: u8,
    data: [u8; FD_MAX_LEN],
}

impl CanFrameData {
    /// A frame carrying `data`.
    ///
    /// # Errors
    /// [`FrameError::DataTooLong`] above 64 bytes, [`FrameError::InvalidFdLength`] for a length
    /// 9..=63 that is not a CAN FD length.
    pub fn new(id: CanId, data: &[u8]) -> Result<CanFrameData, FrameError> {
        let len = data.len();
        if len > FD_MAX_LEN {
            return Err(FrameError::DataTooLong { len });
        }
        if len > CLASSIC_MAX_LEN && !FD_LENGTHS.contains(&len) {
            return Err(FrameError::InvalidFdLength { len });
        }
        let mut buf = [0u8; FD_MAX_LEN];
        buf[..len].copy_from_slice(data);
        Ok(CanFrameData {
            id,
            // ≤ 64 checked above.
            len: len as u8,
            data: buf,
        })
    }

    /// The identifier.
    pub fn id(&self) -> CanId {
        self.id
    }

    /// The data bytes.
    pub fn data(&self) -> &[u8] {
        &self.data[..usize::from(self.len)]
    }

    /// Whether this is a CAN FD frame (more than 8 data bytes).
    pub fn is_fd(&self) -> bool {
        usize::from(self.len) > CLASSIC_MAX_LEN
    }
}

impl fmt::Debug for CanFrameData {
    /// candump style: `0x123#[01 02 03]`.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}#{:02X?}", self.id, self.data())
    }
}

/// What the bus controller reports about itself.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub enum BusState {
    /// Error-active: frames go out normally.
    #[default]
    Active,
    /// Frames still go out, but the controller reports trouble (error warning or error passive,
    /// lost acknowledgements, protocol errors); the text says which.
    Degraded(String),
    /// Bus-off: the controller stopped sending after too many errors. It comes back when the
    /// kernel restarts it (`ip link set can0 type can restart-ms 100`) or by hand
    /// (`ip link set can0 type can restart`).
    BusOff,
}

/// A CAN interface the vehicle sends on.
pub trait CanBus {
    /// A one-line description naming the interface (for logs and errors).
    fn describe(&self) -> String;

    /// Queues `frame` for sending; never blocks.
    ///
    /// # Errors
    /// A classified [`LinkError`] naming the interface: transient when the interface is down or
    /// gone or its queue is full, fatal when retrying cannot help (permission, an FD frame on a
    /// classic interface).
    fn send(&mut self, now: MonoTime, frame: &CanFrameData) -> Result<(), LinkError>;

    /// The controller's state, after taking in every error report queued since the last call;
    /// never blocks.
    ///
    /// # Errors
    /// A classified [`LinkError`] when the reports cannot be read (the interface went away).
    fn state(&mut self) -> Result<BusState, LinkError>;

    /// Closes the interface and opens it again by name, after a failure (an adapter unplugged
    /// and plugged back gets a new interface index, which the old socket cannot reach).
    ///
    /// # Errors
    /// As opening: transient while the interface does not exist or is down.
    fn reopen(&mut self) -> Result<(), LinkError>;
}

impl<B: CanBus + ?Sized> CanBus for Box<B> {
    fn describe(&self) -> String {
        (**self).describe()
    }

    fn send(&mut self, now: MonoTime, frame: &CanFrameData) -> Result<(), LinkError> {
        (**self).send(now, frame)
    }

    fn state(&mut self) -> Result<BusState, LinkError> {
        (**self).state()
    }

    fn reopen(&mut self) -> Result<(), LinkError> {
        (**self).reopen()
    }
}

/// Linux errno values used by [`classify_errno`]. These are the asm-generic numbers, which
/// x86, x86-64, ARM, AArch64 and RISC-V (every board rove targets) use; MIPS, SPARC, Alpha
/// and PA-RISC number some of them differently. Defined here rather than taken from `libc` so
/// that the crate adds no dependency beyond the workspace lock file.
pub mod errno {
    /// Operation not permitted.
    pub const EPERM: i32 = 1;
    /// I/O error.
    pub const EIO: i32 = 5;
    /// No such device or address.
    pub const ENXIO: i32 = 6;
    /// Bad file descriptor.
    pub const EBADF: i32 = 9;
    /// Try again (would block).
    pub const EAGAIN: i32 = 11;
    /// Permission denied.
    pub const EACCES: i32 = 13;
    /// No such device.
    pub const ENODEV: i32 = 19;
    /// Invalid argument.
    pub const EINVAL: i32 = 22;
    /// Message too long.
    pub const EMSGSIZE: i32 = 90;
    /// Protocol not supported.
    pub const EPROTONOSUPPORT: i32 = 93;
    /// Operation not supported.
    pub const EOPNOTSUPP: i32 = 95;
    /// Address family not supported by protocol.
    pub const EAFNOSUPPORT: i32 = 97;
    /// Cannot assign requested address.
    pub const EADDRNOTAVAIL: i32 = 99;
    /// Network is down.
    pub const ENETDOWN: i32 = 100;
    /// Network is unreachable.
    pub const ENETUNREACH: i32 = 101;
    /// No buffer space available.
    pub const ENOBUFS: i32 = 105;
}

/// How a failed socket call with `errno` is handled.
///
/// | errno | meaning on a CAN socket | disposition |
/// |---|---|---|
/// | ENETDOWN, ENETUNREACH | interface down (`ip link set can0 down`), or bus-off | transient |
/// | ENODEV, ENXIO, EADDRNOTAVAIL, EBADF | interface gone (USB adapter unplugged) or never created | transient |
/// | ENOBUFS, EAGAIN | transmit queue full: no node acknowledges, or the bus is saturated | transient |
/// | EIO | driver error | transient |
/// | EPERM, EACCES | no permission (raw CAN sockets need none; a security module said no) | fatal |
/// | EINVAL, EMSGSIZE, EOPNOTSUPP | an FD frame on a classic interface, a bad frame | fatal |
/// | EAFNOSUPPORT, EPROTONOSUPPORT | the kernel has no SocketCAN (`CONFIG_CAN`, `CONFIG_CAN_RAW`) | fatal |
/// | anything else | unknown | transient (retrying is harmless; the vehicle is in failsafe meanwhile) |
///
/// A missing interface is transient, not fatal, because CAN adapters are hot-plugged and
/// `can0` may come up after the gateway: the vehicle waits in failsafe and retries.
pub fn classify_errno(errno: i32) -> Disposition {
    use errno::*;
    match errno {
        EPERM | EACCES | EINVAL | EMSGSIZE | EOPNOTSUPP | EAFNOSUPPORT | EPROTONOSUPPORT => {
            Disposition::Fatal
        }
        _ => Disposition::Transient,
    }
}

/// What an errno means on a CAN socket, for error texts.
pub fn describe_errno(errno: i32) -> &'static str {
    use errno::*;
    match errno {
        ENETDOWN => "interface down",
        ENETUNREACH => "network unreachable",
        ENODEV | ENXIO | EADDRNOTAVAIL => "no such interface",
        EBADF => "socket closed",
        ENOBUFS | EAGAIN => "transmit queue full (is any node acknowledging?)",
        EIO => "I/O error",
        EPERM | EACCES => "permission denied",
        EINVAL => "invalid argument",
        EMSGSIZE => "frame too long for the interface (CAN FD frame on a classic interface?)",
        EOPNOTSUPP => "operation not supported",
        EAFNOSUPPORT | EPROTONOSUPPORT => "the kernel has no SocketCAN support",
        _ => "error",
    }
}

/// A [`LinkError`] for `errno` from `what` (e.g. `can0: send`), classified by
/// [`classify_errno`].
pub fn link_error(what: &str, errno: i32) -> LinkError {
    LinkError {
        disposition: classify_errno(errno),
        detail: format!("{what}: {} (errno {errno})", describe_errno(errno)),
    }
}

/// One frame the fake bus took.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SentFrame {
    /// When it was sent.
    pub at: MonoTime,
    /// The frame.
    pub frame: CanFrameData,
}

/// A fault the fake bus is told to show.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FakeFault {
    /// The controller went bus-off: [`CanBus::state`] says so and sends fail with ENOBUFS
    /// (the queue fills), as on a real interface, until [`FakeBusHandle::heal`].
    BusOff,
    /// The interface is down or was unplugged: sends fail with ENETDOWN and reopening fails
    /// with ENODEV until [`FakeBusHandle::heal`]. The socket stays dead after healing until
    /// the bus is reopened, like a socket bound to a vanished interface index.
    InterfaceGone,
    /// Every send fails with this errno until healed (e.g. EPERM for a fatal error).
    Errno(i32),
}

#[derive(Debug, Default)]
struct FakeState {
    sent: Vec<SentFrame>,
    fault: Option<FakeFault>,
    /// Set when the interface vanished under the open socket; cleared by a reopen.
    socket_dead: bool,
    reopens: u32,
    degraded: Option<String>,
}

/// An in-memory CAN bus: records every frame with its time, and fails on command.
///
/// Build it with [`FakeBus::new`], keep the [`FakeBusHandle`] it returns, and hand the bus to
/// the vehicle.
#[derive(Debug)]
pub struct FakeBus {
    name: String,
    fd: bool,
    shared: Arc<Mutex<FakeState>>,
}

/// The test's side of a [`FakeBus`]: what was sent, and fault injection.
#[derive(Debug, Clone)]
pub struct FakeBusHandle(Arc<Mutex<FakeState>>);

fn lock(state: &Mutex<FakeState>) -> MutexGuard<'_, FakeState> {
    // A panic while holding this lock cannot leave the state inconsistent (every update is a
    // single push or assignment), so a poisoned lock is still safe to use.
    state.lock().unwrap_or_else(|p| p.into_inner())
}

impl FakeBus {
    /// A fake interface `name`; `fd` lets it take CAN FD frames.
    pub fn new(name: &str, fd: bool) -> (FakeBus, FakeBusHandle) {
        let shared = Arc::new(Mutex::new(FakeState::default()));
        (
            FakeBus {
                name: name.to_string(),
                fd,
                shared: Arc::clone(&shared),
            },
            FakeBusHandle(shared),
        )
    }
}

impl CanBus for FakeBus {
    fn describe(&self) -> String {
        format!("fake CAN bus {}", self.name)
    }

    fn send(&mut self, now: MonoTime, frame: &CanFrameData) -> Result<(), LinkError> {
        let mut s = lock(&self.shared);
        let what = format!("{}: send", self.name);
        if s.socket_dead {
            return Err(link_error(&what, errno::ENETDOWN));
        }
        match s.fault {
            Some(FakeFault::BusOff) => return Err(link_error(&what, errno::ENOBUFS)),
            Some(FakeFault::InterfaceGone) => return Err(link_error(&what, errno::ENETDOWN)),
            Some(FakeFault::Errno(e)) => return Err(link_error(&what, e)),
            None => {}
        }
        if frame.is_fd() && !self.fd {
            return Err(link_error(&what, errno::EINVAL));
        }
        s.sent.push(SentFrame {
            at: now,
            frame: *frame,
        });
        Ok(())
    }

    fn state(&mut self) -> Result<BusState, LinkError> {
        let s = lock(&self.shared);
        Ok(match (s.fault, &s.degraded) {
            (Some(FakeFault::BusOff), _) => BusState::BusOff,
            (_, Some(why)) => BusState::Degraded(why.clone()),
            _ => BusState::Active,
        })
    }

    fn reopen(&mut self) -> Result<(), LinkError> {
        let mut s = lock(&self.shared);
        if s.fault == Some(FakeFault::InterfaceGone) {
            return Err(link_error(&format!("{}: open", self.name), errno::ENODEV));
        }
        s.socket_dead = false;
        s.reopens += 1;
        Ok(())
    }
}

impl FakeBusHandle {
    /// Every frame sent so far, oldest first.
    pub fn frames(&self) -> Vec<SentFrame> {
        lock(&self.0).sent.clone()
    }

    /// Takes (and forgets) every frame sent so far.
    pub fn take(&self) -> Vec<SentFrame> {
        std::mem::take(&mut lock(&self.0).sent)
    }

    /// Shows `fault` from now on.
    pub fn fail(&self, fault: FakeFault) {
        let mut s = lock(&self.0);
        if fault == FakeFault::InterfaceGone {
            s.socket_dead = true;
        }
        s.fault = Some(fault);
    }

    /// Ends the fault: the bus restarts, the interface is back (the socket still needs a
    /// reopen after [`FakeFault::InterfaceGone`]).
    pub fn heal(&self) {
        lock(&self.0).fault = None;
    }

    /// Makes [`CanBus::state`] report degraded (`Some(why)`) or not.
    pub fn set_degraded(&self, why: Option<&str>) {
        lock(&self.0).degraded = why.map(str::to_string);
    }

    /// How many times the bus was reopened.
    pub fn reopens(&self) -> u32 {
        lock(&self.0).reopens
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ids_must_fit_their_format() {
        assert_eq!(CanId::new(0x7FF, false), Ok(CanId::Standard(0x7FF)));
        assert_eq!(
            CanId::new(0x800, false),
            Err(FrameError::IdOutOfRange {
                id: 0x800,
                extended: false
            })
        );
        assert_eq!(CanId::new(0x800, true), Ok(CanId::Extended(0x800)));
        assert!(CanId::new(0x2000_0000, true).is_err());
        assert_eq!(CanId::Standard(0x12).to_string(), "0x012");
        assert_eq!(CanId::Extended(0x1003_F264).to_string(), "0x1003F264");
    }

    #[test]
    fn frames_take_classic_and_fd_lengths_only() {
        let id = CanId::Standard(1);
        assert!(CanFrameData::new(id, &[0; 8]).is_ok_and(|f| !f.is_fd()));
        assert!(CanFrameData::new(id, &[0; 12]).is_ok_and(|f| f.is_fd()));
        assert_eq!(
            CanFrameData::new(id, &[0; 9]),
            Err(FrameError::InvalidFdLength { len: 9 })
        );
        assert_eq!(
            CanFrameData::new(id, &[0; 65]),
            Err(FrameError::DataTooLong { len: 65 })
        );
        let f = CanFrameData::new(id, &[1, 0xAB]).expect("valid");
        assert_eq!(format!("{f:?}"), "0x001#[01, AB]");
    }

    #[test]
    fn classify_errno_separates_transient_from_fatal() {
        use errno::*;
        for e in [
            ENETDOWN,
            ENODEV,
            ENOBUFS,
            EAGAIN,
            ENXIO,
            EIO,
            ENETUNREACH,
            12345,
        ] {
            assert_eq!(classify_errno(e), Disposition::Transient, "errno {e}");
        }
        for e in [EPERM, EACCES, EINVAL, EMSGSIZE, EAFNOSUPPORT] {
            assert_eq!(classify_errno(e), Disposition::Fatal, "errno {e}");
        }
        let err = link_error("can0: send", ENETDOWN);
        assert_eq!(err.detail, "can0: send: interface down (errno 100)");
    }

    #[test]
    fn fake_bus_records_fails_and_recovers() {
        let (mut bus, handle) = FakeBus::new("fake0", false);
        let f = CanFrameData::new(CanId::Standard(0x10), &[1]).expect("valid");
        bus.send(MonoTime::from_millis(1), &f).expect("sent");
        handle.fail(FakeFault::BusOff);
        assert_eq!(bus.state(), Ok(BusState::BusOff));
        assert!(bus.send(MonoTime::from_millis(2), &f).is_err());
        handle.heal();
        assert_eq!(bus.state(), Ok(BusState::Active));
        handle.fail(FakeFault::InterfaceGone);
        assert!(bus.reopen().is_err());
        handle.heal();
        // The old socket stays dead until reopened.
        assert!(bus.send(MonoTime::from_millis(3), &f).is_err());
        bus.reopen().expect("interface is back");
        bus.send(MonoTime::from_millis(4), &f).expect("sent");
        let at: Vec<u64> = handle
            .frames()
            .iter()
            .map(|s| s.at.as_nanos() / 1_000_000)
            .collect();
        assert_eq!(at, [1, 4]);
        assert_eq!(handle.reopens(), 1);
        let fd = CanFrameData::new(CanId::Standard(1), &[0; 12]).expect("valid");
        assert_eq!(
            bus.send(MonoTime::ZERO, &fd).map_err(|e| e.disposition),
            Err(Disposition::Fatal)
        );
    }
}
