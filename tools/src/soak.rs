//! `rove bench soak`: does anything grow while operators come and go (issue 51)?
//!
//! A vehicle (sim) driven by a laptop, a bystander desktop that drives nothing and a browser
//! console's host (no browser) run for the whole soak; each cycle a new operator participant
//! joins and leaves:
//! - a phone starts, preempts the laptop, and quits (SIGTERM): control falls back to the laptop;
//! - every `request_every`-th cycle, a tablet asks for the vehicle instead (`--request`), the
//!   laptop grants it, and the tablet quits: its FINISH gives the vehicle back.
//!
//! Each joiner is a new process, so a new DDS participant, as a phone that reconnects is. With
//! `--remote-every N`, every N-th cycle's joiner is a remote operator at a second site that
//! requests the vehicle through the two sites' bridges (long-lived, and measured too).
//!
//! Every `sample_every` cycles the resident memory, open file descriptors and threads of each
//! long-lived process are read from `/proc`. The growth per cycle is the least-squares slope of
//! resident memory over the cycles after the warm-up ([`slope`], pure): a process that keeps
//! something for every participant that left grows by that much per cycle.

use super::harness::{Appended, Rig, security_toml};
use serde::Serialize;
use std::path::Path;
use std::time::{Duration, Instant};

const VEHICLE: i64 = 100;
const LAPTOP: i64 = 11;
const DESKTOP: i64 = 14;
const WEB_HOST: i64 = 20;
/// Phones and tablets take their ids in turn from these: an id a participant just left stays
/// pinned to it for a heartbeat (the trust rules' grace), so one id reused at once would make
/// every cycle wait that long. The tables keyed by device id stay bounded by the rotation.
const PHONES: std::ops::Range<i64> = 30..62;
const TABLETS: std::ops::Range<i64> = 70..78;
const REMOTES: std::ops::Range<i64> = 80..88;
/// The browser console's configured device (never connected: no browser).
const WEB_DEVICE: i64 = 25;
/// How long the two sites' bridges may take to meet.
#[cfg(all(feature = "remote", feature = "security"))]
const SITES_PATIENCE: Duration = Duration::from_secs(60);
/// How long one owner change may take before the soak fails.
const CHANGE_PATIENCE: Duration = Duration::from_secs(15);

/// Options of a soak.
#[derive(Debug, Clone)]
pub struct Options {
    /// Join-and-leave cycles.
    pub cycles: usize,
    /// Cycles before the growth is measured (start-up allocations, caches filling).
    pub warmup: usize,
    /// Cycles between samples.
    pub sample_every: usize,
    /// Every this many cycles, a request (active handover) instead of a preemption; 0: never.
    pub request_every: usize,
    /// Fail when a long-lived process grows by more than this many KiB per cycle.
    pub max_kib_per_cycle: Option<f64>,
    /// Every this many cycles, a remote operator at another site (joined by two bridges,
    /// docs/remote.md) requests the vehicle instead; 0: no second site, no bridges.
    pub remote_every: usize,
    /// Every process of the site secured (DDS Security, one certificate per device id): each
    /// joiner is authenticated by every node, as in a secured fleet.
    pub secure: bool,
}

/// One sample of one process.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct Sample {
    /// Cycles done.
    pub cycle: usize,
    /// Resident memory, KiB.
    pub rss_kib: u64,
    /// Its anonymous part (heap, stacks), KiB: what the process keeps. The rest is mostly the
    /// binary's pages, which grow as code runs for the first time, up to the binary's size.
    pub anon_kib: u64,
    /// Open file descriptors.
    pub fds: usize,
    /// Threads.
    pub threads: u64,
}

/// A long-lived process's samples and growth.
#[derive(Debug, Clone, Serialize)]
pub struct Process {
    /// Its name.
    pub name: String,
    /// Its samples.
    pub samples: Vec<Sample>,
    /// Resident memory growth per cycle after the warm-up, KiB.
    pub kib_per_cycle: f64,
    /// Anonymous resident memory growth per cycle after the warm-up, KiB.
    pub anon_kib_per_cycle: f64,
    /// ERROR lines and panics in its log by the end (a healthy fleet whose operators come and
    /// go logs none).
    pub error_lines: usize,
    /// The first few distinct ERROR lines and panics, without their time stamps.
    pub error_examples: Vec<String>,
    /// A bridge: the times it saw the other site's link drop ("site gone"), which a link on
    /// loopback should never do; 0 for every other process.
    pub sites_gone: usize,
}

/// What a soak found.
#[derive(Debug, Clone, Serialize)]
pub struct Report {
    /// Cycles run.
    pub cycles: usize,
    /// Warm-up cycles.
    pub warmup: usize,
    /// Owner changes seen (two per cycle).
    pub handovers: usize,
    /// Outputs to the safe state while the laptop lived (none expected).
    pub failsafes: usize,
    /// Wall time, s.
    pub seconds: f64,
    /// The long-lived processes.
    pub processes: Vec<Process>,
}

/// The least-squares slope of `y` over `x` (pure); 0 with fewer than two points.
pub fn slope(points: &[(f64, f64)]) -> f64 {
    let n = points.len() as f64;
    if points.len() < 2 {
        return 0.0;
    }
    let (mx, my) = points
        .iter()
        .fold((0.0, 0.0), |(a, b), (x, y)| (a + x / n, b + y / n));
    let (num, den) = points.iter().fold((0.0, 0.0), |(num, den), (x, y)| {
        (num + (x - mx) * (y - my), den + (x - mx) * (x - mx))
    });
    if den == 0.0 { 0.0 } else { num / den }
}

/// Resident memory (all, and its anonymous part), fds and threads of `pid` after `cycle`
/// cycles: one read of `/proc/PID/status` for the three counts it holds.
fn sample(pid: u32, cycle: usize) -> Option<Sample> {
    let fds = std::fs::read_dir(format!("/proc/{pid}/fd")).ok()?.count();
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).ok()?;
    let field = |name: &str| {
        (status.lines())
            .find_map(|l| l.strip_prefix(name))
            .and_then(|v| v.split_whitespace().next()?.parse().ok())
    };
    Some(Sample {
        cycle,
        rss_kib: field("VmRSS:")?,
        anon_kib: field("RssAnon:")?,
        fds,
        threads: field("Threads:")?,
    })
}

/// Reads a vehicle's record as it grows, keeping nothing but the last owner seen.
struct Tail {
    appended: Appended,
    owner: Option<i64>,
    changes: usize,
    safe: usize,
}

impl Tail {
    fn new(path: &Path) -> Tail {
        Tail {
            appended: Appended::new(path),
            owner: None,
            changes: 0,
            safe: 0,
        }
    }

    fn poll(&mut self) {
        for v in self.appended.read() {
            if v["action"] == "safe" {
                self.safe += 1;
            }
            let owner = v["owner"].as_i64();
            if v["action"] == "apply" && owner != self.owner {
                self.owner = owner;
                self.changes += 1;
            }
        }
    }

    /// Waits until `owner` drives.
    fn wait_owner(&mut self, owner: i64) -> anyhow::Result<()> {
        let deadline = Instant::now() + CHANGE_PATIENCE;
        loop {
            self.poll();
            if self.owner == Some(owner) {
                return Ok(());
            }
            anyhow::ensure!(
                Instant::now() < deadline,
                "operator {owner} not driving after {CHANGE_PATIENCE:?} (owner {:?})",
                self.owner
            );
            std::thread::sleep(Duration::from_millis(2));
        }
    }
}

/// With `every` > 0: a second site ("home") joined to the rig's ("lab") by a veth pair and the
/// two sites' bridges, the lab offering the vehicle to home's remote operators.
#[cfg(all(feature = "remote", feature = "security"))]
fn remote_site(rove: &Path, lab: &mut Rig, every: usize) -> anyhow::Result<Option<Rig>> {
    use super::sites::{self, Meet};
    if every == 0 {
        return Ok(None);
    }
    let mut home = Rig::new(rove, "soak-home")?;
    sites::join(lab, &home)?;
    let fleet = sites::fleet(&lab.rove, &lab.dir.join("fleet"))?;
    let remotes: Vec<i64> = REMOTES.collect();
    let offered = sites::peer("home", &remotes, &[VEHICLE]);
    let lab_bridge = sites::bridge(
        lab,
        "lab",
        Meet::Listen(sites::LAB_ADDRESS),
        &fleet.join("site-lab"),
        &offered,
    );
    let lab_ids = sites::peer("lab", &[VEHICLE, LAPTOP], &[]);
    let home_dir = fleet.join("site-home");
    let home_bridge = sites::bridge(
        &mut home,
        "home",
        Meet::Connect(sites::LAB_ADDRESS),
        &home_dir,
        &lab_ids,
    );
    // The cycles start once each bridge has the other site up: a machine busy enough to take
    // longer than an owner change's patience to open the TLS link fails no remote cycle.
    for log in [&lab.procs[lab_bridge].log, &home.procs[home_bridge].log] {
        sites::wait_up(log, SITES_PATIENCE)?;
    }
    Ok(Some(home))
}

#[cfg(not(all(feature = "remote", feature = "security")))]
fn remote_site(_: &Path, _: &mut Rig, every: usize) -> anyhow::Result<Option<Rig>> {
    anyhow::ensure!(
        every == 0,
        "this build has no `rove bridge` (cargo feature `remote`)"
    );
    Ok(None)
}

/// One cycle: a joiner (phone, tablet, or remote operator) takes the vehicle and quits; control
/// is back with the laptop.
fn one_cycle(
    rig: &mut Rig,
    home: Option<&mut Rig>,
    tail: &mut Tail,
    (options, keys): (&Options, Option<&Path>),
    cycle: usize,
) -> anyhow::Result<()> {
    let turn = |ids: std::ops::Range<i64>| ids.start + (cycle as i64 % (ids.end - ids.start));
    if let Some(home) = home.filter(|_| cycle.is_multiple_of(options.remote_every)) {
        let id = turn(REMOTES);
        let args = ["--request", "100"];
        let n = home.operator(id, "remote", "laptop", &[], 3000, "", &args);
        tail.wait_owner(id)?;
        home.procs[n].terminate();
        let exited = home.procs[n].wait_exit(CHANGE_PATIENCE);
        anyhow::ensure!(
            exited.is_some(),
            "cycle {cycle}: the remote operator did not stop"
        );
        tail.wait_owner(LAPTOP)?;
        let gone = home.procs.remove(n);
        let _ = std::fs::remove_file(&gone.log);
        return Ok(());
    }
    let request = options.request_every > 0 && cycle.is_multiple_of(options.request_every);
    let (joiner, id) = if request {
        let id = turn(TABLETS);
        let args = ["--request", "100"];
        let extra = security_toml(keys, id);
        let n = rig.operator(id, "remote", "tablet", &[], 3000, &extra, &args);
        (n, id)
    } else {
        let id = turn(PHONES);
        let extra = security_toml(keys, id);
        (
            rig.operator(id, "mobile", "phone", &[VEHICLE], 2000, &extra, &[]),
            id,
        )
    };
    tail.wait_owner(id)?;
    rig.procs[joiner].terminate();
    let exited = rig.procs[joiner].wait_exit(CHANGE_PATIENCE);
    anyhow::ensure!(exited.is_some(), "cycle {cycle}: the joiner did not stop");
    tail.wait_owner(LAPTOP)?;
    // The finished joiner's handle and log go: the rig must not grow either.
    let gone = rig.procs.remove(joiner);
    let _ = std::fs::remove_file(&gone.log);
    Ok(())
}

/// A long-lived process's log, read once at the end for what it says; empty if it cannot be read.
fn read_log(path: &Path) -> String {
    std::fs::read_to_string(path).unwrap_or_default()
}

/// The ERROR lines and panics in a log's `text`: how many, and the first three distinct ones
/// without their time stamps.
fn error_lines(text: &str) -> (usize, Vec<String>) {
    let mut examples: Vec<String> = Vec::new();
    let mut count = 0;
    // A plain log line is `TIME LEVEL target: message`: the level is the second field (a
    // message may say ERROR too). A panic, on any thread, is `thread 'NAME' (ID) panicked at
    // PLACE:`, on stderr, which the log holds too.
    let errors = (text.lines()).filter_map(|line| {
        if line.starts_with("thread '") && line.contains(" panicked at ") {
            return Some(line);
        }
        let mut fields = line.trim_start().splitn(3, char::is_whitespace);
        let (_, level) = (fields.next(), fields.next());
        (level == Some("ERROR")).then(|| fields.next().unwrap_or("").trim_start())
    });
    for what in errors {
        count += 1;
        let what: String = what.chars().take(200).collect();
        if examples.len() < 3 && !examples.contains(&what) {
            examples.push(what);
        }
    }
    (count, examples)
}

/// The times a log's `text` says a site's link went (`rove bridge`'s "site gone:" line; its
/// devices leave only if it stays away, "site still gone").
fn sites_gone(text: &str) -> usize {
    text.lines()
        .filter(|line| line.contains(": site gone: "))
        .count()
}

/// Every device id of a secured soak's site: the long-lived ones and every joiner's.
fn certified_ids() -> Vec<i64> {
    ([VEHICLE, LAPTOP, DESKTOP, WEB_HOST, WEB_DEVICE].into_iter())
        .chain(PHONES)
        .chain(TABLETS)
        .collect()
}

/// Runs a soak with the `rove` binary at `rove`.
///
/// # Errors
/// The rig cannot be set up (needs root), an owner change does not come, a long-lived process
/// exits, or one grows by more than `max_kib_per_cycle`.
pub fn run(
    rove: &Path,
    options: &Options,
    mut progress: impl FnMut(&str),
) -> anyhow::Result<Report> {
    anyhow::ensure!(
        !(options.secure && options.remote_every > 0),
        "--secure with --remote-every: the soak's bridges speak to their sites unsecured"
    );
    let mut rig = Rig::new(rove, "soak")?;
    let keys = options
        .secure
        .then(|| rig.fleet(&certified_ids()))
        .transpose()?;
    let keys = keys.as_deref();
    let output = format!(
        "{}[output]\nadapter = \"sim\"\n",
        security_toml(keys, VEHICLE)
    );
    let record = rig.vehicle_with_output(VEHICLE, &output);
    let accept = "[handover]\nauto_accept = \"always\"\n";
    let extra = format!("{accept}{}", security_toml(keys, LAPTOP));
    let fallback = [VEHICLE];
    rig.operator(LAPTOP, "stationary", "laptop", &fallback, 1000, &extra, &[]);
    let extra = security_toml(keys, DESKTOP);
    rig.operator(DESKTOP, "stationary", "desktop", &[], 0, &extra, &[]);
    // The browser console's host (its page served, a phone device configured, no browser).
    let device_keys = keys.map(|k| format!("security = {:?}\n", k.join(WEB_DEVICE.to_string())));
    let web = format!(
        "[web]\nlisten = \"127.0.0.1:18443\"\n[[web.device]]\nid = {WEB_DEVICE}\ndrive = [100]\n{}{}",
        device_keys.unwrap_or_default(),
        security_toml(keys, WEB_HOST)
    );
    rig.operator(WEB_HOST, "stationary", "desktop", &[], 0, &web, &[]);
    let mut home = remote_site(rove, &mut rig, options.remote_every)?;
    let mut long_lived: Vec<(String, u32, std::path::PathBuf)> = (rig.procs.iter())
        .map(|p| (p.name.clone(), p.pid(), p.log.clone()))
        .collect();
    if let Some(home) = &home {
        long_lived.extend(
            (home.procs.iter()).map(|p| (format!("home {}", p.name), p.pid(), p.log.clone())),
        );
    }
    let mut tail = Tail::new(&record);
    tail.wait_owner(LAPTOP)?;
    let mut processes: Vec<Process> = (long_lived.iter())
        .map(|(name, _, _)| Process {
            name: name.clone(),
            samples: Vec::new(),
            kib_per_cycle: 0.0,
            anon_kib_per_cycle: 0.0,
            error_lines: 0,
            sites_gone: 0,
            error_examples: Vec::new(),
        })
        .collect();
    let started = Instant::now();
    let safe_before = tail.safe;
    for cycle in 0..=options.cycles {
        if cycle % options.sample_every.max(1) == 0 || cycle == options.cycles {
            for ((_, pid, _), process) in long_lived.iter().zip(&mut processes) {
                let s = sample(*pid, cycle)
                    .ok_or_else(|| anyhow::anyhow!("{} exited during the soak", process.name))?;
                process.samples.push(s);
            }
            let rss: Vec<String> = (processes.iter())
                .filter_map(|p| {
                    let s = p.samples.last()?;
                    Some(format!(
                        "{} {} KiB (anon {})",
                        p.name, s.rss_kib, s.anon_kib
                    ))
                })
                .collect();
            progress(&format!("cycle {cycle}: {}", rss.join(", ")));
        }
        if cycle == options.cycles {
            break;
        }
        one_cycle(&mut rig, home.as_mut(), &mut tail, (options, keys), cycle)?;
    }
    for (p, (_, _, log)) in processes.iter_mut().zip(&long_lived) {
        let text = read_log(log);
        (p.error_lines, p.error_examples) = error_lines(&text);
        p.sites_gone = sites_gone(&text);
        let growth = |kib: fn(&Sample) -> u64| {
            let points: Vec<(f64, f64)> = (p.samples.iter())
                .filter(|s| s.cycle >= options.warmup)
                .map(|s| (s.cycle as f64, kib(s) as f64))
                .collect();
            slope(&points)
        };
        p.kib_per_cycle = growth(|s| s.rss_kib);
        p.anon_kib_per_cycle = growth(|s| s.anon_kib);
    }
    let report = Report {
        cycles: options.cycles,
        warmup: options.warmup,
        handovers: tail.changes,
        failsafes: tail.safe - safe_before,
        seconds: started.elapsed().as_secs_f64(),
        processes,
    };
    if let Some(max) = options.max_kib_per_cycle {
        for p in &report.processes {
            anyhow::ensure!(
                p.kib_per_cycle <= max,
                "{} grows {:.2} KiB per cycle after {} cycles of warm-up (bound {max} KiB)",
                p.name,
                p.kib_per_cycle,
                report.warmup
            );
        }
    }
    Ok(report)
}

/// `rove bench soak`: runs it, prints the curve and the growth, writes `json` if given.
///
/// # Errors
/// As [`run`]; the JSON cannot be written.
pub fn cli(rove: &Path, options: &Options, json: Option<&Path>) -> anyhow::Result<()> {
    let report = run(rove, options, |line| println!("{line}"))?;
    println!(
        "{} cycles in {:.0} s: {} owner changes, {} safe outputs while the laptop lived",
        report.cycles, report.seconds, report.handovers, report.failsafes
    );
    for p in &report.processes {
        let (first, last) = (p.samples.first(), p.samples.last());
        let span = |f: fn(&Sample) -> String| match (first, last) {
            (Some(a), Some(b)) => format!("{} → {}", f(a), f(b)),
            _ => "-".into(),
        };
        let link = if p.name.contains("bridge") {
            format!("; the other site gone {} times", p.sites_gone)
        } else {
            String::new()
        };
        println!(
            "{:<12} RSS {} KiB, {:+.2} KiB/cycle after cycle {} (anonymous {} KiB, {:+.2}); fds {}; \
             threads {}; {} ERROR lines and panics{link}",
            p.name,
            span(|s| s.rss_kib.to_string()),
            p.kib_per_cycle,
            report.warmup,
            span(|s| s.anon_kib.to_string()),
            p.anon_kib_per_cycle,
            span(|s| s.fds.to_string()),
            span(|s| s.threads.to_string()),
            p.error_lines,
        );
        for example in &p.error_examples {
            println!("    ERROR {example}");
        }
    }
    if let Some(path) = json {
        std::fs::write(path, serde_json::to_string_pretty(&report)?)?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_sample_reads_this_process_and_its_anonymous_memory_is_part_of_its_resident() {
        let s = sample(std::process::id(), 7).expect("this process's /proc");
        assert_eq!(s.cycle, 7);
        assert!(0 < s.anon_kib && s.anon_kib < s.rss_kib, "{s:?}");
        assert!(s.fds > 0 && s.threads > 0, "{s:?}");
    }

    #[test]
    fn the_slope_is_the_growth_per_cycle() {
        let line: Vec<(f64, f64)> = (0..10)
            .map(|c| (c as f64, 1000.0 + 36.0 * c as f64))
            .collect();
        assert!((slope(&line) - 36.0).abs() < 1e-9);
        let flat: Vec<(f64, f64)> = (0..10)
            .map(|c| (c as f64, 1000.0 + (c % 2) as f64))
            .collect();
        assert!(slope(&flat).abs() < 0.2);
        assert_eq!(slope(&[(1.0, 5.0)]), 0.0);
        assert_eq!(slope(&[(1.0, 5.0), (1.0, 7.0)]), 0.0, "one x: no slope");
    }

    #[test]
    fn error_lines_and_panics_are_counted_and_the_first_distinct_errors_kept_without_time_stamps() {
        let lines = [
            "2026-11-30T03:00:00.1Z  INFO rove: started",
            "2026-11-30T03:00:01.1Z ERROR rustdds::a: one",
            "2026-11-30T03:00:02.1Z ERROR rustdds::a: one",
            "2026-11-30T03:00:03.1Z  WARN rustdds::b: an ERROR word in a warning",
            "2026-11-30T03:00:04.1Z ERROR rustdds::b: two",
            "2026-11-30T03:00:05.1Z ERROR rustdds::c: three",
            "2026-11-30T03:00:06.1Z ERROR rustdds::d: four",
            "thread 'RustDDS discovery thread' (20150) panicked at std/src/thread.rs:127:9:",
        ];
        let (count, examples) = error_lines(&lines.join("\n"));
        assert_eq!(count, 6, "five ERROR lines and a panic");
        assert_eq!(
            examples,
            ["rustdds::a: one", "rustdds::b: two", "rustdds::c: three"]
        );
        let dir = tempfile::tempdir().expect("a temp dir");
        let absent = read_log(&dir.path().join("absent.log"));
        assert_eq!(
            error_lines(&absent),
            (0, Vec::new()),
            "a log that cannot be read"
        );
    }

    #[test]
    fn a_bridges_link_drops_are_counted_from_its_log() {
        let lines = [
            "2026-11-30T09:16:52.0Z  INFO rove_gateway::bridge: site up site=lab",
            "2026-11-30T09:17:52.8Z  INFO rove_gateway::bridge: site gone: its devices leave this site site=lab",
            "2026-11-30T09:17:52.8Z  INFO rove_gateway::bridge: site up site=lab",
            "2026-11-30T09:22:02.6Z  INFO rove_gateway::bridge::sites: site gone: its devices leave this site unless it is back within the grace site=lab grace_ms=1000",
            "2026-11-30T09:22:02.6Z  INFO rove_gateway::bridge::sites: site back: its devices stayed here site=lab",
            "2026-11-30T09:23:02.6Z  INFO rove_gateway::bridge::sites: site still gone: its devices leave this site site=lab",
        ];
        assert_eq!(sites_gone(&lines.join("\n")), 2);
        let dir = tempfile::tempdir().expect("a temp dir");
        assert_eq!(sites_gone(&read_log(&dir.path().join("absent.log"))), 0);
    }
}
