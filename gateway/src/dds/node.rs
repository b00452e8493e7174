//! What both roles do to be on the network, once: the certificate check, joining the domain,
//! our participant, our DeviceInfo published and withdrawn; and the participant's discovery
//! events as the roles read them ([`Discovery`]).

use super::{Domain, KeyedDeviceInfo, participant_id, strength_of, writer_id};
use rove_core::arbiter::ParticipantId;
use rove_core::hierarchy::Strength;
use rove_core::msg::{DeviceId, DeviceInfo, DeviceType, topic_names};
use rove_core::trust::Certifier;
use rustdds::{DomainParticipantStatusEvent, GUID, RTPSEntity};
use std::sync::Mutex;
use std::time::{Duration, Instant};
use tracing::warn;

/// This device on the DDS network.
pub struct Node {
    /// The participant and the topics.
    pub domain: Domain,
    /// Our participant, as the core names it (the arbiter and the session pin our own id to it).
    pub participant: ParticipantId,
    /// Under `[security]`: who may speak for which id ([`certifier`]).
    pub certifier: Option<Certifier>,
    info: rustdds::with_key::DataWriterCdr<KeyedDeviceInfo>,
    id: DeviceId,
    name: String,
    kind: DeviceType,
    refresh: Mutex<Refresh>,
    /// Participants lost, and when (at most [`MAX_LOST`], for [`LOST_KEPT`]): one found again
    /// gets our DeviceInfo at once.
    lost: Mutex<std::collections::BTreeMap<ParticipantId, std::time::Instant>>,
}

/// Most lost participants remembered for [`Node::observe`].
const MAX_LOST: usize = 1024;
/// How long a lost participant is remembered: one that comes back later is a newcomer (a
/// restarted process has a new participant anyway), and nothing is kept for ever (issue 51).
const LOST_KEPT: std::time::Duration = std::time::Duration::from_secs(60);

/// When our DeviceInfo goes out: at once when `controller_id` changed, else once every
/// `every` ([`super::DEVICE_INFO_REFRESH`]). Presence is the participant's (its SPDP lease), so
/// an unchanged DeviceInfo is only refreshed for a reader that lost it.
#[derive(Debug)]
struct Refresh {
    every: Duration,
    /// What was last written, and when.
    last: Option<(DeviceId, Instant)>,
}

impl Refresh {
    /// Whether `controller_id` should be written at `now`.
    fn due(&self, controller_id: DeviceId, now: Instant) -> bool {
        self.last.is_none_or(|(last, at)| {
            last != controller_id || now.saturating_duration_since(at) >= self.every
        })
    }

    /// `controller_id` was written at `now` (a failed write is not recorded: tried again at
    /// the next check).
    fn written(&mut self, controller_id: DeviceId, now: Instant) {
        self.last = Some((controller_id, now));
    }

    /// After a withdrawal the next publish goes out whatever it says.
    fn forget(&mut self) {
        self.last = None;
    }
}

impl std::fmt::Debug for Node {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Node")
            .field("id", &self.id)
            .field("kind", &self.kind)
            .finish_non_exhaustive()
    }
}

impl Node {
    /// Checks this device's security files (`[security]`), joins the domain confined to the
    /// configured interfaces and creates our DeviceInfo writer. `any_certificate` is the
    /// operator's test hook ([`certifier`]).
    ///
    /// # Errors
    /// The security files are incomplete or another device's, or rustdds cannot create the
    /// participant, a topic or the writer.
    pub fn join(
        common: &NodeSettings,
        kind: DeviceType,
        any_certificate: bool,
    ) -> anyhow::Result<Node> {
        let certifier = certifier(common, any_certificate)?;
        let domain = Domain::join(
            common.domain_id,
            &common.interfaces,
            common.security.as_deref(),
            any_certificate,
            common.presence,
        )?;
        let info = domain.device_info_writer()?;
        let participant = writer_id(domain.participant.guid()).participant;
        Ok(Node {
            domain,
            participant,
            certifier,
            info,
            id: common.id,
            name: common.name.clone(),
            kind,
            refresh: Mutex::new(Refresh {
                every: super::DEVICE_INFO_REFRESH,
                last: None,
            }),
            lost: Mutex::new(std::collections::BTreeMap::new()),
        })
    }

    /// Our device id.
    pub fn id(&self) -> DeviceId {
        self.id
    }

    /// Publishes our DeviceInfo with `controller_id` (a vehicle's owner; an operator's own id)
    /// if it changed or the refresh is due; the roles call it on every change and heartbeat.
    /// A failed write is logged: the next heartbeat publishes again.
    pub fn publish(&self, controller_id: DeviceId) {
        let mut refresh = crate::runtime::lock(&self.refresh);
        let now = Instant::now();
        if !refresh.due(controller_id, now) {
            return;
        }
        let info = DeviceInfo {
            device_id: self.id,
            name: self.name.clone(),
            device_type: self.kind,
            controller_id,
        };
        match self.info.write(KeyedDeviceInfo(info), None) {
            Ok(()) => refresh.written(controller_id, now),
            Err(e) => warn!(cause = ?e, "cannot publish DeviceInfo"),
        }
    }

    /// A discovery event: a participant found again after it was lost gets our DeviceInfo at
    /// the next check rather than at the next refresh. Lost both ways (a lease believed run
    /// out), it already holds our last sample, so a resend of it would be a duplicate there; a
    /// new write is not. A new participant gets the sample from the history: republishing for
    /// every newcomer cost every node a write to every peer per join (measured: late joiners
    /// of 64 devices p99 0.2 → 0.4 s).
    pub fn observe(&self, event: &DomainParticipantStatusEvent) {
        let mut lost = crate::runtime::lock(&self.lost);
        match event {
            DomainParticipantStatusEvent::ParticipantLost { id, .. } => {
                let now = std::time::Instant::now();
                lost.retain(|_, at| now.duration_since(*at) < LOST_KEPT);
                if lost.len() >= MAX_LOST {
                    lost.clear();
                }
                lost.insert(participant_id(id.as_ref()), now);
            }
            DomainParticipantStatusEvent::ParticipantDiscovered { dpd }
                if lost
                    .remove(&participant_id(dpd.guid.prefix.as_ref()))
                    .is_some() =>
            {
                crate::runtime::lock(&self.refresh).forget()
            }
            _ => {}
        }
    }

    /// Leaves the device lists at once (a dispose of our DeviceInfo) rather than after missed
    /// heartbeats.
    pub fn withdraw(&self) {
        crate::runtime::lock(&self.refresh).forget();
        if let Err(e) = self.info.dispose(&self.id, None) {
            warn!(cause = ?e, "cannot withdraw DeviceInfo");
        }
    }
}

/// The participant a sample came from: who sent it is the DDS participant and writer, never a
/// payload field.
pub fn sender(info: &rustdds::SampleInfo) -> ParticipantId {
    writer_id(info.writer_guid()).participant
}

/// What the roles read in the participant's discovery events.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Discovery {
    /// A ControlCommand writer with EXCLUSIVE ownership, and its strength.
    CommandWriter {
        /// The writer.
        guid: GUID,
        /// Its OWNERSHIP_STRENGTH.
        strength: Strength,
    },
    /// A writer left.
    WriterLost {
        /// The writer.
        guid: GUID,
        /// Why discovery says so, for the log.
        why: String,
    },
    /// A participant left (goodbye, or its lease ran out).
    ParticipantLost {
        /// The participant.
        participant: ParticipantId,
        /// Why discovery says so, for the log.
        why: String,
    },
}

impl Discovery {
    /// The event as the roles read it; `None` for what they do not use.
    pub fn of(event: &DomainParticipantStatusEvent) -> Option<Discovery> {
        match event {
            DomainParticipantStatusEvent::WriterDetected { writer }
                if writer.topic_name == topic_names::CONTROL_COMMAND =>
            {
                Some(Discovery::CommandWriter {
                    guid: writer.guid,
                    strength: strength_of(writer.qos.ownership())?,
                })
            }
            DomainParticipantStatusEvent::WriterLost { guid, reason } => {
                Some(Discovery::WriterLost {
                    guid: *guid,
                    why: lost_why(reason),
                })
            }
            DomainParticipantStatusEvent::ParticipantLost { id, reason } => {
                Some(Discovery::ParticipantLost {
                    participant: participant_id(id.as_ref()),
                    why: lost_why(reason),
                })
            }
            _ => None,
        }
    }
}

/// Why discovery lost something, in words for the log.
fn lost_why(reason: &rustdds::LostReason) -> String {
    use rustdds::LostReason;
    match reason {
        LostReason::Disposed => "disposed by its participant".into(),
        LostReason::Timeout { lease, elapsed } => format!(
            "lease of {:?} ran out ({:?} since last heard)",
            lease.to_std(),
            elapsed.to_std()
        ),
    }
}

/// Who a node is and where it joins: what [`Node::join`] needs. The DDS layer owns it; the
/// config fills it (`config::Common::node`).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct NodeSettings {
    /// Device id.
    pub id: rove_core::msg::DeviceId,
    /// Device name.
    pub name: String,
    /// DDS domain.
    pub domain_id: u16,
    /// Interfaces DDS is confined to.
    pub interfaces: Vec<std::net::Ipv4Addr>,
    /// The SPDP period.
    pub presence: std::time::Duration,
    /// The DDS Security directory, if the node joins authenticated.
    pub security: Option<std::path::PathBuf>,
}

/// Under `[security]`: checks this device's DDS Security directory and returns who may speak
/// for which id (a participant only for the id in its certificate, `certs::FleetIdentity`).
/// `None` without `[security]`. `any_id` (a test hook) lets a device run with another device's
/// certificate, to see the others refuse it.
///
/// # Errors
/// The directory is incomplete, the certificate is another device's, or this build has no
/// security.
pub fn certifier(common: &NodeSettings, any_id: bool) -> anyhow::Result<Option<Certifier>> {
    let Some(dir) = &common.security else {
        tracing::warn!(
            "no [security] in the config: participants are not authenticated, device ids are \
             pinned to whichever participant speaks for them first (docs/security.md)"
        );
        return Ok(None);
    };
    #[cfg(feature = "security")]
    {
        // The test hook exists in debug builds only: a release build always checks that the
        // certificate is this device's.
        let any_id = cfg!(debug_assertions) && any_id;
        let fleet = crate::certs::check_device_dir(dir, common.id, any_id)?;
        tracing::info!(
            dir = %dir.display(),
            fleet = fleet.fleet(),
            "DDS Security on: only this fleet's authenticated participants match, each speaking \
             only for the device id in its certificate"
        );
        Ok(Some(std::sync::Arc::new(move |id, participant| {
            fleet.speaks_for(id, participant)
        })))
    }
    #[cfg(not(feature = "security"))]
    {
        let _ = any_id;
        anyhow::bail!(
            "[security] {}: this rove was built without the `security` feature",
            dir.display()
        )
    }
}

#[cfg(test)]
mod tests {
    use super::Refresh;
    use std::time::{Duration, Instant};

    #[test]
    fn device_info_goes_out_on_a_change_at_once_and_else_once_a_refresh() {
        let t0 = Instant::now();
        let at = |ms| t0 + Duration::from_millis(ms);
        let mut refresh = Refresh {
            every: Duration::from_secs(5),
            last: None,
        };
        assert!(refresh.due(7, at(0)), "the first");
        refresh.written(7, at(0));
        assert!(!refresh.due(7, at(500)), "unchanged, within the refresh");
        assert!(refresh.due(8, at(500)), "a change, at once");
        refresh.written(8, at(500));
        assert!(!refresh.due(8, at(5499)));
        assert!(refresh.due(8, at(5500)), "unchanged, the refresh");
        assert!(refresh.due(7, at(600)), "back to the old owner is a change");
        refresh.forget();
        assert!(
            refresh.due(8, at(600)),
            "after a withdrawal, whatever it says"
        );
    }
}
