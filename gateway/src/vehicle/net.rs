//! The vehicle's network edge: what it hears, in the arbiter's terms, and what it tells.
//!
//! [`Net`] is what the loop needs of the network; [`Dds`] is the edge `rove vehicle` runs on
//! (the DDS node, its readers and VehicleStatus writer, and the translation of samples and
//! discovery into arbiter events). The loop's tests put a channel in its place.

use super::intake::{Intake, MAX_BATCH};
use crate::config::VehicleConfig;
use crate::dds::{self, Discovery, KeyedDeviceInfo, Node};
use crate::runtime::{Clock, RateLimited};
use futures::{FutureExt, StreamExt};
use rove_core::arbiter::{Event, ParticipantId};
use rove_core::msg::{DeviceId, DeviceType, VehicleStatus};
use rove_core::trust::Certifier;
use rustdds::StatusEvented;
use rustdds::with_key::Sample;
use tracing::warn;

/// What the vehicle loop needs of the network.
pub(crate) trait Net {
    /// Our participant (the arbiter pins our own id to it).
    fn participant(&self) -> ParticipantId;

    /// Under `[security]`: who may speak for which id.
    fn certifier(&self) -> Option<Certifier>;

    /// Waits for what the network brings next, as arbiter events (none: it meant nothing to
    /// the arbiter: a disposal of another instance, a malformed sample already logged).
    ///
    /// # Errors
    /// The network is gone (a DDS stream ended): the loop ends.
    async fn heard(&mut self, clock: &Clock) -> anyhow::Result<Vec<Event>>;

    /// Tells every peer who drives (DeviceInfo; the failsafe is the vehicle's own id).
    fn publish_owner(&self, controller_id: DeviceId);

    /// Tells every peer how the vehicle is (VehicleStatus).
    fn publish_status(&self, status: &VehicleStatus);

    /// Leaves the device lists at once: DeviceInfo and VehicleStatus withdrawn.
    fn withdraw(&self);
}

/// The DDS edge of `rove vehicle`.
pub(crate) struct Dds {
    node: Node,
    readers: Readers,
    /// `None`: a secured fleet whose permissions predate the topic (said once at start).
    status: Option<rustdds::with_key::DataWriterCdr<dds::KeyedVehicleStatus>>,
    intake: Intake,
    malformed: RateLimited,
}

/// The vehicle's DDS readers, kept until it has stopped: deleting a reader is announced to
/// every peer, and the stop (outputs safe, DeviceInfo) goes first.
struct Readers {
    commands: rustdds::with_key::DataReaderStream<dds::KeyedControlCommand>,
    requests: rustdds::no_key::DataReaderStream<rove_core::msg::RequestControl>,
    infos: rustdds::with_key::DataReaderStream<KeyedDeviceInfo>,
}

impl Dds {
    /// Joins the domain as vehicle `config.common.id` and opens its readers and writers.
    ///
    /// # Errors
    /// The participant, a topic, a reader or writer cannot be created.
    pub(crate) fn join(config: &VehicleConfig) -> anyhow::Result<Dds> {
        let me = config.common.id;
        let node = Node::join(&config.common.node(), DeviceType::Vehicle, false)?;
        let domain = &node.domain;
        let status = domain
            .vehicle_status_writer()
            .map_err(|e| {
                let cause = format!("{e:#}");
                warn!(%cause, "no VehicleStatus: operators will not see the output's health");
            })
            .ok();
        let readers = Readers {
            commands: domain.command_reader(me)?.async_sample_stream(),
            requests: domain.request_reader()?.async_sample_stream(),
            infos: domain.device_info_reader()?.async_sample_stream(),
        };
        Ok(Dds {
            node,
            readers,
            status,
            intake: Intake::new(me, config.arbiter.command_timeout.get()),
            malformed: RateLimited::new("malformed or unreadable RequestControl or DeviceInfo"),
        })
    }

    /// Discovery: strengths learnt, writers and participants gone.
    fn on_discovery(&mut self, discovery: Option<Discovery>) -> Vec<Event> {
        match discovery {
            None => Vec::new(),
            Some(Discovery::CommandWriter { guid, strength }) => {
                self.intake.learn(guid, strength);
                Vec::new()
            }
            Some(Discovery::WriterLost { guid, why }) => {
                if self.intake.forget(guid) {
                    tracing::info!(writer = %dds::writer_id(guid), why, "command writer lost");
                }
                vec![Event::WriterGone {
                    writer: dds::writer_id(guid),
                }]
            }
            Some(Discovery::ParticipantLost { participant, why }) => {
                if self.intake.drives_from(participant) {
                    tracing::info!(%participant, why, "participant of a command writer lost");
                }
                self.intake.forget_participant(participant);
                vec![Event::ParticipantGone { participant }]
            }
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

    async fn heard(&mut self, clock: &Clock) -> anyhow::Result<Vec<Event>> {
        let Readers {
            commands,
            requests,
            infos,
        } = &mut self.readers;
        // The participant's status channel, read through a stream made for this wait.
        let listener = self.node.domain.participant.status_listener();
        let mut status = listener.as_async_status_stream();
        let me = self.node.id();
        let discovery = tokio::select! {
            sample = commands.next() => {
                let Some(first) = sample else {
                    anyhow::bail!("ControlCommand stream ended")
                };
                // With what already queued behind it: only each writer's newest counts.
                let mut batch = vec![first];
                while batch.len() < MAX_BATCH
                    && let Some(Some(more)) = commands.next().now_or_never()
                {
                    batch.push(more);
                }
                return Ok(self.intake.events(&self.node.domain, clock, batch));
            }
            request = requests.next() => return match request {
                Some(Ok(sample)) => {
                    let sender = dds::sender(sample.sample_info());
                    Ok(vec![Event::from_request_control(me, sample.value(), sender)])
                }
                Some(Err(e)) => {
                    self.malformed.warn(&e);
                    Ok(Vec::new())
                }
                None => anyhow::bail!("RequestControl stream ended"),
            },
            info = infos.next() => return match info {
                Some(Ok(sample)) => {
                    let sender = dds::sender(sample.sample_info());
                    match sample.into_value() {
                        Sample::Value(KeyedDeviceInfo(info)) => {
                            Ok(vec![Event::Heard { device: info.device_id, sender }])
                        }
                        Sample::Dispose(_) => Ok(Vec::new()),
                    }
                }
                Some(Err(e)) => {
                    self.malformed.warn(&e);
                    Ok(Vec::new())
                }
                None => anyhow::bail!("DeviceInfo stream ended"),
            },
            ev = status.next() => {
                if let Some(event) = &ev {
                    self.node.observe(event);
                }
                ev.as_ref().and_then(Discovery::of)
            }
        };
        Ok(self.on_discovery(discovery))
    }

    fn publish_owner(&self, controller_id: DeviceId) {
        self.node.publish(controller_id);
    }

    fn publish_status(&self, status: &VehicleStatus) {
        if let Some(writer) = &self.status
            && let Err(e) = writer.write(dds::KeyedVehicleStatus(status.clone()), None)
        {
            warn!(cause = ?e, "cannot publish VehicleStatus");
        }
    }

    fn withdraw(&self) {
        self.node.withdraw();
        if let Some(writer) = &self.status
            && let Err(e) = writer.dispose(&self.node.id(), None)
        {
            warn!(cause = ?e, "cannot withdraw VehicleStatus");
        }
    }
}
