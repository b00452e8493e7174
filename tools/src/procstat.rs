//! What `/proc` says of a process: CPU time and resident memory, for the benches.

use std::time::{Duration, Instant};

/// CPU ticks (user + system) and resident memory (KiB) of process `pid`.
pub(crate) fn sample(pid: u32) -> Option<(u64, u64)> {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).ok()?;
    // Fields after the command name (which may hold spaces): state is field 3, utime 14.
    let rest = &stat[stat.rfind(')')? + 2..];
    let fields: Vec<&str> = rest.split_whitespace().collect();
    let ticks = fields.get(11)?.parse::<u64>().ok()? + fields.get(12)?.parse::<u64>().ok()?;
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).ok()?;
    let rss = status
        .lines()
        .find_map(|l| l.strip_prefix("VmRSS:"))
        .and_then(|v| v.split_whitespace().next()?.parse().ok())?;
    Some((ticks, rss))
}

/// The CPU (percent of a core) of each process in `pids` over `window`.
///
/// # Errors
/// A process exited.
pub fn cpu_of(pids: &[u32], window: Duration) -> anyhow::Result<Vec<f64>> {
    let before: Vec<_> = pids.iter().map(|&p| sample(p)).collect();
    let started = Instant::now();
    std::thread::sleep(window);
    let elapsed = started.elapsed().as_secs_f64();
    let after: Vec<_> = pids.iter().map(|&p| sample(p)).collect();
    let hz = clock_ticks();
    (before.iter().zip(&after))
        .map(|(b, a)| match (b, a) {
            (Some(b), Some(a)) => Ok(a.0.saturating_sub(b.0) as f64 / hz / elapsed * 100.0),
            _ => Err(anyhow::anyhow!(
                "a measured process exited during the window"
            )),
        })
        .collect()
}

/// Clock ticks per second of `/proc/PID/stat` (`getconf CLK_TCK`, 100 on Linux).
pub(crate) fn clock_ticks() -> f64 {
    std::process::Command::new("getconf")
        .arg("CLK_TCK")
        .output()
        .ok()
        .and_then(|o| String::from_utf8(o.stdout).ok()?.trim().parse().ok())
        .unwrap_or(100.0)
}
