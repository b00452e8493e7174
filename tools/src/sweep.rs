//! `rove bench scale --idle-sweep 8,16,32,64`: idle fleets of those many processes (half
//! vehicles, half operators), one after the other, each measured as [`fleet::run`] measures
//! one: CPU per node, and its growth from the smallest fleet to the largest, which is what each
//! peer adds to every node (issue 33; docs/design.md, "Fleet scale").

use crate::fleet::{self, Options, Percentiles};
use serde::Serialize;
use std::path::Path;

/// One idle fleet of the sweep.
#[derive(Debug, Serialize)]
pub struct SweepPoint {
    /// Processes (half vehicles, half operators; the odd one a vehicle).
    pub processes: usize,
    /// Mean CPU of a node, percent of one core.
    pub cpu_per_node_pct: f64,
    /// The busiest node's CPU, percent of one core.
    pub cpu_max_pct: f64,
    /// CPU of the fleet, percent of one core.
    pub cpu_total_pct: f64,
    /// Late joiner: start → every device listed, ms.
    pub latejoin_ms: Option<Percentiles>,
}

/// `rove bench scale --idle-sweep` (`--json`).
#[derive(Debug, Serialize)]
pub struct Sweep {
    /// The fleets, smallest first.
    pub fleets: Vec<SweepPoint>,
    /// CPU per node of the largest fleet over that of the smallest: 1.0 when a node's idle cost
    /// does not depend on the number of its peers.
    pub growth: Option<f64>,
    /// The fleet's check period, ms.
    pub heartbeat_ms: u64,
    /// The fleet's SPDP period, ms.
    pub presence_ms: u64,
}

/// Runs idle fleets of `sizes` processes, smallest first.
///
/// # Errors
/// As [`fleet::run`], or a size below 2.
pub fn run(
    rove: &Path,
    options: &Options,
    sizes: &[usize],
    progress: &mut dyn FnMut(&str),
) -> anyhow::Result<Sweep> {
    let mut sizes = sizes.to_vec();
    sizes.sort_unstable();
    anyhow::ensure!(
        sizes.first().is_some_and(|&n| n >= 2),
        "each fleet of the sweep needs at least 2 processes"
    );
    let mut fleets = Vec::new();
    for n in sizes {
        progress(&format!("idle fleet of {n} processes"));
        let fleet = Options {
            vehicles: n.div_ceil(2),
            operators: n / 2,
            idle: true,
            handover_runs: 0,
            restarts: 0,
            ..options.clone()
        };
        let r = fleet::run(rove, &fleet, progress)?;
        let nodes = r.vehicle.processes + r.operator.processes;
        fleets.push(SweepPoint {
            processes: nodes,
            cpu_per_node_pct: r.cpu_total_pct / nodes as f64,
            cpu_max_pct: r.vehicle.cpu_max_pct.max(r.operator.cpu_max_pct),
            cpu_total_pct: r.cpu_total_pct,
            latejoin_ms: r.latejoin_ms,
        });
    }
    let growth = match (fleets.first(), fleets.last()) {
        (Some(a), Some(b)) if a.cpu_per_node_pct > 0.0 => {
            Some(b.cpu_per_node_pct / a.cpu_per_node_pct)
        }
        _ => None,
    };
    Ok(Sweep {
        fleets,
        growth,
        heartbeat_ms: options.heartbeat_ms.unwrap_or(500),
        presence_ms: options.presence_ms.unwrap_or(crate::DEFAULT_PRESENCE_MS),
    })
}

/// `rove bench scale --idle-sweep`: runs, prints a line per fleet and optionally writes the
/// JSON report.
///
/// # Errors
/// As [`run`], or the JSON file cannot be written.
pub fn cli(
    rove: &Path,
    options: &Options,
    sizes: &[usize],
    json: Option<&Path>,
) -> anyhow::Result<()> {
    let r = run(rove, options, sizes, &mut |line| eprintln!("{line}"))?;
    for f in &r.fleets {
        println!(
            "idle {:>3} processes: {:.2} % of a core per node (max {:.2} %), {:.1} % in all",
            f.processes, f.cpu_per_node_pct, f.cpu_max_pct, f.cpu_total_pct
        );
    }
    if let Some(g) = r.growth {
        println!("per-node idle CPU, largest fleet over smallest: {g:.2}×");
    }
    if let Some(path) = json {
        std::fs::write(path, serde_json::to_string_pretty(&r)? + "\n")?;
    }
    Ok(())
}
