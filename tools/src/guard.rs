//! `rove bench guard`: a short fleet run whose streaming cost is compared against a committed
//! baseline, as ratios in which the machine's speed cancels (docs/design.md, "A guard on the
//! fleet's cost"):
//! - **streaming ÷ idle**: CPU per node of a fleet whose operators stream, over the same fleet
//!   idle (presence, timers, discovery: a node's fixed cost on this machine);
//! - **a sample in arbiter steps**: what the fleet spends per streamed command sample beyond
//!   its idle cost, over what one step of the ownership arbiter costs in this process (a pure
//!   CPU yardstick of this machine).
//!
//! One fleet run is ±10 % from the next on a quiet machine, so an attempt is an idle and a
//! streaming run, and the guard (as the baseline) takes each ratio's median over three attempts: one
//! noisy run either way does not decide.

use crate::fleet::{self, Options};
use rove_core::MonoTime;
use rove_core::arbiter::{Arbiter, ArbiterConfig, Event, ParticipantId, WriterId};
use rove_core::hierarchy::Strength;
use rove_core::msg::{CommandType, ControlCommand, Mode, MovementCommand, TimeT};
use serde::{Deserialize, Serialize};
use std::path::Path;
use std::time::{Duration, Instant};

/// What each operator streams to each vehicle it drives: the operators' default rate.
pub const STREAM_HZ: f64 = 50.0;

/// What `rove bench guard` was asked.
#[derive(Debug, Clone)]
pub struct Guard {
    /// The fleet: vehicles and as many operators.
    pub vehicles: usize,
    /// Each CPU window.
    pub window: Duration,
    /// Attempts, whose medians are compared (or written as the baseline).
    pub attempts: usize,
    /// Allowed growth of streaming ÷ idle over the baseline, a fraction (0.25: 25 %).
    pub tolerance: f64,
    /// Allowed growth of a sample's cost in arbiter steps, a fraction: looser, since the
    /// arbiter, pure CPU, does not follow what the machine's network stack and scheduler do
    /// from one minute to the next (docs/design.md, "A guard on the fleet's cost").
    pub sample_tolerance: f64,
}

/// One attempt's measurements and the ratios made of them.
#[derive(Debug, Clone, Copy, Serialize, Deserialize, PartialEq)]
pub struct Ratios {
    /// Streaming CPU per node ÷ idle CPU per node.
    pub streaming_over_idle: f64,
    /// CPU per streamed command sample beyond the idle fleet's, in arbiter steps.
    pub sample_in_arbiter_steps: f64,
    /// Streaming CPU per node, percent of a core (for the record; not compared).
    pub streaming_node_pct: f64,
    /// Idle CPU per node, percent of a core (for the record; not compared).
    pub idle_node_pct: f64,
    /// One arbiter step, ns (for the record; not compared).
    pub arbiter_step_ns: f64,
}

/// The committed baseline (`--baseline`), written by `--write-baseline`.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Baseline {
    /// What was measured.
    pub ratios: Ratios,
    /// The fleet's vehicles (and operators).
    pub vehicles: usize,
    /// Where and when, in words (the commit, the machine).
    pub note: String,
}

impl Ratios {
    /// The ratios of a streaming and an idle run of the same fleet of `nodes` processes, of
    /// which `operators` stream (CPU of all processes together, percent of a core), with an
    /// arbiter step of `step` on this machine.
    #[must_use]
    pub fn of(
        nodes: usize,
        operators: usize,
        streaming_total_pct: f64,
        idle_total_pct: f64,
        step: Duration,
    ) -> Ratios {
        let nodes = nodes.max(1) as f64;
        let streaming_node_pct = streaming_total_pct / nodes;
        let idle_node_pct = idle_total_pct / nodes;
        // Every operator streams to every vehicle it drives (one each, V = O) at its rate.
        let samples_per_s = (operators as f64 * STREAM_HZ).max(1.0);
        let extra_core = ((streaming_total_pct - idle_total_pct) / 100.0).max(0.0);
        let step_s = step.as_secs_f64().max(1e-12);
        Ratios {
            streaming_over_idle: streaming_node_pct / idle_node_pct.max(1e-9),
            sample_in_arbiter_steps: extra_core / samples_per_s / step_s,
            streaming_node_pct,
            idle_node_pct,
            arbiter_step_ns: step_s * 1e9,
        }
    }

    /// What is over `baseline` by more than its tolerance (fractions: `tolerance` for
    /// streaming ÷ idle, `sample_tolerance` for a sample in arbiter steps), in words; empty:
    /// within.
    #[must_use]
    pub fn over(&self, baseline: &Ratios, tolerance: f64, sample_tolerance: f64) -> Vec<String> {
        let mut over = Vec::new();
        for (name, now, then, tolerance) in [
            (
                "streaming ÷ idle",
                self.streaming_over_idle,
                baseline.streaming_over_idle,
                tolerance,
            ),
            (
                "a sample in arbiter steps",
                self.sample_in_arbiter_steps,
                baseline.sample_in_arbiter_steps,
                sample_tolerance,
            ),
        ] {
            if now > then * (1.0 + tolerance) {
                over.push(format!(
                    "{name}: {now:.2} against {then:.2} (+{:.0} %, bound +{:.0} %)",
                    (now / then - 1.0) * 100.0,
                    tolerance * 100.0
                ));
            }
        }
        over
    }
}

/// One command sample of writer `n` of 32, mixed strengths with ties, as in a busy fleet.
fn busy_sample(n: u32, arrival: MonoTime) -> Event {
    Event::Sample {
        writer: WriterId {
            participant: ParticipantId(u128::from(n)),
            entity: 1,
        },
        strength: Strength(110 + 30 * (n % 8) as u16),
        command: ControlCommand {
            src_id: i64::from(n) + 1,
            dest_id: 1000,
            command_type: CommandType::Movement,
            movement_command: MovementCommand::CENTRED,
            mode: Mode::Manual,
            timestamp: TimeT::UNIX_EPOCH,
        },
        arrival,
    }
}

/// What one arbiter step costs here: the fastest of five rounds of 200 000 samples from 32
/// live writers (as `cargo bench -p rove-core --bench arbiter` steps them).
#[must_use]
pub fn arbiter_step() -> Duration {
    const STEPS: u32 = 200_000;
    let period = Duration::from_micros(625);
    (0..5)
        .map(|_| {
            let mut arbiter = Arbiter::new(1000, ArbiterConfig::default());
            let mut now = MonoTime::ZERO;
            let started = Instant::now();
            for i in 0..STEPS {
                now = now + period;
                std::hint::black_box(
                    arbiter.step(now, std::hint::black_box(busy_sample(i % 32, now))),
                );
            }
            started.elapsed() / STEPS
        })
        .min()
        .unwrap_or(Duration::ZERO)
}

/// The fleet options of one run.
fn fleet_options(options: &Guard, idle: bool) -> Options {
    Options::cpu_only(options.vehicles, options.vehicles, idle, options.window)
}

/// Between two fleets, for the first one's processes and namespace to be gone.
const BETWEEN_FLEETS: Duration = Duration::from_secs(3);

/// One attempt: an idle run, a streaming run, the yardstick. Idle first: measured right after
/// a streaming fleet, an idle fleet cost up to twice its usual in one attempt of four, which a
/// fleet measured on its own never did (8 × 8 idle, seven runs: 0.29–0.34 % per node).
///
/// # Errors
/// A fleet run failed.
pub fn attempt(rove: &Path, options: &Guard) -> anyhow::Result<Ratios> {
    let quiet = &mut |_: &str| {};
    let idle = fleet::run(rove, &fleet_options(options, true), quiet)?;
    std::thread::sleep(BETWEEN_FLEETS);
    let streaming = fleet::run(rove, &fleet_options(options, false), quiet)?;
    std::thread::sleep(BETWEEN_FLEETS);
    Ok(Ratios::of(
        streaming.vehicles + streaming.operators,
        streaming.operators,
        streaming.cpu_total_pct,
        idle.cpu_total_pct,
        arbiter_step(),
    ))
}

/// Reads a baseline written by [`write_baseline`].
///
/// # Errors
/// The file cannot be read or is not a baseline.
pub fn read_baseline(path: &Path) -> anyhow::Result<Baseline> {
    let text = std::fs::read_to_string(path)
        .map_err(|e| anyhow::anyhow!("cannot read the baseline {}: {e}", path.display()))?;
    serde_json::from_str(&text)
        .map_err(|e| anyhow::anyhow!("the baseline {} is not one: {e}", path.display()))
}

/// Prints one attempt.
fn print_attempt(n: usize, vehicles: usize, r: &Ratios) {
    println!(
        "attempt {n}: {vehicles}×{vehicles} streaming {:.2} % per node, idle {:.2} % per node, \
         arbiter step {:.0} ns: streaming ÷ idle {:.2}, a sample {:.0} arbiter steps",
        r.streaming_node_pct,
        r.idle_node_pct,
        r.arbiter_step_ns,
        r.streaming_over_idle,
        r.sample_in_arbiter_steps,
    );
}

/// The median of each ratio (and of each measurement) over `runs`.
#[must_use]
pub fn median(runs: &[Ratios]) -> Option<Ratios> {
    let of = |f: fn(&Ratios) -> f64| {
        let mut v: Vec<f64> = runs.iter().map(f).collect();
        v.sort_by(f64::total_cmp);
        v.get(v.len() / 2).copied()
    };
    Some(Ratios {
        streaming_over_idle: of(|r| r.streaming_over_idle)?,
        sample_in_arbiter_steps: of(|r| r.sample_in_arbiter_steps)?,
        streaming_node_pct: of(|r| r.streaming_node_pct)?,
        idle_node_pct: of(|r| r.idle_node_pct)?,
        arbiter_step_ns: of(|r| r.arbiter_step_ns)?,
    })
}

/// `rove bench guard --write-baseline`: every attempt, their medians written as the baseline.
///
/// # Errors
/// A fleet run failed, or the file cannot be written.
pub fn write_baseline(
    rove: &Path,
    options: &Guard,
    path: &Path,
    note: &str,
) -> anyhow::Result<Baseline> {
    let mut runs = Vec::new();
    for n in 1..=options.attempts.max(1) {
        let r = attempt(rove, options)?;
        print_attempt(n, options.vehicles, &r);
        runs.push(r);
    }
    let b = Baseline {
        ratios: median(&runs).ok_or_else(|| anyhow::anyhow!("no attempt"))?,
        vehicles: options.vehicles,
        note: note.to_string(),
    };
    std::fs::write(path, serde_json::to_string_pretty(&b)? + "\n")?;
    println!(
        "baseline (medians of {} attempts) written to {}: streaming ÷ idle {:.2}, a sample {:.0} \
         arbiter steps",
        runs.len(),
        path.display(),
        b.ratios.streaming_over_idle,
        b.ratios.sample_in_arbiter_steps
    );
    Ok(b)
}

/// `rove bench guard --baseline`: the medians of every attempt against the baseline's bound.
///
/// # Errors
/// A fleet run failed, or a median is over the bound.
pub fn check(rove: &Path, options: &Guard, baseline: &Baseline) -> anyhow::Result<()> {
    anyhow::ensure!(
        baseline.vehicles == options.vehicles,
        "the baseline was measured with {} vehicles, this run has {}",
        baseline.vehicles,
        options.vehicles
    );
    println!(
        "baseline ({}): streaming ÷ idle {:.2} (bound +{:.0} %), a sample {:.0} arbiter steps \
         (bound +{:.0} %)",
        baseline.note,
        baseline.ratios.streaming_over_idle,
        options.tolerance * 100.0,
        baseline.ratios.sample_in_arbiter_steps,
        options.sample_tolerance * 100.0
    );
    let mut runs = Vec::new();
    for n in 1..=options.attempts.max(1) {
        let r = attempt(rove, options)?;
        print_attempt(n, options.vehicles, &r);
        runs.push(r);
    }
    let m = median(&runs).ok_or_else(|| anyhow::anyhow!("no attempt"))?;
    println!(
        "medians of {} attempts: streaming ÷ idle {:.2}, a sample {:.0} arbiter steps",
        runs.len(),
        m.streaming_over_idle,
        m.sample_in_arbiter_steps
    );
    let over = m.over(
        &baseline.ratios,
        options.tolerance,
        options.sample_tolerance,
    );
    if over.is_empty() {
        println!("within the baseline's bound");
        return Ok(());
    }
    anyhow::bail!(
        "the fleet's streaming cost regressed (docs/design.md, \"A guard on the fleet's \
         cost\"): {}",
        over.join("; ")
    )
}

/// `rove bench guard`: with a baseline, [`check`]; with a file to write, [`write_baseline`];
/// else one attempt, printed.
///
/// # Errors
/// As [`check`] and [`write_baseline`].
pub fn cli(
    rove: &Path,
    options: &Guard,
    baseline: Option<&Path>,
    write: Option<(&Path, &str)>,
) -> anyhow::Result<()> {
    match (baseline, write) {
        (Some(path), _) => check(rove, options, &read_baseline(path)?),
        (None, Some((path, note))) => write_baseline(rove, options, path, note).map(drop),
        (None, None) => {
            print_attempt(1, options.vehicles, &attempt(rove, options)?);
            Ok(())
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// 8 × 8: 16 nodes at 1 % streaming and 0.3 % idle, an arbiter step of 100 ns.
    fn eight_by_eight(streaming_node_pct: f64) -> Ratios {
        Ratios::of(
            16,
            8,
            16.0 * streaming_node_pct,
            16.0 * 0.3,
            Duration::from_nanos(100),
        )
    }

    #[test]
    fn the_ratios_cancel_what_the_machine_does_not_change() {
        let r = eight_by_eight(1.0);
        assert!((r.streaming_over_idle - 1.0 / 0.3).abs() < 1e-9);
        // 0.112 of a core beyond idle for 8 × 50 samples a second: 280 µs a sample.
        assert!((r.sample_in_arbiter_steps - 2800.0).abs() < 1e-6);
        // A machine twice as slow: every cost doubles, the ratios stay.
        let slow = Ratios::of(16, 8, 32.0, 9.6, Duration::from_nanos(200));
        assert!((slow.streaming_over_idle - r.streaming_over_idle).abs() < 1e-9);
        assert!((slow.sample_in_arbiter_steps - r.sample_in_arbiter_steps).abs() < 1e-6);
    }

    #[test]
    fn only_growth_beyond_the_tolerance_is_over() {
        let baseline = eight_by_eight(1.0);
        let over =
            |streaming_node_pct| eight_by_eight(streaming_node_pct).over(&baseline, 0.25, 0.6);
        assert!(over(1.0).is_empty());
        // +10 % a node is +14 % a sample (the idle share stays): within both.
        assert!(over(1.1).is_empty());
        assert!(over(0.6).is_empty(), "cheaper is fine");
        // +30 % a node: streaming ÷ idle +30 % (over 25), a sample +43 % (within 60).
        let o = over(1.3);
        assert_eq!(o.len(), 1, "{o:?}");
        assert!(o[0].starts_with("streaming ÷ idle"), "{o:?}");
        // A regression of idle and streaming together: streaming ÷ idle stays, the sample's
        // cost in arbiter steps does not.
        let both = Ratios::of(16, 8, 16.0 * 2.0, 16.0 * 0.6, Duration::from_nanos(100));
        let o = both.over(&baseline, 0.25, 0.6);
        assert_eq!(o.len(), 1, "{o:?}");
        assert!(o[0].starts_with("a sample in arbiter steps"), "{o:?}");
    }

    #[test]
    fn the_baseline_is_each_ratios_median() {
        let runs = [
            eight_by_eight(1.0),
            eight_by_eight(2.0),
            eight_by_eight(1.2),
        ];
        let m = median(&runs).expect("three runs");
        assert_eq!(m, eight_by_eight(1.2));
        assert!(median(&[]).is_none());
    }

    #[test]
    fn an_idle_fleet_that_cost_nothing_does_not_divide_by_zero() {
        let r = Ratios::of(16, 8, 16.0, 0.0, Duration::ZERO);
        assert!(r.streaming_over_idle.is_finite());
        assert!(r.sample_in_arbiter_steps.is_finite());
    }
}
