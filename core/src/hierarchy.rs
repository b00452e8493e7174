//! The control hierarchy (docs/design.md §3): level × device class (+ fine offset) → DDS ownership
//! strength.
//!
//! | level | desktop | laptop | tablet | phone |
//! |---|---|---|---|---|
//! | mobile (near the vehicle) | 310 | 320 | 330 | 340 |
//! | stationary | 210 | 220 | 230 | 240 |
//! | remote | 110 | 120 | 130 | 140 |
//!
//! The onboard failsafe has strength 0 and a priority grant 65535; operators get 1..=65534.
//! The table is configurable, but a configured table must keep the hierarchy's order: every
//! rank (including its fine offsets 0–9) is strictly below the next rank, so that "mobile beats
//! stationary beats remote, phone beats tablet beats laptop beats desktop" holds for any offset.
//! A table that breaks this is rejected at load, naming the key.

use crate::error::{ConfigError, ConfigErrors, Error, Result};
use serde::{Deserialize, Serialize};
use std::fmt;

/// A DDS ownership strength. 0 is the vehicle's failsafe, 65535 a priority grant.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(transparent)]
pub struct Strength(pub u16);

impl Strength {
    /// The vehicle's own failsafe controller: below every operator.
    pub const FAILSAFE: Strength = Strength(0);
    /// The strength of a priority writer (PRIORITY_OS): used only by the holder of an accepted
    /// grant, above every operator.
    pub const PRIORITY: Strength = Strength(u16::MAX);

    /// True for strengths an operator's regular writer may have (1..=65534).
    pub fn is_operator(self) -> bool {
        self != Self::FAILSAFE && self != Self::PRIORITY
    }
}

impl fmt::Display for Strength {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        self.0.fmt(f)
    }
}

/// Where the operator is relative to the vehicle.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Level {
    /// Far away, over a network link.
    Remote,
    /// At a fixed station.
    Stationary,
    /// Near the vehicle, on foot: sees it, wins.
    Mobile,
}

impl Level {
    /// Weakest first.
    pub const ALL: [Level; 3] = [Level::Remote, Level::Stationary, Level::Mobile];
}

/// The operator's device: within a level the more portable device wins.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum DeviceClass {
    /// Least portable.
    Desktop,
    /// Portable.
    Laptop,
    /// More portable.
    Tablet,
    /// Most portable.
    Phone,
}

impl DeviceClass {
    /// Weakest first.
    pub const ALL: [DeviceClass; 4] = [
        DeviceClass::Desktop,
        DeviceClass::Laptop,
        DeviceClass::Tablet,
        DeviceClass::Phone,
    ];
}

/// Largest fine offset an operator config may add to its rank's base strength.
pub const MAX_OFFSET: u8 = 9;

/// One level's row of the table as written in TOML; absent keys keep the default.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LevelRow {
    /// Base strength of a desktop at this level.
    pub desktop: Option<crate::config::Int>,
    /// Base strength of a laptop at this level.
    pub laptop: Option<crate::config::Int>,
    /// Base strength of a tablet at this level.
    pub tablet: Option<crate::config::Int>,
    /// Base strength of a phone at this level.
    pub phone: Option<crate::config::Int>,
}

/// The `[hierarchy]` table as written in TOML; absent rows and keys keep the defaults.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HierarchyTable {
    /// Operators near the vehicle.
    pub mobile: Option<LevelRow>,
    /// Operators at a fixed station.
    pub stationary: Option<LevelRow>,
    /// Remote operators.
    pub remote: Option<LevelRow>,
}

/// A validated hierarchy: base strengths for each level and class, in hierarchy order.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Hierarchy {
    /// `base[level][class]`, indexed by `Level as usize` / `DeviceClass as usize` (weakest first).
    base: [[u16; 4]; 3],
}

impl Default for Hierarchy {
    fn default() -> Self {
        Hierarchy::STANDARD
    }
}

impl Hierarchy {
    /// The table of docs/design.md §3.
    pub const STANDARD: Hierarchy = Hierarchy {
        base: [
            [110, 120, 130, 140], // remote
            [210, 220, 230, 240], // stationary
            [310, 320, 330, 340], // mobile
        ],
    };

    /// Builds a hierarchy from a configured table, filling absent keys from [`Self::STANDARD`].
    ///
    /// # Errors
    /// [`Error::Config`] listing every base strength that is outside 1..=65525 (so that base +
    /// offset stays a valid operator strength) or not above the previous rank's base + 9.
    /// Keys are named relative to the table, e.g. `mobile.laptop`.
    pub fn from_table(table: &HierarchyTable) -> Result<Hierarchy> {
        // Read wide (the config integer policy) so that any value is reported with its key.
        let mut base = Self::STANDARD.base.map(|row| row.map(i64::from));
        for level in Level::ALL {
            let row = match level {
                Level::Mobile => &table.mobile,
                Level::Stationary => &table.stationary,
                Level::Remote => &table.remote,
            };
            let Some(row) = row else { continue };
            let values = [row.desktop, row.laptop, row.tablet, row.phone];
            for (class, value) in DeviceClass::ALL.iter().zip(values) {
                if let Some(v) = value {
                    base[level as usize][*class as usize] = v;
                }
            }
        }

        let max_base = Strength::PRIORITY.0 - 1 - u16::from(MAX_OFFSET);
        let mut errors = ConfigErrors::default();
        let mut previous: Option<(String, i64)> = None;
        for level in Level::ALL {
            for class in DeviceClass::ALL {
                let key = rank_key(level, class);
                let v = base[level as usize][class as usize];
                if v < 1 || v > i64::from(max_base) {
                    errors.push(ConfigError::new(
                        &key,
                        v,
                        format!(
                            "must be 1..={max_base} so that base + fine offset (0..={MAX_OFFSET}) \
                             stays between the failsafe (0) and a priority grant (65535)"
                        ),
                    ));
                }
                if let Some((prev_key, prev)) = &previous {
                    // Saturating: `prev` is any number a file holds (and was reported if out
                    // of range).
                    let min = prev.saturating_add(i64::from(MAX_OFFSET) + 1);
                    if v < min {
                        errors.push(ConfigError::new(
                            &key,
                            v,
                            format!(
                                "must be at least {min} ({prev_key} + {}) so that every {key} \
                                 outranks every {prev_key}, whatever their fine offsets",
                                u32::from(MAX_OFFSET) + 1
                            ),
                        ));
                    }
                }
                previous = Some((key, v));
            }
        }
        // Every value fits once validation passed; the placeholder is never returned.
        let base = base.map(|row| row.map(|v| u16::try_from(v).unwrap_or(1)));
        errors.into_result(Hierarchy { base })
    }

    /// The strength of an operator at `level` on a `class` device with fine `offset`.
    ///
    /// # Errors
    /// [`Error::OffsetOutOfRange`] if `offset` > 9.
    pub fn strength(&self, level: Level, class: DeviceClass, offset: u8) -> Result<Strength> {
        if offset > MAX_OFFSET {
            return Err(Error::OffsetOutOfRange { offset });
        }
        // Cannot overflow: validation keeps every base ≤ 65525.
        Ok(Strength(
            self.base[level as usize][class as usize] + u16::from(offset),
        ))
    }
}

impl Hierarchy {
    /// The base strength of `level` × `class` (fine offset 0).
    pub fn base(&self, level: Level, class: DeviceClass) -> Strength {
        Strength(self.base[level as usize][class as usize])
    }

    /// The rank and fine offset that give `strength`, if the hierarchy can give it.
    pub fn rank_of(&self, strength: Strength) -> Option<(Level, DeviceClass, u8)> {
        Level::ALL.into_iter().find_map(|level| {
            DeviceClass::ALL.into_iter().find_map(|class| {
                let offset = strength.0.checked_sub(self.base(level, class).0)?;
                let offset = u8::try_from(offset).ok().filter(|o| *o <= MAX_OFFSET)?;
                Some((level, class, offset))
            })
        })
    }
}

fn rank_key(level: Level, class: DeviceClass) -> String {
    let l = match level {
        Level::Mobile => "mobile",
        Level::Stationary => "stationary",
        Level::Remote => "remote",
    };
    let c = match class {
        DeviceClass::Desktop => "desktop",
        DeviceClass::Laptop => "laptop",
        DeviceClass::Tablet => "tablet",
        DeviceClass::Phone => "phone",
    };
    format!("{l}.{c}")
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn s(level: Level, class: DeviceClass, offset: u8) -> Strength {
        Hierarchy::STANDARD
            .strength(level, class, offset)
            .expect("valid offset")
    }

    #[test]
    fn standard_table_matches_design() {
        assert_eq!(s(Level::Mobile, DeviceClass::Phone, 0), Strength(340));
        assert_eq!(s(Level::Mobile, DeviceClass::Desktop, 0), Strength(310));
        assert_eq!(s(Level::Stationary, DeviceClass::Laptop, 0), Strength(220));
        assert_eq!(s(Level::Remote, DeviceClass::Tablet, 0), Strength(130));
        assert_eq!(s(Level::Remote, DeviceClass::Desktop, 9), Strength(119));
    }

    #[test]
    fn rank_of_inverts_strength_and_rejects_the_gaps() {
        for level in Level::ALL {
            for class in DeviceClass::ALL {
                for offset in 0..=MAX_OFFSET {
                    let strength = s(level, class, offset);
                    let rank = Hierarchy::STANDARD.rank_of(strength);
                    assert_eq!(rank, Some((level, class, offset)));
                }
            }
        }
        for gap in [0, 1, 109, 150, 209, 250, 350, 65534, 65535] {
            assert_eq!(Hierarchy::STANDARD.rank_of(Strength(gap)), None, "{gap}");
        }
    }

    #[test]
    fn standard_table_is_valid_when_written_out() {
        let table: HierarchyTable = toml::from_str(
            "mobile = { desktop = 310, laptop = 320, tablet = 330, phone = 340 }\n\
             stationary = { desktop = 210, laptop = 220, tablet = 230, phone = 240 }\n\
             remote = { desktop = 110, laptop = 120, tablet = 130, phone = 140 }",
        )
        .expect("parses");
        assert_eq!(Hierarchy::from_table(&table), Ok(Hierarchy::STANDARD));
        assert_eq!(
            Hierarchy::from_table(&HierarchyTable::default()),
            Ok(Hierarchy::STANDARD)
        );
    }

    #[test]
    fn the_largest_numbers_are_refused_not_overflowed() {
        for (key, value) in [
            ("desktop", i64::MAX),
            ("laptop", i64::MAX - 9),
            ("tablet", i64::MIN),
        ] {
            let text = format!("remote = {{ {key} = {value} }}");
            let table: HierarchyTable = toml::from_str(&text).expect("parses");
            let Err(Error::Config(errors)) = Hierarchy::from_table(&table) else {
                panic!("{text}: accepted");
            };
            let keys: Vec<&str> = errors.0.iter().map(|e| e.key.as_str()).collect();
            assert!(
                keys.contains(&format!("remote.{key}").as_str()),
                "{text}: {keys:?}"
            );
        }
    }

    #[test]
    fn rejects_offset_out_of_range() {
        assert_eq!(
            Hierarchy::STANDARD.strength(Level::Mobile, DeviceClass::Phone, 10),
            Err(Error::OffsetOutOfRange { offset: 10 })
        );
    }

    #[test]
    fn rejects_table_that_breaks_hierarchy_order_naming_key() {
        let table: HierarchyTable = toml::from_str("mobile = { laptop = 315 }").expect("parses");
        let err = Hierarchy::from_table(&table).expect_err("laptop overlaps desktop+9");
        let text = err.to_string();
        assert!(
            text.starts_with("mobile.laptop = 315: must be at least 320"),
            "{text}"
        );
    }

    #[test]
    fn rejects_strengths_reserved_for_failsafe_and_priority_and_collects_all() {
        let table: HierarchyTable =
            toml::from_str("remote = { desktop = 0 }\nmobile = { phone = 65530 }").expect("parses");
        let Err(Error::Config(errors)) = Hierarchy::from_table(&table) else {
            panic!("expected config errors");
        };
        let keys: Vec<_> = errors.0.iter().map(|e| e.key.as_str()).collect();
        assert_eq!(keys, ["remote.desktop", "mobile.phone"]);
    }

    #[test]
    fn rejects_unknown_keys() {
        assert!(toml::from_str::<HierarchyTable>("mobile = { watch = 400 }").is_err());
        assert!(toml::from_str::<HierarchyTable>("orbital = {}").is_err());
    }

    #[test]
    fn a_custom_valid_table_is_used() {
        let table: HierarchyTable = toml::from_str("mobile = { phone = 1000 }").expect("parses");
        let h = Hierarchy::from_table(&table).expect("valid");
        assert_eq!(
            h.strength(Level::Mobile, DeviceClass::Phone, 3),
            Ok(Strength(1003))
        );
    }

    fn rank() -> impl Strategy<Value = (Level, DeviceClass, u8)> {
        (
            prop::sample::select(Level::ALL.to_vec()),
            prop::sample::select(DeviceClass::ALL.to_vec()),
            0..=MAX_OFFSET,
        )
    }

    proptest! {
        /// Mobile > stationary > remote; within a level phone > tablet > laptop > desktop;
        /// the fine offset only orders operators of the same rank.
        #[test]
        fn hierarchy_order_holds_for_every_offset(a in rank(), b in rank()) {
            let (sa, sb) = (s(a.0, a.1, a.2), s(b.0, b.1, b.2));
            prop_assert!(sa.is_operator() && sb.is_operator());
            if (a.0, a.1) != (b.0, b.1) {
                prop_assert_eq!((a.0, a.1) < (b.0, b.1), sa < sb);
            } else {
                prop_assert_eq!(a.2.cmp(&b.2), sa.cmp(&sb));
            }
        }

        /// A table is accepted exactly when every rank is at least 10 above the previous one
        /// (and within range); an accepted table keeps the hierarchy's order.
        #[test]
        fn tables_validate_exactly_when_ordered(
            first in 1u16..=100,
            gaps in prop::collection::vec(1u16..=5000, 11),
            a in rank(), b in rank(),
        ) {
            let mut bases = vec![first];
            for g in &gaps {
                bases.push(bases[bases.len() - 1] + g);
            }
            let row = |i: usize| Some(LevelRow {
                desktop: Some(bases[i].into()), laptop: Some(bases[i + 1].into()),
                tablet: Some(bases[i + 2].into()), phone: Some(bases[i + 3].into()),
            });
            let table = HierarchyTable { remote: row(0), stationary: row(4), mobile: row(8) };
            let ordered = gaps.iter().all(|g| *g > u16::from(MAX_OFFSET));
            let result = Hierarchy::from_table(&table);
            prop_assert_eq!(result.is_ok(), ordered);
            if let Ok(h) = result {
                let sa = h.strength(a.0, a.1, a.2).expect("valid offset");
                let sb = h.strength(b.0, b.1, b.2).expect("valid offset");
                prop_assert!(sa.is_operator() && sb.is_operator());
                if (a.0, a.1) != (b.0, b.1) {
                    prop_assert_eq!((a.0, a.1) < (b.0, b.1), sa < sb);
                }
            }
        }
    }
}
