//! `[output] adapter = "can"` as the gateway offers it: [`Can`], and the validated
//! [`CanConfig`] as an [`OutputSpec`].

use crate::config::{CanConfig, CanSettings};
use rove_core::MonoTime;
use rove_core::adapter::{Need, OutputAdapter, OutputKind, OutputSpec};
use rove_core::error::LinkError;

/// CAN servos and ESCs.
#[derive(Debug, Clone, Copy)]
pub struct Can;

impl OutputKind for Can {
    const NAME: &'static str = "can";
    const SUMMARY: &'static str =
        "CAN servos and ESCs: raw frames defined by config, DroneCAN actuator commands.";
    type Settings = CanSettings;

    fn validate(settings: &mut CanSettings) -> rove_core::Result<Box<dyn OutputSpec>> {
        Ok(Box::new(settings.validate()?))
    }
}

impl OutputSpec for CanConfig {
    fn open(&self, now: MonoTime) -> Result<Box<dyn OutputAdapter>, LinkError> {
        let bus = crate::open_bus(self)?;
        Ok(Box::new(crate::CanVehicle::new(self.clone(), bus, now)?))
    }

    fn needs(&self) -> Vec<Need> {
        vec![Need::Can(self.interface.clone())]
    }

    fn clone_spec(&self) -> Box<dyn OutputSpec> {
        Box::new(self.clone())
    }
}
