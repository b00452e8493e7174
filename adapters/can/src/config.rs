//! The `[output]` section of a CAN vehicle (`adapter = "can"`): the raw serde structs, which
//! only parse and reject unknown keys, and [`CanSettings::validate`], which checks every key,
//! collects every problem and returns the validated [`CanConfig`]. The keys are described in
//! the crate docs.
//!
//! Keys of errors are relative to the `[output]` table, e.g. `frames[1].outputs[0].offset`;
//! the gateway puts `output.` in front. Integers are read wide ([`rove_core::config::Int`]) so
//! that a negative or huge value is reported against its key instead of failing the parse.

use crate::bus::{
    CLASSIC_MAX_LEN, CanId, EXTENDED_ID_MAX, FD_LENGTHS, FD_MAX_LEN, STANDARD_ID_MAX,
};
use crate::dronecan::{
    self, ARRAY_COMMAND, MAX_ESCS, MAX_SERVOS, NODE_ID_RANGE, NODE_STATUS, NODE_STATUS_PRIORITY,
    PRIORITY_RANGE, RAW_COMMAND, RAW_COMMAND_RANGE,
};
use crate::raw::{Endian, FieldLayout, Width};
use crate::scale::{Scale, Source, UnitScale};
use rove_core::config::{Int, Unique, UnknownKeys};
use rove_core::error::ConfigErrors;
use rove_core::mapping::Axis;
use serde::de::{self, MapAccess, Visitor};
use serde::{Deserialize, Deserializer, Serialize};
use std::fmt;
use std::ops::RangeInclusive;
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

/// `source = …` as written: an axis name, or `{ mix = [["throttle", 1.0], ["roll", -1.0]] }`.
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
        #[derive(Deserialize)]
        #[serde(deny_unknown_fields)]
        struct Mix {
            mix: Vec<(Axis, f64)>,
        }
        impl<'de> Visitor<'de> for SourceVisitor {
            type Value = SourceSettings;
            fn expecting(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
                f.write_str("an axis or { mix = [[\"throttle\", 1.0], [\"roll\", 1.0]] }")
            }
            fn visit_str<E: de::Error>(self, v: &str) -> Result<SourceSettings, E> {
                Axis::deserialize(de::value::StrDeserializer::new(v)).map(SourceSettings::Axis)
            }
            fn visit_map<A: MapAccess<'de>>(self, map: A) -> Result<SourceSettings, A::Error> {
                let Mix { mix } = Mix::deserialize(de::value::MapAccessDeserializer::new(map))?;
                Ok(SourceSettings::Mix { mix })
            }
        }
        deserializer.deserialize_any(SourceVisitor)
    }
}

impl fmt::Display for SourceSettings {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            SourceSettings::Axis(a) => f.write_str(a.name()),
            SourceSettings::Mix { mix } => {
                let terms: Vec<String> = (mix.iter())
                    .map(|(a, w)| format!("[\"{}\", {w}]", a.name()))
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
    /// The required `source` key, validated.
    fn validate(source: &Option<Self>, errors: &mut ConfigErrors) -> Option<Source> {
        let this = errors.required("source", source)?;
        let mix = match &this {
            SourceSettings::Axis(a) => return Some(Source::Axis(*a)),
            SourceSettings::Mix { mix } => mix,
        };
        if mix.is_empty() || mix.len() > MIX_TERMS_MAX {
            let rule = format!("a mix needs 1..={MIX_TERMS_MAX} terms");
            errors.add("source", &this, rule);
        }
        for (i, (axis, weight)) in mix.iter().enumerate() {
            let name = axis.name();
            if !weight.is_finite() || weight.abs() > MIX_WEIGHT_MAX || *weight == 0.0 {
                let rule =
                    format!("weight of {name} must be non-zero and within ±{MIX_WEIGHT_MAX}");
                errors.add("source", &this, rule);
            }
            if mix[..i].iter().any(|(other, _)| other == axis) {
                errors.add("source", &this, format!("{name} appears twice in the mix"));
            }
        }
        Some(Source::Mix(mix.clone()))
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

fn period_of(rate_hz: i64) -> Duration {
    Duration::from_nanos(1_000_000_000 / rate_hz.clamp(1, 1_000_000_000) as u64)
}

/// A `rate_hz` key, filled with `default` when absent; `default` also stands in for a bad one.
fn check_rate(rate: &mut Option<Int>, default: Int, errors: &mut ConfigErrors) -> Int {
    let rate = *rate.get_or_insert(default);
    (errors.int("rate_hz", rate, RATE_RANGE_HZ, " Hz")).unwrap_or(default)
}

impl<T: Copy + PartialOrd + fmt::Display> ScaleSettings<T> {
    /// Checks the four values (min and max in either order) against `range`, filling
    /// defaults: `(lo, hi)` for min and max, `mid` for the centre, then `failsafe_default` or
    /// the centre. `None` if any is invalid (each invalid key recorded with `rule`).
    fn check(
        &mut self,
        (lo, hi): (T, T),
        mid: fn(T, T) -> T,
        failsafe_default: Option<T>,
        (range, rule): (RangeInclusive<T>, &str),
        errors: &mut ConfigErrors,
    ) -> Option<[T; 4]> {
        let (min, max) = (*self.min.get_or_insert(lo), *self.max.get_or_insert(hi));
        let centre = *self.centre.get_or_insert_with(|| mid(min, max));
        let failsafe = *self
            .failsafe
            .get_or_insert(failsafe_default.unwrap_or(centre));
        let values = [min, centre, max, failsafe];
        let mut ok = true;
        for (key, v) in ["min", "centre", "max", "failsafe"].into_iter().zip(values) {
            if !range.contains(&v) {
                errors.add(key, v, rule);
                ok = false;
            }
        }
        let between = (min < centre && centre < max) || (max < centre && centre < min);
        if ok && !between {
            let rule = format!("must lie strictly between min ({min}) and max ({max})");
            errors.add("centre", centre, rule);
            ok = false;
        }
        ok.then_some(values)
    }
}

/// [`ScaleSettings::check`] for integer device units: `lo..=hi` as the range and its rule.
fn int_scale(
    s: &mut ScaleSettings<Int>,
    defaults: (Int, Int),
    failsafe_default: Option<Int>,
    (lo, hi): (Int, Int),
    errors: &mut ConfigErrors,
) -> Option<(Scale, Int)> {
    let rule = format!("must be {lo}..={hi}");
    // In i128: `a` and `b` are any numbers the file holds (checked against the range next).
    let mid = |a: Int, b: Int| {
        let mid = (i128::from(a) + i128::from(b)).div_euclid(2);
        Int::try_from(mid).unwrap_or(a)
    };
    let [min, centre, max, failsafe] =
        s.check(defaults, mid, failsafe_default, (lo..=hi, &rule), errors)?;
    Some((Scale { min, centre, max }, failsafe))
}

impl CanSettings {
    /// Validates every key, filling defaults into `self` (which then serializes as the
    /// effective config).
    ///
    /// # Errors
    /// [`rove_core::Error::Config`] listing every key that breaks a rule of the crate docs'
    /// key table (or repeats an identifier, name or place), relative to `[output]`.
    pub fn validate(&mut self) -> rove_core::Result<CanConfig> {
        let mut errors = ConfigErrors::default();
        let mut names = Unique::default();
        let fd = *self.fd.get_or_insert(false);
        let interface = (errors.required("interface", &self.interface)).unwrap_or_default();
        let bad = |c: char| !c.is_ascii_graphic() || c == '/' || c == ':';
        let fits = (1..=INTERFACE_NAME_MAX).contains(&interface.len());
        if self.interface.is_some() && (!fits || interface.contains(bad)) {
            let max = INTERFACE_NAME_MAX;
            let rule = format!(
                "must be a network interface name: 1..={max} printable characters, no '/' or ':'"
            );
            errors.add("interface", format!("{interface:?}"), rule);
        }
        let rate = check_rate(&mut self.rate_hz, DEFAULT_RATE_HZ, &mut errors);
        let (mut frames, mut ids) = (Vec::new(), Unique::default());
        for (i, f) in self.frames.iter_mut().enumerate() {
            let frame = errors.within(&format!("frames[{i}]"), |fe| {
                validate_frame(f, i, fd, rate, (&mut names, &mut ids), fe)
            });
            frames.extend(frame);
        }
        let dronecan = (self.dronecan.as_mut())
            .and_then(|d| errors.within("dronecan", |de| d.validate(rate, &mut names, de)));
        if let Some(dc) = &dronecan {
            // Our own DroneCAN identifiers must not be reused by a raw frame (the first is named).
            let ours = [
                (ARRAY_COMMAND, dc.priority),
                (RAW_COMMAND, dc.priority),
                (NODE_STATUS, NODE_STATUS_PRIORITY),
            ];
            for (t, priority) in ours {
                let id = CanId::Extended(dronecan::message_id(priority, t.id, dc.node_id));
                if let Some(frame) = ids.claim(id, "dronecan") {
                    let rule = format!("must differ from our DroneCAN {} identifier", t.name);
                    errors.add(format!("{frame}.id"), id, rule);
                }
            }
        }
        if self.frames.is_empty() && self.dronecan.is_none() {
            let rule =
                "a CAN vehicle needs at least one [[output.frames]] or an [output.dronecan] table";
            errors.add("frames", "[]", rule);
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
    f: &mut FrameSettings,
    i: usize,
    fd: bool,
    section_rate: i64,
    (names, ids): (&mut Unique<String>, &mut Unique<CanId>),
    errors: &mut ConfigErrors,
) -> Option<RawFrameConfig> {
    let extended = *f.extended.get_or_insert(false);
    let id = errors.required("id", &f.id).and_then(|id| {
        let fits = (u32::try_from(id).ok()).and_then(|id| CanId::new(id, extended).ok());
        if fits.is_none() {
            let limit = if extended {
                EXTENDED_ID_MAX
            } else {
                STANDARD_ID_MAX
            };
            let hint = (!extended && (0..=i64::from(EXTENDED_ID_MAX)).contains(&id))
                .then_some(" (set extended = true for a 29-bit identifier)");
            let shown = u64::try_from(id).map_or(id.to_string(), |id| format!("0x{id:X}"));
            let rule = format!("must be 0..=0x{limit:X}{}", hint.unwrap_or_default());
            errors.add("id", shown, rule);
        }
        fits
    });
    let capacity = if fd { FD_MAX_LEN } else { CLASSIC_MAX_LEN };
    let length = f.length.and_then(|len| {
        let ok = (usize::try_from(len).ok())
            .filter(|l| *l <= CLASSIC_MAX_LEN || (fd && FD_LENGTHS.contains(l)));
        if ok.is_none() {
            let rule = match fd {
                true => "must be 0..=8, 12, 16, 20, 24, 32, 48 or 64 bytes",
                false => "must be 0..=8 bytes (longer frames need fd = true)",
            };
            errors.add("length", len, rule);
        }
        ok
    });
    let rate = check_rate(&mut f.rate_hz, section_rate, errors);
    if f.outputs.is_empty() {
        let rule = "a frame needs at least one [[output.frames.outputs]]";
        errors.add("outputs", "[]", rule);
    }
    let limit = length.unwrap_or(capacity);
    let mut outputs: Vec<RawOutputConfig> = Vec::new();
    let mut all_ok = id.is_some();
    for (j, o) in f.outputs.iter_mut().enumerate() {
        let mut oe = ConfigErrors::default();
        let default_name = format!("frames[{i}].outputs[{j}]");
        let output = validate_field(o, &default_name, limit, &outputs, &mut oe);
        if let Some(output) = &output {
            let (key, shown) = (format!("outputs[{j}].name"), format!("{:?}", output.name));
            let (name, owner) = (output.name.clone(), format!("{default_name}.name"));
            names.check(errors, name, owner, (&key, shown), "has the same name");
        }
        all_ok &= output.is_some();
        errors.extend_within(&format!("outputs[{j}]"), oe);
        outputs.extend(output);
    }
    // Checked on the id as written, so a frame with other errors still counts.
    if let Some(id) = id {
        let owner = format!("frames[{i}]");
        ids.check(errors, id, owner, ("id", id), "has the same identifier");
    }
    let id = id?;
    if !all_ok {
        return None;
    }
    let needed = outputs.iter().map(|o| o.layout.end()).max().unwrap_or(0);
    let length = length.unwrap_or_else(|| match needed <= CLASSIC_MAX_LEN {
        true => needed,
        false => FD_LENGTHS
            .into_iter()
            .find(|l| *l >= needed)
            .unwrap_or(FD_MAX_LEN),
    });
    f.length = Some(length as Int);
    let period = period_of(rate);
    Some(RawFrameConfig {
        id,
        length,
        period,
        outputs,
    })
}

fn validate_field(
    o: &mut FieldSettings,
    default_name: &str,
    frame_len: usize,
    earlier: &[RawOutputConfig],
    errors: &mut ConfigErrors,
) -> Option<RawOutputConfig> {
    (o.unknown).check(errors, FieldSettings::KNOWN);
    let name = (o.name.clone()).unwrap_or_else(|| default_name.into());
    if o.name.as_deref().is_some_and(|n| n.trim().is_empty()) {
        errors.add("name", "\"\"", "must not be empty");
    }
    let source = SourceSettings::validate(&o.source, errors);
    let bits = *o.width.get_or_insert(16);
    let width = Width::from_bits(bits);
    if width.is_none() {
        errors.add("width", bits, "must be 8, 16 or 32 (bits)");
    }
    let offset = errors.required("offset", &o.offset).and_then(|off| {
        let ok = usize::try_from(off).ok().filter(|o| *o < frame_len);
        if ok.is_none() {
            let rule = format!("must be 0..{frame_len} (the frame's bytes)");
            errors.add("offset", off, rule);
        }
        ok
    });
    let (offset, width) = (offset?, width?);
    let layout = FieldLayout {
        offset,
        width,
        endian: *o.endian.get_or_insert_default(),
        signed: *o.signed.get_or_insert(true),
    };
    let (end, bytes) = (layout.end(), width.bytes());
    let mut placed = true;
    if end > frame_len {
        let rule = format!(
            "offset + width ({offset} + {bytes} bytes) reaches past the frame's {frame_len} bytes"
        );
        errors.add("offset", offset, rule);
        placed = false;
    }
    if let Some(other) = earlier.iter().find(|e| e.layout.overlaps(&layout)) {
        let (o_start, o_end) = (other.layout.offset, other.layout.end());
        let rule = format!(
            "bytes {offset}..{end} overlap output {:?} (bytes {o_start}..{o_end})",
            other.name
        );
        errors.add("offset", offset, rule);
        placed = false;
    }
    let range = layout.range();
    // Signed fields default to a symmetric range.
    let defaults = (range.0 + Int::from(layout.signed), range.1);
    let (scale, failsafe) = int_scale(&mut o.scale, defaults, None, range, errors)?;
    placed.then_some(RawOutputConfig {
        name,
        source: source?,
        layout,
        scale,
        failsafe,
    })
}

impl DroneCanSettings {
    fn validate(
        &mut self,
        section_rate: Int,
        names: &mut Unique<String>,
        errors: &mut ConfigErrors,
    ) -> Option<DroneCanConfig> {
        let node_id = errors.req_int("node_id", self.node_id, NODE_ID_RANGE, " (0 is anonymous)");
        let priority = *self.priority.get_or_insert(DEFAULT_PRIORITY);
        let priority = errors.int("priority", priority, PRIORITY_RANGE, " (0 highest)");
        let rate = check_rate(&mut self.rate_hz, section_rate, errors);
        if self.servos.is_empty() && self.escs.is_empty() {
            let rule = "[output.dronecan] needs at least one of [[output.dronecan.servos]] or \
                        [[output.dronecan.escs]]";
            errors.add("servos", "[]", rule);
        }
        if self.servos.len() > MAX_SERVOS {
            let rule = format!("at most {MAX_SERVOS} (one ArrayCommand)");
            errors.add("servos", format!("{} entries", self.servos.len()), rule);
        }
        let (servos, escs) = (&mut self.servos, &mut self.escs);
        let servo = |s: &ServoConfig| (s.name.clone(), "actuator_id", s.actuator_id);
        let servos = actuators(
            "servos",
            servos,
            ServoSettings::validate,
            servo,
            names,
            errors,
        );
        let esc = |e: &EscConfig| (e.name.clone(), "index", e.index);
        let escs = actuators("escs", escs, EscSettings::validate, esc, names, errors);
        Some(DroneCanConfig {
            node_id: node_id?,
            priority: priority?,
            period: period_of(rate),
            servos: servos?,
            escs: escs?,
        })
    }
}

/// Validates DroneCAN `servos` or `escs` (`list`) with `validate`: each named uniquely among
/// every output and at a `place` (its name, and the key and number of its actuator id or
/// index) of its own; `None` if any has a problem.
fn actuators<S, C>(
    list: &str,
    settings: &mut [S],
    validate: fn(&mut S, &str, &mut ConfigErrors) -> Option<C>,
    place: fn(&C) -> (String, &'static str, u8),
    names: &mut Unique<String>,
    errors: &mut ConfigErrors,
) -> Option<Vec<C>> {
    let (mut out, mut places, mut ok) = (Vec::new(), Unique::default(), true);
    for (i, s) in settings.iter_mut().enumerate() {
        let (mut se, owner) = (ConfigErrors::default(), format!("{list}[{i}]"));
        let actuator = validate(s, &format!("dronecan.{owner}"), &mut se);
        if let Some((name, key, number)) = actuator.as_ref().map(place) {
            let (name_key, shown) = (format!("{owner}.name"), format!("{name:?}"));
            let (first, what) = (format!("dronecan.{name_key}"), "has the same name");
            names.check(errors, name, first, (name_key.as_str(), shown), what);
            places.check(&mut se, number, &owner, (key, number), "has the same");
        }
        ok &= actuator.is_some() && se.0.is_empty();
        errors.extend_within(&owner, se);
        out.extend(actuator);
    }
    ok.then_some(out)
}

impl ServoSettings {
    fn validate(&mut self, default_name: &str, errors: &mut ConfigErrors) -> Option<ServoConfig> {
        (self.unknown).check(errors, Self::KNOWN);
        let name = (self.name.clone()).unwrap_or_else(|| default_name.into());
        let actuator_id = errors.req_int("actuator_id", self.actuator_id, 0..=255, "");
        let source = SourceSettings::validate(&self.source, errors);
        let range = (-1.0..=1.0, "must be -1..=1 (a unitless actuator command)");
        let mid = |a, b| (a + b) / 2.0;
        let checked = self.scale.check((-1.0, 1.0), mid, None, range, errors)?;
        let [min, centre, max, failsafe] = checked.map(|v| v as f32);
        Some(ServoConfig {
            name,
            actuator_id: actuator_id?,
            source: source?,
            scale: UnitScale { min, centre, max },
            failsafe,
        })
    }
}

impl EscSettings {
    fn validate(&mut self, default_name: &str, errors: &mut ConfigErrors) -> Option<EscConfig> {
        (self.unknown).check(errors, Self::KNOWN);
        let name = (self.name.clone()).unwrap_or_else(|| default_name.into());
        let unit = format!(" (RawCommand has {MAX_ESCS} channels)");
        let index = errors.req_int("index", self.index, 0..=(MAX_ESCS as Int - 1), &unit);
        let source = SourceSettings::validate(&self.source, errors);
        let range = (*RAW_COMMAND_RANGE.start(), *RAW_COMMAND_RANGE.end());
        let (scale, failsafe) = int_scale(&mut self.scale, (0, range.1), Some(0), range, errors)?;
        Some(EscConfig {
            name,
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
