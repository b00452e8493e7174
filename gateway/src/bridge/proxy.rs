//! A device of another site, on this site's DDS network: a participant of its own (the trust
//! rules pin one id to one participant, docs/design.md §4b), named `NAME @SITE`, that
//! publishes its DeviceInfo and writes what the device sends. A vehicle's proxy also reads its
//! commands, as the vehicle would (its own partition), for the bridge to carry them over.

use crate::config::Common;
use crate::dds::{self, KeyedControlCommand, KeyedVehicleStatus, Node};
use crate::runtime::RateLimited;
use futures::StreamExt;
use rove_core::arbiter::ParticipantId;
use rove_core::hierarchy::Strength;
use rove_core::msg::{ControlCommand, DeviceId, DeviceInfo, DeviceType, RequestControl};
use rove_core::site::SiteName;
use rustdds::GUID;
use rustdds::with_key::Sample;
use std::collections::HashMap;
use std::time::Instant;
use tokio::sync::mpsc;

type CommandWriter = rustdds::with_key::DataWriterCdr<KeyedControlCommand>;

/// How many times a release crosses into DDS: as an operator sends it (vehicles read commands
/// best effort).
const RELEASE_REPEATS: usize = 3;

/// Most ControlCommand writers one proxied operator may have here (a regular and a priority
/// writer per vehicle; a site cannot make the bridge create writers without end).
const MAX_WRITERS: usize = 64;

/// A command sample a vehicle's proxy read on this site's network.
#[derive(Debug)]
pub(super) struct Read {
    /// The vehicle whose proxy read it.
    pub(super) vehicle: DeviceId,
    /// Its writer.
    pub(super) writer: GUID,
    /// Its RTPS source time stamp, in ticks.
    pub(super) stamp: Option<u64>,
    /// The sample, or the instance's release.
    pub(super) sample: Sample<KeyedControlCommand, DeviceId>,
}

/// A device of another site.
pub(super) struct Proxy {
    /// Its site.
    pub(super) site: SiteName,
    /// What its site last said of it.
    pub(super) info: DeviceInfo,
    /// When its site last said it.
    pub(super) heard: Instant,
    node: Node,
    status: Option<rustdds::with_key::DataWriterCdr<KeyedVehicleStatus>>,
    commands: HashMap<(DeviceId, Strength), CommandWriter>,
    requests: Option<rustdds::no_key::DataWriterCdr<RequestControl>>,
    /// A vehicle's command reader, read on a task of its own.
    reader: Option<tokio::task::AbortHandle>,
    /// Strengths of the writers its command reader heard.
    strengths: HashMap<GUID, Strength>,
    failed: RateLimited,
}

impl Proxy {
    /// Joins this site's network as `info`'s device of `site` (under its proxy certificate in
    /// `security`, on a secured site) and publishes its DeviceInfo; a vehicle's proxy sends
    /// what its command reader reads to `read`.
    ///
    /// # Errors
    /// rustdds cannot create the participant or an endpoint.
    pub(super) fn join(
        common: &Common,
        site: &SiteName,
        info: DeviceInfo,
        security: Option<&std::path::Path>,
        read: &mpsc::Sender<Read>,
    ) -> anyhow::Result<Proxy> {
        let common = Common {
            id: info.device_id,
            name: rove_core::site::proxy_name(&info.name, site),
            security: security.map(std::path::Path::to_path_buf),
            ..common.clone()
        };
        let node = Node::join(&common.node(), info.device_type, false)?;
        let (status, reader) = match info.device_type {
            DeviceType::Vehicle => {
                let status = node.domain.vehicle_status_writer()?;
                let stream = node.domain.command_reader(info.device_id)?;
                let task = tokio::spawn(read_commands(
                    info.device_id,
                    stream.async_sample_stream(),
                    read.clone(),
                ));
                (Some(status), Some(task.abort_handle()))
            }
            DeviceType::Controller => (None, None),
        };
        let requests = match info.device_type {
            DeviceType::Controller => Some(node.domain.request_writer()?),
            DeviceType::Vehicle => None,
        };
        let proxy = Proxy {
            site: site.clone(),
            heard: Instant::now(),
            node,
            status,
            commands: HashMap::new(),
            requests,
            reader,
            strengths: HashMap::new(),
            failed: RateLimited::new("a write of another site's device failed"),
            info,
        };
        proxy.node.publish(proxy.info.controller_id);
        Ok(proxy)
    }

    /// Its participant here.
    pub(super) fn participant(&self) -> ParticipantId {
        self.node.participant
    }

    /// Its site said `info` again: published at once if its owner changed.
    pub(super) fn update(&mut self, info: DeviceInfo) {
        self.heard = Instant::now();
        self.info = info;
        self.node.publish(self.info.controller_id);
    }

    /// Republishes its DeviceInfo if the refresh is due.
    pub(super) fn refresh(&self) {
        self.node.publish(self.info.controller_id);
    }

    /// Writes a vehicle's VehicleStatus.
    pub(super) fn status(&mut self, status: rove_core::msg::VehicleStatus) {
        if let Some(w) = &self.status
            && let Err(e) = w.write(KeyedVehicleStatus(status), None)
        {
            self.failed.warn(&e);
        }
    }

    /// The writer for `vehicle` at `strength`, made if needed.
    fn command_writer(&mut self, vehicle: DeviceId, strength: Strength) -> Option<&CommandWriter> {
        let key = (vehicle, strength);
        if !self.commands.contains_key(&key) {
            if self.commands.len() >= MAX_WRITERS {
                self.failed
                    .warn(&"too many ControlCommand writers for one device");
                return None;
            }
            let route = dds::Route::Vehicle(vehicle);
            match self.node.domain.command_writer(strength, route) {
                Ok(w) => {
                    tracing::info!(
                        device = self.info.device_id,
                        site = %self.site,
                        vehicle,
                        %strength,
                        "ControlCommand writer made for another site's operator"
                    );
                    self.commands.insert(key, w);
                }
                Err(e) => {
                    self.failed.warn(&e);
                    return None;
                }
            }
        }
        self.commands.get(&key)
    }

    /// Makes an operator's writers for `vehicle` ahead of need (it asked for the vehicle): the
    /// priority writer, so that discovery has matched it by the grant's first sample, and the
    /// regular one at `regular` (the strength the owner's auto-accept looks for).
    pub(super) fn prepare(&mut self, vehicle: DeviceId, regular: Option<Strength>) {
        self.command_writer(vehicle, Strength::PRIORITY);
        if let Some(strength) = regular.filter(|s| s.is_operator()) {
            self.command_writer(vehicle, strength);
        }
    }

    /// Writes an operator's command at `strength`, with its sender's time stamp (ticks).
    pub(super) fn command(
        &mut self,
        strength: Strength,
        command: ControlCommand,
        stamp: Option<u64>,
    ) {
        let stamp = stamp.map_or_else(rustdds::Timestamp::now, rustdds::Timestamp::from_ticks);
        let Some(w) = self.command_writer(command.dest_id, strength) else {
            return;
        };
        if let Err(e) = w.write(KeyedControlCommand(command), Some(stamp)) {
            self.failed.warn(&e);
        }
    }

    /// Releases an operator's stream to `vehicle` at `strength`.
    pub(super) fn release(&mut self, vehicle: DeviceId, strength: Strength) {
        if let Some(w) = self.commands.get(&(vehicle, strength)) {
            for _ in 0..RELEASE_REPEATS {
                if let Err(e) = w.dispose(&vehicle, None) {
                    self.failed.warn(&e);
                    break;
                }
            }
        }
    }

    /// Writes an operator's RequestControl.
    pub(super) fn request(&mut self, msg: RequestControl) {
        if let Some(w) = &self.requests
            && let Err(e) = w.write(msg, None)
        {
            self.failed.warn(&e);
        }
    }

    /// The strength of a writer a vehicle's proxy heard, from its discovery.
    pub(super) fn strength_of(&mut self, writer: GUID) -> Option<Strength> {
        if let Some(s) = self.strengths.get(&writer) {
            return Some(*s);
        }
        let strength = self.node.domain.discovered_strength(writer)?;
        if self.strengths.len() >= 1024 {
            self.strengths.clear();
        }
        self.strengths.insert(writer, strength);
        Some(strength)
    }

    /// Leaves this site's network: the DeviceInfo withdrawn, every stream released, the
    /// participant dropped (so discovery tells everyone at once) and the command reader's task
    /// ended ([`Drop`]).
    pub(super) fn leave(mut self) {
        let streams: Vec<_> = self.commands.keys().copied().collect();
        for (vehicle, strength) in streams {
            self.release(vehicle, strength);
        }
        self.node.withdraw();
    }
}

impl Drop for Proxy {
    fn drop(&mut self) {
        if let Some(reader) = self.reader.take() {
            reader.abort();
        }
    }
}

/// Moves a vehicle proxy's command samples to the bridge's loop.
async fn read_commands(
    vehicle: DeviceId,
    mut stream: rustdds::with_key::DataReaderStream<KeyedControlCommand>,
    read: mpsc::Sender<Read>,
) {
    while let Some(sample) = stream.next().await {
        let Ok(sample) = sample else { continue };
        let info = sample.sample_info();
        let (writer, stamp) = (info.writer_guid(), info.source_timestamp());
        let read_one = Read {
            vehicle,
            writer,
            stamp: stamp.map(rustdds::Timestamp::to_ticks),
            sample: sample.into_value(),
        };
        if read.send(read_one).await.is_err() {
            return;
        }
    }
}
