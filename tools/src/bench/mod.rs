//! `rove bench handover`: the seed's handover experiments (Tables 5.1–5.3) between real processes
//! in a private network namespace.
//!
//! Every controller is a separate `rove operator` process; the vehicle is `rove vehicle` with the
//! sim adapter recording its outputs; an observer (`rove status --events`) timestamps every
//! DeviceInfo and RequestControl sample it receives. Per run, from the trigger instant (quit,
//! kill, or the observer's receipt of the ACCEPT), two latencies:
//! - `deviceinfo`: until the observer receives the vehicle's DeviceInfo naming the new owner;
//! - `applied`: until the vehicle's adapter applies the new owner's command (or goes safe).
//!
//! A ping-pong is counted when, within 1 s of the trigger, the vehicle applies a command from the
//! owner it just left after having applied the new owner's.
//!
//! All processes share one machine clock (wall time in microseconds), so no clock sync is needed.

mod input;
#[cfg(all(feature = "remote", feature = "security"))]
mod remote;
mod report;

pub use input::{input_cli, input_latency};
#[cfg(all(feature = "remote", feature = "security"))]
pub use remote::{Options as RemoteOptions, RemoteReport, Row, remote, remote_cli};
pub use report::{Report, Stats, count_ping_pong, seed_figure, svg, table, write_json};

use crate::harness::{self, Follow, Rig, records, wall_us};
use report::{ms, report};
use serde::Serialize;
use serde_json::Value;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

const VEHICLE: i64 = 100;
/// The window in which a return to the previous owner counts as ping-pong.
const PING_PONG_WINDOW_US: u64 = 1_000_000;

/// Which experiment.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Scenario {
    /// The owner quits gracefully (SIGTERM → release).
    Graceful,
    /// The owner is killed (SIGKILL): detected by the command timeout.
    Crash,
    /// A weaker operator requests control; the owner auto-accepts.
    Active,
    /// A new node joins and lists every device.
    Latejoin,
}

/// Options of one benchmark invocation.
#[derive(Debug, Clone)]
pub struct Options {
    /// Which experiment.
    pub scenario: Scenario,
    /// Controllers in play (graceful/crash: owner + N−1 backups; active: owner, requester and
    /// N−2 bystanders).
    pub controllers: usize,
    /// Devices for latejoin.
    pub devices: usize,
    /// Runs.
    pub runs: usize,
    /// Every process joins with DDS Security (a fleet made for the run).
    pub secure: bool,
    /// The vehicle runs under SCHED_FIFO at this priority (`chrt -f`), as the vehicle unit's
    /// real-time option does.
    pub vehicle_rt: Option<u8>,
}

/// The ids a bench fleet issues certificates for: the vehicle, owner, requester, backups,
/// bystanders, late-join devices and the observers (`status`, id 999).
fn bench_ids(options: &Options) -> Vec<i64> {
    let mut ids = std::collections::BTreeSet::from([VEHICLE, 11, 13, OBSERVER]);
    ids.extend(21..21 + RANKS.len() as i64);
    ids.extend(31..31 + options.controllers as i64);
    ids.extend(200..200 + options.devices as i64);
    ids.into_iter().collect()
}

/// The id whose certificate `rove status` observers use in a secured bench.
const OBSERVER: i64 = 999;

/// `[security]` for device `id` when the bench is secured.
struct BenchSecurity(Option<PathBuf>);

impl BenchSecurity {
    fn toml(&self, id: i64) -> String {
        harness::security_toml(self.0.as_deref(), id)
    }

    /// Starts `rove status --events` as `name`, secured like everyone else; returns its
    /// index (its log is the event stream).
    fn spawn_status(&self, rig: &mut Rig, name: &str) -> usize {
        let observer = self.0.as_ref().map(|f| f.join(OBSERVER.to_string()));
        let observer = observer.as_ref().map(|d| d.display().to_string());
        let mut args = vec!["status", "--events"];
        if let Some(dir) = &observer {
            args.extend(["--security", dir.as_str()]);
        }
        rig.spawn(name, &args)
    }

    /// Starts the vehicle, under SCHED_FIFO at priority `fifo` if given.
    fn vehicle(&self, rig: &mut Rig, fifo: Option<u8>) -> PathBuf {
        let output = format!("{}[output]\nadapter = \"sim\"\n", self.toml(VEHICLE));
        rig.vehicle_scheduled(VEHICLE, &output, fifo)
    }
}

/// Backup ranks, weakest first: (level, class), each cell of the hierarchy (docs/design.md §3).
pub(crate) const RANKS: [(&str, &str); 12] = [
    ("remote", "desktop"),
    ("remote", "laptop"),
    ("remote", "tablet"),
    ("remote", "phone"),
    ("stationary", "desktop"),
    ("stationary", "laptop"),
    ("stationary", "tablet"),
    ("stationary", "phone"),
    ("mobile", "desktop"),
    ("mobile", "laptop"),
    ("mobile", "tablet"),
    ("mobile", "phone"),
];

/// Runs one scenario.
///
/// # Errors
/// The namespace or a process cannot be started, or an expected event never comes.
pub fn run(
    rove: &Path,
    options: &Options,
    progress: &mut dyn FnMut(&str),
) -> anyhow::Result<Report> {
    let mut rig = Rig::new(rove, "bench")?;
    let security = BenchSecurity(match options.secure {
        true => Some(rig.fleet(&bench_ids(options))?),
        false => None,
    });
    let observer = security.spawn_status(&mut rig, "observer");
    let events_path = rig.procs[observer].log.clone();
    let mut events = Follow::new(&events_path);
    let report = match options.scenario {
        Scenario::Latejoin => latejoin(&mut rig, &security, options, progress),
        Scenario::Graceful | Scenario::Crash => {
            passive(&mut rig, &security, options, &mut events, progress)
        }
        Scenario::Active => active(&mut rig, &security, options, &mut events, progress),
    }?;
    Ok(report)
}

fn passive(
    rig: &mut Rig,
    security: &BenchSecurity,
    options: &Options,
    events: &mut Follow,
    progress: &mut dyn FnMut(&str),
) -> anyhow::Result<Report> {
    let record = security.vehicle(rig, options.vehicle_rt);
    let backups = options.controllers.saturating_sub(1).min(RANKS.len() - 1);
    let mut successor = None;
    for (i, (level, class)) in RANKS.iter().take(backups).enumerate() {
        let id = 21 + i as i64;
        rig.operator(id, level, class, &[VEHICLE], 100, &security.toml(id), &[]);
        successor = Some(id);
    }
    if let Some(s) = successor {
        harness::wait_for_output(&record, Some(s), 0).map_err(anyhow::Error::msg)?;
    }
    let (mut info, mut applied, mut ping_pong) = (Vec::new(), Vec::new(), 0);
    for run in 0..options.runs {
        // The owner: a mobile phone, above every backup.
        let owner = rig.operator(
            11,
            "mobile",
            "phone",
            &[VEHICLE],
            2000,
            &security.toml(11),
            &[],
        );
        harness::wait_for_output(&record, Some(11), wall_us()).map_err(anyhow::Error::msg)?;
        let t0 = wall_us();
        if options.scenario == Scenario::Crash {
            rig.procs[owner].crash();
        } else {
            rig.procs[owner].terminate();
        }
        let out = harness::wait_for_output(&record, successor, t0).map_err(anyhow::Error::msg)?;
        let seen = wait_event(events, t0, |e| {
            e["kind"] == "device"
                && e["id"] == VEHICLE
                && e["controller_id"] == successor.unwrap_or(VEHICLE)
        })?;
        info.push(ms(seen - t0));
        applied.push(ms(out.wall_us - t0));
        ping_pong += count_ping_pong(&records(&record), t0, Some(11), successor);
        if options.scenario == Scenario::Graceful {
            rig.procs[owner].wait_exit(harness::PATIENCE);
        }
        progress(&format!(
            "run {}/{}: applied {:.2} ms",
            run + 1,
            options.runs,
            ms(out.wall_us - t0)
        ));
    }
    Ok(report(options, info, applied, ping_pong))
}

fn active(
    rig: &mut Rig,
    security: &BenchSecurity,
    options: &Options,
    events: &mut Follow,
    progress: &mut dyn FnMut(&str),
) -> anyhow::Result<Report> {
    let record = security.vehicle(rig, options.vehicle_rt);
    // The owner accepts every request, as the seed's experiment did.
    // It is the strongest passive controller, so bystanders (all weaker, ranks repeating
    // when there are more bystanders than ranks) never take the vehicle themselves.
    // Its record gives the instant each ACCEPT leaves: the start of the measurement. (An
    // observer's arrival time is no substitute: the vehicle may hear the ACCEPT first.)
    let sent_path = rig.dir.join("owner-sent.jsonl");
    rig.operator(
        11,
        "mobile",
        "phone",
        &[VEHICLE],
        1000,
        &format!(
            "{}[handover]\nauto_accept = \"always\"\n",
            security.toml(11)
        ),
        &["--record", sent_path.to_str().unwrap_or_default()],
    );
    let mut sent = Follow::new(&sent_path);
    harness::wait_for_output(&record, Some(11), 0).map_err(anyhow::Error::msg)?;
    let bystanders = RANKS[..RANKS.len() - 1].iter().cycle();
    for (i, (level, class)) in bystanders
        .take(options.controllers.saturating_sub(2))
        .enumerate()
    {
        let id = 31 + i as i64;
        rig.operator(id, level, class, &[VEHICLE], 100, &security.toml(id), &[]);
    }
    let (mut info, mut applied, mut ping_pong) = (Vec::new(), Vec::new(), 0);
    for run in 0..options.runs {
        let start = wall_us();
        let request = ["--request", "100"];
        let requester = rig.operator(
            13,
            "remote",
            "tablet",
            &[],
            3000,
            &security.toml(13),
            &request,
        );
        let accept = wait_event(&mut sent, start, |e| {
            e["kind"] == "request" && e["ack"] == "accept" && e["src"] == 13 && e["current"] == 11
        })?;
        let out =
            harness::wait_for_output(&record, Some(13), accept).map_err(anyhow::Error::msg)?;
        let seen = wait_event(events, accept, |e| {
            e["kind"] == "device" && e["id"] == VEHICLE && e["controller_id"] == 13
        })?;
        info.push(ms(seen.saturating_sub(accept)));
        applied.push(ms(out.wall_us.saturating_sub(accept)));
        // Hold the grant past the ping-pong window, then FINISH and wait for the owner.
        let hold_until = accept + PING_PONG_WINDOW_US;
        while wall_us() < hold_until {
            std::thread::sleep(Duration::from_millis(20));
        }
        ping_pong += count_ping_pong(&records(&record), accept, Some(11), Some(13));
        let finish = wall_us();
        rig.procs[requester].terminate();
        harness::wait_for_output(&record, Some(11), finish).map_err(anyhow::Error::msg)?;
        rig.procs[requester].wait_exit(harness::PATIENCE);
        progress(&format!(
            "run {}/{}: applied {:.2} ms",
            run + 1,
            options.runs,
            ms(out.wall_us.saturating_sub(accept))
        ));
    }
    Ok(report(options, info, applied, ping_pong))
}

fn latejoin(
    rig: &mut Rig,
    security: &BenchSecurity,
    options: &Options,
    progress: &mut dyn FnMut(&str),
) -> anyhow::Result<Report> {
    let devices = options.devices.max(1);
    security.vehicle(rig, options.vehicle_rt);
    for i in 1..devices {
        let (level, class) = RANKS[i % RANKS.len()];
        let id = 200 + i as i64;
        rig.operator(id, level, class, &[], 0, &security.toml(id), &[]);
    }
    let everyone: std::collections::BTreeSet<i64> = std::iter::once(VEHICLE)
        .chain((1..devices).map(|i| 200 + i as i64))
        .collect();
    let mut listed = Vec::new();
    for run in 0..options.runs {
        let t0 = wall_us();
        let p = security.spawn_status(rig, &format!("joiner-{run}"));
        let path = rig.procs[p].log.clone();
        let done = harness::wait_listed(&path, &everyone, harness::PATIENCE)
            .map_err(anyhow::Error::msg)?;
        // Stopped gracefully: a killed joiner would load every later run.
        rig.procs[p].stop();
        listed.push(ms(done.saturating_sub(t0)));
        progress(&format!(
            "run {}/{}: all {devices} listed after {:.1} ms",
            run + 1,
            options.runs,
            ms(done - t0)
        ));
    }
    let mut r = report(options, listed, Vec::new(), 0);
    r.controllers = devices;
    Ok(r)
}

fn read_events(path: &Path) -> Vec<Value> {
    std::fs::read_to_string(path)
        .unwrap_or_default()
        .lines()
        .filter_map(|l| serde_json::from_str(l).ok())
        .collect()
}

/// The arrival time of the first event after `since` that matches.
fn wait_event(
    follow: &mut Follow,
    since: u64,
    matches: impl Fn(&Value) -> bool,
) -> anyhow::Result<u64> {
    let deadline = Instant::now() + harness::PATIENCE;
    loop {
        follow.poll();
        if let Some(at) = follow
            .find_since(since, &matches)
            .and_then(|e| e["wall_us"].as_u64())
        {
            return Ok(at);
        }
        anyhow::ensure!(
            Instant::now() < deadline,
            "expected event never observed in {}",
            follow.path().display()
        );
        std::thread::sleep(Duration::from_millis(2));
    }
}

/// Where `rove bench handover` writes its results besides the table on stdout.
#[derive(Debug, Clone, Default)]
pub struct Outputs {
    /// One JSON object per scenario run.
    pub json: Option<PathBuf>,
    /// A box plot of all runs.
    pub svg: Option<PathBuf>,
}

/// `rove bench handover`: runs `options` once per controller count in `controllers` (once
/// for the late joiner), prints a table per count and one for all, and writes `outputs`.
///
/// # Errors
/// As [`run`]; or an output file cannot be written.
pub fn handover_cli(
    rove: &Path,
    options: Options,
    controllers: &[usize],
    security: &[bool],
    outputs: &Outputs,
) -> anyhow::Result<()> {
    let mut reports = Vec::new();
    for &n in controllers {
        // Security off and on back to back, so that their cost compares on one machine state.
        for &secure in security {
            let options = Options {
                controllers: n,
                secure,
                ..options.clone()
            };
            let report = run(rove, &options, &mut |line| eprintln!("  {line}"))?;
            print!("{}", table(std::slice::from_ref(&report)));
            reports.push(report);
        }
        if options.scenario == Scenario::Latejoin {
            break;
        }
    }
    println!();
    print!("{}", table(&reports));
    if let Some(path) = &outputs.json {
        write_json(path, &reports)?;
    }
    if let Some(path) = &outputs.svg {
        std::fs::write(path, svg(&reports))?;
    }
    Ok(())
}
