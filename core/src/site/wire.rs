//! What the bridges' messages carry, and how another site's message is read.
//!
//! Payloads are the seed types as JSON (small, self-describing), read only up to
//! [`MAX_PAYLOAD`] bytes; a command travels with its source time stamp.
//! [`Policy::inbound`] reads a message from another site: its key parsed, its site and
//! speaker checked ([`Policy::admit`]), its payload decoded and checked against its key. What
//! the bridge then does with it depends on its state (the devices it knows), not here.

use super::{Key, Policy, Refusal, SiteName, Subject};
use crate::hierarchy::Strength;
use crate::msg::{ControlCommand, DeviceId, DeviceInfo, RequestControl, VehicleStatus};
use serde::{Deserialize, Serialize};

/// The largest payload read; anything longer is refused unread.
pub const MAX_PAYLOAD: usize = 4096;

/// A ControlCommand and the RTPS source time stamp its writer gave it (ticks: seconds and
/// 2⁻³² fractions), so that the vehicle's freshness check compares the sender's own stamps
/// (`crate::freshness`) and a stream that queued up on the link is not applied late.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct Command {
    /// The command as its operator wrote it.
    pub command: ControlCommand,
    /// Its writer's source time stamp, if it had one.
    pub stamp: Option<u64>,
}

/// `value` as a payload.
pub fn encode<T: Serialize>(value: &T) -> Vec<u8> {
    // The seed types serialise to JSON without fail (no maps with non-string keys, no
    // non-finite floats).
    serde_json::to_vec(value).unwrap_or_default()
}

/// A payload as `T`, if it is one and not longer than [`MAX_PAYLOAD`].
pub fn decode<T: for<'de> Deserialize<'de>>(payload: &[u8]) -> Option<T> {
    if payload.len() > MAX_PAYLOAD {
        return None;
    }
    serde_json::from_slice(payload).ok()
}

/// A message of another site, believed: what its key and payload say.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Inbound {
    /// A device's DeviceInfo (the key's id is the payload's).
    Info(DeviceInfo),
    /// A device withdrawn (a delete of its DeviceInfo).
    Withdrawn(DeviceId),
    /// A vehicle's VehicleStatus (the key's id is the payload's).
    Status(VehicleStatus),
    /// A command of operator `src` for our vehicle `dest`, offered to the site, to be written
    /// here with `strength` ([`Policy::strength`]); `None`: the writer released it.
    Command {
        /// The operator.
        src: DeviceId,
        /// Our vehicle.
        dest: DeviceId,
        /// The strength it drives with here.
        strength: Strength,
        /// The command (its ids the key's), or `None` for a release.
        command: Option<Command>,
    },
    /// A RequestControl, its priority taken as a strength here ([`Policy::request`]).
    Request(RequestControl),
}

impl Policy {
    /// Reads a message of another site: `key` as the link delivered it and its payload
    /// (`None`: a delete). `theirs(site, id)` says whether device `id` is known here as
    /// `site`'s (a request may be about one of that site's own vehicles).
    ///
    /// # Errors
    /// Why it is not believed: not a rove key, not for us, a site or id not configured, a
    /// vehicle not offered, a payload missing, malformed or contradicting its key, a strength
    /// the hierarchy cannot give.
    pub fn inbound(
        &self,
        key: &str,
        payload: Option<&[u8]>,
        theirs: impl Fn(&SiteName, DeviceId) -> bool,
    ) -> Result<(SiteName, Inbound), Refusal> {
        let key = Key::parse(key).ok_or(Refusal::NotAKey)?;
        let peer = self.admit(&key)?;
        let subject = key.subject;
        let needed = || payload.ok_or(Refusal::NoPayload);
        let inbound = match subject {
            Subject::Info(id) => match payload {
                Some(bytes) => {
                    let info: DeviceInfo = decode(bytes).ok_or(Refusal::Malformed("DeviceInfo"))?;
                    self.info(subject, &info)?;
                    Inbound::Info(info)
                }
                None => Inbound::Withdrawn(id),
            },
            Subject::Status(id) => {
                let status: VehicleStatus =
                    decode(needed()?).ok_or(Refusal::Malformed("VehicleStatus"))?;
                if status.vehicle_id != id {
                    return Err(Refusal::Mismatch(subject));
                }
                Inbound::Status(status)
            }
            Subject::Command {
                src,
                dest,
                strength,
            } => {
                let (strength, command) = match payload {
                    Some(bytes) => {
                        let sent: Command =
                            decode(bytes).ok_or(Refusal::Malformed("ControlCommand"))?;
                        (self.command(peer, subject, &sent.command)?, Some(sent))
                    }
                    None => (self.strength(peer, strength)?, None),
                };
                Inbound::Command {
                    src,
                    dest,
                    strength,
                    command,
                }
            }
            Subject::Request(_) => {
                let msg: RequestControl =
                    decode(needed()?).ok_or(Refusal::Malformed("RequestControl"))?;
                let theirs = |id| theirs(&key.from, id);
                Inbound::Request(self.request(peer, subject, theirs, msg)?)
            }
        };
        Ok((key.from, inbound))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::msg::{Ack, CommandType, DeviceType, Mode, MovementCommand, TimeT};
    use crate::site::tests::{policy as lab, site};
    use proptest::prelude::*;

    #[test]
    fn the_seed_types_read_back_as_written_and_junk_is_refused() {
        let command = Command {
            command: ControlCommand {
                src_id: 21,
                dest_id: 100,
                command_type: CommandType::Movement,
                movement_command: MovementCommand {
                    throttle: -32767,
                    roll: 5,
                    pitch: 0,
                    yaw: 32767,
                },
                mode: Mode::Assisted,
                timestamp: TimeT(u64::MAX),
            },
            stamp: Some(7 << 32),
        };
        assert_eq!(decode::<Command>(&encode(&command)), Some(command));
        let info = DeviceInfo {
            device_id: 100,
            name: "rover \"1\" é".into(),
            device_type: DeviceType::Vehicle,
            controller_id: 21,
        };
        assert_eq!(decode::<DeviceInfo>(&encode(&info)), Some(info));
        let request = RequestControl {
            src_id: 21,
            dest_id: 100,
            current_controller_id: 31,
            src_priority: 120,
            ack: Ack::Finish,
            timestamp: TimeT(1),
        };
        assert_eq!(decode::<RequestControl>(&encode(&request)), Some(request));
        assert_eq!(decode::<DeviceInfo>(b"{"), None);
        assert_eq!(decode::<Command>(&encode(&request)), None);
        let long = format!("{{\"name\":\"{}\"}}", "x".repeat(MAX_PAYLOAD));
        assert_eq!(decode::<DeviceInfo>(long.as_bytes()), None);
    }

    fn info(id: DeviceId, device_type: DeviceType) -> DeviceInfo {
        DeviceInfo {
            device_id: id,
            name: format!("d{id}"),
            device_type,
            controller_id: id,
        }
    }

    fn command(src: DeviceId, dest: DeviceId) -> Command {
        Command {
            command: crate::site::tests::command(src, dest),
            stamp: Some(1),
        }
    }

    fn request(ack: Ack, dest: DeviceId, priority: i32) -> RequestControl {
        RequestControl {
            src_id: 21,
            dest_id: dest,
            current_controller_id: 31,
            src_priority: priority,
            ack,
            timestamp: TimeT(0),
        }
    }

    fn read(key: &str, payload: Option<Vec<u8>>) -> Result<Inbound, Refusal> {
        let policy = lab();
        let theirs = |s: &SiteName, id| s.as_str() == "home" && id == 500;
        let read = policy.inbound(key, payload.as_deref(), theirs)?;
        assert_eq!(read.0, site("home"), "{key}");
        Ok(read.1)
    }

    #[test]
    fn what_a_site_may_say_is_read() {
        let operator = info(21, DeviceType::Controller);
        assert_eq!(
            read("rove/lab/home/info/21", Some(encode(&operator))),
            Ok(Inbound::Info(operator))
        );
        assert_eq!(
            read("rove/lab/home/info/22", None),
            Ok(Inbound::Withdrawn(22))
        );
        // A mobile laptop at home (320) drives here as a remote laptop (120).
        let sent = command(21, 100);
        assert_eq!(
            read("rove/lab/home/cmd/21/100/320", Some(encode(&sent))),
            Ok(Inbound::Command {
                src: 21,
                dest: 100,
                strength: Strength(120),
                command: Some(sent),
            })
        );
        assert_eq!(
            read("rove/lab/home/cmd/21/100/65535", None),
            Ok(Inbound::Command {
                src: 21,
                dest: 100,
                strength: Strength::PRIORITY,
                command: None,
            })
        );
        let asked = request(Ack::Request, 100, 340);
        let Ok(Inbound::Request(taken)) = read("rove/lab/home/req/21", Some(encode(&asked))) else {
            panic!("request refused");
        };
        assert_eq!(taken.src_priority, 140, "a phone taken as a remote phone");
        // About the site's own vehicle 500, not offered: it is theirs.
        let own = request(Ack::Finish, 500, 0);
        assert_eq!(
            read("rove/lab/home/req/21", Some(encode(&own))),
            Ok(Inbound::Request(own))
        );
    }

    #[test]
    fn the_rest_is_refused_with_its_reason() {
        let operator = encode(&info(21, DeviceType::Controller));
        let long = format!("{{\"name\":\"{}\"}}", "x".repeat(MAX_PAYLOAD)).into_bytes();
        let mut status = crate::msg::VehicleStatus {
            vehicle_id: 500,
            controller_id: 500,
            mode: Mode::Manual,
            failsafe: true,
            output: crate::msg::OutputState::Ok,
            detail: String::new(),
            health: crate::msg::VehicleHealth::UNKNOWN,
        };
        let good_status = encode(&status);
        status.vehicle_id = 100;
        let cases: Vec<(&str, Option<Vec<u8>>, Refusal)> = vec![
            ("rove/lab/home/info/21/x", None, Refusal::NotAKey),
            ("rove/lab/home/info/021", None, Refusal::NotAKey),
            (
                "rove/office/home/info/21",
                None,
                Refusal::NotForUs(site("office")),
            ),
            (
                "rove/lab/attic/info/21",
                None,
                Refusal::UnknownSite(site("attic")),
            ),
            (
                "rove/lab/home/info/31",
                Some(operator.clone()),
                Refusal::NotItsId {
                    site: site("home"),
                    id: 31,
                },
            ),
            (
                "rove/lab/home/cmd/21/101/120",
                None,
                Refusal::NotOffered {
                    site: site("home"),
                    vehicle: 101,
                },
            ),
            ("rove/lab/home/status/500", None, Refusal::NoPayload),
            ("rove/lab/home/req/21", None, Refusal::NoPayload),
            (
                "rove/lab/home/info/21",
                Some(b"{".to_vec()),
                Refusal::Malformed("DeviceInfo"),
            ),
            (
                "rove/lab/home/info/21",
                Some(long),
                Refusal::Malformed("DeviceInfo"),
            ),
            (
                "rove/lab/home/info/22",
                Some(operator),
                Refusal::Mismatch(Subject::Info(22)),
            ),
            (
                "rove/lab/home/cmd/21/100/120",
                Some(good_status.clone()),
                Refusal::Malformed("ControlCommand"),
            ),
            (
                "rove/lab/home/cmd/22/100/120",
                Some(encode(&command(21, 100))),
                Refusal::Mismatch(Subject::Command {
                    src: 22,
                    dest: 100,
                    strength: Strength(120),
                }),
            ),
            (
                "rove/lab/home/cmd/21/100/7",
                None,
                Refusal::Strength(Strength(7)),
            ),
            (
                "rove/lab/home/status/500",
                Some(encode(&status)),
                Refusal::Mismatch(Subject::Status(500)),
            ),
            (
                "rove/lab/home/req/21",
                Some(encode(&request(Ack::Request, 101, 120))),
                Refusal::NotOffered {
                    site: site("home"),
                    vehicle: 101,
                },
            ),
            (
                "rove/lab/home/req/22",
                Some(encode(&request(Ack::Request, 100, 120))),
                Refusal::Mismatch(Subject::Request(22)),
            ),
        ];
        for (key, payload, want) in cases {
            assert_eq!(read(key, payload), Err(want), "{key}");
        }
        assert!(read("rove/lab/home/status/500", Some(good_status)).is_ok());
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(5_000))]

        /// Whatever the key's ids and strength and the payload's, what is read names only ids
        /// the site may speak for, our vehicles offered to it, and strengths at most its level
        /// (or a priority writer's).
        #[test]
        fn what_is_read_stays_within_what_the_site_may_say(
            kind in 0u8..5,
            // Ids the site may speak for, ours offered and not, and others.
            a in prop::sample::select(vec![21i64, 22, 500, 31, 100, 101, 0, -1]),
            b in prop::sample::select(vec![21i64, 22, 500, 31, 100, 101, 0, -1]),
            // Strengths of every level, priority, gaps, and anything.
            strength in prop_oneof![
                prop::sample::select(vec![0u16, 7, 110, 120, 149, 220, 249, 340, 349, 65534, 65535]),
                any::<u16>(),
            ],
            priority in prop_oneof![
                prop::sample::select(vec![0i32, 120, 220, 340, 65535, 65536, -1]),
                any::<i32>(),
            ],
            ack in 0u8..4,
            junk in proptest::collection::vec(any::<u8>(), 0..64),
        ) {
            let ack = [Ack::Request, Ack::Accept, Ack::Refuse, Ack::Finish][usize::from(ack)];
            let (key, payload) = match kind {
                0 => (format!("rove/lab/home/info/{a}"), Some(encode(&info(b, DeviceType::Controller)))),
                1 => (format!("rove/lab/home/cmd/{a}/{b}/{strength}"), Some(encode(&command(a, b)))),
                2 => (format!("rove/lab/home/cmd/{a}/{b}/{strength}"), None),
                3 => (format!("rove/lab/home/req/{a}"), Some(encode(&RequestControl {
                    src_id: a, current_controller_id: a, dest_id: b, ack, ..request(ack, b, priority)
                }))),
                _ => (format!("rove/lab/home/status/{a}"), Some(junk)),
            };
            let policy = lab();
            let peer = &policy.peers[0];
            let within = |s: Strength| s == Strength::PRIORITY
                || policy.hierarchy.rank_of(s).is_some_and(|(level, ..)| level <= peer.level);
            match policy.inbound(&key, payload.as_deref(), |_, _| false) {
                Ok((_, Inbound::Command { src, dest, strength, command })) => {
                    prop_assert!(peer.ids.contains(&src) && peer.offer.contains(&dest));
                    prop_assert!(within(strength));
                    if let Some(sent) = command {
                        prop_assert_eq!((sent.command.src_id, sent.command.dest_id), (src, dest));
                    }
                }
                Ok((_, Inbound::Request(msg))) => {
                    prop_assert!(peer.ids.contains(&msg.sender_id()));
                    prop_assert!(peer.offer.contains(&msg.dest_id));
                    if msg.ack == Ack::Request {
                        let s = u16::try_from(msg.src_priority).map(Strength);
                        prop_assert!(s.is_ok_and(within), "{}", msg.src_priority);
                    }
                }
                Ok((_, Inbound::Info(i))) => prop_assert!(peer.ids.contains(&i.device_id)),
                Ok((_, Inbound::Withdrawn(id))) => prop_assert!(peer.ids.contains(&id)),
                Ok((_, Inbound::Status(s))) => prop_assert!(peer.ids.contains(&s.vehicle_id)),
                Err(refusal) => prop_assert!(!refusal.to_string().is_empty()),
            }
        }
    }
}
