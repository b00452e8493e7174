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

use crate::tools::harness::{self, Follow, Out, Rig, records, wall_us};
use serde::Serialize;
use serde_json::Value;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

const VEHICLE: i64 = 100;
/// The window in which a return to the previous owner counts as ping-pong.
const PING_PONG_WINDOW_US: u64 = 1_000_000;

/// `rove bench input`: input event → vehicle output. A replayed joystick (rove-inputs' replay
/// source) moves the throttle `events` times at `rate_hz`, each to a value of its own; the
/// operator records the instant it reads each value (`--record`), the vehicle the instant its
/// adapter applies it. Latency = applied − read, matched by value, in ms (the first value, the
/// device's state at start-up, is sent before discovery ends and is skipped). What it leaves out:
/// the kernel's evdev delivery (there is no input device here).
///
/// # Errors
/// The rig cannot be built or the processes do not produce the records in time.
pub fn input_latency(
    rove: &Path,
    events: usize,
    rate_hz: f64,
    progress: &mut dyn FnMut(&str),
) -> anyhow::Result<(Stats, usize)> {
    let mut rig = Rig::new(rove, "bench-input")?;
    let vehicle_record = rig.vehicle(VEHICLE);
    // Start after DDS discovery (~1 s here); centred first (rove-inputs' no-jump rule).
    let start_ms = 3000.0;
    let period_ms = 1000.0 / rate_hz.clamp(1.0, 1000.0);
    let mut text = String::from("0 replug Bench Pad\n0 absinfo ABS_Y 0 -32768 32767 0 0\n");
    let mut expected = Vec::with_capacity(events);
    for i in 0..events {
        let t = start_ms + i as f64 * period_ms;
        // 0, 16, 32 … then back down: distinct values, no jump larger than a real stick's.
        let raw = ((i % 2000) as i64 * 16).min(32_000);
        let _ = writeln!(text, "{t:.3} ABS_Y {raw}\n{t:.3} SYN_REPORT");
        expected.push(raw);
    }
    let end_ms = start_ms + events as f64 * period_ms + 500.0;
    let _ = writeln!(text, "{end_ms:.3} unplug end of the benchmark");
    let recording = rig.write("bench-pad.txt", &text);
    let config = rig.write(
        "operator-bench.toml",
        &format!(
            "[device]\nid = 11\nname = \"bench-pad\"\n[operator]\nlevel = \"mobile\"\n\
             device_class = \"phone\"\ndrive = [{VEHICLE}]\n[input]\nsource = \"replay\"\n\
             file = \"{}\"\n[input.axes.throttle]\nabs = \"ABS_Y\"\ndeadzone_pct = 0\n",
            recording.display()
        ),
    );
    let op_record = rig.dir.join("operator-bench.jsonl");
    rig.spawn(
        "operator-bench",
        &[
            "operator",
            "-c",
            config.to_str().unwrap_or_default(),
            "--record",
            op_record.to_str().unwrap_or_default(),
        ],
    );
    progress(&format!(
        "{events} input events at {rate_hz} Hz after a 3 s start"
    ));
    let deadline = Instant::now() + Duration::from_secs_f64(end_ms / 1000.0 + 20.0);
    let mut inputs: Vec<(u64, i64)>;
    loop {
        std::thread::sleep(Duration::from_millis(200));
        inputs = read_events(&op_record)
            .iter()
            .filter(|e| e["kind"] == "input")
            .filter_map(|e| Some((e["wall_us"].as_u64()?, e["throttle"].as_i64()?)))
            .collect();
        let done = records(&vehicle_record)
            .iter()
            .any(|o| o.action != "apply" && o.wall_us > inputs.last().map_or(u64::MAX, |i| i.0));
        if (inputs.len() >= events && done) || Instant::now() > deadline {
            break;
        }
    }
    let outputs = records(&vehicle_record);
    let mut latencies = Vec::new();
    let mut unmatched = 0;
    let mut slow = Vec::new();
    // The first value is the device's centred state at start-up (replug), read and sent before
    // DDS discovery has finished; it measures discovery, not the input path: skipped.
    for (i, (read_us, throttle)) in inputs.iter().enumerate().skip(1) {
        match outputs
            .iter()
            .find(|o| o.owner == Some(11) && o.throttle == Some(*throttle) && o.wall_us >= *read_us)
        {
            Some(o) => {
                let l = ms(o.wall_us - read_us);
                if l > 2.0 {
                    slow.push(format!("#{i} {l:.1}"));
                }
                latencies.push(l);
            }
            // The vehicle applies the newest sample it holds: a value it never saw alone was
            // superseded, not lost.
            None => unmatched += 1,
        }
    }
    progress(&format!(
        "over 2 ms: {} of {}: {}",
        slow.len(),
        inputs.len(),
        slow.iter().take(40).cloned().collect::<Vec<_>>().join(", ")
    ));
    let stats = Stats::of(&latencies).ok_or_else(|| {
        anyhow::anyhow!("no input reached the vehicle; see {}", rig.dir.display())
    })?;
    Ok((stats, unmatched))
}

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

/// Summary statistics in milliseconds.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Stats {
    /// Mean.
    pub mean: f64,
    /// Sample standard deviation.
    pub stdev: f64,
    /// Minimum.
    pub min: f64,
    /// Maximum.
    pub max: f64,
    /// Median.
    pub p50: f64,
    /// 99th percentile (nearest rank).
    pub p99: f64,
}

impl Stats {
    /// Statistics of `values` (ms); `None` if empty.
    pub fn of(values: &[f64]) -> Option<Stats> {
        if values.is_empty() {
            return None;
        }
        let mut v = values.to_vec();
        v.sort_by(f64::total_cmp);
        let n = v.len() as f64;
        let mean = v.iter().sum::<f64>() / n;
        let var = if v.len() > 1 {
            v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0)
        } else {
            0.0
        };
        let rank = |p: f64| v[((p * n).ceil() as usize).clamp(1, v.len()) - 1];
        Some(Stats {
            mean,
            stdev: var.sqrt(),
            min: v[0],
            max: v[v.len() - 1],
            p50: rank(0.50),
            p99: rank(0.99),
        })
    }
}

/// One scenario's result, as written by `--json` (one object per scenario run).
#[derive(Debug, Clone, Serialize)]
pub struct Report {
    /// Scenario.
    pub scenario: Scenario,
    /// Controllers (or devices, for latejoin).
    pub controllers: usize,
    /// Runs measured.
    pub runs: usize,
    /// Always "ms".
    pub unit: &'static str,
    /// Trigger → DeviceInfo with the new owner (latejoin: start → all devices listed).
    pub deviceinfo: Option<Stats>,
    /// Trigger → new owner's command applied (latejoin: not measured).
    pub applied: Option<Stats>,
    /// Returns to the previous owner within 1 s.
    pub ping_pong: usize,
    /// Every process joined with DDS Security.
    pub secure: bool,
    /// Raw samples, ms.
    #[serde(skip)]
    pub raw: (Vec<f64>, Vec<f64>),
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
struct Sec(Option<PathBuf>);

impl Sec {
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
    let sec = Sec(match options.secure {
        true => Some(rig.fleet(&bench_ids(options))?),
        false => None,
    });
    let observer = sec.spawn_status(&mut rig, "observer");
    let events_path = rig.procs[observer].log.clone();
    let mut events = Follow::new(&events_path);
    let report = match options.scenario {
        Scenario::Latejoin => latejoin(&mut rig, &sec, options, progress),
        Scenario::Graceful | Scenario::Crash => {
            passive(&mut rig, &sec, options, &mut events, progress)
        }
        Scenario::Active => active(&mut rig, &sec, options, &mut events, progress),
    }?;
    Ok(report)
}

fn passive(
    rig: &mut Rig,
    sec: &Sec,
    options: &Options,
    events: &mut Follow,
    progress: &mut dyn FnMut(&str),
) -> anyhow::Result<Report> {
    let record = sec.vehicle(rig, options.vehicle_rt);
    let backups = options.controllers.saturating_sub(1).min(RANKS.len() - 1);
    let mut successor = None;
    for (i, (level, class)) in RANKS.iter().take(backups).enumerate() {
        let id = 21 + i as i64;
        rig.operator(id, level, class, &[VEHICLE], 100, &sec.toml(id), &[]);
        successor = Some(id);
    }
    if let Some(s) = successor {
        harness::wait_for_output(&record, Some(s), 0).map_err(anyhow::Error::msg)?;
    }
    let (mut info, mut applied, mut ping_pong) = (Vec::new(), Vec::new(), 0);
    for run in 0..options.runs {
        // The owner: a mobile phone, above every backup.
        let owner = rig.operator(11, "mobile", "phone", &[VEHICLE], 2000, &sec.toml(11), &[]);
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
    sec: &Sec,
    options: &Options,
    events: &mut Follow,
    progress: &mut dyn FnMut(&str),
) -> anyhow::Result<Report> {
    let record = sec.vehicle(rig, options.vehicle_rt);
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
        &format!("{}[handover]\nauto_accept = \"always\"\n", sec.toml(11)),
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
        rig.operator(id, level, class, &[VEHICLE], 100, &sec.toml(id), &[]);
    }
    let (mut info, mut applied, mut ping_pong) = (Vec::new(), Vec::new(), 0);
    for run in 0..options.runs {
        let start = wall_us();
        let request = ["--request", "100"];
        let requester = rig.operator(13, "remote", "tablet", &[], 3000, &sec.toml(13), &request);
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
    sec: &Sec,
    options: &Options,
    progress: &mut dyn FnMut(&str),
) -> anyhow::Result<Report> {
    let devices = options.devices.max(1);
    sec.vehicle(rig, options.vehicle_rt);
    for i in 1..devices {
        let (level, class) = RANKS[i % RANKS.len()];
        let id = 200 + i as i64;
        rig.operator(id, level, class, &[], 0, &sec.toml(id), &[]);
    }
    let everyone: std::collections::BTreeSet<i64> = std::iter::once(VEHICLE)
        .chain((1..devices).map(|i| 200 + i as i64))
        .collect();
    let mut listed = Vec::new();
    for run in 0..options.runs {
        let t0 = wall_us();
        let p = sec.spawn_status(rig, &format!("joiner-{run}"));
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

fn report(options: &Options, info: Vec<f64>, applied: Vec<f64>, ping_pong: usize) -> Report {
    Report {
        scenario: options.scenario,
        controllers: options.controllers,
        runs: options.runs,
        unit: "ms",
        deviceinfo: Stats::of(&info),
        applied: Stats::of(&applied),
        ping_pong,
        secure: options.secure,
        raw: (info, applied),
    }
}

fn ms(us: u64) -> f64 {
    us as f64 / 1000.0
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

/// Within the window after `t0`: once `new` was applied, any later output applied from `old`.
pub fn count_ping_pong(outputs: &[Out], t0: u64, old: Option<i64>, new: Option<i64>) -> usize {
    let window = outputs
        .iter()
        .filter(|o| o.wall_us >= t0 && o.wall_us < t0 + PING_PONG_WINDOW_US);
    let mut after_new = false;
    let mut count = 0;
    let mut previous = None;
    for o in window {
        if o.owner == new {
            after_new = true;
        } else if after_new && o.owner == old && o.action == "apply" && previous != Some(o.owner) {
            count += 1;
        }
        previous = Some(o.owner);
    }
    count
}

/// The seed's figures for comparison (thesis Tables 5.1–5.3), ms.
pub fn seed_figure(scenario: Scenario) -> &'static str {
    match scenario {
        Scenario::Graceful => "31.8–50.4 (mean, by controller count)",
        Scenario::Crash => "424 (0.5 s lease)",
        Scenario::Active => "23.7 mean / 150 max, with ping-pong",
        Scenario::Latejoin => "—",
    }
}

/// The human table for a set of reports.
pub fn table(reports: &[Report]) -> String {
    let mut out = String::new();
    let _ = writeln!(
        out,
        "{:<9} {:>4} {:>5} {:<10} {:>8} {:>8} {:>8} {:>8} {:>8} {:>8} {:>4}  seed",
        "scenario", "n", "runs", "measure", "mean", "stdev", "min", "p50", "p99", "max", "pp"
    );
    for r in reports {
        for (name, s) in [("deviceinfo", r.deviceinfo), ("applied", r.applied)] {
            let Some(s) = s else { continue };
            let _ = writeln!(
                out,
                "{:<9} {:>4} {:>5} {:<10} {:>8.2} {:>8.2} {:>8.2} {:>8.2} {:>8.2} {:>8.2} {:>4}  {}",
                format!("{:?}{}", r.scenario, if r.secure { "+sec" } else { "" }).to_lowercase(),
                r.controllers,
                r.runs,
                name,
                s.mean,
                s.stdev,
                s.min,
                s.p50,
                s.p99,
                s.max,
                r.ping_pong,
                seed_figure(r.scenario)
            );
        }
    }
    out
}

/// A box plot (min, p25, median, p75, max per series) as a self-contained SVG.
pub fn svg(reports: &[Report]) -> String {
    let series: Vec<(String, Vec<f64>)> = reports
        .iter()
        .flat_map(|r| {
            let label = format!("{:?} n={}", r.scenario, r.controllers).to_lowercase();
            [
                (format!("{label} info"), r.raw.0.clone()),
                (format!("{label} applied"), r.raw.1.clone()),
            ]
        })
        .filter(|(_, v)| !v.is_empty())
        .collect();
    let max = series
        .iter()
        .flat_map(|(_, v)| v.iter().copied())
        .fold(1.0_f64, f64::max);
    let (w, row) = (720.0, 28.0);
    let h = 40.0 + row * series.len() as f64;
    let x = |v: f64| 220.0 + (w - 240.0) * v / max;
    let mut s = format!(
        "<svg xmlns='http://www.w3.org/2000/svg' width='{w}' height='{h}' font-family='monospace' font-size='11'>\n\
         <text x='220' y='14'>handover latency, ms (0 … {max:.1})</text>\n"
    );
    for (i, (label, v)) in series.iter().enumerate() {
        let mut v = v.clone();
        v.sort_by(f64::total_cmp);
        let q = |p: f64| v[((p * (v.len() - 1) as f64).round() as usize).min(v.len() - 1)];
        let y = 30.0 + row * i as f64;
        let _ = writeln!(
            s,
            "<text x='4' y='{:.1}'>{label}</text>\
             <line x1='{:.1}' x2='{:.1}' y1='{:.1}' y2='{:.1}' stroke='black'/>\
             <rect x='{:.1}' y='{:.1}' width='{:.1}' height='16' fill='#9cf' stroke='black'/>\
             <line x1='{:.1}' x2='{:.1}' y1='{:.1}' y2='{:.1}' stroke='red'/>",
            y + 12.0,
            x(q(0.0)),
            x(q(1.0)),
            y + 8.0,
            y + 8.0,
            x(q(0.25)),
            y,
            (x(q(0.75)) - x(q(0.25))).max(1.0),
            x(q(0.5)),
            x(q(0.5)),
            y,
            y + 16.0,
        );
    }
    s.push_str("</svg>\n");
    s
}

/// Writes the JSON objects (one per scenario run) to `path`.
///
/// # Errors
/// The file cannot be written.
pub fn write_json(path: &PathBuf, reports: &[Report]) -> anyhow::Result<()> {
    let text: Vec<String> = reports
        .iter()
        .map(serde_json::to_string)
        .collect::<Result<_, _>>()?;
    std::fs::write(path, text.join("\n") + "\n")?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stats_match_hand_computed_values() {
        let s = Stats::of(&[4.0, 1.0, 3.0, 2.0]).expect("non-empty");
        assert_eq!((s.min, s.max, s.mean), (1.0, 4.0, 2.5));
        assert_eq!(s.p50, 2.0);
        assert_eq!(s.p99, 4.0);
        assert!((s.stdev - 1.290_994).abs() < 1e-6);
        assert_eq!(Stats::of(&[]), None);
    }

    fn out(t: u64, owner: Option<i64>) -> Out {
        Out {
            wall_us: t,
            action: "apply".into(),
            owner,
            throttle: None,
        }
    }

    #[test]
    fn ping_pong_counts_returns_to_the_old_owner_after_the_new_one() {
        let seq = [
            out(0, Some(1)),
            out(10, Some(2)),
            out(20, Some(1)),
            out(30, Some(1)),
            out(40, Some(2)),
            out(50, Some(1)),
        ];
        assert_eq!(count_ping_pong(&seq, 0, Some(1), Some(2)), 2);
        // Old owner's outputs before the new one took over are not ping-pong.
        assert_eq!(count_ping_pong(&seq[..2], 0, Some(1), Some(2)), 0);
        // Outside the window nothing counts.
        assert_eq!(
            count_ping_pong(
                &[out(0, Some(2)), out(2_000_000, Some(1))],
                0,
                Some(1),
                Some(2)
            ),
            0
        );
    }

    #[test]
    fn svg_has_one_box_per_series() {
        let r = Report {
            scenario: Scenario::Graceful,
            controllers: 2,
            runs: 2,
            unit: "ms",
            deviceinfo: None,
            applied: None,
            ping_pong: 0,
            secure: false,
            raw: (vec![1.0, 2.0], vec![3.0, 4.0]),
        };
        assert_eq!(svg(&[r]).matches("<rect").count(), 2);
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

/// `rove bench input`: replays `events` stick values at `rate_hz` and prints the latency
/// summary.
///
/// # Errors
/// As [`input_latency`].
pub fn input_cli(rove: &Path, events: usize, rate_hz: f64) -> anyhow::Result<()> {
    let (s, unmatched) = input_latency(rove, events, rate_hz, &mut |line| eprintln!("  {line}"))?;
    println!(
        "input read → vehicle output (ms), {events} events at {rate_hz} Hz: \
         mean {:.3} stdev {:.3} min {:.3} p50 {:.3} p99 {:.3} max {:.3}; unmatched {unmatched}",
        s.mean, s.stdev, s.min, s.p50, s.p99, s.max
    );
    Ok(())
}
