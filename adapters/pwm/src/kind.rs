//! `[output] adapter = "pwm"` as the gateway offers it: [`Pwm`], and the validated
//! [`PwmVehicleConfig`] as an [`OutputSpec`] (the Eyedrive and Naza adapters reuse both).

use crate::config::{BackendConfig, ChannelAddress, PwmVehicleConfig, PwmVehicleSettings};
use rove_core::MonoTime;
use rove_core::adapter::{Need, OutputAdapter, OutputKind, OutputSpec};
use rove_core::error::LinkError;

/// The config-defined PWM vehicle: a new vehicle type is a list of channels in TOML.
#[derive(Debug, Clone, Copy)]
pub struct Pwm;

impl OutputKind for Pwm {
    const NAME: &'static str = "pwm";
    const SUMMARY: &'static str =
        "A PWM vehicle described by its channel list (a new vehicle type needs only TOML).";
    type Settings = PwmVehicleSettings;

    fn validate(settings: &mut PwmVehicleSettings) -> rove_core::Result<Box<dyn OutputSpec>> {
        Ok(Box::new(settings.validate()?))
    }
}

impl OutputSpec for PwmVehicleConfig {
    fn open(&self, now: MonoTime) -> Result<Box<dyn OutputAdapter>, LinkError> {
        let backend = crate::open_backend(self)?;
        Ok(Box::new(crate::PwmVehicle::new(
            self.clone(),
            backend,
            now,
        )?))
    }

    fn needs(&self) -> Vec<Need> {
        let root = match &self.backend {
            BackendConfig::Rppal => return vec![Need::RaspberryPi],
            BackendConfig::Sim => return Vec::new(),
            BackendConfig::Sysfs { root } => root,
        };
        (self.channels.iter())
            .filter_map(|c| match c.address {
                ChannelAddress::Sysfs { chip, channel } => Some(Need::PwmChannel {
                    name: c.name.clone(),
                    root: root.clone(),
                    chip,
                    channel,
                }),
                _ => None,
            })
            .collect()
    }

    fn clone_spec(&self) -> Box<dyn OutputSpec> {
        Box::new(self.clone())
    }
}
