//! rustdds's log records, rate-limited per call site before they reach `tracing`.
//!
//! rustdds logs through the `log` crate, often once per received datagram ("RTPS deserialize
//! error", "unknown start of header", a submessage for an unknown writer…). A corrupt or hostile
//! sender can therefore write 100 000 lines a second into the journal (issue 29). This logger
//! stands where `tracing-log`'s `LogTracer` would: a record from rustdds at INFO or above
//! passes if its call site (file and line) has not logged for [`INTERVAL`]; otherwise it is
//! counted, and the next line that site logs says how many were held back. Other crates'
//! records, and rustdds's DEBUG and TRACE (off unless asked for), pass unchanged.
//!
//! The decision is [`SiteLimiter`], pure and tested with an injected clock.

use std::borrow::Cow;
use std::collections::HashMap;
use std::sync::Mutex;
use std::time::{Duration, Instant};

/// One line per call site and interval. Long enough that a spray of bad datagrams costs a few
/// lines a minute; short enough that a problem that goes on is seen to go on.
pub const INTERVAL: Duration = Duration::from_secs(10);

/// Call sites remembered at most. rustdds has a few hundred log statements; the table is
/// cleared if it ever fills (the worst case is one extra line per site).
const MAX_SITES: usize = 1024;

/// A call site: the source file and line of the log statement. The file is borrowed when the
/// record carries it as `'static` (the `log` macros do), so a flood of records allocates nothing.
type Site = (Cow<'static, str>, u32);

/// What to do with one record.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Verdict {
    /// Log it; `held_back` records of this site were dropped since its last line.
    Log {
        /// Records of this site not logged since its last line.
        held_back: u64,
    },
    /// Drop it (counted).
    Drop,
}

#[derive(Debug)]
struct SiteState {
    last: Instant,
    held_back: u64,
}

/// Per-call-site rate limit: the first record of a site passes, then at most one per
/// [`INTERVAL`], carrying the count of those dropped in between.
#[derive(Debug, Default)]
pub struct SiteLimiter {
    sites: HashMap<Site, SiteState>,
}

impl SiteLimiter {
    /// The verdict for a record of `site` at `now`.
    pub fn check(&mut self, site: Site, now: Instant) -> Verdict {
        if self.sites.len() >= MAX_SITES && !self.sites.contains_key(&site) {
            self.sites.clear();
        }
        match self.sites.get_mut(&site) {
            None => {
                self.sites.insert(
                    site,
                    SiteState {
                        last: now,
                        held_back: 0,
                    },
                );
                Verdict::Log { held_back: 0 }
            }
            Some(state) if now.saturating_duration_since(state.last) >= INTERVAL => {
                let held_back = state.held_back;
                state.last = now;
                state.held_back = 0;
                Verdict::Log { held_back }
            }
            Some(state) => {
                state.held_back += 1;
                Verdict::Drop
            }
        }
    }
}

/// The `log` logger: rustdds's records rate-limited, everything forwarded to `tracing`.
struct Logger {
    inner: tracing_log::LogTracer,
    limiter: Mutex<SiteLimiter>,
}

fn limited(metadata: &log::Metadata<'_>) -> bool {
    metadata.target().starts_with("rustdds") && metadata.level() <= log::Level::Info
}

impl log::Log for Logger {
    fn enabled(&self, metadata: &log::Metadata<'_>) -> bool {
        self.inner.enabled(metadata)
    }

    fn log(&self, record: &log::Record<'_>) {
        if !limited(record.metadata()) {
            return self.inner.log(record);
        }
        let file = match (record.file_static(), record.file()) {
            (Some(file), _) => Cow::Borrowed(file),
            (None, file) => Cow::Owned(file.unwrap_or(record.target()).to_string()),
        };
        let site = (file, record.line().unwrap_or(0));
        let verdict = match self.limiter.lock() {
            Ok(mut limiter) => limiter.check(site, Instant::now()),
            // A panic while holding the table: log rather than lose lines.
            Err(_) => Verdict::Log { held_back: 0 },
        };
        match verdict {
            Verdict::Drop => {}
            Verdict::Log { held_back: 0 } => self.inner.log(record),
            Verdict::Log { held_back } => self.inner.log(
                &log::Record::builder()
                    .metadata(record.metadata().clone())
                    .module_path(record.module_path())
                    .file(record.file())
                    .line(record.line())
                    .args(format_args!(
                        "{} ({held_back} more like this in the last {} s not logged)",
                        record.args(),
                        INTERVAL.as_secs()
                    ))
                    .build(),
            ),
        }
    }

    fn flush(&self) {
        self.inner.flush();
    }
}

/// Installs the logger for `log` records (in place of `tracing-log`'s own), forwarding to the
/// `tracing` subscriber at up to `max` level.
///
/// # Errors
/// A `log` logger is already installed.
pub fn install(max: log::LevelFilter) -> Result<(), log::SetLoggerError> {
    log::set_boxed_logger(Box::new(Logger {
        inner: tracing_log::LogTracer::new(),
        limiter: Mutex::new(SiteLimiter::default()),
    }))?;
    log::set_max_level(max);
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn site(line: u32) -> Site {
        (Cow::Borrowed("src/rtps/message_receiver.rs"), line)
    }

    #[test]
    fn a_site_logs_once_per_interval_then_says_how_many_it_held_back() {
        let mut limiter = SiteLimiter::default();
        let t0 = Instant::now();
        assert_eq!(limiter.check(site(1), t0), Verdict::Log { held_back: 0 });
        for i in 1..=999u64 {
            let t = t0 + INTERVAL.mul_f64(i as f64 / 1000.0);
            assert_eq!(limiter.check(site(1), t), Verdict::Drop);
        }
        assert_eq!(
            limiter.check(site(1), t0 + INTERVAL),
            Verdict::Log { held_back: 999 }
        );
        assert_eq!(
            limiter.check(site(1), t0 + INTERVAL * 2),
            Verdict::Log { held_back: 0 }
        );
    }

    #[test]
    fn sites_are_limited_apart() {
        let mut limiter = SiteLimiter::default();
        let t0 = Instant::now();
        assert_eq!(limiter.check(site(1), t0), Verdict::Log { held_back: 0 });
        assert_eq!(limiter.check(site(2), t0), Verdict::Log { held_back: 0 });
        assert_eq!(limiter.check(site(1), t0), Verdict::Drop);
        let other_file = (Cow::Owned("src/rtps/reader.rs".to_string()), 1);
        assert_eq!(limiter.check(other_file, t0), Verdict::Log { held_back: 0 });
    }

    #[test]
    fn the_table_is_bounded() {
        let mut limiter = SiteLimiter::default();
        let t0 = Instant::now();
        for line in 0..(3 * MAX_SITES as u32) {
            assert_eq!(limiter.check(site(line), t0), Verdict::Log { held_back: 0 });
            assert!(limiter.sites.len() <= MAX_SITES);
        }
    }

    #[test]
    fn only_rustdds_info_and_above_is_limited() {
        let meta = |target, level| log::Metadata::builder().target(target).level(level).build();
        assert!(limited(&meta(
            "rustdds::rtps::message_receiver",
            log::Level::Warn
        )));
        assert!(limited(&meta("rustdds", log::Level::Info)));
        assert!(!limited(&meta("rustdds::rtps", log::Level::Debug)));
        assert!(!limited(&meta("rove_gateway::vehicle", log::Level::Warn)));
    }
}
