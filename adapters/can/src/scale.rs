//! Pure: where an output's value comes from ([`Source`]: one axis, or a mix of axes for skid
//! steering) and how it becomes device units ([`Scale`] for integers, [`UnitScale`] for the
//! normalised DroneCAN servo commands).
//!
//! Both scales map −32767 → `min`, 0 → `centre`, +32767 → `max`, linearly on each half (so an
//! asymmetric range works), then clamp to `[min, max]`. `min` may be larger than `max`: that is
//! a reversed output. −32768 counts as −32767.

use rove_core::mapping::Axis;
use rove_core::msg::MovementCommand;
use std::fmt;

/// Full scale of an axis.
const FULL: f64 = i16::MAX as f64;

/// Where an output's value comes from.
#[derive(Debug, Clone, PartialEq)]
pub enum Source {
    /// One axis as it is.
    Axis(Axis),
    /// A weighted sum of axes, clamped to ±32767: the skid-steer mix is
    /// `left = throttle + roll`, `right = throttle − roll`.
    Mix(Vec<(Axis, f64)>),
}

impl Source {
    /// The source's value in `movement`, in axis units (±32767). Total: any weights, any
    /// inputs give a value in range.
    pub fn value(&self, movement: &MovementCommand) -> i16 {
        match self {
            Source::Axis(axis) => axis.of(movement).max(-i16::MAX),
            Source::Mix(terms) => {
                let sum: f64 = terms
                    .iter()
                    .map(|(axis, weight)| weight * f64::from(axis.of(movement).max(-i16::MAX)))
                    .sum();
                // NaN (from a NaN weight, which validation rejects) becomes 0 here.
                let clamped = if sum.is_nan() {
                    0.0
                } else {
                    sum.clamp(-FULL, FULL)
                };
                clamped.round() as i16
            }
        }
    }
}

impl fmt::Display for Source {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Source::Axis(axis) => write!(f, "{}", axis.name()),
            Source::Mix(terms) => {
                for (i, (axis, weight)) in terms.iter().enumerate() {
                    match (i, *weight < 0.0) {
                        (0, false) => {}
                        (0, true) => f.write_str("-")?,
                        (_, false) => f.write_str(" + ")?,
                        (_, true) => f.write_str(" - ")?,
                    }
                    let magnitude = weight.abs();
                    if magnitude != 1.0 {
                        write!(f, "{magnitude}×")?;
                    }
                    f.write_str(axis.name())?;
                }
                Ok(())
            }
        }
    }
}

/// Axis value → integer device units.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Scale {
    /// Device value at −full scale.
    pub min: i64,
    /// Device value at centre.
    pub centre: i64,
    /// Device value at +full scale.
    pub max: i64,
}

impl Scale {
    /// The device value for `axis`, rounded to the nearest unit and within `[min, max]`.
    pub fn map(&self, axis: i16) -> i64 {
        let x = f64::from(axis.max(-i16::MAX)) / FULL;
        let centre = self.centre as f64;
        let end = if x >= 0.0 { self.max } else { self.min } as f64;
        let value = (centre + x.abs() * (end - centre)).round();
        let (lo, hi) = (self.min.min(self.max), self.min.max(self.max));
        // `as` saturates; the clamp keeps rounding at the ends in range.
        (value as i64).clamp(lo, hi)
    }
}

/// Axis value → a normalised command (DroneCAN unitless servo command, −1..=1).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct UnitScale {
    /// Command at −full scale.
    pub min: f32,
    /// Command at centre.
    pub centre: f32,
    /// Command at +full scale.
    pub max: f32,
}

impl UnitScale {
    /// The command for `axis`, within `[min, max]`.
    pub fn map(&self, axis: i16) -> f32 {
        let x = f64::from(axis.max(-i16::MAX)) / FULL;
        let centre = f64::from(self.centre);
        let end = f64::from(if x >= 0.0 { self.max } else { self.min });
        let value = (centre + x.abs() * (end - centre)) as f32;
        let (lo, hi) = (self.min.min(self.max), self.min.max(self.max));
        value.clamp(lo, hi)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn movement(throttle: i16, roll: i16) -> MovementCommand {
        MovementCommand {
            throttle,
            roll,
            ..MovementCommand::CENTRED
        }
    }

    #[test]
    fn skid_steer_mix_adds_subtracts_and_clamps() {
        let left = Source::Mix(vec![(Axis::Throttle, 1.0), (Axis::Roll, 1.0)]);
        let right = Source::Mix(vec![(Axis::Throttle, 1.0), (Axis::Roll, -1.0)]);
        let m = movement(10_000, 5_000);
        assert_eq!((left.value(&m), right.value(&m)), (15_000, 5_000));
        // Full throttle and full right: left saturates, right stops.
        let m = movement(i16::MAX, i16::MAX);
        assert_eq!((left.value(&m), right.value(&m)), (i16::MAX, 0));
        // Spin in place.
        let m = movement(0, i16::MIN);
        assert_eq!((left.value(&m), right.value(&m)), (-i16::MAX, i16::MAX));
        assert_eq!(left.to_string(), "throttle + roll");
        assert_eq!(right.to_string(), "throttle - roll");
        let half = Source::Mix(vec![(Axis::Yaw, -0.5)]);
        assert_eq!(half.to_string(), "-0.5×yaw");
        assert_eq!(half.value(&MovementCommand { yaw: 1001, ..m }), -501);
    }

    #[test]
    fn scale_maps_each_half_and_reverses() {
        let s = Scale {
            min: -1000,
            centre: 0,
            max: 1000,
        };
        assert_eq!(s.map(0), 0);
        assert_eq!(s.map(i16::MAX), 1000);
        assert_eq!(s.map(i16::MIN), -1000);
        assert_eq!(s.map(16384), 500);
        let asym = Scale {
            min: 1000,
            centre: 1400,
            max: 2000,
        };
        assert_eq!(asym.map(-16384), 1200);
        assert_eq!(asym.map(16384), 1700);
        let reversed = Scale {
            min: 1000,
            centre: 0,
            max: -1000,
        };
        assert_eq!(reversed.map(i16::MAX), -1000);
        assert_eq!(reversed.map(-i16::MAX), 1000);
        let unit = UnitScale {
            min: -1.0,
            centre: 0.0,
            max: 0.5,
        };
        assert_eq!(unit.map(i16::MAX), 0.5);
        assert_eq!(unit.map(i16::MIN), -1.0);
        assert_eq!(unit.map(0), 0.0);
    }
}
