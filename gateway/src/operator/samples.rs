//! DDS samples and discovery events → session events, and what the front ends are shown of
//! them. Who sent a sample is the participant it came from ([`dds::sender`]), never a payload
//! field; what the session does not believe is not shown.

use super::Role;
use crate::dds::{self, Discovery, KeyedDeviceInfo, KeyedVehicleStatus};
use futures::StreamExt;
use rove_console::Event;
use rove_console::model::DeviceKind;
use rove_core::msg::{DeviceType, RequestControl};
use rove_core::session::{Effect, Report, SessionEvent};
use rustdds::DomainParticipantStatusEvent;
use rustdds::dds::ReadResult;
use rustdds::with_key::{DataReaderStream, DataSample, Sample};

/// The next VehicleStatus sample, or never without a reader.
pub(super) async fn next_status(
    statuses: &mut Option<DataReaderStream<KeyedVehicleStatus>>,
) -> Option<ReadResult<DataSample<KeyedVehicleStatus>>> {
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
        Discovery::WriterLost { guid } => SessionEvent::WriterLost {
            writer: dds::writer_id(guid),
        },
        Discovery::ParticipantLost { participant } => SessionEvent::ParticipantGone { participant },
    }
}

impl Role {
    /// A DeviceInfo sample: the session learns the device; the front ends see it if believed.
    /// A withdrawal counts only from the participant that speaks for the device.
    pub(super) fn on_device_info(
        &mut self,
        sample: ReadResult<DataSample<KeyedDeviceInfo>>,
    ) -> Vec<Effect> {
        let sample = match sample {
            Ok(s) => s,
            Err(e) => {
                self.malformed.warn(&e);
                return Vec::new();
            }
        };
        let from = dds::sender(sample.sample_info());
        match sample.into_value() {
            Sample::Value(KeyedDeviceInfo(info)) => {
                let vehicle = info.device_type == DeviceType::Vehicle;
                let seen = Event::DeviceSeen {
                    id: info.device_id,
                    name: info.name.clone(),
                    kind: if vehicle {
                        DeviceKind::Vehicle
                    } else {
                        DeviceKind::Controller
                    },
                    owner: info.controller_id,
                };
                let id = info.device_id;
                let effects = self.step(SessionEvent::DeviceInfo { info, from });
                // Shown only if believed; the session reports it otherwise.
                let untrusted =
                    (effects.iter()).any(|e| matches!(e, Effect::Report(Report::Untrusted(_))));
                if !untrusted {
                    self.ui.emit(seen);
                    if vehicle {
                        self.writers.routes.vehicle_seen(id, from);
                    }
                }
                effects
            }
            Sample::Dispose(id) => {
                let now = self.edges.clock.now();
                if self.session.speaks_for(now, id, from) {
                    self.ui.emit(Event::DeviceGone { id });
                }
                Vec::new()
            }
        }
    }

    /// A VehicleStatus sample: shown if it comes from the participant that speaks for the
    /// vehicle.
    pub(super) fn on_vehicle_status(&mut self, sample: ReadResult<DataSample<KeyedVehicleStatus>>) {
        let Ok(s) = sample else {
            return;
        };
        let Sample::Value(KeyedVehicleStatus(status)) = s.value() else {
            return;
        };
        let from = dds::sender(s.sample_info());
        if self
            .session
            .speaks_for(self.edges.clock.now(), status.vehicle_id, from)
        {
            self.ui.emit(Event::VehicleStatus {
                vehicle: status.vehicle_id,
                mode: Some(status.mode),
                failsafe: status.failsafe,
                link: crate::status::output_text(status),
            });
        }
    }

    /// A RequestControl sample, with the participant it came from.
    pub(super) fn on_request(
        &mut self,
        sample: ReadResult<rustdds::no_key::DataSample<RequestControl>>,
    ) -> Vec<Effect> {
        match sample {
            Ok(s) => {
                let msg = *s.value();
                let from = dds::sender(s.sample_info());
                tracing::debug!(?msg.ack, msg.src_id, msg.current_controller_id, stamp = msg.timestamp.0, %from, "RequestControl");
                self.step(SessionEvent::RequestControl { msg, from })
            }
            Err(e) => {
                self.malformed.warn(&e);
                Vec::new()
            }
        }
    }

    /// A discovery event: routes learnt from it, and the session told what it needs.
    pub(super) fn on_discovery(&mut self, event: &DomainParticipantStatusEvent) -> Vec<Effect> {
        self.writers.routes_learn(event);
        match Discovery::of(event) {
            Some(discovery) => self.step(discovery_event(discovery)),
            None => Vec::new(),
        }
    }
}
