//! Time as a value: the monotonic instants the state machines are stepped with.
//!
//! Nothing in `rove-core` reads a clock. Callers pass `now` into every step; the gateway converts
//! from `tokio::time::Instant` (so `tokio::time::pause()` works in its tests), tests construct
//! instants from milliseconds. Arithmetic saturates: a state machine never panics on time.

use std::fmt;
use std::ops::Add;
use std::time::Duration;

/// A monotonic instant, in nanoseconds since an arbitrary origin chosen by the caller
/// (typically the gateway's start).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Default)]
pub struct MonoTime(u64);

impl MonoTime {
    /// The origin.
    pub const ZERO: MonoTime = MonoTime(0);
    /// The far end of time: later than any instant a clock gives.
    pub const MAX: MonoTime = MonoTime(u64::MAX);

    /// An instant `nanos` nanoseconds after the origin.
    pub const fn from_nanos(nanos: u64) -> Self {
        MonoTime(nanos)
    }

    /// An instant `micros` microseconds after the origin (saturating).
    pub const fn from_micros(micros: u64) -> Self {
        MonoTime(micros.saturating_mul(1_000))
    }

    /// An instant `millis` milliseconds after the origin (saturating).
    pub const fn from_millis(millis: u64) -> Self {
        MonoTime(millis.saturating_mul(1_000_000))
    }

    /// Nanoseconds since the origin.
    pub const fn as_nanos(self) -> u64 {
        self.0
    }

    /// Time elapsed from `earlier` to `self`, zero if `earlier` is later.
    pub fn saturating_since(self, earlier: MonoTime) -> Duration {
        Duration::from_nanos(self.0.saturating_sub(earlier.0))
    }
}

impl Add<Duration> for MonoTime {
    type Output = MonoTime;

    /// Saturates at the far end of time (~584 years) instead of overflowing.
    fn add(self, rhs: Duration) -> MonoTime {
        let nanos = u64::try_from(rhs.as_nanos()).unwrap_or(u64::MAX);
        MonoTime(self.0.saturating_add(nanos))
    }
}

impl fmt::Display for MonoTime {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let micros = self.0 / 1_000;
        write!(f, "{}.{:06}s", micros / 1_000_000, micros % 1_000_000)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn constructors_agree() {
        assert_eq!(MonoTime::from_millis(3), MonoTime::from_micros(3_000));
        assert_eq!(MonoTime::from_micros(3), MonoTime::from_nanos(3_000));
    }

    #[test]
    fn arithmetic_saturates_instead_of_panicking() {
        let end = MonoTime::from_nanos(u64::MAX);
        assert_eq!(end + Duration::from_secs(1), end);
        assert_eq!(MonoTime::from_millis(u64::MAX), end);
        assert_eq!(
            MonoTime::ZERO.saturating_since(MonoTime::from_millis(5)),
            Duration::ZERO
        );
        assert_eq!(MonoTime::ZERO + Duration::MAX, end);
    }

    #[test]
    fn since_measures_forward_time() {
        let a = MonoTime::from_millis(10);
        let b = a + Duration::from_micros(1_500);
        assert_eq!(b.saturating_since(a), Duration::from_micros(1_500));
    }

    #[test]
    fn displays_seconds_with_microseconds() {
        assert_eq!(MonoTime::from_micros(1_234_567).to_string(), "1.234567s");
    }
}
