//! Safety timers: the command timeout and the watchdog that applies it.
//!
//! A [`Watchdog`] is kicked by every sample of a stream and says whether the stream is live at a
//! given instant. The arbiter keeps one per command source; the rule "owner silent for
//! `command_timeout` → re-arbitrate, nobody live → failsafe" is built from it. Liveness is judged
//! on the receiver's own monotonic clock (sender clocks are not synchronised).

use crate::error::{ConfigError, ConfigErrors, Result};
use crate::time::MonoTime;
use std::time::Duration;

/// How long a command stream may stay silent before its sender stops counting as live.
///
/// Default 100 ms (docs/design.md §4): five keep-alive periods at the operators' default 50 Hz, so a
/// single lost or late sample never drops control, while a vehicle stops within a tenth of a second
/// of losing its driver. Shorter risks dropping control on a busy Wi-Fi link; longer lets a
/// vehicle run on after its operator is gone.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct CommandTimeout(Duration);

impl CommandTimeout {
    /// docs/design.md §4 default.
    pub const DEFAULT: CommandTimeout = CommandTimeout(Duration::from_millis(100));
    /// Smallest accepted value: below one scheduler tick a stream can never stay live.
    pub const MIN: Duration = Duration::from_millis(5);
    /// Largest accepted value: a vehicle must not run on for longer without hearing its driver.
    pub const MAX: Duration = Duration::from_secs(10);

    /// Validates a timeout in milliseconds, as written in config under `key`.
    ///
    /// # Errors
    /// [`crate::Error::Config`] naming `key` if `millis` is outside 5..=10 000. There is no
    /// "never expires" value: every command source must time out.
    pub fn from_millis(key: &str, millis: u64) -> Result<CommandTimeout> {
        let d = Duration::from_millis(millis);
        let mut errors = ConfigErrors::default();
        if d < Self::MIN || d > Self::MAX {
            errors.push(ConfigError::new(
                key,
                millis,
                format!(
                    "must be {}..={} ms: every command source must time out",
                    Self::MIN.as_millis(),
                    Self::MAX.as_millis()
                ),
            ));
        }
        errors.into_result(CommandTimeout(d))
    }

    /// The timeout as a duration.
    pub const fn get(self) -> Duration {
        self.0
    }
}

impl Default for CommandTimeout {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// Liveness of one stream: live from a kick until `timeout` after it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Watchdog {
    timeout: Duration,
    last_kick: Option<MonoTime>,
}

impl Watchdog {
    /// A watchdog that has never been kicked (not live).
    pub fn new(timeout: CommandTimeout) -> Self {
        Watchdog {
            timeout: timeout.get(),
            last_kick: None,
        }
    }

    /// Records activity at `at`. An older kick than the last one is ignored.
    pub fn kick(&mut self, at: MonoTime) {
        self.last_kick = Some(self.last_kick.map_or(at, |last| last.max(at)));
    }

    /// Forgets all activity: not live until the next kick (explicit release).
    pub fn clear(&mut self) {
        self.last_kick = None;
    }

    /// Live at `now`: kicked less than `timeout` ago. At exactly `timeout` it has expired.
    pub fn is_live(&self, now: MonoTime) -> bool {
        self.deadline().is_some_and(|d| now < d)
    }

    /// The instant it expires, if it is running.
    pub fn deadline(&self) -> Option<MonoTime> {
        self.last_kick.map(|t| t + self.timeout)
    }

    /// The last kick.
    pub fn last_kick(&self) -> Option<MonoTime> {
        self.last_kick
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ms(v: u64) -> MonoTime {
        MonoTime::from_millis(v)
    }

    #[test]
    fn live_until_exactly_the_timeout() {
        let mut w = Watchdog::new(CommandTimeout::DEFAULT);
        assert!(!w.is_live(ms(0)));
        w.kick(ms(10));
        assert!(w.is_live(ms(10)));
        assert!(w.is_live(ms(109)));
        assert!(!w.is_live(ms(110)));
        assert_eq!(w.deadline(), Some(ms(110)));
    }

    #[test]
    fn an_older_kick_does_not_shorten_the_lease() {
        let mut w = Watchdog::new(CommandTimeout::DEFAULT);
        w.kick(ms(50));
        w.kick(ms(20));
        assert_eq!(w.last_kick(), Some(ms(50)));
    }

    #[test]
    fn clear_ends_liveness_at_once() {
        let mut w = Watchdog::new(CommandTimeout::DEFAULT);
        w.kick(ms(50));
        w.clear();
        assert!(!w.is_live(ms(51)));
        assert_eq!(w.deadline(), None);
    }

    #[test]
    fn rejects_timeouts_that_never_expire_or_are_too_short() {
        assert!(CommandTimeout::from_millis("vehicle.command_timeout_ms", 0).is_err());
        let err = CommandTimeout::from_millis("vehicle.command_timeout_ms", 60_000)
            .expect_err("too long");
        assert!(
            err.to_string()
                .starts_with("vehicle.command_timeout_ms = 60000: must be 5..=10000 ms"),
            "{err}"
        );
        assert_eq!(
            CommandTimeout::from_millis("k", 100),
            Ok(CommandTimeout::DEFAULT)
        );
    }
}
