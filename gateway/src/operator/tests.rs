//! The operator loop in-process, on tokio's paused clock: a channel for the network, the
//! front ends' channels, a future for the shutdown. Times are virtual, so they are exact.

use super::net::{Heard, Net};
use super::*;
use crate::runtime::virtual_time::{ends_with_network_gone, settle, wait_ms};
use rove_console::Source;
use rove_core::arbiter::{ParticipantId, WriterId};
use rove_core::hierarchy::Strength;
use rove_core::msg::{Ack, CommandType, ControlCommand, DeviceInfo, RequestControl, TimeT};
use rove_core::session::{Command, Writer};
use rove_core::trust::Certifier;
use std::sync::Mutex;
use std::time::Duration;
use tokio::sync::{mpsc, oneshot};

const ME: DeviceId = 11;
const VEHICLE: DeviceId = 100;
const VEHICLE_PARTICIPANT: ParticipantId = ParticipantId(0x100);
const PHONE: DeviceId = 12;
const PHONE_PARTICIPANT: ParticipantId = ParticipantId(0x12);

/// What the loop did on the network, in order.
#[derive(Debug, Clone, PartialEq)]
enum Did {
    Announce,
    Write(Writer, CommandType, i16),
    Release(Writer, DeviceId),
    Send(Ack),
    Leave,
}

type Journal = Arc<Mutex<Vec<(u64, Did)>>>;

/// The network: what the test sends is heard; what the loop does is noted, in virtual ms.
struct ChannelNet {
    heard: mpsc::UnboundedReceiver<Heard>,
    journal: Journal,
    clock: Clock,
}

impl ChannelNet {
    fn note(&self, did: Did) {
        let ms = self.clock.now().as_nanos() / 1_000_000;
        self.journal.lock().expect("journal lock").push((ms, did));
    }
}

impl Net for ChannelNet {
    fn participant(&self) -> ParticipantId {
        ParticipantId(0x11)
    }
    fn certifier(&self) -> Option<Certifier> {
        None
    }
    async fn heard(&mut self) -> anyhow::Result<Heard> {
        self.heard
            .recv()
            .await
            .ok_or_else(|| anyhow::anyhow!("network gone"))
    }
    fn announce(&self) {
        self.note(Did::Announce);
    }
    fn vehicle_seen(&mut self, _: DeviceId, _: ParticipantId) {}
    fn prepare(&mut self, _: DeviceId) {}
    fn write(&mut self, writer: Writer, command: ControlCommand) {
        let throttle = command.movement_command.throttle;
        self.note(Did::Write(writer, command.command_type, throttle));
    }
    fn release(&mut self, writer: Writer, vehicle: DeviceId) {
        self.note(Did::Release(writer, vehicle));
    }
    fn send(&mut self, msg: RequestControl) {
        self.note(Did::Send(msg.ack));
    }
    fn leave(&mut self, _: Duration) {
        self.note(Did::Leave);
    }
}

/// A running operator loop and its edges.
struct Rig {
    heard: mpsc::UnboundedSender<Heard>,
    commands: mpsc::Sender<CommandRequest>,
    stop: oneshot::Sender<()>,
    task: tokio::task::JoinHandle<anyhow::Result<()>>,
    journal: Journal,
}

fn config(handover: &str) -> OperatorConfig {
    let dir = tempfile::tempdir().expect("temp dir");
    let path = dir.path().join("operator.toml");
    let text = format!(
        "[device]\nid = {ME}\nname = \"loop\"\n[network]\ninterfaces = [\"127.0.0.1\"]\n\
         heartbeat_ms = 500\n[operator]\nlevel = \"stationary\"\ndevice_class = \"laptop\"\n\
         stream_hz = 50\ndrive = [{VEHICLE}]\n[handover]\n{handover}\n[input]\n\
         source = \"constant\"\nthrottle = 1000\n"
    );
    std::fs::write(&path, text).expect("write config");
    crate::config::load_operator(&path).expect("config loads")
}

impl Rig {
    fn start(handover: &str) -> Rig {
        let (edges, commands) = Edges::new(
            None,
            Arc::new(tokio::sync::Notify::new()),
            Notifier::disabled(),
        );
        let journal = Journal::default();
        let (heard_tx, heard) = mpsc::unbounded_channel();
        let net = ChannelNet {
            heard,
            journal: journal.clone(),
            clock: edges.clock,
        };
        let (stop, stopped) = oneshot::channel::<()>();
        let role = Role::new(config(handover), None, edges, net, None).expect("the role starts");
        let task = tokio::spawn(role.serve(async {
            let _ = stopped.await;
        }));
        Rig {
            heard: heard_tx,
            commands,
            stop,
            task,
            journal,
        }
    }

    fn hear(&self, heard: Heard) {
        self.heard.send(heard).expect("the loop runs");
    }

    /// The vehicle's DeviceInfo naming `owner`.
    fn vehicle_names(&self, owner: DeviceId) {
        let info = DeviceInfo {
            device_id: VEHICLE,
            name: "rover".into(),
            device_type: rove_core::msg::DeviceType::Vehicle,
            controller_id: owner,
        };
        let from = VEHICLE_PARTICIPANT;
        self.hear(Heard::Info { info, from });
    }

    async fn command(&self, command: Command) -> Result<(), String> {
        let (reply, answer) = oneshot::channel();
        let request = CommandRequest {
            command,
            source: Source::Console,
            reply,
        };
        self.commands.send(request).await.expect("the loop runs");
        answer.await.expect("answered")
    }

    fn did(&self) -> Vec<(u64, Did)> {
        self.journal.lock().expect("journal lock").clone()
    }

    async fn finish(self) -> (anyhow::Result<()>, Vec<(u64, Did)>) {
        let _ = self.stop.send(());
        let result = self.task.await.expect("the loop does not panic");
        let did = self.journal.lock().expect("journal lock").clone();
        (result, did)
    }
}

/// When the regular writer sent the constant sticks' MOVEMENT.
fn movement_writes(did: &[(u64, Did)]) -> Vec<u64> {
    (did.iter())
        .filter(|(_, d)| matches!(d, Did::Write(Writer::Regular, CommandType::Movement, 1000)))
        .map(|(t, _)| *t)
        .collect()
}

#[tokio::test(start_paused = true)]
async fn it_streams_at_its_rate_announces_every_heartbeat_and_releases_before_it_leaves() {
    let rig = Rig::start("");
    settle().await;
    // Stopped between two ticks: ticks due at the same instant as the stop may come first
    // or not.
    wait_ms(1010).await;
    let (result, did) = rig.finish().await;
    result.expect("the loop ends cleanly");
    let writes = movement_writes(&did);
    let expected: Vec<u64> = (0..=50).map(|i| i * 20).collect();
    assert_eq!(
        writes, expected,
        "one sample every 20 ms (50 Hz), on the dot"
    );
    let announced: Vec<u64> = (did.iter())
        .filter(|(_, d)| *d == Did::Announce)
        .map(|(t, _)| *t)
        .collect();
    assert_eq!(announced, [0, 0, 500, 1000]);
    let tail: Vec<Did> = did.iter().rev().take(2).map(|(_, d)| d.clone()).collect();
    assert_eq!(
        tail,
        [Did::Leave, Did::Release(Writer::Regular, VEHICLE)],
        "released, then left"
    );
}

#[tokio::test(start_paused = true)]
async fn a_stronger_request_is_accepted_and_the_owner_stands_by_with_probes() {
    let rig = Rig::start("auto_accept = \"higher_priority\"");
    settle().await;
    rig.vehicle_names(ME);
    // Discovery: the phone's regular writer, at its strength (so its priority is believed).
    let writer = WriterId {
        participant: PHONE_PARTICIPANT,
        entity: 1,
    };
    let strength = Strength(340);
    rig.hear(Heard::Discovery(SessionEvent::WriterFound {
        writer,
        strength,
    }));
    settle().await;
    wait_ms(100).await;
    let msg = RequestControl {
        src_id: PHONE,
        dest_id: VEHICLE,
        current_controller_id: ME,
        src_priority: 340,
        ack: Ack::Request,
        timestamp: TimeT(1),
    };
    rig.hear(Heard::Request {
        msg,
        from: PHONE_PARTICIPANT,
    });
    settle().await;
    wait_ms(110).await;
    let did = rig.did();
    let accepted = (did.iter())
        .find(|(_, d)| *d == Did::Send(Ack::Accept))
        .map(|(t, _)| *t)
        .expect("the request is accepted");
    assert_eq!(accepted, 100, "at once");
    let after: Vec<&Did> = (did.iter())
        .filter(|(t, d)| *t > accepted && matches!(d, Did::Write(..)))
        .map(|(_, d)| d)
        .collect();
    assert_eq!(
        after.len(),
        5,
        "the keep-alive goes on every 20 ms: {after:?}"
    );
    assert!(
        after
            .iter()
            .all(|d| matches!(d, Did::Write(Writer::Regular, CommandType::Probe, _))),
        "standing by: PROBEs only, no movement: {after:?}"
    );
    let (result, _) = rig.finish().await;
    result.expect("the loop ends cleanly");
}

#[tokio::test(start_paused = true)]
async fn console_commands_are_answered_and_a_refusal_says_why() {
    let rig = Rig::start("");
    settle().await;
    wait_ms(30).await;
    let released = rig.command(Command::Release {
        vehicle: Some(VEHICLE),
    });
    released.await.expect("a driven vehicle is released");
    settle().await;
    let did = rig.did();
    assert!(
        did.contains(&(30, Did::Release(Writer::Regular, VEHICLE))),
        "{did:?}"
    );
    wait_ms(100).await;
    assert_eq!(
        movement_writes(&rig.did()).last(),
        Some(&20),
        "nothing streams after the release"
    );
    let why = rig
        .command(Command::Finish { vehicle: VEHICLE })
        .await
        .expect_err("no grant to finish");
    assert!(!why.is_empty());
    let (result, _) = rig.finish().await;
    result.expect("the loop ends cleanly");
}

#[tokio::test(start_paused = true)]
async fn a_lost_network_ends_the_loop_with_an_error_and_it_still_releases() {
    let rig = Rig::start("");
    settle().await;
    wait_ms(40).await;
    let Rig {
        heard,
        task,
        journal,
        stop,
        ..
    } = rig;
    drop(heard);
    ends_with_network_gone(task).await;
    drop(stop);
    let did = journal.lock().expect("journal lock").clone();
    let tail: Vec<Did> = did.iter().rev().take(2).map(|(_, d)| d.clone()).collect();
    assert_eq!(tail, [Did::Leave, Did::Release(Writer::Regular, VEHICLE)]);
}
