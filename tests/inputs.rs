//! Inputs end to end: a recorded joystick stream (rove-inputs' replay source) →
//! operator process → vehicle process with the sim adapter; unplugging the joystick releases
//! the vehicle explicitly, and the next operator in the hierarchy drives at once. Each test runs
//! in a network namespace of its own.

use crate::util::{OperatorToml, Rig, eventually, records, wait_for_output};

const V: i64 = 100;

/// The joystick: deadman on BTN_TL, throttle on ABS_Y (up is negative in evdev, so inverted).
const MAPPING: &str = "[input.axes.throttle]\nabs = \"ABS_Y\"\ninvert = true\n\
                       [input.buttons]\ndeadman = \"BTN_TL\"\n";

#[test]
fn a_replayed_joystick_drives_and_unplugging_it_hands_over_to_the_next_operator() {
    let mut rig = Rig::new("inputs-e2e");
    let record = rig.vehicle(V);
    // A weaker operator with constant sticks drives first.
    rig.operator(21, "stationary", "laptop", &[V], 1000, "", &[]);
    wait_for_output(&record, Some(21), 0).expect("the stationary operator drives");

    // Times count from the operator's first poll; 2.5 s leaves room for DDS discovery.
    let recording = rig.write(
        "pad.txt",
        "0    replug Test Pad\n\
         0    absinfo ABS_Y 0 -32768 32767 16 128\n\
         2500 BTN_TL 1\n\
         2500 ABS_Y -32768\n\
         2500 SYN_REPORT\n\
         2700 ABS_Y -16384\n\
         2700 SYN_REPORT\n\
         4500 unplug /dev/input/event7: No such device (os error 19)\n",
    );
    let config = rig.write(
        "operator-11.toml",
        &OperatorToml::new(11, "mobile", "phone")
            .name("pad")
            .drive(&[V])
            .then(&format!(
                "[input]\nsource = \"replay\"\nfile = \"{}\"\n{MAPPING}",
                recording.display()
            ))
            .to_string(),
    );
    let pad = rig.spawn(
        "operator-11",
        &["operator", "-c", config.to_str().unwrap_or("")],
    );

    // Full stick: throttle +32767; then half: the value the mapping gives for −16384.
    let full = wait_for_output(&record, Some(11), 0).expect("the joystick drives");
    assert_eq!(full.throttle, Some(32767), "{full:?}");
    let half = eventually("the half-deflection output", || {
        let outs = records(&record);
        if let Some(o) = outs
            .iter()
            .find(|o| o.owner == Some(11) && o.throttle != Some(32767))
        {
            return Ok(o.clone());
        }
        assert!(
            rig.procs[pad].is_running(),
            "operator exited early: see its log"
        );
        Err(format!(
            "last outputs: {:?}",
            outs.iter().rev().take(5).collect::<Vec<_>>()
        ))
    });
    assert!(
        matches!(half.throttle, Some(t) if (16_000..=16_500).contains(&t)),
        "half deflection: {half:?}"
    );

    // Unplugged: the joystick operator releases; the laptop drives again, without a failsafe
    // gap of a command timeout (the release is explicit).
    let back = wait_for_output(&record, Some(21), half.wall_us).expect("handed over");
    let last_pad = records(&record)
        .iter()
        .filter(|o| o.owner == Some(11))
        .map(|o| o.wall_us)
        .max()
        .unwrap_or(0);
    let gap_ms = back.wall_us.saturating_sub(last_pad) as f64 / 1000.0;
    eprintln!("unplug hand-over: last joystick output → first laptop output {gap_ms:.1} ms");
    let safe_between = records(&record)
        .iter()
        .any(|o| o.wall_us > last_pad && o.wall_us < back.wall_us && o.action != "apply");
    assert!(
        !safe_between,
        "an explicit release hands over directly, with no failsafe in between"
    );
    let log = std::fs::read_to_string(&rig.procs[pad].log).unwrap_or_default();
    assert!(
        log.contains("input not live: releasing control of"),
        "{log}"
    );
    assert!(
        rig.procs[pad].is_running(),
        "a lost input does not stop the operator"
    );
}
