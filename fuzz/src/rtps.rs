//! RTPS datagrams into one participant with a rove vehicle's endpoints, through rustdds's
//! real receive path (the vendored crate's `fuzzing` feature, ROVE-PATCH.md §7): the message
//! receiver, the readers with their writer proxies and fragment assemblers, the writers with
//! their reader proxies (ACKNACK, NACK_FRAG), and discovery (SPDP participants, SEDP readers
//! and writers matched to the vehicle's endpoints, participant messages). State carries from
//! one datagram to the next, so a sequence can first announce a participant and its writers,
//! then send them HEARTBEATs, GAPs and fragments.
//!
//! The input is a sequence of datagrams, each framed by its length (u16, little-endian); the
//! last takes what is left if shorter than it says. At most [`MAX_DATAGRAMS`] are fed.
//! Seeds: datagrams a running fleet (a vehicle, an operator) sent to the vehicle, captured on
//! `lo` (`fuzz/seed-capture/`), re-addressed to the participant here ([`VEHICLE_PREFIX`]).
//!
//! Checked: no panic; and, under libFuzzer with `-malloc_limit_mb`, no allocation sized by a
//! received field beyond that limit (the reason this target exists: issue 29).

use rove_core::hierarchy::Strength;
use rove_core::msg::{topic_names, type_names};
use rove_gateway::dds::{
    control_command_qos, device_info_qos, request_control_qos, vehicle_partition,
};
use rustdds::QosPolicyBuilder;
use rustdds::fuzzing::{Endpoint, Participant, Role};
use rustdds::policy::{History, Partition, Reliability};

/// Most datagrams of one input: enough for discovery, a match and a few rounds of reliable
/// traffic.
pub const MAX_DATAGRAMS: usize = 64;

/// The participant's GUID prefix; seeds are rewritten to address it.
pub const VEHICLE_PREFIX: [u8; 12] = [0x01, 0x0f, 0x52, 0x4f, 0x56, 0x45, 0, 0, 0, 0, 0, 0x64];

/// The vehicle's id (its command partition).
const VEHICLE: i64 = 100;

/// A vehicle's endpoints in the order `rove vehicle` creates them (gateway/src/vehicle.rs): entity
/// ids follow it, so the captured ACKNACKs and HEARTBEATs name these endpoints.
fn vehicle_endpoints() -> Vec<(Role, Endpoint)> {
    let endpoint = |topic: &str, type_name: &str, qos, keyed| Endpoint {
        topic: topic.to_string(),
        type_name: type_name.to_string(),
        qos,
        keyed,
    };
    let command_reader_qos = control_command_qos(Strength::FAILSAFE).modify_by(
        &QosPolicyBuilder::new()
            .reliability(Reliability::BestEffort)
            .history(History::KeepLast { depth: 64 })
            .build()
            .with_partition(Partition {
                names: vec![vehicle_partition(VEHICLE), String::new()],
            }),
    );
    let request_reader_qos = request_control_qos().modify_by(
        &QosPolicyBuilder::new()
            .history(History::KeepLast { depth: 256 })
            .build(),
    );
    // DeviceInfo and VehicleStatus as the vehicle writes them (CDR LE bodies).
    let info = cdr_le(&rove_core::msg::DeviceInfo {
        device_id: VEHICLE,
        name: "sim-rover".to_string(),
        device_type: rove_core::msg::DeviceType::Vehicle,
        controller_id: VEHICLE,
    });
    let status = cdr_le(&rove_core::msg::VehicleStatus {
        vehicle_id: VEHICLE,
        controller_id: VEHICLE,
        mode: rove_core::msg::Mode::Manual,
        failsafe: true,
        output: rove_core::msg::OutputState::Ok,
        detail: "sim".to_string(),
        health: rove_core::msg::VehicleHealth::UNKNOWN,
    });
    vec![
        (
            Role::Writer {
                samples: vec![info.clone(), info],
            },
            endpoint(
                topic_names::DEVICE_INFO,
                type_names::DEVICE_INFO,
                device_info_qos(false),
                true,
            ),
        ),
        (
            Role::Writer {
                samples: vec![status],
            },
            endpoint(
                topic_names::VEHICLE_STATUS,
                type_names::VEHICLE_STATUS,
                device_info_qos(false),
                true,
            ),
        ),
        (
            Role::Reader,
            endpoint(
                topic_names::CONTROL_COMMAND,
                type_names::CONTROL_COMMAND,
                command_reader_qos,
                true,
            ),
        ),
        (
            Role::Reader,
            endpoint(
                topic_names::REQUEST_CONTROL,
                type_names::REQUEST_CONTROL,
                request_reader_qos,
                false,
            ),
        ),
        (
            Role::Reader,
            endpoint(
                topic_names::DEVICE_INFO,
                type_names::DEVICE_INFO,
                device_info_qos(true),
                true,
            ),
        ),
    ]
}

fn cdr_le<T: serde::Serialize>(value: &T) -> Vec<u8> {
    use rustdds::no_key::SerializerAdapter;
    // The adapter's bytes are the CDR body (little-endian); the writer adds the header.
    rustdds::CDRSerializerAdapter::<T>::to_bytes(value)
        .expect("a rove message serializes")
        .to_vec()
}

/// The datagrams of an input: length-framed, at most [`MAX_DATAGRAMS`].
pub fn datagrams(mut data: &[u8]) -> Vec<&[u8]> {
    let mut out = Vec::new();
    while data.len() >= 2 && out.len() < MAX_DATAGRAMS {
        let len = usize::from(u16::from_le_bytes([data[0], data[1]]));
        let rest = &data[2..];
        let (datagram, next) = rest.split_at(len.min(rest.len()));
        out.push(datagram);
        data = next;
    }
    out
}

/// Feeds the datagrams of `data` to a fresh vehicle participant.
pub fn rtps(data: &[u8]) {
    let mut participant = Participant::new(VEHICLE_PREFIX, &vehicle_endpoints());
    for datagram in datagrams(data) {
        participant.receive(datagram);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn framing_takes_each_length_and_the_rest() {
        let input = [3, 0, b'a', b'b', b'c', 5, 0, b'x'];
        assert_eq!(datagrams(&input), vec![&b"abc"[..], &b"x"[..]]);
        assert!(datagrams(&[7]).is_empty());
    }

    /// The seeds are a fleet's discovery and traffic: fed to the participant, its readers
    /// match the operator's writers (otherwise the fuzzer would start far from the proxies).
    /// The first windows of the capture are from before the operator started.
    #[test]
    fn the_captured_seeds_match_remote_writers() {
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("libfuzzer/corpus/rtps");
        let mut seeds = 0;
        let mut matching = 0;
        for entry in std::fs::read_dir(dir).expect("the rtps corpus") {
            let path = entry.expect("entry").path();
            let name = path.file_name().unwrap_or_default().to_string_lossy();
            if !name.starts_with("fleet-") {
                continue;
            }
            let seed = std::fs::read(&path).expect("a seed");
            let mut participant = Participant::new(VEHICLE_PREFIX, &vehicle_endpoints());
            for datagram in datagrams(&seed) {
                participant.receive(datagram);
            }
            seeds += 1;
            if participant.matched_user_writers() > 0 {
                matching += 1;
            }
        }
        assert!(seeds > 0, "no fleet seeds");
        assert!(
            matching * 4 >= seeds * 3,
            "{matching} of {seeds} seeds match a remote writer"
        );
    }

    /// Issue 29: every SPDP announcement with an unseen GUID prefix (one flipped byte of a
    /// real one) was a participant entry kept for its lease. The database keeps at most 1024.
    #[test]
    fn invented_participants_are_remembered_up_to_the_bound() {
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("libfuzzer/corpus/rtps");
        // A remote's SPDP announcement from the capture: DATA from the SPDP writer.
        let spdp = std::fs::read_dir(&dir)
            .expect("the rtps corpus")
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| {
                p.file_name()
                    .is_some_and(|n| n.to_string_lossy().starts_with("fleet-"))
            })
            .filter_map(|p| std::fs::read(p).ok())
            .flat_map(|seed| {
                datagrams(&seed)
                    .into_iter()
                    .map(<[u8]>::to_vec)
                    .collect::<Vec<_>>()
            })
            .find(|d| {
                d.len() > 20
                    && d[8..20] != VEHICLE_PREFIX
                    && d.windows(4).any(|w| w == [0x00, 0x01, 0x00, 0xc2])
            })
            .expect("a captured SPDP announcement");
        let prefix: [u8; 12] = spdp[8..20].try_into().expect("12 bytes");
        let mut participant = Participant::new(VEHICLE_PREFIX, &vehicle_endpoints());
        for n in 0u32..3000 {
            // The same announcement from another participant: its prefix replaced throughout.
            let mut other = prefix;
            other[8..12].copy_from_slice(&n.to_be_bytes());
            let mut datagram = spdp.clone();
            let mut at = 0;
            while let Some(i) = datagram[at..].windows(12).position(|w| w == prefix) {
                datagram[at + i..at + i + 12].copy_from_slice(&other);
                at += i + 12;
            }
            participant.receive(&datagram);
        }
        let known = participant.known_participants();
        assert!(
            known >= 1000,
            "the announcements were not read: {known} participants"
        );
        assert!(known <= 1024, "{known} participants remembered");
    }

    #[test]
    fn framing_stops_at_the_limit() {
        let input = [0u8; 2 * (MAX_DATAGRAMS + 5)];
        assert_eq!(datagrams(&input).len(), MAX_DATAGRAMS);
    }
}
