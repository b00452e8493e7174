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

use crate::codes::{Control, EV_SYN, RawEvent, SYN_DROPPED, SYN_REPORT, abs_name, key_name};
use crate::config::{AxisInput, DeviceSelector, MappingConfig};
use crate::curve::AbsState;
use crate::mapper::{DeviceEvent, InputStatus, Mapper};
use evdev::raw_stream::RawDevice;
use evdev::{AbsoluteAxisCode, KeyCode};
use rove_core::adapter::{InputEvent, InputSource};
use rove_core::error::LinkError;
use rove_core::time::MonoTime;
use std::fmt;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{Receiver, SyncSender, TryRecvError, sync_channel};
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

/// The codes of `needs` the device lacks, by name.
fn missing_codes(dev: &RawDevice, needs: &Needs) -> Vec<String> {
    let abs = dev.supported_absolute_axes();
    let keys = dev.supported_keys();
    let mut missing: Vec<String> = needs
        .abs
        .iter()
        .filter(|c| !abs.is_some_and(|a| a.contains(AbsoluteAxisCode(**c))))
        .map(|c| abs_name(*c))
        .collect();
    missing.extend(
        needs
            .keys
            .iter()
            .filter(|c| !keys.is_some_and(|k| k.contains(KeyCode(**c))))
            .map(|c| key_name(*c)),
    );
    missing
}

/// Case-insensitive match of `name` against `pattern`, where `*` matches any text.
pub fn name_matches(pattern: &str, name: &str) -> bool {
    let pattern = pattern.to_lowercase();
    let name = name.to_lowercase();
    let parts: Vec<&str> = pattern.split('*').collect();
    if parts.len() == 1 {
        return name == pattern;
    }
    let (first, rest) = match parts.split_first() {
        Some(x) => x,
        None => return false,
    };
    let Some(mut remaining) = name.strip_prefix(first) else {
        return false;
    };
    let (last, middle) = match rest.split_last() {
        Some(x) => x,
        None => return true,
    };
    for part in middle {
        match remaining.find(part) {
            Some(i) => remaining = &remaining[i + part.len()..],
            None => return false,
        }
    }
    remaining.len() >= last.len() && remaining.ends_with(last)
}

/// What kind of device it looks like.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DeviceKind {
    /// Has `ABS_X`, `ABS_Y` and joystick or gamepad buttons.
    Joystick,
    /// Has letter keys.
    Keyboard,
    /// Anything else (mouse, power button, touchpad…).
    Other,
}

impl fmt::Display for DeviceKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            DeviceKind::Joystick => "joystick",
            DeviceKind::Keyboard => "keyboard",
            DeviceKind::Other => "other",
        })
    }
}

fn kind_of(dev: &RawDevice) -> DeviceKind {
    let keys = dev.supported_keys();
    let has_key = |k: KeyCode| keys.is_some_and(|set| set.contains(k));
    let abs = dev.supported_absolute_axes();
    let has_abs = |a: AbsoluteAxisCode| abs.is_some_and(|set| set.contains(a));
    // BTN_JOYSTICK (0x120) … 0x13f covers joystick and gamepad buttons.
    let joy_buttons = keys.is_some_and(|set| set.iter().any(|k| (0x120..=0x13f).contains(&k.0)));
    if has_abs(AbsoluteAxisCode::ABS_X) && has_abs(AbsoluteAxisCode::ABS_Y) && joy_buttons {
        DeviceKind::Joystick
    } else if has_key(KeyCode::KEY_A) && has_key(KeyCode::KEY_Z) && has_key(KeyCode::KEY_SPACE) {
        DeviceKind::Keyboard
    } else {
        DeviceKind::Other
    }
}

/// `eventN` nodes under `dir`, by number.
fn event_nodes(dir: &Path) -> Vec<PathBuf> {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return Vec::new();
    };
    let mut nodes: Vec<(u32, PathBuf)> = entries
        .flatten()
        .filter_map(|e| {
            let name = e.file_name();
            let n = name.to_str()?.strip_prefix("event")?.parse().ok()?;
            Some((n, e.path()))
        })
        .collect();
    nodes.sort();
    nodes.into_iter().map(|(_, p)| p).collect()
}

/// Opens the device `selector` names that has every code in `needs`.
fn find(selector: &DeviceSelector, needs: &Needs) -> Result<(PathBuf, RawDevice), Found> {
    match selector {
        DeviceSelector::Path(path) => {
            let dev = RawDevice::open(path)
                .map_err(|e| Found::NotYet(format!("{}: {e}", path.display())))?;
            let missing = missing_codes(&dev, needs);
            if missing.is_empty() {
                Ok((path.clone(), dev))
            } else {
                Err(Found::Mismatch(format!(
                    "{} ({}) has no {}, which the mapping uses",
                    path.display(),
                    dev.name().unwrap_or("unnamed"),
                    missing.join(", ")
                )))
            }
        }
        _ => {
            let mut skipped = Vec::new();
            for path in event_nodes(Path::new(INPUT_DIR)) {
                let Ok(dev) = RawDevice::open(&path) else {
                    continue;
                };
                let name = dev.name().unwrap_or("").to_string();
                let wanted = match selector {
                    DeviceSelector::Name(pattern) => name_matches(pattern, &name),
                    DeviceSelector::AnyKeyboard => kind_of(&dev) == DeviceKind::Keyboard,
                    _ => kind_of(&dev) == DeviceKind::Joystick,
                };
                if !wanted {
                    continue;
                }
                let missing = missing_codes(&dev, needs);
                if missing.is_empty() {
                    return Ok((path, dev));
                }
                skipped.push(format!("{name:?} lacks {}", missing.join(", ")));
            }
            let mut why = format!("no device matching {selector} in {INPUT_DIR}");
            if !skipped.is_empty() {
                why.push_str(&format!(" ({})", skipped.join("; ")));
            }
            Err(Found::NotYet(why))
        }
    }
}

enum Found {
    /// Not there (yet): report lost, keep looking.
    NotYet(String),
    /// The configured device cannot serve the mapping: fatal.
    Mismatch(String),
}

struct Reader {
    selector: DeviceSelector,
    grab: bool,
    reopen_interval: Duration,
    needs: Needs,
    tx: SyncSender<Feed>,
    waker: Arc<Mutex<Option<InputWaker>>>,
    stop: Arc<AtomicBool>,
}

/// The receiver is gone: the thread should end.
struct Closed;

impl Reader {
    fn send(&self, feed: Feed) -> Result<(), Closed> {
        if self.stop.load(Ordering::Relaxed) {
            return Err(Closed);
        }
        self.tx.send(feed).map_err(|_| Closed)
    }

    fn wake(&self) {
        if let Ok(slot) = self.waker.lock()
            && let Some(w) = slot.as_ref()
        {
            w();
        }
    }

    fn run(self) {
        let mut announced_gone = false;
        while !self.stop.load(Ordering::Relaxed) {
            match find(&self.selector, &self.needs) {
                Ok((path, dev)) => match self.serve(&path, dev) {
                    Ok(reason) => {
                        if self
                            .send(Feed::Event(DeviceEvent::Unplugged { reason }))
                            .is_err()
                        {
                            return;
                        }
                        announced_gone = true;
                        self.wake();
                    }
                    Err(Closed) => return,
                },
                Err(Found::Mismatch(why)) => {
                    let _ = self.send(Feed::Fatal(why));
                    self.wake();
                    return;
                }
                Err(Found::NotYet(why)) => {
                    if !announced_gone {
                        let event = DeviceEvent::Unplugged { reason: why };
                        if self.send(Feed::Event(event)).is_err() {
                            return;
                        }
                        announced_gone = true;
                        self.wake();
                    }
                }
            }
            std::thread::sleep(self.reopen_interval);
        }
    }

    /// Reads `dev` until it fails; returns why.
    fn serve(&self, path: &Path, mut dev: RawDevice) -> Result<String, Closed> {
        let name = dev.name().unwrap_or("unnamed").to_string();
        if self.grab
            && let Err(e) = dev.grab()
        {
            return Ok(format!("{} ({name}): cannot grab: {e}", path.display()));
        }
        self.send(Feed::Event(DeviceEvent::Connected { name: name.clone() }))?;
        if let Err(e) = self.snapshot(&dev) {
            return e.map(|why| format!("{} ({name}): {why}", path.display()));
        }
        self.wake();
        let mut dropped = false;
        loop {
            let events: Vec<RawEvent> = match dev.fetch_events() {
                Ok(events) => events.map(RawEvent::from).collect(),
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
                Err(e) => return Ok(format!("{} ({name}): {e}", path.display())),
            };
            for event in events {
                self.send(Feed::Event(DeviceEvent::Raw(event)))?;
                if event.kind == EV_SYN && event.code == SYN_DROPPED {
                    dropped = true;
                } else if event.kind == EV_SYN && event.code == SYN_REPORT && dropped {
                    dropped = false;
                    if let Err(e) = self.snapshot(&dev) {
                        return e.map(|why| format!("{} ({name}): {why}", path.display()));
                    }
                }
            }
            self.wake();
        }
    }

    /// Sends every axis's absinfo and the held keys.
    fn snapshot(&self, dev: &RawDevice) -> Result<(), Result<String, Closed>> {
        let axes = dev
            .get_absinfo()
            .map_err(|e| Ok(format!("reading absinfo: {e}")))?;
        for (code, info) in axes {
            let event = DeviceEvent::AbsState {
                code: code.0,
                state: AbsState::from(info),
            };
            self.send(Feed::Event(event)).map_err(Err)?;
        }
        if dev.supported_keys().is_some() {
            let held = dev
                .get_key_state()
                .map_err(|e| Ok(format!("reading key state: {e}")))?;
            for key in held.iter() {
                let event = DeviceEvent::KeyState {
                    code: key.0,
                    pressed: true,
                };
                self.send(Feed::Event(event)).map_err(Err)?;
            }
        }
        Ok(())
    }
}

/// One device as `rove inputs list` shows it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct DeviceSummary {
    /// `/dev/input/eventN`.
    pub path: PathBuf,
    /// by-id and by-path links to it (stable names for configs).
    pub links: Vec<PathBuf>,
    /// The device's name.
    pub name: String,
    /// What it looks like.
    pub kind: DeviceKind,
    /// Absolute axes with their absinfo.
    pub axes: Vec<(u16, AbsState)>,
    /// Keys and buttons.
    pub keys: Vec<u16>,
}

impl fmt::Display for DeviceSummary {
    /// Several lines: path and name, links, axes with ranges, buttons.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(
            f,
            "{}  {:?}  ({})",
            self.path.display(),
            self.name,
            self.kind
        )?;
        for link in &self.links {
            writeln!(f, "  link: {}", link.display())?;
        }
        for (code, s) in &self.axes {
            writeln!(
                f,
                "  axis {:<12} value {:>6}  range {}..{}  flat {}  fuzz {}",
                abs_name(*code),
                s.value,
                s.minimum,
                s.maximum,
                s.flat,
                s.fuzz
            )?;
        }
        if !self.keys.is_empty() {
            let names: Vec<String> = self.keys.iter().map(|k| key_name(*k)).collect();
            writeln!(f, "  keys: {}", names.join(" "))?;
        }
        Ok(())
    }
}

/// A device node and what could be read from it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ListedDevice {
    /// `/dev/input/eventN`.
    pub path: PathBuf,
    /// Its capabilities, or why it could not be opened (often: permission denied; add the user
    /// to the `input` group).
    pub summary: Result<DeviceSummary, String>,
}

/// Every evdev device under [`INPUT_DIR`] (empty when there is none, as on this CI machine).
pub fn list_devices() -> Vec<ListedDevice> {
    list_devices_in(Path::new(INPUT_DIR))
}

/// Every evdev device under `dir`.
pub fn list_devices_in(dir: &Path) -> Vec<ListedDevice> {
    let links = stable_links(dir);
    event_nodes(dir)
        .into_iter()
        .map(|path| {
            let summary = RawDevice::open(&path)
                .map_err(|e| e.to_string())
                .and_then(|dev| summarise(&path, &dev, &links));
            ListedDevice { path, summary }
        })
        .collect()
}

/// (link, target) pairs from `dir/by-id` and `dir/by-path`.
fn stable_links(dir: &Path) -> Vec<(PathBuf, PathBuf)> {
    let mut out = Vec::new();
    for sub in ["by-id", "by-path"] {
        let Ok(entries) = std::fs::read_dir(dir.join(sub)) else {
            continue;
        };
        for entry in entries.flatten() {
            if let Ok(target) = std::fs::canonicalize(entry.path()) {
                out.push((entry.path(), target));
            }
        }
    }
    out.sort();
    out
}

fn summarise(
    path: &Path,
    dev: &RawDevice,
    links: &[(PathBuf, PathBuf)],
) -> Result<DeviceSummary, String> {
    let canonical = std::fs::canonicalize(path).unwrap_or_else(|_| path.to_path_buf());
    let axes = dev
        .get_absinfo()
        .map_err(|e| format!("reading absinfo: {e}"))?
        .map(|(code, info)| (code.0, AbsState::from(info)))
        .collect();
    Ok(DeviceSummary {
        path: path.to_path_buf(),
        links: links
            .iter()
            .filter(|(_, target)| *target == canonical)
            .map(|(link, _)| link.clone())
            .collect(),
        name: dev.name().unwrap_or("unnamed").to_string(),
        kind: kind_of(dev),
        axes,
        keys: dev
            .supported_keys()
            .map(|k| k.iter().map(|k| k.0).collect())
            .unwrap_or_default(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::InputSettings;

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
