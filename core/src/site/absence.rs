//! When another site's devices leave after its link goes: not at once, but when the site has
//! stayed away for a grace period.
//!
//! A link that drops and comes back within milliseconds (a TLS session that failed and was
//! opened again) is not a site that left. Dropping every proxy of that site at once would take
//! each of its devices off this site and make it again a moment later: every vehicle would see
//! those participants leave and join, and a bridge would make a participant per device again.
//! Safety never waits for the grace: a silent stream is not live after the vehicle's command
//! timeout, so a remote owner stops driving within 100 ms of the cut either way.
//!
//! Pure: the caller passes `now` ([`MonoTime`]).

use super::SiteName;
use crate::time::MonoTime;
use std::collections::BTreeMap;
use std::time::Duration;

/// How long a site whose link went may stay away before its devices leave: as long as a
/// participant that lost its link stays on the device lists (its SPDP lease, 1 s).
pub const GRACE: Duration = Duration::from_secs(1);

/// The sites away, each with the instant its devices leave.
#[derive(Debug, Clone, Default)]
pub struct Absences {
    leave_at: BTreeMap<SiteName, MonoTime>,
}

impl Absences {
    /// No site away.
    pub fn new() -> Absences {
        Absences::default()
    }

    /// `site`'s link went at `now`: its devices leave at `now + GRACE` unless it is back before.
    /// A site already away keeps its first deadline (a link that keeps failing does not put
    /// the leaving off).
    pub fn went(&mut self, site: &SiteName, now: MonoTime) {
        self.leave_at.entry(site.clone()).or_insert(now + GRACE);
    }

    /// `site` is up: whether it was away (its devices stayed).
    pub fn came(&mut self, site: &SiteName) -> bool {
        self.leave_at.remove(site).is_some()
    }

    /// The sites away for the whole grace at `now`: their devices leave. Each is given once.
    pub fn due(&mut self, now: MonoTime) -> Vec<SiteName> {
        let due: Vec<SiteName> = (self.leave_at.iter())
            .filter(|(_, at)| **at <= now)
            .map(|(site, _)| site.clone())
            .collect();
        for site in &due {
            self.leave_at.remove(site);
        }
        due
    }

    /// How many sites are away.
    pub fn len(&self) -> usize {
        self.leave_at.len()
    }

    /// Whether no site is away.
    pub fn is_empty(&self) -> bool {
        self.leave_at.is_empty()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn site(name: &str) -> SiteName {
        SiteName::new(name).expect("a valid site name")
    }

    fn ms(t: u64) -> MonoTime {
        MonoTime::from_millis(t)
    }

    #[test]
    fn a_site_back_within_the_grace_keeps_its_devices() {
        let mut away = Absences::new();
        away.went(&site("lab"), ms(100));
        assert!(away.due(ms(120)).is_empty());
        assert!(away.came(&site("lab")), "it was away");
        assert!(away.due(ms(100_000)).is_empty(), "nothing left to leave");
        assert!(!away.came(&site("lab")), "a site up twice was away once");
    }

    #[test]
    fn a_site_away_for_the_grace_leaves_once() {
        let mut away = Absences::new();
        away.went(&site("lab"), ms(100));
        away.went(&site("home"), ms(600));
        assert!(away.due(ms(1_099)).is_empty());
        assert_eq!(away.due(ms(1_100)), vec![site("lab")]);
        assert_eq!(away.due(ms(1_200)), Vec::<SiteName>::new());
        assert_eq!(away.len(), 1);
        assert_eq!(away.due(ms(5_000)), vec![site("home")]);
        assert!(away.is_empty());
    }

    #[test]
    fn a_link_that_keeps_failing_does_not_put_the_leaving_off() {
        let mut away = Absences::new();
        away.went(&site("lab"), ms(0));
        away.went(&site("lab"), ms(900));
        assert_eq!(away.due(ms(1_000)), vec![site("lab")]);
    }

    #[derive(Debug, Clone)]
    enum Step {
        Went(u8),
        Came(u8),
        Wait(u16),
    }

    fn step() -> impl Strategy<Value = Step> {
        prop_oneof![
            (0u8..3).prop_map(Step::Went),
            (0u8..3).prop_map(Step::Came),
            (0u16..1500).prop_map(Step::Wait),
        ]
    }

    proptest! {
        /// Against a model that remembers when each site last went up or down: a site is due
        /// exactly when it has been down, without coming up, for the grace since it first went.
        #[test]
        fn a_site_leaves_exactly_when_it_stayed_away_for_the_grace(
            steps in proptest::collection::vec(step(), 0..60)
        ) {
            let names = [site("a"), site("b"), site("c")];
            let mut away = Absences::new();
            let mut first_down: [Option<u64>; 3] = [None; 3];
            let mut now = 0u64;
            for s in steps {
                match s {
                    Step::Went(i) => {
                        let i = usize::from(i);
                        away.went(&names[i], ms(now));
                        first_down[i].get_or_insert(now);
                    }
                    Step::Came(i) => {
                        let i = usize::from(i);
                        prop_assert_eq!(away.came(&names[i]), first_down[i].is_some());
                        first_down[i] = None;
                    }
                    Step::Wait(d) => now += u64::from(d),
                }
                let grace = GRACE.as_millis() as u64;
                let expected: Vec<SiteName> = (0..3)
                    .filter(|&i| first_down[i].is_some_and(|t| now >= t + grace))
                    .map(|i| names[i].clone())
                    .collect();
                for down in &mut first_down {
                    if down.is_some_and(|t| now >= t + grace) {
                        *down = None;
                    }
                }
                prop_assert_eq!(away.due(ms(now)), expected);
                prop_assert_eq!(away.len(), first_down.iter().flatten().count());
            }
        }
    }
}
