//! Choosing the evdev device a [`DeviceSelector`] names: by path, by name pattern
//! ([`name_matches`]) or by kind ([`DeviceKind`]), and only one that has every code the mapping
//! reads.

use super::{INPUT_DIR, Needs};
use crate::codes::{abs_name, key_name};
use crate::config::DeviceSelector;
use evdev::raw_stream::RawDevice;
use evdev::{AbsoluteAxisCode, KeyCode};
use std::fmt;
use std::path::{Path, PathBuf};

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

pub(super) fn kind_of(dev: &RawDevice) -> DeviceKind {
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
pub(super) fn event_nodes(dir: &Path) -> Vec<PathBuf> {
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
pub(super) fn find(
    selector: &DeviceSelector,
    needs: &Needs,
) -> Result<(PathBuf, RawDevice), Found> {
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

pub(super) enum Found {
    /// Not there (yet): report lost, keep looking.
    NotYet(String),
    /// The configured device cannot serve the mapping: fatal.
    Mismatch(String),
}
