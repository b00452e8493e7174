//! The link's transports: opening a UDP (in or out), TCP or serial endpoint with rove's timeouts
//! and buffer sizes, its sending and receiving halves, and how a read error is handled
//! ([`classify_read`]).

use super::{CONNECT_TIMEOUT, READ_TIMEOUT, SEND_TIMEOUT, TCP_SEND_BUFFER, lock};
use crate::config::Endpoint;
use std::io::{self, Read, Write};
use std::net::{SocketAddr, TcpListener, TcpStream, ToSocketAddrs, UdpSocket};
use std::sync::{Arc, Mutex};
use tracing::warn;

/// The sending half of an open transport.
pub(super) enum Writer {
    Tcp(Mutex<TcpStream>),
    /// The socket, and where to send: fixed (udpout) or the last sender (udpin).
    Udp(Arc<UdpSocket>, Arc<Mutex<Option<SocketAddr>>>),
    Serial(Mutex<serialport::TTYPort>),
}

impl Writer {
    /// Writes one frame's `bytes` at once (one datagram, one TCP or serial write).
    ///
    /// # Errors
    /// The write failed, or a UDP link has nobody to send to yet (`NotConnected`).
    pub(super) fn write(&self, bytes: &[u8]) -> io::Result<()> {
        match self {
            Writer::Tcp(s) => lock(s).write_all(bytes),
            Writer::Serial(p) => lock(p).write_all(bytes),
            Writer::Udp(sock, peer) => {
                let Some(to) = *lock(peer) else {
                    return Err(io::ErrorKind::NotConnected.into());
                };
                sock.send_to(bytes, to).map(|_| ())
            }
        }
    }

    /// After a failed write: a TCP stream may carry part of a frame, so it is shut down (its
    /// reader reconnects); `true` if it was one, and the caller drops this writer.
    pub(super) fn close_if_stream(&self) -> bool {
        match self {
            Writer::Tcp(s) => {
                let _ = lock(s).shutdown(std::net::Shutdown::Both);
                true
            }
            _ => false,
        }
    }

    /// Whether a send can leave now (a UDP link knows whom to send to).
    pub(super) fn ready(&self) -> bool {
        match self {
            Writer::Udp(_, peer) => lock(peer).is_some(),
            _ => true,
        }
    }
}

/// The receiving half.
pub(super) enum Reader {
    Tcp(TcpStream),
    /// The socket, and the peer to update from each datagram's sender (udpin only).
    Udp(Arc<UdpSocket>, Option<Arc<Mutex<Option<SocketAddr>>>>),
    Serial(serialport::TTYPort),
}

impl Reader {
    /// Reads what arrived; `true` with it when a `udpin:` link's peer is new (its address
    /// changed, or it is the first datagram).
    pub(super) fn read(&mut self, buf: &mut [u8]) -> io::Result<(usize, bool)> {
        match self {
            Reader::Tcp(s) => match s.read(buf)? {
                0 => Err(io::Error::new(
                    io::ErrorKind::UnexpectedEof,
                    "the autopilot closed the connection",
                )),
                n => Ok((n, false)),
            },
            Reader::Udp(sock, peer) => {
                let (n, from) = sock.recv_from(buf)?;
                let new = peer
                    .as_ref()
                    .is_some_and(|peer| lock(peer).replace(from) != Some(from));
                Ok((n, new))
            }
            Reader::Serial(p) => Ok((p.read(buf)?, false)),
        }
    }
}

fn resolve(addr: &str) -> io::Result<SocketAddr> {
    addr.to_socket_addrs()?.next().ok_or_else(|| {
        io::Error::new(
            io::ErrorKind::NotFound,
            format!("{addr}: no address for this host"),
        )
    })
}

pub(super) fn open(
    endpoint: &Endpoint,
    peer: &Arc<Mutex<Option<SocketAddr>>>,
) -> io::Result<(Reader, Writer)> {
    Ok(match endpoint {
        Endpoint::UdpIn(a) => {
            let sock = Arc::new(UdpSocket::bind(resolve(a)?)?);
            sock.set_read_timeout(Some(READ_TIMEOUT))?;
            sock.set_write_timeout(Some(SEND_TIMEOUT))?;
            let peer = Arc::clone(peer);
            (
                Reader::Udp(Arc::clone(&sock), Some(Arc::clone(&peer))),
                Writer::Udp(sock, peer),
            )
        }
        Endpoint::UdpOut(a) => {
            let to = resolve(a)?;
            let any: SocketAddr = if to.is_ipv4() {
                ([0, 0, 0, 0], 0).into()
            } else {
                (std::net::Ipv6Addr::UNSPECIFIED, 0).into()
            };
            let sock = Arc::new(UdpSocket::bind(any)?);
            sock.set_read_timeout(Some(READ_TIMEOUT))?;
            sock.set_write_timeout(Some(SEND_TIMEOUT))?;
            (
                Reader::Udp(Arc::clone(&sock), None),
                Writer::Udp(sock, Arc::new(Mutex::new(Some(to)))),
            )
        }
        Endpoint::TcpOut(a) => tcp(TcpStream::connect_timeout(&resolve(a)?, CONNECT_TIMEOUT)?)?,
        // A listening port is kept across clients by its owner ([`listen`], [`accept`]).
        Endpoint::TcpIn(a) => {
            let why = format!("tcpin:{a} is a listening port: accept on it");
            return Err(io::Error::new(io::ErrorKind::Unsupported, why));
        }
        Endpoint::Serial { device, baud } => {
            let port = serialport::new(device, *baud)
                .data_bits(serialport::DataBits::Eight)
                .parity(serialport::Parity::None)
                .stop_bits(serialport::StopBits::One)
                .flow_control(serialport::FlowControl::None)
                .timeout(READ_TIMEOUT)
                .open_native()
                .map_err(io::Error::from)?;
            // What the port received before we opened it is another process's (the vehicle
            // before `rove failsafe`, or before a restart): an old HEARTBEAT read now would say
            // the autopilot is in a mode it has since left, and "confirm" a safe mode it is not
            // in (seen: `rove failsafe` asked nothing of an autopilot 20 ms into MANUAL).
            if let Err(e) = serialport::SerialPort::clear(&port, serialport::ClearBuffer::Input) {
                warn!(device = %device, cause = %e, "mavlink: cannot discard stale serial input");
            }
            let writer = port.try_clone_native().map_err(io::Error::from)?;
            (Reader::Serial(port), Writer::Serial(Mutex::new(writer)))
        }
    })
}

/// A connected TCP stream's halves, with rove's options.
fn tcp(stream: TcpStream) -> io::Result<(Reader, Writer)> {
    // Each frame is one write and must leave at once (seen against ArduPilot: Nagle held the
    // second of two back-to-back messages ~44 ms).
    stream.set_nodelay(true)?;
    stream.set_read_timeout(Some(READ_TIMEOUT))?;
    stream.set_write_timeout(Some(SEND_TIMEOUT))?;
    socket2::SockRef::from(&stream).set_send_buffer_size(TCP_SEND_BUFFER)?;
    let writer = stream.try_clone()?;
    Ok((Reader::Tcp(stream), Writer::Tcp(Mutex::new(writer))))
}

/// A `tcpin:` port: listening at `address`, whose accept waits at most [`READ_TIMEOUT`] (so
/// its thread notices a stop request).
pub(super) fn listen(address: &str) -> io::Result<TcpListener> {
    let listener = TcpListener::bind(resolve(address)?)?;
    socket2::SockRef::from(&listener).set_read_timeout(Some(READ_TIMEOUT))?;
    Ok(listener)
}

/// The next client of `listener` (`None` when none came within [`READ_TIMEOUT`]).
pub(super) fn accept(listener: &TcpListener) -> io::Result<Option<(Reader, Writer)>> {
    match listener.accept() {
        Ok((stream, _)) => tcp(stream).map(Some),
        Err(e) if classify_read(&e) == ReadOutcome::Idle => Ok(None),
        Err(e) => Err(e),
    }
}

/// How a read error is handled.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ReadOutcome {
    /// Nothing arrived in time: check for stop, read again.
    Idle,
    /// The transport is gone: reconnect.
    Reconnect,
}

/// Classifies a read error (pure, unit-tested).
pub fn classify_read(e: &io::Error) -> ReadOutcome {
    match e.kind() {
        io::ErrorKind::WouldBlock | io::ErrorKind::TimedOut | io::ErrorKind::Interrupted => {
            ReadOutcome::Idle
        }
        // UDP: an ICMP port-unreachable from a peer that is not up yet surfaces here.
        io::ErrorKind::ConnectionRefused => ReadOutcome::Idle,
        _ => ReadOutcome::Reconnect,
    }
}
