//! The DDS binding: rove's three seed topics on rustdds, with the seed's QoS (docs/design.md §2).
//!
//! `rove-core` holds the wire types and knows nothing of DDS; this module wraps them in keyed
//! newtypes (`#[serde(transparent)]`, so the bytes on the wire are exactly the core type's CDR),
//! creates the participant confined to the configured networks, and converts DDS identities
//! (GUIDs) into the core's opaque [`WriterId`] / [`ParticipantId`].
//!
//! Ownership strength: rustdds does not arbitrate EXCLUSIVE ownership, but it carries every remote
//! writer's OWNERSHIP_STRENGTH in discovery (SEDP). The vehicle learns strengths from the
//! participant's `WriterDetected` events, falling back to `discovered_writers()` for a sample
//! whose writer it has not seen announced yet: the standard mechanism, no side channel.
//!
//! # Layout
//! - this file: the keyed wire types, the seed's QoS, [`Domain`] (a participant and the topics,
//!   readers and writers), DDS identities → core identities.
//! - [`Node`] (`node.rs`): what both roles do to be on the network — the certificate check,
//!   joining, our participant, DeviceInfo published and withdrawn — and [`Discovery`], the
//!   participant's events as the roles read them.
//! - [`Routes`] (`routes.rs`): which partition each vehicle's commands travel in.
//!
//! Known limitations (intentional, not bugs):
//! - rustdds has no `unregister_instance`; a graceful release is a `dispose` of the instance.
//! - A foreign *exclusive reader* does not match rove's exclusive writers (a rustdds QoS parsing
//!   bug, see `docs/rustdds.md`); foreign exclusive writers → rove readers do match.

mod node;
mod routes;

pub use node::{Discovery, Node, NodeSettings, certifier, sender};
pub use routes::{Route, Routes, VEHICLE_PARTITION_PREFIX, vehicle_partition};

use anyhow::Context;
use rove_core::arbiter::{ParticipantId, WriterId};
use rove_core::hierarchy::Strength;
use rove_core::msg::{
    ControlCommand, DeviceId, DeviceInfo, RequestControl, VehicleStatus, topic_names, type_names,
};
use rustdds::policy::{Durability, History, Liveliness, Ownership, Partition, Reliability};
use rustdds::{
    DomainParticipant, DomainParticipantBuilder, GUID, Keyed, QosPolicies, QosPolicyBuilder,
    TopicKind,
};
use serde::{Deserialize, Serialize};
use std::net::Ipv4Addr;

/// A DeviceInfo stream's next item as the roles take it: the device's DeviceInfo, or (a dispose)
/// the id of the device that withdrew it, and the participant it came from; `None` for a
/// malformed sample, warned about through `malformed`.
///
/// # Errors
/// The stream ended.
pub fn device_info(
    item: Option<rustdds::dds::ReadResult<rustdds::with_key::DataSample<KeyedDeviceInfo>>>,
    malformed: &mut crate::runtime::RateLimited,
) -> anyhow::Result<
    Option<(
        rustdds::with_key::Sample<DeviceInfo, DeviceId>,
        ParticipantId,
    )>,
> {
    use rustdds::with_key::Sample;
    let sample = match item {
        Some(Ok(sample)) => sample,
        Some(Err(e)) => {
            malformed.warn(&e);
            return Ok(None);
        }
        None => anyhow::bail!("DeviceInfo stream ended"),
    };
    let from = sender(sample.sample_info());
    let value = match sample.into_value() {
        Sample::Value(KeyedDeviceInfo(info)) => Sample::Value(info),
        Sample::Dispose(id) => Sample::Dispose(id),
    };
    Ok(Some((value, from)))
}

/// DeviceInfo keyed by `device_id`.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(transparent)]
pub struct KeyedDeviceInfo(pub DeviceInfo);

impl Keyed for KeyedDeviceInfo {
    type K = DeviceId;
    fn key(&self) -> DeviceId {
        self.0.device_id
    }
}

/// VehicleStatus keyed by `vehicle_id`.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(transparent)]
pub struct KeyedVehicleStatus(pub VehicleStatus);

impl Keyed for KeyedVehicleStatus {
    type K = DeviceId;
    fn key(&self) -> DeviceId {
        self.0.vehicle_id
    }
}

/// ControlCommand keyed by `dest_id` (one instance per vehicle).
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(transparent)]
pub struct KeyedControlCommand(pub ControlCommand);

impl Keyed for KeyedControlCommand {
    type K = DeviceId;
    fn key(&self) -> DeviceId {
        self.0.dest_id
    }
}

/// The participant lease announced, in SPDP periods (`[network] presence_ms`): a peer that goes
/// silent is dropped (`ParticipantLost`) within 1.25 leases (rustdds checks leases every
/// quarter lease, ROVE-PATCH.md §18): 1.25 s at the default 250 ms, so that a crashed device
/// leaves every list within 1.5 s. Three announcements in a row must be lost or late for a
/// live peer to be dropped, and any message from it counts as one (a streaming operator is
/// heard 50 times a second).
pub const PRESENCE_LEASE_PERIODS: u32 = 4;

/// The SPDP period when `[network] presence_ms` is absent.
pub const DEFAULT_PRESENCE: std::time::Duration = std::time::Duration::from_millis(250);

/// How often a device publishes its DeviceInfo when nothing in it changed. Presence comes from
/// the participant (its SPDP lease), so this is a slow refresh for a reader that lost the
/// sample; a change goes out at once. Device lists and id pins also drop a device not heard
/// for three refreshes, a backstop for a participant whose loss is never reported.
pub const DEVICE_INFO_REFRESH: std::time::Duration = std::time::Duration::from_secs(5);

/// How long a device stays listed without a DeviceInfo or a message: three refreshes.
pub const OFFLINE_AFTER: std::time::Duration = DEVICE_INFO_REFRESH.saturating_mul(3);

/// How long a reliable write may block when the send window is full. Control samples are
/// superseded 20 ms later, so waiting longer than a few ms only delays the next one.
const MAX_BLOCKING_MS: i64 = 5;

/// DeviceInfo: reliable, TRANSIENT_LOCAL (late joiners get every device at once), latest only;
/// writer liveliness 1 s, reader 3 s (seed Table 4.2).
pub fn device_info_qos(reader: bool) -> QosPolicies {
    let lease = if reader { 3 } else { 1 };
    QosPolicyBuilder::new()
        .reliability(Reliability::Reliable {
            max_blocking_time: rustdds::Duration::from_millis(MAX_BLOCKING_MS),
        })
        .durability(Durability::TransientLocal)
        .history(History::KeepLast { depth: 1 })
        .liveliness(Liveliness::Automatic {
            lease_duration: rustdds::Duration::from_secs(lease),
        })
        .build()
}

/// ControlCommand: EXCLUSIVE ownership with the writer's strength; reliable so that a dispose
/// (graceful release) is never lost; latest only.
pub fn control_command_qos(strength: Strength) -> QosPolicies {
    QosPolicyBuilder::new()
        .reliability(Reliability::Reliable {
            max_blocking_time: rustdds::Duration::from_millis(MAX_BLOCKING_MS),
        })
        .history(History::KeepLast { depth: 1 })
        .ownership(Ownership::Exclusive {
            strength: i32::from(strength.0),
        })
        .build()
}

/// Samples of each writer the vehicle's command reader holds until its loop takes them (rove's
/// rustdds keeps KEEP_LAST per instance *and writer*, `vendor/rustdds/ROVE-PATCH.md` §12). An
/// honest 50 Hz stream sends 8 in 160 ms, longer than any sample stays fresh (the command
/// timeout, 100 ms). Small, because a flood that outruns the loop is held back to this many
/// samples per writer: 100 writers queue at most 800 samples (a few ms of work) ahead of the
/// owner's newest, where 64 each would be 6 400.
pub const COMMAND_READER_DEPTH: i32 = 8;

/// RequestControl: the DDS default QoS, made reliable on our side (a writer's default) with a
/// short history, so handover messages are not lost between rove peers.
pub fn request_control_qos() -> QosPolicies {
    QosPolicyBuilder::new()
        .reliability(Reliability::Reliable {
            max_blocking_time: rustdds::Duration::from_millis(MAX_BLOCKING_MS),
        })
        .history(History::KeepLast { depth: 16 })
        .build()
}

/// A participant and the three topics.
pub struct Domain {
    /// The participant.
    pub participant: DomainParticipant,
    /// Topic DeviceInfo.
    pub device_info: rustdds::Topic,
    /// Topic ControlCommand.
    pub control_command: rustdds::Topic,
    /// Topic RequestControl.
    pub request_control: rustdds::Topic,
    /// Topic VehicleStatus (same QoS as DeviceInfo: late joiners get every vehicle's).
    pub vehicle_status: rustdds::Topic,
    /// Publisher for all writers.
    pub publisher: rustdds::Publisher,
    /// Subscriber for all readers.
    pub subscriber: rustdds::Subscriber,
}

impl std::fmt::Debug for Domain {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Domain").finish_non_exhaustive()
    }
}

impl Domain {
    /// Joins `domain_id`, confined to `interfaces`; with `security`, as the device whose DDS
    /// Security files are in that directory (`rove keys`); announcing itself by SPDP every
    /// `presence` (`[network] presence_ms`) with a lease of [`PRESENCE_LEASE_PERIODS`]. `any_certificate` is a test hook:
    /// our own certificate's dates are not checked (peers still check them).
    ///
    /// # Errors
    /// rustdds cannot create the participant (ports in use, no such interface, security files
    /// it rejects) or a topic, or security is asked of a build without it.
    pub fn join(
        domain_id: u16,
        interfaces: &[Ipv4Addr],
        security: Option<&std::path::Path>,
        any_certificate: bool,
        presence: std::time::Duration,
    ) -> anyhow::Result<Domain> {
        let builder = DomainParticipantBuilder::new(domain_id)
            .with_only_networks(interfaces.iter().copied())
            .same_host_loopback(true)
            .presence(presence, presence * PRESENCE_LEASE_PERIODS)
            // DCPSTopic is optional (RTPS 8.5.4.2) and nothing reads it: without it a join
            // costs each pair fewer SEDP messages (ROVE-PATCH.md §44).
            .announce_topics(false);
        let builder = match security {
            None => builder,
            #[cfg(feature = "security")]
            Some(dir) => {
                let mut files =
                    rustdds::DomainParticipantSecurityConfigFiles::with_ros_default_names(
                        dir,
                        String::new(),
                    );
                files.own_certificate_unchecked = any_certificate;
                // The fleet's revocation list, when the directory has one (`rove keys`).
                let crl = dir.join("crl.pem");
                files.certificate_revocation_list = crl.exists().then_some(crl);
                builder.builtin_security(files)
            }
            #[cfg(not(feature = "security"))]
            Some(dir) => {
                let _ = any_certificate;
                anyhow::bail!(
                    "[security] {}: this rove was built without the `security` feature",
                    dir.display()
                )
            }
        };
        let participant = builder
            .build()
            .with_context(|| format!("cannot join DDS domain {domain_id} on {interfaces:?}"))?;
        let default = QosPolicyBuilder::new().build();
        let topic = |name: &str, type_name: &str, qos: &QosPolicies, kind| {
            participant
                .create_topic(name.to_string(), type_name.to_string(), qos, kind)
                .with_context(|| format!("cannot create topic {name}"))
        };
        let device_info = topic(
            topic_names::DEVICE_INFO,
            type_names::DEVICE_INFO,
            &device_info_qos(false),
            TopicKind::WithKey,
        )?;
        let control_command = topic(
            topic_names::CONTROL_COMMAND,
            type_names::CONTROL_COMMAND,
            &control_command_qos(Strength(1)),
            TopicKind::WithKey,
        )?;
        let request_control = topic(
            topic_names::REQUEST_CONTROL,
            type_names::REQUEST_CONTROL,
            &request_control_qos(),
            TopicKind::NoKey,
        )?;
        let vehicle_status = topic(
            topic_names::VEHICLE_STATUS,
            type_names::VEHICLE_STATUS,
            &device_info_qos(false),
            TopicKind::WithKey,
        )?;
        let publisher = participant
            .create_publisher(&default)
            .context("cannot create publisher")?;
        let subscriber = participant
            .create_subscriber(&default)
            .context("cannot create subscriber")?;
        Ok(Domain {
            participant,
            device_info,
            control_command,
            request_control,
            vehicle_status,
            publisher,
            subscriber,
        })
    }

    /// A DeviceInfo writer.
    ///
    /// # Errors
    /// rustdds refuses to create it.
    pub fn device_info_writer(
        &self,
    ) -> anyhow::Result<rustdds::with_key::DataWriterCdr<KeyedDeviceInfo>> {
        self.publisher
            .create_datawriter_cdr(&self.device_info, Some(device_info_qos(false)))
            .context("cannot create DeviceInfo writer")
    }

    /// A DeviceInfo reader.
    ///
    /// # Errors
    /// rustdds refuses to create it.
    pub fn device_info_reader(
        &self,
    ) -> anyhow::Result<rustdds::with_key::DataReaderCdr<KeyedDeviceInfo>> {
        self.subscriber
            .create_datareader_cdr(&self.device_info, Some(device_info_qos(true)))
            .context("cannot create DeviceInfo reader")
    }

    /// A VehicleStatus writer.
    ///
    /// # Errors
    /// rustdds refuses to create it (under DDS Security: permissions made before the topic
    /// existed do not name it).
    pub fn vehicle_status_writer(
        &self,
    ) -> anyhow::Result<rustdds::with_key::DataWriterCdr<KeyedVehicleStatus>> {
        self.publisher
            .create_datawriter_cdr(&self.vehicle_status, Some(device_info_qos(false)))
            .context("cannot create VehicleStatus writer")
    }

    /// A VehicleStatus reader.
    ///
    /// # Errors
    /// As [`Domain::vehicle_status_writer`].
    pub fn vehicle_status_reader(
        &self,
    ) -> anyhow::Result<rustdds::with_key::DataReaderCdr<KeyedVehicleStatus>> {
        self.subscriber
            .create_datareader_cdr(&self.vehicle_status, Some(device_info_qos(true)))
            .context("cannot create VehicleStatus reader")
    }

    /// A ControlCommand writer with `strength` for `route`.
    ///
    /// # Errors
    /// rustdds refuses to create it.
    pub fn command_writer(
        &self,
        strength: Strength,
        route: Route,
    ) -> anyhow::Result<rustdds::with_key::DataWriterCdr<KeyedControlCommand>> {
        let qos = match route {
            Route::Vehicle(id) => control_command_qos(strength).with_partition(Partition {
                names: vec![vehicle_partition(id)],
            }),
            Route::Default => control_command_qos(strength),
        };
        self.publisher
            .create_datawriter_cdr(&self.control_command, Some(qos))
            .context("cannot create ControlCommand writer")
    }

    /// Vehicle `me`'s ControlCommand reader (exclusive, as the seed's vehicles read), in its
    /// own partition and the default one.
    ///
    /// # Errors
    /// rustdds refuses to create it.
    pub fn command_reader(
        &self,
        me: DeviceId,
    ) -> anyhow::Result<rustdds::with_key::DataReaderCdr<KeyedControlCommand>> {
        // Every operator writes the same instance (key = the vehicle's id): the history depth
        // is per writer (ROVE-PATCH.md §12), so a writer's samples evict only its own.
        // Best effort, whatever the writers offer: a control stream needs its newest sample,
        // and a reliable reader holds back a stream behind one lost packet (docs/design.md §2,
        // "ControlCommand's reliability"). Partitions: its own, where rove operators send its
        // commands, and the default one, where a peer that knows no partitions sends.
        let qos = QosPolicyBuilder::new()
            .reliability(Reliability::BestEffort)
            .history(History::KeepLast {
                depth: COMMAND_READER_DEPTH,
            })
            .build()
            .with_partition(Partition {
                names: vec![vehicle_partition(me), String::new()],
            });
        self.subscriber
            .create_datareader_cdr(
                &self.control_command,
                Some(control_command_qos(Strength::FAILSAFE).modify_by(&qos)),
            )
            .context("cannot create ControlCommand reader")
    }

    /// A RequestControl writer.
    ///
    /// # Errors
    /// rustdds refuses to create it.
    pub fn request_writer(&self) -> anyhow::Result<rustdds::no_key::DataWriterCdr<RequestControl>> {
        self.publisher
            .create_datawriter_no_key_cdr(&self.request_control, Some(request_control_qos()))
            .context("cannot create RequestControl writer")
    }

    /// A RequestControl reader.
    ///
    /// # Errors
    /// rustdds refuses to create it.
    pub fn request_reader(&self) -> anyhow::Result<rustdds::no_key::DataReaderCdr<RequestControl>> {
        // The topic is keyless: stock rustdds kept one history for every sender's REQUEST,
        // ACCEPT, REFUSE and FINISH, and a burst of sixteen (a flood, or many operators at
        // once) evicted an ACCEPT or a FINISH before the loop took it. rove's rustdds keeps the
        // topic's KEEP_LAST 16 per writer (ROVE-PATCH.md §12): only a sender's own later
        // messages can push one of its messages out, and no honest peer sends sixteen before
        // the loop's next turn.
        let qos = request_control_qos();
        self.subscriber
            .create_datareader_no_key_cdr(&self.request_control, Some(qos))
            .context("cannot create RequestControl reader")
    }

    /// The ownership strength a remote writer announced in discovery, if known.
    pub fn discovered_strength(&self, writer: GUID) -> Option<Strength> {
        self.participant
            .discovered_writers()
            .into_iter()
            .find(|w| w.publication_topic_data.key == writer)
            .and_then(|w| strength_of(w.publication_topic_data.ownership))
    }
}

/// The strength of an EXCLUSIVE writer; `None` for SHARED or absent ownership, and for values
/// outside 0..=65535 (not a rove strength).
pub fn strength_of(ownership: Option<Ownership>) -> Option<Strength> {
    match ownership? {
        Ownership::Exclusive { strength } => u16::try_from(strength).ok().map(Strength),
        Ownership::Shared => None,
    }
}

/// An RTPS time stamp (seconds and 2⁻³² fractions since the epoch) in nanoseconds.
pub fn timestamp_nanos(t: rustdds::Timestamp) -> i128 {
    let ticks = i128::from(t.to_ticks());
    (ticks >> 32) * 1_000_000_000 + (((ticks & 0xffff_ffff) * 1_000_000_000) >> 32)
}

/// The core's identity for a DDS writer: participant = GUID prefix, entity = entity id.
pub fn writer_id(guid: GUID) -> WriterId {
    let bytes = guid.to_bytes();
    let mut entity = [0u8; 4];
    entity.copy_from_slice(&bytes[12..16]);
    WriterId {
        participant: participant_id(&bytes[..12]),
        entity: u32::from_be_bytes(entity),
    }
}

/// The core's identity for a DDS participant from its 12-byte GUID prefix.
pub fn participant_id(prefix: &[u8]) -> ParticipantId {
    let mut wide = [0u8; 16];
    let n = prefix.len().min(12);
    wide[4..4 + n].copy_from_slice(&prefix[..n]);
    ParticipantId(u128::from_be_bytes(wide))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn writer_ids_keep_participant_and_entity_apart() {
        let mut bytes = [0u8; 16];
        bytes[..12].copy_from_slice(&[1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12]);
        bytes[12..].copy_from_slice(&[0, 0, 1, 0x02]);
        let id = writer_id(GUID::from_bytes(bytes));
        assert_eq!(id.entity, 0x0000_0102);
        assert_eq!(id.participant, participant_id(&bytes[..12]));
        let mut other = bytes;
        other[15] = 0x03;
        let other_id = writer_id(GUID::from_bytes(other));
        assert_eq!(other_id.participant, id.participant);
        assert_ne!(other_id, id);
    }

    #[test]
    fn only_exclusive_rove_strengths_count() {
        assert_eq!(
            strength_of(Some(Ownership::Exclusive { strength: 220 })),
            Some(Strength(220))
        );
        assert_eq!(strength_of(Some(Ownership::Shared)), None);
        assert_eq!(strength_of(None), None);
        assert_eq!(
            strength_of(Some(Ownership::Exclusive { strength: -1 })),
            None
        );
        assert_eq!(
            strength_of(Some(Ownership::Exclusive { strength: 70_000 })),
            None
        );
    }

    /// The keyed wrappers put exactly the core type's bytes on the wire.
    #[test]
    fn wrappers_are_transparent_on_the_wire() {
        let cmd = ControlCommand {
            src_id: 1,
            dest_id: 2,
            command_type: rove_core::msg::CommandType::Movement,
            movement_command: rove_core::msg::MovementCommand::CENTRED,
            mode: rove_core::msg::Mode::Auto,
            timestamp: rove_core::msg::TimeT(9),
        };
        let wrapped = serde_json::to_value(KeyedControlCommand(cmd)).expect("json");
        assert_eq!(wrapped, serde_json::to_value(cmd).expect("json"));
        assert_eq!(KeyedControlCommand(cmd).key(), 2);
    }

    #[test]
    fn rtps_time_stamps_convert_to_nanoseconds() {
        let half_past_five = rustdds::Timestamp::from_ticks((5 << 32) | (1 << 31));
        assert_eq!(timestamp_nanos(half_past_five), 5_500_000_000);
        assert_eq!(timestamp_nanos(rustdds::Timestamp::from_ticks(0)), 0);
        let now = timestamp_nanos(rustdds::Timestamp::now());
        let wall = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map(|d| d.as_nanos() as i128)
            .unwrap_or_default();
        assert!((wall - now).abs() < 1_000_000_000, "{now} vs {wall}");
    }
}
