//! `[output] adapter = "mavlink"`: the settings as written, their validation, and the
//! per-autopilot mode tables.
//!
//! Every key is optional; the defaults make an ArduPilot Rover on SITL's TCP port drivable:
//!
//! ```toml
//! [output]
//! adapter = "mavlink"
//! connection = "tcpout:127.0.0.1:5760"
//! ```

use rove_core::config::{Int, Unique, UnknownKeys, keys_of};
use rove_core::error::ConfigErrors;
use rove_core::mapping::{Axis, AxisMap, AxisMapSettings};
use rove_core::msg::Mode;
use serde::{Deserialize, Serialize};
use std::fmt;
use std::time::Duration;

/// The `[output]` table of a MAVLink vehicle, as written (without the `adapter` key, which the
/// gateway's tagged enum consumes).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MavlinkSettings {
    /// `udpin:HOST:PORT`, `udpout:HOST:PORT`, `tcpout:HOST:PORT` (also `udp:` = udpin and
    /// `tcp:` = tcpout), or `serial:DEVICE:BAUD` (absent: `tcpout:127.0.0.1:5760`, SITL).
    pub connection: Option<String>,
    /// 2 (absent) or 1.
    pub mavlink_version: Option<Int>,
    /// Our system id (absent: 255, ArduPilot's default `MAV_GCS_SYSID` / `SYSID_MYGCS`).
    pub system_id: Option<Int>,
    /// Our component id (absent: 190, MAV_COMP_ID_MISSIONPLANNER).
    pub component_id: Option<Int>,
    /// The autopilot's system id (absent: the first autopilot heard).
    pub target_system: Option<Int>,
    /// The autopilot's component id (absent: that of the first autopilot heard, else 1).
    pub target_component: Option<Int>,
    /// `"ardupilot"` (absent) or `"px4"`.
    pub autopilot: Option<AutopilotKind>,
    /// `"rover"` (absent) or `"copter"`: picks the default modes and stick conventions.
    pub vehicle: Option<VehicleKind>,
    /// `"rc_override"` (absent for ArduPilot) or `"manual_control"` (absent for PX4).
    pub method: Option<Method>,
    /// Resend rate of the control message while driving and in failsafe, Hz (absent: 25).
    pub rate_hz: Option<f64>,
    /// No HEARTBEAT from the autopilot for this long → link reported down, ms (absent: 3000).
    pub link_timeout_ms: Option<Int>,
    /// Wait for a mode command's COMMAND_ACK before resending, ms (absent: 300).
    pub command_timeout_ms: Option<Int>,
    /// Resends of an unacknowledged mode command (absent: 3).
    pub command_retries: Option<Int>,
    /// What the control message carries in failsafe: `"release"` (absent for rc_override: hand
    /// every mapped channel back to the radio) or `"neutral"` (centre values, resent at rate;
    /// the only choice for manual_control, which has no release value).
    pub failsafe: Option<FailsafeAction>,
    /// What rove does when the autopilot refuses (or never confirms) the mode it wished for the
    /// operator: `"hold"` (absent: stop driving, release or neutral plus the safe mode, until the
    /// operator picks another mode) or `"continue"` (keep sending the sticks; the refusal is
    /// reported either way).
    pub on_mode_refused: Option<OnModeRefused>,
    /// `[[output.channels]]`: rc_override channel map (absent: the autopilot's default RCMAP).
    #[serde(default)]
    pub channels: Vec<ChannelSettings>,
    /// `[output.manual_control]`.
    pub manual_control: Option<ManualControlSettings>,
    /// `[output.modes]`: the autopilot mode for each rove mode and for failsafe.
    pub modes: Option<ModeSettings>,
}

/// Which autopilot firmware.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum AutopilotKind {
    /// ArduPilot (Rover, Copter).
    Ardupilot,
    /// PX4.
    Px4,
}

/// Which kind of vehicle the autopilot flies or drives.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum VehicleKind {
    /// A ground vehicle.
    Rover,
    /// A multirotor.
    Copter,
}

/// How sticks reach the autopilot.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Method {
    /// RC_CHANNELS_OVERRIDE (ArduPilot).
    RcOverride,
    /// MANUAL_CONTROL (PX4, ArduPilot).
    ManualControl,
}

/// What the control message carries in failsafe.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum FailsafeAction {
    /// Release the overridden channels (rc_override only).
    Release,
    /// Centred sticks, resent at rate.
    Neutral,
}

/// What to do when the autopilot refuses a driven mode.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum OnModeRefused {
    /// Stop driving: the failsafe content and the safe mode, until the operator's mode changes.
    Hold,
    /// Keep driving in whatever mode the autopilot is in.
    Continue,
}

/// One `[[output.channels]]` table: an axis on an RC channel.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct ChannelSettings {
    /// RC channel 1..=18 (9..=18 need MAVLink 2).
    pub channel: Option<Int>,
    /// The axis it carries.
    pub axis: Option<Axis>,
    /// The mapping keys ([`rove_core::mapping::AxisMapSettings`]; no `slew_us_per_s`).
    #[serde(flatten)]
    pub map: AxisMapSettings,
    /// Keys nothing above took: reported by `validate`.
    #[serde(flatten)]
    pub unknown: UnknownKeys,
}

/// `[output.manual_control]`: which axis feeds each MANUAL_CONTROL field.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ManualControlSettings {
    /// `x` (forward; absent: pitch).
    pub x: Option<AxisOrNone>,
    /// `y` (right; Rover steering; absent: roll).
    pub y: Option<AxisOrNone>,
    /// `z` (thrust; Rover throttle; absent: throttle).
    pub z: Option<AxisOrNone>,
    /// `r` (yaw; absent: yaw).
    pub r: Option<AxisOrNone>,
    /// `"signed"`: z is −1000..1000, 0 at centre (ArduPilot Rover); `"positive"`: 0..1000, 500
    /// at centre (PX4 and ArduPilot Copter). Absent: by autopilot and vehicle.
    pub z_range: Option<ZRange>,
    /// Fields whose sign is flipped, e.g. `["y"]`.
    #[serde(default)]
    pub reverse: Vec<ManualField>,
}

/// An axis, or `"none"` for a MANUAL_CONTROL field sent as "invalid" (INT16_MAX).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum AxisOrNone {
    /// `MovementCommand::throttle`.
    Throttle,
    /// `MovementCommand::roll`.
    Roll,
    /// `MovementCommand::pitch`.
    Pitch,
    /// `MovementCommand::yaw`.
    Yaw,
    /// Not sent (INT16_MAX: invalid axis per the MAVLink spec).
    None,
}

impl AxisOrNone {
    fn axis(self) -> Option<Axis> {
        match self {
            AxisOrNone::Throttle => Some(Axis::Throttle),
            AxisOrNone::Roll => Some(Axis::Roll),
            AxisOrNone::Pitch => Some(Axis::Pitch),
            AxisOrNone::Yaw => Some(Axis::Yaw),
            AxisOrNone::None => None,
        }
    }
}

/// A MANUAL_CONTROL stick field.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ManualField {
    /// x.
    X,
    /// y.
    Y,
    /// z.
    Z,
    /// r.
    R,
}

/// The range of MANUAL_CONTROL's z.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ZRange {
    /// −1000..1000, 0 at stick centre.
    Signed,
    /// 0..1000, 500 at stick centre.
    Positive,
}

/// `[output.modes]`: a mode name from the autopilot's table or a raw `custom_mode` number.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ModeSettings {
    /// For rove's MANUAL.
    pub manual: Option<AutopilotModeName>,
    /// For rove's ASSISTED.
    pub assisted: Option<AutopilotModeName>,
    /// For rove's AUTO.
    pub auto: Option<AutopilotModeName>,
    /// Entered when rove stops driving (owner lost, gateway stopping, `rove failsafe`).
    pub safe: Option<AutopilotModeName>,
    /// `false`: never send mode commands; the radio or another GCS owns the mode (absent: true).
    pub set_mode: Option<bool>,
}

/// An autopilot mode as written: a name (`"HOLD"`, `"AUTO.LOITER"`) or a raw custom_mode
/// (resolved into an [`AutopilotMode`]).
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum AutopilotModeName {
    /// A name from the autopilot's table.
    Name(String),
    /// A raw `custom_mode` (PX4: `main << 16 | sub << 24`), 0..=4294967295.
    Number(Int),
}

/// Where the autopilot is.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Endpoint {
    /// We listen on this address; replies go to the last sender.
    UdpIn(String),
    /// We send to this address from an ephemeral port.
    UdpOut(String),
    /// We connect to this TCP server (SITL: 127.0.0.1:5760).
    TcpOut(String),
    /// A serial device at a baud rate.
    Serial {
        /// Device path.
        device: String,
        /// Baud rate.
        baud: u32,
    },
}

impl fmt::Display for Endpoint {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Endpoint::UdpIn(a) => write!(f, "udpin:{a}"),
            Endpoint::UdpOut(a) => write!(f, "udpout:{a}"),
            Endpoint::TcpOut(a) => write!(f, "tcpout:{a}"),
            Endpoint::Serial { device, baud } => write!(f, "serial:{device}:{baud}"),
        }
    }
}

impl Endpoint {
    /// Parses `udpin:`, `udp:`, `udpout:`, `tcpout:`, `tcp:` and `serial:` addresses.
    ///
    /// # Errors
    /// The rule the text breaks.
    pub fn parse(text: &str) -> Result<Endpoint, String> {
        let Some((scheme, rest)) = text.split_once(':') else {
            return Err(
                "must be SCHEME:ADDRESS with SCHEME udpin, udpout, tcpout or serial".into(),
            );
        };
        let host_port = |rest: &str| -> Result<String, String> {
            let (host, port) = rest
                .rsplit_once(':')
                .ok_or_else(|| format!("{scheme}: needs HOST:PORT"))?;
            if host.is_empty() {
                return Err(format!("{scheme}: needs a host before :PORT"));
            }
            match port.parse::<u16>() {
                Ok(p) if p > 0 => Ok(rest.to_string()),
                _ => Err(format!("{scheme}: port must be 1..=65535, not {port:?}")),
            }
        };
        match scheme {
            "udpin" | "udp" => Ok(Endpoint::UdpIn(host_port(rest)?)),
            "udpout" => Ok(Endpoint::UdpOut(host_port(rest)?)),
            "tcpout" | "tcp" => Ok(Endpoint::TcpOut(host_port(rest)?)),
            "serial" => {
                let (device, baud) = rest
                    .rsplit_once(':')
                    .ok_or("serial: needs DEVICE:BAUD, e.g. serial:/dev/ttyACM0:115200")?;
                if device.is_empty() {
                    return Err("serial: needs a device path".into());
                }
                match baud.parse::<u32>() {
                    Ok(b) if b > 0 => Ok(Endpoint::Serial {
                        device: device.to_string(),
                        baud: b,
                    }),
                    _ => Err(format!(
                        "serial: baud must be a positive number, not {baud:?}"
                    )),
                }
            }
            other => Err(format!(
                "unknown scheme {other:?}: use udpin, udpout, tcpout (tcp) or serial"
            )),
        }
    }
}

/// A validated RC channel.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ChannelConfig {
    /// 1..=18.
    pub channel: u8,
    /// Source axis.
    pub axis: Axis,
    /// Axis → µs.
    pub map: AxisMap,
}

/// Validated MANUAL_CONTROL settings.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ManualControlConfig {
    /// Source of x, y, z, r (None: invalid/unused).
    pub fields: [Option<Axis>; 4],
    /// Sign flips for x, y, z, r.
    pub reverse: [bool; 4],
    /// The z convention.
    pub z_range: ZRange,
}

/// A resolved autopilot mode.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct AutopilotMode {
    /// For logs (`HOLD`, or the number as written).
    pub name: String,
    /// The HEARTBEAT's custom_mode when the autopilot is in it.
    pub custom_mode: u32,
}

/// Validated modes.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ModesConfig {
    /// MANUAL, ASSISTED, AUTO in [`Mode::ALL`] order.
    pub driven: [AutopilotMode; 3],
    /// The failsafe mode.
    pub safe: AutopilotMode,
    /// Whether mode commands are sent at all.
    pub set_mode: bool,
}

impl ModesConfig {
    /// The autopilot mode for rove's `mode`.
    pub fn for_mode(&self, mode: Mode) -> &AutopilotMode {
        match mode {
            Mode::Manual => &self.driven[0],
            Mode::Assisted => &self.driven[1],
            Mode::Auto => &self.driven[2],
        }
    }
}

/// The validated `[output]` of a MAVLink vehicle.
#[derive(Debug, Clone, PartialEq)]
pub struct MavlinkConfig {
    /// Where the autopilot is.
    pub endpoint: Endpoint,
    /// 1 or 2.
    pub mavlink_version: u8,
    /// Our ids.
    pub system_id: u8,
    /// Our component id.
    pub component_id: u8,
    /// Fixed target system (None: discover).
    pub target_system: Option<u8>,
    /// Fixed target component (None: discover).
    pub target_component: Option<u8>,
    /// Firmware.
    pub autopilot: AutopilotKind,
    /// Vehicle kind.
    pub vehicle: VehicleKind,
    /// Control method.
    pub method: Method,
    /// Resend period of the control message.
    pub period: Duration,
    /// Link-down threshold.
    pub link_timeout: Duration,
    /// Mode command ACK timeout.
    pub command_timeout: Duration,
    /// Mode command resends.
    pub command_retries: u32,
    /// Failsafe content.
    pub failsafe: FailsafeAction,
    /// Reaction to a refused driven mode.
    pub on_mode_refused: OnModeRefused,
    /// rc_override channels (empty for manual_control).
    pub channels: Vec<ChannelConfig>,
    /// manual_control fields.
    pub manual_control: ManualControlConfig,
    /// Modes.
    pub modes: ModesConfig,
}

/// ArduPilot Rover's modes (`custom_mode`), from its Mode enum.
const ARDUPILOT_ROVER_MODES: &[(&str, u32)] = &[
    ("MANUAL", 0),
    ("ACRO", 1),
    ("STEERING", 3),
    ("HOLD", 4),
    ("LOITER", 5),
    ("FOLLOW", 6),
    ("SIMPLE", 7),
    ("DOCK", 8),
    ("CIRCLE", 9),
    ("AUTO", 10),
    ("RTL", 11),
    ("SMART_RTL", 12),
    ("GUIDED", 15),
];

/// ArduPilot Copter's modes.
const ARDUPILOT_COPTER_MODES: &[(&str, u32)] = &[
    ("STABILIZE", 0),
    ("ACRO", 1),
    ("ALT_HOLD", 2),
    ("AUTO", 3),
    ("GUIDED", 4),
    ("LOITER", 5),
    ("RTL", 6),
    ("CIRCLE", 7),
    ("LAND", 9),
    ("DRIFT", 11),
    ("SPORT", 13),
    ("POSHOLD", 16),
    ("BRAKE", 17),
    ("SMART_RTL", 21),
];

/// PX4's modes as (name, main mode, sub mode); custom_mode = main << 16 | sub << 24.
const PX4_MODES: &[(&str, u8, u8)] = &[
    ("MANUAL", 1, 0),
    ("ALTCTL", 2, 0),
    ("POSCTL", 3, 0),
    ("AUTO.READY", 4, 1),
    ("AUTO.TAKEOFF", 4, 2),
    ("AUTO.LOITER", 4, 3),
    ("AUTO.MISSION", 4, 4),
    ("AUTO.RTL", 4, 5),
    ("AUTO.LAND", 4, 6),
    ("ACRO", 5, 0),
    ("OFFBOARD", 6, 0),
    ("STABILIZED", 7, 0),
];

/// PX4's custom_mode for a main and sub mode.
pub const fn px4_custom_mode(main: u8, sub: u8) -> u32 {
    ((main as u32) << 16) | ((sub as u32) << 24)
}

/// "ArduPilot Rover", "PX4"…, for messages.
pub fn firmware_name(autopilot: AutopilotKind, vehicle: VehicleKind) -> &'static str {
    match (autopilot, vehicle) {
        (AutopilotKind::Ardupilot, VehicleKind::Rover) => "ArduPilot Rover",
        (AutopilotKind::Ardupilot, VehicleKind::Copter) => "ArduPilot Copter",
        (AutopilotKind::Px4, _) => "PX4",
    }
}

/// The mode table of a firmware and vehicle kind: (name, custom_mode).
pub fn mode_table(autopilot: AutopilotKind, vehicle: VehicleKind) -> Vec<(&'static str, u32)> {
    match (autopilot, vehicle) {
        (AutopilotKind::Ardupilot, VehicleKind::Rover) => ARDUPILOT_ROVER_MODES.to_vec(),
        (AutopilotKind::Ardupilot, VehicleKind::Copter) => ARDUPILOT_COPTER_MODES.to_vec(),
        (AutopilotKind::Px4, _) => PX4_MODES
            .iter()
            .map(|&(n, main, sub)| (n, px4_custom_mode(main, sub)))
            .collect(),
    }
}

/// Default (manual, assisted, auto, safe) mode names.
fn default_modes(autopilot: AutopilotKind, vehicle: VehicleKind) -> [&'static str; 4] {
    match (autopilot, vehicle) {
        (AutopilotKind::Ardupilot, VehicleKind::Rover) => ["MANUAL", "STEERING", "AUTO", "HOLD"],
        (AutopilotKind::Ardupilot, VehicleKind::Copter) => {
            ["STABILIZE", "ALT_HOLD", "LOITER", "BRAKE"]
        }
        (AutopilotKind::Px4, _) => ["MANUAL", "ALTCTL", "AUTO.LOITER", "AUTO.LOITER"],
    }
}

/// The autopilot's default RCMAP for rc_override.
fn default_channels(vehicle: VehicleKind) -> Vec<(u8, Axis)> {
    match vehicle {
        VehicleKind::Rover => vec![(1, Axis::Roll), (3, Axis::Throttle)],
        VehicleKind::Copter => vec![
            (1, Axis::Roll),
            (2, Axis::Pitch),
            (3, Axis::Throttle),
            (4, Axis::Yaw),
        ],
    }
}

impl MavlinkSettings {
    /// Validates, collecting every error with its key (relative to `[output]`).
    ///
    /// # Errors
    /// [`rove_core::Error::Config`] listing each invalid key.
    pub fn validate(&self) -> rove_core::Result<MavlinkConfig> {
        let mut errors = ConfigErrors::default();
        let connection = self
            .connection
            .clone()
            .unwrap_or_else(|| "tcpout:127.0.0.1:5760".into());
        let endpoint = Endpoint::parse(&connection).unwrap_or_else(|rule| {
            errors.add("connection", format!("\"{connection}\""), rule);
            Endpoint::TcpOut("127.0.0.1:5760".into())
        });
        let mavlink_version = self.mavlink_version.unwrap_or(2);
        let mavlink_version = errors.int("mavlink_version", mavlink_version, 1..=2, "");
        let id = |errors: &mut ConfigErrors, key: &str, v: Option<Int>| {
            errors.opt_int::<u8>(key, v, 0..=255, "")
        };
        let system_id = id(&mut errors, "system_id", self.system_id);
        let component_id = id(&mut errors, "component_id", self.component_id);
        let target_system = id(&mut errors, "target_system", self.target_system);
        let target_component = id(&mut errors, "target_component", self.target_component);
        let autopilot = self.autopilot.unwrap_or(AutopilotKind::Ardupilot);
        let vehicle = self.vehicle.unwrap_or(VehicleKind::Rover);
        let method = self.method.unwrap_or(match autopilot {
            AutopilotKind::Ardupilot => Method::RcOverride,
            AutopilotKind::Px4 => Method::ManualControl,
        });
        if autopilot == AutopilotKind::Px4 && method == Method::RcOverride {
            errors.add(
                "method",
                "\"rc_override\"",
                "PX4 ignores RC_CHANNELS_OVERRIDE: use \"manual_control\"",
            );
        }
        let rate_hz = self.rate_hz.unwrap_or(25.0);
        let rule = "must be 1..=200 (autopilots time an override out after ~1–3 s)";
        errors.float("rate_hz", rate_hz, 1.0..=200.0, rule);
        let link_timeout_ms = self.link_timeout_ms.unwrap_or(3000);
        let rule = " (the autopilot sends HEARTBEAT at 1 Hz)";
        let link_timeout =
            errors.int::<u64>("link_timeout_ms", link_timeout_ms, 500..=60_000, rule);
        let command_timeout_ms = self.command_timeout_ms.unwrap_or(300);
        let command_timeout =
            errors.int::<u64>("command_timeout_ms", command_timeout_ms, 20..=10_000, "");
        let retries = self.command_retries.unwrap_or(3);
        let command_retries = errors.int("command_retries", retries, 0..=20, "");
        let failsafe = self.failsafe.unwrap_or(match method {
            Method::RcOverride => FailsafeAction::Release,
            Method::ManualControl => FailsafeAction::Neutral,
        });
        if method == Method::ManualControl && failsafe == FailsafeAction::Release {
            errors.add(
                "failsafe",
                "\"release\"",
                "MANUAL_CONTROL has no release value: use \"neutral\" (the safe mode then holds \
                 the vehicle)",
            );
        }
        let version = mavlink_version.unwrap_or(2);
        let channels = self.validate_channels(method, vehicle, version, &mut errors);
        let manual_control = self.validate_manual_control(method, autopilot, vehicle, &mut errors);
        let modes = self.validate_modes(autopilot, vehicle, &mut errors);
        errors.into_result(MavlinkConfig {
            endpoint,
            mavlink_version: version,
            system_id: system_id.unwrap_or(255),
            component_id: component_id.unwrap_or(190),
            target_system,
            target_component,
            autopilot,
            vehicle,
            method,
            // A NaN rate was reported above; the placeholder keeps `from_secs_f64` from panicking.
            period: Duration::from_secs_f64(1.0 / rate_hz.clamp(1.0, 200.0).max(1.0)),
            link_timeout: Duration::from_millis(link_timeout.unwrap_or_default()),
            command_timeout: Duration::from_millis(command_timeout.unwrap_or_default()),
            command_retries: command_retries.unwrap_or_default(),
            failsafe,
            on_mode_refused: self.on_mode_refused.unwrap_or(OnModeRefused::Hold),
            channels,
            manual_control,
            modes,
        })
    }

    fn validate_channels(
        &self,
        method: Method,
        vehicle: VehicleKind,
        version: u8,
        errors: &mut ConfigErrors,
    ) -> Vec<ChannelConfig> {
        if method == Method::ManualControl {
            if !self.channels.is_empty() {
                errors.add(
                    "channels",
                    format!("{} tables", self.channels.len()),
                    "only used with method = \"rc_override\"; map MANUAL_CONTROL in \
                     [output.manual_control]",
                );
            }
            return Vec::new();
        }
        if self.channels.is_empty() {
            return default_channels(vehicle)
                .into_iter()
                .map(|(channel, axis)| ChannelConfig {
                    channel,
                    axis,
                    map: AxisMap::default(),
                })
                .collect();
        }
        let mut out: Vec<ChannelConfig> = Vec::new();
        let mut used = Unique::default();
        let (max_channel, rule) = match version {
            1 => (8, " with mavlink_version = 1 (9..=18 need MAVLink 2)"),
            _ => (18, ""),
        };
        for (i, c) in self.channels.iter().enumerate() {
            let owner = format!("channels[{i}]");
            let mut ce = ConfigErrors::default();
            c.unknown.check(
                &mut ce,
                &[&["channel", "axis"], keys_of::<AxisMapSettings>()],
            );
            let rc = ce.required("channel", &c.channel);
            let channel = rc.and_then(|ch| ce.int::<u8>("channel", ch, 1..=max_channel, rule));
            if let Some(first) = channel.and_then(|ch| used.claim(ch, &owner)) {
                let rule = format!("is already used by {first}");
                ce.add("channel", channel.unwrap_or_default(), rule);
            }
            if c.axis.is_none() {
                ce.absent("axis", "is required: throttle, roll, pitch or yaw");
            }
            let rule = "does not apply to MAVLink channels: the autopilot shapes its own inputs";
            ce.not_for("slew_us_per_s", c.map.slew_us_per_s, rule);
            let map = ce.section("", c.map.validate());
            errors.extend_within(&owner, ce);
            if let (Some(channel), Some(axis), Some(map)) = (channel, c.axis, map) {
                out.push(ChannelConfig { channel, axis, map });
            }
        }
        out
    }

    fn validate_manual_control(
        &self,
        method: Method,
        autopilot: AutopilotKind,
        vehicle: VehicleKind,
        errors: &mut ConfigErrors,
    ) -> ManualControlConfig {
        let s = self.manual_control.clone().unwrap_or_default();
        if method == Method::RcOverride && self.manual_control.is_some() {
            errors.add(
                "manual_control",
                "(table)",
                "only used with method = \"manual_control\"",
            );
        }
        let pick = |v: Option<AxisOrNone>, d: Axis| v.map_or(Some(d), AxisOrNone::axis);
        let mut reverse = [false; 4];
        for f in &s.reverse {
            let i = match f {
                ManualField::X => 0,
                ManualField::Y => 1,
                ManualField::Z => 2,
                ManualField::R => 3,
            };
            reverse[i] = true;
        }
        ManualControlConfig {
            fields: [
                pick(s.x, Axis::Pitch),
                pick(s.y, Axis::Roll),
                pick(s.z, Axis::Throttle),
                pick(s.r, Axis::Yaw),
            ],
            reverse,
            z_range: s.z_range.unwrap_or(match (autopilot, vehicle) {
                (AutopilotKind::Ardupilot, VehicleKind::Rover) => ZRange::Signed,
                _ => ZRange::Positive,
            }),
        }
    }

    fn validate_modes(
        &self,
        autopilot: AutopilotKind,
        vehicle: VehicleKind,
        errors: &mut ConfigErrors,
    ) -> ModesConfig {
        let s = self.modes.clone().unwrap_or_default();
        let table = mode_table(autopilot, vehicle);
        let defaults = default_modes(autopilot, vehicle);
        let mut resolve = |key: &str, written: &Option<AutopilotModeName>, default: &str| {
            let fallback = AutopilotMode {
                name: default.to_string(),
                custom_mode: table
                    .iter()
                    .find(|(n, _)| *n == default)
                    .map_or(0, |&(_, m)| m),
            };
            match written {
                None => fallback,
                Some(AutopilotModeName::Number(n)) => {
                    let key = format!("modes.{key}");
                    match errors.int(&key, *n, 0..=Int::from(u32::MAX), " (a custom_mode number)") {
                        Some(custom_mode) => AutopilotMode {
                            name: n.to_string(),
                            custom_mode,
                        },
                        None => fallback,
                    }
                }
                Some(AutopilotModeName::Name(name)) => {
                    let upper = name.to_ascii_uppercase();
                    match table.iter().find(|(n, _)| *n == upper) {
                        Some(&(n, m)) => AutopilotMode {
                            name: n.to_string(),
                            custom_mode: m,
                        },
                        None => {
                            let names: Vec<&str> = table.iter().map(|(n, _)| *n).collect();
                            errors.add(
                                format!("modes.{key}"),
                                format!("\"{name}\""),
                                format!(
                                    "is not a mode of {}: use one of {} or a custom_mode number",
                                    firmware_name(autopilot, vehicle),
                                    names.join(", ")
                                ),
                            );
                            fallback
                        }
                    }
                }
            }
        };
        let manual = resolve("manual", &s.manual, defaults[0]);
        let assisted = resolve("assisted", &s.assisted, defaults[1]);
        let auto = resolve("auto", &s.auto, defaults[2]);
        let safe = resolve("safe", &s.safe, defaults[3]);
        ModesConfig {
            driven: [manual, assisted, auto],
            safe,
            set_mode: s.set_mode.unwrap_or(true),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(text: &str) -> MavlinkSettings {
        match toml::from_str(text) {
            Ok(s) => s,
            Err(e) => panic!("test TOML does not parse: {e}"),
        }
    }

    fn errors_of(text: &str) -> Vec<String> {
        match parse(text).validate() {
            Ok(_) => Vec::new(),
            Err(e) => e.to_string().lines().map(str::to_string).collect(),
        }
    }

    #[test]
    fn defaults_drive_an_ardupilot_rover_on_sitl() {
        let c = parse("").validate().expect("defaults are valid");
        assert_eq!(c.endpoint, Endpoint::TcpOut("127.0.0.1:5760".into()));
        assert_eq!((c.system_id, c.component_id), (255, 190));
        assert_eq!(c.method, Method::RcOverride);
        assert_eq!(c.failsafe, FailsafeAction::Release);
        assert_eq!(c.period, Duration::from_millis(40));
        let map: Vec<(u8, Axis)> = c.channels.iter().map(|c| (c.channel, c.axis)).collect();
        assert_eq!(map, vec![(1, Axis::Roll), (3, Axis::Throttle)]);
        assert_eq!(c.modes.safe.name, "HOLD");
        assert_eq!(c.modes.safe.custom_mode, 4);
        assert_eq!(c.modes.for_mode(Mode::Manual).custom_mode, 0);
        assert_eq!(c.manual_control.z_range, ZRange::Signed);
        assert_eq!(c.on_mode_refused, OnModeRefused::Hold, "safe by default");
    }

    #[test]
    fn on_mode_refused_takes_hold_or_continue_only() {
        let c = parse("on_mode_refused = \"continue\"")
            .validate()
            .expect("valid");
        assert_eq!(c.on_mode_refused, OnModeRefused::Continue);
        let r: Result<MavlinkSettings, _> = toml::from_str("on_mode_refused = \"ignore\"");
        assert!(r.is_err_and(|e| e.to_string().contains("on_mode_refused")));
    }

    #[test]
    fn px4_defaults_to_manual_control_and_auto_loiter() {
        let c = parse("autopilot = \"px4\"\nvehicle = \"copter\"")
            .validate()
            .expect("valid");
        assert_eq!(c.method, Method::ManualControl);
        assert_eq!(c.failsafe, FailsafeAction::Neutral);
        assert!(c.channels.is_empty());
        assert_eq!(c.modes.safe.name, "AUTO.LOITER");
        assert_eq!(c.modes.safe.custom_mode, (4 << 16) | (3 << 24));
        assert_eq!(c.manual_control.z_range, ZRange::Positive);
    }

    #[test]
    fn copter_defaults_to_brake_and_four_channels() {
        let c = parse("vehicle = \"copter\"").validate().expect("valid");
        assert_eq!(c.modes.safe.name, "BRAKE");
        assert_eq!(c.modes.safe.custom_mode, 17);
        assert_eq!(c.channels.len(), 4);
    }

    #[test]
    fn endpoints_parse_and_reject_with_reasons() {
        assert_eq!(
            Endpoint::parse("udp:127.0.0.1:14550"),
            Ok(Endpoint::UdpIn("127.0.0.1:14550".into()))
        );
        assert_eq!(
            Endpoint::parse("tcp:127.0.0.1:5760"),
            Ok(Endpoint::TcpOut("127.0.0.1:5760".into()))
        );
        assert_eq!(
            Endpoint::parse("serial:/dev/ttyACM0:115200"),
            Ok(Endpoint::Serial {
                device: "/dev/ttyACM0".into(),
                baud: 115_200
            })
        );
        for bad in [
            "127.0.0.1:5760",
            "tcpout:127.0.0.1",
            "tcpout:127.0.0.1:0",
            "tcpout::5760",
            "serial:/dev/ttyS0",
            "serial:/dev/ttyS0:fast",
            "tcpin:127.0.0.1:5760",
        ] {
            assert!(Endpoint::parse(bad).is_err(), "{bad} accepted");
        }
    }

    #[test]
    fn every_bad_key_is_named() {
        let errors = errors_of(
            r#"
            connection = "tcpout:localhost"
            mavlink_version = 3
            rate_hz = 0.5
            link_timeout_ms = 10
            command_timeout_ms = 5
            command_retries = 99
            [[channels]]
            channel = 19
            axis = "roll"
            [[channels]]
            channel = 3
            [[channels]]
            channel = 3
            axis = "throttle"
            max_us = 1400
            [modes]
            safe = "PARK"
            "#,
        );
        let keys: Vec<&str> = errors
            .iter()
            .map(|e| e.split(" = ").next().unwrap_or(""))
            .collect();
        assert_eq!(
            keys,
            [
                "connection",
                "mavlink_version",
                "rate_hz",
                "link_timeout_ms",
                "command_timeout_ms",
                "command_retries",
                "channels[0].channel",
                "channels[1].axis",
                "channels[2].channel",
                "channels[2].centre_us",
                "modes.safe",
            ],
            "{errors:#?}"
        );
        assert!(errors[2].contains("must be 1..=200"), "{}", errors[2]);
        assert!(
            errors[8].contains("already used by channels[1]"),
            "{}",
            errors[8]
        );
        assert!(
            errors[10].contains("HOLD"),
            "lists the valid modes: {}",
            errors[10]
        );
    }

    #[test]
    fn method_specific_keys_are_checked() {
        let e = errors_of("autopilot = \"px4\"\nmethod = \"rc_override\"");
        assert!(e[0].starts_with("method = \"rc_override\""), "{e:?}");
        let e = errors_of("method = \"manual_control\"\nfailsafe = \"release\"");
        assert!(e[0].starts_with("failsafe = \"release\""), "{e:?}");
        let e = errors_of("mavlink_version = 1\n[[channels]]\nchannel = 9\naxis = \"yaw\"");
        assert!(e[0].contains("need MAVLink 2"), "{e:?}");
        let e = errors_of("[manual_control]\nz_range = \"signed\"");
        assert!(e[0].starts_with("manual_control"), "{e:?}");
    }

    #[test]
    fn modes_take_names_case_insensitively_or_numbers() {
        let c = parse("[modes]\nmanual = \"acro\"\nsafe = 11\nset_mode = false")
            .validate()
            .expect("valid");
        assert_eq!(c.modes.driven[0].name, "ACRO");
        assert_eq!(c.modes.driven[0].custom_mode, 1);
        assert_eq!(c.modes.safe.custom_mode, 11);
        assert!(!c.modes.set_mode);
    }

    #[test]
    fn unknown_keys_are_rejected() {
        let r: Result<MavlinkSettings, _> = toml::from_str("rate = 25");
        assert!(r.is_err());
        let e = errors_of("[[channels]]\nchanel = 1\naxis = \"roll\"\nslew_us_per_s = 5");
        assert!(
            e[0].starts_with("channels[0].chanel = 1: unknown key, expected one of `channel`"),
            "{e:?}"
        );
        assert!(
            e[2].starts_with("channels[0].slew_us_per_s = 5: does not apply"),
            "{e:?}"
        );
        // A number no integer type of the message holds is named with its key.
        let e = errors_of(
            "system_id = 300\n[modes]\nsafe = -1\n[[channels]]\nchannel = 300\naxis = \"roll\"",
        );
        assert!(
            e[0].starts_with("system_id = 300: must be 0..=255"),
            "{e:?}"
        );
        assert!(
            e[1].starts_with("channels[0].channel = 300: must be 1..=18"),
            "{e:?}"
        );
        assert!(
            e[2].starts_with("modes.safe = -1: must be 0..=4294967295"),
            "{e:?}"
        );
        // `invert` and `deadzone_pct` are older spellings of `reverse` and `deadband_pct`.
        let c =
            parse("[[channels]]\nchannel = 1\naxis = \"roll\"\ninvert = true\ndeadzone_pct = 5")
                .validate()
                .expect("aliases");
        assert_eq!(c.channels[0].map.map(i16::MAX), 1000);
    }
}
