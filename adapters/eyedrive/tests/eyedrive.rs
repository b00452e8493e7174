//! The Eyedrive preset end to end on the sim backend: exact pulses for full, neutral and
//! extreme inputs, neutral at start, on failsafe and on drop; and the example `[output]`
//! sections parse the way the gateway will parse them (tagged on `adapter`).

use rove_core::MonoTime;
use rove_core::adapter::OutputAdapter;
use rove_core::arbiter::Setpoint;
use rove_core::msg::{Mode, MovementCommand};
use rove_eyedrive::EyedriveSettings;
use rove_pwm::{PwmVehicle, PwmVehicleConfig, SimBackend, SimLog};
use serde::Deserialize;

/// The shape the gateway gives `[output]`: one variant per adapter, tagged by `adapter`.
#[derive(Debug, Deserialize)]
#[serde(tag = "adapter", rename_all = "lowercase")]
enum Output {
    Eyedrive(EyedriveSettings),
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct File {
    output: Output,
}

fn load(text: &str) -> PwmVehicleConfig {
    let file: File = toml::from_str(text).expect("parses");
    let Output::Eyedrive(mut settings) = file.output;
    settings.validate().expect("valid")
}

/// The example's channels and limits on the sim backend (its addresses are kept; sysfs-only
/// section keys are dropped).
fn sim(text: &str) -> (PwmVehicle<SimBackend>, SimLog) {
    let file: File = toml::from_str(text).expect("parses");
    let Output::Eyedrive(mut settings) = file.output;
    settings.pwm.backend = Some(rove_pwm::BackendKind::Sim);
    settings.pwm.sysfs_root = None;
    settings.pwm.chip = None;
    let cfg = settings.validate().expect("valid on sim");
    let backend = SimBackend::for_config(&cfg);
    let log = backend.log();
    let v = PwmVehicle::new(cfg, backend, MonoTime::ZERO).expect("starts");
    (v, log)
}

fn drive(roll: i16, throttle: i16) -> Setpoint {
    Setpoint {
        movement: MovementCommand {
            roll,
            throttle,
            ..MovementCommand::CENTRED
        },
        mode: Mode::Manual,
    }
}

const PI: &str = include_str!("output-eyedrive-pi.toml");
const TUNED: &str = include_str!("output-eyedrive-tuned.toml");

#[test]
fn example_sections_parse_and_name_their_outputs() {
    let cfg = load(PI);
    assert_eq!(
        cfg.addresses(),
        [
            rove_pwm::ChannelAddress::HardwarePwm(0),
            rove_pwm::ChannelAddress::GpioPin(13)
        ]
    );
    assert_eq!(cfg.backend, rove_pwm::BackendConfig::Rppal);
    let cfg = load(TUNED);
    assert_eq!(
        cfg.addresses(),
        [
            rove_pwm::ChannelAddress::Sysfs {
                chip: 0,
                channel: 0
            },
            rove_pwm::ChannelAddress::Sysfs {
                chip: 0,
                channel: 1
            }
        ]
    );
    let file: File = toml::from_str(&PI.replace("pin = 13", "pin = 13\nfoo = 1")).expect("parses");
    let Output::Eyedrive(mut settings) = file.output;
    let err = settings
        .validate()
        .expect_err("unknown key inside a tagged section is rejected");
    assert!(err.to_string().contains(".foo = 1: unknown key"), "{err}");
}

#[test]
fn default_pulses_for_full_neutral_and_extreme_inputs() {
    let (mut v, log) = sim(PI);
    assert_eq!(log.latest(2), [Some(1500), Some(1500)], "neutral at start");
    let cases = [
        (0, 0, [1500, 1500]),
        (i16::MAX, i16::MAX, [2000, 2000]),
        (-i16::MAX, -i16::MAX, [1000, 1000]),
        (i16::MIN, i16::MIN, [1000, 1000]),
        (16384, -16384, [1750, 1250]),
    ];
    for (i, (roll, throttle, want)) in cases.iter().enumerate() {
        v.apply(
            MonoTime::from_millis(10 * i as u64 + 10),
            &drive(*roll, *throttle),
        )
        .expect("ok");
        assert_eq!(
            log.latest(2),
            want.map(Some),
            "roll {roll}, throttle {throttle}"
        );
    }
}

#[test]
fn tuned_limits_trim_reverse_and_deadband() {
    let (mut v, log) = sim(TUNED);
    // Steering: trimmed centre 1520, reversed, 1100..1900. Throttle: neutral 1500.
    assert_eq!(log.latest(2), [Some(1520), Some(1500)]);
    v.apply(MonoTime::from_millis(1000), &drive(i16::MAX, 1000))
        .expect("ok");
    // Throttle 1000/32767 ≈ 3 % is inside the 5 % deadband: still neutral.
    assert_eq!(log.latest(2), [Some(1100), Some(1500)]);
    v.apply(MonoTime::from_millis(2000), &drive(i16::MIN, i16::MAX))
        .expect("ok");
    assert_eq!(log.latest(2), [Some(1900), Some(2000)]);
    // Slew 2000 µs/s: 50 ms later, at most 100 µs toward full reverse.
    v.apply(MonoTime::from_millis(2050), &drive(0, -i16::MAX))
        .expect("ok");
    assert_eq!(log.latest(2), [Some(1520), Some(1900)]);
}

#[test]
fn neutral_on_failsafe_and_on_drop() {
    let (mut v, log) = sim(PI);
    v.apply(MonoTime::from_millis(5), &drive(i16::MAX, i16::MAX))
        .expect("ok");
    v.safe_state(MonoTime::from_millis(6)).expect("ok");
    assert_eq!(log.latest(2), [Some(1500), Some(1500)]);
    v.apply(MonoTime::from_millis(7), &drive(i16::MAX, i16::MAX))
        .expect("ok");
    assert_eq!(log.latest(2), [Some(2000), Some(2000)]);
    drop(v);
    assert_eq!(log.latest(2), [Some(1500), Some(1500)]);
}
