//! A vehicle's file (`rove vehicle`): `[vehicle]`, `[access]`, `[output]` (read in two steps so that
//! errors inside an adapter's settings keep their lines) and the validated [`VehicleConfig`].

use super::*;

rove_core::config_types! {
    /// `[vehicle]`.
    pub table VehicleSection {
        command_timeout_ms: Option<Int> => "Owner silence before re-arbitration (absent: 100).",
        output_deadline_ms: Option<Int> => "A device call (a PWM write, a MAVLink send) running \
            longer counts as a hung output, ms (absent: 50).",
        output_hung_limit_ms: Option<Int> => "How long an output may stay hung before the \
            watchdog keep-alives stop and systemd restarts the unit, ms (absent: 2000).",
        battery_low_pct: Option<Int> => "At or below this battery level (percent, as the \
            output's device reports it: an autopilot's SYS_STATUS) every console that sees the \
            vehicle warns (absent: 25).",
    }

    /// `[access]`: who may drive this vehicle. Absent: any id, at any strength inside the
    /// hierarchy (docs/design.md §4b).
    pub table AccessSection {
        #[serde(default)] operators: Vec<Grant> => "The operators allowed to drive, each with \
            the highest level and device class it may claim (`[[access.operators]]`).",
    }

    /// `[output]`: `adapter` names the output adapter; the other keys are that adapter's.
    ///
    /// Files are not read through this tagged enum (serde buffers a tagged table and loses
    /// every line inside it) but through `parse_vehicle`; it remains for errors about
    /// `adapter` itself.
    #[derive(Debug, Clone, Serialize, Deserialize)]
    #[serde(tag = "adapter", rename_all = "lowercase")]
    pub enum OutputSection {
        Sim => "Records outputs in memory, for tests, demos and benchmarks (`--record` writes \
            them out)." (SimSection),
        Pwm => "A PWM vehicle described by its channel list (a new vehicle type needs only \
            TOML)." (Box<rove_pwm::PwmVehicleSettings>),
        Eyedrive => "The Eyedrive UGV: steering and throttle servos."
            (Box<rove_eyedrive::EyedriveSettings>),
        Naza => "The DJI Naza-M multirotor autopilot: A/E/T/R/U channels."
            (Box<rove_naza::NazaSettings>),
        Mavlink => "An ArduPilot or PX4 autopilot over MAVLink (RC override or MANUAL_CONTROL)."
            (Box<rove_mavlink::MavlinkSettings>),
        Can => "CAN servos and ESCs: raw frames defined by config, DroneCAN actuator commands."
            (Box<rove_can::CanSettings>),
    }

    /// `[output] adapter = "sim"` takes no other keys.
    #[derive(Debug, Clone, Default, Serialize, Deserialize)]
    #[serde(deny_unknown_fields)]
    pub struct SimSection {}

    /// A validated output adapter choice.
    #[derive(Debug, Clone)]
    pub enum OutputConfig {
        Sim => "The core's recording sim output.",
        Pwm => "A config-defined PWM vehicle." (rove_pwm::PwmVehicleConfig),
        Eyedrive => "The Eyedrive preset (a PWM vehicle underneath)." (rove_pwm::PwmVehicleConfig),
        Naza => "The Naza-M." (rove_naza::NazaConfig),
        Mavlink => "A MAVLink autopilot." (Box<rove_mavlink::MavlinkConfig>),
        Can => "A CAN bus." (Box<rove_can::CanConfig>),
    }
}

impl OutputSection {
    pub(super) fn validate(&mut self, errors: &mut ConfigErrors) -> OutputConfig {
        let config = match self {
            OutputSection::Sim(_) => Ok(OutputConfig::Sim),
            OutputSection::Pwm(s) => s.validate().map(OutputConfig::Pwm),
            OutputSection::Eyedrive(s) => s.validate().map(OutputConfig::Eyedrive),
            OutputSection::Naza(s) => s.validate().map(OutputConfig::Naza),
            OutputSection::Mavlink(s) => s.validate().map(|c| OutputConfig::Mavlink(Box::new(c))),
            OutputSection::Can(s) => s.validate().map(|c| OutputConfig::Can(Box::new(c))),
        };
        errors
            .section("output", config)
            .unwrap_or(OutputConfig::Sim)
    }
}

/// Reads a vehicle file in two steps so that errors inside `[output]` keep their lines: first
/// `adapter`, then the same text, with the `adapter` key blanked (every byte offset and line
/// unchanged), as that adapter's settings. An unknown or missing adapter is reported by the
/// tagged [`OutputSection`].
pub(super) fn parse_vehicle(path: &Path, text: &str) -> anyhow::Result<RawVehicle<OutputSection>> {
    #[derive(Deserialize)]
    struct Probe {
        output: Option<ProbeOutput>,
    }
    #[derive(Deserialize)]
    struct ProbeOutput {
        adapter: Option<toml::Spanned<String>>,
    }
    pub(super) fn read<T: for<'de> Deserialize<'de>>(
        path: &Path,
        text: &str,
        wrap: fn(T) -> OutputSection,
    ) -> anyhow::Result<RawVehicle<OutputSection>> {
        let file: RawVehicle<T> = parse(path, text)?;
        Ok(RawVehicle {
            device: file.device,
            network: file.network,
            log: file.log,
            vehicle: file.vehicle,
            hierarchy: file.hierarchy,
            access: file.access,
            security: file.security,
            output: wrap(file.output),
        })
    }
    let probe: Probe = parse(path, text)?;
    let Some(adapter) = probe.output.and_then(|o| o.adapter) else {
        return parse(path, text);
    };
    let blanked = blank_key_value(text, adapter.span());
    match adapter.get_ref().as_str() {
        "sim" => read(path, &blanked, OutputSection::Sim),
        "pwm" => read(path, &blanked, |s| OutputSection::Pwm(Box::new(s))),
        "eyedrive" => read(path, &blanked, |s| OutputSection::Eyedrive(Box::new(s))),
        "naza" => read(path, &blanked, |s| OutputSection::Naza(Box::new(s))),
        "mavlink" => read(path, &blanked, |s| OutputSection::Mavlink(Box::new(s))),
        "can" => read(path, &blanked, |s| OutputSection::Can(Box::new(s))),
        _ => parse(path, text),
    }
}

/// `text` with the key/value pair whose value spans `value` replaced by spaces (newlines
/// kept), together with the comma that separates it in an inline table.
pub(super) fn blank_key_value(text: &str, value: std::ops::Range<usize>) -> String {
    let bytes = text.as_bytes();
    let is_key = |b: u8| b.is_ascii_alphanumeric() || b"_-.\"' \t=".contains(&b);
    let mut start = value.start.min(bytes.len());
    while start > 0 && is_key(bytes[start - 1]) {
        start -= 1;
    }
    let mut end = value.end.min(bytes.len());
    let after = text[end..].trim_start_matches([' ', '\t']);
    if after.starts_with(',') {
        end = text.len() - after.len() + 1;
    } else if text[..start].trim_end_matches([' ', '\t']).ends_with(',') {
        start = text[..start].trim_end_matches([' ', '\t']).len() - 1;
    }
    // One space per byte (newlines kept), so no offset or line after the blank moves.
    let blank: String = (text[start..end].chars())
        .flat_map(|c| std::iter::repeat_n(if c == '\n' { c } else { ' ' }, c.len_utf8()))
        .collect();
    format!("{}{blank}{}", &text[..start], &text[end..])
}

rove_core::config_types! {
    /// A vehicle's file as written. `[output]` is `O`: the tagged [`OutputSection`], or one
    /// adapter's settings while `parse_vehicle` reads it.
    pub table RawVehicle<O> {
        device: DeviceSection => "`[device]`.",
        #[serde(default)] network: NetworkSection => "`[network]`.",
        #[serde(default)] log: LogSection => "`[log]`.",
        #[serde(default)] vehicle: VehicleSection => "`[vehicle]`.",
        #[serde(default)] hierarchy: HierarchyTable => "`[hierarchy]`: the strengths operators \
            may have (absent: docs/design.md §3).",
        access: Option<AccessSection> => "`[access]`: who may drive.",
        security: Option<SecuritySection> => "`[security]`.",
        output: O => "`[output]`.",
    }

    /// A validated vehicle configuration.
    #[derive(Debug, Clone)]
    pub struct VehicleConfig {
        common: Common => "Identity and network.",
        arbiter: ArbiterConfig => "Arbiter settings.",
        access: Access => "The ids and strengths this vehicle believes.",
        output: OutputConfig => "Output adapter.",
        output_deadline: Duration => "`[vehicle] output_deadline_ms`.",
        output_hung_limit: Duration => "`[vehicle] output_hung_limit_ms`.",
        battery_low_pct: u8 => "`[vehicle] battery_low_pct`.",
    }
}

/// Reads and validates a vehicle config.
///
/// # Errors
/// The file cannot be read, is not valid TOML, has unknown keys, or has invalid values; the
/// message names the file, line and key.
pub fn load_vehicle(path: &Path) -> anyhow::Result<VehicleConfig> {
    let text = read(path)?;
    let mut raw = parse_vehicle(path, &text)?;
    let mut config = raw.validate().map_err(|e| located(path, &text, e))?;
    config.common.resolve_paths(path);
    Ok(config)
}

impl RawVehicle<OutputSection> {
    /// Validates, filling defaults.
    ///
    /// # Errors
    /// [`rove_core::Error::Config`] listing every invalid key.
    pub fn validate(&mut self) -> rove_core::Result<VehicleConfig> {
        let mut errors = ConfigErrors::default();
        let mut common =
            validate_common(&mut self.device, &mut self.network, &self.log, &mut errors);
        common.security = self.security.as_ref().map(|s| s.dir.clone());
        let output = self.output.validate(&mut errors);
        let key = "vehicle.command_timeout_ms";
        let default = CommandTimeout::DEFAULT.get().as_millis();
        let millis = *(self.vehicle.command_timeout_ms).get_or_insert(default as Int);
        let timeout = errors
            .int(key, millis, 0..=Int::MAX, "")
            .and_then(|ms| errors.section("", CommandTimeout::from_millis(key, ms)));
        let v = &mut self.vehicle;
        let deadline = *v.output_deadline_ms.get_or_insert(50);
        let deadline = errors.int("vehicle.output_deadline_ms", deadline, 5..=10_000, " ms");
        let limit = *v.output_hung_limit_ms.get_or_insert(2000);
        let limit = errors.int("vehicle.output_hung_limit_ms", limit, 100..=600_000, " ms");
        let low = *v.battery_low_pct.get_or_insert(25);
        let low = errors.int::<u8>("vehicle.battery_low_pct", low, 0..=100, " %");
        let hierarchy = errors.section("hierarchy", Hierarchy::from_table(&self.hierarchy));
        let hierarchy = hierarchy.unwrap_or(Hierarchy::STANDARD);
        let access = match &self.access {
            None => Access::open(hierarchy),
            Some(section) => {
                let mut unique = Unique::default();
                for (i, entry) in section.operators.iter().enumerate() {
                    let key = format!("access.operators[{i}].id");
                    if entry.id <= 0 {
                        errors.add(&key, entry.id, "must be a positive device id");
                    }
                    let shown = (key.as_str(), entry.id);
                    unique.check(&mut errors, entry.id, format!("operators[{i}]"), shown, "");
                }
                Access::listed(hierarchy, &section.operators)
            }
        };
        errors.into_result(VehicleConfig {
            arbiter: ArbiterConfig {
                command_timeout: timeout.unwrap_or(CommandTimeout::DEFAULT),
                trust: common.trust(),
                ..ArbiterConfig::default()
            },
            common,
            access,
            output,
            output_deadline: Duration::from_millis(deadline.unwrap_or_default()),
            output_hung_limit: Duration::from_millis(limit.unwrap_or_default()),
            battery_low_pct: low.unwrap_or_default(),
        })
    }
}
