//! A config-only vehicle end to end: the example `[output]` section (tagged on `adapter` as
//! the gateway parses it) drives the sysfs backend over a temp tree that plays the kernel, and
//! the duty cycles written are checked.

use rove_core::MonoTime;
use rove_core::adapter::OutputAdapter;
use rove_core::arbiter::Setpoint;
use rove_core::msg::{Mode, MovementCommand};
use rove_pwm::{PwmVehicle, PwmVehicleSettings, SysfsBackend};
use serde::Deserialize;
use std::fs;
use std::path::Path;

#[derive(Debug, Deserialize)]
#[serde(tag = "adapter", rename_all = "lowercase")]
enum Output {
    Pwm(PwmVehicleSettings),
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct File {
    output: Output,
}

const CUSTOM: &str = include_str!("output-custom-pwm.toml");

fn fake_kernel(root: &Path) {
    for (chip, channels) in [(0, &[0u32, 1, 2][..]), (1, &[0][..])] {
        let chip_dir = root.join(format!("pwmchip{chip}"));
        fs::create_dir_all(&chip_dir).expect("mkdir");
        fs::write(chip_dir.join("export"), "").expect("export");
        for m in channels {
            let dir = chip_dir.join(format!("pwm{m}"));
            fs::create_dir_all(&dir).expect("mkdir");
            for f in ["period", "duty_cycle", "enable"] {
                fs::write(dir.join(f), "0").expect("attr");
            }
        }
    }
}

fn duty(root: &Path, rel: &str) -> String {
    fs::read_to_string(root.join(rel).join("duty_cycle")).expect("duty")
}

#[test]
fn config_only_vehicle_writes_the_expected_duty_cycles() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let root = tmp.path();
    fake_kernel(root);
    let file: File = toml::from_str(CUSTOM).expect("parses");
    let Output::Pwm(mut settings) = file.output;
    settings.pwm.sysfs_root = Some(root.to_path_buf());
    let cfg = settings.validate().expect("valid");
    let backend = SysfsBackend::new(root.to_path_buf(), &cfg);
    let mut v = PwmVehicle::new(cfg, backend, MonoTime::ZERO).expect("starts");
    let chans = [
        "pwmchip0/pwm0",
        "pwmchip0/pwm1",
        "pwmchip0/pwm2",
        "pwmchip1/pwm0",
    ];
    let all = |root: &Path| chans.map(|c| duty(root, c));
    // Failsafe at start: thrust centre 1500, rudder trimmed centre 1485, mode 1500, light 1900.
    assert_eq!(all(root), ["1500000", "1485000", "1500000", "1900000"]);
    for c in chans {
        assert_eq!(
            fs::read_to_string(root.join(c).join("enable")).expect("enable"),
            "1"
        );
        assert_eq!(
            fs::read_to_string(root.join(c).join("period")).expect("period"),
            "20000000"
        );
    }
    let full = Setpoint {
        movement: MovementCommand {
            throttle: i16::MAX,
            yaw: i16::MAX,
            ..MovementCommand::CENTRED
        },
        mode: Mode::Auto,
    };
    v.apply(MonoTime::from_millis(1000), &full).expect("ok");
    // Thrust reaches 1900 (slew 1600 µs/s over 1 s); rudder reversed → min 1000.
    assert_eq!(all(root), ["1900000", "1000000", "2000000", "1900000"]);
    v.apply(
        MonoTime::from_millis(1100),
        &Setpoint {
            movement: MovementCommand::CENTRED,
            mode: Mode::Manual,
        },
    )
    .expect("ok");
    // 100 ms at 1600 µs/s: thrust 1900 → 1740.
    assert_eq!(all(root), ["1740000", "1485000", "1000000", "1900000"]);
    drop(v);
    assert_eq!(all(root), ["1500000", "1485000", "1500000", "1900000"]);
}
