//! `rove-tools`: the tools around the product, apart from it: what runs the README's demo,
//! measures the gateway and checks its contract under faults, and the process harness the
//! top-level tests share. It knows rove only as a binary (the path of `rove`, run as processes,
//! `rove keys` included) and through rove-core; the gateway's library does not depend on it.
//! The `rove` binary links it for `rove demo` and `rove bench` (docs/design.md, "The product
//! apart from its tools").
//!
//! # Layout
//! - [`harness`]: real `rove` processes in a private network namespace it creates (tests, demo,
//!   benches): start, signal, crash, read their records.
//! - [`demo`]: `rove demo`, the README's story (in one process, or as processes with
//!   `--processes`).
//! - [`bench`](mod@bench): `rove bench handover` (graceful, active, crash) and `rove bench input`.
//! - [`chaos`]: `rove bench chaos`: random faults and packet loss, counted against the contract.
//! - [`fleet`]: `rove bench scale`: a fleet of N vehicles and M operators, per-node cost,
//!   handover and late-joiner times; [`sweep`]: `--idle-sweep`, idle fleets of several sizes;
//!   [`guard`]: `rove bench guard`, a short fleet run against a committed baseline (CI).
//! - [`soak`]: `rove bench soak`: memory, fds and threads of long-lived processes while
//!   operators come and go.

pub mod bench;
pub mod chaos;
pub mod cleanup;
pub mod demo;
pub mod fleet;
pub mod guard;
pub mod harness;
pub mod procstat;
#[cfg(all(feature = "remote", feature = "security"))]
pub mod sites;
pub mod soak;
pub mod sweep;

use std::path::Path;

/// `[network] presence_ms` when a config leaves it out, as the gateway's
/// `dds::DEFAULT_PRESENCE` says (a top-level test checks they agree): what the reports show
/// when a bench did not set it.
pub const DEFAULT_PRESENCE_MS: u64 = 250;

/// `rove bench …`.
#[derive(Debug, clap::Subcommand)]
pub enum Bench {
    /// Input event → vehicle output latency through DDS, with a replayed joystick (needs root).
    Input {
        /// Stick events to replay.
        #[arg(long, default_value_t = 2000)]
        events: usize,
        /// Their rate.
        #[arg(long, default_value_t = 200.0)]
        rate_hz: f64,
    },
    /// Random faults (kill, terminate, stop, restart of operators and of the vehicle under a
    /// supervisor) and packet loss, counted against the ownership contract (needs root and
    /// nftables).
    Chaos {
        /// Operators, of distinct strengths (2–12).
        #[arg(long, default_value_t = 4)]
        operators: usize,
        /// Faults in the chaos phase.
        #[arg(long, default_value_t = 1000)]
        events: usize,
        /// Mean time between faults, ms.
        #[arg(long, default_value_t = 300)]
        interval_ms: u64,
        /// Length of each loss phase, s; 0 skips them.
        #[arg(long, default_value_t = 60)]
        loss_s: u64,
        /// The loss phases, in order: the percentage of UDP packets dropped in each (1–99).
        #[arg(long, value_delimiter = ',', default_values_t = [10u8, 30],
              value_parser = clap::value_parser!(u8).range(1..=99))]
        loss_pct: Vec<u8>,
        /// Seed of the fault sequence.
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Length of each of three partitions of the strongest operator, which runs in a
        /// namespace of its own joined by a veth pair, s; 0 skips them.
        #[arg(long, default_value_t = 5)]
        partition_s: u64,
        /// Write the report as JSON to this file.
        #[arg(long)]
        json: Option<std::path::PathBuf>,
    },
    /// A fleet of real processes, each operator driving its own vehicle: CPU and memory per
    /// process and in total, handover latency and late-joiner time while the fleet streams,
    /// wrong owners and stale outputs (needs root).
    Scale {
        /// Vehicles.
        #[arg(long, default_value_t = 16)]
        vehicles: usize,
        /// Operators (operator i drives vehicle i mod V).
        #[arg(long, default_value_t = 16)]
        operators: usize,
        /// Operators drive nothing: the fixed cost of the fleet's participants.
        #[arg(long)]
        idle: bool,
        /// CPU window, s.
        #[arg(long, default_value_t = 10)]
        window_s: u64,
        /// Handovers measured on the first vehicle while the fleet streams.
        #[arg(long, default_value_t = 20)]
        handover_runs: usize,
        /// How long each phone of the handover phase drives before it quits, ms: 0 quits at
        /// its first command applied, while the fleet still takes in its join.
        #[arg(long, default_value_t = 0)]
        handover_hold_ms: u64,
        /// Restarts of a weaker operator (a desktop) while the fleet streams.
        #[arg(long, default_value_t = 8)]
        restarts: usize,
        /// Late joiners measured.
        #[arg(long, default_value_t = 10)]
        latejoin_runs: usize,
        /// Instead of one fleet: idle fleets of these many processes (half vehicles, half
        /// operators), one after the other, for the CPU each node spends per peer.
        #[arg(long, value_delimiter = ',')]
        idle_sweep: Vec<usize>,
        /// The fleet's check period (`[network] heartbeat_ms`; absent: the default).
        #[arg(long)]
        heartbeat_ms: Option<u64>,
        /// The fleet's SPDP period (`[network] presence_ms`; absent: the default, 250 ms).
        #[arg(long)]
        presence_ms: Option<u64>,
        /// Run vehicle 100 (whose handovers are measured) under SCHED_FIFO at this priority
        /// (`chrt -f`), as the vehicle unit's real-time option does.
        #[arg(long)]
        vehicle_rt: Option<u8>,
        /// Also run the same fleet secured (DDS Security: a certificate per device, `[access]`),
        /// after the unsecured one, and print the two side by side.
        #[arg(long)]
        secure: bool,
        /// With `--secure`: the secured fleet only.
        #[arg(long, requires = "secure")]
        secure_only: bool,
        /// Start the fleet this many times from nothing (each mode), timing each start to every
        /// vehicle driven, before the full run; a start that does not converge in 60 s fails the
        /// bench.
        #[arg(long, default_value_t = 0)]
        starts: usize,
        /// Write the report as JSON to this file.
        #[arg(long)]
        json: Option<std::path::PathBuf>,
    },
    /// Memory, file descriptors and threads of a vehicle, its fallback operator and a
    /// bystander while other operators join, preempt or request, and quit, cycle after cycle:
    /// the growth per cycle after a warm-up (needs root).
    Soak(SoakArgs),
    /// A short fleet run (8 × 8 idle, then streaming) whose cost per node, as ratios in which
    /// the machine's speed cancels, is compared against a committed baseline: fails when the
    /// median of the attempts is more than a tolerance over it (needs root).
    Guard(GuardArgs),
    /// Handover latency between real processes in a private network namespace (needs root):
    /// the seed's Tables 5.1–5.3, plus how fast a late joiner lists every device.
    Handover {
        /// Which experiment.
        #[arg(long, value_enum, required_unless_present = "remote")]
        scenario: Option<bench::Scenario>,
        /// Instead: across two sites joined by their bridges (`rove bridge`) beside the same
        /// on one site, in one run: input → output latency, graceful, crash and active
        /// handovers, the link cut, the bridges' CPU with `--operators` remote operators
        /// streaming (docs/remote.md).
        #[arg(long)]
        remote: bool,
        /// With `--remote`: remote operators streaming in the CPU phase.
        #[arg(long, default_value_t = 8)]
        operators: usize,
        /// With `--remote`: stick events replayed per placement.
        #[arg(long, default_value_t = 1000)]
        events: usize,
        /// Controller counts to run, comma-separated (graceful/crash: owner + N−1 backups;
        /// active: owner, requester and N−2 bystanders).
        #[arg(long, value_delimiter = ',', default_value = "2")]
        controllers: Vec<usize>,
        /// Devices on the network for `latejoin`.
        #[arg(long, default_value_t = 32)]
        devices: usize,
        /// Runs per controller count.
        #[arg(long, default_value_t = 100)]
        runs: usize,
        /// DDS Security: off, on (every process authenticated, RTPS messages encrypted), or
        /// both, back to back for each controller count.
        #[arg(long, value_enum, default_value = "off")]
        security: SecurityMode,
        /// Run the vehicle under SCHED_FIFO at this priority (`chrt -f`), as the vehicle
        /// unit's real-time option does.
        #[arg(long)]
        vehicle_rt: Option<u8>,
        /// Write one JSON object per scenario run to this file.
        #[arg(long)]
        json: Option<std::path::PathBuf>,
        /// Write a box plot of all runs to this SVG file.
        #[arg(long)]
        svg: Option<std::path::PathBuf>,
    },
}

/// `rove bench soak`'s arguments.
#[derive(Debug, clap::Args)]
pub struct SoakArgs {
    /// Join-and-leave cycles.
    #[arg(long, default_value_t = 1000)]
    pub cycles: usize,
    /// Cycles before the growth is measured (default: a fifth of them).
    #[arg(long)]
    pub warmup: Option<usize>,
    /// Cycles between samples.
    #[arg(long, default_value_t = 10)]
    pub sample_every: usize,
    /// Every this many cycles a request (active handover) instead of a preemption; 0:
    /// never.
    #[arg(long, default_value_t = 5)]
    pub request_every: usize,
    /// Fail when a long-lived process grows by more than this many KiB per cycle.
    #[arg(long)]
    pub max_kib_per_cycle: Option<f64>,
    /// Every this many cycles a remote operator at a second site requests the vehicle
    /// through two bridges (measured too); 0: no second site.
    #[arg(long, default_value_t = 0)]
    pub remote_every: usize,
    /// Every process secured (DDS Security, a certificate per device id): every joiner is
    /// authenticated by every node. Not with --remote-every.
    #[arg(long)]
    pub secure: bool,
    /// The `rove` binary the rig's processes run (default: this one), e.g. an older build
    /// for a before/after comparison: its CLI and configs must be this one's.
    #[arg(long)]
    pub rove: Option<std::path::PathBuf>,
    /// Write the report as JSON to this file.
    #[arg(long)]
    pub json: Option<std::path::PathBuf>,
}

/// `rove bench guard`'s arguments.
#[derive(Debug, clap::Args)]
pub struct GuardArgs {
    /// Vehicles, and as many operators.
    #[arg(long, default_value_t = 8)]
    pub vehicles: usize,
    /// Each CPU window, s.
    #[arg(long, default_value_t = 10)]
    pub window_s: u64,
    /// Attempts: each ratio's median over them is compared with the baseline (or written as
    /// the baseline).
    #[arg(long, default_value_t = 3)]
    pub attempts: usize,
    /// Allowed growth of streaming ÷ idle over the baseline, percent.
    #[arg(long, default_value_t = 25.0)]
    pub tolerance_pct: f64,
    /// Allowed growth of a command sample's cost in arbiter steps, percent (looser: the
    /// arbiter does not follow the machine's network stack from one minute to the next).
    #[arg(long, default_value_t = 60.0)]
    pub sample_tolerance_pct: f64,
    /// The baseline to compare with (JSON, as `--write-baseline` writes it).
    #[arg(long, conflicts_with = "write_baseline")]
    pub baseline: Option<std::path::PathBuf>,
    /// Measure once and write the result to this file as the new baseline.
    #[arg(long, requires = "note")]
    pub write_baseline: Option<std::path::PathBuf>,
    /// Where and when the baseline was measured, in words (the commit, the machine).
    #[arg(long)]
    pub note: Option<String>,
    /// The `rove` binary the fleet runs (default: this one), e.g. an older build for a
    /// before/after comparison: its CLI and configs must be this one's.
    #[arg(long)]
    pub rove: Option<std::path::PathBuf>,
}

#[derive(Debug, Clone, Copy, clap::ValueEnum)]
pub enum SecurityMode {
    /// Plain DDS.
    Off,
    /// DDS Security.
    On,
    /// Both, back to back.
    Both,
}

/// Runs `rove bench WHAT` with the `rove` binary at `rove`.
///
/// # Errors
/// The bench cannot set up its processes (namespaces need root), or a measurement failed.
pub fn run(what: Bench, rove: &Path) -> anyhow::Result<()> {
    // A bench stopped by a signal stops its processes and deletes its namespaces first.
    cleanup::stop_on_signals()?;
    match what {
        Bench::Input { events, rate_hz } => bench::input_cli(rove, events, rate_hz),
        Bench::Chaos {
            operators,
            events,
            interval_ms,
            loss_s,
            loss_pct,
            seed,
            partition_s,
            json,
        } => {
            let options = chaos::Options {
                operators,
                events,
                interval: std::time::Duration::from_millis(interval_ms),
                loss: std::time::Duration::from_secs(loss_s),
                loss_pct,
                seed,
                partition: std::time::Duration::from_secs(partition_s),
            };
            chaos::cli(rove, &options, json.as_deref())
        }
        Bench::Scale {
            vehicles,
            operators,
            idle,
            window_s,
            handover_runs,
            handover_hold_ms,
            restarts,
            latejoin_runs,
            idle_sweep,
            heartbeat_ms,
            presence_ms,
            vehicle_rt,
            secure,
            secure_only,
            starts,
            json,
        } => {
            let options = fleet::Options {
                vehicles,
                operators,
                idle,
                window: std::time::Duration::from_secs(window_s),
                handover_runs: if idle { 0 } else { handover_runs },
                handover_hold: std::time::Duration::from_millis(handover_hold_ms),
                restarts: if idle { 0 } else { restarts },
                latejoin_runs,
                heartbeat_ms,
                presence_ms,
                vehicle_rt,
                secure,
            };
            if secure || starts > 0 {
                fleet::starts::cli(rove, &options, starts, secure_only, json.as_deref())
            } else if idle_sweep.is_empty() {
                fleet::cli(rove, &options, json.as_deref())
            } else {
                sweep::cli(rove, &options, &idle_sweep, json.as_deref())
            }
        }
        Bench::Soak(args) => run_soak(rove, args),
        Bench::Guard(args) => run_guard(rove, args),
        Bench::Handover {
            remote: true,
            runs,
            operators,
            events,
            json,
            ..
        } => remote_bench(rove, runs, operators, events, json.as_deref()),
        Bench::Handover {
            scenario,
            controllers,
            devices,
            runs,
            security,
            vehicle_rt,
            json,
            svg,
            ..
        } => {
            let options = bench::Options {
                scenario: scenario.unwrap_or(bench::Scenario::Graceful),
                controllers: 0,
                devices,
                runs,
                secure: false,
                vehicle_rt,
            };
            let outputs = bench::Outputs { json, svg };
            let modes: &[bool] = match security {
                SecurityMode::Off => &[false],
                SecurityMode::On => &[true],
                SecurityMode::Both => &[false, true],
            };
            bench::handover_cli(rove, options, &controllers, modes, &outputs)
        }
    }
}

/// `rove bench handover --remote`.
#[cfg(all(feature = "remote", feature = "security"))]
fn remote_bench(
    rove: &Path,
    runs: usize,
    operators: usize,
    events: usize,
    json: Option<&Path>,
) -> anyhow::Result<()> {
    let options = bench::RemoteOptions {
        runs,
        events,
        operators,
    };
    bench::remote_cli(rove, &options, json)
}

/// `rove bench handover --remote` in a build without the bridge.
#[cfg(not(all(feature = "remote", feature = "security")))]
fn remote_bench(
    _rove: &Path,
    _runs: usize,
    _operators: usize,
    _events: usize,
    _json: Option<&Path>,
) -> anyhow::Result<()> {
    anyhow::bail!("this rove was built without the `remote` and `security` features")
}

/// `rove bench soak`.
fn run_soak(rove: &Path, args: SoakArgs) -> anyhow::Result<()> {
    let options = soak::Options {
        remote_every: args.remote_every,
        cycles: args.cycles,
        warmup: args.warmup.unwrap_or(args.cycles / 5),
        sample_every: args.sample_every,
        request_every: args.request_every,
        max_kib_per_cycle: args.max_kib_per_cycle,
        secure: args.secure,
    };
    let rove = args.rove.as_deref().unwrap_or(rove);
    soak::cli(rove, &options, args.json.as_deref())
}

/// `rove bench guard`.
fn run_guard(rove: &Path, args: GuardArgs) -> anyhow::Result<()> {
    let options = guard::Guard {
        vehicles: args.vehicles,
        window: std::time::Duration::from_secs(args.window_s),
        attempts: args.attempts,
        tolerance: args.tolerance_pct / 100.0,
        sample_tolerance: args.sample_tolerance_pct / 100.0,
    };
    let rove = args.rove.as_deref().unwrap_or(rove);
    let write = (args.write_baseline.as_deref()).zip(args.note.as_deref());
    guard::cli(rove, &options, args.baseline.as_deref(), write)
}
