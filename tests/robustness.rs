//! A vehicle against what no honest peer sends and what no healthy machine does: crafted RTPS
//! packets that claim huge samples, and the whole process stopped (SIGSTOP) and continued. Both
//! broke rustdds 0.15.1 and are fixed by rove's patch of it (`vendor/rustdds/ROVE-PATCH.md`).

use crate::util::*;
use std::process::Command;
use std::time::Duration;

const V: i64 = 100;

/// A field of `/proc/PID/status` in KiB (`VmSize`, `VmHWM`), the process alive.
fn status_kib_of_live(pid: u32, field: &str) -> u64 {
    status_kib(pid, field)
        .unwrap_or_else(|| panic!("no {field} in /proc/{pid}/status (the process died?)"))
}

/// DATA_FRAG submessages, each from an invented participant and claiming a sample of almost
/// 4 GiB, sent to the SPDP reader every participant has (it takes fragments from anyone). Stock
/// rustdds 0.15.1 allocates and zero-fills the claimed size per datagram; patched, a reader
/// reassembles no sample over 1 MiB and commits at most 4 MiB in all. The vehicle's address
/// space is limited to what it uses plus 1 GiB while it is attacked, so that a regression
/// aborts the vehicle (and fails this test) rather than filling the machine's memory.
#[test]
fn crafted_fragments_claiming_4_gib_samples_leave_the_vehicle_driving() {
    let mut rig = Rig::new("datafrag");
    let record = rig.vehicle(V);
    rig.operator(11, "stationary", "laptop", &[V], 1000, "", &[]);
    wait_for_output(&record, Some(11), 0).expect("laptop drives");

    let pid = rig.procs[0].pid();
    limit_address_space("vehicle", pid, 1024 * 1024);
    let before_kib = status_kib_of_live(pid, "VmHWM");

    let out = Command::new("ip")
        .args(["netns", "exec", &rig.ns])
        .arg(rove_testkit::python())
        .arg(rove_testkit::rtps_bomb_script())
        .args(["datafrag", "--count", "64"])
        .output()
        .expect("run rtps_bomb.py");
    let report = String::from_utf8_lossy(&out.stdout).trim().to_string();
    assert!(
        out.status.success() && report.contains("\"sent\""),
        "rtps_bomb.py: {report}{}",
        String::from_utf8_lossy(&out.stderr)
    );

    // Still driving after the datagrams were handled: the laptop's samples keep coming.
    let after_bombs = wall_us();
    wait_for_output(&record, Some(11), after_bombs).expect("the laptop still drives");
    assert!(rig.procs[0].is_running(), "the vehicle died: {report}");
    let grown_kib = status_kib_of_live(pid, "VmHWM").saturating_sub(before_kib);
    eprintln!("{report}: the vehicle's peak RSS grew by {grown_kib} KiB");
    assert!(
        grown_kib < 64 * 1024,
        "the vehicle's peak RSS grew by {grown_kib} KiB under {report}"
    );
}

/// The whole vehicle stopped for 500 ms (SIGSTOP, as a debugger or an overloaded board might)
/// while the laptop streams at 50 Hz, then continued: its DDS threads carry on (stock rustdds
/// 0.15.1 ended both event loops on the EINTR that SIGCONT brings, and the vehicle never heard
/// anything again), none of the samples that queued up in the socket meanwhile is applied as a
/// burst, and the laptop's next fresh sample drives.
#[test]
fn a_vehicle_stopped_and_continued_applies_no_backlog_and_hears_its_owner_again() {
    let mut rig = Rig::new("sigstop");
    let record = rig.vehicle(V);
    rig.operator(11, "stationary", "laptop", &[V], 1000, "", &[]);
    wait_for_output(&record, Some(11), 0).expect("laptop drives");
    let vehicle = &rig.procs[0];

    for round in 0..3 {
        let stopped = wall_us();
        assert!(vehicle.signal("-STOP"), "kill -STOP");
        // The stimulus is a 500 ms stop; nothing is awaited here.
        std::thread::sleep(Duration::from_millis(500));
        assert!(vehicle.signal("-CONT"), "kill -CONT");
        let resumed = wall_us();
        let back = wait_for_output(&record, Some(11), resumed)
            .unwrap_or_else(|e| panic!("round {round}: the laptop never drove again: {e}"));
        eprintln!(
            "round {round}: first apply {:.1} ms after SIGCONT",
            (back.wall_us as f64 - resumed as f64) / 1000.0
        );
        // About 25 samples queued up in the socket. Those sent in the stop's last command
        // timeout (100 ms: 5 at 50 Hz) are still fresh when they arrive, and rustdds, woken
        // with the vehicle, may hand them over one by one: applying them, newest last, is
        // right. Anything older is stale: applied, the backlog would be a burst of about 25.
        let burst = applies_in_burst(&record, stopped, back.wall_us);
        assert!(
            burst.len() <= 8,
            "round {round}: a burst of {} applies after SIGCONT: {burst:?}",
            burst.len()
        );
    }
    // Its DDS is alive both ways: the network still sees it, driven by the laptop.
    rig.device_when("the vehicle seen driven by the laptop", V, |v| {
        v["controller_id"] == 11
    });
}

/// `rove bench chaos`, short, and the ownership contract asserted (docs/design.md, Chaos): after
/// 40 random faults, no wrong owner, no stale output and no failsafe while an operator runs
/// (each judged after the documented grace); 20 s of 10 % UDP loss with at most one lapse of a
/// silent owner and no failsafe;
/// three partitions, each healed operator driving again within 1 s.
///
/// A starved process may truly fall silent for a command timeout on a loaded 2-core machine,
/// so this test runs alone: ignored in the parallel run, and run by `scripts/test` after it.
#[test]
#[ignore = "a timing contract: runs alone, after the other tests (scripts/test runs it)"]
fn the_chaos_bench_holds_the_ownership_contract() {
    rove_testkit::require_tool("nft", "nftables");
    let scratch = Scratch::new("chaos");
    let json = scratch.dir.join("chaos.json");
    let out = Command::new(ROVE)
        .args(["bench", "chaos", "--events", "40", "--interval-ms", "200"])
        .args(["--loss-s", "20", "--loss-pct", "10", "--partition-s", "2"])
        .arg("--json")
        .arg(&json)
        .output()
        .expect("run rove bench chaos");
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{text}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    eprintln!("{text}");
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).expect("the JSON report"))
            .expect("JSON");
    let faults: u64 = (report["faults"].as_object().expect("faults").values())
        .filter_map(serde_json::Value::as_u64)
        .sum();
    assert_eq!(faults, 40, "{report}");
    let counts = &report["counts"];
    for count in ["wrong_owner", "stale", "failsafe_while_live"] {
        assert_eq!(counts[count], 0, "{count}: {text}");
    }
    assert!(report["loss_s"].as_f64() >= Some(20.0), "{report}");
    // Under loss the owner may lapse only when its stream truly fell silent for the command
    // timeout (a change away from an owner heard sooner is a wrong owner, asserted above): five
    // drops in a row at 50 Hz, or four and a late sample, about once in 30 to 100 such phases.
    // Two in one phase would be a stream that loses more than the network does.
    let under_loss = |what: &str| counts[what]["10"].as_u64().unwrap_or(0);
    assert!(under_loss("lapses_under_loss") <= 1, "{text}");
    assert_eq!(under_loss("failsafe_under_loss"), 0, "{text}");
    let recovery = report["recovery_ms"].as_array().expect("recovery_ms");
    assert_eq!(recovery.len(), 3, "{report}");
    assert!(
        recovery
            .iter()
            .all(|r| r.as_f64().is_some_and(|ms| ms < 1000.0)),
        "{text}"
    );
}
