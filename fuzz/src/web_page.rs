//! Messages from a browser into the web console: each line of the input is one WebSocket text
//! message, classified by [`rove_gateway::web::page_message`]; its frames and losses drive a
//! [`RemoteInput`] (the byte after each line's newline advances time by 0–255 ms), as the
//! gateway does.
//!
//! Checked, besides "no panic": a loss reason is at most
//! [`MAX_REASON`] characters with no control characters; axes
//! come out only from a frame with its deadman held; the first axes after the start, a loss or
//! a release are centred.

use rove_core::adapter::InputEvent;
use rove_core::remote::{RemoteInput, is_centred};
use rove_core::time::MonoTime;
use rove_gateway::web::{MAX_REASON, PageMessage, SILENCE, page_message};

/// Feeds every line of `data` as a page message.
pub fn web_page(data: &[u8]) {
    let mut input = RemoteInput::new(SILENCE);
    let mut now = MonoTime::ZERO;
    let mut must_centre = true;
    for line in data.split(|&b| b == b'\n') {
        let step = line.first().copied().unwrap_or(0);
        now = now + std::time::Duration::from_millis(u64::from(step));
        input.tick(now);
        let Ok(text) = std::str::from_utf8(line) else {
            continue;
        };
        let held = match page_message(text) {
            PageMessage::Frame(frame) => {
                input.frame(now, frame);
                frame.deadman
            }
            PageMessage::Lost(why) => {
                assert!(why.chars().count() <= MAX_REASON, "{why:?}");
                assert!(!why.chars().any(char::is_control), "{why:?}");
                input.lost(&why);
                false
            }
            PageMessage::Command => continue,
        };
        while let Some(event) = input.pop() {
            match event {
                InputEvent::Axes(m) => {
                    assert!(held, "axes from a frame without its deadman: {text}");
                    assert!(!must_centre || is_centred(&m), "a jump: {m:?} from {text}");
                    must_centre = false;
                }
                InputEvent::Deadman(false) | InputEvent::Lost { .. } => must_centre = true,
                _ => {}
            }
        }
    }
}
