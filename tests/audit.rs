//! The audit of control between real processes (issue 44): a vehicle's log of who drove it,
//! when and why, and `rove audit --verify` on it as written and tampered with.

use crate::util::{ROVE, Rig, keys, wait_for_output, wall_us};
use serde_json::Value;
use std::path::Path;
use std::process::{Command, Output};

const V: i64 = 100;

/// `rove audit ARGS --dir DIR --vehicle 100`.
fn audit(dir: &Path, args: &[&str]) -> Output {
    Command::new(ROVE)
        .arg("audit")
        .args(args)
        .arg("--dir")
        .arg(dir)
        .args(["--vehicle", &V.to_string()])
        .output()
        .expect("rove audit")
}

/// The entries of the vehicle's log, as stored.
fn entries(dir: &Path) -> Vec<Value> {
    let out = audit(dir, &["--json"]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    (String::from_utf8_lossy(&out.stdout).lines())
        .map(|l| serde_json::from_str(l).expect("an entry"))
        .collect()
}

/// `(why, device, identity)` of each entry.
fn story(entries: &[Value]) -> Vec<(String, Option<i64>, String)> {
    (entries.iter())
        .map(|e| {
            (
                e["why"].as_str().unwrap_or_default().to_string(),
                e["who"]["device"].as_i64(),
                e["who"]["identity"]
                    .as_str()
                    .unwrap_or_default()
                    .to_string(),
            )
        })
        .collect()
}

fn verify(dir: &Path) -> (bool, String) {
    let out = audit(dir, &["--verify"]);
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

/// A laptop drives, a phone preempts and quits, the laptop is killed: the vehicle's log says
/// each change with who (by its participant and, secured, its certificate), then the stop; the
/// chain verifies; an edited entry, a removed one and a cut-short log each fail the check.
fn audit_story(secured: bool) {
    let mut rig = Rig::new(if secured { "audit-secured" } else { "audit" });
    let fleet = rig.dir.join("fleet");
    let security = |id: i64| match secured {
        true => rove_tools::harness::security_toml(Some(&fleet), id),
        false => String::new(),
    };
    if secured {
        let d = fleet.to_str().expect("utf-8 path");
        keys(&["init", "--dir", d, "--fleet", "audit fleet"]);
        for id in [V, 11, 12] {
            keys(&["add", "--dir", d, "--id", &id.to_string()]);
        }
    }
    let output = format!("{}[output]\nadapter = \"sim\"\n", security(V));
    let record = rig.vehicle_with_output(V, &output);
    let laptop = rig.operator(11, "stationary", "laptop", &[V], 1000, &security(11), &[]);
    wait_for_output(&record, Some(11), 0).expect("the laptop drives");
    let phone = rig.operator(12, "mobile", "phone", &[V], 2000, &security(12), &[]);
    wait_for_output(&record, Some(12), 0).expect("the phone preempts");
    let t = wall_us();
    rig.procs[phone].terminate();
    wait_for_output(&record, Some(11), t).expect("the laptop drives again");
    let t = wall_us();
    rig.procs[laptop].crash();
    wait_for_output(&record, None, t).expect("the failsafe");
    rig.procs[0].stop();
    let dir = rig.state_dir();
    let found = story(&entries(&dir));
    let unsecured = |id| format!("unsecured id {id}");
    let certified = |id| format!("certificate of device {id}");
    let name = |id| {
        if secured {
            certified(id)
        } else {
            unsecured(id)
        }
    };
    let want = vec![
        ("start".to_string(), None, "failsafe".to_string()),
        ("join".into(), Some(11), name(11)),
        ("preempt".into(), Some(12), name(12)),
        ("quit".into(), Some(11), name(11)),
        ("crash".into(), None, "failsafe".into()),
        ("stop".into(), None, "failsafe".into()),
    ];
    // In this order; a loaded machine may add a lapse of a stream (crash, join) in between.
    let mut rest = found.iter();
    for step in &want {
        assert!(
            rest.any(|f| f == step),
            "{step:?} missing or out of order in {found:?}"
        );
    }
    assert_eq!(found.first(), want.first(), "{found:?}");
    assert_eq!(found.last(), want.last(), "{found:?}");
    let (ok, said) = verify(&dir);
    assert!(ok, "{said}");
    let intact = format!("{} entries, chain intact from its start", found.len());
    assert!(said.contains(&intact), "{said}");
    // Tampering: each on a copy of the log as written.
    let log = dir.join(format!("vehicle-{V}-audit.jsonl"));
    let written = std::fs::read_to_string(&log).expect("the log");
    let lines: Vec<&str> = written.lines().collect();
    let edited = written.replacen("\"device\":12", "\"device\":13", 1);
    let mut removed = lines.clone();
    removed.remove(2);
    let cut = &lines[..lines.len() - 1];
    for (what, text, needle) in [
        ("edited", edited, "was changed after it was written"),
        ("removed", removed.join("\n") + "\n", "does not follow"),
        ("cut short", cut.join("\n") + "\n", "truncated"),
    ] {
        std::fs::write(&log, text).expect("tamper");
        let (ok, said) = verify(&dir);
        assert!(!ok, "{what}: verified: {said}");
        assert!(said.contains(needle), "{what}: {said}");
    }
    std::fs::write(&log, written).expect("restore");
    assert!(verify(&dir).0);
}

#[test]
fn the_vehicle_audits_who_drove_and_a_tampered_log_fails_the_check() {
    audit_story(false);
}

#[test]
fn a_secured_vehicle_audits_each_driver_by_its_certificate() {
    audit_story(true);
}

/// The output's device fails (the sysfs PWM tree goes away) as a phone takes over from a laptop,
/// and comes back: the audit says the failsafe held the vehicle (`output_down`), then that the
/// phone drives (`output_back`).
#[test]
fn an_output_that_goes_down_and_comes_back_is_in_the_audit() {
    let mut rig = Rig::new("audit-output");
    let root = crate::util::fake_sysfs(&rig.dir);
    let config = crate::util::eyedrive_sysfs(&root);
    let record = rig.vehicle_with_output(V, &config);
    rig.operator(11, "stationary", "laptop", &[V], 1000, "", &[]);
    wait_for_output(&record, Some(11), 0).expect("the laptop drives");
    let chip = root.join("pwmchip0");
    let away = root.join("pwmchip0-away");
    std::fs::rename(&chip, &away).expect("the device goes away");
    // The adapter writes only what changes: a phone's sticks make it write (and fail).
    rig.operator(12, "mobile", "phone", &[V], 2000, "", &[]);
    let dir = rig.state_dir();
    crate::util::eventually("the audit says the output went down", || {
        let found = story(&entries(&dir));
        let down = ("output_down".to_string(), None, "failsafe".to_string());
        found
            .contains(&down)
            .then_some(())
            .ok_or(format!("{found:?}"))
    });
    std::fs::rename(&away, &chip).expect("the device comes back");
    crate::util::eventually("the audit says the output is back with the phone", || {
        let found = story(&entries(&dir));
        let back = (
            "output_back".to_string(),
            Some(12),
            "unsecured id 12".to_string(),
        );
        let at = found.iter().position(|f| f.0 == "output_down");
        let after = at.map(|i| found[i..].contains(&back));
        after
            .unwrap_or(false)
            .then_some(())
            .ok_or(format!("{found:?}"))
    });
    assert!(verify(&dir).0, "the chain verifies");
}
