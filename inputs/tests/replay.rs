//! The sources driven with recorded evdev streams (tests/recordings/) through the example
//! mappings (configs/operator-*.toml), the way `rove operator` polls them: at every deadline.

use rove_core::adapter::{InputAction, InputEvent, InputSource};
use rove_core::msg::{Mode, MovementCommand};
use rove_core::time::MonoTime;
use rove_inputs::config::MappingConfig;
use rove_inputs::{InputSettings, LinkState, ReplaySource};
use serde::Deserialize;
use std::path::{Path, PathBuf};
use std::time::Duration;

#[derive(Deserialize)]
struct File {
    input: InputSettings,
}

fn crate_path(rel: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join(rel)
}

fn example(name: &str) -> InputSettings {
    let path = crate_path(&format!("../configs/operator-{name}.toml"));
    let text = std::fs::read_to_string(&path).expect("example readable");
    toml::from_str::<File>(&text).expect("example parses").input
}

fn mapping(name: &str) -> MappingConfig {
    example(name)
        .validate()
        .expect("example valid")
        .mapping
        .clone()
}

fn recording(name: &str) -> PathBuf {
    crate_path(&format!("tests/recordings/{name}"))
}

/// Plays a source like the operator loop does: poll until empty, sleep until the next
/// deadline, until `until_ms`. Returns (ms, event).
fn play(source: &mut dyn InputSource, until_ms: u64) -> Vec<(u64, InputEvent)> {
    let until = MonoTime::from_millis(until_ms);
    let mut now = MonoTime::ZERO;
    let mut out = Vec::new();
    loop {
        while let Some(e) = source.poll(now).expect("replay never fails") {
            out.push((now.as_nanos() / 1_000_000, e));
        }
        match source.next_deadline() {
            Some(d) if d <= until => now = d.max(now + Duration::from_micros(1)),
            _ => break,
        }
    }
    out
}

fn replay(recording_name: &str, example_name: &str, until_ms: u64) -> Vec<(u64, InputEvent)> {
    let mut source = ReplaySource::open(&recording(recording_name), mapping(example_name))
        .expect("recording loads");
    play(&mut source, until_ms)
}

fn mv(throttle: i16, roll: i16, pitch: i16, yaw: i16) -> InputEvent {
    InputEvent::Axes(MovementCommand {
        throttle,
        roll,
        pitch,
        yaw,
    })
}

fn action(a: InputAction) -> InputEvent {
    InputEvent::Action(a)
}

#[test]
fn gamepad_drive_deadman_and_every_action() {
    let got = replay("gamepad_drive.txt", "gamepad", 10_000);
    let expected = vec![
        (200, InputEvent::Deadman(true)),
        (200, mv(32767, 0, 0, 0)),
        // Right stick half right: deadzone 8 %, expo 0.3 → 11407; left stick centred.
        (300, mv(0, 11407, 0, 0)),
        (400, action(InputAction::Accept)),
        (420, action(InputAction::Refuse)),
        (430, action(InputAction::RequestControl)),
        (440, action(InputAction::Finish)),
        (450, action(InputAction::Release)),
        (460, action(InputAction::Mode(Mode::Manual))),
        (470, action(InputAction::Mode(Mode::Auto))),
        (480, action(InputAction::Mode(Mode::Assisted))),
        (490, action(InputAction::NextVehicle)),
        (500, action(InputAction::PreviousVehicle)),
        (600, InputEvent::Deadman(false)),
    ];
    assert_eq!(got, expected);
}

#[test]
fn gamepad_unplug_is_lost_and_replug_waits_for_centre_and_a_new_deadman_press() {
    let mut source =
        ReplaySource::open(&recording("gamepad_unplug.txt"), mapping("gamepad")).expect("loads");
    let got = play(&mut source, 1_150);
    assert_eq!(
        got,
        vec![
            (100, InputEvent::Deadman(true)),
            (100, mv(32767, 0, 0, 0)),
            (
                200,
                InputEvent::Lost {
                    reason: "replay: /dev/input/event5: No such device (os error 19)".into()
                }
            ),
        ]
    );
    assert_eq!(
        source.status().link,
        LinkState::AwaitingRest {
            axes: vec![rove_core::mapping::Axis::Throttle]
        },
        "replugged with the stick pushed: centre it"
    );
    let rest = play_from(&mut source, 1_150, 10_000);
    assert_eq!(
        rest,
        vec![
            (1400, InputEvent::Deadman(true)),
            (1400, mv(0, 0, 0, 0)),
            // Half up: deadzone 8 %, expo 0.2 → 12590.
            (1500, mv(12590, 0, 0, 0)),
        ]
    );
}

/// Continues playing from `from_ms` (the source's origin is already set).
fn play_from(source: &mut ReplaySource, from_ms: u64, until_ms: u64) -> Vec<(u64, InputEvent)> {
    let until = MonoTime::from_millis(until_ms);
    let mut now = MonoTime::from_millis(from_ms);
    let mut out = Vec::new();
    loop {
        while let Some(e) = source.poll(now).expect("replay never fails") {
            out.push((now.as_nanos() / 1_000_000, e));
        }
        match source.next_deadline() {
            Some(d) if d <= until => now = d.max(now + Duration::from_micros(1)),
            _ => break,
        }
    }
    out
}

#[test]
fn syn_dropped_discards_the_frame_and_resyncs_without_a_jump() {
    let got = replay("gamepad_syn_dropped.txt", "gamepad", 10_000);
    assert_eq!(
        got,
        vec![
            (10, InputEvent::Deadman(true)),
            (10, mv(0, 32767, 0, 0)),
            (
                20,
                InputEvent::Lost {
                    reason: "replay rec: events dropped (SYN_DROPPED), state unknown until re-sync"
                        .replace(
                            "replay rec",
                            &format!("replay {}", recording("gamepad_syn_dropped.txt").display())
                        )
                }
            ),
            // The BTN_SOUTH press inside the dropped frame fired nothing; roll still pushed
            // after the re-sync waited; the held deadman had to be pressed again.
            (50, InputEvent::Deadman(true)),
            (50, mv(0, 0, 0, 0)),
        ]
    );
}

#[test]
fn keyboard_ramps_smoothly_and_springs_back() {
    let got = replay("keyboard_ramp.txt", "keyboard", 10_000);
    assert_eq!(got[0], (0, InputEvent::Deadman(true)));
    assert_eq!(got[1], (0, mv(0, 0, 0, 0)));
    let throttle: Vec<(u64, i16)> = got
        .iter()
        .filter_map(|(t, e)| match e {
            InputEvent::Axes(m) => Some((*t, m.throttle)),
            _ => None,
        })
        .collect();
    let at = |ms: u64| {
        throttle
            .iter()
            .rev()
            .find(|(t, _)| *t <= ms)
            .map(|(_, v)| *v)
    };
    let near = |ms: u64, want: i16| {
        let got = at(ms).expect("a value by then");
        assert!(
            got.abs_diff(want) <= 1,
            "at {ms} ms: {got}, want {want} ± 1"
        );
    };
    // ramp_up_ms = 400: half way 200 ms after the press, full at 400 ms (10 ms steps add up
    // in floating point: ±1).
    near(300, 16384);
    assert_eq!(at(500), Some(32767));
    assert_eq!(at(699), Some(32767));
    // spring_back_ms = 200.
    near(800, 16384);
    assert_eq!(at(900), Some(0));
    // Smooth: no step bigger than 10 ms of ramp (32767 × 10 / 200, rounded up).
    for pair in throttle.windows(2) {
        let step = (i32::from(pair[1].1) - i32::from(pair[0].1)).abs();
        assert!(step <= 1_639, "step {step} between {pair:?}");
    }
    // Nothing emitted while held at full scale (auto-repeat at 350 ms included).
    assert!(throttle.iter().all(|(t, _)| !(501..700).contains(t)));
    assert_eq!(got.last(), Some(&(1000, action(InputAction::Release))));
}

#[test]
fn flight_stick_lever_must_rest_at_idle_first() {
    let got = replay("flight_stick_lever.txt", "flight-stick", 10_000);
    assert_eq!(
        got,
        vec![
            (100, InputEvent::Deadman(true)),
            (200, mv(-32767, 0, 0, 0)),
            (300, mv(32767, 32767, 0, 0)),
            (400, action(InputAction::NextVehicle)),
        ]
    );
}

#[test]
fn a_binary_capture_plays_with_calibration_from_config() {
    let mut settings: InputSettings = toml::from_str(
        r#"
        source = "replay"
        file = "unused"
        [axes.roll]
        abs = "ABS_X"
        min = -32768
        max = 32767
        deadzone_pct = 1.0
        [buttons]
        accept = "BTN_SOUTH"
        "#,
    )
    .expect("parses");
    let config = settings.validate().expect("valid");
    let mut source = ReplaySource::open(&recording("pad_capture.bin"), config.mapping.clone())
        .expect("binary loads");
    assert_eq!(
        play(&mut source, 10_000),
        vec![
            (0, mv(0, 0, 0, 0)),
            (20, mv(0, 32767, 0, 0)),
            (40, action(InputAction::Accept)),
            (40, mv(0, 0, 0, 0)),
        ]
    );
}

#[test]
fn open_plays_a_replay_config_as_a_boxed_source() {
    let text = format!(
        "source = \"replay\"\nfile = {:?}\n{}",
        recording("gamepad_unplug.txt").display().to_string(),
        "[axes.throttle]\nabs = \"ABS_Y\"\ninvert = true\n[buttons]\ndeadman = \"BTN_TL\"\n"
    );
    let mut settings: InputSettings = toml::from_str(&text).expect("parses");
    let config = settings.validate().expect("valid");
    let mut source = rove_inputs::open(&config).expect("opens");
    assert!(source.describe().contains("gamepad_unplug.txt"));
    // Before the first poll the source asks to be polled at once.
    assert_eq!(source.next_deadline(), Some(MonoTime::ZERO));
    let got = play(source.as_mut(), 300);
    assert!(
        matches!(got.last(), Some((200, InputEvent::Lost { .. }))),
        "{got:?}"
    );
}

#[test]
fn open_reports_a_bad_recording_as_a_fatal_error_naming_the_line() {
    let dir = std::env::temp_dir().join(format!("rove-inputs-bad-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");
    let file = dir.join("bad.txt");
    std::fs::write(&file, "0 ABS_X 1\n5 ABS_NOPE 3\n").expect("write");
    let text = format!(
        "source = \"replay\"\nfile = {:?}\n[axes.roll]\nabs = \"ABS_X\"\n",
        file.display().to_string()
    );
    let config = toml::from_str::<InputSettings>(&text)
        .expect("parses")
        .validate()
        .expect("valid");
    let err = rove_inputs::open(&config).err().expect("bad recording");
    assert_eq!(err.disposition, rove_core::error::Disposition::Fatal);
    assert!(err.detail.contains("bad.txt:2:"), "{}", err.detail);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn the_silence_timeout_applies_to_replays() {
    let text = "silence_timeout_ms = 100\nsource = \"replay\"\nfile = \"x\"\n[axes.roll]\nabs = \"ABS_X\"\n";
    let config = toml::from_str::<InputSettings>(text)
        .expect("parses")
        .validate()
        .expect("valid");
    let recording = rove_inputs::Recording::parse_text(
        "0 absinfo ABS_X 0 -100 100\n0 SYN_REPORT\n50 ABS_X 100\n50 SYN_REPORT\n500 ABS_X 0\n500 SYN_REPORT\n",
        Path::new("<memory>"),
    )
    .expect("parses");
    let mut source = ReplaySource::new(recording, config.mapping.clone(), "pad");
    let got = play(&mut source, 1_000);
    assert_eq!(got.len(), 5, "{got:?}");
    assert_eq!(got[0], (0, mv(0, 0, 0, 0)));
    assert_eq!(got[1], (50, mv(0, 32767, 0, 0)));
    assert!(
        matches!(&got[2], (150, InputEvent::Lost { reason }) if reason == "pad: no events for 100 ms"),
        "{got:?}"
    );
    // The device speaks again, centred: live; then silent again.
    assert_eq!(got[3], (500, mv(0, 0, 0, 0)));
    assert!(matches!(&got[4], (600, InputEvent::Lost { .. })), "{got:?}");
}
