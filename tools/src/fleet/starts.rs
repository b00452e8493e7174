//! `rove bench scale --starts N [--secure]`: the same fleet started `N` times from nothing, each
//! start timed to every vehicle driven by its laptop (or the vehicles that never were), then one
//! full run; with `--secure`, unsecured and secured side by side in one invocation (issue 44:
//! a secured fleet must converge in every start, within 2× the unsecured time).

use super::{Options, Percentiles, Report, Started, driven, start};
use crate::harness::Rig;
use serde::Serialize;
use std::path::Path;
use std::time::Duration;

/// How long one start may take to have every vehicle driven before it counts as not converged.
pub const START_PATIENCE: Duration = Duration::from_secs(60);

/// One start of the fleet from nothing.
#[derive(Debug, Clone, Serialize)]
pub struct Start {
    /// From the first process started until every vehicle applied its laptop's command, ms;
    /// `None`: not within [`START_PATIENCE`].
    pub driven_ms: Option<u64>,
    /// The vehicles never driven by their laptops within [`START_PATIENCE`].
    pub undriven: Vec<i64>,
}

/// The starts and the full run of one mode (secured or not).
#[derive(Debug, Serialize)]
pub struct Mode {
    /// Every device had a certificate of its own.
    pub secure: bool,
    /// Each start, in order.
    pub starts: Vec<Start>,
    /// Starts in which every vehicle was driven.
    pub converged: usize,
    /// Of the converged starts: every vehicle driven, ms.
    pub driven_ms: Option<Percentiles>,
    /// The full run (CPU, memory, handover, late joiners).
    pub run: Option<Report>,
}

/// Starts the fleet of `options` in a fresh namespace and waits until every vehicle is driven;
/// stops it again.
///
/// # Errors
/// The namespace or a process cannot be started.
pub fn once(rove: &Path, options: &Options) -> anyhow::Result<Start> {
    let mut rig = Rig::new(rove, "scale-start")?;
    let f: Started = start(&mut rig, options)?;
    Ok(match driven(&f, START_PATIENCE) {
        Ok(ms) => Start {
            driven_ms: Some(ms),
            undriven: Vec::new(),
        },
        Err(undriven) => Start {
            driven_ms: None,
            undriven,
        },
    })
    // The rig's drop stops every process and deletes the namespace.
}

/// `starts` starts of the fleet, then its full run.
///
/// # Errors
/// As [`once`] and [`super::run`].
pub fn mode(
    rove: &Path,
    options: &Options,
    starts: usize,
    progress: &mut dyn FnMut(&str),
) -> anyhow::Result<Mode> {
    let what = if options.secure {
        "secured"
    } else {
        "unsecured"
    };
    let mut all = Vec::new();
    for n in 0..starts {
        let s = once(rove, options)?;
        progress(&match s.driven_ms {
            Some(ms) => format!(
                "{what} start {}/{starts}: every vehicle driven in {ms} ms",
                n + 1
            ),
            None => format!(
                "{what} start {}/{starts}: NOT CONVERGED, vehicles {:?} not driven within {:?}",
                n + 1,
                s.undriven,
                START_PATIENCE
            ),
        });
        all.push(s);
    }
    let times: Vec<f64> = all
        .iter()
        .filter_map(|s| s.driven_ms)
        .map(|ms| ms as f64)
        .collect();
    let run = super::run(rove, options, progress);
    if let Err(e) = &run {
        progress(&format!("{what} full run failed: {e:#}"));
    }
    Ok(Mode {
        secure: options.secure,
        converged: times.len(),
        driven_ms: Percentiles::of(&times),
        starts: all,
        run: run.ok(),
    })
}

/// The lines of the side-by-side table: one row per figure, one column per mode.
pub fn table(modes: &[Mode]) -> Vec<String> {
    let pct = |p: &Option<Percentiles>| {
        p.map_or("-".to_string(), |p| format!("{:.0} / {:.0}", p.p50, p.p99))
    };
    let of_run = |m: &Mode, f: &dyn Fn(&Report) -> String| m.run.as_ref().map_or("-".into(), f);
    type Row<'a> = (&'a str, Box<dyn Fn(&Mode) -> String + 'a>);
    let rows: Vec<Row> = vec![
        (
            "starts converged",
            Box::new(|m: &Mode| format!("{} of {}", m.converged, m.starts.len())),
        ),
        (
            "every vehicle driven, p50 / p99 ms",
            Box::new(|m: &Mode| pct(&m.driven_ms)),
        ),
        (
            "late phone drives, p50 / p99 ms",
            Box::new(move |m: &Mode| of_run(m, &|r| pct(&r.late_operator_ms))),
        ),
        (
            "handover, p50 / p99 ms",
            Box::new(move |m: &Mode| of_run(m, &|r| pct(&r.handover_ms))),
        ),
        (
            "late joiner lists all, p50 / p99 ms",
            Box::new(move |m: &Mode| of_run(m, &|r| pct(&r.latejoin_ms))),
        ),
        (
            "CPU in all, % of a core",
            Box::new(move |m: &Mode| of_run(m, &|r| format!("{:.1}", r.cpu_total_pct))),
        ),
        (
            "memory in all, MiB",
            Box::new(move |m: &Mode| of_run(m, &|r| format!("{}", r.rss_total_kb / 1024))),
        ),
        (
            "wrong owner / stale after the start",
            Box::new(move |m: &Mode| of_run(m, &|r| format!("{} / {}", r.wrong_owner, r.stale))),
        ),
    ];
    let mut lines = vec![format!(
        "| | {} |",
        (modes.iter())
            .map(|m| if m.secure { "secured" } else { "unsecured" })
            .collect::<Vec<_>>()
            .join(" | ")
    )];
    lines.push(format!("|---|{}", "---|".repeat(modes.len())));
    for (name, cell) in &rows {
        let cells: Vec<String> = modes.iter().map(cell).collect();
        lines.push(format!("| {name} | {} |", cells.join(" | ")));
    }
    lines
}

/// `rove bench scale --starts N [--secure [--secure-only]]`: each mode's starts and full run, then the table;
/// `--json` gets every mode.
///
/// # Errors
/// As [`mode`], or the JSON file cannot be written.
pub fn cli(
    rove: &Path,
    options: &Options,
    starts: usize,
    secure_only: bool,
    json: Option<&Path>,
) -> anyhow::Result<()> {
    let secure = [false, true];
    let modes = match (options.secure, secure_only) {
        (true, true) => &secure[1..],
        (true, false) => &secure[..],
        (false, _) => &secure[..1],
    };
    let mut done = Vec::new();
    for &secure in modes {
        let options = Options {
            secure,
            ..options.clone()
        };
        done.push(mode(rove, &options, starts, &mut |line| {
            eprintln!("{line}")
        })?);
    }
    println!(
        "scale {}×{}, {starts} starts each",
        options.vehicles, options.operators
    );
    for line in table(&done) {
        println!("{line}");
    }
    if let Some(path) = json {
        std::fs::write(path, serde_json::to_string_pretty(&done)? + "\n")?;
    }
    let failed = done
        .iter()
        .any(|m| m.converged < m.starts.len() || m.run.is_none());
    anyhow::ensure!(!failed, "a start did not converge or a full run failed");
    Ok(())
}
