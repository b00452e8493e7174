//! A vehicle's file (`rove vehicle`): `[vehicle]`, `[access]`, `[output]` (read by `output.rs`
//! in two steps so that errors inside an adapter's settings keep their lines) and the validated
//! [`VehicleConfig`].

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

impl<O> RawVehicle<O> {
    /// The same file with `[output]` read as `wrap` makes it.
    pub(super) fn with_output<P>(self, wrap: impl FnOnce(O) -> P) -> RawVehicle<P> {
        RawVehicle {
            device: self.device,
            network: self.network,
            log: self.log,
            vehicle: self.vehicle,
            hierarchy: self.hierarchy,
            access: self.access,
            security: self.security,
            output: wrap(self.output),
        }
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
