//! The tools clean up after themselves (issue 51): a `rove bench` stopped by a signal leaves no
//! process and no network namespace behind; one killed outright leaves no process (its children
//! get SIGTERM when it dies: `setpriv --pdeathsig`).

use crate::util::{ROVE, eventually};
use std::process::{Command, Stdio};

/// The processes whose command line names a rig directory of the process `pid`
/// (`/tmp/rove-it-PID-…`), as `pid: command line`.
fn children_of_rigs(pid: u32) -> Vec<String> {
    let mark = format!("rove-it-{pid}-");
    (std::fs::read_dir("/proc").into_iter().flatten().flatten())
        .filter_map(|e| {
            let cmdline = std::fs::read(e.path().join("cmdline")).ok()?;
            let text = String::from_utf8_lossy(&cmdline).replace('\0', " ");
            text.contains(&mark)
                .then(|| format!("{}: {text}", e.file_name().to_string_lossy()))
        })
        .collect()
}

/// The network namespaces of the process `pid`'s rigs (`rove-PID-N`).
fn namespaces_of(pid: u32) -> Vec<String> {
    let out = Command::new("ip").args(["netns", "list"]).output();
    let text = out.map(|o| String::from_utf8_lossy(&o.stdout).into_owned());
    (text.unwrap_or_default().lines())
        .filter_map(|l| l.split_whitespace().next())
        .filter(|ns| ns.starts_with(&format!("rove-{pid}-")))
        .map(str::to_string)
        .collect()
}

/// Starts a long `rove bench handover`, waits until its processes run, sends `signal`; then
/// nothing of it may remain (namespaces too unless `keeps_namespaces`).
fn a_bench_ended_by(signal: &str, keeps_namespaces: bool) {
    let mut bench = Command::new(ROVE)
        .args([
            "bench",
            "handover",
            "--scenario",
            "graceful",
            "--runs",
            "10000",
        ])
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("start rove bench");
    let pid = bench.id();
    eventually("the bench's vehicle and operators run", || {
        let running = children_of_rigs(pid);
        (running.len() >= 3).then_some(()).ok_or(running.join("\n"))
    });
    let sent = Command::new("kill")
        .args([signal, &pid.to_string()])
        .status();
    assert!(sent.is_ok_and(|s| s.success()), "kill {signal}");
    let status = bench.wait().expect("the bench ends");
    eprintln!("rove bench after kill {signal}: {status}");
    eventually("nothing of the bench runs", || {
        let left = children_of_rigs(pid);
        left.is_empty().then_some(()).ok_or(left.join("\n"))
    });
    if !keeps_namespaces {
        assert_eq!(namespaces_of(pid), Vec::<String>::new(), "namespaces left");
    }
    for ns in namespaces_of(pid) {
        let _ = Command::new("ip").args(["netns", "del", &ns]).status();
    }
}

#[test]
fn a_bench_stopped_with_sigterm_leaves_nothing() {
    a_bench_ended_by("-TERM", false);
}

#[test]
fn a_bench_stopped_with_sigint_leaves_nothing() {
    a_bench_ended_by("-INT", false);
}

/// SIGKILL runs nothing of the bench: its children stop (they get SIGTERM as it dies), but
/// the namespaces stay (the test deletes them).
#[test]
fn a_killed_bench_leaves_no_process() {
    a_bench_ended_by("-KILL", true);
}

/// The tools report the presence period a bench ran with; when it set none, the gateway's.
#[test]
fn the_tools_default_presence_is_the_gateways() {
    let gateway = rove_gateway::dds::DEFAULT_PRESENCE.as_millis();
    assert_eq!(u128::from(rove_tools::DEFAULT_PRESENCE_MS), gateway);
}
