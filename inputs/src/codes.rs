//! evdev event types and codes by name: the raw event the mapper consumes, name ↔ number for
//! configs and recordings, and [`Control`], a button-like input (a key, or one direction of an
//! absolute axis such as a d-pad hat or an analogue trigger).
//!
//! Names are the kernel's (`input-event-codes.h`), as the `evdev` crate spells them: `EV_ABS`,
//! `ABS_X`, `ABS_HAT0Y`, `BTN_SOUTH`, `KEY_W`, `SYN_REPORT`. The gamepad aliases `BTN_A`,
//! `BTN_B`, `BTN_X`, `BTN_Y`, `BTN_GAMEPAD`, `BTN_JOYSTICK` and `BTN_MISC` are accepted too.

use evdev::{AbsoluteAxisCode, EventType, KeyCode, SynchronizationCode};
use std::fmt;
use std::str::FromStr;

/// `EV_SYN`: frame markers (`SYN_REPORT`, `SYN_DROPPED`).
pub const EV_SYN: u16 = EventType::SYNCHRONIZATION.0;
/// `EV_KEY`: keys and buttons (value 1 pressed, 0 released, 2 auto-repeat).
pub const EV_KEY: u16 = EventType::KEY.0;
/// `EV_ABS`: absolute axes (sticks, triggers, hats).
pub const EV_ABS: u16 = EventType::ABSOLUTE.0;
/// `SYN_REPORT`: the end of one consistent frame of changes.
pub const SYN_REPORT: u16 = SynchronizationCode::SYN_REPORT.0;
/// `SYN_DROPPED`: the kernel's buffer overflowed; events were lost until the next `SYN_REPORT`.
pub const SYN_DROPPED: u16 = SynchronizationCode::SYN_DROPPED.0;

/// One evdev event without its timestamp: the kernel's `type`, `code` and `value`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct RawEvent {
    /// Event type (`EV_KEY`, `EV_ABS`, `EV_SYN`…).
    pub kind: u16,
    /// Code within the type (`ABS_X`, `BTN_SOUTH`, `SYN_REPORT`…).
    pub code: u16,
    /// Value (axis position, 0/1/2 for keys).
    pub value: i32,
}

impl RawEvent {
    /// An event of type `kind`, `code`, `value`.
    pub const fn new(kind: u16, code: u16, value: i32) -> Self {
        RawEvent { kind, code, value }
    }

    /// `EV_SYN SYN_REPORT 0`.
    pub const fn syn_report() -> Self {
        RawEvent::new(EV_SYN, SYN_REPORT, 0)
    }

    /// The same event as the `evdev` crate's type (time stamp: now).
    pub fn to_evdev(self) -> evdev::InputEvent {
        evdev::InputEvent::new(self.kind, self.code, self.value)
    }
}

impl From<evdev::InputEvent> for RawEvent {
    fn from(e: evdev::InputEvent) -> Self {
        RawEvent::new(e.event_type().0, e.code(), e.value())
    }
}

impl fmt::Display for RawEvent {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "{} {} {}",
            type_name(self.kind),
            code_name(self.kind, self.code),
            self.value
        )
    }
}

const TYPE_NAMES: &[(&str, u16)] = &[
    ("EV_SYN", 0x00),
    ("EV_KEY", 0x01),
    ("EV_REL", 0x02),
    ("EV_ABS", 0x03),
    ("EV_MSC", 0x04),
    ("EV_SW", 0x05),
    ("EV_LED", 0x11),
    ("EV_SND", 0x12),
    ("EV_REP", 0x14),
    ("EV_FF", 0x15),
    ("EV_PWR", 0x16),
    ("EV_FF_STATUS", 0x17),
];

/// Gamepad aliases the kernel defines as equal to another code; the `evdev` crate knows only one
/// name per code.
const KEY_ALIASES: &[(&str, u16)] = &[
    ("BTN_A", 0x130),
    ("BTN_GAMEPAD", 0x130),
    ("BTN_B", 0x131),
    ("BTN_X", 0x133),
    ("BTN_Y", 0x134),
    ("BTN_JOYSTICK", 0x120),
    ("BTN_MISC", 0x100),
];

/// The event type called `name` (`EV_ABS`) or written as a number (`3`, `0x03`).
pub fn parse_type(name: &str) -> Option<u16> {
    TYPE_NAMES
        .iter()
        .find(|(n, _)| *n == name)
        .map(|(_, v)| *v)
        .or_else(|| parse_number(name))
}

/// The name of event type `kind`, or its number.
pub fn type_name(kind: u16) -> String {
    TYPE_NAMES
        .iter()
        .find(|(_, v)| *v == kind)
        .map_or_else(|| kind.to_string(), |(n, _)| (*n).to_string())
}

/// The key or button called `name` (`KEY_W`, `BTN_SOUTH`, `BTN_A`).
pub fn parse_key(name: &str) -> Option<u16> {
    KeyCode::from_str(name).ok().map(|k| k.0).or_else(|| {
        KEY_ALIASES
            .iter()
            .find(|(n, _)| *n == name)
            .map(|(_, v)| *v)
    })
}

/// The absolute axis called `name` (`ABS_X`, `ABS_HAT0Y`).
pub fn parse_abs(name: &str) -> Option<u16> {
    AbsoluteAxisCode::from_str(name).ok().map(|a| a.0)
}

/// The code called `name` within event type `kind`, or a number.
pub fn parse_code(kind: u16, name: &str) -> Option<u16> {
    if let Some(n) = parse_number(name) {
        return Some(n);
    }
    match kind {
        EV_SYN => SynchronizationCode::from_str(name).ok().map(|c| c.0),
        EV_KEY => parse_key(name),
        EV_ABS => parse_abs(name),
        0x02 => evdev::RelativeAxisCode::from_str(name).ok().map(|c| c.0),
        0x04 => evdev::MiscCode::from_str(name).ok().map(|c| c.0),
        0x05 => evdev::SwitchCode::from_str(name).ok().map(|c| c.0),
        _ => None,
    }
}

/// The type a code name belongs to, from its prefix (`ABS_X` → `EV_ABS`), for the short form
/// of recording lines.
pub fn type_of_code_name(name: &str) -> Option<u16> {
    let prefix = name.split('_').next()?;
    match prefix {
        "SYN" => Some(EV_SYN),
        "KEY" | "BTN" => Some(EV_KEY),
        "REL" => Some(0x02),
        "ABS" => Some(EV_ABS),
        "MSC" => Some(0x04),
        "SW" => Some(0x05),
        _ => None,
    }
}

/// The name of `code` within type `kind`, or its number.
pub fn code_name(kind: u16, code: u16) -> String {
    // The evdev crate's Debug prints the kernel name, or "unknown …" for codes it has no name for.
    let name = match kind {
        EV_SYN => format!("{:?}", SynchronizationCode(code)),
        EV_KEY => format!("{:?}", KeyCode(code)),
        EV_ABS => format!("{:?}", AbsoluteAxisCode(code)),
        _ => return code.to_string(),
    };
    if name.starts_with("unknown") || name.contains(' ') {
        code.to_string()
    } else {
        name
    }
}

/// The name of key or button `code`.
pub fn key_name(code: u16) -> String {
    code_name(EV_KEY, code)
}

/// The name of absolute axis `code`.
pub fn abs_name(code: u16) -> String {
    code_name(EV_ABS, code)
}

fn parse_number(s: &str) -> Option<u16> {
    if let Some(hex) = s.strip_prefix("0x") {
        u16::from_str_radix(hex, 16).ok()
    } else if s.bytes().all(|b| b.is_ascii_digit()) && !s.is_empty() {
        s.parse().ok()
    } else {
        None
    }
}

/// A button-like input: a key or button, or one direction of an absolute axis.
///
/// Written in configs as the key's name (`BTN_SOUTH`, `KEY_SPACE`) or an axis name with a sign
/// (`ABS_HAT0Y-`, `ABS_Z+`). An axis direction counts as pressed when the axis is more than half
/// way from its centre towards that end, which is "pressed" for a d-pad hat (−1/0/+1) and
/// "more than half pulled" for an analogue trigger.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Control {
    /// An `EV_KEY` code.
    Key(u16),
    /// An `EV_ABS` axis pushed towards its maximum.
    AbsPositive(u16),
    /// An `EV_ABS` axis pushed towards its minimum.
    AbsNegative(u16),
}

impl Control {
    /// Parses a config name; `None` if it names no key and no signed axis.
    pub fn parse(name: &str) -> Option<Control> {
        if let Some(axis) = name.strip_suffix('+') {
            return parse_abs(axis).map(Control::AbsPositive);
        }
        if let Some(axis) = name.strip_suffix('-') {
            return parse_abs(axis).map(Control::AbsNegative);
        }
        parse_key(name).map(Control::Key)
    }
}

impl fmt::Display for Control {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Control::Key(code) => f.write_str(&key_name(*code)),
            Control::AbsPositive(code) => write!(f, "{}+", abs_name(*code)),
            Control::AbsNegative(code) => write!(f, "{}-", abs_name(*code)),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_round_trip() {
        assert_eq!(parse_type("EV_ABS"), Some(EV_ABS));
        assert_eq!(type_name(EV_KEY), "EV_KEY");
        assert_eq!(parse_code(EV_ABS, "ABS_HAT0X"), Some(0x10));
        assert_eq!(abs_name(0x10), "ABS_HAT0X");
        assert_eq!(parse_code(EV_SYN, "SYN_DROPPED"), Some(SYN_DROPPED));
        assert_eq!(key_name(0x130), "BTN_SOUTH");
        assert_eq!(parse_key("BTN_A"), Some(0x130));
        assert_eq!(parse_code(EV_KEY, "0x130"), Some(0x130));
        assert_eq!(parse_code(EV_KEY, "304"), Some(0x130));
        assert_eq!(parse_key("KEY_NOPE"), None);
        assert_eq!(code_name(EV_KEY, 0x2ff), "767");
        assert_eq!(type_of_code_name("ABS_RZ"), Some(EV_ABS));
        assert_eq!(type_of_code_name("BTN_TL"), Some(EV_KEY));
        assert_eq!(type_of_code_name("unplug"), None);
    }

    #[test]
    fn controls_parse_keys_and_signed_axes() {
        assert_eq!(Control::parse("BTN_TL"), Some(Control::Key(0x136)));
        assert_eq!(
            Control::parse("ABS_HAT0Y-"),
            Some(Control::AbsNegative(0x11))
        );
        assert_eq!(Control::parse("ABS_Z+"), Some(Control::AbsPositive(0x02)));
        assert_eq!(Control::parse("ABS_Z"), None);
        assert_eq!(Control::parse("ABS_NOPE+"), None);
        assert_eq!(Control::AbsNegative(0x11).to_string(), "ABS_HAT0Y-");
    }

    #[test]
    fn converts_from_evdev_events() {
        let e = evdev::InputEvent::new(EV_ABS, 1, -5);
        assert_eq!(RawEvent::from(e), RawEvent::new(EV_ABS, 1, -5));
        assert_eq!(RawEvent::new(EV_ABS, 1, -5).to_string(), "EV_ABS ABS_Y -5");
    }
}
