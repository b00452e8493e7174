//! What `rove bench handover` reports: statistics, the table, the box plot and the JSON.

use super::{Options, PING_PONG_WINDOW_US, Scenario};
use crate::harness::Out;
use serde::Serialize;
use std::fmt::Write as _;
use std::path::PathBuf;

/// Summary statistics in milliseconds.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Stats {
    /// Mean.
    pub mean: f64,
    /// Sample standard deviation.
    pub stdev: f64,
    /// Minimum.
    pub min: f64,
    /// Maximum.
    pub max: f64,
    /// Median.
    pub p50: f64,
    /// 99th percentile (nearest rank).
    pub p99: f64,
}

impl Stats {
    /// Statistics of `values` (ms); `None` if empty.
    pub fn of(values: &[f64]) -> Option<Stats> {
        if values.is_empty() {
            return None;
        }
        let mut v = values.to_vec();
        v.sort_by(f64::total_cmp);
        let n = v.len() as f64;
        let mean = v.iter().sum::<f64>() / n;
        let var = if v.len() > 1 {
            v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0)
        } else {
            0.0
        };
        let rank = |p: f64| v[((p * n).ceil() as usize).clamp(1, v.len()) - 1];
        Some(Stats {
            mean,
            stdev: var.sqrt(),
            min: v[0],
            max: v[v.len() - 1],
            p50: rank(0.50),
            p99: rank(0.99),
        })
    }
}

/// One scenario's result, as written by `--json` (one object per scenario run).
#[derive(Debug, Clone, Serialize)]
pub struct Report {
    /// Scenario.
    pub scenario: Scenario,
    /// Controllers (or devices, for latejoin).
    pub controllers: usize,
    /// Runs measured.
    pub runs: usize,
    /// Always "ms".
    pub unit: &'static str,
    /// Trigger → DeviceInfo with the new owner (latejoin: start → all devices listed).
    pub deviceinfo: Option<Stats>,
    /// Trigger → new owner's command applied (latejoin: not measured).
    pub applied: Option<Stats>,
    /// Returns to the previous owner within 1 s.
    pub ping_pong: usize,
    /// Every process joined with DDS Security.
    pub secure: bool,
    /// Raw samples, ms.
    #[serde(skip)]
    pub raw: (Vec<f64>, Vec<f64>),
}

pub(super) fn report(
    options: &Options,
    info: Vec<f64>,
    applied: Vec<f64>,
    ping_pong: usize,
) -> Report {
    Report {
        scenario: options.scenario,
        controllers: options.controllers,
        runs: options.runs,
        unit: "ms",
        deviceinfo: Stats::of(&info),
        applied: Stats::of(&applied),
        ping_pong,
        secure: options.secure,
        raw: (info, applied),
    }
}

pub(super) fn ms(us: u64) -> f64 {
    us as f64 / 1000.0
}

/// Within the window after `t0`: once `new` was applied, any later output applied from `old`.
pub fn count_ping_pong(outputs: &[Out], t0: u64, old: Option<i64>, new: Option<i64>) -> usize {
    let window = outputs
        .iter()
        .filter(|o| o.wall_us >= t0 && o.wall_us < t0 + PING_PONG_WINDOW_US);
    let mut after_new = false;
    let mut count = 0;
    let mut previous = None;
    for o in window {
        if o.owner == new {
            after_new = true;
        } else if after_new && o.owner == old && o.action == "apply" && previous != Some(o.owner) {
            count += 1;
        }
        previous = Some(o.owner);
    }
    count
}

/// The seed's figures for comparison (thesis Tables 5.1–5.3), ms.
pub fn seed_figure(scenario: Scenario) -> &'static str {
    match scenario {
        Scenario::Graceful => "31.8–50.4 (mean, by controller count)",
        Scenario::Crash => "424 (0.5 s lease)",
        Scenario::Active => "23.7 mean / 150 max, with ping-pong",
        Scenario::Latejoin => "—",
    }
}

/// The human table for a set of reports.
pub fn table(reports: &[Report]) -> String {
    let mut out = String::new();
    let _ = writeln!(
        out,
        "{:<9} {:>4} {:>5} {:<10} {:>8} {:>8} {:>8} {:>8} {:>8} {:>8} {:>4}  seed",
        "scenario", "n", "runs", "measure", "mean", "stdev", "min", "p50", "p99", "max", "pp"
    );
    for r in reports {
        for (name, s) in [("deviceinfo", r.deviceinfo), ("applied", r.applied)] {
            let Some(s) = s else { continue };
            let _ = writeln!(
                out,
                "{:<9} {:>4} {:>5} {:<10} {:>8.2} {:>8.2} {:>8.2} {:>8.2} {:>8.2} {:>8.2} {:>4}  {}",
                format!("{:?}{}", r.scenario, if r.secure { "+sec" } else { "" }).to_lowercase(),
                r.controllers,
                r.runs,
                name,
                s.mean,
                s.stdev,
                s.min,
                s.p50,
                s.p99,
                s.max,
                r.ping_pong,
                seed_figure(r.scenario)
            );
        }
    }
    out
}

/// A box plot (min, p25, median, p75, max per series) as a self-contained SVG.
pub fn svg(reports: &[Report]) -> String {
    let series: Vec<(String, Vec<f64>)> = reports
        .iter()
        .flat_map(|r| {
            let label = format!("{:?} n={}", r.scenario, r.controllers).to_lowercase();
            [
                (format!("{label} info"), r.raw.0.clone()),
                (format!("{label} applied"), r.raw.1.clone()),
            ]
        })
        .filter(|(_, v)| !v.is_empty())
        .collect();
    let max = series
        .iter()
        .flat_map(|(_, v)| v.iter().copied())
        .fold(1.0_f64, f64::max);
    let (w, row) = (720.0, 28.0);
    let h = 40.0 + row * series.len() as f64;
    let x = |v: f64| 220.0 + (w - 240.0) * v / max;
    let mut s = format!(
        "<svg xmlns='http://www.w3.org/2000/svg' width='{w}' height='{h}' font-family='monospace' font-size='11'>\n\
         <text x='220' y='14'>handover latency, ms (0 … {max:.1})</text>\n"
    );
    for (i, (label, v)) in series.iter().enumerate() {
        let mut v = v.clone();
        v.sort_by(f64::total_cmp);
        let q = |p: f64| v[((p * (v.len() - 1) as f64).round() as usize).min(v.len() - 1)];
        let y = 30.0 + row * i as f64;
        let _ = writeln!(
            s,
            "<text x='4' y='{:.1}'>{label}</text>\
             <line x1='{:.1}' x2='{:.1}' y1='{:.1}' y2='{:.1}' stroke='black'/>\
             <rect x='{:.1}' y='{:.1}' width='{:.1}' height='16' fill='#9cf' stroke='black'/>\
             <line x1='{:.1}' x2='{:.1}' y1='{:.1}' y2='{:.1}' stroke='red'/>",
            y + 12.0,
            x(q(0.0)),
            x(q(1.0)),
            y + 8.0,
            y + 8.0,
            x(q(0.25)),
            y,
            (x(q(0.75)) - x(q(0.25))).max(1.0),
            x(q(0.5)),
            x(q(0.5)),
            y,
            y + 16.0,
        );
    }
    s.push_str("</svg>\n");
    s
}

/// Writes the JSON objects (one per scenario run) to `path`.
///
/// # Errors
/// The file cannot be written.
pub fn write_json(path: &PathBuf, reports: &[Report]) -> anyhow::Result<()> {
    let text: Vec<String> = reports
        .iter()
        .map(serde_json::to_string)
        .collect::<Result<_, _>>()?;
    std::fs::write(path, text.join("\n") + "\n")?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stats_match_hand_computed_values() {
        let s = Stats::of(&[4.0, 1.0, 3.0, 2.0]).expect("non-empty");
        assert_eq!((s.min, s.max, s.mean), (1.0, 4.0, 2.5));
        assert_eq!(s.p50, 2.0);
        assert_eq!(s.p99, 4.0);
        assert!((s.stdev - 1.290_994).abs() < 1e-6);
        assert_eq!(Stats::of(&[]), None);
    }

    fn out(t: u64, owner: Option<i64>) -> Out {
        Out {
            wall_us: t,
            action: "apply".into(),
            owner,
            throttle: None,
        }
    }

    #[test]
    fn ping_pong_counts_returns_to_the_old_owner_after_the_new_one() {
        let seq = [
            out(0, Some(1)),
            out(10, Some(2)),
            out(20, Some(1)),
            out(30, Some(1)),
            out(40, Some(2)),
            out(50, Some(1)),
        ];
        assert_eq!(count_ping_pong(&seq, 0, Some(1), Some(2)), 2);
        // Old owner's outputs before the new one took over are not ping-pong.
        assert_eq!(count_ping_pong(&seq[..2], 0, Some(1), Some(2)), 0);
        // Outside the window nothing counts.
        assert_eq!(
            count_ping_pong(
                &[out(0, Some(2)), out(2_000_000, Some(1))],
                0,
                Some(1),
                Some(2)
            ),
            0
        );
    }

    #[test]
    fn svg_has_one_box_per_series() {
        let r = Report {
            scenario: Scenario::Graceful,
            controllers: 2,
            runs: 2,
            unit: "ms",
            deviceinfo: None,
            applied: None,
            ping_pong: 0,
            secure: false,
            raw: (vec![1.0, 2.0], vec![3.0, 4.0]),
        };
        assert_eq!(svg(&[r]).matches("<rect").count(), 2);
    }
}
