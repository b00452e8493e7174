//! `rove bench scale`: a fleet of real processes in a namespace the bench creates, each vehicle
//! with two operators of different strength, measured for what one node and the whole fleet cost
//! (docs/design.md, "Fleet scale").
//!
//! Phases, in order:
//! 1. **Fleet.** `V` sim vehicles (ids 100…) and `O` operators (ids 1000…). The first half of the
//!    operators (rounded up) are laptops, the rest desktops: weaker at the same level. Vehicle `k`
//!    is driven by laptop `k mod L` and desktop `k mod D` (L, D: their counts), each at its default
//!    stream rate (50 Hz); with one operator, by it alone. `--idle`: operators drive nothing, which
//!    shows the fixed cost of a participant and its threads.
//! 2. **Steady.** Once every vehicle applies its laptop's commands (idle: once an observer lists
//!    every device), the bench waits 2 s, then reads every process's CPU time (`/proc/PID/stat`)
//!    over the window and its resident memory at the end.
//! 3. **Churn.** `--restarts` times, a desktop quits (SIGTERM) and starts again, one a second:
//!    a weaker operator joining must not take a vehicle from its laptop.
//! 4. **Handover.** While the fleet streams, a mobile phone takes vehicle 100 and quits
//!    (SIGTERM) at its first command applied, or after `--handover-hold-ms` of driving,
//!    `--handover-runs` times: from the SIGTERM to the first command of vehicle 100's laptop
//!    applied again.
//! 5. **Late joiner.** `rove status --events` starts `--latejoin-runs` times: from its start to
//!    the moment it has listed every device of the fleet.
//!
//! Throughout, [`count`] reads every vehicle's record: an apply from anyone but the vehicle's
//! laptop (or the phone, on vehicle 100) is a wrong owner, chiefly its desktop while the laptop
//! streams; a failsafe entry is stale, since every vehicle's laptop lives and streams throughout.
//!
//! `--idle-sweep 8,16,32,64` runs idle fleets of those many processes (half vehicles, half
//! operators) one after the other instead, and reports each one's CPU per node and the growth
//! from the smallest to the largest: what each peer adds to every node.

mod owners;
mod start;
pub mod starts;

use crate::bench::Stats;
use crate::harness::{self, Rig, wall_us};
use crate::procstat::{clock_ticks, sample};
pub use owners::{Incident, MAX_INCIDENTS, PhaseCount, count};
use owners::{SETTLE_PATIENCE, settle, tally};
use serde::Serialize;
#[cfg(test)]
use start::fleet_ids;
use start::{Keys, Started, driven, observer, phone, start};
use std::collections::BTreeSet;
use std::path::Path;
use std::time::{Duration, Instant};

/// The first vehicle's id; vehicle `k` is `FIRST_VEHICLE + k`.
pub const FIRST_VEHICLE: i64 = 100;
/// The first operator's id.
pub const FIRST_OPERATOR: i64 = 1000;
/// The first phone that takes vehicle 100 in the handover phase: run `k` is phone
/// `PHONE + k`, a device new to the fleet each time (one id quitting and coming back at once is
/// held back by the trust rules' pin while it lasts, which is not what a late join measures).
pub const PHONE: i64 = 9000;
/// Phones at most (handover runs).
pub const PHONES: i64 = 900;
/// How long the churn phase waits between two restarts of a weaker operator.
const RESTART_EVERY: Duration = Duration::from_secs(1);

/// Options of `rove bench scale`.
#[derive(Debug, Clone)]
pub struct Options {
    /// Vehicles.
    pub vehicles: usize,
    /// Operators (operator `i` drives vehicle `i % vehicles`).
    pub operators: usize,
    /// Operators drive nothing: the fleet's fixed cost.
    pub idle: bool,
    /// The CPU window.
    pub window: Duration,
    /// Handovers measured on vehicle 100 (not with `idle`).
    pub handover_runs: usize,
    /// How long each phone drives before it quits. Zero (the default) quits at its first
    /// command applied, while the fleet is still taking in its join; longer measures the
    /// handover alone, after the join has settled.
    pub handover_hold: Duration,
    /// Restarts of a weaker operator in the churn phase (not with `idle`).
    pub restarts: usize,
    /// Late joiners measured.
    pub latejoin_runs: usize,
    /// The fleet's check period (`[network] heartbeat_ms`), `None`: the default.
    pub heartbeat_ms: Option<u64>,
    /// The fleet's SPDP period (`[network] presence_ms`), `None`: the default (250 ms).
    pub presence_ms: Option<u64>,
    /// Vehicle 100 (the one whose handovers are measured) runs under SCHED_FIFO at this
    /// priority (`chrt -f`), as the vehicle unit's real-time option does; `None`: the normal
    /// scheduler.
    pub vehicle_rt: Option<u8>,
    /// Every device with a certificate of its own and `[access]` (DDS Security, `rove keys`).
    pub secure: bool,
}

impl Options {
    /// A fleet measured for its CPU alone: no handovers, restarts or late joiners, the default
    /// network settings, unsecured.
    #[must_use]
    pub fn cpu_only(vehicles: usize, operators: usize, idle: bool, window: Duration) -> Options {
        Options {
            vehicles,
            operators,
            idle,
            window,
            handover_runs: 0,
            handover_hold: Duration::ZERO,
            restarts: 0,
            latejoin_runs: 0,
            heartbeat_ms: None,
            presence_ms: None,
            vehicle_rt: None,
            secure: false,
        }
    }
}

/// CPU and memory of one role's processes.
#[derive(Debug, Clone, Copy, Default, Serialize)]
pub struct Usage {
    /// Processes.
    pub processes: usize,
    /// Mean CPU, percent of one core.
    pub cpu_mean_pct: f64,
    /// Busiest process's CPU, percent of one core.
    pub cpu_max_pct: f64,
    /// Mean resident memory at the end of the window, KiB.
    pub rss_mean_kb: u64,
}

/// p50 and p99 of a measurement, ms.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct Percentiles {
    /// Median.
    pub p50: f64,
    /// 99th percentile (nearest rank).
    pub p99: f64,
    /// Samples.
    pub n: usize,
}

impl Percentiles {
    fn of(samples: &[f64]) -> Option<Percentiles> {
        Stats::of(samples).map(|s| Percentiles {
            p50: s.p50,
            p99: s.p99,
            n: samples.len(),
        })
    }
}

/// What one `rove bench scale` run measured (`--json`).
#[derive(Debug, Serialize)]
pub struct Report {
    /// Vehicles.
    pub vehicles: usize,
    /// Operators.
    pub operators: usize,
    /// Operators drove nothing.
    pub idle: bool,
    /// The fleet's check period, ms.
    pub heartbeat_ms: u64,
    /// The fleet's SPDP period, ms.
    pub presence_ms: u64,
    /// Vehicle 100's SCHED_FIFO priority, if it ran real-time.
    pub vehicle_rt: Option<u8>,
    /// The CPU window, s.
    pub window_s: f64,
    /// CPU of every process together, percent of one core.
    pub cpu_total_pct: f64,
    /// Largest resident memory of any process, KiB.
    pub rss_max_kb: u64,
    /// Resident memory of all processes together, KiB.
    pub rss_total_kb: u64,
    /// The vehicles.
    pub vehicle: Usage,
    /// The operators.
    pub operator: Usage,
    /// Late joiner: start → every device listed, ms.
    pub latejoin_ms: Option<Percentiles>,
    /// Vehicle 100: the phone's SIGTERM → its own operator's command applied again, ms.
    pub handover_ms: Option<Percentiles>,
    /// Restarts of a weaker operator done in the churn phase.
    pub restarts: usize,
    /// Applies from anyone but the vehicle's laptop (or the phone, on vehicle 100).
    pub wrong_owner: usize,
    /// Failsafe entries of a vehicle, all of whose laptops live and stream throughout.
    pub stale: usize,
    /// Outputs recorded by all vehicles after the fleet was steady.
    pub outputs: usize,
    /// The first wrong owners and failsafe entries, where and when (at most
    /// [`MAX_INCIDENTS`]).
    pub incidents: Vec<Incident>,
    /// All of them, by phase (`start`, `steady`, `churn`, `handover`, `late joiner`); the
    /// totals above leave out the start.
    pub incidents_by_phase: std::collections::BTreeMap<&'static str, PhaseCount>,
    /// From the first process started until every vehicle was driven by its laptop and no
    /// vehicle had a wrong owner or a failsafe entry for 2 s, ms.
    pub settle_ms: u64,
    /// From the first process started until every vehicle was driven by its laptop and the
    /// start's last wrong owner or failsafe entry, whichever came later, ms: when the fleet
    /// settled (`settle_ms` adds the quiet that shows it, and waits for it in whole seconds).
    pub settled_ms: u64,
    /// Every device had a certificate of its own (DDS Security).
    pub secure: bool,
    /// From the first process started until every vehicle had applied its laptop's command, ms.
    pub driven_ms: u64,
    /// Vehicle 100: a mobile phone started → its first command applied (a late operator into
    /// the running fleet), ms.
    pub late_operator_ms: Option<Percentiles>,
}

/// The usage of one role from (CPU %, RSS KiB) per process.
fn usage(samples: &[(f64, u64)]) -> Usage {
    let n = samples.len().max(1);
    Usage {
        processes: samples.len(),
        cpu_mean_pct: samples.iter().map(|s| s.0).sum::<f64>() / n as f64,
        cpu_max_pct: samples.iter().map(|s| s.0).fold(0.0, f64::max),
        rss_mean_kb: samples.iter().map(|s| s.1).sum::<u64>() / n as u64,
    }
}

/// How long an observer may take to list the whole fleet: generous, 64 processes joining at
/// once on two cores.
const LISTING_PATIENCE: Duration = Duration::from_secs(60);

/// Stops the process started last (an observer) gracefully ([`harness::Proc::stop`]).
fn stop_last(rig: &mut Rig) {
    if let Some(p) = rig.procs.last_mut() {
        p.stop();
    }
}

/// Runs the bench.
///
/// # Errors
/// The namespace or a process cannot be started, or the fleet never becomes steady.
pub fn run(
    rove: &Path,
    options: &Options,
    progress: &mut dyn FnMut(&str),
) -> anyhow::Result<Report> {
    anyhow::ensure!(options.vehicles >= 1, "needs at least one vehicle");
    let mut rig = Rig::new(rove, "scale")?;
    let mut f = start(&mut rig, options)?;
    let started = f.at;
    let fleet: Vec<usize> = (0..rig.procs.len()).collect();
    progress(&format!(
        "{} vehicles, {} operators started{}",
        f.vehicles.len(),
        f.operators.len(),
        if options.secure { ", secured" } else { "" }
    ));
    let everyone: BTreeSet<i64> = f.vehicles.iter().chain(&f.operators).copied().collect();
    let driven_ms = if options.idle {
        let path = observer(&mut rig, &f.keys, "observer");
        let listed = harness::wait_listed(&path, &everyone, LISTING_PATIENCE);
        stop_last(&mut rig);
        listed.map_err(anyhow::Error::msg)?.saturating_sub(started) / 1000
    } else {
        let driven = driven(&f, SETTLE_PATIENCE).map_err(|undriven| {
            anyhow::anyhow!("vehicles {undriven:?} were not driven by their laptops")
        })?;
        settle(&f.vehicles, &f.records, &f.assignment, started)?;
        driven
    };
    let steady = wall_us();
    let settle_ms = (steady - started) / 1000;
    progress(&format!(
        "every vehicle driven {driven_ms} ms, fleet steady {settle_ms} ms after the start; \
         measuring CPU"
    ));
    let (measured, elapsed) = cpu_window(&rig, &fleet, options.window)?;
    let (v_usage, o_usage) = measured.split_at(f.vehicles.len());
    let mut phases = vec![
        (owners::START, started),
        ("steady", steady),
        ("churn", wall_us()),
    ];
    let restarts = match options.idle {
        true => 0,
        false => churn(&mut rig, &mut f, options.restarts, progress),
    };
    phases.push(("handover", wall_us()));
    let (handover, late_operator) = match options.idle {
        true => (Vec::new(), Vec::new()),
        false => handovers(&mut rig, &f, options, progress)?,
    };
    phases.push(("late joiner", wall_us()));
    let latejoin = late_joiners(
        &mut rig,
        &f.keys,
        &everyone,
        options.latejoin_runs,
        progress,
    )?;
    let tally = tally(&f.vehicles, &f.records, &f.assignment, started, &phases);
    Ok(Report {
        vehicles: f.vehicles.len(),
        operators: f.operators.len(),
        idle: options.idle,
        heartbeat_ms: options.heartbeat_ms.unwrap_or(500),
        presence_ms: options.presence_ms.unwrap_or(crate::DEFAULT_PRESENCE_MS),
        vehicle_rt: options.vehicle_rt,
        window_s: elapsed,
        cpu_total_pct: measured.iter().map(|m| m.0).sum(),
        rss_max_kb: measured.iter().map(|m| m.1).max().unwrap_or(0),
        rss_total_kb: measured.iter().map(|m| m.1).sum(),
        vehicle: usage(v_usage),
        operator: usage(o_usage),
        latejoin_ms: Percentiles::of(&latejoin),
        handover_ms: Percentiles::of(&handover),
        restarts,
        wrong_owner: tally.wrong_owner,
        stale: tally.stale,
        outputs: tally.outputs,
        incidents: tally.incidents,
        incidents_by_phase: tally.by_phase,
        settle_ms,
        settled_ms: driven_ms.max(tally.last_start_at_ms.unwrap_or(0)),
        secure: options.secure,
        driven_ms,
        late_operator_ms: Percentiles::of(&late_operator),
    })
}

/// Every process's CPU (percent of a core) over `window`, 2 s from now, and its resident memory
/// at the end (KiB); the window's length, s.
fn cpu_window(
    rig: &Rig,
    fleet: &[usize],
    window: Duration,
) -> anyhow::Result<(Vec<(f64, u64)>, f64)> {
    std::thread::sleep(Duration::from_secs(2));
    let before: Vec<_> = fleet.iter().map(|&p| sample(rig.procs[p].pid())).collect();
    let started = Instant::now();
    std::thread::sleep(window);
    let elapsed = started.elapsed().as_secs_f64();
    let after: Vec<_> = fleet.iter().map(|&p| sample(rig.procs[p].pid())).collect();
    let hz = clock_ticks();
    let measured = (before.iter().zip(&after))
        .map(|(b, a)| match (b, a) {
            (Some(b), Some(a)) => (a.0.saturating_sub(b.0) as f64 / hz / elapsed * 100.0, a.1),
            _ => (0.0, 0),
        })
        .collect();
    anyhow::ensure!(
        after.iter().all(Option::is_some),
        "a process of the fleet exited during the window"
    );
    Ok((measured, elapsed))
}

/// The churn phase: `restarts` times, a desktop quits (SIGTERM) and starts again with what it
/// was started with (`f.started_as`: its process, class and vehicles), one a second; how many.
fn churn(rig: &mut Rig, f: &mut Started, restarts: usize, progress: &mut dyn FnMut(&str)) -> usize {
    let desktops: Vec<i64> = (f.assignment.values())
        .filter_map(|(_, desktop)| *desktop)
        .collect::<BTreeSet<_>>()
        .into_iter()
        .collect();
    if desktops.is_empty() {
        return 0;
    }
    for run in 0..restarts {
        let id = desktops[run % desktops.len()];
        let (p, class, drive) = f.started_as[&id].clone();
        rig.procs[p].stop();
        let extra = f.extra(id);
        let again = rig.operator(id, "stationary", class, &drive, 1000, &extra, &[]);
        progress(&format!(
            "restart {}/{restarts}: desktop {id} (drives {drive:?})",
            run + 1
        ));
        f.started_as.insert(id, (again, class, drive));
        std::thread::sleep(RESTART_EVERY);
    }
    restarts
}

/// `handover_runs` times: a mobile phone starts and takes the first vehicle from its laptop,
/// drives it for `handover_hold`, then quits. Returns, ms, from the phone's SIGTERM to the
/// laptop's first command applied again, and from the phone's start to its own first command
/// applied (a late operator).
fn handovers(
    rig: &mut Rig,
    f: &Started,
    options: &Options,
    progress: &mut dyn FnMut(&str),
) -> anyhow::Result<(Vec<f64>, Vec<f64>)> {
    let runs = options.handover_runs;
    let (vehicle, record) = (f.vehicles[0], &f.records[0]);
    let owner = f.assignment[&vehicle].0;
    let (mut handover, mut late) = (Vec::new(), Vec::new());
    for run in 0..runs {
        let id = phone(run);
        let extra = f.keys.toml(id);
        let t_start = wall_us();
        let phone = rig.operator(id, "mobile", "phone", &[vehicle], 2000, &extra, &[]);
        let first = harness::wait_for_output(record, Some(id), t_start);
        late.push(
            first
                .map_err(anyhow::Error::msg)?
                .wall_us
                .saturating_sub(t_start) as f64
                / 1e3,
        );
        std::thread::sleep(options.handover_hold);
        let t0 = wall_us();
        rig.procs[phone].terminate();
        let out = harness::wait_for_output(record, Some(owner), t0).map_err(anyhow::Error::msg)?;
        rig.procs[phone].wait_exit(harness::PATIENCE);
        handover.push(out.wall_us.saturating_sub(t0) as f64 / 1000.0);
        progress(&format!(
            "handover {}/{runs}: phone drives {:.1} ms after its start, laptop {:.2} ms after \
             its quit",
            run + 1,
            late[run],
            handover[run]
        ));
    }
    Ok((handover, late))
}

/// `runs` times: `rove status --events` starts; from its start to every device of `everyone`
/// listed, ms.
fn late_joiners(
    rig: &mut Rig,
    keys: &Keys,
    everyone: &BTreeSet<i64>,
    runs: usize,
    progress: &mut dyn FnMut(&str),
) -> anyhow::Result<Vec<f64>> {
    let mut latejoin = Vec::new();
    for run in 0..runs {
        let t0 = wall_us();
        let path = observer(rig, keys, &format!("joiner-{run}"));
        let done =
            harness::wait_listed(&path, everyone, LISTING_PATIENCE).map_err(anyhow::Error::msg)?;
        stop_last(rig);
        latejoin.push(done.saturating_sub(t0) as f64 / 1000.0);
        progress(&format!(
            "late joiner {}/{runs}: {} devices listed after {:.1} ms",
            run + 1,
            everyone.len(),
            latejoin[run]
        ));
    }
    Ok(latejoin)
}

/// `rove bench scale`: runs, prints a summary and optionally writes the JSON report.
///
/// # Errors
/// As [`run`], or the JSON file cannot be written.
pub fn cli(rove: &Path, options: &Options, json: Option<&Path>) -> anyhow::Result<()> {
    let r = run(rove, options, &mut |line| eprintln!("{line}"))?;
    let p = |p: Option<Percentiles>| {
        p.map_or("-".into(), |p| {
            format!("p50 {:.2} / p99 {:.2} ms (n={})", p.p50, p.p99, p.n)
        })
    };
    println!(
        "scale {}×{}{}{}: CPU {:.1} % of a core in all ({:.1} s window)\n  vehicle: mean {:.2} %, \
         max {:.2} %, {} KiB\n  operator: mean {:.2} %, max {:.2} %, {} KiB\n  RSS max {} KiB, \
         total {} KiB\n  handover {}\n  late joiner {}\n  {} restarts of a weaker operator; wrong \
         owner {}, stale {}, {} outputs",
        r.vehicles,
        r.operators,
        if r.idle { " idle" } else { "" },
        r.vehicle_rt
            .map_or(String::new(), |p| format!(" (vehicle 100 SCHED_FIFO {p})")),
        r.cpu_total_pct,
        r.window_s,
        r.vehicle.cpu_mean_pct,
        r.vehicle.cpu_max_pct,
        r.vehicle.rss_mean_kb,
        r.operator.cpu_mean_pct,
        r.operator.cpu_max_pct,
        r.operator.rss_mean_kb,
        r.rss_max_kb,
        r.rss_total_kb,
        p(r.handover_ms),
        p(r.latejoin_ms),
        r.restarts,
        r.wrong_owner,
        r.stale,
        r.outputs
    );
    for (phase, n) in &r.incidents_by_phase {
        println!(
            "  {phase}: wrong owner {}, stale {}",
            n.wrong_owner, n.stale
        );
    }
    if !r.idle {
        println!(
            "  settled {} ms after the start (every vehicle driven by its laptop {} ms, the \
             start's last incident then)",
            r.settled_ms, r.driven_ms
        );
    }
    for i in &r.incidents {
        println!(
            "  vehicle {} at {} ms ({}): {}",
            i.vehicle,
            i.at_ms,
            i.phase,
            i.owner
                .map_or("failsafe".to_string(), |o| format!("applied {o}"))
        );
    }
    if let Some(path) = json {
        std::fs::write(path, serde_json::to_string_pretty(&r)? + "\n")?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn usage_is_mean_and_max_per_role() {
        let u = usage(&[(2.0, 100), (4.0, 300)]);
        assert_eq!(
            (u.processes, u.cpu_mean_pct, u.cpu_max_pct, u.rss_mean_kb),
            (2, 3.0, 4.0, 200)
        );
        assert_eq!(usage(&[]).processes, 0);
    }

    #[test]
    fn operators_are_dealt_round_the_vehicles() {
        let options = Options::cpu_only(2, 3, false, Duration::ZERO);
        assert_eq!(
            fleet_ids(&options),
            (vec![100, 101], vec![1000, 1001, 1002])
        );
    }

    #[test]
    fn samples_this_process() {
        let (_, rss) = sample(std::process::id()).expect("own /proc entry");
        assert!(rss > 0);
    }
}
