//! The `[output]` section of a CAN vehicle (`adapter = "can"`): the raw serde structs, which
//! only parse and reject unknown keys, and [`CanSettings::validate`], which checks every key,
//! collects every problem and returns the validated [`CanConfig`]. The keys are described in
//! the crate docs.
//!
//! Keys of errors are relative to the `[output]` table, e.g. `frames[1].outputs[0].offset`;
//! the gateway puts `output.` in front. Integers are read wide ([`rove_core::config::Int`]) so
//! that a negative or huge value is reported against its key instead of failing the parse.
//!
//! # Layout
//! - this file: the limits and defaults, the settings as written ([`CanSettings`] and its
//!   tables) and the validated config ([`CanConfig`]).
//! - `source.rs`: `source = …`, an axis or a mix ([`SourceSettings`]).
//! - `validate.rs`: [`CanSettings::validate`], the section's own keys, and the checks every
//!   output shares (rates, scales).
//! - `frames.rs`: validating raw frames and the values in them.
//! - `actuators.rs`: validating `[output.dronecan]`, its servos and ESCs.

mod actuators;
mod frames;
mod source;
mod validate;

pub use source::{MIX_TERMS_MAX, MIX_WEIGHT_MAX, SourceSettings};

use crate::bus::CanId;
use crate::raw::{Endian, FieldLayout};
use crate::scale::{Scale, Source, UnitScale};
use rove_core::config::{Int, UnknownKeys};
use std::time::Duration;

/// Default send rate, Hz, of frames and DroneCAN commands: 50 Hz (20 ms), the rate RC systems
/// and most CAN servo controllers expect. Controllers time out a held command after typically
/// 100–500 ms; much below 10 Hz some will stop between frames.
pub const DEFAULT_RATE_HZ: i64 = 50;

/// Accepted send rates, Hz. Above 1 kHz a handful of frames fill a 500 kbit/s bus and starve
/// other nodes; below 1 Hz every CAN actuator times out.
pub const RATE_RANGE_HZ: std::ops::RangeInclusive<i64> = 1..=1000;

/// NodeStatus period: 1 s, the DroneCAN recommendation (the standard allows 2 ms..1 s;
/// receivers drop a node after 3 s of silence).
pub const NODE_STATUS_PERIOD: Duration = Duration::from_secs(1);

/// Default DroneCAN priority of commands: 16, libcanard's "medium" (0 highest, 31 lowest).
pub const DEFAULT_PRIORITY: i64 = 16;

/// Longest Linux interface name (`IFNAMSIZ` 16 less the terminating NUL).
pub const INTERFACE_NAME_MAX: usize = 15;

rove_core::config_types! {
    /// `[output]` for `adapter = "can"`, as written (the gateway consumes `adapter`).
    pub table CanSettings {
        interface: Option<String> => "SocketCAN interface name.",
        fd: Option<bool> => "CAN FD mode.",
        rate_hz: Option<i64> => "Send rate of every frame and command, Hz.",
        #[serde(default)] frames: Vec<FrameSettings> => "`[[output.frames]]`.",
        dronecan: Option<DroneCanSettings> => "`[output.dronecan]`.",
    }

    /// One raw frame (`[[output.frames]]`), as written.
    pub table FrameSettings {
        id: Option<i64> => "CAN identifier.",
        extended: Option<bool> => "29-bit identifier.",
        length: Option<i64> => "Data length, bytes.",
        rate_hz: Option<i64> => "This frame's send rate, Hz.",
        #[serde(default)] outputs: Vec<FieldSettings> => "`[[output.frames.outputs]]`.",
    }

    /// One value in a raw frame (`[[output.frames.outputs]]`), as written.
    pub settings FieldSettings {
        name: Option<String> => "Name for logs and status.",
        source: Option<SourceSettings> => "What drives it.",
        offset: Option<i64> => "First byte.",
        width: Option<i64> => "Bits: 8, 16 or 32.",
        endian: Option<Endian> => "Byte order.",
        signed: Option<bool> => "Two's complement.",
        #[serde(flatten)] scale: ScaleSettings<Int> => "`min`, `centre`, `max`, `failsafe`.",
        #[serde(flatten)] unknown: UnknownKeys => "Keys nothing above took (see `validate`).",
    }

    /// `min`/`centre`/`max`/`failsafe` of a CAN output, as written.
    #[derive(Copy)]
    pub table ScaleSettings<T> {
        min: Option<T> => "Value at −full scale.",
        centre: Option<T> => "Value at centre.",
        max: Option<T> => "Value at +full scale.",
        failsafe: Option<T> => "Value in the safe state.",
    }

    /// `[output.dronecan]`, as written.
    pub table DroneCanSettings {
        node_id: Option<i64> => "Our node id.",
        priority: Option<i64> => "Priority of the commands.",
        rate_hz: Option<i64> => "Command rate, Hz.",
        #[serde(default)] servos: Vec<ServoSettings> => "Servos, sent as one ArrayCommand.",
        #[serde(default)] escs: Vec<EscSettings> => "ESCs, sent as one RawCommand.",
    }

    /// One DroneCAN servo, as written.
    pub settings ServoSettings {
        name: Option<String> => "Name for logs and status.",
        actuator_id: Option<Int> => "The actuator's id.",
        source: Option<SourceSettings> => "What drives it.",
        #[serde(flatten)] scale: ScaleSettings<f64> => "`min`, `centre`, `max`, `failsafe`.",
        #[serde(flatten)] unknown: UnknownKeys => "Keys nothing above took (see `validate`).",
    }

    /// One DroneCAN ESC channel, as written.
    pub settings EscSettings {
        name: Option<String> => "Name for logs and status.",
        index: Option<Int> => "Index in the RawCommand array.",
        source: Option<SourceSettings> => "What drives it.",
        #[serde(flatten)] scale: ScaleSettings<Int> => "`min`, `centre`, `max`, `failsafe`.",
        #[serde(flatten)] unknown: UnknownKeys => "Keys nothing above took (see `validate`).",
    }
}
rove_core::config_types! {
    /// A validated CAN vehicle.
    #[derive(Debug, Clone, PartialEq)]
    pub struct CanConfig {
        interface: String => "The SocketCAN interface name.",
        fd: bool => "Whether the interface is opened in CAN FD mode.",
        frames: Vec<RawFrameConfig> => "The raw frames, in config order.",
        dronecan: Option<DroneCanConfig> => "The DroneCAN settings, if any.",
    }

    /// A validated raw frame.
    #[derive(Debug, Clone, PartialEq)]
    pub struct RawFrameConfig {
        id: CanId => "The identifier.",
        length: usize => "Data length, bytes.",
        period: Duration => "Send period.",
        outputs: Vec<RawOutputConfig> => "The values in the frame.",
    }

    /// A validated value in a raw frame.
    #[derive(Debug, Clone, PartialEq)]
    pub struct RawOutputConfig {
        name: String => "Name.",
        source: Source => "What drives it.",
        layout: FieldLayout => "Where it sits in the frame.",
        scale: Scale => "Axis → device units.",
        failsafe: i64 => "Safe-state value, device units.",
    }

    /// Validated DroneCAN settings.
    #[derive(Debug, Clone, PartialEq)]
    pub struct DroneCanConfig {
        node_id: u8 => "Our node id.",
        priority: u8 => "Priority of the commands.",
        period: Duration => "Command period.",
        servos: Vec<ServoConfig> => "Servos, in ArrayCommand order.",
        escs: Vec<EscConfig> => "ESC channels.",
    }

    /// A validated DroneCAN servo.
    #[derive(Debug, Clone, PartialEq)]
    pub struct ServoConfig {
        name: String => "Name.",
        actuator_id: u8 => "The actuator id.",
        source: Source => "What drives it.",
        scale: UnitScale => "Axis → normalised command.",
        failsafe: f32 => "Safe-state command.",
    }

    /// A validated DroneCAN ESC channel.
    #[derive(Debug, Clone, PartialEq)]
    pub struct EscConfig {
        name: String => "Name.",
        index: u8 => "Index in the RawCommand array.",
        source: Source => "What drives it.",
        scale: Scale => "Axis → raw command.",
        failsafe: i64 => "Safe-state command.",
    }
}

impl CanConfig {
    /// The shortest period of anything sent: how often the vehicle needs a keep-alive.
    pub fn keepalive_period(&self) -> Duration {
        let frames = self.frames.iter().map(|f| f.period);
        let dronecan = (self.dronecan.iter()).flat_map(|d| [d.period, NODE_STATUS_PERIOD]);
        frames.chain(dronecan).min().unwrap_or(NODE_STATUS_PERIOD)
    }

    /// Every output's name, in config order (raw, then servos, then ESCs).
    pub fn output_names(&self) -> Vec<&str> {
        let raw = (self.frames.iter()).flat_map(|f| f.outputs.iter().map(|o| o.name.as_str()));
        let dc = self.dronecan.iter().flat_map(|d| {
            let servos = d.servos.iter().map(|s| s.name.as_str());
            servos.chain(d.escs.iter().map(|e| e.name.as_str()))
        });
        raw.chain(dc).collect()
    }
}

impl DroneCanConfig {
    /// Length of the RawCommand array: highest index + 1 (0 without ESCs).
    pub fn esc_array_len(&self) -> usize {
        let len = self.escs.iter().map(|e| usize::from(e.index) + 1);
        len.max().unwrap_or(0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dronecan;
    use crate::raw::Width;
    use rove_core::mapping::Axis;

    fn parse(text: &str) -> CanSettings {
        match toml::from_str::<CanSettings>(text) {
            Ok(s) => s,
            Err(e) => panic!("does not parse: {e}\n{text}"),
        }
    }

    fn errors_of(text: &str) -> String {
        match parse(text).validate() {
            Ok(c) => panic!("valid, expected errors: {c:?}"),
            Err(e) => e.to_string(),
        }
    }

    fn assert_has(err: &str, expected: &[&str]) {
        for e in expected {
            assert!(err.contains(e), "missing {e:?} in:\n{err}");
        }
    }

    const SKID: &str = r#"
        interface = "can0"
        [[frames]]
        id = 0x201
        [[frames.outputs]]
        name = "left"
        source = { mix = [["throttle", 1.0], ["roll", 1.0]] }
        offset = 0
        min = -1000
        max = 1000
        [[frames.outputs]]
        name = "right"
        source = { mix = [["throttle", 1], ["roll", -1]] }
        offset = 2
        endian = "big"
        min = -1000
        max = 1000
    "#;

    #[test]
    fn defaults_fill_in_quietly() {
        let c = parse(SKID).validate().expect("valid");
        assert_eq!(c.interface, "can0");
        assert!(!c.fd);
        assert_eq!(c.keepalive_period(), Duration::from_millis(20));
        let f = &c.frames[0];
        assert_eq!(f.id, CanId::Standard(0x201));
        assert_eq!(f.length, 4);
        let left = &f.outputs[0];
        assert_eq!(left.layout.width, Width::Bits16);
        assert_eq!(left.layout.endian, Endian::Little);
        assert!(left.layout.signed);
        assert_eq!(
            left.scale,
            Scale {
                min: -1000,
                centre: 0,
                max: 1000
            }
        );
        assert_eq!(left.failsafe, 0);
        assert_eq!(
            &left.source,
            &Source::Mix(vec![(Axis::Throttle, 1.0), (Axis::Roll, 1.0)])
        );
        assert_eq!(c.output_names(), ["left", "right"]);
    }

    #[test]
    fn the_largest_numbers_are_refused_not_overflowed() {
        for (min, max) in [(Int::MAX, 1), (Int::MAX, Int::MAX), (Int::MIN, Int::MIN)] {
            let text = format!(
                "interface = \"vcan0\"\n[[frames]]\nid = 1\n[[frames.outputs]]\n\
                 source = \"yaw\"\noffset = 0\nmin = {min}\nmax = {max}"
            );
            let errors = parse(&text).validate().expect_err("out of range");
            assert!(errors.to_string().contains("min"), "{min}, {max}: {errors}");
        }
    }

    #[test]
    fn unsigned_fields_default_to_their_full_range() {
        let c = parse(
            "interface = \"vcan0\"\n[[frames]]\nid = 1\n[[frames.outputs]]\nsource = \"yaw\"\n\
             offset = 0\nwidth = 8\nsigned = false",
        )
        .validate()
        .expect("valid");
        let o = &c.frames[0].outputs[0];
        assert_eq!(
            o.scale,
            Scale {
                min: 0,
                centre: 127,
                max: 255
            }
        );
        assert_eq!(o.name, "frames[0].outputs[0]");
    }

    #[test]
    fn rejects_unknown_keys_and_bad_sources() {
        assert!(toml::from_str::<CanSettings>("interface = \"can0\"\nbitrate = 500000").is_err());
        let bad_axis = "interface = \"can0\"\n[[frames]]\nid = 1\n[[frames.outputs]]\n\
                        source = \"speed\"\noffset = 0";
        let err = toml::from_str::<CanSettings>(bad_axis)
            .expect_err("unknown axis")
            .to_string();
        assert!(err.contains("speed"), "{err}");
        let bad_mix = "interface = \"can0\"\n[[frames]]\nid = 1\n[[frames.outputs]]\n\
                       source = { mixx = [] }\noffset = 0";
        assert!(toml::from_str::<CanSettings>(bad_mix).is_err());
    }

    #[test]
    fn unknown_keys_of_outputs_are_named_with_their_path() {
        let err = errors_of(
            "interface = \"can0\"\n[[frames]]\nid = 1\n[[frames.outputs]]\nsource = \"yaw\"\n\
             offset = 0\nfailsafe_us = 3\n[dronecan]\nnode_id = 10\n[[dronecan.servos]]\n\
             actuator_id = 1\nsource = \"roll\"\nmaxx = 1.0",
        );
        assert_has(
            &err,
            &[
                "frames[0].outputs[0].failsafe_us = 3: unknown key, expected one of `name`",
                "dronecan.servos[0].maxx = 1: unknown key, expected one of `name`, `actuator_id`",
            ],
        );
    }

    #[test]
    fn frame_layout_errors_name_their_keys() {
        let err = errors_of(
            r#"
            interface = "can0"
            [[frames]]
            id = 0x100
            [[frames.outputs]]
            name = "a"
            source = "throttle"
            offset = 0
            width = 32
            [[frames.outputs]]
            name = "b"
            source = "roll"
            offset = 2
            [[frames.outputs]]
            name = "c"
            source = "roll"
            offset = 7
            [[frames.outputs]]
            source = "roll"
            offset = 4
            width = 12
            [[frames]]
            id = 0x100
            length = 9
            [[frames.outputs]]
            name = "a"
            source = "yaw"
            offset = 0
            "#,
        );
        assert_has(
            &err,
            &[
                "frames[0].outputs[1].offset = 2: bytes 2..4 overlap output \"a\" (bytes 0..4)",
                "frames[0].outputs[2].offset = 7: offset + width (7 + 2 bytes) reaches past the frame's 8 bytes",
                "frames[0].outputs[3].width = 12: must be 8, 16 or 32",
                "frames[1].id = 0x100: must be unique: frames[0] has the same identifier",
                "frames[1].length = 9: must be 0..=8 bytes (longer frames need fd = true)",
                "frames[1].outputs[0].name = \"a\": must be unique: frames[0].outputs[0].name",
            ],
        );
    }

    #[test]
    fn fd_frames_go_to_64_bytes() {
        let text = "interface = \"can0\"\nfd = true\n[[frames]]\nid = 0x10\n\
                    [[frames.outputs]]\nsource = \"roll\"\noffset = 60\nwidth = 32";
        let c = parse(text).validate().expect("valid");
        assert_eq!(c.frames[0].length, 64);
        let text = "interface = \"can0\"\nfd = true\n[[frames]]\nid = 0x10\n\
                    [[frames.outputs]]\nsource = \"roll\"\noffset = 8\nwidth = 16";
        assert_eq!(parse(text).validate().expect("valid").frames[0].length, 12);
        let err = errors_of(
            "interface = \"can0\"\nfd = true\n[[frames]]\nid = 0x10\n[[frames.outputs]]\n\
             source = \"roll\"\noffset = 62\nwidth = 32",
        );
        assert_has(
            &err,
            &[
                "frames[0].outputs[0].offset = 62: offset + width (62 + 4 bytes) reaches past the frame's 64 bytes",
            ],
        );
        let err = errors_of(
            "interface = \"can0\"\nfd = true\n[[frames]]\nid = 0x10\nlength = 13\n\
             [[frames.outputs]]\nsource = \"roll\"\noffset = 0",
        );
        assert_has(&err, &["frames[0].length = 13: must be 0..=8, 12, 16"]);
    }

    #[test]
    fn section_and_scale_errors_name_their_keys() {
        let err = errors_of(
            r#"
            interface = "can0/x"
            rate_hz = 0
            [[frames]]
            id = 0x800
            rate_hz = 5000
            [[frames.outputs]]
            source = { mix = [["throttle", 1.0], ["throttle", 9.0]] }
            offset = 0
            width = 8
            min = -200
            max = 100
            failsafe = 300
            [[frames]]
            id = -1
            extended = true
            [[frames.outputs]]
            source = "pitch"
            offset = 0
            min = 10
            centre = 20
            max = 15
            "#,
        );
        assert_has(
            &err,
            &[
                "interface = \"can0/x\": must be a network interface name",
                "rate_hz = 0: must be 1..=1000 Hz",
                "frames[0].id = 0x800: must be 0..=0x7FF (set extended = true",
                "frames[0].rate_hz = 5000: must be 1..=1000 Hz",
                "frames[0].outputs[0].source = { mix = [[\"throttle\", 1], [\"throttle\", 9]] }: weight of throttle must be non-zero and within ±4",
                "frames[0].outputs[0].source = { mix = [[\"throttle\", 1], [\"throttle\", 9]] }: throttle appears twice",
                "frames[0].outputs[0].min = -200: must be -128..=127",
                "frames[0].outputs[0].failsafe = 300: must be -128..=127",
                "frames[1].id = -1: must be 0..=0x1FFFFFFF",
                "frames[1].outputs[0].centre = 20: must lie strictly between min (10) and max (15)",
            ],
        );
    }

    #[test]
    fn missing_keys_and_an_empty_vehicle_are_reported() {
        let err = errors_of("");
        assert_has(
            &err,
            &[
                "interface = (absent): is required",
                "frames = []: a CAN vehicle needs at least one",
            ],
        );
        let err = errors_of(
            "interface = \"can0\"\n[[frames]]\n[[frames.outputs]]\nwidth = 8\n[[frames]]\nid = 2",
        );
        assert_has(
            &err,
            &[
                "frames[0].id = (absent): is required",
                "frames[0].outputs[0].source = (absent): is required",
                "frames[0].outputs[0].offset = (absent): is required",
                "frames[1].outputs = []: a frame needs at least one",
            ],
        );
    }

    #[test]
    fn dronecan_errors_name_their_keys() {
        let err = errors_of(
            r#"
            interface = "can0"
            [dronecan]
            node_id = 0
            priority = 40
            rate_hz = 2000
            [[dronecan.servos]]
            actuator_id = 300
            source = "roll"
            min = -2.0
            [[dronecan.servos]]
            actuator_id = 1
            source = "pitch"
            [[dronecan.servos]]
            name = "dup"
            actuator_id = 1
            source = "pitch"
            [[dronecan.escs]]
            index = 20
            source = "throttle"
            [[dronecan.escs]]
            name = "dup"
            index = 3
            source = "throttle"
            min = -9000
            "#,
        );
        assert_has(
            &err,
            &[
                "dronecan.node_id = 0: must be 1..=127",
                "dronecan.priority = 40: must be 0..=31",
                "dronecan.rate_hz = 2000: must be 1..=1000 Hz",
                "dronecan.servos[0].actuator_id = 300: must be 0..=255",
                "dronecan.servos[0].min = -2: must be -1..=1",
                "dronecan.servos[2].actuator_id = 1: must be unique: servos[1] has the same",
                "dronecan.escs[0].index = 20: must be 0..=19",
                "dronecan.escs[1].min = -9000: must be -8192..=8191",
            ],
        );
        let err = errors_of("interface = \"can0\"\n[dronecan]\nnode_id = 10");
        assert_has(
            &err,
            &["dronecan.servos = []: [output.dronecan] needs at least one"],
        );
    }

    #[test]
    fn raw_frames_may_not_reuse_our_dronecan_ids() {
        let id = dronecan::message_id(16, 1010, 10);
        let text = format!(
            "interface = \"can0\"\n[dronecan]\nnode_id = 10\n[[dronecan.servos]]\n\
             actuator_id = 0\nsource = \"roll\"\n[[frames]]\nid = {id}\nextended = true\n\
             [[frames.outputs]]\nsource = \"roll\"\noffset = 0"
        );
        assert_has(
            &errors_of(&text),
            &[
                "frames[0].id = 0x1003F20A: must differ from our DroneCAN uavcan.equipment.actuator.ArrayCommand",
            ],
        );
    }

    #[test]
    fn dronecan_defaults() {
        let c = parse(
            "interface = \"can0\"\nrate_hz = 100\n[dronecan]\nnode_id = 10\n\
             [[dronecan.escs]]\nindex = 3\nsource = \"throttle\"\n\
             [[dronecan.servos]]\nactuator_id = 7\nsource = \"roll\"",
        )
        .validate()
        .expect("valid");
        let dc = c.dronecan.as_ref().expect("dronecan");
        assert_eq!((dc.node_id, dc.priority), (10, 16));
        assert_eq!(dc.period, Duration::from_millis(10));
        assert_eq!(c.keepalive_period(), Duration::from_millis(10));
        assert_eq!(dc.esc_array_len(), 4);
        let esc = &dc.escs[0];
        assert_eq!(
            esc.scale,
            Scale {
                min: 0,
                centre: 4095,
                max: 8191
            }
        );
        assert_eq!(esc.failsafe, 0);
        let servo = &dc.servos[0];
        assert_eq!(servo.failsafe, 0.0);
        assert_eq!(servo.name, "dronecan.servos[0]");
    }
}
