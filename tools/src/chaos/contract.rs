//! The ownership contract, counted: what the bench did ([`Logged`]) against what the vehicle
//! output ([`Out`]). Pure and unit-tested.

use super::{COMMAND_TIMEOUT_US, GRACE_US, HEAL_US};
use crate::harness::Out;
use serde::Serialize;
use std::collections::BTreeMap;

/// How much sooner than a command timeout after the owner's last apply a lapse may show in the
/// record: the watchdog is kicked on receipt, a moment before the apply is written.
const LAPSE_SLACK_US: u64 = 5_000;

/// What the bench did, when (wall clock, µs). Operators are named by device id, ranked by
/// strength (a higher rank is stronger).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum Fault {
    /// An operator (re)started.
    Start {
        /// The operator.
        id: i64,
    },
    /// SIGKILL.
    Kill {
        /// The operator.
        id: i64,
    },
    /// SIGTERM (a graceful quit).
    Term {
        /// The operator.
        id: i64,
    },
    /// SIGSTOP.
    Stop {
        /// The operator.
        id: i64,
    },
    /// SIGCONT after a stop.
    Cont {
        /// The operator.
        id: i64,
    },
    /// The vehicle was killed (`graceful`: SIGTERM) and restarted by the supervisor.
    VehicleRestart {
        /// SIGTERM rather than SIGKILL.
        graceful: bool,
    },
    /// The operator's link was cut (a silent partition).
    Cut {
        /// The operator.
        id: i64,
    },
    /// The operator's link was restored.
    Heal {
        /// The operator.
        id: i64,
    },
    /// A loss phase began (`pct` % of UDP packets dropped) or ended (`pct` 0).
    Loss {
        /// Percentage of UDP packets dropped.
        pct: u8,
    },
}

/// One entry of the bench's log.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub struct Logged {
    /// Wall clock, µs, before the bench began doing it (a signal may act at once).
    pub at: u64,
    /// Wall clock, µs, once it was done (the signal sent, the process spawned).
    pub done: u64,
    /// What was done.
    pub fault: Fault,
}

/// What [`analyse`] counts.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct Counts {
    /// Applies from an operator while a stronger, live one that already drove was running.
    pub wrong_owner: usize,
    /// Applies from an operator more than a command timeout + 15 ms after it was killed.
    pub stale: usize,
    /// Safe outputs while an operator that already drove was running.
    pub failsafe_while_live: usize,
    /// Owner changes during each loss phase, by loss percentage.
    pub owner_changes_under_loss: BTreeMap<u8, usize>,
    /// Entries into the failsafe during each loss phase, by loss percentage.
    pub failsafe_under_loss: BTreeMap<u8, usize>,
    /// Owner lapses during each loss phase, by loss percentage: the vehicle left its owner for
    /// a weaker operator or the failsafe after the owner's last apply was a command timeout
    /// old (its stream truly fell silent: enough drops in a row). A change away from an owner
    /// heard more recently is a wrong owner, loss or not.
    pub lapses_under_loss: BTreeMap<u8, usize>,
    /// The first few violations, for a look at the record.
    pub examples: Vec<String>,
}

/// Per operator: what the analysis knows at an instant.
#[derive(Debug, Clone, Copy, Default)]
struct OpState {
    /// Running (started and neither killed nor terminated).
    running: bool,
    /// SIGSTOPped.
    stopped: bool,
    /// Killed or terminated at (µs), until restarted.
    dead_since: Option<u64>,
    /// Has driven this vehicle since both were last started.
    drove: bool,
    /// Not judged before this instant (µs): a start, continue or heal takes effect only after
    /// a grace period.
    settles_at: u64,
}

/// The analysis as it walks the record: each operator's state, the loss phase, the counts.
struct Analysis<'a> {
    ranks: &'a BTreeMap<i64, usize>,
    counts: Counts,
    ops: BTreeMap<i64, OpState>,
    vehicle_changed_at: u64,
    loss: u8,
    last_owner: Option<Option<i64>>,
    /// When each operator was last applied: a violation's example says how long the operator
    /// that should have driven had been silent (a stall longer than the command timeout, say).
    last_applied: BTreeMap<i64, u64>,
}

/// Counts contract violations in `outputs` (the vehicle's record, in time order) given what the
/// bench did (`log`, in time order) and each operator's rank (`ranks`: id → strength order).
pub fn analyse(log: &[Logged], outputs: &[Out], ranks: &BTreeMap<i64, usize>) -> Counts {
    let mut analysis = Analysis {
        ranks,
        counts: Counts::default(),
        ops: BTreeMap::new(),
        vehicle_changed_at: 0,
        loss: 0,
        last_owner: None,
        last_applied: BTreeMap::new(),
    };
    let mut next = log.iter().peekable();
    for out in outputs {
        // Apply every logged fault up to this output.
        while let Some(entry) = next.next_if(|e| e.at <= out.wall_us) {
            analysis.fault(entry);
        }
        analysis.output(out);
    }
    analysis.counts
}

impl Analysis<'_> {
    /// A fault takes effect for the analysis from `at` (a signal may act at once); what comes
    /// after it (settling, the death stale outputs are measured from), from `done`.
    fn fault(&mut self, entry: &Logged) {
        let done = entry.done;
        match entry.fault {
            Fault::Start { id } => {
                let started = OpState {
                    running: true,
                    settles_at: done + GRACE_US,
                    ..OpState::default()
                };
                self.ops.insert(id, started);
            }
            Fault::Kill { id } | Fault::Term { id } => {
                let s = self.ops.entry(id).or_default();
                (s.running, s.stopped, s.drove) = (false, false, false);
                s.dead_since = Some(done);
            }
            Fault::Stop { id } | Fault::Cut { id } => {
                self.ops.entry(id).or_default().stopped = true
            }
            Fault::Cont { id } => {
                let s = self.ops.entry(id).or_default();
                (s.stopped, s.settles_at) = (false, done + GRACE_US);
            }
            Fault::Heal { id } => {
                let s = self.ops.entry(id).or_default();
                (s.stopped, s.settles_at) = (false, done + HEAL_US);
            }
            Fault::VehicleRestart { .. } => {
                self.vehicle_changed_at = done;
                for s in self.ops.values_mut() {
                    s.drove = false;
                }
            }
            Fault::Loss { pct } => {
                self.loss = pct;
                self.last_owner = None;
            }
        }
    }

    fn example(&mut self, what: String) {
        if self.counts.examples.len() < 10 {
            self.counts.examples.push(what);
        }
    }

    fn silent(&self, y: i64, t: u64) -> String {
        match self.last_applied.get(&y) {
            Some(at) => format!("{} ms after its last apply", (t - at) / 1000),
            None => "never applied".to_string(),
        }
    }

    /// An operator that must win at `t`: running, not stopped, drove, and settled.
    fn live(s: &OpState, t: u64) -> bool {
        s.running && !s.stopped && s.drove && t > s.settles_at
    }

    fn rank(&self, id: i64) -> usize {
        self.ranks.get(&id).copied().unwrap_or(0)
    }

    /// Judges one output.
    fn output(&mut self, out: &Out) {
        let t = out.wall_us;
        let vehicle_settled = t > self.vehicle_changed_at + GRACE_US;
        match (out.action.as_str(), out.owner) {
            ("apply", Some(x)) => self.apply(x, t, vehicle_settled),
            ("safe", _) => {
                if vehicle_settled
                    && let Some((&y, _)) = self.ops.iter().find(|(_, s)| Self::live(s, t))
                {
                    self.counts.failsafe_while_live += 1;
                    let why = self.silent(y, t);
                    self.example(format!("failsafe at {t} while {y} ran, {why}"));
                }
            }
            _ => {}
        }
        if self.loss > 0 {
            self.under_loss(out.owner, t);
        }
    }

    /// An output during a loss phase: an owner change is counted, and one away from the owner
    /// to a weaker operator (or the failsafe) is a lapse if the owner had been silent for a
    /// command timeout, else a wrong owner.
    fn under_loss(&mut self, owner: Option<i64>, t: u64) {
        let loss = self.loss;
        if let Some(before) = self.last_owner
            && before != owner
        {
            *self
                .counts
                .owner_changes_under_loss
                .entry(loss)
                .or_default() += 1;
            if owner.is_none() {
                *self.counts.failsafe_under_loss.entry(loss).or_default() += 1;
            }
            if let Some(b) = before
                && owner.is_none_or(|x| self.rank(x) < self.rank(b))
            {
                let silent = self.last_applied.get(&b).map_or(u64::MAX, |at| t - at);
                if silent + LAPSE_SLACK_US >= COMMAND_TIMEOUT_US {
                    *self.counts.lapses_under_loss.entry(loss).or_default() += 1;
                } else {
                    self.counts.wrong_owner += 1;
                    self.example(format!(
                        "under {loss} % loss at {t}: {owner:?} took over from {b}, {}",
                        self.silent(b, t)
                    ));
                }
            }
        }
        self.last_owner = Some(owner);
    }

    /// An apply from `x` at `t`: stale after its death, or a wrong owner while a stronger,
    /// live operator runs (under loss a lapse of the stronger stream is counted as an owner
    /// change instead).
    fn apply(&mut self, x: i64, t: u64, vehicle_settled: bool) {
        if let Some(s) = self.ops.get(&x)
            && let Some(dead) = s.dead_since
            && !s.running
            && t > dead + COMMAND_TIMEOUT_US + 15_000
        {
            self.counts.stale += 1;
            self.example(format!(
                "stale: {x} applied {} ms after it died",
                (t - dead) / 1000
            ));
        }
        let rank = self.rank(x);
        let stronger = (self.ops.iter())
            .find(|(y, s)| self.rank(**y) > rank && Self::live(s, t))
            .map(|(y, _)| *y);
        if vehicle_settled
            && self.loss == 0
            && let Some(y) = stronger
        {
            self.counts.wrong_owner += 1;
            let why = self.silent(y, t);
            self.example(format!(
                "wrong owner at {t}: {x} drove while {y} ran, {why}"
            ));
        }
        if let Some(s) = self.ops.get_mut(&x)
            && s.running
        {
            s.drove = true;
        }
        self.last_applied.insert(x, t);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn apply(t: u64, owner: i64) -> Out {
        Out {
            wall_us: t,
            action: "apply".into(),
            owner: Some(owner),
            throttle: Some(0),
        }
    }

    fn safe(t: u64) -> Out {
        Out {
            wall_us: t,
            action: "safe".into(),
            owner: None,
            throttle: None,
        }
    }

    fn at(at: u64, fault: Fault) -> Logged {
        Logged {
            at,
            done: at,
            fault,
        }
    }

    const WEAK: i64 = 11;
    const STRONG: i64 = 12;
    const S: u64 = 1_000_000;

    fn ranks() -> BTreeMap<i64, usize> {
        [(WEAK, 0), (STRONG, 1)].into_iter().collect()
    }

    fn both_started() -> Vec<Logged> {
        vec![
            at(0, Fault::Start { id: WEAK }),
            at(0, Fault::Start { id: STRONG }),
        ]
    }

    #[test]
    fn the_weaker_driving_while_the_stronger_runs_is_a_wrong_owner_once_the_stronger_drove() {
        let log = both_started();
        // Before the stronger one drove, the weaker may drive (discovery order).
        let outputs = [apply(S, WEAK), apply(2 * S, STRONG), apply(3 * S, WEAK)];
        let counts = analyse(&log, &outputs, &ranks());
        assert_eq!(counts.wrong_owner, 1, "{counts:?}");
    }

    #[test]
    fn the_weaker_driving_while_the_stronger_is_stopped_killed_or_settling_is_right() {
        let mut log = both_started();
        log.push(at(3 * S, Fault::Stop { id: STRONG }));
        log.push(at(4 * S, Fault::Cont { id: STRONG }));
        log.push(at(6 * S, Fault::Kill { id: STRONG }));
        let outputs = [
            apply(2 * S, STRONG),
            apply(3 * S + 150_000, WEAK),             // stopped
            apply(4 * S + GRACE_US / 2, WEAK),        // continued, settling
            apply(4 * S + GRACE_US + 10_000, STRONG), // back
            apply(6 * S + 120_000, WEAK),             // killed
        ];
        let counts = analyse(&log, &outputs, &ranks());
        assert_eq!(counts, Counts::default());
    }

    #[test]
    fn an_apply_from_an_operator_after_its_death_plus_a_timeout_is_stale() {
        let mut log = both_started();
        log.push(at(2 * S, Fault::Kill { id: WEAK }));
        let outputs = [
            apply(S, WEAK),
            apply(2 * S + COMMAND_TIMEOUT_US, WEAK),
            apply(2 * S + COMMAND_TIMEOUT_US + 20_000, WEAK),
        ];
        let counts = analyse(&log, &outputs, &ranks());
        assert_eq!(counts.stale, 1, "{counts:?}");
    }

    #[test]
    fn failsafe_counts_only_while_a_settled_operator_that_drove_runs() {
        let mut log = both_started();
        log.push(at(3 * S, Fault::Term { id: STRONG }));
        log.push(at(3 * S, Fault::Term { id: WEAK }));
        log.push(at(5 * S, Fault::VehicleRestart { graceful: false }));
        let outputs = [
            safe(S / 2), // nobody drove yet
            apply(S, STRONG),
            safe(2 * S),        // STRONG runs and drove: counted
            safe(3 * S + 1000), // both quit
            safe(5 * S + 1000), // the vehicle restarted
        ];
        let counts = analyse(&log, &outputs, &ranks());
        assert_eq!(counts.failsafe_while_live, 1, "{counts:?}");
    }

    #[test]
    fn owner_changes_and_failsafe_entries_are_counted_per_loss_phase() {
        let mut log = both_started();
        log.push(at(2 * S, Fault::Loss { pct: 10 }));
        log.push(at(4 * S, Fault::Loss { pct: 30 }));
        log.push(at(6 * S, Fault::Loss { pct: 0 }));
        let outputs = [
            apply(S, STRONG),
            apply(2 * S + 1, STRONG),
            apply(3 * S, WEAK),
            apply(3 * S + 1, STRONG),
            apply(4 * S + 1, STRONG),
            safe(5 * S),
            apply(5 * S + 1, STRONG),
            apply(7 * S, WEAK),
        ];
        let counts = analyse(&log, &outputs, &ranks());
        assert_eq!(counts.owner_changes_under_loss.get(&10), Some(&2));
        assert_eq!(counts.owner_changes_under_loss.get(&30), Some(&2));
        assert_eq!(counts.failsafe_under_loss.get(&30), Some(&1));
        assert_eq!(counts.failsafe_under_loss.get(&10), None);
        // Each went away from an owner silent for a second: lapses, not wrong owners.
        assert_eq!(counts.lapses_under_loss.get(&10), Some(&1));
        assert_eq!(counts.lapses_under_loss.get(&30), Some(&1));
    }

    #[test]
    fn under_loss_leaving_an_owner_heard_within_the_timeout_is_a_wrong_owner() {
        const MS: u64 = 1_000;
        let mut log = both_started();
        log.push(at(2 * S, Fault::Loss { pct: 10 }));
        let lapse = COMMAND_TIMEOUT_US;
        let outputs = [
            apply(S, STRONG),
            apply(2 * S + 20 * MS, STRONG),
            // Silent for a command timeout: a lapse; then the stronger is back.
            apply(2 * S + 20 * MS + lapse, WEAK),
            apply(2 * S + 30 * MS + lapse, STRONG),
            // Heard 40 ms before the weaker drives: the vehicle left a live owner.
            apply(2 * S + 70 * MS + lapse, WEAK),
        ];
        let counts = analyse(&log, &outputs, &ranks());
        assert_eq!(counts.owner_changes_under_loss.get(&10), Some(&3));
        assert_eq!(counts.lapses_under_loss.get(&10), Some(&1));
        assert_eq!(counts.wrong_owner, 1, "{counts:?}");
        assert!(
            counts.examples[0].contains("40 ms after its last apply"),
            "{counts:?}"
        );
    }
}
