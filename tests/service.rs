//! The systemd integration, tested without systemd (it is not PID 1 here and must
//! never be started as PID 1): the test plays the service manager's side of sd_notify, runs the
//! unit files' own `ExecStopPost=` command line after a SIGKILL, and checks what the unit files
//! promise. `systemd-analyze verify` and `security` run from `systemd/check-units` in CI.
//!
//! Every vehicle runs in a network namespace of its own (the util's [`Rig`]); its outputs are
//! an Eyedrive rover on the sysfs PWM backend over a temp directory.

use crate::util::{
    OperatorToml, PATIENCE, ROVE, Rig, Scratch, duty, eventually, eyedrive_sysfs, fake_sysfs,
    repo_root, vehicle_toml, wait_duty, wait_for_output,
};
use std::os::unix::net::UnixDatagram;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

const V: i64 = 100;
/// Neutral (1500 µs) in sysfs's nanoseconds: the Eyedrive's safe state on both channels.
const SAFE_NS: &str = "1500000";

/// `systemd/`: the unit files.
fn units() -> PathBuf {
    repo_root().join("systemd")
}

// ---------------------------------------------------------------------------------------------
// Unit files

/// A unit file's directives in order, as `(section, key, value)`; comments and blank lines are
/// dropped. (No line continuations: the units do not use them, and this test would catch one as
/// a key without `=`.)
fn directives(text: &str) -> Vec<(String, String, String)> {
    let mut section = String::new();
    let mut out = Vec::new();
    for (n, raw) in text.lines().enumerate() {
        let line = raw.trim();
        if line.is_empty() || line.starts_with('#') || line.starts_with(';') {
            continue;
        }
        if let Some(name) = line.strip_prefix('[').and_then(|l| l.strip_suffix(']')) {
            section = name.to_string();
            continue;
        }
        let (key, value) = line
            .split_once('=')
            .unwrap_or_else(|| panic!("line {}: not KEY=VALUE: {raw:?}", n + 1));
        out.push((section.clone(), key.trim().into(), value.trim().into()));
    }
    out
}

fn unit(name: &str) -> Vec<(String, String, String)> {
    let path = units().join(name);
    let text = std::fs::read_to_string(&path)
        .unwrap_or_else(|e| panic!("cannot read {}: {e}", path.display()));
    directives(&text)
}

fn values<'a>(unit: &'a [(String, String, String)], key: &str) -> Vec<&'a str> {
    unit.iter()
        .filter(|(_, k, _)| k == key)
        .map(|(_, _, v)| v.as_str())
        .collect()
}

fn one<'a>(unit: &'a [(String, String, String)], key: &str) -> &'a str {
    match values(unit, key).as_slice() {
        [value] => value,
        other => panic!("{key}= should be set once, is {other:?}"),
    }
}

/// An `Exec*=` line as the argv systemd runs: the `-`/`+`/`!`/`@`/`:` prefixes dropped and `%i`
/// expanded. Other specifiers and quoting are not supported (the test fails on them rather than
/// run something else than systemd would).
fn command_line(
    unit: &[(String, String, String)],
    key: &str,
    instance: Option<&str>,
) -> Vec<String> {
    let line = one(unit, key).trim_start_matches(['-', '+', '!', '@', ':']);
    let line = match instance {
        Some(i) => line.replace("%i", i),
        None => line.to_string(),
    };
    assert!(
        !line.contains(['%', '"', '\'', '\\', '$']),
        "{key}={line}: specifiers, quotes or variables this test cannot expand"
    );
    line.split_whitespace().map(String::from).collect()
}

fn arg_after<'a>(argv: &'a [String], flag: &str) -> &'a str {
    let at = argv
        .iter()
        .position(|a| a == flag)
        .unwrap_or_else(|| panic!("{argv:?} has no {flag}"));
    argv.get(at + 1)
        .unwrap_or_else(|| panic!("{argv:?}: nothing after {flag}"))
}

/// The argv with the installed paths replaced by this build's: `/usr/bin/rove` → the binary
/// under test, `/etc/rove/FILE` → `dir/FILE`.
fn localize(argv: &[String], dir: &Path) -> Vec<String> {
    argv.iter()
        .map(|a| match (a.as_str(), a.strip_prefix("/etc/rove/")) {
            ("/usr/bin/rove", _) => ROVE.to_string(),
            (_, Some(file)) => dir.join(file).to_string_lossy().into_owned(),
            _ => a.clone(),
        })
        .collect()
}

struct UnitCase {
    file: &'static str,
    role: &'static str,
    instance: Option<&'static str>,
}

const UNIT_FILES: [UnitCase; 4] = [
    UnitCase {
        file: "rove-vehicle.service",
        role: "vehicle",
        instance: None,
    },
    UnitCase {
        file: "rove-vehicle@.service",
        role: "vehicle",
        instance: Some("front"),
    },
    UnitCase {
        file: "rove-operator.service",
        role: "operator",
        instance: None,
    },
    UnitCase {
        file: "rove-bridge.service",
        role: "bridge",
        instance: None,
    },
];

#[test]
fn every_unit_notifies_checks_its_config_first_and_restarts_with_a_limit() {
    let on_disk: Vec<String> = std::fs::read_dir(units())
        .expect("systemd/")
        .filter_map(|e| e.ok()?.file_name().into_string().ok())
        .filter(|n| n.ends_with(".service"))
        .collect();
    assert_eq!(
        on_disk.len(),
        UNIT_FILES.len(),
        "units in systemd/: {on_disk:?}"
    );
    for case in &UNIT_FILES {
        let u = unit(case.file);
        let ctx = case.file;
        for (key, want) in [
            ("Type", "notify"),
            ("Restart", "always"),
            ("User", "rove"),
            ("NoNewPrivileges", "yes"),
            ("ProtectSystem", "strict"),
            ("CapabilityBoundingSet", ""),
        ] {
            assert_eq!(one(&u, key), want, "{ctx}: {key}=");
        }
        assert!(!one(&u, "WatchdogSec").is_empty(), "{ctx}: WatchdogSec=");
        assert!(
            one(&u, "MemoryMax").ends_with('M'),
            "{ctx}: a memory cap (MemoryMax=) turns a blow-up into a restart"
        );
        assert!(one(&u, "StartLimitBurst").parse::<u32>().is_ok(), "{ctx}");
        assert!(
            one(&u, "RestartPreventExitStatus")
                .split_whitespace()
                .any(|s| s == "78"),
            "{ctx}: a config error (exit 78) must not restart"
        );
        // The same file is checked, run and (for a vehicle) made safe.
        let start = command_line(&u, "ExecStart", case.instance);
        assert_eq!(&start[..2], ["/usr/bin/rove", case.role], "{ctx}");
        let config = arg_after(&start, "-c");
        assert!(config.starts_with("/etc/rove/"), "{ctx}: {config}");
        let check = command_line(&u, "ExecStartPre", case.instance);
        assert_eq!(check, ["/usr/bin/rove", "check-config", config], "{ctx}");
        if case.role == "vehicle" {
            let failsafe = command_line(&u, "ExecStopPost", case.instance);
            assert_eq!(
                failsafe,
                ["/usr/bin/rove", "failsafe", "-c", config],
                "{ctx}"
            );
        } else {
            assert!(values(&u, "ExecStopPost").is_empty(), "{ctx}");
        }
    }
}

#[test]
fn the_template_is_the_vehicle_unit_with_a_config_per_instance() {
    let plain = unit("rove-vehicle.service");
    let template: Vec<_> = unit("rove-vehicle@.service")
        .into_iter()
        .map(|(s, k, v)| {
            let v = v
                .replace("/etc/rove/vehicle-%i.toml", "/etc/rove/vehicle.toml")
                .replace("rove-vehicle-%i", "rove-vehicle")
                .replace("gateway %i (", "gateway (");
            (s, k, v)
        })
        .collect();
    assert_eq!(
        plain, template,
        "rove-vehicle@.service must differ from rove-vehicle.service only in %i"
    );
}

#[test]
fn the_installed_default_configs_are_valid() {
    for file in ["vehicle.toml", "operator.toml", "bridge.toml"] {
        let path = units().join("etc").join(file);
        let out = Command::new(ROVE)
            .arg("check-config")
            .arg(&path)
            .output()
            .expect("run rove check-config");
        assert!(
            out.status.success(),
            "{}: {}",
            path.display(),
            String::from_utf8_lossy(&out.stderr)
        );
    }
}

#[test]
fn a_bad_config_exits_78_from_every_role_so_systemd_stops_restarting() {
    let scratch = Scratch::new("service-bad");
    let dir = &scratch.dir;
    let bad = dir.join("bad.toml");
    // The config fails to load before any role touches the network.
    std::fs::write(&bad, "[device]\nid = 0\n[output]\nadapter = \"sim\"\n").expect("config");
    let roles = ["vehicle", "operator", "failsafe"];
    #[cfg(feature = "remote")]
    let roles = [&roles[..], &["bridge"]].concat();
    for role in roles {
        let out = Command::new(ROVE)
            .args([role, "-c"])
            .arg(&bad)
            .stdin(Stdio::null())
            .output()
            .expect("run rove");
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(78), "rove {role}: {stderr}");
        assert!(stderr.contains("bad.toml"), "rove {role}: {stderr}");
    }
    let missing = dir.join("missing.toml");
    let out = Command::new(ROVE)
        .args(["vehicle", "-c"])
        .arg(&missing)
        .output()
        .expect("run rove");
    assert_eq!(out.status.code(), Some(78));
}

#[test]
fn the_stall_test_hook_is_hidden_from_help() {
    let out = Command::new(ROVE)
        .args(["vehicle", "--help"])
        .output()
        .expect("run rove");
    let help = String::from_utf8_lossy(&out.stdout);
    assert!(help.contains("--record"), "{help}");
    assert!(!help.contains("stall"), "{help}");
}

// ---------------------------------------------------------------------------------------------
// sd_notify: the test is the service manager

/// systemd's end of `NOTIFY_SOCKET`: a datagram socket at a path. (An abstract `@name` would
/// not do here: abstract names are per network namespace, and the vehicle runs in its own. The
/// abstract form is covered by `sdnotify`'s unit tests.)
struct Manager {
    socket: UnixDatagram,
    path: PathBuf,
    seen: Vec<String>,
}

impl Manager {
    fn bind(dir: &Path) -> Manager {
        let path = dir.join("notify");
        let socket = UnixDatagram::bind(&path).expect("bind the notify socket");
        Manager {
            socket,
            path,
            seen: Vec::new(),
        }
    }

    /// The next notification within `within`, with its arrival time.
    fn recv(&mut self, within: Duration) -> Option<(Instant, String)> {
        self.socket
            .set_read_timeout(Some(within.max(Duration::from_millis(1))))
            .expect("timeout");
        let mut buf = [0u8; 4096];
        match self.socket.recv(&mut buf) {
            Ok(n) => {
                let text = String::from_utf8_lossy(&buf[..n]).into_owned();
                self.seen.push(text.clone());
                Some((Instant::now(), text))
            }
            Err(e)
                if matches!(
                    e.kind(),
                    std::io::ErrorKind::WouldBlock
                        | std::io::ErrorKind::TimedOut
                        // A signal arrived while waiting (the tests send SIGUSR1 and SIGTERM
                        // to children): the caller waits again for what is left.
                        | std::io::ErrorKind::Interrupted
                ) =>
            {
                None
            }
            Err(e) => panic!("notify socket: {e}"),
        }
    }

    /// Waits for a notification with the line `line` (or, ending in `…`, a line starting with
    /// it), skipping others.
    fn wait_for(&mut self, line: &str) -> (Instant, String) {
        self.wait_for_match(line, |text| has_line(text, line))
    }

    /// Waits for a notification that `matches`, skipping others.
    fn wait_for_match(&mut self, what: &str, matches: impl Fn(&str) -> bool) -> (Instant, String) {
        let deadline = Instant::now() + PATIENCE;
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            let Some((at, text)) = self.recv(left) else {
                panic!(
                    "no {what:?} within {PATIENCE:?}; received so far: {:#?}",
                    self.seen
                );
            };
            if matches(&text) {
                return (at, text);
            }
        }
    }
}

fn has_line(text: &str, want: &str) -> bool {
    match want.strip_suffix('…') {
        Some(prefix) => text.lines().any(|l| l.starts_with(prefix)),
        None => text.lines().any(|l| l == want),
    }
}

/// A `rove vehicle` or `rove operator` started the way systemd starts it (NOTIFY_SOCKET, WATCHDOG_USEC, and
/// JOURNAL_STREAM naming its stderr), inside the rig's network namespace. Killed on drop; its
/// log is printed if the test failed.
struct Service {
    child: Child,
    log: PathBuf,
}

impl Service {
    /// `rove ROLE -c CONFIG EXTRA…`.
    fn start(
        rig: &Rig,
        role: &str,
        config: &Path,
        notify: &Path,
        watchdog: Duration,
        extra: &[&str],
    ) -> Service {
        use std::os::unix::fs::MetadataExt;
        let log = rig.dir.join(format!("service-{role}.log"));
        let file = std::fs::File::create(&log).expect("log file");
        // systemd names the journal stream it connects stderr to; here the "journal" is a file.
        let meta = file.metadata().expect("log file metadata");
        let journal_stream = format!("{}:{}", meta.dev(), meta.ino());
        let child = Command::new("ip")
            .args(["netns", "exec", rig.ns.as_str(), ROVE, role, "-c"])
            .arg(config)
            .args(extra)
            .env_remove("WATCHDOG_PID")
            .env("JOURNAL_STREAM", journal_stream)
            .env("NOTIFY_SOCKET", notify)
            .env("WATCHDOG_USEC", watchdog.as_micros().to_string())
            .env("RUST_LOG", "info,rustdds=warn")
            .stdin(Stdio::null())
            .stdout(file.try_clone().expect("log"))
            .stderr(file)
            .spawn()
            .expect("spawn rove");
        Service { child, log }
    }

    fn signal(&self, name: &str) {
        let status = Command::new("kill")
            .args([&format!("-{name}"), &self.child.id().to_string()])
            .status()
            .expect("run kill");
        assert!(status.success(), "kill -{name}");
    }

    fn wait_exit(&mut self) -> std::process::ExitStatus {
        eventually("the process exits", || {
            self.child.try_wait().expect("wait").ok_or("still running")
        })
    }
}

impl Drop for Service {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
        if std::thread::panicking() {
            let log = std::fs::read_to_string(&self.log).unwrap_or_default();
            eprintln!("===== service ({}) =====\n{log}", self.log.display());
        }
    }
}

/// The watchdog timeout the test hands the vehicle: keep-alives are due every 500 ms.
const WATCHDOG: Duration = Duration::from_secs(1);
/// How long the SIGUSR1 test hook stalls the loop: longer than the watchdog timeout, so that
/// systemd would have killed the gateway.
const STALL: Duration = Duration::from_millis(1500);

#[test]
fn sd_notify_ready_status_keepalives_stall_and_stopping() {
    let mut rig = Rig::new("sdnotify");
    let root = fake_sysfs(&rig.dir);
    let config = rig.write("vehicle.toml", &vehicle_toml(V, &eyedrive_sysfs(&root)));
    let mut manager = Manager::bind(&rig.dir);
    let stall_ms = STALL.as_millis().to_string();
    let mut vehicle = Service::start(
        &rig,
        "vehicle",
        &config,
        &manager.path,
        WATCHDOG,
        &["--test-stall-on-sigusr1", &stall_ms],
    );

    // READY=1 is the first notification, and by then the outputs are in their safe state.
    let (_, first) = manager.recv(PATIENCE).expect("a first notification");
    assert!(has_line(&first, "READY=1"), "first notification: {first:?}");
    assert!(
        has_line(&first, "STATUS=failsafe (no operator live); output ok"),
        "{first:?}"
    );
    assert_eq!(
        (duty(&root, 0), duty(&root, 1)),
        (SAFE_NS.to_string(), SAFE_NS.to_string())
    );

    // Keep-alives every half watchdog timeout, never as late as the timeout.
    let mut beats = Vec::new();
    while beats.len() < 6 {
        beats.push(manager.wait_for("WATCHDOG=1").0);
    }
    let gaps: Vec<Duration> = beats.windows(2).map(|w| w[1] - w[0]).collect();
    let mean = gaps.iter().sum::<Duration>() / gaps.len() as u32;
    eprintln!("keep-alive gaps: {gaps:?}, mean {mean:?}");
    for gap in &gaps {
        assert!(
            *gap > Duration::from_millis(250) && *gap < WATCHDOG,
            "keep-alive gaps {gaps:?}: want about {:?}",
            WATCHDOG / 2
        );
    }
    assert!(
        mean >= Duration::from_millis(400) && mean <= Duration::from_millis(700),
        "mean keep-alive gap {mean:?}, want about {:?}",
        WATCHDOG / 2
    );

    // STATUS follows the owner.
    rig.operator(11, "mobile", "phone", &[V], 32767, "", &[]);
    manager.wait_for("STATUS=driven by 11 (1 operator live); output ok");
    wait_duty(&root, 1, "2000000");

    // A stalled loop sends nothing at all, for longer than the watchdog timeout; then the
    // keep-alives resume.
    vehicle.signal("USR1");
    let (stalled, _) = manager.wait_for("STATUS=control loop stalled by the SIGUSR1 test hook");
    let margin = Duration::from_millis(200);
    if let Some((at, text)) = manager.recv(STALL - margin) {
        panic!(
            "{text:?} {:?} into a {STALL:?} stall of the loop",
            at - stalled
        );
    }
    let (resumed, _) = manager.wait_for("WATCHDOG=1");
    eprintln!("no notification for {:?} while stalled", resumed - stalled);
    assert!(resumed - stalled > WATCHDOG);

    // SIGTERM: STOPPING=1, a clean exit, the outputs safe (the operator still streams full
    // throttle: nothing may apply it once the vehicle stops).
    vehicle.signal("TERM");
    manager.wait_for("STOPPING=1");
    let status = vehicle.wait_exit();
    assert!(status.success(), "exit status {status}");
    safe_after_stop(&root, &vehicle.log, &rig.dir);

    // Journal-style logging: every line carries its syslog priority and no time stamp, and the
    // start-up line names the config, device, domain, interfaces and adapter.
    let log = std::fs::read_to_string(&vehicle.log).expect("log");
    for line in log.lines().filter(|l| !l.is_empty()) {
        let priority = line
            .strip_prefix('<')
            .and_then(|l| l.split_once('>'))
            .and_then(|(p, _)| p.parse::<u8>().ok());
        assert!(
            matches!(priority, Some(0..=7)),
            "no priority prefix: {line:?}"
        );
        assert!(
            !line.contains(" INFO ") && !line[3..].starts_with("20"),
            "{line:?}"
        );
    }
    let started = log
        .lines()
        .find(|l| l.contains("vehicle started"))
        .unwrap_or_else(|| panic!("no start-up line in:\n{log}"));
    assert!(started.starts_with("<6>"), "{started}");
    for field in [
        format!("config={}", config.display()),
        format!("device={V}"),
        "domain=0".to_string(),
        "interfaces=[127.0.0.1]".to_string(),
        "adapter=".to_string(),
        "watchdog_keepalive_ms=500".to_string(),
    ] {
        assert!(started.contains(&field), "{field} missing: {started}");
    }
    assert!(
        log.lines()
            .any(|l| l.starts_with("<4>") && l.contains("test hook")),
        "the stall hook's warning is not at priority 4:\n{log}"
    );
}

/// How long the hung-output test's vehicle lets its output stay hung before it stops the
/// keep-alives (`[vehicle] output_hung_limit_ms`).
const HUNG_LIMIT: Duration = Duration::from_secs(3);

#[test]
fn a_hung_output_leaves_the_vehicle_deciding_and_stops_keepalives_past_its_limit() {
    let mut rig = Rig::new("hung-output");
    let root = fake_sysfs(&rig.dir);
    let limit_ms = HUNG_LIMIT.as_millis();
    let output = format!(
        "[vehicle]\noutput_hung_limit_ms = {limit_ms}\n{}",
        eyedrive_sysfs(&root)
    );
    let config = rig.write("vehicle.toml", &vehicle_toml(V, &output));
    let mut manager = Manager::bind(&rig.dir);
    let mut vehicle = Service::start(&rig, "vehicle", &config, &manager.path, WATCHDOG, &[]);
    manager.wait_for("READY=1");

    // The throttle's duty_cycle becomes a FIFO nobody reads: the next write to it blocks in
    // open(2), as a wedged device write would.
    let fifo = root.join("pwmchip0/pwm1/duty_cycle");
    std::fs::remove_file(&fifo).expect("remove duty_cycle");
    let made = Command::new("mkfifo").arg(&fifo).status().expect("mkfifo");
    assert!(made.success(), "mkfifo");
    let operator = rig.operator(11, "mobile", "phone", &[V], 32767, "", &[]);
    let (hung_at, _) = manager.wait_for("STATUS=driven by 11 (1 operator live); output hung…");
    // Keep-alives go on while the output has been hung for less than the limit.
    let (beat, _) = manager.wait_for("WATCHDOG=1");
    eprintln!("a keep-alive {:?} after the hung status", beat - hung_at);

    // Operators and `rove status` see it in the vehicle's VehicleStatus.
    eventually("rove status shows the hung output", || {
        let status = rig.status();
        let row = Rig::device(&status, V).unwrap_or_default();
        match row["output"].as_str() {
            Some(o) if o.starts_with("hung: a device call has not returned") => Ok(()),
            _ => Err(row.to_string()),
        }
    });

    // The vehicle goes on deciding: its owner quits, and it goes to failsafe with the output
    // still hung.
    rig.procs[operator].terminate();
    manager.wait_for("STATUS=failsafe (no operator live); output hung…");

    // Past the limit the keep-alives stop (systemd would restart the unit), and STATUS says so.
    let stopped = "watchdog keep-alives stopped";
    let (stopped_at, _) = manager.wait_for_match(stopped, |t| t.contains(stopped));
    let quiet_until = stopped_at + WATCHDOG;
    while let Some((at, text)) = manager.recv(quiet_until.saturating_duration_since(Instant::now()))
    {
        assert!(
            !has_line(&text, "WATCHDOG=1"),
            "a keep-alive {:?} after they stopped",
            at - stopped_at
        );
    }

    // The device returns: the blocked write completes, then only the newest command (the
    // safe state) is written, nothing of what the operator streamed meanwhile.
    let written = std::sync::Arc::new(std::sync::Mutex::new(Vec::<String>::new()));
    let reader = {
        let (fifo, written) = (fifo.clone(), std::sync::Arc::clone(&written));
        std::thread::spawn(move || {
            loop {
                let value = std::fs::read_to_string(&fifo).expect("read the FIFO");
                if value == "end" {
                    return;
                }
                written
                    .lock()
                    .expect("writes")
                    .push(value.trim().to_string());
            }
        })
    };
    // (Two writes can arrive as one read: the FIFO's end of file comes only once no writer
    // has it open.)
    let expected = format!("2000000{SAFE_NS}");
    let all_written = || written.lock().expect("writes").concat();
    eventually("the blocked write, then the safe state", || {
        let got = all_written();
        if got == expected { Ok(()) } else { Err(got) }
    });
    manager.wait_for("STATUS=failsafe (no operator live); output ok");
    manager.wait_for("WATCHDOG=1");
    vehicle.signal("TERM");
    assert!(vehicle.wait_exit().success());
    assert_eq!(all_written(), expected, "nothing else written");
    std::fs::write(&fifo, "end").expect("end the reader");
    reader.join().expect("reader");
}

#[test]
fn the_operator_notifies_ready_keepalives_status_and_stopping() {
    let rig = Rig::new("sdnotify-operator");
    let config = rig.write(
        "operator.toml",
        &OperatorToml::new(11, "stationary", "laptop")
            .drive(&[V])
            .to_string(),
    );
    let mut manager = Manager::bind(&rig.dir);
    let mut operator = Service::start(&rig, "operator", &config, &manager.path, WATCHDOG, &[]);
    let (_, first) = manager.recv(PATIENCE).expect("a first notification");
    assert!(has_line(&first, "READY=1"), "first notification: {first:?}");
    assert!(
        has_line(&first, &format!("STATUS=driving {V}; 0 vehicles seen")),
        "{first:?}"
    );
    let (a, _) = manager.wait_for("WATCHDOG=1");
    let (b, _) = manager.wait_for("WATCHDOG=1");
    assert!(b - a < WATCHDOG, "keep-alives {:?} apart", b - a);
    operator.signal("TERM");
    manager.wait_for("STOPPING=1");
    let status = operator.wait_exit();
    assert!(status.success(), "exit status {status}");
}

/// After a clean stop the outputs are safe: the vehicle wrote its safe state, or (a device
/// write that did not return within the stop's wait; here the fake sysfs's plain file, which
/// a busy disk can hold in `truncate`) it said it left that to `rove failsafe`, and the unit's
/// ExecStopPost= then makes them safe, as systemd runs it after every stop.
fn safe_after_stop(root: &Path, log: &Path, dir: &Path) {
    let safe = (SAFE_NS.to_string(), SAFE_NS.to_string());
    let written = (duty(root, 0), duty(root, 1));
    if written == safe {
        return;
    }
    let text = std::fs::read_to_string(log).unwrap_or_default();
    assert!(
        text.contains("leaving it to `rove failsafe`"),
        "outputs {written:?} after a clean stop, and no word of it:\n{text}"
    );
    eprintln!("the stop left the safe state to `rove failsafe` (outputs {written:?})");
    let stop_post = command_line(&unit("rove-vehicle.service"), "ExecStopPost", None);
    run_exec_stop_post(&stop_post, dir);
    assert_eq!((duty(root, 0), duty(root, 1)), safe);
}

/// Runs a unit's ExecStopPost= command line `stop_post` with its paths in `dir`, as systemd
/// would after the service stopped; it must succeed.
fn run_exec_stop_post(stop_post: &[String], dir: &Path) {
    let stop_post = localize(stop_post, dir);
    let out = Command::new(&stop_post[0])
        .args(&stop_post[1..])
        .output()
        .expect("run ExecStopPost");
    assert!(
        out.status.success(),
        "{stop_post:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
}

// ---------------------------------------------------------------------------------------------
// SIGKILL, then the unit's ExecStopPost=

/// Starts the vehicle as `file`'s ExecStart= would (in the rig's namespace, with the config at
/// `/etc/rove/…` moved into the rig's directory), lets an operator drive it to full throttle,
/// kills it with SIGKILL, and runs the unit's ExecStopPost= command line.
fn killed_vehicle_is_made_safe_by_exec_stop_post(file: &str, instance: Option<&str>) {
    let mut rig = Rig::new("stop-post");
    let root = fake_sysfs(&rig.dir);
    let u = unit(file);
    let start = command_line(&u, "ExecStart", instance);
    let stop_post = command_line(&u, "ExecStopPost", instance);
    let installed_config = arg_after(&start, "-c").to_string();
    assert_eq!(arg_after(&stop_post, "-c"), installed_config);
    let start = localize(&start, &rig.dir);
    let config = PathBuf::from(arg_after(&start, "-c"));
    std::fs::write(&config, vehicle_toml(V, &eyedrive_sysfs(&root))).expect("config");

    let record = rig.dir.join("outputs.jsonl");
    let mut args: Vec<&str> = start[1..].iter().map(String::as_str).collect();
    args.extend(["--record", record.to_str().expect("utf-8 path")]);
    let vehicle = rig.spawn("vehicle", &args);
    rig.operator(11, "mobile", "phone", &[V], 32767, "roll = -32767\n", &[]);
    wait_for_output(&record, Some(11), 0).expect("the operator drives");
    wait_duty(&root, 1, "2000000");
    wait_duty(&root, 0, "1000000");

    // SIGKILL: no shutdown code runs, so the servos keep the last command.
    rig.procs[vehicle].crash();
    assert_eq!(duty(&root, 1), "2000000", "full throttle after the kill");

    run_exec_stop_post(&stop_post, &rig.dir);
    assert_eq!(
        (duty(&root, 0), duty(&root, 1)),
        (SAFE_NS.to_string(), SAFE_NS.to_string())
    );
}

#[test]
fn after_sigkill_the_vehicle_units_exec_stop_post_makes_the_outputs_safe() {
    killed_vehicle_is_made_safe_by_exec_stop_post("rove-vehicle.service", None);
}

#[test]
fn after_sigkill_a_template_instances_exec_stop_post_makes_its_outputs_safe() {
    killed_vehicle_is_made_safe_by_exec_stop_post("rove-vehicle@.service", Some("front"));
}

/// `rove bridge` under the service manager: READY=1 once its participant and link are open,
/// a STATUS line that follows the sites up and the devices it carries, keep-alives, and
/// STOPPING=1 on SIGTERM. (The link itself is tested in `sites`.)
#[cfg(all(feature = "remote", feature = "security"))]
#[test]
fn a_bridge_notifies_ready_status_keepalives_and_stopping() {
    use rove_tools::sites;
    let mut rig = Rig::new("bridge-notify");
    let fleet = sites::fleet(&rig.rove, &rig.dir.join("fleet")).expect("keys");
    let files = fleet.join("site-lab");
    let toml = format!(
        "[site]\nname = \"lab\"\n[zenoh]\nlisten = [\"tls/127.0.0.1:7447\"]\nca = \"{}\"\n\
         certificate = \"{}\"\nkey = \"{}\"\n{}",
        files.join("ca.cert.pem").display(),
        files.join("cert.pem").display(),
        files.join("key.pem").display(),
        sites::peer("home", &[21], &[V])
    );
    let config = rig.write("bridge.toml", &toml);
    let mut manager = Manager::bind(&rig.dir);
    let mut bridge = Service::start(&rig, "bridge", &config, &manager.path, WATCHDOG, &[]);

    let (_, first) = manager.recv(PATIENCE).expect("a first notification");
    assert!(has_line(&first, "READY=1"), "first notification: {first:?}");
    let alone = "STATUS=site lab: 0 of 1 sites up (home not connected); 0 devices of other \
                 sites here, 0 on this site";
    assert!(has_line(&first, alone), "{first:?}");

    // A device joins this site: the status line counts it.
    rig.operator(11, "mobile", "phone", &[V], 0, "", &[]);
    manager.wait_for(
        "STATUS=site lab: 0 of 1 sites up (home not connected); 0 devices of other sites \
         here, 1 on this site",
    );

    // Keep-alives every half watchdog timeout.
    let mut beats = Vec::new();
    while beats.len() < 4 {
        beats.push(manager.wait_for("WATCHDOG=1").0);
    }
    let gaps: Vec<Duration> = beats.windows(2).map(|w| w[1] - w[0]).collect();
    eprintln!("keep-alive gaps: {gaps:?}");
    for gap in &gaps {
        assert!(
            *gap > Duration::from_millis(250) && *gap < WATCHDOG,
            "keep-alive gaps {gaps:?}: want about {:?}",
            WATCHDOG / 2
        );
    }

    bridge.signal("TERM");
    manager.wait_for("STOPPING=1");
    let status = bridge.wait_exit();
    assert!(status.success(), "exit status {status}");
    let log = std::fs::read_to_string(&bridge.log).expect("log");
    let started = log
        .lines()
        .find(|l| l.contains("bridge started"))
        .unwrap_or_else(|| panic!("no start-up line in:\n{log}"));
    assert!(started.contains("watchdog_keepalive_ms=500"), "{started}");
}
