//! Freshness from the wire: whether a sample arrived late, judged against its own writer's
//! fastest delivery, so that commands that queued up (in a vehicle that was stalled or stopped,
//! or behind a lost packet that was repaired) are not applied as if they were fresh.
//!
//! A writer stamps each sample with its own clock (the RTPS source timestamp). The vehicle
//! cannot compare that stamp with its own clock, because the machines' clocks differ, but it can
//! compare one writer's samples with each other: `arrival − sent` is the clocks' offset plus the
//! sample's delay, and its smallest value so far (the baseline) is the offset plus the fastest
//! delivery. A sample whose `arrival − sent` exceeds the baseline by more than the limit (the
//! command timeout) waited that much longer than the writer's fastest sample: it is stale.
//!
//! - The baseline creeps up by [`DRIFT_PPM`] of the time between a writer's samples, so that
//!   clocks running at slightly different rates never make a writer's samples stale.
//! - A writer whose samples have all been stale for [`REBASE`] (of arrivals) had its clock
//!   stepped back (NTP): its baseline restarts from its current sample. (Its samples are
//!   dropped meanwhile, so the vehicle treats it as silent for that long.)
//! - A sample that claims to have been sent earlier than its writer's fastest delivery allows
//!   (more than [`EARLY_SLACK`] ahead of the baseline) is fresh, but does not lower the
//!   baseline: a corrupt or forged source timestamp (a mutated copy of the owner's datagram
//!   stamped in the future) made every later real sample of that writer look late, and the
//!   vehicle dropped its owner's stream for a second at a time (issue 29). A writer whose
//!   samples are all that early for [`REBASE`] had its clock stepped forward: its baseline
//!   restarts from its current sample.
//! - A sample without a source timestamp is fresh: there is nothing to judge it by.
//! - The table is bounded ([`Freshness::new`]'s `max_writers`): a new writer beyond it evicts
//!   the one heard from longest ago.

use crate::arbiter::WriterId;
use crate::time::MonoTime;
use std::collections::HashMap;
use std::time::Duration;

/// How fast a writer's baseline may creep up: 100 ppm, well above the drift of any two
/// crystal clocks (typically under 50 ppm), so drift never looks like delay.
pub const DRIFT_PPM: i128 = 100;

/// How long a writer's samples may all be stale (or all early) before its baseline restarts.
pub const REBASE: Duration = Duration::from_secs(1);

/// How much faster than its fastest so far one sample may arrive and move its writer's baseline:
/// 10 ms, more than loopback or a radio link's delivery improves from one sample to the next,
/// far less than the command timeout. Earlier than that, a single sample moves nothing (above).
pub const EARLY_SLACK: Duration = Duration::from_millis(10);

#[derive(Debug, Clone, Copy)]
struct Baseline {
    /// The smallest `arrival − sent` so far (crept up for drift), ns.
    offset: i128,
    last_arrival: MonoTime,
    /// Since when every sample of this writer has been stale.
    stale_since: Option<MonoTime>,
    /// Since when every sample of this writer has been early beyond [`EARLY_SLACK`].
    early_since: Option<MonoTime>,
}

/// Per-writer delivery baselines; see the module docs.
#[derive(Debug, Clone)]
pub struct Freshness {
    limit: Duration,
    max_writers: usize,
    writers: HashMap<WriterId, Baseline>,
}

impl Freshness {
    /// Samples later than `limit` (beyond their writer's fastest) are stale; at most
    /// `max_writers` writers are remembered.
    pub fn new(limit: Duration, max_writers: usize) -> Freshness {
        Freshness {
            limit,
            max_writers: max_writers.max(1),
            writers: HashMap::new(),
        }
    }

    /// `None` if the sample `writer` sent at `sent` (its clock, ns) and which arrived at
    /// `arrival` is fresh; else how much later than the writer's fastest delivery it arrived.
    pub fn judge(
        &mut self,
        writer: WriterId,
        sent: Option<i128>,
        arrival: MonoTime,
    ) -> Option<Duration> {
        let sent = sent?;
        let offset = i128::from(arrival.as_nanos()) - sent;
        if !self.writers.contains_key(&writer) && self.writers.len() >= self.max_writers {
            let oldest = (self.writers.iter())
                .min_by_key(|(_, b)| b.last_arrival)
                .map(|(w, _)| *w);
            if let Some(oldest) = oldest {
                self.writers.remove(&oldest);
            }
        }
        let fresh = Baseline {
            offset,
            last_arrival: arrival,
            stale_since: None,
            early_since: None,
        };
        let base = self.writers.entry(writer).or_insert(fresh);
        let since_last = arrival.saturating_since(base.last_arrival).as_nanos() as i128;
        let crept = base.offset + since_last * DRIFT_PPM / 1_000_000;
        base.last_arrival = arrival;
        let late = offset - crept;
        let limit = self.limit.as_nanos() as i128;
        let slack = EARLY_SLACK.as_nanos() as i128;
        if late < -slack {
            base.stale_since = None;
            let since = *base.early_since.get_or_insert(arrival);
            if arrival.saturating_since(since) >= REBASE {
                *base = fresh;
            } else {
                base.offset = crept;
            }
            return None;
        }
        base.early_since = None;
        if late <= limit {
            base.offset = crept.min(offset);
            base.stale_since = None;
            return None;
        }
        let since = *base.stale_since.get_or_insert(arrival);
        if arrival.saturating_since(since) >= REBASE {
            *base = fresh;
            return None;
        }
        base.offset = crept;
        Some(Duration::from_nanos(
            u64::try_from(late).unwrap_or(u64::MAX),
        ))
    }

    /// Forgets a writer that left.
    pub fn forget(&mut self, writer: WriterId) {
        self.writers.remove(&writer);
    }

    /// Forgets every writer of a participant that left (its writers' own losses may never be
    /// reported: a lease that ran out, a goodbye whose endpoint disposals were lost).
    pub fn forget_participant(&mut self, participant: crate::sender::ParticipantId) {
        self.writers.retain(|w, _| w.participant != participant);
    }

    /// Writers remembered.
    pub fn len(&self) -> usize {
        self.writers.len()
    }

    /// Whether no writer is remembered.
    pub fn is_empty(&self) -> bool {
        self.writers.is_empty()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::arbiter::ParticipantId;
    use proptest::prelude::*;

    const LIMIT: Duration = Duration::from_millis(100);

    fn writer(n: u32) -> WriterId {
        WriterId {
            participant: ParticipantId(7),
            entity: n,
        }
    }

    fn ms(t: u64) -> MonoTime {
        MonoTime::ZERO + Duration::from_millis(t)
    }

    fn ns(t_ms: i128) -> i128 {
        t_ms * 1_000_000
    }

    #[test]
    fn a_steady_stream_is_fresh_whatever_the_clock_offset() {
        for skew in [-3_600_000i128, 0, 42, 86_400_000] {
            let mut f = Freshness::new(LIMIT, 16);
            for i in 0..200u64 {
                let jitter = (i % 7) * 10; // 0..60 ms of varying delay
                let arrival = ms(1_000 + i * 20 + jitter);
                assert_eq!(
                    f.judge(writer(1), Some(ns(i128::from(i) * 20 + skew)), arrival),
                    None
                );
            }
        }
    }

    #[test]
    fn samples_that_queued_during_a_stall_are_stale_except_the_newest() {
        let mut f = Freshness::new(LIMIT, 16);
        for i in 0..50u64 {
            assert_eq!(
                f.judge(writer(1), Some(ns(i128::from(i) * 20)), ms(5 + i * 20)),
                None
            );
        }
        // The vehicle stops for 500 ms (sent 1000..1500), then takes its queue at once.
        let resumed = ms(1_505);
        let mut verdicts = Vec::new();
        for i in 50..=75u64 {
            verdicts.push(f.judge(writer(1), Some(ns(i128::from(i) * 20)), resumed));
        }
        // Those held back more than the limit (by 500, 480, … 120 ms) are stale; the baseline
        // crept up 100 ppm of the 500 ms gap meanwhile.
        let stale = verdicts.iter().filter(|v| v.is_some()).count();
        assert_eq!(stale, 20, "{verdicts:?}");
        let first = verdicts[0].unwrap_or_default();
        assert!(first > Duration::from_millis(499) && first <= Duration::from_millis(500));
        assert_eq!(
            verdicts.last(),
            Some(&None),
            "the newest, sent just now, is fresh"
        );
        // The stream goes on, fresh.
        assert_eq!(f.judge(writer(1), Some(ns(76 * 20)), ms(1_525)), None);
    }

    /// Issue 51: a participant that left takes every baseline of its writers with it, even
    /// when their own losses were never reported.
    #[test]
    fn a_departed_participant_leaves_no_baseline() {
        let mut f = Freshness::new(LIMIT, 16);
        let other = WriterId {
            participant: ParticipantId(8),
            entity: 1,
        };
        for w in [writer(1), writer(2), other] {
            assert_eq!(f.judge(w, Some(ns(0)), ms(5)), None);
        }
        assert_eq!(f.len(), 3);
        f.forget_participant(ParticipantId(7));
        assert_eq!(f.len(), 1, "only the other participant's writer stays");
        f.forget(other);
        assert!(f.is_empty());
    }

    #[test]
    fn drift_never_looks_like_delay() {
        // The writer's clock runs 80 ppm slow for an hour of samples at 10 Hz.
        let mut f = Freshness::new(LIMIT, 16);
        for i in 0..36_000u64 {
            let arrival_ms = i * 100;
            let sent = i128::from(arrival_ms) * 1_000_000 * (1_000_000 - 80) / 1_000_000;
            assert_eq!(
                f.judge(writer(1), Some(sent), ms(arrival_ms)),
                None,
                "sample {i}"
            );
        }
    }

    /// Issue 29: a mutated copy of the owner's sample, stamped far in the future, among its
    /// real samples.
    #[test]
    fn a_sample_stamped_in_the_future_does_not_make_the_next_ones_stale() {
        let mut f = Freshness::new(LIMIT, 16);
        for i in 0..10u64 {
            assert_eq!(
                f.judge(writer(1), Some(ns(i128::from(i) * 20)), ms(i * 20)),
                None
            );
        }
        for forged_ahead_ms in [11i128, 150, 10_000, 1 << 40] {
            assert_eq!(
                f.judge(writer(1), Some(ns(200 + forged_ahead_ms)), ms(200)),
                None,
                "the forged sample itself is not stale"
            );
            for i in 10..20u64 {
                assert_eq!(
                    f.judge(writer(1), Some(ns(i128::from(i) * 20)), ms(i * 20)),
                    None,
                    "real sample {i} after one {forged_ahead_ms} ms ahead"
                );
            }
        }
    }

    #[test]
    fn a_clock_stepped_forward_rebases_after_rebase() {
        let mut f = Freshness::new(LIMIT, 16);
        for i in 0..10u64 {
            assert_eq!(
                f.judge(writer(1), Some(ns(i128::from(i) * 20)), ms(i * 20)),
                None
            );
        }
        // The writer's clock steps forward 10 s: every sample is early, and fresh.
        for i in 10..200u64 {
            let sent = ns(i128::from(i) * 20 + 10_000);
            assert_eq!(f.judge(writer(1), Some(sent), ms(i * 20)), None);
        }
        // By now the baseline is the new clock's: a sample that queued 150 ms is stale.
        assert!(
            f.judge(writer(1), Some(ns(200 * 20 + 10_000 - 150)), ms(200 * 20))
                .is_some()
        );
    }

    #[test]
    fn a_clock_stepped_back_is_stale_for_at_most_rebase() {
        let mut f = Freshness::new(LIMIT, 16);
        for i in 0..10u64 {
            assert_eq!(
                f.judge(writer(1), Some(ns(i128::from(i) * 20)), ms(i * 20)),
                None
            );
        }
        // The writer's clock steps back 10 s.
        let mut first_fresh = None;
        for i in 10..200u64 {
            let verdict = f.judge(writer(1), Some(ns(i128::from(i) * 20 - 10_000)), ms(i * 20));
            if verdict.is_none() {
                first_fresh = Some(i * 20);
                break;
            }
        }
        assert_eq!(first_fresh, Some(200 + REBASE.as_millis() as u64));
    }

    #[test]
    fn untimed_samples_are_fresh_and_the_table_is_bounded() {
        let mut f = Freshness::new(LIMIT, 4);
        assert_eq!(f.judge(writer(1), None, ms(5_000)), None);
        assert!(f.is_empty());
        for w in 0..100 {
            f.judge(writer(w), Some(0), ms(u64::from(w)));
            assert!(f.len() <= 4);
        }
        // The newest four are kept: writer 99 has a baseline (its late sample is stale),
        // writer 0 was evicted (its late sample starts a new baseline).
        assert!(f.judge(writer(99), Some(0), ms(1_099)).is_some());
        assert_eq!(f.judge(writer(0), Some(0), ms(1_100)), None);
        f.forget(writer(0));
        assert_eq!(f.len(), 3);
    }

    proptest! {
        /// Whatever the offset and drift (within 50 ppm), delays within the limit are fresh,
        /// and a sample held back longer than the limit plus the stream's jitter is stale.
        #[test]
        fn fresh_within_the_limit_stale_beyond(
            skew in -1_000_000_000_000i128..1_000_000_000_000,
            drift_ppm in -50i128..50,
            delays in proptest::collection::vec(0u64..40, 20..200),
            held in 150u64..2_000,
        ) {
            let mut f = Freshness::new(LIMIT, 16);
            let sent_of = |t_ms: u64| {
                let t = i128::from(t_ms) * 1_000_000;
                t + t * drift_ppm / 1_000_000 + skew
            };
            let mut t = 0u64;
            for delay in &delays {
                t += 20;
                prop_assert_eq!(f.judge(writer(1), Some(sent_of(t)), ms(t + delay)), None);
            }
            // A sample sent now arrives `held` ms late (jitter so far was under 40 ms).
            t += 20;
            prop_assert!(f.judge(writer(1), Some(sent_of(t)), ms(t + held)).is_some());
        }
    }
}
