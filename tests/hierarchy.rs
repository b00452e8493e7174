//! The DDS hierarchy between real processes: passive and active handover, failsafe,
//! device lists. Each test runs `rove` processes in a network namespace of its own.
//!
//! Latencies are measured and printed (run with `--nocapture` to see them), never asserted:
//! timing goals live in `rove bench`.

use crate::util::{
    self, ROVE, Rig, applies_in_burst, eventually, records, wait_for_output, wall_us,
};
use std::path::Path;
use std::time::Duration;

const V: i64 = 100;

#[test]
fn a_lone_operator_drives_the_vehicle() {
    let mut rig = Rig::new("lone");
    let record = rig.vehicle(V);
    rig.operator(11, "stationary", "laptop", &[V], 1000, "", &[]);
    let out = wait_for_output(&record, Some(11), 0).expect("laptop drives");
    assert_eq!(out.throttle, Some(1000));
    // The vehicle starts in the safe state, before anyone drives.
    assert_eq!(records(&record)[0].action, "safe");
    let status = rig.status();
    let vehicle = Rig::device(&status, V).expect("vehicle listed");
    assert_eq!(vehicle["controller_id"], 11);
    assert_eq!(vehicle["type"], "vehicle");
}

#[test]
fn a_stronger_operator_takes_over_and_a_graceful_quit_hands_back_at_once() {
    let mut rig = Rig::new("preempt");
    let record = rig.vehicle(V);
    rig.operator(11, "stationary", "laptop", &[V], 1000, "", &[]);
    wait_for_output(&record, Some(11), 0).expect("laptop drives");
    let phone = rig.operator(12, "mobile", "phone", &[V], 2000, "", &[]);
    let out = wait_for_output(&record, Some(12), 0).expect("phone preempts");
    assert_eq!(out.throttle, Some(2000));

    let quit = wall_us();
    rig.procs[phone].terminate();
    let back = wait_for_output(&record, Some(11), quit).expect("laptop back");
    eprintln!(
        "graceful quit → laptop applied after {:.1} ms",
        (back.wall_us - quit) as f64 / 1000.0
    );
    assert!(rig.procs[phone].wait_exit(util::PATIENCE).is_some());
}

#[test]
fn a_weaker_or_equal_operator_joining_does_not_take_over() {
    let mut rig = Rig::new("weaker");
    let record = rig.vehicle(V);
    rig.operator(12, "stationary", "tablet", &[V], 2000, "", &[]);
    wait_for_output(&record, Some(12), 0).expect("tablet drives");
    rig.operator(11, "stationary", "laptop", &[V], 1000, "", &[]);
    rig.operator(13, "stationary", "tablet", &[V], 3000, "", &[]);
    // Wait until both newcomers are on the network and streaming, then check nothing changed.
    let status = eventually("both newcomers seen", || {
        let status = rig.status();
        if Rig::device(&status, 11).is_some() && Rig::device(&status, 13).is_some() {
            Ok(status)
        } else {
            Err(status)
        }
    });
    assert_eq!(
        Rig::device(&status, V).expect("vehicle")["controller_id"],
        12
    );
    let later = wall_us();
    wait_for_output(&record, Some(12), later).expect("still the tablet");
    assert!(
        records(&record)
            .iter()
            .all(|o| o.owner != Some(11) && o.owner != Some(13)),
        "a weaker or equal operator was applied"
    );
}

#[test]
fn a_crashed_owner_hands_over_after_the_command_timeout_and_nobody_means_failsafe() {
    let mut rig = Rig::new("crash");
    let record = rig.vehicle(V);
    let laptop = rig.operator(11, "stationary", "laptop", &[V], 1000, "", &[]);
    wait_for_output(&record, Some(11), 0).expect("laptop drives");
    let phone = rig.operator(12, "mobile", "phone", &[V], 2000, "", &[]);
    wait_for_output(&record, Some(12), 0).expect("phone drives");

    let crash = wall_us();
    rig.procs[phone].crash();
    let back = wait_for_output(&record, Some(11), crash).expect("laptop after timeout");
    eprintln!(
        "SIGKILL → laptop applied after {:.1} ms (command timeout 100 ms)",
        (back.wall_us - crash) as f64 / 1000.0
    );

    let crash = wall_us();
    rig.procs[laptop].crash();
    let safe = wait_for_output(&record, None, crash).expect("failsafe");
    eprintln!(
        "SIGKILL of the last operator → failsafe after {:.1} ms",
        (safe.wall_us - crash) as f64 / 1000.0
    );
    // Nothing drives after the failsafe took over.
    std::thread::sleep(Duration::from_millis(300)); // observation window, not synchronisation
    assert!(
        records(&record)
            .iter()
            .filter(|o| o.wall_us > safe.wall_us)
            .all(|o| o.action == "safe"),
        "outputs driven after failsafe"
    );
}

#[test]
fn active_handover_accept_drive_and_finish() {
    let (mut rig, record, laptop, tablet) = granted_to_the_tablet("accept");

    // FINISH (the tablet stops gracefully): the laptop, standing by, drives again.
    let finish = wall_us();
    rig.procs[tablet].terminate();
    let back = wait_for_output(&record, Some(11), finish).expect("laptop resumes");
    eprintln!(
        "FINISH → laptop applied after {:.1} ms",
        (back.wall_us - finish) as f64 / 1000.0
    );
    // No ping-pong: once the laptop was back, the tablet never drove again.
    assert!(
        records(&record)
            .iter()
            .filter(|o| o.wall_us > back.wall_us)
            .all(|o| o.owner != Some(13))
    );
    assert_the_bystander_never_drove(&record, laptop);
}

/// The grant holder crashes: no FINISH ever comes. The vehicle falls back to the standing-by
/// owner once the holder's stream times out, and the owner, seeing itself named again, resumes.
#[test]
fn a_crashed_grant_holder_gives_the_vehicle_back_to_the_owner() {
    let (mut rig, record, laptop, tablet) = granted_to_the_tablet("holder-crash");
    let crash = wall_us();
    rig.procs[tablet].crash();
    let back = wait_for_output(&record, Some(11), crash).expect("laptop resumes");
    assert_eq!(back.throttle, Some(1000));
    eprintln!(
        "holder crash → laptop applied after {:.1} ms",
        (back.wall_us - crash) as f64 / 1000.0
    );
    assert_the_bystander_never_drove(&record, laptop);
}

/// A laptop (auto-accepts every request) drives; a weaker desktop bystander streams; a tablet
/// requests and is granted. Returns the rig, the vehicle's record, the time the laptop first
/// drove and the tablet's process index.
fn granted_to_the_tablet(test: &str) -> (Rig, std::path::PathBuf, u64, usize) {
    let mut rig = Rig::new(test);
    let record = rig.vehicle(V);
    rig.operator(
        11,
        "stationary",
        "laptop",
        &[V],
        1000,
        "[handover]\nauto_accept = \"always\"\n",
        &[],
    );
    let laptop = wait_for_output(&record, Some(11), 0).expect("laptop drives");
    // A weaker bystander streams from now on; it must never get the vehicle.
    rig.operator(31, "remote", "desktop", &[V], 500, "", &[]);
    let asked = wall_us();
    let tablet = rig.operator(13, "remote", "tablet", &[], 3000, "", &["--request", "100"]);
    let granted = wait_for_output(&record, Some(13), asked).expect("tablet granted");
    assert_eq!(granted.throttle, Some(3000));
    (rig, record, laptop.wall_us, tablet)
}

fn assert_the_bystander_never_drove(record: &std::path::Path, since_us: u64) {
    assert!(
        records(record)
            .iter()
            .filter(|o| o.wall_us > since_us)
            .all(|o| o.owner != Some(31)),
        "the bystander drove"
    );
}

#[test]
fn active_handover_refused_at_the_consent_timeout() {
    let mut rig = Rig::new("refuse");
    let record = rig.vehicle(V);
    rig.operator(
        11,
        "stationary",
        "laptop",
        &[V],
        1000,
        "[handover]\nauto_accept = \"never\"\nconsent_timeout_ms = 300\nreply_timeout_ms = 2000\n",
        &[],
    );
    wait_for_output(&record, Some(11), 0).expect("laptop drives");
    let tablet = rig.operator(13, "remote", "tablet", &[], 3000, "", &["--request", "100"]);
    // The request ends refused: the tablet says so in its log.
    let log = rig.procs[tablet].log.clone();
    let text = eventually("an answer in the tablet's log", || {
        let text = std::fs::read_to_string(&log).unwrap_or_default();
        if text.contains("request ended") {
            Ok(text)
        } else {
            Err(format!("no answer:\n{text}"))
        }
    });
    assert!(text.contains("Refused"), "tablet log:\n{text}");
    assert!(records(&record).iter().all(|o| o.owner != Some(13)));
}

#[test]
fn status_lists_every_device_and_reports_duplicate_ids() {
    let mut rig = Rig::new("status");
    rig.vehicle(V);
    rig.operator(11, "stationary", "laptop", &[], 0, "", &[]);
    rig.operator(12, "mobile", "phone", &[], 0, "", &[]);
    rig.operator(12, "remote", "desktop", &[], 0, "", &[]);
    let status = eventually("every device and the duplicate listed", || {
        let status = rig.status();
        let ids: Vec<i64> = status["devices"]
            .as_array()
            .map(|a| a.iter().filter_map(|d| d["id"].as_i64()).collect())
            .unwrap_or_default();
        if ids == [11, 12, V] && status["duplicates"] == serde_json::json!([12]) {
            Ok(status)
        } else {
            Err(format!("incomplete status: {status}"))
        }
    });
    assert!(
        status["devices"]
            .as_array()
            .is_some_and(|a| a.iter().all(|d| d["online"] == true))
    );
}

/// The README's demo runs its whole story over DDS between real processes.
#[test]
fn the_demo_tells_its_story_between_real_processes() {
    demo_story(false);
}

/// `rove demo --secure`: the same story, every process authenticated with a certificate.
#[test]
fn the_secure_demo_tells_the_same_story_with_certificates() {
    demo_story(true);
}

fn demo_story(secure: bool) {
    let mut lines = Vec::new();
    let mut print = |l: &str| lines.push(l.to_string());
    rove_tools::demo::run_processes(Path::new(ROVE), secure, &mut print)
        .unwrap_or_else(|e| panic!("{e:#}"));
    let story = lines.join("\n");
    for expected in [
        "joins: vehicle driven by 11",
        "preempts: vehicle driven by 12",
        "phone quits (releases): vehicle driven by 11",
        "the laptop accepts: vehicle driven by 13",
        "quits: vehicle driven by 11",
        "command timeout 100 ms): vehicle driven by the failsafe",
    ] {
        assert!(
            story.contains(expected),
            "missing {expected:?} in:\n{story}"
        );
    }
}

/// Random datagrams and truncated RTPS messages at every port of the domain, a stronger operator
/// driving another vehicle, and commands from an unknown id for an unknown vehicle change
/// nothing and crash nothing.
#[test]
fn garbage_and_misaddressed_traffic_change_nothing() {
    let mut rig = Rig::new("garbage");
    let record = rig.vehicle(V);
    rig.operator(11, "stationary", "laptop", &[V], 1000, "", &[]);
    wait_for_output(&record, Some(11), 0).expect("laptop drives");
    // A mobile phone (stronger) that drives vehicle 101, and an unknown id driving 999.
    rig.operator(12, "mobile", "phone", &[101], 2000, "", &[]);
    rig.operator(77, "mobile", "phone", &[999], 2000, "", &[]);
    let noise = "for p in $(seq 7400 7420); do \
                   head -c 512 /dev/urandom > /dev/udp/127.0.0.1/$p; \
                   printf 'RTPS\\x02\\x03\\x01\\x0f\\x00\\x01junk' > /dev/udp/127.0.0.1/$p; \
                 done; \
                 head -c 512 /dev/urandom > /dev/udp/239.255.0.1/7400; true";
    for _ in 0..20 {
        rig.sh(noise).expect("send noise");
    }
    // Wait until both newcomers are on the network, then check that nothing changed.
    eventually("both newcomers seen", || {
        let status = rig.status();
        if Rig::device(&status, 12).is_some() && Rig::device(&status, 77).is_some() {
            Ok(())
        } else {
            Err(status)
        }
    });
    let later = wall_us();
    wait_for_output(&record, Some(11), later).expect("still the laptop");
    assert!(rig.procs[0].is_running(), "the vehicle died");
    assert!(
        records(&record)
            .iter()
            .all(|o| o.owner.is_none() || o.owner == Some(11)),
        "a command for another vehicle was applied"
    );
}

/// A vehicle whose control loop stalls for half a second (the hidden SIGUSR1 test hook blocks
/// its thread, as a hung call would) applies none of the samples that queued up meanwhile: of
/// a batch it takes only each writer's newest, and a newest sample that waited longer than the
/// command timeout (its writer died meanwhile) is stale (rove_core::freshness). The whole process
/// stopped by SIGSTOP is `robustness::a_vehicle_stopped_and_continued_…`.
#[test]
fn a_vehicle_stalled_for_500_ms_applies_none_of_the_commands_that_queued_up() {
    let mut rig = Rig::new("stall-fresh");
    let config = rig.write(
        "vehicle.toml",
        &format!("[device]\nid = {V}\n[output]\nadapter = \"sim\"\n"),
    );
    let record = rig.dir.join("vehicle.jsonl");
    let (config, record_arg) = (
        config.to_str().expect("utf-8"),
        record.to_str().expect("utf-8"),
    );
    let name = format!("vehicle-{V}");
    let args = [
        "vehicle",
        "-c",
        config,
        "--record",
        record_arg,
        "--test-stall-on-sigusr1",
        "500",
    ];
    let vehicle = rig.spawn(&name, &args);
    let stall = |rig: &Rig| {
        let pid = rig.procs[vehicle].pid().to_string();
        let status = std::process::Command::new("kill")
            .args(["-USR1", &pid])
            .status()
            .expect("kill");
        assert!(status.success(), "kill -USR1");
    };
    let laptop = rig.operator(11, "stationary", "laptop", &[V], 1000, "", &[]);
    wait_for_output(&record, Some(11), 0).expect("laptop drives");
    // While the loop is stalled the laptop streams at 50 Hz: about 25 samples queue up.
    let stalled = wall_us();
    stall(&rig);
    let resumed = stalled + 500_000;
    let back = wait_for_output(&record, Some(11), resumed).expect("the laptop's fresh samples");
    eprintln!(
        "first apply {:.1} ms after the stall",
        (back.wall_us as f64 - resumed as f64) / 1000.0
    );
    // None of the queued samples is applied: applied, they would come as a burst within
    // microseconds; fresh ones come 20 ms apart.
    let burst = applies_in_burst(&record, stalled, back.wall_us);
    assert!(
        burst.len() <= 3,
        "a burst of {} applies after the stall: {burst:?}",
        burst.len()
    );

    // Stalled again, and the laptop crashes 200 ms into the stall: its newest sample waits
    // about 300 ms in the queue, so it is stale and never applied (it would drive for a
    // command timeout after its operator died); the vehicle goes to failsafe.
    wait_for_output(&record, Some(11), back.wall_us + 1).expect("the laptop drives on");
    let stalled = wall_us();
    stall(&rig);
    std::thread::sleep(Duration::from_millis(200));
    rig.procs[laptop].crash();
    let resumed = stalled + 500_000;
    wait_for_output(&record, None, resumed).expect("failsafe after the stall");
    let late: Vec<u64> = (records(&record).iter())
        .filter(|o| o.owner == Some(11) && o.wall_us >= resumed)
        .map(|o| o.wall_us - resumed)
        .collect();
    assert!(
        late.is_empty(),
        "applied from the dead laptop after the stall: {late:?}"
    );
    let log = eventually("the stale sample reported", || {
        let log = rig.log_of(&name);
        match log.contains("stale ControlCommand sample") {
            true => Ok(log),
            false => Err("not yet"),
        }
    });
    assert!(log.contains("in all"), "{log}");
}
