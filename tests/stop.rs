//! Clean stops (issue 49): a SIGTERM'd vehicle or operator logs no ERROR, secured or not (nor
//! does a secured start), and an
//! operator's stop does not wait on a peer that died (its reader never acknowledges).
//! Stop times are measured and printed, not asserted.

use crate::util::{PATIENCE, Rig, eventually, wait_for_output, wall_us};
use std::time::Instant;

const V: i64 = 100;
const LAPTOP: i64 = 11;
const PHONE: i64 = 12;

/// How far each of `rig`'s logs had got.
fn log_ends(rig: &Rig) -> Vec<usize> {
    (rig.procs.iter())
        .map(|p| std::fs::read(&p.log).map_or(0, |l| l.len()))
        .collect()
}

/// The lines of `rig`'s logs past `from` (see [`log_ends`]) that say ERROR, with the process
/// they came from.
fn errors_since(rig: &Rig, from: &[usize]) -> Vec<String> {
    (rig.procs.iter().enumerate())
        .flat_map(|(n, p)| {
            let log = std::fs::read(&p.log).unwrap_or_default();
            let since = log
                .get(from.get(n).copied().unwrap_or(0)..)
                .unwrap_or_default();
            (String::from_utf8_lossy(since).lines())
                .filter(|l| l.contains(" ERROR "))
                .map(|l| format!("{}: {l}", p.name))
                .collect::<Vec<_>>()
        })
        .collect()
}

/// SIGTERM to process `n`; its exit status must be a clean one. Returns the milliseconds taken.
fn stop(rig: &mut Rig, n: usize) -> f64 {
    let t = Instant::now();
    rig.procs[n].terminate();
    let status = rig.procs[n].wait_exit(PATIENCE);
    assert!(
        status.is_some_and(|s| s.success()),
        "{} stops cleanly: {status:?}",
        rig.procs[n].name
    );
    t.elapsed().as_secs_f64() * 1000.0
}

/// A vehicle, a laptop driving it, a phone that takes over; then each stopped in turn (phone:
/// the laptop drives again; laptop; vehicle). `security` gives each its `[security]` (a fleet),
/// or nothing. Returns the stop times and the ERROR lines logged from the first stop on.
fn stops(
    rig: &mut Rig,
    security: impl Fn(i64) -> String,
    bystander: bool,
) -> ([f64; 3], Vec<String>) {
    let output = format!("{}[output]\nadapter = \"sim\"\n", security(V));
    let record = rig.vehicle_with_output(V, &output);
    let vehicle = rig.procs.len() - 1;
    let laptop = rig.operator(
        LAPTOP,
        "stationary",
        "laptop",
        &[V],
        1000,
        &security(LAPTOP),
        &[],
    );
    wait_for_output(&record, Some(LAPTOP), 0).expect("the laptop drives");
    let phone = rig.operator(PHONE, "mobile", "phone", &[V], 2000, &security(PHONE), &[]);
    wait_for_output(&record, Some(PHONE), 0).expect("the phone takes over");
    if bystander {
        // A `rove status --events` that dies within its lease, once it heard the phone: its
        // readers stay matched with the phone's writers and never acknowledge again.
        let status = rig.spawn("status", &["status", "--events"]);
        eventually("the bystander hears the phone", || {
            let log = std::fs::read_to_string(&rig.procs[status].log).unwrap_or_default();
            log.contains("\"id\":12,").then_some(()).ok_or(log)
        });
        rig.procs[status].crash();
    }
    let from = log_ends(rig);
    let quit = wall_us();
    let phone_ms = stop(rig, phone);
    wait_for_output(&record, Some(LAPTOP), quit).expect("back to the laptop");
    let laptop_ms = stop(rig, laptop);
    let vehicle_ms = stop(rig, vehicle);
    ([phone_ms, laptop_ms, vehicle_ms], errors_since(rig, &from))
}

#[test]
fn a_clean_stop_logs_no_error_and_waits_for_no_dead_peer() {
    let mut rig = Rig::new("stop-clean");
    let ([phone_ms, laptop, vehicle], errors) = stops(&mut rig, |_| String::new(), true);
    eprintln!("stops: phone {phone_ms:.1} ms, laptop {laptop:.1} ms, vehicle {vehicle:.1} ms");
    assert_eq!(errors, Vec::<String>::new(), "no ERROR on a clean stop");
    let phone = (rig.procs.iter()).find(|p| p.name == format!("operator-{PHONE}"));
    let phone_log = std::fs::read_to_string(&phone.expect("the phone").log).unwrap_or_default();
    assert!(
        !phone_log.contains("did not acknowledge"),
        "the phone's stop waited on the dead bystander: {phone_log}"
    );
}

#[cfg(feature = "security")]
#[test]
fn a_clean_secured_stop_logs_no_error() {
    let mut rig = Rig::new("stop-secured");
    let fleet = rig.fleet(&[V, LAPTOP, PHONE]).expect("a fleet");
    let security = |id| rove_tools::harness::security_toml(Some(&fleet), id);
    let ([phone, laptop, vehicle], errors) = stops(&mut rig, security, false);
    eprintln!("secured stops: phone {phone:.1} ms, laptop {laptop:.1} ms, vehicle {vehicle:.1} ms");
    assert_eq!(
        errors,
        Vec::<String>::new(),
        "no ERROR on a clean secured stop"
    );
    // Nor at the secured start: a peer's first submessages that arrive before its keys do not
    // decode, which is the join's normal race (ROVE-PATCH §32), not an error.
    let from_start = errors_since(&rig, &[]);
    assert_eq!(
        from_start,
        Vec::<String>::new(),
        "no ERROR in a secured start"
    );
}
