//! What the bridges' messages carry: the seed types as JSON (small, self-describing, and read
//! only up to [`MAX_PAYLOAD`] bytes), a command with its source time stamp.

use rove_core::msg::ControlCommand;
use serde::{Deserialize, Serialize};

/// The largest payload read; anything longer is refused unread.
pub(super) const MAX_PAYLOAD: usize = 4096;

/// A ControlCommand and the RTPS source time stamp its writer gave it (ticks: seconds and
/// 2⁻³² fractions), so that the vehicle's freshness check compares the sender's own stamps
/// (rove_core::freshness) and a stream that queued up on the link is not applied late.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub(super) struct Command {
    pub(super) command: ControlCommand,
    pub(super) stamp: Option<u64>,
}

/// `value` as a payload.
pub(super) fn encode<T: Serialize>(value: &T) -> Vec<u8> {
    // The seed types serialise to JSON without fail (no maps with non-string keys, no
    // non-finite floats).
    serde_json::to_vec(value).unwrap_or_default()
}

/// A payload as `T`, if it is one and not longer than [`MAX_PAYLOAD`].
pub(super) fn decode<T: for<'de> Deserialize<'de>>(payload: &[u8]) -> Option<T> {
    if payload.len() > MAX_PAYLOAD {
        return None;
    }
    serde_json::from_slice(payload).ok()
}

#[cfg(test)]
mod tests {
    use super::*;
    use rove_core::msg::{
        Ack, CommandType, DeviceInfo, DeviceType, Mode, MovementCommand, RequestControl, TimeT,
    };

    #[test]
    fn the_seed_types_read_back_as_written_and_junk_is_refused() {
        let command = Command {
            command: ControlCommand {
                src_id: 21,
                dest_id: 100,
                command_type: CommandType::Movement,
                movement_command: MovementCommand {
                    throttle: -32767,
                    roll: 5,
                    pitch: 0,
                    yaw: 32767,
                },
                mode: Mode::Assisted,
                timestamp: TimeT(u64::MAX),
            },
            stamp: Some(7 << 32),
        };
        assert_eq!(decode::<Command>(&encode(&command)), Some(command));
        let info = DeviceInfo {
            device_id: 100,
            name: "rover \"1\" é".into(),
            device_type: DeviceType::Vehicle,
            controller_id: 21,
        };
        assert_eq!(decode::<DeviceInfo>(&encode(&info)), Some(info));
        let request = RequestControl {
            src_id: 21,
            dest_id: 100,
            current_controller_id: 31,
            src_priority: 120,
            ack: Ack::Finish,
            timestamp: TimeT(1),
        };
        assert_eq!(decode::<RequestControl>(&encode(&request)), Some(request));
        assert_eq!(decode::<DeviceInfo>(b"{"), None);
        assert_eq!(decode::<Command>(&encode(&request)), None);
        let long = format!("{{\"name\":\"{}\"}}", "x".repeat(MAX_PAYLOAD));
        assert_eq!(decode::<DeviceInfo>(long.as_bytes()), None);
    }
}
