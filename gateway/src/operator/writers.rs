//! The operator's DDS writers: a ControlCommand writer per session writer (regular, priority)
//! and route, made when first needed, and the RequestControl writer.

use crate::dds::{self, Domain, KeyedControlCommand};
use crate::runtime::RateLimited;
use rove_core::hierarchy::Strength;
use rove_core::msg::{Ack, ControlCommand, DeviceId, RequestControl};
use rove_core::session::Writer;
use rustdds::DomainParticipantStatusEvent;
use std::collections::HashMap;
use std::collections::hash_map::Entry;
use tracing::{info, warn};

type CommandWriter = rustdds::with_key::DataWriterCdr<KeyedControlCommand>;

/// How many times a release (dispose) is sent. Vehicles read commands best effort, so each copy
/// may be lost on its own: at 10 % packet loss one copy is lost one time in 10, three one time
/// in 1 000. A vehicle that misses all of them hands over after the command timeout instead,
/// as for a crash. A repeat costs one small datagram; the vehicle ignores a release of a source
/// it has already released.
const RELEASE_REPEATS: usize = 3;

/// The operator's DDS writers.
pub(super) struct Writers {
    /// The regular writers' strength.
    pub(super) strength: Strength,
    /// ControlCommand writers, one per session writer and route, made when first needed: for a
    /// vehicle driven, requested or to drive from the start. Bounded by what this operator
    /// drives or asks for, never by what others send.
    pub(super) commands: HashMap<(Writer, dds::Route), CommandWriter>,
    pub(super) routes: dds::Routes,
    pub(super) requests: rustdds::no_key::DataWriterCdr<RequestControl>,
    pub(super) failed: RateLimited,
}

impl Writers {
    /// The session's `writer` for `vehicle`'s route, made if needed (`None` if rustdds
    /// refuses, which is logged).
    pub(super) fn command_writer(
        &mut self,
        domain: &Domain,
        writer: Writer,
        vehicle: DeviceId,
    ) -> Option<&CommandWriter> {
        let route = self.routes.route(vehicle);
        match self.commands.entry((writer, route)) {
            Entry::Occupied(e) => Some(e.into_mut()),
            Entry::Vacant(e) => {
                let strength = match writer {
                    Writer::Regular => self.strength,
                    Writer::Priority => Strength::PRIORITY,
                };
                match domain.command_writer(strength, route) {
                    Ok(w) => {
                        info!(vehicle, ?route, ?writer, "ControlCommand writer made");
                        Some(e.insert(w))
                    }
                    Err(err) => {
                        self.failed.warn(&err);
                        None
                    }
                }
            }
        }
    }

    /// Both writers for `vehicle` (regular, and priority for a grant), made ahead of need.
    pub(super) fn prepare(&mut self, domain: &Domain, vehicle: DeviceId) {
        for writer in [Writer::Regular, Writer::Priority] {
            self.command_writer(domain, writer, vehicle);
        }
    }

    /// Learns routes from discovery: a ControlCommand reader found, a participant gone.
    pub(super) fn routes_learn(&mut self, event: &DomainParticipantStatusEvent) {
        match event {
            DomainParticipantStatusEvent::ReaderDetected { reader }
                if reader.topic_name == rove_core::msg::topic_names::CONTROL_COMMAND =>
            {
                let participant = dds::writer_id(reader.guid).participant;
                self.routes
                    .reader_found(participant, reader.qos.partition().as_ref());
            }
            DomainParticipantStatusEvent::ParticipantLost { id, .. } => {
                self.routes
                    .participant_gone(dds::participant_id(id.as_ref()));
            }
            _ => {}
        }
    }

    /// Writes `command` on the session's `writer` for its vehicle's route.
    pub(super) fn write(&mut self, domain: &Domain, writer: Writer, command: ControlCommand) {
        let Some(w) = self.command_writer(domain, writer, command.dest_id) else {
            return;
        };
        // The source timestamp lets the vehicle tell a sample that queued up from a fresh one
        // (rove_core::freshness).
        let stamp = Some(rustdds::Timestamp::now());
        if let Err(e) = w.write(KeyedControlCommand(command), stamp) {
            self.failed.warn(&e);
        }
    }

    /// Releases `vehicle`'s instance of the session's `writer`. Vehicles read commands best
    /// effort (dds::Domain::command_reader): a lost dispose would leave them waiting a command
    /// timeout, so it is repeated.
    pub(super) fn release(&mut self, domain: &Domain, writer: Writer, vehicle: DeviceId) {
        let Some(w) = self.command_writer(domain, writer, vehicle) else {
            return;
        };
        for _ in 0..RELEASE_REPEATS {
            if let Err(e) = w.dispose(&vehicle, None) {
                warn!(vehicle, cause = ?e, "release (dispose) failed");
                break;
            }
        }
    }

    /// Sends a RequestControl; asking for a vehicle not selected before makes both its
    /// writers now.
    pub(super) fn send(&mut self, domain: &Domain, msg: RequestControl) {
        if msg.ack == Ack::Request && msg.src_id != msg.current_controller_id {
            self.prepare(domain, msg.dest_id);
        }
        if let Err(e) = self.requests.write(msg, None) {
            warn!(cause = ?e, "cannot send RequestControl");
        }
    }
}
