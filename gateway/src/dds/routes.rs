//! Per-vehicle routing of ControlCommand: each vehicle's commands travel in its own DDS
//! partition, so a vehicle never receives what other vehicles' operators stream.

use rove_core::arbiter::ParticipantId;
use rove_core::msg::DeviceId;
use rustdds::policy::Partition;

/// The DDS partition a vehicle's commands travel in: `rove/vehicle/ID`. Operators write each
/// vehicle's commands there, and a vehicle reads its own partition (and the default one, for
/// peers that use none), so a vehicle never receives, nor an operator sends to it, what other
/// vehicles' operators stream (docs/design.md, "Fleet scale").
pub fn vehicle_partition(vehicle: DeviceId) -> String {
    format!("{VEHICLE_PARTITION_PREFIX}{vehicle}")
}

/// The prefix of [`vehicle_partition`]: a ControlCommand reader in a partition named so is a
/// rove vehicle's.
pub const VEHICLE_PARTITION_PREFIX: &str = "rove/vehicle/";

/// Where an operator sends a vehicle's commands.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Route {
    /// The vehicle's own partition ([`vehicle_partition`]).
    Vehicle(DeviceId),
    /// The default partition, for a vehicle whose command reader uses none (a peer built on
    /// the seed IDL alone). Every rove vehicle reads it too.
    Default,
}

/// Where each vehicle's commands go: its partition, unless discovery showed that the vehicle's
/// participant reads ControlCommand in no rove partition (a peer that knows only the seed IDL),
/// whose commands then go to the default partition. Learnt from ControlCommand readers found
/// in discovery and from the participant each vehicle's DeviceInfo comes from; both tables are
/// bounded (a vehicle beyond them is routed to its partition, as any rove vehicle).
#[derive(Debug, Default)]
pub struct Routes {
    /// Participants with a ControlCommand reader in no rove partition.
    foreign: std::collections::HashSet<ParticipantId>,
    /// The participant each vehicle's DeviceInfo came from.
    vehicles: std::collections::HashMap<DeviceId, ParticipantId>,
}

impl Routes {
    /// At most this many participants and vehicles are remembered.
    pub const MAX: usize = 1024;

    /// A ControlCommand reader of `participant` with `partition` was discovered.
    pub fn reader_found(&mut self, participant: ParticipantId, partition: Option<&Partition>) {
        let names = partition.map_or(&[][..], |p| &p.names[..]);
        if names
            .iter()
            .any(|n| n.starts_with(VEHICLE_PARTITION_PREFIX))
        {
            self.foreign.remove(&participant);
        } else if self.foreign.len() < Self::MAX {
            self.foreign.insert(participant);
        }
    }

    /// A believed DeviceInfo of vehicle `id` came from `participant`.
    pub fn vehicle_seen(&mut self, id: DeviceId, participant: ParticipantId) {
        if self.vehicles.len() < Self::MAX || self.vehicles.contains_key(&id) {
            self.vehicles.insert(id, participant);
        }
    }

    /// A participant left the domain.
    pub fn participant_gone(&mut self, participant: ParticipantId) {
        self.foreign.remove(&participant);
        self.vehicles.retain(|_, p| *p != participant);
    }

    /// Where vehicle `id`'s commands go.
    pub fn route(&self, id: DeviceId) -> Route {
        match self.vehicles.get(&id) {
            Some(p) if self.foreign.contains(p) => Route::Default,
            _ => Route::Vehicle(id),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn vehicles_are_routed_to_their_partition_unless_their_reader_knows_none() {
        let (rove, seed) = (ParticipantId(1), ParticipantId(2));
        let mut routes = Routes::default();
        assert_eq!(routes.route(7), Route::Vehicle(7), "unknown: its partition");
        let ours = Partition {
            names: vec![vehicle_partition(7), String::new()],
        };
        routes.reader_found(rove, Some(&ours));
        routes.reader_found(seed, None);
        routes.vehicle_seen(7, rove);
        routes.vehicle_seen(8, seed);
        assert_eq!(routes.route(7), Route::Vehicle(7));
        assert_eq!(routes.route(8), Route::Default);
        // An empty list is the default partition too.
        let seed2 = ParticipantId(3);
        routes.reader_found(seed2, Some(&Partition { names: vec![] }));
        routes.vehicle_seen(9, seed2);
        assert_eq!(routes.route(9), Route::Default);
        // Order does not matter: the reader may be found after the DeviceInfo.
        routes.vehicle_seen(10, ParticipantId(4));
        assert_eq!(routes.route(10), Route::Vehicle(10));
        routes.reader_found(ParticipantId(4), None);
        assert_eq!(routes.route(10), Route::Default);
        routes.participant_gone(seed);
        assert_eq!(routes.route(8), Route::Vehicle(8));
    }

    #[test]
    fn route_tables_are_bounded() {
        let mut routes = Routes::default();
        for i in 0..3 * Routes::MAX as u128 {
            routes.reader_found(ParticipantId(i), None);
            routes.vehicle_seen(i as DeviceId, ParticipantId(i));
        }
        assert_eq!(routes.foreign.len(), Routes::MAX);
        assert_eq!(routes.vehicles.len(), Routes::MAX);
        // A vehicle already known still moves.
        routes.vehicle_seen(0, ParticipantId(5000));
        assert_eq!(routes.route(0), Route::Vehicle(0));
    }

    #[test]
    fn partitions_match_as_dds_says() {
        let p = |names: &[&str]| Partition {
            names: names.iter().map(|s| s.to_string()).collect(),
        };
        let m = |w: Option<&Partition>, r: Option<&Partition>| Partition::is_match(w, r);
        let (v7, v8) = (p(&["rove/vehicle/7"]), p(&["rove/vehicle/8"]));
        let vehicle7 = p(&["rove/vehicle/7", ""]);
        assert!(m(Some(&v7), Some(&vehicle7)));
        assert!(
            !m(Some(&v8), Some(&vehicle7)),
            "another vehicle's partition"
        );
        assert!(
            m(None, Some(&vehicle7)),
            "a writer in no partition reaches the vehicle"
        );
        assert!(
            !m(Some(&v7), None),
            "a reader in no partition misses partitioned writers"
        );
        assert!(m(None, None));
        assert!(
            m(Some(&p(&[])), Some(&p(&[""]))),
            "empty list = default partition"
        );
        assert!(
            m(Some(&v7), Some(&p(&["rove/vehicle/*"]))),
            "a pattern matches names"
        );
        assert!(m(Some(&p(&["rove/?ehicle/7"])), Some(&vehicle7)));
        assert!(
            !m(Some(&p(&["rove/*"])), Some(&p(&["rove/vehicle/*"]))),
            "never two patterns"
        );
        assert!(!m(Some(&v7), Some(&p(&["rove/vehicle/7?"]))));
    }
}
