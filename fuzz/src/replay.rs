//! evdev recordings into rove-inputs, as `[input] source = "replay"` reads them
//! ([`Recording::load`]'s rule: a NUL byte means raw 24-byte `struct input_event` records,
//! otherwise the text format), then played through a shipped mapping (gamepad, flight stick
//! or keyboard, chosen by the length of the input) the way the operator loop polls a source:
//! at every deadline until the recording is spent.
//!
//! Checked, besides "no panic": a parse error says something; a text recording that
//! parses prints ([`Recording::to_text`]) as text that parses again; playing never fails and
//! ends (the source's deadlines move forward and run out).

use rove_core::adapter::InputSource;
use rove_core::time::MonoTime;
use rove_gateway::config::{AnyConfig, InputChoice, any_from_text};
use rove_inputs::config::MappingConfig;
use rove_inputs::replay::memory_path;
use rove_inputs::{Recording, ReplaySource};
use std::path::Path;
use std::sync::OnceLock;
use std::time::Duration;

/// The shipped operator configs whose `[input]` mappings recordings are played through.
const MAPPINGS: [&str; 3] = [
    include_str!("../../configs/operator-gamepad.toml"),
    include_str!("../../configs/operator-flight-stick.toml"),
    include_str!("../../configs/operator-keyboard.toml"),
];

/// Most polls of one recording: every entry may be a deadline of its own, plus the mapper's
/// own (repeat, silence) deadlines; far above what a spent recording needs.
const MAX_POLLS_PER_ENTRY: usize = 64;

fn mappings() -> &'static [MappingConfig] {
    static MAPPINGS_LOADED: OnceLock<Vec<MappingConfig>> = OnceLock::new();
    MAPPINGS_LOADED.get_or_init(|| {
        MAPPINGS
            .iter()
            .map(
                |text| match any_from_text(Path::new("operator.toml"), text) {
                    Ok((AnyConfig::Operator(config), _)) => match config.input {
                        InputChoice::Device(input) => input.mapping.clone(),
                        InputChoice::Constant(..) => {
                            panic!("a shipped device config has no [input]")
                        }
                    },
                    Ok(_) => panic!("a shipped operator config loads as another kind"),
                    Err(e) => panic!("a shipped operator config does not load: {e:#}"),
                },
            )
            .collect()
    })
}

/// Parses `data` as a recording and plays it.
pub fn replay(data: &[u8]) {
    let path = memory_path();
    let recording = if data.contains(&0) {
        match Recording::parse_binary(data, &path) {
            Ok(r) => r,
            Err(e) => {
                assert!(!e.to_string().trim().is_empty());
                return;
            }
        }
    } else {
        let Ok(text) = std::str::from_utf8(data) else {
            return;
        };
        match Recording::parse_text(text, &path) {
            Ok(r) => {
                let printed = r.to_text();
                if let Err(e) = Recording::parse_text(&printed, &path) {
                    panic!("{e}\n--- printed:\n{printed}\n--- from:\n{text}");
                }
                r
            }
            Err(e) => {
                assert!(!e.to_string().trim().is_empty());
                return;
            }
        }
    };
    let entries = recording.entries().len();
    let mapping = mappings()[data.len() % MAPPINGS.len()].clone();
    let mut source = ReplaySource::new(recording, mapping, "fuzz");
    let mut now = MonoTime::ZERO;
    let mut polls = 0usize;
    loop {
        while source.poll(now).expect("replay never fails").is_some() {
            polls += 1;
            assert!(
                polls <= 16 * (entries + 16),
                "{polls} events from {entries} entries"
            );
        }
        polls += 1;
        assert!(
            polls <= MAX_POLLS_PER_ENTRY * (entries + 16),
            "{polls} polls for {entries} entries: the source does not run out"
        );
        match source.next_deadline() {
            // At the far end of time everything due has been played.
            Some(d) if source.remaining() > 0 && now < MonoTime::MAX => {
                now = d.max(now + Duration::from_micros(1));
            }
            _ => break,
        }
    }
}
