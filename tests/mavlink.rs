//! End to end with an autopilot: operator process → vehicle process with the MAVLink
//! adapter → the pymavlink autopilot of `testkit/fake_autopilot.py`, all inside a
//! network namespace of the test's own (DDS on its loopback, MAVLink on UDP loopback).
//!
//! Needs Python with `pymavlink` (`scripts/test` installs it; missing, the test fails at once).

use crate::util::{FakeAutopilot, PATIENCE, Rig, wait_for_output, wall_us};
use serde_json::Value;

const V: i64 = 100;
/// The vehicle's MAVLink mode command timeout in these tests.
const COMMAND_TIMEOUT_MS: u64 = 300;

/// The fake autopilot on UDP `port`, in the rig's namespace.
fn autopilot(rig: &Rig, port: u16) -> FakeAutopilot {
    rig.autopilot(&["--connection", &format!("udpin:127.0.0.1:{port}")])
}

fn raw(e: &Value) -> Vec<u64> {
    e["raw"]
        .as_array()
        .map(|a| a.iter().filter_map(Value::as_u64).collect())
        .unwrap_or_default()
}

fn wall(e: &Value) -> u64 {
    e["wall_us"].as_u64().unwrap_or(0)
}

fn modified(path: &std::path::Path) -> Option<std::time::SystemTime> {
    std::fs::metadata(path).and_then(|m| m.modified()).ok()
}

fn mavlink_output(port: u16) -> String {
    format!(
        "[output]\nadapter = \"mavlink\"\nconnection = \"udpout:127.0.0.1:{port}\"\n\
         command_timeout_ms = {COMMAND_TIMEOUT_MS}\n"
    )
}

#[test]
fn an_operator_drives_an_autopilot_and_losing_it_releases_and_holds() {
    let mut rig = Rig::new("mavlink-e2e");
    let ap = autopilot(&rig, 14550);
    let record = rig.vehicle_with_output(V, &mavlink_output(14550));
    ap.wait_for("GCS heartbeat from the vehicle", |e| {
        e["event"] == "heartbeat" && e["src"] == 255 && e["comp"] == 190
    });

    // Full throttle, steering half right: ch3 2000, ch1 1750; MANUAL commanded.
    let op = rig.operator(11, "mobile", "phone", &[V], 32767, "roll = 16384\n", &[]);
    wait_for_output(&record, Some(11), 0).expect("operator drives");
    let driven = ap.wait_for("override with the operator's sticks", |e| {
        e["event"] == "rc_override" && raw(e).first() == Some(&1750)
    });
    let r = raw(&driven);
    assert_eq!((r[0], r[2]), (1750, 2000), "{driven}");
    assert!(
        r[3..8].iter().all(|&v| v == 65535),
        "unmapped ch4-8 ignored: {r:?}"
    );
    assert_eq!(driven["accepted"], true);
    ap.wait_for("MANUAL", |e| {
        e["event"] == "set_mode" && e["custom_mode"] == 0
    });

    // The operator crashes: after the 100 ms command timeout the vehicle releases the channels
    // and commands HOLD.
    let crash = wall_us();
    rig.procs[op].crash();
    let release = ap.wait_for("release", |e| {
        e["event"] == "rc_override" && wall(e) > crash && raw(e).first() == Some(&0)
    });
    let hold = ap.wait_for("HOLD", |e| {
        e["event"] == "set_mode" && e["custom_mode"] == 4 && wall(e) > crash
    });
    let to_release_ms = (wall(&release) - crash) as f64 / 1000.0;
    let to_hold_ms = (wall(&hold) - crash) as f64 / 1000.0;
    eprintln!("owner crash → release {to_release_ms:.1} ms, → HOLD command {to_hold_ms:.1} ms");
    // The owner timeout (100 ms) plus one command timeout bounds both, with slack for a busy
    // machine's process scheduling.
    let bound = 100.0 + COMMAND_TIMEOUT_MS as f64 + 200.0;
    assert!(
        to_release_ms < bound && to_hold_ms < bound,
        "{to_release_ms} / {to_hold_ms} ms"
    );
    assert_eq!(
        release["active"],
        serde_json::json!({}),
        "no channel left overridden"
    );
}

/// How a vehicle reaches its autopilot, each the way ArduPilot behaves on it
/// (`testkit/fake_autopilot.py`; ../shared/notes/ardupilot.md).
#[derive(Debug, Clone, Copy)]
enum Transport {
    /// The vehicle listens (`udpin:`); the autopilot is a UDP client that speaks first, so its
    /// address is known only from its first datagram.
    UdpIn,
    /// The vehicle sends to the autopilot's port (`udpout:`).
    UdpOut,
    /// The autopilot is a TCP server that drops a closed client's unread bytes.
    Tcp,
    /// A serial line (a pty pair).
    Serial,
}

/// An autopilot on `transport` in the rig's namespace, and the vehicle's `connection`.
struct Wired {
    ap: FakeAutopilot,
    connection: String,
    _pty: Option<rove_testkit::PtyPair>,
}

fn wire(rig: &Rig, transport: Transport, extra: &[&str]) -> Wired {
    let pty = matches!(transport, Transport::Serial).then(rove_testkit::PtyPair::start);
    let (ap, connection) = match (transport, &pty) {
        (Transport::UdpIn, _) => (
            "udpout:127.0.0.1:14550".into(),
            "udpin:127.0.0.1:14550".into(),
        ),
        (Transport::UdpOut, _) => (
            "udpin:127.0.0.1:14551".into(),
            "udpout:127.0.0.1:14551".into(),
        ),
        (Transport::Tcp, _) => (
            "tcpin:127.0.0.1:5760".into(),
            "tcpout:127.0.0.1:5760".into(),
        ),
        (Transport::Serial, Some(p)) => (
            p.a.display().to_string(),
            format!("serial:{}:115200", p.b.display()),
        ),
        (Transport::Serial, None) => unreachable!("a serial link has its pty pair"),
    };
    let mut args = vec!["--connection", &ap, "--baud", "115200"];
    args.extend_from_slice(extra);
    Wired {
        ap: rig.autopilot(&args),
        connection,
        _pty: pty,
    }
}

/// A count from the environment (to repeat a measurement), else `default`.
fn runs(var: &str, default: usize) -> usize {
    std::env::var(var)
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

/// SIGTERM of a driven vehicle: release and the safe mode, and the vehicle closes the link only
/// once the autopilot confirmed it (issue 30: ArduPilot drops what a TCP client wrote just
/// before closing, so HOLD took effect in 2 of 7 stops). `ROVE_STOP_RUNS` stops (default 2),
/// the operator driving the restarted vehicle again between them.
fn stopping_a_driven_vehicle_leaves_the_autopilot_in_the_safe_mode(transport: Transport) {
    let mut rig = Rig::new(&format!("mavlink-stop-{transport:?}"));
    // The transports ArduPilot was measured on get its HEARTBEAT at once on a mode change; the
    // others the slower model (the new mode only at the next beat), so both are covered.
    let fast = matches!(transport, Transport::UdpIn | Transport::Tcp);
    let wired = wire(
        &rig,
        transport,
        if fast { &["--mode-heartbeat"] } else { &[] },
    );
    let ap = &wired.ap;
    let output = format!(
        "[output]\nadapter = \"mavlink\"\nconnection = \"{}\"\n",
        wired.connection
    );
    rig.operator(11, "mobile", "phone", &[V], 20000, "", &[]);
    let mut outcomes = Vec::new();
    for run in 0..runs("ROVE_STOP_RUNS", 2) {
        let started = wall_us();
        let record = rig.vehicle_with_output(V, &output);
        let vehicle = rig.procs.len() - 1;
        wait_for_output(&record, Some(11), started).expect("operator drives");
        ap.wait_for("MANUAL taken", |e| {
            e["event"] == "set_mode" && e["custom_mode"] == 0 && wall(e) > started
        });
        ap.wait_for("driving", |e| {
            e["event"] == "rc_override" && raw(e).get(2) == Some(&1805) && wall(e) > started
        });
        let stop = wall_us();
        rig.procs[vehicle].terminate();
        let status = rig.procs[vehicle].wait_exit(PATIENCE);
        let exited = wall_us();
        assert!(
            status.is_some_and(|s| s.success()),
            "run {run}: vehicle exits cleanly: {status:?}"
        );
        // Read once the vehicle is gone: an answer recorded by then was read by the autopilot
        // while the vehicle still held the link open.
        let after: Vec<Value> = ap.events().into_iter().filter(|e| wall(e) > stop).collect();
        let hold = after
            .iter()
            .find(|e| e["event"] == "set_mode" && e["custom_mode"] == 4 && e["answered"] == true);
        let release = after
            .iter()
            .find(|e| e["event"] == "rc_override" && raw(e).first() == Some(&0));
        assert!(
            hold.is_some() && release.is_some(),
            "run {run}: release and HOLD read by the autopilot before the vehicle let go: \
             {after:#?}"
        );
        let hold_ms = hold.map_or(0.0, |h| (wall(h) - stop) as f64 / 1000.0);
        outcomes.push(format!(
            "HOLD {hold_ms:.1} ms, exit {:.1} ms",
            (exited - stop) as f64 / 1000.0
        ));
    }
    eprintln!("{transport:?}: SIGTERM → HOLD answered: {outcomes:?}");
}

#[test]
fn stopping_over_udpin_leaves_the_autopilot_in_the_safe_mode() {
    stopping_a_driven_vehicle_leaves_the_autopilot_in_the_safe_mode(Transport::UdpIn);
}

#[test]
fn stopping_over_udpout_leaves_the_autopilot_in_the_safe_mode() {
    stopping_a_driven_vehicle_leaves_the_autopilot_in_the_safe_mode(Transport::UdpOut);
}

#[test]
fn stopping_over_tcp_leaves_the_autopilot_in_the_safe_mode() {
    stopping_a_driven_vehicle_leaves_the_autopilot_in_the_safe_mode(Transport::Tcp);
}

#[test]
fn stopping_over_serial_leaves_the_autopilot_in_the_safe_mode() {
    stopping_a_driven_vehicle_leaves_the_autopilot_in_the_safe_mode(Transport::Serial);
}

/// `rove failsafe` after a `kill -9` of a driven vehicle, `ROVE_FAILSAFE_RUNS` times (default
/// 3): release and HOLD, confirmed, from what the vehicle learned, without waiting for the
/// autopilot. Its HEARTBEAT comes every 5 s here (ArduPilot: 1 s) so that a failsafe that
/// waits for one is seen to (it takes seconds; one that does not, milliseconds); the link
/// timeout is raised to match. Issue 30: on udpin with `target_system` it sent nothing at all.
fn rove_failsafe_after_a_kill_is_immediate(transport: Transport, target_system: bool) {
    let mut rig = Rig::new(&format!("mavlink-failsafe-{transport:?}-{target_system}"));
    // ROVE_FAILSAFE_HEARTBEAT_HZ=1 measures at ArduPilot's rate (the assertion then says less).
    let hz = std::env::var("ROVE_FAILSAFE_HEARTBEAT_HZ").unwrap_or_else(|_| "0.2".into());
    // With `target_system`, the autopilot also beats at once on a mode change (ArduPilot does):
    // the failsafe's summary then comes from that HEARTBEAT, else from the COMMAND_ACK alone.
    let mut args = vec!["--heartbeat-hz", &hz];
    if target_system {
        args.push("--mode-heartbeat");
    }
    let wired = wire(&rig, transport, &args);
    let ap = &wired.ap;
    let target = if target_system {
        "target_system = 1\n"
    } else {
        ""
    };
    let output = format!(
        "[output]\nadapter = \"mavlink\"\nconnection = \"{}\"\nlink_timeout_ms = 10000\n{target}",
        wired.connection
    );
    let record = rig.vehicle_with_output(V, &output);
    rig.operator(11, "mobile", "phone", &[V], 20000, "", &[]);
    wait_for_output(&record, Some(11), 0).expect("operator drives");
    ap.wait_for("driving", |e| {
        e["event"] == "rc_override" && raw(e).get(2) == Some(&1805)
    });
    // The autopilot starts in HOLD; the failsafe's HOLD is a change only once the vehicle's
    // MANUAL has landed (it may still be on its way while the first overrides arrive).
    ap.wait_for("the autopilot in MANUAL", |e| {
        e["event"] == "set_mode" && e["custom_mode"] == 0 && e["answered"] == true
    });
    let name = format!("vehicle-{V}");
    crate::util::eventually("the vehicle heard the autopilot", || {
        match rig.log_of(&name).contains("mavlink: autopilot found") {
            true => Ok(()),
            false => Err("not yet"),
        }
    });
    // The vehicle's keeper writes what it learned on a thread of its own, soon after.
    let memory = rig.runtime_dir().join(format!("vehicle-{V}-mavlink"));
    crate::util::eventually("the vehicle kept what it learned", || {
        std::fs::read_to_string(&memory)
            .ok()
            .filter(|t| t.contains("system=1"))
            .map(|_| ())
            .ok_or("not yet")
    });
    rig.procs[0].crash();
    let kept = (std::fs::read(&memory).ok(), modified(&memory));
    let config = rig.dir.join(format!("vehicle-{V}.toml"));
    let mut times = Vec::new();
    for run in 0..runs("ROVE_FAILSAFE_RUNS", 3) {
        let start = wall_us();
        let t = std::time::Instant::now();
        let out = rig
            .command(&["failsafe", "-c", config.to_str().expect("utf-8 path")])
            .output()
            .expect("run rove failsafe");
        let took = t.elapsed().as_secs_f64() * 1000.0;
        let said = String::from_utf8_lossy(&out.stdout);
        assert!(
            out.status.success(),
            "run {run}: {said}{}",
            String::from_utf8_lossy(&out.stderr)
        );
        // Issue 50: an acknowledged HOLD is an autopilot heard, HEARTBEAT or not.
        assert!(
            said.contains("HOLD") && !said.contains("no autopilot heard"),
            "run {run}: {said}"
        );
        // The autopilot logs an answered SET_MODE after it answered, so its record may lag
        // `rove failsafe`'s exit: waited for, not read once (seen under a loaded machine).
        crate::util::eventually(&format!("run {run}: release and HOLD"), || {
            let after: Vec<Value> = (ap.events().into_iter())
                .filter(|e| wall(e) > start)
                .collect();
            let released =
                (after.iter()).any(|e| e["event"] == "rc_override" && raw(e).first() == Some(&0));
            let held = after.iter().any(|e| {
                e["event"] == "set_mode" && e["custom_mode"] == 4 && e["answered"] == true
            });
            (released && held)
                .then_some(())
                .ok_or(format!("{after:#?}"))
        });
        times.push(took);
        if run == 0 {
            eprintln!(
                "{transport:?} target_system={target_system}: {}",
                said.trim()
            );
        }
    }
    // Issue 50: `rove failsafe` reads the vehicle's memory file and leaves it, and the
    // directory, as they were (it rewrote it and left `vehicle-100-mavlink.tmp` behind).
    let mut listing: Vec<String> = std::fs::read_dir(rig.runtime_dir())
        .expect("the runtime directory")
        .filter_map(|e| e.ok().map(|e| e.file_name().to_string_lossy().into_owned()))
        .collect();
    listing.sort();
    assert_eq!(listing, [format!("vehicle-{V}-mavlink")]);
    assert_eq!(
        (std::fs::read(&memory).ok(), modified(&memory)),
        kept,
        "not rewritten"
    );
    eprintln!(
        "{transport:?} target_system={target_system}: rove failsafe, ms: {times:.1?}; runtime directory after: {listing:?}"
    );
    assert!(
        times.iter().all(|&ms| ms < 1000.0),
        "no run waited for the autopilot's HEARTBEAT (5 s apart): {times:.1?} ms"
    );
}

#[test]
fn rove_failsafe_over_udpin_with_target_system_is_immediate() {
    rove_failsafe_after_a_kill_is_immediate(Transport::UdpIn, true);
}

#[test]
fn rove_failsafe_over_udpin_is_immediate() {
    rove_failsafe_after_a_kill_is_immediate(Transport::UdpIn, false);
}

#[test]
fn rove_failsafe_over_udpout_is_immediate() {
    rove_failsafe_after_a_kill_is_immediate(Transport::UdpOut, false);
}

#[test]
fn rove_failsafe_over_tcp_is_immediate() {
    rove_failsafe_after_a_kill_is_immediate(Transport::Tcp, false);
}

#[test]
fn rove_failsafe_over_serial_is_immediate() {
    rove_failsafe_after_a_kill_is_immediate(Transport::Serial, false);
}

#[test]
fn rove_failsafe_over_udpout_with_target_system_is_immediate() {
    rove_failsafe_after_a_kill_is_immediate(Transport::UdpOut, true);
}

#[test]
fn rove_failsafe_over_tcp_with_target_system_is_immediate() {
    rove_failsafe_after_a_kill_is_immediate(Transport::Tcp, true);
}

#[test]
fn rove_failsafe_over_serial_with_target_system_is_immediate() {
    rove_failsafe_after_a_kill_is_immediate(Transport::Serial, true);
}

/// `rove failsafe` with nothing to go on (no vehicle ran, no autopilot answers) says what was
/// missing and fails, within the link timeout. MAVLink only, on the host's loopback: it
/// listens, and nothing is sent.
#[test]
fn rove_failsafe_with_nobody_to_address_says_so() {
    let scratch = crate::util::Scratch::new("mavlink-failsafe-nobody");
    let port = std::net::UdpSocket::bind("127.0.0.1:0")
        .and_then(|s| s.local_addr())
        .expect("a free port")
        .port();
    let config = scratch.dir.join("vehicle.toml");
    let output = format!(
        "[output]\nadapter = \"mavlink\"\nconnection = \"udpin:127.0.0.1:{port}\"\n\
         target_system = 1\nlink_timeout_ms = 500\n"
    );
    std::fs::write(&config, crate::util::vehicle_toml(V, &output)).expect("config");
    let out = std::process::Command::new(crate::util::ROVE)
        .args(["failsafe", "-c"])
        .arg(&config)
        .env("RUNTIME_DIRECTORY", &scratch.dir)
        .output()
        .expect("run rove failsafe");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{stderr}");
    for says in [
        "nothing sent",
        "no datagram from the autopilot",
        "no running vehicle had written",
    ] {
        assert!(stderr.contains(says), "{says:?} in: {stderr}");
    }
}

/// Regression (rove against ArduPilot SITL): a vehicle that starts while an operator already streams drives at once, with no
/// release or safe-mode command at all (the start-up hold used to end
/// in the same loop turn as the first command and put the driving adapter in its safe state;
/// the start-up release went out just before the first override),
/// and logs no output failure for a link that was only connecting.
/// See: docs/mavlink.md.
#[test]
fn r20_a_vehicle_starting_under_a_streaming_operator_neither_releases_nor_holds() {
    let mut rig = Rig::new("mavlink-start");
    let ap = autopilot(&rig, 14550);
    rig.operator(11, "mobile", "phone", &[V], 20000, "", &[]);
    let record = rig.vehicle_with_output(V, &mavlink_output(14550));
    wait_for_output(&record, Some(11), 0).expect("operator drives");
    let first = ap.wait_for("a driven override", |e| {
        e["event"] == "rc_override" && raw(e).get(2) == Some(&1805)
    });
    let t_first = first["t"].as_f64().unwrap_or(0.0);
    // Watch a while: the failure showed within the first 250 ms hold.
    // An observation window, not a synchronisation: nothing is awaited here.
    std::thread::sleep(std::time::Duration::from_millis(1500));
    let events = ap.events();
    let after: Vec<&Value> = events
        .iter()
        .filter(|e| e["t"].as_f64().is_some_and(|t| t >= t_first))
        .collect();
    assert!(
        after.iter().filter(|e| e["event"] == "rc_override").count() > 20,
        "driving on: {after:#?}"
    );
    // From the vehicle's start on: its first override is the operator's, not a release.
    let all = ap.events();
    let released: Vec<&Value> = all
        .iter()
        .filter(|e| e["event"] == "rc_override" && raw(e).first() == Some(&0))
        .collect();
    assert!(released.is_empty(), "no release: {released:#?}");
    let hold: Vec<&Value> = all
        .iter()
        .filter(|e| e["event"] == "set_mode" && e["custom_mode"] == 4)
        .collect();
    assert!(hold.is_empty(), "no HOLD: {hold:#?}");
    let log = std::fs::read_dir(&rig.dir)
        .into_iter()
        .flatten()
        .flatten()
        .map(|e| e.path())
        .find(|p| p.to_string_lossy().ends_with(&format!("-vehicle-{V}.log")))
        .and_then(|p| std::fs::read_to_string(p).ok())
        .unwrap_or_default();
    // A command before the autopilot's first HEARTBEAT does fail ("no autopilot heard yet") and
    // is reported; a link that is merely opening is not a failure.
    assert!(
        !log.contains("not connected"),
        "no output failure for a link still connecting:\n{log}"
    );
}

/// Regression (rove against ArduPilot SITL, where `rove failsafe` took about a second because
/// the reader sat on a stray start byte): `rove failsafe` — release plus HOLD, confirmed —
/// completes in under 200 ms, 20 runs in a row, against an autopilot that sends ArduPilot's
/// default telemetry bursts. `target_system` is set, as docs/mavlink.md asks for `ExecStopPost`
/// (without it the command first waits for the autopilot's 1 Hz HEARTBEAT). MAVLink only, on
/// the host's loopback: no DDS participant is involved.
#[test]
fn r20_rove_failsafe_completes_within_200_ms_twenty_times() {
    let ap = FakeAutopilot::start(&["--connection", "udpin:127.0.0.1:0"]);
    let scratch = crate::util::Scratch::new("mavlink-failsafe");
    let config = scratch.dir.join("vehicle.toml");
    let output = format!(
        "[output]\nadapter = \"mavlink\"\nconnection = \"udpout:127.0.0.1:{}\"\ntarget_system = 1\n",
        ap.port()
    );
    std::fs::write(&config, crate::util::vehicle_toml(V, &output)).expect("config");
    let mut times = Vec::new();
    for run in 0..20 {
        let start = std::time::Instant::now();
        let out = std::process::Command::new(crate::util::ROVE)
            .args(["failsafe", "-c"])
            .arg(&config)
            .env("RUNTIME_DIRECTORY", &scratch.dir)
            .output()
            .expect("run rove failsafe");
        let took = start.elapsed();
        assert!(
            out.status.success(),
            "run {run}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        times.push(took.as_secs_f64() * 1000.0);
    }
    eprintln!("rove failsafe, ms: {times:.1?}");
    assert!(
        times.iter().all(|&ms| ms < 200.0),
        "every run under 200 ms: {times:.1?}"
    );
    // Each run commanded HOLD (custom mode 4) and released the channels.
    let holds = ap
        .of("set_mode")
        .iter()
        .filter(|e| e["custom_mode"] == 4)
        .count();
    let releases = ap
        .of("rc_override")
        .iter()
        .filter(|e| raw(e).first() == Some(&0))
        .count();
    assert!(
        holds >= 20 && releases >= 20,
        "holds {holds}, releases {releases}"
    );
}

/// An autopilot on TCP that stops reading: the vehicle's sends fill the connection and then
/// time out (they never block the output), the link is reopened, and the vehicle goes on
/// deciding: its owner's crash still brings the failsafe.
#[test]
fn an_autopilot_that_stops_reading_times_sends_out_and_never_stalls_the_vehicle() {
    let mut rig = Rig::new("mavlink-wedged");
    let ap = rig.autopilot(&[
        "--connection",
        "tcpin:127.0.0.1:5760",
        "--stop-reading-after",
        "1",
    ]);
    // 200 Hz overrides fill the link's buffers within seconds once nobody reads.
    let output = "[output]\nadapter = \"mavlink\"\nconnection = \"tcpout:127.0.0.1:5760\"\n\
                  rate_hz = 200\n";
    let record = rig.vehicle_with_output(V, output);
    let op = rig.operator(11, "mobile", "phone", &[V], 32767, "", &[]);
    wait_for_output(&record, Some(11), 0).expect("operator drives");
    ap.wait_for("the autopilot stops reading", |e| {
        e["event"] == "stopped_reading"
    });
    let name = format!("vehicle-{V}");
    let log = crate::util::eventually("a send timed out", || {
        let log = rig.log_of(&name);
        match log.contains("send timed out after 25ms") {
            true => Ok(log),
            false => Err("not yet"),
        }
    });
    assert!(!log.contains("output hung"), "{log}");
    let crash = wall_us();
    rig.procs[op].crash();
    wait_for_output(&record, None, crash).expect("failsafe after the owner's crash");
}

/// What the autopilot says of the vehicle reaches `rove status --json` (issue 35): its mode,
/// armed state and how long ago it was heard, and its battery as it drains, low at
/// `[vehicle] battery_low_pct`; the vehicle's standing for a bystander.
#[test]
fn the_autopilots_battery_mode_and_link_age_reach_rove_status() {
    let mut rig = Rig::new("mavlink-health");
    let _ap = rig.autopilot(&[
        "--connection",
        "udpin:127.0.0.1:14552",
        "--battery-pct",
        "33",
        "--battery-drain",
        "1",
    ]);
    let output = format!("[vehicle]\nbattery_low_pct = 30\n{}", mavlink_output(14552));
    rig.vehicle_with_output(V, &output);
    let row = |what: &str, want: &dyn Fn(&Value) -> bool| {
        rig.device_when(what, V, |d| want(&d["health"]))
    };
    let first = row("the battery in rove status", &|h| h["battery_pct"].is_u64());
    eprintln!("{first}");
    let h = &first["health"];
    assert_eq!(h["autopilot_mode"], "HOLD", "{first}");
    assert_eq!(
        h["autopilot"]
            .as_str()
            .map(|a| a.starts_with("HOLD disarmed")),
        Some(true)
    );
    assert_eq!(h["armed"], false, "{first}");
    // The autopilot speaks once a second; `rove status` saw a VehicleStatus of the last second.
    let age = h["link_age_ms"].as_u64().unwrap_or(u64::MAX);
    assert!(age < 3_000, "{first}");
    // 3S: 10.5 V empty to 12.6 V full, as the test autopilot reports it.
    let (pct, mv) = (h["battery_pct"].as_u64(), h["battery_mv"].as_u64());
    let (pct, mv) = (pct.unwrap_or(999), mv.unwrap_or(0));
    assert!(pct <= 33, "{first}");
    assert!(mv.abs_diff(10_500 + 21 * pct) <= 21, "{first}");
    assert_eq!(h["battery_low"], pct <= 30, "{first}");
    assert_eq!(first["standing"], "failsafe", "{first}");
    let low = row("the battery low", &|h| h["battery_low"] == true);
    let pct = low["health"]["battery_pct"].as_u64();
    assert!(matches!(pct, Some(p) if p <= 30), "{low}");
    assert!(
        (low["health"]["battery"].as_str()).is_some_and(|b| b.contains("V ") && b.ends_with('%')),
        "{low}"
    );
}
