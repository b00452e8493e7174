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

use rove_core::config::{Int, Unique, UnknownKeys};
use rove_core::error::ConfigErrors;
use rove_core::mapping::{Axis, AxisMap, AxisMapSettings};
use rove_core::msg::Mode;
use serde::{Deserialize, Serialize};
use std::time::Duration;

mod endpoint;
mod gcs;

pub use endpoint::Endpoint;
pub use gcs::{GcsConfig, StationConfig};

rove_core::config_types! {
    /// The `[output]` table of a MAVLink vehicle, as written (without the `adapter` key, which
    /// the gateway's tagged enum consumes). Every key is optional; docs/mavlink.md lists the
    /// defaults.
    pub table MavlinkSettings {
        connection: Option<String> => "`udpin:`, `udpout:`, `tcpout:HOST:PORT` (also `udp:` = \
            udpin and `tcp:` = tcpout), or `serial:DEVICE:BAUD`.",
        mavlink_version: Option<Int> => "2 or 1.",
        system_id: Option<Int> => "Our system id (ArduPilot's `MAV_GCS_SYSID` / `SYSID_MYGCS`).",
        component_id: Option<Int> => "Our component id.",
        target_system: Option<Int> => "The autopilot's system id (absent: the first heard).",
        target_component: Option<Int> => "The autopilot's component id (absent: discovered).",
        autopilot: Option<AutopilotKind> => "The firmware.",
        vehicle: Option<VehicleKind> => "Picks the default modes and stick conventions.",
        method: Option<Method> => "How sticks reach the autopilot.",
        rate_hz: Option<f64> => "Resend rate of the control message, Hz.",
        link_timeout_ms: Option<Int> => "No HEARTBEAT for this long → link reported down, ms.",
        command_timeout_ms: Option<Int> => "Wait for a mode command's COMMAND_ACK, ms.",
        command_retries: Option<Int> => "Resends of an unacknowledged mode command.",
        failsafe: Option<FailsafeAction> => "What the control message carries in failsafe.",
        on_mode_refused: Option<OnModeRefused> => "What to do when a driven mode is refused.",
        #[serde(default)] channels: Vec<ChannelSettings> => "rc_override channel map (RCMAP).",
        manual_control: Option<ManualControlSettings> => "`[output.manual_control]`.",
        modes: Option<ModeSettings> => "The autopilot mode for each rove mode and failsafe.",
        #[serde(default)] gcs: Vec<GcsSettings> => "`[[output.gcs]]`: ground stations rove \
            routes the autopilot's link to (docs/mavlink.md).",
    }

    /// One `[[output.gcs]]` table: a ground station (QGroundControl, Mission Planner) that
    /// reaches the autopilot through rove.
    pub settings GcsSettings {
        endpoint: Option<String> => "Where the ground station is: `udpout:HOST:PORT` (rove \
            sends first, as to QGroundControl's 14550), `udpin:HOST:PORT` (the station sends \
            first), `tcpin:HOST:PORT` (the station connects; one at a time) or \
            `tcpout:HOST:PORT`.",
        id: Option<Int> => "The station's device id: with it, the station is an operator of \
            the hierarchy (absent: its link is only routed).",
        system_id: Option<Int> => "The station's MAVLink system id (with `id`; QGroundControl: \
            Application Settings → MAVLink).",
        name: Option<String> => "Its name, shown as `NAME via MAVLink on vehicle N`.",
        level: Option<rove_core::hierarchy::Level> => "Its level (with `id`).",
        device_class: Option<rove_core::hierarchy::DeviceClass> => "Its device class (with `id`).",
        security: Option<std::path::PathBuf> => "Its `[security]` files, as an operator's (a \
            secured fleet: a certificate of its own).",
        #[serde(flatten)] unknown: UnknownKeys => "Keys nothing above took (see `validate`).",
    }

    /// Which autopilot firmware.
    pub keyword AutopilotKind {
        Ardupilot => "ArduPilot (Rover, Copter).",
        Px4 => "PX4.",
    }

    /// Which kind of vehicle the autopilot flies or drives.
    pub keyword VehicleKind {
        Rover => "A ground vehicle.",
        Copter => "A multirotor.",
    }

    /// How sticks reach the autopilot.
    pub keyword Method {
        #[serde(rename = "rc_override")] RcOverride => "RC_CHANNELS_OVERRIDE (ArduPilot).",
        #[serde(rename = "manual_control")] ManualControl => "MANUAL_CONTROL (PX4, ArduPilot).",
    }

    /// What the control message carries in failsafe.
    pub keyword FailsafeAction {
        Release => "Release the overridden channels (rc_override only).",
        Neutral => "Centred sticks, resent at rate.",
    }

    /// What to do when the autopilot refuses a driven mode.
    pub keyword OnModeRefused {
        Hold => "Stop driving (failsafe content, safe mode) until the operator's mode changes.",
        Continue => "Keep driving in whatever mode the autopilot is in.",
    }

    /// One `[[output.channels]]` table: an axis on an RC channel.
    pub settings ChannelSettings {
        channel: Option<Int> => "RC channel 1..=18 (9..=18 need MAVLink 2).",
        axis: Option<Axis> => "The axis it carries.",
        #[serde(flatten)] map: AxisMapSettings => "The mapping keys (no `slew_us_per_s`).",
        #[serde(flatten)] unknown: UnknownKeys => "Keys nothing above took (see `validate`).",
    }

    /// `[output.manual_control]`: which axis feeds each MANUAL_CONTROL field.
    pub table ManualControlSettings {
        x: Option<AxisOrNone> => "`x` (forward; absent: pitch).",
        y: Option<AxisOrNone> => "`y` (right; Rover steering; absent: roll).",
        z: Option<AxisOrNone> => "`z` (thrust; Rover throttle; absent: throttle).",
        r: Option<AxisOrNone> => "`r` (yaw; absent: yaw).",
        z_range: Option<ZRange> => "Range of z (absent: signed on ArduPilot Rover, else positive).",
        #[serde(default)] reverse: Vec<ManualField> => "Fields whose sign is flipped.",
    }

    /// An axis, or `"none"` for a MANUAL_CONTROL field sent as "invalid" (INT16_MAX).
    pub keyword AxisOrNone -> Option<Axis> {
        Throttle => "`MovementCommand::throttle`." = Some(Axis::Throttle),
        Roll => "`MovementCommand::roll`." = Some(Axis::Roll),
        Pitch => "`MovementCommand::pitch`." = Some(Axis::Pitch),
        Yaw => "`MovementCommand::yaw`." = Some(Axis::Yaw),
        None => "Not sent (INT16_MAX: invalid axis per the MAVLink spec)." = None,
    }

    /// A MANUAL_CONTROL stick field.
    pub keyword ManualField {
        X => "x.",
        Y => "y.",
        Z => "z.",
        R => "r.",
    }

    /// The range of MANUAL_CONTROL's z.
    pub keyword ZRange {
        Signed => "−1000..1000, 0 at stick centre.",
        Positive => "0..1000, 500 at stick centre.",
    }

    /// `[output.modes]`: a mode name from the autopilot's table or a raw `custom_mode` number.
    pub table ModeSettings {
        manual: Option<AutopilotModeName> => "For rove's MANUAL.",
        assisted: Option<AutopilotModeName> => "For rove's ASSISTED.",
        auto: Option<AutopilotModeName> => "For rove's AUTO.",
        safe: Option<AutopilotModeName> => "Entered when rove stops driving (failsafe).",
        set_mode: Option<bool> => "`false`: never send mode commands (the radio owns the mode).",
    }

    /// An autopilot mode as written: a name (`"HOLD"`, `"AUTO.LOITER"`) or a raw custom_mode
    /// (resolved into an [`AutopilotMode`]).
    #[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
    #[serde(untagged)]
    pub enum AutopilotModeName {
        Name => "A name from the autopilot's table." (String),
        Number => "A raw `custom_mode` (PX4: `main << 16 | sub << 24`), 0..=4294967295." (Int),
    }
}

rove_core::config_types! {
    /// A validated RC channel.
    #[derive(Debug, Clone, Copy, PartialEq)]
    pub struct ChannelConfig {
        channel: u8 => "1..=18.",
        axis: Axis => "Source axis.",
        map: AxisMap => "Axis → µs.",
    }

    /// Validated MANUAL_CONTROL settings.
    #[derive(Debug, Clone, Copy, PartialEq, Eq)]
    pub struct ManualControlConfig {
        fields: [Option<Axis>; 4] => "Source of x, y, z, r (None: invalid/unused).",
        reverse: [bool; 4] => "Sign flips for x, y, z, r.",
        z_range: ZRange => "The z convention.",
    }

    /// A resolved autopilot mode.
    #[derive(Debug, Clone, PartialEq, Eq)]
    pub struct AutopilotMode {
        name: String => "For logs (`HOLD`, or the number as written).",
        custom_mode: u32 => "The HEARTBEAT's custom_mode when the autopilot is in it.",
    }

    /// Validated modes.
    #[derive(Debug, Clone, PartialEq, Eq)]
    pub struct ModesConfig {
        driven: [AutopilotMode; 3] => "MANUAL, ASSISTED, AUTO in [`Mode::ALL`] order.",
        safe: AutopilotMode => "The failsafe mode.",
        set_mode: bool => "Whether mode commands are sent at all.",
    }
}

impl ModesConfig {
    /// The autopilot mode for rove's `mode`.
    pub fn for_mode(&self, mode: Mode) -> &AutopilotMode {
        let i = Mode::ALL.iter().position(|m| *m == mode);
        &self.driven[i.unwrap_or_default()]
    }
}

rove_core::config_types! {
    /// The validated `[output]` of a MAVLink vehicle.
    #[derive(Debug, Clone, PartialEq)]
    pub struct MavlinkConfig {
        endpoint: Endpoint => "Where the autopilot is.",
        mavlink_version: u8 => "1 or 2.",
        system_id: u8 => "Our ids.",
        component_id: u8 => "Our component id.",
        target_system: Option<u8> => "Fixed target system (None: discover).",
        target_component: Option<u8> => "Fixed target component (None: discover).",
        autopilot: AutopilotKind => "Firmware.",
        vehicle: VehicleKind => "Vehicle kind.",
        method: Method => "Control method.",
        period: Duration => "Resend period of the control message.",
        link_timeout: Duration => "Link-down threshold.",
        command_timeout: Duration => "Mode command ACK timeout.",
        command_retries: u32 => "Mode command resends.",
        failsafe: FailsafeAction => "Failsafe content.",
        on_mode_refused: OnModeRefused => "Reaction to a refused driven mode.",
        channels: Vec<ChannelConfig> => "rc_override channels (empty for manual_control).",
        manual_control: ManualControlConfig => "manual_control fields.",
        modes: ModesConfig => "Modes.",
        memory: Option<std::path::PathBuf> => "Where the link keeps what it learned about the \
            autopilot for `rove failsafe` ([`crate::memory`]); set by the gateway, not a key.",
        gcs: Vec<GcsConfig> => "The ground stations (the link routes them; some are operators).",
    }
}

/// A firmware and vehicle kind's name for messages, its modes as `NAME=custom_mode` (from its
/// Mode enum; PX4's as `NAME=main.sub`, see [`px4_custom_mode`]) and its default manual,
/// assisted, auto and safe modes.
fn firmware(
    autopilot: AutopilotKind,
    vehicle: VehicleKind,
) -> (&'static str, &'static str, [&'static str; 4]) {
    match (autopilot, vehicle) {
        (AutopilotKind::Ardupilot, VehicleKind::Rover) => (
            "ArduPilot Rover",
            "MANUAL=0 ACRO=1 STEERING=3 HOLD=4 LOITER=5 FOLLOW=6 SIMPLE=7 DOCK=8 CIRCLE=9 AUTO=10 \
             RTL=11 SMART_RTL=12 GUIDED=15",
            ["MANUAL", "STEERING", "AUTO", "HOLD"],
        ),
        (AutopilotKind::Ardupilot, VehicleKind::Copter) => (
            "ArduPilot Copter",
            "STABILIZE=0 ACRO=1 ALT_HOLD=2 AUTO=3 GUIDED=4 LOITER=5 RTL=6 CIRCLE=7 LAND=9 DRIFT=11 \
             SPORT=13 POSHOLD=16 BRAKE=17 SMART_RTL=21",
            ["STABILIZE", "ALT_HOLD", "LOITER", "BRAKE"],
        ),
        (AutopilotKind::Px4, _) => (
            "PX4",
            "MANUAL=1.0 ALTCTL=2.0 POSCTL=3.0 AUTO.READY=4.1 AUTO.TAKEOFF=4.2 AUTO.LOITER=4.3 \
             AUTO.MISSION=4.4 AUTO.RTL=4.5 AUTO.LAND=4.6 ACRO=5.0 OFFBOARD=6.0 STABILIZED=7.0",
            ["MANUAL", "ALTCTL", "AUTO.LOITER", "AUTO.LOITER"],
        ),
    }
}

/// PX4's custom_mode for a main and sub mode.
pub const fn px4_custom_mode(main: u8, sub: u8) -> u32 {
    ((main as u32) << 16) | ((sub as u32) << 24)
}

/// The mode table of a firmware and vehicle kind: (name, custom_mode).
pub fn mode_table(autopilot: AutopilotKind, vehicle: VehicleKind) -> Vec<(&'static str, u32)> {
    let mode = |(name, number): (&'static str, &str)| match number.split_once('.') {
        Some((main, sub)) => Some((name, px4_custom_mode(main.parse().ok()?, sub.parse().ok()?))),
        None => Some((name, number.parse().ok()?)),
    };
    let entries = (firmware(autopilot, vehicle).1.split_whitespace())
        .filter_map(|entry| entry.split_once('='));
    entries.filter_map(mode).collect()
}

impl MavlinkSettings {
    /// Validates, filling defaults into `self`, collecting every error with its key (relative
    /// to `[output]`).
    ///
    /// # Errors
    /// [`rove_core::Error::Config`] listing each invalid key.
    pub fn validate(&mut self) -> rove_core::Result<MavlinkConfig> {
        let mut errors = ConfigErrors::default();
        let connection = self
            .connection
            .get_or_insert_with(|| "tcpout:127.0.0.1:5760".into());
        let endpoint = match Endpoint::parse(connection) {
            Ok(Endpoint::TcpIn(_)) => {
                Err("tcpin: is for a ground station ([[output.gcs]]); reach \
                the autopilot with tcpout:, udpin:, udpout: or serial:"
                    .to_string())
            }
            other => other,
        };
        let endpoint = endpoint.unwrap_or_else(|rule| {
            errors.add("connection", format!("\"{connection}\""), rule);
            Endpoint::TcpOut("127.0.0.1:5760".into())
        });
        let version = *self.mavlink_version.get_or_insert(2);
        let version = errors
            .int("mavlink_version", version, 1..=2, "")
            .unwrap_or(2);
        let mut id = |key: &str, v: Option<Int>| errors.opt_int::<u8>(key, v, 0..=255, "");
        let system_id = id("system_id", Some(*self.system_id.get_or_insert(255)));
        let component_id = id("component_id", Some(*self.component_id.get_or_insert(190)));
        let target_system = id("target_system", self.target_system);
        let target_component = id("target_component", self.target_component);
        let autopilot = *self.autopilot.get_or_insert(AutopilotKind::Ardupilot);
        let vehicle = *self.vehicle.get_or_insert(VehicleKind::Rover);
        let method = *self.method.get_or_insert(match autopilot {
            AutopilotKind::Ardupilot => Method::RcOverride,
            AutopilotKind::Px4 => Method::ManualControl,
        });
        if autopilot == AutopilotKind::Px4 && method == Method::RcOverride {
            let rule = "PX4 ignores RC_CHANNELS_OVERRIDE: use \"manual_control\"";
            errors.add("method", "\"rc_override\"", rule);
        }
        let rate_hz = *self.rate_hz.get_or_insert(25.0);
        let rule = "must be 1..=200 (autopilots time an override out after ~1–3 s)";
        errors.float("rate_hz", rate_hz, 1.0..=200.0, rule);
        let link_timeout = *self.link_timeout_ms.get_or_insert(3000);
        let rule = " (the autopilot sends HEARTBEAT at 1 Hz)";
        let link_timeout = errors.int("link_timeout_ms", link_timeout, 500..=60_000, rule);
        let command_timeout = *self.command_timeout_ms.get_or_insert(300);
        let command_timeout = errors.int("command_timeout_ms", command_timeout, 20..=10_000, "");
        let retries = *self.command_retries.get_or_insert(3);
        let command_retries = errors.int("command_retries", retries, 0..=20, "");
        let failsafe = *self.failsafe.get_or_insert(match method {
            Method::RcOverride => FailsafeAction::Release,
            Method::ManualControl => FailsafeAction::Neutral,
        });
        if method == Method::ManualControl && failsafe == FailsafeAction::Release {
            let rule = "MANUAL_CONTROL has no release value: use \"neutral\" (the safe mode then \
                        holds the vehicle)";
            errors.add("failsafe", "\"release\"", rule);
        }
        let channels = self.validate_channels(method, vehicle, version, &mut errors);
        let manual_control = self.validate_manual_control(method, autopilot, vehicle, &mut errors);
        let modes = self.validate_modes(autopilot, vehicle, &mut errors);
        let gcs = self.validate_gcs(&endpoint, system_id, &mut errors);
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
            on_mode_refused: *self.on_mode_refused.get_or_insert(OnModeRefused::Hold),
            channels,
            manual_control,
            modes,
            memory: None,
            gcs,
        })
    }

    fn validate_channels(
        &mut self,
        method: Method,
        vehicle: VehicleKind,
        version: u8,
        errors: &mut ConfigErrors,
    ) -> Vec<ChannelConfig> {
        if method == Method::ManualControl {
            if !self.channels.is_empty() {
                let rule = "only used with method = \"rc_override\"; map MANUAL_CONTROL in \
                            [output.manual_control]";
                errors.add("channels", format!("{} tables", self.channels.len()), rule);
            }
            return Vec::new();
        }
        if self.channels.is_empty() {
            // The autopilot's default RCMAP.
            let rcmap: Vec<(u8, Axis)> = match vehicle {
                VehicleKind::Rover => vec![(1, Axis::Roll), (3, Axis::Throttle)],
                VehicleKind::Copter => (1..=4)
                    .zip([Axis::Roll, Axis::Pitch, Axis::Throttle, Axis::Yaw])
                    .collect(),
            };
            self.channels = (rcmap.into_iter())
                .map(|(channel, axis)| ChannelSettings {
                    channel: Some(channel.into()),
                    axis: Some(axis),
                    ..ChannelSettings::default()
                })
                .collect();
        }
        let mut used = Unique::default();
        let (max_channel, rule) = match version {
            1 => (8, " with mavlink_version = 1 (9..=18 need MAVLink 2)"),
            _ => (18, ""),
        };
        let mut out = Vec::new();
        for (i, c) in self.channels.iter().enumerate() {
            let owner = format!("channels[{i}]");
            let (channel, map) = errors.within(&owner, |ce| {
                c.unknown.check(ce, ChannelSettings::KNOWN);
                let channel = ce.req_int::<u8>("channel", c.channel, 1..=max_channel, rule);
                if let Some(first) = channel.and_then(|ch| used.claim(ch, &owner)) {
                    let rule = format!("is already used by {first}");
                    ce.add("channel", channel.unwrap_or_default(), rule);
                }
                if c.axis.is_none() {
                    ce.absent("axis", "is required: throttle, roll, pitch or yaw");
                }
                let rule =
                    "does not apply to MAVLink channels: the autopilot shapes its own inputs";
                ce.not_for("slew_us_per_s", c.map.slew_us_per_s, rule);
                (channel, ce.section("", c.map.validate()))
            });
            if let (Some(channel), Some(axis), Some(map)) = (channel, c.axis, map) {
                out.push(ChannelConfig { channel, axis, map });
            }
        }
        out
    }

    fn validate_manual_control(
        &mut self,
        method: Method,
        autopilot: AutopilotKind,
        vehicle: VehicleKind,
        errors: &mut ConfigErrors,
    ) -> ManualControlConfig {
        if method == Method::RcOverride && self.manual_control.is_some() {
            let rule = "only used with method = \"manual_control\"";
            errors.add("manual_control", "(table)", rule);
        }
        let mut s = self.manual_control.clone().unwrap_or_default();
        let pick = |v: &mut Option<AxisOrNone>, d| Option::from(*v.get_or_insert(d));
        let fields = [
            pick(&mut s.x, AxisOrNone::Pitch),
            pick(&mut s.y, AxisOrNone::Roll),
            pick(&mut s.z, AxisOrNone::Throttle),
            pick(&mut s.r, AxisOrNone::Yaw),
        ];
        let z_range = *s.z_range.get_or_insert(match (autopilot, vehicle) {
            (AutopilotKind::Ardupilot, VehicleKind::Rover) => ZRange::Signed,
            _ => ZRange::Positive,
        });
        use ManualField as F;
        let reverse = [F::X, F::Y, F::Z, F::R].map(|f| s.reverse.contains(&f));
        if method == Method::ManualControl {
            self.manual_control = Some(s);
        }
        ManualControlConfig {
            fields,
            reverse,
            z_range,
        }
    }

    fn validate_modes(
        &mut self,
        autopilot: AutopilotKind,
        vehicle: VehicleKind,
        errors: &mut ConfigErrors,
    ) -> ModesConfig {
        let s = self.modes.get_or_insert_default();
        let table = mode_table(autopilot, vehicle);
        let (firmware, _, defaults) = firmware(autopilot, vehicle);
        let mut resolve = |key: &str, written: &mut Option<AutopilotModeName>, default: &str| {
            let custom_mode = table.iter().find(|(n, _)| *n == default).map_or(0, |m| m.1);
            let name = default.to_string();
            let fallback = AutopilotMode { name, custom_mode };
            let key = format!("modes.{key}");
            match written.get_or_insert_with(|| AutopilotModeName::Name(default.into())) {
                AutopilotModeName::Number(n) => {
                    let unit = " (a custom_mode number)";
                    let custom_mode = errors.int(&key, *n, 0..=Int::from(u32::MAX), unit);
                    let name = n.to_string();
                    custom_mode.map_or(fallback, |custom_mode| AutopilotMode { name, custom_mode })
                }
                AutopilotModeName::Name(name) => {
                    let upper = name.to_ascii_uppercase();
                    if let Some(&(n, custom_mode)) = table.iter().find(|(n, _)| *n == upper) {
                        let name = n.to_string();
                        return AutopilotMode { name, custom_mode };
                    }
                    let names: Vec<&str> = table.iter().map(|(n, _)| *n).collect();
                    let names = names.join(", ");
                    let rule = format!(
                        "is not a mode of {firmware}: use one of {names} or a custom_mode number"
                    );
                    errors.add(key, format!("\"{name}\""), rule);
                    fallback
                }
            }
        };
        let manual = resolve("manual", &mut s.manual, defaults[0]);
        let assisted = resolve("assisted", &mut s.assisted, defaults[1]);
        let auto = resolve("auto", &mut s.auto, defaults[2]);
        let safe = resolve("safe", &mut s.safe, defaults[3]);
        ModesConfig {
            driven: [manual, assisted, auto],
            safe,
            set_mode: *s.set_mode.get_or_insert(true),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rove_core::hierarchy::{DeviceClass, Level};

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
    fn ground_stations_need_a_network_endpoint_of_their_own() {
        let c = parse(
            "[[gcs]]\nendpoint = \"udpout:127.0.0.1:14550\"\n\
             [[gcs]]\nendpoint = \"udpin:127.0.0.1:14551\"\n\
             [[gcs]]\nendpoint = \"tcpin:127.0.0.1:5770\"",
        )
        .validate()
        .expect("valid");
        let endpoints: Vec<&Endpoint> = c.gcs.iter().map(|g| &g.endpoint).collect();
        assert_eq!(
            endpoints,
            [
                &Endpoint::UdpOut("127.0.0.1:14550".into()),
                &Endpoint::UdpIn("127.0.0.1:14551".into()),
                &Endpoint::TcpIn("127.0.0.1:5770".into())
            ]
        );
        assert!(c.gcs.iter().all(|g| g.station.is_none()));
        assert!(parse("").validate().expect("valid").gcs.is_empty());
        let cases = [
            ("[[gcs]]\nport = 14550", "gcs[0].endpoint"),
            (
                "[[gcs]]\nendpoint = \"serial:/dev/ttyUSB0:57600\"",
                "a serial port",
            ),
            (
                "[[gcs]]\nendpoint = \"tcpout:127.0.0.1:5760\"",
                "the autopilot's connection",
            ),
            (
                "[[gcs]]\nendpoint = \"udpout:h:1\"\n[[gcs]]\nendpoint = \"udpout:h:1\"",
                "is gcs[0]'s too",
            ),
            ("[[gcs]]\nendpoint = \"udpout:h\"", "needs HOST:PORT"),
            (
                "connection = \"tcpin:127.0.0.1:5760\"",
                "is for a ground station",
            ),
        ];
        for (toml, says) in cases {
            let errors = errors_of(toml).join("\n");
            assert!(errors.contains(says), "{toml}: {errors}");
        }
        assert!(
            errors_of("[[gcs]]\nport = 14550")
                .join("\n")
                .contains("gcs[0].port")
        );
    }

    #[test]
    fn a_ground_station_with_an_id_is_an_operator_with_a_system_id_of_its_own() {
        let c = parse(
            "[[gcs]]\nendpoint = \"udpout:127.0.0.1:14550\"\nid = 50\nsystem_id = 250\n\
             name = \"QGC\"\nlevel = \"remote\"",
        )
        .validate()
        .expect("valid");
        let s = c.gcs[0].station.as_ref().expect("an operator");
        assert_eq!((s.id, s.system_id, s.name.as_str()), (50, 250, "QGC"));
        assert_eq!((s.level, s.class), (Level::Remote, DeviceClass::Desktop));
        let cases = [
            ("id = 50", "gcs[0].system_id"),
            ("id = 50\nsystem_id = 255", "rove's own system id"),
            ("id = 50\nsystem_id = 0", "must be 1..=255"),
            ("system_id = 250", "needs `id`"),
            ("level = \"remote\"", "needs `id`"),
        ];
        for (keys, says) in cases {
            let toml = format!("[[gcs]]\nendpoint = \"udpout:127.0.0.1:14550\"\n{keys}");
            let errors = errors_of(&toml).join("\n");
            assert!(errors.contains(says), "{keys}: {errors}");
        }
        let twice = "[[gcs]]\nendpoint = \"udpout:h:1\"\nid = 50\nsystem_id = 250\n\
                     [[gcs]]\nendpoint = \"udpout:h:2\"\nid = 50\nsystem_id = 251";
        assert!(errors_of(twice).join("\n").contains("is gcs[0]'s too"));
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
            Endpoint::parse("tcpin:127.0.0.1:5770"),
            Ok(Endpoint::TcpIn("127.0.0.1:5770".into()))
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
            "tcpin:127.0.0.1",
            "ftp:127.0.0.1:21",
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
