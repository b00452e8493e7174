//! The config files: loading, validation, and errors that name file, line and key.

use super::*;

/// A config file written for one test, in a directory of its own that is removed with it.
struct Written {
    path: PathBuf,
    _dir: tempfile::TempDir,
}

impl std::ops::Deref for Written {
    type Target = Path;
    fn deref(&self) -> &Path {
        &self.path
    }
}

fn write(name: &str, text: &str) -> Written {
    let dir = tempfile::tempdir().expect("temp dir");
    let path = dir.path().join(name);
    std::fs::write(&path, text).expect("write");
    Written { path, _dir: dir }
}

/// Issue 30: docs/mavlink.md's steps drive what they start. In each section of the guide,
/// every operator config it names drives every vehicle config it names, and a vehicle's
/// MAVLink `connection` is the endpoint the section gives (in backquotes).
#[test]
fn the_mavlink_guides_steps_drive_the_vehicles_they_start() {
    let guide = shipped("../docs/mavlink.md");
    let text = std::fs::read_to_string(&guide).expect("docs/mavlink.md");
    let named = |section: &str, role: &str| -> Vec<String> {
        let needle = format!("rove {role} -c configs/");
        section
            .match_indices(&needle)
            .filter_map(|(at, _)| {
                let rest = &section[at + needle.len()..];
                let end = rest.find(|c: char| c.is_whitespace() || c == '`')?;
                Some(rest[..end].to_string())
            })
            .collect()
    };
    let mut pairs = 0;
    for section in text.split("\n## ") {
        let vehicles = named(section, "vehicle");
        let operators = named(section, "operator");
        for vehicle in &vehicles {
            let path = shipped(vehicle);
            let config = load_vehicle(&path).unwrap_or_else(|e| panic!("{e:#}"));
            let raw: toml::Table =
                toml::from_str(&std::fs::read_to_string(&path).expect("read")).expect("toml");
            if let Some(connection) = raw
                .get("output")
                .and_then(|o| o.get("connection"))
                .and_then(|c| c.as_str())
            {
                assert!(
                    section.contains(&format!("`{connection}`")),
                    "{vehicle}: connection {connection} is not the guide's"
                );
            }
            for operator in &operators {
                let op = load_operator(&shipped(operator)).unwrap_or_else(|e| panic!("{e:#}"));
                assert!(
                    op.drive.contains(&config.common.id),
                    "{operator} drives {:?}, not {vehicle}'s id {}",
                    op.drive,
                    config.common.id
                );
                pairs += 1;
            }
        }
    }
    assert!(pairs >= 2, "the guide names {pairs} vehicle/operator pairs");
}

#[test]
fn every_shipped_config_loads() {
    let dir = shipped("");
    let mut seen = 0;
    for entry in std::fs::read_dir(&dir).expect("configs/ exists") {
        let path = entry.expect("entry").path();
        if path.extension().is_some_and(|e| e == "toml") {
            let (config, effective) = load_any(&path).unwrap_or_else(|e| panic!("{e:#}"));
            // The effective config loads again as the same config, and is a fixed point.
            let again = any_from_text(Path::new("effective.toml"), &effective);
            let (again, effective_again) = again.unwrap_or_else(|e| panic!("{e:#}\n{effective}"));
            assert_eq!(
                format!("{again:?}"),
                format!("{config:?}"),
                "{}",
                path.display()
            );
            assert_eq!(effective_again, effective, "{}", path.display());
            seen += 1;
        }
    }
    assert!(seen >= 3, "only {seen} configs in {}", dir.display());
}

#[test]
fn each_output_adapter_loads_from_its_shipped_example() {
    let kind = |name: &str| match load_vehicle(&shipped(name)) {
        Ok(c) => c.output.adapter(),
        Err(e) => panic!("{e:#}"),
    };
    assert_eq!(kind("vehicle-sim.toml"), "sim");
    assert_eq!(kind("vehicle-custom-pwm.toml"), "pwm");
    assert_eq!(kind("vehicle-eyedrive-pi.toml"), "eyedrive");
    assert_eq!(kind("vehicle-naza-pi.toml"), "naza");
    assert_eq!(kind("vehicle-ros2-diffdrive.toml"), "ros2");
    assert_eq!(kind("vehicle-ardupilot-rover-sitl.toml"), "mavlink");
    assert_eq!(kind("vehicle-ardupilot-copter-serial.toml"), "mavlink");
    assert_eq!(kind("vehicle-px4-udp.toml"), "mavlink");
    assert_eq!(kind("vehicle-can-skid-steer.toml"), "can");
    assert_eq!(kind("vehicle-dronecan-servos.toml"), "can");
}

#[test]
fn access_lists_who_may_drive_and_its_errors_name_their_keys() {
    let head = "[device]\nid = 100\n[output]\nadapter = \"sim\"\n";
    let open = load_vehicle(&write("open.toml", head)).expect("loads");
    assert!(open.access.is_open());
    let listed = format!(
        "{head}[access]\noperators = [\n  {{ id = 11, level = \"stationary\", \
         device_class = \"laptop\" }},\n]\n"
    );
    let config = load_vehicle(&write("access.toml", &listed)).expect("loads");
    assert!(!config.access.is_open());
    assert_eq!(config.access.check_strength(11, Strength(229)), Ok(()));
    assert!(config.access.check_strength(12, Strength(110)).is_err());
    let bad = format!(
        "{head}[access]\noperators = [\n  {{ id = 11, level = \"mobile\", device_class = \"phone\" }},\n  \
         {{ id = 11, level = \"remote\", device_class = \"desktop\" }},\n]\n"
    );
    let e = format!(
        "{:#}",
        load_vehicle(&write("bad-access.toml", &bad)).expect_err("dup")
    );
    assert!(
        e.contains("access.operators[1].id = 11: must be unique"),
        "{e}"
    );
    let typo = format!("{head}[access]\noperators = [{{ id = 11, levle = \"mobile\" }}]\n");
    let e = format!(
        "{:#}",
        load_vehicle(&write("typo.toml", &typo)).expect_err("typo")
    );
    assert!(e.contains("levle"), "{e}");
}

#[test]
fn web_devices_are_operators_of_their_own_and_their_errors_name_lines() {
    let config = load_operator(&shipped("operator-web.toml")).expect("shipped web host");
    let web = config.web.expect("[web]");
    assert_eq!(web.listen.port(), 8443);
    assert_eq!(web.session, Duration::from_secs(43_200));
    let (cert, _) = web.certificate.expect("files");
    assert_eq!(cert, Path::new("/var/lib/rove/web-cert.pem"));
    let phone = &web.devices[0];
    assert_eq!((phone.common.id, phone.strength), (40, Strength(340)));
    assert_eq!(phone.drive, vec![100]);
    assert_eq!(phone.common.domain_id, config.common.domain_id);
    assert_eq!(web.devices[1].strength, Strength(330), "a mobile tablet");
    let text = "[device]\nid = 20\n[operator]\nlevel = \"remote\"\ndevice_class = \"desktop\"\n\
                [security]\ndir = \"keys\"\n[web]\nlisten = \"8443\"\ncertificate = \"a.pem\"\n\
                session_s = 0\n[[web.device]]\nid = 20\n[[web.device]]\nid = 41\noffset = 12\n";
    let message = format!(
        "{:#}",
        load_operator(&write("web.toml", text)).expect_err("bad")
    );
    for want in [
        "web.toml:9: web.listen = 8443: must be ADDRESS:PORT",
        "web.toml:8: web.key = (absent): is required with `certificate`",
        "web.toml:11: web.session_s = 0: must be 1..=2592000 s",
        "web.toml:13: web.device[0].id = 20: is used twice",
        "web.toml:12: web.device[0].security = (absent): is required",
        "web.toml:16: web.device[1].offset = 12: must be 0..=9",
    ] {
        assert!(message.contains(want), "missing {want:?} in\n{message}");
    }
    let none = "[device]\nid = 20\n[operator]\nlevel = \"remote\"\ndevice_class = \"desktop\"\n\
                [web]\nlisten = \"127.0.0.1:1\"\n";
    let message = format!(
        "{:#}",
        load_operator(&write("none.toml", none)).expect_err("no device")
    );
    assert!(
        message.contains("web.device = (absent): needs at least one"),
        "{message}"
    );
}

#[test]
fn bridge_files_say_who_may_speak_and_their_errors_name_lines() {
    let lab = load_bridge(&shipped("bridge-lab.toml")).expect("shipped lab bridge");
    assert_eq!(lab.policy.me.as_str(), "lab");
    assert_eq!(lab.link.listen, vec!["tls/203.0.113.7:7447".to_string()]);
    assert_eq!(lab.link.lease, Duration::from_secs(3));
    let home = &lab.policy.peers[0];
    assert_eq!(home.name.as_str(), "home");
    assert_eq!(home.ids, [21, 22].into());
    assert_eq!(home.offer, [100].into());
    assert_eq!(home.level, Level::Remote);
    let text = "[site]\nname = \"Lab\"\n[zenoh]\nlisten = [\"tcp/1.2.3.4:7447\"]\n\
                connect = [\"tls/nowhere\"]\nca = \"a\"\ncertificate = \"b\"\nkey = \"c\"\n\
                lease_ms = 10\n[[zenoh.site]]\nname = \"home\"\nids = [0, 7]\n\
                [[zenoh.site]]\nname = \"home\"\nlevel = \"mobile\"\nids = [7, 9]\n\
                offer = [9]\n";
    let message = format!(
        "{:#}",
        load_bridge(&write("b.toml", text)).expect_err("bad")
    );
    for want in [
        "b.toml:2: site.name = \"Lab\": must be lowercase letters",
        "b.toml:4: zenoh.listen[0] = \"tcp/1.2.3.4:7447\": must be `tls/HOST:PORT`",
        "b.toml:5: zenoh.connect[0] = \"tls/nowhere\": must be `tls/HOST:PORT` (no port)",
        "b.toml:9: zenoh.lease_ms = 10: must be 1000..=60000 ms",
        "b.toml:12: zenoh.site[0].ids[0] = 0: must be a positive device id",
        "b.toml:14: zenoh.site[1].name = \"home\": must be unique: site[0]",
        "b.toml:16: zenoh.site[1].ids[0] = 7: must be unique: site[0].ids",
        "b.toml:16: zenoh.site[1].ids[1] = 9: is offered as this site's vehicle",
    ] {
        assert!(message.contains(want), "missing {want:?} in\n{message}");
    }
    // An unknown key names its line; a secured site's `[security] dir` is the config's.
    let text = "[site]\nname = \"lab\"\n[zenoh]\nlisten = [\"tls/a:1\"]\nca = \"a\"\n\
                certificate = \"b\"\nkey = \"c\"\n[security]\ndir = \"d\"\n";
    let path = write("s.toml", text);
    let security = load_bridge(&path).expect("loads").common.security;
    assert_eq!(security, Some(path.parent().expect("dir").join("d")));
    let text = text.replace("dir =", "directory =");
    let message = format!(
        "{:#}",
        load_bridge(&write("s.toml", &text)).expect_err("bad")
    );
    assert!(
        message.contains("s.toml:9: unknown field `directory`"),
        "{message}"
    );
    // A relative key file is the config file's directory's.
    let text = "[site]\nname = \"a\"\n[zenoh]\nlisten = [\"tls/a:1\"]\nca = \"k/ca.pem\"\n\
                certificate = \"b\"\nkey = \"c\"\n";
    let path = write("rel.toml", text);
    let ca = load_bridge(&path).expect("loads").link.ca;
    assert_eq!(ca, path.parent().expect("dir").join("k/ca.pem"));
}

#[test]
fn a_bridge_checks_its_certificate_files_are_readable_files() {
    let text = "[site]\nname = \"a\"\n[zenoh]\nlisten = [\"tls/a:1\"]\nca = \"certs/ca.pem\"\n\
                certificate = \"certs/cert.pem\"\nkey = \"certs/KEY\"\n";
    let path = write("files.toml", text);
    let dir = path.parent().expect("dir").join("certs");
    std::fs::create_dir_all(&dir).expect("certs dir");
    for file in ["ca.pem", "cert.pem"] {
        std::fs::write(dir.join(file), file).expect("write");
    }
    let mut link = load_bridge(&path).expect("loads").link;
    let missing = format!("{:#}", link.check_files().expect_err("no key"));
    assert!(
        missing.starts_with("[zenoh] key = ") && missing.contains("KEY"),
        "{missing}"
    );
    link.key = dir.clone();
    let directory = format!("{:#}", link.check_files().expect_err("a directory"));
    assert!(directory.contains("not a file"), "{directory}");
    link.key = dir.join("cert.pem");
    link.check_files().expect("three readable files");
}

#[test]
fn output_errors_name_the_line_of_the_channel_key() {
    let text = "[device]\nid = 7\n[output]\nadapter = \"pwm\"\nbackend = \"sim\"\n\
                [[output.channels]]\nname = \"a\"\nsource = \"roll\"\nchannel = 0\n\
                [[output.channels]]\nname = \"b\"\nsource = \"yaw\"\nchannel = 1\n\
                min_us = 2000\nmax_us = 1000\n";
    let path = write("bad-channel.toml", text);
    let message = format!("{:#}", load_vehicle(&path).expect_err("min > max"));
    // min > max is reported on the centre (not written: the channel's header line).
    assert!(
        message.contains("bad-channel.toml:10: output.channels[1].centre_us"),
        "{message}"
    );
    // The sim adapter takes no other keys.
    let path = write(
        "sim-extra.toml",
        "[device]\nid = 7\n[output]\nadapter = \"sim\"\nbackend = \"sysfs\"\n",
    );
    let message = format!("{:#}", load_vehicle(&path).expect_err("unknown key"));
    assert!(message.contains("backend"), "{message}");
    // An unknown adapter is named.
    let path = write(
        "warp.toml",
        "[device]\nid = 7\n[output]\nadapter = \"warp\"\n",
    );
    let message = format!("{:#}", load_vehicle(&path).expect_err("unknown adapter"));
    assert!(message.contains("warp"), "{message}");
}

#[test]
fn errors_inside_output_name_the_line_of_their_key() {
    // A misspelt key in the second channel table: line 17, not `[output]`'s line.
    let text = "[device]\nid = 7\n\n# a comment\n\n[output]\nadapter = \"pwm\"\n\
                backend = \"sim\"\n\n[[output.channels]]\nname = \"a\"\nsource = \"roll\"\n\n\
                [[output.channels]]\nname = \"b\"\nsource = \"yaw\"\nmax_uss = 1900\n";
    let path = write("bad.toml", text);
    let message = format!("{:#}", load_vehicle(&path).expect_err("misspelt key"));
    assert!(
        message.contains("bad.toml:17: output.channels[1].max_uss = 1900: unknown key"),
        "{message}"
    );
    // A type error in a table serde reads directly (no flattening) names its line too.
    let text = "[device]\nid = 7\n[output]\nadapter = \"mavlink\"\n[output.modes]\n\
                set_mode = \"no\"\n";
    let path = write("bad-type.toml", text);
    let message = format!("{:#}", load_vehicle(&path).expect_err("bad type"));
    assert!(message.contains("bad-type.toml:6:"), "{message}");
    // An inline `[output]` and an alias written in the file.
    let text = "# inline\noutput = { backend = \"sim\", adapter = \"pwm\", \
                channels = [{ name = \"a\", source = \"roll\", deadzone_pct = 70 }] }\n\
                [device]\nid = 7\n";
    let path = write("inline.toml", text);
    let message = format!("{:#}", load_vehicle(&path).expect_err("deadband too wide"));
    assert!(
        message.contains("inline.toml:2: output.channels[0].deadband_pct = 70"),
        "{message}"
    );
    // Out-of-range integers are reported against their key, all at once.
    let text = "[device]\nid = 7\n[network]\ndomain_id = 70000\nheartbeat_ms = -1\n\
                presence_ms = 10000\n[output]\nadapter = \"sim\"\n";
    let path = write("ints.toml", text);
    let message = format!("{:#}", load_vehicle(&path).expect_err("ranges"));
    assert!(
        message.contains("ints.toml:4: network.domain_id = 70000: must be 0..=232"),
        "{message}"
    );
    assert!(
        message.contains("ints.toml:5: network.heartbeat_ms = -1: must be 50..=10000"),
        "{message}"
    );
    assert!(
        message.contains("ints.toml:6: network.presence_ms = 10000: must be 250..=500"),
        "{message}"
    );
    let text = "[device]\nid = 5\n[operator]\nlevel = \"mobile\"\ndevice_class = \"phone\"\n\
                offset = 300\n[hierarchy]\nmobile = { laptop = 70000 }\n[handover]\nresend_ms = -1\n";
    let path = write("wide.toml", text);
    let message = format!("{:#}", load_operator(&path).expect_err("ranges"));
    for want in [
        "wide.toml:8: hierarchy.mobile.laptop = 70000: must be 1..=65525",
        "wide.toml:6: operator.offset = 300: must be 0..=9",
        "wide.toml:10: handover.resend_ms = -1: must be 0..=9223372036854775807 ms",
    ] {
        assert!(message.contains(want), "missing {want:?} in\n{message}");
    }
}

#[test]
fn log_level_is_checked_and_keeps_rustdds_quiet() {
    let base = "[device]\nid = 7\n[output]\nadapter = \"sim\"\n[log]\n";
    let path = write("log-ok.toml", &format!("{base}level = \"debug\"\n"));
    let config = load_vehicle(&path).expect("valid level");
    assert_eq!(
        config.common.log_filter.as_deref(),
        Some("debug,rustdds=warn")
    );
    let path = write(
        "log-rtps.toml",
        &format!("{base}level = \"info,rustdds=debug\"\n"),
    );
    let config = load_vehicle(&path).expect("valid directives");
    assert_eq!(
        config.common.log_filter.as_deref(),
        Some("info,rustdds=debug")
    );
    for bad in ["debgu", "loud=", "rustdds=verbose", ""] {
        let path = write("log-bad.toml", &format!("{base}level = \"{bad}\"\n"));
        let message = format!("{:#}", load_vehicle(&path).expect_err("bad level"));
        assert!(
            message.contains("log-bad.toml:6: log.level"),
            "{bad}: {message}"
        );
    }
    assert_eq!(
        load_vehicle(&shipped("vehicle-sim.toml"))
            .map(|c| c.common.log_filter)
            .ok(),
        Some(None)
    );
}

#[test]
fn unknown_key_names_file_line_and_key() {
    let path = write(
        "unknown.toml",
        "[device]\nid = 5\n\n[operator]\nlevel = \"mobile\"\ndevice_class = \"phone\"\nstream_rate = 5\n",
    );
    let err = format!("{:#}", load_operator(&path).expect_err("unknown key"));
    assert!(err.contains("unknown.toml:7:"), "{err}");
    assert!(err.contains("unknown field `stream_rate`"), "{err}");
}

#[test]
fn invalid_values_are_all_reported_with_their_lines() {
    let path = write(
        "invalid.toml",
        "[device]\nid = 5\n\n[operator]\nlevel = \"mobile\"\ndevice_class = \"phone\"\n\
         offset = 12\nstream_hz = 0\ndrive = [5]\n\n[hierarchy]\nmobile = { laptop = 315 }\n",
    );
    let err = format!("{:#}", load_operator(&path).expect_err("invalid"));
    for expected in [
        "invalid.toml:12: hierarchy.mobile.laptop = 315",
        "invalid.toml:7: operator.offset = 12",
        "invalid.toml:8: operator.stream_hz = 0",
        "invalid.toml:9: operator.drive[0] = 5",
    ] {
        assert!(err.contains(expected), "missing {expected:?} in:\n{err}");
    }
}

#[test]
fn vehicle_defaults_are_quiet_and_bad_timeout_is_loud() {
    let path = write(
        "vehicle.toml",
        "[device]\nid = 100\n\n[output]\nadapter = \"sim\"\n",
    );
    let v = load_vehicle(&path).expect("valid");
    assert_eq!(v.common.interfaces, [Ipv4Addr::LOCALHOST]);
    assert_eq!(v.arbiter.command_timeout, CommandTimeout::DEFAULT);
    assert_eq!(v.common.name, "rove-100");
    assert_eq!(v.common.presence, crate::dds::DEFAULT_PRESENCE);
    let path = write(
        "vehicle-bad.toml",
        "[device]\nid = 100\n[vehicle]\ncommand_timeout_ms = 0\n[output]\nadapter = \"sim\"\n",
    );
    let err = format!("{:#}", load_vehicle(&path).expect_err("timeout 0"));
    assert!(
        err.contains("vehicle-bad.toml:4: vehicle.command_timeout_ms = 0"),
        "{err}"
    );
}

#[test]
fn unknown_adapter_is_rejected_naming_the_line() {
    let path = write(
        "adapter.toml",
        "[device]\nid = 100\n[output]\nadapter = \"warp\"\n",
    );
    let err = format!("{:#}", load_vehicle(&path).expect_err("no such adapter"));
    assert!(
        err.contains("adapter.toml:4: output.adapter = \"warp\""),
        "{err}"
    );
    // The message lists every adapter of the gateway's list, with what it drives.
    for adapter in ADAPTERS {
        let line = format!("{:?}: {}", adapter.name, adapter.summary);
        assert!(err.contains(&line), "{line} not in {err}");
    }
    // A missing adapter names `[output]`'s line.
    let path = write(
        "none.toml",
        "[device]\nid = 100\n\n[output]\nbackend = \"sim\"\n",
    );
    let err = format!("{:#}", load_vehicle(&path).expect_err("no adapter"));
    assert!(
        err.contains("none.toml:4: output.adapter = (absent)"),
        "{err}"
    );
}

#[test]
fn key_line_finds_tables_keys_and_inline_entries() {
    let text = "[a]\nx = 1\n[b.c]\ny = { z = 2 }\n";
    assert_eq!(key_line(text, "a.x"), Some(2));
    assert_eq!(key_line(text, "b.c.y.z"), Some(4));
    assert_eq!(key_line(text, "b.c"), Some(3));
    assert_eq!(key_line(text, "q"), None);
    let text = "[output]\nadapter = \"pwm\"\n[[output.channels]]\nname = \"a\"\n\
                [[output.channels]]\nname = \"b\"\nmax_us = 3000\n";
    assert_eq!(key_line(text, "output.channels[1].max_us"), Some(7));
    assert_eq!(key_line(text, "output.channels[0].name"), Some(4));
    // A key left to its default points at its table's header.
    assert_eq!(key_line(text, "output.channels[1].min_us"), Some(5));
    assert_eq!(key_line(text, "output.adapter"), Some(2));
}
