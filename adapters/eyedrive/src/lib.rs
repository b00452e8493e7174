//! `rove-eyedrive`: the Eyedrive UGV preset on [`rove_pwm`] — steering (from the roll axis) and
//! throttle to the rover's servo controller and ESC, so that its config names only the
//! outputs.
//!
//! **Safety.** The rover's wheels turn as soon as the ESC sees a pulse away from neutral. Test
//! with the wheels off the ground, and check that neutral (1500 µs unless configured) stops
//! the motor before first driving.
//!
//! # Layout
//! - [`config`]: `[output]` for `adapter = "eyedrive"` ([`EyedriveSettings`]), validated into
//!   the generic [`rove_pwm::PwmVehicleConfig`] that [`rove_pwm::PwmVehicle`] drives.
//!
//! - [`Eyedrive`]: the adapter as the gateway offers it ([`rove_core::adapter::OutputKind`]).
//!
//! No I/O here: the validated config opens through [`rove_pwm`].
//!
//! # Channels
//!
//! | table | source | default map | failsafe |
//! |---|---|---|---|
//! | `[output.steering]` | roll | 1000 / 1500 / 2000 µs | centre (straight) |
//! | `[output.throttle]` | throttle | 1000 / 1500 / 2000 µs | centre (neutral: stopped) |
//!
//! Each table takes one address (`pin`, `pwm_channel`, or `chip`/`channel` by backend) and,
//! optionally, `polarity` and the mapping keys of [`rove_core::mapping`] (`min_us`, `centre_us`,
//! `max_us`, `trim_us`, `reverse`, `deadband_pct`, `expo`, `slew_us_per_s`). The section takes
//! `backend` (required), `period_us`, `sysfs_root` and `chip` as for `adapter = "pwm"`.
//!
//! # Known limitations (intentional, not bugs)
//! - The failsafe is always neutral (the trimmed centre); there is no `failsafe_us`: a rover
//!   that rolls on in failsafe is never what is wanted.
//! - Neutral is written once at start and held until the first command. An ESC that needs
//!   neutral for longer than the operator takes to start driving arms late; the gateway does
//!   not delay the first command.
//! - No slew limit by default: a stop command must act at once. Set `slew_us_per_s` on
//!   `throttle` for gentler starts (it slows stops too; only the failsafe bypasses it).

#![deny(missing_docs)]

pub mod config;

pub use config::{EyedriveChannelSettings, EyedriveSettings};

use rove_core::adapter::{OutputKind, OutputSpec};

/// `[output] adapter = "eyedrive"`: the preset validates into a [`rove_pwm::PwmVehicleConfig`],
/// which opens and reports itself as `adapter = "pwm"` does.
#[derive(Debug, Clone, Copy)]
pub struct Eyedrive;

impl OutputKind for Eyedrive {
    const NAME: &'static str = "eyedrive";
    const SUMMARY: &'static str = "The Eyedrive UGV: steering and throttle servos.";
    type Settings = EyedriveSettings;

    fn validate(settings: &mut EyedriveSettings) -> rove_core::Result<Box<dyn OutputSpec>> {
        Ok(Box::new(settings.validate()?))
    }
}
