//! Opening the backend a config names: apart from the backends, which know only the
//! [`PwmBackend`] trait, so that neither depends on the other.

use crate::backend::PwmBackend;
use crate::config::{BackendConfig, PwmVehicleConfig};
use rove_core::error::LinkError;

/// Builds the backend `config` names, with its channels.
///
/// Opening touches no device: sysfs and rppal prepare each channel at its first write, so the
/// first error (with the path or pin) comes from [`crate::PwmVehicle::new`]'s safe-state write.
///
/// # Errors
/// A fatal [`LinkError`] for `backend = "rppal"` in a build without the `rppal` feature, or
/// when rppal cannot open the GPIO peripheral.
pub fn open_backend(config: &PwmVehicleConfig) -> Result<Box<dyn PwmBackend + Send>, LinkError> {
    match &config.backend {
        BackendConfig::Sysfs { root } => Ok(Box::new(crate::sysfs::SysfsBackend::new(
            root.clone(),
            config,
        ))),
        BackendConfig::Sim => Ok(Box::new(crate::backend::SimBackend::for_config(config))),
        BackendConfig::Rppal => open_rppal(config),
    }
}

#[cfg(all(feature = "rppal", target_os = "linux"))]
fn open_rppal(config: &PwmVehicleConfig) -> Result<Box<dyn PwmBackend + Send>, LinkError> {
    Ok(Box::new(crate::rppal::RppalBackend::new(config)?))
}

#[cfg(not(all(feature = "rppal", target_os = "linux")))]
fn open_rppal(_config: &PwmVehicleConfig) -> Result<Box<dyn PwmBackend + Send>, LinkError> {
    Err(LinkError::fatal(
        "backend = \"rppal\": this rove was built without the `rppal` feature \
         (rebuild with `--features rove-pwm/rppal` on the Pi, or use backend = \"sysfs\")",
    ))
}
