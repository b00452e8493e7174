//! `rove demo`: a simulated vehicle and three operators, showing every kind of handover.
//!
//! [`run_processes`] (the default) starts real `rove vehicle` / `rove operator` processes in a
//! private network namespace (loopback only, so nothing leaves the machine; needs root and
//! iproute2) and prints each handover as the vehicle's output shows it, with the measured time.
//! [`run`] (`--in-process`, and the fallback without namespaces) plays the same story on the
//! control core alone, on a virtual clock, with the network replaced by direct delivery.
//!
//! The story (default strengths, DESIGN.md §3):
//! 1. a stationary laptop (220) joins and drives;
//! 2. a mobile phone (340) joins and preempts it;
//! 3. the phone quits gracefully: control falls back to the laptop at once;
//! 4. a remote tablet (130) requests control; the laptop's operator accepts; the tablet drives
//!    with a priority grant and later finishes it, handing back to the laptop;
//! 5. the laptop crashes: after the 100 ms command timeout the vehicle enters failsafe.

use rove_core::MonoTime;
use rove_core::adapter::OutputAdapter;
use rove_core::arbiter::{Arbiter, ArbiterConfig, Event, Output, Owner, ParticipantId, WriterId};
use rove_core::handover::{Action, Handover, HandoverConfig};
use rove_core::hierarchy::{DeviceClass, Hierarchy, Level, Strength};
use rove_core::msg::{
    Ack, CommandType, ControlCommand, DeviceId, Mode, MovementCommand, RequestControl, TimeT,
};
use rove_core::sim::{SimAction, SimOutput};
use std::fmt::Write as _;
use std::time::Duration;

const VEHICLE: DeviceId = 100;
/// Operators stream at the default 50 Hz.
const STREAM_PERIOD_MS: u64 = 20;
/// The simulation's resolution: fine enough to show the 100 ms timeout to within 5 ms.
const STEP_MS: u64 = 5;

/// One scripted operator.
struct Operator {
    name: &'static str,
    id: DeviceId,
    strength: Strength,
    handover: Handover,
    /// Streams with its regular writer.
    driving: bool,
    /// Streams with its priority writer (holds a grant).
    priority: bool,
    /// Yielded: keeps its regular stream alive with PROBEs.
    standby: bool,
}

impl Operator {
    fn writer(&self, priority: bool) -> WriterId {
        WriterId {
            participant: ParticipantId(u128::try_from(self.id).unwrap_or_default()),
            entity: if priority { 2 } else { 1 },
        }
    }
}

#[derive(Debug, Clone, Copy)]
enum Cue {
    Join(usize),
    Quit(usize),
    Crash(usize),
    Request(usize),
    Consent(usize, bool),
    Finish(usize),
}

/// Runs the demo. With `pace`, waits in real time between events so it can be watched; the
/// story and its output are the same either way. Returns the printed story.
pub fn run(pace: bool, mut print: impl FnMut(&str)) -> anyhow::Result<DemoSummary> {
    let h = Hierarchy::STANDARD;
    let make = |name, id, level, class| -> anyhow::Result<Operator> {
        let strength = h.strength(level, class, 0)?;
        Ok(Operator {
            name,
            id,
            strength,
            handover: Handover::new(id, strength, HandoverConfig::default()),
            driving: false,
            priority: false,
            standby: false,
        })
    };
    let mut ops = vec![
        make(
            "laptop (stationary)",
            11,
            Level::Stationary,
            DeviceClass::Laptop,
        )?,
        make("phone (mobile)", 12, Level::Mobile, DeviceClass::Phone)?,
        make("tablet (remote)", 13, Level::Remote, DeviceClass::Tablet)?,
    ];
    let script = [
        (100, Cue::Join(0)),
        (600, Cue::Join(1)),
        (1200, Cue::Quit(1)),
        (1800, Cue::Request(2)),
        (2300, Cue::Consent(0, true)),
        (3300, Cue::Finish(2)),
        (4000, Cue::Crash(0)),
    ];
    let end_ms = 4500;

    let mut vehicle = Arbiter::new(VEHICLE, ArbiterConfig::default());
    let mut output = SimOutput::default();
    let mut summary = DemoSummary::default();
    output.safe_state(MonoTime::ZERO)?;
    print(&format!(
        "rove demo: vehicle {VEHICLE} (sim output) and operators {} — in-process simulation of \
         the control core",
        ops.iter()
            .map(|o| format!("{} id {} strength {}", o.name, o.id, o.strength))
            .collect::<Vec<_>>()
            .join(", ")
    ));

    let mut next_cue = 0;
    let started = std::time::Instant::now();
    for t in (0..=end_ms).step_by(STEP_MS as usize) {
        let now = MonoTime::from_millis(t);
        if pace {
            let due = Duration::from_millis(t);
            if let Some(wait) = due.checked_sub(started.elapsed()) {
                std::thread::sleep(wait);
            }
        }
        let mut log = Vec::new();
        let mut events = Vec::new();
        let mut bus: Vec<RequestControl> = Vec::new();

        // Cues due now.
        while let Some((at, cue)) = script.get(next_cue).copied() {
            if at > t {
                break;
            }
            next_cue += 1;
            match cue {
                Cue::Join(i) => {
                    ops[i].driving = true;
                    log.push(format!("{} starts driving", ops[i].name));
                }
                Cue::Quit(i) => {
                    ops[i].driving = false;
                    log.push(format!("{} quits (leaves the network)", ops[i].name));
                    events.push(Event::ParticipantGone {
                        participant: ops[i].writer(false).participant,
                    });
                }
                Cue::Crash(i) => {
                    ops[i].driving = false;
                    log.push(format!(
                        "{} crashes (stops sending, no release)",
                        ops[i].name
                    ));
                }
                Cue::Request(i) => {
                    let owner = vehicle.controller_id();
                    log.push(format!("{} requests control from {owner}", ops[i].name));
                    let stamp = TimeT::from_unix(Duration::from_millis(t));
                    let actions = ops[i].handover.request(now, VEHICLE, owner, stamp)?;
                    handle(&mut ops, i, actions, &mut bus, &mut events, &mut log);
                }
                Cue::Consent(i, accept) => {
                    let verdict = if accept { "accepts" } else { "refuses" };
                    log.push(format!("{}'s operator {verdict}", ops[i].name));
                    let actions = ops[i].handover.decide(now, VEHICLE, accept)?;
                    handle(&mut ops, i, actions, &mut bus, &mut events, &mut log);
                }
                Cue::Finish(i) => {
                    log.push(format!("{} finishes its grant", ops[i].name));
                    let actions = ops[i].handover.finish(VEHICLE)?;
                    handle(&mut ops, i, actions, &mut bus, &mut events, &mut log);
                }
            }
        }
        // Deliver RequestControl samples to every other operator and to the vehicle. They were
        // sent before anything the same actions did to the streams, so the vehicle sees them
        // first.
        let mut grants = Vec::new();
        while let Some(msg) = bus.pop() {
            match msg.ack {
                Ack::Accept => grants.push(Event::GrantAccepted {
                    holder: msg.src_id,
                    granted_by: msg.current_controller_id,
                    stamp: msg.timestamp,
                }),
                Ack::Finish => grants.push(Event::GrantFinished {
                    holder: msg.src_id,
                    stamp: msg.timestamp,
                }),
                Ack::Request | Ack::Refuse => {}
            }
            for i in 0..ops.len() {
                let actions = ops[i].handover.on_message(now, &msg);
                handle(&mut ops, i, actions, &mut bus, &mut events, &mut log);
            }
        }
        grants.append(&mut events);
        let mut events = grants;
        // Streams at 50 Hz.
        if t % STREAM_PERIOD_MS == 0 {
            for op in &ops {
                for (streaming, priority) in [(op.driving, false), (op.priority, true)] {
                    if streaming {
                        events.push(sample(op, priority, CommandType::Movement, now, t));
                    }
                }
                if op.standby {
                    events.push(sample(op, false, CommandType::Probe, now, t));
                }
            }
        }
        events.push(Event::Tick);

        for line in log {
            print(&format!("{:>8}  {line}", now.to_string()));
        }
        for event in events {
            let d = vehicle.step(now, event);
            if let Some(change) = d.owner_change {
                summary
                    .handovers
                    .push((t, change.to.device(), change.reason.to_string()));
                print(&format!(
                    "{:>8}  vehicle {VEHICLE}: {} → {} ({})",
                    now.to_string(),
                    name(&ops, change.from),
                    name(&ops, change.to),
                    change.reason
                ));
            }
            match d.output {
                Some(Output::Apply { setpoint, .. }) => output.apply(now, &setpoint)?,
                Some(Output::SafeState { .. }) => output.safe_state(now)?,
                None => {}
            }
        }
    }
    summary.outputs = output.records().count();
    summary.safe_at_end = matches!(output.last().map(|r| r.action), Some(SimAction::SafeState));
    print(&format!(
        "done: {} handovers, {} outputs recorded, outputs {} at the end",
        summary.handovers.len(),
        summary.outputs,
        if summary.safe_at_end {
            "safe"
        } else {
            "driving"
        }
    ));
    Ok(summary)
}

/// The story with real processes over DDS. Each step waits for the vehicle's output to show the
/// expected owner and prints how long that took from the trigger.
///
/// # Errors
/// The namespace cannot be created (not root, no iproute2), or a step's outcome never shows.
pub fn run_processes(rove: &std::path::Path, print: &mut dyn FnMut(&str)) -> anyhow::Result<()> {
    use crate::harness::{Rig, wait_for_output, wall_us};
    let mut rig = Rig::new(rove, "demo").map_err(anyhow::Error::msg)?;
    let record = rig.vehicle(VEHICLE);
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
        "[handover]\nauto_accept = \"always\"\n",
        &[],
    );
    step(
        "laptop 11 (stationary, 220) starts and joins",
        Some(11),
        start,
    )?;
    let t = wall_us();
    let phone = rig.operator(12, "mobile", "phone", &[VEHICLE], 2000, "", &[]);
    step("phone 12 (mobile, 340) starts and preempts", Some(12), t)?;
    let t = wall_us();
    rig.procs[phone].terminate();
    step("phone quits (releases)", Some(11), t)?;
    let t = wall_us();
    let tablet = rig.operator(13, "remote", "tablet", &[], 3000, "", &["--request", "100"]);
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

fn sample(op: &Operator, priority: bool, kind: CommandType, now: MonoTime, t: u64) -> Event {
    // A gentle sine-like sweep so that applied values visibly change.
    let throttle = ((t / STREAM_PERIOD_MS) % 200) as i16 * 100 - 10_000;
    Event::Sample {
        writer: op.writer(priority),
        strength: if priority {
            Strength::PRIORITY
        } else {
            op.strength
        },
        command: ControlCommand {
            src_id: op.id,
            dest_id: VEHICLE,
            command_type: kind,
            movement_command: MovementCommand {
                throttle,
                ..MovementCommand::CENTRED
            },
            mode: Mode::Manual,
            timestamp: TimeT::from_unix(Duration::from_millis(t)),
        },
        arrival: now,
    }
}

/// Carries out one operator's handover actions.
fn handle(
    ops: &mut [Operator],
    i: usize,
    actions: Vec<Action>,
    bus: &mut Vec<RequestControl>,
    events: &mut Vec<Event>,
    log: &mut Vec<String>,
) {
    for action in actions {
        let op = &mut ops[i];
        match action {
            Action::Send(msg) => bus.push(msg),
            Action::AskOperator { requester, .. } => log.push(format!(
                "{} is asked to give control to {requester}",
                op.name
            )),
            Action::Yield { .. } => {
                op.driving = false;
                op.standby = true;
                log.push(format!("{} yields (stops driving, stands by)", op.name));
            }
            Action::EndStandby { .. } => op.standby = false,
            Action::Resume { .. } => {
                op.driving = true;
                op.standby = false;
                log.push(format!("{} resumes driving", op.name));
            }
            Action::StartPriorityDriving { .. } => {
                op.priority = true;
                log.push(format!("{} drives with its priority writer", op.name));
            }
            Action::StopPriorityDriving { .. } => {
                op.priority = false;
                events.push(Event::Released {
                    writer: op.writer(true),
                });
            }
            Action::RequestEnded { outcome, .. } => log.push(format!(
                "{}: its request ended: {}",
                op.name,
                format!("{outcome:?}").to_lowercase()
            )),
            Action::PromptClosed { outcome, .. } => log.push(format!(
                "{}: consent prompt closed: {}",
                op.name,
                format!("{outcome:?}").to_lowercase()
            )),
        }
    }
}

fn name(ops: &[Operator], owner: Owner) -> String {
    match owner {
        Owner::Failsafe => "failsafe".into(),
        Owner::Controller(c) => {
            let mut s = ops
                .iter()
                .find(|o| o.id == c.device)
                .map_or_else(|| c.device.to_string(), |o| o.name.to_string());
            if c.strength == Strength::PRIORITY {
                let _ = write!(s, " [priority]");
            }
            s
        }
    }
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
                (Some(11), "left"),
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
