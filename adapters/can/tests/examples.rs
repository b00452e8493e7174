//! The CAN examples in the repository's `configs/` parse and validate the way the gateway reads
//! them: through an enum tagged on `adapter`, which consumes the tag so that `CanSettings` can
//! deny every other unknown key.

use rove_can::{CanConfig, CanSettings};
use serde::Deserialize;
use std::path::PathBuf;

/// The gateway's `OutputSection`, cut down to the CAN variant.
#[derive(Debug, Deserialize)]
#[serde(tag = "adapter", rename_all = "lowercase")]
enum OutputSection {
    Can(Box<CanSettings>),
}

/// The `[output]` table of a vehicle file (the gateway checks the other tables).
#[derive(Debug, Deserialize)]
struct File {
    output: OutputSection,
}

fn load(name: &str) -> CanConfig {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../configs")
        .join(name);
    let text = std::fs::read_to_string(&path)
        .unwrap_or_else(|e| panic!("cannot read {}: {e}", path.display()));
    let file: File =
        toml::from_str(&text).unwrap_or_else(|e| panic!("{} does not parse: {e}", path.display()));
    let OutputSection::Can(mut settings) = file.output;
    settings
        .validate()
        .unwrap_or_else(|e| panic!("{} is invalid:\n{e}", path.display()))
}

#[test]
fn skid_steer_example_is_valid() {
    let c = load("vehicle-can-skid-steer.toml");
    assert_eq!(c.interface, "can0");
    assert_eq!(c.output_names(), ["left", "right"]);
    assert_eq!(c.frames[0].length, 8);
    assert!(c.dronecan.as_ref().is_none());
}

#[test]
fn dronecan_example_is_valid() {
    let c = load("vehicle-dronecan-servos.toml");
    let dc = c.dronecan.as_ref().expect("dronecan");
    assert_eq!(dc.node_id, 100);
    assert_eq!(c.output_names(), ["aileron", "elevator", "rudder", "motor"]);
}

#[test]
fn the_tagged_wrapper_still_rejects_unknown_keys() {
    let text = "[output]\nadapter = \"can\"\ninterface = \"can0\"\nbitrate = 500000\n";
    let err = toml::from_str::<File>(text).expect_err("unknown key");
    assert!(err.to_string().contains("bitrate"), "{err}");
}
