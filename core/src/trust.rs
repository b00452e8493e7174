//! Who may say what (docs/design.md §4b): device ids pinned to participants, and the strengths
//! a vehicle believes.
//!
//! Identity is never taken from a payload field. `src_id`, `current_controller_id` and a
//! DeviceInfo's `device_id` are *claims*; the sender is the DDS participant the sample came from.
//! [`Identities`] pins each device id to the first participant heard claiming it, and refuses
//! the claim from any other participant while the pin holds:
//! - a pin is refreshed by every message its participant sends as that id;
//! - it lapses [`TrustConfig::hold`] after the last one (a crashed device, whose participant
//!   lease rustdds only notices after ~50 s, frees its id as it leaves the device lists), or
//!   [`TrustConfig::grace`] after its participant left (a restarted process gets a new
//!   participant and takes its id back, but nobody can snatch the id the instant it is free).
//!
//! Without DDS Security the first participant to speak for an id wins it. That cannot stop a
//! rogue that speaks first or while the device is away; it stops every takeover of a device
//! that is present, which is what an operator relies on. Under security a [`Certifier`] (the
//! certificate, checked by the binding) says which participant may speak for an id, and first
//! sight no longer counts.
//!
//! [`Access`] bounds the strengths a vehicle believes: only strengths the configured hierarchy
//! can give (any level, class and fine offset), the failsafe's 0 never, a priority grant's 65535
//! only through the arbiter's grant rules; with an access list, only listed ids, each up to
//! the highest rank it may claim.

use crate::hierarchy::{DeviceClass, Hierarchy, Level, MAX_OFFSET, Strength};
use crate::msg::DeviceId;
use crate::sender::ParticipantId;
use crate::time::MonoTime;
use std::collections::BTreeMap;
use std::fmt;
use std::time::Duration;

/// How long pins hold, and how many ids are tracked.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TrustConfig {
    /// A pin lapses this long after its participant last spoke as the id: a backstop, for a
    /// participant whose loss is never reported (rove sets three DeviceInfo refreshes).
    pub hold: Duration,
    /// A pin lapses this long after its participant left the domain. Default 500 ms.
    pub grace: Duration,
    /// Most ids pinned at once: a flood of invented ids cannot grow the table beyond it; when it
    /// is full, lapsed pins make room, and a new id is refused if none has lapsed.
    pub max_ids: usize,
}

impl Default for TrustConfig {
    fn default() -> Self {
        TrustConfig {
            hold: Duration::from_secs(3),
            grace: Duration::from_millis(500),
            max_ids: 1024,
        }
    }
}

/// Why a message was not believed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Distrust {
    /// The id belongs to another participant.
    IdOfAnotherParticipant {
        /// The participant the id is pinned to.
        owner: ParticipantId,
    },
    /// The id table is full of live pins.
    TooManyIds,
    /// Under DDS Security: the participant's certificate names another device.
    NotCertified,
    /// A ControlCommand writer's strength that the hierarchy cannot give.
    StrengthOutsideHierarchy(Strength),
    /// The id is not in the vehicle's access list.
    NotAllowed,
    /// A strength above the highest rank the access list gives this id.
    AboveAccess {
        /// The strength claimed.
        claimed: Strength,
        /// The highest the id may have.
        max: Strength,
    },
    /// Under DDS Security: another site's device, shown here by this site's bridge, streams
    /// above the level its proxy certificate allows.
    AboveSite {
        /// The strength claimed.
        claimed: Strength,
        /// The highest level the certificate allows.
        level: Level,
    },
}

/// A message that was not believed: which id it claimed, who sent it, and why.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Suspect {
    /// The device id the message claimed to speak for.
    pub device: DeviceId,
    /// The participant it came from.
    pub sender: ParticipantId,
    /// Why it was not believed.
    pub why: Distrust,
}

impl fmt::Display for Suspect {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let (id, sender) = (self.device, self.sender);
        match self.why {
            Distrust::IdOfAnotherParticipant { owner } => write!(
                f,
                "participant {sender} claims device id {id}, which belongs to participant {owner}"
            ),
            Distrust::NotCertified => write!(
                f,
                "participant {sender} claims device id {id}, which its certificate does not name"
            ),
            Distrust::TooManyIds => write!(
                f,
                "participant {sender} claims device id {id}, but the id table is full"
            ),
            Distrust::StrengthOutsideHierarchy(s) => write!(
                f,
                "participant {sender} streams as device {id} at strength {s}, which the \
                 hierarchy cannot give"
            ),
            Distrust::NotAllowed => write!(
                f,
                "participant {sender} streams as device {id}, which is not in [access]"
            ),
            Distrust::AboveAccess { claimed, max } => write!(
                f,
                "participant {sender} streams as device {id} at strength {claimed}, above its \
                 [access] rank ({max} at most)"
            ),
            Distrust::AboveSite { claimed, level } => write!(
                f,
                "participant {sender} streams as another site's device {id} at strength \
                 {claimed}, above the level its proxy certificate allows ({level:?})"
            ),
        }
    }
}

/// What an authenticated participant's certificate makes it, for one device id.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Certified {
    /// Its certificate names another device (or none).
    No,
    /// It holds the device's own certificate.
    Device,
    /// It holds a site proxy certificate for the device: this site's bridge shows another
    /// site's device here (docs/remote.md), at most at `level`.
    Proxy(Level),
}

/// What a participant's certificate makes it for a device id (under DDS Security; the binding
/// derives it from the authenticated participant's GUID).
pub type Certifier = std::sync::Arc<dyn Fn(DeviceId, ParticipantId) -> Certified + Send + Sync>;

#[derive(Debug, Clone, Copy)]
struct Pin {
    participant: ParticipantId,
    until: MonoTime,
}

/// Device ids pinned to participants; see the module docs.
#[derive(Clone)]
pub struct Identities {
    config: TrustConfig,
    pins: BTreeMap<DeviceId, Pin>,
    certifier: Option<Certifier>,
}

impl fmt::Debug for Identities {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Identities")
            .field("config", &self.config)
            .field("pins", &self.pins)
            .field("certified", &self.certifier.is_some())
            .finish()
    }
}

impl Identities {
    /// An empty table.
    pub fn new(config: TrustConfig) -> Self {
        Identities {
            config,
            pins: BTreeMap::new(),
            certifier: None,
        }
    }

    /// From now on a participant may speak for an id only if `certifier` says it holds that
    /// id's certificate; first sight no longer counts.
    pub fn certify(&mut self, certifier: Certifier) {
        self.certifier = Some(certifier);
    }

    /// Pins `device` to `participant` for good (a node's own id): nobody else can claim it.
    pub fn pin_own(&mut self, device: DeviceId, participant: ParticipantId) {
        self.pins.insert(
            device,
            Pin {
                participant,
                until: MonoTime::MAX,
            },
        );
    }

    /// `participant` speaks as `device` at `now`: believed (and the pin refreshed, or made at
    /// first sight), or the reason it is not.
    pub fn claim(
        &mut self,
        now: MonoTime,
        device: DeviceId,
        participant: ParticipantId,
    ) -> Result<(), Distrust> {
        self.claim_level(now, device, participant).map(|_| ())
    }

    /// [`Identities::claim`], with the highest level the participant may claim for `device`:
    /// `Some` for another site's device shown by this site's bridge under a proxy certificate
    /// ([`Certified::Proxy`]), `None` for no bound beyond `[access]`.
    pub fn claim_level(
        &mut self,
        now: MonoTime,
        device: DeviceId,
        participant: ParticipantId,
    ) -> Result<Option<Level>, Distrust> {
        let until = now + self.config.hold;
        if let Some(certifier) = &self.certifier {
            let level = match certifier(device, participant) {
                Certified::No => return Err(Distrust::NotCertified),
                Certified::Device => None,
                Certified::Proxy(level) => Some(level),
            };
            // Certified: the pin follows the certificate (a restarted device takes its id back
            // at once); kept for `owner`.
            if self.pins.contains_key(&device) || self.pins.len() < self.config.max_ids {
                self.pins.insert(device, Pin { participant, until });
            }
            return Ok(level);
        }
        match self.pins.get_mut(&device) {
            Some(pin) if pin.participant == participant => {
                pin.until = pin.until.max(until);
                return Ok(None);
            }
            Some(pin) if now < pin.until => {
                return Err(Distrust::IdOfAnotherParticipant {
                    owner: pin.participant,
                });
            }
            _ => {}
        }
        if !self.pins.contains_key(&device) && self.pins.len() >= self.config.max_ids {
            self.pins.retain(|_, pin| now < pin.until);
            if self.pins.len() >= self.config.max_ids {
                return Err(Distrust::TooManyIds);
            }
        }
        self.pins.insert(device, Pin { participant, until });
        Ok(None)
    }

    /// [`Identities::claim`] as a [`Suspect`] report.
    pub fn check(
        &mut self,
        now: MonoTime,
        device: DeviceId,
        sender: ParticipantId,
    ) -> Result<(), Suspect> {
        self.claim(now, device, sender).map_err(|why| Suspect {
            device,
            sender,
            why,
        })
    }

    /// The participant `device` is pinned to at `now`, if the pin holds.
    pub fn owner(&self, now: MonoTime, device: DeviceId) -> Option<ParticipantId> {
        self.pins
            .get(&device)
            .filter(|pin| now < pin.until)
            .map(|pin| pin.participant)
    }

    /// `participant` left the domain at `now`: its pins lapse after the grace period.
    pub fn participant_gone(&mut self, now: MonoTime, participant: ParticipantId) {
        let until = now + self.config.grace;
        for pin in self.pins.values_mut() {
            if pin.participant == participant {
                pin.until = pin.until.min(until);
            }
        }
    }

    /// The ids pinned to `participant` at `now` (the devices it speaks for).
    pub fn ids_of(&self, now: MonoTime, participant: ParticipantId) -> Vec<DeviceId> {
        (self.pins.iter())
            .filter(|(_, pin)| pin.participant == participant && now < pin.until)
            .map(|(&id, _)| id)
            .collect()
    }

    /// How many ids are pinned (lapsed pins included until they are replaced or evicted).
    pub fn len(&self) -> usize {
        self.pins.len()
    }

    /// True when no id is pinned.
    pub fn is_empty(&self) -> bool {
        self.pins.is_empty()
    }
}

/// One entry of a vehicle's access list: an operator id and the highest rank it may claim
/// (`[[access.operators]]` in a vehicle's config).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Grant {
    /// The operator's device id.
    pub id: DeviceId,
    /// The highest level it may claim.
    pub level: Level,
    /// The highest device class it may claim at that level.
    pub device_class: DeviceClass,
}

impl Grant {
    /// Operator `id` may claim up to `level` and `device_class`.
    pub const fn new(id: DeviceId, level: Level, device_class: DeviceClass) -> Grant {
        Grant {
            id,
            level,
            device_class,
        }
    }
}

/// The strengths a vehicle believes; see the module docs.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct Access {
    hierarchy: Hierarchy,
    /// `None`: every id inside the hierarchy (no `[access]`).
    allowed: Option<BTreeMap<DeviceId, Strength>>,
}

impl Access {
    /// Every id may drive at any strength `hierarchy` can give.
    pub fn open(hierarchy: Hierarchy) -> Self {
        Access {
            hierarchy,
            allowed: None,
        }
    }

    /// Only the listed ids may drive, each up to its rank (with the largest fine offset).
    pub fn listed(hierarchy: Hierarchy, grants: &[Grant]) -> Self {
        let allowed = grants
            .iter()
            .map(|g| {
                let max = hierarchy.base(g.level, g.device_class).0 + u16::from(MAX_OFFSET);
                (g.id, Strength(max))
            })
            .collect();
        Access {
            hierarchy,
            allowed: Some(allowed),
        }
    }

    /// The hierarchy strengths are judged by.
    pub fn hierarchy(&self) -> &Hierarchy {
        &self.hierarchy
    }

    /// True when any id inside the hierarchy may drive (no access list).
    pub fn is_open(&self) -> bool {
        self.allowed.is_none()
    }

    /// Whether `device` may drive at all.
    pub fn allows(&self, device: DeviceId) -> Result<(), Distrust> {
        match &self.allowed {
            Some(list) if !list.contains_key(&device) => Err(Distrust::NotAllowed),
            _ => Ok(()),
        }
    }

    /// Whether a ControlCommand writer at `strength` may speak for `device`. The priority
    /// strength passes here: the arbiter lets it drive only while `device` holds a grant.
    pub fn check_strength(&self, device: DeviceId, strength: Strength) -> Result<(), Distrust> {
        self.allows(device)?;
        if strength == Strength::PRIORITY {
            return Ok(());
        }
        if self.hierarchy.rank_of(strength).is_none() {
            return Err(Distrust::StrengthOutsideHierarchy(strength));
        }
        match self.allowed.as_ref().and_then(|list| list.get(&device)) {
            Some(&max) if strength > max => Err(Distrust::AboveAccess {
                claimed: strength,
                max,
            }),
            _ => Ok(()),
        }
    }

    /// Whether `strength` stays within `level` (a priority grant's strength always does: the
    /// arbiter lets it drive only while the id holds a grant).
    pub fn within_level(&self, strength: Strength, level: Level) -> bool {
        strength == Strength::PRIORITY
            || (self.hierarchy.rank_of(strength)).is_some_and(|(at, _, _)| at <= level)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const A: ParticipantId = ParticipantId(0xa);
    const B: ParticipantId = ParticipantId(0xb);

    fn at(ms: u64) -> MonoTime {
        MonoTime::from_millis(ms)
    }

    fn ids() -> Identities {
        Identities::new(TrustConfig {
            hold: Duration::from_secs(3),
            grace: Duration::from_millis(500),
            max_ids: 4,
        })
    }

    #[test]
    fn first_participant_to_speak_for_an_id_owns_it_while_it_speaks() {
        let mut ids = ids();
        assert_eq!(ids.claim(at(0), 11, A), Ok(()));
        assert_eq!(
            ids.claim(at(10), 11, B),
            Err(Distrust::IdOfAnotherParticipant { owner: A })
        );
        // A keeps speaking: the pin never lapses.
        for t in (1000..=9000).step_by(1000) {
            assert_eq!(ids.claim(at(t), 11, A), Ok(()));
            assert!(ids.claim(at(t + 500), 11, B).is_err());
        }
        assert_eq!(ids.owner(at(9000), 11), Some(A));
    }

    #[test]
    fn a_silent_pin_lapses_after_hold_and_a_departed_one_after_grace() {
        let mut ids = ids();
        ids.claim(at(0), 11, A).expect("first sight");
        assert!(ids.claim(at(2999), 11, B).is_err());
        assert_eq!(ids.claim(at(3000), 11, B), Ok(()));
        assert_eq!(ids.owner(at(3000), 11), Some(B));

        ids.claim(at(4000), 12, A).expect("first sight");
        ids.participant_gone(at(4100), A);
        assert!(ids.claim(at(4599), 12, B).is_err());
        assert_eq!(ids.claim(at(4600), 12, B), Ok(()));
    }

    #[test]
    fn the_ids_of_a_participant_are_those_pinned_to_it_while_the_pins_hold() {
        let mut ids = ids();
        ids.claim(at(0), 11, A).expect("first sight");
        ids.claim(at(0), 12, A).expect("first sight");
        ids.claim(at(0), 13, B).expect("first sight");
        assert_eq!(ids.ids_of(at(1), A), vec![11, 12]);
        assert_eq!(ids.ids_of(at(1), B), vec![13]);
        // B takes 12 once A's pin lapsed; A no longer speaks for it.
        ids.claim(at(2000), 11, A).expect("A's own");
        ids.claim(at(2000), 13, B).expect("B's own");
        ids.claim(at(3000), 12, B).expect("lapsed");
        assert_eq!(ids.ids_of(at(3000), A), vec![11]);
        assert_eq!(ids.ids_of(at(3000), B), vec![12, 13]);
        ids.participant_gone(at(3000), A);
        assert_eq!(
            ids.ids_of(at(3500), A),
            Vec::<DeviceId>::new(),
            "gone after the grace"
        );
    }

    #[test]
    fn own_id_is_never_given_away() {
        let mut ids = ids();
        ids.pin_own(100, A);
        ids.participant_gone(at(0), B);
        assert!(ids.claim(at(1_000_000), 100, B).is_err());
        // Leaving lapses even our own pin: a node that left has no id.
        ids.participant_gone(at(1_000_000), A);
        assert_eq!(ids.claim(at(1_000_500), 100, B), Ok(()));
    }

    #[test]
    fn under_a_certifier_only_the_certified_participant_speaks_for_an_id() {
        let mut ids = ids();
        ids.certify(std::sync::Arc::new(|device, p| match (device, p) {
            (11, A) | (12, B) => Certified::Device,
            _ => Certified::No,
        }));
        assert_eq!(
            ids.claim(at(0), 11, B),
            Err(Distrust::NotCertified),
            "first sight is no proof"
        );
        assert_eq!(ids.claim(at(1), 11, A), Ok(()));
        assert_eq!(ids.claim(at(2), 12, A), Err(Distrust::NotCertified));
        assert_eq!(ids.claim(at(3), 12, B), Ok(()));
        assert_eq!(ids.owner(at(3), 11), Some(A));
    }

    #[test]
    fn a_proxy_certificate_speaks_for_its_id_with_its_level() {
        let mut ids = ids();
        ids.certify(std::sync::Arc::new(|device, p| match (device, p) {
            (21, A) => Certified::Proxy(Level::Remote),
            (12, B) => Certified::Device,
            _ => Certified::No,
        }));
        assert_eq!(ids.claim_level(at(0), 21, A), Ok(Some(Level::Remote)));
        assert_eq!(ids.claim_level(at(0), 12, B), Ok(None));
        assert_eq!(ids.claim_level(at(0), 21, B), Err(Distrust::NotCertified));
        assert_eq!(ids.owner(at(1), 21), Some(A));
    }

    #[test]
    fn within_a_level_means_at_or_below_it_and_priority_always() {
        let h = Hierarchy::STANDARD;
        let access = Access::open(h.clone());
        for level in Level::ALL {
            for class in DeviceClass::ALL {
                for at in Level::ALL {
                    let s = h.base(at, class);
                    assert_eq!(
                        access.within_level(s, level),
                        at <= level,
                        "{at:?} in {level:?}"
                    );
                    let top = Strength(s.0 + u16::from(MAX_OFFSET));
                    assert_eq!(access.within_level(top, level), at <= level);
                }
            }
            assert!(access.within_level(Strength::PRIORITY, level));
            assert!(
                !access.within_level(Strength(7), level),
                "outside the hierarchy"
            );
        }
    }

    #[test]
    fn a_full_table_evicts_lapsed_pins_and_refuses_when_all_hold() {
        let mut ids = ids();
        for id in 1..=4 {
            ids.claim(at(0), id, A).expect("room");
        }
        assert_eq!(ids.claim(at(100), 5, B), Err(Distrust::TooManyIds));
        // Known ids are still believed when the table is full.
        assert_eq!(ids.claim(at(100), 1, A), Ok(()));
        assert_eq!(ids.claim(at(3000), 5, B), Ok(()));
        assert!(ids.len() <= 4);
        assert_eq!(ids.owner(at(3000), 1), Some(A), "refreshed at 100 ms");
    }

    #[test]
    fn open_access_takes_every_hierarchy_strength_and_nothing_else() {
        let access = Access::open(Hierarchy::STANDARD);
        for s in [110, 119, 220, 229, 349, 65535] {
            assert_eq!(access.check_strength(11, Strength(s)), Ok(()), "{s}");
        }
        for s in [1, 109, 150, 350, 65534] {
            assert_eq!(
                access.check_strength(11, Strength(s)),
                Err(Distrust::StrengthOutsideHierarchy(Strength(s)))
            );
        }
    }

    #[test]
    fn an_access_list_limits_ids_and_their_rank() {
        let access = Access::listed(
            Hierarchy::STANDARD,
            &[Grant {
                id: 11,
                level: Level::Stationary,
                device_class: DeviceClass::Laptop,
            }],
        );
        assert!(!access.is_open());
        assert_eq!(access.check_strength(11, Strength(229)), Ok(()));
        assert_eq!(access.check_strength(11, Strength(110)), Ok(()));
        assert_eq!(access.check_strength(11, Strength::PRIORITY), Ok(()));
        assert_eq!(
            access.check_strength(11, Strength(240)),
            Err(Distrust::AboveAccess {
                claimed: Strength(240),
                max: Strength(229)
            })
        );
        assert_eq!(
            access.check_strength(12, Strength(110)),
            Err(Distrust::NotAllowed)
        );
        assert_eq!(access.allows(12), Err(Distrust::NotAllowed));
    }
}
