//! Where a vehicle stands for one operator, derived once from what the operator does with it
//! (its session's role) and what the vehicle publishes (DeviceInfo's owner, VehicleStatus).
//!
//! Every front end shows this and nothing else for "who drives": the terminal console's header
//! and rows, the local API's `standing` events (and through them the web page's banner and
//! list), and `rove status` (which has no role: a bystander). Pure; no clock, no I/O.

use crate::model::{ConsoleState, MyRole, VehicleView};
use rove_core::msg::{DeviceId, OutputState};

/// Where a vehicle stands, for one operator (or for a bystander: `rove status`).
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Standing {
    /// Not announced lately, or withdrawn.
    Offline,
    /// Its own failsafe owns it: outputs safe, nobody drives.
    Failsafe,
    /// An operator owns it, but its outputs are held safe.
    Held {
        /// The owner.
        owner: DeviceId,
        /// Why.
        by: Hold,
    },
    /// This operator drives it.
    Driving {
        /// Through a priority grant.
        grant: bool,
    },
    /// This operator streams to it, but a stronger operator drives it.
    Outranked {
        /// The owner.
        by: DeviceId,
    },
    /// This operator gave it to a grant holder and stays its fallback.
    Yielded {
        /// The grant holder (the owner).
        to: DeviceId,
    },
    /// This operator would drive it, but its input is not live (deadman released, device lost).
    Paused {
        /// The owner.
        owner: DeviceId,
    },
    /// Another operator drives it; this one does not take part.
    StandingBy {
        /// The owner.
        owner: DeviceId,
    },
}

/// What holds a vehicle's outputs safe while an operator owns it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Hold {
    /// The output holds them by its own decision: an autopilot refused the operator's mode.
    Autopilot,
    /// The output is down (its device is gone or does not answer). (A hung output is not
    /// safe: its outputs cannot change at all; the LINK column says so.)
    Output,
}

/// Where `vehicle` stands for the operator `me` whose role with it is `role` (`None` for both:
/// a bystander), given what the vehicle published (`view`) and whether it is `online`.
///
/// Order: an offline vehicle is offline; outputs that are safe are said first (the failsafe
/// owns it, or something holds them), since that is what the vehicle does; then the owner
/// against this operator's role. A status's `failsafe` is believed only for the owner it was
/// published under: the owner (DeviceInfo) and the status are two topics, and a takeover from
/// the failsafe must not read as "held" until the new owner's status arrives.
pub fn standing(
    vehicle: DeviceId,
    online: bool,
    view: &VehicleView,
    me: Option<DeviceId>,
    role: Option<MyRole>,
) -> Standing {
    let owner = view.owner;
    if !online {
        return Standing::Offline;
    }
    if owner == vehicle {
        return Standing::Failsafe;
    }
    if view.failsafe && view.status_owner == Some(owner) {
        let by = match view.health.held && view.output != Some(OutputState::Down) {
            true => Hold::Autopilot,
            false => Hold::Output,
        };
        return Standing::Held { owner, by };
    }
    // Paused: the release is on its way, the vehicle still names us for a moment.
    if Some(owner) == me && role != Some(MyRole::Paused) {
        return Standing::Driving {
            grant: role == Some(MyRole::Holding),
        };
    }
    match role {
        Some(MyRole::Driving | MyRole::Holding) => Standing::Outranked { by: owner },
        Some(MyRole::Standby) => Standing::Yielded { to: owner },
        Some(MyRole::Paused) => Standing::Paused { owner },
        None => Standing::StandingBy { owner },
    }
}

impl Standing {
    /// A stable name for programs (the API's `state`): `offline`, `failsafe`, `held`,
    /// `driving`, `outranked`, `yielded`, `paused`, `driven` (someone else drives it; this
    /// operator, or a bystander, takes no part — it was `standby`, which read as "nobody drives").
    pub fn kind(&self) -> &'static str {
        match self {
            Standing::Offline => "offline",
            Standing::Failsafe => "failsafe",
            Standing::Held { .. } => "held",
            Standing::Driving { .. } => "driving",
            Standing::Outranked { .. } => "outranked",
            Standing::Yielded { .. } => "yielded",
            Standing::Paused { .. } => "paused",
            Standing::StandingBy { .. } => "driven",
        }
    }

    /// The other device it names (owner, outranking operator, grant holder), if any.
    pub fn other(&self) -> Option<DeviceId> {
        match *self {
            Standing::Offline | Standing::Failsafe | Standing::Driving { .. } => None,
            Standing::Held { owner, .. }
            | Standing::Paused { owner }
            | Standing::StandingBy { owner }
            | Standing::Outranked { by: owner }
            | Standing::Yielded { to: owner } => Some(owner),
        }
    }

    /// Whether the vehicle's outputs are safe (nobody's sticks reach them).
    pub fn is_safe(&self) -> bool {
        matches!(self, Standing::Failsafe | Standing::Held { .. })
    }

    /// For people: the same words on every console, with devices named by `label` (which
    /// names this operator "you").
    pub fn text(&self, label: impl Fn(DeviceId) -> String) -> String {
        match self {
            Standing::Offline => "offline".into(),
            Standing::Failsafe => "failsafe: stopped, nobody drives".into(),
            Standing::Held { owner, by } => {
                let what = match by {
                    Hold::Autopilot => "held by autopilot",
                    Hold::Output => "held safe: output down",
                };
                format!("{what} · owner {}", label(*owner))
            }
            Standing::Driving { grant: false } => "YOU DRIVE".into(),
            Standing::Driving { grant: true } => "YOU DRIVE (grant)".into(),
            Standing::Outranked { by } => format!("outranked by {}", label(*by)),
            Standing::Yielded { to } => format!("yielded to {}", label(*to)),
            Standing::Paused { owner } => {
                format!("paused · input not live · owner {}", label(*owner))
            }
            Standing::StandingBy { owner } => format!("driven by {}", label(*owner)),
        }
    }
}

impl ConsoleState {
    /// Where `vehicle` stands for this operator; `None` if it is not a known vehicle.
    pub fn standing(&self, vehicle: DeviceId) -> Option<Standing> {
        let device = self.devices.get(&vehicle)?;
        let view = device.vehicle.as_ref()?;
        let me = self.identity.id;
        let role = self.mine.get(&vehicle).copied();
        Some(standing(vehicle, device.online, view, Some(me), role))
    }

    /// [`ConsoleState::standing`] with its words, as every console shows them.
    pub fn standing_text(&self, vehicle: DeviceId) -> Option<(Standing, String)> {
        let s = self.standing(vehicle)?;
        let text = s.text(|id| self.label(id));
        Some((s, text))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const V: DeviceId = 100;
    const ME: DeviceId = 11;
    const PHONE: DeviceId = 12;

    fn view(owner: DeviceId) -> VehicleView {
        VehicleView::new(owner)
    }

    /// Every combination of role, owner and vehicle state gives exactly one standing, and the
    /// safe states win over who owns.
    #[test]
    fn each_state_is_derived_from_role_owner_and_status() {
        let roles = [
            None,
            Some(MyRole::Driving),
            Some(MyRole::Holding),
            Some(MyRole::Standby),
            Some(MyRole::Paused),
        ];
        for role in roles {
            let s = |v: &VehicleView, online| standing(V, online, v, Some(ME), role);
            assert_eq!(s(&view(ME), false), Standing::Offline);
            assert_eq!(s(&view(V), true), Standing::Failsafe);
            let mut held = view(PHONE);
            held.failsafe = true;
            held.health.held = true;
            // A status of the previous owner's time says nothing of this one.
            held.status_owner = Some(V);
            assert_ne!(s(&held, true).kind(), "held");
            held.status_owner = Some(PHONE);
            let autopilot = Standing::Held {
                owner: PHONE,
                by: Hold::Autopilot,
            };
            assert_eq!(s(&held, true), autopilot);
            held.output = Some(OutputState::Down);
            assert_eq!(
                s(&held, true),
                Standing::Held {
                    owner: PHONE,
                    by: Hold::Output
                }
            );
            let mine = s(&view(ME), true);
            let expected = match role {
                Some(MyRole::Paused) => Standing::Paused { owner: ME },
                _ => Standing::Driving {
                    grant: role == Some(MyRole::Holding),
                },
            };
            assert_eq!(mine, expected);
            let other = s(&view(PHONE), true);
            let expected = match role {
                None => Standing::StandingBy { owner: PHONE },
                Some(MyRole::Driving | MyRole::Holding) => Standing::Outranked { by: PHONE },
                Some(MyRole::Standby) => Standing::Yielded { to: PHONE },
                Some(MyRole::Paused) => Standing::Paused { owner: PHONE },
            };
            assert_eq!(other, expected);
            assert_eq!(other.other(), Some(PHONE));
            assert!(!other.is_safe());
        }
        // A bystander (`rove status`) never drives.
        assert_eq!(
            standing(V, true, &view(ME), None, None),
            Standing::StandingBy { owner: ME }
        );
    }

    #[test]
    fn the_words_name_the_other_device() {
        let label = |id: DeviceId| format!("dev ({id})");
        assert_eq!(
            Standing::Outranked { by: PHONE }.text(label),
            "outranked by dev (12)"
        );
        let held = Standing::Held {
            owner: ME,
            by: Hold::Autopilot,
        };
        assert_eq!(held.text(label), "held by autopilot · owner dev (11)");
        assert_eq!(held.kind(), "held");
        assert!(held.is_safe());
    }

    /// Issue 49: a bystander's name for a vehicle someone drives agrees with its words.
    #[test]
    fn a_driven_vehicle_is_driven_for_a_bystander() {
        let s = standing(V, true, &view(PHONE), None, None);
        assert_eq!(s.kind(), "driven");
        assert_eq!(s.text(|id| format!("phone ({id})")), "driven by phone (12)");
    }
}
