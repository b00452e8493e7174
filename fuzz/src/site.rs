//! Messages of another site into the bridge's reader ([`Policy::inbound`]): a key as the
//! link delivers it (any text) and its payload or a delete, for a lab that meets two sites,
//! `home` (remote operators 21, 22 and its own vehicle 500; offered vehicle 100) and `office`
//! (operator 41, stationary at most; offered 100 and 101).
//!
//! Input: byte 0 chooses a delete (bit 0) and which devices count as the sender's own
//! (bits 1–2: none, vehicle 500 as home's, every device as the sender's); then the key up to
//! the first newline; the rest is the payload.
//!
//! Checked, besides "no panic": a key that is read renders back as sent, is for the lab and
//! from a configured site; what is read speaks only for ids that site may speak for, about
//! vehicles offered to it (or, for a request, its own), with strengths at most its level or a
//! priority writer's; a payload's ids are its key's, and it encodes and reads back equal; a
//! refusal says why.

use rove_core::hierarchy::{Hierarchy, Level, Strength};
use rove_core::msg::{Ack, DeviceId};
use rove_core::site::wire::{self, Inbound, MAX_PAYLOAD};
use rove_core::site::{Key, Peer, Policy, SiteName, Subject};

fn name(name: &str) -> SiteName {
    SiteName::new(name).unwrap_or_else(|e| panic!("{name}: {e}"))
}

fn lab() -> Policy {
    Policy {
        me: name("lab"),
        hierarchy: Hierarchy::STANDARD,
        peers: vec![
            Peer {
                name: name("home"),
                ids: [21, 22, 500].into(),
                offer: [100].into(),
                level: Level::Remote,
            },
            Peer {
                name: name("office"),
                ids: [41].into(),
                offer: [100, 101].into(),
                level: Level::Stationary,
            },
        ],
    }
}

/// Reads one message and checks what was read.
pub fn site(data: &[u8]) {
    let Some((&flags, rest)) = data.split_first() else {
        return;
    };
    let (key, payload) = match rest.iter().position(|&b| b == b'\n') {
        Some(at) => (&rest[..at], Some(&rest[at + 1..])),
        None => (rest, None),
    };
    let Ok(key) = std::str::from_utf8(key) else {
        return; // The link's keys are text.
    };
    let payload = if flags & 1 == 1 { None } else { payload };
    let theirs = |from: &SiteName, id: DeviceId| match (flags >> 1) & 3 {
        0 => false,
        1 => from.as_str() == "home" && id == 500,
        _ => true,
    };
    let policy = lab();
    let (from, inbound) = match policy.inbound(key, payload, theirs) {
        Ok(read) => read,
        Err(refusal) => {
            assert!(!refusal.to_string().is_empty(), "{refusal:?}");
            return;
        }
    };
    let parsed = Key::parse(key).expect("read, so a key");
    assert_eq!(parsed.render(), key);
    assert_eq!((&parsed.to, &parsed.from), (&policy.me, &from));
    let peer = policy.peer(&from).expect("a configured site");
    let subject = parsed.subject;
    assert!(peer.ids.contains(&subject.speaker()), "{key}");
    assert!(payload.is_none_or(|p| p.len() <= MAX_PAYLOAD));
    let within = |s: Strength| {
        s == Strength::PRIORITY
            || (policy.hierarchy.rank_of(s)).is_some_and(|(level, ..)| level <= peer.level)
    };
    match inbound {
        Inbound::Info(info) => {
            assert_eq!(subject, Subject::Info(info.device_id));
            assert_eq!(wire::decode(&wire::encode(&info)).as_ref(), Some(&info));
        }
        Inbound::Withdrawn(id) => {
            assert_eq!(subject, Subject::Info(id));
            assert!(payload.is_none());
        }
        Inbound::Status(status) => {
            assert_eq!(subject, Subject::Status(status.vehicle_id));
            assert_eq!(wire::decode(&wire::encode(&status)).as_ref(), Some(&status));
        }
        Inbound::Command {
            src,
            dest,
            strength,
            command,
        } => {
            assert!(
                matches!(subject, Subject::Command { src: s, dest: d, .. } if (s, d) == (src, dest))
            );
            assert!(peer.offer.contains(&dest), "{key}: {dest} not offered");
            assert!(within(strength), "{key}: drives with {strength:?}");
            match command {
                Some(sent) => {
                    assert_eq!((sent.command.src_id, sent.command.dest_id), (src, dest));
                    assert_eq!(wire::decode(&wire::encode(&sent)), Some(sent));
                }
                None => assert!(payload.is_none()),
            }
        }
        Inbound::Request(msg) => {
            assert_eq!(subject, Subject::Request(msg.sender_id()));
            let dest = msg.dest_id;
            assert!(
                peer.offer.contains(&dest) || theirs(&from, dest),
                "{key}: {dest}"
            );
            if msg.ack == Ack::Request {
                let priority = u16::try_from(msg.src_priority).map(Strength);
                assert!(priority.is_ok_and(within), "{key}: {}", msg.src_priority);
            }
        }
    }
}
