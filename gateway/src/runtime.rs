//! Process plumbing shared by the roles: the monotonic clock handed to the core, shutdown
//! signals, rate-limited warnings and logging set-up.

use rove_core::MonoTime;
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};
use tracing::warn;

/// The role's clock: `MonoTime` for the core (nanoseconds since start), convertible back to a
/// tokio instant for timers, plus wall-clock time for records.
#[derive(Debug, Clone, Copy)]
pub struct Clock {
    start: Instant,
}

impl Clock {
    /// Starts the clock now.
    pub fn start() -> Clock {
        Clock {
            start: Instant::now(),
        }
    }

    /// Now, for the core.
    pub fn now(&self) -> MonoTime {
        MonoTime::from_nanos(u64::try_from(self.start.elapsed().as_nanos()).unwrap_or(u64::MAX))
    }

    /// The tokio instant of a core time, for `sleep_until`.
    pub fn instant(&self, t: MonoTime) -> tokio::time::Instant {
        tokio::time::Instant::from_std(self.start + Duration::from_nanos(t.as_nanos()))
    }

    /// Microseconds since the Unix epoch (0 if the system clock is before 1970).
    pub fn wall_micros(&self) -> u64 {
        SystemTime::now()
            .duration_since(UNIX_EPOCH)
            .map_or(0, |d| u64::try_from(d.as_micros()).unwrap_or(u64::MAX))
    }

    /// The wall-clock time stamp for samples.
    pub fn stamp(&self) -> rove_core::msg::TimeT {
        rove_core::msg::TimeT::from_unix(
            SystemTime::now()
                .duration_since(UNIX_EPOCH)
                .unwrap_or(Duration::ZERO),
        )
    }
}

/// Resolves on SIGTERM (systemd stop) or SIGINT (Ctrl-C).
///
/// # Errors
/// The signal handlers cannot be installed.
pub fn shutdown_signal() -> anyhow::Result<impl std::future::Future<Output = ()>> {
    use tokio::signal::unix::{SignalKind, signal};
    let mut term = signal(SignalKind::terminate())?;
    let mut int = signal(SignalKind::interrupt())?;
    Ok(async move {
        tokio::select! {
            _ = term.recv() => {}
            _ = int.recv() => {}
        }
    })
}

/// A warning that is logged at most once per [`RateLimited::INTERVAL`], with a count of the
/// occurrences it stood for, so a flood of bad samples cannot flood the journal.
#[derive(Debug)]
pub struct RateLimited {
    what: &'static str,
    last: Option<Instant>,
    suppressed: u64,
}

impl RateLimited {
    /// At most one line per 5 s per kind of problem: enough to see it is still happening.
    pub const INTERVAL: Duration = Duration::from_secs(5);

    /// A limiter for warnings about `what`.
    pub fn new(what: &'static str) -> Self {
        RateLimited {
            what,
            last: None,
            suppressed: 0,
        }
    }

    /// Logs `cause` unless a warning was logged less than the interval ago.
    pub fn warn(&mut self, cause: &dyn std::fmt::Debug) {
        let due = self.last.is_none_or(|t| t.elapsed() >= Self::INTERVAL);
        if due {
            warn!(
                what = self.what,
                ?cause,
                suppressed = self.suppressed,
                "ignored"
            );
            self.last = Some(Instant::now());
            self.suppressed = 0;
        } else {
            self.suppressed += 1;
        }
    }
}

/// Logging: `RUST_LOG` (default: rove at `info`, rustdds at `warn` — its `info` level logs every
/// discovery step), to stderr; without a terminal (systemd), no timestamps (journald adds its
/// own) and no colours.
pub fn init_logging() {
    use std::io::IsTerminal;
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info,rustdds=warn"));
    let builder = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr);
    if std::io::stderr().is_terminal() {
        builder.init();
    } else {
        builder.without_time().with_ansi(false).init();
    }
}

/// Sleeps until `deadline`, or forever when there is none (a `select!` branch that never fires).
pub async fn sleep_until(deadline: Option<tokio::time::Instant>) {
    match deadline {
        Some(d) => tokio::time::sleep_until(d).await,
        None => std::future::pending().await,
    }
}

/// An append-only JSON-lines record for tests and benchmarks, flushed per line so readers can
/// follow it while the process runs. Write failures are warned about, never fatal: the record
/// is an instrument, not part of control.
#[derive(Debug)]
pub struct JsonLines {
    file: std::io::BufWriter<std::fs::File>,
}

impl JsonLines {
    /// Creates (truncates) the record file.
    ///
    /// # Errors
    /// The file cannot be created.
    pub fn create(path: &std::path::Path) -> anyhow::Result<JsonLines> {
        use anyhow::Context;
        let file = std::fs::File::create(path)
            .with_context(|| format!("cannot create record {}", path.display()))?;
        Ok(JsonLines {
            file: std::io::BufWriter::new(file),
        })
    }

    /// Appends one line.
    pub fn write(&mut self, line: &serde_json::Value) {
        use std::io::Write;
        let ok = writeln!(self.file, "{line}").and_then(|()| self.file.flush());
        if let Err(e) = ok {
            warn!(cause = %e, "cannot write record");
        }
    }
}

/// A RequestControl sample as a JSON object, stamped with the wall clock now (µs), as
/// `rove status --events` prints it and `rove operator --record` records it.
pub fn request_json(clock: &Clock, rc: &rove_core::msg::RequestControl) -> serde_json::Value {
    serde_json::json!({
        "wall_us": clock.wall_micros(), "kind": "request",
        "ack": format!("{:?}", rc.ack).to_lowercase(), "src": rc.src_id,
        "dest": rc.dest_id, "current": rc.current_controller_id,
        "stamp": rc.timestamp.0,
    })
}
