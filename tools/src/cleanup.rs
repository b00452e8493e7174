//! Rigs that outlive their tool: `rove bench` and `rove demo` stopped by a signal stop their
//! processes and delete their namespaces first ([`stop_on_signals`]).

use std::process::Command;
use std::time::{Duration, Instant};

/// The namespaces of the rigs alive in this process, for [`stop_on_signals`].
static LIVE: std::sync::Mutex<std::collections::BTreeSet<String>> =
    std::sync::Mutex::new(std::collections::BTreeSet::new());

/// The live rigs' namespaces, the lock taken even if a panic poisoned it (every holder leaves
/// the set consistent).
fn live() -> std::sync::MutexGuard<'static, std::collections::BTreeSet<String>> {
    LIVE.lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner)
}

/// Makes SIGTERM, SIGINT and SIGHUP stop every rig of this process before it exits: each
/// namespace's processes get SIGTERM (a clean stop), then SIGKILL after a second, and the
/// namespace is deleted. For `rove bench` and `rove demo`, whose rigs would otherwise outlive
/// them (their drops do not run when a signal ends the process). Children also get SIGTERM when
/// this process dies some other way (`setpriv --pdeathsig`, [`Rig::command`]).
///
/// [`Rig::command`]: super::harness::Rig::command
///
/// # Errors
/// The signal handlers cannot be installed.
pub fn stop_on_signals() -> anyhow::Result<()> {
    use tokio::signal::unix::{SignalKind, signal};
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_io()
        .build()?;
    let (mut term, mut int, mut hup) = runtime.block_on(async {
        anyhow::Ok((
            signal(SignalKind::terminate())?,
            signal(SignalKind::interrupt())?,
            signal(SignalKind::hangup())?,
        ))
    })?;
    std::thread::Builder::new()
        .name("rove-rig-signals".into())
        .spawn(move || {
            let code = runtime.block_on(async {
                tokio::select! {
                    _ = term.recv() => 143,
                    _ = int.recv() => 130,
                    _ = hup.recv() => 129,
                }
            });
            let live: Vec<String> = live().iter().cloned().collect();
            eprintln!("stopping {} rig(s) on a signal", live.len());
            stop_namespaces(&live);
            std::process::exit(code);
        })?;
    Ok(())
}

/// Every process in the namespaces `live` stopped (SIGTERM, then SIGKILL after a second), and
/// the namespaces deleted.
fn stop_namespaces(live: &[String]) {
    let pids = |ns: &str| -> Vec<String> {
        Command::new("ip")
            .args(["netns", "pids", ns])
            .output()
            .map(|o| {
                (String::from_utf8_lossy(&o.stdout).split_whitespace())
                    .map(str::to_string)
                    .collect()
            })
            .unwrap_or_default()
    };
    let signal = |sig: &str, ns: &str| {
        let pids = pids(ns);
        if !pids.is_empty() {
            let _ = Command::new("kill").arg(sig).args(&pids).status();
        }
    };
    for ns in live {
        signal("-TERM", ns);
    }
    let deadline = Instant::now() + Duration::from_secs(1);
    while Instant::now() < deadline && live.iter().any(|ns| !pids(ns).is_empty()) {
        std::thread::sleep(Duration::from_millis(20));
    }
    for ns in live {
        signal("-KILL", ns);
        let _ = Command::new("ip").args(["netns", "del", ns]).status();
    }
}

/// A rig's namespace `ns` was made.
pub(crate) fn alive(ns: &str) {
    live().insert(ns.to_string());
}

/// A rig's namespace `ns` was deleted.
pub(crate) fn gone(ns: &str) {
    live().remove(ns);
}
