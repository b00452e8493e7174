//! Bytes from an autopilot into rove-mavlink's frame decoder ([`Decoder`]), in reads of the
//! sizes a serial port or socket hands over: the first byte chooses the read size, every
//! read is followed by draining the decoder, as the link's reader thread does.
//!
//! Checked, besides "no panic": the decoder never counts more bytes skipped than it was given;
//! every frame of the dialect it yields re-encodes (as MAVLink 2) to one frame that decodes to
//! the same message; a frame of the operator-control protocol decodes again from its bytes to the
//! same message.

use mavlink::MavlinkVersion;
use rove_mavlink::frame::{Decoder, Payload, encode};

/// Feeds `data` to a decoder.
pub fn mavlink(data: &[u8]) {
    let Some((&size, bytes)) = data.split_first() else {
        return;
    };
    let size = usize::from(size % 64) + 1;
    let mut decoder = Decoder::new();
    let mut pushed = 0u64;
    for chunk in bytes.chunks(size) {
        decoder.push(chunk);
        pushed += chunk.len() as u64;
        while let Some(frame) = decoder.next_frame() {
            // As MAVLink 2 whatever the frame was: MAVLink 1 does not serialize extension
            // fields, yet a MAVLink 1 payload that carries their bytes decodes them (the
            // mavlink crate's reading, and pymavlink's), so a MAVLink 1 re-encoding would drop
            // them. Seen by this target; no message rove acts on depends on it.
            let again = match &frame.message {
                Payload::Mav(msg) => encode(MavlinkVersion::V2, frame.header, msg)
                    .unwrap_or_else(|e| panic!("{frame:?} decoded but does not encode: {e}")),
                Payload::Control(_) => decoder.raw().to_vec(),
            };
            let mut fresh = Decoder::new();
            fresh.push(&again);
            let decoded = fresh.next_frame().unwrap_or_else(|| {
                panic!("{frame:?} re-encoded to {again:?}, which does not decode")
            });
            assert_eq!(
                format!("{:?}", decoded.message),
                format!("{:?}", frame.message)
            );
            assert_eq!(fresh.skipped(), 0);
        }
        assert!(
            decoder.skipped() <= pushed,
            "{} skipped of {pushed}",
            decoder.skipped()
        );
    }
}
