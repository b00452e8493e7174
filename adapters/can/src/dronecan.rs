//! Pure: DroneCAN (UAVCAN v0) on classic CAN — the message transport and the three messages
//! rove sends.
//!
//! # Transport
//! - **CAN id** (29-bit, message frames): `priority << 24 | data_type_id << 8 | 0 << 7 |
//!   source_node_id` ([`message_id`]).
//! - **Tail byte**, last byte of every frame: start-of-transfer `0x80`, end-of-transfer `0x40`,
//!   toggle `0x20` (0 on the first frame, alternating), transfer id (5 bits, counted per
//!   message type and incremented per transfer, [`TransferIds`]).
//! - **Single frame**: payloads of up to 7 bytes, then the tail byte.
//! - **Multi-frame**: the payload is preceded by the transfer CRC (little-endian) and cut into
//!   7-byte pieces, each followed by a tail byte. The CRC is CRC-16-CCITT (poly 0x1021, no
//!   reflection, no final xor) over the data type signature (8 bytes, little-endian) and then
//!   the payload, starting from 0xFFFF ([`transfer_crc`]).
//!
//! # Messages (DSDL bit-packing: little-endian values, bits filled from the most significant
//! end of each byte)
//! - `uavcan.equipment.actuator.ArrayCommand` (1010): `Command[<=15]` with tail array
//!   optimisation (no length prefix); each command is `uint8 actuator_id, uint8 command_type,
//!   float16 command_value`. rove sends `COMMAND_TYPE_UNITLESS` (−1..=1).
//! - `uavcan.equipment.esc.RawCommand` (1030): `int14[<=20] cmd`, tail array optimisation,
//!   −8192..=8191.
//! - `uavcan.protocol.NodeStatus` (341): `uint32 uptime_sec, uint2 health, uint3 mode,
//!   uint3 sub_mode, uint16 vendor_specific_status_code`.
//!
//! Data type ids and signatures are those of the DSDL shipped with pydronecan 1.0.27 (printed
//! by `tests/golden/gen_dronecan.py`); the golden tests below compare against frames that
//! script produced with pydronecan's own `Transfer.to_frames()`.

use crate::bus::{CanFrameData, CanId};
use crate::error::FrameError;

/// A DroneCAN message type: its data type id and DSDL signature.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct DataType {
    /// Full name, for logs.
    pub name: &'static str,
    /// Default data type id.
    pub id: u16,
    /// Data type signature (from the normalised DSDL definition).
    pub signature: u64,
}

/// `uavcan.equipment.actuator.ArrayCommand`.
pub const ARRAY_COMMAND: DataType = DataType {
    name: "uavcan.equipment.actuator.ArrayCommand",
    id: 1010,
    signature: 0xD8A7_4862_38EC_3AF3,
};

/// `uavcan.equipment.esc.RawCommand`.
pub const RAW_COMMAND: DataType = DataType {
    name: "uavcan.equipment.esc.RawCommand",
    id: 1030,
    signature: 0x217F_5C87_D7EC_951D,
};

/// `uavcan.protocol.NodeStatus`.
pub const NODE_STATUS: DataType = DataType {
    name: "uavcan.protocol.NodeStatus",
    id: 341,
    signature: 0x0F08_68D0_C1A7_C6F1,
};

/// Most commands in one ArrayCommand (`Command[<=15]`).
pub const MAX_SERVOS: usize = 15;

/// Most ESC channels in one RawCommand (`int14[<=20]`).
pub const MAX_ESCS: usize = 20;

/// RawCommand's range (int14).
pub const RAW_COMMAND_RANGE: std::ops::RangeInclusive<i64> = -8192..=8191;

/// Node ids a node may take (0 is anonymous, 128+ do not fit 7 bits).
pub const NODE_ID_RANGE: std::ops::RangeInclusive<i64> = 1..=127;

/// Transfer priorities (0 highest, 31 lowest).
pub const PRIORITY_RANGE: std::ops::RangeInclusive<i64> = 0..=31;

/// Priority of NodeStatus: libcanard's "low" (24). Status is not urgent; commands should win
/// arbitration over it.
pub const NODE_STATUS_PRIORITY: u8 = 24;

/// `ArrayCommand` command type for unitless commands in −1..=1.
pub const COMMAND_TYPE_UNITLESS: u8 = 0;

const SOT: u8 = 0x80;
const EOT: u8 = 0x40;
const TOGGLE: u8 = 0x20;
const TRANSFER_ID_MASK: u8 = 0x1F;

/// Data bytes per classic frame before the tail byte.
const FRAME_PAYLOAD: usize = 7;

/// CRC-16-CCITT (poly 0x1021, MSB first, no final xor) of `bytes`, continuing from `crc`.
pub fn crc16_ccitt(mut crc: u16, bytes: &[u8]) -> u16 {
    for &byte in bytes {
        crc ^= u16::from(byte) << 8;
        for _ in 0..8 {
            crc = if crc & 0x8000 != 0 {
                (crc << 1) ^ 0x1021
            } else {
                crc << 1
            };
        }
    }
    crc
}

/// The transfer CRC of a multi-frame transfer of `payload` of type `data_type`: seeded with the
/// data type signature, as the specification requires.
pub fn transfer_crc(data_type: &DataType, payload: &[u8]) -> u16 {
    let seed = crc16_ccitt(0xFFFF, &data_type.signature.to_le_bytes());
    crc16_ccitt(seed, payload)
}

/// The 29-bit CAN id of a message of type `data_type_id` from `source_node` at `priority`
/// (both masked to their field widths).
pub fn message_id(priority: u8, data_type_id: u16, source_node: u8) -> u32 {
    (u32::from(priority & 0x1F) << 24)
        | (u32::from(data_type_id) << 8)
        | u32::from(source_node & 0x7F)
}

/// The frames of one transfer: `payload` of `data_type` as transfer `transfer_id`.
///
/// # Errors
/// [`FrameError::IdOutOfRange`] cannot happen for a masked id; kept for the frame builder's
/// signature. Never panics for any payload length.
pub fn transfer_frames(
    data_type: &DataType,
    priority: u8,
    source_node: u8,
    transfer_id: u8,
    payload: &[u8],
) -> Result<Vec<CanFrameData>, FrameError> {
    let id = CanId::new(message_id(priority, data_type.id, source_node), true)?;
    let tid = transfer_id & TRANSFER_ID_MASK;
    let body: Vec<u8> = if payload.len() <= FRAME_PAYLOAD {
        payload.to_vec()
    } else {
        let crc = transfer_crc(data_type, payload);
        let mut body = Vec::with_capacity(payload.len() + 2);
        body.extend_from_slice(&crc.to_le_bytes());
        body.extend_from_slice(payload);
        body
    };
    // An empty payload is still one frame (tail byte only).
    let pieces: Vec<&[u8]> = if body.is_empty() {
        vec![&[]]
    } else {
        body.chunks(FRAME_PAYLOAD).collect()
    };
    let last = pieces.len() - 1;
    let mut frames = Vec::with_capacity(pieces.len());
    for (i, piece) in pieces.iter().enumerate() {
        let mut tail = tid;
        if i == 0 {
            tail |= SOT;
        }
        if i == last {
            tail |= EOT;
        }
        if i % 2 == 1 {
            tail |= TOGGLE;
        }
        let mut data = [0u8; FRAME_PAYLOAD + 1];
        data[..piece.len()].copy_from_slice(piece);
        data[piece.len()] = tail;
        frames.push(CanFrameData::new(id, &data[..=piece.len()])?);
    }
    Ok(frames)
}

/// Per-message-type transfer id counters (5 bits, wrapping).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct TransferIds {
    array_command: u8,
    raw_command: u8,
    node_status: u8,
}

impl TransferIds {
    /// The id for the next transfer of `data_type`, advancing its counter.
    pub fn next(&mut self, data_type: &DataType) -> u8 {
        let counter = match data_type.id {
            id if id == ARRAY_COMMAND.id => &mut self.array_command,
            id if id == RAW_COMMAND.id => &mut self.raw_command,
            _ => &mut self.node_status,
        };
        let id = *counter;
        *counter = (id + 1) & TRANSFER_ID_MASK;
        id
    }
}

/// Writes DSDL bit streams.
#[derive(Debug, Default)]
struct BitWriter {
    bytes: Vec<u8>,
    bits: usize,
}

impl BitWriter {
    fn push_bit(&mut self, bit: bool) {
        if self.bits.is_multiple_of(8) {
            self.bytes.push(0);
        }
        if let (true, Some(last)) = (bit, self.bytes.last_mut()) {
            *last |= 0x80 >> (self.bits % 8);
        }
        self.bits += 1;
    }

    /// Appends the low `bitlen` bits of `value` (≤ 64) as DSDL does: whole bytes from the least
    /// significant up, then the remaining high bits; each piece most significant bit first.
    fn write(&mut self, value: u64, bitlen: u32) {
        let mut remaining = bitlen.min(64);
        let mut v = value;
        while remaining > 0 {
            let n = remaining.min(8);
            let chunk = v & ((1u64 << n) - 1);
            for i in (0..n).rev() {
                self.push_bit(chunk >> i & 1 == 1);
            }
            v = v.checked_shr(8).unwrap_or(0);
            remaining -= n;
        }
    }

    fn finish(self) -> Vec<u8> {
        self.bytes
    }
}

/// IEEE 754 half precision bits of `value`, bit for bit as libuavcan and pydronecan round
/// (`f16_from_f32`): round half up on the magnitude, overflow to infinity, NaN to 0x7FFF.
pub fn f16_bits(value: f32) -> u16 {
    const F32_INFTY: u32 = 255 << 23;
    const F16_INFTY: u32 = 31 << 23;
    const ROUND_MASK: u32 = !0xFFF;
    let magic = f32::from_bits(15 << 23);
    let mut bits = value.to_bits();
    let sign = bits & 0x8000_0000;
    bits ^= sign;
    let out = if bits >= F32_INFTY {
        if bits > F32_INFTY { 0x7FFF } else { 0x7C00 }
    } else {
        bits &= ROUND_MASK;
        let scaled = f32::from_bits(bits) * magic;
        let mut u = scaled.to_bits().wrapping_sub(ROUND_MASK);
        if u > F16_INFTY {
            u = F16_INFTY;
        }
        (u >> 13) & 0xFFFF
    };
    (out | (sign >> 16)) as u16
}

/// `ArrayCommand` payload: one unitless command per `(actuator_id, value)`, at most
/// [`MAX_SERVOS`] (extra ones are left out; validation prevents them).
pub fn array_command(commands: &[(u8, f32)]) -> Vec<u8> {
    let mut w = BitWriter::default();
    for (actuator_id, value) in commands.iter().take(MAX_SERVOS) {
        w.write(u64::from(*actuator_id), 8);
        w.write(u64::from(COMMAND_TYPE_UNITLESS), 8);
        w.write(u64::from(f16_bits(*value)), 16);
    }
    w.finish()
}

/// `RawCommand` payload: `cmd`, each clamped to int14, at most [`MAX_ESCS`].
pub fn raw_command(cmd: &[i16]) -> Vec<u8> {
    let mut w = BitWriter::default();
    for c in cmd.iter().take(MAX_ESCS) {
        let clamped = i64::from(*c).clamp(*RAW_COMMAND_RANGE.start(), *RAW_COMMAND_RANGE.end());
        w.write(clamped as u64 & 0x3FFF, 14);
    }
    w.finish()
}

/// `NodeStatus.health`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum NodeHealth {
    /// `HEALTH_OK`.
    Ok = 0,
    /// `HEALTH_WARNING`.
    Warning = 1,
    /// `HEALTH_ERROR`.
    Error = 2,
    /// `HEALTH_CRITICAL`.
    Critical = 3,
}

/// `NodeStatus` payload for `MODE_OPERATIONAL`, sub-mode 0.
pub fn node_status(uptime_sec: u32, health: NodeHealth, vendor_status: u16) -> Vec<u8> {
    const MODE_OPERATIONAL: u64 = 0;
    let mut w = BitWriter::default();
    w.write(u64::from(uptime_sec), 32);
    w.write(health as u64, 2);
    w.write(MODE_OPERATIONAL, 3);
    w.write(0, 3);
    w.write(u64::from(vendor_status), 16);
    w.finish()
}

/// Reassembles one transfer as a receiver does (pydronecan `Transfer.from_frames`): checks
/// the tail bits and, for several frames, the CRC; returns the payload, or `None` if the frames
/// are not one valid transfer. rove only transmits; this is the receiver its tests and the
/// fuzz target check [`transfer_frames`] against.
pub fn reassemble(data_type: &DataType, frames: &[CanFrameData]) -> Option<Vec<u8>> {
    let mut body = Vec::new();
    let tid = frames.first()?.data().last()? & TRANSFER_ID_MASK;
    for (i, f) in frames.iter().enumerate() {
        let (tail, data) = f.data().split_last()?;
        let ok = (tail & TRANSFER_ID_MASK) == tid
            && ((tail & SOT) != 0) == (i == 0)
            && ((tail & EOT) != 0) == (i == frames.len() - 1)
            && ((tail & TOGGLE) != 0) == (i % 2 == 1);
        if !ok {
            return None;
        }
        body.extend_from_slice(data);
    }
    if frames.len() == 1 {
        return Some(body);
    }
    let crc = u16::from_le_bytes([*body.first()?, *body.get(1)?]);
    let payload = body.split_off(2);
    (crc == transfer_crc(data_type, &payload)).then_some(payload)
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// `(29-bit CAN id, data bytes)` as printed by tests/golden/gen_dronecan.py.
    type Golden = (u32, &'static [u8]);

    fn frames_of(frames: &[CanFrameData]) -> Vec<(u32, Vec<u8>)> {
        frames
            .iter()
            .map(|f| (f.id().raw(), f.data().to_vec()))
            .collect()
    }

    fn golden(expected: &[Golden]) -> Vec<(u32, Vec<u8>)> {
        expected.iter().map(|(id, d)| (*id, d.to_vec())).collect()
    }

    // All golden frames below: node id 100, priority 16 (NodeStatus 24), produced by
    // tests/golden/gen_dronecan.py with pydronecan (PyPI `dronecan`) 1.0.27.

    #[test]
    fn golden_array_command_single_frame() {
        // payload 00 00 00 38: actuator 0, unitless, 0.5 = f16 0x3800 little-endian.
        let payload = array_command(&[(0, 0.5)]);
        assert_eq!(payload, [0x00, 0x00, 0x00, 0x38]);
        let frames = transfer_frames(&ARRAY_COMMAND, 16, 100, 0, &payload).expect("frames");
        // id 0x1003F264: priority 16, dtid 1010 (0x3F2), message, node 100 (0x64);
        // tail 0xC0: start + end, toggle 0, transfer id 0.
        let expected: &[Golden] = &[(0x1003_F264, &[0x00, 0x00, 0x00, 0x38, 0xC0])];
        assert_eq!(frames_of(&frames), golden(expected));
    }

    #[test]
    fn golden_array_command_multi_frame_with_crc() {
        // Three servos: −1.0 (0xBC00), 0.3333 (0x3555, rounded), 0.25 (0x3400).
        let payload = array_command(&[(0, -1.0), (1, 0.3333), (2, 0.25)]);
        assert_eq!(
            payload,
            [
                0x00, 0x00, 0x00, 0xBC, 0x01, 0x00, 0x55, 0x35, 0x02, 0x00, 0x00, 0x34
            ]
        );
        let frames = transfer_frames(&ARRAY_COMMAND, 16, 100, 5, &payload).expect("frames");
        let expected: &[Golden] = &[
            // CRC 0x129C (little-endian 9C 12), 5 payload bytes, tail 0x85: start, tid 5.
            (
                0x1003_F264,
                &[0x9C, 0x12, 0x00, 0x00, 0x00, 0xBC, 0x01, 0x85],
            ),
            // 7 payload bytes, tail 0x65: end, toggle, tid 5.
            (
                0x1003_F264,
                &[0x00, 0x55, 0x35, 0x02, 0x00, 0x00, 0x34, 0x65],
            ),
        ];
        assert_eq!(frames_of(&frames), golden(expected));
        assert_eq!(transfer_crc(&ARRAY_COMMAND, &payload), 0x129C);
    }

    #[test]
    fn golden_raw_command_single_and_multi_frame() {
        // Four int14 values in 56 bits = 7 bytes: one frame.
        let payload = raw_command(&[0, 8191, -8192, 1234]);
        let frames = transfer_frames(&RAW_COMMAND, 16, 100, 7, &payload).expect("frames");
        // id 0x10040664: dtid 1030 (0x406); tail 0xC7: start + end, tid 7.
        let expected: &[Golden] = &[(
            0x1004_0664,
            &[0x00, 0x03, 0xFD, 0xF0, 0x08, 0x34, 0x84, 0xC7],
        )];
        assert_eq!(frames_of(&frames), golden(expected));
        // Six values: 84 bits = 11 bytes; CRC A0E2 seeded with RawCommand's signature.
        let payload = raw_command(&[100, -100, 4000, -4000, 0, 8191]);
        let frames = transfer_frames(&RAW_COMMAND, 16, 100, 30, &payload).expect("frames");
        let expected: &[Golden] = &[
            (
                0x1004_0664,
                &[0xE2, 0xA0, 0x64, 0x02, 0x73, 0xFA, 0x03, 0x9E],
            ),
            (0x1004_0664, &[0xD8, 0x30, 0x00, 0x03, 0xFD, 0xF0, 0x7E]),
        ];
        assert_eq!(frames_of(&frames), golden(expected));
    }

    #[test]
    fn golden_node_status() {
        let payload = node_status(12345, NodeHealth::Ok, 0);
        let frames = transfer_frames(&NODE_STATUS, 24, 100, 31, &payload).expect("frames");
        // id 0x18015564: priority 24, dtid 341 (0x155); tail 0xDF: start + end, tid 31.
        let expected: &[Golden] = &[(
            0x1801_5564,
            &[0x39, 0x30, 0x00, 0x00, 0x00, 0x00, 0x00, 0xDF],
        )];
        assert_eq!(frames_of(&frames), golden(expected));
        // Health WARNING is the top two bits of byte 4 (0x40); vendor code little-endian.
        let payload = node_status(70000, NodeHealth::Warning, 0xBEEF);
        let frames = transfer_frames(&NODE_STATUS, 24, 100, 2, &payload).expect("frames");
        let expected: &[Golden] = &[(
            0x1801_5564,
            &[0x70, 0x11, 0x01, 0x00, 0x40, 0xEF, 0xBE, 0xC2],
        )];
        assert_eq!(frames_of(&frames), golden(expected));
    }

    #[test]
    fn crc_matches_the_ccitt_check_value_and_signature_seeds() {
        assert_eq!(crc16_ccitt(0xFFFF, b"123456789"), 0x29B1);
        // pydronecan's base_crc of each type (CRC of the signature alone).
        for (t, base) in [
            (ARRAY_COMMAND, 0x5E37),
            (RAW_COMMAND, 0xE4B8),
            (NODE_STATUS, 0xBE5F),
        ] {
            assert_eq!(transfer_crc(&t, &[]), base, "{}", t.name);
        }
    }

    #[test]
    fn f16_matches_the_reference_conversion() {
        for (value, bits) in [
            (0.0f32, 0x0000u16),
            (-0.0, 0x8000),
            (1.0, 0x3C00),
            (-1.0, 0xBC00),
            (0.5, 0x3800),
            (0.3333, 0x3555),
            (65504.0, 0x7BFF),
            (1e6, 0x7C00),
            (f32::INFINITY, 0x7C00),
            (f32::NEG_INFINITY, 0xFC00),
            (f32::NAN, 0x7FFF),
        ] {
            assert_eq!(f16_bits(value), bits, "{value}");
        }
    }

    #[test]
    fn transfer_ids_count_per_type_and_wrap_at_32() {
        let mut ids = TransferIds::default();
        assert_eq!(ids.next(&ARRAY_COMMAND), 0);
        assert_eq!(ids.next(&ARRAY_COMMAND), 1);
        assert_eq!(ids.next(&NODE_STATUS), 0);
        for _ in 2..31 {
            ids.next(&ARRAY_COMMAND);
        }
        assert_eq!(ids.next(&ARRAY_COMMAND), 31);
        assert_eq!(ids.next(&ARRAY_COMMAND), 0);
        assert_eq!(ids.next(&RAW_COMMAND), 0);
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(2_000))]

        /// Any payload (0..=100 bytes) splits into frames a receiver reassembles, with a valid
        /// CRC when it takes more than one frame.
        #[test]
        fn transfers_reassemble(payload in prop::collection::vec(any::<u8>(), 0..=100), tid: u8) {
            let frames = transfer_frames(&RAW_COMMAND, 16, 100, tid, &payload).expect("frames");
            prop_assert!(frames.iter().all(|f| f.data().len() <= 8 && !f.is_fd()));
            prop_assert_eq!(reassemble(&RAW_COMMAND, &frames), Some(payload));
        }

        /// Encoders take any values without panicking and produce the DSDL lengths.
        #[test]
        fn encoders_are_total(
            cmds in prop::collection::vec((any::<u8>(), any::<f32>()), 0..=20),
            raw in prop::collection::vec(any::<i16>(), 0..=25),
        ) {
            prop_assert_eq!(array_command(&cmds).len(), 4 * cmds.len().min(MAX_SERVOS));
            prop_assert_eq!(raw_command(&raw).len(), (14 * raw.len().min(MAX_ESCS)).div_ceil(8));
        }
    }
}
