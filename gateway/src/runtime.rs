//! Process plumbing shared by the roles: the monotonic clock handed to the core, shutdown
//! signals, rate-limited warnings and logging set-up (terminal, file or systemd's journal).

use rove_core::MonoTime;
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};
use tracing::warn;

/// The role's clock: `MonoTime` for the core (nanoseconds since start), convertible back to a
/// tokio instant for timers, plus wall-clock time for records.
///
/// On tokio's clock, so that a test with tokio's time paused drives the loops in virtual
/// time. Outside a runtime (the output's thread) tokio's clock is the system's monotonic one.
#[derive(Debug, Clone, Copy)]
pub struct Clock {
    start: tokio::time::Instant,
}

impl Clock {
    /// Starts the clock now.
    pub fn start() -> Clock {
        Clock {
            start: tokio::time::Instant::now(),
        }
    }

    /// A clock that started at `start` (tests: a clock already running for a while).
    #[cfg(test)]
    pub(crate) fn since(start: Instant) -> Clock {
        Clock {
            start: tokio::time::Instant::from_std(start),
        }
    }

    /// Now, for the core.
    pub fn now(&self) -> MonoTime {
        MonoTime::from_nanos(u64::try_from(self.start.elapsed().as_nanos()).unwrap_or(u64::MAX))
    }

    /// The tokio instant of a core time, for `sleep_until`.
    pub fn instant(&self, t: MonoTime) -> tokio::time::Instant {
        self.start + Duration::from_nanos(t.as_nanos())
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

/// The filter used when `RUST_LOG` is not set: rove at `info`, rustdds at `warn` (its `info`
/// level logs every discovery step), and rustdds's UDP sender at `error`: it warns
/// `send_to_locator: Message size = N` for every datagram over 1500 bytes (discovery data with
/// several interfaces), which filled the log; its failed sends stay visible as errors.
pub const DEFAULT_LOG_FILTER: &str = "info,rustdds=warn,rustdds::network::udp_sender=error";

/// How log lines are written to stderr.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LogStyle {
    /// A person at a terminal: time stamps and colours.
    Terminal,
    /// systemd's journal (`JOURNAL_STREAM` names our stderr): each line starts with its syslog
    /// priority (`<4>` for a warning), which journald takes as the entry's priority
    /// (`journalctl -p warning`) and strips; no time stamps, since journald adds its own; no
    /// colours.
    Journal,
    /// A file or pipe (tests, `2>log`): time stamps, no colours.
    Plain,
}

impl LogStyle {
    /// The style for a stderr that is (or is not) a terminal and is (or is not) the journal.
    pub fn choose(is_terminal: bool, is_journal: bool) -> LogStyle {
        match (is_journal, is_terminal) {
            (true, _) => LogStyle::Journal,
            (false, true) => LogStyle::Terminal,
            (false, false) => LogStyle::Plain,
        }
    }

    /// The style for this process's stderr.
    pub fn detect() -> LogStyle {
        use std::io::IsTerminal;
        LogStyle::choose(std::io::stderr().is_terminal(), stderr_is_journal())
    }
}

/// `JOURNAL_STREAM`'s value, `DEVICE:INODE` in decimal (systemd.exec(5)).
pub fn parse_journal_stream(value: &std::ffi::OsStr) -> Option<(u64, u64)> {
    let (dev, ino) = value.to_str()?.split_once(':')?;
    let number = |s: &str| -> Option<u64> {
        if s.is_empty() || !s.bytes().all(|b| b.is_ascii_digit()) {
            return None;
        }
        s.parse().ok()
    };
    Some((number(dev)?, number(ino)?))
}

/// True when stderr is the stream systemd connected to the journal. Checking the device and
/// inode (rather than only that `JOURNAL_STREAM` is set) keeps a child whose stderr was
/// redirected from prefixing its lines with priorities.
fn stderr_is_journal() -> bool {
    use std::os::fd::AsFd;
    use std::os::unix::fs::MetadataExt;
    let Some((dev, ino)) = std::env::var_os("JOURNAL_STREAM")
        .as_deref()
        .and_then(parse_journal_stream)
    else {
        return false;
    };
    let Ok(fd) = std::io::stderr().as_fd().try_clone_to_owned() else {
        return false;
    };
    match std::fs::File::from(fd).metadata() {
        Ok(meta) => meta.dev() == dev && meta.ino() == ino,
        Err(_) => false,
    }
}

/// The syslog priority journald reads from a `<N>` line prefix (sd-daemon(3)).
pub fn syslog_priority(level: tracing::Level) -> u8 {
    match level {
        tracing::Level::ERROR => 3,
        tracing::Level::WARN => 4,
        tracing::Level::INFO => 6,
        tracing::Level::DEBUG | tracing::Level::TRACE => 7,
    }
}

/// Prefixes each event with its `<N>` syslog priority, then formats it as `inner` does.
struct JournalFormat<F>(F);

impl<S, N, F> tracing_subscriber::fmt::FormatEvent<S, N> for JournalFormat<F>
where
    S: tracing::Subscriber + for<'a> tracing_subscriber::registry::LookupSpan<'a>,
    N: for<'a> tracing_subscriber::fmt::FormatFields<'a> + 'static,
    F: tracing_subscriber::fmt::FormatEvent<S, N>,
{
    fn format_event(
        &self,
        ctx: &tracing_subscriber::fmt::FmtContext<'_, S, N>,
        mut writer: tracing_subscriber::fmt::format::Writer<'_>,
        event: &tracing::Event<'_>,
    ) -> std::fmt::Result {
        write!(writer, "<{}>", syslog_priority(*event.metadata().level()))?;
        self.0.format_event(ctx, writer.by_ref(), event)
    }
}

/// Logging to stderr, in the [`LogStyle`] that fits it. The filter is `RUST_LOG` when set
/// (and valid), else `default_filter` (e.g. a level from the config), else
/// [`DEFAULT_LOG_FILTER`]. Call once, in `main`.
pub fn init_logging(default_filter: Option<&str>) {
    init_logging_with(default_filter, None);
}

/// A layer beside the log's own, seeing every event its `sees` filter lets through whatever the
/// log's filter shows: the bridge's Zenoh TLS watch.
pub struct Watch {
    /// The layer.
    pub layer: Box<dyn tracing_subscriber::Layer<tracing_subscriber::Registry> + Send + Sync>,
    /// The events it sees.
    pub sees: tracing_subscriber::filter::Targets,
    /// Events the log itself no longer shows (the layer says them in its own words).
    pub hides: tracing_subscriber::filter::Targets,
}

impl std::fmt::Debug for Watch {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Watch")
            .field("sees", &self.sees)
            .field("hides", &self.hides)
            .finish_non_exhaustive()
    }
}

/// [`init_logging`], with a [`Watch`] beside the log.
pub fn init_logging_with(default_filter: Option<&str>, watch: Option<Watch>) {
    let filter = env_filter(default_filter);
    let (subscriber, log_max) = subscriber(filter, watch, std::io::stderr, LogStyle::detect());
    install_subscriber(subscriber, log_max);
}

/// `RUST_LOG` when set (and valid), else `default_filter`, else [`DEFAULT_LOG_FILTER`].
fn env_filter(default_filter: Option<&str>) -> tracing_subscriber::EnvFilter {
    use tracing_subscriber::EnvFilter;
    EnvFilter::try_from_default_env()
        .or_else(|_| EnvFilter::try_new(default_filter.unwrap_or(DEFAULT_LOG_FILTER)))
        .unwrap_or_else(|_| EnvFilter::new(DEFAULT_LOG_FILTER))
}

/// The log (to `writer`, in `style`, showing what `filter` lets through less what the watch
/// hides) and the watch beside it; and the most verbose level the log itself shows.
fn subscriber<W>(
    filter: tracing_subscriber::EnvFilter,
    watch: Option<Watch>,
    writer: W,
    style: LogStyle,
) -> (
    Box<dyn tracing::Subscriber + Send + Sync>,
    tracing::level_filters::LevelFilter,
)
where
    W: for<'w> tracing_subscriber::fmt::MakeWriter<'w> + Send + Sync + 'static,
{
    use tracing_subscriber::Layer;
    use tracing_subscriber::filter::FilterExt;
    use tracing_subscriber::layer::SubscriberExt;
    // rustdds's `log` records are made only up to the log's own level: a watch of Zenoh's
    // DEBUG lines must not make every rustdds `debug!` format its arguments.
    let log_max = filter
        .max_level_hint()
        .unwrap_or(tracing::level_filters::LevelFilter::TRACE);
    let (watch, hides) = match watch {
        Some(w) => (Some(w.layer.with_filter(w.sees)), w.hides),
        None => (None, tracing_subscriber::filter::Targets::new()),
    };
    // An empty `Targets` enables nothing, so `not` of it hides nothing.
    let shown = filter.and(hides.not());
    let layer = tracing_subscriber::fmt::layer().with_writer(writer);
    let registry = tracing_subscriber::registry().with(watch);
    let subscriber: Box<dyn tracing::Subscriber + Send + Sync> = match style {
        LogStyle::Terminal => Box::new(registry.with(layer.with_filter(shown))),
        LogStyle::Plain => Box::new(registry.with(layer.with_ansi(false).with_filter(shown))),
        LogStyle::Journal => {
            let format = tracing_subscriber::fmt::format()
                .without_time()
                .with_ansi(false)
                .with_level(false);
            Box::new(
                registry.with(
                    layer
                        .with_ansi(false)
                        .event_format(JournalFormat(format))
                        .with_filter(shown),
                ),
            )
        }
    };
    (subscriber, log_max)
}

/// Makes `subscriber` the process's, and routes `log` records (rustdds's) to it through
/// [`crate::dds_log`], which rate-limits rustdds's per-datagram lines.
fn install_subscriber<S>(subscriber: S, log_max: tracing::level_filters::LevelFilter)
where
    S: tracing::Subscriber + Send + Sync + 'static,
{
    use tracing_log::AsLog;
    if tracing::subscriber::set_global_default(subscriber).is_err() {
        // Set up already (a test, or called twice): keep what is there.
        return;
    }
    let max = log_max.as_log();
    // Fails only if a `log` logger was installed already; then that one stays.
    let _ = crate::dds_log::install(max);
}

/// Logging into `path` (appended), for when a console owns the terminal.
///
/// # Errors
/// The file cannot be opened.
pub fn init_logging_to_file(
    default_filter: Option<&str>,
    path: &std::path::Path,
) -> anyhow::Result<()> {
    let file = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(path)
        .map_err(|e| anyhow::anyhow!("log file {}: {e}", path.display()))?;
    let writer = std::sync::Mutex::new(file);
    let (subscriber, log_max) =
        subscriber(env_filter(default_filter), None, writer, LogStyle::Plain);
    install_subscriber(subscriber, log_max);
    Ok(())
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
    /// Opens the record file for appending, creating it if needed (`--record` appends, as its
    /// help says: a restarted vehicle adds to the record of the run before).
    ///
    /// # Errors
    /// The file cannot be created or opened.
    pub fn create(path: &std::path::Path) -> anyhow::Result<JsonLines> {
        use anyhow::Context;
        let file = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(path)
            .with_context(|| format!("cannot open record {}", path.display()))?;
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

/// Locks `mutex`, taking a poisoned one as it is: for state that every holder leaves
/// consistent, so a panic elsewhere while holding it must not stop the gateway too.
pub fn lock<T>(mutex: &std::sync::Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    mutex
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner)
}

/// Writes a new file (never overwriting one that exists) with `mode`: `rove keys`' files, the
/// web console's certificate. Errors name the path.
///
/// # Errors
/// The file exists, or cannot be created or written.
pub fn create_file(path: &std::path::Path, contents: &[u8], mode: u32) -> anyhow::Result<()> {
    use anyhow::Context;
    use std::io::Write;
    use std::os::unix::fs::OpenOptionsExt;
    let mut file = std::fs::OpenOptions::new()
        .write(true)
        .create_new(true)
        .mode(mode)
        .open(path)
        .with_context(|| format!("cannot create {}", path.display()))?;
    file.write_all(contents)
        .with_context(|| format!("cannot write {}", path.display()))
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

/// For the role loops' tests, on tokio's paused clock.
#[cfg(test)]
pub(crate) mod virtual_time {
    use std::time::Duration;

    /// Lets the loop take what was sent (no virtual time passes while tasks can run). Tests
    /// look between ticks: what is due at the instant a test wakes may not have run yet.
    pub(crate) async fn settle() {
        for _ in 0..10 {
            tokio::task::yield_now().await;
        }
    }

    /// Lets `ms` of virtual time pass.
    pub(crate) async fn wait_ms(ms: u64) {
        tokio::time::sleep(Duration::from_millis(ms)).await;
    }

    /// Awaits a loop whose network went away: it must end with that error, not panic.
    pub(crate) async fn ends_with_network_gone(task: tokio::task::JoinHandle<anyhow::Result<()>>) {
        let error = task
            .await
            .expect("the loop does not panic")
            .expect_err("the loop reports the lost network");
        assert!(error.to_string().contains("network gone"), "{error:#}");
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::ffi::OsStr;

    #[test]
    fn journal_stream_is_device_colon_inode() {
        let cases: &[(&str, Option<(u64, u64)>)] = &[
            ("8:12345", Some((8, 12345))),
            ("0:0", Some((0, 0))),
            ("", None),
            ("8", None),
            ("8:", None),
            (":5", None),
            ("8:5:1", None),
            ("x:5", None),
            ("-1:5", None),
            ("99999999999999999999999:1", None),
        ];
        for (value, want) in cases {
            assert_eq!(
                parse_journal_stream(OsStr::new(value)),
                *want,
                "JOURNAL_STREAM={value:?}"
            );
        }
    }

    #[test]
    fn r20_record_appends_across_starts() {
        let path =
            std::env::temp_dir().join(format!("rove-r20-record-{}.jsonl", std::process::id()));
        let _ = std::fs::remove_file(&path);
        for n in 0..2 {
            let mut rec = JsonLines::create(&path).expect("opens");
            rec.write(&serde_json::json!({ "start": n }));
        }
        let text = std::fs::read_to_string(&path).expect("reads");
        let _ = std::fs::remove_file(&path);
        assert_eq!(text, "{\"start\":0}\n{\"start\":1}\n");
    }

    #[test]
    fn the_journal_wins_then_the_terminal() {
        assert_eq!(LogStyle::choose(false, true), LogStyle::Journal);
        assert_eq!(LogStyle::choose(true, true), LogStyle::Journal);
        assert_eq!(LogStyle::choose(true, false), LogStyle::Terminal);
        assert_eq!(LogStyle::choose(false, false), LogStyle::Plain);
    }

    /// The bridge's watch sees what its filter names whatever the log shows, and what it hides
    /// is not in the log (issue 49: Zenoh's misleading hint).
    #[test]
    fn a_watch_sees_past_the_log_and_hides_what_it_says_itself() {
        use std::sync::{Arc, Mutex};
        use tracing_subscriber::filter::Targets;
        #[derive(Clone, Default)]
        struct Buffer(Arc<Mutex<Vec<u8>>>);
        impl std::io::Write for Buffer {
            fn write(&mut self, b: &[u8]) -> std::io::Result<usize> {
                lock(&self.0).extend_from_slice(b);
                Ok(b.len())
            }
            fn flush(&mut self) -> std::io::Result<()> {
                Ok(())
            }
        }
        struct Seen(Arc<Mutex<Vec<String>>>);
        impl<S: tracing::Subscriber> tracing_subscriber::Layer<S> for Seen {
            fn on_event(
                &self,
                e: &tracing::Event<'_>,
                _: tracing_subscriber::layer::Context<'_, S>,
            ) {
                lock(&self.0).push(e.metadata().target().to_string());
            }
        }
        let (log, seen) = (Buffer::default(), Arc::new(Mutex::new(Vec::new())));
        let watch = Watch {
            layer: Box::new(Seen(Arc::clone(&seen))),
            sees: Targets::new()
                .with_target("watched", tracing::Level::DEBUG)
                .with_target("hidden", tracing::Level::WARN),
            hides: Targets::new().with_target("hidden", tracing::Level::WARN),
        };
        let writer = log.clone();
        let (subscriber, max) = subscriber(
            tracing_subscriber::EnvFilter::new("info"),
            Some(watch),
            move || writer.clone(),
            LogStyle::Plain,
        );
        assert_eq!(max, tracing::level_filters::LevelFilter::INFO);
        tracing::subscriber::with_default(subscriber, || {
            tracing::debug!(target: "watched", "watched debug");
            tracing::warn!(target: "hidden", "hidden warn");
            tracing::info!(target: "shown", "shown info");
            tracing::debug!(target: "shown", "not shown debug");
        });
        let text = String::from_utf8_lossy(&lock(&log.0)).into_owned();
        assert!(text.contains("shown info"), "{text}");
        for absent in ["watched debug", "hidden warn", "not shown debug"] {
            assert!(!text.contains(absent), "{absent}: {text}");
        }
        assert_eq!(*lock(&seen), ["watched", "hidden"]);
    }

    #[test]
    fn priorities_are_syslogs() {
        assert_eq!(syslog_priority(tracing::Level::ERROR), 3);
        assert_eq!(syslog_priority(tracing::Level::WARN), 4);
        assert_eq!(syslog_priority(tracing::Level::INFO), 6);
        assert_eq!(syslog_priority(tracing::Level::DEBUG), 7);
    }
}
