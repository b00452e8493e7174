//! The thin I/O layer over Linux evdev: choosing a device, reading it on its own thread, and
//! listing devices for `rove inputs list`.
//!
//! The reader thread opens the device chosen by a [`DeviceSelector`], sends `Connected`, the
//! absinfo of every axis and the keys held ([`DeviceEvent`] snapshots), then blocks in
//! `read(2)` and forwards every event over a bounded channel. After `SYN_DROPPED` it forwards
//! events up to the next `SYN_REPORT` (the mapper discards them) and then re-reads the kernel's
//! state as snapshots. A read error (ENODEV on unplug) is sent as `Unplugged`; the thread then
//! retries the same selector every `reopen_interval`, so a replugged device (or a by-id link
//! that reappears) resumes by itself, subject to the mapper's no-jump rule.
//!
//! Everything that decides anything lives in [`crate::mapper`]; this module cannot be run on a
//! machine without `/dev/input` and is kept small for that reason.
//!
//! # Known limitations (intentional, not bugs)
//! - A dropped [`EvdevSource`]'s thread blocks in `read(2)` until the device's next event or
//!   error and only then exits (and releases a grab): std offers no way to interrupt a blocking
//!   read without `unsafe`, which this crate forbids.
//! - Events are stamped with the time they are polled, not the kernel's time stamp (which is
//!   `CLOCK_REALTIME` and cannot be related to the caller's [`MonoTime`]).
//! - "Permission denied" is reported as a `Lost` reason and retried, not as a fatal error: udev
//!   often applies the device's permissions just after the node appears on a replug.
//!
//! # Layout
//! - this file: [`EvdevSource`], the source side of the reader thread, and the codes a
//!   mapping needs.
//! - `choose.rs`: choosing the device a selector names ([`name_matches`], [`DeviceKind`]).
//! - `reader.rs`: the reader thread: open, snapshot, read, reopen.
//! - `list.rs`: listing devices for `rove inputs list` ([`list_devices`]).

mod choose;
mod list;
mod reader;

pub use choose::{DeviceKind, name_matches};
pub use list::{DeviceSummary, ListedDevice, list_devices, list_devices_in};

use crate::codes::Control;
use crate::config::{AxisInput, DeviceSelector, MappingConfig};
use crate::mapper::{DeviceEvent, InputStatus, Mapper};
use reader::Reader;
use rove_core::adapter::{InputEvent, InputSource};
use rove_core::error::LinkError;
use rove_core::time::MonoTime;
use std::fmt;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{Receiver, TryRecvError, sync_channel};
use std::sync::{Arc, Mutex};
use std::time::Duration;

/// Where Linux puts evdev nodes.
pub const INPUT_DIR: &str = "/dev/input";

/// Capacity of the reader → source channel, in events. A busy gamepad sends ~1 000 events/s;
/// this is a second of backlog. When full, the reader blocks, the kernel's buffer fills and the
/// kernel reports `SYN_DROPPED`, which the mapper handles: no unbounded memory, no silent loss.
const CHANNEL_CAPACITY: usize = 1_024;

/// Called by the reader thread after it queued events, so an event-driven caller can poll at
/// once (e.g. `move || notify.notify_one()` with a `tokio::sync::Notify`). It must not block.
pub type InputWaker = Arc<dyn Fn() + Send + Sync>;

enum Feed {
    Event(DeviceEvent),
    Fatal(String),
}

/// An [`InputSource`] reading an evdev device on its own thread.
pub struct EvdevSource {
    mapper: Mapper,
    rx: Receiver<Feed>,
    waker: Arc<Mutex<Option<InputWaker>>>,
    stop: Arc<AtomicBool>,
    describe: String,
    fatal: Option<String>,
}

impl fmt::Debug for EvdevSource {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("EvdevSource")
            .field("describe", &self.describe)
            .field("fatal", &self.fatal)
            .finish_non_exhaustive()
    }
}

impl EvdevSource {
    /// Starts the reader thread for `selector`. The device need not exist yet: until it does,
    /// the source reports `Lost` and keeps looking every `reopen_interval`.
    ///
    /// # Errors
    /// A fatal [`LinkError`] if the thread cannot be started.
    pub fn spawn(
        selector: DeviceSelector,
        grab: bool,
        reopen_interval: Duration,
        mapping: MappingConfig,
    ) -> Result<Self, LinkError> {
        let (tx, rx) = sync_channel(CHANNEL_CAPACITY);
        let waker: Arc<Mutex<Option<InputWaker>>> = Arc::new(Mutex::new(None));
        let stop = Arc::new(AtomicBool::new(false));
        let describe = format!("evdev {selector}");
        let reader = Reader {
            selector,
            grab,
            reopen_interval,
            needs: needed_codes(&mapping),
            tx,
            waker: Arc::clone(&waker),
            stop: Arc::clone(&stop),
        };
        std::thread::Builder::new()
            .name("rove-evdev".into())
            .spawn(move || reader.run())
            .map_err(|e| {
                LinkError::fatal(format!("{describe}: cannot start reader thread: {e}"))
            })?;
        Ok(EvdevSource {
            mapper: Mapper::new(mapping, describe.clone()),
            rx,
            waker,
            stop,
            describe,
            fatal: None,
        })
    }

    /// Sets the function the reader calls after queuing events.
    pub fn set_waker(&mut self, waker: InputWaker) {
        if let Ok(mut slot) = self.waker.lock() {
            *slot = Some(waker);
        }
    }

    /// The mapper's status.
    pub fn status(&self) -> InputStatus {
        self.mapper.status()
    }
}

impl Drop for EvdevSource {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
    }
}

impl InputSource for EvdevSource {
    fn describe(&self) -> String {
        self.describe.clone()
    }

    fn poll(&mut self, now: MonoTime) -> Result<Option<InputEvent>, LinkError> {
        loop {
            match self.rx.try_recv() {
                Ok(Feed::Event(e)) => self.mapper.feed(now, e),
                Ok(Feed::Fatal(reason)) => {
                    self.mapper.fail(reason.clone());
                    self.fatal = Some(reason.clone());
                    return Err(LinkError::fatal(reason));
                }
                Err(TryRecvError::Empty) => break,
                Err(TryRecvError::Disconnected) => {
                    if self.fatal.is_none() {
                        let reason = format!("{}: reader thread ended", self.describe);
                        self.mapper.fail(reason.clone());
                        self.fatal = Some(reason.clone());
                        return Err(LinkError::fatal(reason));
                    }
                    break;
                }
            }
        }
        self.mapper.tick(now);
        Ok(self.mapper.pop())
    }

    fn next_deadline(&self) -> Option<MonoTime> {
        self.mapper.next_deadline()
    }
}

/// The codes a mapping reads: a device must have them all to be chosen.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
struct Needs {
    abs: Vec<u16>,
    keys: Vec<u16>,
}

fn needed_codes(mapping: &MappingConfig) -> Needs {
    let mut needs = Needs::default();
    for axis in mapping.axes.iter().flatten() {
        match axis.input {
            AxisInput::Abs { code, .. } => needs.abs.push(code),
            AxisInput::Keys {
                negative, positive, ..
            } => needs
                .keys
                .extend([negative, positive].into_iter().flatten()),
        }
    }
    let controls = mapping
        .deadman
        .iter()
        .chain(mapping.actions.iter().map(|(c, _)| c));
    for control in controls {
        match *control {
            Control::Key(code) => needs.keys.push(code),
            Control::AbsPositive(code) | Control::AbsNegative(code) => needs.abs.push(code),
        }
    }
    needs.abs.sort_unstable();
    needs.abs.dedup();
    needs.keys.sort_unstable();
    needs.keys.dedup();
    needs
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::InputSettings;
    use std::path::Path;

    #[test]
    fn name_patterns() {
        assert!(!name_matches("Xbox*", "Microsoft Xbox 360 pad"));
        assert!(name_matches("*xbox*", "Microsoft Xbox 360 pad"));
        assert!(name_matches("Logitech*3D", "Logitech Extreme 3D"));
        assert!(name_matches("logitech extreme 3d", "Logitech Extreme 3D"));
        assert!(!name_matches("Logitech", "Logitech Extreme 3D"));
        assert!(name_matches("*", ""));
        assert!(!name_matches("a*b*c", "acb"));
        assert!(name_matches("a*b*c", "a-b-c"));
        assert!(!name_matches("ab*ba", "aba"));
    }

    #[test]
    fn needs_lists_every_mapped_code_once() {
        let mut settings: InputSettings = toml::from_str(
            r#"
            source = "joystick"
            [axes.roll]
            abs = "ABS_X"
            [axes.yaw]
            negative = "BTN_TL"
            positive = "BTN_TR"
            [buttons]
            deadman = "BTN_SOUTH"
            next_vehicle = "ABS_HAT0X+"
            previous_vehicle = "ABS_HAT0X-"
            "#,
        )
        .expect("parses");
        let config = settings.validate().expect("valid");
        assert_eq!(
            needed_codes(&config.mapping),
            Needs {
                abs: vec![0x00, 0x10],
                keys: vec![0x130, 0x136, 0x137],
            }
        );
    }

    #[test]
    fn listing_a_directory_without_devices_is_empty() {
        let dir = std::env::temp_dir().join(format!("rove-inputs-empty-{}", std::process::id()));
        let _ = std::fs::create_dir_all(&dir);
        assert!(list_devices_in(&dir).is_empty());
        assert!(list_devices_in(Path::new("/nonexistent/input")).is_empty());
        let _ = std::fs::remove_dir(&dir);
    }

    #[test]
    fn a_missing_device_is_reported_lost_not_fatal() {
        let mut settings: InputSettings = toml::from_str(
            "source = \"joystick\"\ndevice = \"/nonexistent/event99\"\n[axes.roll]\nabs = \"ABS_X\"\n",
        )
        .expect("parses");
        let config = settings.validate().expect("valid");
        let crate::config::SourceConfig::Evdev {
            selector,
            grab,
            reopen_interval,
        } = config.source.clone()
        else {
            panic!("evdev source expected");
        };
        let mut source =
            EvdevSource::spawn(selector, grab, reopen_interval, config.mapping.clone())
                .expect("thread starts");
        let woken = Arc::new(AtomicBool::new(false));
        let flag = Arc::clone(&woken);
        source.set_waker(Arc::new(move || flag.store(true, Ordering::SeqCst)));
        // Poll until the reader reports (bounded wait, no fixed sleep for correctness).
        let deadline = std::time::Instant::now() + Duration::from_secs(5);
        let event = loop {
            if let Some(e) = source.poll(MonoTime::from_millis(1)).expect("not fatal") {
                break e;
            }
            assert!(std::time::Instant::now() < deadline, "no Lost within 5 s");
            std::thread::sleep(Duration::from_millis(5));
        };
        match event {
            InputEvent::Lost { reason } => {
                assert!(reason.contains("/nonexistent/event99"), "{reason}")
            }
            other => panic!("expected Lost, got {other:?}"),
        }
        assert!(matches!(
            source.status().link,
            crate::mapper::LinkState::Lost { .. }
        ));
    }
}
