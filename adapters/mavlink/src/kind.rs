//! `[output] adapter = "mavlink"` as the gateway offers it: [`Mavlink`], and the validated
//! [`MavlinkConfig`] as an [`OutputSpec`].

use crate::config::{Endpoint, MavlinkConfig, MavlinkSettings};
use rove_core::MonoTime;
use rove_core::adapter::{HostedOperator, Need, OutputAdapter, OutputKind, OutputSpec};
use rove_core::error::LinkError;
use std::path::PathBuf;

/// An ArduPilot or PX4 autopilot over MAVLink.
#[derive(Debug, Clone, Copy)]
pub struct Mavlink;

impl OutputKind for Mavlink {
    const NAME: &'static str = "mavlink";
    const SUMMARY: &'static str =
        "An ArduPilot or PX4 autopilot over MAVLink (RC override or MANUAL_CONTROL).";
    type Settings = MavlinkSettings;

    fn validate(settings: &mut MavlinkSettings) -> rove_core::Result<Box<dyn OutputSpec>> {
        Ok(Box::new(settings.validate()?))
    }
}

impl OutputSpec for MavlinkConfig {
    fn open(&self, now: MonoTime) -> Result<Box<dyn OutputAdapter>, LinkError> {
        Ok(Box::new(crate::MavlinkVehicle::new(self.clone(), now)?))
    }

    /// The autopilot must be found first, and its safe mode confirmed.
    fn failsafe(&self) -> Result<String, LinkError> {
        crate::failsafe(self)
    }

    /// The serial port, if the link is one, and the file where the link keeps the autopilot's
    /// address and ids for `rove failsafe`.
    fn needs(&self) -> Vec<Need> {
        let mut needs = vec![Need::Memory];
        if let Endpoint::Serial { device, .. } = &self.endpoint {
            needs.push(Need::Serial(device.clone()));
        }
        needs
    }

    fn remember_in(&mut self, file: PathBuf) {
        self.memory = Some(file);
    }

    fn clone_spec(&self) -> Box<dyn OutputSpec> {
        Box::new(self.clone())
    }

    /// The ground stations with an `id`: operators of the hierarchy.
    fn hosted(&self) -> Vec<HostedOperator> {
        (self.gcs.iter().filter_map(|g| g.station.as_ref()))
            .map(|s| HostedOperator {
                id: s.id,
                name: s.name.clone(),
                level: s.level,
                class: s.class,
                security: s.security.clone(),
                link: s.feed.clone(),
            })
            .collect()
    }
}
