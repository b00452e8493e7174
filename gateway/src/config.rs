//! Configuration files: one TOML file per device (docs/design.md §7).
//!
//! Two stages: the raw serde structs below reject unknown keys and only parse; `validate()`
//! turns them into [`VehicleConfig`] / [`OperatorConfig`], collecting every problem. Every error
//! names the file, the line and the key: `vehicle.toml:7: vehicle.command_timeout_ms = 0: …`.
//! An absent key takes its default quietly; a present but invalid key is an error.

use anyhow::{Context, anyhow};
use rove_core::arbiter::ArbiterConfig;
use rove_core::config::{ABSENT, Int, Unique};
use rove_core::error::ConfigErrors;
use rove_core::handover::{HandoverConfig, HandoverSettings};
use rove_core::hierarchy::{DeviceClass, Hierarchy, HierarchyTable, Level, Strength};
use rove_core::msg::{DeviceId, Mode, MovementCommand};
use rove_core::trust::{Access, Grant, TrustConfig};
use rove_core::watchdog::CommandTimeout;
use serde::{Deserialize, Serialize};
use std::net::Ipv4Addr;
use std::path::Path;
#[cfg(test)]
use std::path::PathBuf;
use std::time::Duration;

rove_core::config_types! {
    /// `[device]`.
    pub table DeviceSection {
        id: DeviceId => "This device's id on the network; unique per device.",
        name: Option<String> => "Human-readable name (absent: `rove-<id>`).",
    }

    /// `[network]`.
    pub table NetworkSection {
        domain_id: Option<Int> => "DDS domain id (absent: 0).",
        interfaces: Option<Vec<Ipv4Addr>> => "IPv4 addresses of the interfaces DDS may use \
            (absent: loopback only).",
        heartbeat_ms: Option<Int> => "How often the role checks its state (`STATUS=`, \
            VehicleStatus, DeviceInfo changes), ms (absent: 500). DeviceInfo goes out on a change \
            and otherwise every 5 s.",
        presence_ms: Option<Int> => "SPDP announcement period, ms, 250 to 500 (absent: 250). \
            The participant lease announced is four periods: a crashed device leaves every list \
            within five periods. The announcements also assert the DeviceInfo writer's 1 s \
            liveliness for foreign readers (docs/design.md, \"Fleet scale\").",
    }

    /// `[log]`.
    pub table LogSection {
        level: Option<String> => "A level (`error`, `warn`, `info`, `debug`, `trace`) or tracing \
            filter directives such as `\"info,rove_gateway=debug\"` (absent: `info`). rustdds \
            stays at `warn` unless a directive names it (its `info` is very chatty). `RUST_LOG`, \
            when set, overrides all of this.",
    }

    /// `[vehicle]`.
    pub table VehicleSection {
        command_timeout_ms: Option<Int> => "Owner silence before re-arbitration (absent: 100).",
        output_deadline_ms: Option<Int> => "A device call (a PWM write, a MAVLink send) running \
            longer counts as a hung output, ms (absent: 50).",
        output_hung_limit_ms: Option<Int> => "How long an output may stay hung before the \
            watchdog keep-alives stop and systemd restarts the unit, ms (absent: 2000).",
        battery_low_pct: Option<Int> => "At or below this battery level (percent, as the \
            output's device reports it: an autopilot's SYS_STATUS) every console that sees the \
            vehicle warns (absent: 25).",
    }

    /// `[security]`: join as an authenticated participant (DDS Security, docs/security.md).
    pub table SecuritySection {
        dir: std::path::PathBuf => "This device's directory from `rove keys add` (relative \
            paths: to the config file): identity CA, certificate, private key, permissions CA, \
            governance and permissions.",
    }

    /// `[access]`: who may drive this vehicle. Absent: any id, at any strength inside the
    /// hierarchy (docs/design.md §4b).
    pub table AccessSection {
        #[serde(default)] operators: Vec<Grant> => "The operators allowed to drive, each with \
            the highest level and device class it may claim (`[[access.operators]]`).",
    }

    /// `[output]`: `adapter` names the output adapter; the other keys are that adapter's.
    ///
    /// Files are not read through this tagged enum (serde buffers a tagged table and loses
    /// every line inside it) but through `parse_vehicle`; it remains for errors about
    /// `adapter` itself.
    #[derive(Debug, Clone, Serialize, Deserialize)]
    #[serde(tag = "adapter", rename_all = "lowercase")]
    pub enum OutputSection {
        Sim => "Records outputs in memory, for tests, demos and benchmarks (`--record` writes \
            them out)." (SimSection),
        Pwm => "A PWM vehicle described by its channel list (a new vehicle type needs only \
            TOML)." (Box<rove_pwm::PwmVehicleSettings>),
        Eyedrive => "The Eyedrive UGV: steering and throttle servos."
            (Box<rove_eyedrive::EyedriveSettings>),
        Naza => "The DJI Naza-M multirotor autopilot: A/E/T/R/U channels."
            (Box<rove_naza::NazaSettings>),
        Mavlink => "An ArduPilot or PX4 autopilot over MAVLink (RC override or MANUAL_CONTROL)."
            (Box<rove_mavlink::MavlinkSettings>),
        Can => "CAN servos and ESCs: raw frames defined by config, DroneCAN actuator commands."
            (Box<rove_can::CanSettings>),
    }

    /// `[output] adapter = "sim"` takes no other keys.
    #[derive(Debug, Clone, Default, Serialize, Deserialize)]
    #[serde(deny_unknown_fields)]
    pub struct SimSection {}

    /// A validated output adapter choice.
    #[derive(Debug, Clone)]
    pub enum OutputConfig {
        Sim => "The core's recording sim output.",
        Pwm => "A config-defined PWM vehicle." (rove_pwm::PwmVehicleConfig),
        Eyedrive => "The Eyedrive preset (a PWM vehicle underneath)." (rove_pwm::PwmVehicleConfig),
        Naza => "The Naza-M." (rove_naza::NazaConfig),
        Mavlink => "A MAVLink autopilot." (Box<rove_mavlink::MavlinkConfig>),
        Can => "A CAN bus." (Box<rove_can::CanConfig>),
    }
}

impl OutputSection {
    fn validate(&mut self, errors: &mut ConfigErrors) -> OutputConfig {
        let config = match self {
            OutputSection::Sim(_) => Ok(OutputConfig::Sim),
            OutputSection::Pwm(s) => s.validate().map(OutputConfig::Pwm),
            OutputSection::Eyedrive(s) => s.validate().map(OutputConfig::Eyedrive),
            OutputSection::Naza(s) => s.validate().map(OutputConfig::Naza),
            OutputSection::Mavlink(s) => s.validate().map(|c| OutputConfig::Mavlink(Box::new(c))),
            OutputSection::Can(s) => s.validate().map(|c| OutputConfig::Can(Box::new(c))),
        };
        errors
            .section("output", config)
            .unwrap_or(OutputConfig::Sim)
    }
}

/// Reads a vehicle file in two steps so that errors inside `[output]` keep their lines: first
/// `adapter`, then the same text, with the `adapter` key blanked (every byte offset and line
/// unchanged), as that adapter's settings. An unknown or missing adapter is reported by the
/// tagged [`OutputSection`].
fn parse_vehicle(path: &Path, text: &str) -> anyhow::Result<RawVehicle<OutputSection>> {
    #[derive(Deserialize)]
    struct Probe {
        output: Option<ProbeOutput>,
    }
    #[derive(Deserialize)]
    struct ProbeOutput {
        adapter: Option<toml::Spanned<String>>,
    }
    fn read<T: for<'de> Deserialize<'de>>(
        path: &Path,
        text: &str,
        wrap: fn(T) -> OutputSection,
    ) -> anyhow::Result<RawVehicle<OutputSection>> {
        let file: RawVehicle<T> = parse(path, text)?;
        Ok(RawVehicle {
            device: file.device,
            network: file.network,
            log: file.log,
            vehicle: file.vehicle,
            hierarchy: file.hierarchy,
            access: file.access,
            security: file.security,
            output: wrap(file.output),
        })
    }
    let probe: Probe = parse(path, text)?;
    let Some(adapter) = probe.output.and_then(|o| o.adapter) else {
        return parse(path, text);
    };
    let blanked = blank_key_value(text, adapter.span());
    match adapter.get_ref().as_str() {
        "sim" => read(path, &blanked, OutputSection::Sim),
        "pwm" => read(path, &blanked, |s| OutputSection::Pwm(Box::new(s))),
        "eyedrive" => read(path, &blanked, |s| OutputSection::Eyedrive(Box::new(s))),
        "naza" => read(path, &blanked, |s| OutputSection::Naza(Box::new(s))),
        "mavlink" => read(path, &blanked, |s| OutputSection::Mavlink(Box::new(s))),
        "can" => read(path, &blanked, |s| OutputSection::Can(Box::new(s))),
        _ => parse(path, text),
    }
}

/// `text` with the key/value pair whose value spans `value` replaced by spaces (newlines
/// kept), together with the comma that separates it in an inline table.
fn blank_key_value(text: &str, value: std::ops::Range<usize>) -> String {
    let bytes = text.as_bytes();
    let is_key = |b: u8| b.is_ascii_alphanumeric() || b"_-.\"' \t=".contains(&b);
    let mut start = value.start.min(bytes.len());
    while start > 0 && is_key(bytes[start - 1]) {
        start -= 1;
    }
    let mut end = value.end.min(bytes.len());
    let after = text[end..].trim_start_matches([' ', '\t']);
    if after.starts_with(',') {
        end = text.len() - after.len() + 1;
    } else if text[..start].trim_end_matches([' ', '\t']).ends_with(',') {
        start = text[..start].trim_end_matches([' ', '\t']).len() - 1;
    }
    // One space per byte (newlines kept), so no offset or line after the blank moves.
    let blank: String = (text[start..end].chars())
        .flat_map(|c| std::iter::repeat_n(if c == '\n' { c } else { ' ' }, c.len_utf8()))
        .collect();
    format!("{}{blank}{}", &text[..start], &text[end..])
}

rove_core::config_types! {
    /// A vehicle's file as written. `[output]` is `O`: the tagged [`OutputSection`], or one
    /// adapter's settings while `parse_vehicle` reads it.
    pub table RawVehicle<O> {
        device: DeviceSection => "`[device]`.",
        #[serde(default)] network: NetworkSection => "`[network]`.",
        #[serde(default)] log: LogSection => "`[log]`.",
        #[serde(default)] vehicle: VehicleSection => "`[vehicle]`.",
        #[serde(default)] hierarchy: HierarchyTable => "`[hierarchy]`: the strengths operators \
            may have (absent: docs/design.md §3).",
        access: Option<AccessSection> => "`[access]`: who may drive.",
        security: Option<SecuritySection> => "`[security]`.",
        output: O => "`[output]`.",
    }

    /// `[operator]`.
    #[derive(Debug, Clone, Serialize, Deserialize)]
    #[serde(deny_unknown_fields)]
    pub struct OperatorSection {
        level: Level => "Where the operator is: mobile, stationary or remote.",
        device_class: DeviceClass => "The device: desktop, laptop, tablet or phone.",
        offset: Option<Int> => "Fine offset 0..=9 within the rank (absent: 0).",
        stream_hz: Option<Int> => "Keep-alive stream rate while driving, Hz (absent: 50).",
        #[serde(default)] drive: Vec<DeviceId> => "Vehicles to drive from the start.",
    }

    /// `[input]`: `source` picks constant sticks, an evdev joystick or keyboard, or a recorded
    /// event stream (the last three are rove-inputs' keys, see `inputs/README.md`).
    #[derive(Debug, Clone, Serialize, Deserialize)]
    #[serde(deny_unknown_fields, tag = "source", rename_all = "lowercase")]
    pub enum InputSection {
        Constant => "Constant stick values." (ConstantInput),
        Joystick => "An evdev joystick or gamepad." (Box<rove_inputs::InputSettings>),
        Keyboard => "An evdev keyboard." (Box<rove_inputs::InputSettings>),
        Replay => "A recorded event stream (tests, demos, benchmarks)."
            (Box<rove_inputs::InputSettings>),
    }

    /// A validated `[input]`.
    #[derive(Debug, Clone)]
    pub enum InputChoice {
        Constant => "The same sticks and mode for ever (no `[input]`: centred, MANUAL); driving \
            starts at once." (MovementCommand, Mode),
        Device => "A device or recording; driving waits until it reports live, centred sticks."
            (Box<rove_inputs::InputConfig>),
    }

    /// `[input] source = "constant"`: the same sticks and mode for ever.
    pub table ConstantInput {
        #[serde(default)] throttle: Int => "Throttle axis (absent: 0).",
        #[serde(default)] roll: Int => "Roll axis (absent: 0).",
        #[serde(default)] pitch: Int => "Pitch axis (absent: 0).",
        #[serde(default)] yaw: Int => "Yaw axis (absent: 0).",
        mode: Option<ModeName> => "Mode (absent: manual).",
    }

    /// Mode names in config.
    pub keyword ModeName -> Mode {
        Manual => "MANUAL." = Mode::Manual,
        Assisted => "ASSISTED." = Mode::Assisted,
        Auto => "AUTO." = Mode::Auto,
    }
}

rove_core::config_types! {
    /// An operator's file as written.
    #[derive(Debug, Clone, Serialize, Deserialize)]
    #[serde(deny_unknown_fields)]
    pub struct RawOperator {
        device: DeviceSection => "`[device]`.",
        #[serde(default)] network: NetworkSection => "`[network]`.",
        #[serde(default)] log: LogSection => "`[log]`.",
        operator: OperatorSection => "`[operator]`.",
        #[serde(default)] hierarchy: HierarchyTable => "`[hierarchy]`: a custom strength table \
            (absent: docs/design.md §3).",
        #[serde(default)] handover: HandoverSettings => "`[handover]`.",
        input: Option<InputSection> => "`[input]` (absent: centred sticks).",
        #[serde(default)] console: ConsoleSection => "`[console]`.",
        security: Option<SecuritySection> => "`[security]`.",
        web: Option<WebSection> => "`[web]`: the browser operator console (docs/web.md).",
    }

    /// `[web]`: an HTTPS page that phones and tablets pair with and drive from (docs/web.md).
    pub table WebSection {
        listen: String => "Address and port of the HTTPS server, such as \"0.0.0.0:8443\".",
        certificate: Option<std::path::PathBuf> => "PEM certificate chain, with `key`: loaded if \
            both files exist, made (self-signed) and written there if neither does (absent: a new \
            self-signed certificate at every start).",
        key: Option<std::path::PathBuf> => "PEM private key of `certificate`.",
        session_s: Option<Int> => "How long a paired browser stays paired, seconds (absent: \
            43200, 12 hours).",
        #[serde(default)] device: Vec<WebDeviceSection> => "`[[web.device]]`: the operator \
            devices browsers pair as, one browser each.",
    }

    /// `[[web.device]]`: one operator device a browser pairs as.
    pub table WebDeviceSection {
        id: DeviceId => "Its device id (unique in the fleet).",
        name: Option<String> => "Its name (absent: web-ID).",
        level: Option<Level> => "Hierarchy level (absent: mobile).",
        device_class: Option<DeviceClass> => "Device class (absent: phone).",
        offset: Option<Int> => "Fine offset 0..=9 within the rank (absent: 0).",
        #[serde(default)] drive: Vec<DeviceId> => "Vehicles it drives while a finger is on a \
            stick (or the gamepad's deadman is held).",
        security: Option<std::path::PathBuf> => "DDS Security directory of this device \
            (`rove keys`); required when the operator has `[security]`.",
    }

    /// `[console]`: the local API for other front ends (docs/api.md).
    pub table ConsoleSection {
        api_socket: Option<std::path::PathBuf> => "Unix socket path of the local API, created with \
            mode 0660 (absent: no API).",
    }

    /// Validated identity and network settings, shared by both roles.
    #[derive(Debug, Clone, PartialEq, Eq)]
    pub struct Common {
        id: DeviceId => "Device id.",
        name: String => "Device name.",
        domain_id: u16 => "DDS domain.",
        interfaces: Vec<Ipv4Addr> => "Interfaces DDS is confined to.",
        heartbeat: Duration => "Presence heartbeat period.",
        presence: Duration => "`[network] presence_ms`: the SPDP period.",
        log_filter: Option<String> => "The log filter from `[log] level`, if any.",
        security: Option<std::path::PathBuf> => "`[security] dir`: join authenticated, with the \
            DDS Security files there.",
    }
}

impl Common {
    /// Makes a relative `[security] dir` relative to the config file's directory.
    pub fn resolve_paths(&mut self, config_path: &Path) {
        let dir = config_path.parent().unwrap_or(Path::new("."));
        // Joined to an absolute path, `dir` is dropped.
        if let Some(security) = &mut self.security {
            *security = dir.join(&*security);
        }
    }

    /// How long device ids stay pinned to their participants: until one heartbeat after the
    /// participant left the domain (its lease ran out or it said goodbye), and at most three
    /// DeviceInfo refreshes after the device's last message (a backstop, as in the lists).
    pub fn trust(&self) -> TrustConfig {
        TrustConfig {
            hold: crate::dds::OFFLINE_AFTER,
            grace: self.heartbeat,
            ..TrustConfig::default()
        }
    }
}

rove_core::config_types! {
    /// A validated vehicle configuration.
    #[derive(Debug, Clone)]
    pub struct VehicleConfig {
        common: Common => "Identity and network.",
        arbiter: ArbiterConfig => "Arbiter settings.",
        access: Access => "The ids and strengths this vehicle believes.",
        output: OutputConfig => "Output adapter.",
        output_deadline: Duration => "`[vehicle] output_deadline_ms`.",
        output_hung_limit: Duration => "`[vehicle] output_hung_limit_ms`.",
        battery_low_pct: u8 => "`[vehicle] battery_low_pct`.",
    }

    /// A validated operator configuration.
    #[derive(Debug, Clone)]
    pub struct OperatorConfig {
        common: Common => "Identity and network.",
        level: Level => "Rank in the hierarchy.",
        device_class: DeviceClass => "Device class.",
        strength: Strength => "Ownership strength of the regular writer.",
        stream_period: Duration => "Keep-alive period.",
        drive: Vec<DeviceId> => "Vehicles driven from the start.",
        handover: HandoverConfig => "Active-handover settings.",
        input: InputChoice => "Where stick values and mode come from.",
        api_socket: Option<std::path::PathBuf> => "The local API's socket, if any.",
        web: Option<WebConfig> => "The browser console, if any.",
    }

    /// A validated `[web]`.
    #[derive(Debug, Clone)]
    pub struct WebConfig {
        listen: std::net::SocketAddr => "Where the HTTPS server listens.",
        certificate: Option<(std::path::PathBuf, std::path::PathBuf)> => "Certificate and key \
            files (made if both are missing), or none: self-signed in memory.",
        session: Duration => "How long a pairing lasts.",
        devices: Vec<OperatorConfig> => "One operator per `[[web.device]]`: the host's network \
            and handover settings with the device's identity, strength and `drive`.",
    }
}

/// Reads and validates a vehicle config.
///
/// # Errors
/// The file cannot be read, is not valid TOML, has unknown keys, or has invalid values; the
/// message names the file, line and key.
pub fn load_vehicle(path: &Path) -> anyhow::Result<VehicleConfig> {
    let text = read(path)?;
    let mut raw = parse_vehicle(path, &text)?;
    let mut config = raw.validate().map_err(|e| located(path, &text, e))?;
    config.common.resolve_paths(path);
    Ok(config)
}

/// Reads and validates an operator config.
///
/// # Errors
/// As [`load_vehicle`].
pub fn load_operator(path: &Path) -> anyhow::Result<OperatorConfig> {
    let text = read(path)?;
    let mut raw: RawOperator = parse(path, &text)?;
    let mut config = raw.validate().map_err(|e| located(path, &text, e))?;
    config.resolve_paths(path);
    Ok(config)
}

impl OperatorConfig {
    /// Makes relative paths in the config (a replay `file`) relative to the file's directory.
    pub fn resolve_paths(&mut self, config_path: &Path) {
        self.common.resolve_paths(config_path);
        let dir = config_path.parent().unwrap_or(Path::new("."));
        if let InputChoice::Device(input) = &mut self.input {
            input.resolve_relative_to(dir);
        }
        if let Some(socket) = &mut self.api_socket {
            *socket = dir.join(&*socket);
        }
        if let Some(web) = &mut self.web {
            if let Some((cert, key)) = &mut web.certificate {
                *cert = dir.join(&*cert);
                *key = dir.join(&*key);
            }
            for device in &mut web.devices {
                device.common.resolve_paths(config_path);
            }
        }
    }
}

rove_core::config_types! {
    /// A site bridge's file as written (`rove bridge`, docs/remote.md).
    pub table RawBridge {
        site: SiteSection => "`[site]`.",
        #[serde(default)] network: NetworkSection => "`[network]`: the site's DDS network.",
        #[serde(default)] log: LogSection => "`[log]`.",
        #[serde(default)] hierarchy: HierarchyTable => "`[hierarchy]`: the strengths this \
            site's vehicles believe (absent: docs/design.md §3); another site's operators are \
            taken at most at its `level`.",
        zenoh: ZenohSection => "`[zenoh]`: the link to other sites.",
        security: Option<SecuritySection> => "`[security]`: a secured site (DDS Security):             `dir` is the site's directory from `rove keys site --proxies` (`DIR/site-NAME`).",
    }

    /// `[site]`.
    pub table SiteSection {
        name: String => "This site's name: lowercase letters, digits and '-' (its \
            certificate's common name is `rove-site-NAME`, from `rove keys site`).",
    }

    /// `[zenoh]`: the link between sites, Zenoh over mutual TLS.
    pub table ZenohSection {
        #[serde(default)] listen: Vec<String> => "Endpoints other sites connect to, such as \
            \"tls/192.0.2.1:7447\" (absent: none).",
        #[serde(default)] connect: Vec<String> => "Endpoints of other sites' bridges to connect \
            to (absent: none). At least one of `listen` and `connect`.",
        ca: std::path::PathBuf => "The fleet's CA certificate (`ca.cert.pem`): a site's \
            certificate must be signed by it.",
        certificate: std::path::PathBuf => "This site's certificate (`rove keys site`).",
        key: std::path::PathBuf => "This site's private key.",
        lease_ms: Option<Int> => "How long a silent link stays up, ms, 1000 to 60000 (absent: \
            3000). The vehicles' command timeout, not this, stops them on a cut link; when the \
            lease runs out the other site's devices leave this site's lists.",
        #[serde(default)] site: Vec<PeerSection> => "`[[zenoh.site]]`: the sites this one \
            meets. Any other is refused.",
    }

    /// `[[zenoh.site]]`: another site.
    pub table PeerSection {
        name: String => "Its name (its certificate's common name is `rove-site-NAME`).",
        #[serde(default)] ids: Vec<DeviceId> => "The device ids it may speak for: its \
            operators, and its vehicles this site may drive.",
        #[serde(default)] offer: Vec<DeviceId> => "This site's vehicles it may see and drive \
            (absent: none).",
        level: Option<Level> => "The highest hierarchy level its operators may claim here \
            (absent: remote); a stronger claim is taken at this level.",
    }

    /// A validated `[zenoh]`.
    #[derive(Debug, Clone)]
    pub struct ZenohLink {
        listen: Vec<String> => "Endpoints listened on.",
        connect: Vec<String> => "Endpoints connected to.",
        ca: std::path::PathBuf => "The fleet's CA.",
        certificate: std::path::PathBuf => "This site's certificate.",
        key: std::path::PathBuf => "This site's key.",
        lease: Duration => "The link's lease.",
    }

    /// A validated bridge configuration.
    #[derive(Debug, Clone)]
    pub struct BridgeConfig {
        common: Common => "The site's DDS network (`id` 0: the bridge is no device).",
        policy: rove_core::site::Policy => "This site, and what other sites may say here.",
        link: ZenohLink => "The link.",
    }
}

/// Reads and validates a bridge config.
///
/// # Errors
/// As [`load_vehicle`].
pub fn load_bridge(path: &Path) -> anyhow::Result<BridgeConfig> {
    let text = read(path)?;
    let mut raw: RawBridge = parse(path, &text)?;
    let mut config = raw.validate().map_err(|e| located(path, &text, e))?;
    config.resolve_paths(path);
    Ok(config)
}

impl BridgeConfig {
    /// Makes the link's files relative to the config file's directory.
    pub fn resolve_paths(&mut self, config_path: &Path) {
        self.common.resolve_paths(config_path);
        let dir = config_path.parent().unwrap_or(Path::new("."));
        let link = &mut self.link;
        for file in [&mut link.ca, &mut link.certificate, &mut link.key] {
            *file = dir.join(&*file);
        }
    }
}

impl ZenohLink {
    /// Whether this process can read the link's certificate files (the bridge checks at start,
    /// `check-config` does not: an installed config names files made later).
    ///
    /// # Errors
    /// The first file that cannot be opened, with its `[zenoh]` key and the cause.
    pub fn check_files(&self) -> anyhow::Result<()> {
        for (key, file) in [
            ("ca", &self.ca),
            ("certificate", &self.certificate),
            ("key", &self.key),
        ] {
            let readable = std::fs::File::open(file).and_then(|f| {
                if f.metadata()?.is_file() {
                    Ok(())
                } else {
                    Err(std::io::Error::other("not a file"))
                }
            });
            readable.map_err(|e| {
                anyhow::anyhow!(
                    "[zenoh] {key} = {}: {e} (a site's files come from `rove keys site`, and \
                     must be readable by the user the bridge runs as)",
                    file.display()
                )
            })?;
        }
        Ok(())
    }
}

impl RawBridge {
    /// Validates, filling defaults into `self`.
    ///
    /// # Errors
    /// [`rove_core::Error::Config`] listing every invalid key.
    pub fn validate(&mut self) -> rove_core::Result<BridgeConfig> {
        use rove_core::site::{Peer, Policy, SiteName};
        let mut errors = ConfigErrors::default();
        let name = |errors: &mut ConfigErrors, key: &str, name: &str| {
            SiteName::new(name)
                .map_err(|rule| errors.add(key, format!("{name:?}"), rule))
                .ok()
        };
        let me = name(&mut errors, "site.name", &self.site.name);
        let mut device = DeviceSection {
            id: 1,
            name: Some(format!("bridge-{}", self.site.name)),
        };
        let mut common = validate_common(&mut device, &mut self.network, &self.log, &mut errors);
        common.id = 0;
        common.security = self.security.as_ref().map(|s| s.dir.clone());
        let hierarchy = errors.section("hierarchy", Hierarchy::from_table(&self.hierarchy));
        let z = &mut self.zenoh;
        if z.listen.is_empty() && z.connect.is_empty() {
            let rule = "name at least one endpoint in `listen` or `connect`";
            errors.add("zenoh.listen", "[]", rule);
        }
        for (list, endpoints) in [("listen", &z.listen), ("connect", &z.connect)] {
            for (i, endpoint) in endpoints.iter().enumerate() {
                if let Err(rule) = check_endpoint(endpoint) {
                    errors.add(format!("zenoh.{list}[{i}]"), format!("{endpoint:?}"), rule);
                }
            }
        }
        let lease = *z.lease_ms.get_or_insert(3000);
        let lease = errors.int::<u64>("zenoh.lease_ms", lease, 1000..=60_000, " ms");
        let mut peers = Vec::new();
        let mut unique = Unique::default();
        // An id belongs to one site: to one other site, or to this one (offered).
        let mut owners = Unique::default();
        let offered: std::collections::BTreeSet<DeviceId> = z
            .site
            .iter()
            .flat_map(|p| p.offer.iter().copied())
            .collect();
        for (i, peer) in z.site.iter_mut().enumerate() {
            let key = format!("zenoh.site[{i}].name");
            let Some(site) = name(&mut errors, &key, &peer.name) else {
                continue;
            };
            if Some(&site) == me.as_ref() {
                errors.add(&key, format!("{:?}", peer.name), "is this site's own name");
            }
            let shown = (key.as_str(), format!("{:?}", peer.name));
            unique.check(&mut errors, site.clone(), format!("site[{i}]"), shown, "");
            for (list, ids) in [("ids", &peer.ids), ("offer", &peer.offer)] {
                for (j, id) in ids.iter().enumerate() {
                    if *id <= 0 {
                        let key = format!("zenoh.site[{i}].{list}[{j}]");
                        errors.add(key, id, "must be a positive device id");
                    }
                }
            }
            for (j, id) in peer.ids.iter().enumerate() {
                let key = format!("zenoh.site[{i}].ids[{j}]");
                if offered.contains(id) {
                    let rule = "is offered as this site's vehicle: an id belongs to one site";
                    errors.add(&key, id, rule);
                }
                let shown = (key.as_str(), id);
                owners.check(&mut errors, *id, format!("site[{i}].ids"), shown, "");
            }
            peers.push(Peer {
                name: site,
                ids: peer.ids.iter().copied().collect(),
                offer: peer.offer.iter().copied().collect(),
                level: *peer.level.get_or_insert(Level::Remote),
            });
        }
        let link = ZenohLink {
            listen: z.listen.clone(),
            connect: z.connect.clone(),
            ca: z.ca.clone(),
            certificate: z.certificate.clone(),
            key: z.key.clone(),
            lease: Duration::from_millis(lease.unwrap_or(3000)),
        };
        let Some(me) = me else {
            // `site.name` is invalid, and `name` recorded why.
            return Err(rove_core::Error::Config(errors));
        };
        let policy = Policy {
            me,
            hierarchy: hierarchy.unwrap_or(Hierarchy::STANDARD),
            peers,
        };
        errors.into_result(BridgeConfig {
            common,
            policy,
            link,
        })
    }
}

/// A link endpoint as the bridge takes it: `tls/HOST:PORT` (the link is always mutual TLS).
fn check_endpoint(endpoint: &str) -> Result<(), &'static str> {
    let Some(address) = endpoint.strip_prefix("tls/") else {
        return Err("must be `tls/HOST:PORT`: sites meet only over mutual TLS");
    };
    let (host, port) = address
        .rsplit_once(':')
        .ok_or("must be `tls/HOST:PORT` (no port)")?;
    if host.is_empty() || port.parse::<u16>().is_err() {
        return Err("must be `tls/HOST:PORT` with a port 0 to 65535");
    }
    Ok(())
}

rove_core::config_types! {
    /// A config file, either role, for `rove check-config`.
    #[derive(Debug)]
    pub enum AnyConfig {
        Vehicle => "A vehicle's file." (VehicleConfig),
        Operator => "An operator's file." (OperatorConfig),
        Bridge => "A site bridge's file." (BridgeConfig),
    }
}

/// Loads a file of either role, telling them apart by their `[vehicle]`/`[output]` or
/// `[operator]` table; also returns the effective config: the file's settings with every
/// default filled in, as TOML that loads again as the same config.
///
/// # Errors
/// As [`load_vehicle`]; also when the file has neither role's table.
pub fn load_any(path: &Path) -> anyhow::Result<(AnyConfig, String)> {
    any_from_text(path, &read(path)?)
}

/// [`load_any`] of `text`, read from `path` (`path` only names the file in messages; nothing
/// is read). Public for the fuzz targets, which feed every config kind through it.
///
/// # Errors
/// As [`load_any`].
pub fn any_from_text(path: &Path, text: &str) -> anyhow::Result<(AnyConfig, String)> {
    let table: toml::Table = toml::from_str(text)
        .map_err(|e| anyhow!("{}: {}", path.display(), e.to_string().trim_end()))?;
    let located = |e| located(path, text, e);
    let (config, effective) = if table.contains_key("zenoh") {
        let mut raw: RawBridge = parse(path, text)?;
        let config = AnyConfig::Bridge(raw.validate().map_err(located)?);
        (config, toml::to_string(&raw))
    } else if table.contains_key("operator") {
        let mut raw: RawOperator = parse(path, text)?;
        let config = AnyConfig::Operator(raw.validate().map_err(located)?);
        (config, toml::to_string(&raw))
    } else if table.contains_key("output") || table.contains_key("vehicle") {
        let mut raw = parse_vehicle(path, text)?;
        let config = AnyConfig::Vehicle(raw.validate().map_err(located)?);
        (config, toml::to_string(&raw))
    } else {
        return Err(anyhow!(
            "{}: neither a vehicle config ([output]), an operator config ([operator]) nor a \
             bridge config ([zenoh])",
            path.display()
        ));
    };
    let effective = effective.context("cannot write the effective config as TOML")?;
    Ok((config, effective))
}

fn read(path: &Path) -> anyhow::Result<String> {
    std::fs::read_to_string(path).with_context(|| format!("cannot read {}", path.display()))
}

fn parse<T: for<'de> Deserialize<'de>>(path: &Path, text: &str) -> anyhow::Result<T> {
    toml::from_str(text).map_err(|e| {
        let line = e
            .span()
            .map(|span| text[..span.start.min(text.len())].matches('\n').count() + 1);
        let message = e.message().trim_end();
        match line {
            Some(line) => anyhow!("{}:{line}: {message}", path.display()),
            None => anyhow!("{}: {message}", path.display()),
        }
    })
}

/// Turns validation errors into one message per problem, each `file:line: key = value: rule`.
fn located(path: &Path, text: &str, error: rove_core::Error) -> anyhow::Error {
    match error {
        rove_core::Error::Config(errors) => {
            let lines: Vec<String> = errors
                .0
                .iter()
                .map(|e| match key_line(text, &e.key) {
                    Some(line) => format!("{}:{line}: {e}", path.display()),
                    None => format!("{}: {e}", path.display()),
                })
                .collect();
            anyhow!("{}", lines.join("\n"))
        }
        other => anyhow!("{}: {other}", path.display()),
    }
}

/// The 1-based line where the dotted `key` (`operator.stream_hz`, `output.channels[2].max_us`,
/// `hierarchy.mobile.laptop` in an inline table, `operator.drive[1]`) is written, from the
/// parsed document's own positions; a key in an older spelling counts as its current name. An
/// absent key (left to a default that broke a rule) points at the nearest table that holds it;
/// `None` if nothing of it is in the file.
pub fn key_line(text: &str, key: &str) -> Option<usize> {
    use toml_edit::{Item, TableLike, Value};
    let doc = toml_edit::ImDocument::parse(text).ok()?;
    // The byte offset of the deepest part of `key` found so far.
    let (mut table, mut at): (&dyn TableLike, Option<usize>) = (doc.as_table(), None);
    for segment in key.split('.') {
        let (name, index) = match segment.split_once('[') {
            Some((name, i)) => (name, i.trim_end_matches(']').parse::<usize>().ok()),
            None => (segment, None),
        };
        let old = rove_core::config::ALIASES
            .iter()
            .filter(|(_, new)| *new == name);
        let names = std::iter::once(name).chain(old.map(|(old, _)| *old));
        let Some((k, item)) = names.into_iter().find_map(|n| table.get_key_value(n)) else {
            break;
        };
        at = k.span().or(item.span()).map(|span| span.start).or(at);
        let next = match (item, index) {
            (Item::ArrayOfTables(tables), Some(i)) => tables.get(i).map(|t| {
                at = t.span().map(|span| span.start).or(at);
                t as &dyn TableLike
            }),
            (Item::Value(Value::Array(values)), Some(i)) => values.get(i).and_then(|v| {
                at = v.span().map(|span| span.start).or(at);
                v.as_inline_table().map(|t| t as &dyn TableLike)
            }),
            (item, _) => item.as_table_like(),
        };
        let Some(next) = next else { break };
        table = next;
    }
    at.map(|at| text[..at.min(text.len())].matches('\n').count() + 1)
}

const DEFAULT_HEARTBEAT_MS: Int = 500;
const DEFAULT_STREAM_HZ: Int = 50;

fn validate_common(
    device: &mut DeviceSection,
    network: &mut NetworkSection,
    log: &LogSection,
    errors: &mut ConfigErrors,
) -> Common {
    let heartbeat_ms = *network.heartbeat_ms.get_or_insert(DEFAULT_HEARTBEAT_MS);
    let heartbeat = errors.int("network.heartbeat_ms", heartbeat_ms, 50..=10_000, "");
    // At most half the DeviceInfo writer's 1 s lease, which the announcements assert for
    // foreign readers; at least the 250 ms at which liveness is reported.
    let default_presence = crate::dds::DEFAULT_PRESENCE.as_millis() as Int;
    let presence_ms = *network.presence_ms.get_or_insert(default_presence);
    let rule = " (at least the 250 ms liveness report period, at most half the DeviceInfo \
                writer's 1 s lease)";
    let presence = errors.int("network.presence_ms", presence_ms, 250..=500, rule);
    if device.id <= 0 {
        errors.add("device.id", device.id, "must be a positive device id");
    }
    let domain_id = *network.domain_id.get_or_insert(0);
    // RTPS maps domain ids to ports (7400 + 250 × domain); above 232 the ports overflow.
    let rule = " (RTPS port mapping)";
    let domain_id = errors.int("network.domain_id", domain_id, 0..=232, rule);
    if let Some(level) = &log.level
        && !is_log_filter(level)
    {
        let rule = "must be a level (off, error, warn, info, debug, trace) or comma-separated \
                    `target=level` directives";
        errors.add("log.level", format!("{level:?}"), rule);
    }
    let interfaces = (network.interfaces).get_or_insert_with(|| vec![Ipv4Addr::LOCALHOST]);
    if interfaces.is_empty() {
        let rule = "must name at least one interface address (absent: loopback)";
        errors.add("network.interfaces", "[]", rule);
    }
    let id = device.id;
    let name = device.name.get_or_insert_with(|| format!("rove-{id}"));
    let log_filter = |level: &String| match level.contains("rustdds") {
        true => level.clone(),
        false => format!("{level},rustdds=warn"),
    };
    Common {
        id,
        name: name.clone(),
        domain_id: domain_id.unwrap_or(0),
        interfaces: interfaces.clone(),
        heartbeat: Duration::from_millis(heartbeat.unwrap_or(500)),
        presence: presence.map_or(crate::dds::DEFAULT_PRESENCE, Duration::from_millis),
        log_filter: log.level.as_ref().map(log_filter),
        security: None,
    }
}

/// A log filter as `[log] level` takes it: levels and `target=level` directives. Stricter than
/// tracing's own parser, which takes a misspelt level for a target name and logs nothing.
fn is_log_filter(filter: &str) -> bool {
    const LEVELS: [&str; 6] = ["off", "error", "warn", "info", "debug", "trace"];
    let is_level = |l: &str| LEVELS.contains(&l.trim().to_ascii_lowercase().as_str());
    !filter.trim().is_empty()
        && filter.split(',').all(|d| match d.split_once('=') {
            Some((target, level)) => !target.trim().is_empty() && is_level(level),
            None => is_level(d),
        })
        && tracing_subscriber::EnvFilter::try_new(filter).is_ok()
}

impl RawVehicle<OutputSection> {
    /// Validates, filling defaults.
    ///
    /// # Errors
    /// [`rove_core::Error::Config`] listing every invalid key.
    pub fn validate(&mut self) -> rove_core::Result<VehicleConfig> {
        let mut errors = ConfigErrors::default();
        let mut common =
            validate_common(&mut self.device, &mut self.network, &self.log, &mut errors);
        common.security = self.security.as_ref().map(|s| s.dir.clone());
        let output = self.output.validate(&mut errors);
        let key = "vehicle.command_timeout_ms";
        let default = CommandTimeout::DEFAULT.get().as_millis();
        let millis = *(self.vehicle.command_timeout_ms).get_or_insert(default as Int);
        let timeout = errors
            .int(key, millis, 0..=Int::MAX, "")
            .and_then(|ms| errors.section("", CommandTimeout::from_millis(key, ms)));
        let v = &mut self.vehicle;
        let deadline = *v.output_deadline_ms.get_or_insert(50);
        let deadline = errors.int("vehicle.output_deadline_ms", deadline, 5..=10_000, " ms");
        let limit = *v.output_hung_limit_ms.get_or_insert(2000);
        let limit = errors.int("vehicle.output_hung_limit_ms", limit, 100..=600_000, " ms");
        let low = *v.battery_low_pct.get_or_insert(25);
        let low = errors.int::<u8>("vehicle.battery_low_pct", low, 0..=100, " %");
        let hierarchy = errors.section("hierarchy", Hierarchy::from_table(&self.hierarchy));
        let hierarchy = hierarchy.unwrap_or(Hierarchy::STANDARD);
        let access = match &self.access {
            None => Access::open(hierarchy),
            Some(section) => {
                let mut unique = Unique::default();
                for (i, entry) in section.operators.iter().enumerate() {
                    let key = format!("access.operators[{i}].id");
                    if entry.id <= 0 {
                        errors.add(&key, entry.id, "must be a positive device id");
                    }
                    let shown = (key.as_str(), entry.id);
                    unique.check(&mut errors, entry.id, format!("operators[{i}]"), shown, "");
                }
                Access::listed(hierarchy, &section.operators)
            }
        };
        errors.into_result(VehicleConfig {
            arbiter: ArbiterConfig {
                command_timeout: timeout.unwrap_or(CommandTimeout::DEFAULT),
                trust: common.trust(),
                ..ArbiterConfig::default()
            },
            common,
            access,
            output,
            output_deadline: Duration::from_millis(deadline.unwrap_or_default()),
            output_hung_limit: Duration::from_millis(limit.unwrap_or_default()),
            battery_low_pct: low.unwrap_or_default(),
        })
    }
}

impl RawOperator {
    /// Validates, filling defaults into `self`.
    ///
    /// # Errors
    /// [`rove_core::Error::Config`] listing every invalid key.
    pub fn validate(&mut self) -> rove_core::Result<OperatorConfig> {
        let mut errors = ConfigErrors::default();
        let mut common =
            validate_common(&mut self.device, &mut self.network, &self.log, &mut errors);
        common.security = self.security.as_ref().map(|s| s.dir.clone());
        let hierarchy = errors.section("hierarchy", Hierarchy::from_table(&self.hierarchy));
        let hierarchy = hierarchy.unwrap_or(Hierarchy::STANDARD);
        let op = &mut self.operator;
        let (level, class, offset) = (op.level, op.device_class, *op.offset.get_or_insert(0));
        let strength = operator_strength(
            &hierarchy,
            level,
            class,
            offset,
            "operator.offset",
            &mut errors,
        );
        let strength = strength.unwrap_or(Strength(1));
        let stream_hz = *op.stream_hz.get_or_insert(DEFAULT_STREAM_HZ);
        let rule = "; at least 10 keeps a vehicle with the default 100 ms command timeout from \
                    timing out between samples";
        let stream_hz = errors.int::<u32>("operator.stream_hz", stream_hz, 1..=1000, rule);
        let handover = errors.section("handover", self.handover.validate());
        let handover = handover.unwrap_or_default();
        for (i, v) in op.drive.iter().enumerate() {
            if *v == self.device.id {
                let rule = "is this operator's own device id";
                errors.add(format!("operator.drive[{i}]"), v, rule);
            }
        }
        let constant = InputChoice::Constant(MovementCommand::CENTRED, Mode::Manual);
        let mut device = |settings: &mut rove_inputs::InputSettings, kind| {
            let input = errors.section("input", settings.validate_as(kind));
            input.map_or(constant.clone(), |c| InputChoice::Device(Box::new(c)))
        };
        let centred = || InputSection::Constant(ConstantInput::default());
        let input = match self.input.get_or_insert_with(centred) {
            InputSection::Constant(c) => {
                let range = || i16::MIN.into()..=i16::MAX.into();
                let mut stick = |key, v| errors.int(key, v, range(), "").unwrap_or(0);
                let movement = MovementCommand {
                    throttle: stick("input.throttle", c.throttle),
                    roll: stick("input.roll", c.roll),
                    pitch: stick("input.pitch", c.pitch),
                    yaw: stick("input.yaw", c.yaw),
                };
                InputChoice::Constant(movement, (*c.mode.get_or_insert(ModeName::Manual)).into())
            }
            InputSection::Joystick(s) => device(s, rove_inputs::SourceKind::Joystick),
            InputSection::Keyboard(s) => device(s, rove_inputs::SourceKind::Keyboard),
            InputSection::Replay(s) => device(s, rove_inputs::SourceKind::Replay),
        };
        let mut config = OperatorConfig {
            common,
            level,
            device_class: class,
            strength,
            stream_period: Duration::from_secs_f64(1.0 / f64::from(stream_hz.unwrap_or(1))),
            drive: self.operator.drive.clone(),
            handover,
            input,
            api_socket: self.console.api_socket.clone(),
            web: None,
        };
        if let Some(web) = &mut self.web {
            config.web = errors.within("web", |e| web.validate(&config, &hierarchy, e));
        }
        errors.into_result(config)
    }
}

/// An operator's strength from its level, class and `offset` (written at `key`): the offset
/// is checked against 0..=9, the rest is the hierarchy's.
fn operator_strength(
    hierarchy: &Hierarchy,
    level: Level,
    class: DeviceClass,
    offset: Int,
    key: &str,
    errors: &mut ConfigErrors,
) -> Option<Strength> {
    let offset_range = 0..=Int::from(rove_core::hierarchy::MAX_OFFSET);
    (errors.int(key, offset, offset_range, ""))
        .and_then(|o| hierarchy.strength(level, class, o).ok())
}

/// How long a pairing lasts without `session_s`: a working day.
const DEFAULT_WEB_SESSION_S: Int = 43_200;

impl WebSection {
    /// Validates `[web]` of the operator `host`; each device becomes an operator of its own.
    fn validate(
        &mut self,
        host: &OperatorConfig,
        hierarchy: &Hierarchy,
        errors: &mut ConfigErrors,
    ) -> Option<WebConfig> {
        let listen = match self.listen.parse::<std::net::SocketAddr>() {
            Ok(a) => Some(a),
            Err(_) => {
                errors.add(
                    "listen",
                    &self.listen,
                    "must be ADDRESS:PORT, such as 0.0.0.0:8443",
                );
                None
            }
        };
        let certificate = match (&self.certificate, &self.key) {
            (Some(c), Some(k)) => Some((c.clone(), k.clone())),
            (None, None) => None,
            (Some(_), None) => {
                errors.add("key", ABSENT, "is required with `certificate`");
                None
            }
            (None, Some(_)) => {
                errors.add("certificate", ABSENT, "is required with `key`");
                None
            }
        };
        let session_s = *self.session_s.get_or_insert(DEFAULT_WEB_SESSION_S);
        let session = errors.int::<u64>("session_s", session_s, 1..=2_592_000, " s");
        if self.device.is_empty() {
            errors.add("device", ABSENT, "needs at least one [[web.device]]");
        }
        let mut seen = std::collections::BTreeSet::from([host.common.id]);
        let mut devices = Vec::new();
        for (i, d) in self.device.iter_mut().enumerate() {
            let at = format!("device[{i}]");
            if !seen.insert(d.id) {
                let rule = "is used twice (the operator's own id or another web device)";
                errors.add(format!("{at}.id"), d.id, rule);
            }
            let level = *d.level.get_or_insert(Level::Mobile);
            let class = *d.device_class.get_or_insert(DeviceClass::Phone);
            let offset = *d.offset.get_or_insert(0);
            let key = format!("{at}.offset");
            let strength = operator_strength(hierarchy, level, class, offset, &key, errors);
            if host.common.security.is_some() && d.security.is_none() {
                let rule = "is required: the operator has [security], and each web device is a \
                            participant with its own certificate";
                errors.add(format!("{at}.security"), ABSENT, rule);
            }
            let name = d
                .name
                .get_or_insert_with(|| format!("web-{}", d.id))
                .clone();
            let mut common = host.common.clone();
            (common.id, common.name, common.security) = (d.id, name, d.security.clone());
            devices.push(OperatorConfig {
                common,
                level,
                device_class: class,
                strength: strength.unwrap_or(Strength(1)),
                stream_period: host.stream_period,
                drive: d.drive.clone(),
                handover: host.handover,
                input: InputChoice::Constant(MovementCommand::CENTRED, Mode::Manual),
                api_socket: None,
                web: None,
            });
        }
        Some(WebConfig {
            listen: listen?,
            certificate,
            session: Duration::from_secs(session?),
            devices,
        })
    }
}

/// The path of a config shipped in `configs/`.
#[cfg(test)]
pub fn shipped(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("..")
        .join("configs")
        .join(name)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn write(name: &str, text: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("rove-config-test-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("temp dir");
        let path = dir.join(name);
        std::fs::write(&path, text).expect("write");
        path
    }

    /// Issue 30: docs/mavlink.md's steps drive what they start. In each section of the guide,
    /// every operator config it names drives every vehicle config it names, and a vehicle's
    /// MAVLink `connection` is the endpoint the section gives (in backquotes).
    #[test]
    fn the_mavlink_guides_steps_drive_the_vehicles_they_start() {
        let guide = shipped("../docs/mavlink.md");
        let text = std::fs::read_to_string(&guide).expect("docs/mavlink.md");
        let named = |section: &str, role: &str| -> Vec<String> {
            let needle = format!("rove {role} -c configs/");
            section
                .match_indices(&needle)
                .filter_map(|(at, _)| {
                    let rest = &section[at + needle.len()..];
                    let end = rest.find(|c: char| c.is_whitespace() || c == '`')?;
                    Some(rest[..end].to_string())
                })
                .collect()
        };
        let mut pairs = 0;
        for section in text.split("\n## ") {
            let vehicles = named(section, "vehicle");
            let operators = named(section, "operator");
            for vehicle in &vehicles {
                let path = shipped(vehicle);
                let config = load_vehicle(&path).unwrap_or_else(|e| panic!("{e:#}"));
                let raw: toml::Table =
                    toml::from_str(&std::fs::read_to_string(&path).expect("read")).expect("toml");
                if let Some(connection) = raw
                    .get("output")
                    .and_then(|o| o.get("connection"))
                    .and_then(|c| c.as_str())
                {
                    assert!(
                        section.contains(&format!("`{connection}`")),
                        "{vehicle}: connection {connection} is not the guide's"
                    );
                }
                for operator in &operators {
                    let op = load_operator(&shipped(operator)).unwrap_or_else(|e| panic!("{e:#}"));
                    assert!(
                        op.drive.contains(&config.common.id),
                        "{operator} drives {:?}, not {vehicle}'s id {}",
                        op.drive,
                        config.common.id
                    );
                    pairs += 1;
                }
            }
        }
        assert!(pairs >= 2, "the guide names {pairs} vehicle/operator pairs");
    }

    #[test]
    fn every_shipped_config_loads() {
        let dir = shipped("");
        let mut seen = 0;
        for entry in std::fs::read_dir(&dir).expect("configs/ exists") {
            let path = entry.expect("entry").path();
            if path.extension().is_some_and(|e| e == "toml") {
                let (config, effective) = load_any(&path).unwrap_or_else(|e| panic!("{e:#}"));
                // The effective config loads again as the same config, and is a fixed point.
                let again = any_from_text(Path::new("effective.toml"), &effective);
                let (again, effective_again) =
                    again.unwrap_or_else(|e| panic!("{e:#}\n{effective}"));
                assert_eq!(
                    format!("{again:?}"),
                    format!("{config:?}"),
                    "{}",
                    path.display()
                );
                assert_eq!(effective_again, effective, "{}", path.display());
                seen += 1;
            }
        }
        assert!(seen >= 3, "only {seen} configs in {}", dir.display());
    }

    #[test]
    fn each_output_adapter_loads_from_its_shipped_example() {
        let kind = |name: &str| match load_vehicle(&shipped(name)) {
            Ok(c) => crate::output::kind(&c.output),
            Err(e) => panic!("{e:#}"),
        };
        assert_eq!(kind("vehicle-sim.toml"), "sim");
        assert_eq!(kind("vehicle-custom-pwm.toml"), "pwm");
        assert_eq!(kind("vehicle-eyedrive-pi.toml"), "eyedrive");
        assert_eq!(kind("vehicle-naza-pi.toml"), "naza");
        assert_eq!(kind("vehicle-ardupilot-rover-sitl.toml"), "mavlink");
        assert_eq!(kind("vehicle-ardupilot-copter-serial.toml"), "mavlink");
        assert_eq!(kind("vehicle-px4-udp.toml"), "mavlink");
        assert_eq!(kind("vehicle-can-skid-steer.toml"), "can");
        assert_eq!(kind("vehicle-dronecan-servos.toml"), "can");
    }

    #[test]
    fn access_lists_who_may_drive_and_its_errors_name_their_keys() {
        let head = "[device]\nid = 100\n[output]\nadapter = \"sim\"\n";
        let open = load_vehicle(&write("open.toml", head)).expect("loads");
        assert!(open.access.is_open());
        let listed = format!(
            "{head}[access]\noperators = [\n  {{ id = 11, level = \"stationary\", \
             device_class = \"laptop\" }},\n]\n"
        );
        let config = load_vehicle(&write("access.toml", &listed)).expect("loads");
        assert!(!config.access.is_open());
        assert_eq!(config.access.check_strength(11, Strength(229)), Ok(()));
        assert!(config.access.check_strength(12, Strength(110)).is_err());
        let bad = format!(
            "{head}[access]\noperators = [\n  {{ id = 11, level = \"mobile\", device_class = \"phone\" }},\n  \
             {{ id = 11, level = \"remote\", device_class = \"desktop\" }},\n]\n"
        );
        let e = format!(
            "{:#}",
            load_vehicle(&write("bad-access.toml", &bad)).expect_err("dup")
        );
        assert!(
            e.contains("access.operators[1].id = 11: must be unique"),
            "{e}"
        );
        let typo = format!("{head}[access]\noperators = [{{ id = 11, levle = \"mobile\" }}]\n");
        let e = format!(
            "{:#}",
            load_vehicle(&write("typo.toml", &typo)).expect_err("typo")
        );
        assert!(e.contains("levle"), "{e}");
    }

    #[test]
    fn web_devices_are_operators_of_their_own_and_their_errors_name_lines() {
        let config = load_operator(&shipped("operator-web.toml")).expect("shipped web host");
        let web = config.web.expect("[web]");
        assert_eq!(web.listen.port(), 8443);
        assert_eq!(web.session, Duration::from_secs(43_200));
        let (cert, _) = web.certificate.expect("files");
        assert_eq!(cert, Path::new("/var/lib/rove/web-cert.pem"));
        let phone = &web.devices[0];
        assert_eq!((phone.common.id, phone.strength), (40, Strength(340)));
        assert_eq!(phone.drive, vec![100]);
        assert_eq!(phone.common.domain_id, config.common.domain_id);
        assert_eq!(web.devices[1].strength, Strength(330), "a mobile tablet");
        let text = "[device]\nid = 20\n[operator]\nlevel = \"remote\"\ndevice_class = \"desktop\"\n\
                    [security]\ndir = \"keys\"\n[web]\nlisten = \"8443\"\ncertificate = \"a.pem\"\n\
                    session_s = 0\n[[web.device]]\nid = 20\n[[web.device]]\nid = 41\noffset = 12\n";
        let message = format!(
            "{:#}",
            load_operator(&write("web.toml", text)).expect_err("bad")
        );
        for want in [
            "web.toml:9: web.listen = 8443: must be ADDRESS:PORT",
            "web.toml:8: web.key = (absent): is required with `certificate`",
            "web.toml:11: web.session_s = 0: must be 1..=2592000 s",
            "web.toml:13: web.device[0].id = 20: is used twice",
            "web.toml:12: web.device[0].security = (absent): is required",
            "web.toml:16: web.device[1].offset = 12: must be 0..=9",
        ] {
            assert!(message.contains(want), "missing {want:?} in\n{message}");
        }
        let none = "[device]\nid = 20\n[operator]\nlevel = \"remote\"\ndevice_class = \"desktop\"\n\
                    [web]\nlisten = \"127.0.0.1:1\"\n";
        let message = format!(
            "{:#}",
            load_operator(&write("none.toml", none)).expect_err("no device")
        );
        assert!(
            message.contains("web.device = (absent): needs at least one"),
            "{message}"
        );
    }

    #[test]
    fn bridge_files_say_who_may_speak_and_their_errors_name_lines() {
        let lab = load_bridge(&shipped("bridge-lab.toml")).expect("shipped lab bridge");
        assert_eq!(lab.policy.me.as_str(), "lab");
        assert_eq!(lab.link.listen, vec!["tls/203.0.113.7:7447".to_string()]);
        assert_eq!(lab.link.lease, Duration::from_secs(3));
        let home = &lab.policy.peers[0];
        assert_eq!(home.name.as_str(), "home");
        assert_eq!(home.ids, [21, 22].into());
        assert_eq!(home.offer, [100].into());
        assert_eq!(home.level, Level::Remote);
        let text = "[site]\nname = \"Lab\"\n[zenoh]\nlisten = [\"tcp/1.2.3.4:7447\"]\n\
                    connect = [\"tls/nowhere\"]\nca = \"a\"\ncertificate = \"b\"\nkey = \"c\"\n\
                    lease_ms = 10\n[[zenoh.site]]\nname = \"home\"\nids = [0, 7]\n\
                    [[zenoh.site]]\nname = \"home\"\nlevel = \"mobile\"\nids = [7, 9]\n\
                    offer = [9]\n";
        let message = format!(
            "{:#}",
            load_bridge(&write("b.toml", text)).expect_err("bad")
        );
        for want in [
            "b.toml:2: site.name = \"Lab\": must be lowercase letters",
            "b.toml:4: zenoh.listen[0] = \"tcp/1.2.3.4:7447\": must be `tls/HOST:PORT`",
            "b.toml:5: zenoh.connect[0] = \"tls/nowhere\": must be `tls/HOST:PORT` (no port)",
            "b.toml:9: zenoh.lease_ms = 10: must be 1000..=60000 ms",
            "b.toml:12: zenoh.site[0].ids[0] = 0: must be a positive device id",
            "b.toml:14: zenoh.site[1].name = \"home\": must be unique: site[0]",
            "b.toml:16: zenoh.site[1].ids[0] = 7: must be unique: site[0].ids",
            "b.toml:16: zenoh.site[1].ids[1] = 9: is offered as this site's vehicle",
        ] {
            assert!(message.contains(want), "missing {want:?} in\n{message}");
        }
        // An unknown key names its line; a secured site's `[security] dir` is the config's.
        let text = "[site]\nname = \"lab\"\n[zenoh]\nlisten = [\"tls/a:1\"]\nca = \"a\"\n\
                    certificate = \"b\"\nkey = \"c\"\n[security]\ndir = \"d\"\n";
        let path = write("s.toml", text);
        let security = load_bridge(&path).expect("loads").common.security;
        assert_eq!(security, Some(path.parent().expect("dir").join("d")));
        let text = text.replace("dir =", "directory =");
        let message = format!(
            "{:#}",
            load_bridge(&write("s.toml", &text)).expect_err("bad")
        );
        assert!(
            message.contains("s.toml:9: unknown field `directory`"),
            "{message}"
        );
        // A relative key file is the config file's directory's.
        let text = "[site]\nname = \"a\"\n[zenoh]\nlisten = [\"tls/a:1\"]\nca = \"k/ca.pem\"\n\
                    certificate = \"b\"\nkey = \"c\"\n";
        let path = write("rel.toml", text);
        let ca = load_bridge(&path).expect("loads").link.ca;
        assert_eq!(ca, path.parent().expect("dir").join("k/ca.pem"));
    }

    #[test]
    fn a_bridge_checks_its_certificate_files_are_readable_files() {
        let text = "[site]\nname = \"a\"\n[zenoh]\nlisten = [\"tls/a:1\"]\nca = \"certs/ca.pem\"\n\
                    certificate = \"certs/cert.pem\"\nkey = \"certs/KEY\"\n";
        let path = write("files.toml", text);
        let dir = path.parent().expect("dir").join("certs");
        std::fs::create_dir_all(&dir).expect("certs dir");
        for file in ["ca.pem", "cert.pem"] {
            std::fs::write(dir.join(file), file).expect("write");
        }
        let mut link = load_bridge(&path).expect("loads").link;
        let missing = format!("{:#}", link.check_files().expect_err("no key"));
        assert!(
            missing.starts_with("[zenoh] key = ") && missing.contains("KEY"),
            "{missing}"
        );
        link.key = dir.clone();
        let directory = format!("{:#}", link.check_files().expect_err("a directory"));
        assert!(directory.contains("not a file"), "{directory}");
        link.key = dir.join("cert.pem");
        link.check_files().expect("three readable files");
    }

    #[test]
    fn output_errors_name_the_line_of_the_channel_key() {
        let text = "[device]\nid = 7\n[output]\nadapter = \"pwm\"\nbackend = \"sim\"\n\
                    [[output.channels]]\nname = \"a\"\nsource = \"roll\"\nchannel = 0\n\
                    [[output.channels]]\nname = \"b\"\nsource = \"yaw\"\nchannel = 1\n\
                    min_us = 2000\nmax_us = 1000\n";
        let path = write("bad-channel.toml", text);
        let message = format!("{:#}", load_vehicle(&path).expect_err("min > max"));
        // min > max is reported on the centre (not written: the channel's header line).
        assert!(
            message.contains("bad-channel.toml:10: output.channels[1].centre_us"),
            "{message}"
        );
        // The sim adapter takes no other keys.
        let path = write(
            "sim-extra.toml",
            "[device]\nid = 7\n[output]\nadapter = \"sim\"\nbackend = \"sysfs\"\n",
        );
        let message = format!("{:#}", load_vehicle(&path).expect_err("unknown key"));
        assert!(message.contains("backend"), "{message}");
        // An unknown adapter is named.
        let path = write(
            "warp.toml",
            "[device]\nid = 7\n[output]\nadapter = \"warp\"\n",
        );
        let message = format!("{:#}", load_vehicle(&path).expect_err("unknown adapter"));
        assert!(message.contains("warp"), "{message}");
    }

    #[test]
    fn errors_inside_output_name_the_line_of_their_key() {
        // A misspelt key in the second channel table: line 17, not `[output]`'s line.
        let text = "[device]\nid = 7\n\n# a comment\n\n[output]\nadapter = \"pwm\"\n\
                    backend = \"sim\"\n\n[[output.channels]]\nname = \"a\"\nsource = \"roll\"\n\n\
                    [[output.channels]]\nname = \"b\"\nsource = \"yaw\"\nmax_uss = 1900\n";
        let path = write("bad.toml", text);
        let message = format!("{:#}", load_vehicle(&path).expect_err("misspelt key"));
        assert!(
            message.contains("bad.toml:17: output.channels[1].max_uss = 1900: unknown key"),
            "{message}"
        );
        // A type error in a table serde reads directly (no flattening) names its line too.
        let text = "[device]\nid = 7\n[output]\nadapter = \"mavlink\"\n[output.modes]\n\
                    set_mode = \"no\"\n";
        let path = write("bad-type.toml", text);
        let message = format!("{:#}", load_vehicle(&path).expect_err("bad type"));
        assert!(message.contains("bad-type.toml:6:"), "{message}");
        // An inline `[output]` and an alias written in the file.
        let text = "# inline\noutput = { backend = \"sim\", adapter = \"pwm\", \
                    channels = [{ name = \"a\", source = \"roll\", deadzone_pct = 70 }] }\n\
                    [device]\nid = 7\n";
        let path = write("inline.toml", text);
        let message = format!("{:#}", load_vehicle(&path).expect_err("deadband too wide"));
        assert!(
            message.contains("inline.toml:2: output.channels[0].deadband_pct = 70"),
            "{message}"
        );
        // Out-of-range integers are reported against their key, all at once.
        let text = "[device]\nid = 7\n[network]\ndomain_id = 70000\nheartbeat_ms = -1\n\
                    presence_ms = 10000\n[output]\nadapter = \"sim\"\n";
        let path = write("ints.toml", text);
        let message = format!("{:#}", load_vehicle(&path).expect_err("ranges"));
        assert!(
            message.contains("ints.toml:4: network.domain_id = 70000: must be 0..=232"),
            "{message}"
        );
        assert!(
            message.contains("ints.toml:5: network.heartbeat_ms = -1: must be 50..=10000"),
            "{message}"
        );
        assert!(
            message.contains("ints.toml:6: network.presence_ms = 10000: must be 250..=500"),
            "{message}"
        );
        let text = "[device]\nid = 5\n[operator]\nlevel = \"mobile\"\ndevice_class = \"phone\"\n\
                    offset = 300\n[hierarchy]\nmobile = { laptop = 70000 }\n[handover]\nresend_ms = -1\n";
        let path = write("wide.toml", text);
        let message = format!("{:#}", load_operator(&path).expect_err("ranges"));
        for want in [
            "wide.toml:8: hierarchy.mobile.laptop = 70000: must be 1..=65525",
            "wide.toml:6: operator.offset = 300: must be 0..=9",
            "wide.toml:10: handover.resend_ms = -1: must be 0..=9223372036854775807 ms",
        ] {
            assert!(message.contains(want), "missing {want:?} in\n{message}");
        }
    }

    #[test]
    fn log_level_is_checked_and_keeps_rustdds_quiet() {
        let base = "[device]\nid = 7\n[output]\nadapter = \"sim\"\n[log]\n";
        let path = write("log-ok.toml", &format!("{base}level = \"debug\"\n"));
        let config = load_vehicle(&path).expect("valid level");
        assert_eq!(
            config.common.log_filter.as_deref(),
            Some("debug,rustdds=warn")
        );
        let path = write(
            "log-rtps.toml",
            &format!("{base}level = \"info,rustdds=debug\"\n"),
        );
        let config = load_vehicle(&path).expect("valid directives");
        assert_eq!(
            config.common.log_filter.as_deref(),
            Some("info,rustdds=debug")
        );
        for bad in ["debgu", "loud=", "rustdds=verbose", ""] {
            let path = write("log-bad.toml", &format!("{base}level = \"{bad}\"\n"));
            let message = format!("{:#}", load_vehicle(&path).expect_err("bad level"));
            assert!(
                message.contains("log-bad.toml:6: log.level"),
                "{bad}: {message}"
            );
        }
        assert_eq!(
            load_vehicle(&shipped("vehicle-sim.toml"))
                .map(|c| c.common.log_filter)
                .ok(),
            Some(None)
        );
    }

    #[test]
    fn unknown_key_names_file_line_and_key() {
        let path = write(
            "unknown.toml",
            "[device]\nid = 5\n\n[operator]\nlevel = \"mobile\"\ndevice_class = \"phone\"\nstream_rate = 5\n",
        );
        let err = format!("{:#}", load_operator(&path).expect_err("unknown key"));
        assert!(err.contains("unknown.toml:7:"), "{err}");
        assert!(err.contains("unknown field `stream_rate`"), "{err}");
    }

    #[test]
    fn invalid_values_are_all_reported_with_their_lines() {
        let path = write(
            "invalid.toml",
            "[device]\nid = 5\n\n[operator]\nlevel = \"mobile\"\ndevice_class = \"phone\"\n\
             offset = 12\nstream_hz = 0\ndrive = [5]\n\n[hierarchy]\nmobile = { laptop = 315 }\n",
        );
        let err = format!("{:#}", load_operator(&path).expect_err("invalid"));
        for expected in [
            "invalid.toml:12: hierarchy.mobile.laptop = 315",
            "invalid.toml:7: operator.offset = 12",
            "invalid.toml:8: operator.stream_hz = 0",
            "invalid.toml:9: operator.drive[0] = 5",
        ] {
            assert!(err.contains(expected), "missing {expected:?} in:\n{err}");
        }
    }

    #[test]
    fn vehicle_defaults_are_quiet_and_bad_timeout_is_loud() {
        let path = write(
            "vehicle.toml",
            "[device]\nid = 100\n\n[output]\nadapter = \"sim\"\n",
        );
        let v = load_vehicle(&path).expect("valid");
        assert_eq!(v.common.interfaces, [Ipv4Addr::LOCALHOST]);
        assert_eq!(v.arbiter.command_timeout, CommandTimeout::DEFAULT);
        assert_eq!(v.common.name, "rove-100");
        assert_eq!(v.common.presence, crate::dds::DEFAULT_PRESENCE);
        let path = write(
            "vehicle-bad.toml",
            "[device]\nid = 100\n[vehicle]\ncommand_timeout_ms = 0\n[output]\nadapter = \"sim\"\n",
        );
        let err = format!("{:#}", load_vehicle(&path).expect_err("timeout 0"));
        assert!(
            err.contains("vehicle-bad.toml:4: vehicle.command_timeout_ms = 0"),
            "{err}"
        );
    }

    #[test]
    fn unknown_adapter_is_rejected_naming_the_line() {
        let path = write(
            "adapter.toml",
            "[device]\nid = 100\n[output]\nadapter = \"warp\"\n",
        );
        let err = format!("{:#}", load_vehicle(&path).expect_err("no such adapter"));
        assert!(err.contains("adapter.toml:4:"), "{err}");
    }

    #[test]
    fn key_line_finds_tables_keys_and_inline_entries() {
        let text = "[a]\nx = 1\n[b.c]\ny = { z = 2 }\n";
        assert_eq!(key_line(text, "a.x"), Some(2));
        assert_eq!(key_line(text, "b.c.y.z"), Some(4));
        assert_eq!(key_line(text, "b.c"), Some(3));
        assert_eq!(key_line(text, "q"), None);
        let text = "[output]\nadapter = \"pwm\"\n[[output.channels]]\nname = \"a\"\n\
                    [[output.channels]]\nname = \"b\"\nmax_us = 3000\n";
        assert_eq!(key_line(text, "output.channels[1].max_us"), Some(7));
        assert_eq!(key_line(text, "output.channels[0].name"), Some(4));
        // A key left to its default points at its table's header.
        assert_eq!(key_line(text, "output.channels[1].min_us"), Some(5));
        assert_eq!(key_line(text, "output.adapter"), Some(2));
    }
}
