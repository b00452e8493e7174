//! The bridge's own side of its site's DDS network: the DeviceInfo, VehicleStatus and
//! RequestControl of the site's devices, with the participant each came from, and the
//! participants lost. The bridge's participant is no device: it writes nothing.

use crate::config::Common;
use crate::dds::{self, Discovery, Domain, KeyedDeviceInfo, KeyedVehicleStatus};
use crate::runtime::RateLimited;
use futures::StreamExt;
use rove_core::arbiter::ParticipantId;
use rove_core::msg::{DeviceId, DeviceInfo, RequestControl, VehicleStatus};
use rustdds::StatusEvented;
use rustdds::with_key::Sample;

/// What the bridge heard on its site's network.
#[derive(Debug)]
pub(super) enum Heard {
    /// A device's DeviceInfo.
    Info {
        info: DeviceInfo,
        from: ParticipantId,
    },
    /// A device's DeviceInfo withdrawn.
    InfoGone { id: DeviceId, from: ParticipantId },
    /// A vehicle's VehicleStatus.
    Status {
        status: VehicleStatus,
        from: ParticipantId,
    },
    /// A RequestControl.
    Request {
        msg: RequestControl,
        from: ParticipantId,
    },
    /// A participant left (goodbye, or its lease ran out).
    Lost(ParticipantId),
    /// Nothing for the bridge.
    Nothing,
}

/// The bridge's participant and readers.
pub(super) struct Local {
    domain: Domain,
    infos: rustdds::with_key::DataReaderStream<KeyedDeviceInfo>,
    statuses: rustdds::with_key::DataReaderStream<KeyedVehicleStatus>,
    requests: rustdds::no_key::DataReaderStream<RequestControl>,
    malformed: RateLimited,
}

impl Local {
    /// Joins the site's domain (as the site, with the DDS Security files in `security` on a
    /// secured site) and opens the readers.
    ///
    /// # Errors
    /// rustdds cannot create the participant, a topic or a reader.
    pub(super) fn join(
        common: &Common,
        security: Option<&std::path::Path>,
    ) -> anyhow::Result<Local> {
        let domain = Domain::join(
            common.domain_id,
            &common.interfaces,
            security,
            false,
            common.presence,
        )?;
        Ok(Local {
            infos: domain.device_info_reader()?.async_sample_stream(),
            statuses: domain.vehicle_status_reader()?.async_sample_stream(),
            requests: domain.request_reader()?.async_sample_stream(),
            domain,
            malformed: RateLimited::new("malformed sample on the site's network"),
        })
    }

    /// Waits for what the network brings next.
    ///
    /// # Errors
    /// A reader's stream ended.
    pub(super) async fn heard(&mut self) -> anyhow::Result<Heard> {
        let listener = self.domain.participant.status_listener();
        let mut discovery = listener.as_async_status_stream();
        let heard = tokio::select! {
            sample = self.infos.next() => match dds::device_info(sample, &mut self.malformed)? {
                Some((Sample::Value(info), from)) => Heard::Info { info, from },
                Some((Sample::Dispose(id), from)) => Heard::InfoGone { id, from },
                None => Heard::Nothing,
            },
            sample = self.statuses.next() => match sample {
                Some(Ok(s)) => {
                    let from = dds::sender(s.sample_info());
                    match s.into_value() {
                        Sample::Value(KeyedVehicleStatus(status)) => Heard::Status { status, from },
                        Sample::Dispose(_) => Heard::Nothing,
                    }
                }
                Some(Err(e)) => {
                    self.malformed.warn(&e);
                    Heard::Nothing
                }
                None => anyhow::bail!("VehicleStatus stream ended"),
            },
            sample = self.requests.next() => match sample {
                Some(Ok(s)) => Heard::Request { msg: *s.value(), from: dds::sender(s.sample_info()) },
                Some(Err(e)) => {
                    self.malformed.warn(&e);
                    Heard::Nothing
                }
                None => anyhow::bail!("RequestControl stream ended"),
            },
            event = discovery.next() => match event.as_ref().and_then(Discovery::of) {
                Some(Discovery::ParticipantLost { participant, .. }) => Heard::Lost(participant),
                _ => Heard::Nothing,
            },
        };
        Ok(heard)
    }
}
