//! Bytes → MAVLink messages, never stalling on bytes that are not a message. Pure:
//! no I/O, no clock.
//!
//! The reader thread pushes whatever a read returned; [`Decoder::next_frame`] yields every complete
//! frame whose CRC (with the message's CRC_EXTRA) checks and whose id the `ardupilotmega`
//! dialect knows, decoded with the mavlink crate's own parser ([`Message::parse`]), and every
//! message of the operator-control protocol, which that dialect lacks ([`crate::control`]).
//!
//! Resynchronisation: a candidate that fails (bad CRC, unknown id, unknown incompatibility flag)
//! is skipped by one byte and the bytes already received are scanned again from there. A
//! candidate that is merely *incomplete* (its length byte claims more than has arrived) is not
//! waited for if a complete, valid frame starts later in the buffer: a stray 0xFE inside some
//! payload then costs nothing, where a reader that trusts the claimed length waits for up to 280
//! bytes that may never form a message (ArduPilot's SIMSTATE delayed COMMAND_ACKs by up to 1 s
//! that way).
//!
//! Known limitation (intentional): a frame still arriving whose payload itself contains a whole
//! valid MAVLink frame (a tunnelled one) gives up its place to that inner frame. No message rove
//! receives from an autopilot tunnels MAVLink.

use mavlink::dialects::ardupilotmega::MavMessage;
use mavlink::{MAV_STX, MAV_STX_V2, MavHeader, MavlinkVersion, Message, calculate_crc};

/// Bytes before a MAVLink 2 payload: STX, len, incompat, compat, seq, sysid, compid, msgid×3.
const V2_HEADER: usize = 10;
/// Bytes before a MAVLink 1 payload: STX, len, seq, sysid, compid, msgid.
const V1_HEADER: usize = 6;
/// The CRC after the payload.
const CHECKSUM: usize = 2;
/// A MAVLink 2 signature (link id, timestamp, signature) after the CRC.
const SIGNATURE: usize = 13;
/// MAVLINK_IFLAG_SIGNED, the only incompatibility flag MAVLink 2 defines.
const IFLAG_SIGNED: u8 = 0x01;

/// A decoded frame.
#[derive(Debug, Clone, PartialEq)]
pub struct Frame {
    /// 1 or 2.
    pub version: MavlinkVersion,
    /// Sender and sequence.
    pub header: MavHeader,
    /// The message.
    pub message: Payload,
}

/// A frame's message.
// The dialect's messages are most frames: boxing them would cost an allocation per frame to
// shrink the rare protocol one.
#[allow(clippy::large_enum_variant)]
#[derive(Debug, Clone, PartialEq)]
pub enum Payload {
    /// One the `ardupilotmega` dialect knows.
    Mav(MavMessage),
    /// One of the operator-control protocol.
    Control(crate::control::Message),
}

/// What the bytes at a frame-start marker are.
enum Candidate {
    /// A valid frame of this many bytes.
    Valid(usize, Box<Frame>),
    /// Not a frame: skip the marker.
    Bad,
    /// Could be a frame; more bytes needed.
    Incomplete,
}

/// A frame decoder over a growing byte buffer.
#[derive(Debug, Default)]
pub struct Decoder {
    buf: Vec<u8>,
    skipped: u64,
    /// The bytes of the frame [`Decoder::next_frame`] returned last (reused: no allocation per
    /// frame once it has held the longest).
    last: Vec<u8>,
}

impl Decoder {
    /// An empty decoder.
    pub fn new() -> Decoder {
        Decoder::default()
    }

    /// Appends received bytes.
    pub fn push(&mut self, bytes: &[u8]) {
        self.buf.extend_from_slice(bytes);
    }

    /// Bytes thrown away so far (garbage, bad CRC, unknown messages).
    pub fn skipped(&self) -> u64 {
        self.skipped
    }

    /// The bytes of the frame [`Decoder::next_frame`] returned last, as received (sequence,
    /// signature and all): what a router forwards.
    pub fn raw(&self) -> &[u8] {
        &self.last
    }

    /// Forgets buffered bytes (the transport was reopened).
    pub fn clear(&mut self) {
        self.buf.clear();
    }

    /// The next complete frame, if the buffer holds one.
    pub fn next_frame(&mut self) -> Option<Frame> {
        let mut from = 0;
        loop {
            let Some(start) = find_marker(&self.buf, from) else {
                // Nothing that could start a frame: all of it is garbage.
                self.drop_front(self.buf.len());
                return None;
            };
            match candidate(&self.buf[start..]) {
                Candidate::Valid(len, frame) => {
                    self.drop_front(start);
                    self.take_front(len);
                    return Some(*frame);
                }
                Candidate::Bad => from = start + 1,
                Candidate::Incomplete => {
                    // Do not wait for the claimed length if a valid frame already follows.
                    let mut next = start + 1;
                    while let Some(later) = find_marker(&self.buf, next) {
                        if let Candidate::Valid(len, frame) = candidate(&self.buf[later..]) {
                            self.drop_front(later);
                            self.take_front(len);
                            return Some(*frame);
                        }
                        next = later + 1;
                    }
                    self.drop_front(start);
                    return None;
                }
            }
        }
    }

    /// Moves the frame of `len` bytes at the front into [`Decoder::raw`].
    fn take_front(&mut self, len: usize) {
        self.last.clear();
        self.last.extend(self.buf.drain(..len));
    }

    fn drop_front(&mut self, n: usize) {
        self.skipped += n as u64;
        self.buf.drain(..n);
    }
}

fn find_marker(buf: &[u8], from: usize) -> Option<usize> {
    buf.get(from..)?
        .iter()
        .position(|&b| b == MAV_STX || b == MAV_STX_V2)
        .map(|i| i + from)
}

/// Parses the frame at the start of `b` (whose first byte is a marker).
fn candidate(b: &[u8]) -> Candidate {
    let (version, header_len, trailer) = match b.first() {
        Some(&MAV_STX_V2) => {
            let Some(&incompat) = b.get(2) else {
                return Candidate::Incomplete;
            };
            if incompat & !IFLAG_SIGNED != 0 {
                return Candidate::Bad;
            }
            let signature = if incompat & IFLAG_SIGNED != 0 {
                SIGNATURE
            } else {
                0
            };
            (MavlinkVersion::V2, V2_HEADER, CHECKSUM + signature)
        }
        Some(&MAV_STX) => (MavlinkVersion::V1, V1_HEADER, CHECKSUM),
        _ => return Candidate::Bad,
    };
    let Some(&payload_len) = b.get(1) else {
        return Candidate::Incomplete;
    };
    let payload_end = header_len + usize::from(payload_len);
    let len = payload_end + trailer;
    if b.len() < len {
        return Candidate::Incomplete;
    }
    let (seq, sys, comp, id) = match version {
        MavlinkVersion::V2 => (b[4], b[5], b[6], u32::from_le_bytes([b[7], b[8], b[9], 0])),
        MavlinkVersion::V1 => (b[2], b[3], b[4], u32::from(b[5])),
    };
    let crc = u16::from_le_bytes([b[payload_end], b[payload_end + 1]]);
    let extra = crate::control::crc_extra(id).unwrap_or_else(|| MavMessage::extra_crc(id));
    if calculate_crc(&b[1..payload_end], extra) != crc {
        return Candidate::Bad;
    }
    let payload = &b[header_len..payload_end];
    let message = match MavMessage::parse(version, id, payload) {
        Ok(message) => Some(Payload::Mav(message)),
        // Unknown id or a field out of its enum: not a message we can use, unless it is the
        // operator-control protocol's.
        Err(_) => crate::control::parse(id, payload).map(Payload::Control),
    };
    match message {
        Some(message) => Candidate::Valid(
            len,
            Box::new(Frame {
                version,
                header: MavHeader {
                    system_id: u32::from(sys),
                    component_id: comp,
                    sequence: seq,
                },
                message,
            }),
        ),
        None => Candidate::Bad,
    }
}

/// `msg` as one frame's bytes.
///
/// # Errors
/// The message cannot be framed (a MAVLink 1 frame for a message id above 255).
pub fn encode(
    version: MavlinkVersion,
    header: MavHeader,
    msg: &MavMessage,
) -> Result<Vec<u8>, String> {
    if version == MavlinkVersion::V1 && msg.message_id() > 255 {
        return Err(format!(
            "{} (id {}) has no MAVLink 1 form",
            msg.message_name(),
            msg.message_id()
        ));
    }
    let mut out = Vec::with_capacity(64);
    mavlink::write_versioned_msg(&mut out, version, header, msg).map_err(|e| e.to_string())?;
    Ok(out)
}

/// A message the dialect does not know (id `id`, its `crc_extra`, its `payload`) as one frame's
/// bytes, from `header`.
///
/// # Errors
/// A MAVLink 1 frame for an id above 255, or a payload over 255 bytes.
pub fn encode_raw(
    version: MavlinkVersion,
    header: MavHeader,
    (id, crc_extra): (u32, u8),
    payload: &[u8],
) -> Result<Vec<u8>, String> {
    let len =
        u8::try_from(payload.len()).map_err(|_| format!("payload of {} bytes", payload.len()))?;
    let sys = u8::try_from(header.system_id).map_err(|_| "system id over 255".to_string())?;
    let id_bytes = id.to_le_bytes();
    let mut out = match version {
        MavlinkVersion::V2 => vec![
            MAV_STX_V2,
            len,
            0,
            0,
            header.sequence,
            sys,
            header.component_id,
            id_bytes[0],
            id_bytes[1],
            id_bytes[2],
        ],
        MavlinkVersion::V1 => {
            let id = u8::try_from(id).map_err(|_| format!("message {id} has no MAVLink 1 form"))?;
            vec![MAV_STX, len, header.sequence, sys, header.component_id, id]
        }
    };
    out.extend_from_slice(payload);
    let crc = calculate_crc(&out[1..], crc_extra);
    out.extend(crc.to_le_bytes());
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use mavlink::dialects::ardupilotmega::{
        COMMAND_ACK_DATA, HEARTBEAT_DATA, MavCmd, MavResult, SIMSTATE_DATA,
    };

    fn header(seq: u8) -> MavHeader {
        MavHeader {
            system_id: 1,
            component_id: 1,
            sequence: seq,
        }
    }

    fn ack() -> MavMessage {
        MavMessage::COMMAND_ACK(COMMAND_ACK_DATA {
            command: MavCmd::MAV_CMD_DO_SET_MODE,
            result: MavResult::MAV_RESULT_ACCEPTED,
            ..COMMAND_ACK_DATA::default()
        })
    }

    fn bytes(version: MavlinkVersion, msg: &MavMessage) -> Vec<u8> {
        encode(version, header(7), msg).expect("encodes")
    }

    fn all(d: &mut Decoder) -> Vec<MavMessage> {
        std::iter::from_fn(|| d.next_frame().map(|f| mav(f.message))).collect()
    }

    fn mav(p: Payload) -> MavMessage {
        match p {
            Payload::Mav(m) => m,
            other => panic!("not a dialect message: {other:?}"),
        }
    }

    #[test]
    fn the_operator_control_protocol_decodes_and_a_wrong_crc_extra_does_not() {
        use crate::control::{self, Message};
        let h = header(3);
        let mut d = Decoder::new();
        let status = (control::CONTROL_STATUS, control::CONTROL_STATUS_CRC_EXTRA);
        d.push(&encode_raw(MavlinkVersion::V2, h, status, &[1, 250]).expect("frame"));
        let request = control::request_payload(true, 255, (1, 1));
        d.push(&encode_raw(MavlinkVersion::V2, h, control::COMMAND_LONG, &request).expect("frame"));
        let ack = control::ack_payload(control::RESULT_ACCEPTED, (255, 190));
        d.push(&encode_raw(MavlinkVersion::V1, h, control::COMMAND_ACK, &ack).expect("frame"));
        // CONTROL_STATUS framed with another CRC_EXTRA: not a message.
        d.push(
            &encode_raw(
                MavlinkVersion::V2,
                h,
                (control::CONTROL_STATUS, 0),
                &[1, 250],
            )
            .expect("frame"),
        );
        let got: Vec<Payload> = std::iter::from_fn(|| d.next_frame().map(|f| f.message)).collect();
        assert_eq!(
            got,
            vec![
                Payload::Control(Message::Status {
                    flags: 1,
                    gcs_main: 250
                }),
                Payload::Control(Message::Request {
                    request: true,
                    takeover: false,
                    timeout_s: 10.0,
                    gcs: 255,
                    target: (1, 1)
                }),
                Payload::Control(Message::Ack {
                    result: 0,
                    target_system: 255
                }),
            ]
        );
        assert!(
            d.skipped() > 0,
            "the frame with the wrong CRC_EXTRA was skipped"
        );
        assert!(encode_raw(MavlinkVersion::V1, h, status, &[1]).is_err());
    }

    #[test]
    fn a_stray_stx_before_a_valid_frame_does_not_delay_it() {
        // A 0xFE (MAVLink 1 start) claiming 116 payload bytes, then a COMMAND_ACK: the ACK is
        // decoded at once, not after 116 more bytes.
        let mut input = vec![0x00, MAV_STX, 116, 0x12, 0x34];
        input.extend(bytes(MavlinkVersion::V2, &ack()));
        let mut d = Decoder::new();
        d.push(&input);
        let f = d.next_frame().expect("the ACK decodes at once");
        assert_eq!(f.message, Payload::Mav(ack()));
        assert_eq!(f.header, header(7));
        assert_eq!(f.version, MavlinkVersion::V2);
        assert_eq!(d.skipped(), 5, "the stray bytes");
        assert_eq!(d.next_frame(), None);
    }

    #[test]
    fn raw_is_each_frame_as_received_without_what_came_between() {
        let (ack, beat) = (
            bytes(MavlinkVersion::V2, &ack()),
            bytes(
                MavlinkVersion::V1,
                &MavMessage::HEARTBEAT(HEARTBEAT_DATA::default()),
            ),
        );
        let mut d = Decoder::new();
        d.push(&[0x00, MAV_STX, 116, 0x12]);
        d.push(&ack);
        d.push(&[0x55, 0xAA]);
        d.push(&beat);
        assert!(d.next_frame().is_some());
        assert_eq!(d.raw(), &ack[..]);
        assert!(d.next_frame().is_some());
        assert_eq!(d.raw(), &beat[..]);
    }

    #[test]
    fn a_stray_stx_then_a_frame_arriving_later_is_decoded_when_it_completes() {
        let ack = bytes(MavlinkVersion::V2, &ack());
        let mut d = Decoder::new();
        d.push(&[MAV_STX_V2, 200, 0, 0]);
        assert_eq!(d.next_frame(), None, "could still be a frame");
        d.push(&ack[..5]);
        assert_eq!(d.next_frame(), None);
        d.push(&ack[5..]);
        assert!(d.next_frame().is_some(), "decoded with its last byte");
    }

    #[test]
    fn frames_split_anywhere_decode_in_order() {
        let mut stream = Vec::new();
        let sim = MavMessage::SIMSTATE(SIMSTATE_DATA {
            roll: f32::from_le_bytes([0xFE, 0xFE, 0xFD, 0x3F]),
            ..SIMSTATE_DATA::default()
        });
        let hb = MavMessage::HEARTBEAT(HEARTBEAT_DATA::default());
        for m in [&sim, &ack(), &hb] {
            stream.extend(bytes(MavlinkVersion::V2, m));
            stream.extend(bytes(MavlinkVersion::V1, m));
        }
        for chunk in [1, 3, 7, 64, stream.len()] {
            let mut d = Decoder::new();
            let mut got = Vec::new();
            for c in stream.chunks(chunk) {
                d.push(c);
                got.extend(all(&mut d));
            }
            assert_eq!(got.len(), 6, "chunk {chunk}");
            assert_eq!(got[0], sim, "an ardupilotmega message decodes whole");
            assert_eq!(d.skipped(), 0, "chunk {chunk}");
        }
    }

    #[test]
    fn bad_crc_and_unknown_ids_are_skipped_past_their_marker_only() {
        let mut bad = bytes(MavlinkVersion::V2, &ack());
        let last = bad.len() - 1;
        bad[last] ^= 0xFF;
        // A well-formed frame with an id no dialect rove knows (CRC_EXTRA 0).
        let mut unknown = vec![
            MAV_STX_V2, 3, 0, 0, 0, 1, 1, 0x42, 0x42, 0x42, MAV_STX, 0xF0, 1,
        ];
        let crc = calculate_crc(&unknown[1..], 0);
        unknown.extend(crc.to_le_bytes());
        let mut input = bad;
        input.extend(&unknown);
        input.extend(bytes(MavlinkVersion::V2, &ack()));
        let mut d = Decoder::new();
        d.push(&input);
        assert_eq!(all(&mut d), vec![ack()]);
    }

    #[test]
    fn garbage_never_panics_and_never_grows_the_buffer() {
        let mut d = Decoder::new();
        let mut x: u32 = 0x1234_5678;
        for _ in 0..2000 {
            let chunk: Vec<u8> = (0..37)
                .map(|_| {
                    x ^= x << 13;
                    x ^= x >> 17;
                    x ^= x << 5;
                    // Plenty of markers.
                    if x.is_multiple_of(5) {
                        MAV_STX
                    } else {
                        (x >> 8) as u8
                    }
                })
                .collect();
            d.push(&chunk);
            let _ = all(&mut d);
            assert!(d.buf.len() <= V2_HEADER + 255 + CHECKSUM + SIGNATURE);
        }
    }

    #[test]
    fn mavlink_1_cannot_carry_ids_above_255() {
        let msg = MavMessage::ODOMETRY(Default::default());
        assert!(encode(MavlinkVersion::V1, header(0), &msg).is_err());
        assert!(encode(MavlinkVersion::V2, header(0), &msg).is_ok());
    }

    /// A MAVLink 1 frame longer than its message's base fields (a sender that appends the
    /// extension fields) decodes with those fields and is not skipped; re-encoded as MAVLink 1
    /// they are gone (MAVLink 1 does not serialize extensions), as MAVLink 2 they stay. Seen
    /// by the `mavlink` fuzz target (fuzz/README.md), whose round-trip check assumed otherwise.
    #[test]
    fn decoder_reads_extension_bytes_of_a_mavlink1_frame() {
        // COMMAND_ACK (id 77): command u16 (176, DO_SET_MODE), result u8, then the extensions
        // progress u8, result_param2 i32, target_system u8, target_component u8.
        let payload = [176, 0, 0, 50, 1, 0, 0, 0, 255, 190];
        let mut frame = vec![MAV_STX, 10, 7, 1, 1, 77];
        frame.extend_from_slice(&payload);
        let crc = calculate_crc(&frame[1..], MavMessage::extra_crc(77));
        frame.extend_from_slice(&crc.to_le_bytes());
        let mut d = Decoder::new();
        d.push(&frame);
        let f = d.next_frame().expect("a frame");
        assert_eq!(d.skipped(), 0);
        assert_eq!(f.version, MavlinkVersion::V1);
        let msg = mav(f.message);
        let MavMessage::COMMAND_ACK(ack) = &msg else {
            panic!("not a COMMAND_ACK: {msg:?}");
        };
        assert_eq!(ack.command, MavCmd::MAV_CMD_DO_SET_MODE);
        assert_eq!((ack.progress, ack.target_component), (50, 190));
        let mut v1 = Decoder::new();
        v1.push(&bytes(MavlinkVersion::V1, &msg));
        let MavMessage::COMMAND_ACK(again) = mav(v1.next_frame().expect("v1 frame").message) else {
            panic!("not a COMMAND_ACK");
        };
        assert_eq!((again.progress, again.target_component), (0, 0));
        let mut v2 = Decoder::new();
        v2.push(&bytes(MavlinkVersion::V2, &msg));
        assert_eq!(
            v2.next_frame().expect("v2 frame").message,
            Payload::Mav(msg)
        );
    }
}
