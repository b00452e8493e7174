//! The operator's network edge: what it hears, with the participant each message came from,
//! and what it writes.
//!
//! [`Net`] is what the loop needs of the network; [`Dds`] is the edge `rove operator` runs on
//! (the DDS node, its readers, its ControlCommand and RequestControl writers, routes learnt
//! from discovery). The loop's tests put a channel in its place.

use super::writers::Writers;
use crate::config::OperatorConfig;
use crate::dds::{self, Discovery, KeyedDeviceInfo, KeyedVehicleStatus, Node};
use crate::runtime::RateLimited;
use futures::StreamExt;
use rove_core::arbiter::ParticipantId;
use rove_core::msg::VehicleStatus;
use rove_core::msg::{ControlCommand, DeviceId, DeviceInfo, DeviceType, RequestControl};
use rove_core::session::{SessionEvent, Writer};
use rove_core::trust::Certifier;
use rustdds::StatusEvented;
use rustdds::with_key::Sample;
use std::collections::HashMap;
use std::time::Duration;
use tracing::{info, warn};

/// What the operator heard, and from which participant.
#[derive(Debug, Clone)]
pub(crate) enum Heard {
    /// A device's DeviceInfo.
    Info {
        /// The sample.
        info: DeviceInfo,
        /// Its participant.
        from: ParticipantId,
    },
    /// A device's DeviceInfo withdrawn.
    InfoGone {
        /// The device.
        id: DeviceId,
        /// Whose withdrawal.
        from: ParticipantId,
    },
    /// A RequestControl.
    Request {
        /// The sample.
        msg: RequestControl,
        /// Its participant.
        from: ParticipantId,
    },
    /// A vehicle's VehicleStatus.
    Status {
        /// The sample.
        status: VehicleStatus,
        /// Its participant.
        from: ParticipantId,
    },
    /// What discovery tells the session (ControlCommand writers found and lost, participants
    /// gone).
    Discovery(SessionEvent),
    /// Nothing for the loop (a malformed sample, already logged; discovery of no interest).
    Nothing,
}

/// What the operator loop needs of the network.
pub(crate) trait Net {
    /// Our participant (the session pins our own id to it).
    fn participant(&self) -> ParticipantId;

    /// Under `[security]`: who may speak for which id.
    fn certifier(&self) -> Option<Certifier>;

    /// Waits for what the network brings next.
    ///
    /// # Errors
    /// The network is gone (a DDS stream ended): the loop ends.
    async fn heard(&mut self) -> anyhow::Result<Heard>;

    /// Announces us (DeviceInfo naming our own id).
    fn announce(&self);

    /// A believed vehicle's DeviceInfo came from `from` (its route).
    fn vehicle_seen(&mut self, vehicle: DeviceId, from: ParticipantId);

    /// Both writers for `vehicle`, ahead of need (so that discovery has matched them by the
    /// first command).
    fn prepare(&mut self, vehicle: DeviceId);

    /// Writes `command` on the session's `writer`.
    fn write(&mut self, writer: Writer, command: ControlCommand);

    /// Releases `vehicle`'s instance of the session's `writer` (a dispose).
    fn release(&mut self, writer: Writer, vehicle: DeviceId);

    /// Sends a RequestControl.
    fn send(&mut self, msg: RequestControl);

    /// Leaves: DeviceInfo withdrawn, and a bounded wait (`wait` per writer) for the peers to
    /// acknowledge the last FINISHes, releases and the withdrawal.
    fn leave(&mut self, wait: Duration);
}

/// The DDS edge of `rove operator`.
pub(crate) struct Dds {
    node: Node,
    readers: Readers,
    writers: Writers,
    malformed: RateLimited,
}

/// The role's DDS readers, kept until it has left: deleting a reader is announced to every
/// peer, which ahead of the releases delayed a graceful handover by about a millisecond
/// (measured).
struct Readers {
    infos: rustdds::with_key::DataReaderStream<KeyedDeviceInfo>,
    requests: rustdds::no_key::DataReaderStream<RequestControl>,
    /// The vehicles' output health for the front ends; optional (a secured fleet's
    /// permissions may predate the topic).
    statuses: Option<rustdds::with_key::DataReaderStream<KeyedVehicleStatus>>,
}

impl Dds {
    /// Joins the domain as operator `config.common.id`, opens the readers, and makes the
    /// writers the config needs from the start (those of the vehicles to drive, and of the one
    /// to ask for).
    ///
    /// # Errors
    /// The participant, a topic, a reader or writer cannot be created.
    pub(crate) fn join(
        config: &OperatorConfig,
        request: Option<DeviceId>,
        any_certificate: bool,
    ) -> anyhow::Result<Dds> {
        let node = Node::join(
            &config.common.node(),
            DeviceType::Controller,
            any_certificate,
        )?;
        let domain = &node.domain;
        let mut writers = Writers {
            strength: config.strength,
            commands: HashMap::new(),
            routes: dds::Routes::default(),
            requests: domain.request_writer()?,
            failed: RateLimited::new("ControlCommand write failed"),
        };
        for &vehicle in &config.drive {
            writers.command_writer(domain, Writer::Regular, vehicle);
        }
        if let Some(vehicle) = request {
            writers.prepare(domain, vehicle);
        }
        // The readers after the writers, as before the edges were split out: a requester's
        // writers are announced first. (`rove bench handover --scenario active` depends on
        // such start-up order: with the readers first it measured p50 4.5–4.7 ms against
        // 3.7–4.6 ms before the split, and 0.6–0.8 ms with this order.)
        let readers = Readers {
            infos: domain.device_info_reader()?.async_sample_stream(),
            requests: domain.request_reader()?.async_sample_stream(),
            statuses: domain
                .vehicle_status_reader()
                .map_err(|e| {
                    let cause = format!("{e:#}");
                    warn!(%cause, "no VehicleStatus: the console shows no output health");
                })
                .ok()
                .map(|r| r.async_sample_stream()),
        };
        Ok(Dds {
            node,
            readers,
            writers,
            malformed: RateLimited::new("malformed DeviceInfo or RequestControl sample"),
        })
    }
}

/// The next VehicleStatus sample, or never without a reader.
async fn next_status(
    statuses: &mut Option<rustdds::with_key::DataReaderStream<KeyedVehicleStatus>>,
) -> Option<rustdds::dds::ReadResult<rustdds::with_key::DataSample<KeyedVehicleStatus>>> {
    match statuses {
        Some(stream) => stream.next().await,
        None => std::future::pending().await,
    }
}

/// What discovery tells the session: ControlCommand writers found (with their strength) and
/// lost, participants gone.
fn discovery_event(discovery: Discovery) -> SessionEvent {
    match discovery {
        Discovery::CommandWriter { guid, strength } => SessionEvent::WriterFound {
            writer: dds::writer_id(guid),
            strength,
        },
        Discovery::WriterLost { guid, .. } => SessionEvent::WriterLost {
            writer: dds::writer_id(guid),
        },
        Discovery::ParticipantLost { participant, .. } => {
            SessionEvent::ParticipantGone { participant }
        }
    }
}

impl Net for Dds {
    fn participant(&self) -> ParticipantId {
        self.node.participant
    }

    fn certifier(&self) -> Option<Certifier> {
        self.node.certifier.clone()
    }

    async fn heard(&mut self) -> anyhow::Result<Heard> {
        let Readers {
            infos,
            requests,
            statuses,
        } = &mut self.readers;
        // The participant's status channel, read through a stream made for this wait.
        let listener = self.node.domain.participant.status_listener();
        let mut discovery = listener.as_async_status_stream();
        let heard = tokio::select! {
            sample = infos.next() => match dds::device_info(sample, &mut self.malformed)? {
                Some((Sample::Value(info), from)) => Heard::Info { info, from },
                Some((Sample::Dispose(id), from)) => Heard::InfoGone { id, from },
                None => Heard::Nothing,
            },
            Some(sample) = next_status(statuses) => match sample {
                Ok(s) => match s.value() {
                    Sample::Value(KeyedVehicleStatus(status)) => Heard::Status {
                        status: status.clone(),
                        from: dds::sender(s.sample_info()),
                    },
                    Sample::Dispose(_) => Heard::Nothing,
                },
                Err(_) => Heard::Nothing,
            },
            sample = requests.next() => match sample {
                Some(Ok(s)) => {
                    let msg = *s.value();
                    let from = dds::sender(s.sample_info());
                    tracing::debug!(?msg.ack, msg.src_id, msg.current_controller_id, stamp = msg.timestamp.0, %from, "RequestControl");
                    Heard::Request { msg, from }
                }
                Some(Err(e)) => {
                    self.malformed.warn(&e);
                    Heard::Nothing
                }
                None => anyhow::bail!("RequestControl stream ended"),
            },
            event = discovery.next() => match event {
                Some(event) => {
                    // Routes are learnt here; the session is told what it needs.
                    self.writers.routes_learn(&event);
                    self.node.observe(&event);
                    Discovery::of(&event).map_or(Heard::Nothing, |d| {
                        Heard::Discovery(discovery_event(d))
                    })
                }
                None => Heard::Nothing,
            },
        };
        Ok(heard)
    }

    fn announce(&self) {
        self.node.publish(self.node.id());
    }

    fn vehicle_seen(&mut self, vehicle: DeviceId, from: ParticipantId) {
        self.writers.routes.vehicle_seen(vehicle, from);
    }

    fn prepare(&mut self, vehicle: DeviceId) {
        self.writers.prepare(&self.node.domain, vehicle);
    }

    fn write(&mut self, writer: Writer, command: ControlCommand) {
        self.writers.write(&self.node.domain, writer, command);
    }

    fn release(&mut self, writer: Writer, vehicle: DeviceId) {
        self.writers.release(&self.node.domain, writer, vehicle);
    }

    fn send(&mut self, msg: RequestControl) {
        self.writers.send(&self.node.domain, msg);
    }

    fn leave(&mut self, wait: Duration) {
        self.node.withdraw();
        // The FINISHes and releases (disposals) are reliable writes; leaving the domain at once
        // would drop them before every reader has them (seen: a replier never resumed). So the
        // stop waits for their acknowledgments, all under one deadline (not one per writer).
        // Blocking is fine here: the event loop is over.
        //
        // The DeviceInfo withdrawal is sent but not waited for: it only updates lists (consoles,
        // `rove status`), and the participant's own disposal, sent as it closes, does the same.
        // Waiting for it cost every stop 300 ms whenever a peer had died within its lease (a
        // killed `rove status --events`: its reader never answers), issue 49.
        let deadline = std::time::Instant::now() + wait;
        let left = || deadline.saturating_duration_since(std::time::Instant::now());
        let mut acked = vec![(
            "RequestControl (FINISH)",
            self.writers.requests.wait_for_acknowledgments(left()),
        )];
        for writer in self.writers.commands.values() {
            acked.push((
                "ControlCommand (release)",
                writer.wait_for_acknowledgments(left()),
            ));
        }
        for (writer, result) in acked {
            match result {
                Ok(true) => {}
                // A reader that did not answer: its peer died or is unreachable; it falls back
                // to its own timeout, which is what it does for a crashed operator anyway.
                Ok(false) => info!(
                    writer,
                    wait_ms = wait.as_millis() as u64,
                    "a matched reader did not acknowledge before exit; it falls back to its timeout"
                ),
                Err(e) => warn!(writer, cause = ?e, "cannot wait for acknowledgments"),
            }
        }
    }
}
