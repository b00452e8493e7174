//! What the session does with each vehicle: one [`Role`] per vehicle (module docs of
//! [`super`], "Roles").

use crate::msg::DeviceId;
use std::collections::BTreeMap;

/// What this operator does with one vehicle. A vehicle it has nothing to do with has no role.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Role {
    /// Ours on the regular writer: driven while the input is live, paused (released, and driven
    /// again once the input is live) while it is not.
    Driving {
        /// We also hold a grant for it and drive it with the priority writer.
        grant: bool,
    },
    /// Yielded to a grant holder (the handover machine's `Yielded`): never driven on the regular
    /// writer until the grant is over or a `drive` command takes it back.
    Yielded {
        /// PROBEs on the regular writer keep us the vehicle's fallback (the standby).
        standby: bool,
        /// We hold a grant for it ourselves (we asked the holder for it back).
        grant: bool,
    },
    /// Only a grant: driven with the priority writer.
    Granted,
}

impl Role {
    /// Whether we hold a grant for the vehicle.
    fn grant(self) -> bool {
        match self {
            Role::Driving { grant } | Role::Yielded { grant, .. } => grant,
            Role::Granted => true,
        }
    }
}

/// The role of every vehicle the session has something to do with, by id (so every list
/// drawn from it is in id order).
#[derive(Debug, Clone, Default)]
pub(super) struct Roles(BTreeMap<DeviceId, Role>);

impl Roles {
    /// `vehicles` driven (the configured ones, at start).
    pub(super) fn driving(vehicles: &[DeviceId]) -> Self {
        let role = Role::Driving { grant: false };
        Roles(vehicles.iter().map(|&v| (v, role)).collect())
    }

    /// Whether `vehicle` has a role at all.
    pub(super) fn has(&self, vehicle: DeviceId) -> bool {
        self.0.contains_key(&vehicle)
    }

    /// Whether `vehicle` is ours on the regular writer (driven or paused).
    pub(super) fn is_driving(&self, vehicle: DeviceId) -> bool {
        matches!(self.0.get(&vehicle), Some(Role::Driving { .. }))
    }

    /// Whether we hold a grant for `vehicle`.
    pub(super) fn holds_grant(&self, vehicle: DeviceId) -> bool {
        self.0.get(&vehicle).is_some_and(|r| r.grant())
    }

    /// The vehicles ours on the regular writer (driven or paused).
    pub(super) fn driving_ones(&self) -> impl Iterator<Item = DeviceId> + '_ {
        self.select(|r| matches!(r, Role::Driving { .. }))
    }

    /// The vehicles we hold a grant for.
    pub(super) fn granted(&self) -> impl Iterator<Item = DeviceId> + '_ {
        self.select(Role::grant)
    }

    /// The vehicles we stand by for (PROBEs).
    pub(super) fn standing_by(&self) -> impl Iterator<Item = DeviceId> + '_ {
        self.select(|r| matches!(r, Role::Yielded { standby: true, .. }))
    }

    fn select(&self, keep: fn(Role) -> bool) -> impl Iterator<Item = DeviceId> + '_ {
        (self.0.iter())
            .filter(move |(_, r)| keep(**r))
            .map(|(v, _)| *v)
    }

    /// Makes `vehicle` ours on the regular writer (in place of a yield, which the caller has
    /// ended); a grant stays.
    pub(super) fn drive(&mut self, vehicle: DeviceId) {
        let grant = self.holds_grant(vehicle);
        self.0.insert(vehicle, Role::Driving { grant });
    }

    /// `vehicle` is no longer ours on the regular writer; a grant stays. Whether it was.
    pub(super) fn stop_driving(&mut self, vehicle: DeviceId) -> bool {
        let Some(Role::Driving { grant }) = self.0.get(&vehicle).copied() else {
            return false;
        };
        self.only_grant(vehicle, grant);
        true
    }

    /// Every vehicle ours on the regular writer is no longer (grants stay): the ones that were.
    pub(super) fn stop_driving_all(&mut self) -> Vec<DeviceId> {
        let driving: Vec<DeviceId> = self.driving_ones().collect();
        for &v in &driving {
            self.stop_driving(v);
        }
        driving
    }

    /// We hold a grant for `vehicle` (`true`) or no longer do; its other role stays.
    pub(super) fn set_grant(&mut self, vehicle: DeviceId, grant: bool) {
        match self.0.get_mut(&vehicle) {
            Some(Role::Driving { grant: held } | Role::Yielded { grant: held, .. }) => {
                *held = grant;
            }
            Some(Role::Granted) | None => self.only_grant(vehicle, grant),
        }
    }

    /// We yielded `vehicle` to a grant holder, standing by for it or not; a grant stays.
    pub(super) fn yield_to_holder(&mut self, vehicle: DeviceId, standby: bool) {
        let grant = self.holds_grant(vehicle);
        self.0.insert(vehicle, Role::Yielded { standby, grant });
    }

    /// The standby for `vehicle` ends (it stays yielded).
    pub(super) fn end_standby(&mut self, vehicle: DeviceId) {
        if let Some(Role::Yielded { standby, .. }) = self.0.get_mut(&vehicle) {
            *standby = false;
        }
    }

    /// Every standby ends (the vehicles stay yielded): the vehicles stood by for.
    pub(super) fn end_standby_all(&mut self) -> Vec<DeviceId> {
        let standby: Vec<DeviceId> = self.standing_by().collect();
        for &v in &standby {
            self.end_standby(v);
        }
        standby
    }

    /// `vehicle` is no longer yielded (a grant stays). `None` if it was not; else whether we
    /// stood by for it.
    pub(super) fn end_yield(&mut self, vehicle: DeviceId) -> Option<bool> {
        let Some(Role::Yielded { standby, grant }) = self.0.get(&vehicle).copied() else {
            return None;
        };
        self.only_grant(vehicle, grant);
        Some(standby)
    }

    /// `vehicle` keeps only its grant, if `grant`; else it has no role.
    fn only_grant(&mut self, vehicle: DeviceId, grant: bool) {
        if grant {
            self.0.insert(vehicle, Role::Granted);
        } else {
            self.0.remove(&vehicle);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const V: DeviceId = 100;

    fn role(roles: &Roles) -> Option<Role> {
        roles.0.get(&V).copied()
    }

    #[test]
    fn a_grant_comes_and_goes_beside_the_regular_part() {
        let mut roles = Roles::driving(&[V]);
        roles.set_grant(V, true);
        assert_eq!(role(&roles), Some(Role::Driving { grant: true }));
        assert!(roles.stop_driving(V));
        assert_eq!(role(&roles), Some(Role::Granted));
        roles.yield_to_holder(V, true);
        assert_eq!(
            role(&roles),
            Some(Role::Yielded {
                standby: true,
                grant: true
            })
        );
        roles.set_grant(V, false);
        assert_eq!(
            role(&roles),
            Some(Role::Yielded {
                standby: true,
                grant: false
            })
        );
        assert_eq!(roles.end_yield(V), Some(true));
        assert_eq!(role(&roles), None, "nothing left: no role");
        assert_eq!(roles.end_yield(V), None);
        assert!(!roles.stop_driving(V));
    }

    #[test]
    fn a_standby_ends_but_the_yield_stays() {
        let mut roles = Roles::default();
        roles.yield_to_holder(V, true);
        roles.yield_to_holder(101, false);
        assert_eq!(roles.end_standby_all(), vec![V]);
        assert_eq!(roles.standing_by().count(), 0);
        assert_eq!(roles.end_yield(V), Some(false));
        assert!(roles.has(101) && !roles.has(V));
    }

    #[test]
    fn lists_are_in_id_order_and_a_driven_holder_is_in_both() {
        let mut roles = Roles::driving(&[102, 100]);
        roles.set_grant(101, true);
        roles.set_grant(102, true);
        assert_eq!(roles.driving_ones().collect::<Vec<_>>(), vec![100, 102]);
        assert_eq!(roles.granted().collect::<Vec<_>>(), vec![101, 102]);
        assert_eq!(roles.stop_driving_all(), vec![100, 102]);
        assert_eq!(roles.granted().collect::<Vec<_>>(), vec![101, 102]);
        assert!(!roles.has(100));
    }
}
