//! `rove bench handover --remote`: what the link between sites (`rove bridge`, docs/remote.md)
//! adds, measured in one run on one machine: two sites (tools::sites) with their bridges, the
//! vehicle in the lab, and each measurement made with the operators in the lab (local) and then
//! at home (remote, through both bridges and the Zenoh link):
//! - input → vehicle output latency (a replayed joystick, as `rove bench input`);
//! - handovers: graceful (the owner quits), crash (it is killed), active (a weaker operator
//!   asks through the local API, the owner auto-accepts), trigger → the new owner's first
//!   applied command;
//! - a cut link (veth down, then a silent nftables drop): the cut → the vehicle's safe state,
//!   and the link's return → the remote operator driving again;
//! - the CPU each bridge uses while `operators` remote operators stream at 50 Hz, each to a
//!   vehicle of its own.
//!
//! All processes share the machine's clock; latencies are wall-clock differences.

use super::input::{Replay, replay_to};
use super::report::{Stats, ms};
use crate::harness::{Rig, wait_for_output, wall_us};
use crate::sites::{self, Cut, Meet};
use serde::Serialize;
use std::path::{Path, PathBuf};
use std::time::Duration;

const VEHICLE: i64 = 100;
/// The operators of each placement (their ids differ, so that no id is pinned to a participant
/// that just left): the replayed joystick's, the owner in the handover runs (remote phone,
/// 140, auto-accepts) and the backup and requester (remote laptop, 120).
#[derive(Debug, Clone, Copy)]
struct Ids {
    replay: i64,
    owner: i64,
    backup: i64,
}

const LOCAL: Ids = Ids {
    replay: 11,
    owner: 12,
    backup: 13,
};
const REMOTE: Ids = Ids {
    replay: 14,
    owner: 15,
    backup: 16,
};
/// The remote owner of the link cuts.
const CUT_OWNER: i64 = 17;
/// The first of the streaming operators of the CPU phase (their vehicles from 101).
const STREAMERS: i64 = 21;

/// What to run.
#[derive(Debug, Clone, Copy)]
pub struct Options {
    /// Runs of each handover scenario, per placement.
    pub runs: usize,
    /// Stick events replayed per placement.
    pub events: usize,
    /// Remote operators streaming in the CPU phase.
    pub operators: usize,
}

/// Where the operators are.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
enum Placement {
    Local,
    Remote,
}

/// One measurement.
#[derive(Debug, Clone, Serialize)]
pub struct Row {
    /// What was measured.
    pub what: String,
    /// Where the operators were: `local` (the vehicle's site) or `remote`.
    pub placement: &'static str,
    /// Latency statistics, ms.
    pub stats: Stats,
    /// Samples.
    pub n: usize,
}

/// The whole run.
#[derive(Debug, Clone, Serialize)]
pub struct RemoteReport {
    /// Every measurement.
    pub rows: Vec<Row>,
    /// Percent of a core each bridge used while the remote operators streamed: (lab, home).
    pub bridge_cpu_pct: (f64, f64),
    /// Remote operators streaming then, at 50 Hz each.
    pub operators: usize,
    /// Each bridge's resident memory (KiB) before those operators and their vehicles joined,
    /// and while they streamed: ((lab before, lab after), (home before, home after)). Each
    /// bridge then holds one more proxy participant per streaming operator (lab: the
    /// operators; home: their vehicles).
    pub bridge_rss_kib: ((u64, u64), (u64, u64)),
}

/// The two sites, their bridges and the lab's vehicles.
struct Sites {
    lab: Rig,
    home: Rig,
    veth: String,
    bridges: (usize, usize),
    record: PathBuf,
}

impl Sites {
    fn new(rove: &Path, options: &Options) -> anyhow::Result<Sites> {
        let mut lab = Rig::new(rove, "bench-remote-lab")?;
        let mut home = Rig::new(rove, "bench-remote-home")?;
        let veth = sites::join(&lab, &home)?;
        let fleet = sites::fleet(&lab.rove, &lab.dir.join("fleet"))?;
        let streamers = (STREAMERS..).take(options.operators);
        let vehicles: Vec<i64> = (VEHICLE..).take(options.operators + 1).collect();
        let mine = [REMOTE.replay, REMOTE.owner, REMOTE.backup, CUT_OWNER];
        let ids: Vec<i64> = mine.into_iter().chain(streamers).collect();
        let lab_peers = sites::peer("home", &ids, &vehicles);
        let listen = Meet::Listen(sites::LAB_ADDRESS);
        let lab_bridge =
            sites::bridge(&mut lab, "lab", listen, &fleet.join("site-lab"), &lab_peers);
        let home_peers = sites::peer("lab", &vehicles, &[]);
        let connect = Meet::Connect(sites::LAB_ADDRESS);
        let home_dir = fleet.join("site-home");
        let home_bridge = sites::bridge(&mut home, "home", connect, &home_dir, &home_peers);
        let record = lab.vehicle(VEHICLE);
        Ok(Sites {
            lab,
            home,
            veth,
            bridges: (lab_bridge, home_bridge),
            record,
        })
    }

    fn at(&mut self, placement: Placement) -> (&mut Rig, Ids) {
        match placement {
            Placement::Local => (&mut self.lab, LOCAL),
            Placement::Remote => (&mut self.home, REMOTE),
        }
    }
}

/// Runs the bench.
///
/// # Errors
/// The sites cannot be built, or an expected output never comes.
pub fn remote(
    rove: &Path,
    options: &Options,
    progress: &mut dyn FnMut(&str),
) -> anyhow::Result<RemoteReport> {
    let mut sites = Sites::new(rove, options)?;
    let mut rows = Vec::new();
    for placement in [Placement::Local, Placement::Remote] {
        let name = format!("{placement:?}").to_lowercase();
        progress(&format!("input → output, operator {name}"));
        let record = sites.record.clone();
        let (rig, ids) = sites.at(placement);
        let replay = Replay {
            operator: ids.replay,
            start_ms: 4000.0,
            events: options.events,
            rate_hz: 100.0,
        };
        let (stats, _) = replay_to(rig, &record, &replay, progress)?;
        rows.push(row("input → output", placement, stats, options.events));
        rows.extend(handovers(&mut sites, placement, options.runs, progress)?);
    }
    rows.extend(cuts(&mut sites, options.runs.clamp(1, 5), progress)?);
    progress(&format!("{} remote operators streaming", options.operators));
    let before = bridges_rss(&sites)?;
    let bridge_cpu_pct = streaming_cpu(&mut sites, options.operators)?;
    let after = bridges_rss(&sites)?;
    Ok(RemoteReport {
        rows,
        bridge_cpu_pct,
        operators: options.operators,
        bridge_rss_kib: ((before.0, after.0), (before.1, after.1)),
    })
}

fn row(what: &str, placement: Placement, stats: Stats, n: usize) -> Row {
    Row {
        what: what.to_string(),
        placement: match placement {
            Placement::Local => "local",
            Placement::Remote => "remote",
        },
        stats,
        n,
    }
}

/// An owner `id` (a remote phone that auto-accepts every request) started in `rig`.
fn start_owner(rig: &mut Rig, id: i64) -> usize {
    let always = "[handover]\nauto_accept = \"always\"\n";
    rig.operator(id, "remote", "phone", &[VEHICLE], 1000, always, &[])
}

/// Graceful, crash and active handovers, `runs` each, with both operators placed so.
fn handovers(
    sites: &mut Sites,
    placement: Placement,
    runs: usize,
    progress: &mut dyn FnMut(&str),
) -> anyhow::Result<Vec<Row>> {
    let record = sites.record.clone();
    let (rig, ids) = sites.at(placement);
    let socket = rig.dir.join(format!("api-{}.sock", ids.backup));
    let api = format!(
        "[console]\napi_socket = {:?}\n",
        socket.display().to_string()
    );
    let backup = rig.operator(ids.backup, "remote", "laptop", &[VEHICLE], 500, &api, &[]);
    let mut owner = start_owner(rig, ids.owner);
    wait_for_output(&record, Some(ids.owner), wall_us()).map_err(anyhow::Error::msg)?;
    let mut rows = Vec::new();
    // Active first, while the owner is the process every peer pinned its id to: after a
    // crash its restarted process takes the id back only when the old one's lease has run out
    // and its pin lapsed (docs/design.md §4b), and a requester would not believe its ACCEPT
    // until then.
    for scenario in ["active", "graceful", "crash"] {
        progress(&format!("{scenario} handovers, operators {placement:?}"));
        let mut latencies = Vec::new();
        for _ in 0..runs {
            let t = wall_us();
            match scenario {
                "graceful" => rig.procs[owner].terminate(),
                "crash" => rig.procs[owner].crash(),
                _ => api_command(&socket, "request", ids.owner)?,
            }
            let next = wait_for_output(&record, Some(ids.backup), t).map_err(anyhow::Error::msg)?;
            latencies.push(ms(next.wall_us.saturating_sub(t)));
            let again = wall_us();
            match scenario {
                "active" => api_command(&socket, "finish", ids.backup)?,
                _ => owner = start_owner(rig, ids.owner),
            }
            wait_for_output(&record, Some(ids.owner), again).map_err(anyhow::Error::msg)?;
        }
        let stats = Stats::of(&latencies).ok_or_else(|| anyhow::anyhow!("no runs"))?;
        rows.push(row(&format!("{scenario} handover"), placement, stats, runs));
    }
    for proc in [owner, backup] {
        rig.procs[proc].terminate();
        rig.procs[proc].wait_exit(Duration::from_secs(5));
    }
    Ok(rows)
}

/// Sends `{"cmd": CMD, "vehicle": 100}` to an operator's local API once its console shows
/// the vehicle owned by `owner` (a requester must know whom to ask), and waits for the reply.
fn api_command(socket: &Path, cmd: &str, owner: i64) -> anyhow::Result<()> {
    use std::io::{BufRead, Write};
    let stream = std::os::unix::net::UnixStream::connect(socket)
        .map_err(|e| anyhow::anyhow!("{}: {e}", socket.display()))?;
    stream.set_read_timeout(Some(Duration::from_secs(10)))?;
    let mut lines = std::io::BufReader::new(stream.try_clone()?).lines();
    let mut until = |want: &dyn Fn(&serde_json::Value) -> bool| -> anyhow::Result<()> {
        for line in lines.by_ref() {
            let value: serde_json::Value = serde_json::from_str(&line?).unwrap_or_default();
            if want(&value) {
                return Ok(());
            }
        }
        anyhow::bail!("{}: the operator's API closed", socket.display())
    };
    until(&|v| v["event"] == "device" && v["id"] == VEHICLE && v["owner"] == owner)?;
    writeln!(&stream, "{{\"cmd\":\"{cmd}\",\"vehicle\":{VEHICLE}}}")?;
    until(&|v| v.get("ok").is_some() || v.get("error").is_some())
}

/// The link cut `runs` times each way while the remote owner drives: cut → safe state, and
/// the link back → driving again.
fn cuts(
    sites: &mut Sites,
    runs: usize,
    progress: &mut dyn FnMut(&str),
) -> anyhow::Result<Vec<Row>> {
    let record = sites.record.clone();
    let owner = start_owner(&mut sites.home, CUT_OWNER);
    wait_for_output(&record, Some(CUT_OWNER), wall_us()).map_err(anyhow::Error::msg)?;
    let mut rows = Vec::new();
    for how in [Cut::Down, Cut::Drop] {
        progress(&format!("link cut ({how:?}) {runs} times"));
        let (mut safe, mut back) = (Vec::new(), Vec::new());
        for _ in 0..runs {
            let t = wall_us();
            sites::cut(&sites.lab, &sites.veth, how, true)?;
            let out = wait_for_output(&record, None, t).map_err(anyhow::Error::msg)?;
            safe.push(ms(out.wall_us.saturating_sub(t)));
            // Past the link's lease (3 s) and the grace after it (1 s, with the bridge's
            // half-second tick): both bridges see the other site go and its devices leave.
            std::thread::sleep(Duration::from_secs(5));
            let healed = wall_us();
            sites::cut(&sites.lab, &sites.veth, how, false)?;
            let out = wait_for_output(&record, Some(CUT_OWNER), healed);
            let out = out.map_err(anyhow::Error::msg)?;
            back.push(ms(out.wall_us.saturating_sub(healed)));
        }
        let stats = |v: &[f64]| Stats::of(v).ok_or_else(|| anyhow::anyhow!("no runs"));
        let what = format!("link cut ({how:?}) → safe state");
        rows.push(row(&what, Placement::Remote, stats(&safe)?, runs));
        let what = format!("link back ({how:?}) → remote drives");
        rows.push(row(&what, Placement::Remote, stats(&back)?, runs));
    }
    sites.home.procs[owner].terminate();
    sites.home.procs[owner].wait_exit(Duration::from_secs(5));
    Ok(rows)
}

/// `operators` remote operators, each streaming at 50 Hz to a vehicle of its own: the CPU
/// each bridge uses over 10 s, percent of a core (lab, home).
fn streaming_cpu(sites: &mut Sites, operators: usize) -> anyhow::Result<(f64, f64)> {
    let pairs: Vec<(i64, i64)> = (0..operators as i64)
        .map(|i| (STREAMERS + i, VEHICLE + 1 + i))
        .collect();
    let records: Vec<PathBuf> = pairs.iter().map(|(_, v)| sites.lab.vehicle(*v)).collect();
    for (op, vehicle) in &pairs {
        sites
            .home
            .operator(*op, "remote", "laptop", &[*vehicle], 700, "", &[]);
    }
    for ((op, _), record) in pairs.iter().zip(&records) {
        wait_for_output(record, Some(*op), 0).map_err(anyhow::Error::msg)?;
    }
    let pids = [
        sites.lab.procs[sites.bridges.0].pid(),
        sites.home.procs[sites.bridges.1].pid(),
    ];
    let cpu = crate::procstat::cpu_of(&pids, Duration::from_secs(10))?;
    Ok((cpu[0], cpu[1]))
}

/// Each bridge's resident memory, KiB: (lab, home).
fn bridges_rss(sites: &Sites) -> anyhow::Result<(u64, u64)> {
    let rss = |rig: &Rig, index: usize| {
        crate::procstat::sample(rig.procs[index].pid())
            .map(|(_, rss)| rss)
            .ok_or_else(|| anyhow::anyhow!("a bridge exited"))
    };
    Ok((
        rss(&sites.lab, sites.bridges.0)?,
        rss(&sites.home, sites.bridges.1)?,
    ))
}

/// `rove bench handover --remote`: runs and prints the report; `json` gets it as JSON.
///
/// # Errors
/// As [`remote`], or the file cannot be written.
pub fn remote_cli(rove: &Path, options: &Options, json: Option<&Path>) -> anyhow::Result<()> {
    let report = remote(rove, options, &mut |line| eprintln!("  {line}"))?;
    println!(
        "{:<40} {:>7} {:>4} {:>9} {:>9} {:>9}",
        "ms", "where", "n", "p50", "p99", "max"
    );
    for r in &report.rows {
        let s = &r.stats;
        println!(
            "{:<40} {:>7} {:>4} {:>9.3} {:>9.3} {:>9.3}",
            r.what, r.placement, r.n, s.p50, s.p99, s.max
        );
    }
    for what in [
        "input → output",
        "graceful handover",
        "crash handover",
        "active handover",
    ] {
        let p50 = |placement| {
            (report.rows.iter())
                .find(|r| r.what == what && r.placement == placement)
                .map(|r| r.stats.p50)
        };
        if let (Some(local), Some(remote)) = (p50("local"), p50("remote")) {
            println!("{what}: the link adds {:.3} ms at p50", remote - local);
        }
    }
    let (lab, home) = report.bridge_cpu_pct;
    println!(
        "{} remote operators at 50 Hz: lab bridge {lab:.1} %, home bridge {home:.1} % of a core",
        report.operators
    );
    let n = report.operators.max(1) as f64;
    for (site, (before, after)) in [
        ("lab", report.bridge_rss_kib.0),
        ("home", report.bridge_rss_kib.1),
    ] {
        let per = (after as f64 - before as f64) / n / 1024.0;
        println!(
            "{site} bridge resident memory: {:.1} MiB before, {:.1} MiB with {} more proxies \
             ({per:.2} MiB each)",
            before as f64 / 1024.0,
            after as f64 / 1024.0,
            report.operators
        );
    }
    if let Some(path) = json {
        std::fs::write(path, serde_json::to_string_pretty(&report)? + "\n")?;
    }
    Ok(())
}
