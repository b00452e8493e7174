//! `rove-inputs`: the operator's input devices — evdev joysticks, gamepads and keyboards —
//! mapped by config to [`InputEvent`]s (sticks, deadman, actions, lost), with the safety rules
//! that keep a stale input from driving a vehicle.
//!
//! `rove operator` builds an [`InputConfig`] from its `[input]` table
//! ([`InputSettings::validate`]), opens it with [`open`] and polls the returned
//! [`InputSource`]. What the operator must do with each event:
//!
//! | event | operator |
//! |---|---|
//! | `Axes(m)` | drive with `m` at once (the source already applied deadzone, expo, deadman and the no-jump rule); after a `Lost` or `Deadman(false)` the next `Axes` means "live again" |
//! | `Deadman(false)` | stop driving and release control explicitly |
//! | `Deadman(true)` | may drive again; an `Axes` follows |
//! | `Lost { reason }` | stop driving and release control explicitly; show the reason |
//! | `Action(a)` | mode change, request / accept / refuse / finish, release, vehicle selection |
//! | `Err(LinkError)` | as `Lost`; a fatal one (the device lacks a mapped control) is not retried |
//!
//! # Layout
//! - [`config`]: `[input]` settings, validation (errors name keys such as
//!   `axes.throttle.deadzone_pct`), the validated [`InputConfig`].
//! - [`mapper`]: the pure state machine: raw events → `InputEvent`s; frames, deadman, lost,
//!   no-jump, key ramps, silence timeout. No I/O, no clock.
//! - [`curve`]: pure axis math: calibration, invert, deadzone, expo, scale, clamp; key ramps.
//! - [`codes`]: evdev type and code names, raw events, button-like controls.
//! - [`replay`]: recordings (text and raw `input_event` binary) and [`ReplaySource`].
//! - [`ros2`]: [`Ros2Source`], a ROS 2 `sensor_msgs/Joy` topic fed to the mapper as a joystick.
//! - [`device`]: the thin evdev layer: device selection, reader thread, [`list_devices`].
//! - [`error`]: recording errors.
//!
//! Everything but [`device`] is pure and tested through [`ReplaySource`] with recordings in
//! `tests/recordings/`. The crate forbids `unsafe` and never panics on device or file input.

#![deny(missing_docs)]
#![forbid(unsafe_code)]

pub mod codes;
pub mod config;
pub mod curve;
pub mod device;
pub mod error;
pub mod mapper;
pub mod replay;
pub mod ros2;

pub use codes::{Control, RawEvent};
pub use config::{InputConfig, InputSettings, SourceConfig, SourceKind};
pub use device::{EvdevSource, InputWaker, ListedDevice, list_devices};
pub use error::{Error, Result};
pub use mapper::{DeviceEvent, InputStatus, LinkState, Mapper};
pub use replay::{Recording, ReplaySource};
pub use ros2::Ros2Source;

use rove_core::adapter::{InputEvent, InputSource};
use rove_core::error::LinkError;
use rove_core::time::MonoTime;

/// An opened input: a replay or an evdev device, with status and wake-up on top of
/// [`InputSource`].
#[derive(Debug)]
pub enum MappedSource {
    /// A recording.
    Replay(ReplaySource),
    /// An evdev device.
    Evdev(EvdevSource),
    /// A ROS 2 Joy topic.
    Ros2(Box<Ros2Source>),
}

impl MappedSource {
    /// Link state, mapped stick values, held buttons: for status displays and
    /// `rove inputs show`.
    pub fn status(&self) -> InputStatus {
        match self {
            MappedSource::Replay(s) => s.status(),
            MappedSource::Evdev(s) => s.status(),
            MappedSource::Ros2(s) => s.status(),
        }
    }

    /// Sets the function a device's reader thread calls when events are queued, so the
    /// caller can poll at once instead of on its next tick. A replay needs none: its
    /// [`InputSource::next_deadline`] says when to poll.
    pub fn set_waker(&mut self, waker: InputWaker) {
        if let MappedSource::Evdev(s) = self {
            s.set_waker(waker);
        }
    }
}

impl InputSource for MappedSource {
    fn describe(&self) -> String {
        match self {
            MappedSource::Replay(s) => s.describe(),
            MappedSource::Evdev(s) => s.describe(),
            MappedSource::Ros2(s) => s.describe(),
        }
    }

    fn poll(&mut self, now: MonoTime) -> Result<Option<InputEvent>, LinkError> {
        match self {
            MappedSource::Replay(s) => s.poll(now),
            MappedSource::Evdev(s) => s.poll(now),
            MappedSource::Ros2(s) => s.poll(now),
        }
    }

    fn next_deadline(&self) -> Option<MonoTime> {
        match self {
            MappedSource::Replay(s) => s.next_deadline(),
            MappedSource::Evdev(s) => s.next_deadline(),
            MappedSource::Ros2(s) => s.next_deadline(),
        }
    }
}

/// Opens the source `config` describes, as a concrete [`MappedSource`].
///
/// A device that is not plugged in yet is no error: the source reports `Lost` and keeps
/// looking.
///
/// # Errors
/// A fatal [`LinkError`] when a recording cannot be read or parsed (naming the file and line),
/// or a device reader thread cannot be started.
pub fn open_mapped(config: &InputConfig) -> Result<MappedSource, LinkError> {
    match &config.source {
        SourceConfig::Replay { file } => ReplaySource::open(file, config.mapping.clone())
            .map(MappedSource::Replay)
            .map_err(|e| LinkError::fatal(e.to_string())),
        SourceConfig::Evdev {
            selector,
            grab,
            reopen_interval,
        } => EvdevSource::spawn(
            selector.clone(),
            *grab,
            *reopen_interval,
            config.mapping.clone(),
        )
        .map(MappedSource::Evdev),
        SourceConfig::Ros2 { .. } => Ros2Source::open(&config.source, config.mapping.clone())
            .map(|s| MappedSource::Ros2(Box::new(s))),
    }
}

/// Opens the source `config` describes.
///
/// # Errors
/// As [`open_mapped`].
pub fn open(config: &InputConfig) -> Result<Box<dyn InputSource + Send>, LinkError> {
    open_mapped(config).map(|s| Box::new(s) as Box<dyn InputSource + Send>)
}
