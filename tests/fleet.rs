//! Routing by vehicle (docs/design.md, "Fleet scale"): each vehicle's commands travel in its own
//! DDS partition, and peers that know no partitions still interoperate. Checked against a
//! foreign DDS implementation (Cyclone DDS, `testkit/rogue.py listen`), not against rove itself.

use crate::util::{Rig, foreign_summary, wait_for_output};
use std::process::Stdio;

const OPERATOR: i64 = 11;
/// A foreign vehicle built on the seed IDL alone: no partition, publishes its DeviceInfo.
const SEED_VEHICLE: i64 = 300;

/// Starts a Cyclone DDS listener (`rogue.py listen ARGS`) in the rig's namespace.
fn listen(rig: &Rig, args: &[&str]) -> std::process::Child {
    let mut all = vec!["listen"];
    all.extend_from_slice(args);
    (rig.foreign_peer(&all)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped()))
    .spawn()
    .expect("start the listener")
}

/// The listener's counts once it ends: samples for its id, samples for other vehicles.
fn heard(child: std::process::Child) -> (i64, i64) {
    let out = child.wait_with_output().expect("the listener ends");
    let v = foreign_summary(out, &["listen"]);
    let count = |key: &str| v[key].as_i64().unwrap_or(-1);
    (count("samples"), count("others"))
}

#[test]
fn each_vehicle_hears_only_its_own_commands_and_a_seed_vehicle_is_still_driven() {
    let mut rig = Rig::new("fleet-partitions");
    let records = [rig.vehicle(100), rig.vehicle(101)];
    // A foreign vehicle in no partition, announcing itself as a seed vehicle would; and a
    // foreign reader in vehicle 100's partition.
    let seed = listen(&rig, &["--id", "300", "--vehicle-info", "--seconds", "8"]);
    let in_100 = listen(
        &rig,
        &[
            "--id",
            "100",
            "--partition",
            "rove/vehicle/100",
            "--seconds",
            "8",
        ],
    );
    rig.operator(
        OPERATOR,
        "stationary",
        "laptop",
        &[100, 101, SEED_VEHICLE],
        1000,
        "",
        &[],
    );
    for record in &records {
        wait_for_output(record, Some(OPERATOR), 0).expect("the operator drives both rove vehicles");
    }
    let (seed_own, seed_others) = heard(seed);
    let (own_100, others_100) = heard(in_100);
    assert!(
        seed_own > 0,
        "the seed vehicle (no partition) got no command of its own"
    );
    assert_eq!(
        seed_others, 0,
        "a reader in no partition got rove vehicles' commands"
    );
    assert!(own_100 > 0, "a reader in rove/vehicle/100 got nothing");
    assert_eq!(
        others_100, 0,
        "a reader in rove/vehicle/100 got other vehicles' commands"
    );
}

/// Twelve processes started at once, each vehicle with a laptop and a weaker desktop (the scale
/// bench's fleet, `rove bench scale --vehicles 4 --operators 8`): every vehicle is driven by its
/// laptop, a desktop restarting takes nothing, and no vehicle falls to failsafe. Before
/// ROVE-PATCH.md §17, discovery and the event loop of one process or another deadlocked as the
/// fleet joined (the discovery thread sent to the event loop's full channel while holding the
/// database's lock, which the event loop was waiting for): that process never heard or spoke
/// again, and its vehicle was driven by the desktop or by nobody (4 of 4 runs).
#[test]
fn a_fleet_started_at_once_is_driven_by_each_vehicles_stronger_operator() {
    let options = rove_tools::fleet::Options {
        vehicles: 4,
        operators: 8,
        idle: false,
        window: std::time::Duration::from_secs(1),
        handover_runs: 2,
        // Each phone drives a moment before it quits (the option is exercised).
        handover_hold: std::time::Duration::from_millis(100),
        restarts: 4,
        latejoin_runs: 1,
        heartbeat_ms: None,
        presence_ms: None,
        vehicle_rt: None,
        secure: false,
    };
    let rove = std::path::Path::new(crate::util::ROVE);
    let report = rove_tools::fleet::run(rove, &options, &mut |line| eprintln!("{line}"))
        .unwrap_or_else(|e| panic!("the fleet never became steady: {e:#}"));
    eprintln!("{report:?}");
    assert_eq!(
        (report.wrong_owner, report.stale, report.restarts),
        (0, 0, 4),
        "wrong owners, stale failsafe entries, restarts: {report:?}"
    );
    assert!(report.outputs > 0);
}

/// Presence by SPDP (issue 33, ROVE-PATCH.md §18, §19): every participant announces itself
/// every 250 ms (the default `presence_ms`), which is at most half the DeviceInfo writer's
/// liveliness lease, so no ParticipantMessage goes out; and a peer whose own announcements
/// arrive by multicast gets ours by multicast alone, not once more by unicast. Counted on the
/// wire, in the first 3 s of a vehicle and a laptop (their own capture, `rtps_spray.py
/// census`). Before, each sent a reliable ParticipantMessage a second to every peer, and each
/// announcement went to the group and to every known peer (73 SPDP datagrams, 24 by
/// multicast, in this census). Nor does any DCPSTopic message go out (ROVE-PATCH.md §44): rove
/// announces no topics, so a join costs each pair none of that topic's DATA, HEARTBEATs and
/// ACKNACKs (before: 30 DATA and 15 HEARTBEATs and ACKNACKs to the peer in this census).
#[test]
fn presence_by_spdp_sends_no_liveliness_messages_and_announces_by_multicast() {
    let mut rig = Rig::new("presence-census");
    let (_record, capture) = crate::spray::captured_driving_fleet_with(&mut rig, false, "");
    let mut child = crate::spray::sprayer(
        &rig,
        &["census", "--capture", capture.to_str().expect("utf-8 path")],
    );
    let out = std::io::BufReader::new(child.stdout.take().expect("piped"));
    let census = crate::spray::summary(child, out);
    eprintln!("census of the first 3 s: {census}");
    let count = |key: &str| census[key].as_u64().unwrap_or(0);
    assert_eq!(count("participant_message"), 0, "{census}");
    assert_eq!(
        count("sedp_topic_any"),
        0,
        "DCPSTopic on the wire: {census}"
    );
    // Two participants for most of 3 s at 4 a second: at least 2 × 2 s × 4 by multicast.
    assert!(count("spdp_multicast") >= 16, "{census}");
    // By unicast: the eleven fixed localhost ports once each (every 10 s) and a few before the
    // peer was heard by multicast; not one per peer and period (before: 46 in this census, 24
    // of them to the peer).
    assert!(
        count("spdp_unicast") <= 2 * 11 + 4,
        "announcements by unicast to a peer heard by multicast: {census}"
    );
    assert!(count("user") > 0, "{census}");
}

/// Issue 33, item 3: a foreign observer (Cyclone DDS, the seed's DeviceInfo reader QoS: liveliness
/// lease 3 s) that joins late lists every device and owner at once, from the transient-local
/// history, and sees no writer lose its liveliness and no instance change over 8 s although an
/// unchanged DeviceInfo is refreshed only every 5 s: the SPDP announcements (every 250 ms)
/// assert the DeviceInfo writers' 1 s liveliness (Cyclone renews a proxy participant's
/// automatic writers on any message from it). Every device is listed within 1 s of the
/// observer's start (measured and printed).
#[test]
fn a_late_foreign_observer_lists_every_device_and_owner_and_none_lapses() {
    let mut rig = Rig::new("fleet-observer");
    let driven = rig.vehicle(100);
    rig.vehicle(101);
    rig.operator(OPERATOR, "stationary", "laptop", &[100], 1000, "", &[]);
    wait_for_output(&driven, Some(OPERATOR), 0).expect("the laptop drives 100");
    let observer = (rig.foreign_peer(&["observe", "--seconds", "8"]))
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("start the observer");
    let out = observer.wait_with_output().expect("the observer ends");
    let v = foreign_summary(out, &["observe"]);
    eprintln!("the late observer: {v}");
    let device = |id: i64| v["devices"][id.to_string()].clone();
    let owner = |id: i64| device(id)["controller_id"].as_i64();
    assert_eq!(owner(100), Some(OPERATOR), "{v}");
    assert_eq!(
        owner(101),
        Some(101),
        "an undriven vehicle names itself: {v}"
    );
    assert_eq!(device(OPERATOR)["type"], 1, "the laptop, a controller: {v}");
    assert_eq!(device(100)["type"], 0, "{v}");
    for id in [100, 101, OPERATOR] {
        let first = v["first_ms"][id.to_string()].as_u64().unwrap_or(u64::MAX);
        assert!(
            first < 1_000,
            "device {id} listed {first} ms after the start: {v}"
        );
    }
    assert_eq!(v["liveliness_lost"], 0, "a writer's liveliness lapsed: {v}");
    assert_eq!(
        v["instance_changes"], 0,
        "an instance lost its writers: {v}"
    );
}

/// Issue 33, item 3: a foreign controller (Cyclone DDS on the seed's IDL and QoS, at a stationary
/// laptop's strength) still drives a rove vehicle under SPDP presence, and when it stops, the
/// vehicle falls to its failsafe at the command timeout.
#[test]
fn a_foreign_controller_drives_a_rove_vehicle_and_its_stop_brings_the_failsafe() {
    let mut rig = Rig::new("fleet-foreign-controller");
    let record = rig.vehicle(100);
    let args = [
        "inflate",
        "--id",
        "13",
        "--dest",
        "100",
        "--strength",
        "220",
        "--seconds",
        "3",
    ];
    let out = rig
        .foreign_peer(&args)
        .output()
        .expect("run the foreign controller");
    let v = foreign_summary(out, &args);
    assert!(v["samples"].as_i64().unwrap_or(0) > 0, "{v}");
    let driven = wait_for_output(&record, Some(13), 0).expect("the foreign controller drives");
    assert_eq!(driven.throttle, Some(31111), "its sticks: {driven:?}");
    wait_for_output(&record, None, driven.wall_us).expect("the failsafe after it stopped");
}
