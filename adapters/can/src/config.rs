//! The `[output]` section of a CAN vehicle (`adapter = "can"`): the raw serde structs, which
//! only parse and reject unknown keys, and [`CanSettings::validate`], which checks every key,
//! collects every problem and returns the validated [`CanConfig`].
//!
//! Keys of errors are relative to the `[output]` table, e.g. `frames[1].outputs[0].offset`;
//! the gateway puts `output.` in front. Integers are read as `i64` so that a negative or huge
//! value is reported against its key instead of failing the parse.

use crate::bus::{
    CLASSIC_MAX_LEN, CanId, EXTENDED_ID_MAX, FD_LENGTHS, FD_MAX_LEN, STANDARD_ID_MAX,
};
use crate::dronecan::{
    self, ARRAY_COMMAND, MAX_ESCS, MAX_SERVOS, NODE_ID_RANGE, NODE_STATUS, NODE_STATUS_PRIORITY,
    PRIORITY_RANGE, RAW_COMMAND, RAW_COMMAND_RANGE,
};
use crate::raw::{Endian, FieldLayout, Width};
use crate::scale::{Scale, Source, UnitScale, axis_name};
use rove_core::error::{ConfigError, ConfigErrors};
use rove_core::mapping::Axis;
use serde::de::{self, MapAccess, Visitor};
use serde::{Deserialize, Deserializer, Serialize};
use std::collections::HashMap;
use std::fmt;
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

/// `[output]` for `adapter = "can"`, as written.
///
/// The gateway reads `[output]` as an internally tagged enum on `adapter`; the tag is
/// consumed there, so this struct sees only the other keys and can deny unknown ones.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CanSettings {
    /// SocketCAN interface name: `can0`, `vcan0`, `slcan0` (required).
    pub interface: Option<String>,
    /// Open the interface in CAN FD mode, allowing raw frames longer than 8 bytes (absent:
    /// false).
    pub fd: Option<bool>,
    /// Send rate of every frame and DroneCAN command, Hz (absent: [`DEFAULT_RATE_HZ`]).
    pub rate_hz: Option<i64>,
    /// Raw frames (`[[output.frames]]`).
    #[serde(default)]
    pub frames: Vec<FrameSettings>,
    /// DroneCAN actuators (`[output.dronecan]`).
    pub dronecan: Option<DroneCanSettings>,
}

/// One raw frame (`[[output.frames]]`), as written.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FrameSettings {
    /// CAN identifier (required; write it in hex: `id = 0x201`).
    pub id: Option<i64>,
    /// 29-bit identifier (absent: false, an 11-bit identifier).
    pub extended: Option<bool>,
    /// Data length in bytes (absent: just long enough for the outputs).
    pub length: Option<i64>,
    /// This frame's send rate, Hz (absent: the section's `rate_hz`).
    pub rate_hz: Option<i64>,
    /// The values in the frame (`[[output.frames.outputs]]`).
    #[serde(default)]
    pub outputs: Vec<FieldSettings>,
}

/// One value in a raw frame (`[[output.frames.outputs]]`), as written.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FieldSettings {
    /// Name for logs and status (absent: `frames[i].outputs[j]`).
    pub name: Option<String>,
    /// What drives it (required): an axis, or a mix of axes.
    pub source: Option<SourceSettings>,
    /// First byte (required).
    pub offset: Option<i64>,
    /// Bits: 8, 16 or 32 (absent: 16).
    pub width: Option<i64>,
    /// `"little"` or `"big"` (absent: little).
    pub endian: Option<Endian>,
    /// Two's complement (absent: true).
    pub signed: Option<bool>,
    /// Device value at −full scale (absent: the field's lowest value, symmetric for signed).
    pub min: Option<i64>,
    /// Device value at centre (absent: halfway between min and max).
    pub centre: Option<i64>,
    /// Device value at +full scale (absent: the field's highest value).
    pub max: Option<i64>,
    /// Device value in the safe state (absent: centre).
    pub failsafe: Option<i64>,
}

/// `[output.dronecan]`, as written.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DroneCanSettings {
    /// Our node id, 1..=127 (required; must differ from every other node on the bus).
    pub node_id: Option<i64>,
    /// Priority of the commands, 0 (highest)..=31 (absent: [`DEFAULT_PRIORITY`]).
    pub priority: Option<i64>,
    /// Command rate, Hz (absent: the section's `rate_hz`).
    pub rate_hz: Option<i64>,
    /// Servos, sent as one `uavcan.equipment.actuator.ArrayCommand` (`[[output.dronecan.servos]]`).
    #[serde(default)]
    pub servos: Vec<ServoSettings>,
    /// ESCs, sent as one `uavcan.equipment.esc.RawCommand` (`[[output.dronecan.escs]]`).
    #[serde(default)]
    pub escs: Vec<EscSettings>,
}

/// One DroneCAN servo, as written.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ServoSettings {
    /// Name for logs and status (absent: `dronecan.servos[i]`).
    pub name: Option<String>,
    /// The actuator's id, 0..=255 (required).
    pub actuator_id: Option<i64>,
    /// What drives it (required).
    pub source: Option<SourceSettings>,
    /// Command at −full scale, −1..=1 (absent: −1).
    pub min: Option<f64>,
    /// Command at centre (absent: halfway between min and max).
    pub centre: Option<f64>,
    /// Command at +full scale (absent: 1).
    pub max: Option<f64>,
    /// Command in the safe state (absent: centre).
    pub failsafe: Option<f64>,
}

/// One DroneCAN ESC channel, as written.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct EscSettings {
    /// Name for logs and status (absent: `dronecan.escs[i]`).
    pub name: Option<String>,
    /// Index in the RawCommand array, 0..=19 (required). Unlisted indices below the highest
    /// are sent as 0 (stop).
    pub index: Option<i64>,
    /// What drives it (required).
    pub source: Option<SourceSettings>,
    /// Command at −full scale, −8192..=8191 (absent: 0).
    pub min: Option<i64>,
    /// Command at centre (absent: halfway between min and max).
    pub centre: Option<i64>,
    /// Command at +full scale (absent: 8191).
    pub max: Option<i64>,
    /// Command in the safe state (absent: 0, motor stopped).
    pub failsafe: Option<i64>,
}

/// `source = …` as written: an axis name (`"throttle"`, `"roll"`, `"pitch"`, `"yaw"`), or
/// `{ mix = [["throttle", 1.0], ["roll", -1.0]] }`, a weighted sum of axes.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(untagged)]
pub enum SourceSettings {
    /// One axis.
    Axis(Axis),
    /// A weighted sum.
    Mix {
        /// `(axis, weight)` pairs.
        mix: Vec<(Axis, f64)>,
    },
}

impl<'de> Deserialize<'de> for SourceSettings {
    fn deserialize<D: Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        struct SourceVisitor;

        impl<'de> Visitor<'de> for SourceVisitor {
            type Value = SourceSettings;

            fn expecting(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
                f.write_str(
                    "an axis (\"throttle\", \"roll\", \"pitch\", \"yaw\") or \
                     { mix = [[\"throttle\", 1.0], [\"roll\", 1.0]] }",
                )
            }

            fn visit_str<E: de::Error>(self, v: &str) -> Result<SourceSettings, E> {
                match v {
                    "throttle" => Ok(SourceSettings::Axis(Axis::Throttle)),
                    "roll" => Ok(SourceSettings::Axis(Axis::Roll)),
                    "pitch" => Ok(SourceSettings::Axis(Axis::Pitch)),
                    "yaw" => Ok(SourceSettings::Axis(Axis::Yaw)),
                    _ => Err(E::invalid_value(de::Unexpected::Str(v), &self)),
                }
            }

            fn visit_map<A: MapAccess<'de>>(self, mut map: A) -> Result<SourceSettings, A::Error> {
                let mut mix = None;
                while let Some(key) = map.next_key::<String>()? {
                    if key != "mix" {
                        return Err(de::Error::unknown_field(&key, &["mix"]));
                    }
                    if mix.is_some() {
                        return Err(de::Error::duplicate_field("mix"));
                    }
                    mix = Some(map.next_value::<Vec<(Axis, f64)>>()?);
                }
                mix.map(|mix| SourceSettings::Mix { mix })
                    .ok_or_else(|| de::Error::missing_field("mix"))
            }
        }

        deserializer.deserialize_any(SourceVisitor)
    }
}

impl fmt::Display for SourceSettings {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            SourceSettings::Axis(a) => f.write_str(axis_name(*a)),
            SourceSettings::Mix { mix } => {
                let terms: Vec<String> = mix
                    .iter()
                    .map(|(a, w)| format!("[\"{}\", {w}]", axis_name(*a)))
                    .collect();
                write!(f, "{{ mix = [{}] }}", terms.join(", "))
            }
        }
    }
}

/// Most terms in a mix: one per axis.
pub const MIX_TERMS_MAX: usize = 4;

/// Largest weight magnitude in a mix. Weights are gains on ±32767 axes; 4 already saturates a
/// quarter stick, anything larger is almost surely a typo (a device unit where a gain belongs).
pub const MIX_WEIGHT_MAX: f64 = 4.0;

impl SourceSettings {
    fn validate(&self, errors: &mut ConfigErrors) -> Source {
        match self {
            SourceSettings::Axis(a) => Source::Axis(*a),
            SourceSettings::Mix { mix } => {
                if mix.is_empty() || mix.len() > MIX_TERMS_MAX {
                    errors.push(ConfigError::new(
                        "source",
                        self,
                        format!("a mix needs 1..={MIX_TERMS_MAX} terms"),
                    ));
                }
                for (i, (axis, weight)) in mix.iter().enumerate() {
                    if !weight.is_finite() || weight.abs() > MIX_WEIGHT_MAX || *weight == 0.0 {
                        errors.push(ConfigError::new(
                            "source",
                            self,
                            format!(
                                "weight of {} must be non-zero and within ±{MIX_WEIGHT_MAX}",
                                axis_name(*axis)
                            ),
                        ));
                    }
                    if mix[..i].iter().any(|(other, _)| other == axis) {
                        errors.push(ConfigError::new(
                            "source",
                            self,
                            format!("{} appears twice in the mix", axis_name(*axis)),
                        ));
                    }
                }
                Source::Mix(mix.clone())
            }
        }
    }
}

/// A validated CAN vehicle.
#[derive(Debug, Clone, PartialEq)]
pub struct CanConfig {
    interface: String,
    fd: bool,
    frames: Vec<RawFrameConfig>,
    dronecan: Option<DroneCanConfig>,
}

/// A validated raw frame.
#[derive(Debug, Clone, PartialEq)]
pub struct RawFrameConfig {
    id: CanId,
    length: usize,
    period: Duration,
    outputs: Vec<RawOutputConfig>,
}

/// A validated value in a raw frame.
#[derive(Debug, Clone, PartialEq)]
pub struct RawOutputConfig {
    name: String,
    source: Source,
    layout: FieldLayout,
    scale: Scale,
    failsafe: i64,
}

/// Validated DroneCAN settings.
#[derive(Debug, Clone, PartialEq)]
pub struct DroneCanConfig {
    node_id: u8,
    priority: u8,
    period: Duration,
    servos: Vec<ServoConfig>,
    escs: Vec<EscConfig>,
}

/// A validated DroneCAN servo.
#[derive(Debug, Clone, PartialEq)]
pub struct ServoConfig {
    name: String,
    actuator_id: u8,
    source: Source,
    scale: UnitScale,
    failsafe: f32,
}

/// A validated DroneCAN ESC channel.
#[derive(Debug, Clone, PartialEq)]
pub struct EscConfig {
    name: String,
    index: u8,
    source: Source,
    scale: Scale,
    failsafe: i64,
}

impl CanConfig {
    /// The SocketCAN interface name.
    pub fn interface(&self) -> &str {
        &self.interface
    }

    /// Whether the interface is opened in CAN FD mode.
    pub fn fd(&self) -> bool {
        self.fd
    }

    /// The raw frames, in config order.
    pub fn frames(&self) -> &[RawFrameConfig] {
        &self.frames
    }

    /// The DroneCAN settings, if any.
    pub fn dronecan(&self) -> Option<&DroneCanConfig> {
        self.dronecan.as_ref()
    }

    /// The shortest period of anything sent: how often the vehicle needs a keep-alive.
    pub fn keepalive_period(&self) -> Duration {
        let frames = self.frames.iter().map(|f| f.period);
        let dronecan = self
            .dronecan
            .iter()
            .flat_map(|d| [d.period, NODE_STATUS_PERIOD]);
        frames.chain(dronecan).min().unwrap_or(NODE_STATUS_PERIOD)
    }

    /// Every output's name, in config order (raw, then servos, then ESCs).
    pub fn output_names(&self) -> Vec<&str> {
        let raw = self
            .frames
            .iter()
            .flat_map(|f| f.outputs.iter().map(|o| o.name.as_str()));
        let dc = self.dronecan.iter().flat_map(|d| {
            d.servos
                .iter()
                .map(|s| s.name.as_str())
                .chain(d.escs.iter().map(|e| e.name.as_str()))
        });
        raw.chain(dc).collect()
    }
}

impl RawFrameConfig {
    /// The identifier.
    pub fn id(&self) -> CanId {
        self.id
    }

    /// Data length, bytes.
    pub fn length(&self) -> usize {
        self.length
    }

    /// Send period.
    pub fn period(&self) -> Duration {
        self.period
    }

    /// The values in the frame.
    pub fn outputs(&self) -> &[RawOutputConfig] {
        &self.outputs
    }
}

impl RawOutputConfig {
    /// Name.
    pub fn name(&self) -> &str {
        &self.name
    }

    /// What drives it.
    pub fn source(&self) -> &Source {
        &self.source
    }

    /// Where it sits in the frame.
    pub fn layout(&self) -> FieldLayout {
        self.layout
    }

    /// Axis → device units.
    pub fn scale(&self) -> Scale {
        self.scale
    }

    /// Safe-state value, device units.
    pub fn failsafe(&self) -> i64 {
        self.failsafe
    }
}

impl DroneCanConfig {
    /// Our node id.
    pub fn node_id(&self) -> u8 {
        self.node_id
    }

    /// Priority of the commands.
    pub fn priority(&self) -> u8 {
        self.priority
    }

    /// Command period.
    pub fn period(&self) -> Duration {
        self.period
    }

    /// Servos, in ArrayCommand order.
    pub fn servos(&self) -> &[ServoConfig] {
        &self.servos
    }

    /// ESC channels.
    pub fn escs(&self) -> &[EscConfig] {
        &self.escs
    }

    /// Length of the RawCommand array: highest index + 1 (0 without ESCs).
    pub fn esc_array_len(&self) -> usize {
        self.escs
            .iter()
            .map(|e| usize::from(e.index) + 1)
            .max()
            .unwrap_or(0)
    }
}

impl ServoConfig {
    /// Name.
    pub fn name(&self) -> &str {
        &self.name
    }

    /// The actuator id.
    pub fn actuator_id(&self) -> u8 {
        self.actuator_id
    }

    /// What drives it.
    pub fn source(&self) -> &Source {
        &self.source
    }

    /// Axis → normalised command.
    pub fn scale(&self) -> UnitScale {
        self.scale
    }

    /// Safe-state command.
    pub fn failsafe(&self) -> f32 {
        self.failsafe
    }
}

impl EscConfig {
    /// Name.
    pub fn name(&self) -> &str {
        &self.name
    }

    /// Index in the RawCommand array.
    pub fn index(&self) -> u8 {
        self.index
    }

    /// What drives it.
    pub fn source(&self) -> &Source {
        &self.source
    }

    /// Axis → raw command.
    pub fn scale(&self) -> Scale {
        self.scale
    }

    /// Safe-state command.
    pub fn failsafe(&self) -> i64 {
        self.failsafe
    }
}

fn period_of(rate_hz: i64) -> Duration {
    Duration::from_nanos(1_000_000_000 / rate_hz.clamp(1, 1_000_000_000) as u64)
}

fn check_rate(key: &str, rate: Option<i64>, errors: &mut ConfigErrors) -> Option<i64> {
    match rate {
        Some(r) if !RATE_RANGE_HZ.contains(&r) => {
            errors.push(ConfigError::new(
                key,
                r,
                format!(
                    "must be {}..={} Hz",
                    RATE_RANGE_HZ.start(),
                    RATE_RANGE_HZ.end()
                ),
            ));
            None
        }
        r => r,
    }
}

fn required<T: Clone>(key: &str, value: &Option<T>, errors: &mut ConfigErrors) -> Option<T> {
    if value.is_none() {
        errors.push(ConfigError::new(key, "(absent)", "is required"));
    }
    value.clone()
}

/// Checks `min`/`centre`/`max` (in either order) and `failsafe` against `range`, filling
/// defaults; `None` if any is invalid (each invalid key recorded).
#[allow(clippy::too_many_arguments)]
fn check_scale(
    min: Option<i64>,
    centre: Option<i64>,
    max: Option<i64>,
    failsafe: Option<i64>,
    defaults: (i64, i64),
    failsafe_default: Option<i64>,
    range: (i64, i64),
    errors: &mut ConfigErrors,
) -> Option<(Scale, i64)> {
    let min = min.unwrap_or(defaults.0);
    let max = max.unwrap_or(defaults.1);
    let centre = centre.unwrap_or_else(|| (min + max).div_euclid(2));
    let failsafe = failsafe.or(failsafe_default).unwrap_or(centre);
    let mut ok = true;
    let rule = format!("must be {}..={}", range.0, range.1);
    for (key, v) in [
        ("min", min),
        ("centre", centre),
        ("max", max),
        ("failsafe", failsafe),
    ] {
        if !(range.0..=range.1).contains(&v) {
            errors.push(ConfigError::new(key, v, rule.clone()));
            ok = false;
        }
    }
    let between = (min < centre && centre < max) || (max < centre && centre < min);
    if ok && !between {
        errors.push(ConfigError::new(
            "centre",
            centre,
            format!("must lie strictly between min ({min}) and max ({max})"),
        ));
        ok = false;
    }
    ok.then_some((Scale { min, centre, max }, failsafe))
}

struct Names(HashMap<String, String>);

impl Names {
    /// Records `name`, whose full key path is `full_key`, or reports a duplicate at `key`
    /// (relative to the section `errors` collects for).
    fn claim(&mut self, name: &str, full_key: &str, key: &str, errors: &mut ConfigErrors) {
        if let Some(first) = self.0.get(name) {
            errors.push(ConfigError::new(
                key,
                format!("{name:?}"),
                format!("must be unique: {first} has the same name"),
            ));
        } else {
            self.0.insert(name.to_string(), full_key.to_string());
        }
    }
}

impl CanSettings {
    /// Validates every key, filling defaults.
    ///
    /// # Errors
    /// [`rove_core::Error::Config`] listing every problem, each naming its key relative to
    /// `[output]`: a missing or bad interface, rates outside [`RATE_RANGE_HZ`], identifiers
    /// that do not fit 11/29 bits or repeat, frame lengths that are not CAN lengths, outputs
    /// past the frame's end or overlapping another, widths other than 8/16/32, scale values
    /// the field cannot hold, DroneCAN node ids, priorities, actuator ids and ESC indices out
    /// of range or repeated, and a vehicle with nothing to send.
    pub fn validate(&self) -> rove_core::Result<CanConfig> {
        let mut errors = ConfigErrors::default();
        let mut names = Names(HashMap::new());
        let fd = self.fd.unwrap_or(false);
        let interface = required("interface", &self.interface, &mut errors).unwrap_or_default();
        if self.interface.is_some()
            && (interface.is_empty()
                || interface.len() > INTERFACE_NAME_MAX
                || !interface
                    .chars()
                    .all(|c| c.is_ascii_graphic() && c != '/' && c != ':'))
        {
            errors.push(ConfigError::new(
                "interface",
                format!("{interface:?}"),
                format!(
                    "must be a network interface name: 1..={INTERFACE_NAME_MAX} printable \
                     characters, no '/' or ':'"
                ),
            ));
        }
        let rate = check_rate("rate_hz", self.rate_hz, &mut errors).unwrap_or(DEFAULT_RATE_HZ);
        let mut frames: Vec<RawFrameConfig> = Vec::new();
        let mut ids: HashMap<CanId, usize> = HashMap::new();
        for (i, f) in self.frames.iter().enumerate() {
            let mut fe = ConfigErrors::default();
            let frame = validate_frame(f, i, fd, rate, &mut names, &mut fe);
            // Checked on the id as written, so a frame with other errors still counts.
            let id = f.id.and_then(|id| {
                CanId::new(u32::try_from(id).ok()?, f.extended.unwrap_or(false)).ok()
            });
            if let Some(id) = id {
                if let Some(first) = ids.get(&id) {
                    fe.push(ConfigError::new(
                        "id",
                        id,
                        format!("must be unique: frames[{first}] has the same identifier"),
                    ));
                } else {
                    ids.insert(id, i);
                }
            }
            errors.extend_within(&format!("frames[{i}]"), fe);
            frames.extend(frame);
        }
        let dronecan = self.dronecan.as_ref().and_then(|d| {
            let mut de = ConfigErrors::default();
            let config = d.validate(rate, &mut names, &mut de);
            errors.extend_within("dronecan", de);
            config
        });
        if let Some(dc) = &dronecan {
            // Our own DroneCAN identifiers must not be reused by a raw frame.
            let ours = [
                (ARRAY_COMMAND, dc.priority),
                (RAW_COMMAND, dc.priority),
                (NODE_STATUS, NODE_STATUS_PRIORITY),
            ];
            for (t, priority) in ours {
                let id = CanId::Extended(dronecan::message_id(priority, t.id, dc.node_id));
                if let Some(i) = ids.get(&id) {
                    errors.push(ConfigError::new(
                        format!("frames[{i}].id"),
                        id,
                        format!("must differ from our DroneCAN {} identifier", t.name),
                    ));
                }
            }
        }
        if self.frames.is_empty() && self.dronecan.is_none() {
            errors.push(ConfigError::new(
                "frames",
                "[]",
                "a CAN vehicle needs at least one [[output.frames]] or an [output.dronecan] table",
            ));
        }
        errors.into_result(CanConfig {
            interface,
            fd,
            frames,
            dronecan,
        })
    }
}

fn validate_frame(
    f: &FrameSettings,
    i: usize,
    fd: bool,
    section_rate: i64,
    names: &mut Names,
    errors: &mut ConfigErrors,
) -> Option<RawFrameConfig> {
    let extended = f.extended.unwrap_or(false);
    let id = required("id", &f.id, errors).and_then(|id| {
        let limit = if extended {
            EXTENDED_ID_MAX
        } else {
            STANDARD_ID_MAX
        };
        let fits = u32::try_from(id)
            .ok()
            .and_then(|id| CanId::new(id, extended).ok());
        if fits.is_none() {
            let hint = if !extended && (0..=i64::from(EXTENDED_ID_MAX)).contains(&id) {
                " (set extended = true for a 29-bit identifier)"
            } else {
                ""
            };
            let shown = if id < 0 {
                id.to_string()
            } else {
                format!("0x{id:X}")
            };
            errors.push(ConfigError::new(
                "id",
                shown,
                format!("must be 0..=0x{limit:X}{hint}"),
            ));
        }
        fits
    });
    let capacity = if fd { FD_MAX_LEN } else { CLASSIC_MAX_LEN };
    let length = f.length.and_then(|len| {
        let ok = usize::try_from(len)
            .ok()
            .filter(|l| *l <= CLASSIC_MAX_LEN || (fd && FD_LENGTHS.contains(l)));
        if ok.is_none() {
            let rule = if fd {
                "must be 0..=8, 12, 16, 20, 24, 32, 48 or 64 bytes"
            } else {
                "must be 0..=8 bytes (longer frames need fd = true)"
            };
            errors.push(ConfigError::new("length", len, rule));
        }
        ok
    });
    let rate = check_rate("rate_hz", f.rate_hz, errors).unwrap_or(section_rate);
    if f.outputs.is_empty() {
        errors.push(ConfigError::new(
            "outputs",
            "[]",
            "a frame needs at least one [[output.frames.outputs]]",
        ));
    }
    let limit = length.unwrap_or(capacity);
    let mut outputs: Vec<RawOutputConfig> = Vec::new();
    let mut all_ok = id.is_some();
    for (j, o) in f.outputs.iter().enumerate() {
        let mut oe = ConfigErrors::default();
        let default_name = format!("frames[{i}].outputs[{j}]");
        let output = validate_field(o, &default_name, limit, &outputs, &mut oe);
        if let Some(output) = &output {
            names.claim(
                &output.name,
                &format!("{default_name}.name"),
                &format!("outputs[{j}].name"),
                errors,
            );
        }
        all_ok &= output.is_some();
        errors.extend_within(&format!("outputs[{j}]"), oe);
        outputs.extend(output);
    }
    let id = id?;
    if !all_ok {
        return None;
    }
    let needed = outputs.iter().map(|o| o.layout.end()).max().unwrap_or(0);
    let length = length.unwrap_or_else(|| {
        if needed <= CLASSIC_MAX_LEN {
            needed
        } else {
            FD_LENGTHS
                .iter()
                .copied()
                .find(|l| *l >= needed)
                .unwrap_or(FD_MAX_LEN)
        }
    });
    Some(RawFrameConfig {
        id,
        length,
        period: period_of(rate),
        outputs,
    })
}

fn validate_field(
    o: &FieldSettings,
    default_name: &str,
    frame_len: usize,
    earlier: &[RawOutputConfig],
    errors: &mut ConfigErrors,
) -> Option<RawOutputConfig> {
    let name = o.name.clone().unwrap_or_else(|| default_name.to_string());
    if o.name.as_deref().is_some_and(|n| n.trim().is_empty()) {
        errors.push(ConfigError::new("name", "\"\"", "must not be empty"));
    }
    let source = required("source", &o.source, errors).map(|s| s.validate(errors));
    let width = match o.width {
        None => Some(Width::Bits16),
        Some(w) => {
            let width = Width::from_bits(w);
            if width.is_none() {
                errors.push(ConfigError::new("width", w, "must be 8, 16 or 32 (bits)"));
            }
            width
        }
    };
    let offset = required("offset", &o.offset, errors).and_then(|off| {
        let ok = usize::try_from(off).ok().filter(|o| *o < frame_len);
        if ok.is_none() {
            errors.push(ConfigError::new(
                "offset",
                off,
                format!("must be 0..{frame_len} (the frame's bytes)"),
            ));
        }
        ok
    });
    let (offset, width) = (offset?, width?);
    let layout = FieldLayout {
        offset,
        width,
        endian: o.endian.unwrap_or_default(),
        signed: o.signed.unwrap_or(true),
    };
    let mut placed = true;
    if layout.end() > frame_len {
        errors.push(ConfigError::new(
            "offset",
            offset,
            format!(
                "offset + width ({offset} + {} bytes) reaches past the frame's {frame_len} bytes",
                width.bytes()
            ),
        ));
        placed = false;
    }
    if let Some(other) = earlier.iter().find(|e| e.layout.overlaps(&layout)) {
        errors.push(ConfigError::new(
            "offset",
            offset,
            format!(
                "bytes {}..{} overlap output {:?} (bytes {}..{})",
                layout.offset,
                layout.end(),
                other.name,
                other.layout.offset,
                other.layout.end()
            ),
        ));
        placed = false;
    }
    let range = layout.range();
    let defaults = if layout.signed {
        (range.0 + 1, range.1)
    } else {
        range
    };
    let scaled = check_scale(
        o.min, o.centre, o.max, o.failsafe, defaults, None, range, errors,
    );
    let (scale, failsafe) = scaled?;
    if !placed {
        return None;
    }
    Some(RawOutputConfig {
        name,
        source: source?,
        layout,
        scale,
        failsafe,
    })
}

impl DroneCanSettings {
    fn validate(
        &self,
        section_rate: i64,
        names: &mut Names,
        errors: &mut ConfigErrors,
    ) -> Option<DroneCanConfig> {
        let node_id = required("node_id", &self.node_id, errors).and_then(|n| {
            let ok = u8::try_from(n).ok().filter(|_| NODE_ID_RANGE.contains(&n));
            if ok.is_none() {
                errors.push(ConfigError::new(
                    "node_id",
                    n,
                    "must be 1..=127 (0 is anonymous)",
                ));
            }
            ok
        });
        let priority = self.priority.unwrap_or(DEFAULT_PRIORITY);
        let priority = u8::try_from(priority)
            .ok()
            .filter(|_| PRIORITY_RANGE.contains(&priority));
        if priority.is_none() {
            errors.push(ConfigError::new(
                "priority",
                self.priority.unwrap_or(DEFAULT_PRIORITY),
                "must be 0..=31 (0 highest)",
            ));
        }
        let rate = check_rate("rate_hz", self.rate_hz, errors).unwrap_or(section_rate);
        if self.servos.is_empty() && self.escs.is_empty() {
            errors.push(ConfigError::new(
                "servos",
                "[]",
                "[output.dronecan] needs at least one of [[output.dronecan.servos]] or \
                 [[output.dronecan.escs]]",
            ));
        }
        if self.servos.len() > MAX_SERVOS {
            errors.push(ConfigError::new(
                "servos",
                format!("{} entries", self.servos.len()),
                format!("at most {MAX_SERVOS} (one ArrayCommand)"),
            ));
        }
        let mut ok = true;
        let mut servos = Vec::new();
        let mut actuator_ids: HashMap<u8, usize> = HashMap::new();
        for (i, s) in self.servos.iter().enumerate() {
            let mut se = ConfigErrors::default();
            let key = format!("dronecan.servos[{i}]");
            let servo = s.validate(&key, &mut se);
            if let Some(servo) = &servo {
                names.claim(
                    &servo.name,
                    &format!("{key}.name"),
                    &format!("servos[{i}].name"),
                    errors,
                );
                if let Some(first) = actuator_ids.insert(servo.actuator_id, i) {
                    se.push(ConfigError::new(
                        "actuator_id",
                        servo.actuator_id,
                        format!("must be unique: servos[{first}] has the same"),
                    ));
                }
            }
            ok &= servo.is_some() && se.0.is_empty();
            errors.extend_within(&format!("servos[{i}]"), se);
            servos.extend(servo);
        }
        let mut escs = Vec::new();
        let mut indices: HashMap<u8, usize> = HashMap::new();
        for (i, e) in self.escs.iter().enumerate() {
            let mut ee = ConfigErrors::default();
            let key = format!("dronecan.escs[{i}]");
            let esc = e.validate(&key, &mut ee);
            if let Some(esc) = &esc {
                names.claim(
                    &esc.name,
                    &format!("{key}.name"),
                    &format!("escs[{i}].name"),
                    errors,
                );
                if let Some(first) = indices.insert(esc.index, i) {
                    ee.push(ConfigError::new(
                        "index",
                        esc.index,
                        format!("must be unique: escs[{first}] has the same"),
                    ));
                }
            }
            ok &= esc.is_some() && ee.0.is_empty();
            errors.extend_within(&format!("escs[{i}]"), ee);
            escs.extend(esc);
        }
        if !ok {
            return None;
        }
        Some(DroneCanConfig {
            node_id: node_id?,
            priority: priority?,
            period: period_of(rate),
            servos,
            escs,
        })
    }
}

impl ServoSettings {
    fn validate(&self, default_name: &str, errors: &mut ConfigErrors) -> Option<ServoConfig> {
        let actuator_id = required("actuator_id", &self.actuator_id, errors).and_then(|a| {
            let ok = u8::try_from(a).ok();
            if ok.is_none() {
                errors.push(ConfigError::new("actuator_id", a, "must be 0..=255"));
            }
            ok
        });
        let source = required("source", &self.source, errors).map(|s| s.validate(errors));
        let min = self.min.unwrap_or(-1.0);
        let max = self.max.unwrap_or(1.0);
        let centre = self.centre.unwrap_or((min + max) / 2.0);
        let failsafe = self.failsafe.unwrap_or(centre);
        let mut ok = true;
        for (key, v) in [
            ("min", min),
            ("centre", centre),
            ("max", max),
            ("failsafe", failsafe),
        ] {
            if !(-1.0..=1.0).contains(&v) {
                errors.push(ConfigError::new(
                    key,
                    v,
                    "must be -1..=1 (a unitless actuator command)",
                ));
                ok = false;
            }
        }
        let between = (min < centre && centre < max) || (max < centre && centre < min);
        if ok && !between {
            errors.push(ConfigError::new(
                "centre",
                centre,
                format!("must lie strictly between min ({min}) and max ({max})"),
            ));
            ok = false;
        }
        if !ok {
            return None;
        }
        Some(ServoConfig {
            name: self
                .name
                .clone()
                .unwrap_or_else(|| default_name.to_string()),
            actuator_id: actuator_id?,
            source: source?,
            scale: UnitScale {
                min: min as f32,
                centre: centre as f32,
                max: max as f32,
            },
            failsafe: failsafe as f32,
        })
    }
}

impl EscSettings {
    fn validate(&self, default_name: &str, errors: &mut ConfigErrors) -> Option<EscConfig> {
        let index = required("index", &self.index, errors).and_then(|i| {
            let ok = u8::try_from(i).ok().filter(|i| usize::from(*i) < MAX_ESCS);
            if ok.is_none() {
                errors.push(ConfigError::new(
                    "index",
                    i,
                    format!(
                        "must be 0..={} (RawCommand has {MAX_ESCS} channels)",
                        MAX_ESCS - 1
                    ),
                ));
            }
            ok
        });
        let source = required("source", &self.source, errors).map(|s| s.validate(errors));
        let range = (*RAW_COMMAND_RANGE.start(), *RAW_COMMAND_RANGE.end());
        let (scale, failsafe) = check_scale(
            self.min,
            self.centre,
            self.max,
            self.failsafe,
            (0, range.1),
            Some(0),
            range,
            errors,
        )?;
        Some(EscConfig {
            name: self
                .name
                .clone()
                .unwrap_or_else(|| default_name.to_string()),
            index: index?,
            source: source?,
            scale,
            failsafe,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

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
        assert_eq!(c.interface(), "can0");
        assert!(!c.fd());
        assert_eq!(c.keepalive_period(), Duration::from_millis(20));
        let f = &c.frames()[0];
        assert_eq!(f.id(), CanId::Standard(0x201));
        assert_eq!(f.length(), 4);
        let left = &f.outputs()[0];
        assert_eq!(left.layout().width, Width::Bits16);
        assert_eq!(left.layout().endian, Endian::Little);
        assert!(left.layout().signed);
        assert_eq!(
            left.scale(),
            Scale {
                min: -1000,
                centre: 0,
                max: 1000
            }
        );
        assert_eq!(left.failsafe(), 0);
        assert_eq!(
            left.source(),
            &Source::Mix(vec![(Axis::Throttle, 1.0), (Axis::Roll, 1.0)])
        );
        assert_eq!(c.output_names(), ["left", "right"]);
    }

    #[test]
    fn unsigned_fields_default_to_their_full_range() {
        let c = parse(
            "interface = \"vcan0\"\n[[frames]]\nid = 1\n[[frames.outputs]]\nsource = \"yaw\"\n\
             offset = 0\nwidth = 8\nsigned = false",
        )
        .validate()
        .expect("valid");
        let o = &c.frames()[0].outputs()[0];
        assert_eq!(
            o.scale(),
            Scale {
                min: 0,
                centre: 127,
                max: 255
            }
        );
        assert_eq!(o.name(), "frames[0].outputs[0]");
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
        assert_eq!(c.frames()[0].length(), 64);
        let text = "interface = \"can0\"\nfd = true\n[[frames]]\nid = 0x10\n\
                    [[frames.outputs]]\nsource = \"roll\"\noffset = 8\nwidth = 16";
        assert_eq!(
            parse(text).validate().expect("valid").frames()[0].length(),
            12
        );
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
        let dc = c.dronecan().expect("dronecan");
        assert_eq!((dc.node_id(), dc.priority()), (10, 16));
        assert_eq!(dc.period(), Duration::from_millis(10));
        assert_eq!(c.keepalive_period(), Duration::from_millis(10));
        assert_eq!(dc.esc_array_len(), 4);
        let esc = &dc.escs()[0];
        assert_eq!(
            esc.scale(),
            Scale {
                min: 0,
                centre: 4095,
                max: 8191
            }
        );
        assert_eq!(esc.failsafe(), 0);
        let servo = &dc.servos()[0];
        assert_eq!(servo.failsafe(), 0.0);
        assert_eq!(servo.name(), "dronecan.servos[0]");
    }
}
