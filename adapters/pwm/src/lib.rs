//! `rove-pwm`: servo-style PWM output for rove — one backend interface with Linux sysfs,
//! Raspberry Pi (rppal) and simulated devices, and the **config-defined PWM vehicle**: a new
//! vehicle type is a list of channels in TOML, no code.
//!
//! # Layout
//! - [`config`]: `[output]` as written ([`PwmVehicleSettings`]) and validated
//!   ([`PwmVehicleConfig`]).
//! - [`backend`]: the [`PwmBackend`] trait and the recording [`SimBackend`]; `open.rs`:
//!   [`open_backend`], the backend a config names.
//! - [`sysfs`]: `/sys/class/pwm` ([`SysfsBackend`]).
//! - `rppal` (feature `rppal`): Raspberry Pi hardware and software PWM (`RppalBackend`).
//! - [`vehicle`]: [`PwmVehicle`], the [`rove_core::adapter::OutputAdapter`].
//! - `kind.rs`: [`Pwm`], the adapter as the gateway offers it ([`rove_core::adapter::OutputKind`]).
//!
//! This crate does no arbitration and reads no clock: time comes in as `now`. It never
//! depends on the gateway.
//!
//! # Config keys (`[output]`, `adapter = "pwm"`)
//!
//! | key | where | meaning |
//! |---|---|---|
//! | `backend` | section | `"sysfs"`, `"rppal"` or `"sim"` (required) |
//! | `period_us` | section | PWM period, µs (default 20000 = 50 Hz) |
//! | `sysfs_root`, `chip` | section, sysfs only | PWM class dir (default `/sys/class/pwm`), default chip (0) |
//! | `name` | channel | unique name (required) |
//! | `source` | channel | `throttle`, `roll`, `pitch`, `yaw`, `mode`, `constant` (required) |
//! | `chip`, `channel` | channel, sysfs | `pwmchip{chip}/pwm{channel}` |
//! | `pin` / `pwm_channel` | channel, rppal | software PWM on BCM GPIO 0..=27 / hardware PWM 0..=1 |
//! | `polarity` | channel, sysfs or `pwm_channel` | `"normal"` / `"inversed"` (default: untouched) |
//! | `min_us` … `slew_us_per_s` | channel, axis sources | [`rove_core::mapping`] keys (`reverse` also as `invert`, `deadband_pct` also as `deadzone_pct`) |
//! | `manual_us`, `assisted_us`, `auto_us` | channel, `mode` | levels (default 1000/1500/2000) |
//! | `value_us` | channel, `constant` | the pulse |
//! | `failsafe_us` | channel | safe-state pulse (default: centre / ASSISTED level / `value_us`) |
//!
//! The sim backend accepts any one address form or none, so a Pi config runs on a laptop by
//! changing only `backend`.
//!
//! # Known limitations (intentional, not bugs)
//! - sysfs writes `period` before `duty_cycle`. A channel left by another program with a duty
//!   cycle longer than our period fails setup (`EINVAL`, fatal); write `0` to its
//!   `duty_cycle` once.
//! - sysfs `polarity` is written before `enable`; a driver that refuses polarity changes on a
//!   channel left enabled reports `EBUSY` (transient) until the channel is disabled.
//! - Hardware PWM channel 0 and software PWM on its GPIO (12 or 18) are not detected as the
//!   same output: which GPIO a PWM channel uses depends on the Pi's overlay.
//! - A vehicle whose safe state cannot be written at start does not start
//!   ([`PwmVehicle::new`] fails): the gateway reports it and exits or retries.
//! - sysfs and rppal leave the last pulse on the pin after exit (the safe state, written on
//!   drop). rppal software PWM stops with the process, since its timing thread ends.

#![deny(missing_docs)]

pub mod backend;
pub mod config;
mod kind;
mod open;
#[cfg(all(feature = "rppal", target_os = "linux"))]
pub mod rppal;
pub mod sysfs;
pub mod vehicle;

pub use backend::{PulseRecord, PwmBackend, SimBackend, SimLog};
pub use config::{
    BackendConfig, BackendKind, ChannelAddress, ChannelConfig, ChannelSettings, ChannelSource,
    ChannelSourceKind, Polarity, PwmAddressSettings, PwmBackendSettings, PwmVehicleConfig,
    PwmVehicleSettings, ServoChannelSettings,
};
pub use kind::Pwm;
pub use open::open_backend;
pub use sysfs::SysfsBackend;
pub use vehicle::PwmVehicle;
