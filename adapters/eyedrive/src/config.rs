//! `[output]` for `adapter = "eyedrive"`: the raw settings and their validation into a generic
//! PWM vehicle config. Errors name the Eyedrive keys (`steering.max_us`), not the generic
//! channel list.

use rove_core::config::UnknownKeys;
use rove_core::error::ConfigErrors;
use rove_pwm::config::{finish_preset, preset_tables, rename_channels};
use rove_pwm::{ChannelSourceKind, PwmBackendSettings, PwmVehicleConfig};

rove_core::config_types! {
    /// `[output]` for the Eyedrive, as written.
    pub settings EyedriveSettings {
        #[serde(flatten)] pwm: PwmBackendSettings => "rove-pwm's backend keys.",
        steering: Option<EyedriveChannelSettings> => "`[output.steering]`.",
        throttle: Option<EyedriveChannelSettings> => "`[output.throttle]`.",
        #[serde(flatten)] unknown: UnknownKeys => "Keys nothing above took (see `validate`).",
    }
}

/// `[output.steering]` / `[output.throttle]`: the address, and optional limits (defaults
/// 1000/1500/2000 µs, neutral as failsafe).
pub type EyedriveChannelSettings = rove_pwm::ServoChannelSettings;

/// The generic channel order the preset builds; error keys are translated back by it.
const CHANNELS: [(&str, ChannelSourceKind); 2] = [
    ("steering", ChannelSourceKind::Roll),
    ("throttle", ChannelSourceKind::Throttle),
];

impl EyedriveSettings {
    /// Validates into the generic PWM vehicle config: steering from roll, throttle from
    /// throttle, both failing safe to neutral (a missing table counts as empty, so that its
    /// address errors are reported too). The backend keys' defaults are filled into `self`.
    ///
    /// # Errors
    /// [`rove_core::Error::Config`] listing every problem, keyed as written in `[output]`
    /// (`steering.pin`, `throttle.max_us`, `backend`…).
    pub fn validate(&mut self) -> rove_core::Result<PwmVehicleConfig> {
        let mut errors = ConfigErrors::default();
        self.unknown.check(&mut errors, Self::KNOWN);
        let tables = [&self.steering, &self.throttle];
        let unknown = tables.map(|t| t.as_ref().map(|t| &t.unknown));
        let names = CHANNELS.map(|c| c.0);
        preset_tables(
            &mut errors,
            &names,
            &unknown,
            EyedriveChannelSettings::KNOWN,
        );
        let mut channels: Vec<_> = (CHANNELS.iter().zip(tables))
            .map(|((name, source), t)| t.clone().unwrap_or_default().to_channel(name, *source))
            .collect();
        let config = self.pwm.vehicle(&mut channels, ConfigErrors::default());
        finish_preset(errors, config, |e| rename_channels(e, &names))
    }
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
    fn unknown_keys_are_rejected_naming_their_table() {
        for (text, want) in [
            (
                "failsafe_us = 1500\n[steering]\n[throttle]",
                "failsafe_us = 1500: unknown key, expected one of `backend`",
            ),
            (
                "[steering]\nfailsafe_us = 1500\n[throttle]",
                "steering.failsafe_us = 1500: unknown key, expected one of `chip`",
            ),
            (
                "[steering]\n[throttle]\nsource = \"yaw\"",
                "throttle.source = \"yaw\": unknown key",
            ),
        ] {
            let err = errors(&format!("backend = \"sim\"\n{text}"));
            assert!(err.contains(want), "missing {want:?} in\n{err}");
            assert_eq!(err.lines().count(), 1, "{err}");
        }
    }
}
