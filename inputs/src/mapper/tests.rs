//! Unit tests of the mapper: frames, deadman, actions, lost, no-jump, ramps, silence.

use super::*;
use crate::codes::{EV_ABS, EV_KEY, EV_SYN};
use crate::config::InputSettings;
use rove_core::adapter::InputAction;
use rove_core::mapping::Axis;
use rove_core::msg::Mode;

const ABS_X: u16 = 0x00;
const ABS_Y: u16 = 0x01;
const ABS_Z: u16 = 0x02;
const ABS_HAT0X: u16 = 0x10;
const ABS_HAT0Y: u16 = 0x11;
const BTN_SOUTH: u16 = 0x130;
const BTN_TL: u16 = 0x136;
const KEY_W: u16 = 17;
const KEY_S: u16 = 31;

fn mapping(toml_text: &str) -> MappingConfig {
    let mut settings: InputSettings = toml::from_str(toml_text).expect("test TOML parses");
    settings
        .validate()
        .expect("test mapping is valid")
        .mapping
        .clone()
}

fn ms(t: u64) -> MonoTime {
    MonoTime::from_millis(t)
}

/// A stick pad: roll = ABS_X, throttle = ABS_Y inverted, both 0..255.
const PAD: &str = r#"
source = "joystick"
[axes.roll]
abs = "ABS_X"
deadzone_pct = 2.0
[axes.throttle]
abs = "ABS_Y"
invert = true
deadzone_pct = 2.0
"#;

struct Rig {
    m: Mapper,
}

impl Rig {
    fn new(text: &str) -> Rig {
        Rig {
            m: Mapper::new(mapping(text), "test pad"),
        }
    }

    /// A pad connected with both sticks at `x`, `y` (0..255).
    fn pad_at(text: &str, x: i32, y: i32) -> Rig {
        let mut rig = Rig::new(text);
        rig.connect(0, x, y);
        rig
    }

    fn connect(&mut self, t: u64, x: i32, y: i32) {
        self.m
            .feed(ms(t), DeviceEvent::Connected { name: "Pad".into() });
        for (code, value) in [(ABS_X, x), (ABS_Y, y)] {
            self.absinfo(t, code, value, 0, 255);
        }
    }

    fn absinfo(&mut self, t: u64, code: u16, value: i32, minimum: i32, maximum: i32) {
        self.m.feed(
            ms(t),
            DeviceEvent::AbsState {
                code,
                state: AbsState {
                    value,
                    minimum,
                    maximum,
                    fuzz: 0,
                    flat: 0,
                },
            },
        );
    }

    fn raw(&mut self, t: u64, kind: u16, code: u16, value: i32) {
        self.m
            .feed(ms(t), DeviceEvent::Raw(RawEvent::new(kind, code, value)));
    }

    fn abs(&mut self, t: u64, code: u16, value: i32) {
        self.raw(t, EV_ABS, code, value);
    }

    fn key(&mut self, t: u64, code: u16, value: i32) {
        self.raw(t, EV_KEY, code, value);
    }

    fn syn(&mut self, t: u64) {
        self.raw(t, EV_SYN, SYN_REPORT, 0);
    }

    fn drain(&mut self) -> Vec<InputEvent> {
        std::iter::from_fn(|| self.m.pop()).collect()
    }
}

fn axes(throttle: i16, roll: i16) -> InputEvent {
    InputEvent::Axes(MovementCommand {
        throttle,
        roll,
        pitch: 0,
        yaw: 0,
    })
}

fn lost(events: &[InputEvent]) -> usize {
    events
        .iter()
        .filter(|e| matches!(e, InputEvent::Lost { .. }))
        .count()
}

#[test]
fn off_centre_sticks_at_start_emit_nothing_until_centred() {
    let mut rig = Rig::pad_at(PAD, 250, 128);
    assert_eq!(rig.drain(), []);
    assert_eq!(
        rig.m.status().link,
        LinkState::AwaitingRest {
            axes: vec![Axis::Roll]
        }
    );
    // Moving but still off-centre: nothing.
    rig.abs(10, ABS_X, 200);
    rig.syn(10);
    assert_eq!(rig.drain(), []);
    // Centred: the "live" Axes, then changes.
    rig.abs(20, ABS_X, 128);
    rig.syn(20);
    assert_eq!(rig.drain(), [axes(0, 0)]);
    assert_eq!(rig.m.status().link, LinkState::Live);
    rig.abs(30, ABS_X, 255);
    rig.syn(30);
    assert_eq!(rig.drain(), [axes(0, 32767)]);
}

#[test]
fn a_frame_is_one_axes_event_emitted_at_its_syn_report() {
    let mut rig = Rig::pad_at(PAD, 128, 128);
    assert_eq!(rig.drain(), [axes(0, 0)]);
    rig.abs(5, ABS_X, 0);
    rig.abs(5, ABS_Y, 0);
    assert_eq!(rig.drain(), [], "nothing before SYN_REPORT");
    rig.syn(5);
    // ABS_Y is inverted: up (0) is +throttle.
    assert_eq!(rig.drain(), [axes(32767, -32767)]);
    // A frame that changes nothing mapped emits nothing.
    rig.abs(6, ABS_Z, 9);
    rig.syn(6);
    rig.syn(7);
    assert_eq!(rig.drain(), []);
}

#[test]
fn axes_are_always_within_full_scale() {
    let mut rig = Rig::pad_at(PAD, 128, 128);
    rig.drain();
    rig.abs(1, ABS_X, i32::MAX);
    rig.abs(1, ABS_Y, i32::MIN);
    rig.syn(1);
    assert_eq!(rig.drain(), [axes(32767, 32767)]);
}

#[test]
fn deadzone_defaults_to_the_device_flat_and_config_overrides_it() {
    let with_flat = |text: &str| {
        let mut rig = Rig::new(text);
        rig.m.feed(
            ms(0),
            DeviceEvent::AbsState {
                code: ABS_X,
                state: AbsState {
                    value: 127,
                    minimum: 0,
                    maximum: 254,
                    fuzz: 0,
                    flat: 13,
                },
            },
        );
        assert_eq!(rig.drain(), [axes(0, 0)]);
        // 10 of 127 from centre.
        rig.abs(1, ABS_X, 137);
        rig.syn(1);
        rig.drain()
    };
    let device_flat = "source = \"joystick\"\n[axes.roll]\nabs = \"ABS_X\"\n";
    assert_eq!(with_flat(device_flat), [], "inside the device's flat of 13");
    let configured = "source = \"joystick\"\n[axes.roll]\nabs = \"ABS_X\"\ndeadzone_pct = 5.0\n";
    // (10/127 − 0.05) / 0.95 × 32767 ≈ 991.
    assert_eq!(with_flat(configured), [axes(0, 991)]);
}

#[test]
fn config_calibration_expo_and_scale_apply() {
    let text = r#"
        source = "joystick"
        [axes.roll]
        abs = "ABS_X"
        min = 100
        centre = 150
        max = 200
        expo = 1.0
        scale_pct = 50.0
        "#;
    let mut rig = Rig::new(text);
    rig.absinfo(0, ABS_X, 150, 0, 255);
    assert_eq!(rig.drain(), [axes(0, 0)]);
    rig.abs(1, ABS_X, 175);
    rig.syn(1);
    // 0.5 → expo 0.125 → scale 0.0625 → 2048.
    assert_eq!(rig.drain(), [axes(0, 2048)]);
    rig.abs(2, ABS_X, 0);
    rig.syn(2);
    assert_eq!(rig.drain(), [axes(0, -16384)]);
}

#[test]
fn an_axis_without_calibration_never_drives() {
    let mut rig = Rig::new(PAD);
    rig.abs(0, ABS_X, 128);
    rig.abs(0, ABS_Y, 128);
    rig.syn(0);
    assert_eq!(rig.drain(), []);
    assert!(matches!(
        rig.m.status().link,
        LinkState::AwaitingRest { .. }
    ));
}

const DEADMAN_PAD: &str = r#"
source = "joystick"
[axes.roll]
abs = "ABS_X"
deadzone_pct = 2.0
[buttons]
deadman = "BTN_TL"
release = "BTN_SOUTH"
"#;

#[test]
fn deadman_gates_axes_and_its_release_says_stop() {
    let mut rig = Rig::new(DEADMAN_PAD);
    rig.absinfo(0, ABS_X, 128, 0, 255);
    assert_eq!(rig.drain(), [], "live but deadman up: nothing");
    assert_eq!(rig.m.status().deadman, Some(false));
    rig.abs(1, ABS_X, 255);
    rig.syn(1);
    assert_eq!(rig.drain(), []);
    assert_eq!(rig.m.status().output, MovementCommand::CENTRED);
    assert_eq!(rig.m.status().sticks.roll, 32767);
    rig.key(2, BTN_TL, 1);
    rig.syn(2);
    assert_eq!(rig.drain(), [InputEvent::Deadman(true), axes(0, 32767)]);
    rig.abs(3, ABS_X, 128);
    rig.syn(3);
    assert_eq!(rig.drain(), [axes(0, 0)]);
    rig.abs(4, ABS_X, 0);
    rig.key(4, BTN_TL, 0);
    rig.syn(4);
    assert_eq!(rig.drain(), [InputEvent::Deadman(false)]);
    // Pressing again resumes with the current values.
    rig.key(5, BTN_TL, 1);
    rig.syn(5);
    assert_eq!(rig.drain(), [InputEvent::Deadman(true), axes(0, -32767)]);
}

#[test]
fn deadman_release_comes_before_actions_in_a_frame() {
    let mut rig = Rig::new(DEADMAN_PAD);
    rig.absinfo(0, ABS_X, 128, 0, 255);
    rig.key(1, BTN_TL, 1);
    rig.syn(1);
    rig.drain();
    rig.key(2, BTN_SOUTH, 1);
    rig.key(2, BTN_TL, 0);
    rig.syn(2);
    assert_eq!(
        rig.drain(),
        [
            InputEvent::Deadman(false),
            InputEvent::Action(InputAction::Release)
        ]
    );
}

const ALL_ACTIONS: &str = r#"
source = "joystick"
[axes.roll]
abs = "ABS_X"
deadzone_pct = 2.0
[buttons]
mode_manual = "BTN_SOUTH"
mode_assisted = "BTN_EAST"
mode_auto = "BTN_NORTH"
request_control = "BTN_WEST"
accept = "BTN_TL"
refuse = "BTN_TR"
finish = "BTN_SELECT"
release = "BTN_START"
next_vehicle = "ABS_HAT0X+"
previous_vehicle = "ABS_HAT0X-"
"#;

#[test]
fn every_action_fires_on_press_only() {
    let mut rig = Rig::new(ALL_ACTIONS);
    rig.absinfo(0, ABS_X, 128, 0, 255);
    rig.absinfo(0, ABS_HAT0X, 0, -1, 1);
    assert_eq!(rig.drain(), [axes(0, 0)]);
    let buttons = [
        (0x130, InputAction::Mode(Mode::Manual)),
        (0x131, InputAction::Mode(Mode::Assisted)),
        (0x133, InputAction::Mode(Mode::Auto)),
        (0x134, InputAction::RequestControl),
        (0x136, InputAction::Accept),
        (0x137, InputAction::Refuse),
        (0x13a, InputAction::Finish),
        (0x13b, InputAction::Release),
    ];
    let mut t = 1;
    for (code, action) in buttons {
        rig.key(t, code, 1);
        rig.syn(t);
        assert_eq!(rig.drain(), [InputEvent::Action(action)], "{code:#x}");
        // Auto-repeat and release fire nothing.
        rig.key(t + 1, code, 2);
        rig.syn(t + 1);
        rig.key(t + 2, code, 0);
        rig.syn(t + 2);
        assert_eq!(rig.drain(), [], "{code:#x} repeat/release");
        t += 3;
    }
    for (value, action) in [
        (1, InputAction::NextVehicle),
        (-1, InputAction::PreviousVehicle),
    ] {
        rig.abs(t, ABS_HAT0X, value);
        rig.syn(t);
        assert_eq!(rig.drain(), [InputEvent::Action(action)]);
        rig.abs(t + 1, ABS_HAT0X, 0);
        rig.syn(t + 1);
        assert_eq!(rig.drain(), []);
        t += 2;
    }
}

#[test]
fn hats_work_as_axes_and_triggers_as_deadman() {
    let text = r#"
        source = "joystick"
        [axes.pitch]
        abs = "ABS_HAT0Y"
        invert = true
        [buttons]
        deadman = "ABS_Z+"
        "#;
    let mut rig = Rig::new(text);
    rig.absinfo(0, ABS_HAT0Y, 0, -1, 1);
    rig.absinfo(0, ABS_Z, 0, 0, 255);
    rig.abs(1, ABS_Z, 100);
    rig.syn(1);
    assert_eq!(rig.drain(), [], "trigger less than half pulled");
    rig.abs(2, ABS_Z, 250);
    rig.abs(2, ABS_HAT0Y, -1);
    rig.syn(2);
    assert_eq!(
        rig.drain(),
        [
            InputEvent::Deadman(true),
            InputEvent::Axes(MovementCommand {
                pitch: 32767,
                ..MovementCommand::CENTRED
            })
        ]
    );
}

#[test]
fn unplug_is_lost_once_and_replug_waits_for_centred_sticks() {
    let mut rig = Rig::pad_at(PAD, 128, 128);
    rig.abs(1, ABS_X, 255);
    rig.syn(1);
    assert_eq!(rig.drain(), [axes(0, 0), axes(0, 32767)]);
    rig.m.feed(
        ms(2),
        DeviceEvent::Unplugged {
            reason: "Pad: No such device".into(),
        },
    );
    rig.m.feed(
        ms(3),
        DeviceEvent::Unplugged {
            reason: "not found".into(),
        },
    );
    // Stray events of a gone device are ignored.
    rig.abs(4, ABS_X, 0);
    rig.syn(4);
    assert_eq!(
        rig.drain(),
        [InputEvent::Lost {
            reason: "Pad: No such device".into()
        }]
    );
    assert!(matches!(rig.m.status().link, LinkState::Lost { .. }));
    // Replugged with the stick still pushed: no jump.
    rig.connect(10, 255, 128);
    rig.abs(11, ABS_X, 250);
    rig.syn(11);
    assert_eq!(rig.drain(), []);
    assert_eq!(
        rig.m.status().link,
        LinkState::AwaitingRest {
            axes: vec![Axis::Roll]
        }
    );
    // 12.5 of 127.5 from centre, past the deadzone: 0.080, outside the 5 % rest tolerance.
    rig.abs(12, ABS_X, 140);
    rig.syn(12);
    assert_eq!(rig.drain(), []);
    // (5.5/127.5 − 0.02) / 0.98 = 0.024: at rest, so live, with the small value it has.
    rig.abs(13, ABS_X, 133);
    rig.syn(13);
    assert_eq!(rig.drain(), [axes(0, 774)]);
}

#[test]
fn syn_dropped_is_lost_until_resync_and_values_are_reread() {
    let mut rig = Rig::pad_at(PAD, 128, 128);
    rig.drain();
    rig.raw(1, EV_SYN, SYN_DROPPED, 0);
    rig.abs(1, ABS_X, 255);
    rig.abs(1, ABS_X, 128);
    assert_eq!(lost(&rig.drain()), 1);
    rig.syn(2);
    // Re-synced but the values are unknown until re-read.
    assert_eq!(rig.drain(), []);
    assert!(matches!(
        rig.m.status().link,
        LinkState::AwaitingRest { .. }
    ));
    // The device layer's snapshot: X centred, Y pushed → still waiting for throttle.
    rig.absinfo(2, ABS_X, 128, 0, 255);
    rig.absinfo(2, ABS_Y, 0, 0, 255);
    assert_eq!(rig.drain(), []);
    assert_eq!(
        rig.m.status().link,
        LinkState::AwaitingRest {
            axes: vec![Axis::Throttle]
        }
    );
    rig.abs(3, ABS_Y, 128);
    rig.syn(3);
    assert_eq!(rig.drain(), [axes(0, 0)]);
}

#[test]
fn buttons_held_through_a_resync_must_be_pressed_again() {
    let mut rig = Rig::new(DEADMAN_PAD);
    rig.absinfo(0, ABS_X, 128, 0, 255);
    rig.key(1, BTN_TL, 1);
    rig.syn(1);
    assert_eq!(rig.drain(), [InputEvent::Deadman(true), axes(0, 0)]);
    rig.raw(2, EV_SYN, SYN_DROPPED, 0);
    rig.syn(2);
    rig.absinfo(2, ABS_X, 128, 0, 255);
    rig.m.feed(
        ms(2),
        DeviceEvent::KeyState {
            code: BTN_TL,
            pressed: true,
        },
    );
    assert_eq!(lost(&rig.drain()), 1);
    assert_eq!(rig.m.status().deadman, Some(false));
    rig.key(3, BTN_TL, 2);
    rig.syn(3);
    assert_eq!(rig.drain(), [], "auto-repeat is no press");
    rig.key(4, BTN_TL, 0);
    rig.syn(4);
    rig.key(5, BTN_TL, 1);
    rig.syn(5);
    assert_eq!(rig.drain(), [InputEvent::Deadman(true), axes(0, 0)]);
}

#[test]
fn silence_timeout_is_opt_in() {
    let mut rig = Rig::pad_at(PAD, 128, 128);
    rig.drain();
    rig.m.tick(ms(3_600_000));
    assert_eq!(rig.drain(), [], "no timeout configured");
    assert_eq!(rig.m.next_deadline(), None);
}

#[test]
fn silence_is_lost_and_any_event_resumes_when_at_rest() {
    let text = format!("silence_timeout_ms = 100\n{PAD}");
    let mut rig = Rig::pad_at(&text, 128, 128);
    assert_eq!(rig.drain(), [axes(0, 0)]);
    assert_eq!(rig.m.next_deadline(), Some(ms(100)));
    rig.abs(50, ABS_X, 255);
    rig.syn(50);
    assert_eq!(rig.drain(), [axes(0, 32767)]);
    assert_eq!(rig.m.next_deadline(), Some(ms(150)));
    rig.m.tick(ms(149));
    assert_eq!(rig.drain(), []);
    rig.m.tick(ms(150));
    let events = rig.drain();
    assert_eq!(lost(&events), 1, "{events:?}");
    assert!(
        matches!(&events[0], InputEvent::Lost { reason } if reason.contains("no events for 100 ms")),
        "{events:?}"
    );
    assert_eq!(rig.m.next_deadline(), None, "lost: nothing to wake for");
    // The device speaks again with the stick still pushed: waits for centre.
    rig.abs(400, ABS_Y, 128);
    rig.syn(400);
    assert_eq!(rig.drain(), []);
    rig.abs(410, ABS_X, 128);
    rig.syn(410);
    assert_eq!(rig.drain(), [axes(0, 0)]);
}

const KEYBOARD: &str = r#"
source = "keyboard"
[axes.throttle]
negative = "KEY_S"
positive = "KEY_W"
ramp_up_ms = 200
spring_back_ms = 100
[buttons]
release = "KEY_ESC"
"#;

fn throttle(v: i16) -> InputEvent {
    axes(v, 0)
}

#[test]
fn keyboard_ramps_up_and_springs_back_with_deadlines() {
    let mut rig = Rig::new(KEYBOARD);
    rig.m
        .feed(ms(0), DeviceEvent::Connected { name: "kbd".into() });
    assert_eq!(rig.drain(), [throttle(0)], "keyboard is live at once");
    rig.key(0, KEY_W, 1);
    rig.syn(0);
    assert_eq!(rig.drain(), []);
    assert_eq!(rig.m.next_deadline(), Some(ms(10)));
    rig.m.tick(ms(10));
    assert_eq!(rig.drain(), [throttle(1638)]);
    rig.m.tick(ms(50));
    assert_eq!(rig.drain(), [throttle(8192)]);
    rig.m.tick(ms(500));
    assert_eq!(rig.drain(), [throttle(32767)]);
    assert_eq!(rig.m.next_deadline(), None, "at full scale: no ramp");
    // Auto-repeat changes nothing.
    rig.key(510, KEY_W, 2);
    rig.syn(510);
    assert_eq!(rig.drain(), []);
    rig.key(600, KEY_W, 0);
    rig.syn(600);
    assert_eq!(rig.m.next_deadline(), Some(ms(610)));
    rig.m.tick(ms(650));
    assert_eq!(rig.drain(), [throttle(16384)]);
    rig.m.tick(ms(700));
    assert_eq!(rig.drain(), [throttle(0)]);
    assert_eq!(rig.m.next_deadline(), None);
}

#[test]
fn keyboard_reversal_springs_back_first() {
    let mut rig = Rig::new(KEYBOARD);
    rig.m
        .feed(ms(0), DeviceEvent::Connected { name: "kbd".into() });
    rig.key(0, KEY_W, 1);
    rig.syn(0);
    rig.m.tick(ms(200));
    rig.drain();
    rig.key(200, KEY_W, 0);
    rig.key(200, KEY_S, 1);
    rig.syn(200);
    rig.m.tick(ms(350));
    assert_eq!(rig.drain(), [throttle(-8192)]);
}

#[test]
fn a_key_held_through_a_replug_is_stale_until_released() {
    let mut rig = Rig::new(KEYBOARD);
    rig.m
        .feed(ms(0), DeviceEvent::Connected { name: "kbd".into() });
    rig.m.feed(
        ms(0),
        DeviceEvent::KeyState {
            code: KEY_W,
            pressed: true,
        },
    );
    rig.m.tick(ms(300));
    assert_eq!(rig.drain(), [throttle(0)], "the held key drives nothing");
    rig.key(310, KEY_W, 0);
    rig.syn(310);
    rig.key(320, KEY_W, 1);
    rig.syn(320);
    rig.m.tick(ms(420));
    assert_eq!(rig.drain(), [throttle(16384)]);
}

#[test]
fn a_keyboard_unplugged_mid_ramp_replugs_centred() {
    let mut rig = Rig::new(KEYBOARD);
    rig.m
        .feed(ms(0), DeviceEvent::Connected { name: "kbd".into() });
    rig.key(0, KEY_W, 1);
    rig.syn(0);
    rig.m.tick(ms(100));
    rig.m.feed(
        ms(100),
        DeviceEvent::Unplugged {
            reason: "gone".into(),
        },
    );
    let events = rig.drain();
    assert_eq!(
        events.last(),
        Some(&InputEvent::Lost {
            reason: "gone".into()
        })
    );
    assert_eq!(rig.m.next_deadline(), None);
    rig.m
        .feed(ms(500), DeviceEvent::Connected { name: "kbd".into() });
    assert_eq!(rig.drain(), [throttle(0)]);
    assert_eq!(rig.m.status().sticks, MovementCommand::CENTRED);
}

#[test]
fn a_throttle_lever_can_rest_low() {
    let text = r#"
        source = "joystick"
        [axes.throttle]
        abs = "ABS_THROTTLE"
        rest = "low"
        "#;
    let mut rig = Rig::new(text);
    rig.absinfo(0, 0x06, 128, 0, 255);
    assert_eq!(
        rig.drain(),
        [],
        "a lever at mid-travel must go to idle first"
    );
    rig.raw(1, EV_ABS, 0x06, 0);
    rig.syn(1);
    assert_eq!(rig.drain(), [throttle(-32767)]);
}

#[test]
fn a_key_axis_and_actions_on_the_same_keyboard() {
    let mut rig = Rig::new(KEYBOARD);
    rig.m
        .feed(ms(0), DeviceEvent::Connected { name: "kbd".into() });
    rig.drain();
    rig.key(1, 1, 1);
    rig.syn(1);
    assert_eq!(rig.drain(), [InputEvent::Action(InputAction::Release)]);
}

#[test]
fn status_lists_raw_values_and_held_buttons() {
    let mut rig = Rig::pad_at(DEADMAN_PAD, 128, 64);
    rig.key(1, BTN_SOUTH, 1);
    rig.syn(1);
    let status = rig.m.status();
    assert_eq!(status.abs, vec![(ABS_X, 128), (ABS_Y, 64)]);
    assert_eq!(status.pressed, vec![BTN_SOUTH]);
    assert_eq!(status.device.as_deref(), Some("Pad"));
    let line = status.to_string();
    assert!(line.contains("deadman=up"), "{line}");
    assert!(line.contains("ABS_Y=64"), "{line}");
    assert!(line.contains("BTN_SOUTH"), "{line}");
}

#[test]
fn the_queue_is_bounded() {
    let mut rig = Rig::pad_at(PAD, 128, 128);
    for t in 0..5_000u64 {
        rig.abs(t, ABS_X, (t % 256) as i32);
        rig.syn(t);
    }
    assert!(rig.drain().len() <= MAX_QUEUED);
}

#[test]
fn unused_constants_are_real_codes() {
    assert_eq!(crate::codes::parse_abs("ABS_HAT0X"), Some(ABS_HAT0X));
    assert_eq!(crate::codes::parse_key("KEY_W"), Some(KEY_W));
    assert_eq!(crate::codes::parse_key("KEY_S"), Some(KEY_S));
}
