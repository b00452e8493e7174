//! `[output]` for `adapter = "eyedrive"`: the raw settings and their validation into a generic
//! PWM vehicle config. Errors name the Eyedrive keys (`steering.max_us`), not the generic
//! channel list.

use rove_core::error::{ConfigError, ConfigErrors};
use rove_pwm::{BackendKind, PwmVehicleConfig, PwmVehicleSettings, SourceKind};
use serde::{Deserialize, Serialize};
use std::path::PathBuf;

/// `[output]` for the Eyedrive, as written.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct EyedriveSettings {
    /// `"sysfs"`, `"rppal"` or `"sim"` (required).
    pub backend: Option<BackendKind>,
    /// PWM period, µs (absent: 20000).
    pub period_us: Option<u32>,
    /// sysfs only: the PWM class directory (absent: `/sys/class/pwm`).
    pub sysfs_root: Option<PathBuf>,
    /// sysfs only: default `pwmchipN` (absent: 0).
    pub chip: Option<i64>,
    /// `[output.steering]` (required).
    pub steering: Option<EyedriveChannelSettings>,
    /// `[output.throttle]` (required).
    pub throttle: Option<EyedriveChannelSettings>,
}

/// `[output.steering]` / `[output.throttle]`: the address, and optional limits (defaults
/// 1000/1500/2000 µs, neutral as failsafe).
pub type EyedriveChannelSettings = rove_pwm::ServoChannelSettings;

/// The generic channel order the preset builds; error keys are translated back by it.
const CHANNELS: [(&str, SourceKind); 2] = [
    ("steering", SourceKind::Roll),
    ("throttle", SourceKind::Throttle),
];

impl EyedriveSettings {
    /// The equivalent generic `adapter = "pwm"` settings (missing tables count as empty, so
    /// that their address errors are reported too).
    pub fn to_generic(&self) -> PwmVehicleSettings {
        let tables = [&self.steering, &self.throttle];
        PwmVehicleSettings {
            backend: self.backend,
            period_us: self.period_us,
            sysfs_root: self.sysfs_root.clone(),
            chip: self.chip,
            channels: CHANNELS
                .iter()
                .zip(tables)
                .map(|((name, source), t)| t.clone().unwrap_or_default().to_channel(name, *source))
                .collect(),
        }
    }

    /// Validates into the generic PWM vehicle config: steering from roll, throttle from
    /// throttle, both failing safe to neutral.
    ///
    /// # Errors
    /// [`rove_core::Error::Config`] listing every problem, keyed as written in `[output]`
    /// (`steering.pin`, `throttle.max_us`, `backend`…): a missing table, and everything
    /// [`PwmVehicleSettings::validate`] rejects.
    pub fn validate(&self) -> rove_core::Result<PwmVehicleConfig> {
        let mut errors = ConfigErrors::default();
        for (name, table) in [("steering", &self.steering), ("throttle", &self.throttle)] {
            if table.is_none() {
                errors.push(ConfigError::new(
                    name,
                    "(absent)",
                    format!("must give [output.{name}] with its output (pin, pwm_channel or chip/channel)"),
                ));
            }
        }
        match self.to_generic().validate() {
            Ok(config) => errors.into_result(config),
            Err(rove_core::Error::Config(generic)) => {
                errors.0.extend(
                    generic
                        .0
                        .into_iter()
                        .map(|e| rename(e, &CHANNELS.map(|c| c.0))),
                );
                Err(rove_core::Error::Config(errors))
            }
            Err(other) => Err(other),
        }
    }
}

/// Rewrites `channels[i]` in a generic error's key and rule to the preset's table name.
pub(crate) fn rename(mut e: ConfigError, names: &[&str]) -> ConfigError {
    for (i, name) in names.iter().enumerate() {
        let generic = format!("channels[{i}]");
        if let Some(rest) = e.key.strip_prefix(&generic) {
            e.key = format!("{name}{rest}");
        }
        e.rule = e.rule.replace(&generic, name);
    }
    e
}

#[cfg(test)]
mod tests {
    use super::*;

    fn errors(text: &str) -> String {
        toml::from_str::<EyedriveSettings>(text)
            .expect("parses")
            .validate()
            .expect_err("invalid")
            .to_string()
    }

    #[test]
    fn errors_name_the_eyedrive_keys() {
        let err = errors(
            "backend = \"rppal\"\n[steering]\npin = 40\n[throttle]\npin = 19\nmin_us = 1600",
        );
        assert!(err.contains("steering.pin = 40: must be 0..=27"), "{err}");
        assert!(
            err.contains("throttle.centre_us = 1500: centre_us + trim_us"),
            "{err}"
        );
        assert_eq!(err.lines().count(), 2, "{err}");
    }

    #[test]
    fn missing_tables_and_duplicate_outputs_are_rejected() {
        let err = errors("backend = \"rppal\"\n[steering]\npin = 18");
        assert!(
            err.starts_with("throttle = (absent): must give [output.throttle]"),
            "{err}"
        );
        let err = errors("backend = \"rppal\"\n[steering]\npin = 18\n[throttle]\npin = 18");
        assert!(
            err.contains("throttle.pin = GPIO18: must be unique: steering drives the same output"),
            "{err}"
        );
    }

    #[test]
    fn unknown_keys_are_rejected_at_parse() {
        for text in [
            "backend = \"sim\"\nfailsafe_us = 1500",
            "backend = \"sim\"\n[steering]\nfailsafe_us = 1500",
            "backend = \"sim\"\n[throttle]\nsource = \"yaw\"",
        ] {
            assert!(toml::from_str::<EyedriveSettings>(text).is_err(), "{text}");
        }
    }
}
