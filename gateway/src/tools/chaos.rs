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
//!    loopback (nftables), 10 % and then 30 %, each for `loss_secs`.
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
//! - **owner changes** under loss (none is demanded: nothing else happens then; a weaker
//!   operator driving then counts here, not as a wrong owner), and failsafe entries under loss;
//! - **recovery**: from the partition's heal to the first apply from the healed operator.

use crate::tools::harness::{Out, Rig, records, wall_us};
use serde::Serialize;
use std::collections::BTreeMap;
use std::path::Path;
use std::process::Command;
use std::time::{Duration, Instant};

const VEHICLE: i64 = 100;

/// The vehicle's command timeout, µs (the default of `[vehicle] command_timeout_ms`).
const COMMAND_TIMEOUT_US: u64 = 100_000;

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
const LADDER: [(&str, &str); 12] = crate::tools::bench::RANKS;

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

/// Counts contract violations in `outputs` (the vehicle's record, in time order) given what the
/// bench did (`log`, in time order) and each operator's rank (`ranks`: id → strength order).
pub fn analyse(log: &[Logged], outputs: &[Out], ranks: &BTreeMap<i64, usize>) -> Counts {
    let mut counts = Counts::default();
    let mut ops: BTreeMap<i64, OpState> = BTreeMap::new();
    let mut vehicle_changed_at = 0u64;
    let mut loss: u8 = 0;
    let mut last_owner: Option<Option<i64>> = None;
    // When each operator was last applied: a violation's example says how long the operator
    // that should have driven had been silent (a stall longer than the command timeout, say).
    let mut last_applied: BTreeMap<i64, u64> = BTreeMap::new();
    let silent = |last: &BTreeMap<i64, u64>, y: i64, t: u64| match last.get(&y) {
        Some(at) => format!("{} ms after its last apply", (t - at) / 1000),
        None => "never applied".to_string(),
    };
    let mut next = log.iter().peekable();
    let example = |counts: &mut Counts, what: String| {
        if counts.examples.len() < 10 {
            counts.examples.push(what);
        }
    };
    for out in outputs {
        // Apply every logged fault up to this output.
        while let Some(entry) = next.next_if(|e| e.at <= out.wall_us) {
            // A fault takes effect for the analysis from `at` (a signal may act at once); what
            // comes after it (settling, the death stale outputs are measured from), from `done`.
            let done = entry.done;
            match entry.fault {
                Fault::Start { id } => {
                    ops.insert(
                        id,
                        OpState {
                            running: true,
                            settles_at: done + GRACE_US,
                            ..OpState::default()
                        },
                    );
                }
                Fault::Kill { id } | Fault::Term { id } => {
                    let s = ops.entry(id).or_default();
                    (s.running, s.stopped, s.drove) = (false, false, false);
                    s.dead_since = Some(done);
                }
                Fault::Stop { id } | Fault::Cut { id } => ops.entry(id).or_default().stopped = true,
                Fault::Cont { id } => {
                    let s = ops.entry(id).or_default();
                    (s.stopped, s.settles_at) = (false, done + GRACE_US);
                }
                Fault::Heal { id } => {
                    let s = ops.entry(id).or_default();
                    (s.stopped, s.settles_at) = (false, done + HEAL_US);
                }
                Fault::VehicleRestart { .. } => {
                    vehicle_changed_at = done;
                    for s in ops.values_mut() {
                        s.drove = false;
                    }
                }
                Fault::Loss { pct } => {
                    loss = pct;
                    last_owner = None;
                }
            }
        }
        let t = out.wall_us;
        // Operators that must win now: running, not stopped, drove, and settled.
        let live = |s: &OpState| s.running && !s.stopped && s.drove && t > s.settles_at;
        let vehicle_settled = t > vehicle_changed_at + GRACE_US;
        match (out.action.as_str(), out.owner) {
            ("apply", Some(x)) => {
                if let Some(s) = ops.get(&x)
                    && let Some(dead) = s.dead_since
                    && !s.running
                    && t > dead + COMMAND_TIMEOUT_US + 15_000
                {
                    counts.stale += 1;
                    example(
                        &mut counts,
                        format!("stale: {x} applied {} ms after it died", (t - dead) / 1000),
                    );
                }
                let rank = ranks.get(&x).copied().unwrap_or(0);
                // Under loss a lapse of the stronger stream is counted as an owner change.
                if vehicle_settled
                    && loss == 0
                    && let Some((y, _)) = (ops.iter())
                        .find(|(y, s)| ranks.get(y).copied().unwrap_or(0) > rank && live(s))
                {
                    counts.wrong_owner += 1;
                    let why = silent(&last_applied, *y, t);
                    example(
                        &mut counts,
                        format!("wrong owner at {t}: {x} drove while {y} ran, {why}"),
                    );
                }
                if let Some(s) = ops.get_mut(&x)
                    && s.running
                {
                    s.drove = true;
                }
                last_applied.insert(x, t);
            }
            ("safe", _) => {
                if vehicle_settled && let Some((y, _)) = ops.iter().find(|(_, s)| live(s)) {
                    counts.failsafe_while_live += 1;
                    let why = silent(&last_applied, *y, t);
                    example(&mut counts, format!("failsafe at {t} while {y} ran, {why}"));
                }
            }
            _ => {}
        }
        if loss > 0 {
            let owner = out.owner;
            if let Some(before) = last_owner
                && before != owner
            {
                *counts.owner_changes_under_loss.entry(loss).or_default() += 1;
                if owner.is_none() {
                    *counts.failsafe_under_loss.entry(loss).or_default() += 1;
                }
            }
            last_owner = Some(owner);
        }
    }
    counts
}

/// Options of `rove bench chaos`.
#[derive(Debug, Clone)]
pub struct Options {
    /// Operators, of distinct strengths (at most 12: the hierarchy's cells).
    pub operators: usize,
    /// Faults in the chaos phase.
    pub events: usize,
    /// Mean time between faults.
    pub interval: Duration,
    /// Length of each loss phase (10 %, then 30 %); 0 skips them.
    pub loss: Duration,
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

/// A small deterministic generator (xorshift64*): a seed replays a run's fault sequence.
#[derive(Debug)]
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_f491_4f6c_dd1d)
    }

    /// Uniform in `0..n` (`n` > 0).
    fn below(&mut self, n: usize) -> usize {
        (self.next() % n as u64) as usize
    }

    /// Uniform in `[lo, hi)`.
    fn between(&mut self, lo: Duration, hi: Duration) -> Duration {
        let span = (hi - lo).as_micros().max(1) as u64;
        lo + Duration::from_micros(self.next() % span)
    }
}

/// The operators and the vehicle as the bench drives them.
struct Fleet {
    rig: Rig,
    record: std::path::PathBuf,
    vehicle: usize,
    /// id → its process in the rig while it runs.
    running: BTreeMap<i64, usize>,
    /// id → when it is to be continued, while stopped.
    stopped: BTreeMap<i64, Instant>,
    log: Vec<Logged>,
    failsafe_ms: Vec<f64>,
}

impl Fleet {
    /// Logs `fault`, begun at `at` (wall µs) and done now.
    fn note(&mut self, at: u64, fault: Fault) {
        let done = wall_us();
        self.log.push(Logged { at, done, fault });
    }

    fn start(&mut self, id: i64) {
        let at = wall_us();
        let (level, class) = LADDER[(id - 11) as usize];
        let proc = (self.rig).operator(id, level, class, &[VEHICLE], 1000 + id as i16, "", &[]);
        self.running.insert(id, proc);
        self.note(at, Fault::Start { id });
    }

    /// Sends `signal` to operator `id` and logs `fault`.
    fn signal(&mut self, id: i64, signal: &str, fault: Fault) {
        let at = wall_us();
        if let Some(&proc) = self.running.get(&id) {
            self.rig.procs[proc].signal(signal);
        }
        self.note(at, fault);
    }

    fn cont_due(&mut self, now: Instant) {
        let due: Vec<i64> = (self.stopped.iter())
            .filter(|(_, at)| **at <= now)
            .map(|(id, _)| *id)
            .collect();
        for id in due {
            self.stopped.remove(&id);
            self.signal(id, "-CONT", Fault::Cont { id });
        }
    }

    fn restart_vehicle(&mut self, graceful: bool) -> anyhow::Result<()> {
        let at = wall_us();
        let proc = &mut self.rig.procs[self.vehicle];
        if graceful {
            proc.terminate();
            if proc.wait_exit(Duration::from_secs(5)).is_none() {
                proc.crash();
            }
        } else {
            proc.crash();
        }
        // As systemd's ExecStopPost= would, then Restart=.
        let config = self.rig.dir.join(format!("vehicle-{VEHICLE}.toml"));
        let started = Instant::now();
        let status = Command::new("ip")
            .args(["netns", "exec", &self.rig.ns])
            .arg(&self.rig.rove)
            .args(["failsafe", "-c"])
            .arg(&config)
            .output()?;
        anyhow::ensure!(
            status.status.success(),
            "rove failsafe: {}",
            String::from_utf8_lossy(&status.stderr)
        );
        self.failsafe_ms
            .push(started.elapsed().as_secs_f64() * 1000.0);
        let args = [
            "vehicle",
            "-c",
            config.to_str().unwrap_or_default(),
            "--record",
            self.record.to_str().unwrap_or_default(),
        ];
        self.vehicle = self.rig.spawn(&format!("vehicle-{VEHICLE}"), &args);
        self.note(at, Fault::VehicleRestart { graceful });
        Ok(())
    }

    /// Every operator running and continued.
    fn heal(&mut self, ids: &[i64]) {
        self.cont_due(Instant::now() + Duration::from_secs(3600));
        for &id in ids {
            if !self.running.contains_key(&id) {
                self.start(id);
            }
        }
    }
}

/// The vehicle's end of the veth pair to the far namespace.
const VETH_NEAR: &str = "10.77.0.1";
/// The far operator's end.
const VETH_FAR: &str = "10.77.0.2";

/// A second namespace joined to `near`'s by a veth pair (`VETH_NEAR` there, `VETH_FAR` here),
/// multicast routed over it: a host of its own on a link the bench can cut.
fn far_namespace(rove: &Path, near: &Rig) -> anyhow::Result<Rig> {
    let far = Rig::new(rove, "bench-chaos-far")?;
    let tag = std::process::id() % 100_000;
    let (a, b) = (format!("rc{tag}a"), format!("rc{tag}b"));
    let (near_addr, far_addr) = (format!("{VETH_NEAR}/24"), format!("{VETH_FAR}/24"));
    let steps: [&[&str]; 6] = [
        &[
            "ip", "link", "add", &a, "netns", &near.ns, "type", "veth", "peer", "name", &b,
            "netns", &far.ns,
        ],
        &["ip", "-n", &near.ns, "addr", "add", &near_addr, "dev", &a],
        &["ip", "-n", &far.ns, "addr", "add", &far_addr, "dev", &b],
        &[
            "ip",
            "-n",
            &near.ns,
            "link",
            "set",
            &a,
            "up",
            "multicast",
            "on",
        ],
        &[
            "ip",
            "-n",
            &far.ns,
            "link",
            "set",
            &b,
            "up",
            "multicast",
            "on",
        ],
        // The far host's multicast goes over the veth, not its own loopback.
        &[
            "ip",
            "-n",
            &far.ns,
            "route",
            "replace",
            "224.0.0.0/4",
            "dev",
            &b,
        ],
    ];
    for step in steps {
        crate::tools::harness::run(step).map_err(anyhow::Error::msg)?;
    }
    Ok(far)
}

/// nftables in the rig's namespace: drops `pct` % of UDP packets (0 removes the rule).
fn set_loss(rig: &Rig, pct: u8) -> anyhow::Result<()> {
    let rule = format!("meta l4proto udp numgen random mod 100 < {pct} drop");
    nft(rig, (pct > 0).then_some(&rule), &["input"])
}

/// The far operator's veth cut (both ways, silently: nothing is refused) or restored.
fn set_cut(rig: &Rig, cut: bool) -> anyhow::Result<()> {
    nft(
        rig,
        cut.then_some("meta l4proto udp drop"),
        &["input", "output"],
    )
}

/// Replaces rove's nftables table in `rig`'s namespace with one holding `rule` in a filter
/// chain on each of `hooks`; `None` removes the table.
fn nft(rig: &Rig, rule: Option<&str>, hooks: &[&str]) -> anyhow::Result<()> {
    let mut script = "table inet rove_chaos\ndelete table inet rove_chaos\n".to_string();
    if let Some(rule) = rule {
        script.push_str("table inet rove_chaos {\n");
        for hook in hooks {
            script.push_str(&format!(
                "chain {hook} {{ type filter hook {hook} priority 0; {rule}; }}\n"
            ));
        }
        script.push_str("}\n");
    }
    let path = rig.write("chaos.nft", &script);
    let out = Command::new("ip")
        .args(["netns", "exec", &rig.ns, "nft", "-f"])
        .arg(&path)
        .output()
        .map_err(|e| anyhow::anyhow!("nft (Debian: apt-get install nftables): {e}"))?;
    anyhow::ensure!(
        out.status.success(),
        "nft: {}",
        String::from_utf8_lossy(&out.stderr).trim()
    );
    Ok(())
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
    crate::tools::harness::wait_for_output(&fleet.record, Some(strongest), 0)
        .map_err(|e| anyhow::anyhow!("the fleet never started: {e}"))?;
    progress(&format!(
        "{} operators ({ids:?}, weakest first) drive vehicle {VEHICLE}; {} faults, one every ~{:?}",
        options.operators, options.events, options.interval
    ));

    let mut rng = Rng(options.seed.max(1));
    let mut faults: BTreeMap<&'static str, usize> = BTreeMap::new();
    let chaos_start = Instant::now();
    for n in 0..options.events {
        std::thread::sleep(rng.between(options.interval / 2, options.interval * 3 / 2));
        fleet.cont_due(Instant::now());
        let movable: Vec<i64> = (ids.iter().copied())
            .filter(|id| fleet.running.contains_key(id) && !fleet.stopped.contains_key(id))
            .collect();
        let dead: Vec<i64> = (ids.iter().copied())
            .filter(|id| !fleet.running.contains_key(id))
            .collect();
        // Restart the dead about as often as others die, so the fleet neither empties nor
        // stays whole.
        let kind = match rng.below(20) {
            0 => "vehicle_kill",
            1 => "vehicle_term",
            2..=8 if !dead.is_empty() => "restart",
            9..=11 => "kill",
            12..=14 => "term",
            _ => "stop",
        };
        let kind = if movable.is_empty() && kind != "vehicle_kill" && kind != "vehicle_term" {
            if dead.is_empty() {
                "vehicle_kill"
            } else {
                "restart"
            }
        } else {
            kind
        };
        match kind {
            "vehicle_kill" | "vehicle_term" => fleet.restart_vehicle(kind == "vehicle_term")?,
            "restart" => {
                let id = dead[rng.below(dead.len())];
                fleet.start(id);
            }
            _ => {
                let id = movable[rng.below(movable.len())];
                match kind {
                    "kill" => {
                        fleet.signal(id, "-KILL", Fault::Kill { id });
                        fleet.running.remove(&id);
                    }
                    "term" => {
                        fleet.signal(id, "-TERM", Fault::Term { id });
                        fleet.running.remove(&id);
                    }
                    _ => {
                        fleet.signal(id, "-STOP", Fault::Stop { id });
                        let pause =
                            rng.between(Duration::from_millis(100), Duration::from_millis(600));
                        fleet.stopped.insert(id, Instant::now() + pause);
                    }
                }
            }
        }
        *faults.entry(kind).or_default() += 1;
        if (n + 1) % 100 == 0 {
            progress(&format!("{} faults done", n + 1));
        }
    }
    let chaos_s = chaos_start.elapsed().as_secs_f64();

    if !options.loss.is_zero() {
        fleet.heal(&ids);
        let since = wall_us();
        crate::tools::harness::wait_for_output(&fleet.record, Some(strongest), since)
            .map_err(|e| anyhow::anyhow!("after the chaos, the strongest never drove: {e}"))?;
        // Let every restarted operator be discovered and drive its turn… it never will: the
        // strongest drives. One heartbeat of quiet, then the loss.
        std::thread::sleep(Duration::from_secs(1));
        for pct in [10, 30] {
            progress(&format!("{pct} % UDP loss for {:?}", options.loss));
            let at = wall_us();
            set_loss(&fleet.rig, pct)?;
            fleet.note(at, Fault::Loss { pct });
            std::thread::sleep(options.loss);
        }
        let at = wall_us();
        set_loss(&fleet.rig, 0)?;
        fleet.note(at, Fault::Loss { pct: 0 });
    }
    let mut recovery_ms = Vec::new();
    // The far namespace (and its operator) lives until the record is read: dropping it kills
    // the operator, which the analysis would not know of.
    let mut far = far;
    if let Some(far) = far.as_mut() {
        let (level, class) = LADDER[top];
        let network = format!("[network]\ninterfaces = [\"{VETH_FAR}\"]\n");
        let at = wall_us();
        far.operator(far_id, level, class, &[VEHICLE], 3000, &network, &[]);
        fleet.note(at, Fault::Start { id: far_id });
        crate::tools::harness::wait_for_output(&fleet.record, Some(far_id), 0)
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
            let back = crate::tools::harness::wait_for_output(&fleet.record, Some(far_id), healed)
                .map_err(|e| anyhow::anyhow!("the far operator never drove after the heal: {e}"))?;
            recovery_ms.push((back.wall_us - healed) as f64 / 1000.0);
            std::thread::sleep(Duration::from_secs(1));
        }
    }
    // The last outputs reach the record.
    std::thread::sleep(Duration::from_millis(200));

    let mut outputs = records(&fleet.record);
    outputs.sort_by_key(|o| o.wall_us);
    let counts = analyse(&fleet.log, &outputs, &ranks);
    drop(far);
    let minutes = options.loss.as_secs_f64() / 60.0;
    let owner_changes_per_min = [10u8, 30]
        .into_iter()
        .filter(|_| minutes > 0.0)
        .map(|pct| {
            let n = counts
                .owner_changes_under_loss
                .get(&pct)
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
        failsafe_ms: fleet.failsafe_ms,
        recovery_ms,
    })
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
            "  {pct} % loss: {per_min:.1} owner changes a minute, {} failsafe entries",
            c.failsafe_under_loss.get(pct).copied().unwrap_or(0)
        );
    }
    if let Some(stats) = crate::tools::bench::Stats::of(&report.failsafe_ms) {
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
    }
}
