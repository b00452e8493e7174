//! Property tests: any event sequence never panics, axes stay within ±32767, and the first
//! `Axes` after a start or a `Lost` is at rest (the no-jump rule). Cases: `PROPTEST_CASES`
//! (CI runs 10 000).

use proptest::prelude::*;
use rove_core::adapter::InputEvent;
use rove_core::time::MonoTime;
use rove_inputs::codes::RawEvent;
use rove_inputs::config::MappingConfig;
use rove_inputs::curve::AbsState;
use rove_inputs::mapper::REST_TOLERANCE;
use rove_inputs::{DeviceEvent, InputSettings, Mapper, Recording};
use std::path::Path;

fn mapping(deadman: bool, silence: bool) -> MappingConfig {
    let mut text = String::from(
        r#"
        source = "joystick"
        [axes.roll]
        abs = "ABS_X"
        deadzone_pct = 3.0
        expo = 0.4
        [axes.throttle]
        abs = "ABS_Y"
        invert = true
        min = -1000
        max = 1000
        [axes.pitch]
        abs = "ABS_HAT0Y"
        [axes.yaw]
        negative = "KEY_A"
        positive = "KEY_D"
        ramp_up_ms = 30
        spring_back_ms = 0
        [buttons]
        accept = "BTN_SOUTH"
        next_vehicle = "ABS_HAT0X+"
        previous_vehicle = "ABS_HAT0X-"
        "#,
    );
    if deadman {
        text.push_str("deadman = \"BTN_TL\"\n");
    }
    if silence {
        text = format!("silence_timeout_ms = 60\n{text}");
    }
    toml::from_str::<InputSettings>(&text)
        .expect("parses")
        .validate()
        .expect("valid")
        .mapping
        .clone()
}

fn raw() -> impl Strategy<Value = RawEvent> {
    prop_oneof![
        4 => prop_oneof![Just(0u16), Just(3)].prop_map(|c| RawEvent::new(0, c, 0)),
        3 => (
            prop_oneof![Just(0x130u16), Just(0x136), Just(30), Just(32), 0u16..0x300],
            0i32..3
        )
            .prop_map(|(c, v)| RawEvent::new(1, c, v)),
        4 => (
            0u16..0x12,
            prop_oneof![any::<i32>(), -2i32..3, -1100i32..1100, -33000i32..33000]
        )
            .prop_map(|(c, v)| RawEvent::new(3, c, v)),
        1 => (any::<u16>(), any::<u16>(), any::<i32>()).prop_map(|(k, c, v)| RawEvent::new(k, c, v)),
    ]
}

fn device_event() -> impl Strategy<Value = DeviceEvent> {
    prop_oneof![
        10 => raw().prop_map(DeviceEvent::Raw),
        2 => (0u16..0x12, any::<i32>(), any::<i32>(), any::<i32>(), any::<i32>()).prop_map(
            |(code, value, minimum, maximum, flat)| DeviceEvent::AbsState {
                code,
                state: AbsState { value, minimum, maximum, fuzz: 0, flat },
            }
        ),
        1 => (prop_oneof![Just(0x130u16), Just(0x136), Just(30), Just(32)], any::<bool>())
            .prop_map(|(code, pressed)| DeviceEvent::KeyState { code, pressed }),
        1 => Just(DeviceEvent::Connected { name: "pad".into() }),
        1 => Just(DeviceEvent::Unplugged { reason: "gone".into() }),
    ]
}

/// (ms since the previous step, event or a bare tick).
fn steps() -> impl Strategy<Value = Vec<(u64, Option<DeviceEvent>)>> {
    prop::collection::vec(
        (0u64..40, prop::option::weighted(0.85, device_event())),
        0..200,
    )
}

const AT_REST: i32 = (REST_TOLERANCE * 32767.0) as i32 + 1;

proptest! {
    #![proptest_config(ProptestConfig { cases: 10_000, ..ProptestConfig::default() })]

    #[test]
    fn any_sequence_is_safe(deadman in any::<bool>(), silence in any::<bool>(), steps in steps()) {
        let mut m = Mapper::new(mapping(deadman, silence), "prop");
        let mut t = 0u64;
        // The first Axes after the start or a Lost must be at rest, unless a deadman press
        // (a deliberate act, allowed to resume with the sticks where they are) came first.
        let mut awaiting_first = true;
        for (dt, event) in steps {
            t += dt;
            let now = MonoTime::from_millis(t);
            match event {
                Some(e) => m.feed(now, e),
                None => m.tick(now),
            }
            if let Some(d) = m.next_deadline() {
                prop_assert!(d >= MonoTime::from_millis(t).min(d));
            }
            while let Some(out) = m.pop() {
                match out {
                    InputEvent::Axes(mv) => {
                        for v in [mv.throttle, mv.roll, mv.pitch, mv.yaw] {
                            prop_assert!((-32767..=32767).contains(&v), "{mv:?}");
                        }
                        if awaiting_first {
                            for v in [mv.throttle, mv.roll, mv.pitch, mv.yaw] {
                                prop_assert!(i32::from(v).abs() <= AT_REST, "jump after lost: {mv:?}");
                            }
                            awaiting_first = false;
                        }
                    }
                    InputEvent::Lost { .. } => awaiting_first = true,
                    InputEvent::Deadman(true) => awaiting_first = false,
                    InputEvent::Deadman(false) | InputEvent::Action(_) => {}
                }
            }
            let status = m.status();
            for v in [status.sticks.throttle, status.sticks.roll, status.sticks.pitch, status.sticks.yaw] {
                prop_assert!((-32767..=32767).contains(&v));
            }
        }
    }

    #[test]
    fn any_text_parses_or_errors_without_panicking(text in "\\PC{0,200}") {
        let _ = Recording::parse_text(&text, Path::new("<prop>"));
    }

    #[test]
    fn recording_like_text_never_panics(lines in prop::collection::vec(
        (0u32..1000, prop_oneof![
            Just("ABS_X".to_string()), Just("EV_ABS ABS_Y".to_string()), Just("SYN_REPORT".to_string()),
            Just("absinfo ABS_X".to_string()), Just("keystate BTN_TL".to_string()), Just("unplug".to_string()),
            Just("replug".to_string()), Just("3 0".to_string()), "[A-Z_]{1,10}",
        ], prop::collection::vec("-?[0-9]{1,12}", 0..5)),
        0..30,
    )) {
        let text: String = lines
            .iter()
            .map(|(t, what, args)| format!("{t} {what} {}\n", args.join(" ")))
            .collect();
        let _ = Recording::parse_text(&text, Path::new("<prop>"));
    }

    #[test]
    fn any_bytes_parse_or_error_without_panicking(bytes in prop::collection::vec(any::<u8>(), 0..400)) {
        let _ = Recording::parse_binary(&bytes, Path::new("<prop>"));
    }
}
