//! The vehicle loop in-process, on tokio's paused clock: a channel for the network, a recorder
//! for the output, a future for the shutdown. Times are virtual, so they are exact.

use super::*;
use crate::output::OutputReport;
use crate::runtime::virtual_time::{ends_with_network_gone, settle, wait_ms};
use rove_core::adapter::Health;
use rove_core::arbiter::{ParticipantId, WriterId};
use rove_core::hierarchy::Strength;
use rove_core::msg::{CommandType, ControlCommand, DeviceId, Mode, MovementCommand, VehicleStatus};
use rove_core::trust::Certifier;
use std::sync::{Arc, Mutex};
use tokio::sync::{mpsc, oneshot};

const ME: DeviceId = 100;
const OPERATOR: DeviceId = 11;

/// What the loop did, in order, with the virtual time.
#[derive(Debug, Clone, PartialEq)]
enum Did {
    Owner(DeviceId),
    Status(VehicleStatus),
    Withdrawn,
    Apply(i16),
    Safe,
}

type Journal = Arc<Mutex<Vec<(MonoTime, Did)>>>;

fn note(journal: &Journal, clock: &Clock, did: Did) {
    journal
        .lock()
        .expect("journal lock")
        .push((clock.now(), did));
}

/// The network: events the test sends, and what the loop tells, noted.
struct ChannelNet {
    heard: mpsc::UnboundedReceiver<Vec<Event>>,
    journal: Journal,
    clock: Clock,
}

impl Net for ChannelNet {
    fn participant(&self) -> ParticipantId {
        ParticipantId(0xffff)
    }
    fn certifier(&self) -> Option<Certifier> {
        None
    }
    async fn heard(&mut self, _: &Clock) -> anyhow::Result<Vec<Event>> {
        self.heard
            .recv()
            .await
            .ok_or_else(|| anyhow::anyhow!("network gone"))
    }
    fn publish_owner(&self, controller_id: DeviceId) {
        note(&self.journal, &self.clock, Did::Owner(controller_id));
    }
    fn publish_status(&self, status: &VehicleStatus) {
        note(&self.journal, &self.clock, Did::Status(status.clone()));
    }
    fn withdraw(&self) {
        note(&self.journal, &self.clock, Did::Withdrawn);
    }
}

/// The output: every call noted.
struct Recorder {
    journal: Journal,
    clock: Clock,
}

impl Outputs for Recorder {
    fn apply(&self, _: MonoTime, setpoint: Setpoint) {
        let throttle = setpoint.movement.throttle;
        note(&self.journal, &self.clock, Did::Apply(throttle));
    }
    fn safe_state(&self) {
        note(&self.journal, &self.clock, Did::Safe);
    }
    fn report(&self) -> OutputReport {
        OutputReport {
            describe: "recorder".into(),
            health: Health::Ok,
            detail: None,
            hung: None,
            stale: 0,
            held_safe: false,
            telemetry: Default::default(),
        }
    }
    fn stop(self, _: Duration) -> bool {
        note(&self.journal, &self.clock, Did::Safe);
        true
    }
}

/// A running vehicle loop and its edges.
struct Rig {
    send: mpsc::UnboundedSender<Vec<Event>>,
    stop: oneshot::Sender<()>,
    task: tokio::task::JoinHandle<anyhow::Result<()>>,
    journal: Journal,
    clock: Clock,
}

fn config() -> VehicleConfig {
    let dir = tempfile::tempdir().expect("temp dir");
    let path = dir.path().join("vehicle.toml");
    let text = format!(
        "[device]\nid = {ME}\nname = \"loop\"\n[network]\ninterfaces = [\"127.0.0.1\"]\n\
         heartbeat_ms = 500\n[vehicle]\ncommand_timeout_ms = 100\n[output]\nadapter = \"sim\"\n"
    );
    std::fs::write(&path, text).expect("write config");
    crate::config::load_vehicle(&path).expect("config loads")
}

impl Rig {
    fn start() -> Rig {
        let clock = Clock::start();
        let journal = Journal::default();
        let (send, heard) = mpsc::unbounded_channel();
        let (stop, stopped) = oneshot::channel::<()>();
        let net = ChannelNet {
            heard,
            journal: journal.clone(),
            clock,
        };
        let output = Recorder {
            journal: journal.clone(),
            clock,
        };
        let notify = Notifier::disabled();
        let vehicle = Vehicle::new(&config(), None, clock, net, output, None, notify);
        let task = tokio::spawn(vehicle.serve(async {
            let _ = stopped.await;
        }));
        Rig {
            send,
            stop,
            task,
            journal,
            clock,
        }
    }

    /// A MOVEMENT sample from the operator's regular writer, arriving now.
    fn sample(&self, throttle: i16) {
        let command = ControlCommand {
            src_id: OPERATOR,
            dest_id: ME,
            command_type: CommandType::Movement,
            movement_command: MovementCommand {
                throttle,
                ..MovementCommand::CENTRED
            },
            mode: Mode::Manual,
            timestamp: self.clock.stamp(),
        };
        let event = Event::Sample {
            writer: WriterId {
                participant: ParticipantId(11),
                entity: 1,
            },
            strength: Strength(220),
            command,
            arrival: self.clock.now(),
        };
        self.send.send(vec![event]).expect("the loop runs");
    }

    fn did(&self) -> Vec<(MonoTime, Did)> {
        self.journal.lock().expect("journal lock").clone()
    }

    /// What the loop did, without VehicleStatus.
    fn actions(&self) -> Vec<(u64, Did)> {
        (self.did().into_iter())
            .filter(|(_, d)| !matches!(d, Did::Status(_)))
            .map(|(t, d)| (t.as_nanos() / 1_000_000, d))
            .collect()
    }

    async fn finish(self) -> (anyhow::Result<()>, Vec<(u64, Did)>, Journal) {
        let _ = self.stop.send(());
        let result = self.task.await.expect("the loop does not panic");
        let actions = (self.journal.lock().expect("journal lock").iter())
            .filter(|(_, d)| !matches!(d, Did::Status(_)))
            .map(|(t, d)| (t.as_nanos() / 1_000_000, d.clone()))
            .collect();
        (result, actions, self.journal)
    }
}

#[tokio::test(start_paused = true)]
async fn an_owner_that_falls_silent_is_dropped_exactly_one_command_timeout_after_its_last_sample() {
    let rig = Rig::start();
    settle().await;
    rig.sample(1000);
    settle().await;
    wait_ms(30).await;
    rig.sample(2000);
    settle().await;
    wait_ms(300).await;
    let (result, actions, _) = rig.finish().await;
    result.expect("the loop ends cleanly");
    assert_eq!(
        actions,
        [
            (0, Did::Owner(ME)),
            (0, Did::Owner(ME)),
            (0, Did::Owner(OPERATOR)),
            (0, Did::Apply(1000)),
            (30, Did::Apply(2000)),
            // 100 ms after the last sample, not after the first.
            (130, Did::Owner(ME)),
            (130, Did::Safe),
            (330, Did::Safe),
            (330, Did::Owner(ME)),
            (330, Did::Withdrawn),
        ],
        "the loop start (DeviceInfo, then the heartbeat's first), the drive, the timeout, the stop"
    );
}

#[tokio::test(start_paused = true)]
async fn the_heartbeat_republishes_who_drives_and_the_status_follows_the_owner() {
    let rig = Rig::start();
    settle().await;
    rig.sample(0);
    settle().await;
    for _ in 0..7 {
        wait_ms(20).await;
        rig.sample(0);
        settle().await;
    }
    wait_ms(1100).await;
    let owners: Vec<(u64, DeviceId)> = (rig.actions().into_iter())
        .filter_map(|(t, d)| match d {
            Did::Owner(id) => Some((t, id)),
            _ => None,
        })
        .collect();
    // Start and the interval's first tick; the change to 11 and back at once; every 500 ms.
    assert_eq!(
        owners,
        [
            (0, ME),
            (0, ME),
            (0, OPERATOR),
            (240, ME),
            (500, ME),
            (1000, ME)
        ]
    );
    let statuses: Vec<(u64, DeviceId, bool)> = (rig.did().into_iter())
        .filter_map(|(t, d)| match d {
            Did::Status(s) => Some((t.as_nanos() / 1_000_000, s.controller_id, s.failsafe)),
            _ => None,
        })
        .collect();
    // Published on change only: not again at each heartbeat.
    assert_eq!(
        statuses,
        [(0, ME, true), (0, OPERATOR, false), (240, ME, true)]
    );
    let (result, _, _) = rig.finish().await;
    result.expect("the loop ends cleanly");
}

#[tokio::test(start_paused = true)]
async fn a_lost_network_ends_the_loop_with_an_error_after_the_outputs_went_safe() {
    let rig = Rig::start();
    settle().await;
    rig.sample(500);
    settle().await;
    let Rig {
        send,
        stop,
        task,
        journal,
        ..
    } = rig;
    drop(send);
    ends_with_network_gone(task).await;
    drop(stop);
    let did = journal.lock().expect("journal lock").clone();
    let tail: Vec<Did> = did.into_iter().rev().take(3).map(|(_, d)| d).collect();
    assert_eq!(tail, [Did::Withdrawn, Did::Owner(ME), Did::Safe]);
}

#[tokio::test(start_paused = true)]
async fn the_stop_makes_the_outputs_safe_before_it_tells_and_leaves() {
    let rig = Rig::start();
    settle().await;
    rig.sample(700);
    settle().await;
    wait_ms(10).await;
    let (result, actions, _) = rig.finish().await;
    result.expect("the loop ends cleanly");
    let tail: Vec<Did> = actions.into_iter().rev().take(3).map(|(_, d)| d).collect();
    assert_eq!(tail, [Did::Withdrawn, Did::Owner(ME), Did::Safe]);
}
