//! The Debian package. `[package.metadata.deb]` in gateway/Cargo.toml must install
//! the binary, every unit in systemd/, the configs the units name (as conffiles), the examples
//! and the deployment guide.
//!
//! With `ROVE_DEB=path/to/rove_….deb` (absolute, or relative to the workspace root; `.ci/run`
//! sets it after `cargo deb`), the built package itself is opened with `dpkg-deb` and checked:
//! its file list, conffiles and maintainer scripts, that its binary runs and accepts its own
//! default configs, and (as root) that postinst creates the `rove` user, against a copy of
//! `/etc` in a private mount namespace so the machine's own users are untouched.

use crate::util::{Scratch, elf_arch, repo_root, run_any_arch};
use std::collections::BTreeSet;
use std::path::Path;
use std::process::Command;

/// `gateway/`: the package's directory, which cargo-deb's asset sources are relative to.
const GATEWAY: &str = env!("CARGO_MANIFEST_DIR");

fn metadata() -> toml::Table {
    let path = Path::new(GATEWAY).join("Cargo.toml");
    let text = std::fs::read_to_string(&path).expect("gateway/Cargo.toml");
    let manifest: toml::Table = toml::from_str(&text).expect("Cargo.toml parses");
    manifest["package"]["metadata"]["deb"]
        .as_table()
        .expect("[package.metadata.deb]")
        .clone()
}

/// `(source, dest, mode)` of every asset.
fn assets(deb: &toml::Table) -> Vec<(String, String, String)> {
    deb["assets"]
        .as_array()
        .expect("assets")
        .iter()
        .map(|a| {
            let a = a.as_array().expect("an asset is [source, dest, mode]");
            let s = |i: usize| a[i].as_str().expect("asset strings").to_string();
            (s(0), s(1), s(2))
        })
        .collect()
}

fn unit_files() -> Vec<String> {
    let mut units: Vec<String> = std::fs::read_dir(repo_root().join("systemd"))
        .expect("systemd/")
        .filter_map(|e| e.ok()?.file_name().into_string().ok())
        .filter(|n| n.ends_with(".service"))
        .collect();
    units.sort();
    units
}

/// The `conf-files` of a `[package.metadata.deb]` table (or a variant's).
fn conf_files(deb: &toml::Table) -> Vec<String> {
    (deb["conf-files"].as_array().expect("conf-files").iter())
        .filter_map(|v| v.as_str().map(String::from))
        .collect()
}

/// The unit of `rove bridge`, a role only binaries built with the `remote` feature have.
const BRIDGE_UNIT: &str = "rove-bridge.service";

/// The units a package whose binary has (`bridge`) or lacks the bridge role must install.
fn units_for(bridge: bool) -> Vec<String> {
    let mut units = unit_files();
    units.retain(|u| bridge || u != BRIDGE_UNIT);
    units
}

/// The `/etc/rove/…` files the (non-template) units run with.
fn configs_named_by_units(units: &[String]) -> BTreeSet<String> {
    let mut configs = BTreeSet::new();
    for unit in units.iter().filter(|u| !u.contains('@')) {
        let text =
            std::fs::read_to_string(repo_root().join("systemd").join(unit)).expect("unit file");
        let exec_lines = text.lines().filter(|l| l.trim_start().starts_with("Exec"));
        for word in exec_lines.flat_map(str::split_whitespace) {
            if word.starts_with("/etc/rove/") {
                configs.insert(word.to_string());
            }
        }
    }
    configs
}

#[test]
fn the_package_installs_the_binary_units_conffiles_examples_and_guide() {
    let deb = metadata();
    assert_eq!(deb["name"].as_str(), Some("rove"));
    let assets = assets(&deb);
    let installs = |dest: &str| assets.iter().find(|(_, d, _)| d == dest);

    let binary = installs("usr/bin/").expect("the binary");
    assert_eq!(
        (binary.0.as_str(), binary.2.as_str()),
        ("target/release/rove", "755")
    );
    let units = unit_files();
    assert!(units.len() >= 3, "{units:?}");
    for unit in &units {
        let source = format!("../systemd/{unit}");
        assert!(
            assets
                .iter()
                .any(|(s, d, m)| *s == source && d == "lib/systemd/system/" && m == "644"),
            "{unit} is not installed to lib/systemd/system/"
        );
    }
    let conf_files = conf_files(&deb);
    let configs = configs_named_by_units(&units);
    assert!(configs.contains("/etc/rove/vehicle.toml"), "{configs:?}");
    assert!(configs.contains("/etc/rove/bridge.toml"), "{configs:?}");
    for config in &configs {
        let dest = config.trim_start_matches('/');
        assert!(
            installs(dest).is_some(),
            "{config} is named by a unit but not installed"
        );
        assert!(conf_files.contains(config), "{config} is not a conffile");
    }
    assert!(installs("usr/share/doc/rove/examples/").is_some());
    assert!(installs("usr/share/doc/rove/").is_some());

    // Every source exists (globs: the directory has a match); the binary is built by cargo deb.
    for (source, _, _) in &assets {
        if source.starts_with("target/release/") {
            continue;
        }
        let path = Path::new(GATEWAY).join(source);
        match source.split_once('*') {
            Some((dir, ext)) => {
                let dir = Path::new(GATEWAY).join(dir);
                let matches = std::fs::read_dir(&dir)
                    .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
                    .filter_map(|e| e.ok()?.file_name().into_string().ok())
                    .filter(|n| n.ends_with(ext))
                    .count();
                assert!(matches > 0, "{source} matches nothing");
            }
            None => assert!(path.is_file(), "{source} does not exist"),
        }
    }

    the_pi_variant_is_the_package_without_the_bridge(&deb);

    // The maintainer scripts exist, are executable and are shell scripts that parse.
    let scripts = Path::new(GATEWAY).join(deb["maintainer-scripts"].as_str().expect("dir"));
    for script in ["postinst", "prerm", "postrm"] {
        use std::os::unix::fs::PermissionsExt;
        let path = scripts.join(script);
        let mode = std::fs::metadata(&path)
            .unwrap_or_else(|e| panic!("{}: {e}", path.display()))
            .permissions()
            .mode();
        assert_eq!(mode & 0o111, 0o111, "{script} is not executable");
        let parsed = Command::new("sh")
            .arg("-n")
            .arg(&path)
            .status()
            .expect("sh");
        assert!(parsed.success(), "{script} does not parse");
    }
}

/// The Pi variant is built without the `remote` feature, so its binary has no `rove bridge`:
/// it installs what the main package does but the bridge's unit, config and guide.
fn the_pi_variant_is_the_package_without_the_bridge(deb: &toml::Table) {
    let pi = deb["variants"]["pi"].as_table().expect("[…variants.pi]");
    let features: Vec<&str> = (pi["features"].as_array().expect("pi features").iter())
        .filter_map(|f| f.as_str())
        .collect();
    assert_eq!(pi["default-features"].as_bool(), Some(false));
    assert!(!features.contains(&"remote"), "{features:?}");
    let of_bridge = |(source, _, _): &(String, String, String)| {
        source.contains("bridge") || source.ends_with("remote.md")
    };
    let mut without: Vec<_> = assets(deb);
    let before = without.len();
    without.retain(|a| !of_bridge(a));
    assert_eq!(
        before - without.len(),
        3,
        "the bridge's unit, config and guide"
    );
    assert_eq!(assets(pi), without);
    let mut main = conf_files(deb);
    main.retain(|c| c != "/etc/rove/bridge.toml");
    assert_eq!(conf_files(pi), main);
}

/// `dpkg-deb OPTION DEB REST…`'s output.
fn dpkg_deb(option: &str, deb: &Path, rest: &[&str]) -> String {
    let out = Command::new("dpkg-deb")
        .arg(option)
        .arg(deb)
        .args(rest)
        .output()
        .expect("run dpkg-deb");
    assert!(
        out.status.success(),
        "dpkg-deb {option} {} {rest:?}: {}",
        deb.display(),
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

#[test]
#[ignore = "needs ROVE_DEB: packages built by `cargo deb` (.ci/run builds them and runs this)"]
fn the_built_packages_hold_binary_units_and_conffiles() {
    let debs = std::env::var_os("ROVE_DEB")
        .expect("set ROVE_DEB to packages built by `cargo deb -p rove-gateway`");
    // Tests run in gateway/; a relative path is taken from the workspace root, where
    // `cargo deb` is run.
    for deb in debs.to_string_lossy().split_whitespace() {
        check_package(&repo_root().join(deb));
    }
}

/// One package, for any of the architectures: a board's binary runs under qemu-user.
fn check_package(deb: &Path) {
    let scratch = Scratch::new("deb");
    let dir = &scratch.dir;
    // The packaged binary is for the package's architecture and runs (under qemu-user for a
    // board's); whether it has `rove bridge` says which units the package must hold.
    let root = dir.join("root");
    dpkg_deb("--extract", deb, &[root.to_str().expect("utf-8 temp dir")]);
    let binary = root.join("usr/bin/rove");
    let arch = dpkg_deb("--field", deb, &["Architecture"]);
    assert_eq!(elf_arch(&binary), Some(arch.trim()), "{}", deb.display());
    let bridge = (run_any_arch(&binary).args(["bridge", "--help"]).output())
        .expect("run the packaged rove")
        .status
        .success();
    let units = units_for(bridge);

    // `drwxr-xr-x root/root 0 2024-01-01 00:00 ./usr/bin/` → mode and path.
    let listing = dpkg_deb("--contents", deb, &[]);
    let files: Vec<(&str, &str)> = listing
        .lines()
        .filter_map(|l| {
            let mut words = l.split_whitespace();
            Some((words.next()?, words.last()?))
        })
        .collect();
    let mode = |path: &str| {
        files
            .iter()
            .find(|(_, p)| *p == path)
            .map(|(m, _)| *m)
            .unwrap_or_else(|| panic!("{path} is not in the package:\n{listing}"))
    };
    assert_eq!(mode("./usr/bin/rove"), "-rwxr-xr-x");
    for unit in &units {
        assert_eq!(mode(&format!("./lib/systemd/system/{unit}")), "-rw-r--r--");
    }
    if !bridge {
        let unit = format!("./lib/systemd/system/{BRIDGE_UNIT}");
        assert!(
            files.iter().all(|(_, p)| *p != unit),
            "{unit} in a package whose binary has no `rove bridge`"
        );
    }
    for path in [
        "./etc/rove/vehicle.toml",
        "./etc/rove/operator.toml",
        "./usr/share/doc/rove/deploy.md",
        "./usr/share/doc/rove/examples/vehicle-sim.toml",
        "./usr/share/doc/rove/examples/vehicle-eyedrive-pi.toml",
    ] {
        assert_eq!(mode(path), "-rw-r--r--", "{path}");
    }

    assert_eq!(dpkg_deb("--field", deb, &["Package"]).trim(), "rove");
    let depends = dpkg_deb("--field", deb, &["Depends"]);
    assert!(depends.contains("passwd"), "Depends: {depends}");

    // Control files: conffiles and the maintainer scripts.
    let control = dir.join("control");
    dpkg_deb(
        "--control",
        deb,
        &[control.to_str().expect("utf-8 temp dir")],
    );
    let conffiles = std::fs::read_to_string(control.join("conffiles")).expect("conffiles");
    let conffiles: BTreeSet<&str> = conffiles.lines().map(str::trim).collect();
    let configs = configs_named_by_units(&units);
    for config in &configs {
        assert!(
            conffiles.contains(config.as_str()),
            "{config}: {conffiles:?}"
        );
    }
    let prerm = std::fs::read_to_string(control.join("prerm")).expect("prerm");
    assert!(prerm.contains("systemctl --system stop"), "{prerm}");
    postinst_creates_the_service_user(&control.join("postinst"), dir);

    // The packaged binary accepts the packaged default configs.
    for config in &configs {
        let out = run_any_arch(&binary)
            .arg("check-config")
            .arg(root.join(config.trim_start_matches('/')))
            .output()
            .expect("run the packaged rove");
        assert!(
            out.status.success(),
            "{config}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
    }
    // A release build cannot be told to skip the certificate's identity check (the test hook
    // exists in debug builds only): clap refuses the flag before any config is read.
    let out = run_any_arch(&binary)
        .args(["operator", "--test-any-certificate", "--headless", "-c"])
        .arg(root.join("etc/rove/operator.toml"))
        .output()
        .expect("run the packaged rove");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{stderr}");
    assert!(stderr.contains("unexpected argument"), "{stderr}");
    // Nor be told to stall its control loop on SIGUSR1 (issue 45: the packages carry no test
    // hook).
    let out = run_any_arch(&binary)
        .args(["vehicle", "--test-stall-on-sigusr1", "100", "-c"])
        .arg(root.join("etc/rove/vehicle.toml"))
        .output()
        .expect("run the packaged rove");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{stderr}");
    assert!(stderr.contains("unexpected argument"), "{stderr}");
}

/// Runs `postinst configure` twice (install, then as an upgrade) with a copy of `/etc` mounted
/// over `/etc` in a private mount namespace, and checks that the system user `rove` exists
/// with no login shell and is in `dialout` (a group every Debian has). Needs root and
/// util-linux's `unshare`.
fn postinst_creates_the_service_user(postinst: &Path, scratch: &Path) {
    let is_root = Command::new("id")
        .arg("-u")
        .output()
        .is_ok_and(|o| String::from_utf8_lossy(&o.stdout).trim() == "0");
    assert!(
        is_root,
        "running postinst needs root (a private mount namespace)"
    );
    let etc = scratch.join("etc");
    let copied = Command::new("cp")
        .args(["-a", "/etc"])
        .arg(&etc)
        .status()
        .expect("cp");
    assert!(copied.success(), "cannot copy /etc");
    let script = format!(
        "mount --bind '{etc}' /etc && sh -e '{postinst}' configure && \
         sh -e '{postinst}' configure 0.1.0-1 && getent passwd rove && id -nG rove",
        etc = etc.display(),
        postinst = postinst.display()
    );
    let out = Command::new("unshare")
        .args(["--mount", "sh", "-c", &script])
        .output()
        .expect("run unshare");
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "postinst: {stdout}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let mut lines = stdout.lines().rev();
    let groups: Vec<&str> = lines
        .next()
        .unwrap_or_default()
        .split_whitespace()
        .collect();
    let passwd = lines.next().unwrap_or_default();
    assert!(
        passwd.starts_with("rove:") && passwd.ends_with(":/nonexistent:/usr/sbin/nologin"),
        "{passwd}"
    );
    assert!(
        groups.contains(&"rove") && groups.contains(&"dialout"),
        "{groups:?}"
    );
}
