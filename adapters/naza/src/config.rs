//! `[output]` for `adapter = "naza"`: the raw settings and their validation into a
//! [`NazaConfig`] (a generic PWM vehicle plus the Naza's own policies). Errors name the Naza
//! keys (`mode.atti_us`, `throttle.max_us`), not the generic channel list.

use rove_core::config::{Int, UnknownKeys};
use rove_core::error::{ConfigError, ConfigErrors};
use rove_core::mapping::{ModeLevels, ModeLevelsSettings};
use rove_core::msg::{Mode, MovementCommand};
use rove_pwm::config::{finish_preset, preset_tables, rename_channels};
use rove_pwm::{
    ChannelSettings, ChannelSource, ChannelSourceKind, PwmAddressSettings, PwmBackendSettings,
    PwmVehicleConfig,
};
use std::time::Duration;

/// Default U levels, µs: Manual low, ATTI middle, GPS high — what a Naza-M calibrated on a
/// common 3-position switch reads (≈1100/1520/1850 µs reported by Naza-M Lite users). The
/// Naza decides by thresholds between its calibrated end points, so round values inside each
/// band work; a value near a threshold can flicker between two modes.
pub const DEFAULT_LEVELS: ModeLevels = ModeLevels::new(1100, 1500, 1900);

/// Default throttle slew, µs/s: the whole 1000 µs travel in one second, so a new operator's
/// throttle takes ≥ 0.5 s to go from hover to an end. Faster lets a change of hands jerk
/// the aircraft; slower makes the throttle feel laggy.
pub const DEFAULT_THROTTLE_SLEW_US_PER_S: Int = 1_000;

/// Default CSC hold, ms. The Naza starts the motors once it sees the CSC (its manual gives no
/// minimum); 1.5 s covers its input filtering and a frame or two of jitter from software PWM,
/// and is short enough that the operator is not left waiting. Longer is harmless: the
/// throttle is at minimum throughout.
pub const DEFAULT_CSC_HOLD_MS: Int = 1_500;

/// Accepted CSC hold times, ms.
pub const CSC_HOLD_RANGE_MS: std::ops::RangeInclusive<Int> = 200..=5_000;

/// Default land ramp, ms: from hover throttle to the land floor. Gentle enough that the
/// aircraft does not drop; quick enough that a lost link does not leave it hovering long.
pub const DEFAULT_LAND_RAMP_MS: Int = 3_000;

/// Accepted land ramp times, ms.
pub const LAND_RAMP_RANGE_MS: std::ops::RangeInclusive<Int> = 100..=60_000;

/// The default land floor as a fraction of the way from the throttle centre down to its
/// minimum: 40 % (1300 µs with the defaults) descends steadily in ATTI/GPS and stays well
/// above the 10 % (1100 µs) at which the Naza's default "Immediately" stop type cuts motors.
pub const DEFAULT_LAND_FRACTION: f64 = 0.4;

rove_core::config_types! {
    /// Mode the U channel is put in by the failsafe.
    pub keyword FailsafeMode -> Mode {
        Atti => "ATTI: holds attitude and altitude; drifts with wind. Works without GPS lock."
            = Mode::Assisted,
        Gps => "GPS: also holds position; needs a GPS lock." = Mode::Auto,
    }

    /// What the failsafe does with the throttle.
    pub keyword FailsafePolicy {
        Hover => "Throttle centred: hold altitude.",
        Land => "Throttle ramps from centre down to `land_throttle_us` over `land_ramp_ms`.",
    }

    /// Which corners the sticks go to for the CSC (mode-2 sticks: left = throttle/yaw, right =
    /// pitch/roll; both always at the bottom), and the sticks' positions there.
    pub keyword CscPattern -> MovementCommand {
        Outer => "Left stick bottom-left, right stick bottom-right." = csc(-FULL, FULL),
        Inner => "Left stick bottom-right, right stick bottom-left." = csc(FULL, -FULL),
        Left => "Both sticks bottom-left." = csc(-FULL, -FULL),
        Right => "Both sticks bottom-right." = csc(FULL, FULL),
    }
}

const FULL: i16 = i16::MAX;

/// The CSC's stick positions: yaw and roll as given, throttle and pitch at the bottom.
const fn csc(yaw: i16, roll: i16) -> MovementCommand {
    MovementCommand {
        throttle: -FULL,
        roll,
        pitch: -FULL,
        yaw,
    }
}

/// `[output.aileron]` … `[output.rudder]`: address and optional limits; the throttle's slew
/// limit defaults to [`DEFAULT_THROTTLE_SLEW_US_PER_S`].
pub type StickSettings = rove_pwm::ServoChannelSettings;

rove_core::config_types! {
    /// `[output.mode]`: the U channel's address and levels (µs).
    pub settings ModeChannelSettings {
        #[serde(flatten)] address: PwmAddressSettings => "The address keys (rove-pwm's).",
        manual_us: Option<Int> => "Level for Manual (MANUAL).",
        atti_us: Option<Int> => "Level for ATTI (ASSISTED).",
        gps_us: Option<Int> => "Level for GPS (AUTO).",
        #[serde(flatten)] unknown: UnknownKeys => "Keys nothing above took (see `validate`).",
    }

    /// `[output]` for the Naza-M, as written.
    pub settings NazaSettings {
        #[serde(flatten)] pwm: PwmBackendSettings => "rove-pwm's backend keys.",
        aileron: Option<StickSettings> => "A: roll.",
        elevator: Option<StickSettings> => "E: pitch.",
        throttle: Option<StickSettings> => "T: throttle.",
        rudder: Option<StickSettings> => "R: yaw.",
        mode: Option<ModeChannelSettings> => "U: mode switch.",
        failsafe_mode: Option<FailsafeMode> => "U level in failsafe.",
        failsafe_policy: Option<FailsafePolicy> => "Throttle in failsafe.",
        land_throttle_us: Option<Int> => "`land`: throttle floor, µs (absent: see \
            [`DEFAULT_LAND_FRACTION`]).",
        land_ramp_ms: Option<Int> => "`land`: ramp time from centre to the floor, ms.",
        csc: Option<CscPattern> => "CSC corners.",
        csc_hold_ms: Option<Int> => "How long the CSC is held, ms.",
        #[serde(flatten)] unknown: UnknownKeys => "Keys nothing above took (see `validate`).",
    }
}

rove_core::config_types! {
    /// The throttle in failsafe, validated.
    #[derive(Debug, Clone, Copy, PartialEq, Eq)]
    pub enum FailsafeThrottle {
        Hover => "Centre.",
        Land => "Linear ramp from centre to `floor_us` over `ramp`." {
            floor_us: u16 => "Final throttle pulse, µs.",
            ramp: Duration => "Ramp duration.",
        },
    }

    /// A validated Naza-M output.
    #[derive(Debug, Clone, PartialEq)]
    pub struct NazaConfig {
        pwm: PwmVehicleConfig => "The generic PWM vehicle (channels in the order A, E, T, R, U).",
        failsafe_mode: Mode => "The mode the failsafe selects (ASSISTED = ATTI, AUTO = GPS).",
        failsafe_throttle: FailsafeThrottle => "The throttle policy in failsafe.",
        csc: CscPattern => "The CSC corners.",
        csc_hold: Duration => "How long the CSC is held.",
    }
}

impl NazaConfig {
    /// Index of the throttle channel in the generic config.
    pub const THROTTLE: usize = 2;
    /// Index of the mode (U) channel in the generic config.
    pub const MODE: usize = 4;
}

/// (preset table name, source), in the generic channel order.
const CHANNELS: [(&str, ChannelSourceKind); 5] = [
    ("aileron", ChannelSourceKind::Roll),
    ("elevator", ChannelSourceKind::Pitch),
    ("throttle", ChannelSourceKind::Throttle),
    ("rudder", ChannelSourceKind::Yaw),
    ("mode", ChannelSourceKind::Mode),
];

impl NazaSettings {
    fn safe_mode(&self) -> Mode {
        self.failsafe_mode.unwrap_or(FailsafeMode::Atti).into()
    }

    /// The equivalent generic channels (A, E, T, R, U; missing tables count as empty so their
    /// address errors are reported too). The throttle gets a slew limit unless one is set, so
    /// that it never jumps when control changes hands.
    fn channels(&self) -> Vec<ChannelSettings> {
        let sticks = [&self.aileron, &self.elevator, &self.throttle, &self.rudder];
        let mut channels: Vec<ChannelSettings> = (CHANNELS[..4].iter().zip(sticks))
            .map(|((name, source), t)| t.clone().unwrap_or_default().to_channel(name, *source))
            .collect();
        let slew = &mut channels[NazaConfig::THROTTLE].map.slew_us_per_s;
        slew.get_or_insert(DEFAULT_THROTTLE_SLEW_US_PER_S);
        let m = self.mode.clone().unwrap_or_default();
        let level = |v: Option<Int>, d: Mode| v.unwrap_or(DEFAULT_LEVELS.level(d).into());
        let failsafe = match self.safe_mode() {
            Mode::Manual => m.manual_us,
            Mode::Assisted => m.atti_us,
            Mode::Auto => m.gps_us,
        };
        channels.push(ChannelSettings {
            name: Some("mode".into()),
            source: Some(ChannelSourceKind::Mode),
            address: m.address,
            levels: ModeLevelsSettings {
                manual_us: Some(level(m.manual_us, Mode::Manual)),
                assisted_us: Some(level(m.atti_us, Mode::Assisted)),
                auto_us: Some(level(m.gps_us, Mode::Auto)),
            },
            failsafe_us: Some(level(failsafe, self.safe_mode())),
            ..ChannelSettings::default()
        });
        channels
    }

    /// Validates into a [`NazaConfig`], filling the section's defaults into `self`.
    ///
    /// # Errors
    /// [`rove_core::Error::Config`] listing every problem, keyed as written in `[output]`
    /// (`aileron.pin`, `mode.atti_us`, `land_throttle_us`…).
    pub fn validate(&mut self) -> rove_core::Result<NazaConfig> {
        let mut errors = ConfigErrors::default();
        self.unknown.check(&mut errors, Self::KNOWN);
        let names = CHANNELS.map(|c| c.0);
        let sticks = [&self.aileron, &self.elevator, &self.throttle, &self.rudder];
        let sticks = sticks.map(|t| t.as_ref().map(|t| &t.unknown));
        preset_tables(&mut errors, &names[..4], &sticks, StickSettings::KNOWN);
        let mode = [self.mode.as_ref().map(|m| &m.unknown)];
        preset_tables(&mut errors, &names[4..], &mode, ModeChannelSettings::KNOWN);
        let hold_ms = *self.csc_hold_ms.get_or_insert(DEFAULT_CSC_HOLD_MS);
        let hold = errors.int("csc_hold_ms", hold_ms, CSC_HOLD_RANGE_MS, " ms");
        let policy = *self.failsafe_policy.get_or_insert(FailsafePolicy::Hover);
        self.failsafe_mode.get_or_insert(FailsafeMode::Atti);
        self.csc.get_or_insert(CscPattern::Outer);
        if policy == FailsafePolicy::Hover {
            let rule = "only applies with failsafe_policy = \"land\"";
            errors.not_for("land_throttle_us", self.land_throttle_us, rule);
            errors.not_for("land_ramp_ms", self.land_ramp_ms, rule);
        }
        let ramp_ms = self.land_ramp_ms.unwrap_or(DEFAULT_LAND_RAMP_MS);
        let ramp = errors.int("land_ramp_ms", ramp_ms, LAND_RAMP_RANGE_MS, " ms");
        let mut channels = self.channels();
        let pwm = self.pwm.vehicle(&mut channels, ConfigErrors::default());
        let failsafe_throttle = match (policy, &pwm) {
            (FailsafePolicy::Hover, _) | (_, Err(_)) => FailsafeThrottle::Hover,
            (FailsafePolicy::Land, Ok(pwm)) => {
                let (min, centre) = match pwm.channels[NazaConfig::THROTTLE].source {
                    ChannelSource::Axis(_, map) => (map.min_us(), map.centre_us()),
                    // The throttle channel is built as an axis above.
                    _ => (1000, 1500),
                };
                let default_floor =
                    f64::from(centre) - DEFAULT_LAND_FRACTION * f64::from(centre - min);
                let floor_us = *(self.land_throttle_us).get_or_insert(default_floor.round() as Int);
                self.land_ramp_ms = Some(ramp_ms);
                if !(Int::from(min)..Int::from(centre)).contains(&floor_us) {
                    let rule = format!(
                        "must be at least throttle.min_us ({min}) and below the throttle \
                         centre ({centre}), or the aircraft would not descend"
                    );
                    errors.add("land_throttle_us", floor_us, rule);
                }
                let floor_us = u16::try_from(floor_us).unwrap_or(min);
                let ramp = Duration::from_millis(ramp.unwrap_or_default());
                FailsafeThrottle::Land { floor_us, ramp }
            }
        };
        let config = pwm.map(|pwm| NazaConfig {
            pwm,
            failsafe_mode: self.safe_mode(),
            failsafe_throttle,
            csc: self.csc.unwrap_or(CscPattern::Outer),
            csc_hold: Duration::from_millis(hold.unwrap_or_default()),
        });
        finish_preset(errors, config, |e| rename(e, &names))
    }
}

/// Rewrites `channels[i]` to the preset's table name, and the U channel's generic level keys
/// to the Naza's names.
fn rename(e: ConfigError, names: &[&str]) -> ConfigError {
    let mut e = rename_channels(e, names);
    let naza = |s: &str| {
        s.replace("assisted_us", "atti_us")
            .replace("auto_us", "gps_us")
    };
    if ["mode.assisted_us", "mode.auto_us"].contains(&e.key.as_str()) {
        e.key = naza(&e.key);
    }
    e.rule = naza(&e.rule);
    e
}

#[cfg(test)]
mod tests {
    use super::*;

    const MINIMAL: &str =
        "backend = \"sim\"\n[aileron]\n[elevator]\n[throttle]\n[rudder]\n[mode]\n";

    fn parse(text: &str) -> NazaSettings {
        toml::from_str(text).expect("parses")
    }

    fn errors(text: &str) -> String {
        parse(text).validate().expect_err("invalid").to_string()
    }

    #[test]
    fn defaults() {
        let cfg = parse(MINIMAL).validate().expect("valid");
        assert_eq!(cfg.failsafe_mode, Mode::Assisted);
        assert_eq!(cfg.failsafe_throttle, FailsafeThrottle::Hover);
        assert_eq!(cfg.csc, CscPattern::Outer);
        assert_eq!(cfg.csc_hold, Duration::from_millis(1500));
        let names: Vec<&str> = cfg.pwm.channels.iter().map(|c| c.name.as_str()).collect();
        assert_eq!(names, ["aileron", "elevator", "throttle", "rudder", "mode"]);
        assert_eq!(cfg.pwm.channels[NazaConfig::MODE].failsafe_us, 1500);
        let cfg = parse(&MINIMAL.replace(
            "backend = \"sim\"",
            "backend = \"sim\"\nfailsafe_policy = \"land\"\nfailsafe_mode = \"gps\"",
        ))
        .validate()
        .expect("valid");
        assert_eq!(
            cfg.failsafe_throttle,
            FailsafeThrottle::Land {
                floor_us: 1300,
                ramp: Duration::from_millis(3000)
            }
        );
        assert_eq!(cfg.pwm.channels[NazaConfig::MODE].failsafe_us, 1900);
    }

    #[test]
    fn errors_use_the_naza_key_names() {
        let err = errors(
            "backend = \"sim\"\n[aileron]\n[elevator]\n[throttle]\nmax_us = 900\n[rudder]\n\
             [mode]\natti_us = 1100",
        );
        assert!(err.contains("throttle.centre_us = 1500"), "{err}");
        assert!(
            err.contains("mode.atti_us = 1100: must differ from manual_us"),
            "{err}"
        );
        let err = errors(
            "backend = \"rppal\"\n[aileron]\npin = 5\n[elevator]\npin = 5\n[throttle]\npin = 6\n[rudder]\npin = 7\n[mode]\npin = 99",
        );
        assert!(
            err.contains("elevator.pin = GPIO5: must be unique: aileron drives the same output"),
            "{err}"
        );
        assert!(err.contains("mode.pin = 99"), "{err}");
    }

    #[test]
    fn rejects_bad_land_and_csc_settings_and_missing_tables() {
        let err = errors(
            "backend = \"sim\"\nfailsafe_policy = \"land\"\nland_throttle_us = 1500\nland_ramp_ms = 10\n\
             csc_hold_ms = 0\n[aileron]\n[elevator]\n[throttle]\n[rudder]\n[mode]",
        );
        for want in [
            "land_throttle_us = 1500: must be at least throttle.min_us (1000) and below the throttle centre (1500)",
            "land_ramp_ms = 10: must be 100..=60000 ms",
            "csc_hold_ms = 0: must be 200..=5000 ms",
        ] {
            assert!(err.contains(want), "missing {want:?} in\n{err}");
        }
        let err = errors(&format!("land_throttle_us = 1200\n{MINIMAL}"));
        assert_eq!(
            err,
            "land_throttle_us = 1200: only applies with failsafe_policy = \"land\""
        );
        let err = errors("backend = \"sim\"\n[aileron]\n[elevator]\n[throttle]\n[rudder]");
        assert_eq!(
            err,
            "mode = (absent): must give [output.mode] with its output (pin, pwm_channel or chip/channel)"
        );
        let err = errors(&MINIMAL.replace("[mode]", "[mode]\nassisted_us = 1500"));
        assert!(
            err.starts_with("mode.assisted_us = 1500: unknown key, expected one of `chip`"),
            "{err}"
        );
        assert!(toml::from_str::<NazaSettings>("failsafe_policy = \"drop\"").is_err());
    }

    #[test]
    fn csc_patterns_put_both_sticks_at_the_bottom() {
        for p in [
            CscPattern::Outer,
            CscPattern::Inner,
            CscPattern::Left,
            CscPattern::Right,
        ] {
            let m = MovementCommand::from(p);
            assert_eq!((m.throttle, m.pitch), (-i16::MAX, -i16::MAX), "{p:?}");
            assert_eq!(m.roll.abs(), i16::MAX);
            assert_eq!(m.yaw.abs(), i16::MAX);
        }
        assert_eq!(MovementCommand::from(CscPattern::Outer).yaw, -i16::MAX);
        assert_eq!(MovementCommand::from(CscPattern::Outer).roll, i16::MAX);
        assert_eq!(MovementCommand::from(CscPattern::Inner).yaw, i16::MAX);
        assert_eq!(MovementCommand::from(CscPattern::Inner).roll, -i16::MAX);
    }
}
