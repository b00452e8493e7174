//! The `[output]` section of a config-defined PWM vehicle: the raw serde structs (which only
//! parse and reject unknown keys) and `validate()`, which checks every key, collects every
//! problem and returns the validated [`PwmVehicleConfig`]. The keys are described in the crate
//! docs.
//!
//! Keys of errors are relative to the `[output]` table, e.g. `channels[2].max_us`; the gateway
//! puts `output.` in front.

use rove_core::config::{ABSENT, Int, Unique, UnknownKeys};
use rove_core::error::{ConfigError, ConfigErrors};
use rove_core::mapping::{
    Axis, AxisMap, AxisMapSettings, ModeLevels, ModeLevelsSettings, PULSE_RANGE_US, pulse,
};
use rove_core::msg::Mode;
use std::path::PathBuf;
use std::time::Duration;

/// Default PWM period in µs: 20 ms (50 Hz), the frame rate every analogue servo, ESC and RC
/// flight controller accepts. Shorter periods (digital servos at 333 Hz) are configurable;
/// an analogue servo driven faster than it expects can overheat.
pub const DEFAULT_PERIOD_US: u32 = 20_000;

/// Accepted PWM periods, µs: 2.5 ms (400 Hz) to 100 ms (10 Hz). Outside this no RC device
/// understands the signal; inside, every pulse must still be shorter than the period.
pub const PERIOD_RANGE_US: std::ops::RangeInclusive<Int> = 2_500..=100_000;

/// Default root of the Linux PWM class in sysfs.
pub const DEFAULT_SYSFS_ROOT: &str = "/sys/class/pwm";

/// BCM GPIO numbers usable for software PWM on the Raspberry Pi's 40-pin header.
pub const GPIO_PIN_RANGE: std::ops::RangeInclusive<i64> = 0..=27;

/// Hardware PWM channels of the Raspberry Pi (PWM0, PWM1).
pub const HARDWARE_PWM_CHANNEL_RANGE: std::ops::RangeInclusive<i64> = 0..=1;

/// Default levels of a generic `source = "mode"` channel: a three-position switch at the
/// servo standard's ends and centre. Device presets (Naza-M) bring their own.
pub const DEFAULT_MODE_LEVELS: ModeLevels = ModeLevels::new(1000, 1500, 2000);

rove_core::config_types! {
    /// Which PWM device drives the channels.
    pub keyword BackendKind {
        Sysfs => "Linux `/sys/class/pwm` (any board with a kernel PWM driver, RaMstix included).",
        Rppal => "Raspberry Pi hardware PWM and software PWM on GPIO, via rppal.",
        Sim => "Records pulses in memory.",
    }

    /// What a channel outputs, as written in `source = …`; the axis it outputs, if any.
    pub keyword ChannelSourceKind -> Option<Axis> {
        Throttle => "The throttle axis." = Some(Axis::Throttle),
        Roll => "The roll axis (UGV steering)." = Some(Axis::Roll),
        Pitch => "The pitch axis." = Some(Axis::Pitch),
        Yaw => "The yaw axis." = Some(Axis::Yaw),
        Mode => "The mode, as one of three levels." = None,
        Constant => "A fixed pulse (`value_us`)." = None,
    }

    /// Output polarity, as the kernel's sysfs `polarity` file spells it (the word written there).
    pub keyword Polarity -> &'static str {
        Normal => "Active high (the pulse is high)." = "normal",
        Inversed => "Active low, for an inverting level shifter." = "inversed",
    }

    /// The backend keys of `[output]`, as written: the one definition shared by `adapter = "pwm"`,
    /// `"eyedrive"` and `"naza"` (flattened into each).
    pub table PwmBackendSettings {
        backend: Option<BackendKind> => "Which device drives the channels.",
        period_us: Option<Int> => "PWM period, µs.",
        sysfs_root: Option<PathBuf> => "sysfs: the PWM class directory.",
        chip: Option<Int> => "sysfs: the `pwmchipN` of channels that name no `chip`.",
    }

    /// Where a channel is wired, as written: the one definition of the address keys, shared by
    /// generic channels and the preset tables (flattened into each).
    pub table PwmAddressSettings {
        chip: Option<Int> => "sysfs: the `pwmchipN`.",
        channel: Option<Int> => "sysfs: the channel within the chip (`pwmchipN/pwmM`).",
        pin: Option<Int> => "rppal: software PWM on this BCM GPIO pin.",
        pwm_channel: Option<Int> => "rppal: hardware PWM channel.",
        polarity: Option<Polarity> => "sysfs and rppal hardware PWM: output polarity.",
    }

    /// `[output]` for `adapter = "pwm"`, as written.
    pub settings PwmVehicleSettings {
        #[serde(flatten)] pwm: PwmBackendSettings => "The backend keys.",
        #[serde(default)] channels: Vec<ChannelSettings> => "`[[output.channels]]`.",
        #[serde(flatten)] unknown: UnknownKeys => "Keys nothing above took (see `validate`).",
    }

    /// A servo channel of a preset vehicle (the Eyedrive's steering and throttle, the Naza-M's
    /// sticks): where it is wired, and optional limits. Presets turn it into a generic
    /// [`ChannelSettings`] with [`ServoChannelSettings::to_channel`], so the keys and their rules
    /// are the generic channel's.
    pub settings ServoChannelSettings {
        #[serde(flatten)] address: PwmAddressSettings => "The address keys.",
        #[serde(flatten)] map: AxisMapSettings => "The mapping keys.",
        #[serde(flatten)] unknown: UnknownKeys => "Keys nothing above (see [`preset_tables`]).",
    }
}

impl ServoChannelSettings {
    /// The generic channel `name` fed from `source`; its failsafe is the generic default (the
    /// trimmed centre).
    pub fn to_channel(&self, name: &str, source: ChannelSourceKind) -> ChannelSettings {
        ChannelSettings {
            name: Some(name.to_string()),
            source: Some(source),
            address: self.address.clone(),
            map: self.map,
            ..ChannelSettings::default()
        }
    }
}

rove_core::config_types! {
    /// One `[[output.channels]]` table, as written.
    pub settings ChannelSettings {
        name: Option<String> => "Unique name, for logs and status.",
        source: Option<ChannelSourceKind> => "What the channel outputs.",
        value_us: Option<Int> => "`source = \"constant\"`: the pulse, µs.",
        failsafe_us: Option<Int> => "Pulse in the safe state, µs.",
        #[serde(flatten)] address: PwmAddressSettings => "The address keys.",
        #[serde(flatten)] map: AxisMapSettings => "Axis sources: the mapping keys.",
        #[serde(flatten)] levels: ModeLevelsSettings => "`source = \"mode\"`: the levels.",
        #[serde(flatten)] unknown: UnknownKeys => "Keys nothing above took (see `validate`).",
    }
}

rove_core::config_types! {
    /// Where a channel is wired.
    #[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
    pub enum ChannelAddress {
        Sysfs => "sysfs `pwmchip{chip}/pwm{channel}`." {
            chip: u32 => "Chip number.",
            channel: u32 => "Channel within the chip.",
        },
        GpioPin => "rppal software PWM on a BCM GPIO pin." (u8),
        HardwarePwm => "rppal hardware PWM channel." (u8),
        Unaddressed => "Sim backend channel named by nothing but its position.",
    }
}

impl std::fmt::Display for ChannelAddress {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            ChannelAddress::Sysfs { chip, channel } => write!(f, "pwmchip{chip}/pwm{channel}"),
            ChannelAddress::GpioPin(pin) => write!(f, "GPIO{pin}"),
            ChannelAddress::HardwarePwm(ch) => write!(f, "PWM{ch}"),
            ChannelAddress::Unaddressed => f.write_str("unaddressed"),
        }
    }
}

rove_core::config_types! {
    /// What drives a validated channel.
    #[derive(Debug, Clone, Copy, PartialEq)]
    pub enum ChannelSource {
        Axis => "A movement axis through its map (and slew limiter)." (Axis, AxisMap),
        Mode => "The mode, as levels." (ModeLevels),
        Constant => "A fixed pulse, µs." (u16),
    }

    /// A validated channel.
    #[derive(Debug, Clone, PartialEq)]
    pub struct ChannelConfig {
        name: String => "The channel's name.",
        address: ChannelAddress => "Where it is wired.",
        polarity: Option<Polarity> => "Polarity to set, if configured.",
        source: ChannelSource => "What drives it.",
        failsafe_us: u16 => "Its safe-state pulse, µs.",
    }

    /// Validated backend choice with its options.
    #[derive(Debug, Clone, PartialEq, Eq)]
    pub enum BackendConfig {
        Sysfs => "sysfs under `root`." {
            root: PathBuf => "The PWM class directory.",
        },
        Rppal => "rppal.",
        Sim => "In-memory recording.",
    }

    /// A validated PWM vehicle: only this type crosses crate boundaries.
    #[derive(Debug, Clone, PartialEq)]
    pub struct PwmVehicleConfig {
        backend: BackendConfig => "The backend and its options.",
        period: Duration => "The PWM period.",
        channels: Vec<ChannelConfig> => "The channels, in config order (as backends index them).",
    }
}

impl PwmVehicleConfig {
    /// Every channel's address, in order: what a backend is opened with.
    pub fn addresses(&self) -> Vec<ChannelAddress> {
        self.channels.iter().map(|c| c.address).collect()
    }
}

const ONLY_SYSFS: &str = "only applies to backend = \"sysfs\"";

impl PwmVehicleSettings {
    /// Validates, filling defaults into `self`; keys in errors are relative to `[output]`.
    ///
    /// # Errors
    /// As [`PwmBackendSettings::vehicle`].
    pub fn validate(&mut self) -> rove_core::Result<PwmVehicleConfig> {
        let mut errors = ConfigErrors::default();
        self.unknown.check(&mut errors, Self::KNOWN);
        self.pwm.vehicle(&mut self.channels, errors)
    }
}

impl PwmBackendSettings {
    /// The vehicle these backend keys drive through `channels` (`[[output.channels]]`, or a
    /// preset's tables as generic channels), filling defaults into both; `errors` holds the
    /// problems the caller found first.
    ///
    /// # Errors
    /// [`rove_core::Error::Config`] listing every key that breaks a rule of the crate docs'
    /// key table, does not apply to its backend or source, or repeats a name or an address.
    pub fn vehicle(
        &mut self,
        channels: &mut [ChannelSettings],
        mut errors: ConfigErrors,
    ) -> rove_core::Result<PwmVehicleConfig> {
        let backend_kind = self.backend.unwrap_or_else(|| {
            errors.absent("backend", "must be one of \"sysfs\", \"rppal\", \"sim\"");
            BackendKind::Sim
        });
        let period_us = *self.period_us.get_or_insert(DEFAULT_PERIOD_US.into());
        let rule = " µs (400 Hz to 10 Hz)";
        errors.int::<u32>("period_us", period_us, PERIOD_RANGE_US, rule);
        if backend_kind == BackendKind::Sysfs {
            self.sysfs_root
                .get_or_insert_with(|| DEFAULT_SYSFS_ROOT.into());
            self.chip.get_or_insert(0);
        } else {
            let root = (self.sysfs_root.as_ref()).map(|r| format!("{:?}", r.display().to_string()));
            errors.not_for("sysfs_root", root, ONLY_SYSFS);
            errors.not_for("chip", self.chip, ONLY_SYSFS);
        }
        let chip = errors.opt_int("chip", self.chip, 0..=u32::MAX.into(), "");
        let default_chip = chip.unwrap_or(0);
        if channels.is_empty() {
            let rule = "must list at least one channel ([[output.channels]])";
            errors.add("channels", "[]", rule);
        }
        let (mut validated, mut names, mut addresses) =
            (Vec::new(), Unique::default(), Unique::default());
        for (i, raw) in channels.iter_mut().enumerate() {
            let owner = format!("channels[{i}]");
            let channel = errors.within(&owner, |errors| {
                let channel = raw.validate(backend_kind, default_chip, period_us, errors);
                if let Some(name) = raw.name.clone() {
                    let shown = ("name", format!("{name:?}"));
                    names.check(errors, name, &owner, shown, "has the same name");
                }
                let addressed = channel.as_ref().map(|c| c.address);
                if let Some(a) = addressed.filter(|a| *a != ChannelAddress::Unaddressed) {
                    let key = (raw.address.address_key(), a);
                    addresses.check(errors, a, &owner, key, "drives the same output");
                }
                channel
            });
            validated.extend(channel);
        }
        let backend = match backend_kind {
            BackendKind::Sysfs => BackendConfig::Sysfs {
                root: self.sysfs_root.clone().unwrap_or_default(),
            },
            BackendKind::Rppal => BackendConfig::Rppal,
            BackendKind::Sim => BackendConfig::Sim,
        };
        errors.into_result(PwmVehicleConfig {
            backend,
            period: Duration::from_micros(period_us.unsigned_abs()),
            channels: validated,
        })
    }
}

impl PwmAddressSettings {
    /// The key a duplicate-address error is filed under: the one that names the device.
    fn address_key(&self) -> &'static str {
        match (self.pin, self.pwm_channel) {
            (Some(_), _) => "pin",
            (None, Some(_)) => "pwm_channel",
            (None, None) => "channel",
        }
    }

    /// The validated address for `backend`, recording every problem.
    fn validate(
        &self,
        backend: BackendKind,
        default_chip: u32,
        errors: &mut ConfigErrors,
    ) -> Option<ChannelAddress> {
        let gpio = " (BCM GPIO number)";
        let pin = (self.pin).map(|v| errors.int("pin", v, GPIO_PIN_RANGE, gpio));
        let hw_rule = " (Raspberry Pi hardware PWM channel)";
        let hw = (self.pwm_channel)
            .map(|v| errors.int("pwm_channel", v, HARDWARE_PWM_CHANNEL_RANGE, hw_rule));
        let sysfs_given = self.chip.is_some() || self.channel.is_some();
        if usize::from(pin.is_some()) + usize::from(hw.is_some()) + usize::from(sysfs_given) > 1 {
            let shown = self.pin.map_or(ABSENT.into(), |p| p.to_string());
            let rule = "give one address: `pin`, `pwm_channel`, or `chip`/`channel`";
            errors.add("pin", shown, rule);
            return None;
        }
        // The one address key given (checked above), the channel's before the chip's.
        let keys = [("pin", self.pin), ("pwm_channel", self.pwm_channel)];
        let keys = keys
            .into_iter()
            .chain([("channel", self.channel), ("chip", self.chip)]);
        let given = keys.filter_map(|(key, v)| v.map(|v| (key, v))).next();
        let u32_range = 0..=Int::from(u32::MAX);
        match (backend, given) {
            (BackendKind::Sysfs, Some((key @ ("pin" | "pwm_channel"), v))) => {
                let rule =
                    "only applies to backend = \"rppal\"; sysfs channels take `chip` and `channel`";
                errors.add(key, v, rule);
                None
            }
            (BackendKind::Rppal, Some((key @ ("channel" | "chip"), v))) => {
                let rule = "only applies to backend = \"sysfs\"; rppal channels take `pin` or \
                            `pwm_channel`";
                errors.add(key, v, rule);
                None
            }
            (_, Some(("pin", _))) => {
                if backend == BackendKind::Rppal {
                    let rule = "software PWM on a GPIO pin has no polarity setting; use a \
                                hardware `pwm_channel` or invert externally";
                    errors.not_for("polarity", self.polarity.map(<&str>::from), rule);
                }
                pin.flatten().map(ChannelAddress::GpioPin)
            }
            (_, Some(("pwm_channel", _))) => hw.flatten().map(ChannelAddress::HardwarePwm),
            (BackendKind::Rppal, None) => {
                let rule = "must give `pin` (software PWM) or `pwm_channel` (hardware PWM) for \
                            backend = \"rppal\"";
                errors.absent("pin", rule);
                None
            }
            // Sim takes any one address form (so that a Pi config runs on a laptop by changing
            // only `backend`), or none.
            (BackendKind::Sim, None) => Some(ChannelAddress::Unaddressed),
            // `chip`/`channel`, given or (sysfs) required.
            _ => {
                let chip = match self.chip {
                    Some(c) => errors.int("chip", c, u32_range.clone(), "")?,
                    None => default_chip,
                };
                let Some(channel) = self.channel else {
                    let rule = "must name the channel within the chip (pwmchipN/pwmM) for \
                                backend = \"sysfs\"";
                    errors.absent("channel", rule);
                    return None;
                };
                let channel = errors.int("channel", channel, u32_range, "")?;
                Some(ChannelAddress::Sysfs { chip, channel })
            }
        }
    }
}

impl ChannelSettings {
    fn validate(
        &mut self,
        backend: BackendKind,
        default_chip: u32,
        period_us: Int,
        errors: &mut ConfigErrors,
    ) -> Option<ChannelConfig> {
        self.unknown.check(errors, Self::KNOWN);
        let name = match self.name.as_deref() {
            Some(n) if !n.trim().is_empty() => Some(n.to_string()),
            other => {
                let shown = format!("{:?}", other.unwrap_or(ABSENT));
                errors.add("name", shown, "must be a non-empty name");
                None
            }
        };
        let address = self.address.validate(backend, default_chip, errors);
        let Some(kind) = self.source else {
            let rule = "must be one of throttle, roll, pitch, yaw, mode, constant";
            errors.absent("source", rule);
            return None;
        };
        let kind_name = format!("{kind:?}").to_lowercase();
        let rule = format!("does not apply to source = \"{kind_name}\"");
        let not_for = |errors: &mut ConfigErrors, given: Vec<(&str, String)>| {
            (given.into_iter()).for_each(|(key, v)| errors.add(key, v, rule.as_str()))
        };
        if kind != ChannelSourceKind::Constant {
            errors.not_for("value_us", self.value_us, &rule);
        }
        let levels = self.levels.given().into_iter();
        let levels = levels.map(|(k, v)| (k, v.to_string()));
        // (source, the failsafe's range, highest pulse it can output, default failsafe)
        let (source, range, hi, default_failsafe) = match kind {
            ChannelSourceKind::Mode => {
                not_for(errors, self.map.given());
                let levels = errors.section("", self.levels.validate(DEFAULT_MODE_LEVELS))?;
                let hi = Mode::ALL.map(|m| levels.level(m)).into_iter().max();
                let (source, assisted) =
                    (ChannelSource::Mode(levels), levels.level(Mode::Assisted));
                // A mode channel may fail safe to any level the device understands.
                (source, PULSE_RANGE_US, hi.unwrap_or(0), assisted)
            }
            ChannelSourceKind::Constant => {
                not_for(errors, self.map.given().into_iter().chain(levels).collect());
                let Some(v) = self.value_us else {
                    errors.absent("value_us", "must give the pulse for source = \"constant\"");
                    return None;
                };
                let v = pulse(errors, "value_us", v)?;
                (ChannelSource::Constant(v), v.into()..=v.into(), v, v)
            }
            axis => {
                not_for(errors, levels.collect());
                let axis = Option::from(axis).unwrap_or(Axis::Yaw);
                let map = errors.section("", self.map.validate())?;
                let source = ChannelSource::Axis(axis, map);
                let range = map.min_us().into()..=map.max_us().into();
                (source, range, map.max_us(), map.centre_us())
            }
        };
        let given_failsafe = self.failsafe_us.is_some();
        let failsafe_us = *self.failsafe_us.get_or_insert(default_failsafe.into());
        if !range.contains(&failsafe_us) {
            let (lo, hi) = (range.start(), range.end());
            let rule = format!("must be within the channel's range {lo}..={hi} µs");
            errors.add("failsafe_us", failsafe_us, rule);
        }
        let highest = Int::from(hi).max(failsafe_us);
        if highest >= period_us {
            let key = match source {
                _ if given_failsafe && failsafe_us >= period_us => "failsafe_us",
                ChannelSource::Axis(..) => "max_us",
                ChannelSource::Mode(_) => "auto_us",
                ChannelSource::Constant(_) => "value_us",
            };
            let rule = format!("must be shorter than the PWM period ({period_us} µs)");
            errors.add(key, highest, rule);
        }
        Some(ChannelConfig {
            name: name?,
            address: address?,
            polarity: self.address.polarity,
            source,
            failsafe_us: u16::try_from(failsafe_us).ok()?,
        })
    }
}

/// Checks a preset's channel tables (`[output.NAME]` for each of `names`): each must be given,
/// and may hold only the keys of `known`.
pub fn preset_tables(
    errors: &mut ConfigErrors,
    names: &[&str],
    tables: &[Option<&UnknownKeys>],
    known: &[&[&str]],
) {
    for (name, table) in names.iter().zip(tables) {
        match table {
            None => {
                let rule = "with its output (pin, pwm_channel or chip/channel)";
                errors.absent(name, format!("must give [output.{name}] {rule}"));
            }
            Some(unknown) => errors.within(name, |e| unknown.check(e, known)),
        }
    }
}

/// Rewrites `channels[i]` in a generic error's key and rule to a preset's table name
/// (`names[i]`), so that errors name the keys as written.
pub fn rename_channels(mut e: ConfigError, names: &[&str]) -> ConfigError {
    for (i, name) in names.iter().enumerate() {
        let generic = format!("channels[{i}]");
        if let Some(rest) = e.key.strip_prefix(&generic) {
            e.key = format!("{name}{rest}");
        }
        e.rule = e.rule.replace(&generic, name);
    }
    e
}

/// A preset's own `errors` followed by the generic validation's, each renamed by `rename`.
///
/// # Errors
/// [`rove_core::Error::Config`] with both lists, if either has any problem.
pub fn finish_preset<T>(
    mut errors: ConfigErrors,
    generic: rove_core::Result<T>,
    rename: impl Fn(ConfigError) -> ConfigError,
) -> rove_core::Result<T> {
    match generic {
        Ok(config) => errors.into_result(config),
        Err(rove_core::Error::Config(generic)) => {
            errors.0.extend(generic.0.into_iter().map(rename));
            Err(rove_core::Error::Config(errors))
        }
        Err(other) => Err(other),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(text: &str) -> PwmVehicleSettings {
        toml::from_str(text).expect("parses")
    }

    fn errors(text: &str) -> String {
        parse(text)
            .validate()
            .expect_err("must be rejected")
            .to_string()
    }

    const SYSFS_TWO: &str = r#"
        backend = "sysfs"
        sysfs_root = "/tmp/pwm"
        [[channels]]
        name = "steering"
        source = "roll"
        channel = 0
        [[channels]]
        name = "throttle"
        source = "throttle"
        chip = 1
        channel = 0
        reverse = true
        slew_us_per_s = 2000
    "#;

    #[test]
    fn absent_keys_take_their_defaults() {
        let cfg = parse(SYSFS_TWO).validate().expect("valid");
        assert_eq!(cfg.period, Duration::from_millis(20));
        assert_eq!(
            cfg.backend,
            BackendConfig::Sysfs {
                root: PathBuf::from("/tmp/pwm")
            }
        );
        assert_eq!(
            cfg.addresses(),
            [
                ChannelAddress::Sysfs {
                    chip: 0,
                    channel: 0
                },
                ChannelAddress::Sysfs {
                    chip: 1,
                    channel: 0
                }
            ]
        );
        let steering = &cfg.channels[0];
        assert_eq!(steering.failsafe_us, 1500);
        assert_eq!(steering.polarity, None);
        assert_eq!(
            cfg.channels.iter().position(|c| c.name == "throttle"),
            Some(1)
        );
        match cfg.channels[1].source {
            ChannelSource::Axis(Axis::Throttle, map) => {
                assert_eq!(map.map(i16::MAX), 1000, "reversed");
            }
            other => panic!("unexpected source {other:?}"),
        }
    }

    #[test]
    fn sysfs_root_defaults_to_the_kernel_class() {
        let cfg = parse(&SYSFS_TWO.replace("sysfs_root = \"/tmp/pwm\"", ""))
            .validate()
            .expect("valid");
        assert_eq!(
            cfg.backend,
            BackendConfig::Sysfs {
                root: PathBuf::from("/sys/class/pwm")
            }
        );
    }

    #[test]
    fn unknown_keys_are_rejected_naming_their_key() {
        let err =
            errors("backend = \"sim\"\n[[channels]]\nname = \"a\"\nsource = \"roll\"\nmax_uss = 3");
        assert!(
            err.starts_with("channels[0].max_uss = 3: unknown key, expected one of `name`"),
            "{err}"
        );
        assert!(err.contains("`max_us`"), "lists the valid keys: {err}");
        let err =
            errors("backend = \"sim\"\nperiod = 3\n[[channels]]\nname = \"a\"\nsource = \"roll\"");
        assert!(err.starts_with("period = 3: unknown key"), "{err}");
        // The older spellings of the mapping keys are accepted.
        let cfg = parse(
            "backend = \"sim\"\n[[channels]]\nname = \"a\"\nsource = \"roll\"\ninvert = true\n\
             deadzone_pct = 10",
        )
        .validate()
        .expect("aliases");
        match cfg.channels[0].source {
            ChannelSource::Axis(_, map) => assert_eq!(map.map(i16::MAX), 1000, "reversed"),
            other => panic!("unexpected source {other:?}"),
        }
    }

    #[test]
    fn integers_out_of_any_range_name_their_key() {
        let err = errors(
            "backend = \"sim\"\nperiod_us = -5\n[[channels]]\nname = \"a\"\nsource = \"roll\"\n\
             max_us = 70000\nslew_us_per_s = -1",
        );
        for want in [
            "period_us = -5: must be 2500..=100000 µs",
            "channels[0].max_us = 70000: must be 100..=10000 µs",
            "channels[0].slew_us_per_s = -1: must be 1..=4294967295 µs/s",
        ] {
            assert!(err.contains(want), "missing {want:?} in\n{err}");
        }
    }

    #[test]
    fn rejects_pin_out_of_range_and_names_the_channel() {
        let err = errors(
            "backend = \"rppal\"\n[[channels]]\nname = \"a\"\nsource = \"roll\"\npin = 12\n\
             [[channels]]\nname = \"b\"\nsource = \"yaw\"\npin = 28\n\
             [[channels]]\nname = \"c\"\nsource = \"yaw\"\npwm_channel = 2",
        );
        assert!(
            err.contains("channels[1].pin = 28: must be 0..=27 (BCM GPIO number)"),
            "{err}"
        );
        assert!(
            err.contains("channels[2].pwm_channel = 2: must be 0..=1"),
            "{err}"
        );
        assert_eq!(err.lines().count(), 2, "{err}");
    }

    #[test]
    fn rejects_min_above_max_with_the_channel_key() {
        let err = errors(
            "backend = \"sim\"\n[[channels]]\nname = \"a\"\nsource = \"roll\"\n\
             [[channels]]\nname = \"b\"\nsource = \"roll\"\n\
             [[channels]]\nname = \"c\"\nsource = \"roll\"\nmin_us = 2100\nmax_us = 1000",
        );
        assert!(
            err.starts_with("channels[2].centre_us = 1500: centre_us + trim_us"),
            "{err}"
        );
    }

    #[test]
    fn rejects_duplicate_channel_and_duplicate_name() {
        let err = errors(
            "backend = \"sysfs\"\nchip = 2\n\
             [[channels]]\nname = \"a\"\nsource = \"roll\"\nchannel = 1\n\
             [[channels]]\nname = \"a\"\nsource = \"yaw\"\nchip = 2\nchannel = 1",
        );
        assert!(
            err.contains("channels[1].name = \"a\": must be unique: channels[0] has the same name"),
            "{err}"
        );
        assert!(
            err.contains(
                "channels[1].channel = pwmchip2/pwm1: must be unique: channels[0] drives the same output"
            ),
            "{err}"
        );
        let err = errors(
            "backend = \"rppal\"\n[[channels]]\nname = \"a\"\nsource = \"roll\"\npin = 5\n\
             [[channels]]\nname = \"b\"\nsource = \"yaw\"\npin = 5",
        );
        assert!(
            err.contains("channels[1].pin = GPIO5: must be unique"),
            "{err}"
        );
    }

    #[test]
    fn rejects_failsafe_outside_the_range_and_empty_channel_list() {
        let err = errors(
            "backend = \"sim\"\n[[channels]]\nname = \"a\"\nsource = \"throttle\"\n\
             min_us = 1100\nfailsafe_us = 1000",
        );
        assert_eq!(
            err,
            "channels[0].failsafe_us = 1000: must be within the channel's range 1100..=2000 µs"
        );
        assert_eq!(
            errors("backend = \"sim\""),
            "channels = []: must list at least one channel ([[output.channels]])"
        );
        assert!(errors("[[channels]]\nname = \"a\"\nsource = \"roll\"").starts_with("backend"));
    }

    #[test]
    fn rejects_keys_meant_for_another_backend_or_source() {
        let err = errors(
            "backend = \"rppal\"\nsysfs_root = \"/x\"\n\
             [[channels]]\nname = \"a\"\nsource = \"roll\"\nchannel = 3\n\
             [[channels]]\nname = \"m\"\nsource = \"mode\"\npin = 4\nmax_us = 1900\n\
             [[channels]]\nname = \"k\"\nsource = \"constant\"\npin = 6\n\
             [[channels]]\nname = \"p\"\nsource = \"roll\"\npin = 7\npolarity = \"inversed\"",
        );
        for want in [
            "sysfs_root = \"/x\": only applies to backend = \"sysfs\"",
            "channels[0].channel = 3: only applies to backend = \"sysfs\"",
            "channels[1].max_us = 1900: does not apply to source = \"mode\"",
            "channels[2].value_us = (absent): must give the pulse",
            "channels[3].polarity = inversed: software PWM on a GPIO pin has no polarity",
        ] {
            assert!(err.contains(want), "missing {want:?} in\n{err}");
        }
        let err = errors(
            "backend = \"sysfs\"\n[[channels]]\nname = \"a\"\nsource = \"roll\"\npin = 3\n\
             [[channels]]\nname = \"b\"\nsource = \"roll\"",
        );
        assert!(
            err.contains("channels[0].pin = 3: only applies to backend = \"rppal\""),
            "{err}"
        );
        assert!(err.contains("channels[1].channel = (absent)"), "{err}");
    }

    #[test]
    fn pulses_must_fit_in_the_period() {
        let err = errors(
            "backend = \"sim\"\nperiod_us = 2500\n[[channels]]\nname = \"a\"\nsource = \"roll\"\n\
             [[channels]]\nname = \"b\"\nsource = \"constant\"\nvalue_us = 2600",
        );
        assert!(
            err.contains(
                "channels[1].value_us = 2600: must be shorter than the PWM period (2500 µs)"
            ),
            "{err}"
        );
        assert_eq!(err.lines().count(), 1, "{err}");
        let err = errors(
            "backend = \"sim\"\nperiod_us = 0\n[[channels]]\nname = \"a\"\nsource = \"roll\"",
        );
        assert!(
            err.starts_with("period_us = 0: must be 2500..=100000"),
            "{err}"
        );
    }

    #[test]
    fn mode_and_constant_channels() {
        let cfg = parse(
            "backend = \"sim\"\n[[channels]]\nname = \"U\"\nsource = \"mode\"\nmanual_us = 1100\n\
             [[channels]]\nname = \"k\"\nsource = \"constant\"\nvalue_us = 1234",
        )
        .validate()
        .expect("valid");
        let u = &cfg.channels[0];
        assert_eq!(u.address, ChannelAddress::Unaddressed);
        assert_eq!(u.failsafe_us, 1500, "assisted level");
        match u.source {
            ChannelSource::Mode(levels) => {
                assert_eq!(levels.level(rove_core::msg::Mode::Manual), 1100);
                assert_eq!(levels.level(rove_core::msg::Mode::Auto), 2000);
            }
            other => panic!("unexpected {other:?}"),
        }
        assert_eq!(cfg.channels[1].failsafe_us, 1234);
        assert_eq!(cfg.channels[1].source, ChannelSource::Constant(1234));
        let err = errors(
            "backend = \"sim\"\n[[channels]]\nname = \"U\"\nsource = \"mode\"\nmanual_us = 1500",
        );
        assert!(
            err.starts_with("channels[0].assisted_us = 1500: must differ"),
            "{err}"
        );
    }

    #[test]
    fn collects_every_problem_at_once() {
        let err = errors(
            "backend = \"sysfs\"\nperiod_us = 1\n[[channels]]\nsource = \"roll\"\nchannel = -1\n\
             expo = 2.0",
        );
        for want in [
            "period_us = 1",
            "channels[0].name",
            "channels[0].channel = -1",
            "channels[0].expo = 2",
        ] {
            assert!(err.contains(want), "missing {want:?} in\n{err}");
        }
    }
}
