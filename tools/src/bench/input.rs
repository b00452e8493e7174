//! `rove bench input`: input event → vehicle output latency through DDS.

use super::report::{Stats, ms};
use super::{VEHICLE, read_events};
use crate::harness::{Rig, records};
use std::fmt::Write as _;
use std::path::Path;
use std::time::{Duration, Instant};

/// `rove bench input`: input event → vehicle output. A replayed joystick (rove-inputs' replay
/// source) moves the throttle `events` times at `rate_hz`, each to a value of its own; the
/// operator records the instant it reads each value (`--record`), the vehicle the instant its
/// adapter applies it. Latency = applied − read, matched by value, in ms (the first value, the
/// device's state at start-up, is sent before discovery ends and is skipped). What it leaves out:
/// the kernel's evdev delivery (there is no input device here).
///
/// # Errors
/// The rig cannot be built or the processes do not produce the records in time.
pub fn input_latency(
    rove: &Path,
    events: usize,
    rate_hz: f64,
    progress: &mut dyn FnMut(&str),
) -> anyhow::Result<(Stats, usize)> {
    let mut rig = Rig::new(rove, "bench-input")?;
    let vehicle_record = rig.vehicle(VEHICLE);
    // Start after DDS discovery (~1 s here).
    let replay = Replay {
        operator: 11,
        start_ms: 3000.0,
        events,
        rate_hz,
    };
    replay_to(&mut rig, &vehicle_record, &replay, progress)
}

/// A replayed joystick: its operator's id (a mobile phone driving vehicle 100), its first
/// event `start_ms` after the operator starts, `events` at `rate_hz`.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Replay {
    pub(crate) operator: i64,
    pub(crate) start_ms: f64,
    pub(crate) events: usize,
    pub(crate) rate_hz: f64,
}

/// [`input_latency`] with the `replay`'s operator in `rig`, which may be the vehicle's or
/// another site's; the vehicle records to `vehicle_record`. The operator is stopped at the end.
///
/// # Errors
/// As [`input_latency`].
pub(crate) fn replay_to(
    rig: &mut Rig,
    vehicle_record: &Path,
    replay: &Replay,
    progress: &mut dyn FnMut(&str),
) -> anyhow::Result<(Stats, usize)> {
    let Replay {
        operator: id,
        start_ms,
        events,
        rate_hz,
    } = *replay;
    // Centred first (rove-inputs' no-jump rule).
    let period_ms = 1000.0 / rate_hz.clamp(1.0, 1000.0);
    let mut text = String::from("0 replug Bench Pad\n0 absinfo ABS_Y 0 -32768 32767 0 0\n");
    let mut expected = Vec::with_capacity(events);
    for i in 0..events {
        let t = start_ms + i as f64 * period_ms;
        // 0, 16, 32 … then back down: distinct values, no jump larger than a real stick's.
        let raw = ((i % 2000) as i64 * 16).min(32_000);
        let _ = writeln!(text, "{t:.3} ABS_Y {raw}\n{t:.3} SYN_REPORT");
        expected.push(raw);
    }
    let end_ms = start_ms + events as f64 * period_ms + 500.0;
    let _ = writeln!(text, "{end_ms:.3} unplug end of the benchmark");
    let recording = rig.write("bench-pad.txt", &text);
    let config = rig.write(
        &format!("operator-bench-{id}.toml"),
        &format!(
            "[device]\nid = {id}\nname = \"bench-pad\"\n[operator]\nlevel = \"mobile\"\n\
             device_class = \"phone\"\ndrive = [{VEHICLE}]\n[input]\nsource = \"replay\"\n\
             file = \"{}\"\n[input.axes.throttle]\nabs = \"ABS_Y\"\ndeadzone_pct = 0\n",
            recording.display()
        ),
    );
    let op_record = rig.dir.join(format!("operator-bench-{id}.jsonl"));
    let operator = rig.spawn(
        "operator-bench",
        &[
            "operator",
            "-c",
            config.to_str().unwrap_or_default(),
            "--record",
            op_record.to_str().unwrap_or_default(),
        ],
    );
    progress(&format!(
        "{events} input events at {rate_hz} Hz after a {:.0} s start",
        start_ms / 1000.0
    ));
    let deadline = Instant::now() + Duration::from_secs_f64(end_ms / 1000.0 + 20.0);
    let mut inputs: Vec<(u64, i64)>;
    loop {
        std::thread::sleep(Duration::from_millis(200));
        inputs = read_events(&op_record)
            .iter()
            .filter(|e| e["kind"] == "input")
            .filter_map(|e| Some((e["wall_us"].as_u64()?, e["throttle"].as_i64()?)))
            .collect();
        let done = records(vehicle_record)
            .iter()
            .any(|o| o.action != "apply" && o.wall_us > inputs.last().map_or(u64::MAX, |i| i.0));
        if (inputs.len() >= events && done) || Instant::now() > deadline {
            break;
        }
    }
    let outputs = records(vehicle_record);
    let mut latencies = Vec::new();
    let mut unmatched = 0;
    let mut slow = Vec::new();
    // The first value is the device's centred state at start-up (replug), read and sent before
    // DDS discovery has finished; it measures discovery, not the input path: skipped.
    for (i, (read_us, throttle)) in inputs.iter().enumerate().skip(1) {
        match outputs
            .iter()
            .find(|o| o.owner == Some(id) && o.throttle == Some(*throttle) && o.wall_us >= *read_us)
        {
            Some(o) => {
                let l = ms(o.wall_us - read_us);
                if l > 2.0 {
                    slow.push(format!("#{i} {l:.1}"));
                }
                latencies.push(l);
            }
            // The vehicle applies the newest sample it holds: a value it never saw alone was
            // superseded, not lost.
            None => unmatched += 1,
        }
    }
    progress(&format!(
        "over 2 ms: {} of {}: {}",
        slow.len(),
        inputs.len(),
        slow.iter().take(40).cloned().collect::<Vec<_>>().join(", ")
    ));
    rig.procs[operator].terminate();
    rig.procs[operator].wait_exit(Duration::from_secs(5));
    let stats = Stats::of(&latencies).ok_or_else(|| {
        anyhow::anyhow!("no input reached the vehicle; see {}", rig.dir.display())
    })?;
    Ok((stats, unmatched))
}

/// `rove bench input`: replays `events` stick values at `rate_hz` and prints the latency
/// summary.
///
/// # Errors
/// As [`input_latency`].
pub fn input_cli(rove: &Path, events: usize, rate_hz: f64) -> anyhow::Result<()> {
    let (s, unmatched) = input_latency(rove, events, rate_hz, &mut |line| eprintln!("  {line}"))?;
    println!(
        "input read → vehicle output (ms), {events} events at {rate_hz} Hz: \
         mean {:.3} stdev {:.3} min {:.3} p50 {:.3} p99 {:.3} max {:.3}; unmatched {unmatched}",
        s.mean, s.stdev, s.min, s.p50, s.p99, s.max
    );
    Ok(())
}
