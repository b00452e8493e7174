//! Pure: a vehicle's outputs for one movement command (or for the safe state) as raw frames and
//! DroneCAN command values. `None` for the movement means "the safe state": every output takes
//! its configured `failsafe` value.

use crate::bus::CanFrameData;
use crate::config::{DroneCanConfig, RawFrameConfig};
use crate::error::FrameError;
use rove_core::msg::MovementCommand;

/// The frame `frame` carries for `movement` (`None`: failsafe values). Bytes no output covers
/// are 0.
///
/// # Errors
/// A [`FrameError`] if the frame's layout is inconsistent, which validation rules out.
pub fn raw_frame(
    frame: &RawFrameConfig,
    movement: Option<&MovementCommand>,
) -> Result<CanFrameData, FrameError> {
    let mut buf = [0u8; crate::bus::FD_MAX_LEN];
    let data = buf
        .get_mut(..frame.length)
        .ok_or(FrameError::DataTooLong { len: frame.length })?;
    for output in &frame.outputs {
        let value = match movement {
            Some(m) => output.scale.map(output.source.value(m)),
            None => output.failsafe,
        };
        output.layout.encode(data, value)?;
    }
    CanFrameData::new(frame.id, data)
}

/// The ArrayCommand entries `(actuator_id, command)` for `movement` (`None`: failsafe), in
/// config order.
pub fn servo_commands(dc: &DroneCanConfig, movement: Option<&MovementCommand>) -> Vec<(u8, f32)> {
    dc.servos
        .iter()
        .map(|s| {
            let value = match movement {
                Some(m) => s.scale.map(s.source.value(m)),
                None => s.failsafe,
            };
            (s.actuator_id, value)
        })
        .collect()
}

/// The RawCommand array for `movement` (`None`: failsafe): one entry per index up to the highest
/// configured one; indices no ESC uses are 0 (stop).
pub fn esc_commands(dc: &DroneCanConfig, movement: Option<&MovementCommand>) -> Vec<i16> {
    let mut cmd = vec![0i16; dc.esc_array_len()];
    for e in &dc.escs {
        let value = match movement {
            Some(m) => e.scale.map(e.source.value(m)),
            None => e.failsafe,
        };
        if let Some(slot) = cmd.get_mut(usize::from(e.index)) {
            // Validated to −8192..=8191; the clamp keeps the conversion total.
            *slot = value.clamp(i64::from(i16::MIN), i64::from(i16::MAX)) as i16;
        }
    }
    cmd
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::CanSettings;

    fn config(text: &str) -> crate::CanConfig {
        toml::from_str::<CanSettings>(text)
            .expect("parses")
            .validate()
            .expect("valid")
    }

    #[test]
    fn shared_frame_carries_each_output_scaled_at_its_place() {
        let c = config(
            r#"
            interface = "can0"
            [[frames]]
            id = 0x123
            length = 8
            [[frames.outputs]]
            source = "throttle"
            offset = 0
            width = 16
            min = -1000
            max = 1000
            failsafe = -5
            [[frames.outputs]]
            source = "roll"
            offset = 2
            width = 8
            signed = false
            min = 0
            centre = 100
            max = 250
            [[frames.outputs]]
            source = "yaw"
            offset = 4
            width = 32
            endian = "big"
            min = 1000000
            max = -1000000
            "#,
        );
        let f = &c.frames[0];
        let m = MovementCommand {
            throttle: 16384,
            roll: -i16::MAX,
            pitch: 0,
            yaw: i16::MAX,
        };
        let frame = raw_frame(f, Some(&m)).expect("frame");
        // throttle 500 (0x01F4 LE), roll → 0, yaw → −1 000 000 (0xFFF0BDC0 BE), byte 3 unused.
        assert_eq!(
            frame.data(),
            [0xF4, 0x01, 0x00, 0x00, 0xFF, 0xF0, 0xBD, 0xC0]
        );
        let safe = raw_frame(f, None).expect("frame");
        // failsafe −5 (0xFFFB), roll centre 100, yaw centre 0.
        assert_eq!(safe.data(), [0xFB, 0xFF, 100, 0, 0, 0, 0, 0]);
    }

    #[test]
    fn dronecan_values_follow_sources_and_fill_unused_esc_indices() {
        let c = config(
            r#"
            interface = "can0"
            [dronecan]
            node_id = 10
            [[dronecan.servos]]
            actuator_id = 4
            source = "roll"
            failsafe = 0.5
            [[dronecan.escs]]
            index = 2
            source = "throttle"
            min = -8191
            max = 8191
            [[dronecan.escs]]
            index = 0
            source = "throttle"
            "#,
        );
        let dc = c.dronecan.as_ref().expect("dronecan");
        let m = MovementCommand {
            throttle: i16::MAX,
            roll: -i16::MAX,
            ..MovementCommand::CENTRED
        };
        assert_eq!(servo_commands(dc, Some(&m)), [(4, -1.0)]);
        assert_eq!(servo_commands(dc, None), [(4, 0.5)]);
        assert_eq!(esc_commands(dc, Some(&m)), [8191, 0, 8191]);
        assert_eq!(esc_commands(dc, None), [0, 0, 0]);
    }
}
