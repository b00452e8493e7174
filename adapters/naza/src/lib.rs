//! `rove-naza`: the DJI Naza-M flight controller preset on [`rove_pwm`] — the A/E/T/R stick
//! channels (roll, pitch, throttle, yaw) and the U mode-switch channel, driven by servo PWM as
//! a receiver would, with motor start/stop by the combination stick command (CSC) and a hover
//! or land failsafe.
//!
//! **Safety.** Remove the propellers for every first test. The Naza starts its motors on a CSC
//! and, with its default "Immediately" stop type, **stops them in the air** when throttle falls
//! under 10 % after take-off: never configure `land_throttle_us` under 10 % of the throttle
//! range unless the Naza's stop type is "Intelligent".
//!
//! # Layout
//! - [`config`]: `[output]` for `adapter = "naza"` ([`NazaSettings`] → [`NazaConfig`]).
//! - [`vehicle`]: [`NazaVehicle`], the [`rove_core::adapter::OutputAdapter`], with the CSC and
//!   land-ramp state machine on an injected clock.
//! - [`error`]: the crate's error type, [`NazaError`].
//! - [`Naza`]: the adapter as the gateway offers it ([`rove_core::adapter::OutputKind`]).
//!
//! No I/O here beyond the backend opened with [`rove_pwm::open_backend`].
//!
//! # Channels and defaults
//!
//! | table | Naza input | source | default | failsafe |
//! |---|---|---|---|---|
//! | `[output.aileron]` | A | roll | 1000/1500/2000 µs | centre |
//! | `[output.elevator]` | E | pitch | 1000/1500/2000 µs | centre |
//! | `[output.throttle]` | T | throttle | 1000/1500/2000 µs, slew 1000 µs/s | centre (hold altitude) or land ramp |
//! | `[output.rudder]` | R | yaw | 1000/1500/2000 µs | centre |
//! | `[output.mode]` | U | mode | MANUAL→Manual 1100, ASSISTED→ATTI 1500, AUTO→GPS 1900 µs | ATTI (or GPS) |
//!
//! The U levels are those a Naza-M calibrated on a common 3-position switch sees (low = Manual,
//! middle = ATTI, high = GPS); set `manual_us`/`atti_us`/`gps_us` to what the Naza Assistant
//! shows for your setup.
//!
//! Section keys: `backend` (required), `period_us`, `sysfs_root`, `chip` (as for `pwm`);
//! `failsafe_mode` = `"atti"` | `"gps"` (default atti); `failsafe_policy` = `"hover"` | `"land"`
//! (default hover); `land_throttle_us` (default: 40 % of the way from centre down to min, 1300
//! µs with defaults — a steady descent in ATTI/GPS that stays clear of the Naza's 10 % motor
//! cut); `land_ramp_ms` (default 3000); `csc` = `"outer"` | `"inner"` | `"left"` | `"right"`
//! (default outer); `csc_hold_ms` (default 1500).
//!
//! # Known limitations (intentional, not bugs)
//! - Stick directions assume +roll = right, +pitch = forward (stick up), +yaw = right,
//!   +throttle = up, as the operator sends them. A transmitter-style reversal is set with
//!   `reverse` per channel; the CSC goes through the same maps, so a correctly flying setup
//!   also gives a correct CSC.
//! - `start_motors` and `stop_motors` both send the CSC: the Naza toggles. Which one happens
//!   depends on the Naza's state, which PWM cannot read back.
//! - The land policy only lowers the throttle stick; the Naza judges the landing. With the
//!   default floor it does not cut the motors on the ground: send `stop_motors` (or set a floor
//!   under 10 % with the "Intelligent" stop type).
//! - The land ramp and the end of a CSC need time to pass: the gateway calls
//!   [`rove_core::adapter::OutputAdapter::keepalive`] every
//!   [`rove_core::adapter::OutputAdapter::keepalive_period`] in **every** state (or at
//!   [`NazaVehicle::next_deadline`]).
//! - On drop the hover values are written whatever the policy (the process is ending; the
//!   kernel holds the last sysfs pulse).

#![deny(missing_docs)]

pub mod config;
pub mod error;
pub mod vehicle;

pub use config::{CscPattern, FailsafeMode, FailsafePolicy, NazaConfig, NazaSettings};
pub use error::NazaError;
pub use vehicle::{MotorCommand, NazaState, NazaVehicle};

use rove_core::MonoTime;
use rove_core::adapter::{Need, OutputAdapter, OutputKind, OutputSpec};
use rove_core::error::LinkError;

/// `[output] adapter = "naza"`.
#[derive(Debug, Clone, Copy)]
pub struct Naza;

impl OutputKind for Naza {
    const NAME: &'static str = "naza";
    const SUMMARY: &'static str = "The DJI Naza-M multirotor autopilot: A/E/T/R/U channels.";
    type Settings = NazaSettings;

    fn validate(settings: &mut NazaSettings) -> rove_core::Result<Box<dyn OutputSpec>> {
        Ok(Box::new(settings.validate()?))
    }
}

impl OutputSpec for NazaConfig {
    fn open(&self, now: MonoTime) -> Result<Box<dyn OutputAdapter>, LinkError> {
        let backend = rove_pwm::open_backend(&self.pwm)?;
        Ok(Box::new(NazaVehicle::new(self.clone(), backend, now)?))
    }

    fn needs(&self) -> Vec<Need> {
        self.pwm.needs()
    }

    fn clone_spec(&self) -> Box<dyn OutputSpec> {
        Box::new(self.clone())
    }
}
