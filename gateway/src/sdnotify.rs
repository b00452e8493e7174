//! systemd's service notifications (`sd_notify(3)`), spoken over a std [`UnixDatagram`]:
//! `READY=1` once the role is up, `STATUS=` lines for `systemctl status`, `WATCHDOG=1`
//! keep-alives and `STOPPING=1` at shutdown.
//!
//! systemd passes the socket in `NOTIFY_SOCKET` (a path, or `@name` for an abstract socket)
//! and, with `WatchdogSec=`, the watchdog timeout in `WATCHDOG_USEC` (and possibly
//! `WATCHDOG_PID`, naming the process it is meant for). Without `NOTIFY_SOCKET` (a terminal, a
//! test) every call here does nothing.
//!
//! Keep-alives are *not* sent from a timer task of their own: each role's `select!` loop sends
//! them from a [`KeepaliveTimer`] branch, so a loop that hangs (a blocking device write, a
//! deadlock) stops them and systemd kills and restarts the gateway.
//!
//! Sending never blocks and never fails the caller: the socket is non-blocking (a slow
//! service manager must not stall the control loop), and send errors are logged, rate-limited.
//!
//! No crate: the protocol is one datagram of `KEY=VALUE` lines, and the `sd-notify` crate
//! (0.5) cannot address abstract sockets.

use crate::runtime::RateLimited;
use std::ffi::OsStr;
use std::os::unix::ffi::OsStrExt;
use std::os::unix::net::{SocketAddr, UnixDatagram};
use std::path::PathBuf;
use std::time::Duration;
use tracing::warn;

/// Where notifications go, as `NOTIFY_SOCKET` names it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Target {
    /// A socket in the file system (`/run/systemd/notify`).
    Path(PathBuf),
    /// An abstract socket (`@name`; the name without the `@`). Abstract names belong to a
    /// network namespace: the listener must be in the same one.
    Abstract(Vec<u8>),
}

/// Reads `NOTIFY_SOCKET`'s value. `Ok(None)` for an empty value (no notifications).
///
/// # Errors
/// A value that is neither an absolute path nor `@name` (e.g. systemd's `vsock:` form, which
/// rove does not support), or a bare `@`.
pub fn parse_socket(value: &OsStr) -> Result<Option<Target>, String> {
    let bytes = value.as_bytes();
    match bytes.first() {
        None => Ok(None),
        Some(b'/') => Ok(Some(Target::Path(PathBuf::from(value)))),
        Some(b'@') if bytes.len() > 1 => Ok(Some(Target::Abstract(bytes[1..].to_vec()))),
        Some(_) => Err(format!(
            "NOTIFY_SOCKET={}: not an absolute path or @abstract name",
            value.to_string_lossy()
        )),
    }
}

/// The keep-alive period for `WATCHDOG_USEC` (the timeout) and `WATCHDOG_PID`: half the
/// timeout, as `sd_watchdog_enabled(3)` recommends, so that one late turn of the loop is not
/// yet fatal. `Ok(None)` when there is no watchdog, or it is meant for another process.
///
/// # Errors
/// A value that is not a positive decimal number.
pub fn parse_watchdog(
    usec: Option<&OsStr>,
    pid: Option<&OsStr>,
    my_pid: u32,
) -> Result<Option<Duration>, String> {
    let Some(usec) = usec else {
        return Ok(None);
    };
    if let Some(pid) = pid {
        let pid: u32 = decimal(pid)
            .filter(|p| *p > 0)
            .and_then(|p| u32::try_from(p).ok())
            .ok_or_else(|| format!("WATCHDOG_PID={}: not a pid", pid.to_string_lossy()))?;
        if pid != my_pid {
            return Ok(None);
        }
    }
    match decimal(usec) {
        Some(us) if us > 0 => Ok(Some(Duration::from_micros(us / 2))),
        _ => Err(format!(
            "WATCHDOG_USEC={}: not a positive number of microseconds",
            usec.to_string_lossy()
        )),
    }
}

fn decimal(value: &OsStr) -> Option<u64> {
    let text = value.to_str()?;
    if text.is_empty() || !text.bytes().all(|b| b.is_ascii_digit()) {
        return None;
    }
    text.parse().ok()
}

/// One notification datagram: `KEY=VALUE` lines. A `STATUS=` text is one line: line breaks in
/// it become spaces (a newline would start a new, bogus assignment).
pub fn message(fields: &[(&str, &str)]) -> String {
    let mut out = String::new();
    for (key, value) in fields {
        out.push_str(key);
        out.push('=');
        out.extend(
            value
                .chars()
                .map(|c| if c == '\n' || c == '\r' { ' ' } else { c }),
        );
        out.push('\n');
    }
    out
}

/// The connection to the service manager (or nothing, when not run by one).
pub struct Notifier {
    socket: Option<(UnixDatagram, SocketAddr)>,
    watchdog: Option<Duration>,
    failed: RateLimited,
}

impl std::fmt::Debug for Notifier {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Notifier")
            .field("enabled", &self.socket.is_some())
            .field("watchdog", &self.watchdog)
            .finish()
    }
}

impl Notifier {
    /// From `NOTIFY_SOCKET`, `WATCHDOG_USEC` and `WATCHDOG_PID`. A malformed value is logged
    /// and that part is left off: a gateway must start even when its supervisor is odd. (Under
    /// systemd the consequence is visible: a Type=notify start times out without READY=1.)
    pub fn from_env() -> Notifier {
        let target = match std::env::var_os("NOTIFY_SOCKET").map(|v| parse_socket(&v)) {
            None | Some(Ok(None)) => None,
            Some(Ok(Some(target))) => Some(target),
            Some(Err(e)) => {
                warn!(cause = %e, "no service notifications");
                None
            }
        };
        let watchdog = parse_watchdog(
            std::env::var_os("WATCHDOG_USEC").as_deref(),
            std::env::var_os("WATCHDOG_PID").as_deref(),
            std::process::id(),
        )
        .unwrap_or_else(|e| {
            warn!(cause = %e, "no watchdog keep-alives");
            None
        });
        Notifier::new(target, watchdog)
    }

    /// Notifications to `target` (none for `None`); keep-alives every `watchdog`, if given
    /// (only sent where there is a target).
    pub fn new(target: Option<Target>, watchdog: Option<Duration>) -> Notifier {
        let socket = target.and_then(|t| match open(&t) {
            Ok(s) => Some(s),
            Err(e) => {
                warn!(target = ?t, cause = %e, "no service notifications");
                None
            }
        });
        Notifier {
            watchdog: watchdog.filter(|_| socket.is_some()),
            socket,
            failed: RateLimited::new("service notification (sd_notify) failed"),
        }
    }

    /// No service manager: every call does nothing.
    pub fn disabled() -> Notifier {
        Notifier::new(None, None)
    }

    /// Whether notifications are sent.
    pub fn is_enabled(&self) -> bool {
        self.socket.is_some()
    }

    /// The keep-alive period (half the watchdog timeout), if systemd wants keep-alives.
    pub fn watchdog_period(&self) -> Option<Duration> {
        self.watchdog
    }

    /// A timer for the role's loop that fires once per keep-alive period (never, without a
    /// watchdog).
    pub fn keepalive_timer(&self) -> KeepaliveTimer {
        KeepaliveTimer::new(self.watchdog)
    }

    /// `READY=1` with a first status line.
    pub fn ready(&mut self, status: &str) {
        self.send(&message(&[("READY", "1"), ("STATUS", status)]));
    }

    /// A new `STATUS=` line.
    pub fn status(&mut self, status: &str) {
        self.send(&message(&[("STATUS", status)]));
    }

    /// `WATCHDOG=1`: the loop is alive.
    pub fn keepalive(&mut self) {
        self.send(&message(&[("WATCHDOG", "1")]));
    }

    /// `STOPPING=1` with a last status line.
    pub fn stopping(&mut self, status: &str) {
        self.send(&message(&[("STOPPING", "1"), ("STATUS", status)]));
    }

    fn send(&mut self, text: &str) {
        let Some((socket, addr)) = &self.socket else {
            return;
        };
        if let Err(e) = socket.send_to_addr(text.as_bytes(), addr) {
            self.failed.warn(&e);
        }
    }
}

fn open(target: &Target) -> std::io::Result<(UnixDatagram, SocketAddr)> {
    let addr = match target {
        Target::Path(path) => SocketAddr::from_pathname(path)?,
        Target::Abstract(name) => {
            use std::os::linux::net::SocketAddrExt;
            SocketAddr::from_abstract_name(name)?
        }
    };
    let socket = UnixDatagram::unbound()?;
    socket.set_nonblocking(true)?;
    Ok((socket, addr))
}

/// The keep-alive tick of a role's `select!` loop: a branch `_ = timer.tick() => notifier.keepalive()`.
/// After a stall it fires once, not once per missed period.
#[derive(Debug)]
pub struct KeepaliveTimer(Option<tokio::time::Interval>);

impl KeepaliveTimer {
    fn new(period: Option<Duration>) -> KeepaliveTimer {
        KeepaliveTimer(period.filter(|p| !p.is_zero()).map(|p| {
            let mut interval = tokio::time::interval(p);
            interval.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
            interval
        }))
    }

    /// Resolves when a keep-alive is due; never without a watchdog.
    pub async fn tick(&mut self) {
        match &mut self.0 {
            Some(interval) => {
                interval.tick().await;
            }
            None => std::future::pending().await,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::atomic::{AtomicUsize, Ordering};

    static NEXT: AtomicUsize = AtomicUsize::new(0);

    fn os(s: &str) -> &OsStr {
        OsStr::new(s)
    }

    #[test]
    fn notify_socket_forms() {
        let cases: &[(&str, Result<Option<Target>, ()>)] = &[
            ("", Ok(None)),
            (
                "/run/systemd/notify",
                Ok(Some(Target::Path("/run/systemd/notify".into()))),
            ),
            (
                "@/org/freedesktop/systemd1/notify/123",
                Ok(Some(Target::Abstract(
                    b"/org/freedesktop/systemd1/notify/123".to_vec(),
                ))),
            ),
            ("@", Err(())),
            ("run/notify", Err(())),
            ("vsock:2:1234", Err(())),
        ];
        for (value, want) in cases {
            let got = parse_socket(os(value)).map_err(|_| ());
            assert_eq!(&got, want, "NOTIFY_SOCKET={value:?}");
        }
    }

    #[test]
    fn watchdog_period_is_half_the_timeout_and_only_for_this_process() {
        /// Keep-alive period, or `Err` for a malformed variable.
        type Want = Result<Option<Duration>, ()>;
        let ms = |n: u64| -> Want { Ok(Some(Duration::from_millis(n))) };
        let cases: &[(Option<&str>, Option<&str>, Want)] = &[
            (None, None, Ok(None)),
            (Some("1000000"), None, ms(500)),
            (Some("3000000"), Some("42"), ms(1500)),
            (Some("3000000"), Some("43"), Ok(None)),
            (Some("0"), None, Err(())),
            (Some(""), None, Err(())),
            (Some("-5"), None, Err(())),
            (Some("+5"), None, Err(())),
            (Some("1s"), None, Err(())),
            (Some("99999999999999999999999"), None, Err(())),
            (Some("1000000"), Some("pid"), Err(())),
            (Some("1000000"), Some("0"), Err(())),
        ];
        for (usec, pid, want) in cases {
            let got = parse_watchdog(usec.map(os), pid.map(os), 42).map_err(|_| ());
            assert_eq!(&got, want, "WATCHDOG_USEC={usec:?} WATCHDOG_PID={pid:?}");
        }
    }

    #[test]
    fn non_utf8_environment_is_an_error_not_a_panic() {
        let bad = OsStr::from_bytes(b"\xff\xfe");
        assert!(parse_watchdog(Some(bad), None, 1).is_err());
        assert!(parse_watchdog(Some(os("1000")), Some(bad), 1).is_err());
        assert!(parse_socket(bad).is_err());
        // A path need not be UTF-8.
        let path = OsStr::from_bytes(b"/tmp/\xff");
        assert!(matches!(parse_socket(path), Ok(Some(Target::Path(_)))));
    }

    #[test]
    fn status_is_kept_on_one_line() {
        assert_eq!(
            message(&[("READY", "1"), ("STATUS", "owner 11\nSTOPPING=1\r")]),
            "READY=1\nSTATUS=owner 11 STOPPING=1 \n"
        );
    }

    fn receive(listener: &UnixDatagram) -> String {
        listener
            .set_read_timeout(Some(Duration::from_secs(5)))
            .expect("timeout");
        let mut buf = [0u8; 1024];
        let n = listener.recv(&mut buf).expect("a datagram");
        String::from_utf8_lossy(&buf[..n]).into_owned()
    }

    #[test]
    fn sends_to_a_path_socket() {
        let dir = std::env::temp_dir().join(format!(
            "rove-sdnotify-{}-{}",
            std::process::id(),
            NEXT.fetch_add(1, Ordering::SeqCst)
        ));
        std::fs::create_dir_all(&dir).expect("dir");
        let path = dir.join("notify");
        let listener = UnixDatagram::bind(&path).expect("bind");
        let mut notifier = Notifier::new(
            Some(Target::Path(path.clone())),
            Some(Duration::from_millis(5)),
        );
        assert_eq!(notifier.watchdog_period(), Some(Duration::from_millis(5)));
        notifier.ready("up");
        assert_eq!(receive(&listener), "READY=1\nSTATUS=up\n");
        notifier.keepalive();
        assert_eq!(receive(&listener), "WATCHDOG=1\n");
        notifier.stopping("bye");
        assert_eq!(receive(&listener), "STOPPING=1\nSTATUS=bye\n");
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn sends_to_an_abstract_socket() {
        use std::os::linux::net::SocketAddrExt;
        let name = format!(
            "rove-sdnotify-test-{}-{}",
            std::process::id(),
            NEXT.fetch_add(1, Ordering::SeqCst)
        );
        let addr = SocketAddr::from_abstract_name(name.as_bytes()).expect("addr");
        let listener = UnixDatagram::bind_addr(&addr).expect("bind abstract");
        let target = parse_socket(os(&format!("@{name}")))
            .expect("parses")
            .expect("a target");
        let mut notifier = Notifier::new(Some(target), None);
        notifier.status("owner 11");
        assert_eq!(receive(&listener), "STATUS=owner 11\n");
    }

    #[test]
    fn a_missing_listener_or_no_target_is_harmless() {
        let mut gone = Notifier::new(
            Some(Target::Path("/nonexistent/rove/notify".into())),
            Some(Duration::from_secs(1)),
        );
        assert!(gone.is_enabled());
        gone.ready("up");
        gone.keepalive();
        let mut none = Notifier::disabled();
        assert!(!none.is_enabled());
        assert_eq!(none.watchdog_period(), None);
        none.ready("up");
        // No socket, no keep-alives: a watchdog without a target is dropped.
        assert_eq!(
            Notifier::new(None, Some(Duration::from_secs(1))).watchdog_period(),
            None
        );
    }
}
