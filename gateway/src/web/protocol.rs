//! The page's WebSocket messages (docs/web.md, "Protocol"): input frames, a loss, or a
//! local-API command line. Pure.

use rove_core::msg::MovementCommand;
use rove_core::remote::Frame;

/// A message from the page.
#[derive(Debug, serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct FrameMsg {
    /// Throttle, roll, pitch, yaw.
    #[serde(rename = "in")]
    sticks: [i64; 4],
    /// The deadman is held.
    dm: bool,
}

fn axis(v: i64) -> i16 {
    i16::try_from(v.clamp(i64::from(-i16::MAX), i64::from(i16::MAX))).unwrap_or(0)
}

/// What a page's message is.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum PageMessage {
    /// An input frame, axes clamped to ±32767.
    Frame(Frame),
    /// The page cannot be trusted now (hidden, closing); why, bounded and printable.
    Lost(String),
    /// Anything else: a local-API command line, parsed and answered as the API does.
    Command,
}

/// Longest loss reason taken from a page, in characters.
pub const MAX_REASON: usize = 80;

/// Classifies one text message from a page (docs/web.md, "Protocol").
pub fn page_message(text: &str) -> PageMessage {
    if let Ok(frame) = serde_json::from_str::<FrameMsg>(text) {
        let [throttle, roll, pitch, yaw] = frame.sticks.map(axis);
        let sticks = MovementCommand {
            throttle,
            roll,
            pitch,
            yaw,
        };
        return PageMessage::Frame(Frame {
            sticks,
            deadman: frame.dm,
        });
    }
    let value = serde_json::from_str::<serde_json::Value>(text).ok();
    match value.as_ref().and_then(|v| v.get("lost")?.as_str()) {
        // Said by the page: bounded and printable before it reaches the log.
        Some(why) => PageMessage::Lost(
            why.chars()
                .filter(|c| !c.is_control())
                .take(MAX_REASON)
                .collect(),
        ),
        None => PageMessage::Command,
    }
}
