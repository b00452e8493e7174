//! `rove bench chaos`: real processes under random faults, counted against the ownership
//! contract (docs/design.md §4, §5).
//!
//! One vehicle (sim adapter, recording its outputs) and N operators of distinct strengths run in
//! a network namespace the bench creates. Three phases:
//! 1. **Chaos**: `events` random faults, one every `interval` (±50 %): an operator SIGKILLed,
//!    SIGTERMed, SIGSTOPped (continued 100–600 ms later) or restarted; the vehicle SIGKILLed or
//!    SIGTERMed under a supervisor that runs `rove failsafe` and restarts it, as systemd's
//!    `ExecStopPost=` and `Restart=` do.
//! 2. **Loss**: every operator running, then random loss of UDP packets on the namespace's
//!    loopback (nftables), by default 10 % and then 30 %, each for `loss`.
//! 3. **Partition** (with `--partition`): the strongest operator runs in a second namespace
//!    joined by a veth pair; its link is cut (an nftables drop: a silent partition) and
//!    restored, and the bench measures how long after the heal it drives again.
//!
//! What is counted comes from the vehicle's record and the bench's own log of what it did, both
//! in wall-clock microseconds ([`analyse`], pure and unit-tested):
//! - **wrong owner**: an apply from X while a stronger operator that already drove this vehicle
//!   (since both were last started) is running, neither stopped nor told to stop, for longer
//!   than [`GRACE_US`];
//! - **stale**: an apply from X later than the command timeout plus 15 ms after X was killed or
//!   terminated;
//! - **failsafe while live**: the vehicle going safe while such an operator runs;
//! - **owner changes** under loss (none is demanded: nothing else happens then), and among them
//!   **lapses**: the vehicle leaving its owner for a weaker operator or the failsafe after the
//!   owner's last apply was a command timeout old (drops in a row silenced it: at 50 Hz and
//!   10 % loss, about one 20 s phase in 30 to 100 has one). Leaving an owner heard more
//!   recently is a wrong owner under loss too; and failsafe entries under loss;
//! - **recovery**: from the partition's heal to the first apply from the healed operator.

mod contract;
mod fleet;

pub use contract::{Counts, Fault, Logged, analyse};

use crate::harness::{Rig, records, wall_us};
use fleet::{Fleet, Rng, VETH_FAR, VETH_NEAR, far_namespace, set_cut, set_loss};
use serde::Serialize;
use std::collections::BTreeMap;
use std::path::Path;
use std::time::{Duration, Instant};

const VEHICLE: i64 = 100;

/// The vehicle's command timeout, µs (the default of `[vehicle] command_timeout_ms`).
const COMMAND_TIMEOUT_US: u64 = rove_core::watchdog::CommandTimeout::DEFAULT
    .get()
    .as_micros() as u64;

/// How long after a fault (or the end of one: a SIGCONT, a restart) the bench does not judge
/// the owner: one command timeout for the vehicle to notice, plus what a loaded 2-core machine
/// needs to resume a continued process and deliver its next sample. A fault's effect that
/// outlasts it is counted.
pub const GRACE_US: u64 = 300_000;

/// How soon after a partition heals the right owner must drive again (the target: one
/// second; discovery already knows the peer, so its next sample takes over).
pub const HEAL_US: u64 = 1_000_000;

/// The `(level, class)` of each operator, weakest first: distinct strengths (docs/design.md §3),
/// the handover bench's ranks.
const LADDER: [(&str, &str); 12] = crate::bench::RANKS;

/// Options of `rove bench chaos`.
#[derive(Debug, Clone)]
pub struct Options {
    /// Operators, of distinct strengths (at most 12: the hierarchy's cells).
    pub operators: usize,
    /// Faults in the chaos phase.
    pub events: usize,
    /// Mean time between faults.
    pub interval: Duration,
    /// Length of each loss phase; 0 skips them.
    pub loss: Duration,
    /// The loss phases, in order: the percentage of UDP packets dropped in each.
    pub loss_pct: Vec<u8>,
    /// Seed of the fault sequence (the same seed, the same sequence).
    pub seed: u64,
    /// How long each of the three partitions lasts; 0 skips them.
    pub partition: Duration,
}

/// What a chaos run measured.
#[derive(Debug, Serialize)]
pub struct Report {
    /// Operators.
    pub operators: usize,
    /// Faults done in the chaos phase, by kind.
    pub faults: BTreeMap<&'static str, usize>,
    /// The seed.
    pub seed: u64,
    /// Length of the chaos phase, s.
    pub chaos_s: f64,
    /// Length of each loss phase, s.
    pub loss_s: f64,
    /// Outputs the vehicle recorded.
    pub outputs: usize,
    /// What [`analyse`] counted.
    pub counts: Counts,
    /// Owner changes per minute under each loss percentage.
    pub owner_changes_per_min: BTreeMap<u8, f64>,
    /// How long each `rove failsafe` of the supervisor took, ms.
    pub failsafe_ms: Vec<f64>,
    /// From each partition's heal to the first apply from the operator behind it, ms.
    pub recovery_ms: Vec<f64>,
}

/// The bench's fleet once started: the operators by rank, the far namespace with partitions.
struct Started {
    fleet: Fleet,
    /// The far namespace (and its operator) lives until the record is read: dropping it kills
    /// the operator, which the analysis would not know of.
    far: Option<Rig>,
    /// The operators in the vehicle's namespace, weakest first.
    ids: Vec<i64>,
    /// The far operator's id and its ladder cell.
    far_id: i64,
    top: usize,
    ranks: BTreeMap<i64, usize>,
}

/// Runs the chaos bench; `progress` hears what happens.
///
/// # Errors
/// The rig cannot be built, nftables is missing, or a process does not start.
pub fn run(
    rove: &Path,
    options: &Options,
    progress: &mut dyn FnMut(&str),
) -> anyhow::Result<Report> {
    let mut started = start(rove, options, progress)?;
    let chaos_start = Instant::now();
    let faults = chaos_phase(&mut started, options, progress)?;
    let chaos_s = chaos_start.elapsed().as_secs_f64();
    if !options.loss.is_zero() && !options.loss_pct.is_empty() {
        loss_phase(&mut started, options, progress)?;
    }
    let recovery_ms = partition_phase(&mut started, options, progress)?;
    // The last outputs reach the record.
    std::thread::sleep(Duration::from_millis(200));
    let mut outputs = records(&started.fleet.record);
    outputs.sort_by_key(|o| o.wall_us);
    let counts = analyse(&started.fleet.log, &outputs, &started.ranks);
    drop(started.far);
    let minutes = options.loss.as_secs_f64() / 60.0;
    let owner_changes_per_min = (options.loss_pct.iter().copied())
        .filter(|_| minutes > 0.0)
        .map(|pct| {
            let n = (counts.owner_changes_under_loss.get(&pct))
                .copied()
                .unwrap_or(0);
            (pct, n as f64 / minutes)
        })
        .collect();
    Ok(Report {
        operators: options.operators,
        faults,
        seed: options.seed,
        chaos_s,
        loss_s: options.loss.as_secs_f64(),
        outputs: outputs.len(),
        counts,
        owner_changes_per_min,
        failsafe_ms: started.fleet.failsafe_ms,
        recovery_ms,
    })
}

/// The rig (and the far namespace with partitions), the vehicle, and the operators driving.
fn start(
    rove: &Path,
    options: &Options,
    progress: &mut dyn FnMut(&str),
) -> anyhow::Result<Started> {
    anyhow::ensure!(options.operators >= 2, "--operators must be at least 2");
    let mut rig = Rig::new(rove, "bench-chaos")?;
    let partitions = !options.partition.is_zero();
    // With partitions, the vehicle also listens on its end of the veth pair to the far
    // namespace, where the strongest operator will run.
    let far = if partitions {
        Some(far_namespace(rove, &rig)?)
    } else {
        None
    };
    let network = if partitions {
        format!("[network]\ninterfaces = [\"127.0.0.1\", \"{VETH_NEAR}\"]\n")
    } else {
        String::new()
    };
    let record =
        rig.vehicle_with_output(VEHICLE, &format!("[output]\nadapter = \"sim\"\n{network}"));
    let vehicle = rig.procs.len() - 1;
    let mut fleet = Fleet {
        rig,
        record,
        vehicle,
        running: BTreeMap::new(),
        stopped: BTreeMap::new(),
        log: Vec::new(),
        failsafe_ms: Vec::new(),
    };
    // The strongest `operators` cells (below the far operator's, the strongest, with
    // partitions), so that ranks follow strengths.
    let top = LADDER.len() - usize::from(partitions);
    anyhow::ensure!(options.operators <= top, "--operators must be 2..={top}");
    let ids: Vec<i64> = (top - options.operators..top)
        .map(|i| 11 + i as i64)
        .collect();
    let far_id = 11 + top as i64;
    let mut ranks: BTreeMap<i64, usize> = ids.iter().enumerate().map(|(r, id)| (*id, r)).collect();
    ranks.insert(far_id, ids.len());
    for &id in &ids {
        fleet.start(id);
    }
    let strongest = ids[ids.len() - 1];
    crate::harness::wait_for_output(&fleet.record, Some(strongest), 0)
        .map_err(|e| anyhow::anyhow!("the fleet never started: {e}"))?;
    progress(&format!(
        "{} operators ({ids:?}, weakest first) drive vehicle {VEHICLE}; {} faults, one every ~{:?}",
        options.operators, options.events, options.interval
    ));
    Ok(Started {
        fleet,
        far,
        ids,
        far_id,
        top,
        ranks,
    })
}

/// `options.events` random faults; returns how many of each kind.
fn chaos_phase(
    started: &mut Started,
    options: &Options,
    progress: &mut dyn FnMut(&str),
) -> anyhow::Result<BTreeMap<&'static str, usize>> {
    let (fleet, ids) = (&mut started.fleet, &started.ids);
    let mut rng = Rng(options.seed.max(1));
    let mut faults: BTreeMap<&'static str, usize> = BTreeMap::new();
    for n in 0..options.events {
        std::thread::sleep(rng.between(options.interval / 2, options.interval * 3 / 2));
        fleet.cont_due(Instant::now());
        let movable: Vec<i64> = (ids.iter().copied())
            .filter(|id| fleet.running.contains_key(id) && !fleet.stopped.contains_key(id))
            .collect();
        let dead: Vec<i64> = (ids.iter().copied())
            .filter(|id| !fleet.running.contains_key(id))
            .collect();
        let kind = fault_kind(&mut rng, movable.is_empty(), dead.is_empty());
        match kind {
            "vehicle_kill" | "vehicle_term" => fleet.restart_vehicle(kind == "vehicle_term")?,
            "restart" => {
                let id = dead[rng.below(dead.len())];
                fleet.start(id);
            }
            "kill" | "term" => {
                let id = movable[rng.below(movable.len())];
                let (signal, fault) = match kind {
                    "kill" => ("-KILL", Fault::Kill { id }),
                    _ => ("-TERM", Fault::Term { id }),
                };
                fleet.signal(id, signal, fault);
                fleet.running.remove(&id);
            }
            _ => {
                let id = movable[rng.below(movable.len())];
                fleet.signal(id, "-STOP", Fault::Stop { id });
                let pause = rng.between(Duration::from_millis(100), Duration::from_millis(600));
                fleet.stopped.insert(id, Instant::now() + pause);
            }
        }
        *faults.entry(kind).or_default() += 1;
        if (n + 1) % 100 == 0 {
            progress(&format!("{} faults done", n + 1));
        }
    }
    Ok(faults)
}

/// The next fault's kind. Restarts of the dead come about as often as others die, so the fleet
/// neither empties nor stays whole; with nobody to signal, the vehicle or a restart.
fn fault_kind(rng: &mut Rng, none_movable: bool, none_dead: bool) -> &'static str {
    let kind = match rng.below(20) {
        0 => "vehicle_kill",
        1 => "vehicle_term",
        2..=8 if !none_dead => "restart",
        9..=11 => "kill",
        12..=14 => "term",
        _ => "stop",
    };
    match (none_movable && !kind.starts_with("vehicle"), none_dead) {
        (false, _) => kind,
        (true, true) => "vehicle_kill",
        (true, false) => "restart",
    }
}

/// Every operator running, then each of `options.loss_pct` % UDP loss for `options.loss`.
fn loss_phase(
    started: &mut Started,
    options: &Options,
    progress: &mut dyn FnMut(&str),
) -> anyhow::Result<()> {
    let fleet = &mut started.fleet;
    fleet.heal(&started.ids);
    let strongest = started.ids[started.ids.len() - 1];
    let since = wall_us();
    crate::harness::wait_for_output(&fleet.record, Some(strongest), since)
        .map_err(|e| anyhow::anyhow!("after the chaos, the strongest never drove: {e}"))?;
    // Let every restarted operator be discovered and drive its turn… it never will: the
    // strongest drives. One heartbeat of quiet, then the loss.
    std::thread::sleep(Duration::from_secs(1));
    for &pct in &options.loss_pct {
        progress(&format!("{pct} % UDP loss for {:?}", options.loss));
        let at = wall_us();
        set_loss(&fleet.rig, pct)?;
        fleet.note(at, Fault::Loss { pct });
        std::thread::sleep(options.loss);
    }
    let at = wall_us();
    set_loss(&fleet.rig, 0)?;
    fleet.note(at, Fault::Loss { pct: 0 });
    Ok(())
}

/// With partitions: the strongest operator in the far namespace, its link cut and restored
/// three times; returns, per heal, how long until it drove again (ms).
fn partition_phase(
    started: &mut Started,
    options: &Options,
    progress: &mut dyn FnMut(&str),
) -> anyhow::Result<Vec<f64>> {
    let mut recovery_ms = Vec::new();
    let (fleet, far_id) = (&mut started.fleet, started.far_id);
    let Some(far) = started.far.as_mut() else {
        return Ok(recovery_ms);
    };
    let (level, class) = LADDER[started.top];
    let network = format!("[network]\ninterfaces = [\"{VETH_FAR}\"]\n");
    let at = wall_us();
    far.operator(far_id, level, class, &[VEHICLE], 3000, &network, &[]);
    fleet.note(at, Fault::Start { id: far_id });
    crate::harness::wait_for_output(&fleet.record, Some(far_id), 0)
        .map_err(|e| anyhow::anyhow!("the far operator never drove: {e}"))?;
    for n in 0..3 {
        progress(&format!(
            "partition {}: cut for {:?}",
            n + 1,
            options.partition
        ));
        let at = wall_us();
        set_cut(far, true)?;
        fleet.note(at, Fault::Cut { id: far_id });
        std::thread::sleep(options.partition);
        let healed = wall_us();
        set_cut(far, false)?;
        fleet.note(healed, Fault::Heal { id: far_id });
        let back = crate::harness::wait_for_output(&fleet.record, Some(far_id), healed)
            .map_err(|e| anyhow::anyhow!("the far operator never drove after the heal: {e}"))?;
        recovery_ms.push((back.wall_us - healed) as f64 / 1000.0);
        std::thread::sleep(Duration::from_secs(1));
    }
    Ok(recovery_ms)
}

/// `rove bench chaos`: runs, prints a summary, writes `json` if asked.
///
/// # Errors
/// As [`run`], or the JSON file cannot be written.
pub fn cli(rove: &Path, options: &Options, json: Option<&Path>) -> anyhow::Result<()> {
    let report = run(rove, options, &mut |line| eprintln!("{line}"))?;
    let c = &report.counts;
    println!(
        "chaos: {} faults in {:.0} s ({:?}), {} outputs\n  wrong owner {}, stale {}, failsafe while live {}",
        report.faults.values().sum::<usize>(),
        report.chaos_s,
        report.faults,
        report.outputs,
        c.wrong_owner,
        c.stale,
        c.failsafe_while_live
    );
    for (pct, per_min) in &report.owner_changes_per_min {
        println!(
            "  {pct} % loss: {per_min:.1} owner changes a minute, {} lapses of a silent owner, {} failsafe entries",
            c.lapses_under_loss.get(pct).copied().unwrap_or(0),
            c.failsafe_under_loss.get(pct).copied().unwrap_or(0)
        );
    }
    if let Some(stats) = crate::bench::Stats::of(&report.failsafe_ms) {
        println!(
            "  rove failsafe (supervisor): {} runs, p50 {:.1} ms, max {:.1} ms",
            report.failsafe_ms.len(),
            stats.p50,
            stats.max
        );
    }
    if !report.recovery_ms.is_empty() {
        println!(
            "  partitions healed: the far operator drove again after {:.1?} ms",
            report.recovery_ms
        );
    }
    for example in &c.examples {
        println!("  e.g. {example}");
    }
    if let Some(path) = json {
        std::fs::write(path, serde_json::to_string_pretty(&report)? + "\n")?;
    }
    Ok(())
}
