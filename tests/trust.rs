//! Trust between real processes (docs/design.md §4b): a rogue DDS peer — Cyclone DDS speaking
//! rove's wire model (`testkit/rogue.py`), a foreign participant on the vehicle's network —
//! tries to take or disturb a vehicle an honest laptop (id 11) drives. For each attack:
//! - the vehicle never applies a rogue sample (every rogue command carries throttle 31111);
//! - the honest owner keeps control;
//! - no honest operator writes to a vehicle it did not drive;
//! - the attempt is reported (the vehicle's or the operator's log names it).

use crate::util::{Rig, foreign_summary, laptop_drives_sim, records, wait_for_output, wall_us};
use std::path::Path;

const V: i64 = 100;
const LAPTOP: i64 = 11;
const ROGUE_THROTTLE: i64 = 31111;

/// Runs one attack of the rogue in the rig's namespace, to its end (bounded by `--seconds`);
/// its summary.
fn rogue(rig: &Rig, args: &[&str]) -> serde_json::Value {
    let out = rig.foreign_peer(args).output().expect("run the rogue");
    foreign_summary(out, args)
}

/// No rogue sample was applied, and after the attack the laptop still drives.
fn assert_vehicle_kept(record: &Path, rogue_ids: &[i64]) {
    let after = wall_us();
    wait_for_output(record, Some(LAPTOP), after).expect("the laptop still drives");
    let outs = records(record);
    let rogue = outs.iter().find(|o| {
        o.throttle == Some(ROGUE_THROTTLE) || o.owner.is_some_and(|id| rogue_ids.contains(&id))
    });
    assert!(rogue.is_none(), "a rogue sample was applied: {rogue:?}");
    let first = outs
        .iter()
        .position(|o| o.owner == Some(LAPTOP))
        .unwrap_or(0);
    assert!(
        outs[first..].iter().all(|o| o.owner == Some(LAPTOP)),
        "the laptop lost the vehicle during the attack"
    );
}

fn assert_reported(rig: &Rig, name: &str, needle: &str) {
    let log = rig.log_of(name);
    assert!(
        log.contains(needle),
        "{name} did not report {needle:?}:\n{log}"
    );
}

/// One attack on the vehicle the laptop drives: no sample of `rogue_ids` (or with the rogue's
/// throttle) applied, the laptop kept, and the vehicle's log says `reported`.
fn vehicle_attack(test: &str, access: &str, args: &[&str], rogue_ids: &[i64], reported: &str) {
    let mut rig = Rig::new(test);
    let record = laptop_drives_sim(&mut rig, V, access, "");
    let s = rogue(&rig, args);
    eprintln!("{}: {s}", args[0]);
    assert_vehicle_kept(&record, rogue_ids);
    assert_reported(&rig, "vehicle-100", reported);
}

#[test]
fn inflated_strength_takes_nothing() {
    let args = ["inflate", "--id", "13", "--strength", "65534"];
    vehicle_attack(
        "rogue-inflate",
        "",
        &args,
        &[13],
        "which the hierarchy cannot give",
    );
}

#[test]
fn forged_accept_naming_the_owner_grants_nothing() {
    let args = ["forge-accept", "--id", "13", "--owner", "11"];
    vehicle_attack("rogue-accept", "", &args, &[13], "claims device id 11");
}

#[test]
fn the_owners_id_from_another_participant_drives_nothing() {
    let args = ["spoof-src", "--id", "11", "--strength", "240"];
    vehicle_attack("rogue-src", "", &args, &[], "claims device id 11");
}

#[test]
fn a_request_then_finish_cannot_turn_an_honest_operator_against_another_vehicle() {
    let mut rig = Rig::new("rogue-request");
    let record = laptop_drives_sim(&mut rig, V, "", "");
    // Vehicle 101 exists, but the laptop does not drive it.
    let other = rig.vehicle(101);
    wait_for_output(&other, None, 0).expect("vehicle 101 safe at start");
    let args = [
        "request-finish",
        "--id",
        "13",
        "--dest",
        "101",
        "--owner",
        "11",
        "--priority",
        "400",
    ];
    let s = rogue(&rig, &args);
    eprintln!("request-finish (101): {s}");
    // And for the vehicle it drives, a priority discovery does not confirm is not auto-accepted.
    let args = [
        "request-finish",
        "--id",
        "13",
        "--dest",
        "100",
        "--owner",
        "11",
        "--priority",
        "400",
    ];
    rogue(&rig, &args);
    assert_vehicle_kept(&record, &[13]);
    let driven = records(&other).into_iter().find(|o| o.action == "apply");
    assert!(driven.is_none(), "vehicle 101 was driven: {driven:?}");
    assert_reported(&rig, "operator-11", "which we do not drive: not answered");
    let log = rig.log_of("operator-11");
    assert!(
        !log.contains("yielding vehicle"),
        "the laptop yielded:\n{log}"
    );
}

#[test]
fn a_false_device_info_for_the_vehicle_is_not_believed() {
    let mut rig = Rig::new("rogue-info");
    let record = laptop_drives_sim(&mut rig, V, "", "");
    let s = rogue(&rig, &["device-info", "--id", "100", "--controller", "13"]);
    eprintln!("device-info: {s}");
    assert_vehicle_kept(&record, &[13]);
    assert_reported(&rig, "operator-11", "claims device id 100");
    assert_reported(&rig, "vehicle-100", "claims device id 100");
    let status = rig.status();
    let vehicle = Rig::device(&status, V).expect("vehicle listed");
    assert_eq!(vehicle["controller_id"], LAPTOP, "{status}");
}

#[test]
fn three_hundred_rogue_writers_move_nothing_past_an_access_list() {
    let access =
        "[access]\noperators = [{ id = 11, level = \"stationary\", device_class = \"laptop\" }]\n";
    let args = [
        "flood",
        "--writers",
        "300",
        "--id",
        "1000",
        "--strength",
        "340",
    ];
    let ids: Vec<i64> = (1000..1300).collect();
    vehicle_attack(
        "rogue-flood",
        access,
        &args,
        &ids,
        "which is not in [access]",
    );
}

#[test]
fn a_forged_finish_in_the_holders_name_ends_no_grant() {
    let mut rig = Rig::new("rogue-finish");
    let always = "[handover]\nauto_accept = \"always\"\n";
    let record = laptop_drives_sim(&mut rig, V, "", always);
    let asked = wall_us();
    rig.operator(13, "remote", "tablet", &[], 3000, "", &["--request", "100"]);
    let granted = wait_for_output(&record, Some(13), asked).expect("the tablet is granted");
    let s = rogue(
        &rig,
        &[
            "forge-finish",
            "--id",
            "13",
            "--owner",
            "11",
            "--dest",
            "100",
        ],
    );
    eprintln!("forge-finish: {s}");
    let after = wall_us();
    wait_for_output(&record, Some(13), after).expect("the tablet still drives");
    let outs = records(&record);
    let lost = outs
        .iter()
        .find(|o| o.wall_us > granted.wall_us && o.owner != Some(13));
    assert!(lost.is_none(), "the grant ended: {lost:?}");
    assert_reported(&rig, "vehicle-100", "claims device id 13");
    assert_reported(&rig, "operator-11", "claims device id 13");
    let log = rig.log_of("operator-11");
    assert!(!log.contains("driving again"), "the laptop resumed:\n{log}");
}
