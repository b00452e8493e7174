//! Sites joined over a wide-area link (`rove bridge`, docs/remote.md): the key space the
//! bridges' messages travel under, and what another site may say here.
//!
//! A site is a set of devices on one DDS network, with one bridge. Bridges exchange the
//! devices' DeviceInfo, VehicleStatus, ControlCommand streams and RequestControl messages, each
//! under a key that names the receiving site, the sending site and the subject:
//!
//! ```text
//! rove/<to>/<from>/info/<id>                      DeviceInfo (delete: withdrawn)
//! rove/<to>/<from>/status/<id>                    VehicleStatus
//! rove/<to>/<from>/cmd/<src>/<dest>/<strength>    ControlCommand (delete: released)
//! rove/<to>/<from>/req/<sender>                   RequestControl
//! rove-live/<site>                                a bridge's liveliness token
//! ```
//!
//! The link's access control lets a site's certificate put only under `rove/*/<its name>/**`
//! and subscribe only to `rove/<its name>/**`, so `<from>` is authenticated by the link; which
//! ids that site may speak for, and which of our vehicles it may see, is [`Policy`]'s.

pub mod absence;
pub mod wire;

use crate::hierarchy::{Hierarchy, Level, Strength};
use crate::msg::{Ack, ControlCommand, DeviceId, DeviceInfo, DeviceType, RequestControl};
use std::collections::BTreeSet;
use std::fmt;

/// A site's name: 1 to 32 of `a`–`z`, `0`–`9` and `-`, not starting with `-` (it is a key
/// segment and a certificate's common name, `rove-site-<name>`).
#[derive(Debug, Clone, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct SiteName(String);

impl SiteName {
    /// The longest name.
    pub const MAX_LEN: usize = 32;

    /// `name`, if it is a valid site name.
    ///
    /// # Errors
    /// The rule it breaks.
    pub fn new(name: &str) -> Result<SiteName, &'static str> {
        let valid = |c: char| c.is_ascii_lowercase() || c.is_ascii_digit() || c == '-';
        if name.is_empty() || name.len() > Self::MAX_LEN {
            Err("must be 1 to 32 characters")
        } else if !name.chars().all(valid) || name.starts_with('-') {
            Err("must be lowercase letters, digits and '-', not starting with '-'")
        } else {
            Ok(SiteName(name.to_string()))
        }
    }

    /// The name.
    pub fn as_str(&self) -> &str {
        &self.0
    }

    /// The common name of the site's certificate (`rove keys site`).
    pub fn common_name(&self) -> String {
        format!("rove-site-{}", self.0)
    }

    /// Everything sent to this site: what its bridge subscribes to.
    pub fn inbox(&self) -> String {
        format!("rove/{}/**", self.0)
    }

    /// This site's bridge's liveliness token.
    pub fn liveliness(&self) -> String {
        format!("{LIVE_PREFIX}{}", self.0)
    }

    /// The site a liveliness token `key` names.
    pub fn of_liveliness(key: &str) -> Option<SiteName> {
        SiteName::new(key.strip_prefix(LIVE_PREFIX)?).ok()
    }
}

/// The name another site's device goes by on this site's network: `NAME @SITE`, which is
/// how device lists show where it is.
pub fn proxy_name(name: &str, site: &SiteName) -> String {
    format!("{name} @{site}")
}

/// The site in a name made by [`proxy_name`], if any.
pub fn site_of_name(name: &str) -> Option<SiteName> {
    let (_, site) = name.rsplit_once(" @")?;
    SiteName::new(site).ok()
}

impl fmt::Display for SiteName {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.0)
    }
}

/// Where the bridges' liveliness tokens live.
pub const LIVE_PREFIX: &str = "rove-live/";

/// Every bridge's liveliness token.
pub const ALL_LIVE: &str = "rove-live/*";

/// What a message is about.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Subject {
    /// A device's DeviceInfo.
    Info(DeviceId),
    /// A vehicle's VehicleStatus.
    Status(DeviceId),
    /// One writer's ControlCommand stream: operator `src` to vehicle `dest`, with the
    /// writer's ownership strength at the sending site.
    Command {
        /// The operator.
        src: DeviceId,
        /// The vehicle.
        dest: DeviceId,
        /// The writer's strength.
        strength: Strength,
    },
    /// A RequestControl sent by `sender` ([`RequestControl::sender_id`]).
    Request(DeviceId),
}

impl Subject {
    /// The device that speaks in this message.
    pub fn speaker(self) -> DeviceId {
        match self {
            Subject::Info(id) | Subject::Status(id) | Subject::Request(id) => id,
            Subject::Command { src, .. } => src,
        }
    }
}

/// A message's key: to whom, from whom, about what.
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub struct Key {
    /// The receiving site.
    pub to: SiteName,
    /// The sending site.
    pub from: SiteName,
    /// The subject.
    pub subject: Subject,
}

impl Key {
    /// The key as text.
    pub fn render(&self) -> String {
        let (to, from) = (&self.to, &self.from);
        match self.subject {
            Subject::Info(id) => format!("rove/{to}/{from}/info/{id}"),
            Subject::Status(id) => format!("rove/{to}/{from}/status/{id}"),
            Subject::Command {
                src,
                dest,
                strength,
            } => format!("rove/{to}/{from}/cmd/{src}/{dest}/{strength}"),
            Subject::Request(id) => format!("rove/{to}/{from}/req/{id}"),
        }
    }

    /// Reads a key; `None` for anything not rendered by [`Key::render`].
    pub fn parse(key: &str) -> Option<Key> {
        let mut parts = key.split('/');
        if parts.next()? != "rove" {
            return None;
        }
        let to = SiteName::new(parts.next()?).ok()?;
        let from = SiteName::new(parts.next()?).ok()?;
        let kind = parts.next()?;
        // Numbers as rendered only (no sign, no leading zero): one key per subject.
        fn number<T: std::str::FromStr + ToString>(part: Option<&str>) -> Option<T> {
            let part = part?;
            let n = part.parse::<T>().ok()?;
            (n.to_string() == part).then_some(n)
        }
        let mut id = || number::<DeviceId>(parts.next());
        let subject = match kind {
            "info" => Subject::Info(id()?),
            "status" => Subject::Status(id()?),
            "req" => Subject::Request(id()?),
            "cmd" => {
                let (src, dest) = (id()?, id()?);
                let strength = number::<u16>(parts.next())?;
                Subject::Command {
                    src,
                    dest,
                    strength: Strength(strength),
                }
            }
            _ => return None,
        };
        if parts.next().is_some() {
            return None;
        }
        Some(Key { to, from, subject })
    }
}

/// Another site, as this site's bridge is configured to meet it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Peer {
    /// Its name (its certificate's common name is [`SiteName::common_name`]).
    pub name: SiteName,
    /// The device ids it may speak for.
    pub ids: BTreeSet<DeviceId>,
    /// Our vehicles it may see and drive.
    pub offer: BTreeSet<DeviceId>,
    /// The highest level its operators may claim here: a stronger claim is taken at this
    /// level, with its device class and fine offset.
    pub level: Level,
}

/// Why a message from another site was not believed.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum Refusal {
    /// The key is not one [`Key::render`] makes.
    #[error("not a rove key")]
    NotAKey,
    /// A put without a payload.
    #[error("no payload")]
    NoPayload,
    /// The payload is not the key's type (or longer than [`wire::MAX_PAYLOAD`]).
    #[error("malformed {0}")]
    Malformed(&'static str),
    /// Not addressed to us.
    #[error("addressed to site {0}, not to us")]
    NotForUs(SiteName),
    /// From a site we are not configured to meet.
    #[error("site {0} is not configured here")]
    UnknownSite(SiteName),
    /// The site spoke for an id it may not.
    #[error("site {site} may not speak for device {id}")]
    NotItsId {
        /// The site.
        site: SiteName,
        /// The id.
        id: DeviceId,
    },
    /// A command or request for a vehicle of ours not offered to that site.
    #[error("vehicle {vehicle} is not offered to site {site}")]
    NotOffered {
        /// The site.
        site: SiteName,
        /// The vehicle.
        vehicle: DeviceId,
    },
    /// The payload contradicts its key.
    #[error("the payload does not match its key {0:?}")]
    Mismatch(Subject),
    /// A strength the hierarchy cannot give.
    #[error("strength {0} is outside the hierarchy")]
    Strength(Strength),
}

/// What this site's bridge believes of other sites.
#[derive(Debug, Clone)]
pub struct Policy {
    /// This site.
    pub me: SiteName,
    /// The strengths this site's vehicles believe.
    pub hierarchy: Hierarchy,
    /// The sites configured.
    pub peers: Vec<Peer>,
}

impl Policy {
    /// The configured site named `name`.
    pub fn peer(&self, name: &SiteName) -> Option<&Peer> {
        self.peers.iter().find(|p| &p.name == name)
    }

    /// The site and subject of a message under `key`, if it is for us and its site may speak
    /// for its subject's device.
    ///
    /// # Errors
    /// Why it is not believed.
    pub fn admit(&self, key: &Key) -> Result<&Peer, Refusal> {
        if key.to != self.me {
            return Err(Refusal::NotForUs(key.to.clone()));
        }
        let peer = self
            .peer(&key.from)
            .ok_or_else(|| Refusal::UnknownSite(key.from.clone()))?;
        let id = key.subject.speaker();
        if !peer.ids.contains(&id) {
            return Err(Refusal::NotItsId {
                site: peer.name.clone(),
                id,
            });
        }
        if let Subject::Command { dest, .. } = key.subject {
            peer.offered(dest)?;
        }
        Ok(peer)
    }

    /// The strength an operator of `peer` claiming `strength` drives with here: a priority
    /// writer stays one (the vehicle lets it drive only with a grant); a rank above the site's
    /// level is taken at that level.
    ///
    /// # Errors
    /// A strength the hierarchy cannot give (nor the failsafe's).
    pub fn strength(&self, peer: &Peer, strength: Strength) -> Result<Strength, Refusal> {
        if strength == Strength::PRIORITY {
            return Ok(strength);
        }
        let (level, class, offset) = self
            .hierarchy
            .rank_of(strength)
            .ok_or(Refusal::Strength(strength))?;
        if level <= peer.level {
            return Ok(strength);
        }
        self.hierarchy
            .strength(peer.level, class, offset)
            .map_err(|_| Refusal::Strength(strength))
    }

    /// A command of `peer` under `subject`, checked against its key; the strength it drives
    /// with here ([`Policy::strength`]).
    ///
    /// # Errors
    /// The payload names another source or vehicle, or the strength is not believed.
    pub fn command(
        &self,
        peer: &Peer,
        subject: Subject,
        command: &ControlCommand,
    ) -> Result<Strength, Refusal> {
        match subject {
            Subject::Command {
                src,
                dest,
                strength,
            } if command.src_id == src && command.dest_id == dest => self.strength(peer, strength),
            _ => Err(Refusal::Mismatch(subject)),
        }
    }

    /// A DeviceInfo under `subject`, checked against its key.
    ///
    /// # Errors
    /// The payload names another device, or a controller claims to be driven by another.
    pub fn info(&self, subject: Subject, info: &DeviceInfo) -> Result<(), Refusal> {
        let consistent = match info.device_type {
            DeviceType::Vehicle => true,
            DeviceType::Controller => info.controller_id == info.device_id,
        };
        match subject {
            Subject::Info(id) if id == info.device_id && consistent => Ok(()),
            _ => Err(Refusal::Mismatch(subject)),
        }
    }

    /// A RequestControl of `peer` under `subject`, checked against its key, with the
    /// requester's priority taken as a strength here ([`Policy::strength`]: auto-accept
    /// compares it with the owner's strength). Its vehicle must be one offered to that site or
    /// one of that site's own (`theirs`): whether or not this bridge has heard the vehicle yet,
    /// a site never asks for, answers for or finishes a vehicle it was not offered.
    ///
    /// # Errors
    /// The sender is not the key's, the vehicle is not offered, or the priority is not
    /// believed.
    pub fn request(
        &self,
        peer: &Peer,
        subject: Subject,
        theirs: impl Fn(DeviceId) -> bool,
        mut msg: RequestControl,
    ) -> Result<RequestControl, Refusal> {
        if subject != Subject::Request(msg.sender_id()) {
            return Err(Refusal::Mismatch(subject));
        }
        if !theirs(msg.dest_id) {
            peer.offered(msg.dest_id)?;
        }
        if msg.ack == Ack::Request {
            let claimed = u16::try_from(msg.src_priority).map_err(|_| {
                Refusal::Strength(Strength(msg.src_priority.clamp(0, 65535) as u16))
            })?;
            msg.src_priority = i32::from(self.strength(peer, Strength(claimed))?.0);
        }
        Ok(msg)
    }

    /// Whether our device `info` is shown to `peer`: a vehicle only if offered to it; an
    /// operator always (a remote requester must hear its answer from our operators).
    pub fn shows(&self, peer: &Peer, info: &DeviceInfo) -> bool {
        match info.device_type {
            DeviceType::Vehicle => peer.offer.contains(&info.device_id),
            DeviceType::Controller => true,
        }
    }
}

impl Peer {
    /// Whether our vehicle `vehicle` is offered to this site.
    ///
    /// # Errors
    /// It is not.
    pub fn offered(&self, vehicle: DeviceId) -> Result<(), Refusal> {
        if self.offer.contains(&vehicle) {
            Ok(())
        } else {
            Err(Refusal::NotOffered {
                site: self.name.clone(),
                vehicle,
            })
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::hierarchy::DeviceClass;
    use crate::msg::{CommandType, Mode, MovementCommand, TimeT};
    use proptest::prelude::*;

    pub(super) fn site(name: &str) -> SiteName {
        SiteName::new(name).unwrap_or_else(|e| panic!("{name}: {e}"))
    }

    /// The lab: home may speak for its operators 21 and 22 and its vehicle 500, and drive our
    /// vehicle 100, as remote operators at most.
    pub(super) fn policy() -> Policy {
        Policy {
            me: site("lab"),
            hierarchy: Hierarchy::STANDARD,
            peers: vec![Peer {
                name: site("home"),
                ids: [21, 22, 500].into(),
                offer: [100].into(),
                level: Level::Remote,
            }],
        }
    }

    pub(super) fn command(src: DeviceId, dest: DeviceId) -> ControlCommand {
        ControlCommand {
            src_id: src,
            dest_id: dest,
            command_type: CommandType::Movement,
            movement_command: MovementCommand::CENTRED,
            mode: Mode::Manual,
            timestamp: TimeT(0),
        }
    }

    fn key(from: &str, subject: Subject) -> Key {
        Key {
            to: site("lab"),
            from: site(from),
            subject,
        }
    }

    #[test]
    fn site_names_are_key_segments_and_nothing_else() {
        for good in ["a", "lab-2", "x".repeat(32).as_str()] {
            assert!(SiteName::new(good).is_ok(), "{good}");
        }
        for bad in [
            "",
            "Lab",
            "a/b",
            "a*",
            "-a",
            "é",
            "x".repeat(33).as_str(),
            "a b",
        ] {
            assert!(SiteName::new(bad).is_err(), "{bad}");
        }
        assert_eq!(site("home").common_name(), "rove-site-home");
        assert_eq!(
            SiteName::of_liveliness("rove-live/home"),
            Some(site("home"))
        );
        assert_eq!(SiteName::of_liveliness("rove/live/home"), None);
        let named = proxy_name("op 21", &site("home"));
        assert_eq!(named, "op 21 @home");
        assert_eq!(site_of_name(&named), Some(site("home")));
        assert_eq!(site_of_name("op21"), None);
        assert_eq!(site_of_name("a @Home"), None);
    }

    #[test]
    fn a_site_speaks_only_for_its_ids_and_drives_only_what_it_was_offered() {
        let p = policy();
        let cmd = |src, dest| {
            key(
                "home",
                Subject::Command {
                    src,
                    dest,
                    strength: Strength(120),
                },
            )
        };
        assert!(p.admit(&cmd(21, 100)).is_ok());
        assert!(matches!(
            p.admit(&cmd(31, 100)),
            Err(Refusal::NotItsId { id: 31, .. })
        ));
        assert!(matches!(
            p.admit(&cmd(21, 101)),
            Err(Refusal::NotOffered { vehicle: 101, .. })
        ));
        assert!(matches!(
            p.admit(&key("attic", Subject::Info(21))),
            Err(Refusal::UnknownSite(_))
        ));
        let mut elsewhere = key("home", Subject::Info(21));
        elsewhere.to = site("home");
        assert!(matches!(p.admit(&elsewhere), Err(Refusal::NotForUs(_))));
        // The payload must say what its key says.
        let peer = &p.peers[0];
        let subject = cmd(21, 100).subject;
        assert!(p.command(peer, subject, &command(21, 100)).is_ok());
        assert!(p.command(peer, subject, &command(22, 100)).is_err());
        assert!(p.command(peer, subject, &command(21, 101)).is_err());
    }

    #[test]
    fn a_stronger_claim_than_the_site_may_make_is_taken_at_its_level() {
        let p = policy();
        let peer = &p.peers[0];
        let h = Hierarchy::STANDARD;
        let rank = |level| h.strength(level, DeviceClass::Phone, 3).ok();
        let (mobile_phone, remote_phone) = (rank(Level::Mobile), rank(Level::Remote));
        let taken = mobile_phone.map(|s| p.strength(peer, s));
        assert_eq!(taken, remote_phone.map(Ok));
        let remote_laptop = h.base(Level::Remote, DeviceClass::Laptop);
        assert_eq!(p.strength(peer, remote_laptop), Ok(remote_laptop));
        assert_eq!(p.strength(peer, Strength::PRIORITY), Ok(Strength::PRIORITY));
        assert!(p.strength(peer, Strength(5)).is_err());
        assert!(p.strength(peer, Strength::FAILSAFE).is_err());
        // And a requester's priority the same way.
        let request = RequestControl {
            src_id: 21,
            dest_id: 100,
            current_controller_id: 31,
            src_priority: 340,
            ack: Ack::Request,
            timestamp: TimeT(1),
        };
        let theirs = |_| false;
        let taken = p.request(peer, Subject::Request(21), theirs, request);
        assert_eq!(taken.map(|m| m.src_priority), Ok(140));
        // A vehicle not offered is refused whether or not it is known here, at every stage.
        let mut stranger = request;
        stranger.dest_id = 101;
        for ack in [Ack::Request, Ack::Finish, Ack::Accept, Ack::Refuse] {
            stranger.ack = ack;
            let speaker = Subject::Request(stranger.sender_id());
            let refused = p.request(peer, speaker, theirs, stranger);
            assert!(
                matches!(refused, Err(Refusal::NotOffered { .. })),
                "{ack:?}"
            );
        }
        // Unless it is the site's own vehicle (a lab operator asking home for it).
        stranger.ack = Ack::Request;
        assert!(
            p.request(peer, Subject::Request(21), |v| v == 101, stranger)
                .is_ok()
        );
        // An answer is spoken by the owner asked, not by the requester.
        let mut accept = request;
        accept.ack = Ack::Accept;
        assert!(
            p.request(peer, Subject::Request(21), theirs, accept)
                .is_err()
        );
        accept.current_controller_id = 22;
        assert!(
            p.request(peer, Subject::Request(22), theirs, accept)
                .is_ok()
        );
    }

    #[test]
    fn only_offered_vehicles_are_shown_and_a_controller_names_itself() {
        let p = policy();
        let peer = &p.peers[0];
        let info = |id, kind, controller| DeviceInfo {
            device_id: id,
            name: String::new(),
            device_type: kind,
            controller_id: controller,
        };
        assert!(p.shows(peer, &info(100, DeviceType::Vehicle, 100)));
        assert!(!p.shows(peer, &info(101, DeviceType::Vehicle, 101)));
        assert!(p.shows(peer, &info(31, DeviceType::Controller, 31)));
        let subject = Subject::Info(21);
        assert!(
            p.info(subject, &info(21, DeviceType::Controller, 21))
                .is_ok()
        );
        assert!(
            p.info(subject, &info(21, DeviceType::Controller, 22))
                .is_err()
        );
        assert!(
            p.info(subject, &info(22, DeviceType::Controller, 22))
                .is_err()
        );
    }

    fn subjects() -> impl Strategy<Value = Subject> {
        let id = any::<DeviceId>();
        prop_oneof![
            id.prop_map(Subject::Info),
            id.prop_map(Subject::Status),
            id.prop_map(Subject::Request),
            (id, id, any::<u16>()).prop_map(|(src, dest, s)| Subject::Command {
                src,
                dest,
                strength: Strength(s),
            }),
        ]
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(10_000))]

        #[test]
        fn keys_read_back_as_rendered(
            to in "[a-z0-9][a-z0-9-]{0,31}",
            from in "[a-z0-9][a-z0-9-]{0,31}",
            subject in subjects(),
        ) {
            let key = Key { to: site(&to), from: site(&from), subject };
            prop_assert_eq!(Key::parse(&key.render()), Some(key));
        }

        #[test]
        fn any_text_parses_without_panic_and_only_as_what_renders_it(text in ".{0,80}") {
            if let Some(key) = Key::parse(&text) {
                prop_assert_eq!(key.render(), text);
            }
        }

        #[test]
        fn a_demoted_strength_never_exceeds_the_sites_level(s in 1u16..65535) {
            let p = policy();
            if let Ok(taken) = p.strength(&p.peers[0], Strength(s)) {
                let rank = p.hierarchy.rank_of(taken);
                prop_assert!(rank.is_some_and(|(level, ..)| level <= Level::Remote));
                prop_assert!(taken <= Strength(s));
            }
        }
    }
}
