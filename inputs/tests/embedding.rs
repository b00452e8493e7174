//! How the gateway can embed `[input]`: next to its own `source = "constant"` variant in an
//! internally tagged enum. serde removes the tag before the variant's struct sees the table, so
//! the variant validates with `validate_as`; unknown keys are still rejected.

use rove_inputs::{InputSettings, SourceKind};
use serde::Deserialize;

#[derive(Debug, Deserialize)]
#[serde(tag = "source", rename_all = "lowercase")]
enum InputSection {
    Constant {
        #[serde(default)]
        throttle: i16,
    },
    Joystick(Box<InputSettings>),
    Keyboard(Box<InputSettings>),
    Replay(Box<InputSettings>),
}

impl InputSection {
    /// What the gateway's validation would do: the constant source is its own; the others are
    /// validated by rove-inputs (error keys then get `input.` in front).
    fn validate(&mut self) -> Option<rove_core::Result<rove_inputs::InputConfig>> {
        match self {
            InputSection::Constant { throttle: _ } => None,
            InputSection::Joystick(s) => Some(s.validate_as(SourceKind::Joystick)),
            InputSection::Keyboard(s) => Some(s.validate_as(SourceKind::Keyboard)),
            InputSection::Replay(s) => Some(s.validate_as(SourceKind::Replay)),
        }
    }
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct Operator {
    input: InputSection,
}

fn parse(text: &str) -> Result<Operator, toml::de::Error> {
    toml::from_str(text)
}

#[test]
fn a_tagged_enum_variant_validates_with_validate_as() {
    let mut op = parse("[input]\nsource = \"keyboard\"\n[input.axes.yaw]\nnegative = \"KEY_A\"\n")
        .expect("parses");
    let InputSection::Keyboard(settings) = &op.input else {
        panic!("keyboard variant expected, got {:?}", op.input);
    };
    assert_eq!(settings.source, None, "the tag was consumed by the enum");
    let config = op
        .input
        .validate()
        .expect("a device variant")
        .expect("valid");
    assert_eq!(config.kind, SourceKind::Keyboard);
    let mut replay = parse("[input]\nsource = \"replay\"\n[input.axes.roll]\nabs = \"ABS_X\"\n")
        .expect("parses");
    let err = replay
        .input
        .validate()
        .expect("a device variant")
        .expect_err("no file");
    assert!(err.to_string().starts_with("file = (absent)"), "{err}");
    let mut constant = parse("[input]\nsource = \"constant\"\nthrottle = 5\n").expect("parses");
    assert!(matches!(
        constant.input,
        InputSection::Constant { throttle: 5 }
    ));
    assert!(constant.input.validate().is_none());
}

#[test]
fn unknown_keys_are_still_rejected_inside_the_variant() {
    let err = parse("[input]\nsource = \"joystick\"\ndevise = \"/dev/input/event0\"\n")
        .expect_err("typo rejected");
    assert!(err.to_string().contains("devise"), "{err}");
}

#[test]
fn the_struct_alone_reads_the_source_key_itself() {
    #[derive(Deserialize)]
    #[serde(deny_unknown_fields)]
    struct Plain {
        input: InputSettings,
    }
    let mut plain: Plain = toml::from_str(
        "[input]\nsource = \"replay\"\nfile = \"r.txt\"\n[input.axes.roll]\nabs = \"ABS_X\"\n",
    )
    .expect("parses");
    assert_eq!(
        plain.input.validate().expect("valid").kind,
        SourceKind::Replay
    );
}
