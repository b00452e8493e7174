//! rove patch (ROVE-PATCH.md §31): authenticated participants whose messages no longer decode.
//!
//! A pair that authenticated but whose key material went out of step (a handshake that crossed
//! another, keys of a previous session) stays deaf for good: every message fails to decode,
//! and nothing starts over. This keeps, per remote participant, the current streak of decode
//! failures with no success in between. A streak that lasts [`UNDECODABLE_AFTER`] with at
//! least [`UNDECODABLE_MIN`] failures names the participant undecodable; discovery then drops
//! it as if it had left, and its next announcement authenticates it again (§24 restarts the
//! handshake on both sides).
//!
//! A live peer decodes all the time (heartbeats, data), so one success ends a streak: garbage
//! sent under a live peer's GUID prefix by someone else does not get that peer dropped.
//!
//! Pure: time is passed in.

use std::{
  collections::HashMap,
  time::{Duration, Instant},
};

use crate::structure::guid::GuidPrefix;

/// How long a streak of failures, with no success, lasts before its participant is named. Long
/// enough that pairs still settling in a secured fleet's start storm (64 processes on 2 cores:
/// streaks of 10 to 17 failures over 2 s, measured) are left to settle: dropping them made
/// more handshakes, and 32 + 32 never converged.
pub const UNDECODABLE_AFTER: Duration = Duration::from_secs(10);
/// The fewest failures in a streak that name its participant: 10 a second on average. A deaf
/// pair that streams fails far more often (issue 44: 567 in 10 s); a settling one far less.
pub const UNDECODABLE_MIN: u32 = 100;
/// Most streaks kept: a flood of invented prefixes cannot grow the table beyond it.
const MAX_STREAKS: usize = 1024;

#[derive(Debug, Clone, Copy)]
struct Streak {
  first: Instant,
  failures: u32,
}

/// Decode failure streaks per remote participant; see the module docs.
#[derive(Debug, Default)]
pub struct Undecodable {
  streaks: HashMap<GuidPrefix, Streak>,
}

impl Undecodable {
  /// A message from `prefix` did not decode at `now`.
  pub fn failed(&mut self, prefix: GuidPrefix, now: Instant) {
    if let Some(streak) = self.streaks.get_mut(&prefix) {
      streak.failures = streak.failures.saturating_add(1);
      return;
    }
    if self.streaks.len() >= MAX_STREAKS {
      // Streaks older than the limit have been reported or are garbage's: make room.
      self
        .streaks
        .retain(|_, s| now.saturating_duration_since(s.first) < UNDECODABLE_AFTER);
      if self.streaks.len() >= MAX_STREAKS {
        return;
      }
    }
    self.streaks.insert(
      prefix,
      Streak {
        first: now,
        failures: 1,
      },
    );
  }

  /// A message from `prefix` decoded: its streak, if any, ends.
  pub fn decoded(&mut self, prefix: &GuidPrefix) {
    if !self.streaks.is_empty() {
      self.streaks.remove(prefix);
    }
  }

  /// The participant is gone (or authenticating again): its streak is forgotten.
  pub fn forget(&mut self, prefix: &GuidPrefix) {
    self.streaks.remove(prefix);
  }

  /// The participants undecodable at `now`, with their failure counts; each is forgotten (a
  /// new streak starts after it authenticated again).
  pub fn take_undecodable(&mut self, now: Instant) -> Vec<(GuidPrefix, u32)> {
    let due: Vec<(GuidPrefix, u32)> = (self.streaks.iter())
      .filter(|(_, s)| {
        s.failures >= UNDECODABLE_MIN && now.saturating_duration_since(s.first) >= UNDECODABLE_AFTER
      })
      .map(|(p, s)| (*p, s.failures))
      .collect();
    for (prefix, _) in &due {
      self.streaks.remove(prefix);
    }
    due
  }
}

#[cfg(test)]
mod tests {
  use super::*;

  fn prefix(n: u8) -> GuidPrefix {
    GuidPrefix::new(&[n; 12])
  }

  #[test]
  fn a_streak_of_failures_without_a_success_names_its_participant_once() {
    let t0 = Instant::now();
    let at = |ms| t0 + Duration::from_millis(ms);
    let mut u = Undecodable::default();
    let after = UNDECODABLE_AFTER.as_millis() as u64;
    for i in 0..UNDECODABLE_MIN {
      u.failed(prefix(1), at(u64::from(i) * 10));
    }
    assert_eq!(u.take_undecodable(at(after - 1)), vec![], "not long enough yet");
    assert_eq!(
      u.take_undecodable(at(after)),
      vec![(prefix(1), UNDECODABLE_MIN)]
    );
    assert_eq!(u.take_undecodable(at(after * 3)), vec![], "named once");
  }

  #[test]
  fn one_success_ends_a_streak_and_few_failures_name_nobody() {
    let t0 = Instant::now();
    let at = |ms| t0 + Duration::from_millis(ms);
    let mut u = Undecodable::default();
    for i in 0..1000 {
      u.failed(prefix(1), at(i * 30));
      if i % 10 == 0 {
        // A live peer: its heartbeats decode between the garbage sent under its prefix.
        u.decoded(&prefix(1));
      }
    }
    // A settling pair of a start storm: a dozen failures in its streak.
    for i in 0..12 {
      u.failed(prefix(2), at(i * 150));
    }
    assert_eq!(u.take_undecodable(at(30_000)), vec![]);
    assert_eq!(u.take_undecodable(at(60_000)), vec![], "2 had too few");
    u.forget(&prefix(1));
    assert!(u.streaks.is_empty() || u.streaks.keys().all(|p| *p == prefix(2)));
  }

  #[test]
  fn invented_prefixes_cannot_grow_the_table() {
    let t0 = Instant::now();
    let mut u = Undecodable::default();
    for n in 0..5000u32 {
      let mut bytes = [0u8; 12];
      bytes[..4].copy_from_slice(&n.to_be_bytes());
      u.failed(GuidPrefix::new(&bytes), t0);
    }
    assert_eq!(u.streaks.len(), MAX_STREAKS);
    // Once they are old, new ones make room.
    u.failed(prefix(7), t0 + UNDECODABLE_AFTER);
    assert!(u.streaks.contains_key(&prefix(7)));
  }
}
