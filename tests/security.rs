//! DDS Security between real processes (docs/security.md): a fleet made by `rove keys`, a
//! secured vehicle and operators, and what an unauthenticated peer or a wrong certificate gets.

use crate::util::{ROVE, Rig, laptop_drives_sim, records, wait_for_output, wall_us};
use std::path::{Path, PathBuf};
use std::process::Command;

const V: i64 = 100;

/// `rove keys init` in the rig's directory, then `rove keys add` for each id; returns the
/// fleet's directory.
fn fleet(rig: &Rig, ids: &[i64]) -> PathBuf {
    let dir = rig.dir.join("fleet");
    let keys = |args: &[&str]| {
        let out = Command::new(ROVE)
            .arg("keys")
            .args(args)
            .output()
            .expect("rove keys");
        assert!(
            out.status.success(),
            "rove keys {args:?}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
    };
    let d = dir.to_str().expect("utf-8 path");
    keys(&["init", "--dir", d, "--fleet", "test fleet"]);
    for id in ids {
        keys(&["add", "--dir", d, "--id", &id.to_string()]);
    }
    dir
}

fn security(fleet: &Path, id: i64) -> String {
    rove_gateway::tools::harness::security_toml(Some(fleet), id)
}

/// The secured vehicle, and the secured laptop (11) driving it; returns the vehicle's record.
fn secured_laptop_drives(rig: &mut Rig, fleet: &Path) -> PathBuf {
    let record = laptop_drives_sim(rig, V, &security(fleet, V), &security(fleet, 11));
    let first = wait_for_output(&record, Some(11), 0).expect("the secured laptop drives");
    eprintln!("secured: the laptop drives from {} µs", first.wall_us);
    record
}

#[test]
fn a_secured_fleet_drives_and_an_unauthenticated_peer_matches_nothing() {
    let mut rig = Rig::new("secure-fleet");
    let fleet = fleet(&rig, &[V, 11]);
    let record = secured_laptop_drives(&mut rig, &fleet);
    // An unauthenticated participant (rove status without keys) sees no device.
    let status = rig.status();
    assert_eq!(status["devices"], serde_json::json!([]), "{status}");
    // A Cyclone DDS peer without keys matches no reader and moves nothing.
    let args = [
        "inflate",
        "--id",
        "13",
        "--strength",
        "340",
        "--seconds",
        "1",
    ];
    let out = rig.foreign_peer(&args).output().expect("run the rogue");
    let summary = String::from_utf8_lossy(&out.stdout);
    assert!(summary.contains("\"matched\": false"), "{summary}");
    let after = wall_us();
    wait_for_output(&record, Some(11), after).expect("the laptop still drives");
    let rogue = records(&record).into_iter().find(|o| o.owner == Some(13));
    assert!(
        rogue.is_none(),
        "an unauthenticated sample was applied: {rogue:?}"
    );
}

#[test]
fn a_certificate_for_one_device_cannot_speak_for_another() {
    let mut rig = Rig::new("secure-wrong-cert");
    let fleet = fleet(&rig, &[V, 11, 12]);
    let record = secured_laptop_drives(&mut rig, &fleet);
    // A stronger operator configured as 12 but holding 11's certificate: authenticated, yet
    // everything it sends as 12 is refused.
    let hook = ["--test-any-certificate"];
    rig.operator(
        12,
        "mobile",
        "phone",
        &[V],
        2000,
        &security(&fleet, 11),
        &hook,
    );
    let needle = "which its certificate does not name";
    crate::util::eventually("the vehicle refuses 12", || {
        if rig.log_of("vehicle-100").contains(needle) {
            Ok(())
        } else {
            Err("not yet")
        }
    });
    let after = wall_us();
    wait_for_output(&record, Some(11), after).expect("the laptop still drives");
    let wrong = records(&record).into_iter().find(|o| o.owner == Some(12));
    assert!(wrong.is_none(), "12 was applied: {wrong:?}");
    // Without the hook the operator refuses to start with another device's certificate.
    let refused = rig.operator(
        12,
        "mobile",
        "phone",
        &[V],
        2000,
        &security(&fleet, 11),
        &[],
    );
    let status = rig.procs[refused]
        .wait_exit(crate::util::PATIENCE)
        .expect("exits");
    assert!(!status.success());
    let log = std::fs::read_to_string(&rig.procs[refused].log).unwrap_or_default();
    assert!(log.contains("not device 12's"), "{log}");
}
