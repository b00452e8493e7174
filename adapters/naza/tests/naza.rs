//! The Naza-M preset on the sim backend with injected time: mode levels, the CSC sequence,
//! failsafe values (hover and land), the throttle slew on a change of hands; and the example
//! `[output]` sections parse the way the gateway will parse them (tagged on `adapter`).

use rove_core::MonoTime;
use rove_core::adapter::{Health, OutputAdapter};
use rove_core::arbiter::Setpoint;
use rove_core::error::LinkError;
use rove_core::msg::{Mode, MovementCommand};
use rove_naza::{MotorCommand, NazaConfig, NazaError, NazaSettings, NazaState, NazaVehicle};
use rove_pwm::{SimBackend, SimLog};
use serde::Deserialize;
use std::time::Duration;

#[derive(Debug, Deserialize)]
#[serde(tag = "adapter", rename_all = "lowercase")]
enum Output {
    Naza(NazaSettings),
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct File {
    output: Output,
}

const PI: &str = include_str!("output-naza-pi.toml");
const LAND: &str = include_str!("output-naza-land.toml");

fn settings(text: &str) -> NazaSettings {
    let file: File = toml::from_str(text).expect("parses");
    let Output::Naza(s) = file.output;
    s
}

/// The example on the sim backend (addresses kept; sysfs-only keys dropped).
fn sim(text: &str) -> (NazaVehicle<SimBackend>, SimLog) {
    let mut s = settings(text);
    s.pwm.backend = Some(rove_pwm::BackendKind::Sim);
    s.pwm.sysfs_root = None;
    s.pwm.chip = None;
    let cfg = s.validate().expect("valid");
    let backend = SimBackend::for_config(&cfg.pwm);
    let log = backend.log();
    (NazaVehicle::new(cfg, backend, ms(0)).expect("starts"), log)
}

fn ms(t: u64) -> MonoTime {
    MonoTime::from_millis(t)
}

/// [A, E, T, R, U] as last written.
fn pulses(log: &SimLog) -> [u16; 5] {
    let l = log.latest(5);
    [0, 1, 2, 3, 4].map(|i| l[i].unwrap_or(0))
}

fn sp(roll: i16, pitch: i16, throttle: i16, yaw: i16, mode: Mode) -> Setpoint {
    Setpoint {
        movement: MovementCommand {
            throttle,
            roll,
            pitch,
            yaw,
        },
        mode,
    }
}

#[test]
fn examples_parse() {
    let cfg = settings(PI).validate().expect("valid");
    assert_eq!(cfg.pwm.channels.len(), 5);
    assert_eq!(
        cfg.pwm.addresses()[NazaConfig::THROTTLE],
        rove_pwm::ChannelAddress::HardwarePwm(0)
    );
    let cfg = settings(LAND).validate().expect("valid");
    assert_eq!(
        cfg.pwm.addresses()[NazaConfig::MODE],
        rove_pwm::ChannelAddress::Sysfs {
            chip: 1,
            channel: 0
        }
    );
    let err = settings(&PI.replace("pin = 26", "pin = 26\nu_us = 1"))
        .validate()
        .expect_err("unknown key");
    assert!(err.to_string().contains(".u_us = 1: unknown key"), "{err}");
}

#[test]
fn starts_in_hover_failsafe_in_atti() {
    let (v, log) = sim(PI);
    assert_eq!(pulses(&log), [1500, 1500, 1500, 1500, 1500]);
    assert_eq!(v.state(), NazaState::Failsafe { since: ms(0) });
    assert_eq!(v.keepalive_period(), Some(Duration::from_millis(20)));
    assert_eq!(v.next_deadline(ms(0)), None, "hover needs no ticks");
}

#[test]
fn modes_map_to_u_levels() {
    let (mut v, log) = sim(PI);
    for (i, (mode, want)) in [
        (Mode::Manual, 1100),
        (Mode::Assisted, 1500),
        (Mode::Auto, 1900),
    ]
    .iter()
    .enumerate()
    {
        v.apply(ms(10 + i as u64), &sp(0, 0, 0, 0, *mode))
            .expect("ok");
        assert_eq!(pulses(&log)[4], *want, "{mode:?}");
    }
    // Configurable.
    let text = PI.replace("gps_us = 1900", "gps_us = 1950");
    let (mut v, log) = sim(&text);
    v.apply(ms(10), &sp(0, 0, 0, 0, Mode::Auto)).expect("ok");
    assert_eq!(pulses(&log)[4], 1950);
}

#[test]
fn sticks_map_exactly_and_throttle_is_slew_limited_on_a_change_of_hands() {
    let (mut v, log) = sim(PI);
    v.apply(
        ms(1000),
        &sp(i16::MAX, -i16::MAX, 0, i16::MIN, Mode::Assisted),
    )
    .expect("ok");
    assert_eq!(pulses(&log), [2000, 1000, 1500, 1000, 1500]);
    // Operator A pushes throttle to full: 1000 µs/s default slew → 20 µs per 20 ms frame.
    let mut t = 1000;
    for want in [1520, 1540, 1560] {
        t += 20;
        v.apply(ms(t), &sp(0, 0, i16::MAX, 0, Mode::Assisted))
            .expect("ok");
        assert_eq!(pulses(&log)[2], want);
    }
    t += 1000;
    v.apply(ms(t), &sp(0, 0, i16::MAX, 0, Mode::Assisted))
        .expect("ok");
    assert_eq!(pulses(&log)[2], 2000);
    // Operator B takes over with throttle at minimum: no jump, it ramps down.
    t += 20;
    v.apply(ms(t), &sp(0, 0, -i16::MAX, 0, Mode::Assisted))
        .expect("ok");
    assert_eq!(pulses(&log)[2], 1980);
}

#[test]
fn hover_failsafe_centres_everything_immediately_and_gps_is_configurable() {
    let (mut v, log) = sim(PI);
    // 2 s in: the slew-limited throttle has reached full.
    v.apply(
        ms(2000),
        &sp(i16::MAX, i16::MAX, i16::MAX, i16::MAX, Mode::Manual),
    )
    .expect("ok");
    assert_eq!(pulses(&log), [2000, 2000, 2000, 2000, 1100]);
    v.safe_state(ms(2005)).expect("ok");
    assert_eq!(
        pulses(&log),
        [1500, 1500, 1500, 1500, 1500],
        "no slew in failsafe"
    );
    let (mut v, log) = sim(&PI.replace("failsafe_mode = \"atti\"", "failsafe_mode = \"gps\""));
    v.apply(ms(0), &sp(0, 0, 0, 0, Mode::Manual)).expect("ok");
    v.safe_state(ms(5)).expect("ok");
    assert_eq!(pulses(&log)[4], 1900);
}

#[test]
fn land_failsafe_ramps_throttle_to_the_floor_with_ticks() {
    let (mut v, log) = sim(LAND);
    // GPS failsafe, throttle centre 1500 → 1250 over 4 s, elevator reversed (centre still 1500).
    v.apply(ms(100), &sp(0, 0, 0, 0, Mode::Manual)).expect("ok");
    v.safe_state(ms(1000)).expect("ok");
    assert_eq!(pulses(&log), [1500, 1500, 1500, 1500, 1900]);
    assert_eq!(v.next_deadline(ms(1000)), Some(ms(1020)));
    v.keepalive(ms(3000)).expect("ok");
    assert_eq!(pulses(&log)[2], 1375, "half way");
    // A repeated safe state does not restart the ramp.
    v.safe_state(ms(4000)).expect("ok");
    assert_eq!(pulses(&log)[2], 1313);
    v.keepalive(ms(5000)).expect("ok");
    assert_eq!(pulses(&log)[2], 1250);
    v.keepalive(ms(60_000)).expect("ok");
    assert_eq!(pulses(&log)[2], 1250, "holds the floor");
    assert_eq!(v.next_deadline(ms(60_000)), None);
    // Control comes back: the throttle ramps up from the floor (800 µs/s), no jump.
    v.apply(ms(60_020), &sp(0, 0, 0, 0, Mode::Assisted))
        .expect("ok");
    assert_eq!(pulses(&log)[2], 1266);
}

#[test]
fn csc_holds_the_corners_for_the_configured_time_then_releases_with_throttle_low() {
    let (mut v, log) = sim(PI);
    v.apply(ms(0), &sp(0, 0, 0, 0, Mode::Assisted)).expect("ok");
    log.clear();
    v.start_motors(ms(100)).expect("sent");
    // Outer: A (roll) +full, E (pitch) −full, T min, R (yaw) −full; U unchanged (ATTI).
    assert_eq!(pulses(&log), [2000, 1000, 1000, 1000, 1500]);
    assert_eq!(
        v.state(),
        NazaState::Csc {
            command: MotorCommand::Start,
            until: ms(1600),
            resume: rove_naza::vehicle::Resume::Driving
        }
    );
    assert_eq!(v.next_deadline(ms(100)), Some(ms(1600)));
    assert_eq!(
        v.stop_motors(ms(200)),
        Err(NazaError::CscInProgress { until: ms(1600) })
    );
    // Setpoints during the hold do not move the sticks.
    v.apply(
        ms(500),
        &sp(i16::MAX, i16::MAX, i16::MAX, i16::MAX, Mode::Assisted),
    )
    .expect("ok");
    assert_eq!(pulses(&log), [2000, 1000, 1000, 1000, 1500]);
    v.keepalive(ms(1599)).expect("ok");
    assert!(matches!(v.state(), NazaState::Csc { .. }));
    v.keepalive(ms(1600)).expect("ok");
    assert_eq!(v.state(), NazaState::Driving);
    assert_eq!(
        pulses(&log),
        [1500, 1500, 1000, 1500, 1500],
        "released, throttle low"
    );
    // The operator's throttle ramps up from minimum.
    v.apply(ms(1620), &sp(0, 0, 0, 0, Mode::Assisted))
        .expect("ok");
    assert_eq!(pulses(&log)[2], 1020);
    // Now a stop is accepted.
    v.stop_motors(ms(2000)).expect("sent");
    assert!(matches!(
        v.state(),
        NazaState::Csc {
            command: MotorCommand::Stop,
            ..
        }
    ));
}

#[test]
fn inner_csc_with_a_reversed_elevator_and_a_failsafe_abort() {
    let (mut v, log) = sim(LAND);
    v.start_motors(ms(0)).expect("sent");
    // Inner: yaw +full, roll −full; elevator reversed, so pitch −full is 2000 µs. U = GPS
    // (the failsafe mode: no setpoint yet).
    assert_eq!(pulses(&log), [1000, 2000, 1000, 2000, 1900]);
    // The CSC started from the failsafe, so it resumes it after 1 s.
    v.keepalive(ms(1000)).expect("ok");
    assert_eq!(v.state(), NazaState::Failsafe { since: ms(1000) });
    assert_eq!(pulses(&log), [1500, 1500, 1500, 1500, 1900]);
    // A failsafe during a CSC aborts it at once.
    v.apply(ms(2000), &sp(0, 0, 0, 0, Mode::Auto)).expect("ok");
    v.start_motors(ms(2100)).expect("sent");
    v.safe_state(ms(2200)).expect("ok");
    assert_eq!(v.state(), NazaState::Failsafe { since: ms(2200) });
    assert_eq!(pulses(&log), [1500, 1500, 1500, 1500, 1900]);
}

#[test]
fn a_failed_csc_write_is_reported_and_not_left_in_progress() {
    let (mut v, log) = sim(PI);
    log.fail_with(LinkError::transient("sim: unplugged"));
    assert_eq!(
        v.start_motors(ms(10)),
        Err(NazaError::Link(LinkError::transient("sim: unplugged")))
    );
    assert!(matches!(v.state(), NazaState::Failsafe { .. }));
    assert_eq!(v.health(), Health::Down("sim: unplugged".into()));
    log.restore();
    v.start_motors(ms(20)).expect("retry works");
    assert_eq!(v.health(), Health::Ok);
}

#[test]
fn drop_writes_hover() {
    let (mut v, log) = sim(PI);
    v.apply(
        ms(0),
        &sp(i16::MAX, i16::MAX, i16::MAX, i16::MAX, Mode::Manual),
    )
    .expect("ok");
    v.start_motors(ms(10)).expect("sent");
    drop(v);
    assert_eq!(pulses(&log), [1500, 1500, 1500, 1500, 1500]);
}
