//! The operators a vehicle's output hosts (a MAVLink vehicle's ground stations with an `id`,
//! [`rove_core::adapter::HostedOperator`]): each runs as an operator of the hierarchy in this
//! process, a participant of its own with its own certificate, as a web console's devices do
//! (docs/design.md, "Ground stations"; docs/mavlink.md, "A ground station in the hierarchy").
//!
//! Its sticks ([`StationSticks`]) come from what the adapter heard. A station drives only once
//! it asked for control (MAV_CMD_REQUEST_OPERATOR_CONTROL, as QGroundControl does before it
//! sends MANUAL_CONTROL) and until it gives it back or goes quiet: its MANUAL_CONTROL silent
//! for the command timeout is a lost input, which releases at once, as an unplugged joystick.
//! Between its request and its first MANUAL_CONTROL its sticks are centred, while its HEARTBEAT
//! comes.

use crate::config::{InputChoice, OperatorConfig, VehicleConfig};
use crate::operator::{Edges, Options, STOP_BOUND, Spawned, Sticks};
use rove_console::{Event, Stamped};
use rove_core::adapter::{
    HostedEvent, HostedLink, HostedOperator, InputAction, InputEvent, InputSource,
};
use rove_core::error::LinkError;
use rove_core::handover::{HandoverConfig, Outcome};
use rove_core::msg::{DeviceId, Mode, MovementCommand};
use rove_core::remote::{Frame, RemoteInput};
use rove_core::time::MonoTime;
use std::collections::VecDeque;
use std::sync::Arc;
use std::time::{Duration, Instant};
use tokio::sync::{Notify, broadcast};
use tracing::info;

/// A station whose HEARTBEAT is older than this no longer holds its request up.
const HEARTBEAT_SILENCE: Duration = Duration::from_secs(3);
/// How often centred sticks are fed while a station waits to stream.
const CENTRED_EVERY: Duration = Duration::from_millis(50);
/// The stream rate of a station's operator, as an operator's default.
const STREAM_PERIOD: Duration = Duration::from_millis(20);

/// The running stations' loops.
#[derive(Debug, Default)]
pub(super) struct Stations {
    running: Vec<Spawned>,
}

impl Stations {
    /// Starts an operator loop for each of `hosted`, driving `config`'s vehicle.
    ///
    /// # Errors
    /// A station's level and class are outside the hierarchy, or a secured vehicle's station has
    /// no certificate of its own.
    pub(super) fn start(
        config: &VehicleConfig,
        hosted: Vec<HostedOperator>,
    ) -> anyhow::Result<Stations> {
        let mut stations = Stations::default();
        for h in hosted {
            let op = operator_config(config, &h)?;
            let silence = config.arbiter.command_timeout.get();
            let sticks = StationSticks::new(Arc::clone(&h.link), silence);
            let wake = Arc::new(Notify::new());
            let waker = Arc::clone(&wake);
            h.link.set_waker(Arc::new(move || waker.notify_one()));
            let boxed: Box<dyn Sticks> = Box::new(sticks);
            let (edges, _commands) =
                Edges::new(Some(boxed), wake, crate::sdnotify::Notifier::disabled());
            tokio::spawn(answer(
                h.id,
                config.common.id,
                edges.events.subscribe(),
                Arc::clone(&h.link),
            ));
            info!(station = h.id, name = %op.common.name, strength = op.strength.0, "ground station joins the hierarchy");
            let operator =
                Spawned::start(op, Options::default(), edges, "ground station's operator");
            stations.running.push(operator);
        }
        Ok(stations)
    }

    /// Stops every station's loop (each releases what it drives), and waits for them, each
    /// at most [`STOP_BOUND`].
    pub(super) async fn stop(mut self) {
        for operator in &mut self.running {
            operator.signal();
        }
        for operator in &mut self.running {
            operator.wait(STOP_BOUND).await;
        }
    }
}

/// A station's operator config: the vehicle's network, the station's identity, its strength
/// from the vehicle's hierarchy, driving this vehicle.
fn operator_config(config: &VehicleConfig, h: &HostedOperator) -> anyhow::Result<OperatorConfig> {
    if config.common.security.is_some() && h.security.is_none() {
        anyhow::bail!(
            "[[output.gcs]] id {}: this vehicle has [security], and a ground station is a \
             participant of its own: give it `security` (its own certificate)",
            h.id
        );
    }
    let strength = (config.access.hierarchy())
        .strength(h.level, h.class, 0)
        .map_err(|e| anyhow::anyhow!("[[output.gcs]] id {}: {e}", h.id))?;
    let mut common = config.common.clone();
    common.id = h.id;
    common.name = format!("{} via MAVLink on vehicle {}", h.name, config.common.id);
    common.security.clone_from(&h.security);
    Ok(OperatorConfig {
        common,
        level: h.level,
        device_class: h.class,
        strength,
        stream_period: STREAM_PERIOD,
        drive: vec![config.common.id],
        handover: HandoverConfig::default(),
        // The sticks are the station's (`Edges::sticks`); this is not read.
        input: InputChoice::Constant(MovementCommand::CENTRED, Mode::Manual),
        api_socket: None,
        web: None,
    })
}

/// Tells the station's port what the hierarchy made of its requests: the answer to each (for
/// its COMMAND_ACK), and whether it holds control (for CONTROL_STATUS).
async fn answer(
    station: DeviceId,
    vehicle: DeviceId,
    mut events: broadcast::Receiver<Stamped>,
    link: Arc<dyn HostedLink>,
) {
    // It holds control while it holds a grant or owns the vehicle (it drives with its regular
    // writer: nobody drove it, or it is the stronger). Told here as the loop learns it, so the
    // station hears it at once, not when the vehicle's own view reaches the adapter.
    let (mut granted, mut owns, mut told) = (false, false, false);
    loop {
        let event = match events.recv().await {
            Ok(stamped) => stamped.event,
            Err(broadcast::error::RecvError::Lagged(_)) => continue,
            Err(broadcast::error::RecvError::Closed) => return,
        };
        match event {
            Event::RequestEnded {
                vehicle: v,
                outcome,
            } if v == vehicle => {
                link.answered(outcome == Outcome::Accepted);
            }
            Event::Driving { holding, .. } => granted = holding.contains(&vehicle),
            Event::OwnerChanged { vehicle: v, to, .. } if v == vehicle => {
                // Driving it without a grant: control without asking.
                if to == station && !granted && !owns {
                    link.answered(true);
                }
                owns = to == station;
            }
            _ => {}
        }
        let holds = granted || owns;
        if holds != told {
            told = holds;
            link.holds(holds);
        }
    }
}

/// A station's sticks, as an operator's input (module docs).
struct StationSticks {
    link: Arc<dyn HostedLink>,
    input: RemoteInput,
    actions: VecDeque<InputEvent>,
    /// It asked for control and has not given it back.
    engaged: bool,
    /// Its MANUAL_CONTROL flows (since it engaged).
    streaming: bool,
    heard: Option<Instant>,
    next_centred: Option<MonoTime>,
}

impl StationSticks {
    fn new(link: Arc<dyn HostedLink>, silence: Duration) -> StationSticks {
        StationSticks {
            link,
            input: RemoteInput::named(silence, "the ground station"),
            actions: VecDeque::new(),
            engaged: false,
            streaming: false,
            heard: None,
            next_centred: None,
        }
    }

    fn take(&mut self, now: MonoTime) {
        for event in self.link.take() {
            match event {
                HostedEvent::Alive(at) => self.heard = Some(at),
                HostedEvent::Sticks(sticks) if self.engaged => {
                    self.streaming = true;
                    self.input.frame(
                        now,
                        Frame {
                            sticks,
                            deadman: true,
                        },
                    );
                }
                HostedEvent::Sticks(_) => {}
                HostedEvent::Request => {
                    self.engaged = true;
                    self.streaming = false;
                    self.heard = Some(Instant::now());
                    self.input.frame(now, centred());
                    self.actions
                        .push_back(InputEvent::Action(InputAction::RequestControl));
                }
                HostedEvent::Release => {
                    self.engaged = false;
                    self.input.lost("the ground station gave control back");
                    self.actions
                        .push_back(InputEvent::Action(InputAction::Finish));
                    self.actions
                        .push_back(InputEvent::Action(InputAction::Release));
                }
            }
        }
        // Waiting to stream: centred, while its HEARTBEAT comes.
        let alive = self.heard.is_some_and(|t| t.elapsed() <= HEARTBEAT_SILENCE);
        if self.engaged && !self.streaming && alive && self.next_centred.is_none_or(|t| now >= t) {
            self.input.frame(now, centred());
            self.next_centred = Some(now + CENTRED_EVERY);
        }
        self.input.tick(now);
        if matches!(self.input.link(), rove_core::remote::RemoteLink::Lost(_))
            && self.engaged
            && (self.streaming || !alive)
        {
            // Gone quiet: as an unplugged joystick; it asks again to drive again.
            self.engaged = false;
            self.streaming = false;
        }
    }
}

fn centred() -> Frame {
    Frame {
        sticks: MovementCommand::CENTRED,
        deadman: true,
    }
}

impl InputSource for StationSticks {
    fn describe(&self) -> String {
        self.link.describe()
    }

    fn poll(&mut self, now: MonoTime) -> Result<Option<InputEvent>, LinkError> {
        self.take(now);
        Ok(self.actions.pop_front().or_else(|| self.input.pop()))
    }

    fn next_deadline(&self) -> Option<MonoTime> {
        let centred = (self.engaged && !self.streaming)
            .then_some(self.next_centred)
            .flatten();
        match (self.input.next_deadline(), centred) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (a, b) => a.or(b),
        }
    }
}

impl Sticks for StationSticks {
    fn link(&self) -> (Option<bool>, String) {
        (
            Some(self.input.deadman()),
            format!("{:?}", self.input.link()),
        )
    }
}

impl std::fmt::Debug for StationSticks {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.link.describe())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::Mutex;

    /// A station's handle whose events the test sets.
    #[derive(Debug, Default)]
    struct Fake(Mutex<Vec<HostedEvent>>);

    impl HostedLink for Fake {
        fn describe(&self) -> String {
            "fake station".into()
        }
        fn take(&self) -> Vec<HostedEvent> {
            std::mem::take(&mut *self.0.lock().expect("events"))
        }
        fn set_waker(&self, _: Arc<dyn Fn() + Send + Sync>) {}
        fn answered(&self, _: bool) {}
        fn holds(&self, _: bool) {}
    }

    /// What the loop gets at `now`, the deadman's presses aside (`RemoteInput`'s, tested there).
    fn events(sticks: &mut StationSticks, now: MonoTime) -> Vec<InputEvent> {
        std::iter::from_fn(|| sticks.poll(now).expect("a station's sticks do not fail"))
            .filter(|e| !matches!(e, InputEvent::Deadman(_)))
            .collect()
    }

    fn forward() -> HostedEvent {
        let m = MovementCommand {
            throttle: 1000,
            ..MovementCommand::CENTRED
        };
        HostedEvent::Sticks(m)
    }

    #[test]
    fn sticks_count_only_after_a_request_and_a_silence_or_release_ends_them() {
        let fake = Arc::new(Fake::default());
        let silence = Duration::from_millis(100);
        let mut s = StationSticks::new(fake.clone(), silence);
        let t = MonoTime::from_millis(1000);
        // Sticks before any request: nothing.
        fake.0.lock().expect("events").push(forward());
        assert_eq!(events(&mut s, t), vec![]);
        // A request: the action, and centred sticks (live) while it waits to stream.
        fake.0.lock().expect("events").push(HostedEvent::Request);
        let got = events(&mut s, t);
        assert_eq!(
            got,
            vec![
                InputEvent::Action(InputAction::RequestControl),
                InputEvent::Axes(MovementCommand::CENTRED),
            ]
        );
        // Centred frames keep it live while it waits (its HEARTBEAT is fresh).
        for ms in (1050..1500).step_by(50) {
            assert_eq!(events(&mut s, MonoTime::from_millis(ms)), vec![], "{ms}");
        }
        // Its sticks drive; their silence is a lost input.
        fake.0.lock().expect("events").push(forward());
        let t = MonoTime::from_millis(1500);
        assert!(matches!(events(&mut s, t)[..], [InputEvent::Axes(m)] if m.throttle == 1000));
        let lost = events(&mut s, MonoTime::from_millis(1601));
        assert!(matches!(lost[..], [InputEvent::Lost { .. }]), "{lost:?}");
        // Lost: sticks count again only after a new request.
        fake.0.lock().expect("events").push(forward());
        assert_eq!(events(&mut s, MonoTime::from_millis(1700)), vec![]);
        // A release gives a grant back and stops driving.
        fake.0.lock().expect("events").push(HostedEvent::Request);
        events(&mut s, MonoTime::from_millis(1800));
        fake.0.lock().expect("events").push(HostedEvent::Release);
        let released = events(&mut s, MonoTime::from_millis(1810));
        assert!(released.contains(&InputEvent::Action(InputAction::Finish)));
        assert!(released.contains(&InputEvent::Action(InputAction::Release)));
    }
}
