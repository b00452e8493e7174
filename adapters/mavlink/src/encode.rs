//! Stick values → MAVLink control fields, and the values that release or ignore a channel.
//! Pure: no I/O, no clock.
//!
//! RC_CHANNELS_OVERRIDE rules (MAVLink spec, confirmed on ArduPilot, docs/mavlink.md, "ArduPilot as a GCS sees it"):
//! ch1–8: `0` releases the channel back to the radio, `u16::MAX` leaves it alone ("ignore");
//! ch9–18: `0` and `u16::MAX` ignore, `u16::MAX − 1` releases.

use crate::config::{ChannelConfig, ManualControlConfig, ZRange};
use rove_core::msg::MovementCommand;

/// RC channels an override message can carry.
pub const RC_CHANNELS: usize = 18;

/// "Leave this channel alone" for channel `ch` (1-based).
pub const fn ignore_value(ch: u8) -> u16 {
    if ch <= 8 { u16::MAX } else { 0 }
}

/// "Hand this channel back to the radio" for channel `ch` (1-based).
pub const fn release_value(ch: u8) -> u16 {
    if ch <= 8 { 0 } else { u16::MAX - 1 }
}

/// All 18 fields set to "ignore".
pub fn all_ignored() -> [u16; RC_CHANNELS] {
    let mut v = [0u16; RC_CHANNELS];
    for (i, slot) in v.iter_mut().enumerate() {
        *slot = ignore_value(channel_number(i));
    }
    v
}

fn channel_number(index: usize) -> u8 {
    u8::try_from(index + 1).unwrap_or(u8::MAX)
}

/// The override fields for `movement`: mapped channels carry their pulse, the rest "ignore".
pub fn override_values(
    channels: &[ChannelConfig],
    movement: &MovementCommand,
) -> [u16; RC_CHANNELS] {
    let mut v = all_ignored();
    for c in channels {
        if let Some(slot) = v.get_mut(usize::from(c.channel).wrapping_sub(1)) {
            *slot = c.map.map(c.axis.of(movement));
        }
    }
    v
}

/// The override fields that release every mapped channel (the rest "ignore").
pub fn release_values(channels: &[ChannelConfig]) -> [u16; RC_CHANNELS] {
    let mut v = all_ignored();
    for c in channels {
        if let Some(slot) = v.get_mut(usize::from(c.channel).wrapping_sub(1)) {
            *slot = release_value(c.channel);
        }
    }
    v
}

/// MANUAL_CONTROL's "this axis is invalid" (MAVLink spec).
pub const MANUAL_INVALID: i16 = i16::MAX;

/// ±32767 → ±1000, rounded to nearest; −32768 clamps to −1000.
pub fn scale_signed(v: i16) -> i16 {
    let scaled = (i32::from(v) * 1000 + if v >= 0 { 16_383 } else { -16_383 }) / 32_767;
    i16::try_from(scaled.clamp(-1000, 1000)).unwrap_or(0)
}

/// ±32767 → 0..1000 with 500 at centre (PX4 / Copter throttle).
pub fn scale_positive(v: i16) -> i16 {
    let shifted = i32::from(v).clamp(-32_767, 32_767) + 32_767; // 0..=65534
    let scaled = (shifted * 1000 + 32_767) / 65_534;
    i16::try_from(scaled.clamp(0, 1000)).unwrap_or(500)
}

/// MANUAL_CONTROL's x, y, z, r for `movement`.
pub fn manual_control_values(cfg: &ManualControlConfig, movement: &MovementCommand) -> [i16; 4] {
    let mut out = [MANUAL_INVALID; 4];
    for (i, slot) in out.iter_mut().enumerate() {
        let (Some(Some(axis)), Some(&reverse)) = (cfg.fields.get(i), cfg.reverse.get(i)) else {
            continue;
        };
        let raw = axis.of(movement);
        // `saturating_neg` keeps −32768 inside the range.
        let v = if reverse { raw.saturating_neg() } else { raw };
        *slot = if i == 2 && cfg.z_range == ZRange::Positive {
            scale_positive(v)
        } else {
            scale_signed(v)
        };
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::MavlinkSettings;
    use proptest::prelude::*;
    use rove_core::mapping::{Axis, AxisMap};

    fn mc(throttle: i16, roll: i16, pitch: i16, yaw: i16) -> MovementCommand {
        MovementCommand {
            throttle,
            roll,
            pitch,
            yaw,
        }
    }

    fn rover_channels() -> Vec<ChannelConfig> {
        vec![
            ChannelConfig {
                channel: 1,
                axis: Axis::Roll,
                map: AxisMap::default(),
            },
            ChannelConfig {
                channel: 3,
                axis: Axis::Throttle,
                map: AxisMap::default(),
            },
        ]
    }

    #[test]
    fn mapped_channels_carry_pulses_and_the_rest_are_ignored() {
        let v = override_values(&rover_channels(), &mc(32767, -32767, 5000, 5000));
        assert_eq!(v[0], 1000, "steering full left");
        assert_eq!(v[2], 2000, "throttle full");
        for ch in [2usize, 4, 5, 6, 7, 8] {
            assert_eq!(v[ch - 1], u16::MAX, "ch{ch} ignored");
        }
        for ch in 9..=18usize {
            assert_eq!(v[ch - 1], 0, "ch{ch} ignored (0 above ch8)");
        }
        let centred = override_values(&rover_channels(), &MovementCommand::CENTRED);
        assert_eq!((centred[0], centred[2]), (1500, 1500));
    }

    #[test]
    fn release_uses_zero_up_to_ch8_and_65534_above() {
        let mut channels = rover_channels();
        channels.push(ChannelConfig {
            channel: 12,
            axis: Axis::Yaw,
            map: AxisMap::default(),
        });
        let v = release_values(&channels);
        assert_eq!((v[0], v[2], v[11]), (0, 0, 65534));
        assert_eq!((v[1], v[10], v[17]), (u16::MAX, 0, 0));
    }

    #[test]
    fn manual_control_scales_per_spec() {
        assert_eq!(scale_signed(0), 0);
        assert_eq!(scale_signed(32767), 1000);
        assert_eq!(scale_signed(-32767), -1000);
        assert_eq!(scale_signed(-32768), -1000);
        assert_eq!(scale_signed(16384), 500);
        assert_eq!(scale_positive(0), 500);
        assert_eq!(scale_positive(32767), 1000);
        assert_eq!(scale_positive(-32767), 0);
        assert_eq!(scale_positive(-32768), 0);
        let rover = MavlinkSettings {
            method: Some(crate::config::Method::ManualControl),
            ..MavlinkSettings::default()
        }
        .validate()
        .expect("valid");
        // ArduPilot Rover: y steering, z throttle, both signed (docs/mavlink.md: y=500,
        // z=500 → 1750/1750).
        assert_eq!(
            manual_control_values(&rover.manual_control, &mc(16384, 16384, 0, 0)),
            [0, 500, 500, 0]
        );
        let mut px4 = rover.manual_control;
        px4.z_range = ZRange::Positive;
        px4.reverse[1] = true;
        px4.fields[3] = None;
        assert_eq!(
            manual_control_values(&px4, &mc(0, 32767, -32767, 100)),
            [-1000, -1000, 500, MANUAL_INVALID]
        );
    }

    proptest! {
        #[test]
        fn scaled_values_stay_in_range_and_keep_sign(v in any::<i16>()) {
            let s = scale_signed(v);
            prop_assert!((-1000..=1000).contains(&s));
            // `unsigned_abs`: −32768 has no positive i16 (found by CI, seed kept in
            // proptest-regressions/encode.txt).
            prop_assert_eq!(s.signum(), if v.unsigned_abs() < 17 { s.signum() } else { v.signum() });
            let p = scale_positive(v);
            prop_assert!((0..=1000).contains(&p));
        }

        #[test]
        fn override_values_are_pulses_or_markers(t in any::<i16>(), r in any::<i16>()) {
            let v = override_values(&rover_channels(), &mc(t, r, 0, 0));
            prop_assert!((1000..=2000).contains(&v[0]));
            prop_assert!((1000..=2000).contains(&v[2]));
        }
    }
}
