//! `rove` built for the boards: the Raspberry Pi (aarch64, or armv7 on a 32-bit OS) and the
//! RaMstix (armv7 hard-float), run under qemu-user on this machine.
//!
//! With `ROVE_BOARD_BINS="PATH …"` (absolute, or relative to the workspace root; `.ci/run` sets
//! it after cross-building), each binary must print its version, accept every shipped config,
//! drive a fake sysfs PWM tree to its safe state with `rove failsafe`, and play the in-process
//! demo with the same story, line for line, as the binary built for this machine.

use crate::util::{
    ROVE, Scratch, duty, elf_arch, eyedrive_sysfs, fake_sysfs, repo_root, run_any_arch,
    vehicle_toml,
};
use std::path::PathBuf;
use std::process::Output;

/// The cross-built binaries named by `ROVE_BOARD_BINS`, each checked to be for a board.
fn board_bins() -> Vec<PathBuf> {
    let list = std::env::var_os("ROVE_BOARD_BINS")
        .expect("set ROVE_BOARD_BINS to rove binaries cross-built for the boards");
    let bins: Vec<PathBuf> = (list.to_string_lossy().split_whitespace())
        .map(|p| repo_root().join(p))
        .collect();
    assert!(!bins.is_empty(), "ROVE_BOARD_BINS names no binary");
    for bin in &bins {
        let arch = elf_arch(bin);
        assert!(
            matches!(arch, Some("arm64" | "armhf")),
            "{}: not a board's binary ({arch:?})",
            bin.display()
        );
    }
    bins
}

fn ok(what: &str, out: Output) -> String {
    let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
    assert!(
        out.status.success(),
        "{what}: {}\n{stdout}{}",
        out.status,
        String::from_utf8_lossy(&out.stderr)
    );
    stdout
}

#[test]
#[ignore = "needs ROVE_BOARD_BINS: rove cross-built for the boards (.ci/run builds them and runs this)"]
fn the_board_binaries_run_their_version_configs_failsafe_and_demo() {
    let native_demo = ok(
        "native demo",
        run_any_arch(ROVE.as_ref())
            .args(["demo", "--in-process", "--fast"])
            .output()
            .expect("run rove"),
    );
    for bin in board_bins() {
        let name = format!("{} ({})", bin.display(), elf_arch(&bin).unwrap_or("?"));
        let run = |args: &[&str]| {
            let what = format!("{name} {}", args.join(" "));
            let out = run_any_arch(&bin).args(args).output().expect("run qemu");
            ok(&what, out)
        };

        let version = run(&["--version"]);
        assert_eq!(
            version.trim(),
            format!("rove {}", env!("CARGO_PKG_VERSION"))
        );

        let mut configs: Vec<PathBuf> = std::fs::read_dir(repo_root().join("configs"))
            .expect("configs/")
            .filter_map(|e| Some(e.ok()?.path()))
            .filter(|p| p.extension().is_some_and(|e| e == "toml"))
            .collect();
        configs.sort();
        assert!(configs.len() >= 10, "{configs:?}");
        for config in &configs {
            run(&["check-config", config.to_str().expect("utf-8 path")]);
        }

        let scratch = Scratch::new("board-failsafe");
        let root = fake_sysfs(&scratch.dir);
        // A crashed gateway left the throttle at full.
        std::fs::write(root.join("pwmchip0/pwm1/duty_cycle"), "2000000").expect("duty");
        let config = scratch.dir.join("vehicle.toml");
        std::fs::write(&config, vehicle_toml(7, &eyedrive_sysfs(&root))).expect("config");
        run(&["failsafe", "-c", config.to_str().expect("utf-8 path")]);
        assert_eq!(
            (duty(&root, 0), duty(&root, 1)),
            ("1500000".into(), "1500000".into())
        );

        let demo = run(&["demo", "--in-process", "--fast"]);
        assert_eq!(demo, native_demo, "{name}: the demo's story differs");
    }
}
