//! `rove doctor` against fake machines: a sysfs, /dev, /etc and /proc tree in a temp dir.

use super::*;
use std::os::unix::fs::PermissionsExt;

/// A fake system root; device files belong to the test's own user (root: gid 0), so the
/// fake /etc/group names gid 0 as the device group under test.
/// The root, and the temp dir that holds it (removed when the test drops it).
fn tree() -> (tempfile::TempDir, Roots) {
    let dir = tempfile::tempdir().expect("tree");
    let roots = Roots(dir.path().to_path_buf());
    (dir, roots)
}

fn put(roots: &Roots, path: &str, text: &str, mode: u32) {
    let path = roots.at(path);
    std::fs::create_dir_all(path.parent().expect("parent")).expect("dirs");
    std::fs::write(&path, text).expect("write");
    std::fs::set_permissions(&path, std::fs::Permissions::from_mode(mode)).expect("mode");
}

fn vehicle(roots: &Roots, output: &str) -> AnyConfig {
    let text = format!(
        "[device]\nid = 100\n[network]\ninterfaces = [\"10.42.0.2\", \"127.0.0.1\"]\n{output}"
    );
    let path = roots.0.join("vehicle.toml");
    std::fs::write(&path, text).expect("config");
    crate::config::load_any(&path).expect("valid config").0
}

fn line<'a>(found: &'a [Finding], starts: &str) -> &'a Finding {
    (found.iter())
        .find(|f| f.what.starts_with(starts))
        .unwrap_or_else(|| panic!("no {starts:?} in {found:#?}"))
}

#[test]
fn a_pi_with_pwm_serial_and_groups_is_reported_and_the_configs_needs_checked() {
    let (_tmp, roots) = tree();
    put(
        &roots,
        "/etc/group",
        "root:x:0:rove\ndialout:x:20:\nrove:x:999:\n",
        0o644,
    );
    put(
        &roots,
        "/proc/device-tree/model",
        "Raspberry Pi 4 Model B Rev 1.5\0",
        0o444,
    );
    put(&roots, "/sys/class/pwm/pwmchip0/npwm", "2\n", 0o444);
    put(&roots, "/dev/gpiochip0", "", 0o660);
    put(&roots, "/dev/ttyAMA0", "", 0o600);
    put(&roots, "/sys/class/net/can0/type", "280\n", 0o444);
    put(&roots, "/sys/class/net/can0/operstate", "down\n", 0o444);
    put(&roots, "/sys/class/net/eth0/type", "1\n", 0o444);
    put(
        &roots,
        "/proc/net/fib_trie",
        "Main:\n  +-- 10.42.0.0/24 2 0 2\n     |-- 10.42.0.2\n        /32 host LOCAL\n",
        0o444,
    );
    let config = vehicle(
        &roots,
        "[output]\nadapter = \"eyedrive\"\nbackend = \"sysfs\"\n\
         [output.steering]\nchannel = 1\n[output.throttle]\nchannel = 2\n",
    );
    let found = check(&roots, "rove", Some(&config));
    let shown: Vec<String> = found.iter().map(Finding::to_string).collect();
    eprintln!("{}", shown.join("\n"));

    assert_eq!(line(&found, "user: rove").status, Status::Ok);
    assert_eq!(line(&found, "board: Raspberry Pi 4").status, Status::Ok);
    assert_eq!(line(&found, "gpio: /dev/gpiochip0").status, Status::Ok);
    assert_eq!(
        line(&found, "pwm: pwmchip0 with 2 channels").status,
        Status::Ok
    );
    assert_eq!(line(&found, "pwm: \"steering\"").status, Status::Ok);
    // Channel 2 of a two-channel chip.
    let throttle = line(&found, "pwm: \"throttle\"");
    assert_eq!(throttle.status, Status::Wrong);
    assert!(
        throttle.to_string().contains("has 2 channels"),
        "{throttle}"
    );
    // Only root reaches it: told how to give it to dialout, never to join root; not needed by
    // this config.
    let serial = line(&found, "serial: /dev/ttyAMA0");
    assert_eq!(serial.status, Status::Ok);
    let advice = serial.to_string();
    assert!(advice.contains("not needed by the config"), "{advice}");
    assert!(
        advice.contains("GROUP=\"dialout\"") && advice.contains("KERNEL==\"ttyAMA0\""),
        "{advice}"
    );
    assert!(advice.contains("usermod -aG dialout rove"), "{advice}");
    assert!(!advice.contains("-aG root"), "{advice}");

    assert_eq!(line(&found, "can: can0 (down)").status, Status::Ok);
    assert!(!found.iter().any(|f| f.what.starts_with("can: eth0")));
    assert_eq!(line(&found, "network: 10.42.0.2").status, Status::Ok);
    assert_eq!(line(&found, "network: 127.0.0.1").status, Status::Ok);
}

#[test]
fn what_a_config_needs_and_the_computer_lacks_is_missing_or_wrong_with_the_fix() {
    let (_tmp, roots) = tree();
    put(&roots, "/etc/group", "input:x:0:\n", 0o644);
    let config = vehicle(
        &roots,
        "[output]\nadapter = \"eyedrive\"\nbackend = \"rppal\"\n[output.steering]\n\
         pwm_channel = 0\n[output.throttle]\npin = 13\n",
    );
    let found = check(&roots, "rove", Some(&config));
    assert_eq!(line(&found, "user: rove").status, Status::Missing);
    let board = line(&found, "board: no device-tree model");
    assert_eq!(board.status, Status::Missing);
    assert!(board.to_string().contains("backend = \"sysfs\""), "{board}");
    assert_eq!(
        line(&found, "gpio: no /dev/gpiochip").status,
        Status::Missing
    );
    let net = line(&found, "network: 10.42.0.2");
    assert_eq!(net.status, Status::Missing);
    assert!(net.fix.as_deref().is_some_and(|f| f.contains("ip addr")));

    let can = vehicle(
        &roots,
        "[output]\nadapter = \"can\"\ninterface = \"can1\"\n[output.dronecan]\nnode_id = 10\n\
         [[output.dronecan.servos]]\nactuator_id = 1\nsource = \"roll\"\n",
    );
    let found = check(&roots, "rove", Some(&can));
    assert_eq!(line(&found, "can: can1 (absent)").status, Status::Missing);
    put(&roots, "/sys/class/net/can1/type", "280\n", 0o444);
    put(&roots, "/sys/class/net/can1/operstate", "down\n", 0o444);
    let found = check(&roots, "rove", Some(&can));
    let down = line(&found, "can: can1 (down)");
    assert_eq!(down.status, Status::Wrong);
    assert!(down.to_string().contains("ip link set can1 up"), "{down}");

    let serial = vehicle(
        &roots,
        "[output]\nadapter = \"mavlink\"\nconnection = \"serial:/dev/ttyACM0:115200\"\n",
    );
    let found = check(&roots, "rove", Some(&serial));
    assert_eq!(line(&found, "serial: /dev/ttyACM0").status, Status::Missing);
    put(&roots, "/dev/ttyACM0", "", 0o660);
    let found = check(&roots, "rove", Some(&serial));
    let port = line(&found, "serial: /dev/ttyACM0");
    assert_eq!(
        port.status,
        Status::Wrong,
        "needed, and rove is not in its group"
    );
    assert!(
        port.to_string().contains("usermod -aG input rove"),
        "{port}"
    );
    put(&roots, "/etc/group", "dialout:x:0:rove\n", 0o644);
    let found = check(&roots, "rove", Some(&serial));
    assert_eq!(line(&found, "serial: /dev/ttyACM0").status, Status::Ok);
}

/// `rove doctor` never advises joining a group that gives more than the device; where only
/// such a group reaches the device, it points at a udev rule and the device's own group.
#[test]
fn advice_never_names_a_privileged_group() {
    let (_tmp, roots) = tree();
    let serial = vehicle(
        &roots,
        "[output]\nadapter = \"mavlink\"\nconnection = \"serial:/dev/ttyUSB0:57600\"\n",
    );
    put(&roots, "/dev/ttyUSB0", "", 0o660);
    for group in PRIVILEGED_GROUPS {
        put(&roots, "/etc/group", &format!("{group}:x:0:\n"), 0o644);
        let found = check(&roots, "rove", Some(&serial));
        let port = line(&found, "serial: /dev/ttyUSB0");
        let advice = port.to_string();
        assert_eq!(port.status, Status::Wrong, "{advice}");
        assert!(!advice.contains(&format!("-aG {group}")), "{advice}");
        assert!(advice.contains("udev"), "{advice}");
        assert!(advice.contains("usermod -aG dialout rove"), "{advice}");
    }
    // Already in dialout: the rule alone.
    put(
        &roots,
        "/etc/group",
        "root:x:0:\ndialout:x:20:rove\n",
        0o644,
    );
    let found = check(&roots, "rove", Some(&serial));
    let advice = line(&found, "serial: /dev/ttyUSB0").to_string();
    assert!(advice.contains("GROUP=\"dialout\""), "{advice}");
    assert!(!advice.contains("usermod"), "{advice}");
    // A device group without group write: the mode, not only the membership.
    put(&roots, "/etc/group", "dialout:x:0:\n", 0o644);
    put(&roots, "/dev/ttyUSB0", "", 0o600);
    let found = check(&roots, "rove", Some(&serial));
    let advice = line(&found, "serial: /dev/ttyUSB0").to_string();
    assert!(advice.contains("MODE=\"0660\""), "{advice}");
}

#[test]
fn input_devices_are_listed_by_name_with_their_access() {
    let (_tmp, roots) = tree();
    put(&roots, "/etc/group", "input:x:0:rove\n", 0o644);
    put(&roots, "/dev/input/event3", "", 0o660);
    put(
        &roots,
        "/sys/class/input/event3/device/name",
        "Logitech Gamepad F310\n",
        0o444,
    );
    let found = check(&roots, "rove", None);
    let pad = line(&found, "input: /dev/input/event3 \"Logitech Gamepad F310\"");
    assert_eq!(pad.status, Status::Ok);
    assert!(!found.iter().any(|f| f.what.starts_with("network")));
}

/// A vehicle config whose `[security] dir` holds device 100's files, issued for `days` days
/// starting `starts_in_days` from now.
#[cfg(feature = "security")]
fn secured_vehicle(roots: &Roots, starts_in_days: i64, days: u32) -> AnyConfig {
    use crate::certs::{Lifetime, add, init};
    let fleet = roots.0.join("fleet");
    init(&fleet, "doctor fleet", 0).expect("fleet");
    let lifetime = Lifetime {
        days,
        starts_in_days,
    };
    let dir = add(&fleet, 100, lifetime, false).expect("device");
    let text = format!(
        "[device]\nid = 100\n[network]\ninterfaces = [\"127.0.0.1\"]\n[security]\ndir = \"{}\"\n\
         [output]\nadapter = \"sim\"\n",
        dir.display()
    );
    let path = roots.0.join("vehicle.toml");
    std::fs::write(&path, text).expect("config");
    crate::config::load_any(&path).expect("valid config").0
}

#[cfg(feature = "security")]
#[test]
fn a_certificate_near_its_end_is_a_warning_and_an_expired_one_is_wrong() {
    let cases = [
        (0, 365, Status::Ok, "valid until"),
        (0, 20, Status::Warning, "days)"),
        (-10, 5, Status::Wrong, "EXPIRED on"),
        (3, 30, Status::Wrong, "not valid yet"),
    ];
    for (starts, days, status, says) in cases {
        let (_tmp, roots) = tree();
        let config = secured_vehicle(&roots, starts, days);
        let found = check(&roots, "rove", Some(&config));
        let cert = line(&found, "security: certificate");
        assert_eq!(cert.status, status, "{cert}");
        assert!(cert.what.contains(says), "{cert}");
        if status != Status::Ok {
            let fix = cert.fix.as_deref().unwrap_or_default();
            assert!(
                fix.contains("rove keys add") && fix.contains("--renew"),
                "{cert}"
            );
        }
    }
}

/// Issue 49: `rove doctor` says where a MAVLink vehicle keeps `rove failsafe`'s memory, or that
/// it keeps none.
#[test]
fn a_mavlink_vehicle_is_told_where_the_failsafe_memory_lives() {
    let (_tmp, roots) = tree();
    let mavlink = vehicle(
        &roots,
        "[output]\nadapter = \"mavlink\"\nconnection = \"udpin:127.0.0.1:14550\"\n",
    );
    let root = crate::dirs::runtime_dir_from(None, None, true);
    let kept = failsafe_memory(Some(&mavlink), root).expect("a line");
    assert_eq!(kept.status, Status::Ok);
    assert_eq!(
        kept.what,
        "failsafe memory: /run/rove/vehicle-100-mavlink (root without systemd or XDG_RUNTIME_DIR)"
    );
    let none = failsafe_memory(Some(&mavlink), None).expect("a line");
    assert_eq!(none.status, Status::Missing);
    assert!(none.to_string().contains("RuntimeDirectory="), "{none}");
    let pwm = vehicle(&roots, "[output]\nadapter = \"sim\"\n");
    assert_eq!(
        failsafe_memory(Some(&pwm), None),
        None,
        "only MAVLink keeps one"
    );
}
