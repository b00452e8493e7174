//! The reader thread: finds the device, sends `Connected` and the kernel's state as snapshots,
//! forwards every event it reads, re-reads the state after `SYN_DROPPED`, and after a read error
//! reports `Unplugged` and looks for the device again every `reopen_interval`.

use super::choose::{Found, find};
use super::{Feed, InputWaker, Needs};
use crate::codes::{EV_SYN, RawEvent, SYN_DROPPED, SYN_REPORT};
use crate::config::DeviceSelector;
use crate::curve::AbsState;
use crate::mapper::DeviceEvent;
use evdev::raw_stream::RawDevice;
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::SyncSender;
use std::sync::{Arc, Mutex};
use std::time::Duration;

pub(super) struct Reader {
    pub(super) selector: DeviceSelector,
    pub(super) grab: bool,
    pub(super) reopen_interval: Duration,
    pub(super) needs: Needs,
    pub(super) tx: SyncSender<Feed>,
    pub(super) waker: Arc<Mutex<Option<InputWaker>>>,
    pub(super) stop: Arc<AtomicBool>,
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

    pub(super) fn run(self) {
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
