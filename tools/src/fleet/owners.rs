//! Who should drive each vehicle of the scale bench, and the outputs that say otherwise: a
//! wrong owner (an apply from anyone but the vehicle's laptop) or a failsafe entry.

use super::{PHONE, PHONES};
use crate::harness::{self, Out, wall_us};
use serde::Serialize;
use std::collections::BTreeMap;
use std::path::PathBuf;
use std::time::Duration;

/// The phase from the first process started until the fleet settled: its incidents are
/// counted by phase, not in the totals.
pub const START: &str = "start";

/// Incidents listed at most in a report.
pub const MAX_INCIDENTS: usize = 20;

/// A wrong owner or a failsafe entry, for the report.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct Incident {
    /// The vehicle.
    pub vehicle: i64,
    /// The bench's phase: `steady` (the CPU window), `churn`, `handover`, `late joiner`.
    pub phase: &'static str,
    /// Since the first process of the fleet started, ms.
    pub at_ms: u64,
    /// Who it applied (a wrong owner), or `None`: it went to the failsafe.
    pub owner: Option<i64>,
}

/// The incidents of one vehicle's record from `since_us` on, as [`count`] counts them; each
/// in the last phase (name, start) that began before it.
fn incidents_of(
    outputs: &[Out],
    since_us: u64,
    allowed: &[i64],
    phases: &[(&'static str, u64)],
    vehicle: i64,
) -> Vec<Incident> {
    let mut safe = false;
    let mut found = Vec::new();
    for o in outputs.iter().filter(|o| o.wall_us >= since_us) {
        let incident = match (o.action.as_str(), o.owner) {
            ("apply", Some(owner)) => {
                safe = false;
                (!allowed.contains(&owner)).then_some(Some(owner))
            }
            ("safe", _) => (!std::mem::replace(&mut safe, true)).then_some(None),
            _ => None,
        };
        if let Some(owner) = incident {
            let phase = (phases.iter().rev())
                .find(|(_, start)| *start <= o.wall_us)
                .map_or("steady", |(name, _)| name);
            found.push(Incident {
                vehicle,
                phase,
                at_ms: (o.wall_us - since_us) / 1000,
                owner,
            });
        }
    }
    found
}

/// Wrong owners and stale failsafe entries in `outputs` (one vehicle's record) from `since_us`
/// on: `allowed` may drive; the vehicle's operator lives throughout.
pub fn count(outputs: &[Out], since_us: u64, allowed: &[i64]) -> (usize, usize) {
    wrong_and_stale(&incidents_of(outputs, since_us, allowed, &[], 0))
}

/// Of `incidents`, how many are wrong owners and how many failsafe entries.
fn wrong_and_stale(incidents: &[Incident]) -> (usize, usize) {
    let wrong = incidents.iter().filter(|i| i.owner.is_some()).count();
    (wrong, incidents.len() - wrong)
}

/// For each vehicle, its laptop and its desktop (if any).
pub(super) type Assignment = BTreeMap<i64, (i64, Option<i64>)>;

/// Who drives what: for each vehicle its laptop (the stronger) and its desktop (the weaker, none
/// with a single operator). The first half of `operators` (rounded up) are the laptops.
pub(super) fn assign(vehicles: &[i64], operators: &[i64]) -> Assignment {
    let (laptops, desktops) = operators.split_at(operators.len().div_ceil(2));
    (vehicles.iter().enumerate())
        .filter(|_| !laptops.is_empty())
        .map(|(k, &v)| {
            let desktop = (!desktops.is_empty()).then(|| desktops[k % desktops.len()]);
            (v, (laptops[k % laptops.len()], desktop))
        })
        .collect()
}

/// The vehicles `operator` drives under `assignment`.
pub(super) fn drives_of(assignment: &Assignment, operator: i64) -> Vec<i64> {
    (assignment.iter())
        .filter(|(_, (laptop, desktop))| *laptop == operator || *desktop == Some(operator))
        .map(|(&v, _)| v)
        .collect()
}

/// Whether `operator` is a laptop (the stronger) under `assignment`.
pub(super) fn is_laptop(assignment: &Assignment, operator: i64) -> bool {
    assignment.values().any(|(laptop, _)| *laptop == operator)
}

/// Wrong owners and failsafe entries of one phase.
#[derive(Debug, Clone, Copy, Default, Serialize, PartialEq, Eq)]
pub struct PhaseCount {
    /// Applies from anyone but the vehicle's laptop (or the phone).
    pub wrong_owner: usize,
    /// Failsafe entries.
    pub stale: usize,
}

/// What [`tally`] finds in every vehicle's record since the fleet was steady.
#[derive(Debug, Default)]
pub(super) struct Tally {
    pub wrong_owner: usize,
    pub stale: usize,
    pub outputs: usize,
    /// The first [`MAX_INCIDENTS`] incidents after the start.
    pub incidents: Vec<Incident>,
    /// All of them, counted by phase.
    pub by_phase: BTreeMap<&'static str, PhaseCount>,
    /// When the last one happened (ms after `since`).
    pub last_at_ms: Option<u64>,
    /// When the start's last one happened (ms after `since`).
    pub last_start_at_ms: Option<u64>,
}

/// Wrong owners, stale failsafe entries and outputs of every vehicle's record since `since`,
/// by phase (the start's incidents apart, its outputs not counted), and the first
/// [`MAX_INCIDENTS`] incidents after the start.
pub(super) fn tally(
    vehicles: &[i64],
    records: &[PathBuf],
    assignment: &Assignment,
    since: u64,
    phases: &[(&'static str, u64)],
) -> Tally {
    let mut t = Tally::default();
    // Outputs are counted from the end of the start (the first other phase).
    let counted_from = (phases.iter())
        .find(|(name, _)| *name != START)
        .map_or(since, |(_, at)| *at);
    for (&vehicle, record) in vehicles.iter().zip(records) {
        let outs = harness::records(record);
        let mut allowed: Vec<i64> = (assignment.get(&vehicle))
            .map(|(laptop, _)| *laptop)
            .into_iter()
            .collect();
        if vehicle == vehicles[0] {
            allowed.extend(PHONE..PHONE + PHONES);
        }
        let found = incidents_of(&outs, since, &allowed, phases, vehicle);
        for i in &found {
            t.last_at_ms = t.last_at_ms.max(Some(i.at_ms));
            if i.phase == START {
                t.last_start_at_ms = t.last_start_at_ms.max(Some(i.at_ms));
            }
            let phase = t.by_phase.entry(i.phase).or_default();
            match i.owner {
                Some(_) => phase.wrong_owner += 1,
                None => phase.stale += 1,
            }
        }
        // The start (the fleet joining at once) is counted by phase only.
        let after_start: Vec<Incident> = (found.iter())
            .filter(|i| i.phase != START)
            .cloned()
            .collect();
        let (wrong, failsafe) = wrong_and_stale(&after_start);
        t.wrong_owner += wrong;
        t.stale += failsafe;
        let room = MAX_INCIDENTS.saturating_sub(t.incidents.len());
        t.incidents.extend(after_start.into_iter().take(room));
        t.outputs += outs.iter().filter(|o| o.wall_us >= counted_from).count();
    }
    t
}

/// A streaming fleet has settled after this long without a wrong owner or a failsafe entry:
/// the start of every process at once (discovery of every pair) is over.
pub const SETTLE_QUIET: Duration = Duration::from_secs(2);

/// How long a streaming fleet may take to settle.
pub(super) const SETTLE_PATIENCE: Duration = Duration::from_secs(60);

/// Waits until every vehicle was driven by its laptop and the fleet settled: no wrong owner
/// and no failsafe entry for [`SETTLE_QUIET`] (checked once a second: reading every record
/// costs the fleet CPU).
pub(super) fn settle(
    vehicles: &[i64],
    records: &[PathBuf],
    assignment: &Assignment,
    started: u64,
) -> anyhow::Result<()> {
    for (&vehicle, record) in vehicles.iter().zip(records) {
        if let Some(&(laptop, _)) = assignment.get(&vehicle) {
            harness::wait_for_output(record, Some(laptop), 0).map_err(anyhow::Error::msg)?;
        }
    }
    let give_up = std::time::Instant::now() + SETTLE_PATIENCE;
    let phases = [(START, started)];
    loop {
        let last = tally(vehicles, records, assignment, started, &phases).last_at_ms;
        let quiet_since_us = started + last.map_or(0, |ms| ms * 1000);
        if wall_us().saturating_sub(quiet_since_us) >= SETTLE_QUIET.as_micros() as u64 {
            return Ok(());
        }
        anyhow::ensure!(
            std::time::Instant::now() < give_up,
            "the fleet did not settle within {SETTLE_PATIENCE:?}"
        );
        std::thread::sleep(Duration::from_secs(1));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn out(t: u64, action: &str, owner: Option<i64>) -> Out {
        Out {
            wall_us: t,
            action: action.into(),
            owner,
            throttle: None,
        }
    }

    #[test]
    fn counts_strangers_and_each_failsafe_entry_after_the_start() {
        let outs = [
            out(1, "apply", Some(7)),
            out(1, "safe", None),
            out(10, "apply", Some(1000)),
            out(11, "apply", Some(7)),
            out(12, "safe", None),
            out(13, "safe", None),
            out(14, "apply", Some(9000)),
            out(15, "safe", None),
            out(16, "apply", Some(1000)),
        ];
        assert_eq!(count(&outs, 10, &[1000, 9000]), (1, 2));
        assert_eq!(count(&outs, 10, &[1000]), (2, 2));
        assert_eq!(count(&outs, 0, &[1000, 9000]), (2, 3));
        assert_eq!(count(&outs, 17, &[1000]), (0, 0));
        let phases = [("steady", 10), ("churn", 13), ("handover", 14)];
        let found = incidents_of(&outs, 10, &[1000, 9000], &phases, 100);
        let brief: Vec<_> = found.iter().map(|i| (i.phase, i.at_ms, i.owner)).collect();
        assert_eq!(
            brief,
            vec![
                ("steady", 0, Some(7)),
                ("steady", 0, None),
                ("handover", 0, None)
            ]
        );
        assert_eq!(found.len(), count(&outs, 10, &[1000, 9000]).0 + 2);
    }

    #[test]
    fn the_start_s_last_incident_is_told_apart_from_the_last_of_all() {
        let dir = tempfile::tempdir().expect("tempdir");
        let line = |t: u64, action: &str, owner: Option<i64>| {
            serde_json::json!({"wall_us": t, "action": action, "owner": owner}).to_string()
        };
        // Vehicle 100 (laptop 1000): failsafe, its desktop, its laptop; then a failsafe
        // entry once the fleet is steady. Vehicle 101: its laptop only.
        let records = [
            [
                line(1_000, "safe", None),
                line(10_000, "apply", Some(1002)),
                line(30_000, "apply", Some(1000)),
                line(60_000, "safe", None),
            ],
            [
                line(5_000, "apply", Some(1001)),
                line(20_000, "apply", Some(1001)),
                line(40_000, "apply", Some(1001)),
                line(70_000, "apply", Some(1001)),
            ],
        ];
        let paths: Vec<PathBuf> = (records.iter().enumerate())
            .map(|(k, lines)| {
                let path = dir.path().join(format!("{k}.jsonl"));
                std::fs::write(&path, lines.join("\n") + "\n").expect("write");
                path
            })
            .collect();
        let a = assign(&[100, 101], &[1000, 1001, 1002, 1003]);
        let t = tally(
            &[100, 101],
            &paths,
            &a,
            0,
            &[(START, 0), ("steady", 50_000)],
        );
        assert_eq!(t.last_start_at_ms, Some(10), "the desktop at 10 ms");
        assert_eq!(t.last_at_ms, Some(60), "the failsafe entry when steady");
        assert_eq!((t.wrong_owner, t.stale), (0, 1), "the start is not counted");
        let start = t.by_phase[START];
        assert_eq!((start.wrong_owner, start.stale), (1, 1));
    }

    #[test]
    fn every_vehicle_gets_a_laptop_and_a_weaker_desktop() {
        let vehicles = [100, 101, 102, 103];
        let a = assign(&vehicles, &[1000, 1001, 1002, 1003]);
        assert_eq!(a[&100], (1000, Some(1002)));
        assert_eq!(a[&101], (1001, Some(1003)));
        assert_eq!(a[&102], (1000, Some(1002)));
        assert_eq!(drives_of(&a, 1003), vec![101, 103]);
        assert!(is_laptop(&a, 1001) && !is_laptop(&a, 1002));
        // Three operators: two laptops, one desktop behind every vehicle.
        let a = assign(&vehicles, &[1000, 1001, 1002]);
        assert_eq!(a[&103], (1001, Some(1002)));
        assert_eq!(drives_of(&a, 1002), vec![100, 101, 102, 103]);
        // One operator drives alone; none drives nothing.
        assert_eq!(assign(&vehicles, &[1000])[&102], (1000, None));
        assert!(assign(&vehicles, &[]).is_empty());
    }
}
