//! DroneCAN transfers through rove-can's transport ([`transfer_frames`]) and back through a
//! receiver's reassembly ([`reassemble`], pydronecan's `Transfer.from_frames`: rove-can only
//! transmits, so the receiver is the model of the nodes on the bus its own tests use too).
//!
//! The payload is one of rove's own messages built from the input by its encoders
//! (ArrayCommand from any `(actuator, f32)` pairs, RawCommand from any `i16`s, NodeStatus from
//! any values) or any bytes (up to 300, many frames); data type, priority, source node and
//! transfer id are any values.
//!
//! Checked, besides "no panic": framing never fails; every frame is a classic CAN frame of at
//! most 8 bytes with a 29-bit id carrying priority, type and node; the tail bits (start, end,
//! toggle, transfer id) are those of frame `i` of `n`; a multi-frame transfer's CRC, seeded
//! with the type's signature, checks; reassembly gives the payload back; the encoders keep to
//! their DSDL lengths.

use crate::bytes::Bytes;
use rove_can::dronecan::{
    ARRAY_COMMAND, DataType, MAX_ESCS, MAX_SERVOS, NODE_STATUS, NodeHealth, RAW_COMMAND,
    array_command, node_status, raw_command, reassemble, transfer_frames,
};

/// Frames `data`'s transfer and reassembles it.
pub fn dronecan(data: &[u8]) {
    let mut input = Bytes::new(data);
    let data_type = match input.u8() % 4 {
        0 => ARRAY_COMMAND,
        1 => RAW_COMMAND,
        2 => NODE_STATUS,
        _ => DataType {
            name: "fuzz",
            id: input.u16(),
            signature: input.u64(),
        },
    };
    let priority = input.u8();
    let node = input.u8();
    let tid = input.u8();
    let payload = match input.u8() % 4 {
        0 => {
            let n = input.below(20);
            let commands: Vec<(u8, f32)> = (0..n)
                .map(|_| (input.u8(), f32::from_bits(input.u32())))
                .collect();
            let payload = array_command(&commands);
            assert_eq!(payload.len(), 4 * n.min(MAX_SERVOS));
            payload
        }
        1 => {
            let n = input.below(25);
            let cmds: Vec<i16> = (0..n).map(|_| input.i16()).collect();
            let payload = raw_command(&cmds);
            assert_eq!(payload.len(), (14 * n.min(MAX_ESCS)).div_ceil(8));
            payload
        }
        2 => {
            let health = [
                NodeHealth::Ok,
                NodeHealth::Warning,
                NodeHealth::Error,
                NodeHealth::Critical,
            ][input.below(4)];
            let payload = node_status(input.u32(), health, input.u16());
            assert_eq!(payload.len(), 7);
            payload
        }
        _ => {
            let n = input.below(256) + usize::from(input.u8() % 45);
            (0..n).map(|_| input.u8()).collect()
        }
    };
    let frames = transfer_frames(&data_type, priority, node, tid, &payload)
        .unwrap_or_else(|e| panic!("{} bytes do not frame: {e}", payload.len()));
    let want_id = (u32::from(priority & 0x1F) << 24)
        | (u32::from(data_type.id) << 8)
        | u32::from(node & 0x7F);
    for f in &frames {
        assert!(!f.is_fd() && f.data().len() <= 8 && !f.data().is_empty());
        assert!(f.id().is_extended());
        assert_eq!(f.id().raw(), want_id);
    }
    assert_eq!(
        reassemble(&data_type, &frames),
        Some(payload),
        "{} frames",
        frames.len()
    );
}
