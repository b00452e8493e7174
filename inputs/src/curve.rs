//! Pure axis math: raw device units → calibrated −1..1 → shaped (invert, deadzone, expo, scale)
//! → a ±32767 wire axis; and the keyboard ramp that turns held keys into a smooth stick.
//!
//! The chain for an absolute axis, in order:
//! 1. **calibrate**: `min`/`centre`/`max` (from the device's absinfo, each overridable) map the
//!    raw value to −1..1, each half separately so an off-centre stick still reaches both ends;
//!    values beyond `min`/`max` clamp to ±1;
//! 2. **invert**: negate;
//! 3. **deadzone**: |x| ≤ d outputs 0; outside, the rest of the travel is rescaled to d..1 → 0..1
//!    so the output has no step at the deadzone's edge;
//! 4. **expo**: `(1 − e)·x + e·x³` (0 linear, 1 cubic: fine control near centre);
//! 5. **scale**: multiply by 0..1 (a gentle vehicle's full stick is less than full scale);
//! 6. **round and clamp** to ±32767.
//!
//! Key axes skip steps 1 and 3: their value in −1..1 comes from [`Ramp`].
//!
//! Every function is total: NaN, infinities and degenerate calibrations (min = max) give 0,
//! never a panic.

use rove_core::msg::AXIS_MAX;
use std::time::Duration;

/// An absolute axis's state as the kernel reports it (`struct input_absinfo`, without
/// resolution): the current value and its calibration.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct AbsState {
    /// Current position.
    pub value: i32,
    /// Lowest position.
    pub minimum: i32,
    /// Highest position.
    pub maximum: i32,
    /// Noise filter the kernel applies (informational).
    pub fuzz: i32,
    /// The device's suggested dead zone around centre, raw units.
    pub flat: i32,
}

impl From<evdev::AbsInfo> for AbsState {
    fn from(info: evdev::AbsInfo) -> Self {
        AbsState {
            value: info.value(),
            minimum: info.minimum(),
            maximum: info.maximum(),
            fuzz: info.fuzz(),
            flat: info.flat(),
        }
    }
}

/// The raw positions of an axis's ends and centre.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Calibration {
    /// Raw value at −1.
    pub min: f64,
    /// Raw value at 0.
    pub centre: f64,
    /// Raw value at +1.
    pub max: f64,
}

impl Calibration {
    /// A calibration from the device's `absinfo` with each of `min`, `centre`, `max` replaced by
    /// the config's value when given. The centre defaults to the midpoint of min and max (the
    /// kernel reports no centre).
    pub fn resolve(
        device: Option<&AbsState>,
        min: Option<i32>,
        centre: Option<i32>,
        max: Option<i32>,
    ) -> Option<Calibration> {
        let min = f64::from(min.or(device.map(|d| d.minimum))?);
        let max = f64::from(max.or(device.map(|d| d.maximum))?);
        let centre = centre.map_or((min + max) / 2.0, f64::from);
        Some(Calibration { min, centre, max })
    }

    /// `raw` as −1..1 (clamped).
    pub fn normalise(&self, raw: i32) -> f64 {
        let raw = f64::from(raw);
        let x = if raw >= self.centre {
            ratio(raw - self.centre, self.max - self.centre)
        } else {
            -ratio(self.centre - raw, self.centre - self.min)
        };
        clamp_unit(x)
    }

    /// The device's `flat` (raw units) as a fraction of the half range, capped at 0.5.
    pub fn flat_fraction(&self, flat: i32) -> f64 {
        clamp01(ratio(f64::from(flat.max(0)), (self.max - self.min) / 2.0)).min(0.5)
    }
}

/// `num / den`, 0 when `den` is not positive or the result is not finite.
fn ratio(num: f64, den: f64) -> f64 {
    if den > 0.0 {
        let r = num / den;
        if r.is_finite() { r } else { 0.0 }
    } else {
        0.0
    }
}

fn clamp_unit(x: f64) -> f64 {
    if x.is_nan() { 0.0 } else { x.clamp(-1.0, 1.0) }
}

fn clamp01(x: f64) -> f64 {
    if x.is_nan() { 0.0 } else { x.clamp(0.0, 1.0) }
}

/// Invert, deadzone, expo and scale, as validated from config.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Shaping {
    /// Negate the axis.
    pub invert: bool,
    /// Dead zone, fraction of the half range (0..=0.5).
    pub deadzone: f64,
    /// Expo, 0..=1.
    pub expo: f64,
    /// Output at full deflection, fraction of full scale (0..=1).
    pub scale: f64,
}

impl Default for Shaping {
    /// Linear, no deadzone, full scale.
    fn default() -> Self {
        Shaping {
            invert: false,
            deadzone: 0.0,
            expo: 0.0,
            scale: 1.0,
        }
    }
}

impl Shaping {
    /// Applies invert → deadzone → expo → scale to `x` (−1..1), returning −1..1.
    pub fn apply(&self, x: f64) -> f64 {
        let mut x = clamp_unit(x);
        if self.invert {
            x = -x;
        }
        let d = clamp01(self.deadzone).min(0.5);
        let mag = rove_core::mapping::deadband_expo(x.abs(), d, clamp01(self.expo));
        let mag = mag * clamp01(self.scale);
        clamp_unit(mag.copysign(x))
    }
}

/// −1..1 → a wire axis, rounded, clamped to ±32767 (never −32768).
pub fn to_axis(x: f64) -> i16 {
    let v = (clamp_unit(x) * f64::from(AXIS_MAX)).round();
    // In range by the clamp above; the cast cannot truncate.
    v.clamp(-f64::from(AXIS_MAX), f64::from(AXIS_MAX)) as i16
}

/// A keyboard axis: two keys drive a value in −1..1 that ramps towards the held key's end and
/// springs back to centre when both (or neither) are held.
///
/// Moving away from centre takes `ramp_up` for the full travel 0 → ±1; moving towards centre
/// (released, or the opposite key pressed) takes `spring_back` for ±1 → 0. A zero duration is an
/// instant step. Reversing first springs back to 0, then ramps up the other way.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Ramp {
    ramp_up: Duration,
    spring_back: Duration,
    value: f64,
    target: f64,
}

impl Ramp {
    /// A ramp at rest.
    pub fn new(ramp_up: Duration, spring_back: Duration) -> Self {
        Ramp {
            ramp_up,
            spring_back,
            value: 0.0,
            target: 0.0,
        }
    }

    /// The current value, −1..1.
    pub fn value(&self) -> f64 {
        self.value
    }

    /// Where the ramp is heading, −1, 0 or +1.
    pub fn target(&self) -> f64 {
        self.target
    }

    /// Still moving.
    pub fn is_moving(&self) -> bool {
        self.value != self.target
    }

    /// Sets the target from the keys held: only `negative` → −1, only `positive` → +1, else 0.
    pub fn set_keys(&mut self, negative: bool, positive: bool) {
        self.target = match (negative, positive) {
            (true, false) => -1.0,
            (false, true) => 1.0,
            _ => 0.0,
        };
    }

    /// Back to centre at once (device lost).
    pub fn reset(&mut self) {
        self.value = 0.0;
        self.target = 0.0;
    }

    /// Moves the value towards the target for `dt`.
    pub fn advance(&mut self, dt: Duration) {
        let mut left = dt.as_secs_f64();
        // At most two phases: spring back to 0, then ramp up the other way.
        for _ in 0..2 {
            if self.value == self.target || left <= 0.0 {
                break;
            }
            let towards_centre = self.target == 0.0
                || (self.value != 0.0 && self.value.signum() != self.target.signum());
            let (goal, period) = if towards_centre {
                (0.0, self.spring_back)
            } else {
                (self.target, self.ramp_up)
            };
            let period = period.as_secs_f64();
            let distance = (goal - self.value).abs();
            if period <= 0.0 {
                self.value = goal;
                continue;
            }
            let needed = distance * period;
            if needed <= left {
                self.value = goal;
                left -= needed;
            } else {
                self.value += (goal - self.value).signum() * left / period;
                left = 0.0;
            }
        }
        self.value = clamp_unit(self.value);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cal(min: i32, max: i32) -> Calibration {
        Calibration::resolve(
            Some(&AbsState {
                minimum: min,
                maximum: max,
                ..AbsState::default()
            }),
            None,
            None,
            None,
        )
        .expect("device gives min and max")
    }

    #[test]
    fn calibration_maps_ends_and_centre() {
        let c = cal(0, 255);
        assert_eq!(c.normalise(0), -1.0);
        assert_eq!(c.normalise(255), 1.0);
        assert!(c.normalise(128).abs() < 0.01);
        assert_eq!(to_axis(c.normalise(255)), 32767);
        assert_eq!(to_axis(c.normalise(0)), -32767);
    }

    #[test]
    fn calibration_clamps_values_beyond_the_ends() {
        let c = cal(-100, 100);
        assert_eq!(c.normalise(500), 1.0);
        assert_eq!(c.normalise(i32::MIN), -1.0);
    }

    #[test]
    fn config_overrides_device_calibration_per_half() {
        let device = AbsState {
            minimum: 0,
            maximum: 1000,
            ..AbsState::default()
        };
        // A stick that rests at 600 and only reaches 900.
        let c = Calibration::resolve(Some(&device), None, Some(600), Some(900)).expect("given");
        assert_eq!(c.normalise(600), 0.0);
        assert_eq!(c.normalise(900), 1.0);
        assert_eq!(c.normalise(300), -0.5);
        assert_eq!(c.normalise(0), -1.0);
    }

    #[test]
    fn missing_calibration_is_none() {
        assert_eq!(Calibration::resolve(None, Some(0), None, None), None);
        assert!(Calibration::resolve(None, Some(0), None, Some(10)).is_some());
    }

    #[test]
    fn degenerate_calibration_gives_zero() {
        let c = cal(5, 5);
        assert_eq!(c.normalise(5), 0.0);
        assert_eq!(c.normalise(9), 0.0);
        assert_eq!(c.flat_fraction(3), 0.0);
    }

    #[test]
    fn flat_becomes_a_fraction_of_the_half_range() {
        assert_eq!(cal(-32768, 32767).flat_fraction(0), 0.0);
        assert!((cal(0, 255).flat_fraction(15) - 15.0 / 127.5).abs() < 1e-9);
        assert_eq!(cal(0, 10).flat_fraction(100), 0.5);
    }

    #[test]
    fn invert_negates() {
        let s = Shaping {
            invert: true,
            ..Shaping::default()
        };
        assert_eq!(s.apply(0.25), -0.25);
        assert_eq!(s.apply(-1.0), 1.0);
    }

    #[test]
    fn deadzone_zeroes_the_centre_and_rescales_the_rest() {
        let s = Shaping {
            deadzone: 0.1,
            ..Shaping::default()
        };
        assert_eq!(s.apply(0.1), 0.0);
        assert_eq!(s.apply(-0.05), 0.0);
        assert!((s.apply(0.55) - 0.5).abs() < 1e-9);
        assert_eq!(s.apply(1.0), 1.0);
        assert_eq!(s.apply(-1.0), -1.0);
        // Just outside the deadzone the output is near zero: no step.
        assert!(s.apply(0.1001) < 0.001);
    }

    #[test]
    fn expo_softens_the_centre_and_keeps_the_ends() {
        let s = Shaping {
            expo: 1.0,
            ..Shaping::default()
        };
        assert!((s.apply(0.5) - 0.125).abs() < 1e-9);
        assert_eq!(s.apply(1.0), 1.0);
        assert_eq!(s.apply(-1.0), -1.0);
        let half = Shaping {
            expo: 0.5,
            ..Shaping::default()
        };
        assert!((half.apply(-0.5) + 0.3125).abs() < 1e-9);
    }

    #[test]
    fn scale_limits_full_deflection() {
        let s = Shaping {
            scale: 0.5,
            ..Shaping::default()
        };
        assert_eq!(to_axis(s.apply(1.0)), 16384);
        assert_eq!(to_axis(s.apply(-1.0)), -16384);
    }

    #[test]
    fn to_axis_clamps_and_never_gives_minus_32768() {
        assert_eq!(to_axis(2.0), 32767);
        assert_eq!(to_axis(-2.0), -32767);
        assert_eq!(to_axis(f64::NAN), 0);
        assert_eq!(to_axis(f64::NEG_INFINITY), -32767);
        assert_eq!(to_axis(0.5), 16384);
    }

    #[test]
    fn shaping_is_total_on_odd_inputs() {
        let s = Shaping {
            invert: true,
            deadzone: 0.9,
            expo: f64::NAN,
            scale: f64::INFINITY,
        };
        for x in [f64::NAN, f64::INFINITY, -1.0, 0.0, 0.7, 1.0] {
            let y = s.apply(x);
            assert!((-1.0..=1.0).contains(&y), "{x} → {y}");
        }
    }

    #[test]
    fn ramp_rises_linearly_and_springs_back() {
        let mut r = Ramp::new(Duration::from_millis(200), Duration::from_millis(100));
        r.set_keys(false, true);
        r.advance(Duration::from_millis(50));
        assert!((r.value() - 0.25).abs() < 1e-9);
        r.advance(Duration::from_millis(500));
        assert_eq!(r.value(), 1.0);
        assert!(!r.is_moving());
        r.set_keys(false, false);
        r.advance(Duration::from_millis(50));
        assert!((r.value() - 0.5).abs() < 1e-9);
        r.advance(Duration::from_millis(50));
        assert_eq!(r.value(), 0.0);
    }

    #[test]
    fn ramp_reversal_springs_back_then_ramps_the_other_way() {
        let mut r = Ramp::new(Duration::from_millis(200), Duration::from_millis(100));
        r.set_keys(false, true);
        r.advance(Duration::from_millis(200));
        assert_eq!(r.value(), 1.0);
        r.set_keys(true, false);
        // 100 ms to centre, then 50 ms of ramp up = −0.25.
        r.advance(Duration::from_millis(150));
        assert!((r.value() + 0.25).abs() < 1e-9);
    }

    #[test]
    fn zero_durations_step_and_both_keys_centre() {
        let mut r = Ramp::new(Duration::ZERO, Duration::ZERO);
        r.set_keys(true, false);
        r.advance(Duration::from_nanos(1));
        assert_eq!(r.value(), -1.0);
        r.set_keys(true, true);
        assert_eq!(r.target(), 0.0);
        r.advance(Duration::from_nanos(1));
        assert_eq!(r.value(), 0.0);
    }
}
