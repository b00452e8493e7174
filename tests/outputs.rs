//! Output adapters in the real gateway: an operator process drives a vehicle process
//! whose `[output]` is a PWM vehicle on the sysfs backend, over a temp directory standing in for
//! `/sys/class/pwm`; and `rove failsafe` writes the safe state and exits.

use crate::util::{
    ROVE, Rig, Scratch, duty, eyedrive_sysfs, fake_sysfs, vehicle_toml, wait_duty, wait_for_output,
    wall_us,
};
use std::process::Command;

const V: i64 = 100;

#[test]
fn an_operator_drives_eyedrive_servos_through_sysfs_and_a_crash_brings_neutral() {
    let mut rig = Rig::new("pwm-e2e");
    let root = fake_sysfs(&rig.dir);
    let record = rig.vehicle_with_output(V, &eyedrive_sysfs(&root));
    // Neutral at start (ESC arming), before anyone drives: 1500 µs, 20 ms period, enabled.
    wait_duty(&root, 1, "1500000");
    let period = std::fs::read_to_string(root.join("pwmchip0/pwm1/period")).unwrap_or_default();
    assert_eq!(period.trim(), "20000000");
    let enable = std::fs::read_to_string(root.join("pwmchip0/pwm1/enable")).unwrap_or_default();
    assert_eq!(enable.trim(), "1");

    // Full throttle forward, steering full left (roll −32767).
    let op = rig.operator(11, "mobile", "phone", &[V], 32767, "roll = -32767\n", &[]);
    wait_for_output(&record, Some(11), 0).expect("operator drives");
    wait_duty(&root, 1, "2000000");
    wait_duty(&root, 0, "1000000");

    // The operator crashes: one command timeout later, neutral on both channels.
    let crash = wall_us();
    rig.procs[op].crash();
    wait_for_output(&record, None, crash).expect("failsafe");
    wait_duty(&root, 1, "1500000");
    wait_duty(&root, 0, "1500000");
}

#[test]
fn rove_failsafe_writes_the_safe_state_and_exits() {
    let scratch = Scratch::new("failsafe");
    let dir = &scratch.dir;
    let root = fake_sysfs(dir);
    // A crashed gateway left the throttle at full.
    std::fs::write(root.join("pwmchip0/pwm1/duty_cycle"), "2000000").expect("duty");
    std::fs::write(root.join("pwmchip0/pwm1/enable"), "1").expect("enable");
    let config = dir.join("vehicle.toml");
    std::fs::write(&config, vehicle_toml(V, &eyedrive_sysfs(&root))).expect("config");
    let out = Command::new(ROVE)
        .args(["failsafe", "-c"])
        .arg(&config)
        .output()
        .expect("run rove failsafe");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert_eq!(duty(&root, 1), "1500000");
    assert_eq!(duty(&root, 0), "1500000");

    // Outputs that cannot be written: a clear error naming the path, and a failure exit.
    let missing = dir.join("vehicle-missing.toml");
    std::fs::write(
        &missing,
        vehicle_toml(V, &eyedrive_sysfs(&dir.join("no-such-pwm-class"))),
    )
    .expect("config");
    let out = Command::new(ROVE)
        .args(["failsafe", "-c"])
        .arg(&missing)
        .output()
        .expect("run rove failsafe");
    assert!(!out.status.success());
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stderr.contains("no-such-pwm-class"), "{stderr}");
}

/// `rove doctor` on a fake board (the hidden `--root` puts /sys, /dev, /etc and /proc in a
/// temp dir): a bare computer lacks what the Pi config needs (exit 1, each line with its fix);
/// a Pi with its GPIO and the service user in its groups passes (exit 0).
#[test]
fn rove_doctor_reports_what_a_board_lacks_for_a_config_and_passes_a_ready_one() {
    let scratch = Scratch::new("doctor");
    let root = &scratch.dir;
    let config = crate::util::repo_root().join("configs/vehicle-eyedrive-pi.toml");
    let doctor = || {
        Command::new(ROVE)
            .args(["doctor", "--root"])
            .arg(root)
            .arg("-c")
            .arg(&config)
            .output()
            .expect("run rove doctor")
    };
    let out = doctor();
    let report = String::from_utf8_lossy(&out.stdout);
    assert_eq!(out.status.code(), Some(1), "{report}");
    for line in [
        "missing  user: rove has no groups in /etc/group",
        "missing  board: no device-tree model (not a Raspberry Pi) — backend = \"rppal\" needs",
        "missing  gpio: no /dev/gpiochip*",
    ] {
        assert!(
            report.lines().any(|l| l.starts_with(line)),
            "{line:?} in:\n{report}"
        );
    }

    let put = |path: &str, text: &str| {
        let path = root.join(path);
        std::fs::create_dir_all(path.parent().expect("parent")).expect("dirs");
        std::fs::write(path, text).expect("write");
    };
    // Device files belong to the test's user (root, gid 0): the fake group 0 is `gpio`.
    put("etc/group", "gpio:x:0:rove\nrove:x:999:\n");
    put("proc/device-tree/model", "Raspberry Pi 4 Model B Rev 1.5\0");
    put("dev/gpiochip0", "");
    use std::os::unix::fs::PermissionsExt;
    let perms = std::fs::Permissions::from_mode(0o660);
    std::fs::set_permissions(root.join("dev/gpiochip0"), perms).expect("mode");
    let out = doctor();
    let report = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{report}");
    assert!(
        report.contains("ok       gpio: /dev/gpiochip0 (group gpio, mode 660)"),
        "{report}"
    );
}
