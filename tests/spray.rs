//! Corrupt and hostile datagrams against a driving fleet, unsecured and secured (issue 29: "a
//! live test in CI"). Laptop 11 drives vehicle 100 (sim output) in the rig's namespace while
//! `testkit/rtps_spray.py` sends mutated copies of the fleet's own RTPS datagrams (its own
//! capture, discovery included: bytes flipped, datagrams spliced, 32-bit fields set to extreme
//! values, truncations) to the addresses and ports they went to, at 1000 a second for 20 s.
//! Every process lives, neither grows its peak RSS by 32 MiB, and the laptop drives the vehicle
//! throughout with no gap over 150 ms between outputs.
//!
//! The mutations keep each datagram's RTPS header, so in an unsecured fleet they arrive as the
//! laptop's and the vehicle's own participants speaking: forged sequence numbers in DATA, GAP,
//! HEARTBEAT and ACKNACK included. Under DDS Security (RTPS protection) they fail
//! authentication and are dropped whole.
//!
//! Stock rustdds 0.15 (and rove's patch before issue 29) let fields of a datagram size
//! allocations. Measured here before the fix (2026-11-26), unsecured: the vehicle reached
//! 0.9 GB RSS 1.4 s into the spray and aborted when `RtpsWriterProxy::missing_seqnums` (a
//! HEARTBEAT's range) asked for 1 GiB; the laptop had grown by 118 MiB by then. Secured: passed,
//! +0.1 MiB each. So that a regression aborts the process rather than filling the machine's
//! memory, the vehicle's and the operator's address space is limited to what they use plus
//! [`HEADROOM_KIB`] before the spray. The figures (RSS before and after, the largest gap, what
//! was sent) are printed on stderr:
//! `cargo test -p rove-gateway --test e2e spray:: -- --nocapture`.
//!
//! See: issue 29 ("Corrupt or hostile datagrams never take down a vehicle or an operator").

use crate::util::*;
use serde_json::Value;
use std::io::{BufRead, BufReader, Read};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::{Mutex, PoisonError};
use std::time::{Duration, Instant};

const V: i64 = 100;
const LAPTOP: i64 = 11;

/// How long the capture listens, s: the fleet starts a moment after it opens (its discovery is
/// in the capture), and the laptop streams for the rest.
const CAPTURE_S: u32 = 3;
/// The spray: datagrams a second and for how long, s (the minimum; at this rate stock
/// rustdds took an unsecured vehicle to 12 GB). `ROVE_SPRAY_RATE` and `ROVE_SPRAY_S` override
/// them for a measurement (`ROVE_SPRAY_RATE=0`: the sprayer's full speed); never lower.
const SPRAY_RATE: u32 = 1000;
const SPRAY_S: u32 = 20;
/// The most a full-speed spray may send a second (`--max-datagrams` is this times the seconds):
/// a bound on the loop, above what Python sends on this machine (60 000 to 120 000/s).
const FULL_SPEED_CAP: u32 = 1_000_000;
/// The sprayer's seed: a failure can be replayed datagram for datagram (`ROVE_SPRAY_SEED`
/// overrides it, and `ROVE_SPRAY_MODE` the mutations: `flip`, `splice`, `extreme`, `truncate`).
const SPRAY_SEED: u32 = 29;
/// Peak RSS growth allowed a process over the spray, KiB. A bounded receive path holds some
/// per-remote state and buffers; an unbounded one grew by gigabytes.
const RSS_GROWTH_LIMIT_KIB: u64 = 32 * 1024;
/// Address space granted beyond what a process has mapped when the spray starts, KiB: far more
/// than [`RSS_GROWTH_LIMIT_KIB`], so that the limit only ends a runaway (the allocation fails
/// and the process aborts) instead of the kernel's OOM killer choosing among the machine's
/// processes.
const HEADROOM_KIB: u64 = 1024 * 1024;
/// The largest gap allowed between two outputs of the laptop's 50 Hz stream, µs: 150 ms is one
/// and a half command timeouts (100 ms), so a gap this long means the vehicle either lapsed to
/// the failsafe or stalled.
const MAX_GAP_US: u64 = 150_000;
/// How often the test samples the processes' RSS and liveness during the spray.
const SAMPLE_EVERY: Duration = Duration::from_millis(100);

/// Each test keeps two DDS processes and the sprayer busy (and on code that regresses, a
/// runaway): one at a time, so that neither measures the other's load.
static ONE_AT_A_TIME: Mutex<()> = Mutex::new(());

#[test]
fn an_unsecured_fleet_sprayed_with_its_own_datagrams_mutated_keeps_driving() {
    spray_a_driving_fleet("spray-unsecured", false);
}

#[test]
fn a_secured_fleet_sprayed_with_its_own_datagrams_mutated_keeps_driving() {
    spray_a_driving_fleet("spray-secured", true);
}

/// `rtps_spray.py ARGS` in the rig's namespace, its stdout piped.
pub(crate) fn sprayer(rig: &Rig, args: &[&str]) -> Child {
    Command::new("ip")
        .args(["netns", "exec", &rig.ns])
        .arg(rove_testkit::python())
        .arg(rove_testkit::rtps_spray_script())
        .args(args)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("run rtps_spray.py")
}

/// Waits (at most [`PATIENCE`]) for a capture started by [`sprayer`] to end; its last stdout
/// line (read from `stdout`) as JSON.
///
/// # Panics
/// It does not end in time (it is killed) or fails, or its last line is not JSON.
pub(crate) fn summary(mut child: Child, mut stdout: BufReader<std::process::ChildStdout>) -> Value {
    let deadline = Instant::now() + PATIENCE;
    let status = loop {
        if let Some(status) = child.try_wait().expect("wait for rtps_spray.py") {
            break status;
        }
        if Instant::now() > deadline {
            let _ = child.kill();
            let _ = child.wait();
            panic!("rtps_spray.py did not end within {PATIENCE:?} of its own bound");
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    let mut text = String::new();
    (stdout.read_to_string(&mut text)).expect("read rtps_spray.py's output");
    let mut err = String::new();
    let _ = child.stderr.take().expect("piped").read_to_string(&mut err);
    assert!(status.success(), "rtps_spray.py failed: {text}{err}");
    let last = text.lines().last().unwrap_or_default();
    serde_json::from_str(last).unwrap_or_else(|e| panic!("rtps_spray.py said {text:?}: {e}"))
}

/// One process's memory over the spray, KiB.
#[derive(Debug)]
struct Memory {
    name: &'static str,
    pid: u32,
    hwm_before: u64,
    /// The last VmRSS read while it lived, and when (s into the spray).
    rss_last: u64,
    rss_last_s: f64,
    /// The process's end, s into the spray, if it died.
    died_s: Option<f64>,
}

impl Memory {
    fn new(name: &'static str, pid: u32) -> Memory {
        let hwm =
            status_kib(pid, "VmHWM").unwrap_or_else(|| panic!("{name} died before the spray"));
        let rss = status_kib(pid, "VmRSS").unwrap_or(0);
        Memory {
            name,
            pid,
            hwm_before: hwm,
            rss_last: rss,
            rss_last_s: 0.0,
            died_s: None,
        }
    }

    fn sample(&mut self, at_s: f64) {
        match status_kib(self.pid, "VmRSS") {
            Some(rss) => {
                self.rss_last = rss;
                self.rss_last_s = at_s;
            }
            None if self.died_s.is_none() => self.died_s = Some(at_s),
            None => {}
        }
    }

    /// Peak RSS growth over the spray, KiB (`None`: the process is gone).
    fn growth(&self) -> Option<u64> {
        Some(status_kib(self.pid, "VmHWM")?.saturating_sub(self.hwm_before))
    }

    fn describe(&self) -> String {
        let growth = match self.growth() {
            Some(g) => format!(
                "peak RSS {} → {} KiB (+{g} KiB)",
                self.hwm_before,
                self.hwm_before + g
            ),
            None => format!(
                "DIED {:.1} s into the spray; peak RSS before {} KiB, last RSS read {} KiB at \
                 {:.1} s ({:.0} MiB/s since the start)",
                self.died_s.unwrap_or(f64::NAN),
                self.hwm_before,
                self.rss_last,
                self.rss_last_s,
                (self.rss_last.saturating_sub(self.hwm_before) as f64 / 1024.0)
                    / self.rss_last_s.max(0.1)
            ),
        };
        format!("{} (pid {}): {growth}", self.name, self.pid)
    }
}

/// `var` as a number if set (it must parse), else `default`.
fn setting(var: &str, default: u32) -> u32 {
    std::env::var(var).map_or(default, |v| {
        v.parse()
            .unwrap_or_else(|e| panic!("{var}={v:?} is not a number: {e}"))
    })
}

/// Stops the sprayer early (SIGTERM: it still prints what it sent), at most [`PATIENCE`] later
/// by SIGKILL.
fn stop_early(sprayer: &mut Child) {
    let _ = Command::new("kill")
        .args(["-TERM", &sprayer.id().to_string()])
        .status();
    let deadline = Instant::now() + PATIENCE;
    while matches!(sprayer.try_wait(), Ok(None)) {
        if Instant::now() > deadline {
            let _ = sprayer.kill();
            let _ = sprayer.wait();
            return;
        }
        std::thread::sleep(Duration::from_millis(10));
    }
}

/// What the vehicle's record says about `[from_us, to_us]`: outputs not from the laptop, the
/// largest gap between consecutive outputs (the window's ends count as outputs' times only
/// through the outputs around them) and how many outputs.
fn outputs_between(record: &Path, from_us: u64, to_us: u64) -> (Vec<String>, u64, usize) {
    let all = records(record);
    // The last output before the window and the first after it bound its first and last gap.
    let before = all.iter().rev().find(|o| o.wall_us < from_us);
    let after = all.iter().find(|o| o.wall_us > to_us);
    let inside: Vec<_> = (all.iter())
        .filter(|o| (from_us..=to_us).contains(&o.wall_us))
        .collect();
    let wrong: Vec<String> = (inside.iter())
        .filter(|o| o.action != "apply" || o.owner != Some(LAPTOP))
        .map(|o| format!("{o:?}"))
        .collect();
    let times: Vec<u64> = (before.iter().chain(&inside).chain(after.iter()))
        .map(|o| o.wall_us)
        .collect();
    let max_gap = times.windows(2).map(|w| w[1] - w[0]).max().unwrap_or(0);
    (wrong, max_gap, inside.len())
}

/// Laptop 11 driving vehicle 100 (sim output) in `rig`, their RTPS traffic captured from before
/// they start (discovery included): the vehicle's output record and the capture.
pub(crate) fn captured_driving_fleet(rig: &mut Rig, secured: bool) -> (PathBuf, PathBuf) {
    captured_driving_fleet_with(rig, secured, "")
}

/// As [`captured_driving_fleet`], with `extra_toml` in both devices' configs.
pub(crate) fn captured_driving_fleet_with(
    rig: &mut Rig,
    secured: bool,
    extra_toml: &str,
) -> (PathBuf, PathBuf) {
    let fleet: Option<PathBuf> =
        secured.then(|| rig.fleet(&[V, LAPTOP]).expect("rove keys for 100 and 11"));
    let security = |id| {
        let toml = rove_tools::harness::security_toml(fleet.as_deref(), id);
        format!("{toml}{extra_toml}")
    };

    // The capture listens before the fleet starts, so that it holds discovery too.
    let capture = rig.dir.join("fleet.cap");
    let capture_arg = capture.to_str().expect("utf-8 path").to_string();
    let mut capturing = sprayer(
        rig,
        &[
            "capture",
            "--seconds",
            &CAPTURE_S.to_string(),
            "--out",
            &capture_arg,
        ],
    );
    let mut capture_out = BufReader::new(capturing.stdout.take().expect("piped"));
    let mut first = String::new();
    capture_out.read_line(&mut first).expect("read the capture");
    assert!(
        first.contains("listening"),
        "rtps_spray.py capture: {first:?}"
    );

    let record = laptop_drives_sim(rig, V, &security(V), &security(LAPTOP));
    let captured = summary(capturing, capture_out);
    assert!(
        captured["captured"].as_u64().unwrap_or(0) > 0,
        "nothing captured: {captured}"
    );
    eprintln!("capture: {captured}");
    (record, capture)
}

fn spray_a_driving_fleet(test: &str, secured: bool) {
    let _turn = ONE_AT_A_TIME.lock().unwrap_or_else(PoisonError::into_inner);
    let mut rig = Rig::new(test);
    let (record, capture) = captured_driving_fleet(&mut rig, secured);
    let capture_arg = capture.to_str().expect("utf-8 path").to_string();

    let (vehicle_pid, laptop_pid) = (rig.procs[0].pid(), rig.procs[1].pid());
    limit_address_space("vehicle", vehicle_pid, HEADROOM_KIB);
    limit_address_space("laptop", laptop_pid, HEADROOM_KIB);
    let mut memory = [
        Memory::new("vehicle", vehicle_pid),
        Memory::new("laptop", laptop_pid),
    ];

    let rate = setting("ROVE_SPRAY_RATE", SPRAY_RATE);
    let seconds = setting("ROVE_SPRAY_S", SPRAY_S).max(SPRAY_S);
    assert!(
        rate == 0 || rate >= SPRAY_RATE,
        "ROVE_SPRAY_RATE={rate}: at least {SPRAY_RATE}, or 0 for full speed"
    );
    let max =
        (u64::from(if rate == 0 { FULL_SPEED_CAP } else { rate }) * u64::from(seconds)).to_string();
    let mode = std::env::var("ROVE_SPRAY_MODE").unwrap_or_else(|_| "mixed".into());
    let spray_start = wall_us();
    let started = Instant::now();
    let mut spraying = sprayer(
        &rig,
        &[
            "spray",
            "--capture",
            &capture_arg,
            "--rate",
            &rate.to_string(),
            "--seconds",
            &seconds.to_string(),
            "--mode",
            &mode,
            "--seed",
            &setting("ROVE_SPRAY_SEED", SPRAY_SEED).to_string(),
            "--max-datagrams",
            &max,
        ],
    );
    // Sample until the sprayer ends (its own bound is `seconds`), or a process dies: then the
    // spray is stopped at once, the verdict is in.
    let patience = Duration::from_secs(u64::from(seconds)) + PATIENCE;
    loop {
        let at_s = started.elapsed().as_secs_f64();
        for m in &mut memory {
            m.sample(at_s);
        }
        let dead = !(rig.procs[0].is_running() && rig.procs[1].is_running());
        if spraying.try_wait().expect("wait for the sprayer").is_some() {
            break;
        }
        if dead || started.elapsed() > patience {
            stop_early(&mut spraying);
            break;
        }
        std::thread::sleep(SAMPLE_EVERY);
    }
    let spray_end = wall_us();
    let mut sprayed = String::new();
    let _ = spraying
        .stdout
        .take()
        .expect("piped")
        .read_to_string(&mut sprayed);
    let sprayed: Value =
        serde_json::from_str(sprayed.trim()).unwrap_or(Value::String(sprayed.clone()));

    let alive = [rig.procs[0].is_running(), rig.procs[1].is_running()];
    // The first output after the spray ends the window's last gap; a vehicle that no longer
    // hears its owner fails here too.
    let after = alive[0]
        .then(|| wait_for_output(&record, Some(LAPTOP), spray_end).ok())
        .flatten();
    let (wrong, max_gap_us, outputs) = outputs_between(&record, spray_start, spray_end);
    let report = format!(
        "{} fleet; sprayed {sprayed}; {}; {}; {outputs} outputs during the spray, largest gap \
         {:.1} ms, {} not from the laptop; the laptop drives after it: {}",
        if secured { "secured" } else { "unsecured" },
        memory[0].describe(),
        memory[1].describe(),
        max_gap_us as f64 / 1000.0,
        wrong.len(),
        after.is_some(),
    );
    eprintln!("{report}");

    assert!(
        alive[0] && alive[1],
        "a process died under the spray: {report}"
    );
    let sent = sprayed["sent"].as_u64().unwrap_or(0);
    assert!(
        sent >= u64::from(SPRAY_RATE * seconds) * 99 / 100,
        "the sprayer fell short of {SPRAY_RATE}/s for {seconds} s: {report}"
    );
    for m in &memory {
        let growth = m.growth().unwrap_or(u64::MAX);
        assert!(
            growth < RSS_GROWTH_LIMIT_KIB,
            "the {}'s peak RSS grew by {growth} KiB: {report}",
            m.name
        );
    }
    assert!(
        wrong.is_empty(),
        "outputs not from the laptop: {wrong:?}; {report}"
    );
    assert!(
        max_gap_us <= MAX_GAP_US,
        "a gap of {:.1} ms between outputs: {report}",
        max_gap_us as f64 / 1000.0
    );
    assert!(after.is_some(), "the laptop no longer drives: {report}");
}

/// `rtps_spray.py forge --kind KIND ARGS` against the capture, to its end; its JSON line.
fn forge(rig: &Rig, capture: &Path, kind: &str, args: &[&str]) -> Value {
    let capture = capture.to_str().expect("utf-8 path");
    let mut all = vec!["forge", "--capture", capture, "--kind", kind];
    all.extend_from_slice(args);
    let mut child = sprayer(rig, &all);
    let out = BufReader::new(child.stdout.take().expect("piped"));
    let forged = summary(child, out);
    assert!(
        forged["forged"].as_u64().unwrap_or(0) > 0,
        "nothing forged: {forged}"
    );
    forged
}

/// How long the test watches for a forged announcement's effect after the last one, µs: more
/// than rustdds's participant cleanup period (2 s), the tick at which a lease believed to have
/// run out drops the participant, and than the grace a goodbye waits (1 s).
const WATCH_US: u64 = 5_000_000;

/// A live peer's own SPDP announcement, forged with its lease set to 0 or as a goodbye, under
/// its own or a new sequence number, must not drop that peer (ROVE-PATCH.md §16). A corrupt copy
/// of an announcement is such a forgery, and they made the random spray fail now and then: the
/// vehicle dropped the laptop's participant with its writers, went to the failsafe, and never
/// matched the laptop again. Forged here for both participants, three times each, while the
/// laptop streams, and it drives throughout. Before §16 the new sequence numbers did it: 0 s of
/// lease believed, a goodbye taken at once.
#[test]
fn a_live_peers_announcement_forged_with_lease_0_or_as_a_goodbye_changes_nothing() {
    forged_announcements_change_nothing("forged-spdp", false);
}

/// The same, secured: an authenticated participant's announcements on the unsecured topic, a
/// lease of 0 or a goodbye, are refused (secured discovery takes a goodbye only on the secured
/// topic), so the laptop keeps driving.
#[cfg(feature = "security")]
#[test]
fn a_live_secured_peers_announcement_forged_with_lease_0_or_as_a_goodbye_changes_nothing() {
    forged_announcements_change_nothing("forged-spdp-secured", true);
}

/// Forges both participants' announcements with lease 0 and as goodbyes, under their own and
/// new sequence numbers, while the laptop drives: the laptop keeps driving.
fn forged_announcements_change_nothing(name: &str, secured: bool) {
    let _turn = ONE_AT_A_TIME.lock().unwrap_or_else(PoisonError::into_inner);
    let mut rig = Rig::new(name);
    let (record, capture) = captured_driving_fleet(&mut rig, secured);
    for (kind, sn) in [
        ("lease0", "same"),
        ("lease0", "new"),
        ("goodbye", "same"),
        ("goodbye", "new"),
    ] {
        let start = wall_us();
        let args = ["--sn", sn, "--count", "3", "--every", "0.5"];
        let forged = forge(&rig, &capture, kind, &args);
        let participants = forged["participants"].as_array().map_or(0, Vec::len);
        assert!(participants >= 2, "forged for fewer than both: {forged}");
        let watched = wall_us() + WATCH_US;
        let _ = wait_for_output(&record, Some(LAPTOP), watched);
        let (wrong, max_gap_us, outputs) = outputs_between(&record, start, watched);
        eprintln!(
            "{kind} under the {sn} sequence number: {forged}; {outputs} outputs in {:.1} s, \
             largest gap {:.1} ms",
            (watched - start) as f64 / 1e6,
            max_gap_us as f64 / 1000.0
        );
        assert!(
            wrong.is_empty(),
            "after a forged {kind} ({sn} sequence number), outputs not from the laptop: {wrong:?}"
        );
        assert!(
            max_gap_us <= MAX_GAP_US,
            "after a forged {kind} ({sn} sequence number), a gap of {:.1} ms between outputs",
            max_gap_us as f64 / 1000.0
        );
    }
}

/// How long a participant may take to announce itself again, µs: rustdds's SPDP period is 10 s.
const ANNOUNCEMENT_US: u64 = 10_000_000;

/// A goodbye from a peer that then stays silent is believed, forged or not: here the laptop is
/// stopped (SIGSTOP, as an overloaded board might be) when its goodbye is forged, and the vehicle
/// drops it. Continued, the laptop streams again, and when it next announces itself its
/// endpoints come back (ROVE-PATCH.md §16) and it drives again. Before, they never did: the
/// vehicle stayed in failsafe while its operator lived and streamed.
#[test]
fn an_operator_dropped_on_a_forged_goodbye_drives_again_at_its_next_announcement() {
    let _turn = ONE_AT_A_TIME.lock().unwrap_or_else(PoisonError::into_inner);
    let mut rig = Rig::new("forged-goodbye");
    let (record, capture) = captured_driving_fleet(&mut rig, false);
    assert!(rig.procs[1].signal("-STOP"), "kill -STOP the laptop");
    let forged = forge(&rig, &capture, "goodbye", &["--sn", "new"]);
    eventually(
        "the vehicle believes the stopped laptop's forged goodbye",
        || {
            let log = rig.log_of("vehicle-100");
            match log.contains("participant of a command writer lost") {
                true => Ok(()),
                false => Err(format!("forged {forged}")),
            }
        },
    );
    let continued = wall_us();
    assert!(rig.procs[1].signal("-CONT"), "kill -CONT the laptop");
    let patience = Duration::from_micros(ANNOUNCEMENT_US) + PATIENCE;
    let again = rove_testkit::eventually_within(patience, "the laptop drives again", || {
        wait_for_output(&record, Some(LAPTOP), continued).map_err(|e| format!("{forged}: {e}"))
    });
    eprintln!(
        "goodbye (new sequence number) forged while the laptop was stopped: {forged}; the laptop \
         drove again {:.2} s after it was continued",
        (again.wall_us - continued) as f64 / 1e6
    );
    let log = rig.log_of("vehicle-100");
    assert!(
        log.contains("found again"),
        "no restored endpoints in the vehicle's log: {log}"
    );
}
