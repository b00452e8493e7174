//! Axis → output mapping shared by the PWM and MAVLink adapters: a ±32767 axis becomes a pulse
//! width in microseconds, and a [`Mode`] becomes a pulse level.
//!
//! The chain for one channel, in order: reverse → deadband → expo → scale around the trimmed
//! centre (separately for each half, so asymmetric min/centre/max work) → round → clamp to
//! `[min_us, max_us]` → optional slew limit ([`SlewLimiter`]).
//!
//! | key | unit | meaning |
//! |---|---|---|
//! | `min_us`, `centre_us`, `max_us` | µs | pulse at −full, centre and +full scale |
//! | `trim_us` | µs | shifts the centre; must stay strictly between min and max |
//! | `reverse` | bool | swaps the two halves |
//! | `deadband_pct` | % of full scale | stick travel around centre that outputs centre |
//! | `expo` | 0..=1 | 0 linear; 1 cubic (fine control near centre) |
//! | `slew_us_per_s` | µs/s | largest change of the output per second |
//!
//! Safe-state values are written without slew limiting: a failsafe must not be slowed down.

use crate::config::Int;
use crate::error::{ConfigErrors, Result};
use crate::msg::{Mode, MovementCommand};
use crate::time::MonoTime;
use serde::{Deserialize, Serialize};

/// Pulse widths accepted anywhere in a channel map, in µs. Servo and autopilot signals live in
/// 500–2500 µs; the wider bounds leave room for unusual devices while still rejecting typos such
/// as `15000`.
pub const PULSE_RANGE_US: std::ops::RangeInclusive<Int> = 100..=10_000;

/// One of the four movement axes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Axis {
    /// `MovementCommand::throttle`.
    Throttle,
    /// `MovementCommand::roll` (UGV steering).
    Roll,
    /// `MovementCommand::pitch`.
    Pitch,
    /// `MovementCommand::yaw`.
    Yaw,
}

impl Axis {
    /// The axis's value in `movement`.
    pub fn of(self, movement: &MovementCommand) -> i16 {
        match self {
            Axis::Throttle => movement.throttle,
            Axis::Roll => movement.roll,
            Axis::Pitch => movement.pitch,
            Axis::Yaw => movement.yaw,
        }
    }

    /// The axis's name in config files.
    pub fn name(self) -> &'static str {
        match self {
            Axis::Throttle => "throttle",
            Axis::Roll => "roll",
            Axis::Pitch => "pitch",
            Axis::Yaw => "yaw",
        }
    }
}

crate::config_types! {
    /// A channel's mapping as written in TOML: the one definition of these keys, flattened into
    /// the PWM and MAVLink channel tables (`#[serde(flatten)]`). `min_us`/`centre_us`/`max_us`
    /// default to the servo standard 1000/1500/2000 µs; the others to "off". Integers are read
    /// wide ([`crate::config::Int`]) and range-checked by [`AxisMapSettings::validate`].
    #[derive(Copy)]
    pub table AxisMapSettings {
        min_us: Option<Int> => "Pulse at −32767 (or +32767 when reversed), µs.",
        centre_us: Option<Int> => "Pulse at 0 before trim, µs.",
        max_us: Option<Int> => "Pulse at +32767 (or −32767 when reversed), µs.",
        trim_us: Option<Int> => "Shift of the centre, µs.",
        #[serde(alias = "invert")] reverse: Option<bool> => "Swap directions (`invert` is \
            accepted as an older spelling).",
        #[serde(alias = "deadzone_pct")] deadband_pct: Option<f64> => "Dead zone around centre, \
            percent of full scale (0..=50; `deadzone_pct` is accepted as an older spelling).",
        expo: Option<f64> => "Expo (0..=1).",
        slew_us_per_s: Option<Int> => "Slew limit in µs per second (absent: none).",
    }
}

/// A validated axis → pulse mapping.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AxisMap {
    min_us: u16,
    centre_us: u16,
    max_us: u16,
    reverse: bool,
    /// Dead zone as a fraction of full scale, 0..=0.5.
    deadband: f64,
    expo: f64,
    slew_us_per_s: Option<u32>,
}

impl Default for AxisMap {
    /// 1000/1500/2000 µs, linear, no deadband, no slew limit.
    fn default() -> Self {
        AxisMap {
            min_us: 1000,
            centre_us: 1500,
            max_us: 2000,
            reverse: false,
            deadband: 0.0,
            expo: 0.0,
            slew_us_per_s: None,
        }
    }
}

/// The rule of `deadband_pct` wherever it is written (outputs and inputs).
pub const DEADBAND_RANGE_PCT: std::ops::RangeInclusive<f64> = 0.0..=50.0;

/// The rule of `expo` wherever it is written (outputs and inputs).
pub const EXPO_RANGE: std::ops::RangeInclusive<f64> = 0.0..=1.0;

/// A pulse key checked against [`PULSE_RANGE_US`].
pub fn pulse(errors: &mut ConfigErrors, key: &str, value: Int) -> Option<u16> {
    errors.int(key, value, PULSE_RANGE_US, " µs")
}

impl AxisMapSettings {
    /// The keys that were written, for "does not apply to this source" errors.
    pub fn given(&self) -> Vec<(&'static str, String)> {
        let s = |v: Option<Int>| v.map(|v| v.to_string());
        let f = |v: Option<f64>| v.map(|v| v.to_string());
        [
            ("min_us", s(self.min_us)),
            ("centre_us", s(self.centre_us)),
            ("max_us", s(self.max_us)),
            ("trim_us", s(self.trim_us)),
            ("reverse", self.reverse.map(|v| v.to_string())),
            ("deadband_pct", f(self.deadband_pct)),
            ("expo", f(self.expo)),
            ("slew_us_per_s", s(self.slew_us_per_s)),
        ]
        .into_iter()
        .filter_map(|(k, v)| Some((k, v?)))
        .collect()
    }

    /// Validates, filling defaults. Keys are named relative to the channel's table.
    ///
    /// # Errors
    /// [`crate::Error::Config`] listing every key that is out of range: pulses outside
    /// [`PULSE_RANGE_US`], `min_us < centre_us + trim_us < max_us` broken, deadband outside
    /// 0..=50 %, expo outside 0..=1, a slew rate outside 1..=1000000 µs/s.
    pub fn validate(&self) -> Result<AxisMap> {
        let d = AxisMap::default();
        let mut errors = ConfigErrors::default();
        let min = self.min_us.unwrap_or(d.min_us.into());
        let centre = self.centre_us.unwrap_or(d.centre_us.into());
        let max = self.max_us.unwrap_or(d.max_us.into());
        let (min_us, _, max_us) = (
            pulse(&mut errors, "min_us", min),
            pulse(&mut errors, "centre_us", centre),
            pulse(&mut errors, "max_us", max),
        );
        let trimmed = centre.saturating_add(self.trim_us.unwrap_or(0));
        if !(min < trimmed && trimmed < max) {
            let (key, value) = match self.trim_us {
                Some(t) => ("trim_us", t),
                None => ("centre_us", centre),
            };
            errors.add(
                key,
                value,
                format!(
                    "centre_us + trim_us ({trimmed}) must lie strictly between min_us ({min}) \
                     and max_us ({max})"
                ),
            );
        }
        let deadband_pct = self.deadband_pct.unwrap_or(0.0);
        let rule = "must be 0..=50 (percent of full scale)";
        errors.float("deadband_pct", deadband_pct, DEADBAND_RANGE_PCT, rule);
        let expo = errors.float(
            "expo",
            self.expo.unwrap_or(0.0),
            EXPO_RANGE,
            "must be 0..=1",
        );
        let slew_range = 1..=Int::from(u32::MAX);
        let slew = " µs/s (omit the key for no slew limit)";
        let slew = errors.opt_int("slew_us_per_s", self.slew_us_per_s, slew_range, slew);
        errors.into_result(AxisMap {
            min_us: min_us.unwrap_or(d.min_us),
            // Within (min, max) ⊂ u16 once validation passed.
            centre_us: u16::try_from(trimmed).unwrap_or(d.centre_us),
            max_us: max_us.unwrap_or(d.max_us),
            reverse: self.reverse.unwrap_or(false),
            deadband: deadband_pct / 100.0,
            expo,
            slew_us_per_s: slew,
        })
    }
}

impl AxisMap {
    /// Pulse at −full scale.
    pub fn min_us(&self) -> u16 {
        self.min_us
    }

    /// Pulse at centre, trim included: the neutral output.
    pub fn centre_us(&self) -> u16 {
        self.centre_us
    }

    /// Pulse at +full scale.
    pub fn max_us(&self) -> u16 {
        self.max_us
    }

    /// The slew limiter this channel needs (unlimited if no `slew_us_per_s`).
    pub fn slew_limiter(&self) -> SlewLimiter {
        SlewLimiter::new(self.slew_us_per_s)
    }

    /// Maps an axis value to a pulse width. Total: every `i16` gives a pulse in `[min, max]`;
    /// −32768 counts as −32767.
    pub fn map(&self, axis: i16) -> u16 {
        let mut x = f64::from(axis.max(-i16::MAX)) / f64::from(i16::MAX);
        if self.reverse {
            x = -x;
        }
        let shaped = deadband_expo(x.abs(), self.deadband, self.expo);
        let centre = f64::from(self.centre_us);
        let pulse = if x >= 0.0 {
            centre + shaped * (f64::from(self.max_us) - centre)
        } else {
            centre - shaped * (centre - f64::from(self.min_us))
        };
        // In range by construction (shaped ∈ [0, 1]); clamp guards rounding at the ends.
        pulse
            .round()
            .clamp(f64::from(self.min_us), f64::from(self.max_us)) as u16
    }
}

/// Dead band, then expo, on a stick magnitude in 0..=1 (outputs and inputs share it): the first
/// `deadband` of the travel (below 1) gives 0 and the rest is rescaled to 0..=1, so there is no
/// jump at its edge; then `(1 − expo)·m + expo·m³` (0 linear, 1 cubic).
pub fn deadband_expo(magnitude: f64, deadband: f64, expo: f64) -> f64 {
    let m = if magnitude <= deadband {
        0.0
    } else {
        (magnitude - deadband) / (1.0 - deadband)
    };
    (1.0 - expo) * m + expo * m.powi(3)
}

/// Limits how fast an output may change, for gentle starts on servos and ESCs.
///
/// Keeps the fractional position, so slow rates at high update rates still move.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SlewLimiter {
    rate_us_per_s: Option<u32>,
    last: Option<(MonoTime, f64)>,
}

impl SlewLimiter {
    /// A limiter allowing `rate_us_per_s` (unlimited if `None`).
    pub fn new(rate_us_per_s: Option<u32>) -> Self {
        SlewLimiter {
            rate_us_per_s,
            last: None,
        }
    }

    /// Moves toward `target_us`, at most `rate × elapsed` since the last step. The first step
    /// after construction or [`Self::reset`] passes the target through.
    pub fn step(&mut self, now: MonoTime, target_us: u16) -> u16 {
        let target = f64::from(target_us);
        let next = match (self.rate_us_per_s, self.last) {
            (Some(rate), Some((then, position))) => {
                let budget = f64::from(rate) * now.saturating_since(then).as_secs_f64();
                position + (target - position).clamp(-budget, budget)
            }
            _ => target,
        };
        self.last = Some((now, next));
        next.round() as u16
    }

    /// Jumps to `value_us` with no limit (safe state), and limits from there.
    pub fn reset(&mut self, now: MonoTime, value_us: u16) {
        self.last = Some((now, f64::from(value_us)));
    }
}

crate::config_types! {
    /// The levels of a mode-switch channel as written in TOML: the pulse for each mode.
    #[derive(Copy, Eq)]
    pub table ModeLevelsSettings {
        manual_us: Option<Int> => "Pulse for MANUAL, µs.",
        assisted_us: Option<Int> => "Pulse for ASSISTED, µs.",
        auto_us: Option<Int> => "Pulse for AUTO, µs.",
    }
}

/// Pulse levels of a mode-switch channel, one per [`Mode`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ModeLevels {
    manual_us: u16,
    assisted_us: u16,
    auto_us: u16,
}

impl ModeLevelsSettings {
    /// The keys that were written, for "does not apply to this source" errors.
    pub fn given(&self) -> Vec<(&'static str, Int)> {
        [
            ("manual_us", self.manual_us),
            ("assisted_us", self.assisted_us),
            ("auto_us", self.auto_us),
        ]
        .into_iter()
        .filter_map(|(k, v)| Some((k, v?)))
        .collect()
    }

    /// Validates against `defaults` (each adapter knows its device's usual levels).
    ///
    /// # Errors
    /// [`crate::Error::Config`] for a level outside [`PULSE_RANGE_US`] or two modes sharing a
    /// level (the device could not tell them apart).
    pub fn validate(&self, defaults: ModeLevels) -> Result<ModeLevels> {
        let mut errors = ConfigErrors::default();
        let mut level = |key: &str, v: Option<Int>, default: u16| {
            v.map_or(Some(default), |v| pulse(&mut errors, key, v))
        };
        let named = [
            (
                "manual_us",
                level("manual_us", self.manual_us, defaults.manual_us),
            ),
            (
                "assisted_us",
                level("assisted_us", self.assisted_us, defaults.assisted_us),
            ),
            ("auto_us", level("auto_us", self.auto_us, defaults.auto_us)),
        ];
        for (i, (key, v)) in named.iter().enumerate() {
            if let Some((other, _)) = named[..i].iter().find(|(_, w)| v.is_some() && w == v) {
                errors.add(
                    *key,
                    v.unwrap_or_default(),
                    format!("must differ from {other}: the device could not tell the modes apart"),
                );
            }
        }
        let levels = ModeLevels {
            manual_us: named[0].1.unwrap_or(defaults.manual_us),
            assisted_us: named[1].1.unwrap_or(defaults.assisted_us),
            auto_us: named[2].1.unwrap_or(defaults.auto_us),
        };
        errors.into_result(levels)
    }
}

impl ModeLevels {
    /// Levels from explicit values, unvalidated: for adapters' built-in defaults.
    pub const fn new(manual_us: u16, assisted_us: u16, auto_us: u16) -> Self {
        ModeLevels {
            manual_us,
            assisted_us,
            auto_us,
        }
    }

    /// The pulse for `mode`.
    pub fn level(&self, mode: Mode) -> u16 {
        match mode {
            Mode::Manual => self.manual_us,
            Mode::Assisted => self.assisted_us,
            Mode::Auto => self.auto_us,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;
    use std::time::Duration;

    fn map(toml_text: &str) -> AxisMap {
        toml::from_str::<AxisMapSettings>(toml_text)
            .expect("parses")
            .validate()
            .expect("valid")
    }

    #[test]
    fn default_map_is_the_servo_standard() {
        let m = AxisMap::default();
        assert_eq!(m.map(0), 1500);
        assert_eq!(m.map(i16::MAX), 2000);
        assert_eq!(m.map(-i16::MAX), 1000);
        assert_eq!(m.map(i16::MIN), 1000);
        assert_eq!(m.map(16384), 1750);
        assert_eq!(AxisMapSettings::default().validate(), Ok(m));
    }

    #[test]
    fn trim_shifts_centre_and_halves_scale_separately() {
        let m = map("trim_us = 20");
        assert_eq!(m.map(0), 1520);
        assert_eq!(m.map(i16::MAX), 2000);
        assert_eq!(m.map(-i16::MAX), 1000);
        assert_eq!(m.centre_us(), 1520);
        // Asymmetric ranges: each half has its own span.
        let m = map("min_us = 1100\ncentre_us = 1400\nmax_us = 2000");
        assert_eq!(m.map(-16384), 1250);
        assert_eq!(m.map(16384), 1700);
    }

    #[test]
    fn reverse_swaps_directions() {
        let m = map("reverse = true");
        assert_eq!(m.map(i16::MAX), 1000);
        assert_eq!(m.map(-i16::MAX), 2000);
        assert_eq!(m.map(0), 1500);
    }

    #[test]
    fn deadband_outputs_centre_then_rescales_without_a_jump() {
        let m = map("deadband_pct = 10");
        assert_eq!(m.map(3276), 1500); // 9.998 % of full scale
        assert_eq!(m.map(-3276), 1500);
        assert_eq!(m.map(3300), 1500); // just past: moves by < 1 µs, no jump
        assert_eq!(m.map(i16::MAX), 2000);
    }

    #[test]
    fn expo_softens_the_centre_and_keeps_the_ends() {
        let m = map("expo = 1.0");
        assert_eq!(m.map(16384), 1563); // 0.5³ × 500 = 62.5 → 1562.5 rounds up
        assert_eq!(m.map(i16::MAX), 2000);
        let half = map("expo = 0.5");
        assert_eq!(half.map(16384), 1656); // (0.25 + 0.0625) × 500 = 156.25
    }

    #[test]
    fn validation_names_every_bad_key() {
        let raw: AxisMapSettings = toml::from_str(
            "min_us = 1600\nmax_us = 20000\ndeadband_pct = 60\nexpo = -0.1\nslew_us_per_s = 0",
        )
        .expect("parses");
        let err = raw.validate().expect_err("invalid").to_string();
        for key in [
            "max_us = 20000",
            "centre_us = 1500: centre_us + trim_us (1500) must lie strictly between min_us (1600)",
            "deadband_pct = 60",
            "expo = -0.1",
            "slew_us_per_s = 0",
        ] {
            assert!(err.contains(key), "missing {key:?} in:\n{err}");
        }
    }

    #[test]
    fn trim_beyond_the_range_is_rejected_naming_trim() {
        let raw: AxisMapSettings = toml::from_str("trim_us = 500").expect("parses");
        let err = raw.validate().expect_err("trim to max").to_string();
        assert!(err.starts_with("trim_us = 500:"), "{err}");
    }

    #[test]
    fn rejects_unknown_keys() {
        assert!(toml::from_str::<AxisMapSettings>("centre = 1500").is_err());
    }

    #[test]
    fn slew_limits_rate_and_keeps_fractions() {
        let mut s = SlewLimiter::new(Some(100)); // 100 µs per second
        let t0 = MonoTime::from_millis(0);
        assert_eq!(s.step(t0, 1500), 1500);
        // 1 ms steps allow 0.1 µs each: after 10 steps the output has moved 1 µs.
        let mut out = 0;
        for i in 1..=10 {
            out = s.step(t0 + Duration::from_millis(i), 2000);
        }
        assert_eq!(out, 1501);
        assert_eq!(s.step(t0 + Duration::from_millis(1010), 2000), 1601);
        s.reset(t0 + Duration::from_millis(1010), 1500);
        assert_eq!(s.step(t0 + Duration::from_millis(1010), 1000), 1500);
        assert_eq!(s.step(t0 + Duration::from_millis(2010), 1000), 1400);
    }

    #[test]
    fn unlimited_slew_passes_through() {
        let mut s = SlewLimiter::new(None);
        assert_eq!(s.step(MonoTime::ZERO, 1000), 1000);
        assert_eq!(s.step(MonoTime::ZERO, 2000), 2000);
    }

    #[test]
    fn mode_levels_map_each_mode_and_must_differ() {
        let defaults = ModeLevels::new(1100, 1500, 1900);
        let levels = ModeLevelsSettings {
            auto_us: Some(1950),
            ..Default::default()
        }
        .validate(defaults)
        .expect("valid");
        assert_eq!(levels.level(Mode::Manual), 1100);
        assert_eq!(levels.level(Mode::Assisted), 1500);
        assert_eq!(levels.level(Mode::Auto), 1950);
        let err = ModeLevelsSettings {
            auto_us: Some(1500),
            ..Default::default()
        }
        .validate(defaults)
        .expect_err("duplicate level")
        .to_string();
        assert!(
            err.starts_with("auto_us = 1500: must differ from assisted_us"),
            "{err}"
        );
    }

    #[test]
    fn axis_picks_its_field() {
        let m = MovementCommand {
            throttle: 1,
            roll: 2,
            pitch: 3,
            yaw: 4,
        };
        let picked: Vec<i16> = [Axis::Throttle, Axis::Roll, Axis::Pitch, Axis::Yaw]
            .iter()
            .map(|a| a.of(&m))
            .collect();
        assert_eq!(picked, [1, 2, 3, 4]);
    }

    prop_compose! {
        fn valid_map()(
            min in 500u16..1400, span_lo in 10u16..500, span_hi in 10u16..900,
            trim in -5i16..=5, reverse: bool, deadband in 0.0f64..=50.0, expo in 0.0f64..=1.0,
        ) -> AxisMap {
            AxisMapSettings {
                min_us: Some(min.into()), centre_us: Some((min + span_lo).into()),
                max_us: Some((min + span_lo + span_hi).into()),
                trim_us: Some(trim.into()), reverse: Some(reverse), deadband_pct: Some(deadband),
                expo: Some(expo), slew_us_per_s: None,
            }.validate().expect("valid by construction")
        }
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(2_000))]

        /// Every axis value maps into [min, max]; centre maps to the trimmed centre; full scale to
        /// the ends; and the map is monotonic (rising, or falling when reversed).
        #[test]
        fn mapping_is_bounded_centred_and_monotonic(m in valid_map(), a: i16, b: i16) {
            let (pa, pb) = (m.map(a), m.map(b));
            prop_assert!(m.min_us() <= pa && pa <= m.max_us());
            prop_assert_eq!(m.map(0), m.centre_us());
            let (lo, hi) = if m.reverse { (m.max_us(), m.min_us()) } else { (m.min_us(), m.max_us()) };
            prop_assert_eq!(m.map(-i16::MAX), lo);
            prop_assert_eq!(m.map(i16::MAX), hi);
            let (a, b, pa, pb) = if a <= b { (a, b, pa, pb) } else { (b, a, pb, pa) };
            let _ = (a, b);
            if m.reverse { prop_assert!(pa >= pb) } else { prop_assert!(pa <= pb) }
        }

        /// The slew limiter never moves faster than its rate (±1 µs of rounding) and reaches any
        /// target given enough time.
        #[test]
        fn slew_never_exceeds_rate(
            rate in 1u32..5_000,
            steps in prop::collection::vec((1u64..50, 1000u16..=2000), 1..50),
        ) {
            let mut s = SlewLimiter::new(Some(rate));
            let mut now = MonoTime::ZERO;
            let mut last = s.step(now, 1500);
            for (dt_ms, target) in steps {
                now = now + Duration::from_millis(dt_ms);
                let out = s.step(now, target);
                let budget = f64::from(rate) * dt_ms as f64 / 1000.0;
                prop_assert!(f64::from(out.abs_diff(last)) <= budget.ceil() + 1.0);
                last = out;
            }
            let later = now + Duration::from_secs(1000 / u64::from(rate) + 2);
            prop_assert_eq!(s.step(later, 1234), 1234);
        }
    }
}
