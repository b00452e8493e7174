//! rove patch (ROVE-PATCH.md §7): one participant's receive path, without
//! sockets, threads or a poll, so that a fuzzer can feed it datagrams.
//!
//! [`Participant`] holds the real [`DPEventLoop`] (its message receiver, the
//! readers with their writer proxies and fragment assemblers, the writers with
//! their reader proxies), the DDS cache and the discovery database. A datagram
//! goes where the UDP listener would hand it: `MessageReceiver` parses it and
//! dispatches its submessages; ACKNACKs and NACK_FRAGs reach the writers as on
//! the loop's next wake. What the built-in discovery readers received is then
//! decoded and applied as the discovery thread does (database update, then the
//! event loop's proxy updates), synchronously.
//!
//! Not covered: DDS Security, the discovery thread's own timers and sends, the
//! user-facing `DataReader`s (rove's own fuzz target `cdr` decodes samples).
//! Every send is discarded: destinations come from fuzzed data.

use std::{
  any::Any,
  collections::HashMap,
  net::{Ipv4Addr, SocketAddr},
  sync::{Arc, Mutex, RwLock},
  time::Duration as StdDuration,
};

use bytes::Bytes;

use crate::{
  dds::{
    adapters::{no_key::DeserializerAdapter as _, with_key::DeserializerAdapter as _},
    qos::QosPolicies,
    statusevents::sync_status_channel,
    typedesc::TypeDesc,
    with_key::datawriter::WriteOptions,
  },
  discovery::{
    discovery::Discovery,
    discovery_db::DiscoveryDB,
    sedp_messages::{DiscoveredReaderData, DiscoveredWriterData, ParticipantMessageData},
    spdp_participant_data::SpdpDiscoveredParticipantData,
  },
  messages::submessages::elements::serialized_payload::SerializedPayload,
  polling::{ready_channel, wake_channel, wake_channel_unbounded, LoopWaker, WakeSender},
  rtps::{
    constant::{
      builtin_topic_names, builtin_topic_type_names, DiscoveryNotificationType,
      TokenReceiverPair, ADD_READER_TOKEN, ADD_WRITER_TOKEN, REMOVE_READER_TOKEN,
      REMOVE_WRITER_TOKEN,
    },
    dp_event_loop::{DPEventLoop, DomainInfo},
    reader::ReaderIngredients,
    writer::WriterIngredients,
    writer_send_buffer::WriterSendBuffer,
  },
  serialization::pl_cdr_adapters::PlCdrDeserializerAdapter,
  structure::{
    cache_change::CacheChange,
    dds_cache::{DDSCache, TopicCache},
    guid::{EntityId, EntityKind, GuidPrefix, GUID},
    time::Timestamp,
  },
  dds::ddsdata::DDSData,
  CDRDeserializerAdapter, RepresentationIdentifier,
};

/// A user topic's endpoint of the participant under test.
#[derive(Clone, Debug)]
pub struct Endpoint {
  /// Topic name.
  pub topic: String,
  /// Type name.
  pub type_name: String,
  /// The endpoint's QoS (as the application creates it).
  pub qos: QosPolicies,
  /// Whether the topic is keyed.
  pub keyed: bool,
}

/// Whether an [`Endpoint`] reads or writes.
#[derive(Clone, Debug)]
pub enum Role {
  /// A reader.
  Reader,
  /// A writer, with these serialized samples (CDR, little-endian, without
  /// the encapsulation header) already in its history.
  Writer {
    /// The samples' payloads.
    samples: Vec<Vec<u8>>,
  },
}

/// What the discovery thread would read from one built-in reader.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Builtin {
  Participant,
  Publication,
  Subscription,
  ParticipantMessage,
}

/// A participant whose receive path is driven by hand.
pub struct Participant {
  event_loop: DPEventLoop,
  discovery_db: Arc<RwLock<DiscoveryDB>>,
  discovery_updates: WakeSender<DiscoveryNotificationType>,
  builtin: Vec<(Builtin, Arc<Mutex<TopicCache>>, Timestamp)>,
  // The other ends of channels the endpoints report into: kept, so that a
  // report is a queued message, as in a participant, and not a send error.
  _keep: Vec<Box<dyn Any>>,
}

/// Where fuzzed datagrams claim to come from.
const SOURCE: SocketAddr = SocketAddr::new(std::net::IpAddr::V4(Ipv4Addr::LOCALHOST), 7411);

impl Participant {
  /// A participant with the built-in discovery endpoints and the given user
  /// readers and writers (entity ids assigned in order, as a participant
  /// does).
  ///
  /// # Panics
  /// If the event loop cannot be built (no fuzzed input is involved).
  pub fn new(guid_prefix: [u8; 12], endpoints: &[(Role, Endpoint)]) -> Self {
    let prefix = GuidPrefix::new(&guid_prefix);
    let mut keep: Vec<Box<dyn Any>> = Vec::new();
    let waker = LoopWaker::new();
    let (add_reader_tx, add_reader_rx) = wake_channel::<ReaderIngredients>(8, &waker);
    let (remove_reader_tx, remove_reader_rx) = wake_channel::<GUID>(8, &waker);
    let (add_writer_tx, add_writer_rx) = wake_channel::<WriterIngredients>(8, &waker);
    let (remove_writer_tx, remove_writer_rx) = wake_channel::<GUID>(8, &waker);
    let (stop_tx, stop_rx) = wake_channel_unbounded(&waker);
    let (discovery_updates, discovery_updates_rx) = wake_channel(1024, &waker);
    let discovery_waker = LoopWaker::new();
    let (command_tx, command_rx) = wake_channel(1024, &discovery_waker);
    let (liveness_tx, liveness_rx) = wake_channel(1024, &discovery_waker);
    let (reader_ready_tx, reader_ready) = ready_channel(&waker);
    let (writer_ready_tx, writer_ready) = ready_channel(&waker);
    let (status_tx, status_rx) = sync_status_channel(1024).expect("status channel");
    let (db_event_tx, db_event_rx) = std::sync::mpsc::sync_channel(1024);
    keep.push(Box::new((add_reader_tx, remove_reader_tx, add_writer_tx)));
    keep.push(Box::new((remove_writer_tx, stop_tx, command_rx, liveness_rx)));
    keep.push(Box::new((reader_ready_tx, writer_ready_tx, status_rx, db_event_rx)));

    let participant_guid = GUID::new_with_prefix_and_id(prefix, EntityId::PARTICIPANT);
    let dds_cache = Arc::new(RwLock::new(DDSCache::new()));
    let discovery_db = Arc::new(RwLock::new(DiscoveryDB::new(
      participant_guid,
      db_event_tx,
      status_tx.clone(),
    )));
    let mut event_loop = DPEventLoop::new(
      DomainInfo {
        domain_participant_guid: participant_guid,
        domain_id: 0,
        participant_id: 0,
      },
      Arc::clone(&dds_cache),
      HashMap::new(),
      Arc::clone(&discovery_db),
      prefix,
      TokenReceiverPair {
        token: ADD_READER_TOKEN,
        receiver: add_reader_rx,
      },
      TokenReceiverPair {
        token: REMOVE_READER_TOKEN,
        receiver: remove_reader_rx,
      },
      TokenReceiverPair {
        token: ADD_WRITER_TOKEN,
        receiver: add_writer_rx,
      },
      TokenReceiverPair {
        token: REMOVE_WRITER_TOKEN,
        receiver: remove_writer_rx,
      },
      stop_rx,
      discovery_updates_rx,
      command_tx,
      liveness_tx,
      status_tx.clone(),
      None,
      Some(Arc::from([std::net::IpAddr::V4(Ipv4Addr::LOCALHOST)])),
      0,
      false,
      None,
      reader_ready,
      writer_ready,
      waker,
    )
    .expect("event loop");
    event_loop.fuzz_discard_sends().expect("a discarding sender");

    let mut builtin = Vec::new();
    // `None`: received and stored, not acted on (topic data; rove uses none).
    let builtins: [(Option<Builtin>, &str, &str, QosPolicies, QosPolicies, EntityId, EntityId); 5] = [
      (
        Some(Builtin::Participant),
        builtin_topic_names::DCPS_PARTICIPANT,
        builtin_topic_type_names::DCPS_PARTICIPANT,
        Discovery::create_spdp_participant_qos(),
        Discovery::create_spdp_participant_qos(),
        EntityId::SPDP_BUILTIN_PARTICIPANT_READER,
        EntityId::SPDP_BUILTIN_PARTICIPANT_WRITER,
      ),
      (
        Some(Builtin::Subscription),
        builtin_topic_names::DCPS_SUBSCRIPTION,
        builtin_topic_type_names::DCPS_SUBSCRIPTION,
        Discovery::builtin_sedp_reader_qos(),
        Discovery::builtin_publisher_qos(),
        EntityId::SEDP_BUILTIN_SUBSCRIPTIONS_READER,
        EntityId::SEDP_BUILTIN_SUBSCRIPTIONS_WRITER,
      ),
      (
        Some(Builtin::Publication),
        builtin_topic_names::DCPS_PUBLICATION,
        builtin_topic_type_names::DCPS_PUBLICATION,
        Discovery::builtin_sedp_reader_qos(),
        Discovery::builtin_publisher_qos(),
        EntityId::SEDP_BUILTIN_PUBLICATIONS_READER,
        EntityId::SEDP_BUILTIN_PUBLICATIONS_WRITER,
      ),
      (
        None,
        builtin_topic_names::DCPS_TOPIC,
        builtin_topic_type_names::DCPS_TOPIC,
        Discovery::builtin_sedp_reader_qos(),
        Discovery::builtin_publisher_qos(),
        EntityId::SEDP_BUILTIN_TOPIC_READER,
        EntityId::SEDP_BUILTIN_TOPIC_WRITER,
      ),
      (
        Some(Builtin::ParticipantMessage),
        builtin_topic_names::DCPS_PARTICIPANT_MESSAGE,
        builtin_topic_type_names::DCPS_PARTICIPANT_MESSAGE,
        Discovery::PARTICIPANT_MESSAGE_QOS,
        Discovery::PARTICIPANT_MESSAGE_QOS,
        EntityId::P2P_BUILTIN_PARTICIPANT_MESSAGE_READER,
        EntityId::P2P_BUILTIN_PARTICIPANT_MESSAGE_WRITER,
      ),
    ];
    for (kind, topic, type_name, reader_qos, writer_qos, reader_id, writer_id) in builtins {
      let cache = dds_cache.write().expect("cache").add_new_topic(
        topic.to_string(),
        TypeDesc::new(type_name.to_string()),
        &reader_qos,
      );
      let reader = reader_ingredients(
        GUID::new_with_prefix_and_id(prefix, reader_id),
        topic,
        &cache,
        reader_qos,
        &mut keep,
      );
      event_loop.fuzz_add_reader(reader);
      let writer = writer_ingredients(
        GUID::new_with_prefix_and_id(prefix, writer_id),
        topic,
        writer_qos,
        &mut keep,
      );
      event_loop.fuzz_add_writer(writer.0);
      if let Some(kind) = kind {
        builtin.push((kind, cache, Timestamp::ZERO));
      }
    }

    // User endpoints, numbered in order as `DomainParticipant::new_entity_id`
    // does.
    for (key, (role, e)) in (0u32..).zip(endpoints) {
      let [_, a, b, c] = key.to_be_bytes();
      let kind = match (role, e.keyed) {
        (Role::Reader, true) => EntityKind::READER_WITH_KEY_USER_DEFINED,
        (Role::Reader, false) => EntityKind::READER_NO_KEY_USER_DEFINED,
        (Role::Writer { .. }, true) => EntityKind::WRITER_WITH_KEY_USER_DEFINED,
        (Role::Writer { .. }, false) => EntityKind::WRITER_NO_KEY_USER_DEFINED,
      };
      let guid = GUID::new_with_prefix_and_id(prefix, EntityId::new([a, b, c], kind));
      match role {
        Role::Reader => {
          let cache = dds_cache.write().expect("cache").add_new_topic(
            e.topic.clone(),
            TypeDesc::new(e.type_name.clone()),
            &e.qos,
          );
          let reader = reader_ingredients(guid, &e.topic, &cache, e.qos.clone(), &mut keep);
          event_loop.fuzz_add_reader(reader);
        }
        Role::Writer { samples } => {
          let (writer, buffer) = writer_ingredients(guid, &e.topic, e.qos.clone(), &mut keep);
          event_loop.fuzz_add_writer(writer);
          for sample in samples {
            let data = DDSData::new(SerializedPayload::new(
              RepresentationIdentifier::CDR_LE,
              sample.clone(),
            ));
            let _ = buffer.admit_blocking(WriteOptions::default(), data, Some(StdDuration::ZERO));
          }
        }
      }
    }
    event_loop.fuzz_settle();

    Self {
      event_loop,
      discovery_db,
      discovery_updates,
      builtin,
      _keep: keep,
    }
  }

  /// One datagram, as received on a UDP port of this participant, and what
  /// the event loop and discovery do with it.
  pub fn receive(&mut self, datagram: &[u8]) {
    self
      .event_loop
      .fuzz_receive(&Bytes::copy_from_slice(datagram), SOURCE);
    self.discover();
    self.event_loop.fuzz_settle();
  }

  /// Remote writers matched to the user readers (discovery worked).
  pub fn matched_user_writers(&self) -> usize {
    self.event_loop.fuzz_matched_user_writers()
  }

  /// Remote participants in the discovery database (this one included, once
  /// it has heard itself).
  pub fn known_participants(&self) -> usize {
    self
      .discovery_db
      .read()
      .map(|db| db.participant_count())
      .unwrap_or(0)
  }

  /// Runs the event loop's timers that are due (heartbeats, ACKNACK
  /// responses, cache clean-up).
  pub fn timers(&mut self) {
    self.event_loop.fuzz_timers();
    self.event_loop.fuzz_settle();
  }

  /// The discovery thread's share: what the built-in readers received since
  /// the last call, decoded and applied.
  fn discover(&mut self) {
    for (kind, cache, last) in &mut self.builtin {
      let changes: Vec<(Timestamp, CacheChange)> = {
        let cache = cache.lock().expect("topic cache");
        cache
          .get_changes_in_range_best_effort(*last, Timestamp::now())
          .map(|(t, c)| (t, c.clone()))
          .collect()
      };
      for (t, change) in changes {
        *last = t;
        let note = match (&*kind, &change.data_value) {
          (Builtin::Participant, DDSData::Data { serialized_payload: p }) => {
            match PlCdrDeserializerAdapter::<SpdpDiscoveredParticipantData>::from_bytes(
              &p.value,
              p.representation_identifier,
            ) {
              Ok(data) => {
                self
                  .discovery_db
                  .write()
                  .expect("db")
                  .update_participant(&data);
                Some(DiscoveryNotificationType::ParticipantUpdated {
                  guid_prefix: data.participant_guid.prefix,
                })
              }
              Err(_) => None,
            }
          }
          (Builtin::Participant, DDSData::DisposeByKey { key, .. }) => {
            match PlCdrDeserializerAdapter::<SpdpDiscoveredParticipantData>::key_from_bytes(
              &key.value,
              key.representation_identifier,
            ) {
              Ok(guid) => {
                let prefix = guid.0.prefix;
                self
                  .discovery_db
                  .write()
                  .expect("db")
                  .remove_participant(prefix, true);
                Some(DiscoveryNotificationType::ParticipantLost {
                  guid_prefix: prefix,
                })
              }
              Err(_) => None,
            }
          }
          (Builtin::Publication, DDSData::Data { serialized_payload: p }) => {
            match PlCdrDeserializerAdapter::<DiscoveredWriterData>::from_bytes(
              &p.value,
              p.representation_identifier,
            ) {
              Ok(data) => self
                .discovery_db
                .write()
                .expect("db")
                .update_publication(&data)
                .map(|data| DiscoveryNotificationType::WriterUpdated {
                  discovered_writer_data: data,
                }),
              Err(_) => None,
            }
          }
          (Builtin::Publication, DDSData::DisposeByKey { key, .. }) => {
            match PlCdrDeserializerAdapter::<DiscoveredWriterData>::key_from_bytes(
              &key.value,
              key.representation_identifier,
            ) {
              Ok(guid) => {
                self
                  .discovery_db
                  .write()
                  .expect("db")
                  .remove_topic_writer(guid.0);
                Some(DiscoveryNotificationType::WriterLost {
                  writer_guid: guid.0,
                })
              }
              Err(_) => None,
            }
          }
          (Builtin::Subscription, DDSData::Data { serialized_payload: p }) => {
            match PlCdrDeserializerAdapter::<DiscoveredReaderData>::from_bytes(
              &p.value,
              p.representation_identifier,
            ) {
              Ok(data) => self
                .discovery_db
                .write()
                .expect("db")
                .update_subscription(&data)
                .map(|data| DiscoveryNotificationType::ReaderUpdated {
                  discovered_reader_data: data,
                }),
              Err(_) => None,
            }
          }
          (Builtin::Subscription, DDSData::DisposeByKey { key, .. }) => {
            match PlCdrDeserializerAdapter::<DiscoveredReaderData>::key_from_bytes(
              &key.value,
              key.representation_identifier,
            ) {
              Ok(guid) => {
                self
                  .discovery_db
                  .write()
                  .expect("db")
                  .remove_topic_reader(guid.0);
                Some(DiscoveryNotificationType::ReaderLost {
                  reader_guid: guid.0,
                })
              }
              Err(_) => None,
            }
          }
          (Builtin::ParticipantMessage, DDSData::Data { serialized_payload: p }) => {
            if let Ok(data) = CDRDeserializerAdapter::<ParticipantMessageData>::from_bytes(
              &p.value,
              p.representation_identifier,
            ) {
              self
                .discovery_db
                .write()
                .expect("db")
                .update_lease_duration(&data);
            }
            None
          }
          _ => None,
        };
        if let Some(note) = note {
          let _ = self.discovery_updates.try_send(note);
        }
      }
    }
  }
}

fn reader_ingredients(
  guid: GUID,
  topic: &str,
  cache: &Arc<Mutex<TopicCache>>,
  qos: QosPolicies,
  keep: &mut Vec<Box<dyn Any>>,
) -> ReaderIngredients {
  let (notification_sender, notification_receiver) = crate::mio_source::notification_channel(4);
  let (status_sender, status_receiver) = sync_status_channel(4).expect("status channel");
  let (command_sender, command_receiver) = wake_channel(0, &LoopWaker::new());
  let (poll_source, poll_event_sender) =
    crate::mio_source::make_poll_channel().expect("poll channel");
  keep.push(Box::new((notification_receiver, status_receiver, command_sender)));
  keep.push(Box::new(poll_source));
  ReaderIngredients {
    guid,
    notification_sender,
    status_sender,
    topic_name: topic.to_string(),
    topic_cache_handle: Arc::clone(cache),
    like_stateless: false,
    qos_policy: qos,
    data_reader_command_receiver: command_receiver,
    data_reader_waker: Arc::new(Mutex::new(None)),
    poll_event_sender,
    security_plugins: None,
    discovery_notify: None,
  }
}

fn writer_ingredients(
  guid: GUID,
  topic: &str,
  qos: QosPolicies,
  keep: &mut Vec<Box<dyn Any>>,
) -> (WriterIngredients, WriterSendBuffer) {
  let (status_sender, status_receiver) = sync_status_channel(4).expect("status channel");
  keep.push(Box::new(status_receiver));
  let volatile = !matches!(
    qos.durability(),
    Some(crate::policy::Durability::TransientLocal)
      | Some(crate::policy::Durability::Transient)
      | Some(crate::policy::Durability::Persistent)
  );
  let send_buffer = WriterSendBuffer::new(
    guid,
    topic.to_string(),
    qos.is_reliable(),
    guid.entity_id.entity_kind.is_built_in(),
    volatile,
    32,
    32,
    16,
  );
  (
    WriterIngredients {
      guid,
      send_buffer: send_buffer.clone(),
      topic_name: topic.to_string(),
      like_stateless: false,
      qos_policies: qos,
      status_sender,
      security_plugins: None,
    },
    send_buffer,
  )
}
