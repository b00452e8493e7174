//! Recorded event streams and the source that plays them through the mapper.
//!
//! A [`Recording`] is a list of `(offset, DeviceEvent)` read from a file in one of two formats,
//! told apart by content (a file containing a NUL byte is binary):
//!
//! **Text**, one entry per line, `#` starts a comment:
//! ```text
//! # t_ms  what
//! 0       absinfo ABS_X 128 0 255 0 15    # code value min max [fuzz [flat]]
//! 0       keystate BTN_TL 1               # snapshot: held, fires nothing
//! 10      EV_ABS ABS_X 200                # type code value (names or numbers)
//! 10      ABS_Y 30                        # short form: the type follows from the prefix
//! 10      SYN_REPORT                      # value optional for SYN_*
//! 20      3 0 128                         # all numeric
//! 500     unplug cable pulled             # device gone (reason optional)
//! 900     replug Logitech Extreme 3D      # device back (name optional)
//! ```
//! Times are milliseconds (decimals allowed) from the start of playback and never go back.
//!
//! **Binary**: raw 24-byte `struct input_event` records as `cat /dev/input/eventN > file`
//! captures them on 64-bit Linux (`i64 tv_sec, i64 tv_usec, u16 type, u16 code, i32 value`,
//! little-endian); times are relative to the first record. A capture carries no absinfo, so
//! the mapping must give `min`/`max` for its axes.

use crate::codes::{
    EV_KEY, EV_SYN, RawEvent, parse_abs, parse_code, parse_key, parse_type, type_of_code_name,
};
use crate::config::MappingConfig;
use crate::curve::AbsState;
use crate::error::{Error, Result};
use crate::mapper::{DeviceEvent, InputStatus, Mapper};
use rove_core::adapter::{InputEvent, InputSource};
use rove_core::error::LinkError;
use rove_core::time::MonoTime;
use std::collections::VecDeque;
use std::path::{Path, PathBuf};
use std::time::Duration;

/// Size of one `struct input_event` on 64-bit Linux.
pub const INPUT_EVENT_SIZE: usize = 24;

/// A recorded device stream: events at offsets from the start of playback.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct Recording {
    entries: Vec<(Duration, DeviceEvent)>,
}

impl Recording {
    /// A recording of `entries`, sorted by offset (stable).
    pub fn from_entries(mut entries: Vec<(Duration, DeviceEvent)>) -> Self {
        entries.sort_by_key(|(t, _)| *t);
        Recording { entries }
    }

    /// The entries, in order.
    pub fn entries(&self) -> &[(Duration, DeviceEvent)] {
        &self.entries
    }

    /// Reads a recording file (text or binary, told apart by content).
    ///
    /// # Errors
    /// [`Error::ReadRecording`] if the file cannot be read; [`Error::RecordingSyntax`] or
    /// [`Error::RecordingLength`] if it does not parse.
    pub fn load(path: &Path) -> Result<Recording> {
        let bytes = std::fs::read(path).map_err(|source| Error::ReadRecording {
            path: path.to_path_buf(),
            source,
        })?;
        if bytes.contains(&0) {
            Recording::parse_binary(&bytes, path)
        } else {
            let text = String::from_utf8(bytes).map_err(|e| Error::RecordingSyntax {
                path: path.to_path_buf(),
                line: 0,
                detail: format!("not UTF-8 text and not binary (no NUL byte): {e}"),
            })?;
            Recording::parse_text(&text, path)
        }
    }

    /// Parses the text format; `path` only names the source in errors.
    ///
    /// # Errors
    /// [`Error::RecordingSyntax`] naming the first bad line.
    pub fn parse_text(text: &str, path: &Path) -> Result<Recording> {
        let mut entries = Vec::new();
        let mut last = Duration::ZERO;
        for (i, line) in text.lines().enumerate() {
            let err = |detail: String| Error::RecordingSyntax {
                path: path.to_path_buf(),
                line: i + 1,
                detail,
            };
            let line = line.split('#').next().unwrap_or_default().trim();
            if line.is_empty() {
                continue;
            }
            let tokens: Vec<&str> = line.split_whitespace().collect();
            let (t_token, rest) = tokens
                .split_first()
                .ok_or_else(|| err("empty line".into()))?;
            let at = parse_ms(t_token).ok_or_else(|| {
                err(format!(
                    "{t_token:?} is not a time in ms (a number ≥ 0 such as 12 or 12.5)"
                ))
            })?;
            if at < last {
                return Err(err(format!(
                    "time {t_token} ms goes back (previous entry at {} ms)",
                    last.as_secs_f64() * 1e3
                )));
            }
            last = at;
            let event = parse_entry(rest).map_err(err)?;
            entries.push((at, event));
        }
        Ok(Recording { entries })
    }

    /// Parses raw 24-byte `struct input_event` records; `path` only names the source in errors.
    ///
    /// # Errors
    /// [`Error::RecordingLength`] if the length is not a multiple of 24.
    pub fn parse_binary(bytes: &[u8], path: &Path) -> Result<Recording> {
        if !bytes.len().is_multiple_of(INPUT_EVENT_SIZE) {
            return Err(Error::RecordingLength {
                path: path.to_path_buf(),
                len: bytes.len(),
            });
        }
        let mut entries = Vec::with_capacity(bytes.len() / INPUT_EVENT_SIZE);
        let mut first: Option<i128> = None;
        let mut last = Duration::ZERO;
        for record in bytes.chunks_exact(INPUT_EVENT_SIZE) {
            let (sec, usec, kind, code, value) = decode_record(record);
            let micros = i128::from(sec) * 1_000_000 + i128::from(usec);
            let origin = *first.get_or_insert(micros);
            // Clock steps in a capture (the kernel stamps CLOCK_REALTIME by default) must not
            // make time go backwards: clamp to the previous offset.
            let offset = u64::try_from(micros - origin).unwrap_or(0);
            let at = Duration::from_micros(offset).max(last);
            last = at;
            entries.push((at, DeviceEvent::Raw(RawEvent::new(kind, code, value))));
        }
        Ok(Recording { entries })
    }

    /// The recording as the text format (what [`Recording::parse_text`] reads back).
    pub fn to_text(&self) -> String {
        use std::fmt::Write;
        let mut s = String::new();
        for (at, e) in &self.entries {
            let ms = at.as_secs_f64() * 1e3;
            let what = match e {
                DeviceEvent::Raw(r) => r.to_string(),
                DeviceEvent::AbsState { code, state } => format!(
                    "absinfo {} {} {} {} {} {}",
                    crate::codes::abs_name(*code),
                    state.value,
                    state.minimum,
                    state.maximum,
                    state.fuzz,
                    state.flat
                ),
                DeviceEvent::KeyState { code, pressed } => {
                    format!(
                        "keystate {} {}",
                        crate::codes::key_name(*code),
                        u8::from(*pressed)
                    )
                }
                DeviceEvent::Connected { name } => format!("replug {name}"),
                DeviceEvent::Unplugged { reason } => {
                    // The parser puts "replay: " in front; do not double it.
                    format!(
                        "unplug {}",
                        reason.strip_prefix("replay: ").unwrap_or(reason)
                    )
                }
            };
            let _ = writeln!(s, "{ms} {what}");
        }
        s
    }
}

/// Encodes one raw event as a 24-byte `struct input_event` (for writing binary recordings).
pub fn encode_record(at: Duration, event: RawEvent) -> [u8; INPUT_EVENT_SIZE] {
    let mut out = [0u8; INPUT_EVENT_SIZE];
    let sec = i64::try_from(at.as_secs()).unwrap_or(i64::MAX);
    out[0..8].copy_from_slice(&sec.to_le_bytes());
    out[8..16].copy_from_slice(&i64::from(at.subsec_micros()).to_le_bytes());
    out[16..18].copy_from_slice(&event.kind.to_le_bytes());
    out[18..20].copy_from_slice(&event.code.to_le_bytes());
    out[20..24].copy_from_slice(&event.value.to_le_bytes());
    out
}

fn decode_record(r: &[u8]) -> (i64, i64, u16, u16, i32) {
    let mut b8 = [0u8; 8];
    let mut b4 = [0u8; 4];
    let mut b2 = [0u8; 2];
    b8.copy_from_slice(&r[0..8]);
    let sec = i64::from_le_bytes(b8);
    b8.copy_from_slice(&r[8..16]);
    let usec = i64::from_le_bytes(b8);
    b2.copy_from_slice(&r[16..18]);
    let kind = u16::from_le_bytes(b2);
    b2.copy_from_slice(&r[18..20]);
    let code = u16::from_le_bytes(b2);
    b4.copy_from_slice(&r[20..24]);
    let value = i32::from_le_bytes(b4);
    (sec, usec, kind, code, value)
}

fn parse_ms(s: &str) -> Option<Duration> {
    let ms: f64 = s.parse().ok()?;
    (0.0..1e15)
        .contains(&ms)
        .then(|| Duration::from_secs_f64(ms / 1e3))
}

fn parse_int(s: &str, what: &str) -> Result<i32, String> {
    s.parse()
        .map_err(|_| format!("{s:?} is not a whole number ({what})"))
}

fn parse_entry(tokens: &[&str]) -> Result<DeviceEvent, String> {
    let Some((&head, args)) = tokens.split_first() else {
        return Err("missing event after the time".into());
    };
    match head {
        "unplug" => Ok(DeviceEvent::Unplugged {
            reason: if args.is_empty() {
                "replay: unplugged".into()
            } else {
                format!("replay: {}", args.join(" "))
            },
        }),
        "replug" => Ok(DeviceEvent::Connected {
            name: if args.is_empty() {
                "replay".into()
            } else {
                args.join(" ")
            },
        }),
        "absinfo" => {
            let [code, value, min, max, more @ ..] = args else {
                return Err("absinfo needs: CODE VALUE MIN MAX [FUZZ [FLAT]]".into());
            };
            if more.len() > 2 {
                return Err("absinfo takes at most CODE VALUE MIN MAX FUZZ FLAT".into());
            }
            let code = parse_abs(code)
                .or_else(|| parse_code(crate::codes::EV_ABS, code))
                .ok_or_else(|| format!("{code:?} is not an absolute axis"))?;
            let state = AbsState {
                value: parse_int(value, "value")?,
                minimum: parse_int(min, "min")?,
                maximum: parse_int(max, "max")?,
                fuzz: more.first().map_or(Ok(0), |s| parse_int(s, "fuzz"))?,
                flat: more.get(1).map_or(Ok(0), |s| parse_int(s, "flat"))?,
            };
            Ok(DeviceEvent::AbsState { code, state })
        }
        "keystate" => {
            let [code, value] = args else {
                return Err("keystate needs: CODE 0|1".into());
            };
            let code = parse_key(code)
                .or_else(|| parse_code(EV_KEY, code))
                .ok_or_else(|| format!("{code:?} is not a key or button"))?;
            let pressed = match *value {
                "0" => false,
                "1" => true,
                other => return Err(format!("{other:?} is not 0 or 1")),
            };
            Ok(DeviceEvent::KeyState { code, pressed })
        }
        _ => parse_raw(head, args).map(DeviceEvent::Raw),
    }
}

fn parse_raw(head: &str, args: &[&str]) -> Result<RawEvent, String> {
    // Full form: TYPE CODE VALUE; short form: CODE [VALUE] with the type from the prefix.
    let (kind, code, value) = if head.starts_with("EV_") || head.bytes().all(|b| b.is_ascii_digit())
    {
        let kind =
            parse_type(head).ok_or_else(|| format!("{head:?} is not an event type (EV_ABS, 3)"))?;
        match args {
            [code, value] => (kind, *code, Some(*value)),
            [code] if kind == EV_SYN => (kind, *code, None),
            _ => return Err(format!("{head} needs: CODE VALUE")),
        }
    } else {
        let kind = type_of_code_name(head).ok_or_else(|| {
            format!(
                "{head:?} is not an event (EV_ABS ABS_X 5, ABS_X 5, SYN_REPORT) nor one of \
                 unplug, replug, absinfo, keystate"
            )
        })?;
        match args {
            [value] => (kind, head, Some(*value)),
            [] if kind == EV_SYN => (kind, head, None),
            _ => return Err(format!("{head} needs one VALUE")),
        }
    };
    let code_num =
        parse_code(kind, code).ok_or_else(|| format!("{code:?} is not a code of this type"))?;
    let value = match value {
        Some(v) => parse_int(v, "value")?,
        None => 0,
    };
    Ok(RawEvent::new(kind, code_num, value))
}

/// An [`InputSource`] playing a [`Recording`] through a [`Mapper`]: what the gateway's
/// `source = "replay"` opens, and what the tests drive.
///
/// Offsets count from the origin: the first `poll`'s `now` unless set with
/// [`ReplaySource::with_origin`]. Before the origin is known, [`InputSource::next_deadline`] is
/// `MonoTime::ZERO` ("poll me now"). When the recording ends the last state holds (end a
/// recording with `unplug` or centred sticks).
#[derive(Debug, Clone)]
pub struct ReplaySource {
    mapper: Mapper,
    entries: VecDeque<(Duration, DeviceEvent)>,
    origin: Option<MonoTime>,
    name: String,
}

impl ReplaySource {
    /// Plays `recording` through `mapping`; `name` names it in logs and reasons.
    pub fn new(recording: Recording, mapping: MappingConfig, name: impl Into<String>) -> Self {
        let name = name.into();
        ReplaySource {
            mapper: Mapper::new(mapping, name.clone()),
            entries: recording.entries.into(),
            origin: None,
            name,
        }
    }

    /// Loads `path` (see [`Recording::load`]) and plays it through `mapping`.
    ///
    /// # Errors
    /// As [`Recording::load`].
    pub fn open(path: &Path, mapping: MappingConfig) -> Result<Self> {
        let recording = Recording::load(path)?;
        Ok(ReplaySource::new(
            recording,
            mapping,
            format!("replay {}", path.display()),
        ))
    }

    /// Offsets count from `origin` instead of the first poll.
    pub fn with_origin(mut self, origin: MonoTime) -> Self {
        self.origin = Some(origin);
        self
    }

    /// Entries not yet played.
    pub fn remaining(&self) -> usize {
        self.entries.len()
    }

    /// The mapper's status (link state, mapped values, buttons).
    pub fn status(&self) -> InputStatus {
        self.mapper.status()
    }
}

impl InputSource for ReplaySource {
    fn describe(&self) -> String {
        format!("{} ({} entries left)", self.name, self.entries.len())
    }

    fn poll(&mut self, now: MonoTime) -> Result<Option<InputEvent>, LinkError> {
        let origin = *self.origin.get_or_insert(now);
        while let Some((offset, _)) = self.entries.front() {
            let at = origin + *offset;
            if at > now {
                break;
            }
            if let Some((_, event)) = self.entries.pop_front() {
                self.mapper.feed(at, event);
            }
        }
        self.mapper.tick(now);
        Ok(self.mapper.pop())
    }

    fn next_deadline(&self) -> Option<MonoTime> {
        let Some(origin) = self.origin else {
            return Some(MonoTime::ZERO);
        };
        let next = self.entries.front().map(|(offset, _)| origin + *offset);
        match (next, self.mapper.next_deadline()) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (a, b) => a.or(b),
        }
    }
}

/// A path for error messages of recordings parsed from memory.
pub fn memory_path() -> PathBuf {
    PathBuf::from("<memory>")
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::codes::{EV_ABS, SYN_REPORT};

    fn parse(text: &str) -> Result<Recording> {
        Recording::parse_text(text, &memory_path())
    }

    #[test]
    fn parses_every_line_form() {
        let r = parse(
            "# header\n\
             0 absinfo ABS_X 128 0 255 0 15\n\
             0 keystate BTN_TL 1\n\
             \n\
             10 EV_ABS ABS_X 200 # trailing comment\n\
             10 ABS_Y -30\n\
             10.5 SYN_REPORT\n\
             20 3 0 128\n\
             20 EV_SYN SYN_REPORT 0\n\
             500 unplug cable pulled\n\
             900 replug Pad 2\n",
        )
        .expect("parses");
        let ms = Duration::from_millis;
        assert_eq!(
            r.entries(),
            &[
                (
                    ms(0),
                    DeviceEvent::AbsState {
                        code: 0,
                        state: AbsState {
                            value: 128,
                            minimum: 0,
                            maximum: 255,
                            fuzz: 0,
                            flat: 15
                        }
                    }
                ),
                (
                    ms(0),
                    DeviceEvent::KeyState {
                        code: 0x136,
                        pressed: true
                    }
                ),
                (ms(10), DeviceEvent::Raw(RawEvent::new(EV_ABS, 0, 200))),
                (ms(10), DeviceEvent::Raw(RawEvent::new(EV_ABS, 1, -30))),
                (
                    Duration::from_micros(10_500),
                    DeviceEvent::Raw(RawEvent::syn_report())
                ),
                (ms(20), DeviceEvent::Raw(RawEvent::new(EV_ABS, 0, 128))),
                (
                    ms(20),
                    DeviceEvent::Raw(RawEvent::new(EV_SYN, SYN_REPORT, 0))
                ),
                (
                    ms(500),
                    DeviceEvent::Unplugged {
                        reason: "replay: cable pulled".into()
                    }
                ),
                (
                    ms(900),
                    DeviceEvent::Connected {
                        name: "Pad 2".into()
                    }
                ),
            ]
        );
        // And back through the writer.
        assert_eq!(parse(&r.to_text()).expect("round trip"), r);
    }

    #[test]
    fn syntax_errors_name_the_line_and_token() {
        let cases = [
            ("x ABS_X 1", 1, "\"x\" is not a time"),
            ("0 ABS_X 1\n-1 ABS_X 2", 2, "\"-1\" is not a time"),
            ("5 ABS_X 1\n4 ABS_X 2", 2, "goes back"),
            ("0 ABS_Q 1", 1, "\"ABS_Q\" is not a code"),
            ("0 FOO 1", 1, "\"FOO\" is not an event"),
            ("0 ABS_X", 1, "ABS_X needs one VALUE"),
            ("0 ABS_X one", 1, "\"one\" is not a whole number"),
            ("0 EV_NOPE 1 2", 1, "\"EV_NOPE\" is not an event type"),
            ("0 absinfo ABS_X 1 2", 1, "absinfo needs"),
            ("0 keystate BTN_TL 3", 1, "\"3\" is not 0 or 1"),
            ("0", 1, "missing event"),
        ];
        for (text, line, needle) in cases {
            let err = parse(text).expect_err(text).to_string();
            assert!(
                err.starts_with(&format!("<memory>:{line}: ")) && err.contains(needle),
                "{text:?} → {err}"
            );
        }
    }

    #[test]
    fn binary_records_round_trip_with_relative_times() {
        let mut bytes = Vec::new();
        let base = Duration::from_secs(1_700_000_000);
        bytes.extend(encode_record(base, RawEvent::new(EV_ABS, 1, 77)));
        bytes.extend(encode_record(
            base + Duration::from_micros(2_500),
            RawEvent::syn_report(),
        ));
        // A clock step backwards is clamped, not an error.
        bytes.extend(encode_record(base, RawEvent::new(EV_KEY, 0x130, 1)));
        let r = Recording::parse_binary(&bytes, &memory_path()).expect("parses");
        assert_eq!(
            r.entries(),
            &[
                (
                    Duration::ZERO,
                    DeviceEvent::Raw(RawEvent::new(EV_ABS, 1, 77))
                ),
                (
                    Duration::from_micros(2_500),
                    DeviceEvent::Raw(RawEvent::syn_report())
                ),
                (
                    Duration::from_micros(2_500),
                    DeviceEvent::Raw(RawEvent::new(EV_KEY, 0x130, 1))
                ),
            ]
        );
        assert!(matches!(
            Recording::parse_binary(&bytes[..30], &memory_path()),
            Err(Error::RecordingLength { len: 30, .. })
        ));
    }

    #[test]
    fn missing_file_is_an_error_naming_it() {
        let err = Recording::load(Path::new("/nonexistent/rec.txt")).expect_err("missing");
        assert!(err.to_string().contains("/nonexistent/rec.txt"), "{err}");
    }
}
