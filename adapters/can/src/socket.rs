//! I/O: [`SocketCanBus`], the [`CanBus`] on a Linux SocketCAN raw socket (feature `socketcan`,
//! on by default).
//!
//! The socket is non-blocking: the output trait is synchronous and must not stall the gateway,
//! so a full transmit queue is reported (EAGAIN/ENOBUFS, transient) rather than waited on. That
//! is also why the `tokio` feature of the socketcan crate is not used: nothing here waits for
//! the bus, and reading error frames is a non-blocking drain on each call.
//!
//! The socket receives no data frames (an empty receive filter: traffic of other nodes must not
//! fill its queue) but all error frames, from which [`CanBus::state`] follows the controller:
//! bus-off, error warning/passive, restarted. While bus-off it also asks the kernel for the
//! controller's state over netlink, so a missed "restarted" report cannot keep the vehicle down.

use crate::bus::{BusState, CanBus, CanFrameData, CanId, link_error};
use rove_core::MonoTime;
use rove_core::error::LinkError;
use socketcan::errors::ControllerProblem;
use socketcan::{
    CanAnyFrame, CanError, CanFdFrame, CanFdSocket, CanFrame, CanSocket, EmbeddedFrame, ExtendedId,
    Id, Socket, SocketOptions, StandardId,
};
use std::io;

/// Most error frames taken in per [`CanBus::state`] call: a noisy bus (no other node
/// acknowledging produces an error frame per retransmission) must not keep one call busy;
/// the rest are read on the next call.
const ERROR_FRAMES_PER_POLL: usize = 64;

/// The errno of an I/O error (EIO if it has none, e.g. an invalid-data error from the crate).
fn errno_of(e: &io::Error) -> i32 {
    e.raw_os_error().unwrap_or(crate::bus::errno::EIO)
}

#[derive(Debug)]
enum Sock {
    Classic(CanSocket),
    Fd(CanFdSocket),
}

/// A SocketCAN interface (`can0`, `vcan0`, `slcan0`) opened by name.
#[derive(Debug)]
pub struct SocketCanBus {
    interface: String,
    fd: bool,
    socket: Sock,
    state: BusState,
}

fn open_socket(interface: &str, fd: bool) -> Result<Sock, LinkError> {
    let what = format!("{interface}: open");
    let err = |e: io::Error| link_error(&what, errno_of(&e));
    let sock = if fd {
        Sock::Fd(CanFdSocket::open(interface).map_err(err)?)
    } else {
        Sock::Classic(CanSocket::open(interface).map_err(err)?)
    };
    let setup = |s: &dyn Fn() -> io::Result<()>| s().map_err(err);
    match &sock {
        Sock::Classic(s) => {
            setup(&|| s.set_nonblocking(true))?;
            setup(&|| s.set_filter_drop_all())?;
            setup(&|| s.set_error_filter_accept_all())?;
        }
        Sock::Fd(s) => {
            setup(&|| s.set_nonblocking(true))?;
            setup(&|| s.set_filter_drop_all())?;
            setup(&|| s.set_error_filter_accept_all())?;
        }
    }
    Ok(sock)
}

impl SocketCanBus {
    /// Opens `interface`, in CAN FD mode if `fd`.
    ///
    /// # Errors
    /// A classified [`LinkError`]: transient if the interface does not exist (ENODEV) or is
    /// down, fatal if the kernel has no SocketCAN (EAFNOSUPPORT) or FD mode is refused.
    pub fn open(interface: &str, fd: bool) -> Result<SocketCanBus, LinkError> {
        Ok(SocketCanBus {
            interface: interface.to_string(),
            fd,
            socket: open_socket(interface, fd)?,
            state: BusState::Active,
        })
    }

    fn take_error(&mut self, error: CanError) -> Option<String> {
        match error {
            CanError::BusOff => {
                self.state = BusState::BusOff;
                None
            }
            CanError::Restarted | CanError::ControllerProblem(ControllerProblem::Active) => {
                self.state = BusState::Active;
                None
            }
            CanError::ControllerProblem(p) => {
                let why = p.to_string();
                if self.state != BusState::BusOff {
                    self.state = BusState::Degraded(why.clone());
                }
                Some(why)
            }
            // Per-frame errors (no ACK, lost arbitration, protocol violations): report them
            // for this poll, but they do not change the controller's state.
            other => Some(other.to_string()),
        }
    }

    /// Asks the kernel (netlink) whether a bus-off controller is back.
    fn restarted_per_netlink(&self) -> bool {
        use socketcan::nl::{CanInterface, CanState};
        CanInterface::open(&self.interface)
            .ok()
            .and_then(|i| i.state().ok().flatten())
            .is_some_and(|s| {
                matches!(
                    s,
                    CanState::ErrorActive | CanState::ErrorWarning | CanState::ErrorPassive
                )
            })
    }
}

impl CanBus for SocketCanBus {
    fn describe(&self) -> String {
        format!(
            "SocketCAN {}{}",
            self.interface,
            if self.fd { " (CAN FD)" } else { "" }
        )
    }

    fn send(&mut self, _now: MonoTime, frame: &CanFrameData) -> Result<(), LinkError> {
        let what = format!("{}: send {:?}", self.interface, frame.id());
        let id = match frame.id() {
            CanId::Standard(id) => StandardId::new(id).map(Id::Standard),
            CanId::Extended(id) => ExtendedId::new(id).map(Id::Extended),
        };
        let Some(id) = id else {
            return Err(LinkError::fatal(format!("{what}: identifier out of range")));
        };
        let result = match (&self.socket, frame.is_fd()) {
            (Sock::Classic(s), false) => match CanFrame::new(id, frame.data()) {
                Some(f) => s.write_frame(&f),
                None => return Err(LinkError::fatal(format!("{what}: frame not accepted"))),
            },
            (Sock::Fd(s), false) => match CanFrame::new(id, frame.data()) {
                Some(f) => s.write_frame(&f),
                None => return Err(LinkError::fatal(format!("{what}: frame not accepted"))),
            },
            (Sock::Fd(s), true) => match CanFdFrame::new(id, frame.data()) {
                Some(f) => s.write_frame(&f),
                None => return Err(LinkError::fatal(format!("{what}: frame not accepted"))),
            },
            (Sock::Classic(_), true) => {
                return Err(LinkError::fatal(format!(
                    "{what}: a {}-byte frame needs fd = true",
                    frame.data().len()
                )));
            }
        };
        result.map_err(|e| link_error(&what, errno_of(&e)))
    }

    fn state(&mut self) -> Result<BusState, LinkError> {
        let mut passing = None;
        for _ in 0..ERROR_FRAMES_PER_POLL {
            let read = match &self.socket {
                Sock::Classic(s) => s.read_frame().map(|f| match f {
                    CanFrame::Error(e) => Some(e.into_error()),
                    _ => None,
                }),
                Sock::Fd(s) => s.read_frame().map(|f| match f {
                    CanAnyFrame::Error(e) => Some(e.into_error()),
                    _ => None,
                }),
            };
            match read {
                Ok(Some(error)) => {
                    if let Some(why) = self.take_error(error) {
                        passing = Some(why);
                    }
                }
                Ok(None) => {}
                Err(e) if e.kind() == io::ErrorKind::WouldBlock => break,
                Err(e) => {
                    let what = format!("{}: read error frames", self.interface);
                    return Err(link_error(&what, errno_of(&e)));
                }
            }
        }
        if self.state == BusState::BusOff && self.restarted_per_netlink() {
            self.state = BusState::Active;
        }
        Ok(match (&self.state, passing) {
            (BusState::Active, Some(why)) => BusState::Degraded(why),
            (state, _) => state.clone(),
        })
    }

    fn reopen(&mut self) -> Result<(), LinkError> {
        self.socket = open_socket(&self.interface, self.fd)?;
        self.state = BusState::Active;
        Ok(())
    }
}
