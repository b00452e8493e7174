//! The input examples in the repository's `configs/` (operator files) parse and validate.

use rove_inputs::config::{AXES, SourceConfig};
use rove_inputs::{InputSettings, SourceKind};
use serde::Deserialize;
use std::path::Path;

/// The `[input]` table of an operator file (the gateway checks the other tables).
#[derive(Deserialize)]
struct File {
    input: InputSettings,
}

fn load(name: &str) -> rove_inputs::InputConfig {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../configs")
        .join(name);
    let text = std::fs::read_to_string(&path).expect("example readable");
    let mut file: File = toml::from_str(&text).unwrap_or_else(|e| panic!("{name}: {e}"));
    file.input
        .validate()
        .unwrap_or_else(|e| panic!("{name}: {e}"))
}

#[test]
fn every_example_in_the_directory_is_valid() {
    let names = [
        "operator-flight-stick.toml",
        "operator-gamepad.toml",
        "operator-keyboard.toml",
    ];
    for name in names {
        let config = load(name);
        // Every example maps all four axes, a deadman and all ten actions.
        for (slot, axis) in AXES.iter().enumerate() {
            assert!(config.mapping.axes[slot].is_some(), "{name}: {axis:?}");
        }
        assert!(config.mapping.deadman.is_some(), "{name}: deadman");
        assert_eq!(config.mapping.actions.len(), 10, "{name}: actions");
    }
}

#[test]
fn examples_choose_their_source_kind() {
    assert_eq!(load("operator-gamepad.toml").kind, SourceKind::Joystick);
    assert_eq!(
        load("operator-flight-stick.toml").kind,
        SourceKind::Joystick
    );
    let keyboard = load("operator-keyboard.toml");
    assert_eq!(keyboard.kind, SourceKind::Keyboard);
    assert!(matches!(
        &keyboard.source,
        SourceConfig::Evdev { grab: false, .. }
    ));
}
