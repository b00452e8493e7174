//! `rove demo`: a simulated vehicle and three operators, showing every kind of handover.
//!
//! [`run_processes`] (the default) starts real `rove vehicle` / `rove operator` processes in a
//! private network namespace (loopback only, so nothing leaves the machine; needs root and
//! iproute2) and prints each handover as the vehicle's output shows it, with the measured time.
//! [`run`] (`--in-process`, and the fallback without namespaces) plays the same story on the
//! control core alone, on a virtual clock, with the network replaced by direct delivery.
//!
//! The story (default strengths, docs/design.md §3):
//! 1. a stationary laptop (220) joins and drives;
//! 2. a mobile phone (340) joins and preempts it;
//! 3. the phone quits gracefully: control falls back to the laptop at once;
//! 4. a remote tablet (130) requests control; the laptop's operator accepts; the tablet drives
//!    with a priority grant and later finishes it, handing back to the laptop;
//! 5. the laptop crashes: after the 100 ms command timeout the vehicle enters failsafe.

use rove_core::MonoTime;
use rove_core::adapter::{InputEvent, OutputAdapter};
use rove_core::arbiter::{Arbiter, ArbiterConfig, Decision, Event, Output, Owner, ParticipantId};
use rove_core::handover::HandoverConfig;
use rove_core::hierarchy::{DeviceClass, Hierarchy, Level, Strength};
use rove_core::msg::{DeviceId, MovementCommand};
use rove_core::session::{Command, Effect, Report, SessionConfig, SessionEvent, SessionInput};
use rove_core::sim::{SimAction, SimOutput};
use rove_core::trust::TrustConfig;
use rove_core::world::{Observer, Operator, View, World};
use std::fmt::Write as _;
use std::time::Duration;

const VEHICLE: DeviceId = 100;
/// The vehicle's participant, which its DeviceInfo comes from.
const VEHICLE_PARTICIPANT: ParticipantId = ParticipantId(0x100_0000);
/// Operators stream at the default 50 Hz.
const STREAM_PERIOD_MS: u64 = 20;
/// The vehicle publishes its DeviceInfo at the default heartbeat, and at once on owner changes.
const HEARTBEAT_MS: u64 = 500;
/// The simulation's resolution: fine enough to show the 100 ms timeout to within 5 ms.
const STEP_MS: u64 = 5;

#[derive(Debug, Clone, Copy)]
enum Cue {
    Join(usize),
    Quit(usize),
    Crash(usize),
    Command(usize, Command),
}

/// The in-process story's observer: prints what happens, drives the sim output from the
/// arbiter's decisions and keeps the summary.
struct Story<'p> {
    names: Vec<&'static str>,
    output: SimOutput,
    summary: DemoSummary,
    print: &'p mut dyn FnMut(&str),
}

impl Story<'_> {
    fn say(&mut self, now: MonoTime, line: &str) {
        (self.print)(&format!("{:>8}  {line}", now.to_string()));
    }

    fn name(&self, world: View<'_>, owner: Owner) -> String {
        match owner {
            Owner::Failsafe => "failsafe".into(),
            Owner::Controller(c) => {
                let mut s = (world.operators.iter().position(|o| o.id == c.device))
                    .and_then(|i| self.names.get(i))
                    .map_or_else(|| c.device.to_string(), ToString::to_string);
                if c.strength == Strength::PRIORITY {
                    let _ = write!(s, " [priority]");
                }
                s
            }
        }
    }
}

impl Observer for Story<'_> {
    type Error = anyhow::Error;

    fn effect(&mut self, world: View<'_>, from: usize, effect: &Effect) -> anyhow::Result<()> {
        let name = self.names.get(from).copied().unwrap_or("?");
        match effect {
            Effect::Report(Report::Selected { .. } | Report::InputLive { .. }) => {}
            Effect::Report(report) => self.say(world.now, &format!("{name}: {report}")),
            Effect::Refused(why) => anyhow::bail!("{name}: {why}"),
            _ => {}
        }
        Ok(())
    }

    fn decision(&mut self, world: View<'_>, d: &Decision) -> anyhow::Result<()> {
        if let Some(change) = d.owner_change {
            let ms = world.now.saturating_since(MonoTime::ZERO).as_millis();
            let ms = u64::try_from(ms).unwrap_or(u64::MAX);
            let reason = change.reason.to_string();
            let line = format!(
                "vehicle {VEHICLE}: {} → {} ({reason})",
                self.name(world, change.from),
                self.name(world, change.to),
            );
            self.summary
                .handovers
                .push((ms, change.to.device(), reason));
            self.say(world.now, &line);
        }
        match d.output {
            Some(Output::Apply { setpoint, .. }) => self.output.apply(world.now, &setpoint)?,
            Some(Output::SafeState { .. }) => self.output.safe_state(world.now)?,
            None => {}
        }
        Ok(())
    }
}

type Demo<'p> = World<Story<'p>>;

/// Plays one cue of the script.
fn cue(world: &mut Demo<'_>, cue: Cue) -> anyhow::Result<()> {
    let now = world.now();
    let name = |w: &Demo<'_>, i: usize| w.observer().names.get(i).copied().unwrap_or("?");
    match cue {
        Cue::Join(i) => {
            let line = format!("{} starts", name(world, i));
            world.observer_mut().say(now, &line);
            world.start(i);
            // DeviceInfo is TRANSIENT_LOCAL: a joiner gets the vehicle's at once.
            world.publish_owner()?;
        }
        Cue::Quit(i) => {
            let line = format!("{} quits (releases, leaves the network)", name(world, i));
            world.observer_mut().say(now, &line);
            world.quit(i)?;
        }
        Cue::Crash(i) => {
            let line = format!("{} crashes (stops sending, no release)", name(world, i));
            world.observer_mut().say(now, &line);
            world.crash(i);
        }
        Cue::Command(i, command) => {
            let line = format!("{}'s operator: {}", name(world, i), command.name());
            world.observer_mut().say(now, &line);
            world.step(i, SessionEvent::Command(command))?;
        }
    }
    Ok(())
}

/// The story's three operators (names, and the operators not started yet): a stationary
/// laptop and a mobile phone that drive the vehicle from the start, and a remote tablet that
/// asks for it.
fn operators() -> anyhow::Result<(Vec<&'static str>, Vec<Operator>)> {
    let h = Hierarchy::STANDARD;
    let make = |id, level, class, drive: &[DeviceId]| -> anyhow::Result<Operator> {
        let config = SessionConfig {
            me: id,
            strength: h.strength(level, class, 0)?,
            handover: HandoverConfig::default(),
            drive: drive.to_vec(),
            input: SessionInput::Device,
            heartbeat: Duration::from_millis(HEARTBEAT_MS),
            confirm_actions: false,
            request: None,
            participant: ParticipantId(u128::from(id.unsigned_abs())),
            trust: TrustConfig::default(),
        };
        Ok(Operator::new(config, MonoTime::ZERO).not_started())
    };
    let (stationary, mobile) = (Level::Stationary, Level::Mobile);
    let ops = vec![
        make(11, stationary, DeviceClass::Laptop, &[VEHICLE])?,
        make(12, mobile, DeviceClass::Phone, &[VEHICLE])?,
        make(13, Level::Remote, DeviceClass::Tablet, &[])?,
    ];
    let names = vec!["laptop (stationary)", "phone (mobile)", "tablet (remote)"];
    Ok((names, ops))
}

/// Runs the demo. With `pace`, waits in real time between events so it can be watched; the
/// story and its output are the same either way. Returns the printed story.
pub fn run(pace: bool, mut print: impl FnMut(&str)) -> anyhow::Result<DemoSummary> {
    let (names, ops) = operators()?;
    let vehicle = Command::Request { vehicle: VEHICLE };
    let script = [
        (100, Cue::Join(0)),
        (600, Cue::Join(1)),
        (1200, Cue::Quit(1)),
        (1700, Cue::Join(2)),
        (1800, Cue::Command(2, vehicle)),
        (2300, Cue::Command(0, Command::Accept { vehicle: VEHICLE })),
        (3300, Cue::Command(2, Command::Finish { vehicle: VEHICLE })),
        (4000, Cue::Crash(0)),
    ];
    let end_ms = 4500;

    let line = format!(
        "rove demo: vehicle {VEHICLE} (sim output) and operators {} — in-process simulation of \
         the control core (the operators run rove operator's session)",
        names
            .iter()
            .zip(&ops)
            .map(|(name, o)| format!("{name} id {} strength {}", o.id, o.strength))
            .collect::<Vec<_>>()
            .join(", ")
    );
    print(&line);
    let mut print = |line: &str| print(line);
    let story = Story {
        names,
        output: SimOutput::default(),
        summary: DemoSummary::default(),
        print: &mut print,
    };
    let arbiter = Arbiter::new(VEHICLE, ArbiterConfig::default());
    let mut world = World::new(arbiter, VEHICLE_PARTICIPANT, ops, story);
    world.observer_mut().output.safe_state(MonoTime::ZERO)?;

    let mut next_cue = 0;
    let started = std::time::Instant::now();
    for t in (0..=end_ms).step_by(STEP_MS as usize) {
        world.set_now(MonoTime::from_millis(t));
        if pace {
            let due = Duration::from_millis(t);
            if let Some(wait) = due.checked_sub(started.elapsed()) {
                std::thread::sleep(wait);
            }
        }
        // Cues due now.
        while let Some((at, next)) = script.get(next_cue).copied() {
            if at > t {
                break;
            }
            next_cue += 1;
            cue(&mut world, next)?;
        }
        if t % STREAM_PERIOD_MS == 0 {
            // A gentle sweep on every joystick, so that applied values visibly change; the
            // session sends each change at once, and keeps standby streams alive.
            let throttle = ((t / STREAM_PERIOD_MS) % 200) as i16 * 100 - 10_000;
            let sticks = MovementCommand {
                throttle,
                ..MovementCommand::CENTRED
            };
            for i in 0..world.operators().len() {
                world.step(i, SessionEvent::Input(InputEvent::Axes(sticks)))?;
                world.step(i, SessionEvent::StreamTick)?;
            }
        }
        if t % HEARTBEAT_MS == 0 {
            world.publish_owner()?;
        }
        for i in 0..world.operators().len() {
            world.step(i, SessionEvent::Tick)?;
        }
        world.vehicle_step(Event::Tick)?;
    }
    let story = world.into_observer();
    let mut summary = story.summary;
    summary.outputs = story.output.records().count();
    summary.safe_at_end = matches!(
        story.output.last().map(|r| r.action),
        Some(SimAction::SafeState)
    );
    let line = format!(
        "done: {} handovers, {} outputs recorded, outputs {} at the end",
        summary.handovers.len(),
        summary.outputs,
        if summary.safe_at_end {
            "safe"
        } else {
            "driving"
        }
    );
    print(&line);
    Ok(summary)
}

/// The story with real processes over DDS. Each step waits for the vehicle's output to show the
/// expected owner and prints how long that took from the trigger. With `secure`, every process
/// joins with DDS Security, its certificate from a fleet made for the story (`rove keys`).
///
/// # Errors
/// The namespace cannot be created (not root, no iproute2), the keys cannot be made, or a
/// step's outcome never shows.
pub fn run_processes(
    rove: &std::path::Path,
    secure: bool,
    print: &mut dyn FnMut(&str),
) -> anyhow::Result<()> {
    use crate::harness::{Rig, security_toml, wait_for_output, wall_us};
    let mut rig = Rig::new(rove, "demo")?;
    let fleet = if secure {
        let dir = rig.fleet(&[VEHICLE, 11, 12, 13])?;
        print(&format!(
            "DDS Security: fleet CA, governance and certificates for 100, 11, 12, 13 in {}",
            dir.display()
        ));
        Some(dir)
    } else {
        None
    };
    let sec = |id| security_toml(fleet.as_deref(), id);
    let output = format!("{}[output]\nadapter = \"sim\"\n", sec(VEHICLE));
    let record = rig.vehicle_with_output(VEHICLE, &output);
    print(&format!(
        "vehicle {VEHICLE} (sim output) started in a private network namespace (loopback only)"
    ));
    let start = wall_us();
    let mut step = |what: &str, owner: Option<DeviceId>, since: u64| {
        let out = wait_for_output(&record, owner, since).map_err(anyhow::Error::msg)?;
        let who = owner.map_or("the failsafe (outputs safe)".to_string(), |o| o.to_string());
        print(&format!(
            "{what}: vehicle driven by {who} — {:.1} ms later",
            (out.wall_us.saturating_sub(since)) as f64 / 1000.0
        ));
        anyhow::Ok(())
    };
    let laptop = rig.operator(
        11,
        "stationary",
        "laptop",
        &[VEHICLE],
        1000,
        &format!("{}[handover]\nauto_accept = \"always\"\n", sec(11)),
        &[],
    );
    step(
        "laptop 11 (stationary, 220) starts and joins",
        Some(11),
        start,
    )?;
    let t = wall_us();
    let phone = rig.operator(12, "mobile", "phone", &[VEHICLE], 2000, &sec(12), &[]);
    step("phone 12 (mobile, 340) starts and preempts", Some(12), t)?;
    let t = wall_us();
    rig.procs[phone].terminate();
    step("phone quits (releases)", Some(11), t)?;
    let t = wall_us();
    let request = ["--request", "100"];
    let tablet = rig.operator(13, "remote", "tablet", &[], 3000, &sec(13), &request);
    step(
        "tablet 13 (remote, 130) starts and requests; the laptop accepts",
        Some(13),
        t,
    )?;
    let t = wall_us();
    rig.procs[tablet].terminate();
    step("tablet finishes its grant and quits", Some(11), t)?;
    let t = wall_us();
    rig.procs[laptop].crash();
    step(
        "laptop crashes (SIGKILL, no release; command timeout 100 ms)",
        None,
        t,
    )?;
    print("done: every process stops; the namespace is removed");
    Ok(())
}

/// What the demo did, for its test.
#[derive(Debug, Default)]
pub struct DemoSummary {
    /// (time in ms, new owner device, reason) per ownership change.
    pub handovers: Vec<(u64, Option<DeviceId>, String)>,
    /// Outputs the sim vehicle recorded.
    pub outputs: usize,
    /// The vehicle's outputs were in the safe state at the end.
    pub safe_at_end: bool,
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The demo's story happens as printed: each handover at its cue, for its reason, ending in
    /// failsafe after the crash — within the command timeout (100 ms) plus one stream period.
    #[test]
    fn demo_tells_the_whole_story() {
        let mut lines = Vec::new();
        let summary = run(false, |l| lines.push(l.to_string())).expect("demo runs");
        let got: Vec<(Option<DeviceId>, &str)> = summary
            .handovers
            .iter()
            .map(|(_, who, why)| (*who, why.as_str()))
            .collect();
        assert_eq!(
            got,
            [
                (Some(11), "joined"),
                (Some(12), "preempted"),
                // The phone quits as `rove operator` does: it releases before it leaves.
                (Some(11), "released"),
                (Some(13), "granted"),
                // The laptop stood by with PROBEs: no detour through the failsafe.
                (Some(11), "grant returned"),
                (None, "timed out"),
            ],
            "story:\n{}",
            lines.join("\n")
        );
        // The laptop's last sample before its crash at 4000 ms was at 3980 ms.
        let (crash_ms, _, _) = summary.handovers[5];
        assert_eq!(crash_ms, 3980 + 100, "failsafe exactly one timeout later");
        assert!(summary.safe_at_end);
        assert!(summary.outputs > 100);
    }
}
