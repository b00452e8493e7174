//! The pure core: a state machine that turns a device's events into [`InputEvent`]s.
//!
//! [`Mapper::feed`] takes what a device layer reports ([`DeviceEvent`]: raw evdev events,
//! absinfo and key-state snapshots, connect and unplug) with the time it happened;
//! [`Mapper::tick`] advances key ramps and the silence timer; [`Mapper::pop`] hands out the
//! resulting events in order. It reads no clock and does no I/O.
//!
//! # Rules
//! - **Frames.** State changes (`EV_ABS`, `EV_KEY`) take effect at the `SYN_REPORT` that ends
//!   their frame: one consistent [`InputEvent::Axes`] per frame, emitted at once if the mapped
//!   values changed. Key ramps emit between frames, every [`RAMP_TICK`] while moving.
//! - **Order within a frame**: `Deadman(false)` first (stop before anything else), then actions
//!   in config order, then `Deadman(true)`, then `Axes`.
//! - **Deadman.** With a deadman control configured, axes are emitted only while it is held;
//!   its release emits `Deadman(false)` and nothing else; its press emits `Deadman(true)`
//!   followed by an `Axes` with the current values.
//! - **Lost.** Unplug, `SYN_DROPPED`, and (opt-in) silence emit one `Lost` and then nothing
//!   until the device is back: after an unplug, a `Connected`; after `SYN_DROPPED`, the next
//!   `SYN_REPORT` (values are then unknown until re-reported, which the device layer does from
//!   the kernel's state); after silence, any event.
//! - **No jump.** At start and after every `Lost`, no `Axes` is emitted until every mapped axis
//!   has been seen at its rest position ([`Rest`](crate::config::Rest), within
//!   [`REST_TOLERANCE`]) and no axis key is held. The first `Axes` after that is always
//!   emitted, even if centred: it is the "live again" signal. [`Mapper::status`] names the axes
//!   still awaited so a UI can say "centre the sticks".
//! - **Stale keys.** A key a snapshot reports held drives no ramp until released.
//! - **Press edges only.** Actions and the deadman fire on a press seen as an event, never on a
//!   state snapshot (a button held through a replug must be pressed again); auto-repeat
//!   (`value 2`) is no press.
//!
//! Silence detection is opt-in (`silence_timeout_ms`): evdev joysticks report only on change
//! and send no heartbeat, so a still stick on a healthy device is silent too. Unplugs are
//! detected without it (the read fails with ENODEV at once); the timeout is for devices that
//! stream continuously (many gamepads report motion sensors or noisy sticks at 100+ Hz), where
//! silence means a frozen device or a dead wireless link.
//!
//! # Layout
//! - this file: [`Mapper`], its link state and its entry points: device events, ticks, the
//!   output queue, raw events, losing the device.
//! - `status.rs`: [`InputStatus`] and [`LinkState`], the snapshot shown to users.
//! - `axes.rs`: the end of a frame: control edges (actions, deadman), key-ramp targets, each
//!   axis's value, the no-jump rest check and the `Axes` output.
//! - `tests.rs`: its unit tests.

mod axes;
mod status;

pub use status::{InputStatus, LinkState};

use crate::codes::{Control, EV_ABS, EV_KEY, RawEvent, SYN_DROPPED, SYN_REPORT};
use crate::config::{AxisConfig, AxisInput, MappingConfig};
use crate::curve::{AbsState, Ramp};
use rove_core::adapter::InputEvent;
use rove_core::msg::MovementCommand;
use rove_core::time::MonoTime;
use std::collections::{BTreeMap, BTreeSet, HashMap, VecDeque};
use std::time::Duration;

/// How often a moving key ramp emits, 10 ms: 100 Hz, twice the operator's default 50 Hz
/// stream, so a ramp looks smooth on the wire. Shorter only wakes the process more often.
pub const RAMP_TICK: Duration = Duration::from_millis(10);

/// How close to its rest position an axis must be for the no-jump rule, as a fraction of full
/// scale (5 %): loose enough that a worn stick that rests slightly off centre (outside a small
/// deadzone) is accepted, tight enough that no vehicle moves noticeably when driving resumes.
pub const REST_TOLERANCE: f64 = 0.05;

/// Bound on queued output events. Each device event adds at most a handful; a caller that
/// stops polling must not grow memory without limit. When full, the oldest `Axes` are dropped
/// first (a newer one supersedes them); other events are kept.
const MAX_QUEUED: usize = 1_024;

/// What a device layer reports to the mapper.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum DeviceEvent {
    /// An event read from the device.
    Raw(RawEvent),
    /// An absolute axis's absinfo (calibration and current value), at open or after a re-sync.
    AbsState {
        /// `EV_ABS` code.
        code: u16,
        /// The state.
        state: AbsState,
    },
    /// A key's state from a snapshot (at open or after a re-sync): sets the state without
    /// firing actions.
    KeyState {
        /// `EV_KEY` code.
        code: u16,
        /// Held.
        pressed: bool,
    },
    /// The device was opened (first time or after an unplug). Values are unknown until
    /// reported (the device layer sends `AbsState`/`KeyState` next).
    Connected {
        /// The device's name, for status and reasons.
        name: String,
    },
    /// The device is gone (read error, ENODEV, not found).
    Unplugged {
        /// Why, naming the device.
        reason: String,
    },
}

/// Why input is not being used, and whether it can come back.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum LostCause {
    Unplugged,
    Dropped,
    Silent,
}

#[derive(Debug, Clone, PartialEq, Eq)]
enum Link {
    Live,
    AwaitingRest,
    Lost(LostCause, String),
}

/// The mapping state machine (see the module docs for its rules).
#[derive(Debug, Clone)]
pub struct Mapper {
    mapping: MappingConfig,
    device: Option<String>,
    label: String,
    absinfo: HashMap<u16, AbsState>,
    abs: BTreeMap<u16, i32>,
    keys: BTreeSet<u16>,
    /// Keys reported held by a snapshot: they drive no ramp until released (a key held through
    /// a replug or re-sync is stale input).
    stale_keys: BTreeSet<u16>,
    /// Bound controls' state as of the last evaluated frame.
    controls: BTreeMap<Control, bool>,
    ramps: [Option<Ramp>; 4],
    ramp_at: Option<MonoTime>,
    link: Link,
    deadman_held: bool,
    last_emitted: Option<MovementCommand>,
    last_activity: Option<MonoTime>,
    /// Whether the first device event was seen: the no-jump rule is first evaluated then.
    started: bool,
    out: VecDeque<InputEvent>,
}

impl Mapper {
    /// A mapper for `mapping`; `label` names the device in `Lost` reasons until it reports its
    /// name. It starts awaiting rest with every value unknown.
    pub fn new(mapping: MappingConfig, label: impl Into<String>) -> Self {
        let ramps = mapping.axes.map(|a| match a {
            Some(AxisConfig {
                input:
                    AxisInput::Keys {
                        ramp_up,
                        spring_back,
                        ..
                    },
                ..
            }) => Some(Ramp::new(ramp_up, spring_back)),
            _ => None,
        });
        Mapper {
            mapping,
            device: None,
            label: label.into(),
            absinfo: HashMap::new(),
            abs: BTreeMap::new(),
            keys: BTreeSet::new(),
            stale_keys: BTreeSet::new(),
            started: false,
            controls: BTreeMap::new(),
            ramps,
            ramp_at: None,
            link: Link::AwaitingRest,
            deadman_held: false,
            last_emitted: None,
            last_activity: None,
            out: VecDeque::new(),
        }
    }

    /// The mapping in use.
    pub fn mapping(&self) -> &MappingConfig {
        &self.mapping
    }

    /// Processes one device event that happened at `at` (after advancing time to `at`).
    pub fn feed(&mut self, at: MonoTime, event: DeviceEvent) {
        self.tick(at);
        if !self.started {
            // Key axes are at rest before anything is pressed: a keyboard is live from its
            // first event, and a key already held then is held from before (stale).
            self.started = true;
            self.evaluate(false);
        }
        match event {
            DeviceEvent::Raw(e) => self.raw(at, e),
            DeviceEvent::AbsState { code, state } => {
                self.absinfo.insert(code, state);
                if !self.is_gone() {
                    self.abs.insert(code, state.value);
                    self.evaluate(false);
                }
            }
            DeviceEvent::KeyState { code, pressed } => {
                if !self.is_gone() {
                    if pressed {
                        self.keys.insert(code);
                        self.stale_keys.insert(code);
                    } else {
                        self.keys.remove(&code);
                        self.stale_keys.remove(&code);
                    }
                    self.evaluate(false);
                }
            }
            DeviceEvent::Connected { name } => {
                self.device = Some(name);
                self.clear_values();
                self.last_activity = Some(at);
                if matches!(self.link, Link::Lost(..)) {
                    self.link = Link::AwaitingRest;
                }
                self.evaluate(false);
            }
            DeviceEvent::Unplugged { reason } => self.lose(LostCause::Unplugged, reason),
        }
    }

    /// Advances ramps and the silence timer to `now`, emitting what is due.
    pub fn tick(&mut self, now: MonoTime) {
        if self.last_activity.is_none() {
            self.last_activity = Some(now);
        }
        if let (Some(timeout), Some(last)) = (self.mapping.silence_timeout, self.last_activity)
            && !matches!(self.link, Link::Lost(..))
            && now >= last + timeout
        {
            let reason = format!(
                "{}: no events for {} ms",
                self.name(),
                now.saturating_since(last).as_millis()
            );
            self.lose(LostCause::Silent, reason);
        }
        let dt = self
            .ramp_at
            .map_or(Duration::ZERO, |t| now.saturating_since(t));
        if self.ramp_at.is_none_or(|t| now > t) {
            self.ramp_at = Some(now);
        }
        if dt.is_zero() || matches!(self.link, Link::Lost(..)) {
            return;
        }
        let mut moved = false;
        for ramp in self.ramps.iter_mut().flatten() {
            if ramp.is_moving() {
                ramp.advance(dt);
                moved = true;
            }
        }
        if moved {
            self.update_axes();
        }
    }

    /// The next output event, oldest first.
    pub fn pop(&mut self) -> Option<InputEvent> {
        self.out.pop_front()
    }

    /// When [`Mapper::tick`] next has something to do without a device event: the next ramp
    /// step while a key axis moves, or the silence deadline.
    pub fn next_deadline(&self) -> Option<MonoTime> {
        if matches!(self.link, Link::Lost(..)) {
            return None;
        }
        let ramp = self
            .ramps
            .iter()
            .flatten()
            .any(Ramp::is_moving)
            .then(|| self.ramp_at.map_or(MonoTime::ZERO, |t| t + RAMP_TICK));
        let silence = self
            .mapping
            .silence_timeout
            .zip(self.last_activity)
            .map(|(timeout, last)| last + timeout);
        match (ramp, silence) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (a, b) => a.or(b),
        }
    }

    /// The device failed in a way retrying cannot fix: lost for good (until `Connected`).
    pub fn fail(&mut self, reason: impl Into<String>) {
        self.lose(LostCause::Unplugged, reason.into());
    }

    /// A snapshot for displays.
    pub fn status(&self) -> InputStatus {
        let sticks = self.sticks();
        let link = match &self.link {
            Link::Live => LinkState::Live,
            Link::AwaitingRest => LinkState::AwaitingRest {
                axes: self.axes_not_at_rest(),
            },
            Link::Lost(_, reason) => LinkState::Lost {
                reason: reason.clone(),
            },
        };
        let driving =
            self.link == Link::Live && (self.mapping.deadman.is_none() || self.deadman_held);
        InputStatus {
            device: self.device.clone(),
            link,
            deadman: self.mapping.deadman.map(|_| self.deadman_held),
            sticks,
            output: if driving {
                sticks
            } else {
                MovementCommand::CENTRED
            },
            abs: self.abs.iter().map(|(c, v)| (*c, *v)).collect(),
            pressed: self.keys.iter().copied().collect(),
        }
    }

    fn name(&self) -> &str {
        self.device.as_deref().unwrap_or(&self.label)
    }

    /// Unplugged: only a `Connected` brings it back.
    fn is_gone(&self) -> bool {
        matches!(self.link, Link::Lost(LostCause::Unplugged, _))
    }

    fn raw(&mut self, at: MonoTime, e: RawEvent) {
        self.last_activity = Some(at);
        match &self.link {
            Link::Lost(LostCause::Unplugged, _) => return,
            Link::Lost(LostCause::Dropped, _) => {
                // The kernel's rule: discard everything up to and including the next
                // SYN_REPORT; the state is then re-read (the device layer sends snapshots).
                if e.kind == crate::codes::EV_SYN && e.code == SYN_REPORT {
                    self.clear_values();
                    self.link = Link::AwaitingRest;
                    self.evaluate(false);
                }
                return;
            }
            Link::Lost(LostCause::Silent, _) => self.link = Link::AwaitingRest,
            Link::Live | Link::AwaitingRest => {}
        }
        match e.kind {
            crate::codes::EV_SYN if e.code == SYN_DROPPED => {
                let reason = format!(
                    "{}: events dropped (SYN_DROPPED), state unknown until re-sync",
                    self.name()
                );
                self.lose(LostCause::Dropped, reason);
            }
            crate::codes::EV_SYN if e.code == SYN_REPORT => self.evaluate(true),
            EV_KEY => match e.value {
                0 => {
                    self.keys.remove(&e.code);
                    self.stale_keys.remove(&e.code);
                }
                1 => {
                    self.keys.insert(e.code);
                }
                // Auto-repeat of a key we did not see go down (after a re-sync) is no press.
                _ => {}
            },
            EV_ABS => {
                self.abs.insert(e.code, e.value);
            }
            _ => {}
        }
    }

    fn lose(&mut self, cause: LostCause, reason: String) {
        let was_lost = matches!(self.link, Link::Lost(..));
        if was_lost && cause == LostCause::Silent {
            return;
        }
        if matches!(cause, LostCause::Unplugged | LostCause::Dropped) {
            self.clear_values();
        }
        for ramp in self.ramps.iter_mut().flatten() {
            ramp.reset();
        }
        self.deadman_held = false;
        self.last_emitted = None;
        if !was_lost {
            self.push(InputEvent::Lost {
                reason: reason.clone(),
            });
        }
        self.link = Link::Lost(cause, reason);
    }

    /// Forgets every value: they must be reported again.
    fn clear_values(&mut self) {
        self.abs.clear();
        self.keys.clear();
        self.stale_keys.clear();
        self.controls.clear();
        for ramp in self.ramps.iter_mut().flatten() {
            ramp.reset();
        }
    }

    fn push(&mut self, event: InputEvent) {
        if self.out.len() >= MAX_QUEUED {
            if let Some(i) = self
                .out
                .iter()
                .position(|e| matches!(e, InputEvent::Axes(_)))
            {
                self.out.remove(i);
            } else {
                self.out.pop_front();
            }
        }
        self.out.push_back(event);
    }
}

#[cfg(test)]
mod tests;
